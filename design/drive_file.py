"""Strict loading of TOML sections into frozen dataclasses: the schema machinery of every family's drive file.

A family writes its drive-file schema as frozen dataclasses whose field metadata carries the physical
dimension and the validity check (:func:`q`); :func:`load_section` fills one from a TOML table. Loading
is strict: an unknown key, a missing key, a wrong type or unit, or a non-physical value raises
:class:`~sensorless.design.units.DriveFileError` naming the file and the dotted key.

Conventions (docs/conventions.md): SI units; speeds are electrical angular speeds in rad/s; per-unit
values and other relative units ("0.13 pu", "2 R_s_hat") are resolved by the caller's ``relative`` map.
"""

from __future__ import annotations

import contextlib
import dataclasses
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sensorless.design.units import MAX_POLE_PAIRS, DriveFileError, check_magnitude, parse_quantity


def read_text(path: Path) -> str:
    """The UTF-8 text of a drive or scenario file; DriveFileError naming it if unreadable or not UTF-8."""
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise DriveFileError(str(path), "(encoding)", f"not UTF-8 text (byte {e.start})") from None
    except OSError as e:
        raise DriveFileError(str(path), "(file)", f"cannot read: {e.strerror}") from None


def q(
    dim: str,
    check: str | None = "positive",
    doc: str = "",
    default: Any = dataclasses.MISSING,
    optional: bool = False,
) -> Any:
    """A dataclass field holding a quantity of dimension ``dim`` (SI), validated by ``check``;
    ``default`` for a key that may be left out (``load_section(optional=...)``, or always with
    ``optional``: a key a shared section gained, which every family's loader keeps optional)."""
    meta = {"dim": dim, "check": check, "doc": doc, **({"optional": True} if optional else {})}
    return field(default=default, metadata=meta)


_CHECKS: dict[str, tuple[Callable[[float], bool], str]] = {
    "positive": (lambda x: x > 0, "must be > 0"),
    "nonnegative": (lambda x: x >= 0, "must be >= 0"),
    "any": (lambda x: True, ""),
    "pole_pairs": (lambda x: 1 <= x <= MAX_POLE_PAIRS, f"pole pairs from 1 to {MAX_POLE_PAIRS}"),
}


def table(data: Mapping[str, Any], key: str, file: str, prefix: str = "") -> Mapping[str, Any]:
    """The TOML table ``data[key]``; DriveFileError naming ``prefix + key`` if missing or not a table."""
    full = f"{prefix}{key}"
    if key not in data:
        raise DriveFileError(file, full, "missing section")
    t = data[key]
    if not isinstance(t, dict):
        raise DriveFileError(file, full, "expected a table [section]")
    return t


def load_section(
    cls: type,
    table: Mapping[str, Any],
    file: str,
    section: str,
    relative: Mapping[str, float] | None = None,
    skip: tuple[str, ...] = (),
    optional: tuple[str, ...] = (),
) -> Any:
    """Build dataclass ``cls`` from a TOML table, strictly; ``relative`` maps relative units to SI.

    Keys in ``skip`` are accepted and left to the caller; keys in ``optional`` are read like the
    others when given and keep the field's default otherwise."""
    relative = relative or {}
    names = [f.name for f in dataclasses.fields(cls) if f.name not in skip]
    for k in table:
        if k not in names and k not in skip:
            allowed = ", ".join(names) or "(no keys)"
            raise DriveFileError(file, f"{section}.{k}", f"unknown key (allowed: {allowed})")
    values: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        key = f"{section}.{f.name}"
        dim = f.metadata.get("dim")
        if f.name not in table:
            if f.name in optional or f.metadata.get("optional"):
                continue
            raise DriveFileError(file, key, f"missing key ({f.metadata.get('doc', dim)})")
        raw = table[f.name]
        if dim == "choice":
            if not isinstance(raw, str):
                raise DriveFileError(file, key, f"expected a string, got {raw!r}")
            values[f.name] = raw
            continue
        x, rel = parse_quantity(raw, dim, file=file, key=key)
        if rel is not None:
            if rel not in relative:
                raise DriveFileError(file, key, f"unit '{rel}' cannot be resolved here")
            x = check_magnitude(x * relative[rel], raw, file=file, key=key)
        check = f.metadata.get("check") or "any"
        ok, why = _CHECKS[check]
        if not ok(x):
            raise DriveFileError(file, key, f"non-physical value {raw!r}: {why}")
        values[f.name] = int(x) if dim == "integer" else x
    return cls(**values)


# The longest drive or scenario name: names become directory names with the commands' prefixes and
# suffixes (``simulation-<drive>-<scenario>``, the staging directory ``.<dir>.stage-<pid>-<tag>``), which
# must fit a file system's 255 bytes per path component
NAME_MAX = 64


