"""`sensorless analyze deangelo2006` end to end: poles printed, outputs deterministic, clear errors."""

import csv
import math

import pytest
from sensorless.design.drive import load_drive
from sensorless.reports.cli.main import main
from sensorless.reports.pmac_reduced_order import analyze as analyze_pmac


def run(args, capsys):
    code = main(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_analyze_preset_prints_poles_and_writes_outputs(tmp_path, capsys):
    args = ["analyze", "deangelo2006", "--speed", "250rpm,-250 rpm", "--load", "0,5Nm"]
    code, out, _ = run([*args, "--out", str(tmp_path / "a")], capsys)
    assert code == 0
    assert "with load-torque estimation" in out and "without load-torque estimation" in out
    assert "rk2-model at T_s = 180 us" in out
    lines = [ln for ln in out.splitlines() if ln.strip().startswith(("250", "-250"))]
    assert len(lines) == 8  # 2 speeds x 2 loads x 2 observers
    assert all("-10.6" in ln for ln in lines[:4])  # the slow load-estimation pole, both columns
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert names == ["poles.png", "poles.svg", "poles_TL.csv", "poles_noTL.csv"]
    head = (tmp_path / "a" / "poles_TL.csv").read_text().splitlines()
    # the shared pole table (reports/pole_map.py), the mechanical speed beside the electrical one
    assert "rk2-model" in head[0] and head[1].startswith("w_m_pu,w_m_rad_s,T_L_Nm,speed_rpm,pole_c0_re")
    assert len(head) == 2 + 4
    rows = list(csv.DictReader(head[1:]))
    p = load_drive("deangelo2006").motor.p  # electrical rad/s = r/min * 2 pi / 60 * pole pairs
    for r in rows:
        assert float(r["w_m_rad_s"]) == pytest.approx(float(r["speed_rpm"]) * 2 * math.pi / 60 * p, rel=1e-9)
    assert sorted({float(r["speed_rpm"]) for r in rows}) == pytest.approx([-250.0, 250.0], rel=1e-9)
    # deterministic: the same command again gives byte-identical files
    assert run([*args, "--out", str(tmp_path / "b")], capsys)[0] == 0
    for p in (tmp_path / "a").iterdir():
        assert (tmp_path / "b" / p.name).read_bytes() == p.read_bytes(), p.name


def test_study_option(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(analyze_pmac, "STUDY_SAMPLING", (180e-6,))
    monkeypatch.setattr(analyze_pmac, "STUDY_SPEEDS", (250.0,))
    code, out, _ = run(
        ["analyze", "deangelo2006", "--speed", "250rpm", "--load", "5", "--study", "--out", str(tmp_path)],
        capsys,
    )
    assert code == 0
    rows = [ln for ln in out.splitlines() if "180us" in ln]
    assert {ln.split()[0] for ln in rows} == {
        "euler",
        "rk2-hold",
        "rk2",
        "midpoint",
        "rk2-rotating",
        "rk2-model",
    }
    assert (tmp_path / "discretization_study.csv").read_text().count("\n") == 2 + 6


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--speed", "0rpm"], "--speed"),
        (["--speed", "250 ohm"], "not a mech speed unit"),
        (["--discretization", "rk4"], "unknown scheme"),
        (["--gain-set", "speed"], "it applies to: ipmsm_adaptive"),
        (["--injection"], "it applies to: ipmsm_adaptive"),
    ],
)
def test_bad_options_exit_2_and_write_nothing(tmp_path, capsys, extra, words):
    code, _, err = run(
        ["analyze", "deangelo2006", "--load", "5", *extra, "--out", str(tmp_path / "o")], capsys
    )
    assert code == 2 and words in err, err
    assert not (tmp_path / "o").exists()


def test_pmac_options_refused_for_the_other_kind(tmp_path, capsys):
    code, _, err = run(["analyze", "piippo2008", "--speed", "250rpm", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "it applies to: pmac_reduced_order" in err
