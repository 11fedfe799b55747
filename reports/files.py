"""Output files that never end half-written: stage everything, then rename into place at once.

Every command that writes several files (tables, figures, C sources, reports) collects them in an
:class:`OutputSet`. Nothing touches the destination until the whole set has been produced; then each
file is written to a temporary name in the destination directory and renamed over (atomic on POSIX).
Existing files are refused unless ``force`` is given, so a run never silently destroys earlier results.
"""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path
from typing import Any


class OutputExistsError(FileExistsError):
    """An output file already exists and overwriting was not requested."""


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same directory and a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


class OutputSet:
    """Files to be written together into ``directory``; see the module docstring."""

    def __init__(self, directory: str | Path, force: bool = False) -> None:
        self.directory = Path(directory)
        self.force = force
        self.files: dict[str, bytes] = {}

    def add_bytes(self, name: str, data: bytes) -> None:
        """Stage a file."""
        self.files[name] = data

    def add_text(self, name: str, text: str) -> None:
        """Stage a UTF-8 text file (LF line ends)."""
        self.add_bytes(name, text.encode("utf-8"))

    def add_figure(self, name: str, fig: Any, **kwargs: Any) -> None:
        """Stage a matplotlib figure; the format follows the name's suffix. Metadata that would
        differ between runs (dates, software strings) is left out so files are byte-identical."""
        fmt = Path(name).suffix[1:]
        meta = {"Date": None} if fmt == "svg" else {"Software": None} if fmt == "png" else {}
        buf = io.BytesIO()
        fig.savefig(buf, format=fmt, metadata=meta, **kwargs)
        self.add_bytes(name, buf.getvalue())

    def paths(self) -> list[Path]:
        """Destination paths of the staged files."""
        return [self.directory / n for n in self.files]

    def check_free(self) -> None:
        """Raise OutputExistsError if a destination exists and ``force`` is off."""
        if self.force:
            return
        taken = [str(p) for p in self.paths() if p.exists()]
        if taken:
            raise OutputExistsError(
                f"output exists: {', '.join(taken)} (choose another --out or pass --force)"
            )

    def commit(self) -> list[Path]:
        """Write all staged files; returns their paths."""
        self.check_free()
        for name, data in self.files.items():
            atomic_write_bytes(self.directory / name, data)
        return self.paths()
