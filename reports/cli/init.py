"""``sensorless init``: the complete drive file of a minimal one, every derived value with its rule.

A minimal drive file gives the motor in datasheet terms, its rating and the inverter (docs/motor_data.md,
README "Your own motor"); its observer family derives everything else by documented rules
(``ObserverFamily.document``, e.g. design/ipmsm_adaptive/derive.py) and this command writes the result
as a drive file to review and edit. The written file is loaded back before it is moved into place, so
what is written loads; every command also accepts the minimal file itself, with the same result.
"""

from __future__ import annotations

import argparse
import tomllib
from pathlib import Path
from typing import Any

from sensorless.design import registry
from sensorless.design.drive import load_drive_text, preset_text
from sensorless.design.drive_file import read_text, table
from sensorless.design.units import DriveFileError
from sensorless.reports.cli.common import print_warnings
from sensorless.reports.files import OutputFile


def register(sub: Any) -> None:
    """Add the ``init`` subcommand."""
    p = sub.add_parser(
        "init",
        help="write the complete drive file of a minimal one (motor datasheet, rating, inverter)",
        description="Read a minimal drive file ([drive] name and kind; [motor] in datasheet terms; [rating] "
        "n_N and T_N or I_N; [inverter] u_dc and f_s) or a preset, derive every other value by the observer "
        "family's documented rules, and write the complete drive file, each derived value with its rule as "
        "a comment (docs/motor_data.md).",
    )
    p.add_argument("drive", metavar="MINIMAL_TOML_OR_PRESET", help="minimal drive TOML (or a preset name)")
    p.add_argument("--out", required=True, metavar="DRIVE.toml", help="the drive file to write")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Derive, check by loading, write."""
    text, file = _source(args.drive)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise DriveFileError(file, "(syntax)", f"not valid TOML: {e}") from None
    kind = table(data, "drive", file).get("kind")
    try:
        fam = registry.family(kind) if isinstance(kind, str) else None
    except KeyError:
        fam = None
    if fam is None:
        raise DriveFileError(
            file, "drive.kind", f"unknown drive kind {kind!r} (known: {', '.join(registry.kinds())})"
        )
    out = OutputFile(args.out, force=args.force)
    out.check()
    doc = fam.document(data, file)
    written = doc.toml()
    source = load_drive_text(text, file)  # the source loads (errors and warnings name its keys)
    drive = load_drive_text(written, str(args.out))  # and so does what is written
    out.set_text(written)
    path = out.commit()
    print_warnings("init", source)
    n = doc.derived()
    print(f"wrote {path}: {drive.name} ({fam.title}); {n} values derived, each with its rule as a comment")
    print(f"review them, then e.g.: sensorless tune {path}")
    return 0


def _source(spec: str) -> tuple[str, str]:
    """(text, name for messages) of a drive file or a preset."""
    path = Path(spec)
    if path.suffix != ".toml" and "/" not in spec:
        text = preset_text(spec)
        if text is not None:
            return text, f"preset:{spec}"
    if not path.is_file():
        raise FileNotFoundError(f"{spec}: no such drive file, and not a preset")
    return read_text(path), str(path)
