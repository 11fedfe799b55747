"""`sensorless analyze` end to end: outputs, determinism, clear errors, nothing half-written."""

import contextlib
import io
import shutil

import pytest
from helpers.figures_off import figure_files_off
from sensorless.reports.cli.main import main


def run(args, capsys):
    """``main(args)``, its figure files built but not rendered (tests/helpers/figures_off.py): the tests
    that call it check the file names and the data; the preset analysis below renders its figures and
    checks their bytes."""
    with figure_files_off():
        code = main(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def quiet_run(args):
    """``main(args)`` with its stdout and stderr captured (for module fixtures: capsys is per test)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(args)
    return code, out.getvalue(), err.getvalue()


ALL = ["analyze", "piippo2008", "--gain-set", "all", "--points", "201"]


@pytest.fixture(scope="module")
def preset_all(tmp_path_factory):
    """``analyze piippo2008 --gain-set all --points 201``, run once for this module: (directory, exit
    status, stdout, {file name: bytes})."""
    out = tmp_path_factory.mktemp("analyze") / "a"
    code, stdout, _ = quiet_run([*ALL, "--out", str(out)])
    return out, code, stdout, {p.name: p.read_bytes() for p in out.iterdir()}


@pytest.fixture(scope="module")
def rerun(preset_all, tmp_path_factory):
    """The same analysis again over a copy of its outputs: first with another --torque (refused: the
    outputs exist), then with --force, spelling --gain-set as it was (--gain). The second run is both
    the --force run and the determinism check (the same bytes as the first run's)."""
    out = tmp_path_factory.mktemp("analyze") / "b"
    shutil.copytree(preset_all[0], out)
    args = ["analyze", "piippo2008", "--gain", "all", "--points", "201", "--out", str(out)]
    refused = quiet_run([*args, "--torque", "14"])
    after_refused = {p.name: p.read_bytes() for p in out.iterdir()}
    forced = quiet_run([*args, "--force"])
    return refused, after_refused, forced, {p.name: p.read_bytes() for p in out.iterdir()}


def test_analyze_preset_writes_csv_and_figures(preset_all, rerun):
    _, code, stdout, files = preset_all
    assert code == 0
    names = sorted(files)
    assert names == sorted(
        [
            "poles_zero_T+14Nm.csv",
            "poles_constant_T+14Nm.csv",
            "poles_speed_T+14Nm.csv",
            "pole_map_T+14Nm.png",
            "pole_map_T+14Nm.svg",
        ]
    )
    for g in ("zero", "constant", "speed"):
        line = next(ln for ln in stdout.splitlines() if ln.startswith(g))
        assert "(motoring)" in line and "+0.0000.." in line
    head = files["poles_speed_T+14Nm.csv"].decode().splitlines()[:2]
    assert "speed base" in head[0] and head[1].startswith("w_m_pu,w_m_rad_s,T_e_Nm")
    # deterministic: a second run (module fixture rerun: with --force over a copy of the first run's
    # outputs) produces identical bytes; it spells --gain-set as it was (--gain), which still works for
    # one release, with a note naming the new spelling
    _, _, (code, _, err), again = rerun
    assert code == 0 and "note: --gain is now --gain-set" in err
    assert again.keys() == files.keys()
    for name, data in files.items():
        assert again[name] == data, name


def test_existing_outputs_are_not_overwritten(preset_all, rerun):
    # the module fixture rerun: the analysis of preset_all again into a copy of its outputs
    (code, _, err), after_refused, (forced, _, _), _ = rerun
    assert code == 2 and "output exists" in err and "--force" in err
    assert after_refused == preset_all[3]
    assert forced == 0


def test_injection_and_torque_options(tmp_path, capsys):
    code, stdout, _ = run(
        [
            "analyze",
            "piippo2008",
            "--injection",
            "--torque=1T_N,-1T_N",
            "--points",
            "201",
            "--speed-max",
            "0.2",
            "--out",
            str(tmp_path),
        ],
        capsys,
    )
    assert code == 0
    assert stdout.count("none") == 2  # no unstable band in either torque direction
    assert (tmp_path / "pole_map_inj_T-14Nm.svg").exists()


def test_bad_drive_file_exits_2_naming_key(tmp_path, capsys):
    from importlib import resources

    text = (resources.files("sensorless.design.ipmsm_adaptive.presets") / "piippo2008.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('L_d = "0.036 H"', 'L_d = "-1 H"', 1))
    code, _, err = run(["analyze", str(bad), "--out", str(tmp_path / "o")], capsys)
    assert code == 2
    assert str(bad) in err and "motor.L_d" in err
    assert not (tmp_path / "o").exists()
    code, _, err = run(["analyze", "piippo2008", "--gain-set", "nope", "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "observer.gains.nope" in err


def test_discrete_analysis_and_study(tmp_path, capsys):
    """--discrete: the runtime step's one-step map beside the continuous loop (the drive's scheme, zoh:
    no voltage feedthrough, steady angle error 0.01 deg); --discretization picks another scheme
    (heun: k_p T_s / 2 = 0.115 rad/s per V); --study: every scheme over 50..400 us."""
    import numpy as np

    out = tmp_path / "d"
    code, stdout, _ = run(
        ["analyze", "piippo2008", "--discrete", "--points", "201", "--out", str(out)], capsys
    )
    assert code == 0
    assert "discrete-time observer that runs: zoh at T_s = 200 us" in stdout
    row = [ln for ln in stdout.splitlines() if ln.startswith("speed")][-1].split()
    assert float(row[-1]) == 0 and abs(float(row[4])) < 0.02  # feedthrough; steady error [deg]
    for name in ("poles_discrete_speed_T+14Nm.csv", "pole_map_discrete_T+14Nm.svg", "poles_speed_T+14Nm.csv"):
        assert (out / name).exists(), name
    data = np.genfromtxt(out / "poles_discrete_speed_T+14Nm.csv", delimiter=",", names=True, skip_header=1)
    assert data.size == 201 and np.nanmax(np.abs(data["err_theta_deg"])) < 0.02
    code, stdout, _ = run(
        [
            "analyze",
            "piippo2008",
            "--discretization",
            "heun",
            "--points",
            "51",
            "--study",
            "--out",
            str(tmp_path / "h"),
        ],
        capsys,
    )
    assert code == 0 and "heun at T_s = 200 us" in stdout
    row = [ln for ln in stdout.splitlines() if ln.startswith("speed")][-1].split()
    assert float(row[-1]) == 0.115
    study = (tmp_path / "h" / "discretization_study.csv").read_text().splitlines()
    assert len(study) == 2 + 4 * 4  # comment, header, 4 schemes x 4 sampling periods
    assert any(ln.startswith("speed,zoh,0.0002,") for ln in study)


def test_discrete_analysis_refuses_what_it_cannot_do(tmp_path, capsys):
    code, _, err = run(["analyze", "piippo2008", "--discrete", "--injection", "--out", str(tmp_path)], capsys)
    assert code == 2 and "without the HF injection" in err
    code, _, err = run(["analyze", "piippo2008", "--discretization", "rk9", "--out", str(tmp_path)], capsys)
    assert code == 2 and "'rk9'" in err and "zoh" in err
    code, _, err = run(["analyze", "deangelo2006", "--discrete", "--out", str(tmp_path)], capsys)
    assert code == 2 and "--discrete" in err
    assert not any(tmp_path.iterdir())
