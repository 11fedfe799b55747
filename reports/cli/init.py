"""``sensorless init``: the complete drive file of a minimal one, every derived value with its rule.

A minimal drive file gives the motor in datasheet terms, its rating and the inverter (docs/motor_data.md,
README "Your own motor"); its observer family derives everything else by documented rules
(``ObserverFamily.document``, e.g. design/ipmsm_adaptive/derive.py) and this command writes the result
as a drive file to review and edit. The written file is loaded back before it is moved into place, so
what is written loads; every command also accepts the minimal file itself, with the same result.

``--from NAME FILE`` reads a firmware's configuration file instead (VESC Tool's XML, an odrivetool
backup, ...): the observer families declare the formats they read (reports/family.py ``Importer``) and
each format's options; the minimal drive file it gives is written after it loads, and the notes of the
conversion (missing values, assumptions, which of two redundant values was used) go to stderr.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sensorless.design import registry
from sensorless.design.capabilities import Documented, OpenLoopStart, require
from sensorless.design.drive import load_drive_text, preset_text
from sensorless.design.drive_file import Entry, read_text, table
from sensorless.design.family import CapabilityError, Drive, ObserverFamily
from sensorless.design.startup import DERIVED_FROM, SECTION, document_entries, optional_lines
from sensorless.design.units import DriveFileError
from sensorless.reports.cli.common import UsageError, print_warnings
from sensorless.reports.family import (
    Importer,
    add_family_options,
    add_options,
    all_options,
    hooks,
    import_options,
    importers,
    refuse_foreign,
)
from sensorless.reports.files import OutputFile

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.drive_file import DriveDocument


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``init`` subcommand."""
    p = sub.add_parser(
        "init",
        help="write the complete drive file of a minimal one (motor datasheet, rating, inverter)",
        description="Read a minimal drive file ([drive] name and kind; [motor] in datasheet terms; [rating] "
        "n_N and T_N or I_N; [inverter] u_dc and f_s) or a preset, derive every other value by the observer "
        "family's documented rules, and write the complete drive file, each derived value with its rule as "
        "a comment (docs/motor_data.md).",
    )
    p.add_argument(
        "drive", nargs="?", metavar="MINIMAL_TOML_OR_PRESET", help="minimal drive TOML (or a preset name)"
    )
    formats = importers()
    p.add_argument(
        "--from",
        dest="from_firmware",
        nargs=2,
        metavar=("FIRMWARE", "FILE"),
        help="instead of a drive file, read a firmware's configuration file and write the minimal drive "
        f"file it gives (firmware: {', '.join(sorted(formats)) or 'none declared'})",
    )
    p.add_argument("--out", required=True, metavar="DRIVE.toml", help="the drive file to write")
    p.add_argument("--force", action="store_true", help="overwrite an existing file")
    add_options(
        p,
        import_options(),
        "options of --from (each firmware declares its own; refused by the others)",
        "--from ",
    )
    add_family_options(p, "init")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Derive, check by loading, write."""
    if args.from_firmware is not None:
        if args.drive is not None:
            raise UsageError(f"--from reads {args.from_firmware[1]}: give no drive file beside it")
        for opt, _ in all_options("init").values():
            if getattr(args, opt.dest, None) is not None:
                raise UsageError(f"{opt.flags[0]}: an option of a minimal drive file, not of --from")
        return run_import(args)
    if args.drive is None:
        raise UsageError("give a minimal drive file (or a preset), or --from FIRMWARE FILE")
    for opt, _ in import_options().values():
        if getattr(args, opt.dest, None) is not None:
            raise UsageError(f"{opt.flags[0]}: an option of --from FIRMWARE FILE only")
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
    refuse_foreign(args, fam, "init")
    own = hooks(fam).init_data
    if own is not None:
        data = dict(own(data, args, file))
    out = OutputFile(args.out, force=args.force)
    out.check()
    given_start = data.pop(SECTION, None)  # [startup] is read by design/drive.py for every family
    doc = require(fam, Documented).document(data, file)
    written = doc.toml()
    source = load_drive_text(text, file)  # the source loads (errors and warnings name its keys)
    drive = load_drive_text(written, str(args.out))  # and so does what is written
    if isinstance(fam, OpenLoopStart) and _startup_section(doc, fam, drive, given_start):
        written = doc.toml()
        try:
            drive = load_drive_text(written, str(args.out))
        except DriveFileError as e:  # a [startup] value derived from the user's: name theirs
            key = e.key.removeprefix(f"{SECTION}.")
            if key not in DERIVED_FROM or (given_start and key in given_start):
                raise
            raise DriveFileError(
                file, DERIVED_FROM[key], f"the I-f start's {key} derived from them: {e.problem}"
            ) from None
    out.set_text(written)
    path = out.commit()
    print_warnings("init", source)
    n = doc.derived()
    print(f"wrote {path}: {drive.name} ({fam.title}); {n} values derived, each with its rule as a comment")
    print(f"review them, then e.g.: sensorless tune {path}")
    return 0


def _startup_section(doc: DriveDocument, fam: ObserverFamily, drive: Drive, given: Any) -> bool:
    """Add the ``[startup]`` section (design/startup.py) to ``doc``: the keys given as written, the
    others by their rules at the drive's own gains; False where the observer needs no start."""
    from sensorless.design.pmsm_drive import startup_values

    note = "the open-loop I-f start below the minimum sensorless speed (design/startup.py)"
    try:
        values, _, w_min = startup_values(drive, fam.gains(drive))  # ``drive`` has no [startup] yet
    except CapabilityError as e:
        # no minimum-speed analysis (an observer without a linearization): the speeds cannot follow a
        # rule, so they are left for the user to give, with the reason; the rest keeps its rules
        sec = doc.section(SECTION, f"{note}; handover speeds not derived: {e}")
        sec.update({k: Entry(v, given=True) for k, v in (given or {}).items()})
        doc.optional.setdefault(SECTION, []).extend(
            line
            for line in (
                'w_on = "..."  # give the handover speed (rad/s, Hz or p.u.) to run the start',
                'w_off = "..."  # and the speed below w_on where the drive goes back to open loop',
            )
            if not (given and line.split()[0] in given)
        )
        return True
    if values is None and given is None:
        return False
    ramped = _speed_ramp(doc, fam, drive, values, w_min, given)
    if ramped is not None:  # the start's values on the drive with its ramp
        drive, values, w_min = ramped
    sec = doc.section(SECTION, note)
    if values is not None:
        sec.update(document_entries(values, drive.w_base, w_min))
        if not (given and "dwell" in given):
            doc.optional.setdefault(SECTION, []).extend(optional_lines(values))
    sec.update({k: Entry(v, given=True) for k, v in (given or {}).items()})
    return True


