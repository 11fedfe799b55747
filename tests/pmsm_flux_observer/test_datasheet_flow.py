"""A datasheet hub motor (tests/pmsm_flux_observer/drives/hub500.toml, not a preset) for VESC from init to
export: `init --firmware vesc` writes VESC's variant, `tune` with its default options meets the family's
criterion (exit 0), and the table it writes is one `export --target vesc` takes and `codegen` prints."""

from __future__ import annotations

import json
from pathlib import Path

from sensorless.design.low_speed import minimum_speed
from sensorless.reports.cli.main import main

DRIVES = Path(__file__).parent / "drives"


def test_hub_motor_from_init_to_export(tmp_path, capsys):
    # on a coarse envelope (4 speeds per direction, kept by init): the same flow on a third of the points
    minimal = tmp_path / "hub500.toml"
    minimal.write_text((DRIVES / "hub500.toml").read_text() + "\n[envelope]\nspeeds = 4\n")
    drive = tmp_path / "hub.toml"
    assert main(["init", str(minimal), "--firmware", "vesc", "--out", str(drive)]) == 0
    # the file's law: voltage-scaled
    assert main(["tune", str(drive), "--out", str(tmp_path / "t"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "tuned voltage-scaled:" in out
    # the start's analysis of the tuned gains that export and codegen ask for is the one tune's start-up
    # line computed in this process, under another name of the table (design/memo.py: not keyed on it)
    table = tmp_path / "t" / "gains_voltage-scaled.json"
    hits, misses = minimum_speed.cache_info()
    s = json.loads(table.read_text())["summary"]
    assert s["low_speed_limit_pu"] < 1 and s["worst_decay_1_s"] >= s["required"]["decay"] * (1 - 1e-9)
    assert (
        main(["export", str(drive), "--gains", str(table), "--target", "vesc", "--out", str(tmp_path / "f")])
        == 0
    )
    xml = (tmp_path / "f" / "vesc.xml").read_text()
    assert "<foc_observer_type>0</foc_observer_type>" in xml
    assert main(["codegen", str(drive), "--gains", str(table), "--out", str(tmp_path / "c")]) == 0
    assert minimum_speed.cache_info() == (hits + 1, misses)
