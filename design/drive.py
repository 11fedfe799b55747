"""Drive descriptions: load a preset or a TOML file; the file's ``[drive] kind`` picks the family's schema.

A drive TOML names its kind in ``[drive] kind``; the family registered for that kind
(design/registry.py) validates the rest strictly into frozen dataclasses (its ``schema`` module).
Errors raise :class:`~sensorless.design.units.DriveFileError` naming the file and the dotted key.
"""

from __future__ import annotations

import hashlib
import tomllib
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

from sensorless.design import registry
from sensorless.design.capabilities import OpenLoopStart
from sensorless.design.drive_file import check_name, read_text, table
from sensorless.design.family import Drive, ObserverFamily
from sensorless.design.units import DriveFileError


def _preset_files() -> dict[str, Traversable]:
    """Preset name -> resource, over every family's presets package."""
    out: dict[str, Traversable] = {}
    for fam in registry.families():
        if fam.presets is None:
            continue
        for p in resources.files(fam.presets).iterdir():
            if p.name.endswith(".toml"):
                out[p.name[:-5]] = p
    return out


def preset_names() -> list[str]:
    """Names of the built-in presets (package data of the families)."""
    return sorted(_preset_files())


def preset_text(name: str) -> str | None:
    """The TOML text of the built-in preset ``name`` (None if there is none)."""
    res = _preset_files().get(name)
    return None if res is None else res.read_text(encoding="utf-8")


def load_drive_text(text: str, file: str) -> Drive:
    """Parse and validate the TOML ``text``; ``file`` is the name used in error messages."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise DriveFileError(file, "(syntax)", f"not valid TOML: {e}") from None
    head = table(data, "drive", file)
    if "name" in head:  # it becomes part of the outputs' names (each family requires the key)
        check_name(head["name"], file, "drive.name")
    kind = head.get("kind")
    try:
        fam = registry.family(kind) if isinstance(kind, str) else None
    except KeyError:
        fam = None
    if fam is None:
        known = ", ".join(registry.kinds())
        raise DriveFileError(file, "drive.kind", f"unknown drive kind {kind!r} (known: {known})")
    digest = hashlib.sha256(text.encode()).hexdigest()
    return with_startup_section(fam, data, file, digest)


def with_startup_section(fam: ObserverFamily, data: dict[str, Any], file: str, digest: str) -> Drive:
    """``fam``'s drive of ``data``, its optional ``[startup]`` section (design/startup.py) read here for
    every family that has the open-loop start (design/capabilities.py ``OpenLoopStart``)."""
    from sensorless.design.startup import SECTION, load_startup

    if SECTION not in data:
        return fam.load(data, file, digest)
    if not isinstance(fam, OpenLoopStart):
        raise DriveFileError(file, SECTION, f"observer family {fam.name!r} has no open-loop start")
    rest = {k: v for k, v in data.items() if k != SECTION}
    drive = fam.load(rest, file, digest)
    return fam.with_startup(drive, load_startup(data, file, drive.w_base))


def load_drive(spec: str | Path) -> Drive:
    """Load a built-in preset by name (e.g. ``"piippo2008"``) or a drive TOML file by path."""
    spec_s = str(spec)
    path = Path(spec_s)
    presets = _preset_files()
    if path.suffix != ".toml" and "/" not in spec_s and spec_s in presets:
        return load_drive_text(presets[spec_s].read_text(encoding="utf-8"), f"preset:{spec_s}")
    if not path.is_file():
        raise FileNotFoundError(
            f"{spec_s}: no such drive file, and not a preset (presets: {', '.join(sorted(presets))})"
        )
    return load_drive_text(read_text(path), str(path))
