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

TESTS = Path(__file__).resolve().parents[1]
SERVO = (TESTS / "ipmsm_adaptive" / "drives" / "servo_minimal.toml").read_text()
HUB = (TESTS / "pmac_reduced_order" / "drives" / "hub48v_minimal.toml").read_text()


def write(tmp_path, text, name="mine.toml"):
    f = tmp_path / name
    f.write_text(text)
    return str(f)


def edited_preset(tmp_path, preset, pattern, repl):
    """The preset's text with the line matching ``pattern`` replaced, as a drive file of the user's."""
    text, n = re.subn(pattern, repl, preset_text(preset), count=1, flags=re.M)
    assert n == 1, pattern
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


def test_the_rated_point_mismatch_of_a_salient_motor_names_its_inductance(tmp_path):
    f = edited_preset(tmp_path, "piippo2008", r'^L_d = "0.036 H"', 'L_d = "36 H"')
    msg = load_error(f)
    assert "motor.L_d" in msg and "rating.I_N" in msg, msg
