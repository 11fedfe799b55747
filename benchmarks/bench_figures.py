"""Benchmark: CPU of a report's figures (build + SVG), figure by figure, against a plain matplotlib figure.

Run:  python benchmarks/bench_figures.py [--repeat 5] [--report piippo2008] [--report hubmotor48] [--servo]
      [--save DIR]

Each report is computed once in this process with the figures rendered here (SENSORLESS_NO_FORK=1),
every figure job the report hands to reports/svg_render.py ``svg_later`` recorded (the function and data
that make a figure: what a forked child runs). Then each job is run again ``--repeat`` times, build and
SVG (document.py ``svg_uri``), and its median CPU seconds printed; the sum is what a report's figures
cost, whichever process renders them. ``--servo`` adds the README flow's report (init, tune and then
``report servo-drive.toml --gains ... --quick``, the README's commands; tune is not timed).

The baseline, timed here between the figures (so that a busy machine slows both alike): a plain 2x2
matplotlib figure with four 200-point lines and a legend in each axes, built and saved as SVG with
matplotlib's defaults. The ratio of a report's figures to it is the number to compare across runs and
machines. ``--save DIR`` writes each figure's SVG (DIR/<report>/NN.svg) to compare renders.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import gc
import io
import os
import shutil
import statistics
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path


def baseline_figure() -> None:
    """A plain matplotlib figure as a user would make it: 2x2, four lines each, legends, SVG."""
    import numpy as np
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 6))
    t = np.linspace(0, 1, 200)
    for k, ax in enumerate(fig.subplots(2, 2).ravel()):
        for j in range(4):
            ax.plot(t, np.sin(2 * np.pi * (j + 1) * t + k), label=f"line {j}")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("value")
        ax.legend(loc="upper right")
    fig.savefig(io.BytesIO(), format="svg", metadata={"Date": None})


def child_cpu(fn: Callable[[], object], out: Path | None = None) -> float:
    """CPU seconds (user + system) of ``fn`` run in a forked child, as reports/svg_render.py runs a
    figure: a copy of this process with its caches as they are here (a child's text metrics and layouts
    start from the parent's, which draws nothing), no garbage collection. ``out``: where the child
    writes what ``fn`` returns (a data URI), decoded."""
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            gc.disable()
            uri = fn()
            if out is not None:
                out.write_bytes(base64.b64decode(str(uri).split(",", 1)[1]))
            code = 0
        finally:
            os._exit(code)
    _, status, usage = os.wait4(pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit("a figure failed in its child")
    return usage.ru_utime + usage.ru_stime


def capture(argv: list[str], cwd: Path) -> list[Callable]:
    """The figure jobs of one report command, computed in this process (none drawn)."""
    from sensorless.reports import svg_render
    from sensorless.reports.cli.main import main

    jobs: list[Callable] = []
    made, uri = svg_render._made, svg_render.svg_uri

    def recording(fig):  # svg_later without fork renders svg_uri(_made(fig)): record the job, no render
        jobs.append(fig if callable(fig) else lambda: fig)
        return None

    os.environ["SENSORLESS_NO_FORK"] = "1"
    # nothing rendered here: a report's process, which forks its figures, draws none of them itself
    svg_render._made, svg_render.svg_uri = recording, lambda _: "data:image/svg+xml;base64,"
    here = os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            code = main([*argv, "--force"])
    finally:
        os.chdir(here)
        svg_render._made, svg_render.svg_uri = made, uri
    if code not in (0, 3):  # 3: a verdict
        raise SystemExit(f"sensorless {' '.join(argv)} exited with {code}")
    return jobs


def readme_servo(work: Path) -> list[str]:
    """Run the README flow's init and tune in ``work`` (bench_flow.py reads them from README.md); the
    argv of its report command."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_flow import COMMANDS, readme_servo
    from sensorless.reports.cli.main import main

    (work / "servo.toml").write_text(readme_servo())
    here = os.getcwd()
    os.chdir(work)
    try:
        for name, argv in COMMANDS:
            if name in ("init", "tune"):
                with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                    if main([*argv, "--force"]) not in (0, 3):
                        raise SystemExit(f"sensorless {' '.join(argv)} failed")
    finally:
        os.chdir(here)
    return next(argv for name, argv in COMMANDS if name == "report")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="runs of each figure (default 5); medians")
    ap.add_argument("--report", action="append", default=None, help="preset (repeatable; default piippo2008)")
    ap.add_argument("--servo", action="store_true", help="also the README flow's report (its servo)")
    ap.add_argument("--save", default=None, metavar="DIR", help="write each figure's SVG to DIR/<report>/")
    a = ap.parse_args()
    from sensorless.reports import svg_render
    from sensorless.reports.document import svg_uri

    svg_render._shared_before_fork()  # what the report's parent process has before it forks
    work = Path(tempfile.mkdtemp(prefix="bench_figures_"))
    runs: list[tuple[str, list[str], Path]] = [
        (p, ["report", p, "--quick", "--out", f"rep-{p}"], work) for p in (a.report or ["piippo2008"])
    ]
    if a.servo:
        servo = work / "servo"
        servo.mkdir()
        runs.append(("servo", readme_servo(servo), servo))
    base: list[float] = []
    print(f"report figures, CPU s per figure (build + SVG), median of {a.repeat} runs")
    totals = {}
    for name, argv, cwd in runs:
        jobs = capture(argv, cwd)
        times = []
        out = Path(a.save) / name if a.save else work / "svg" / name
        out.mkdir(parents=True, exist_ok=True)
        for k, job in enumerate(jobs):
            ts = []
            for r in range(a.repeat):
                base.append(child_cpu(baseline_figure))
                ts.append(child_cpu(lambda job=job: svg_uri(job()), out / f"{k:02d}.svg" if r == 0 else None))
            times.append(statistics.median(ts))
            label = getattr(getattr(job, "func", job), "__qualname__", "?")
            size = (out / f"{k:02d}.svg").stat().st_size
            print(f"  {name:<11} {k:2d} {label:<28} {times[-1]:6.3f} s  {size / 1024:7.1f} kB", flush=True)
        totals[name] = (len(jobs), sum(times))
    shutil.rmtree(work, ignore_errors=True)
    b = statistics.median(base)
    print(f"baseline (plain 2x2 matplotlib figure, SVG): median {b:.3f} s CPU")
    for name, (n, s) in totals.items():
        print(f"{name:<11} {n:2d} figures: {s:6.2f} s CPU = {s / b:6.1f} baselines")


if __name__ == "__main__":
    main()
