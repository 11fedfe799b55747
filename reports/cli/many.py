"""Many drives in one command: ``tune``/``report`` over a directory or a glob of drive files, on Dask.

The positional argument names several drives when it is not a file and not a preset name: an existing
directory (its ``*.toml`` files, sorted by name) or a pattern with ``*``, ``?`` or ``[`` (Python's
glob, sorted; quote it so the shell does not expand it first). A file or a preset keeps the one-drive
behaviour, byte for byte. With several drives:

- every drive file is loaded first (a bad one: its one line, exit 2, nothing written); two files with
  the same drive name, or an existing ``--out DIR/<name>`` without ``--force``, are refused the same
  way;
- each drive is one task on the engine (reports/engine.py: a local cluster by default,
  ``--scheduler``), running the one-drive command with ``--out DIR/<drive name>`` (each set written
  atomically, as the one-drive command writes it) and its output captured;
- the drives' output is printed in their order, then a summary table, also written atomically as
  ``DIR/summary.csv``: drive, file, exit status, result (tune: the tuned gains' worst damping;
  report: the verdict) and the drive's error or first warning line;
- the exit status is the worst of the drives' (1 > 2 > 3 > 0): a drive that fails does not stop the
  others, and the sets written stay.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import glob
import io
import json
import os
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any, TypedDict

from sensorless.reports import interrupts
from sensorless.reports.cli.common import Number, UsageError
from sensorless.reports.engine import scheduler_address

SUMMARY = "summary.csv"
_PATTERN = set("*?[")


def add_engine_options(p: argparse.ArgumentParser) -> None:
    """``--scheduler`` and ``--workers``: where several drives run (as for ``montecarlo``)."""
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        type=scheduler_address,
        help="with several drives: Dask scheduler (tcp://HOST:PORT) to run on, or 'synchronous' (in "
        "this process); default: a local cluster",
    )
    p.add_argument(
        "--workers",
        type=Number(1, 1024, integer=True),
        help="with several drives: worker processes of the local cluster (default: one per core)",
    )


def drive_files(spec: str) -> list[str] | None:
    """The drive files ``spec`` names when it names several (module docstring); None: one drive."""
    from sensorless.design.drive import preset_names

    path = Path(spec)
    if path.is_file() or spec in preset_names():
        return None
    if path.is_dir():
        files = sorted(str(f) for f in path.glob("*.toml") if f.is_file())
        if not files:
            raise UsageError(f"argument PRESET_OR_TOML: {spec}: a directory without drive files (*.toml)")
        return files
    if _PATTERN & set(spec):
        files = sorted(f for f in glob.glob(spec) if Path(f).is_file())
        if not files:
            raise UsageError(f"argument PRESET_OR_TOML: {spec}: no drive file matches")
        return files
    return None


def gain_table_of(gains: str, name: str) -> str:
    """The gain table ``--gains`` names for drive ``name``: the file itself, or in a directory that
    ``tune`` wrote its one ``gains_*.json`` (``tune FILE --out DIR``) or ``<name>/gains_*.json`` (``tune
    DIR --out DIR``, one directory per drive). UsageError naming --gains where there is none or more
    than one."""
    d = Path(gains)
    if not d.is_dir():
        return gains
    found = sorted((d / name).glob("gains_*.json")) or sorted(d.glob("gains_*.json"))
    if len(found) != 1:
        what = "no gain table (gains_*.json)" if not found else f"{len(found)} gain tables"
        raise UsageError(
            f"argument --gains: {gains}: {what} for drive {name!r} in it or in {d / name}; "
            "give the gain table's file"
        )
    return str(found[0])


def refuse_engine_options(args: argparse.Namespace) -> None:
    """One drive: the engine options have nothing to run."""
    for opt in ("scheduler", "workers"):
        if getattr(args, opt, None) is not None:
            raise UsageError(f"argument --{opt}: only with several drives (a directory or a glob)")


def run(command: str, args: argparse.Namespace, files: list[str]) -> int:
    """Run ``command`` on every drive of ``files`` on the engine; print and write the summary."""
    from sensorless.design.drive import load_drive
    from sensorless.reports.engine import Engine, EngineError

    if not args.out:
        raise UsageError("argument --out: required with several drives (one directory per drive in it)")
    if args.workers and args.scheduler:
        raise UsageError("argument --workers: sizes the local cluster; not with --scheduler")
    root = Path(args.out)
    names: dict[str, str] = {}
    for f in files:
        name = load_drive(f).name  # a bad file: its one line, nothing written
        if name in names:
            raise UsageError(
                f"{f}: drive name {name!r} is also the name of {names[name]}: outputs would collide"
            )
        names[name] = f
    if not args.force:
        for name in names:
            d = root / name
            if d.exists() and (not d.is_dir() or any(d.iterdir())):
                raise UsageError(f"argument --out: {d} exists (use --force to overwrite)")
        if (root / SUMMARY).exists():
            raise UsageError(f"argument --out: {root / SUMMARY} exists (use --force to overwrite)")
    base = {k: v for k, v in vars(args).items() if k not in ("scheduler", "workers")}
    tables = {name: gain_table_of(args.gains, name) for name in names} if getattr(args, "gains", None) else {}
    items = [
        (command, {**base, **({"gains": tables[name]} if tables else {})}, f, str(root / name))
        for name, f in names.items()
    ]
    try:
        with Engine(args.scheduler, args.workers, quiet=getattr(args, "quiet", False)) as engine:
            results = engine.map(one, items, f"{command}: drives")
    except EngineError as e:
        raise UsageError(str(e)) from None
    rows = []
    for (name, f), res in zip(names.items(), results, strict=True):
        print(f"== {name} ({f}): exit status {res['code']}")
        sys.stdout.write(res["stdout"])
        for line in res["stderr"].splitlines():
            print(f"{name}: {line}", file=sys.stderr)
        rows.append(_row(command, name, f, root / name, res))
    text = _csv(rows)
    print(f"summary of {len(rows)} drives:")
    sys.stdout.write(_table(rows))
    _write_atomic(root / SUMMARY, text)
    print(f"wrote {root / SUMMARY}")
    codes = {r["exit_status"] for r in rows}
    return next((c for c in (1, 2, 3) if c in codes), 0)


class Run(TypedDict):
    """One drive's command as run on a worker (:func:`one`)."""

    code: int  # its exit status
    stdout: str
    stderr: str


