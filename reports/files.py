"""Output sets that appear whole or not at all: staged beside the target directory, moved in at once.

Every command writes its files (tables, figures, C sources, reports) as one :class:`OutputSet`, whose
unit is the output directory (``--out``):

1. :meth:`OutputSet.check`, before any computation, checks the path: an existing path must be a
   directory (not a file), holding files only (an output directory has no subdirectories), and not
   the current directory; its parent must be writable; without ``force``, no output may exist (when
   a command cannot name its files before computing them, an existing directory must be empty).
   Each problem is one :class:`OutputError` line naming the path.
2. Files are staged in memory (:meth:`add_bytes`, :meth:`add_text`, :meth:`add_figure`); a name given
   twice is an error.
3. :meth:`OutputSet.commit` writes them into a new directory beside the target, in the same parent
   (``.<name>.sensorless-<pid>-<random>``), and moves that directory into place with one rename. If
   the target exists, its files that are not outputs of this run are carried over (hard links) and
   the two directories are exchanged atomically (Linux ``renameat2(RENAME_EXCHANGE)``; where that is
   missing, two renames in a row), then the old directory is removed.

So a kill at any point leaves the target as it was or with the whole new set; what a hard kill
(SIGKILL) can leave is a hidden staging directory beside it, which the next run for the same target
removes. Ctrl-C and SIGTERM are recorded (reports/interrupts.py): an interrupt that arrives before the
move writes nothing, one during the move lets it finish.

One exception: a target that is a mount point (a container's volume, say) cannot be renamed. Its set
is staged inside it (``.sensorless-stage-<pid>-<random>``) and renamed in file by file, so each file
is whole, but a kill during those renames can leave new files beside old ones.
"""

from __future__ import annotations

import ctypes
import errno
import io
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

from sensorless.reports import interrupts

if TYPE_CHECKING:
    from matplotlib.figure import Figure as MplFigure

STAGE_TAG = ".sensorless-"
INNER_STAGE = re.compile(r"^\.sensorless-stage-(\d+)-[A-Za-z0-9_]+$")  # inside a mount point


class OutputError(Exception):
    """An output path cannot be written as asked; the message names it (one line)."""


class OutputExistsError(OutputError, FileExistsError):
    """Outputs already exist and overwriting was not requested."""


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _stage_pattern(name: str) -> re.Pattern[str]:
    return re.compile(rf"^\.{re.escape(name)}{re.escape(STAGE_TAG)}(\d+)-[A-Za-z0-9_-]+$")


def remove_stale_stages(target: Path) -> list[Path]:
    """Remove the staging directories of ``target`` left by killed runs (their process is gone)."""
    parent = target.parent
    pat = _stage_pattern(target.name)
    removed = []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return removed
    for e in entries:
        m = pat.match(e.name)
        if m and int(m.group(1)) != os.getpid() and not _alive(int(m.group(1))):
            shutil.rmtree(e.path, ignore_errors=True)
            removed.append(Path(e.path))
    return removed


def _remove_stale_inner_stages(target: Path) -> None:
    """Staging directories that killed runs left inside a mount-point target."""
    try:
        entries = list(os.scandir(target))
    except OSError:
        return
    for e in entries:
        m = INNER_STAGE.match(e.name)
        if m and int(m.group(1)) != os.getpid() and not _alive(int(m.group(1))):
            shutil.rmtree(e.path, ignore_errors=True)


def _exchange(a: Path, b: Path) -> None:
    """Swap the directories ``a`` and ``b`` atomically where the system can (Linux renameat2)."""
    fn = getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
    if fn is not None:
        at_fdcwd, rename_exchange = -100, 2
        if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
            return
        err = ctypes.get_errno()
        if err not in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP):
            raise OSError(err, os.strerror(err), str(b))
    # no atomic exchange here: two renames, with a moment in between where ``b`` is absent
    aside = a.with_name(a.name + "-old")
    os.rename(b, aside)
    os.rename(a, b)
    os.rename(aside, a)


