"""Installation: the console script exists and runs, and only the ``sensorless`` namespace is installed."""

import gc
import os
import subprocess
import sys
from pathlib import Path

import pytest


def test_installed_console_script_runs(tmp_path):
    """The ``sensorless`` script that ``pip install`` puts next to the interpreter, run as a program."""
    script = Path(sys.executable).parent / "sensorless"
    assert script.is_file(), f"no console script at {script}"
    r = subprocess.run([str(script), "--version"], capture_output=True, text=True, cwd=tmp_path, check=False)
    assert r.returncode == 0 and r.stdout.startswith("sensorless "), r.stderr
    r = subprocess.run([str(script), "analyze", "nope"], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "nope" in r.stderr  # one line, no traceback


@pytest.mark.parametrize("name", ["design", "reports", "symbolic", "tuning"])
def test_no_generic_top_level_modules(tmp_path, name):
    """The card folders install under the sensorless namespace only. Checked in a fresh interpreter
    started outside the checkout, so that the repository's own folders are not on the path."""
    code = (
        "import importlib.util, sys\n"
        f"assert importlib.util.find_spec('sensorless.{name}') is not None\n"
        f"sys.exit(0 if importlib.util.find_spec('{name}') is None else 1)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr or f"a top-level module {name!r} is importable"


def test_every_source_folder_is_a_package():
    """setup.py installs packages only: a folder of modules without __init__.py would be missing
    from a non-editable install (the editable one used in development hides it)."""
    root = Path(__file__).resolve().parents[2]
    missing = [
        str(d.relative_to(root))
        for layer in ("symbolic", "design", "tuning", "reports")
        for d in [root / layer, *(root / layer).rglob("*")]
        if d.is_dir()
        and d.name != "__pycache__"
        and any(d.glob("*.py"))
        and not (d / "__init__.py").is_file()
    ]
    assert not missing, missing


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="counts threads in Linux's /proc")
def test_commands_load_numpy_with_one_blas_thread(tmp_path):
    """The command line's numpy starts no OpenBLAS worker threads unless the user asks for them
    (reports/cli/main.py): counted in a fresh interpreter whose environment names no thread count.
    The same interpreter with OPENBLAS_NUM_THREADS=2 must show the worker, else the count proves nothing."""
    code = (
        "import os, sys\n"
        "import sensorless.reports.cli.main\n"
        "import numpy\n"
        "print(len(os.listdir('/proc/self/task')))\n"
    )
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "GOTO_NUM_THREADS")
    }
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env)
    assert r.returncode == 0, r.stderr
    assert int(r.stdout) == 1, f"{r.stdout.strip()} threads after importing numpy under the command line"
    if (os.cpu_count() or 1) > 1:  # the user's own setting is kept, and starts OpenBLAS's workers
        env["OPENBLAS_NUM_THREADS"] = "2"
        r = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, env=env
        )
        assert r.returncode == 0 and int(r.stdout) == 2, r.stderr or r.stdout


def test_commands_leave_the_garbage_collector_as_they_found_it(tmp_path):
    """main() freezes what the imports built and collects the young generation less often
    (reports/cli/main.py): given arguments (a caller whose process goes on) it undoes both on the way
    out, and leaves a caller's own frozen objects frozen; run as the script (arguments from sys.argv),
    the process exits with its heap frozen, for no collection to walk."""
    from sensorless.reports.cli.main import YOUNG_COLLECTION, main

    # a run that parses, imports, then fails on the missing file: exit status 2
    missing = [str(tmp_path / "missing.toml"), "--out", str(tmp_path / "out.toml")]
    assert gc.get_freeze_count() == 0, "an earlier test left objects frozen"
    threshold = gc.get_threshold()
    assert threshold[0] != YOUNG_COLLECTION, "an earlier test left the collector's thresholds changed"
    assert main(["init", *missing]) == 2
    assert gc.get_freeze_count() == 0 and gc.get_threshold() == threshold
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        assert frozen > 0
        assert main(["init", *missing]) == 2
        assert gc.get_freeze_count() == frozen
    finally:
        gc.unfreeze()
    code = (
        "import atexit, gc, sys\n"
        "from sensorless.reports.cli.main import main\n"
        "atexit.register(lambda: print(gc.get_freeze_count(), gc.get_threshold()[0]))\n"
        "sys.argv = ['sensorless', 'init', 'missing.toml', '--out', 'out.toml']\n"
        "sys.exit(main())\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    frozen_at_exit, young = (int(v) for v in r.stdout.split())
    assert frozen_at_exit > 0, "the script's run left nothing frozen for its exit"
    assert young == YOUNG_COLLECTION
