"""Strict loading of TOML sections into frozen dataclasses: the schema machinery of every family's drive file.

A family writes its drive-file schema as frozen dataclasses whose field metadata carries the physical
dimension and the validity check (:func:`q`); :func:`load_section` fills one from a TOML table. Loading
is strict: an unknown key, a missing key, a wrong type or unit, or a non-physical value raises
:class:`~sensorless.design.units.DriveFileError` naming the file and the dotted key.

Conventions (docs/conventions.md): SI units; speeds are electrical angular speeds in rad/s; per-unit
values and other relative units ("0.13 pu", "2 R_s_hat") are resolved by the caller's ``relative`` map.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import field
from pathlib import Path
from typing import Any

from sensorless.design.units import DriveFileError, check_magnitude, parse_quantity


def read_text(path: Path) -> str:
    """The UTF-8 text of a drive or scenario file; DriveFileError naming it if unreadable or not UTF-8."""
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise DriveFileError(str(path), "(encoding)", f"not UTF-8 text (byte {e.start})") from None
    except OSError as e:
        raise DriveFileError(str(path), "(file)", f"cannot read: {e.strerror}") from None


def q(dim: str, check: str | None = "positive", doc: str = "") -> Any:
    """A dataclass field holding a quantity of dimension ``dim`` (SI), validated by ``check``."""
    return field(metadata={"dim": dim, "check": check, "doc": doc})


_CHECKS: dict[str, tuple[Callable[[float], bool], str]] = {
    "positive": (lambda x: x > 0, "must be > 0"),
    "nonnegative": (lambda x: x >= 0, "must be >= 0"),
    "any": (lambda x: True, ""),
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
) -> Any:
    """Build dataclass ``cls`` from a TOML table, strictly; ``relative`` maps relative units to SI."""
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


def check_keys(data: Mapping[str, Any], allowed: tuple[str, ...], file: str, prefix: str) -> None:
    """DriveFileError naming the first key of ``data`` not in ``allowed``."""
    for k in data:
        if k not in allowed:
            raise DriveFileError(file, f"{prefix}{k}", f"unknown key (allowed: {', '.join(allowed)})")


def drive_header(data: Mapping[str, Any], file: str) -> Mapping[str, Any]:
    """The [drive] table common to every kind: name, kind, source (strings)."""
    head = table(data, "drive", file)
    check_keys(head, ("name", "kind", "source"), file, "drive.")
    for k in ("name", "source"):
        if not isinstance(head.get(k), str):
            raise DriveFileError(file, f"drive.{k}", "missing key or not a string")
    return head
