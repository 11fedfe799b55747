"""Benchmark: time of the README flow init + tune + codegen + report on a non-preset motor, per command.

Run:  python benchmarks/bench_flow.py [--repeat 3] [--cold-cache] [--in-process] [--no-baseline] [--keep DIR]

The flow a user runs on their own motor (README "Your own motor"), on the README's minimal drive file (its
`# servo.toml` block, written to a temporary directory): a 400 W servo from its datasheet (10 poles, kE
33 V/krpm line-line rms, R_ll 3.6 ohm and L_ll 10 mH wye, J 0.6 kg cm2, 3000 rpm, 1.27 N m, 310 V,
10 kHz). The four commands are the README's own (its ``sh`` block of ``sensorless init servo.toml``, read
from README.md so that the benchmark times exactly what it shows), run in one Python process through
``sensorless.reports.cli.main.main([...])``, exactly as the command line parses them.

Each round is a fresh process (the default): the CasADi Functions and caches a process builds on its
first call are part of what a user waits for, and a second round in the same process would not pay
them (``--in-process`` runs the rounds here, to see that difference). Compiled code is cached on disk
($SENSORLESS_CACHE, design/compiled.py) and reused by later processes, as it is for a user after the
first run; ``--cold-cache`` gives each round an empty cache (the first run on a machine). The analyses
kept on disk (design/memo.py: ``report`` reuses those its ``tune`` made) start empty in every round: a
round is a user's first flow on a new motor, not a rerun of the last round's. The imports
are timed as their own row. The toolbox's bytecode is compiled before the first round (``python -m
compileall`` on its four packages, as ``pip install`` does): a shell with PYTHONDONTWRITEBYTECODE=1 would
otherwise have every process compile its ~150 modules again (0.3-0.5 s CPU per command), which no
installed user pays (``--source-compile``: leave the bytecode as it is, to see that cost). Inside
``tune`` and ``report`` each progress line (stderr; for report also stdout) is time-stamped; the time
from one line to the next is that stage's. The report's figures are rendered by child processes while
it computes on (reports/svg_render.py): its stage times are those of the main process, and the wait for
the last figures falls in the last stage. Prints median stage times over the rounds, wall and CPU (the
process's and its reaped children's, the figure renderers: on a shared machine the CPU time is the
figure to compare), the report's CPU split into its process and its children (``--separate`` too),
the total against the 10 s target (wall, what a user waits for, and CPU, what one core would take),
and the stages of report and tune.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import itertools
import json
import os
import re
import resource
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_S = 10.0  # init + tune + codegen + report, one process, imports included

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PACKAGES = ("symbolic", "design", "tuning", "reports")  # setup.py ROOTS: the sensorless.* packages
# the compiled-code cache of design/compiled.py (``cache_dir``; not imported here: the imports are timed)
JIT_CACHE = Path(os.environ.get("SENSORLESS_CACHE") or Path.home() / ".cache" / "sensorless") / "jit"


def readme_servo() -> str:
    """The README's own-motor drive file (its ``toml`` block that starts with ``# servo.toml``): the
    benchmark times exactly the flow the README shows."""
    for body in re.findall(r"^```toml\n(.*?)^```", README.read_text(encoding="utf-8"), re.S | re.M):
        if body.startswith("# servo.toml"):
            return body
    raise SystemExit(f"{README}: no toml block starting with '# servo.toml'")


def readme_commands() -> tuple[tuple[str, list[str]], ...]:
    """(name, argv) of the README's flow: the ``sensorless ...`` lines of its ``sh`` block that starts
    with ``sensorless init servo.toml``."""
    for body in re.findall(r"^```sh\n(.*?)^```", README.read_text(encoding="utf-8"), re.S | re.M):
        if body.startswith("sensorless init servo.toml"):
            lines = [shlex.split(ln)[1:] for ln in body.splitlines() if ln.startswith("sensorless ")]
            return tuple((argv[0], argv) for argv in lines)
    raise SystemExit(f"{README}: no sh block starting with 'sensorless init servo.toml'")


COMMANDS = readme_commands()
# the baseline, in a fresh process of its own in every round (so that a busy machine slows both alike):
# the built-in preset's report alone, which the flow's 15 s target was set against (9-17 s before)
BASELINE = (("report", ["report", "piippo2008", "--out", "rep-preset"]),)


class Stamped(io.TextIOBase):
    """A text stream that keeps each line with the time it was written."""

    def __init__(self) -> None:
        self.lines: list[tuple[float, str]] = []
        self._part = ""

    def write(self, s: str) -> int:
        self._part += s
        *done, self._part = self._part.split("\n")
        now = time.process_time()  # CPU: the stages on a shared machine
        self.lines += [(now, ln) for ln in done if ln.strip()]
        return len(s)


def stage_times(lines: list[tuple[float, str]], t0: float, t_end: float) -> list[tuple[str, float]]:
    """(progress line, seconds until the next line or the end) of a command's progress lines."""
    out = []
    marks = [*lines, (t_end, "")]
    out.append(("(start: load, check inputs)", marks[0][0] - t0))
    for (t, text), (t_next, _) in itertools.pairwise(marks):
        text = re.sub(r"^\[\s*[\d.]+ s\]\s*", "", text.strip())  # tune's own time stamp
        out.append((text, t_next - t))
    return out


