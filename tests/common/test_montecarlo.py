"""sensorless montecarlo, the shared part: spread options, reproducible chunked draws, clipping, the
rank correlation, one-line errors, and a run on a motor of the examples (not a preset) whose outputs
are deterministic."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from sensorless.design import montecarlo as mc
from sensorless.reports.cli.main import main

EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples" / "motors"
PARAMS = (
    mc.Uncertain("a", 2.0, 2.5, "ohm", True),
    mc.Uncertain("b", 1e-3, 1e-3, "H", True),
    mc.Uncertain("J", 0.01, None, "kg m^2", False),
)


def test_spreads_parse_with_their_distribution_and_refuse_bad_entries():
    s = mc.parse_spreads("a=10%,J=30%u", "--spread", PARAMS, False)
    assert s == {"a": mc.Spread(0.1, False), "J": mc.Spread(0.3, True)}
    for text, part in (
        ("a=10", "is not NAME=X%"),
        ("q=5%", "not one of the drive's parameters"),
        ("a=5%,a=6%", "given twice"),
        ("a=50%", "non-physical"),
        ("a=100%u", "non-physical"),
        ("a=nan%", "NAME=X%"),
        ("a=-5%", "a finite percentage >= 0"),
    ):
        with pytest.raises(mc.SpreadError, match=part):
            mc.parse_spreads(text, "--spread", PARAMS, False)
    with pytest.raises(mc.SpreadError, match="estimated parameters"):
        mc.parse_spreads("J=5%", "--estimate-error", PARAMS, True)


def test_draws_depend_on_seed_and_index_only_and_follow_their_distribution():
    plant = {"a": mc.Spread(0.1), "J": mc.Spread(0.2, True)}
    est = {"a": mc.Spread(0.05)}
    long = mc.draw(PARAMS, 4 * mc.CHUNK + 3, 7, plant, est)
    short = mc.draw(PARAMS, mc.CHUNK + 1, 7, plant, est)
    np.testing.assert_array_equal(long.plant[: mc.CHUNK + 1], short.plant)
    np.testing.assert_array_equal(long.estimate[: mc.CHUNK + 1], short.estimate)
    assert not np.array_equal(mc.draw(PARAMS, 10, 8, plant, est).plant, long.plant[:10])
    # spreading one more parameter leaves the others' draws as they were
    more = mc.draw(PARAMS, 4 * mc.CHUNK + 3, 7, {**plant, "b": mc.Spread(0.1)}, est)
    np.testing.assert_array_equal(more.plant[:, [0, 2]], long.plant[:, [0, 2]])
    dev = long.plant[:, 0] / 2.0 - 1
    assert abs(dev.std() - 0.1) < 0.01 and abs(dev.mean()) < 0.01
    uni = long.plant[:, 2] / 0.01 - 1
    assert uni.min() >= -0.2 and uni.max() <= 0.2 and uni.std() == pytest.approx(0.2 / np.sqrt(3), rel=0.1)
    np.testing.assert_array_equal(long.plant[:, 1], 1e-3)  # not spread
    e = long.estimate[:, 0] / 2.5 - 1  # around the estimate, independent of the plant's draw
    assert abs(e.std() - 0.05) < 0.005 and abs(np.corrcoef(e, dev)[0, 1]) < 0.1


def test_non_physical_draws_are_clipped_and_counted():
    d = mc.draw(PARAMS, 4000, 1, {"J": mc.Spread(0.45)}, {})
    # P(1 + 0.45 z <= 0) = Phi(-2.22) = 1.3 %: about 53 of 4000
    n = d.clipped["plant J"]
    assert 25 < n < 90
    assert (d.plant[:, 2] > 0).all() and (d.plant[:, 2] == mc.CLIP_FRACTION * 0.01).sum() == n


def test_spearman_matches_scipy_with_ties_and_infinities():
    from scipy.stats import spearmanr  # here, not at collection: ~0.9 s a worker that runs no such test

    rng = np.random.default_rng(0)
    a = rng.standard_normal(300)
    b = np.round(a + rng.standard_normal(300), 1)
    b[:20] = -np.inf  # draws without equilibrium rank lowest, tied
    assert mc.spearman(a, b) == pytest.approx(spearmanr(a, b).statistic, abs=1e-12)


@pytest.fixture(scope="module")
def servo(tmp_path_factory):
    """A non-preset drive: the examples' 400-W servo, completed by sensorless init."""
    d = tmp_path_factory.mktemp("servo")
    assert main(["init", str(EXAMPLES / "servo400.toml"), "--out", str(d / "servo.toml")]) == 0
    path = d / "servo.toml"
    text = path.read_text(encoding="utf-8")
    assert "\nspeeds = 20" in text
    path.write_text(
        text.replace("\nspeeds = 20", "\nspeeds = 3"), encoding="utf-8"
    )  # a coarser envelope: fast
    return str(path)