def name_problem(name: object) -> str | None:
    """Why ``name`` cannot be a drive's (or scenario's) name, which becomes part of a file name: not a
    string, empty, a path separator, '..', a control character, leading '-' or '.', or too long
    (:data:`NAME_MAX` bytes of UTF-8); None if it can."""
    if not isinstance(name, str):
        return f"expected a string, got {name!r}"
    if not name.strip():
        return "empty"
    bad = [c for c in name if c in "/\\" or ord(c) < 32 or ord(c) == 127]
    if bad:
        return (
            f"{name!r} holds {bad[0]!r}: a name becomes part of file names (no path separators or "
            "control characters)"
        )
    if ".." in name or name[0] in ".-":
        return f"{name!r}: a name becomes part of file names (no '..', no leading '.' or '-')"
    if len(name.encode()) > NAME_MAX:
        return f"{len(name.encode())} bytes: at most {NAME_MAX} (a name becomes part of file names)"
    return None


def check_name(name: object, file: str, key: str) -> str:
    """``name`` if :func:`name_problem` finds none, else DriveFileError naming ``file`` and ``key``."""
    why = name_problem(name)
    if why is not None:
        raise DriveFileError(file, key, why)
    assert isinstance(name, str)
    return name


def check_keys(data: Mapping[str, Any], allowed: tuple[str, ...], file: str, prefix: str) -> None:
    """DriveFileError naming the first key of ``data`` not in ``allowed``."""
    for k in data:
        if k not in allowed:
            raise DriveFileError(file, f"{prefix}{k}", f"unknown key (allowed: {', '.join(allowed)})")


def drive_header(data: Mapping[str, Any], file: str) -> Mapping[str, Any]:
    """The [drive] table common to every kind: name, kind and, optionally, source (strings; where the
    data come from, default :data:`DEFAULT_SOURCE`)."""
    head = table(data, "drive", file)
    check_keys(head, ("name", "kind", "source"), file, "drive.")
    for k in ("name", "kind", "source"):
        if k == "source" and k not in head:
            continue
        if not isinstance(head.get(k), str):
            raise DriveFileError(file, f"drive.{k}", "missing key or not a string")
    return {**head, "source": head.get("source", DEFAULT_SOURCE)}


DEFAULT_SOURCE = "the user's motor data"


def positive(t: Mapping[str, Any], k: str, dim: str, file: str, section: str) -> float:
    """A positive SI quantity of ``t[k]`` (a number in SI or a string with a unit of ``dim``);
    DriveFileError naming ``section.k``."""
    x, rel = parse_quantity(t[k], dim, file=file, key=f"{section}.{k}")
    if rel is not None:
        raise DriveFileError(file, f"{section}.{k}", f"unit '{rel}' cannot be resolved here")
    if not x > 0:
        raise DriveFileError(file, f"{section}.{k}", f"non-physical value {t[k]!r}: must be > 0")
    return x


def nonempty_list(table: Mapping[str, Any], key: str, file: str, section: str) -> list[Any]:
    """The non-empty list ``table[key]``; DriveFileError naming ``section.key`` otherwise."""
    full = f"{section}.{key}"
    if key not in table:
        raise DriveFileError(file, full, "missing key")
    v = table[key]
    if not isinstance(v, list) or not v:
        raise DriveFileError(file, full, f"expected a non-empty list, got {v!r}")
    return v


def quantities(table: Mapping[str, Any], key: str, dim: str, file: str, section: str) -> tuple[float, ...]:
    """The non-empty list ``table[key]`` of quantities of dimension ``dim``, in SI; each is named
    ``section.key[k]`` in errors."""
    out = []
    for k, v in enumerate(nonempty_list(table, key, file, section)):
        x, rel = parse_quantity(v, dim, file=file, key=f"{section}.{key}[{k}]")
        if rel is not None:
            raise DriveFileError(file, f"{section}.{key}[{k}]", f"unit '{rel}' cannot be resolved here")
        out.append(x)
    return tuple(out)


def sampling_frequency(inv: Mapping[str, Any], ctl: Mapping[str, Any], file: str) -> tuple[float, str]:
    """(sampling frequency [Hz], the key it came from) of a drive file: [inverter] f_s or [control] T_s
    (both given: they must agree)."""
    f_inv = positive(inv, "f_s", "frequency", file, "inverter") if "f_s" in inv else None
    f_ctl = 1 / positive(ctl, "T_s", "time", file, "control") if "T_s" in ctl else None
    if f_inv is None and f_ctl is None:
        raise DriveFileError(file, "inverter.f_s", "missing key (sampling frequency, e.g. '10 kHz')")
    if f_inv is not None and f_ctl is not None and abs(f_inv / f_ctl - 1) > 1e-9:
        raise DriveFileError(
            file, "inverter.f_s", f"{f_inv:g} Hz, but control.T_s is 1/{f_ctl:g} Hz: give one of them"
        )
    return (f_inv, "inverter.f_s") if f_inv is not None else (f_ctl, "control.T_s")  # type: ignore[return-value]


