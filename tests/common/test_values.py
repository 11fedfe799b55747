"""Every number a user gives is checked for finiteness and range before use, with one line naming it.

Two matrices, both enumerated from the code rather than listed here, so that a new option, preset or
scenario key is covered without editing this file:

- every option that takes a value, of every command, read from the parsers themselves (the families'
  options included, the test-tree family's too), gets NaN, +-Inf, +-1e300, 0 and a negative value:
  the command either refuses with one line (exit status 2) or gets as far as computing, which the
  test stops at the output check (``OutputSet.check`` comes after every option is checked);
- every number of every preset drive file and built-in scenario of every family is replaced by values
  that parse to infinity or NaN, or are far out of range (1e300, 1e-300): loading fails with an error
  naming the file and that key.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import re
import tomllib
from importlib import resources
from pathlib import Path

import pytest
from families.pll.design import FAMILY as PLL
from sensorless.design.drive import load_drive, load_drive_text
from sensorless.design.registry import families, kinds, registered
from sensorless.design.scenario import drive_units, load_scenario_text
from sensorless.design.units import DriveFileError
from sensorless.reports.cli import main as cli
from sensorless.reports.cli.common import Number
from sensorless.reports.family import all_options
from sensorless.reports.files import OutputFile, OutputSet

PLL_DRIVE = str(Path(__file__).resolve().parents[1] / "families" / "pll" / "presets" / "pll_servo.toml")
BAD = ("nan", "inf", "-inf", "1e300", "-1e300", "0", "-1")
FAMILY_KINDS = ("analyze", "tune")  # commands with family options (reports/family.py)
# a command's own options run on a preset of every registered family (the registry's, not a list here)
BUILT_IN = tuple(f.name for f in families() if f.presets is not None)


class Reached(Exception):
    """The command got past every check, to its first computation."""


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def _value_options(sub: argparse.ArgumentParser) -> list[argparse.Action]:
    """The options of a subcommand that take a value (flags with nargs != 0), from the parser."""
    return [a for a in sub._actions if a.option_strings and a.nargs != 0 and a.dest != "help"]


@contextlib.contextmanager
def _with_pll():
    """The test-tree family registered (unless it already is: a nested registration would end it)."""
    if PLL.kind in kinds():
        yield
    else:
        with registered(PLL):
            yield


def _cases():
    """(command, option flag, drive) for every value-taking option of every command; a family's
    option is run against a drive of each family that declares it, a command's own option against
    the built-in presets."""
    with _with_pll():
        parser = cli.build_parser()
        drives = {f.name: _a_drive(f) for f in families()}
        out = []
        for command, sub in _subparsers(parser).items():
            declared = (
                {d: fams for d, (_, fams) in all_options(command).items()} if command in FAMILY_KINDS else {}
            )
            for action in _value_options(sub):
                flag = action.option_strings[0]
                for fam in declared.get(action.dest) or BUILT_IN:
                    out.append(pytest.param(command, flag, drives[fam], id=f"{command}{flag}-{fam}"))
        return out


def _a_drive(fam) -> str:
    if fam is PLL:
        return PLL_DRIVE
    # the first preset (in name order) that loads without plausibility warnings, so that an option's
    # error is the one line on stderr (a preset that warns, e.g. a motor with L/R of a few sampling
    # periods, prints its warning line before any option is checked)
    names = sorted(p.name[:-5] for p in resources.files(fam.presets).iterdir() if p.name.endswith(".toml"))
    return next((n for n in names if not load_drive(n).warnings), names[0])


REQUIRED = {  # what each command needs besides the option under test (built-in scenarios by family)
    "simulate": lambda drive: ["--scenario", _scenario(drive), "--quiet"],
    "tune": lambda drive: ["--quiet"],
    "report": lambda drive: ["--quick"],
    "export": lambda drive: ["--target", "any"],  # the output check comes before the target's capability
}


@functools.cache
def _scenario(drive: str) -> str:
    from sensorless.design.scenario import builtin_names

    return builtin_names(load_drive(drive).kind)[0]


@pytest.fixture(scope="module", autouse=True)
def pll_registered():
    """The test-tree family registered; the command line's parser built once and each preset loaded
    once for the whole matrix (main() builds its parser on every call, and each command loads its
    drive: ~90 % of a call's time here; neither is what this file checks, and both stay as they are
    for the whole module: the registry does not change in it)."""
    import sensorless.design.drive as drive_module

    with _with_pll(), pytest.MonkeyPatch.context() as mp:
        parser = cli.build_parser()
        mp.setattr(cli, "build_parser", lambda only="": parser)
        mp.setattr(drive_module, "load_drive", functools.cache(drive_module.load_drive))
        yield


@pytest.fixture
def stop_at_output_check(monkeypatch):
    """Stop a command where it would start computing: right after its (real) output check."""
    for cls in (OutputSet, OutputFile):
        real = cls.check

        def check(self, real=real):
            real(self)
            raise Reached

        monkeypatch.setattr(cls, "check", check)


@pytest.mark.parametrize(("command", "flag", "drive"), _cases())
def test_every_option_takes_bad_numbers_without_traceback(
    command, flag, drive, tmp_path, capsys, stop_at_output_check
):
    parser = cli.build_parser()
    action = next(a for a in _subparsers(parser)[command]._actions if flag in a.option_strings)
    numeric = isinstance(action.type, Number)
    for value in BAD:
        out = tmp_path / f"o{BAD.index(value)}"
        extra = [] if flag == "--out" else ["--out", str(out)]
        argv = [command, drive, *REQUIRED.get(command, lambda d: [])(drive), *extra, f"{flag}={value}"]
        try:
            code = cli.main(argv)
        except SystemExit as e:  # argparse refuses the value
            code = e.code
        except Reached:  # accepted: every check passed and the command is about to compute
            code = None
        err = capsys.readouterr().err
        if code is None:
            assert not (numeric and value in ("nan", "inf", "-inf", "1e300", "-1e300")), (argv, "accepted")
            continue
        assert code == 2, (argv, code, err)
        assert err.count("\n") == 1 and "Traceback" not in err, (argv, err)
        assert err.startswith(f"sensorless {command}: error: "), (argv, err)
        assert flag in err or value in err, (argv, err)  # names the option (or the file it names)
        if numeric:
            assert flag in err, (argv, err)
        assert not out.exists(), argv


def test_the_matrix_covers_every_family_option_and_the_commands_own():
    """The cases come from the parsers: each family's declared options are among them, and a
    numeric option of each command is typed (so the matrix checks its range, not only 'no traceback')."""
    ids = {c.id for c in _cases()}
    for command in ("analyze", "tune"):
        for opt, fams in all_options(command).values():
            if opt.kwargs.get("action") in ("store_true",):
                continue
            for fam in fams:
                assert f"{command}{opt.flags[0]}-{fam}" in ids, (command, opt.flags[0], fam)
    for case in ("simulate--duration", "simulate--every", "report--min-damping", "codegen--prefix"):
        assert any(i.startswith(case) for i in ids), case
    parser = cli.build_parser()
    subs = _subparsers(parser)
    typed = {
        (cmd, a.option_strings[0])
        for cmd, sub in subs.items()
        for a in sub._actions
        if isinstance(a.type, Number)
    }
    assert {
        ("analyze", "--points"),
        ("tune", "--g-max"),
        ("tune", "--w-pll-max"),
        ("simulate", "--every"),
    } <= typed


# ----------------------------------------------------------------------------------- drive files
_NUMBER = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)")
NEW_IN_STRINGS = ("1e999", "1e300", "-1e300", "1e-300")
NEW_BARE = (*NEW_IN_STRINGS, "nan", "inf", "-inf")


def _toml(v) -> str:
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return repr(v)


def _replaced(v):
    """(text of the value with one number replaced, the new number) for every number in ``v``: a bare
    number, the number of a quantity string ("<number> <unit>"), or such an element of a list."""
    if isinstance(v, bool):
        return
    if isinstance(v, int | float):
        for new in NEW_BARE:
            yield new, new
    elif isinstance(v, str) and (m := _NUMBER.match(v)):
        for new in NEW_IN_STRINGS:
            yield _toml(v[: m.start(1)] + new + v[m.end(1) :]), new
    elif isinstance(v, list):
        for j, x in enumerate(v):
            for text, new in _replaced(x):
                yield (
                    "["
                    + ", ".join([*(_toml(y) for y in v[:j]), text, *(_toml(y) for y in v[j + 1 :])])
                    + "]",
                    new,
                )


def _variants(text: str):
    """(dotted key, new number, document with that number replaced) for every number of a TOML
    document's values (strings count when they are quantities)."""
    section = ""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        head = re.match(r"^\s*\[([^\]]+)\]\s*(#.*)?$", line)
        if head:
            section = head.group(1).strip()
            continue
        m = re.match(r"^\s*([A-Za-z_]\w*)\s*=", line)
        if not m:
            continue
        try:
            value = tomllib.loads(line)[m.group(1)]
        except tomllib.TOMLDecodeError:
            continue
        for text, new in _replaced(value):
            variant = [*lines[:i], f"{m.group(1)} = {text}", *lines[i + 1 :]]
            yield f"{section}.{m.group(1)}", new, "\n".join(variant) + "\n"


