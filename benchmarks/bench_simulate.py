"""Benchmark: wall time per simulated control period of `sensorless simulate`, vs motulator in the same run.

Run:  python benchmarks/bench_simulate.py [--repeats N] [--motulator-python PATH] [--no-motulator]

Ours: the Fig. 9(b) scenario of Piippo, Hinkkanen, Luomi (2008) on the ``piippo2008`` preset (4 s at
5 kHz: 20001 control periods of the whole drive - motor with RK4 between samples, controllers, adaptive
observer with HF injection chain, zoh), run as a compiled CasADi ``mapaccum`` over the loop step built
by the family's simulation set-up (``family_of(drive).simulation``). Also shown: the same loop on
CasADi's virtual machine (no compiler), and the one-off cost of building and compiling it.

Baseline: motulator's sensorless 2.2-kW IPMSM drive (the same motor, flux-vector control with its
sensorless observer, motulator's own example configuration: speed step to 2 p.u. at 0.2 s, 0.7 p.u. load
at 0.8 s, 1.6 s simulated) timed in a subprocess. motulator needs Python >= 3.12: the benchmark uses the
current interpreter if it is new enough, else ``--motulator-python``, ``$MOTULATOR_PYTHON``, a
``python3.12``/``python3.13`` on PATH or under ~/.pyenv; it installs motulator from PyPI into a
virtual environment under the sensorless cache directory. Where no such interpreter exists (or the
install fails) the comparison is skipped and the reason printed. Timings are medians of repeated runs.
"""

from __future__ import annotations

import argparse
import dataclasses
import glob
import json
import os
import shutil
import statistics
import subprocess
import sys
import time

from sensorless.design.compiled import cache_dir
from sensorless.design.drive import load_drive
from sensorless.design.registry import family_of
from sensorless.design.scenario import load_scenario
from sensorless.design.simulate import CHUNK, compiled_chunk, run_loop

# Configures motulator's sensorless 2.2-kW IPMSM drive through its public API, runs it, prints JSON.
MOTULATOR_SCRIPT = r"""
import json, sys, time, io, contextlib
from math import pi
import motulator.drive.control.sm as control
from motulator.drive import model, utils

nominal = utils.NominalValues(U=370, I=4.3, f=75, P=2.2e3, tau=14)
base = utils.BaseValues.from_nominal(nominal, n_p=3)
machine_pars = model.SynchronousMachinePars(n_p=3, R_s=3.6, L_d=0.036, L_q=0.051, psi_f=0.545)
drive_model = model.Drive(
    model.SynchronousMachine(machine_pars),
    model.MechanicalSystem(J=0.015),
    model.VoltageSourceConverter(u_dc=540),
)
config = control.FluxVectorControllerCfg(i_s_max=1.5 * base.i, sensorless=True)
controller = control.VectorControlSystem(
    control.FluxVectorController(machine_pars, config), control.SpeedController(J=0.015, alpha_s=2 * pi * 4)
)
controller.set_speed_ref(lambda t: (t > 0.2) * 2 * base.w_M)
drive_model.mechanics.set_external_load_torque(lambda t: (t > 0.8) * 0.7 * nominal.tau)
simulation = model.Simulation(drive_model, controller)
t_stop = float(sys.argv[1])
with contextlib.redirect_stderr(io.StringIO()):  # its progress bar
    t0 = time.perf_counter()
    simulation.simulate(t_stop=t_stop)
    wall = time.perf_counter() - t0
from importlib.metadata import version
py = ".".join(map(str, sys.version_info[:3]))
result = {"wall": wall, "t_stop": t_stop, "T_s": config.T_s, "version": version("motulator"), "python": py}
print(json.dumps(result))
"""


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def find_python(explicit: str | None) -> tuple[str | None, str]:
    """An interpreter >= 3.12 for motulator, or (None, reason)."""
    if sys.version_info >= (3, 12):
        return sys.executable, "current interpreter"
    cands = [
        explicit,
        os.environ.get("MOTULATOR_PYTHON"),
        shutil.which("python3.13"),
        shutil.which("python3.12"),
    ]
    home = os.path.expanduser("~")
    cands += sorted(glob.glob(f"{home}/.pyenv/versions/3.1[2-9]*/bin/python3"), reverse=True)
    for c in cands:
        if not c:
            continue
        try:
            out = subprocess.run(
                [c, "-c", "import sys; print(sys.version_info >= (3, 12))"], capture_output=True, text=True
            )
        except OSError:
            continue
        if out.stdout.strip() == "True":
            return c, c
    v = ".".join(map(str, sys.version_info[:3]))
    return None, f"motulator needs Python >= 3.12; this is {v} and no python3.12+ was found"


