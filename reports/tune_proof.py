"""The proof of a tuned gain table before ``sensorless tune`` writes it: the drive as it runs, judged
against the drive file's own gains.

Tuned gains that run worse than the drive file's are a bug, so before a table is written as "tuned"
its gains go through the checks a report holds them to, and the drive file's gains through the same:

- the **linear analysis** over the drive's real range (reports/drive_range.py, the range and analysis
  ``sensorless report`` judges the gains under review on too): speeds +-[0.05, 1] p.u. (both
  directions) x torques {-T_max, -T_N, 0, T_N, T_max} (motoring and regenerating at the torque limit
  the speed loop reaches in every acceleration), the whole sampled drive where the family has a drive
  loop, the family's observer linearization at the saturated loads and without one (:data:`ANALYSIS`);
- the **time-domain checks** of ``sensorless report`` (reports/time_domain.py: a preset's paper
  scenarios, else the generic ones scaled to the drive), each simulated and judged by the same limits.

The tuned gains are *worse* (:func:`worse`) where the drive file's are stable at an envelope point and
they are not, or where a time-domain check's status (reports/time_domain.py ``check_status``: pass, warn,
fail) is worse with them than with the drive file's: they fail a check the drive file's pass, or pass
it only "not tested sensorless" (the I-f start, not the observer, had the loop: a warn) where the drive
file's pass it with the observer in the loop (or they lose the rotor where the drive file's hold it).
The command (reports/cli/tune.py) then falls back to the tuner's next candidate, or exits 3 naming the
point and the check, and writes nothing.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from sensorless.design import forked
from sensorless.design.capabilities import Scaled
from sensorless.design.family import Drive, GainSet
from sensorless.design.linearization import Linearization
from sensorless.design.registry import family_of
from sensorless.design.scenario import Scenario, builtin_names
from sensorless.design.simulate import simulated
from sensorless.reports import time_domain
from sensorless.reports.causes import START_CAUSES, classify_all
from sensorless.reports.drive_range import (  # the range and its analysis, shared with the report
    Combined,
    drive_analysis,
    envelope,
    observer_analysis,
)

# (drive, gains, w [rad/s electrical], torque [N m]) -> the figures (a Linearization, design/linearization.py)
Analysis = Callable[[Drive, GainSet, np.ndarray, np.ndarray], "Linearization | Combined"]
# the analysis ``sensorless tune`` proves with, over the drive's range: reports/drive_range.py, the one
# ``sensorless report`` judges the gains under review on too
ANALYSIS: Analysis = drive_analysis


class ProofCheck(time_domain.Status):
    """One time-domain check of a proof: a scenario judged (reports/time_domain.py ``assess``)."""

    name: str
    failed: list[str]
    problems: list[str]
    metrics: time_domain.Metrics
    causes: list[str]  # the failures' causes (reports/causes.py), as the report names them


@dataclass(frozen=True)
class Proof:
    """One gain set's figures: per envelope point (max Re [1/s], NaN: no equilibrium) and per check."""

    label: str
    w: np.ndarray = field(default_factory=lambda: np.zeros(0))
    torque: np.ndarray = field(default_factory=lambda: np.zeros(0))
    max_real: np.ndarray = field(default_factory=lambda: np.zeros(0))
    worst_damping: float = float("nan")
    checks: tuple[ProofCheck, ...] = ()

    def stable(self) -> np.ndarray:
        """(N,) bool: an equilibrium exists and every pole has Re < 0."""
        with np.errstate(invalid="ignore"):
            return np.isfinite(self.max_real) & (self.max_real < 0)

    def line(self) -> str:
        """One line: the figures of this gain set."""
        td = ", ".join(
            f"{c['name']} {STATUS_WORD[time_domain.check_status(c)]}"
            + (
                f" {c['metrics']['max_abs_theta_err_deg']:.3g} deg"
                if isinstance(c["metrics"].get("max_abs_theta_err_deg"), int | float)
                else ""
            )
            # the closed loop's error above, the open-loop I-f start's part apart (as the report's table)
            + _open_loop(c["metrics"].get("open_loop_fraction"))
            for c in self.checks
        )
        lin = (
            f"worst damping {self.worst_damping:.4f}, stable at {int(self.stable().sum())}/{self.w.size} "
            "points"
            if self.w.size
            else "no linear analysis"
        )
        return f"{self.label}: {lin}; {td or 'no time-domain checks'}"


def _open_loop(share: float | None) -> str:
    """A check's open-loop share, apart from its closed loop's error ("" where the observer had the loop
    throughout)."""
    return f" ({100 * share:.0f} % open loop)" if share else ""


def runs(drive: Drive) -> list[Scenario]:
    """The time-domain checks of ``sensorless report`` on this drive (reports/time_domain.py)."""
    return time_domain.scenarios(drive, builtin_names(drive.kind))


