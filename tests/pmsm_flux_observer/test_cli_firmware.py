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
    notes = err.splitlines()
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
