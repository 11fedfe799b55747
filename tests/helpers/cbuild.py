"""Test helper: a C program built once per test process, whichever test asks for it first.

Several tests build the same generated C with the same flags (the reduced-order family's default C
replayed on the clean and on the glitched trajectory; the fixed-point C of piippo2008's codegen formats
replayed and fuzzed). :func:`build` runs the compiler the first time a command is asked for, asserts
it succeeds warning-free (nothing on stderr), and hands later askers a copy of that executable: the
key is the command (compiler, flags, file names, the output path left out) and the bytes of every
source on it and of the headers beside them, so a copy is only ever of the same program.
"""

from __future__ import annotations

import atexit
import hashlib
import shutil
import subprocess
import tempfile
from pathlib import Path

_BUILT: dict[str, Path] = {}
_STORE: list[Path] = []  # the directory holding the built programs (made when first needed)


def _key(cmd: list[str], exe: Path) -> str:
    h = hashlib.sha256()
    for arg in cmd:
        h.update(b"<exe>" if arg == str(exe) else arg.encode())
        h.update(b"\0")
        p = Path(arg)
        if p.suffix == ".c" and p.is_file():
            h.update(p.read_bytes())
            for hdr in sorted(p.parent.glob("*.h")):
                h.update(hdr.name.encode() + b"\0" + hdr.read_bytes())
    return h.hexdigest()


def build(cmd: list[str], exe: Path) -> Path:
    """``exe`` built by the compiler command ``cmd`` (which names ``exe`` after -o), warning-free; the
    program is compiled once per process for equal commands on equal sources (module docstring)."""
    exe = Path(exe)
    cmd = [str(a) for a in cmd]
    key = _key(cmd, exe)
    if key not in _BUILT:
        r = subprocess.run(cmd, capture_output=True, text=True)
        assert r.returncode == 0 and r.stderr == "", r.stderr
        if not _STORE:
            _STORE.append(Path(tempfile.mkdtemp(prefix="sensorless-cbuild-")))
            atexit.register(shutil.rmtree, _STORE[0], ignore_errors=True)
        _BUILT[key] = _STORE[0] / key
        shutil.copy2(exe, _BUILT[key])
        return exe
    exe.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy2(_BUILT[key], exe)
    return exe