def children_cpu() -> float:
    """CPU seconds of this process's reaped children (the report's figure renderers)."""
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return c.ru_utime + c.ru_stime


def cpu_time() -> float:
    """CPU seconds of this process and of its reaped children (the report's figure renderers)."""
    return time.process_time() + children_cpu()


def separate_round(work: Path, env: dict, commands: tuple = COMMANDS) -> dict:
    """Write the minimal drive file and run ``commands`` as a user does, each in a process of its own
    (imports in each command's row); wall and CPU seconds (the process's and its children's)."""
    res: dict = {"stages": {}, "cpu": {}, "children": {}, "inner": {}}
    work.mkdir(parents=True, exist_ok=True)
    (work / "servo.toml").write_text(readme_servo())
    # the command's own CPU, written at its exit (its figure renderers leave by os._exit: not theirs);
    # main() reads sys.argv as the console script does (main(argv) is a caller's run: it keeps the
    # collector as it found it and has no watchdog)
    run = (
        "import atexit, os, sys, time; "
        "atexit.register(lambda: open(os.environ['BENCH_OWN_CPU'], 'w').write(repr(time.process_time()))); "
        "from sensorless.reports.cli.main import main; sys.exit(main())"
    )
    own = work / "own_cpu.txt"
    for name, argv in commands:
        t0, c0 = time.perf_counter(), children_cpu()
        p = subprocess.run(
            [sys.executable, "-c", run, *argv, "--force"],
            cwd=work,
            env={**env, "BENCH_OWN_CPU": str(own)},
            capture_output=True,
        )
        res["stages"][name], res["cpu"][name] = time.perf_counter() - t0, children_cpu() - c0
        # the command's children: the report's figure renderers (and the C compiler with an empty cache)
        res["children"][name] = max(0.0, res["cpu"][name] - float(own.read_text())) if own.exists() else 0.0
        own.unlink(missing_ok=True)
        if p.returncode != 0 and not (commands is BASELINE and p.returncode == 3):
            raise SystemExit(f"sensorless {name} exited with {p.returncode}:\n{p.stderr.decode()}")
    return res


