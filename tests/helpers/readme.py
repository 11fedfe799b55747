"""The README's command lines and example files, split into their independent chains (the commands of
one drive), and one run of a chain (the README test and the own-motor tests share the servo's run; the
chains run on different pytest-xdist workers: together they were the suite's longest step)."""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"
BLOCK = re.compile(r"^```(\w+)\n(.*?)^```", re.S | re.M)


def blocks(lang: str) -> list[str]:
    return [body for kind, body in BLOCK.findall(README.read_text(encoding="utf-8")) if kind == lang]


def commands() -> list[list[str]]:
    """Every ``sensorless`` line of the README's ``sh`` blocks, in order, as argv (without the program)."""
    out = []
    for body in blocks("sh"):
        for line in body.splitlines():
            if line.startswith("sensorless "):
                out.append(shlex.split(line, comments=True)[1:])
    return out


def chain_of(argv: list[str]) -> str:
    """The chain a README command belongs to: the drive it works on (``init`` names the drive file it
    writes with ``--out``; the other commands name it first), without ``-drive.toml`` or ``.toml``."""
    drive = argv[argv.index("--out") + 1] if argv[0] == "init" else argv[1]
    return re.sub(r"(-drive)?\.toml$", "", Path(drive).name)


def chains() -> list[str]:
    """The README's chains, in the order of their first command."""
    return list(dict.fromkeys(chain_of(argv) for argv in commands()))


def chain_commands(chain: str) -> list[list[str]]:
    """The README's commands of one chain, in the README's order."""
    return [argv for argv in commands() if chain_of(argv) == chain]


@dataclass(frozen=True)
class ReadmeRun:
    """Where the README's commands ran, and each command's argv, exit status and standard error (and,
    in the same order, each command's standard output)."""

    dir: Path
    results: tuple[tuple[list[str], int, str], ...]
    outputs: tuple[str, ...] = ()
    # in the same order, what each command asked of the memo of the minimum speed under the estimate
    # errors (design/low_speed.py ``minimum_speed_under``): (hits, misses) during the command
    memo: tuple[tuple[int, int], ...] = ()

    def code(self, command: str, file: str) -> int:
        """The exit status of the first ``command`` whose arguments name ``file``."""
        return next(c for argv, c, _ in self.results if argv[0] == command and file in argv)


def run_readme(where: Path, chain: str | None = None) -> ReadmeRun:
    """Run the README commands of ``chain`` (default: all of them) as written, in order, in ``where``
    holding the README's example files (``toml`` blocks that start with a ``# NAME.toml`` line) and the
    repository's docs/examples. A chain runs in a directory of its own: that it succeeds there shows it
    needs no other chain's outputs."""
    from sensorless.design.low_speed import minimum_speed_under
    from sensorless.reports.cli.main import main

    for body in blocks("toml"):
        m = re.fullmatch(r"# (\S+\.toml)", body.splitlines()[0])
        if m:
            (where / m.group(1)).write_text(body, encoding="utf-8")
    shutil.copytree(README.parent / "docs" / "examples", where / "docs" / "examples")
    results, outputs, memo = [], [], []
    cwd = os.getcwd()
    os.chdir(where)
    try:
        for argv in commands() if chain is None else chain_commands(chain):
            err, out = io.StringIO(), io.StringIO()
            before = minimum_speed_under.cache_info()  # type: ignore[attr-defined]
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
                code = main(argv)
            after = minimum_speed_under.cache_info()  # type: ignore[attr-defined]
            results.append((argv, code, err.getvalue()))
            outputs.append(out.getvalue())
            memo.append((after[0] - before[0], after[1] - before[1]))
    finally:
        os.chdir(cwd)
    return ReadmeRun(where, tuple(results), tuple(outputs), tuple(memo))