def prove(
    drive: Drive,
    gains: GainSet | None,
    label: str,
    scenarios: Sequence[Scenario],
    analysis: Analysis = observer_analysis,
    progress: Callable[[str], None] = lambda s: None,
    beside: bool = False,
) -> Proof:
    """The figures of ``gains`` (None: the drive file's, each scenario its own choice, as ``report``).
    ``beside``: the linear analysis in a forked child while the simulations run here (design/forked.py;
    a caller with a core to spare: the last proof of ``sensorless tune``)."""
    fam = family_of(drive)
    env = envelope(drive)
    w = t = mr = np.zeros(0)
    wd = float("nan")
    lin: (
        forked.Pending[tuple[np.ndarray, np.ndarray], None]
        | Callable[[], tuple[np.ndarray, np.ndarray]]
        | None
    )
    lin = None
    if env is not None:
        w, t = env
        linear = functools.partial(
            _linear, analysis, drive, gains if gains is not None else fam.gains(drive), w, t
        )
        lin = forked.later(linear) if beside else linear
    checks = _checks(drive, gains, label, scenarios, progress)
    if lin is not None:
        mr, d = lin.result() if isinstance(lin, forked.Pending) else lin()
        wd = float(np.nanmin(d)) if np.isfinite(d).any() else float("nan")
    return Proof(label, w, t, mr, wd, checks)


def _linear(
    analysis: Analysis, drive: Drive, gains: GainSet, w: np.ndarray, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(max Re [1/s], worst damping) of ``gains`` at the points (w, t) by ``analysis``."""
    lin = analysis(drive, gains, w, t)
    return np.asarray(lin.max_real, float), np.asarray(lin.worst_damping, float)


def _checks(
    drive: Drive,
    gains: GainSet | None,
    label: str,
    scenarios: Sequence[Scenario],
    progress: Callable[[str], None],
) -> tuple[ProofCheck, ...]:
    """The time-domain checks of ``gains`` (None: the drive file's), judged as the report judges them."""
    fam = family_of(drive)
    scales = fam.scales(drive) if isinstance(fam, Scaled) else None
    family, unstable = time_domain.finders(drive, gains)
    checks: list[ProofCheck] = []
    for sc in scenarios:
        progress(f"checking {label} gains: simulating {sc.name}")
        tr = simulated(drive, sc, gains)  # kept: the report runs the same checks (design/simulate.py)
        j = time_domain.assess(tr, sc, drive.w_base, scales)  # as the report judges it
        named = classify_all(j.failures, family, unstable) if j.failures else []
        checks.append(
            {
                "name": sc.name,
                "passed": not j.failed,
                "failed": j.failed,
                "problems": j.problems,
                "metrics": j.metrics,
                "untested": j.untested,
                "causes": sorted({n.cause for n in named}),
            }
        )
    return tuple(checks)


def failed_in_the_start(proof: Proof) -> list[str]:
    """The names of the time-domain checks ``proof``'s gains fail (status fail; a warn is not a failure)
    with a cause of the I-f start (START_CAUSES)."""
    return [
        c["name"]
        for c in proof.checks
        if time_domain.check_status(c) == "fail" and START_CAUSES & set(c.get("causes", ()))
    ]


def worse(tuned: Proof, base: Proof, w_base: float) -> list[str]:
    """What the tuned gains do worse than the drive file's (module docstring), one clause each naming
    the point or the check; empty: no worse."""
    out = []
    if tuned.w.size and base.w.size:
        lost = base.stable() & ~tuned.stable()
        if lost.any():
            k = np.flatnonzero(lost)
            j = int(k[np.argmax(np.nan_to_num(tuned.max_real[k], nan=np.inf))])
            mr = tuned.max_real[j]
            out.append(
                f"linear analysis: unstable at w = {tuned.w[j] / w_base:+.3f} p.u., "
                f"T = {tuned.torque[j]:+.4g} N m "
                + (f"(max Re {mr:+.3g} 1/s)" if np.isfinite(mr) else "(no equilibrium)")
                + f" and at {k.size - 1} more of the {tuned.w.size} points where the drive file's gains "
                "are stable"
            )
    was = {c["name"]: c for c in base.checks}
    for c in tuned.checks:
        b = was.get(c["name"])
        if b is None:
            continue
        st, bst = RANK[time_domain.check_status(c)], RANK[time_domain.check_status(b)]
        if st > bst or (c["problems"] and not b["problems"]):
            why = f" (cause: {', '.join(c['causes'])})" if c.get("causes") else ""
            what = (
                "; ".join(c["failed"]) + why
                if c["failed"]
                else f"not tested sensorless: {c['untested']}"
                if c.get("untested")
                else "; ".join(c["problems"])
            )
            theirs = {0: "pass it", 1: "pass it only without the observer in the loop", 2: "fail it too"}[bst]
            out.append(f"time-domain check {c['name']}: {what} (the drive file's gains {theirs})")
    return out


# a check's status, worst last (reports/time_domain.py check_status): a check the tuned gains pass only
# with the I-f start in the loop ("not tested sensorless", a warn) is worse than one the drive file's
# gains pass with the observer in the loop
RANK = {s: k for k, s in enumerate(time_domain.STATUS_ORDER)}
STATUS_WORD = {"pass": "pass", "warn": "warn (not tested sensorless)", "fail": "FAIL"}
