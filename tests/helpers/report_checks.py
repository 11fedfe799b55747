"""What every family's flow on a user's motor must keep: a report whose verdict follows from its checks,
and generated C whose example builds and initializes."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

from sensorless.reports.causes import CATALOGUE


def verdict_agrees_with_checks(report_dir: Path, exit_code: int) -> dict[str, Any]:
    """Assert that report.json's verdict follows from its checks and the HTML says the same; the data."""
    data = json.loads((report_dir / "report.json").read_text())
    v, td = data["verdict"], data["time_domain"]
    failed = [c for c in td if not c["passed"]]
    assert all(c["failed"] for c in failed) and not any(c["failed"] for c in td if c["passed"])
    if failed:  # one rule: any failed check fails the verdict, each failure named by its cause
        assert v["status"] == "fail" and exit_code == 3
        assert {f.get("check") for f in v["findings"]} >= {c["name"] for c in failed}
        assert all(len(c["failures"]) == len(c["failed"]) for c in failed)
        assert all(x["cause"] in CATALOGUE and x["fix"] for c in failed for x in c["failures"])
    if any(c.get("untested") for c in td):  # a check the observer did not close: at best a warning
        assert v["status"] != "pass"
    for c in td:  # each check's verdict follows from its numbers and stated limits
        lim, met = c["limits"], c["metrics"]
        if met["max_abs_theta_err_deg"] > lim["max_abs_theta_err_deg"]:
            assert not c["passed"]
    html = (report_dir / "report.html").read_text()
    assert f"verdict-{v['status']}" in html or v["status"].upper() in html.upper()
    return data


def c_example_initializes(c_dir: Path) -> None:
    """Build the generated C's example (its Makefile) and run it: it exits 0, its init accepts the
    defaults and its first samples are valid."""
    subprocess.run(["make", "-s", "-C", str(c_dir)], check=True, capture_output=True, timeout=120)
    exe = next(p for p in c_dir.iterdir() if p.is_file() and p.suffix == "" and p.name != "Makefile")
    out = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "init failed" not in out.stdout + out.stderr, out.stdout[-500:]
    assert "valid=1" in out.stdout
