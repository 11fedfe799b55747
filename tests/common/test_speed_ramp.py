"""The speed reference's rate limiter (symbolic/speed_ramp.py, ``[control] speed_ramp``) against what
it must do, checked independently of its code:

- the drive file's key in rad/s^2 or p.u./s (the base stated), a negative one refused naming the key;
- in the simulated drive (the loop ``simulate`` runs) the reference the speed controller tracks moves by
  exactly a T_s a period from a step of the command, and the rotor's own speed (the mechanics, not the
  limiter) follows at the key's slope below the torque limit, where the same step without the key asks
  for several times the torque;
- the whole-drive linearization at fixed points is the same with the limiter (it is inactive there);
- the generated C replays the limiter like the Python step, and its output's slope is the key;
- ``sensorless init`` derives it on the gimbal motor of docs/examples/motors, whose handover the rule
  puts at the rated speed without it, and not on a motor that hands over below.
"""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from sensorless.design.drive import load_drive, load_drive_text
from sensorless.design.drive_analysis import linearize_drive
from sensorless.design.registry import family_of
from sensorless.design.runtime import run_trajectory
from sensorless.design.scenario import drive_units, load_scenario_text
from sensorless.design.simulate import simulate
from sensorless.design.speed_ramp import drive_ramp
from sensorless.design.units import DriveFileError

MOTORS = Path(__file__).resolve().parents[2] / "docs" / "examples" / "motors"
SERVO = MOTORS / "servo400.toml"
CC = shutil.which("gcc") or shutil.which("cc")


def servo_text(ramp: str) -> str:
    return SERVO.read_text(encoding="utf-8") + f'\n[control]\nspeed_ramp = "{ramp}"\n'


def test_the_key_reads_rad_per_s2_and_pu_per_s_and_refuses_a_negative_one():
    base = load_drive(SERVO)
    assert base.control.speed_ramp == 0.0  # absent: no limiter
    pu = load_drive_text(servo_text("2 pu/s"), "servo.toml")
    assert pu.control.speed_ramp == pytest.approx(2 * base.w_base, rel=1e-12)
    si = load_drive_text(servo_text("1500 rad/s^2"), "servo.toml")
    assert si.control.speed_ramp == 1500.0
    with pytest.raises(DriveFileError) as e:
        load_drive_text(servo_text("-1 rad/s^2"), "servo.toml")
    assert "control.speed_ramp" in str(e.value) and "servo.toml" in str(e.value)


def _step(drive, w0: float, w1: float, duration: float):
    text = (
        '[scenario]\nname = "ramp"\ntitle = "step of the command"\n'
        f'kind = "{drive.kind}"\nduration = "{duration:.6g} s"\n'
        f'[initial]\nw_m = "{w0:g} pu"\n[speed_reference]\nt = [0, {0.002:g}]\n'
        f'value = ["{w0:g} pu", "{w1:g} pu"]\n'
    )
    return load_scenario_text(text, "ramp", drive_units(drive))


def test_the_simulated_reference_ramps_at_the_key_and_the_rotor_follows_it():
    base = load_drive(SERVO)
    scales = family_of(base).scales(base)
    # a quarter of what the torque gives at most, and a ramp of 20 / alpha_s: the speed loop's transient
    # (a few 1 / alpha_s) is over in its second half
    a = min(0.25 * float(scales.braking(0.0)), 0.5 * base.w_base * scales.alpha_s / 20)
    drive = dataclasses.replace(base, control=dataclasses.replace(base.control, speed_ramp=a))
    t_ramp = 0.5 * base.w_base / a
    sc = _step(drive, 0.5, 1.0, 0.002 + t_ramp + 0.05)
    tr = simulate(drive, sc, None, compile=False)
    assert not tr.problems()
    r, T_s = np.asarray(tr["w_ref_r"]), drive.T_s
    moving = np.flatnonzero(np.abs(np.asarray(tr["w_ref"]) - r) > 1e-9)
    steps = np.diff(r)[moving[:-1]]
    # every period of the ramp but its last moves by exactly a T_s (the limiter's equation, typed here)
    assert steps.size > 50 and np.allclose(steps[:-1], a * T_s, rtol=1e-9)
    assert r[-1] == pytest.approx(base.w_base)  # it has reached the command
    # the rotor (the mechanics under the speed loop) follows at the key's slope in the ramp's middle
    t, w = tr.t, np.asarray(tr["w_m"])
    mid = (t > 0.002 + 0.5 * t_ramp) & (t < 0.002 + 0.9 * t_ramp)
    slope = np.polyfit(t[mid], w[mid], 1)[0]
    assert slope == pytest.approx(a, rel=0.03)
    assert np.max(np.abs(tr["T_ref"])) < 0.9 * drive.control.T_max
    # without the key the same step is the speed loop's own response: several times the torque
    plain = simulate(base, _step(base, 0.5, 1.0, 0.03), None, compile=False)
    assert "w_ref_r" not in plain.data
    assert np.max(np.abs(plain["T_ref"])) > 2 * np.max(np.abs(tr["T_ref"]))


