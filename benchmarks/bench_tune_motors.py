"""Benchmark: ``sensorless tune`` with its defaults on every example motor (docs/examples/motors), against
the 30 s target, with ratios against an in-process baseline.

For each motor the flow a user runs: ``sensorless init MOTOR.toml`` (in this process, through the command
line's main), then ``sensorless tune DRIVE`` with its defaults, through the same main: the drive's default
law and settings (the schedule, its speed-dependent seed, the pointwise bound, the NLP, the dense
re-verification) and the proof before the table is written (reports/tune_proof.py; the benchmark unsets
$SENSORLESS_TUNE_UNCHECKED), which is what a user waits for. CPU seconds count the compiler's child
processes too (design/compiled.py: the first run on a motor compiles its simulation loops; with
``--repeat`` the later rounds also read the proof's runs and the pointwise bound that the first kept in
$SENSORLESS_CACHE/memo: a user's second tune of the same drive; run with an empty $SENSORLESS_CACHE and
``--repeat 1`` for the first). The
baseline, timed in the same process between the motors, is the paper's law on the paper's preset
(``tune(piippo2008, "speed-dependent")``): the ratio motor / baseline says how a motor compares with the
tuner's best-known case whatever the machine's speed or load (this machine is shared; CPU seconds are
printed beside the wall seconds). Prints per motor the median over the rounds: wall and CPU seconds,
IPOPT iterations, worst damping (dense), the ratio, and whether it is within the target.

    python benchmarks/bench_tune_motors.py [--repeat 3] [--motor drone ...]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import resource
import statistics
import tempfile
import time
from pathlib import Path

from sensorless.design.drive import load_drive
from sensorless.reports.cli.main import main as cli
from sensorless.reports.cli.tune import UNCHECKED_ENV
from sensorless.tuning.tune import tune

MOTORS = Path(__file__).resolve().parents[1] / "docs" / "examples" / "motors"
TARGET_S = 30.0


def cpu() -> float:
    """CPU seconds of this process and its reaped children (the C compiler of design/compiled.py)."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def timed(fn):
    """(wall s, CPU s, result) of fn()."""
    w, c = time.perf_counter(), cpu()
    r = fn()
    return time.perf_counter() - w, cpu() - c, r


def tune_command(drive_file: Path, out: Path) -> dict:
    """``sensorless tune DRIVE --out OUT`` with its defaults and proof; the written table's summary."""
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        rc = cli(["tune", str(drive_file), "--out", str(out), "--force", "--quiet"])
    tables = sorted(out.glob("gains_*.json"))
    if rc not in (0, 3) or not tables:
        raise SystemExit(f"tune {drive_file.stem} failed (exit {rc})")
    return json.loads(tables[0].read_text())["summary"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1, help="rounds per motor (medians)")
    ap.add_argument("--motor", action="append", help="only these motors (file stems), default all")
    args = ap.parse_args()
    os.environ.pop(UNCHECKED_ENV, None)  # the proof is part of the command
    paper = load_drive("piippo2008")
    tune(paper, "speed-dependent")  # builds the solvers and JIT libraries the baseline's rounds reuse
    stems = args.motor or sorted(p.stem for p in MOTORS.glob("*.toml"))
    print(f"{'motor':10} {'wall s':>8} {'CPU s':>8} {'ratio':>7} {'IPOPT it':>9} {'worst damp':>10}  target")
    with tempfile.TemporaryDirectory() as tmp:
        for stem in stems:
            out = Path(tmp, f"{stem}.toml")
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                if cli(["init", str(MOTORS / f"{stem}.toml"), "--out", str(out), "--force"]) != 0:
                    raise SystemExit(f"init {stem} failed")
            walls, cpus, ratios = [], [], []
            s: dict = {}
            for _ in range(args.repeat):
                _, bc, _ = timed(lambda: tune(paper, "speed-dependent"))
                w, c, s = timed(lambda o=out, st=stem: tune_command(o, Path(tmp, f"tune-{st}")))
                walls.append(w)
                cpus.append(c)
                ratios.append(c / bc)
            wall, cpu_s = statistics.median(walls), statistics.median(cpus)
            print(
                f"{stem:10} {wall:8.1f} {cpu_s:8.1f} {statistics.median(ratios):7.1f} "
                f"{s.get('ipopt_iterations', 0):9d} {s['worst_damping']:10.4f}  "
                f"{'ok' if cpu_s <= TARGET_S else 'OVER'} (<= {TARGET_S:g} s CPU)"
            )


if __name__ == "__main__":
    main()