def motulator_python(explicit: str | None) -> tuple[str | None, str]:
    """A Python with motulator importable (installing it into a cached venv if needed), or (None, reason)."""
    py, why = find_python(explicit)
    if py is None:
        return None, why
    if py == sys.executable:
        try:
            import motulator  # noqa: F401

            return py, why
        except ImportError:
            pass
    venv = cache_dir().parent / "motulator-venv"
    vpy = venv / "bin" / "python"
    ok = (
        vpy.exists()
        and subprocess.run([str(vpy), "-c", "import motulator"], capture_output=True).returncode == 0
    )
    if not ok:
        print(f"installing motulator into {venv} (with {py}) ...", flush=True)
        r = subprocess.run([py, "-m", "venv", str(venv)], capture_output=True, text=True)
        if r.returncode == 0:
            r = subprocess.run(
                [str(vpy), "-m", "pip", "install", "-q", "motulator"], capture_output=True, text=True
            )
        if r.returncode != 0:
            return None, f"installing motulator failed: {(r.stderr or r.stdout).strip()[-300:]}"
    return str(vpy), f"venv {venv}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--motulator-python", help="a Python >= 3.12 for the motulator baseline")
    ap.add_argument("--motulator-repeats", type=int, default=3)
    ap.add_argument("--motulator-t-stop", type=float, default=1.6, help="seconds simulated by motulator")
    ap.add_argument("--no-motulator", action="store_true")
    args = ap.parse_args()

    drive = load_drive("piippo2008")
    sc = load_scenario("fig9b", drive)
    t0 = time.perf_counter()
    setup = family_of(drive).simulation(drive, sc, None)
    compiled_chunk(setup.loop, CHUNK)
    t_build = time.perf_counter() - t0
    n = setup.inputs.shape[1]
    run_loop(setup)  # warm-up
    t_ours = median_time(lambda: run_loop(setup), args.repeats)
    short = dataclasses.replace(setup, inputs=setup.inputs[:, : 4 * CHUNK])
    run_loop(short, compile=False)
    t_vm = (
        median_time(lambda: run_loop(short, compile=False), max(1, args.repeats // 2)) / short.inputs.shape[1]
    )
    per_ours = t_ours / n
    print(f"sensorless simulate, piippo2008 Fig. 9(b): {n} control periods (T_s = {setup.T_s * 1e6:g} us)")
    print(f"  build + compile (once; cached on disk afterwards): {t_build:.2f} s")
    print(f"  compiled mapaccum loop:   {per_ours * 1e6:8.2f} us per control period (median {t_ours:.3f} s)")
    print(
        f"  same loop on CasADi's VM: {t_vm * 1e6:8.2f} us per control period ({t_vm / per_ours:.1f}x slower)"
    )

    if args.no_motulator:
        print("motulator: skipped (--no-motulator)")
        return
    py, why = motulator_python(args.motulator_python)
    if py is None:
        print(f"motulator: skipped ({why})")
        print("target: >= 100x faster per control period than motulator (not measured in this run)")
        return
    walls, info = [], {}
    for _ in range(args.motulator_repeats):
        r = subprocess.run(
            [py, "-c", MOTULATOR_SCRIPT, str(args.motulator_t_stop)],
            capture_output=True,
            text=True,
            check=False,
        )
        if r.returncode != 0:
            print(f"motulator: skipped (its run failed: {r.stderr.strip()[-300:]})")
            return
        info = json.loads(r.stdout.strip().splitlines()[-1])
        walls.append(info["wall"])
    periods = round(info["t_stop"] / info["T_s"])
    per_mot = statistics.median(walls) / periods
    print(
        f"motulator {info['version']} (Python {info['python']}, {why}): sensorless 2.2-kW IPMSM (FVC), "
        f"{periods} control periods "
        f"(T_s = {info['T_s'] * 1e6:g} us): {per_mot * 1e6:8.1f} us per control period "
        f"(median of {len(walls)}: {statistics.median(walls):.2f} s)"
    )
    print(f"ratio motulator / sensorless per control period: {per_mot / per_ours:.0f}x   (target: >= 100x)")


if __name__ == "__main__":
    main()
