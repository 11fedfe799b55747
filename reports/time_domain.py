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

Only sensorless runs count: a run whose open-loop I-f start (its output ``startup_mode``) never handed
over, had the loop for more than MAX_OPEN_LOOP_SHARE of the time or ended in it is "not tested
sensorless" (:func:`untested_reason`; the check is then at best "warn"); the position errors are the
closed loop's, the open-loop part its own metric and column. One verdict rule (:func:`status_with`): a
failed check makes the verdict "fail". Each failure carries its evidence and its cause from the
catalogue reports/causes.py (the family's own finding first, its report hooks' ``failure_cause``),
with the change that fixes it; it is said in its entry, in the section, in the report's verdict (a
finding) and by ``sensorless report`` (a warning line, exit status 3).
"""

from __future__ import annotations

import contextvars
import dataclasses
import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypedDict, Unpack

import numpy as np
from sensorless.design.capabilities import Linearizable, Scaled
from sensorless.design.family import CapabilityError, Drive, DriveScales, GainSet
from sensorless.design.registry import family_of
from sensorless.design.runtime import StepVariant, step_variant
from sensorless.design.scenario import (
    ZERO_SPEED_LOW_PU,
    Scenario,
    crosses_zero,
    generic_scenarios,
    load_scenario,
    spins_up,
    zero_speed_limit,
)
from sensorless.design.simulate import simulate, simulated
from sensorless.design.startup import ACCELERATION_LIMIT
from sensorless.reports.causes import CATALOGUE, Failure, Named, classify_all, operating_torque_pu
from sensorless.reports.document import Block, Figure, Paragraph, Section, Table, f, num
from sensorless.reports.svg_render import svg_later

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.simulate import Traces

LIMITS = {
    "max_abs_theta_err_deg": 30.0,
    "final_speed_err_pu": 0.02,
    "final_tracking_err_pu": 0.05,
}
# a run whose open-loop I-f start had the loop longer than this share of it did not test the observer
MAX_OPEN_LOOP_SHARE = 0.5


# the observer step the checks run (design/runtime.step_variant's variant), None: the double one;
# set by `report --precision fixed` (reports/fixed_review.py judged_with)
JUDGED_STEP: contextvars.ContextVar[StepVariant | None] = contextvars.ContextVar("judged_step", default=None)


def scenarios(drive: Drive, paper: Sequence[str], user: Sequence[str] = ()) -> list[Scenario]:
    """The scenarios of a report: a preset's ``paper`` ones (its family's names), else the generic ones
    scaled to the drive (without those through zero speed where the observer does not run there:
    :func:`limitations`); then the user's files (``--scenario``), as given."""
    out: list[Scenario] = []
    if not drive.file.startswith("preset:"):
        if isinstance(family_of(drive), Scaled):  # else (a family without scales): its own scenarios
            out = generic_scenarios(drive)
        if zero_speed_limit(drive):  # nor a start from standstill, unless the drive spins up once
            keep_start = spins_up(drive)
            out = [sc for sc in out if not crosses_zero(sc) and (keep_start or not sc.startup)]
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
        "Not checked: running through zero speed (no generic reversal"
        + ("" if spins_up(drive) else " or start from standstill")
        + f"; the speed steps go down to {ZERO_SPEED_LOW_PU:g} p.u. only). {why} A reversal can still be "
        "simulated (sensorless simulate DRIVE --scenario reversal) or checked with --scenario FILE."
    ]


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * np.asarray(a, float)))


# a check's figures (report.json ``metrics``): seconds, shares, errors; None where a run gives none
Metrics = dict[str, float | None]
# a failure of a check (report.json ``failures``): reports/causes.py ``Failure``'s fields and its cause
FailureRecord = dict[str, str | float | bool | None]


class Status(TypedDict):
    """What a check's status is read from (:func:`check_status`)."""

    passed: bool
    untested: str  # why the run did not test the observer ("" where it did)


