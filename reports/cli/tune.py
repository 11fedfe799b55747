"""``sensorless tune``: tuned observer gains over an operating envelope, written as gain tables.

The drive's observer family offers tunable gain laws (tuning/family.py; ``--law``, default its
first on a built-in preset, the family's best on a drive of the user's own); envelope and constraints
come from the drive file and the family's options (reports/family.py).
Progress goes to stderr; the summary (with the pointwise bound on a line of its own) and the written
files to stdout: ``gains_<law>.json``/``.csv``, ``speeds_<law>.csv`` (the bound beside the
law, its seed and the drive file's gains at every dense speed) when the tuner computed the bound,
``pareto_<law>.csv`` with ``--pareto``. If the tuner fails or the constraints cannot be met, one line
says so (for an infeasible envelope, with its evidence) and the exit status is 2; nothing is written. If
the best gains found are still below the damping a report requires by default (common.MIN_DAMPING; the
one ``--min-damping`` requires where the drive's family takes it), or
their worst damping is not finite, the tables are written (they are the result) with a warning line, and
the exit status is 3; a tuner whose outcome judges by a criterion of its family's own
(``TuneOutcome.shortfalls``) says what its gains miss instead, one warning line each (exit 3).

Before anything is written the table is proved (reports/tune_proof.py): its gains and the drive file's
over the drive's real range (+-T_max) by the linear analysis and on the report's time-domain checks. A
table that runs worse than the drive file's gains is not written as tuned: the tuner's fallback (a
seeded law: its seed's optimum in this law's parameters) is proved next, and if none holds the command
says which point and which check, writes nothing and exits 3. ``--unchecked`` skips the proof.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import importlib
import math
import os
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

from sensorless.design import forked
from sensorless.design.envelope import TuningSettings
from sensorless.design.family import CapabilityError, Drive
from sensorless.design.registry import families, family_of
from sensorless.reports import interrupts
from sensorless.reports.cli import many
from sensorless.reports.cli.common import MIN_DAMPING, Number, UsageError, load
from sensorless.reports.family import add_family_options, hooks, refuse_foreign
from sensorless.reports.files import OutputSet
from sensorless.reports.gain_csv import pareto_csv, speeds_csv, table_csv
from sensorless.reports.low_speed import tune_line
from sensorless.tuning.family import TuningError, all_tunables, estimate_errors, tunable_for

if TYPE_CHECKING:  # typed by name only
    from collections.abc import Callable

    from sensorless.design.family import EstimateErrors, GainSet
    from sensorless.reports.tune_proof import Proof
    from sensorless.tuning.family import Tunable, TuneOutcome, TuneSettings

UNCHECKED_ENV = "SENSORLESS_TUNE_UNCHECKED"  # set: --unchecked by default (the test suite's other tests)


class _OldFlag(argparse.Action):
    """``--family``, the former name of ``--law``: works, and says its new name (for one release)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[str] | None,
        option_string: str | None = None,
    ) -> None:
        print("sensorless tune: note: --family is now called --law", file=sys.stderr)
        setattr(namespace, self.dest, values)


