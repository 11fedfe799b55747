"""Hostile inputs that load but used to break a later stage, were accepted silently or named the wrong
thing: each refused (exit status 2, one line naming the user's file and key or the option, nothing
written) or warned about, on drive files that are not presets (minimal files of docs/examples and
tests/*/drives, or a preset copied to a file of the user's own)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from sensorless.design.drive import load_drive, preset_text
from sensorless.design.units import DriveFileError
from sensorless.reports.cli.main import main
from sensorless.reports.family import all_options

pytestmark = pytest.mark.long(24)  # CPU seconds of this file, measured: scheduled first (tests/conftest.py)

TESTS = Path(__file__).resolve().parents[1]
SERVO = (TESTS / "ipmsm_adaptive" / "drives" / "servo_minimal.toml").read_text()
HUB = (TESTS / "pmac_reduced_order" / "drives" / "hub48v_minimal.toml").read_text()


def write(tmp_path, text, name="mine.toml"):
    f = tmp_path / name
    f.write_text(text)
    return str(f)


def edited_preset(tmp_path, preset, pattern, repl, count=1):
    """The preset's text with the line matching ``pattern`` replaced (the first ``count``; 0: all), as a
    drive file of the user's."""
    text, n = re.subn(pattern, repl, preset_text(preset), count=count, flags=re.M)
    assert n >= 1, pattern
    return write(tmp_path, text)


def refused(argv, capsys, *words):
    """The command exits 2 with one line naming each of ``words``; returns the line."""
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, (w, err)
    assert "Traceback" not in err
    return err


def load_error(path):
    with pytest.raises(DriveFileError) as e:
        load_drive(path)
    return str(e.value)


# ------------------------------------------------------- every [tuning] key: the range of its option
def _tuning_options():
    """(drive-file key, Number) of every numeric tune option that is also a [tuning] key."""
    out = []
    for dest, (opt, _) in all_options("tune").items():
        t = opt.kwargs.get("type")
        if hasattr(t, "hi") and dest in ("speed_max", "speeds", "dense_factor", "min_decay", "breakpoints"):
            out.append((dest, t))
    return out


@pytest.mark.parametrize(("key", "number"), _tuning_options(), ids=lambda x: getattr(x, "__name__", str(x)))
def test_every_tuning_key_of_a_drive_file_has_the_range_of_its_option(tmp_path, key, number):
    unit = " pu" if key.startswith("speed_") else (" 1/s" if key == "min_decay" else "")
    over = number.hi * 1e6 if number.hi >= 1 else number.hi + 1  # e.g. speeds = 1e9 (the option: 1000)
    value = f'"{over:g}{unit}"' if unit else f"{int(over)}"
    text = preset_text("piippo2008").replace("[tuning]", f"[tuning]\n{key} = {value}", 1)
    # the key once: ours, not the preset's own line of it
    lines, seen = [], False
    for line in text.splitlines():
        if line.startswith(f"{key} = "):
            if seen:
                continue
            seen = True
        lines.append(line)
    msg = load_error(write(tmp_path, "\n".join(lines) + "\n"))
    assert f"tuning.{key}" in msg and f"--{key.replace('_', '-')}" in msg, msg


def test_carrier_delay_of_a_billion_samples_is_refused(tmp_path):
    f = edited_preset(tmp_path, "piippo2008", r"^carrier_delay = .*$", "carrier_delay = 1000000000")
    assert "runtime.carrier_delay" in load_error(f)
    ok = edited_preset(tmp_path, "piippo2008", r"^carrier_delay = .*$", "carrier_delay = 2")
    assert load_drive(ok).runtime.carrier_delay == 2


# ------------------------------------------------------------------- errors naming the user's keys
def test_a_derived_value_out_of_range_names_the_users_key(tmp_path):
    # f_s = 1e12 Hz: the carrier w_c = f_s/6 is out of range, but the user wrote f_s
    msg = load_error(write(tmp_path, SERVO.replace('f_s = "10 kHz"', 'f_s = "1e12 Hz"')))
    assert "key 'inverter.f_s'" in msg and "injection.w_c" in msg, msg
    # J = 1e-12 kg m2 on a reduced-order drive: Gamma ~ J^2 underflows; the user wrote J
    msg = load_error(write(tmp_path, re.sub(r"^J = .*$", 'J = "1e-12 kgm2"', HUB, flags=re.M)))
    assert msg.split(": ")[1].startswith("keys 'motor.J") and "observer.Gamma" in msg, msg