class Row(TypedDict):
    """One drive's line of the summary (SUMMARY, :func:`_row`)."""

    drive: str
    file: str
    exit_status: int
    result: str
    message: str
    out: str


def one(command: str, base: dict[str, Any], file: str, out: str) -> Run:
    """One drive on a worker: the one-drive command with its output captured; its exit status as the
    command line would give it (a user error: 2 and its line; a bug: 1 and its last line)."""
    from sensorless.reports.cli.main import _exit_status

    ns = argparse.Namespace(**{**base, "drive": file, "out": out, "scheduler": None, "workers": None})
    if "quiet" in base:
        ns.quiet = True  # progress lines would only interleave
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # as main() does: the command says what is not finite
        try:
            code = int(ns.func(ns) or 0)
        except KeyboardInterrupt as e:
            if getattr(e, "signum", None) != interrupts.BUDGET:
                raise
            # this drive's time budget (on the synchronous engine): its line, the others go on
            text, code = interrupts.line(e.signum)
            interrupts.reset()
            print(text, file=sys.stderr)
        except SystemExit:
            raise
        except Exception as e:
            try:
                code = _exit_status(e, f"sensorless {command}")
            except Exception as bug:  # a bug in one drive's run: recorded, the others go on
                print(f"sensorless {command}: bug: {type(bug).__name__}: {bug}", file=sys.stderr)
                code = 1
    return {"code": code, "stdout": stdout.getvalue(), "stderr": stderr.getvalue()}


def _row(command: str, name: str, file: str, out: Path, res: Run) -> Row:
    # the line that says why: a run that ends in an error gives the error, not an earlier warning
    err = res["stderr"].splitlines()
    lines = [ln for ln in err if ": error: " in ln or ": bug: " in ln] if res["code"] else []
    lines += [ln for ln in err if ": warning: " in ln]
    result = ""
    if res["code"] in (0, 3):
        if command == "tune":
            vals = []
            for p in sorted(out.glob("gains_*.json")):
                w = json.loads(p.read_text()).get("summary", {}).get("worst_damping")
                vals.append(f"worst damping {w:.4g}" if isinstance(w, int | float) else "worst damping ?")
            result = "; ".join(vals)
        else:
            verdict = [ln for ln in res["stdout"].splitlines() if ln.startswith("verdict: ")]
            result = verdict[0].split(";")[0] if verdict else ""
    return {
        "drive": name,
        "file": file,
        "exit_status": res["code"],
        "result": result,
        "message": lines[0] if lines else "",
        "out": str(out) if res["code"] in (0, 3) else "",
    }


def _csv(rows: list[Row]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def _table(rows: list[Row]) -> str:
    cols = ("drive", "exit_status", "result", "message")
    cells = [[str(r[c]) for c in cols] for r in rows]
    width = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]
    lines = ["  ".join(c.ljust(width[i]) for i, c in enumerate(cols)).rstrip()]
    lines += ["  ".join(v.ljust(width[i]) for i, v in enumerate(row)).rstrip() for row in cells]
    return "\n".join(lines) + "\n"


def _write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
