"""A hash seed for a child process that differs from this process's, and a command run here and in such a
child (determinism across processes)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def other_hash_seed() -> str:
    """PYTHONHASHSEED for a child: this process's seed + 1 where it is fixed; else (randomized, one of
    2**32 seeds) 1, which differs from it but for a 2**-32 chance."""
    mine = os.environ.get("PYTHONHASHSEED", "")
    return str(int(mine) + 1) if mine.isdigit() else "1"


def here_and_fresh(tmp_path: Path, argv: list[str]) -> list[dict[str, bytes]]:
    """The files a command (``argv`` without ``--out``) writes when run here, in this process (its
    module caches warm from the tests before), and in a fresh process with another hash seed; each as
    {file name: bytes}."""
    from sensorless.reports.cli.main import main

    outs = []
    for d in (tmp_path / "here", tmp_path / "fresh"):
        args = [*argv, "--out", str(d)]
        if d.name == "here":
            assert main(args) == 0
        else:
            env = {**os.environ, "PYTHONHASHSEED": other_hash_seed()}
            subprocess.run(
                [sys.executable, "-m", "sensorless.reports.cli.main", *args],
                check=True,
                env=env,
                capture_output=True,
            )
        outs.append({p.name: p.read_bytes() for p in sorted(d.iterdir())})
    return outs