def test_a_dc_link_of_another_drive_is_refused_naming_it(tmp_path):
    # 1e6 V for a 400-W servo (rated point ~91 V peak phase): 6000x; 10x warns, 100x is refused
    msg = load_error(write(tmp_path, SERVO.replace('u_dc = "310 V"', 'u_dc = "1e6 V"')))
    assert "keys 'inverter.u_dc" in msg, msg
    warned = load_drive(write(tmp_path, SERVO.replace('u_dc = "310 V"', 'u_dc = "5000 V"')))
    assert any("inverter.u_dc" in w for w in warned.warnings), warned.warnings
    assert not load_drive(write(tmp_path, SERVO)).warnings


@pytest.mark.parametrize("R", ["1e-11 ohm", "0.001 mohm"])
def test_a_resistance_far_too_small_is_refused_before_any_analysis(tmp_path, R):
    # the report's pointwise bound never ended, and its figures got NaN axis limits, on R = 1e-11 ohm
    msg = load_error(write(tmp_path, SERVO.replace('R_s = "1.8 ohm"', f'R_s = "{R}"')))
    assert "keys 'motor.R_s, motor.L_s'" in msg and "L/R" in msg, msg
    full = edited_preset(tmp_path, "piippo2008", r'^R_s = "3.59 ohm"', f'R_s = "{R}"', count=0)
    assert "motor.R_s" in load_error(full)


def test_the_rated_point_mismatch_of_a_salient_motor_names_its_inductance(tmp_path):
    f = edited_preset(tmp_path, "piippo2008", r'^L_d = "0.036 H"', 'L_d = "36 H"')
    msg = load_error(f)
    assert "motor.L_d" in msg and "rating.I_N" in msg, msg


# ----------------------------------------------------------------- command-line values and paths
@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["analyze", "piippo2008", "--out", ""], "--out"),
        (["codegen", "piippo2008", "--prefix", "", "--out", "{d}/c"], "--prefix"),
        (["codegen", "piippo2008", "--prefix", "a" * 300, "--out", "{d}/c"], "--prefix"),
        (
            ["simulate", "piippo2008", "--scenario", "fig10", "--duration", "1e-6", "--out", "{d}/s"],
            "--duration",
        ),
        (["tune", "deangelo2006", "--max-noise=position=0deg", "--out", "{d}/t"], "--max-noise"),
        (["tune", "piippo2008", "--max-noise=speed=0pu", "--out", "{d}/t"], "--max-noise"),
    ],
)
def test_an_option_given_empty_or_meaningless_is_refused_naming_it(
    tmp_path, capsys, monkeypatch, argv, option
):
    monkeypatch.chdir(tmp_path)
    err = refused([a.replace("{d}", str(tmp_path)) for a in argv], capsys, option)
    assert "--out" not in err or option == "--out", err  # --prefix is not blamed on --out
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_init_out_with_a_trailing_slash_writes_no_file_named_like_the_directory(tmp_path, capsys):
    src = write(tmp_path, SERVO, "servo.toml")
    refused(["init", src, "--out", f"{tmp_path}/newdir/"], capsys, "--out")
    assert not (tmp_path / "newdir").exists()


# ----------------------------------------------------------------------------------- gain tables
def _table(tmp_path, capsys, drive, name):
    assert (
        main(
            [
                "tune",
                drive,
                "--quiet",
                "--out",
                str(tmp_path / "t"),
                *(["--speeds", "3"] if "law" in name else []),
            ]
        )
        == 0
    )
    capsys.readouterr()
    return tmp_path / "t" / name


