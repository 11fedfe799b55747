"""Time-domain checks of a report: scenarios re-run with the gains under review, judged by stated limits.

Shared by every family with a simulation (design/simulate.py). Which scenarios: :func:`scenarios` picks a
preset's paper-figure scenarios (the family's report names them) and, for any other drive, the generic
scenarios scaled to the drive's own rating and time constants (design/scenario.py
``generic_scenarios``: speed steps, load steps at T_N and a slow reversal, in per unit), plus the
user's (``sensorless report --scenario FILE``). Each scenario is simulated with the gains under review
and becomes one check (:func:`checks`): a dict with ``name``, ``passed`` (true/false), ``failed`` (what
failed, where), its ``metrics`` and the ``limits`` they were held to (:data:`LIMITS`):

- the run holds (design/simulate.Traces.problems: finite, no rejected samples, position not lost);
- the peak position error, from the first sample within the limit on, at most 30 deg (electrical:
  the torque then still has 87 % of its commanded value);
- the final speed-estimation error (mean of the last 5 %) at most 2 % of the base speed;
- in speed control, the final speed within 5 % of the base speed of its reference (the drive reached
  what it was asked; the generic scenarios give it the time its torque limit needs).

A failed check is said in its entry, in the section, in the report's verdict (a finding; the status is
then at best "warn") and by ``sensorless report`` (a warning line, exit status 3).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from sensorless.design.family import CapabilityError, Drive, GainSet
from sensorless.design.scenario import (
    ZERO_SPEED_LOW_PU,
    Scenario,
    crosses_zero,
    generic_scenarios,
    load_scenario,
    zero_speed_limit,
)
from sensorless.design.simulate import simulate
from sensorless.design.startup import ACCELERATION_LIMIT
from sensorless.reports.document import Figure, Paragraph, Section, Table, f, num
from sensorless.reports.svg_render import svg_later

LIMITS = {
    "max_abs_theta_err_deg": 30.0,
    "final_speed_err_pu": 0.02,
    "final_tracking_err_pu": 0.05,
}


def scenarios(drive: Drive, paper: Sequence[str], user: Sequence[str] = ()) -> list[Scenario]:
    """The scenarios of a report: a preset's ``paper`` ones (its family's names), else the generic ones
    scaled to the drive (without those through zero speed where the observer does not run there:
    :func:`limitations`); then the user's files (``--scenario``), as given."""
    out: list[Scenario] = []
    if not drive.file.startswith("preset:"):
        try:
            out = generic_scenarios(drive)
        except CapabilityError:  # a family without scales: its own scenarios
            pass
        if zero_speed_limit(drive):  # nor a start from standstill, which its loop cannot simulate
            out = [sc for sc in out if not crosses_zero(sc) and not sc.startup]
    if not out:
        out = [load_scenario(name, drive) for name in paper]
    return out + [load_scenario(path, drive) for path in user]


def limitations(drive: Drive) -> list[str]:
    """What the report's generic checks leave out for this drive, and why (the verdict and the
    section say it): zero speed, where the family says its observer does not run through it."""
    why = "" if drive.file.startswith("preset:") else zero_speed_limit(drive)
    if not why:
        return []
    return [
        "Not checked: running through zero speed (no generic reversal or start from standstill; the "
        f"speed steps go down to {ZERO_SPEED_LOW_PU:g} p.u. only). {why} A reversal can still be simulated "
        "(sensorless simulate DRIVE --scenario reversal) or checked with --scenario FILE."
    ]


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * np.asarray(a, float)))


