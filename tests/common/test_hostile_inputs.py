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
    """The command exits 2 with one line naming each of ``words`` (argparse's own errors included);
    returns the line."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as e:  # argparse's error on an option's value: exit status 2, one line
        code = e.code
    assert code == 2
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
def _table(tmp_path, preset):
    """A gain table of ``preset`` (its drive file's gains: what the tests read is the table's drive),
    written by the writer `sensorless tune` uses (GainTable.to_json); a tuning for it cost ~1.5 s of
    CPU and only the gains would differ."""
    from sensorless.design.drive import load_drive
    from sensorless.design.gain_table import GainTable
    from sensorless.design.registry import family_of

    drive = load_drive(preset)
    g = family_of(drive).gains(drive)
    table = GainTable(
        law=g.law,
        drive={"name": drive.name, "kind": drive.kind, "sha256": drive.digest},
        gains=dict(g.values),
    )
    path = tmp_path / f"gains_{g.law}.json"
    path.write_text(table.to_json())
    return path


@pytest.fixture(scope="module")
def deangelo_table():
    """A gain table of the reduced-order preset (the document, for edited copies: the tests set its
    gains, they do not read them), written by the writer `sensorless tune` uses (GainTable.to_json)
    for the drive file's own gains: tuning one for these tests (one speed, one load) cost ~3 s of CPU
    and only its gains, which the tests replace, would differ."""
    import json

    from sensorless.design.drive import load_drive
    from sensorless.design.gain_table import GainTable

    drive = load_drive("deangelo2006")
    table = GainTable(
        law="constant",
        drive={"name": drive.name, "kind": drive.kind, "sha256": drive.digest},
        gains={"g": float(drive.observer.g), "Gamma": float(drive.observer.Gamma)},
    )
    return json.loads(table.to_json())


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
    table = _table(tmp_path, "piippo2008")
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
    for csv in (tmp_path / "a").glob("*.csv"):  # empty cells, each such row saying why: no nan
        rows = csv.read_text().splitlines()[2:]
        assert "nan" not in csv.read_text() and all(r.endswith(",") or "overflows" in r for r in rows)
        assert any("overflows" in r for r in rows), csv.name
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


# ------------------------------------------------------------- external engines: one line each
BAD_SCHEDULERS = ["bogus", "tcp://", "tcp://127.0.0.1:notaport", "http://127.0.0.1:1", "inproc://x"]


@pytest.mark.parametrize("address", BAD_SCHEDULERS)
def test_a_scheduler_address_dask_cannot_parse_is_one_line_before_anything_runs(
    tmp_path, capsys, monkeypatch, address
):
    # Dask's address parser raised bare ValueErrors (a traceback) for each of these
    monkeypatch.chdir(tmp_path)
    drives = tmp_path / "drives"
    drives.mkdir()
    (drives / "servo.toml").write_text(SERVO)
    mc = ["montecarlo", "piippo2008", "--spread", "R_s=10%", "--samples", "2", "--out", "mc"]
    for argv in ([*mc, "--scheduler", address], ["tune", drives, "--out", "t", "--scheduler", address]):
        refused(argv, capsys, "--scheduler", repr(address))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["drives"]


def test_an_odrive_backup_nested_beyond_the_parser_is_one_line(tmp_path, capsys):
    deep = tmp_path / "deep.json"
    deep.write_text('{"a":' * 100_000 + "1" + "}" * 100_000)  # RecursionError before
    refused(
        ["init", "--from", "odrive", deep, "--u-dc", "24", "--out", tmp_path / "d.toml"], capsys, str(deep)
    )
    assert not (tmp_path / "d.toml").exists()


def test_codegen_startup_on_a_drive_without_a_pmsm_motor_says_why(tmp_path, capsys):
    # the reduced-order drive has no psi_pm: a CasADi shape error before
    refused(["codegen", "deangelo2006", "--startup", "--out", tmp_path / "c"], capsys, "I-f start", "PMSM")
    assert not (tmp_path / "c").exists()


# ------------------------------------------ imported and derived values: ranges, the user's keys
FLUX = preset_text("outrunner270")


@pytest.mark.parametrize(
    ("edit", "keys"),
    [
        (('KV = "270 rpm/V"', 'KV = "1e7 rpm/V"'), "inverter.u_dc, motor.KV, motor.poles, observer.T_obs"),
        (('u_dc = "24 V"', 'u_dc = "1e6 V"'), "inverter.u_dc, motor.KV, motor.poles, observer.T_obs"),
        (('T_obs = "125 us"', 'T_obs = "1 s"'), "observer.T_obs"),
        (('T_obs = "125 us"\n', ""), "inverter.f_s"),  # with f_s = 10 Hz below
    ],
)
def test_the_flux_familys_speed_limit_names_the_keys_the_user_wrote(tmp_path, edit, keys):
    text = FLUX.replace(*edit)
    if not edit[1]:
        text = text.replace('f_s = "8 kHz"', 'f_s = "10 Hz"')
    msg = load_error(write(tmp_path, text))
    # 'envelope.speed_max', derived, was the only key named before
    assert keys in msg and "mine.toml" in msg and "observer periods" in msg, msg


@pytest.mark.parametrize(
    ("line", "key", "words"),
    [
        ("poles = 1000000", "motor.poles", "more than 1000"),
        ("p = " + "1" * 301, "motor.p", "1.11111e+300"),  # the value in 6 digits, not 301
    ],
)
def test_pole_pairs_have_the_range_of_the_option(tmp_path, line, key, words):
    msg = load_error(write(tmp_path, FLUX.replace("poles = 14", line)))
    assert f"key '{key}'" in msg and words in msg and len(msg) < 300, msg


def test_a_servo_with_pole_pairs_past_the_range_is_refused(tmp_path):
    assert "more than 1000" in load_error(write(tmp_path, re.sub(r"^p = \d+", "p = 5000", SERVO, flags=re.M)))


def _xml(**fields):
    from sensorless.design.pmsm_flux_observer.firmware import vesc

    example = Path(__file__).resolve().parents[2] / "docs" / "examples" / "firmware" / "skate6374_mcconf.xml"
    text = example.read_text()
    for k, v in fields.items():
        text, n = re.subn(rf"<{k}>[^<]*</{k}>", f"<{k}>{v}</{k}>", text)
        assert n == 1, k
    assert vesc.ROOT in text
    return text


@pytest.mark.parametrize(
    ("fields", "options", "words"),
    [
        ({"foc_f_zv": "1e12"}, [], ["key 'foc_f_zv'", "5e+11 Hz", "1e+06 Hz"]),  # accepted before
        ({"foc_f_zv": "10"}, [], ["key 'foc_f_zv'", "5 Hz"]),  # envelope.speed_max of v.toml before
        ({"si_motor_poles": "1000000"}, [], ["key 'si_motor_poles'", "500000", "1 to 1000"]),
        ({"si_battery_cells": "100000"}, [], ["key 'si_battery_cells'", "370000 V"]),
        # 1000 cells = 3700 V is within --u-dc's range: the drive's speed limit, named by its fields
        ({"si_battery_cells": "1000"}, [], ["inverter.u_dc = si_battery_cells x 3.7 V", "observer periods"]),
    ],
)
def test_an_imported_value_has_the_range_of_its_option_and_names_the_file_read(
    tmp_path, capsys, fields, options, words
):
    f = tmp_path / "cfg.xml"
    f.write_text(_xml(**fields))
    out = tmp_path / "v.toml"
    err = refused(["init", "--from", "vesc", f, *options, "--out", out], capsys, f"{f}: ", *words)
    assert "v.toml" not in err and not out.exists(), err


def test_a_derived_startup_value_names_the_motor_keys_it_follows_from(tmp_path, capsys):
    # J = 1e-12 kg m2: the start's acceleration p (T_max - T_N) / (2 J) overflows; it blamed the
    # derived startup.acceleration of the file being written
    src = write(tmp_path, re.sub(r"^J = .*$", 'J = "1e-12 kgm2"', SERVO, flags=re.M), "servo.toml")
    err = refused(["init", src, "--out", tmp_path / "s.toml"], capsys, f"{src}: ", "motor.J", "acceleration")
    assert "s.toml" not in err and not (tmp_path / "s.toml").exists()


# -------------------------------------------------------------- names that become file names
@pytest.mark.parametrize("name", ["../evil", "a/b", "..", ".hidden", "-rf", "a\tb", "x" * 300])
def test_a_drive_name_is_checked_as_a_path_component(tmp_path, capsys, monkeypatch, name):
    monkeypatch.chdir(tmp_path)
    src = write(tmp_path, re.sub(r"^name = .*$", f"name = {name!r}".replace("'", '"'), SERVO, flags=re.M))
    msg = load_error(src)
    assert "key 'drive.name'" in msg, msg
    xml = tmp_path / "cfg.xml"
    xml.write_text(_xml())
    refused(["init", "--from", "vesc", xml, "--name", name, "--out", "d.toml"], capsys, "--name")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cfg.xml", "mine.toml"]


def test_names_from_file_names_and_prefixes_name_what_the_user_gave(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    long = tmp_path / ("b" * 200 + ".xml")  # the default name is the file's: give --name
    long.write_text(_xml())
    refused(["init", "--from", "vesc", long, "--out", "d.toml"], capsys, "--name", "at most 64")
    # a 60-character name is a drive name, but too long for a C prefix: --prefix was not given
    src = write(tmp_path, re.sub(r"^name = .*$", f'name = "{"n" * 60}"', SERVO, flags=re.M))
    err = refused(["codegen", src, "--out", "c"], capsys, "drive.name", "give --prefix")
    assert "argument --prefix" not in err and "--out" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == [long.name, "mine.toml"]


# -------------------------------------------------------------------------------------- [startup]
@pytest.mark.parametrize(
    ("line", "key"),
    [
        ('current = "1e6 A"', "startup.current"),
        ('dwell = "1e6 s"', "startup.dwell"),
        ('w_on = "100 pu"', "startup.w_on"),
        ('w_on = "1e9 rad/s"', "startup.w_on"),
        ('w_on = "1000 w_min"', "startup.w_on"),
    ],
)
def test_startup_values_have_ranges(tmp_path, capsys, line, key):
    src = write(tmp_path, f"{preset_text('hubmotor48')}\n[startup]\n{line}\n")  # a drive without warnings
    refused(["codegen", src, "--startup", "--out", tmp_path / "c"], capsys, src, key)
    assert not (tmp_path / "c").exists()
