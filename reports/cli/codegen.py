"""``sensorless codegen``: C code of the runtime observer of a drive (docs/codegen.md).

Writes ``<prefix>.c``, ``<prefix>.h``, an example ``main.c`` and a ``Makefile`` into ``--out``, all or
nothing (OutputSet), refusing to overwrite unless ``--force``. Deterministic: the same drive, gains and
options give byte-identical files. Any observer family with a runtime observer (design/family.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import struct
import sys

from sensorless.design.family import CapabilityError
from sensorless.design.gain_table import GainTableError, read_gain_table
from sensorless.design.registry import family_of
from sensorless.design.speed_ramp import drive_ramp
from sensorless.design.units import DriveFileError
from sensorless.reports.cli.common import UsageError, foreign_table, load, version
from sensorless.reports.codegen.generate import (
    PRECISIONS,
    Provenance,
    c_identifier,
    check_prefix,
    generate,
    output_names,
)
from sensorless.reports.files import OutputSet
from sensorless.reports.options import Renamed


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``codegen`` subcommand."""
    p = sub.add_parser(
        "codegen",
        help="generate the runtime observer as C (state/input/param structs, init, step, gains)",
        description="Generate C99 code of the drive's runtime observer from the same CasADi expressions "
        "used for analysis and simulation: typed API, parameter struct (gains included) from the drive "
        "and the gains, double or float.",
    )
    p.add_argument("drive", metavar="PRESET_OR_TOML", help="built-in preset name or drive TOML file")
    p.add_argument("--gains", metavar="TABLE", help="tuned gain table (JSON, sensorless-gain-table/1)")
    p.add_argument(
        "--gain-set",
        "--gain",
        action=Renamed,
        default=None,
        metavar="NAME",
        help="without --gains: which of the drive file's named gain sets, where its observer family has "
        "several (default: the drive file's choice; --gain: its former spelling, accepted until the next "
        "release)",
    )
    p.add_argument(
        "--precision",
        choices=(*PRECISIONS, "fixed"),
        default="float",
        help="C floating type, or fixed: 32-bit integer arithmetic for MCUs without an FPU (default float)",
    )
    p.add_argument(
        "--discretization",
        default=None,
        help="override the drive's discretization of the runtime step (the family's schemes)",
    )
    p.add_argument(
        "--startup",
        action="store_true",
        help="wrap the observer in the open-loop I-f start below the design's minimum sensorless speed "
        "(symbolic/startup.py; its parameters in the struct, a mode output, the speed command an input)",
    )
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="with --precision fixed: a runtime parameter's SI value (repeatable; e.g. psi_pm=3.2e-3): "
        "also writes <prefix>_params.bin, the parameter struct's raw words for these values in the "
        "formats the C is proven for (the example's third argument), and prints its initializer",
    )
    p.add_argument("--prefix", default=None, help="C name prefix (default: the drive name)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.set_defaults(func=run)


def _param_values(items: list[str], fixed: bool) -> dict[str, float]:
    """--param NAME=VALUE items as {name: SI value}; one line naming the option where one is wrong."""
    if items and not fixed:
        raise UsageError(
            "argument --param: needs --precision fixed (the float and double P_params take SI values)"
        )
    values = {}
    for item in items:
        name, sep, text = item.partition("=")
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        if not sep or not name.strip() or not math.isfinite(v):
            raise UsageError(f"argument --param: {item!r} is not NAME=VALUE with a finite SI value")
        values[name.strip()] = v
    return values


def run(args: argparse.Namespace) -> int:
    """Generate and write the files."""
    drive = load(args.drive, "codegen")
    fam = family_of(drive)
    table = read_gain_table(args.gains) if args.gains else None
    if table is not None and args.gain_set:
        raise UsageError("--gain-set and --gains exclude each other (the table holds the gains)")
    prefix = c_identifier(drive.name) if args.prefix is None else args.prefix
    try:
        check_prefix(prefix)
    except ValueError as e:
        if args.prefix is not None:
            raise UsageError(f"argument --prefix: {e}") from None
        # the default, from the drive's name: name that, and the option that overrides it
        raise DriveFileError(
            drive.file, "drive.name", f"the C prefix made of it, {e}; give --prefix"
        ) from None
    gains = fam.gains(drive, name=args.gain_set, table=table, table_file=args.gains or "")
    foreign = foreign_table(table, args.gains, drive) if table is not None else None
    if foreign:
        print(f"sensorless codegen: warning: {foreign}", file=sys.stderr)
    try:
        setup = fam.runtime(drive, gains, discretization=args.discretization)
    except (CapabilityError, DriveFileError, GainTableError):
        raise  # already one line naming the family, or the file and key (not the option)
    except ValueError as e:
        raise UsageError(f"argument --discretization: {e}" if args.discretization else str(e)) from None
    if args.startup:
        from sensorless.design.pmsm_drive import startup_setup

        setup, line = startup_setup(drive, setup)
        setup = dataclasses.replace(setup, notes=(*setup.notes, line)) if "no I-f" in line else setup
    # the drive's speed reference rate limiter ([control] speed_ramp): in the step, as the loop runs it
    setup = drive_ramp(drive, setup)
    fixed = args.precision == "fixed"
    values = _param_values(args.param, fixed)
    names = (*output_names(prefix), f"{prefix}_formats.json") if fixed else output_names(prefix)
    names = (*names, f"{prefix}_params.bin") if values else names
    known = [f.name for f in setup.observer.params]
    unknown = [k for k in values if k not in known]
    if unknown:  # before the C is generated
        raise UsageError(f"argument --param: unknown parameter {unknown[0]!r} (known: {', '.join(known)})")
    out = OutputSet(args.out, force=args.force, names=names)
    out.check()  # before the C is generated
    words: list[int] = []
    try:
        if fixed:
            from sensorless.reports.codegen.fixed_generate import fixed_model, generate_fixed
            from sensorless.reports.codegen.fixed_params import params_from_si

            prov = Provenance(drive.name, drive.file, drive.digest, f"sensorless {version()}")
            model = fixed_model(drive, gains, setup)
            files = generate_fixed(setup, model, prov, prefix)
            try:
                words = params_from_si(setup, model.program(setup), values) if values else []
            except ValueError as e:
                raise UsageError(f"argument --param: {str(e).removeprefix('params_from_si: ')}") from None
        else:
            files = generate(
                setup,
                Provenance(drive.name, drive.file, drive.digest, f"sensorless {version()}"),
                precision=args.precision,
                prefix=prefix,
            )
    except (ValueError, NotImplementedError) as e:
        raise UsageError(str(e)) from None
    for name, text in files.items():
        out.add_text(name, text)
    if values:
        out.add_bytes(f"{prefix}_params.bin", struct.pack(f"<{len(words)}i", *words))
    written = out.commit()
    print(f"{drive.name}: {setup.observer.title}")
    print(
        f"{setup.discretization} at T_s = {drive.T_s * 1e6:g} us, {args.precision}; "
        f"gains: {setup.gain_source}"
    )
    api = f"{prefix}_init, {prefix}_step" + (f", {prefix}_gains" if setup.schedule is not None else "")
    print(f"API: {api} ({prefix}.h)")
    for note in setup.notes:
        print(f"note: {note}")
    for p in written:
        print(f"wrote {p}")
    if fixed:
        print(f"formats: {prefix}_formats.json; Cortex-M0+ object: make -C {args.out} {prefix}-m0.o")
    if values:
        given = ", ".join(f"{k} = {v:g}" for k, v in values.items())
        print(f"params ({given}): const {prefix}_params prm = {{{', '.join(str(w) for w in words)}}};")
    else:
        print(f"build the example: make -C {args.out}; Cortex-M4F object: make -C {args.out} {prefix}-m4.o")
    return 0