def _run(argv, capsys):
    code = main(["montecarlo", *argv])
    return code, capsys.readouterr()


@pytest.mark.parametrize(
    ("argv", "part"),
    [
        (["--spread", "R_s=60%"], "--spread: 'R_s=60%': a normal spread of 50 % or more"),
        (["--spread", "Q=5%"], "--spread: 'Q' is not one of"),
        (["--estimate-error", "J=5%"], "--estimate-error: 'J' is not one of the drive's estimated"),
        (["--spread", ""], "--spread: empty"),  # none given: the family's typical spread
        (["--spread", "R_s=5%", "--samples", "3", "--time-domain", "4"], "--time-domain: 4 is more"),
        (["--spread", "R_s=5%", "--workers", "2", "--scheduler", "synchronous"], "--workers"),
        (["--spread", "R_s=5%", "--gains", "nope.json"], "nope.json"),
    ],
)
def test_bad_input_is_one_line_and_writes_nothing(servo, tmp_path, capsys, argv, part):
    out = tmp_path / "mc"
    code, cap = _run([servo, *argv, "--out", str(out)], capsys)
    assert code == 2 and cap.err.count("\n") == 1 and part in cap.err, cap.err
    assert cap.err.startswith("sensorless montecarlo: error: ")
    assert not out.exists()


def test_runs_on_an_example_motor_with_deterministic_outputs(servo, tmp_path, capsys):
    argv = [servo, "--samples", "40", "--spread", "R_s=10%,L_d=10%u,psi_pm=5%,J=30%"]
    argv += ["--estimate-error", "R_s=20%", "--time-domain", "1", "--seed", "3", "--scheduler", "synchronous"]
    # a damping floor some draws meet and others miss (at the report's 0.2 the drive file's gains meet it in
    # none of the 40: the count of passes below could not tell a wrong pass column from a right one)
    argv += ["--min-damping", "0.1"]
    code, cap = _run([*argv, "--out", str(tmp_path / "a"), "--quiet"], capsys)
    assert code in (0, 3), cap.err
    s = json.loads((tmp_path / "a" / "summary.json").read_text())
    y = s["yield"]
    assert 0 <= y["damping"]["value"] <= 1 and y["damping"]["draws"] == 40
    # 3 speeds x 2 directions x 5 torques (the derived envelope: -T_max, -T_N, 0, T_N, T_max)
    assert y["time_domain"]["draws"] == 1 and s["envelope_points"] == 3 * 2 * 5
    assert {r["parameter"] for r in s["sensitivity"]} == {
        "plant R_s", "plant L_d", "plant psi_pm", "plant J", "estimate R_s"
    }  # fmt: skip
    rows = (tmp_path / "a" / "draws.csv").read_text().splitlines()
    assert len(rows) == 41 and rows[0].startswith("draw,plant_R_s,")
    passes = sum(int(r.split(",")[-3]) for r in rows[1:])
    assert 0 < passes < 40 and passes == round(40 * y["damping"]["value"])
    code2, _ = _run([*argv, "--out", str(tmp_path / "b"), "--quiet"], capsys)
    assert code2 == code
    for f in sorted((tmp_path / "a").iterdir()):
        assert f.read_bytes() == (tmp_path / "b" / f.name).read_bytes(), f.name


def test_report_montecarlo_on_a_family_without_it_is_one_line_before_computing(tmp_path, capsys):
    from families.pll.design import FAMILY as PLL
    from sensorless.design.registry import kinds, registered

    drive = Path(__file__).resolve().parents[1] / "families" / "pll" / "presets" / "pll_servo.toml"
    argv = ["report", str(drive), "--montecarlo", "5", "--out", str(tmp_path / "r")]
    if PLL.kind in kinds():
        code = main(argv)
    else:
        with registered(PLL):
            code = main(argv)
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "declares no parameters to spread" in err
    assert not (tmp_path / "r").exists()


def test_the_test_family_without_montecarlo_is_one_capability_line(tmp_path, capsys):
    from families.pll.design import FAMILY as PLL
    from sensorless.design.registry import kinds, registered

    drive = Path(__file__).resolve().parents[1] / "families" / "pll" / "presets" / "pll_servo.toml"
    if PLL.kind in kinds():
        code, cap = _run([str(drive), "--spread", "R_s=5%", "--out", str(tmp_path / "mc")], capsys)
    else:
        with registered(PLL):
            code, cap = _run([str(drive), "--spread", "R_s=5%", "--out", str(tmp_path / "mc")], capsys)
    assert code == 2 and cap.err.count("\n") == 1, cap.err
    assert f"observer family {PLL.name!r} declares no parameters to spread" in cap.err
    assert not (tmp_path / "mc").exists()
