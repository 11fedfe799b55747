"""Drive files of the flux observer: a minimal file in datasheet terms completed by the documented rules
(J, the rating, the firmware's variant and defaults), errors naming file and key, and the commands
end to end on a motor that is not a preset."""

from __future__ import annotations

import json
import math

import pytest
from sensorless.design import registry
from sensorless.design.drive import load_drive
from sensorless.design.gain_table import GainTable, GainTableError
from sensorless.design.pmsm_drive import startup_values
from sensorless.design.units import DriveFileError
from sensorless.reports.cli.main import main

MINIMAL = """
[drive]
name = "mymotor"
kind = "pmsm-flux-observer"

[motor]
poles = 12
KV = "180 rpm/V"
R_ll = "0.14 ohm"
connection = "wye"
L_ll = "90 uH"

[inverter]
u_dc = "36 V"
f_s = "10 kHz"

[observer]
firmware = "vesc"
"""


BOX = MINIMAL.replace(
    'firmware = "vesc"', 'firmware = "vesc"\ncorrection = "box-clamp"\nlambda_adaptation = true'
)


@pytest.fixture
def minimal(tmp_path):
    p = tmp_path / "mymotor.toml"
    p.write_text(MINIMAL)
    return p


def test_rules_of_a_minimal_file(minimal):
    d = load_drive(str(minimal))
    p = 6
    psi = 1 / (180 * 2 * math.pi / 60 * math.sqrt(3) * p)  # KV: line-line peak back-EMF per r/min
    assert d.motor.psi_pm == pytest.approx(psi)
    assert d.motor.R_s == pytest.approx(0.07) and d.motor.L_d == pytest.approx(45e-6)
    n0 = 36 / (math.sqrt(3) * psi * p) * 30 / math.pi  # no-load speed at the DC link [r/min]
    assert d.rating.n_N == pytest.approx(0.8 * n0)
    I_N = 0.05 * 36 / 0.07
    assert d.T_N == pytest.approx(1.5 * p * psi * math.sqrt(2) * I_N, rel=1e-6)
    assert d.motor.J == pytest.approx(0.1 * d.T_N / (d.rating.n_N * math.pi / 30), rel=1e-5)
    o = d.observer
    # VESC's ORTEGA_ORIGINAL: the observer whose gain its law tunes (the box clamp has none)
    assert (o.correction, o.inductance_rule, o.lambda_adaptation) == (
        "clamped-gradient",
        "interpolated",
        False,
    )
    assert o.T_obs == pytest.approx(1e-4)
    g = d.gains_table
    assert g["law"] == "voltage-scaled" and g["foc_observer_gain"] == pytest.approx(1e3 / psi**2, rel=1e-5)