def _documents():
    """(family, kind of document, name, text) of every preset and built-in scenario."""
    out = []
    with _with_pll():
        fams = families()
    for fam in fams:
        for pkg, what in ((fam.presets, "drive"), (fam.scenarios, "scenario")):
            if pkg is None:
                continue
            for p in sorted(resources.files(pkg).iterdir(), key=lambda r: r.name):
                if p.name.endswith(".toml"):
                    out.append(
                        pytest.param(
                            fam, what, p.name, p.read_text(encoding="utf-8"), id=f"{fam.name}-{p.name}"
                        )
                    )
    return out


def test_documents_cover_every_family():
    docs = {(p.values[0].name, p.values[1]) for p in _documents()}
    assert {(f, w) for f in (*BUILT_IN, PLL.name) for w in ("drive", "scenario")} <= docs


@pytest.mark.parametrize(("fam", "what", "name", "text"), _documents())
def test_every_drive_and_scenario_number_is_checked_at_load(fam, what, name, text):
    drive = load_drive(_a_drive(fam)) if what == "scenario" else None
    n = 0
    for key, value, variant in _variants(text):
        n += 1
        with pytest.raises(DriveFileError) as e:
            if what == "drive":
                load_drive_text(variant, "x.toml")
            else:
                load_scenario_text(variant, "x.toml", drive_units(drive))
        assert e.value.file == "x.toml" and e.value.key.startswith(key), (name, key, value, str(e.value))
    assert n >= 8, (name, n)  # the document does have numbers, and they were found
