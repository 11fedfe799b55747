"""The registry of observer families: the one place that maps a drive kind to a family.

Built-in families are found, not listed: every subpackage of ``sensorless.design`` that defines
``FAMILY`` (an :class:`~sensorless.design.family.ObserverFamily`) is one, so adding a family means
adding its folders. Families installed by other distributions register through the entry-point group
``sensorless.families`` (each entry point names an ObserverFamily instance); a test or a script may
also :func:`register` one directly. The higher layers find a family's hooks through the module names
the family record carries (sensorless.tuning.family, sensorless.reports.family).
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Iterator
from contextlib import contextmanager
from importlib.metadata import entry_points

from sensorless.design.family import ObserverFamily
from sensorless.design.units import UnknownName

ENTRY_POINTS = "sensorless.families"

_FAMILIES: dict[str, ObserverFamily] = {}
_discovered = False


def register(family: ObserverFamily) -> ObserverFamily:
    """Add ``family`` (keyed by its kind); a second family of the same kind or name is an error (gain
    laws may share names across families)."""
    _discover()
    # gain-law names are each family's own (a gain table names its drive kind): two may share one
    for other in _FAMILIES.values():
        if other is family:
            continue
        if other.kind == family.kind or other.name == family.name:
            raise ValueError(f"{family!r} clashes with the registered {other!r}: kind or name")
    _FAMILIES[family.kind] = family
    return family


def unregister(family: ObserverFamily) -> None:
    """Remove ``family`` (if registered)."""
    if _FAMILIES.get(family.kind) is family:
        del _FAMILIES[family.kind]


@contextmanager
def registered(family: ObserverFamily) -> Iterator[ObserverFamily]:
    """``with registered(f):`` the family is known inside the block only (tests, scripts)."""
    register(family)
    try:
        yield family
    finally:
        unregister(family)


def _discover() -> None:
    global _discovered
    if _discovered:
        return
    _discovered = True
    import sensorless.design as pkg

    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
        if info.ispkg:
            fam = getattr(importlib.import_module(f"{pkg.__name__}.{info.name}"), "FAMILY", None)
            if isinstance(fam, ObserverFamily):
                register(fam)
    for ep in sorted(entry_points(group=ENTRY_POINTS), key=lambda e: e.name):
        fam = ep.load()
        if isinstance(fam, ObserverFamily):
            register(fam)


def families() -> list[ObserverFamily]:
    """Every registered family, in a stable order (by name)."""
    _discover()
    return sorted(_FAMILIES.values(), key=lambda f: f.name)


def kinds() -> list[str]:
    """The drive kinds of the registered families."""
    return [f.kind for f in families()]


def family(kind: str) -> ObserverFamily:
    """The family of drive kind ``kind``; KeyError naming the known kinds if there is none."""
    _discover()
    try:
        return _FAMILIES[kind]
    except KeyError:
        raise UnknownName(f"unknown drive kind {kind!r} (known: {', '.join(kinds())})") from None


def family_of(drive: object) -> ObserverFamily:
    """The family of a loaded drive."""
    return family(drive.kind)  # type: ignore[attr-defined]