def move_into_place(stage: Path, target: Path) -> None:
    """The one step that publishes a staged set: rename, or exchange with an existing target."""
    if target.exists():
        _exchange(stage, target)
    else:
        os.rename(stage, target)


def _carry_over(src: Path, dst: Path, names: Iterable[str]) -> None:
    """Hard-link (or copy) the entries of ``src`` not in ``names`` into ``dst``; symlinks as symlinks."""
    skip = set(names)
    for e in os.scandir(src):
        if e.name in skip:
            continue
        if e.is_symlink():
            os.symlink(os.readlink(e.path), dst / e.name)
            continue
        try:
            os.link(e.path, dst / e.name, follow_symlinks=False)
        except OSError:
            shutil.copy2(e.path, dst / e.name, follow_symlinks=False)


class OutputSet:
    """Files to be written together as the directory ``directory``; see the module docstring.

    ``names``: the file names the command will write, when it knows them before computing (an
    existing file of those names is refused without ``force``); None: the command names its files
    only while computing, so an existing non-empty directory is refused without ``force``.
    ``option``: how messages name the path (the command-line option).
    """

    def __init__(
        self,
        directory: str | Path,
        force: bool = False,
        names: Iterable[str] | None = None,
        option: str = "--out",
    ) -> None:
        self.directory = Path(directory)
        # results that do not hold, staged with the files: the command prints each and exits 3
        self.warnings: list[str] = []
        self.force = force
        self.names = None if names is None else list(names)
        self.option = option
        self.files: dict[str, bytes] = {}
        if self.names is not None:
            for n in self.names:
                self._check_name(n)
            dup = sorted({n for n in self.names if self.names.count(n) > 1})
            if dup:
                raise OutputError(f"{self._label()}: {', '.join(dup)} would be written twice")

    # ------------------------------------------------------------------------------------ staging
    def _label(self) -> str:
        return f"{self.option} {self.directory}" if self.option else str(self.directory)

    def _check_name(self, name: str) -> None:
        if not name or "/" in name or name in (".", "..") or "\0" in name or os.sep in name:
            raise OutputError(f"{self._label()}: {name!r} is not a file name")

    def add_bytes(self, name: str, data: bytes) -> None:
        """Stage a file; a name staged twice is an error (two outputs would collide)."""
        self._check_name(name)
        if name in self.files:
            raise OutputError(f"{self._label()}: two outputs named {name}")
        self.files[name] = data

    def add_text(self, name: str, text: str) -> None:
        """Stage a UTF-8 text file (LF line ends)."""
        self.add_bytes(name, text.encode("utf-8"))

    def add_figure(self, name: str, fig: MplFigure, **kwargs: float) -> None:
        """Stage a matplotlib figure; the format follows the name's suffix. Metadata that would
        differ between runs (dates, software strings) is left out so files are byte-identical."""
        fmt = Path(name).suffix[1:]
        meta = {"Date": None} if fmt == "svg" else {"Software": None} if fmt == "png" else {}
        from sensorless.reports.document import pyplot

        pyplot()  # the report figures' settings (deterministic SVG ids)
        engine = fig.get_layout_engine()
        if engine is not None:
            # a layout engine lays the figure out again at every save (a second draw each): once here,
            # and the positions kept for every format staged (add_figures: PNG and SVG)
            engine.execute(fig)
            fig.set_layout_engine(None)
        buf = io.BytesIO()
        fig.savefig(buf, format=fmt, metadata=meta, **kwargs)
        self.add_bytes(name, buf.getvalue())

    def add_figures(self, stem: str, fig: MplFigure) -> None:
        """Stage ``fig`` as ``stem.png`` (110 dpi, to look at) and ``stem.svg`` (to zoom and print)."""
        self.add_figure(f"{stem}.png", fig, dpi=110)
        self.add_figure(f"{stem}.svg", fig)

    def paths(self) -> list[Path]:
        """Destination paths of the staged files."""
        return [self.directory / n for n in self.files]

    # ------------------------------------------------------------------------------------- checks
    def check(self) -> None:
        """Check the output path before anything is computed (module docstring); OutputError if not."""
        d = self.directory
        label = self._label()
        if os.path.lexists(d):
            real = Path(os.path.realpath(d))
            if not real.exists():
                raise OutputError(f"{label}: a symbolic link to nothing")
            if not real.is_dir():
                raise OutputError(f"{label}: exists and is not a directory")
            cwd = Path.cwd().resolve()
            if real == cwd or real in cwd.parents:
                raise OutputError(
                    f"{label}: is the current directory or contains it; outputs replace their directory "
                    "as a whole, so name a directory of their own"
                )
            mount = os.path.ismount(real)
            if mount:
                _remove_stale_inner_stages(real)
            try:
                entries = [e for e in os.scandir(real) if not (mount and INNER_STAGE.match(e.name))]
            except OSError as e:
                raise OutputError(f"{label}: cannot read the directory: {e.strerror}") from None
            for e in entries:
                if e.is_dir(follow_symlinks=False):
                    raise OutputError(
                        f"{label}: holds the subdirectory '{e.name}'; an output directory holds files only "
                        "(choose a new or empty directory)"
                    )
                if not (e.is_file(follow_symlinks=False) or e.is_symlink()):
                    raise OutputError(f"{label}: holds '{e.name}', which is not a regular file")
            if not self.force:
                present = {e.name for e in entries}
                if self.names is None and present:
                    raise OutputExistsError(
                        f"output exists: {d} is not empty and this command names its files only while "
                        "computing them (choose another --out or pass --force)"
                    )
                taken = dict.fromkeys(
                    str(d / n) for n in (self.names or []) + list(self.files) if n in present
                )
                if taken:
                    raise OutputExistsError(
                        f"output exists: {', '.join(taken)} (choose another --out or pass --force)"
                    )
            if not os.access(real, os.W_OK | os.X_OK):
                raise OutputError(f"{label}: not writable")
            self._probe(real if mount else real.parent, label)
        else:
            anc = Path(os.path.abspath(d)).parent
            while not os.path.lexists(anc) and anc != anc.parent:
                anc = anc.parent
            if not anc.is_dir():
                raise OutputError(f"{label}: '{anc}' is not a directory")
            self._probe(anc, label)

    def _probe(self, where: Path, label: str) -> None:
        """Can a directory be created in ``where`` (the staging directory will be)? One line if not."""
        if not os.access(where, os.W_OK | os.X_OK):
            raise OutputError(f"{label}: cannot create files in '{where}': permission denied")
        try:
            probe = tempfile.mkdtemp(prefix=f".{self.directory.name}{STAGE_TAG}{os.getpid()}-", dir=where)
        except OSError as e:
            raise OutputError(f"{label}: cannot create files in '{where}': {e.strerror}") from None
        os.rmdir(probe)

    # ------------------------------------------------------------------------------------- commit
    def commit(self) -> list[Path]:
        """Write the whole set and move it into place at once (module docstring); returns the paths.

        Raises :class:`~sensorless.reports.interrupts.Interrupted` without writing anything if Ctrl-C
        or SIGTERM arrived earlier (even if the computation swallowed it)."""
        interrupts.check()
        self.check()
        target = Path(os.path.realpath(self.directory))
        remove_stale_stages(target)
        if target.exists() and os.path.ismount(target):
            return self._commit_into_mount_point(target)
        with interrupts.deferred():
            stage: Path | None = None
            try:
                target.parent.mkdir(parents=True, exist_ok=True)
                prefix = f".{target.name}{STAGE_TAG}{os.getpid()}-"
                stage = Path(tempfile.mkdtemp(prefix=prefix, dir=target.parent))
                mode = 0o666 & ~_umask()
                for name, data in self.files.items():
                    with open(stage / name, "xb") as f:
                        f.write(data)
                    os.chmod(stage / name, mode)
                if target.exists():
                    _carry_over(target, stage, self.files)
                    os.chmod(stage, stat.S_IMODE(os.stat(target).st_mode))
                else:
                    os.chmod(stage, 0o777 & ~_umask())
                move_into_place(stage, target)
            except OSError as e:
                raise OutputError(f"{self._label()}: cannot write: {e.strerror or e}") from None
            finally:
                if stage is not None:  # the staging leftovers, or the old directory after an exchange
                    shutil.rmtree(stage, ignore_errors=True)
        return self.paths()

    def _commit_into_mount_point(self, target: Path) -> list[Path]:
        """A target that cannot be renamed: stage inside it, then rename the files in one by one."""
        with interrupts.deferred():
            stage: Path | None = None
            try:
                stage = Path(tempfile.mkdtemp(prefix=f".sensorless-stage-{os.getpid()}-", dir=target))
                mode = 0o666 & ~_umask()
                for name, data in self.files.items():
                    with open(stage / name, "xb") as f:
                        f.write(data)
                    os.chmod(stage / name, mode)
                for name in self.files:
                    os.replace(stage / name, target / name)
            except OSError as e:
                raise OutputError(f"{self._label()}: cannot write: {e.strerror or e}") from None
            finally:
                if stage is not None:
                    shutil.rmtree(stage, ignore_errors=True)
        return self.paths()