class Check(Status):
    """The check of one scenario, as report.json's ``time_domain`` holds it (:func:`entry`)."""

    name: str
    title: str
    source: str
    crosses_zero: bool
    status: str  # "pass", "warn" (not tested sensorless) or "fail"
    sensorless: bool
    failed: list[str]
    failures: list[FailureRecord]
    causes: list[str]
    problems: list[str]
    metrics: Metrics
    limits: dict[str, float]
    caption: str


class Evidence(TypedDict, total=False):
    """Where a failure happened: the evidence fields of reports/causes.py ``Failure``."""

    t: float | None
    w_pu: float | None
    load_pu: float | None
    torque_e_pu: float | None
    torque_pu: float | None
    limit_pu: float | None
    accel_share: float | None
    open_loop: bool
    open_s: float | None
    avail_s: float | None
    need_s: float | None
    w_ref_pu: float | None
    drop_accel_share: float | None
    drop_speed_err_pu: float | None


class DropBack(TypedDict, total=False):
    """How an open-loop run that began as a drop back from closed loop began (Evidence's drop_*)."""

    drop_accel_share: float | None
    drop_speed_err_pu: float | None


class Finding(TypedDict):
    """A verdict finding of a check that failed or did not test the observer (:func:`findings`)."""

    issue: str
    check: str
    causes: list[str]
    text: str


@dataclass(frozen=True)
class Judged:
    """One simulated scenario judged: its metrics, what failed (with the evidence where: reports/causes.py
    ``Failure``), what makes the run not hold, and why it did not test the observer ("" where it did)."""

    metrics: Metrics
    failures: list[Failure]
    problems: list[str]
    untested: str

    @property
    def failed(self) -> list[str]:
        """What failed, one line each."""
        return [x.text for x in self.failures]


