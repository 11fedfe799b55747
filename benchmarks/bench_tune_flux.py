"""Benchmark: ``sensorless tune --law constant`` on the outrunner preset (target: under 3 s).

Times, as medians of repeated runs, wall clock and CPU time (the process's own, or its child's for the
command line: on a loaded machine CPU time is the figure to compare with the target):
- the whole command ``sensorless tune outrunner270 --law constant`` in a fresh interpreter (imports,
  CasADi Function builds, the grid search, writing the tables);
- ``tune(drive, "constant")`` in this process, first call and warm;
- the baseline, in this process: one judgement of the two firmware defaults over the envelope under
  the estimate errors (``assess``, the unit the grid search repeats), and the warm tune's ratio to it.

    python benchmarks/bench_tune_flux.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

from sensorless.design.drive import load_drive
from sensorless.tuning.pmsm_flux_observer import FluxTuneSettings, assess, odrive_defaults, vesc_detection
from sensorless.tuning.tune import tune

PRESET = "outrunner270"
TARGET_S = 3.0


def timed(fn) -> tuple[float, float]:
    """(wall, CPU) seconds of one call of ``fn`` in this process."""
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def cli_once(out: str) -> tuple[float, float]:
    """(wall, CPU of the child) seconds of the command in a fresh interpreter."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    w = time.perf_counter()
    cmd = [sys.executable, "-m", "sensorless.reports.cli.main", "tune", PRESET, "--law", "constant"]
    cmd += ["--out", out, "--force"]
    subprocess.run(cmd, check=False, capture_output=True, env={**os.environ, "PYTHONHASHSEED": "0"})
    wall = time.perf_counter() - w
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def med(xs: list[tuple[float, float]]) -> tuple[float, float]:
    return statistics.median(x[0] for x in xs), statistics.median(x[1] for x in xs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cli = med([cli_once(os.path.join(tmp, "t")) for _ in range(a.repeat)])
    drive = load_drive(PRESET)
    settings = FluxTuneSettings()
    first = timed(lambda: tune(drive, "constant", settings))
    warm = med([timed(lambda: tune(drive, "constant", settings)) for _ in range(a.repeat)])
    cands = [odrive_defaults(), vesc_detection(drive)]
    base = med([timed(lambda: assess(drive, cands, settings)) for _ in range(a.repeat)])
    print(f"{PRESET}, law constant; medians of {a.repeat} runs (wall / CPU seconds)")
    print(f"  sensorless tune (fresh interpreter): {cli[0]:7.3f} / {cli[1]:7.3f}   target < {TARGET_S:g} s")
    print(f"  tune() first call in this process:  {first[0]:7.3f} / {first[1]:7.3f}")
    print(f"  tune() warm:                         {warm[0]:7.3f} / {warm[1]:7.3f}")
    print(f"  baseline: assess of the 2 defaults:  {base[0]:7.3f} / {base[1]:7.3f}")
    print(f"  warm tune / baseline (CPU):          {warm[1] / base[1]:7.1f} x")
    verdict = "within" if cli[1] < TARGET_S else "BEYOND"
    print(f"the command's CPU time is {verdict} the {TARGET_S:g} s target")


if __name__ == "__main__":
    main()
