"""Output sets are all or nothing; output paths are checked before any computation; Ctrl-C, a kill,
a closed pipe and another day change nothing but what they should (reports/files.py,
reports/interrupts.py, reports/cli/main.py).

Kills are real: a child process runs the command (or an output set) with the step under test
replaced by one that sends SIGKILL or SIGINT to itself, and the test looks at what is left.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from datetime import date
from pathlib import Path

import pytest
from helpers.another_day import exit_of, runs
from sensorless.reports import files, interrupts
from sensorless.reports.cli import codegen as codegen_cli
from sensorless.reports.cli.main import main
from sensorless.reports.files import OutputError, OutputSet

# CPU seconds of this file's tests, measured, beside the another-day test (which runs in group report-runs
# of tests/conftest.py with test_report.py: the session fixtures of tests/common/conftest.py)
pytestmark = pytest.mark.long(10)

SCRIPT = Path(sys.executable).parent / "sensorless"  # the installed console script
OLD = {"a.txt": b"old a\n", "b.txt": b"old b\n"}
NEW = {"a.txt": b"new a\n", "b.txt": b"new b\n"}


def run(args, capsys):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def snapshot(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())} if d.exists() else {}


def stages(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if files.STAGE_TAG in p.name)


@pytest.fixture
def no_codegen(monkeypatch):
    """Fail the test if codegen gets as far as generating C: path checks come first."""

    def boom(*a, **k):
        raise AssertionError("computed before the output check")

    monkeypatch.setattr(codegen_cli, "generate", boom)


# ------------------------------------------------------------------------------------ path cases
def _file(tmp):
    (tmp / "f").write_text("x")
    return tmp / "f", [], "exists and is not a directory"


def _under_file(tmp):
    (tmp / "f").write_text("x")
    return tmp / "f" / "sub", [], "is not a directory"


def _existing(tmp):
    (tmp / "o").mkdir()
    (tmp / "o" / "main.c").write_text("mine")
    return tmp / "o", [], "output exists"


def _subdirectory(tmp):
    (tmp / "o" / "src").mkdir(parents=True)
    return tmp / "o", ["--force"], "holds the subdirectory 'src'"


def _dangling(tmp):
    (tmp / "o").symlink_to(tmp / "nowhere")
    return tmp / "o", [], "symbolic link to nothing"


def _prefix_main(tmp):
    return tmp / "o", ["--prefix", "main"], "argument --prefix: prefix 'main': main.c is also the example"


def _prefix_not_c(tmp):
    return tmp / "o", ["--prefix", "9lives"], "argument --prefix: prefix '9lives' is not a C identifier"


@pytest.mark.parametrize(
    "case", [_file, _under_file, _existing, _subdirectory, _dangling, _prefix_main, _prefix_not_c]
)
def test_output_path_problems_are_one_line_before_any_computation(case, tmp_path, capsys, no_codegen):
    out, extra, words = case(tmp_path)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    code, stdout, err = run(["codegen", "piippo2008", "--out", out, *extra], capsys)
    assert code == 2 and err.count("\n") == 1 and words in err, err
    assert err.startswith("sensorless codegen: error: ") and stdout == ""
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before  # nothing written


def test_the_current_directory_is_refused(tmp_path, capsys, monkeypatch, no_codegen):
    monkeypatch.chdir(tmp_path)
    code, _, err = run(["codegen", "piippo2008", "--out", ".", "--force"], capsys)
    assert code == 2 and "is the current directory" in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_an_unwritable_directory_is_refused(tmp_path, capsys, monkeypatch, no_codegen):
    """A parent directory the user may not write into (simulated: the tests may run as root, who may)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    real = os.access
    monkeypatch.setattr(files.os, "access", lambda p, mode: False if Path(p) == ro else real(p, mode))
    code, stdout, err = run(["codegen", "piippo2008", "--out", ro / "x"], capsys)
    assert code == 2 and err.count("\n") == 1 and f"cannot create files in '{ro}'" in err, err
    assert stdout == ""
    (ro / "x").mkdir()  # an existing output directory that is not writable itself
    monkeypatch.setattr(files.os, "access", lambda p, mode: False if Path(p) == ro / "x" else real(p, mode))
    code, _, err = run(["codegen", "piippo2008", "--out", ro / "x"], capsys)
    assert code == 2 and err.count("\n") == 1 and "not writable" in err, err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into any directory: the simulated test covers it")
