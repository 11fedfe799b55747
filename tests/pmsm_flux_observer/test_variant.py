"""One observer variant from init to export: `init --firmware` writes that firmware's variant, and a law
that the drive's variant cannot run is refused up front by `tune` (one line, nothing written), never
tuned into a table `export` refuses."""

from __future__ import annotations

from pathlib import Path

import pytest
from sensorless.design.drive import load_drive
from sensorless.reports.cli.main import main

# a datasheet 6374 outrunner's minimal file (no [observer]: the firmware is given by --firmware or the key)
MINIMAL = (Path(__file__).parent / "drives" / "skate6374.toml").read_text()


def _init(tmp_path, text, *opts):
    src = tmp_path / "min.toml"
    src.write_text(text)
    out = tmp_path / "full.toml"
    return main(["init", str(src), "--out", str(out), "--force", *opts]), out


@pytest.mark.parametrize(
    "firmware, variant, law",
    [
        ("vesc", ("clamped-gradient", "interpolated", False), "voltage-scaled"),
        ("odrive", ("gradient", "fixed", False), "constant"),
        ("simplefoc", ("box-clamp", "q-axis", False), "constant"),
    ],
)
def test_init_writes_the_firmwares_variant(tmp_path, firmware, variant, law):
    rc, out = _init(tmp_path, MINIMAL, "--firmware", firmware)
    assert rc == 0
    d = load_drive(str(out))
    o = d.observer
    assert (o.firmware, o.correction, o.inductance_rule, o.lambda_adaptation) == (firmware, *variant)
    assert d.gains_table["law"] == law
    # the file's own key gives the same file
    rc, same = _init(tmp_path, MINIMAL + f'\n[observer]\nfirmware = "{firmware}"\n')
    assert rc == 0 and load_drive(str(same)).observer == o


def test_init_firmware_refusals(tmp_path, capsys):
    rc, out = _init(tmp_path, MINIMAL + '\n[observer]\nfirmware = "odrive"\n', "--firmware", "vesc")
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--firmware vesc" in err[0] and "'odrive'" in err[0]
    assert not out.exists()
    rc = main(["init", "--from", "vesc", "x.xml", "--firmware", "vesc", "--out", str(tmp_path / "y.toml")])
    assert rc == 2 and "not of --from" in capsys.readouterr().err
    rc = main(
        ["init", "docs/examples/motors/servo400.toml", "--firmware", "vesc", "--out", str(tmp_path / "s")]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--firmware" in err[0] and "not an option" in err[0]


@pytest.mark.parametrize(
    "observer, law, says",
    [
        ("", "voltage-scaled", "unclamped gradient"),  # the generic variant: VESC has no unclamped gradient
        ('firmware = "odrive"', "voltage-scaled", "init --firmware vesc"),
        ('firmware = "vesc"\ncorrection = "box-clamp"', "voltage-scaled", "no observer gain"),
        ('firmware = "simplefoc"', "constant", "no observer gain"),
    ],
)
def test_tune_refuses_a_law_the_variant_cannot_run_up_front(tmp_path, capsys, observer, law, says):
    text = MINIMAL + (f"\n[observer]\n{observer}\n" if observer else "")
    drive = tmp_path / "d.toml"
    drive.write_text(text)
    out = tmp_path / "t"
    assert main(["tune", str(drive), "--law", law, "--out", str(out), "--quiet"]) == 2
    err = [x for x in capsys.readouterr().err.strip().splitlines() if "warning" not in x]
    assert len(err) == 1 and says in err[0] and "d.toml" in err[0] and "Traceback" not in err[0]
    assert not out.exists()