def one_round(work: Path, commands: tuple = COMMANDS) -> dict:
    """Write the minimal drive file and run ``commands`` in this process; times in seconds."""
    t, c = time.perf_counter(), cpu_time()
    from sensorless.reports.cli.main import build_parser, main

    build_parser()  # imports every subcommand (CasADi, the families) as the first command would
    res: dict = {
        "stages": {"imports": time.perf_counter() - t},
        "cpu": {"imports": cpu_time() - c},
        "children": {"imports": 0.0},
        "inner": {},
    }
    work.mkdir(parents=True, exist_ok=True)
    (work / "servo.toml").write_text(readme_servo())
    cwd = os.getcwd()
    os.chdir(work)
    try:
        for name, argv in commands:
            # report: stdout too (its "wrote" lines mark where computing ends and writing the files starts)
            err = Stamped()
            out = err if name == "report" else io.StringIO()
            t0, c0, p0, k0 = time.perf_counter(), cpu_time(), time.process_time(), children_cpu()
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
                code = main([*argv, "--force"])
            t1, c1 = time.perf_counter(), cpu_time()
            res["children"][name] = children_cpu() - k0
            if code != 0 and not (commands is BASELINE and code == 3):  # 3: a verdict, still timed
                lines = "\n".join(s for _, s in err.lines)
                raise SystemExit(f"sensorless {name} exited with {code}:\n{lines}")
            res["stages"][name] = t1 - t0
            res["cpu"][name] = c1 - c0
            if name in ("tune", "report"):
                res["inner"][name] = stage_times(err.lines, p0, time.process_time())
    finally:
        os.chdir(cwd)
    return res


def median_inner(rounds: list[dict], name: str) -> list[tuple[str, float]]:
    """Median time of each progress line of ``name`` over rounds (lines matched by position)."""
    runs = [r["inner"][name] for r in rounds]
    n = min(len(r) for r in runs)
    return [(runs[0][k][0], statistics.median(r[k][1] for r in runs)) for k in range(n)]