def judge(tr: Traces, sc: Scenario, base_w: float) -> tuple[Metrics, list[str], list[str]]:
    """(metrics, what failed, problems) of one simulated scenario against :data:`LIMITS`."""
    j = assess(tr, sc, base_w)
    return j.metrics, j.failed, j.problems


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, one past last) index of each run of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(int), [0]))))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def untested_reason(open_loop: np.ndarray | None, dt: float) -> str:
    """Why a run with the open-loop I-f start ``open_loop`` (per sample) did not test the observer: the
    start had the loop throughout (never handed over), for more than :data:`MAX_OPEN_LOOP_SHARE` of the
    run, or at its end; "" where the observer had the loop (or the run has no start)."""
    if open_loop is None or not open_loop.any():
        return ""
    share = float(np.mean(open_loop))
    t_open = np.count_nonzero(open_loop) * dt
    if open_loop[0] and not (~open_loop).any():
        return f"the open-loop I-f start ran throughout ({t_open:.3g} s): the observer never had the loop"
    if share > MAX_OPEN_LOOP_SHARE:
        return (
            f"the open-loop I-f start had the loop for {100 * share:.0f} % of the run ({t_open:.3g} s), the "
            f"observer for {100 * (1 - share):.0f} %"
        )
    if open_loop[-max(1, open_loop.size // 20) :].any():
        return "the run ended in the open-loop I-f start: its final speed is not the observer's"
    return ""


def assess(tr: Traces, sc: Scenario, base_w: float, scales: DriveScales | None = None) -> Judged:
    """One simulated scenario judged against :data:`LIMITS`, each failure with its evidence (the torque
    limit and full acceleration from ``scales``, where given)."""
    m: Metrics = {"duration_s": f(tr.t[-1]), "samples": int(tr.t.size)}
    dt = float(tr.t[1] - tr.t[0]) if tr.t.size > 1 else 0.0
    T_N = float(tr.meta.get("T_N") or (scales.T_N if scales is not None else 0.0)) or None
    has = tr.data.__contains__
    w_m = np.asarray(tr["w_m"], float) if has("w_m") else None
    open_loop = np.asarray(tr["startup_mode"]) > 0.5 if has("startup_mode") else None
    # the window before a failure in which the drive's acceleration and torque command are read: a fifth
    # of the time the full acceleration needs for 1 p.u. (the observer's lag builds up over it)
    n_w = 20
    if scales is not None and dt > 0:
        n_w = max(n_w, int(0.2 * scales.J * scales.w_base / (scales.pole_pairs * scales.T_max) / dt))

    def evidence(
        kind: str, text: str, k: int | None, lo: int | None = None, **kw: Unpack[Evidence]
    ) -> Failure:
        if k is None:
            return Failure(kind, text, **kw)
        k = int(min(max(k, 0), tr.t.size - 1))
        a = max(0, k - n_w) if lo is None else lo
        out: Evidence = {
            "t": float(tr.t[k]),
            "open_loop": bool(open_loop[k]) if open_loop is not None else False,
        }
        if w_m is not None:
            out["w_pu"] = float(w_m[k] / base_w)
            if has("w_ref"):
                out["w_ref_pu"] = float(tr["w_ref"][k] / base_w)
            if scales is not None and k > a:
                a_max = scales.pole_pairs * scales.T_max / scales.J
                out["accel_share"] = float(abs(w_m[k] - w_m[a]) / (tr.t[k] - tr.t[a]) / a_max)
        if T_N:
            if has("T_L"):
                out["load_pu"] = float(tr["T_L"][k] / T_N)
            if has("T_e"):
                out["torque_e_pu"] = float(tr["T_e"][k] / T_N)
            if has("T_ref"):
                out["torque_pu"] = float(np.max(np.abs(tr["T_ref"][a : k + 1])) / T_N)
            if scales is not None:
                out["limit_pu"] = scales.T_max / T_N
        out.update(kw)
        return Failure(kind, text, **out)

    def drop_back(a: int) -> DropBack:
        # an open-loop run that began as a drop back from closed loop (sample a): how fast the drive's
        # speed changed over the window before it, and how far the open-loop frame started off the rotor
        if a <= 0 or w_m is None or scales is None or not has("w_hat"):
            return {}
        a0 = max(0, a - n_w)
        a_max = scales.pole_pairs * scales.T_max / scales.J
        return {
            "drop_accel_share": float(abs(w_m[a] - w_m[a0]) / (tr.t[a] - tr.t[a0]) / a_max),
            "drop_speed_err_pu": float((w_m[a] - tr["w_hat"][a]) / base_w),
        }

    def open_time(k_tail: int) -> Evidence:
        # since the reference's last step: the I-f start's time, the time to the judged tail, and what
        # the rest of the step (outside the start's speeds) needs at the torque limit against the load
        if open_loop is None or w_m is None or scales is None or not has("w_ref") or dt <= 0:
            return {}
        w_ref = np.asarray(tr["w_ref"], float)
        steps = np.flatnonzero(np.diff(w_ref[: k_tail + 1]) != 0)
        k0 = int(steps[-1]) + 1 if steps.size else 0
        ol = np.flatnonzero(open_loop[k0:k_tail])
        if not ol.size:
            return {}
        dw = w_ref[k_tail] - w_m[k0]
        covered = abs(w_m[k0 + ol[-1]] - w_m[k0 + ol[0]])
        load = float(tr["T_L"][k_tail]) if has("T_L") else 0.0
        margin = scales.T_max - np.sign(dw) * load
        if margin <= 0:
            return {}
        a_lim = scales.pole_pairs * margin / scales.J
        if scales.speed_ramp > 0:  # the drive's own ramp of the reference: no faster than it
            a_lim = min(a_lim, scales.speed_ramp)
        return {
            "open_s": ol.size * dt,
            "avail_s": (k_tail - k0) * dt,
            "need_s": float(max(0.0, abs(dw) - covered) / a_lim),
        }

    failures: list[Failure] = []
    problems = tr.problems()
    theta = np.asarray(tr["theta_err"], float) if has("theta_err") else None
    lim = np.radians(LIMITS["max_abs_theta_err_deg"])
    first_beyond: int | None = None
    if theta is not None:
        th = _wrap(theta)
        if open_loop is not None:
            th = np.where(open_loop, 0.0, th)
        within = np.flatnonzero(np.abs(th) <= lim)
        start = int(within[0]) if within.size else 0
        beyond = np.flatnonzero(np.abs(th[start:]) > lim)
        first_beyond = start + int(beyond[0]) if beyond.size else None
    for p in problems:
        kind = "diverged" if "diverged" in p else "rejected" if "rejected" in p else "lost"
        k = first_beyond if kind == "lost" else None
        if kind == "rejected" and has("valid"):
            k = int(np.argmax(np.asarray(tr["valid"]) < 0.5))
        if kind == "diverged":
            bad = tr.nonfinite()
            k = int(np.searchsorted(tr.t, bad[1])) - 1 if bad is not None else None
        failures.append(evidence(kind, p, k))
    if open_loop is not None:
        # the I-f start: theta_hat is the current vector's angle there, not an estimate; the position
        # error is judged from the handovers on (the first closed-loop sample after each)
        m["open_loop_s"] = f(np.count_nonzero(open_loop) * dt)
        m["open_loop_fraction"] = f(np.mean(open_loop))
        k_on = np.flatnonzero(open_loop[:-1] & ~open_loop[1:]) + 1
        m["handovers"] = int(k_on.size)
        if k_on.size:
            m["handover_theta_err_deg"] = f(np.degrees(np.abs(_wrap(tr["theta_err"][k_on])).max()))
        if open_loop.all() and has("w_ref") and has("w_hat"):
            # the start alone, throughout: fine where the reference stays within its range, not where it
            # asks for more (the open-loop frame turns at most at the handover speed)
            top, asked = np.max(np.abs(tr["w_hat"])), np.max(np.abs(tr["w_ref"]))
            if asked > 1.05 * top:
                failures.append(
                    evidence(
                        "no_handover",
                        "the drive never handed over to the observer: the open-loop start ran throughout, "
                        f"at most {top / base_w:.3g} p.u., while the reference asked for "
                        f"{asked / base_w:.3g} p.u.",
                        tr.t.size - 1,
                    )
                )
        slip = out_of_step(tr.t, np.asarray(tr["theta_err"]), open_loop)
        if slip is not None:
            speed = f", speed {w_m[slip[1]] / base_w:+.3f} p.u." if w_m is not None else ""
            text = (
                f"the rotor fell out of step in the open-loop I-f start at t = {slip[0]:.4g} s{speed} "
                "(it slipped half a turn against the current vector)"
            )
            problems = [*problems, text]
            # what the current carried: the peak |T_e| of the open-loop run up to the slip
            a = next(r[0] for r in _runs(open_loop) if r[0] <= slip[1] < r[1])
            carried = float(np.max(np.abs(tr["T_e"][a : slip[1] + 1])) / T_N) if T_N and has("T_e") else None
            failures.append(evidence("slip", text, slip[1], lo=a, torque_pu=carried, **drop_back(a)))
    if theta is not None:
        th = _wrap(theta)
        closed = ~open_loop if open_loop is not None else np.ones(th.size, bool)
        # the closed-loop error: over the samples where the observer had the loop
        m["rms_theta_err_deg"] = f(np.degrees(np.sqrt(np.mean(th[closed] ** 2)))) if closed.any() else None
        if open_loop is not None:
            th = np.where(open_loop, 0.0, th)
        within = np.flatnonzero(np.abs(th) <= lim)
        start = int(within[0]) if within.size else 0
        k = start + int(np.argmax(np.abs(th[start:])))
        m["max_abs_theta_err_deg"] = f(np.degrees(np.abs(th[k])))
        m["max_abs_theta_err_at_s"] = f(tr.t[k])
        if np.abs(th[k]) > lim and not any("position estimate was lost" in p for p in problems):
            where = f" at t = {tr.t[k]:.4g} s" + (
                f", speed {w_m[k] / base_w:+.3f} p.u." if w_m is not None else ""
            )
            text = (
                f"position error {np.degrees(np.abs(th[k])):.3g} deg{where} "
                f"(limit {LIMITS['max_abs_theta_err_deg']:g} deg)"
            )
            failures.append(evidence("position", text, first_beyond if first_beyond is not None else k))
    if w_m is not None and has("w_hat"):
        e = w_m - np.asarray(tr["w_hat"])
        n_tail = max(1, e.size // 20)
        tail = slice(-n_tail, None)
        m["max_abs_speed_err_rad_s"] = f(np.max(np.abs(e)))
        m["final_speed_err_rad_s"] = f(np.mean(e[tail]))
        m["final_speed_err_pu"] = f(np.mean(e[tail]) / base_w)
        # in the open-loop I-f start w_hat is the current vector's speed, not an estimate (the rotor
        # swings about it): a run that ends there is judged by its tracking alone
        ends_open = open_loop is not None and bool(open_loop[tail].any())
        if not ends_open and abs(np.mean(e[tail])) > LIMITS["final_speed_err_pu"] * base_w:
            text = (
                f"final speed-estimation error {np.mean(e[tail]) / base_w:+.3g} p.u. "
                f"({np.mean(e[tail]):+.4g} rad/s; limit {LIMITS['final_speed_err_pu']:g} p.u.)"
            )
            failures.append(evidence("speed_estimate", text, e.size - 1, lo=e.size - n_tail))
        if sc.mode == "speed" and not sc.stiff_load and has("w_ref"):
            # the reference the speed controller tracks: the drive's rate-limited one where it has the
            # limiter (symbolic/speed_ramp.py): a drive that follows its own ramp follows its reference
            ref = tr["w_ref_r"] if has("w_ref_r") else tr["w_ref"]
            d = np.mean(np.asarray(ref)[tail] - w_m[tail]) / base_w
            if has("w_ref_r"):  # where the ramp has not reached the command at the end: said, by how much
                m["final_ramp_gap_pu"] = f(np.mean(np.asarray(tr["w_ref"])[tail] - ref[tail]) / base_w)
            m["final_tracking_err_pu"] = f(d)
            if abs(d) > LIMITS["final_tracking_err_pu"]:
                text = (
                    f"the drive ended {d:+.3g} p.u. away from its speed reference (limit "
                    f"{LIMITS['final_tracking_err_pu']:g} p.u.)"
                )
                failures.append(
                    evidence("tracking", text, e.size - 1, lo=e.size - n_tail, **open_time(e.size - n_tail))
                )
    limit = tr.meta.get("startup", "").partition(ACCELERATION_LIMIT)[2]
    # the start said where its handover rule judges that the observer cannot follow the full
    # acceleration: the rule's steady lag to an endless ramp, not what a brake of a few ms builds (the
    # gimbal motor of docs/examples/motors, tuned: 90 deg steady at 0.5 p.u., 10 deg braking from 1 p.u.
    # read at its speed estimate), so it is quoted as the rule's, not as a physical limit
    if failures and limit:
        note = f"; the handover rule (design/startup.py): {ACCELERATION_LIMIT}{limit}"
        failures[-1] = dataclasses.replace(failures[-1], text=failures[-1].text + note)
    return Judged(m, failures, problems, untested_reason(open_loop, dt))


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


def finders(
    drive: Drive, gains: GainSet | None
) -> tuple[Callable[[Failure], Named | None] | None, Callable[[Failure], bool | None]]:
    """The cause finders of ``drive`` (reports/causes.py ``classify``): its family's own (its report hooks'
    ``failure_cause`` bound to the drive and ``gains``, None: the drive file's) and the shared test of a
    right-half-plane pole of its linearization at a failure's speed and load (not where the family holds
    zero speed by something the plain linearization leaves out, e.g. an injection: its hook judges)."""
    from sensorless.reports.family import hooks

    fam = family_of(drive)
    own = hooks(fam).failure_cause
    g = gains

    def reviewed() -> GainSet:
        nonlocal g
        g = g if g is not None else fam.gains(drive)
        return g

    family = (lambda x: own(drive, reviewed(), x)) if own is not None else None

    def unstable(x: Failure) -> bool | None:
        torque = operating_torque_pu(x)
        if x.w_pu is None or torque is None or fam.holds_zero_speed(drive):
            return None
        if not isinstance(fam, Linearizable):
            return None
        try:  # a drive its family does not linearize (a firmware variant) refuses it
            lin = fam.linearize(
                drive, reviewed(), np.array([x.w_pu * drive.w_base]), np.array([torque * drive.T_N])
            )
        except CapabilityError:
            return None
        return bool(np.nanmax(lin.max_real) > 0)

    return family, unstable


def entry(sc: Scenario, j: Judged, causes: Sequence[Named], label: str) -> Check:
    """The check of one judged scenario (report.json ``time_domain``), its failures with their causes."""
    cap = f"{sc.title} ({sc.source}), re-run with the gains under review ({label})."
    if j.untested:
        cap += f" Not tested sensorless: {j.untested}."
    if j.failed:
        cap += " Failed: " + "; ".join(j.failed) + "."
    if open_loop_in(j.metrics):
        cap += " Grey: the open-loop I-f start has the loop."
    failures: list[FailureRecord] = [
        {
            **{k: v for k, v in dataclasses.asdict(x).items() if v is not None},
            "cause": c.cause,
            "cause_title": c.title,
            "detail": c.detail,
            "fix": c.fix,
        }
        for x, c in zip(j.failures, causes, strict=True)
    ]
    return {
        "name": sc.name,
        "title": sc.title,
        "source": sc.source,
        "crosses_zero": crosses_zero(sc),
        "passed": not j.failed,
        "status": "fail" if j.failed else "warn" if j.untested else "pass",
        "sensorless": not j.untested,
        "untested": j.untested,
        "failed": j.failed,
        "failures": failures,
        "causes": sorted({c.cause for c in causes} | ({"not_tested_sensorless"} if j.untested else set())),
        "problems": j.problems,
        "metrics": j.metrics,
        "limits": dict(LIMITS),
        "caption": cap,
    }


def open_loop_in(metrics: Metrics) -> bool:
    """Whether a run had the open-loop I-f start in the loop at some time."""
    return bool(metrics.get("open_loop_s"))


def checks(
    drive: Drive,
    gains: GainSet | None,
    runs: Sequence[Scenario | str],
    label: str,
    progress: Callable[[str], None],
) -> tuple[list[Check], list[Figure]]:
    """Simulate each scenario (a Scenario, or a built-in name or file) with ``gains`` (None: each
    scenario's own choice) and judge it, each failure with its cause (reports/causes.py); (checks,
    figures)."""
    from sensorless.reports.sim_figure import labels, plot_traces

    fam = family_of(drive)
    scales: DriveScales | None = fam.scales(drive) if isinstance(fam, Scaled) else None
    family, unstable = finders(drive, gains)
    out: list[Check] = []
    figs: list[Figure] = []
    for item in runs:
        sc = item if isinstance(item, Scenario) else load_scenario(item, drive)
        progress(f"      simulating {sc.name}: {sc.title}")
        variant = JUDGED_STEP.get()
        if variant is None:  # the run ``sensorless tune`` proved these gains with, where it did
            tr = simulated(drive, sc, gains)
        else:  # the step under review, e.g. the fixed-point one (report --precision fixed)
            with step_variant(variant):
                tr = simulate(drive, sc, gains)
        j = assess(tr, sc, drive.w_base, scales)
        check = entry(sc, j, classify_all(j.failures, family, unstable), label)
        out.append(check)
        make = functools.partial(plot_traces, tr, sc.figure, f"{drive.name}: {sc.title}")
        figs.append(Figure(svg_later(make, labels(tr, sc.figure)), check["caption"]))
    return out, figs


def findings(td: Sequence[Check]) -> list[Finding]:
    """Verdict findings of the checks that failed (what, where, its cause and the change that fixes it)
    and of those that did not test the observer (why)."""
    out: list[Finding] = []
    for c in td:
        if not c["passed"]:
            why = [cause_clause(x) for x in c["failures"]]
            out.append(
                {
                    "issue": "time-domain check failed",
                    "check": c["name"],
                    "causes": c.get("causes", []),
                    "text": f"time-domain check {c['name']} ({c['title']}) failed: " + "; ".join(why),
                }
            )
        elif c.get("untested"):
            fix = CATALOGUE["not_tested_sensorless"].fix
            out.append(
                {
                    "issue": "not tested sensorless",
                    "check": c["name"],
                    "causes": ["not_tested_sensorless"],
                    "text": f"time-domain check {c['name']} ({c['title']}) not tested sensorless: "
                    f"{c['untested']} (fix: {fix})",
                }
            )
    return out


def cause_clause(x: FailureRecord) -> str:
    """A failure of a check (report.json ``failures``) with its cause and fix, for a finding."""
    detail = f": {x['detail']}" if x.get("detail") else ""
    return f"{x['text']} ({x['cause_title']}{detail}; fix: {x['fix']})"


def lost(td: Sequence[Check]) -> bool:
    """Whether a check did not hold at all (diverged or lost the rotor position)."""
    return any(c["problems"] for c in td)


STATUS_ORDER = ("pass", "warn", "fail")


def check_status(c: Status) -> str:
    """A check's own status: "fail" where it failed, "warn" where it passed without testing the observer
    (not tested sensorless), else "pass"."""
    return "fail" if not c["passed"] else "warn" if c.get("untested") else "pass"


def status_with(status: str, td: Sequence[Check]) -> str:
    """A verdict's status with the checks (one rule): any failed check makes it "fail", a check not
    tested sensorless at best "warn"."""
    return worst_status(status, *(check_status(c) for c in td))


def worst_status(*statuses: str) -> str:
    """The worst of verdict statuses (STATUS_ORDER)."""
    return max(statuses, key=STATUS_ORDER.index)


def section(number: int, td: Sequence[Check], figs: list[Figure], left_out: Sequence[str] = ()) -> Section:
    """The report section of the checks; ``left_out``: what they do not check (:func:`limitations`)."""
    title = f"{number}. Time-domain checks"
    notes = tuple(Paragraph(x) for x in left_out)
    if not td:
        none = Paragraph("No time-domain simulation results are included in this report.")
        return Section(title, (none, *notes))
    rows = []
    for item in td:
        m = item["metrics"]
        share = m.get("open_loop_fraction")
        rows.append(
            (
                f"{item['name']}: {item['title']}",
                {"pass": "pass", "warn": "not sensorless", "fail": "FAIL"}[check_status(item)],
                num(m["duration_s"]),
                f"{num(m['open_loop_s'])} ({100 * share:.0f} %)" if share is not None else "none",
                num(m.get("rms_theta_err_deg")),
                num(m.get("max_abs_theta_err_deg")),
                num(m.get("max_abs_speed_err_rad_s")),
                num(m.get("final_speed_err_rad_s")),
                ", ".join(item.get("causes", [])) or "-",
            )
        )
    header = (
        "scenario",
        "check",
        "simulated (s)",
        "open loop (s, share)",
        "RMS position error, closed loop (deg)",
        "max |position error|, closed loop (deg)",
        "max |speed error| (rad/s)",
        "final speed error (rad/s)",
        "cause",
    )
    limits = (
        f"A check passes when the run holds (finite, no rejected samples, rotor position not lost), the peak "
        f"position error stays within {LIMITS['max_abs_theta_err_deg']:g} deg, the final speed-estimation "
        f"error within {LIMITS['final_speed_err_pu']:g} p.u. and, in speed control, the final speed within "
        f"{LIMITS['final_tracking_err_pu']:g} p.u. of its reference; and only where the observer had the "
        "loop: a run whose open-loop I-f start never handed over, had the loop for more than "
        f"{100 * MAX_OPEN_LOOP_SHARE:g} % of the time or ended in it is not tested sensorless (at best a "
        "warning). The position errors are the closed loop's (from each handover on); the open-loop part is "
        "its own column and shaded grey in the figures. A failure names its cause (reports/causes.py) and "
        "the change that fixes it."
    )
    table = Table(header, tuple(rows), numeric=frozenset({2, 4, 5, 6, 7}))
    blocks: list[Block] = [Paragraph(limits), *notes, table]
    for c in findings(td):
        blocks.append(Paragraph(c["text"] + ".", "bad" if c["issue"] != "not tested sensorless" else ""))
    return Section(title, (*blocks, *figs))