# The default time budget [s] of one drive's tuning: twice the slowest tune of the example motors on a
# loaded machine (~400 s); a drive with implausible data (J in kg m2 for kg cm2) ran on for hours
TIME_LIMIT = 900.0


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``tune`` subcommand."""
    laws = all_tunables()
    old = {o: n for fam in families() for o, n in fam.law_aliases.items()}
    p = sub.add_parser(
        "tune",
        help="optimal observer gains over an operating envelope (gain tables CSV + JSON)",
        description="Tune a gain law of the drive's observer over an envelope of operating points, "
        "re-verify on a denser grid, and write the gain table. Laws: "
        + "; ".join(f"{k}: {v}" for k, v in laws.items()),
    )
    p.add_argument(
        "drive",
        metavar="PRESET_OR_TOML",
        help="built-in preset name or drive TOML file; or a directory or a quoted glob of drive files: "
        "each drive run on Dask into --out DIR/<drive name>/, with DIR/summary.csv",
    )
    p.add_argument(
        "--law",
        default=None,
        choices=[*laws, *old],
        metavar="{" + ",".join(laws) + "}",
        help="gain law to tune (default: on a built-in preset the first of its observer family, the "
        "paper's law; on a drive file of your own the best the family declares); former names, "
        "accepted for one release: " + ", ".join(f"{o} = {n}" for o, n in old.items()),
    )
    p.add_argument(
        "--family",
        dest="law",
        action=_OldFlag,
        choices=[*laws, *old],
        metavar="LAW",
        help="former name of --law, accepted for one release",
    )
    p.add_argument("--out", default=None, help="output directory (default: tune-<drive name>)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument(
        "--unchecked",
        action="store_true",
        default=bool(os.environ.get(UNCHECKED_ENV)),
        help="write the table without its proof (the linear analysis over +-T_max and the report's "
        "time-domain checks against the drive file's gains: reports/tune_proof.py); default: checked, "
        f"unless ${UNCHECKED_ENV} is set",
    )
    p.add_argument(
        "--time-limit",
        type=Number(0, 1e6, unit="s"),
        default=TIME_LIMIT,
        metavar="SECONDS",
        help=f"give up after this many seconds of wall time, writing nothing (default {TIME_LIMIT:g}; 0: "
        "none): a drive with implausible data can make the tuning run far longer than usual",
    )
    add_family_options(p, "tune")
    many.add_engine_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Tune, print the summary, write the tables."""
    from sensorless.tuning.tune import tune

    files = many.drive_files(args.drive)
    if files is not None:
        return many.run("tune", args, files)
    many.refuse_engine_options(args)
    drive = load(args.drive, "tune")
    fam = family_of(drive)
    h = hooks(fam)
    law = args.law
    if law in fam.law_aliases:
        print(f"sensorless tune: note: law {law!r} is now called {fam.law_aliases[law]!r}", file=sys.stderr)
        law = fam.law_aliases[law]
    tunable = tunable_for(drive, law)
    refuse_foreign(args, fam, "tune")
    own = h.tune_settings
    settings = own(drive, args, tunable) if own is not None else tunable.settings(drive)
    json_name, csv_name = f"gains_{tunable.name}.json", f"gains_{tunable.name}.csv"
    speeds_name, pareto_name = f"speeds_{tunable.name}.csv", f"pareto_{tunable.name}.csv"
    names = [json_name, csv_name]
    if settings.bound:
        names.append(speeds_name)
    if settings.pareto:
        names.append(pareto_name)
    out = OutputSet(args.out or f"tune-{drive.name}", force=args.force, names=names)
    out.check()  # refuse unwritable or existing outputs before the work
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    print(f"{drive.name}: {drive.source}")
    print(f"law {tunable.name}: {tunable.description}")
    if h.describe_envelope is not None:
        print(h.describe_envelope(drive, settings))
    limit = getattr(args, "time_limit", None)  # a many-drive task's namespace may predate the option
    note = (
        f"the tuning did not end within {limit:g} s (--time-limit); nothing written. A drive whose data "
        "are implausible (the warnings above, e.g. J's unit) can make it run far longer than usual: check "
        "them, or raise --time-limit"
    )
    base = None
    if not args.unchecked:
        # the drive file's gains proved first: where they fail a check in the I-f start (whose remedy is
        # a lower handover, i.e. gains tuned for a lower w_min), their figures bound nothing
        # (TuningSettings.hold_bounded: servo400's speed steps); the proof still holds the tuned gains
        # to every check they pass. A failure of the observer's own (piippo2008's fig6a, without
        # injection at 0.01 p.u.) keeps them: the lag-held schedule passes it there. The proof runs in
        # a child process while the tuning starts as if they passed (they mostly do): where they fail in
        # the start, the tuning stops at its next progress line and starts again without the bound.
        pending = _drive_file_proof(drive, progress)
    early = None
    try:
        with interrupts.budget(limit, note):
            if args.unchecked:
                r = tune(drive, tunable.name, settings, progress=progress)
            else:
                base, settings, r, early = _tuned_beside_the_proof(
                    drive, tunable.name, settings, pending, json_name, progress
                )
    except (TuningError, CapabilityError) as e:
        raise UsageError(str(e)) from None
    proof: list[str] = []
    outputs = (json_name, csv_name, speeds_name, pareto_name)
    ready = None  # (a result, its files' texts), prepared while its proof runs
    after = None  # the lines after the proof (_after), where the child that proved the kept result gave them
    if base is not None:
        if early is None or early[0] is not r:
            early = _proving(drive, r, json_name, estimate_errors(drive, tunable, settings), pending[1])
        ready = (r, _texts(tunable, r, outputs))  # while a child proves r
        kept, proof, after = _proved(drive, r, settings, json_name, base, progress, early)
        pending[1].close()
        if kept is None:
            print("\n".join(r.summary_lines(drive)))
            print("\n".join(proof))
            print(
                f"sensorless tune: error: no table written: the tuned gains run worse than the drive file's "
                f"({proof[-1].partition(': ')[2]})",
                file=sys.stderr,
            )
            return 3
        r = kept
    print("\n".join(r.summary_lines(drive)))
    if proof:
        print("\n".join(proof))
    if after is None:
        tuned = fam.gains(drive, table=r.table, table_file=json_name)
        after = _after(drive, tuned, estimate_errors(drive, tunable, settings))
    texts = ready[1] if ready is not None and ready[0] is r else _texts(tunable, r, outputs)
    for line in after:
        print(line)
    for name, text in texts.items():
        out.add_text(name, text)
    for p in out.commit():
        print(f"wrote {p}")
    own = getattr(r, "shortfalls", None)
    if own is not None:  # the family's own criterion (tuning/family.py TuneOutcome.shortfalls)
        missed = own(drive)
        for line in missed:
            print(f"sensorless tune: warning: {line}", file=sys.stderr)
        return 3 if missed else 0
    worst = r.table.summary.get("worst_damping")
    # the damping the user requires where the family takes --min-damping, else the report's default
    need = MIN_DAMPING if getattr(args, "min_damping", None) is None else float(args.min_damping)
    if not isinstance(worst, int | float) or not math.isfinite(worst) or worst < need:
        shown = f"{worst:.4g}" if isinstance(worst, int | float) else "not finite"
        print(
            f"sensorless tune: warning: the tuned gains' worst damping ({shown}) is below {need:g}, "
            + (
                "the damping `sensorless report` requires by default"
                if need == MIN_DAMPING
                else "the damping --min-damping requires"
            )
            + ": poorly damped somewhere in the envelope (narrow the envelope or relax its constraints)",
            file=sys.stderr,
        )
        return 3
    return 0