# --------------------------------------------------------------------------------------------------
# Complete drive documents (``sensorless init``)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Entry:
    """One key of a complete drive document: its TOML value (a quantity string, number, boolean, list or
    inline table) and, for a derived value, the rule it was derived by (written as its comment)."""

    value: Any
    rule: str = ""
    given: bool = False


@dataclass
class DriveDocument:
    """A complete drive file as data, derived by a family from a (possibly minimal) one: its sections
    (dotted names such as ``observer.gains.speed``) of :class:`Entry`, comment lines above sections,
    commented-out optional keys, and the plausibility warnings. :meth:`data` is what the family's
    strict loader reads; :meth:`toml` is the text ``sensorless init`` writes, which loads to the same."""

    header: list[str] = dataclasses.field(default_factory=list)
    sections: dict[str, dict[str, Entry]] = dataclasses.field(default_factory=dict)
    notes: dict[str, list[str]] = dataclasses.field(default_factory=dict)  # comment lines per section
    optional: dict[str, list[str]] = dataclasses.field(default_factory=dict)  # commented-out keys
    warnings: list[str] = dataclasses.field(default_factory=list)
    context: dict[str, Any] = dataclasses.field(default_factory=dict)  # the family's own (e.g. motor data)

    def section(self, name: str, note: str = "") -> dict[str, Entry]:
        """The section ``name`` (created empty, with a comment line ``note``, if new)."""
        if name not in self.sections:
            self.sections[name] = {}
            if note:
                self.notes.setdefault(name, []).append(note)
        return self.sections[name]

    def data(self) -> dict[str, Any]:
        """The nested TOML data of the document (what tomllib would read from :meth:`toml`)."""
        out: dict[str, Any] = {}
        for name, entries in self.sections.items():
            t = out
            for part in name.split("."):
                t = t.setdefault(part, {})
            t.update({k: e.value for k, e in entries.items()})
        return out

    def derived(self) -> int:
        """How many values were derived (not given)."""
        return sum(not e.given for entries in self.sections.values() for e in entries.values())

    @contextlib.contextmanager
    def blaming_given_keys(self, given: Mapping[str, Any], file: str) -> Iterator[None]:
        """Re-raise a DriveFileError on a value the file did not give (a derived one) naming the keys of
        ``given`` (the file's data) that its rule uses: the user's keys, not one they never wrote."""
        try:
            yield
        except DriveFileError as e:
            raise self._blame(e, given, file) from None

    def _blame(self, e: DriveFileError, given: Mapping[str, Any], file: str) -> DriveFileError:
        section, _, key = e.key.rpartition(".")
        entry = self.sections.get(section, {}).get(key)
        if entry is None or entry.given or not entry.rule:
            return e
        words = set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", entry.rule))
        users = [
            f"{s}.{k}"
            for s, t in given.items()
            if isinstance(t, Mapping) and s != "drive"
            for k in t
            if k in words
        ]
        if not users:
            return e
        why = f"{e.problem} (in {e.key} = {toml_value(entry.value)}, derived as {entry.rule})"
        return DriveFileError(file, ", ".join(users), why)

    def toml(self) -> str:
        """The document as TOML text, each derived value with its rule as a comment."""
        lines = [f"# {h}" if h else "#" for h in self.header]
        for name, entries in self.sections.items():
            lines.append("")
            lines += [f"# {n}" for n in self.notes.get(name, [])]
            lines.append(f"[{name}]")
            for k, e in entries.items():
                text = f"{k} = {toml_value(e.value)}"
                comment = ("# " + e.rule) if e.rule else ""
                if not comment:
                    lines.append(text)
                elif len(text) + 2 + len(comment) <= 110:
                    lines.append(f"{text}  {comment}")
                else:
                    lines += [comment, text]
            lines += [f"# {o}" for o in self.optional.get(name, [])]
        return "\n".join(lines).lstrip("\n") + "\n"


def g6(x: float) -> str:
    """A number with 6 significant digits (the precision of derived values)."""
    return f"{x:.6g}"


def toml_value(v: object) -> str:
    """A value as TOML text (strings quoted, lists and inline tables written out)."""
    import json

    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {v!r} as TOML")


def derived_document(data: Mapping[str, Any], file: str, page: str) -> DriveDocument:
    """A complete drive document begun: the header every derived drive file starts with (``page``: the
    family's doc that gives the rules) and its [drive] section, each key given kept as written."""
    head = drive_header(data, file)
    doc = DriveDocument()
    doc.header = [
        f"Drive file of {head['name']} ({head.get('kind')}): every value the source file did not give is",
        f"derived by the rule in its comment ({page}, 'Derived drive files';",
        "docs/motor_data.md). Review and edit them: this file is complete and loads as it is.",
    ]
    given = table(data, "drive", file)
    sec = doc.section("drive")
    for k, v in head.items():
        sec[k] = Entry(v, given=True) if k in given else Entry(v, "default: say where the data come from")
    return doc
