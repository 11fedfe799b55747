"""Every command run once more in a fresh process whose clock is 400 days on (a faked other day, another
year even): the run that tests/common/test_outputs.py compares, byte for byte, with today's, and that
tests/common/test_report.py compares today's reports with (a second run that gives the same bytes on
another day, in another process, is a fortiori a second run that gives the same bytes)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

FAKE_CLOCK = """
import datetime, time
SHIFT = 400 * 86400.0 + 3 * 3600 + 17
_time = time.time
time.time = lambda: _time() + SHIFT
time.time_ns = lambda: int((_time() + SHIFT) * 1e9)
_localtime, _gmtime, _strftime, _ctime = time.localtime, time.gmtime, time.strftime, time.ctime
time.localtime = lambda t=None: _localtime(time.time() if t is None else t)
time.gmtime = lambda t=None: _gmtime(time.time() if t is None else t)
time.strftime = lambda f, t=None: _strftime(f, time.localtime() if t is None else t)
time.ctime = lambda t=None: _ctime(time.time() if t is None else t)
class _DT(datetime.datetime):
    @classmethod
    def now(cls, tz=None):
        return datetime.datetime.fromtimestamp(time.time(), tz)
    @classmethod
    def today(cls):
        return datetime.datetime.fromtimestamp(time.time())
    @classmethod
    def utcnow(cls):
        return datetime.datetime.fromtimestamp(time.time(), datetime.timezone.utc).replace(tzinfo=None)
class _D(datetime.date):
    @classmethod
    def today(cls):
        return datetime.date.fromtimestamp(time.time())
datetime.datetime, datetime.date = _DT, _D
"""

# the presets whose `report --quick` both days make (today's: session fixtures, tests/common/conftest.py)
REPORTS = ("piippo2008", "deangelo2006")
# their exit status: deangelo2006's verdict is `fail` over the drive's range (at the paper's 180 us the
# whole sampled drive holds no operating point from 0.6 p.u.: docs/tuning.md), its checks pass
REPORT_EXIT = {"piippo2008": 0, "deangelo2006": 3}


def exit_of(args: list[str]) -> int:
    """The exit status a run of :func:`runs` gives."""
    return REPORT_EXIT[args[1]] if args[0] == "report" else 0


def runs(out: str) -> list[list[str]]:
    """One run of every command, into ``out`` (a report of each family with a paper's figures)."""
    return [
        ["codegen", "deangelo2006", "--out", f"{out}/codegen"],
        ["analyze", "deangelo2006", "--speed", "250rpm", "--load", "5", "--out", f"{out}/analyze"],
        [
            "simulate",
            "deangelo2006",
            "--scenario",
            "fig3",
            "--duration",
            "0.05",
            "--quiet",
            "--out",
            f"{out}/sim",
        ],
        ["tune", "piippo2008", "--speeds", "3", "--torque=1T_N", "--quiet", "--out", f"{out}/tune"],
        *(["report", preset, "--quick", "--out", f"{out}/report-{preset}"] for preset in REPORTS),
    ]


LATER = """
import sys
from sensorless.reports.cli.main import main
for args, code in {runs}:
    assert main(args) == code, args
"""


class AnotherDay:
    """The run of :func:`runs` on another day, started at once in the background (so that the caller
    may compute today's outputs meanwhile); :meth:`outputs` waits for it."""

    def __init__(self, root: Path):
        self.root = root
        (root / "clock").mkdir()
        (root / "clock" / "sitecustomize.py").write_text(textwrap.dedent(FAKE_CLOCK))
        env = {k: v for k, v in os.environ.items() if k != "SOURCE_DATE_EPOCH"}
        env["PYTHONPATH"] = os.pathsep.join([str(root / "clock"), *filter(None, [env.get("PYTHONPATH")])])
        self.stderr = root / "stderr.txt"  # a file, not a pipe: nobody reads it while the process runs
        with self.stderr.open("w") as err:
            self.process = subprocess.Popen(
                [
                    sys.executable,
                    "-c",
                    LATER.format(runs=[(a, exit_of(a)) for a in runs(str(root / "later"))]),
                ],
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=err,
            )
        probe = "import datetime, time; print(datetime.date.today().isoformat(), time.strftime('%Y'))"
        out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True).stdout
        self.date, self.year = out.split()  # what the faked clock says in such a process
        self._done = False

    def outputs(self) -> Path:
        """The directory of the later day's outputs, once they are all made."""
        if not self._done:
            assert self.process.wait(timeout=600) == 0, self.stderr.read_text()[-2000:]
            self._done = True
        return self.root / "later"

    def report(self, preset: str) -> Path:
        """The later day's ``report <preset> --quick`` directory."""
        return self.outputs() / f"report-{preset}"

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait()
