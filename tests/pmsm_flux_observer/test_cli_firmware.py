"""``sensorless init --from`` and ``sensorless export`` on the command line: what is written, the notes
on stderr, and the one-line errors (exit 2, nothing written) of bad files and options.

The importers are the family's (reports/pmsm_flux_observer/firmware_io.py). Until the family record is
registered, the fixture puts them where the shared command finds them, and stands in for the family's
loading of the written file with a TOML parse.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from types import SimpleNamespace

import pytest
from sensorless.design import registry
from sensorless.reports import family as report_family
from sensorless.reports.cli import init as init_cli
from sensorless.reports.cli.main import main
from sensorless.reports.pmsm_flux_observer.firmware_io import importers

KIND = "pmsm-flux-observer"
EXAMPLES = Path(__file__).resolve().parents[2] / "docs" / "examples" / "firmware"


@pytest.fixture
def firmware(monkeypatch):
    if KIND in registry.kinds():
        return
    found = {name: [(None, imp)] for name, imp in importers(KIND).items()}
    monkeypatch.setattr(report_family, "importers", lambda: found)
    monkeypatch.setattr(init_cli, "importers", report_family.importers)

    def load(text, file):
        return SimpleNamespace(name=tomllib.loads(text)["drive"]["name"], warnings=[])

    monkeypatch.setattr(init_cli, "load_drive_text", load)


def run(args, capsys):
    try:
        code = main([str(a) for a in args])
    except SystemExit as e:  # argparse's own errors
        code = e.code
    out = capsys.readouterr()
    return code, out.out, out.err


def test_import_writes_the_drive_file_and_says_what_was_assumed(firmware, tmp_path, capsys):
    out = tmp_path / "hub.toml"
    code, stdout, err = run(
        ["init", "--from", "vesc", EXAMPLES / "hub_motor_mcconf.xml", "--out", out], capsys
    )
    assert code == 0, err
    d = tomllib.loads(out.read_text())
    assert d["drive"]["kind"] == KIND and d["motor"]["p"] == 20
    notes = [n for n in err.splitlines() if not n.startswith("sensorless init: warning: ")]  # plausibility
    assert notes and all(n.startswith("sensorless init: note: ") for n in notes)
    assert any("--u-dc" in n for n in notes)
    assert f"wrote {out}" in stdout
    # the same file again: byte-identical
    out2 = tmp_path / "hub2.toml"
    run(["init", "--from", "vesc", EXAMPLES / "hub_motor_mcconf.xml", "--out", out2], capsys)
    assert out2.read_bytes() == out.read_bytes()


def test_import_options_supply_missing_fields(firmware, tmp_path, capsys):
    old = EXAMPLES / "outrunner_old_mcconf.xml"
    out = tmp_path / "old.toml"
    code, _, err = run(["init", "--from", "vesc", old, "--out", out], capsys)
    assert code == 2 and not out.exists()
    assert err.count("\n") == 1 and "si_motor_poles" in err and "--pole-pairs" in err and str(old) in err
    code, _, err = run(
        ["init", "--from", "vesc", old, "--pole-pairs", "7", "--u-dc", "36", "--J", "3e-4", "--out", out],
        capsys,
    )
    assert code == 0, err
    d = tomllib.loads(out.read_text())
    assert d["motor"]["p"] == 7 and d["motor"]["J"] == "0.0003 kg m^2"


def test_odrive_import(firmware, tmp_path, capsys):
    out = tmp_path / "o.toml"
    cfg = EXAMPLES / "outrunner_odrive.json"
    code, _, err = run(["init", "--from", "odrive", cfg, "--out", out], capsys)
    assert code == 2 and "--u-dc" in err and err.count("\n") == 1 and not out.exists()
    code, _, err = run(["init", "--from", "odrive", cfg, "--u-dc", "24", "--KV", "150", "--out", out], capsys)
    assert code == 0, err
    assert "pm_flux_linkage is still the factory default" in err


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--f-s", "8000"], "--f-s: not an option of --from vesc"),
        (["--u-dc", "nan"], "--u-dc"),
        (["--pole-pairs", "0"], "--pole-pairs"),
        (["--KV", "inf"], "--KV"),
    ],
)
def test_import_option_errors(firmware, tmp_path, capsys, extra, says):
    out = tmp_path / "x.toml"
    code, _, err = run(
        ["init", "--from", "vesc", EXAMPLES / "hub_motor_mcconf.xml", *extra, "--out", out], capsys
    )
    assert code == 2 and says in err and err.count("\n") == 1 and not out.exists()


def test_bad_files_one_line_nothing_written(firmware, tmp_path, capsys):
    bad = tmp_path / "bad.xml"
    bad.write_text(
        "<MCConfiguration><si_motor_poles>14</si_motor_poles><foc_motor_r>oops</foc_motor_r></MCConfiguration>"
    )
    out = tmp_path / "x.toml"
    code, _, err = run(["init", "--from", "vesc", bad, "--out", out], capsys)
    assert code == 2 and err.count("\n") == 1 and str(bad) in err and "foc_motor_r" in err
    assert not out.exists()
    code, _, err = run(["init", "--from", "vesc", tmp_path / "none.xml", "--out", out], capsys)
    assert code == 2 and "none.xml" in err and not out.exists()


def test_existing_output_is_kept(firmware, tmp_path, capsys):
    out = tmp_path / "x.toml"
    out.write_text("mine\n")
    code, _, err = run(["init", "--from", "vesc", EXAMPLES / "hub_motor_mcconf.xml", "--out", out], capsys)
    assert code == 2 and "--force" in err and out.read_text() == "mine\n"


def test_unknown_firmware_and_mixed_usage(firmware, tmp_path, capsys):
    out = tmp_path / "x.toml"
    code, _, err = run(["init", "--from", "nosuch", "f.xml", "--out", out], capsys)
    assert code == 2 and "no importer for 'nosuch'" in err and "vesc" in err
    code, _, err = run(["init", "piippo2008", "--pole-pairs", "3", "--out", out], capsys)
    assert code == 2 and "--pole-pairs" in err and "--from" in err
    code, _, err = run(["init", "piippo2008", "--from", "vesc", "f.xml", "--out", out], capsys)
    assert code == 2 and err.count("\n") == 1
    assert not out.exists()


def test_export_to_a_firmware_the_family_lacks(tmp_path, capsys):
    code, _, err = run(["export", "piippo2008", "--target", "vesc", "--out", tmp_path / "e"], capsys)
    assert code == 2 and err.count("\n") == 1 and "--target vesc" in err and "export to: none" in err
    assert not (tmp_path / "e").exists()


family_registered = pytest.mark.skipif(KIND not in registry.kinds(), reason="the family is not registered")


@family_registered
def test_round_trip_through_the_commands(tmp_path, capsys):
    """import -> export -> import with the family's drive files: the same motor values and gains."""
    from sensorless.design.drive import load_drive

    first, again = tmp_path / "a.toml", tmp_path / "b.toml"
    cfg = EXAMPLES / "outrunner_odrive.json"
    assert run(["init", "--from", "odrive", cfg, "--u-dc", "24", "--out", first], capsys)[0] == 0
    code, _, err = run(["export", first, "--target", "odrive", "--out", tmp_path / "e"], capsys)
    assert code == 0, err
    code, _, err = run(
        ["init", "--from", "odrive", tmp_path / "e" / "odrive.json", "--u-dc", "24", "--out", again], capsys
    )
    assert code == 0, err
    a, b = load_drive(first), load_drive(again)
    for k in ("R_s", "L_d", "L_q", "psi_pm", "p"):
        assert getattr(b.motor, k) == pytest.approx(getattr(a.motor, k), rel=1.2e-7), k  # float32
    assert b.observer.T_obs == pytest.approx(a.observer.T_obs, rel=1e-11)
    assert b.gains_table == a.gains_table


