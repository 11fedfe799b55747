"""Benchmark of the generated C steps against hand-written C references of the same discrete equations.

    python benchmarks/bench_codegen.py [--passes 21] [--observer ipmsm_adaptive|pmac_reduced_order|...]

For each observer family with a runtime observer:
- the speed-adaptive observer of Piippo et al. (2008), preset piippo2008 (zoh, law (16), HF
  injection), against benchmarks/ref_step_ipmsm_adaptive.c, on 12000 samples of the simulated motor
  (tests/helpers/runtime_loop.py);
- the reduced-order EMF and load-torque observer of De Angelo et al. (2006), preset deangelo2006
  (rk2-model, EMF harmonics 1 and 5), against benchmarks/ref_step_pmac_reduced_order.c, on 14444 samples
  of the independent plant (tests/helpers/plant_pmac.py: load steps, speed ramps through zero);
- the flux observer + PLL of Lee et al. (2010) as ODrive runs it, preset outrunner270 (gradient, fixed
  inductance, constant gain), against benchmarks/ref_step_pmsm_flux_observer.c, on 12000 samples of
  8 steady operating points (tests/helpers/fuzz.py pmsm_steady_segments);

it generates the double step, compiles it with the yardstick (written by hand from the equations with
every parameter-only quantity precomputed, and the runtime contract's guard, state bounds, coasting and
self-reset written with branches, symbolic/runtime.py) and benchmarks/bench_codegen_main.c into one
program, checks that both compute the same outputs and states on the trajectory, and on a copy of it
with samples the guard must reject (``with_rejected_samples``: coasting, the counter, self-resets),
then measures on the clean trajectory, in the same run:
- ns/step of each (median of interleaved passes over the trajectory) and their ratio;
- instructions/step of each under valgrind's callgrind (only the step functions and their callees),
  and their ratio, where valgrind is installed;
- the Cortex-M4F (arm-none-eabi-gcc -O2, fpv4-sp-d16 hard float) size of the float build: the object's
  .text and the step and init functions' own sizes.
Target: generated <= 1.10 x hand-written (instructions/step). The ratios are the figures to compare;
absolute times depend on the machine (and its other load).
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))  # the trajectories the codegen tests check on

import numpy as np  # noqa: E402
from sensorless.design.drive import load_drive  # noqa: E402
from sensorless.design.registry import family_of  # noqa: E402
from sensorless.reports.codegen.generate import Provenance, c_identifier, generate  # noqa: E402

CFLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]
ARM = ["-std=c99", "-O2", "-mthumb", "-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"]
TARGET = 1.10


def adaptive_trajectory(setup: Any, drive: Any) -> np.ndarray:
    from helpers.runtime_loop import TRAJECTORY_SEGMENTS, profile_from_segments, simulate

    prof = profile_from_segments(TRAJECTORY_SEGMENTS, drive.control.T_s, drive.base.w, drive.T_N)
    return simulate(setup, drive, prof, theta0=0.2)["meas"]


def reduced_order_trajectory(setup: Any, drive: Any) -> np.ndarray:
    from helpers.plant_pmac import codegen_trajectory

    return codegen_trajectory(drive)["meas"]


def flux_observer_trajectory(setup: Any, drive: Any) -> np.ndarray:
    from helpers.fuzz import pmsm_steady_segments, steady_rows

    m = drive.motor
    rows = steady_rows(np.random.default_rng(2010), 8, (0.3, 1.0), drive.w_base, drive.T_N)
    seg = pmsm_steady_segments((m.R_s, m.L_d, m.L_q, m.psi_pm, m.p), drive.T_s, rows, 1500)
    return seg.reshape(-1, 6)[:, :4]


def with_rejected_samples(meas: np.ndarray) -> np.ndarray:
    """The trajectory with samples the guard must reject: a short NaN burst (coasting), absurd but finite
    currents, a long burst of infinite voltage (a reset at RESET_AFTER), then 2 rejected samples of every
    3 (the counter climbs by one per 3 samples: a reset only if accepted samples count it down by one)."""
    m = meas.copy()
    n = len(m)
    m[n // 5 : n // 5 + 10, 0] = np.nan
    m[n // 4 : n // 4 + 3, :2] = 1e4 * np.abs(meas[:, :2]).max()
    m[n // 3 : n // 3 + 150, 2] = np.inf
    k = np.arange(n // 2, n // 2 + 330)
    m[k[k % 3 != 0], 1] = np.nan
    return m


@dataclass(frozen=True)
class Case:
    """One observer: its preset, yardstick, and trajectory."""

    name: str  # the family's name; -DBENCH_<NAME> selects it in bench_codegen_main.c
    preset: str
    reference: str  # benchmarks/<reference>.c
    ref_function: str  # the yardstick's step function (callgrind)
    trajectory: Callable[[Any, Any], np.ndarray]
    what: str


CASES = (
    Case(
        "ipmsm_adaptive",
        "piippo2008",
        "ref_step_ipmsm_adaptive",
        "ref_step",
        adaptive_trajectory,
        "speed-adaptive observer (Piippo et al. 2008): law (16), HF injection",
    ),
    Case(
        "pmac_reduced_order",
        "deangelo2006",
        "ref_step_pmac_reduced_order",
        "ref_pmac_step",
        reduced_order_trajectory,
        "reduced-order EMF + load-torque observer (De Angelo et al. 2006): EMF harmonics 1, 5",
    ),
    Case(
        "pmsm_flux_observer",
        "outrunner270",
        "ref_step_pmsm_flux_observer",
        "ref_flux_step",
        flux_observer_trajectory,
        "flux observer + PLL (Lee et al. 2010) as ODrive runs it: gradient, fixed L, constant gain",
    ),
)


def write(files: dict[str, str], d: Path) -> None:
    d.mkdir(parents=True, exist_ok=True)
    for n, t in files.items():
        (d / n).write_text(t)


def callgrind(exe: Path, mode: str, traj: Path, fn: str, n: int, work: Path) -> float:
    """Instructions per step executed inside ``fn`` (and what it calls)."""
    out = work / f"cg.{mode}.out"
    r = subprocess.run(
        [
            "valgrind",
            "--tool=callgrind",
            f"--callgrind-out-file={out}",
            "--collect-atstart=no",
            f"--toggle-collect={fn}",
            str(exe),
            mode,
            str(traj),
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    m = re.search(r"Collected\s*:\s*(\d+)", r.stderr)
    if not m:
        raise RuntimeError(f"callgrind gave no count:\n{r.stderr}")
    return int(m.group(1)) / n


def m4_sizes(arm: str, src: Path, prefix: str, work: Path) -> tuple[int, int, int]:
    """(.text, <prefix>_step, <prefix>_init) in bytes of the float build for the Cortex-M4F."""
    obj = work / f"{prefix}-m4.o"
    subprocess.run([arm, *ARM, "-c", "-o", str(obj), str(src)], check=True)
    size = subprocess.run([arm.replace("gcc", "size"), str(obj)], capture_output=True, text=True).stdout
    text = int(size.splitlines()[1].split()[0])
    nm = subprocess.run([arm.replace("gcc", "nm"), "-S", str(obj)], capture_output=True, text=True).stdout
    sizes = {ln.split()[-1]: int(ln.split()[1], 16) for ln in nm.splitlines() if len(ln.split()) == 4}
    return text, sizes[f"{prefix}_step"], sizes[f"{prefix}_init"]


def run_case(case: Case, cc: str, passes: int, work: Path) -> dict[str, Any] | None:
    """Measure one observer; prints as it goes; returns the figures (None if the check fails)."""
    drive = load_drive(case.preset)
    fam = family_of(drive)
    setup = fam.runtime(drive, fam.gains(drive))
    prefix = c_identifier(drive.name)
    prov = Provenance(drive.name, drive.file, drive.digest, "bench")
    meas = case.trajectory(setup, drive)
    n = len(meas)
    work.mkdir(parents=True)
    write(generate(setup, prov, precision="double"), work / "double")
    write(generate(setup, prov, precision="float"), work / "float")
    traj, hostile = work / "samples.bin", work / "rejected.bin"
    np.ascontiguousarray(meas, dtype="<f8").tofile(traj)
    np.ascontiguousarray(with_rejected_samples(meas), dtype="<f8").tofile(hostile)
    exe = work / "bench"
    src = [work / "double" / f"{prefix}.c", HERE / f"{case.reference}.c", HERE / "bench_codegen_main.c"]
    inc = ["-I", str(work / "double"), "-I", str(HERE), f"-DBENCH_{case.name.upper()}"]
    subprocess.run([cc, *CFLAGS, *inc, "-o", str(exe), *map(str, src), "-lm"], check=True)

    print(f"\n{case.what}")
    print(f"preset {drive.name}, {setup.discretization}, double; trajectory of {n} samples")
    for what, path in (("", traj), (" with rejected samples", hostile)):
        r = subprocess.run([str(exe), "check", str(path)], capture_output=True, text=True, check=True)
        d_y, d_x, rejected, resets = (float(v) for v in r.stdout.split())
        print(
            f"generated vs hand-written{what}: max relative difference outputs {d_y:.1e}, states {d_x:.1e}"
            f" ({rejected:.0f} rejected, {resets:.0f} resets)"
        )
        if not (d_y < 1e-11 and d_x < 1e-11):
            print("the two implementations disagree: the yardstick is not the same equations")
            return None

    res: dict[str, Any] = {"case": case, "n": n}
    r = subprocess.run([str(exe), "time", str(traj), str(passes)], capture_output=True, text=True)
    res["ns"] = tuple(map(float, r.stdout.split()))
    print(f"{'':24}{'generated':>12}{'hand-written':>14}{'ratio':>8}")
    t_gen, t_ref = res["ns"]
    print(f"{'ns/step (median)':24}{t_gen:12.1f}{t_ref:14.1f}{t_gen / t_ref:8.3f}")
    if shutil.which("valgrind"):
        i_gen = callgrind(exe, "gen", traj, f"{prefix}_step", n, work)
        i_ref = callgrind(exe, "ref", traj, case.ref_function, n, work)
        res["instr"] = (i_gen, i_ref)
        print(f"{'instructions/step':24}{i_gen:12.1f}{i_ref:14.1f}{i_gen / i_ref:8.3f}")
    else:
        print("instructions/step: valgrind not installed")
    arm = shutil.which("arm-none-eabi-gcc")
    if arm:
        text, step, init = m4_sizes(arm, work / "float" / f"{prefix}.c", prefix, work)
        res["m4"] = (text, step, init)
        print(
            f"Cortex-M4F float build (-O2): .text {text} bytes; {prefix}_step {step} bytes, "
            f"{prefix}_init {init} bytes"
        )
    else:
        print("Cortex-M4F size: arm-none-eabi-gcc not installed")
    return res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", type=int, default=21, help="timed passes over the trajectory (median)")
    ap.add_argument("--observer", choices=[c.name for c in CASES], help="only this observer")
    args = ap.parse_args()
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        print("no C compiler (gcc/cc): nothing to measure")
        return 1
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            if args.observer in (None, case.name):
                res = run_case(case, cc, args.passes, Path(tmp) / case.name)
                if res is None:
                    return 1
                results.append(res)
    print(f"\nsummary (generated / hand-written, target <= {TARGET:.2f} in instructions/step)")
    ok = True
    for res in results:
        line = f"  {res['case'].preset:14} ns/step {res['ns'][0] / res['ns'][1]:.3f}"
        if "instr" in res:
            ratio = res["instr"][0] / res["instr"][1]
            ok &= ratio <= TARGET
            line += f", instructions/step {ratio:.3f} ({'met' if ratio <= TARGET else 'NOT met'})"
        print(line)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
