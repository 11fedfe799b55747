"""A hash seed for a child process that differs from this process's (determinism across processes)."""

from __future__ import annotations

import os


def other_hash_seed() -> str:
    """PYTHONHASHSEED for a child: this process's seed + 1 where it is fixed; else (randomized, one of
    2**32 seeds) 1, which differs from it but for a 2**-32 chance."""
    mine = os.environ.get("PYTHONHASHSEED", "")
    return str(int(mine) + 1) if mine.isdigit() else "1"
