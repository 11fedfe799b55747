"""Report hooks of the observer families: their command-line options, analysis output and report sections.

An observer family names the module of its report hooks (``ObserverFamily.report``); that module
defines ``HOOKS``, a :class:`ReportHooks`. The shared commands (reports/cli/) reach a family only
through it and through the family record: ``analyze`` asks it to analyse and stage its files,
``tune`` to turn its command-line options into a tunable's settings, ``simulate`` to apply its
options to a scenario, ``report`` for the report's
content (data and sections, reports/document.py), which the shared renderer turns into HTML.

Options are data (:class:`Option`), declared per family and registered once per flag by the CLI; a
flag that the drive's family does not declare is refused with one line, never silently ignored.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Generic

from sensorless.design.family import CapabilityError, DriveT, ObserverFamily
from sensorless.design.registry import families
from sensorless.reports.options import COUNT, FINITE

if TYPE_CHECKING:  # typed by name only: a command reads the hooks' options without these modules
    from sensorless.design.family import GainSet
    from sensorless.design.scenario import Scenario
    from sensorless.reports.causes import Failure, Named
    from sensorless.reports.document import Report
    from sensorless.reports.files import OutputSet
    from sensorless.tuning.family import Tunable, TuneSettings


@dataclass(frozen=True)
class Option:
    """A command-line option: its flags and the argparse keywords (``default`` is always None, so a
    command can tell a value the user gave from none; the family applies its own default)."""

    flags: tuple[str, ...]
    kwargs: dict[str, Any] = field(default_factory=dict)

    @property
    def dest(self) -> str:
        """The attribute name on the parsed arguments."""
        return self.flags[0].lstrip("-").replace("-", "_")


@dataclass(frozen=True)
class Importer:
    """A firmware configuration format that ``sensorless init --from NAME FILE`` reads into a minimal
    drive file of the declaring family: ``read(text, file, given)`` -> (drive-file TOML, notes), where
    ``given`` maps the dest of each of its ``options`` that was given to its value; a bad file is a
    DriveFileError naming the file and the field; the notes (missing values, assumptions, which of two
    redundant values was used) go to stderr."""

    title: str  # e.g. the firmware tool's name for the file
    read: Callable[[str, str, Mapping[str, Any]], tuple[str, Sequence[str]]]
    options: tuple[Option, ...] = ()


@dataclass(frozen=True)
class Exporter(Generic[DriveT]):
    """A firmware's configuration written by ``sensorless export --target NAME``: ``export(drive,
    gains)`` -> ({file name: text}, notes), the names among ``files``; a DriveFileError (one line naming
    the gain or drive key) where the gains break the firmware's own limits."""

    title: str
    files: tuple[str, ...]
    export: Callable[[DriveT, GainSet], tuple[Mapping[str, str], Sequence[str]]]


@dataclass(frozen=True)
class ReportHooks(Generic[DriveT]):
    """What a family contributes to the commands (each callable is optional), generic in its drive type
    (its callables take its own drive)."""

    # sensorless analyze: options, and (drive, args, out: OutputSet) -> None (prints, stages files);
    # analyze_check (drive, args) -> None checks the options against the drive before anything is
    # computed or written (one-line errors; analyze may then trust them)
    analyze_options: tuple[Option, ...] = ()
    analyze: Callable[[DriveT, argparse.Namespace, OutputSet], None] | None = None
    analyze_check: Callable[[DriveT, argparse.Namespace], None] | None = None
    # sensorless tune: options, (drive, args, tunable) -> settings, (drive, settings) -> one line
    tune_options: tuple[Option, ...] = ()
    tune_settings: Callable[[DriveT, argparse.Namespace, Tunable[DriveT]], TuneSettings] | None = None
    describe_envelope: Callable[[DriveT, Any], str] | None = None  # (drive, the tunable's own settings)
    # (drive, tuned gains) -> the lines tune says of the drive's start-up at the tuned gains (the values
    # it proposes, the drive file's kept where they hold, each change with why)
    startup_lines: Callable[[DriveT, GainSet], list[str]] | None = None
    # sensorless simulate: options, and (drive, args, scenario) -> the scenario with them applied
    # (one-line errors naming the option or the drive file)
    simulate_options: tuple[Option, ...] = ()
    simulate_scenario: Callable[[DriveT, argparse.Namespace, Scenario], Scenario] | None = None
    # sensorless report: (drive, table or None, table file, min_damping, resolution, progress) -> Report
    report: Callable[..., Report] | None = None
    # the cause of a failed time-domain check in the family's own analysis (reports/causes.py): (drive,
    # the gains under review, the failure with its evidence) -> a Named catalogue id, or None where the
    # shared rules judge (a PLL's root, an HF injection's coupling band: causes shared code cannot name)
    failure_cause: Callable[[DriveT, GainSet, Failure], Named | None] | None = None
    # drive sections that hold settings of other commands, not drive data: left out of the report's
    # drive-data tables (reports/review.py opening)
    settings_sections: tuple[str, ...] = ()
    # sensorless init (of a minimal drive file): options, and (data, args, file) -> the file's data with
    # them applied (e.g. which variant of its observer the file is for; one-line errors naming the
    # option or the file's key)
    init_options: tuple[Option, ...] = ()
    init_data: Callable[[Mapping[str, Any], argparse.Namespace, str], Mapping[str, Any]] | None = None
    # sensorless init --from NAME FILE and sensorless export --target NAME: firmware formats by name
    importers: Mapping[str, Importer] = field(default_factory=dict)
    exporters: Mapping[str, Exporter[DriveT]] = field(default_factory=dict)