def _speed_ramp(
    doc: DriveDocument,
    fam: ObserverFamily,
    drive: Drive,
    values: dict[str, float] | None,
    w_min: float,
    given: Mapping[str, object] | None,
) -> tuple[Drive, dict[str, float] | None, float] | None:
    """Add ``[control] speed_ramp`` (design/speed_ramp.py) to ``doc`` where the drive needs one, and
    return (the drive with it, its start's values, their w_min); None where it needs none. It needs one
    where the start's rule puts the handover at the rated speed (ON_FACTOR w_min at rated load, w_min
    judged under the full braking p (T_max + T_N) / J: design/startup.py), so that no check below it
    runs sensorless, and a speed reference ramped at the start's acceleration (a drive's own rate)
    brings the handover below it (the gimbal of docs/examples/motors: w_min 1 p.u. under the full
    braking, 0.18 p.u. along the ramp; every check passes). Not where the drive file gives the key, or
    fixes the start's acceleration or its handover."""
    from sensorless.design.pmsm_drive import startup_values
    from sensorless.design.startup import ON_FACTOR

    ctl = doc.sections.get("control")
    if (
        values is None
        or ctl is None
        or "speed_ramp" in ctl
        or (given and ({"acceleration", "w_on"} & set(given)))
    ):
        return None
    w_base = drive.w_base
    if ON_FACTOR * w_min < w_base * (1 - 1e-9):
        return None
    a = float(f"{values['if_acc']:.6g}")
    ctl["speed_ramp"] = Entry(
        f"{a:.6g} rad/s^2",
        f"the I-f start's acceleration: under the full braking the start's handover is at the rated "
        f"speed (w_min {w_min / w_base:.3g} p.u.); along this ramp it is lower (0: a step asks for the "
        "torque limit)",
    )
    try:
        ramped = load_drive_text(doc.toml(), drive.file)
    except DriveFileError:  # a start's value out of range (its own error follows, naming the user's keys)
        del ctl["speed_ramp"]
        return None
    v, _, w = startup_values(ramped, fam.gains(ramped))
    if v is None or ON_FACTOR * w >= w_base * (1 - 1e-9):  # the ramp does not help: not derived
        del ctl["speed_ramp"]
        return None
    return ramped, v, w


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