def test_an_unwritable_directory_is_refused_for_real(tmp_path, capsys, no_codegen):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        code, _, err = run(["codegen", "piippo2008", "--out", ro / "x"], capsys)
    finally:
        ro.chmod(0o755)
    assert code == 2 and err.count("\n") == 1 and "cannot create files" in err, err


@pytest.mark.skipif(not Path("/sys/kernel").is_dir(), reason="no sysfs (not Linux)")
def test_a_read_only_file_system_is_refused(capsys, no_codegen):
    """sysfs refuses new directories even to root: the probe of the staging directory finds out."""
    code, _, err = run(["codegen", "piippo2008", "--out", "/sys/kernel/sensorless-test"], capsys)
    assert code == 2 and err.count("\n") == 1 and "cannot create files in '/sys/kernel'" in err, err


def test_existing_outputs_are_refused_before_computing_by_every_command(tmp_path, capsys):
    """Each command checks its outputs first: refused at once (nothing printed, the files untouched;
    no wall-clock limit: timing belongs to benchmarks/, and under load it failed a correct run)."""
    cases = {
        "report": (["report", "deangelo2006", "--quick"], "report.json"),
        "tune": (["tune", "deangelo2006", "--quiet"], "gains_constant.csv"),
        "simulate": (["simulate", "deangelo2006", "--scenario", "fig3", "--quiet"], "fig3.svg"),
        "analyze": (["analyze", "deangelo2006"], "anything.txt"),  # names known only when computed
        "codegen": (["codegen", "deangelo2006"], "Makefile"),
    }
    for command, (args, name) in cases.items():
        out = tmp_path / command
        out.mkdir()
        (out / name).write_text("mine")
        code, stdout, err = run([*args, "--out", out], capsys)
        assert code == 2 and "output exists" in err and "--force" in err and err.count("\n") == 1, err
        assert stdout == "", command
        assert snapshot(out) == {name: b"mine"}


# ------------------------------------------------------------------------------------ the commit
def test_force_replaces_the_set_and_carries_other_files_over(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "a.txt").write_bytes(b"old a\n")
    (out / "notes.md").write_text("mine")
    (out / "link").symlink_to("notes.md")
    ino = (out / "notes.md").stat().st_ino
    s = OutputSet(out, force=True, names=NEW)
    s.check()
    for k, v in NEW.items():
        s.add_bytes(k, v)
    s.commit()
    assert snapshot(out) == {**NEW, "link": b"mine", "notes.md": b"mine"}
    assert (out / "notes.md").stat().st_ino == ino and os.readlink(out / "link") == "notes.md"
    assert stages(tmp_path) == []


def test_without_an_atomic_exchange_two_renames_do(tmp_path, monkeypatch):
    """Where renameat2 is missing, the set still ends up whole (two renames in a row)."""
    monkeypatch.setattr(files.ctypes, "CDLL", lambda *a, **k: object())
    out = tmp_path / "o"
    out.mkdir()
    (out / "a.txt").write_bytes(b"old")
    (out / "keep").write_text("k")
    s = OutputSet(out, force=True)
    for k, v in NEW.items():
        s.add_bytes(k, v)
    s.commit()
    assert snapshot(out) == {**NEW, "keep": b"k"} and stages(tmp_path) == []


def test_a_mount_point_gets_its_files_renamed_in_one_by_one(tmp_path, monkeypatch):
    """A mount point cannot be renamed (EBUSY): the set is staged inside it; a staging directory a
    killed run left there is removed (not taken for a subdirectory of the outputs)."""
    out = tmp_path / "volume"
    out.mkdir()
    (out / "a.txt").write_bytes(b"old")
    (out / "keep").write_text("k")
    (out / ".sensorless-stage-999999999-dead").mkdir()  # pid 999999999: no such process
    real_ismount = os.path.ismount
    monkeypatch.setattr(files.os.path, "ismount", lambda p: Path(p) == out or real_ismount(p))
    monkeypatch.setattr(files, "move_into_place", lambda *a: pytest.fail("renamed the mount point"))
    s = OutputSet(out, force=True, names=NEW)
    s.check()
    for k, v in NEW.items():
        s.add_bytes(k, v)
    s.commit()
    assert snapshot(out) == {**NEW, "keep": b"k"} and stages(tmp_path) == []


def test_an_output_named_twice_is_an_error(tmp_path):
    with pytest.raises(OutputError, match="would be written twice"):
        OutputSet(tmp_path / "o", names=["x.c", "x.c"])
    s = OutputSet(tmp_path / "o")
    s.add_text("x.c", "")
    with pytest.raises(OutputError, match=r"two outputs named x\.c"):
        s.add_text("x.c", "")