def _after(drive: Drive, gains: GainSet, errors: EstimateErrors) -> list[str]:
    """The lines printed after the summary and the proof: the tuned ``gains``' low-speed line (under
    ``errors``, the tune run's estimate errors) and the I-f start's."""
    fam = family_of(drive)
    h = hooks(fam)
    low = tune_line(drive, gains, fam.min_damping(), errors)
    return ([low] if low else []) + (
        list(h.startup_lines(drive, gains)) if h.startup_lines is not None else []
    )


def _texts(tunable: Tunable, r: TuneOutcome, names: tuple[str, str, str, str]) -> dict[str, str]:
    """The texts of the files written for the result ``r``; ``names``: the files' (JSON, CSV, speeds,
    pareto)."""
    json_name, csv_name, speeds_name, pareto_name = names
    texts = {json_name: r.table.to_json(), csv_name: table_csv(r.table, tunable.columns)}
    if "speeds" in r.table.summary:
        texts[speeds_name] = speeds_csv(r.table)
    if "pareto" in r.table.summary:
        texts[pareto_name] = pareto_csv(r.table)
    return texts


def _drive_file_proof(drive: Drive, progress: Callable[[str], None]) -> tuple[list, Prover]:
    """(the proof's time-domain runs, the drive file's gains' proof) (reports/tune_proof.py), the proof
    computed by a child process (design/forked.py) while this one tunes; the child stays for the tuned
    gains' proof and the lines printed after it (:func:`_proving`, :func:`_after`), which reuse what the
    first one built (its simulations' set-up, the whole drive's linearization and the I-f start's: 0.2 s
    CPU instead of 1.0 s for the proof on the README servo)."""
    from sensorless.design import memo
    from sensorless.reports import tune_proof

    # what the child and this process both compute, done once before it forks: the disk memo's
    # fingerprint, and numpy.ma, which np.unique imports at its first call (numpy 2.4: 15-30 ms CPU)
    memo.before_fork()
    importlib.import_module("numpy.ma")
    runs = tune_proof.runs(drive)
    progress(f"proof: the drive file's and the tuned gains, {len(runs)} time-domain checks, +-T_max")
    prove = functools.partial(tune_proof.prove, drive, scenarios=runs, analysis=tune_proof.ANALYSIS)
    first = functools.partial(prove, None, "drive file", progress=progress)
    return runs, forked.later(
        first, stderr=True, then=lambda q: (prove(q[0], "tuned", progress=progress), _after(drive, *q))
    )


class _Unbound(Exception):
    """The drive file's gains fail a check in the I-f start: the tuning, started before that was known,
    stops."""


# the drive file's proof's child, which stays for the tuned gains' proof and the lines after it (_after)
Prover = forked.Pending["Proof", tuple["Proof", list[str]]]
# a result and the function that gives its proof and the lines printed after it (:func:`_after`), started
# while this process tunes on or prepares what it writes
Early = tuple["TuneOutcome", "Callable[[], tuple[Proof, list[str]]]"]


