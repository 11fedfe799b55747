"""The report names the firmware values that fix a failure, and with them applied the drive passes: the
2017 VESC motor XML (docs/examples/firmware), whose own PLL (foc_pll_kp 2000, foc_pll_ki 40000) leaves
the whole sampled drive unstable at every speed and whose open-loop start (400 ERPM in 0.5 s) never
hands over.

Checked independently of the finding's own numbers: the whole drive's poles (design/drive_analysis.py)
at the file's PLL and at the one named (a double root at -k_p/2: k_i = k_p^2/4, typed here), the
start judged again with the named values (nothing left to change), and the time-domain start check
simulated with them (a short subset of the report's checks: the one the start-up values decide).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from sensorless.design.drive import load_drive_text
from sensorless.design.drive_analysis import linearize_drive
from sensorless.design.pmsm_flux_observer.firmware import vesc
from sensorless.design.registry import family_of
from sensorless.design.simulate import simulate
from sensorless.design.startup_check import judge_startup
from sensorless.reports import time_domain
from sensorless.reports.pmsm_flux_observer.startup import startup_findings

KIND = "pmsm-flux-observer"
XML = Path(__file__).resolve().parents[2] / "docs" / "examples" / "firmware" / "skate_2017_mcconf.xml"
UNITS = {"current": "A", "acceleration": "rad/s2", "w_on": "rad/s", "w_off": "rad/s"}


def with_values(text: str, section: str, values: dict[str, str]) -> str:
    """The drive file ``text`` with ``values`` (key -> TOML value) set in ``[section]``."""
    head, rest = text.split(f"[{section}]\n", 1)
    body, _, tail = rest.partition("\n[")
    lines = [x for x in body.split("\n") if x.split("=")[0].strip() not in values]
    lines += [f"{k} = {v}" for k, v in values.items()]
    return head + f"[{section}]\n" + "\n".join(lines) + ("\n[" + tail if tail else "\n")


@pytest.fixture(scope="module")
def imported():
    text = vesc.read(XML.read_text(), XML.name, {"pole_pairs": 7}, KIND).text
    d = load_drive_text(text, XML.name)
    return text, d, family_of(d).gains(d)


def test_the_2017_vesc_file_with_the_named_pll_and_start_passes(imported):
    text, d, g = imported
    lines, data = startup_findings(d, g)
    # the file's own PLL: w_min at rated speed, no start-up value fixes it; the PLL's values are named
    # and the start judged at them
    assert any("no start-up value fixes it" in x and "speed_unreachable" in x for x in lines)
    named = [x for x in lines if x.startswith("start-up with the PLL's fix")]
    assert len(named) == 1 and data["at_gains"] == "the PLL's fix"
    m = re.search(r"foc_pll_ki = ([0-9.e+]+)", named[0])
    assert m is not None
    k_p = float(g.values["foc_pll_kp"])
    ki = float(m.group(1))
    assert ki == pytest.approx(k_p**2 / 4)  # a double root at -k_p/2 = -1000 1/s
    fixes = {s["key"]: s["needed"] for s in data["shortfalls"]}
    assert set(fixes) >= {"w_on", "acceleration"}

    fixed_text = with_values(text, "gains", {"foc_pll_ki": f'"{ki:g} 1/s2"'})
    fixed_text = with_values(fixed_text, "startup", {k: f'"{v:.12g} {UNITS[k]}"' for k, v in fixes.items()})
    fixed = load_drive_text(fixed_text, "fixed.toml")
    g2 = family_of(fixed).gains(fixed)
    assert g2.values["foc_pll_ki"] == ki
    # the whole sampled drive: unstable at the file's PLL (its slow pair), stable at the named one
    w = np.array([0.25, 1.0]) * d.w_base
    before = linearize_drive(d, g, w, d.T_N).max_real
    after = linearize_drive(fixed, g2, w, d.T_N).max_real
    assert (before > 0).all() and (after < 0).all()
    # judged again: nothing left to change
    again = judge_startup(fixed, g2)
    assert again is not None and again.shortfalls == ()
    # the report's start check, simulated with the named values: hands over and holds rated load
    (start,) = [sc for sc in time_domain.scenarios(fixed, ()) if sc.name == "start"]
    _, failed, problems = time_domain.judge(simulate(fixed, start, None), start, fixed.w_base)
    assert failed == [] and problems == []
