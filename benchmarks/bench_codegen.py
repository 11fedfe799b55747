"""Benchmark of the generated C step against a hand-written C reference of the same discrete equations.

    python benchmarks/bench_codegen.py [--passes 21]

Generates the paper-000 observer (preset piippo2008: Heun, law (16), HF injection, double), compiles it
with benchmarks/ref_step_000.c (the yardstick, written by hand from docs/runtime.md with every
parameter-only quantity precomputed) and benchmarks/bench_codegen_main.c into one program, checks that
both compute the same outputs on a recorded trajectory (12000 samples of tests/runtime_sim.py), then
prints, in the same run:
- ns/step of each (median of interleaved passes over the trajectory) and their ratio;
- instructions/step of each under valgrind's callgrind (only the step functions and their callees),
  and their ratio, where valgrind is installed;
- the Cortex-M4F (arm-none-eabi-gcc -O2, fpv4-sp-d16 hard float) size of the float build: the object's
  .text and the step function's own size.
Target: generated <= 1.10 x hand-written.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))  # the motor simulation helper of the tests

import numpy as np  # noqa: E402
from runtime_sim import TRAJECTORY_SEGMENTS, profile_from_segments, simulate  # noqa: E402
from sensorless.design.drive import load_drive  # noqa: E402
from sensorless.design.runtime import runtime_setup  # noqa: E402
from sensorless.tuning.codegen import Provenance, generate  # noqa: E402

CFLAGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]
ARM = ["-std=c99", "-O2", "-mthumb", "-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"]


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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--passes", type=int, default=21, help="timed passes over the trajectory (median)")
    args = ap.parse_args()
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        print("no C compiler (gcc/cc): nothing to measure")
        return 1

    drive = load_drive("piippo2008")
    setup = runtime_setup(drive)
    prov = Provenance(drive.name, drive.file, drive.digest, "bench")
    prof = profile_from_segments(TRAJECTORY_SEGMENTS, drive.control.T_s, drive.base.w, drive.T_N)
    meas = simulate(setup, drive, prof, theta0=0.2)["meas"]
    n = len(meas)

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        write(generate(setup, prov, precision="double"), work / "double")
        write(generate(setup, prov, precision="float"), work / "float")
        traj = work / "samples.bin"
        np.ascontiguousarray(meas, dtype="<f8").tofile(traj)
        exe = work / "bench"
        src = [work / "double" / "piippo2008.c", HERE / "ref_step_000.c", HERE / "bench_codegen_main.c"]
        inc = ["-I", str(work / "double"), "-I", str(HERE)]
        subprocess.run([cc, *CFLAGS, *inc, "-o", str(exe), *map(str, src), "-lm"], check=True)

        print(
            f"paper-000 observer, {setup.discretization}, law (16), HF injection; trajectory of {n} samples"
        )
        agree = float(subprocess.run([str(exe), "check", str(traj)], capture_output=True, text=True).stdout)
        print(f"generated vs hand-written outputs: max relative difference {agree:.1e}")
        if not agree < 1e-9:
            print("the two implementations disagree: the yardstick is not the same equations")
            return 1

        r = subprocess.run([str(exe), "time", str(traj), str(args.passes)], capture_output=True, text=True)
        t_gen, t_ref = map(float, r.stdout.split())
        print(f"{'':24}{'generated':>12}{'hand-written':>14}{'ratio':>8}")
        print(f"{'ns/step (median)':24}{t_gen:12.1f}{t_ref:14.1f}{t_gen / t_ref:8.3f}")

        if shutil.which("valgrind"):
            i_gen = callgrind(exe, "gen", traj, "piippo2008_step", n, work)
            i_ref = callgrind(exe, "ref", traj, "ref_step", n, work)
            print(f"{'instructions/step':24}{i_gen:12.1f}{i_ref:14.1f}{i_gen / i_ref:8.3f}")
        else:
            print("instructions/step: valgrind not installed")

        arm = shutil.which("arm-none-eabi-gcc")
        if arm:
            obj = work / "m4.o"
            subprocess.run(
                [arm, *ARM, "-c", "-o", str(obj), str(work / "float" / "piippo2008.c")], check=True
            )
            size = subprocess.run(
                [arm.replace("gcc", "size"), str(obj)], capture_output=True, text=True
            ).stdout
            text = int(size.splitlines()[1].split()[0])
            nm = subprocess.run(
                [arm.replace("gcc", "nm"), "-S", str(obj)], capture_output=True, text=True
            ).stdout
            sizes = {ln.split()[-1]: int(ln.split()[1], 16) for ln in nm.splitlines() if len(ln.split()) == 4}
            print(
                f"Cortex-M4F float build (-O2): .text {text} bytes; "
                f"piippo2008_step {sizes['piippo2008_step']} bytes, "
                f"piippo2008_init {sizes['piippo2008_init']} bytes"
            )
        else:
            print("Cortex-M4F size: arm-none-eabi-gcc not installed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