class OutputFile:
    """One output file (``sensorless init``'s drive file) that appears whole or not at all: checked
    before anything is computed (:meth:`check`: not a directory, its directory exists and is writable,
    absent unless ``force``), written beside itself and renamed into place (:meth:`commit`)."""

    def __init__(self, path: str | Path, force: bool = False, option: str = "--out") -> None:
        self.path = Path(path)
        self._raw = str(path)  # Path drops a trailing '/', which says the user meant a directory
        self.force = force
        self.option = option
        self.data: bytes | None = None

    def _label(self) -> str:
        return f"{self.option} {self.path}" if self.option else str(self.path)

    def check(self) -> None:
        """OutputError (one line naming the path) if the file cannot be written as asked."""
        p, label = self.path, self._label()
        if p.name in ("", ".", "..") or self._raw.endswith(("/", os.sep)):
            raise OutputError(f"{label}: not a file name (a directory?); name the file to write")
        if os.path.lexists(p):
            if os.path.isdir(p):
                raise OutputError(f"{label}: is a directory; name the drive file to write")
            if not self.force:
                raise OutputExistsError(f"output exists: {p} (choose another --out or pass --force)")
        parent = Path(os.path.abspath(p)).parent
        if not parent.is_dir():
            raise OutputError(f"{label}: '{parent}' is not a directory")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise OutputError(f"{label}: cannot create files in '{parent}': permission denied")

    def set_text(self, text: str) -> None:
        """The file's content (UTF-8, LF line ends)."""
        self.data = text.encode("utf-8")

    def commit(self) -> Path:
        """Write the file beside its target and rename it into place; returns the path."""
        interrupts.check()
        self.check()
        assert self.data is not None, "set_text first"
        parent = Path(os.path.abspath(self.path)).parent
        with interrupts.deferred():
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}{STAGE_TAG}{os.getpid()}-", dir=parent)
            try:
                with os.fdopen(fd, "wb") as f:
                    f.write(self.data)
                os.chmod(tmp, 0o666 & ~_umask())
                os.replace(tmp, self.path)
            except OSError as e:
                raise OutputError(f"{self._label()}: cannot write: {e.strerror or e}") from None
            finally:
                if os.path.exists(tmp):
                    os.unlink(tmp)
        return self.path