def test_the_whole_drive_linearization_is_unchanged_at_fixed_points():
    base = load_drive(SERVO)
    drive = dataclasses.replace(base, control=dataclasses.replace(base.control, speed_ramp=1000.0))
    w = np.array([0.3, -0.6]) * base.w_base
    T = np.array([0.5, -1.0]) * base.T_N
    gains = family_of(base).gains(base)
    a, b = linearize_drive(base, gains, w, T), linearize_drive(drive, gains, w, T)
    assert np.isfinite(a.poles).all()
    np.testing.assert_allclose(b.y, a.y, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(b.poles, a.poles, rtol=1e-9)
    np.testing.assert_allclose(b.ramp_lag, a.ramp_lag, rtol=1e-9)


@pytest.mark.skipif(CC is None, reason="no host C compiler (gcc/cc) on PATH")
def test_the_generated_c_replays_the_ramp_like_python(tmp_path):
    from sensorless.reports.cli.main import main

    drive_file = tmp_path / "servo.toml"
    drive_file.write_text(servo_text("2000 rad/s^2"), encoding="utf-8")
    out = tmp_path / "c"
    assert (
        main(["codegen", str(drive_file), "--out", str(out), "--prefix", "srv", "--precision", "double"]) == 0
    )
    h = (out / "srv.h").read_text(encoding="utf-8")
    assert "ramp_acc;" in h and "w_cmd;" in h and "w_ref_r;" in h
    exe = tmp_path / "replay"
    r = subprocess.run(
        [CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-o", str(exe),
         str(out / "main.c"), str(out / "srv.c"), "-lm"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert r.returncode == 0 and r.stderr == "", r.stderr
    drive = load_drive(drive_file)
    fam = family_of(drive)
    setup = drive_ramp(drive, fam.runtime(drive, fam.gains(drive)))
    obs = setup.observer
    n = 400
    meas = np.zeros((n, len(obs.meas)))
    meas[:, -1] = np.where(np.arange(n) < 150, 300.0, -200.0)  # the command steps, up then down
    f = tmp_path / "samples.bin"
    np.ascontiguousarray(meas, dtype="<f8").tofile(f)
    run = subprocess.run([str(exe), str(f)], capture_output=True)
    assert run.returncode == 0, run.stderr.decode()
    c = np.frombuffer(run.stdout, "<f8").reshape(n, len(obs.outputs) + len(obs.state))
    xs, ys = run_trajectory(setup, meas)
    ref = np.hstack([ys, xs])  # every output and state, in the example's order
    scale = np.maximum(1.0, np.max(np.abs(ref), axis=0))
    assert np.all(np.abs(c - ref) <= 1e-12 * scale)
    k = obs.index("outputs", "w_ref_r")
    # the ramp's slope is the key: 2000 rad/s^2 at T_s, from 0 up to 300 rad/s, then down towards -200
    d = np.diff(c[:, k]) / drive.T_s
    assert np.allclose(d[:100], 2000.0, rtol=1e-9) and np.allclose(d[160:300], -2000.0, rtol=1e-9)


def test_init_derives_the_ramp_where_the_handover_sits_at_the_rated_speed(tmp_path, capsys):
    from sensorless.design.startup import ON_FACTOR
    from sensorless.reports.cli.main import main

    out = tmp_path / "gimbal.toml"
    assert main(["init", str(MOTORS / "gimbal.toml"), "--out", str(out)]) == 0
    drive = load_drive(out)
    text = out.read_text(encoding="utf-8")
    acc = float(text.split("[startup]")[1].split('acceleration = "')[1].split()[0])
    assert drive.control.speed_ramp == pytest.approx(acc)  # the start's acceleration
    # the handover written is below the rated speed along the ramp (w_min as the file's comment says)
    w_min_pu = float(text.split("for the handover")[1].split(": ")[1].split(" p.u.")[0])
    assert ON_FACTOR * w_min_pu < 1.0