@family_registered
def test_tuned_table_exported_and_refused_where_it_breaks_a_limit(tmp_path, capsys):
    """The tuned gain table's values are what odrive.json holds; a table whose PLL breaks ODrive's
    T kp < 1 is refused with one line, nothing written."""
    import json

    drive = tmp_path / "o.toml"
    assert (
        run(
            ["init", "--from", "odrive", EXAMPLES / "outrunner_odrive.json", "--u-dc", "24", "--out", drive],
            capsys,
        )[0]
        == 0
    )
    assert "[envelope]" not in drive.read_text()
    with drive.open("a") as f:  # a coarse envelope (4 speeds per direction): a third of tune's points
        f.write("\n[envelope]\nspeeds = 4\n")
    # the table `tune --law constant` writes (its default settings), from the tuner itself: the command's
    # own summary lines (the tuned gains' w_min under the errors, the start) are test_drive_file.py's
    from sensorless.design.drive import load_drive
    from sensorless.tuning.pmsm_flux_observer import FluxTuneSettings, tune_constant

    table = tmp_path / "gains_constant.json"
    table.write_text(tune_constant(load_drive(str(drive)), FluxTuneSettings()).table.to_json())
    gains = json.loads(table.read_text())["gains"]
    code, _, err = run(
        ["export", drive, "--gains", table, "--target", "odrive", "--out", tmp_path / "e"], capsys
    )
    assert code == 0, err
    written = json.loads((tmp_path / "e" / "odrive.json").read_text())
    assert written["axis0.sensorless_estimator.config.observer_gain"] == pytest.approx(gains["observer_gain"])
    assert written["axis0.sensorless_estimator.config.pll_bandwidth"] == pytest.approx(gains["pll_bandwidth"])
    doc = json.loads(table.read_text())
    doc["gains"]["pll_bandwidth"] = 4000.0  # T kp = 125 us x 8000 1/s = 1
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    code, _, err = run(
        ["export", drive, "--gains", bad, "--target", "odrive", "--out", tmp_path / "f"], capsys
    )
    err = [line for line in err.splitlines() if not line.startswith("sensorless export: warning: ")]
    assert code == 2 and len(err) == 1 and "pll_bandwidth" in err[0] and "T kp = 1 >= 1" in err[0]
    assert not (tmp_path / "f").exists()


@family_registered
def test_vesc_round_trip_through_the_commands(tmp_path, capsys):
    """VESC: import (values as typed: --l-scale 1) -> export the drive file's gains -> import again."""
    from sensorless.design.drive import load_drive

    first, again = tmp_path / "a.toml", tmp_path / "b.toml"
    opts = ["--u-dc", "36", "--l-scale", "1"]
    cfg = EXAMPLES / "hub_motor_mcconf.xml"
    assert run(["init", "--from", "vesc", cfg, *opts, "--out", first], capsys)[0] == 0
    code, _, err = run(["export", first, "--target", "vesc", "--out", tmp_path / "e"], capsys)
    assert code == 0, err
    code, _, err = run(["init", "--from", "vesc", tmp_path / "e" / "vesc.xml", *opts, "--out", again], capsys)
    assert code == 0, err
    a, b = load_drive(first), load_drive(again)
    for k in ("R_s", "L_d", "L_q", "psi_pm", "p"):
        assert getattr(b.motor, k) == pytest.approx(getattr(a.motor, k), rel=1e-11), k
    assert (b.observer.correction, b.observer.lambda_adaptation) == ("box-clamp", True)
    assert b.observer.T_obs == pytest.approx(a.observer.T_obs, rel=1e-11)
    assert b.gains_table == a.gains_table