def hooks(family: ObserverFamily[DriveT]) -> ReportHooks[DriveT]:
    """The report hooks of ``family`` (empty hooks if it names none)."""
    if family.report is None:
        return ReportHooks()
    h = getattr(importlib.import_module(family.report), "HOOKS", None)
    if not isinstance(h, ReportHooks):
        raise CapabilityError(f"{family.report} defines no ReportHooks HOOKS")
    return h


def all_options(command: str) -> dict[str, tuple[Option, list[str]]]:
    """Every family's options of command ``command`` ("analyze", "tune", "simulate" or "init"): dest ->
    (option, families)."""
    out: dict[str, tuple[Option, list[str]]] = {}
    for fam in families():
        for opt in getattr(hooks(fam), f"{command}_options"):
            if opt.dest in out:
                out[opt.dest][1].append(fam.name)
            else:
                out[opt.dest] = (opt, [fam.name])
    return out


def add_family_options(parser: argparse.ArgumentParser, command: str) -> None:
    """Register every family's options of command ``command``, each flag once, under one group.

    A numeric option declared with a bare ``float`` or ``int`` is parsed by the shared checked number
    (reports/options.py: finite, of a magnitude drive files accept); families state ranges with
    ``options.Number`` themselves."""
    add_options(parser, all_options(command), "options of some observer families (refused by the others)")


def add_options(
    parser: argparse.ArgumentParser,
    options: Mapping[str, tuple[Option, list[str]]],
    title: str,
    tag: str = "",
) -> None:
    """Register ``options`` (dest -> (option, its owners)) under one group ``title``, each help ending
    with its owners (after ``tag``); bare ``float`` and ``int`` types become the shared checked numbers."""
    group = parser.add_argument_group(title)
    for opt, owners in options.values():
        kw = {**opt.kwargs, "default": None}
        kw["type"] = {float: FINITE, int: COUNT}.get(kw.get("type"), kw.get("type"))
        if kw["type"] is None:
            del kw["type"]
        kw["help"] = f"{kw.get('help', '')} [{tag}{', '.join(owners)}]".strip()
        group.add_argument(*opt.flags, **kw)


def refuse_foreign(args: argparse.Namespace, family: ObserverFamily, command: str) -> None:
    """CapabilityError naming the first option given that ``family`` does not declare for ``command``."""
    mine = {o.dest for o in getattr(hooks(family), f"{command}_options")}
    for dest, (opt, fams) in all_options(command).items():
        if dest not in mine and getattr(args, dest, None) not in (None, False):
            raise CapabilityError(
                f"{opt.flags[0]}: not an option for {family.title} drives (kind '{family.kind}'); "
                f"it applies to: {', '.join(fams)}"
            )


def importers() -> dict[str, list[tuple[ObserverFamily, Importer]]]:
    """Every family's firmware importers by name (``sensorless init --from``), with their families."""
    out: dict[str, list[tuple[ObserverFamily, Importer]]] = {}
    for fam in families():
        for name, imp in hooks(fam).importers.items():
            out.setdefault(name, []).append((fam, imp))
    return out


def import_options() -> dict[str, tuple[Option, list[str]]]:
    """Every importer's options: dest -> (option, the firmware names that declare it)."""
    out: dict[str, tuple[Option, list[str]]] = {}
    for name, found in sorted(importers().items()):
        for _, imp in found:
            for opt in imp.options:
                out.setdefault(opt.dest, (opt, []))[1].append(name)
    return out


def exporter_names() -> list[str]:
    """The firmware names any family exports to (``sensorless export --target``)."""
    return sorted({name for fam in families() for name in hooks(fam).exporters})