def compile_bytecode() -> None:
    """Compile the toolbox's modules to bytecode in their ``__pycache__`` (what ``pip install`` does;
    Python reads it, PYTHONDONTWRITEBYTECODE or not), quietly; untimed."""
    dirs = [str(ROOT / d) for d in PACKAGES]
    subprocess.run([sys.executable, "-m", "compileall", "-q", *dirs], check=True, stdout=subprocess.DEVNULL)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="rounds (default 3); medians are printed")
    ap.add_argument("--in-process", action="store_true", help="all rounds in this process (warm caches)")
    ap.add_argument("--cold-cache", action="store_true", help="an empty compiled-code cache for each round")
    ap.add_argument("--keep", default=None, metavar="DIR", help="work in DIR and keep the files")
    ap.add_argument("--one-round", default=None, metavar="DIR", help=argparse.SUPPRESS)  # a child's round
    ap.add_argument("--baseline-round", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--no-baseline", action="store_true", help="skip the preset report's baseline")
    ap.add_argument(
        "--separate",
        action="store_true",
        help="each command in a process of its own, as the README's shell lines",
    )
    ap.add_argument(
        "--source-compile",
        action="store_true",
        help="do not compile the toolbox's bytecode first (each process compiles what it has not cached)",
    )
    a = ap.parse_args()
    if a.cold_cache and a.in_process:
        ap.error("--cold-cache needs fresh processes (not --in-process)")
    if a.separate and a.in_process:
        ap.error("--separate runs each command in a process of its own (not --in-process)")
    if a.one_round:
        print(json.dumps(one_round(Path(a.one_round), BASELINE if a.baseline_round else COMMANDS)))
        return
    if not a.source_compile:
        compile_bytecode()
    base = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="bench_flow_"))
    rounds, baselines = [], []

    def fresh(work: Path, env: dict, *flags: str) -> dict:
        argv = [sys.executable, __file__, "--one-round", str(work), *flags]
        p = subprocess.run(argv, capture_output=True, text=True, env=env)
        if p.returncode != 0:
            raise SystemExit(p.stdout + p.stderr)
        return json.loads(p.stdout.splitlines()[-1])

    try:
        for k in range(a.repeat):
            work = base / f"round{k}"
            env = dict(os.environ)
            cache = base / f"cache{k}"
            if not a.cold_cache:
                # the compiled code as a user has it after a first run, and no analyses kept on disk
                # (design/memo.py) but those the round's own commands make: a first flow on a new motor
                cache.mkdir(parents=True)
                (cache / "jit").symlink_to(JIT_CACHE, target_is_directory=True)
            env["SENSORLESS_CACHE"] = str(cache)  # cold: what the first run on a machine pays
            if a.separate:
                rounds.append(separate_round(work, env))
            else:
                rounds.append(one_round(work) if a.in_process else fresh(work, env))
            total = sum(rounds[-1]["stages"].values())
            line = (
                f"round {k + 1}/{a.repeat}: {total:.1f} s wall, {sum(rounds[-1]['cpu'].values()):.1f} s CPU"
            )
            if not (a.no_baseline or a.in_process):
                if a.separate:
                    b = separate_round(base / f"baseline{k}", env, BASELINE)
                else:
                    b = fresh(base / f"baseline{k}", env, "--baseline-round")
                baselines.append(sum(b["cpu"].values()))
                line += f"; baseline {baselines[-1]:.1f} s CPU"
            print(line, file=sys.stderr, flush=True)
    finally:
        if not a.keep:
            shutil.rmtree(base, ignore_errors=True)
    how = "all in this process" if a.in_process else "each in a fresh process"
    how = "each command in a process of its own" if a.separate else how
    how += ", empty compiled-code cache" if a.cold_cache else ""
    how += ", bytecode compiled by each process" if a.source_compile else ""
    print(f"user flow on a minimal non-preset drive (servo400), {a.repeat} rounds ({how}); medians")
    for _name, argv in COMMANDS:
        print(f"  sensorless {' '.join(argv)}")
    print(f"{'command':<10} {'wall (s)':>9} {'min':>6} {'max':>6}   {'CPU (s)':>8} {'min':>6} {'max':>6}")
    for name in rounds[0]["stages"]:
        ts = [r["stages"][name] for r in rounds]
        cs = [r["cpu"][name] for r in rounds]
        print(
            f"{name:<10} {statistics.median(ts):9.2f} {min(ts):6.2f} {max(ts):6.2f}   "
            f"{statistics.median(cs):8.2f} {min(cs):6.2f} {max(cs):6.2f}"
        )
    totals = [sum(r["stages"].values()) for r in rounds]
    cpus = [sum(r["cpu"].values()) for r in rounds]
    med, cpu = statistics.median(totals), statistics.median(cpus)
    print(
        f"{'total':<10} {med:9.2f} {min(totals):6.2f} {max(totals):6.2f}   "
        f"{cpu:8.2f} {min(cpus):6.2f} {max(cpus):6.2f}"
    )
    kids = statistics.median(r["children"]["report"] for r in rounds)
    rep = statistics.median(r["cpu"]["report"] for r in rounds)
    print(
        f"  report's CPU: {rep - kids:.2f} s its process, {kids:.2f} s its children (the figure "
        "renderers; with an empty cache the C compiler too; medians)"
    )

    # the target is the flow's time, in wall seconds as the example motors' tune target: what a user
    # waits for on this machine's cores; its CPU is the stricter figure (what one core would take, and
    # the one a busy machine disturbs less), printed beside it
    def met(t: float) -> str:
        return "met" if t <= TARGET_S else "NOT met"

    print(
        f"target: init + tune + codegen + report <= {TARGET_S:g} s, imports included: wall {med:.2f} s on "
        f"{os.cpu_count()} cores: {met(med)}; CPU {cpu:.2f} s (what one core would take): {met(cpu)}"
    )
    if baselines:
        b = statistics.median(baselines)
        print(
            f"baseline: `sensorless report piippo2008` alone (imports included), median {b:.2f} s CPU; "
            f"flow / baseline = {cpu / b:.2f} (CPU medians; the ratio holds on a busy machine too)"
        )
    for name in ("report", "tune") if not a.separate else ():
        print(f"\nwhere {name} spends its time (median CPU per progress line, to the next; main process):")
        for text, t in median_inner(rounds, name):
            print(f"  {t:7.2f} s  {text[:100]}")


if __name__ == "__main__":
    main()