def _proving(drive: Drive, r: TuneOutcome, table_file: str, errors: EstimateErrors, prover: Prover) -> Early:
    """(r, the function that gives the proof of its gains and the lines after it): asked of the drive
    file's proof's child (:func:`_drive_file_proof`), while this process tunes on or prepares what it
    writes."""
    g = family_of(drive).gains(drive, table=r.table, table_file=table_file)
    return r, prover.ask((g, errors))


def _tuned_beside_the_proof(
    drive: Drive,
    law: str,
    settings: TuneSettings,
    proof: tuple[list, Prover],
    table_file: str,
    progress: Callable[[str], None],
) -> tuple[tuple[list, Proof], TuneSettings, TuneOutcome, Early | None]:
    """(the drive file's proof, the settings, the tuned result, the early proof of its gains if any): the
    tuning with the settings the drive file's proof gives (``hold_bounded`` False where its gains fail a
    check in the I-f start), run while the proof is computed (``proof``: :func:`_drive_file_proof`) under
    the settings as given; where the proof, once there, asks for other settings, the tuning stops at its
    next progress line and runs again with them: the result is the sequential one. Where the tuning runs
    again with the handover's floor, a child proves the first tuning's gains meanwhile (the result unless
    the second tuning finds gains)."""
    from sensorless.reports import tune_proof
    from sensorless.tuning.tune import tune

    runs, pending = proof
    tunable = tunable_for(drive, law)

    def unbound(base: Proof) -> list[str]:
        failed = tune_proof.failed_in_the_start(base)
        return failed if failed and isinstance(settings, TuningSettings) and settings.hold_bounded else []

    known: list[Proof] = []  # the drive file's proof, once collected
    early: list[Early] = []

    def watched(msg: str) -> None:
        progress(msg)
        if not known and pending.forked and pending.done():
            known.append(pending.result())
            if unbound(known[0]):
                raise _Unbound

    def retuning(first: TuneOutcome) -> None:
        early.append(_proving(drive, first, table_file, estimate_errors(drive, tunable, settings), pending))

    if not pending.forked:  # no child: the proof first, as it decides the settings
        known.append(pending.result())
    r = None
    if not (known and unbound(known[0])):
        try:
            r = tune(drive, law, settings, progress=watched, retuning=retuning)
        except _Unbound:
            early.clear()  # (their replies, if any, are not read)
    base = known[0] if known else pending.result()
    failed = unbound(base)
    if failed:
        assert isinstance(settings, TuningSettings)  # (unbound says so)
        settings = dataclasses.replace(settings, hold_bounded=False)
        progress(
            f"the drive file's gains fail {', '.join(failed)} in the I-f start: the tuning does not "
            "hold their figures"
        )
        r = tune(drive, law, settings, progress=progress, retuning=retuning)
    assert r is not None
    kept = next(((res, p) for res, p in early if res is r), None)
    return (runs, base), settings, r, kept


def _proved(
    drive: Drive,
    r: TuneOutcome,
    settings: TuneSettings,
    table_file: str,
    proved: tuple[list, Proof],
    progress: Callable[[str], None],
    early: Early | None = None,
) -> tuple[TuneOutcome | None, list[str], list[str] | None]:
    """(the result whose table is written, lines saying its proof, the lines after it if ``early``
    gave them) or (None, lines ending with what the last candidate does worse, None): the tuned gains and
    then the tuner's fallbacks (tuning/tune.py), each against the drive file's gains (``proved``: the
    drive file's proof; reports/tune_proof.py). ``early``: the tuned gains' proof, already started
    (:func:`_proving`)."""
    from sensorless.reports import tune_proof
    from sensorless.tuning.tune import fallbacks

    fam = family_of(drive)
    runs, base = proved
    lines = [f"proof (linear analysis over +-T_max, {len(runs)} time-domain checks): {base.line()}"]
    cands: list[tuple[str, TuneOutcome]] = [("tuned", r)]
    i = 0
    while i < len(cands):
        label, res = cands[i]
        g = fam.gains(drive, table=res.table, table_file=table_file)
        after = None
        if i == 0 and early is not None and early[0] is res:
            p, after = early[1]()
        else:
            p = tune_proof.prove(drive, g, label, runs, tune_proof.ANALYSIS, progress, beside=True)
        lines.append(f"proof: {p.line()}")
        bad = tune_proof.worse(p, base, drive.w_base)
        if not bad:
            if i:
                lines.append(f"proof: kept {label} (the tuned gains ran worse than the drive file's)")
            return res, lines, after
        lines.append(f"proof: {label} worse than the drive file's gains: " + "; ".join(bad))
        if i == 0:
            cands += fallbacks(drive, r, settings)
        i += 1
    return None, lines, None