CHILD = """
import os, signal, sys
from pathlib import Path
from sensorless.reports import files
from sensorless.reports.files import OutputSet

where, out = sys.argv[1], Path(sys.argv[2])
real_move, real_carry = files.move_into_place, files._carry_over

def die():
    os.kill(os.getpid(), signal.SIGKILL)

def move(stage, target):
    if where == "before-move":
        die()
    real_move(stage, target)
    if where == "after-move":
        die()

def carry(src, dst, names):
    real_carry(src, dst, names)
    if where == "staging":
        die()

files.move_into_place, files._carry_over = move, carry
s = OutputSet(out, force=True)
s.add_bytes("a.txt", b"new a\\n")
s.add_bytes("b.txt", b"new b\\n")
s.commit()
"""


@pytest.mark.parametrize(
    ("where", "existing", "expected", "left"),
    [
        ("staging", True, OLD, 1),
        ("before-move", True, OLD, 1),
        ("after-move", True, NEW, 1),  # the old set, at the staging name
        ("before-move", False, {}, 1),
        ("after-move", False, NEW, 0),
    ],
)
def test_a_kill_at_the_rename_step_leaves_the_old_set_or_the_new_one(
    where, existing, expected, left, tmp_path
):
    """SIGKILL while staging, just before the one rename and just after it: the target holds exactly
    the old set or exactly the new one; the staging directory left behind is removed by the next run."""
    out = tmp_path / "o"
    if existing:
        out.mkdir()
        for k, v in OLD.items():
            (out / k).write_bytes(v)
    r = subprocess.run([sys.executable, "-c", CHILD, where, str(out)], capture_output=True, cwd=tmp_path)
    assert r.returncode == -signal.SIGKILL, r.stderr.decode()
    assert snapshot(out) == expected
    assert len(stages(tmp_path)) == left  # what a hard kill cannot clean up: hidden, beside the target
    s = OutputSet(out, force=True)
    s.add_bytes("a.txt", b"again\n")
    s.commit()
    assert stages(tmp_path) == []  # the next run removed it


def test_a_real_command_killed_at_the_rename_step_leaves_the_old_set(tmp_path):
    """`sensorless codegen --force` over an earlier set (made here, in-process), killed just before
    the rename: the earlier set is intact, file for file."""
    out = tmp_path / "c"
    assert main(["codegen", "deangelo2006", "--out", str(out)]) == 0
    before = snapshot(out)
    code = (
        "import os, signal, sys\n"
        "from sensorless.reports import files\n"
        "files.move_into_place = lambda *a: os.kill(os.getpid(), signal.SIGKILL)\n"
        "from sensorless.reports.cli.main import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    args = ["codegen", "deangelo2006", "--precision", "double", "--force", "--out", str(out)]
    r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True)
    assert r.returncode == -signal.SIGKILL, r.stderr.decode()
    assert snapshot(out) == before and b"typedef float" in before["deangelo2006.h"]  # the old, float set


# ----------------------------------------------------------------------------------- Ctrl-C
def _interrupting_generate(monkeypatch, then):
    """codegen's generate, with a Ctrl-C (a real SIGINT to this process) in it; ``then`` is what the
    computation does with it: CasADi turns it into a RuntimeError, or swallows it and goes on."""
    real = codegen_cli.generate

    def generate(*a, **k):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)  # the handler runs here
        except KeyboardInterrupt:
            if then == "error":
                raise RuntimeError("KeyboardInterrupt") from None  # what CasADi makes of it
        return real(*a, **k)  # swallowed: the computation finishes normally

    monkeypatch.setattr(codegen_cli, "generate", generate)


@pytest.mark.parametrize("then", ["error", "swallowed"])
def test_ctrl_c_in_a_computation_is_one_line_exit_130_and_nothing_written(
    then, tmp_path, capsys, monkeypatch
):
    _interrupting_generate(monkeypatch, then)
    # the handler the process had (Python's default, or SIG_IGN where a shell started it in the background)
    before = signal.getsignal(signal.SIGINT)
    code, _, err = run(["codegen", "deangelo2006", "--out", tmp_path / "o"], capsys)
    assert code == 130 and err == "sensorless codegen: interrupted\n"
    assert not (tmp_path / "o").exists() and stages(tmp_path) == []
    assert signal.getsignal(signal.SIGINT) is before  # handlers restored