def judge(tr: Any, sc: Scenario, base_w: float) -> tuple[dict[str, Any], list[str], list[str]]:
    """(metrics, what failed, problems) of one simulated scenario against :data:`LIMITS`."""
    m: dict[str, Any] = {"duration_s": f(tr.t[-1]), "samples": int(tr.t.size)}
    failed: list[str] = []
    problems = tr.problems()
    failed += problems
    open_loop = np.asarray(tr["startup_mode"]) > 0.5 if "startup_mode" in tr.data else None
    if open_loop is not None:
        # the I-f start: theta_hat is the current vector's angle there, not an estimate; the position
        # error is judged from the handovers on (the first closed-loop sample after each)
        m["open_loop_s"] = f(np.count_nonzero(open_loop) * (tr.t[1] - tr.t[0]) if tr.t.size > 1 else 0)
        k_on = np.flatnonzero(open_loop[:-1] & ~open_loop[1:]) + 1
        m["handovers"] = int(k_on.size)
        if k_on.size:
            m["handover_theta_err_deg"] = f(np.degrees(np.abs(_wrap(tr["theta_err"][k_on])).max()))
        if open_loop.all() and "w_ref" in tr.data and "w_hat" in tr.data:
            # the start alone, throughout: fine where the reference stays within its range, not where it
            # asks for more (the open-loop frame turns at most at the handover speed)
            top, asked = np.max(np.abs(tr["w_hat"])), np.max(np.abs(tr["w_ref"]))
            if asked > 1.05 * top:
                failed = [
                    *failed,
                    f"the drive never handed over to the observer: the open-loop start ran throughout, at "
                    f"most {top / base_w:.3g} p.u., while the reference asked for {asked / base_w:.3g} p.u.",
                ]
        slip = out_of_step(tr.t, np.asarray(tr["theta_err"]), open_loop)
        if slip is not None:
            speed = f", speed {tr['w_m'][slip[1]] / base_w:+.3f} p.u." if "w_m" in tr.data else ""
            problems = [
                *problems,
                f"the rotor fell out of step in the open-loop I-f start at t = {slip[0]:.4g} s{speed} "
                "(it slipped half a turn against the current vector)",
            ]
            failed = [*failed, problems[-1]]
    if "theta_err" in tr.data:
        th = _wrap(tr["theta_err"])
        if open_loop is not None:
            th = np.where(open_loop, 0.0, th)
        m["rms_theta_err_deg"] = f(np.degrees(np.sqrt(np.mean(th**2))))
        lim = np.radians(LIMITS["max_abs_theta_err_deg"])
        within = np.flatnonzero(np.abs(th) <= lim)
        start = int(within[0]) if within.size else 0
        k = start + int(np.argmax(np.abs(th[start:])))
        m["max_abs_theta_err_deg"] = f(np.degrees(np.abs(th[k])))
        m["max_abs_theta_err_at_s"] = f(tr.t[k])
        if np.abs(th[k]) > lim and not any("position estimate was lost" in p for p in problems):
            where = f" at t = {tr.t[k]:.4g} s" + (
                f", speed {tr['w_m'][k] / base_w:+.3f} p.u." if "w_m" in tr.data else ""
            )
            failed.append(
                f"position error {np.degrees(np.abs(th[k])):.3g} deg{where} "
                f"(limit {LIMITS['max_abs_theta_err_deg']:g} deg)"
            )
    if "w_m" in tr.data and "w_hat" in tr.data:
        e = np.asarray(tr["w_m"]) - np.asarray(tr["w_hat"])
        tail = slice(-max(1, e.size // 20), None)
        m["max_abs_speed_err_rad_s"] = f(np.max(np.abs(e)))
        m["final_speed_err_rad_s"] = f(np.mean(e[tail]))
        m["final_speed_err_pu"] = f(np.mean(e[tail]) / base_w)
        # in the open-loop I-f start w_hat is the current vector's speed, not an estimate (the rotor
        # swings about it): a run that ends there is judged by its tracking alone
        ends_open = open_loop is not None and bool(open_loop[tail].any())
        if not ends_open and abs(np.mean(e[tail])) > LIMITS["final_speed_err_pu"] * base_w:
            failed.append(
                f"final speed-estimation error {np.mean(e[tail]) / base_w:+.3g} p.u. "
                f"({np.mean(e[tail]):+.4g} rad/s; limit {LIMITS['final_speed_err_pu']:g} p.u.)"
            )
        if sc.mode == "speed" and not sc.stiff_load and "w_ref" in tr.data:
            d = np.mean(np.asarray(tr["w_ref"])[tail] - np.asarray(tr["w_m"])[tail]) / base_w
            m["final_tracking_err_pu"] = f(d)
            if abs(d) > LIMITS["final_tracking_err_pu"]:
                failed.append(
                    f"the drive ended {d:+.3g} p.u. away from its speed reference (limit "
                    f"{LIMITS['final_tracking_err_pu']:g} p.u.)"
                )
    limit = tr.meta.get("startup", "").partition(ACCELERATION_LIMIT)[2]
    if failed and limit:  # the start said where the observer cannot follow the drive (physics)
        failed.append(f"physical limit: {ACCELERATION_LIMIT}{limit}")
    return m, failed, problems


def out_of_step(t: np.ndarray, theta_err: np.ndarray, open_loop: np.ndarray) -> tuple[float, int] | None:
    """(time [s], index) at which the rotor slips in an open-loop run: its angle against the current
    vector's (theta_err there, followed continuously from the run's start) passes +-180 deg; None if it
    never does. A rotor that swings beyond 90 deg and comes back has not slipped."""
    runs = np.flatnonzero(np.diff(np.concatenate(([0], open_loop.astype(int), [0]))))
    for a, b in zip(runs[::2], runs[1::2], strict=True):
        lag = np.unwrap(theta_err[a:b])
        k = np.flatnonzero(np.abs(lag) >= np.pi)
        if k.size:
            return float(t[a + k[0]]), int(a + k[0])
    return None


def checks(
    drive: Drive,
    gains: GainSet | None,
    runs: Sequence[Scenario | str],
    label: str,
    progress: Callable[[str], None],
) -> tuple[list[dict[str, Any]], list[Figure]]:
    """Simulate each scenario (a Scenario, or a built-in name or file) with ``gains`` (None: each
    scenario's own choice) and judge it; (checks, figures)."""
    from sensorless.reports.sim_figure import plot_traces

    out: list[dict[str, Any]] = []
    figs: list[Figure] = []
    for item in runs:
        sc = item if isinstance(item, Scenario) else load_scenario(item, drive)
        progress(f"      simulating {sc.name}: {sc.title}")
        tr = simulate(drive, sc, gains)
        m, failed, problems = judge(tr, sc, drive.w_base)
        cap = f"{sc.title} ({sc.source}), re-run with the gains under review ({label})."
        if failed:
            cap += " Failed: " + "; ".join(failed) + "."
        out.append(
            {
                "name": sc.name,
                "title": sc.title,
                "source": sc.source,
                "passed": not failed,
                "failed": failed,
                "problems": problems,
                "metrics": m,
                "limits": dict(LIMITS),
                "caption": cap,
            }
        )
        make = functools.partial(plot_traces, tr, sc.figure, f"{drive.name}: {sc.title}")
        figs.append(Figure(svg_later(make), cap))
    return out, figs


def findings(td: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Verdict findings of the failed checks: what failed and where."""
    return [
        {
            "issue": "time-domain check failed",
            "check": c["name"],
            "text": f"time-domain check {c['name']} ({c['title']}) failed: " + "; ".join(c["failed"]),
        }
        for c in td
        if not c["passed"]
    ]


def lost(td: Sequence[dict[str, Any]]) -> bool:
    """Whether a check did not hold at all (diverged or lost the rotor position)."""
    return any(c["problems"] for c in td)


STATUS_ORDER = ("pass", "warn", "fail")


def status_with(status: str, td: Sequence[dict[str, Any]]) -> str:
    """A verdict's status with the checks: a failed check makes it at best "warn"; a run that does not
    hold (diverged, rotor position lost) makes it "fail"."""
    worst = "fail" if lost(td) else "warn" if any(not c["passed"] for c in td) else "pass"
    return max(status, worst, key=STATUS_ORDER.index)


def section(
    number: int, td: Sequence[dict[str, Any]], figs: list[Figure], left_out: Sequence[str] = ()
) -> Section:
    """The report section of the checks; ``left_out``: what they do not check (:func:`limitations`)."""
    title = f"{number}. Time-domain checks"
    notes = tuple(Paragraph(x) for x in left_out)
    if not td:
        none = Paragraph("No time-domain simulation results are included in this report.")
        return Section(title, (none, *notes))
    rows = []
    for item in td:
        m = item["metrics"]
        rows.append(
            (
                f"{item['name']}: {item['title']}",
                "pass" if item["passed"] else "FAIL",
                num(m["duration_s"]),
                num(m.get("rms_theta_err_deg")),
                num(m.get("max_abs_theta_err_deg")),
                num(m.get("max_abs_speed_err_rad_s")),
                num(m.get("final_speed_err_rad_s")),
            )
        )
    header = (
        "scenario",
        "check",
        "simulated (s)",
        "RMS position error (deg)",
        "max |position error| (deg)",
        "max |speed error| (rad/s)",
        "final speed error (rad/s)",
    )
    limits = (
        f"A check passes when the run holds (finite, no rejected samples, rotor position not lost), the peak "
        f"position error stays within {LIMITS['max_abs_theta_err_deg']:g} deg, the final speed-estimation "
        f"error within {LIMITS['final_speed_err_pu']:g} p.u. and, in speed control, the final speed within "
        f"{LIMITS['final_tracking_err_pu']:g} p.u. of its reference."
    )
    table = Table(header, tuple(rows), numeric=frozenset({2, 3, 4, 5, 6}))
    blocks: list[Any] = [Paragraph(limits), *notes, table]
    blocks += [Paragraph(f"{c['name']}: " + "; ".join(c["failed"]) + ".", "bad") for c in td if c["failed"]]
    return Section(title, (*blocks, *figs))
