"""The ``sensorless`` entry point: the parser of every subcommand, one-line errors and exit statuses.

Exit statuses (docs/conventions.md):

- 0: done.
- 2: an error the user can fix (bad drive file, gain table or option value, missing file, output path
  that cannot be written, a capability the drive's observer family lacks): one line naming the file,
  key or option; nothing is written.
- 3: the computation ran but its result does not hold: not finite (nothing is written), or written
  with a warning line (a simulated drive that lost the rotor position, tuned gains below the damping
  a report requires).
- 130 (Ctrl-C) or 143 (SIGTERM): one line "interrupted"; nothing is written (reports/interrupts.py); a
  computation that does not stop within seconds is ended, with the processes it started.
- 3 also when a command's time budget runs out (``tune --time-limit``): one line; nothing is written.
- 141: standard output closed early (``| head``): quietly.
- 1: a bug (the traceback says where).
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import warnings
from collections.abc import Sequence
from typing import NoReturn

from sensorless.reports import interrupts

# Figures are files here, never windows: matplotlib, imported only by the commands that draw
# (reports/document.py ``pyplot``), starts on Agg without probing for a display.
os.environ.setdefault("MPLBACKEND", "Agg")

# numpy's and scipy's OpenBLAS in one thread unless the user says otherwise (read when numpy is first
# imported). Its matrices here are small (a drive's state has tens of entries), so its worker threads
# cost more than they save: they spin when numpy loads (0.07-0.1 s CPU per command, 4 commands in the
# README flow) and again whenever it is woken. A command's parallelism is its forked children (tune's
# proof, the figure renderers); with one BLAS thread it computes the bits the test suite and a Dask worker do.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

# The subcommands (each module's register(subparsers) sets ``func``); imported by main() once Ctrl-C
# is handled, since importing CasADi and the families takes a moment.
COMMAND_NAMES = ("init", "analyze", "tune", "simulate", "codegen", "export", "report", "montecarlo")
EXIT_USAGE, EXIT_RESULT, EXIT_PIPE = 2, 3, 141
# A command's young garbage collections: one per this many new container objects (Python's default:
# 700). A command allocates in bursts of objects that live on (a gain table's JSON, CasADi's wrappers,
# matplotlib's artists): at 700, a report made ~300 collections that walked them and freed little
# (0.06 s CPU); at this, ~10 (0.035 s).
YOUNG_COLLECTION = 20_000


def user_errors() -> tuple[type[BaseException], ...]:
    """The errors a user can cause: one line, exit status 2."""
    from sensorless.design.family import CapabilityError
    from sensorless.design.gain_table import GainTableError
    from sensorless.design.simulate import SimulationError
    from sensorless.design.units import DriveFileError, UnknownName
    from sensorless.reports.cli.common import UsageError
    from sensorless.reports.files import OutputError
    from sensorless.tuning.family import TuningError

    return (
        DriveFileError,
        FileNotFoundError,
        OutputError,
        UsageError,
        GainTableError,
        CapabilityError,
        TuningError,
        SimulationError,
        UnknownName,
    )


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors: 'sensorless analyze: error: argument --points: ...'."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser(only: str = "") -> argparse.ArgumentParser:
    """The argument parser with every subcommand registered; ``only``: that subcommand alone (main()
    where the command line names one: registering a subcommand imports what it computes with, and the
    other seven's imports cost a command ~0.1-0.5 s CPU, each of the README flow's four)."""
    import importlib

    from sensorless.reports.cli.common import version

    parser = Parser(
        prog="sensorless",
        description="Design, analyse, tune and code-generate observers for sensorless PM drives.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in (only,) if only in COMMAND_NAMES else COMMAND_NAMES:
        importlib.import_module(f"sensorless.reports.cli.{name}").register(sub)
    return parser


def _quiet_stdout() -> None:
    """After a broken pipe: send what is left of stdout to /dev/null (no second error at exit)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout is not a real file (e.g. captured by a test)
        pass


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sensorless`` script; returns the exit status (module docstring).

    ``argv`` None: the script's own arguments; the process exits next, so a Ctrl-C that arrives after
    the work is done is ignored rather than killing it on the way out, and a signal the computation
    swallows ends the process (the watchdog, reports/interrupts.py). ``argv`` given: a caller's run in
    its own process (a test), which the watchdog never ends."""
    words = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("-")]
    # the garbage collector's generations are this run's to arrange unless a caller froze objects itself
    ours = argv is None or gc.get_freeze_count() == 0
    threshold = gc.get_threshold()
    if ours:  # from here: the command's imports are its first burst
        gc.set_threshold(YOUNG_COLLECTION, *threshold[1:])
    command = words[0] if words and words[0] in COMMAND_NAMES else ""
    try:
        with interrupts.handled(f"sensorless {command}".strip(), watchdog=argv is None):
            try:
                args = (build_parser(command) if command else build_parser()).parse_args(argv)
                _refuse_empty(args)
                if ours:
                    # what the imports built (~100 000 objects) lives as long as the process: out of the
                    # collector's full passes, each of which walked all of it (0.03-0.05 s a report)
                    gc.freeze()
                with warnings.catch_warnings():
                    # numpy's warnings on NaN or overflow name no input and would leak to stderr: the
                    # commands check what they write and say why a number is not finite
                    warnings.simplefilter("ignore", RuntimeWarning)
                    code = int(args.func(args) or 0)
                interrupts.check()  # an interrupt the computation swallowed (CasADi may)
                sys.stdout.flush()  # a closed pipe shows here, not at exit
                return code
            except BaseException as e:
                return _exit_status(e, f"sensorless {command}".strip())
    finally:
        if argv is None:
            interrupts.ignore()
            # the process exits next, freeing everything with it: the collections at the interpreter's
            # exit would only walk the whole heap (after a report: 0.17 -> 0.02 s CPU from atexit to the end)
            gc.freeze()
        elif ours:  # a caller's process goes on: its garbage is collectable as before
            gc.unfreeze()
            gc.set_threshold(*threshold)


def _refuse_empty(args: argparse.Namespace) -> None:
    """UsageError for an option given as an empty string (``--out ""``, ``--prefix ""``): a command
    must not fall back to its default for a value the user did give."""
    from sensorless.reports.cli.common import UsageError

    for dest, v in vars(args).items():
        if isinstance(v, str) and not v.strip():
            name = "PRESET_OR_TOML" if dest == "drive" else "--" + dest.replace("_", "-")
            raise UsageError(f"argument {name}: empty; give a value or leave the option out")


def _exit_status(e: BaseException, prefix: str) -> int:
    """The exit status of a run that ended with ``e``, after its one line on stderr."""
    signum = interrupts.received()
    if signum is not None:  # whatever the exception: CasADi turns Ctrl-C into its own errors
        interrupts.reset()
        text, code = interrupts.line(signum)
        print(text, file=sys.stderr)
        return code
    if isinstance(e, SystemExit):
        raise e
    if isinstance(e, BrokenPipeError):
        _quiet_stdout()
        return EXIT_PIPE
    from sensorless.reports.cli.common import ResultError

    if isinstance(e, ResultError):
        print(f"{prefix}: error: {e}", file=sys.stderr)
        return EXIT_RESULT
    if isinstance(e, user_errors()):
        msg = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
        print(f"{prefix}: error: {msg}", file=sys.stderr)
        return EXIT_USAGE
    raise e


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