def test_ctrl_c_at_the_rename_step_lets_the_move_finish(tmp_path, capsys, monkeypatch):
    """A SIGINT during the move is recorded, the move completes (the new set, whole), then exit 130."""
    real = files.move_into_place

    def move(stage, target):
        os.kill(os.getpid(), signal.SIGINT)
        real(stage, target)

    monkeypatch.setattr(files, "move_into_place", move)
    out = tmp_path / "o"
    code, _, err = run(["codegen", "deangelo2006", "--out", out], capsys)
    assert code == 130 and err.endswith("sensorless codegen: interrupted\n")
    assert sorted(p.name for p in out.iterdir()) == ["Makefile", "deangelo2006.c", "deangelo2006.h", "main.c"]
    assert stages(tmp_path) == []


def test_interrupts_outside_the_command_line_still_interrupt(tmp_path):
    """An OutputSet used from Python (no command line): a SIGINT during the move is raised after it."""
    real = files.move_into_place
    s = OutputSet(tmp_path / "o")
    s.add_bytes("a.txt", b"x")
    try:
        files.move_into_place = lambda a, b: (os.kill(os.getpid(), signal.SIGINT), real(a, b))
        with pytest.raises(KeyboardInterrupt):
            s.commit()
    finally:
        files.move_into_place = real
    assert snapshot(tmp_path / "o") == {"a.txt": b"x"} and interrupts.received() is None


@pytest.mark.parametrize(
    ("sig", "code", "word"), [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")]
)
def test_a_signal_to_the_installed_script_mid_computation(sig, code, word, tmp_path):
    """The installed script, signalled while it computes a report: one line, 128 + signal, no output
    and no staging directory."""
    out = tmp_path / "r"
    p = subprocess.Popen(
        [SCRIPT, "report", "deangelo2006", "--quick", "--out", out],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    first = p.stderr.readline()  # the first progress line: the computation has started
    assert first, p.communicate()
    p.send_signal(sig)
    _, err = p.communicate(timeout=120)
    assert p.returncode == code, err
    assert err.splitlines()[-1] == f"sensorless report: {word}" and "Traceback" not in err, err
    assert not out.exists() and stages(tmp_path) == []


def test_a_closed_stdout_is_quiet(tmp_path):
    """`sensorless simulate deangelo2006 --list | head -1`: no BrokenPipeError traceback."""
    p = subprocess.Popen(
        [SCRIPT, "simulate", "deangelo2006", "--list"], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    p.stdout.close()  # the reader is gone before anything is written
    err = p.stderr.read()
    assert p.wait(timeout=60) == 141 and err == b""


# ------------------------------------------------------------------------------- another day
# CPU seconds, measured, of group report-runs (this test with test_report.py, and the other day's process
# it starts): the group that builds the session fixtures of tests/common/conftest.py starts first
@pytest.mark.long(60)
def test_outputs_are_byte_identical_on_another_day(
    another_day, tmp_path, capsys, report_piippo_quick, report_deangelo_quick
):  # another_day first: its process runs while this one makes today's outputs
    """Every command's outputs, made today (here) and another day (a fresh process with the clock
    moved 400 days on: tests/helpers/another_day.py), are the same bytes; and no output holds either
    date. Today's reports are the session's runs of the same commands (tests/common/conftest.py), made
    in this process today; tests/common/test_report.py reads this same other day's reports as the
    second run of its "two runs give identical JSON"."""
    today_reports = {"piippo2008": report_piippo_quick, "deangelo2006": report_deangelo_quick}
    for args in runs(str(tmp_path / "today")):
        if args[0] == "report":  # the same command, already run once in this process today
            preset = args[1]
            assert args[2:] == ["--quick", "--out", f"{tmp_path / 'today'}/report-{preset}"]
            shutil.copytree(today_reports[preset], tmp_path / "today" / f"report-{preset}")
            continue
        assert main(args) == exit_of(args), args
    capsys.readouterr()
    later = another_day.outputs()
    d1, y1 = another_day.date, another_day.year
    d0, y0 = date.today().isoformat(), time.strftime("%Y")
    assert d0 != d1 and y0 != y1  # the clock did move, to another year even

    def outputs(root: Path) -> dict[Path, bytes]:
        return {p.relative_to(root): p.read_bytes() for p in root.rglob("*") if p.is_file()}

    today, other = outputs(tmp_path / "today"), outputs(later)
    assert len(today) >= 16 and set(today) == set(other)
    for name, data in today.items():
        assert data == other[name], f"{name} differs between days"
        for day in (d0, d1, d0.replace("-", ""), d1.replace("-", "")):
            assert day.encode() not in data, f"{name} holds the date {day}"
    for preset in today_reports:
        assert json.loads(today[Path(f"report-{preset}/report.json")])["format"] == "sensorless-report/1"