@pytest.mark.parametrize(
    "edit, key",
    [
        (('firmware = "vesc"', 'firmware = "vesc"\ncorrection = "ortega"'), "observer.correction"),
        (('f_s = "10 kHz"', 'f_s = "10 kHz"\nbogus = 1'), "inverter.bogus"),
        (('f_s = "10 kHz"\n', ""), "inverter.f_s"),
        (
            ('firmware = "vesc"', 'firmware = "vesc"\n[gains]\nlaw = "constant"\nobserver_gain = "-3 1/s"'),
            "gains",
        ),
    ],
)
def test_errors_name_file_and_key(tmp_path, capsys, edit, key):
    p = tmp_path / "bad.toml"
    p.write_text(MINIMAL.replace(*edit))
    assert main(["analyze", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.toml" in err[0] and key in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "o").exists()


def test_commands_end_to_end_on_a_non_preset_motor(minimal, tmp_path, capsys, readme_run):
    # a coarse envelope (4 speeds per direction): init keeps it
    text = MINIMAL.replace('firmware = "vesc"', 'firmware = "odrive"') + "\n[envelope]\nspeeds = 4\n"
    minimal.write_text(text)
    full = tmp_path / "full.toml"
    assert main(["init", str(minimal), "--out", str(full)]) == 0
    assert load_drive(str(full)).T_N == pytest.approx(load_drive(str(minimal)).T_N)
    assert load_drive(str(full)).envelope.rule.count == 4
    # tune, codegen and report of an ODrive drive that is not a preset: the README's ODrive flow (its
    # skate motor, from the firmware's settings), run once in this process for the README test and this
    # one (group readme-skate-odrive of tests/conftest.py: one worker); test_datasheet_flow.py runs a
    # minimal file in datasheet terms from init to export
    run = readme_run("skate-odrive")
    step = {argv[0]: k for k, (argv, _, _) in enumerate(run.results)}
    codes = {c: run.results[step[c]][1] for c in ("tune", "codegen", "report")}
    assert codes["tune"] in (0, 3) and codes["codegen"] == 0 and codes["report"] in (0, 3), codes
    out = run.outputs[step["tune"]]
    assert "ODrive defaults" in out and "VESC detection" in out
    # --quick: the report's coarser low-speed grid (design/low_speed.py QUICK); the analyses it holds
    # are the same, and the full grid under every corner of the estimate errors is half a report's CPU.
    # The report's w_min of the tuned gains under the errors is the one tune's summary line computed in
    # this process, under another name of the table (design/memo.py: not keyed on it), not a second time
    assert "--quick" in run.results[step["report"]][0]
    assert run.memo[step["report"]] == (1, 0)
    rep = json.loads((run.dir / "report-skate-odrive" / "report.json").read_text())
    assert {"ODrive defaults", "VESC detection", "drive file", "tuned"} <= set(rep["analysis"])
    # box clamp: analysis refused in one line, simulation runs
    box = tmp_path / "box.toml"
    box.write_text(BOX)  # VESC's MXLEMMING: box clamp
    assert main(["analyze", str(box), "--out", str(tmp_path / "a")]) == 2
    assert "not linearizable" in capsys.readouterr().err


def test_init_of_a_box_clamp_leaves_the_handover_speeds_to_give(minimal, tmp_path, capsys):
    """The box clamp (VESC's default) has no linearization, so no w_min: init still writes the drive
    file, its [startup] asking for the handover speeds with the reason, and the file loads; given them,
    the start runs on them."""
    full = tmp_path / "full.toml"
    minimal.write_text(BOX)
    assert main(["init", str(minimal), "--out", str(full)]) == 0
    text = full.read_text()
    head = text.split("[startup]")[0].rstrip().splitlines()[-1]
    assert "not derived" in head and "not linearizable" in head
    assert '# w_on = "..."' in text and '# w_off = "..."' in text
    drive = load_drive(str(full))
    assert drive.startup is not None and drive.startup.needs_w_min
    given = text.replace('# w_on = "..."', 'w_on = "0.2 pu"').replace('# w_off = "..."', 'w_off = "0.1 pu"')
    full.write_text(given)
    with_speeds = load_drive(str(full))
    assert with_speeds.startup.w_on == pytest.approx(0.2 * drive.w_base)
    fam = registry.family_of(with_speeds)
    values, line, _ = startup_values(with_speeds, fam.gains(with_speeds))  # other keys: rules; no analysis
    assert values["if_w_on"] == pytest.approx(0.2 * drive.w_base) and values["if_i"] > 0, line
    assert not fam.scales(with_speeds).zero_speed  # the checks go through zero


def test_an_observer_gain_past_the_euler_limit_is_refused_naming_the_keys(tmp_path, capsys):
    """k T_obs >= 2 (laws.py EULER_LIMIT: the forward-Euler step of the flux amplitude's error, 1 - k T_obs
    per period, diverges): a drive file's [gains] gives one line naming the file, the gain and the key of
    the period, with the largest gain to give; 1.9 / T_obs (the tuner's largest) loads; a schedule names
    its offending speed; a gain table gets the same check against the drive it is used with."""
    T = 1e-4  # f_s = 10 kHz
    odrive = 'firmware = "vesc"\n[gains]\nlaw = "constant"\npll_bandwidth = "1000 rad/s"\n'
    odrive += 'observer_gain = "{} 1/s"'
    p = tmp_path / "bad.toml"
    p.write_text(MINIMAL.replace('firmware = "vesc"', odrive.format(2.1 / T)))
    assert main(["analyze", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0] and not (tmp_path / "o").exists()
    assert "bad.toml" in err[0] and "gains.observer_gain" in err[0] and "(inverter.f_s)" in err[0]
    assert "k T_obs = 2.1," in err[0] and f"at most {1.9 / T:.4g} 1/s" in err[0]
    p.write_text(MINIMAL.replace('firmware = "vesc"', odrive.format(1.9 / T)))
    drive = load_drive(str(p))
    assert drive.observer.T_obs == pytest.approx(T)
    schedule = (
        'firmware = "vesc"\nT_obs = "50 us"\n[gains]\nlaw = "schedule"\npll_bandwidth = "1000 rad/s"\n'
        'speeds = ["100 rad/s", "900 rad/s"]\nobserver_gain = ["1000 1/s", "50000 1/s"]'
    )
    p.write_text(MINIMAL.replace('firmware = "vesc"', schedule))
    with pytest.raises(DriveFileError, match=r"observer_gain.*its value at 900 rad/s.*\(observer\.T_obs\)"):
        load_drive(str(p))
    table = GainTable("constant", {"kind": drive.kind}, {"observer_gain": 2.1 / T, "pll_bandwidth": 1000.0})
    with pytest.raises(GainTableError, match=r"^t\.json: key 'gains\.observer_gain': 21000 1/s"):
        registry.family_of(drive).gains(drive, table=table, table_file="t.json")