@pytest.fixture(scope="module")
def deangelo_table():
    """A tuned gain table of the reduced-order preset (the document, for edited copies): tuned on a
    small envelope (two speeds, two loads: 3.5 s instead of the default's 14 s) and written by the
    writer `sensorless tune` uses."""
    import dataclasses
    import json

    from sensorless.design.drive import load_drive
    from sensorless.tuning.pmac_reduced_order.settings import default_settings
    from sensorless.tuning.pmac_reduced_order.tuner import tune_deangelo

    drive = load_drive("deangelo2006")
    small = dataclasses.replace(default_settings(drive), speeds_rpm=(250.0, 1000.0), loads_Nm=(0.0, 5.0))
    return json.loads(tune_deangelo(drive, small).table.to_json())


def test_gain_table_errors_name_the_file_and_the_key(tmp_path, capsys, deangelo_table):
    import json

    doc = deangelo_table
    capsys.readouterr()
    for key, bad in (("g", -5), ("Gamma", [1, 2])):
        f = tmp_path / f"bad_{key}.json"
        f.write_text(json.dumps({**doc, "gains": {**doc["gains"], key: bad}}))
        refused(
            ["analyze", "deangelo2006", "--gains", f, "--out", tmp_path / "a"], capsys, str(f), f"gains.{key}"
        )


def test_analyze_warns_about_a_table_tuned_for_another_drive(tmp_path, capsys):
    table = _table(tmp_path, capsys, "piippo2008", "gains_speed-dependent.json")
    servo = write(tmp_path, SERVO, "servo.toml")
    assert (
        main(["analyze", servo, "--gains", str(table), "--points", "11", "--out", str(tmp_path / "a")]) == 0
    )
    err = capsys.readouterr().err
    assert "warning" in err and "piippo2008" in err and "servo400" in err, err


# ------------------------------------------------------ values that break a later stage; NaN in CSVs
def test_an_overflowing_linearization_gives_nan_poles_not_a_traceback():
    import numpy as np
    from sensorless.design.pmac_reduced_order.linearize import floquet_exponents

    M = np.stack([np.eye(3), np.full((3, 3), np.inf)])
    s = floquet_exponents(M, np.array([1.0, 1.0]))
    assert np.all(np.isfinite(s[0])) and np.all(np.isnan(s[1]))


def test_analyze_says_why_it_writes_numbers_that_are_not_finite(tmp_path, capsys, deangelo_table):
    import json

    # a reduced-order gain table with g = 1e9 1/s (within --g-max's range): the observer overflows
    f = tmp_path / "g1e9.json"
    f.write_text(json.dumps({**deangelo_table, "gains": {**deangelo_table["gains"], "g": 1e9}}))
    capsys.readouterr()
    code = main(
        ["analyze", "deangelo2006", "--gains", str(f), "--speed", "100,250", "--out", str(tmp_path / "a")]
    )
    err = capsys.readouterr().err
    assert code == 3, err
    assert "RuntimeWarning" not in err and "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert lines and all("warning" in x and "no finite poles" in x and ".csv" in x for x in lines), err
    # the reduced-order drive with its inductance in H where uH was meant is refused at load (L/R)
    h = edited_preset(tmp_path, "deangelo2006", r'^L = "100 uH"', 'L = "100 H"', count=0)  # motor, estimate
    assert "motor.L" in load_error(h)


# ----------------------------------------------------------------------------------------- Ctrl-C
def test_casadis_own_report_of_a_caught_interrupt_is_silenced(capsys):
    import sys

    from sensorless.reports import interrupts

    with interrupts.handled():
        # as IPOPT's callback prints it, in pieces; other CasADi lines and other text pass
        for piece in (
            "CasADi - 2026-01-01 00:00:00 WARNING(",
            '"KeyboardInterruptException")',
            " [ipopt_nlp.cpp:95]\n",
        ):
            sys.stderr.write(piece)
        sys.stderr.write('CasADi - 2026-01-01 00:00:00 WARNING("something else") [x.cpp:1]\n')
        sys.stderr.write("progress\n")
    err = capsys.readouterr().err
    assert err == 'CasADi - 2026-01-01 00:00:00 WARNING("something else") [x.cpp:1]\nprogress\n', err