def _importer(name: str) -> Importer:
    """The importer of firmware ``name``: one line naming the firmwares there are if none or several."""
    found = importers().get(name, [])
    if not found:
        known = ", ".join(sorted(importers())) or "none: no observer family declares one"
        raise UsageError(f"argument --from: no importer for {name!r} (known: {known})")
    if len(found) > 1:
        fams = ", ".join(f.name for f, _ in found)
        raise CapabilityError(f"--from {name}: declared by several observer families ({fams})")
    return found[0][1]


def _rules(text: str, keys: str) -> str:
    """'inverter.u_dc = si_battery_cells x 3.7 V; ...': each drive-file key of ``keys`` (comma-separated)
    with the rule an import wrote as its comment (the firmware's fields it comes from)."""
    found, section = {}, ""
    for line in text.splitlines():
        if line.startswith("["):
            section = line.strip("[] ")
        elif " = " in line and "  # " in line:
            found[f"{section}.{line.split(' = ', 1)[0].strip()}"] = line.rsplit("  # ", 1)[1].strip()
    wanted = [k.strip() for k in keys.split(",")]
    return "; ".join(f"{k} = {found.get(k, 'a rule of the drive file')}" for k in wanted)


def run_import(args: argparse.Namespace) -> int:
    """Read a firmware's configuration, check the drive file it gives by loading it, write it."""
    name, spec = args.from_firmware
    imp = _importer(name)
    mine = {opt.dest for opt in imp.options}
    for dest, (opt, owners) in import_options().items():
        if dest not in mine and getattr(args, dest, None) is not None:
            raise UsageError(
                f"{opt.flags[0]}: not an option of --from {name} (it is of --from {', '.join(owners)})"
            )
    out = OutputFile(args.out, force=args.force)
    out.check()
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(f"{spec}: no such file")
    given = {d: getattr(args, d) for d in sorted(mine) if getattr(args, d, None) is not None}
    written, notes = imp.read(read_text(path), spec, given)
    try:
        drive = load_drive_text(written, str(args.out))  # what is written loads
    except DriveFileError as e:  # nothing was written: name the file read and the fields behind the keys
        raise DriveFileError(spec, e.key, f"{e.problem} (converted as {_rules(written, e.key)})") from None
    out.set_text(written)
    target = out.commit()
    for note in notes:
        print(f"sensorless init: note: {note}", file=sys.stderr)
    print_warnings("init", drive)
    print(f"wrote {target}: {drive.name} from {spec} ({imp.title}); the conversions are its comments")
    print(f"review it, then e.g.: sensorless tune {target}")
    return 0
