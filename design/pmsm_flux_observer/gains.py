"""Gains of the flux-observer family in each firmware's terms, and the runtime set-up they give.

Laws (docs/families/pmsm_flux_observer.md "Gains"), named by what the observer gain does:
- ``constant``: observer_gain = gamma lambda^2 [1/s] and pll_bandwidth [rad/s], k_p = 2 bw, k_i = bw^2
  (ODrive's terms, its sensorless_estimator: gamma = observer_gain / lambda^2, k_i = k_p^2 / 4);
- ``voltage-scaled``: foc_observer_gain (raw as VESC stores it), foc_observer_gain_slow, foc_pll_kp,
  foc_pll_ki (VESC's terms); run-time k = gamma lambda^2 = 4 foc_observer_gain lambda^2
  max(foc_observer_gain_slow, |duty| V_bus / 40 V), |duty| V_bus = sqrt(3) |u| (so u_ref = 40 V / sqrt(3));
- ``schedule``: observer_gain (gamma lambda^2) a table over |PLL speed| (``speeds``, linear in
  between, held beyond the ends), and pll_bandwidth. (Law names are each family's own: the adaptive
  observer's ``schedule`` is another law.)
Former names (``odrive``, ``vesc``, ``flux_schedule``) are read from drive files, gain tables and
``tune --law`` for one release, with a note (laws.py ``LAW_ALIASES``).

The laws' keys and their reader are laws.py (the drive file's schema reads its [gains] there).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import casadi as ca
from sensorless.design.family import GainSet
from sensorless.design.gain_table import GainTableError
from sensorless.design.pmsm_flux_observer.laws import parse_law, section_gains
from sensorless.design.runtime import GainSchedule, RuntimeSetup
from sensorless.design.units import DriveFileError
from sensorless.symbolic.pmsm_flux_observer.observer import runtime_observer
from sensorless.symbolic.runtime import Field

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive

# the voltage-scaled law's constants: VESC's run-time schedule (docs/families/pmsm_flux_observer.md)
SCALED_GAIN_FACTOR = 4.0  # gamma = 4 foc_observer_gain max(slow, |duty| V_bus / 40 V) (factor 5 before 2020)
SCALED_U_REF = 40.0 / math.sqrt(3)  # [V]: |duty| V_bus / 40 V = |u| / this


def drive_gains(drive: FluxObserverDrive) -> GainSet:
    """The drive file's [gains]."""
    return section_gains(drive.gains_table, drive.file)


def table_values(
    law: str, gains: Mapping[str, Any], where: str, T_obs: float | None = None
) -> dict[str, Any]:
    """The SI gains of a gain table of ``law`` (design/law_gains.py ``table_gains`` checks kind and law);
    ``T_obs``: the drive's observer period, which the observer gain must suit (laws.py ``check_euler``)."""
    try:
        return parse_law(law, {"law": law, **gains}, where, "gains", T_obs, "the drive's observer.T_obs")
    except DriveFileError as e:
        raise GainTableError(f"{where}: key '{e.key}': {e.problem}") from None


def pll_gains(gains: GainSet) -> tuple[float, float]:
    """(k_p [1/s], k_i [1/s^2]) of a gain set."""
    v = gains.values
    if gains.law == "voltage-scaled":
        return float(v["foc_pll_kp"]), float(v["foc_pll_ki"])
    bw = float(v["pll_bandwidth"])
    return 2 * bw, bw**2


def base_gain(gains: GainSet, psi_hat: float) -> float:
    """k_0 [1/s]: gamma lambda^2 before VESC's voltage factor (constant: observer_gain; voltage-scaled:
    4 raw lambda^2)."""
    v = gains.values
    if gains.law == "voltage-scaled":
        return SCALED_GAIN_FACTOR * float(v["foc_observer_gain"]) * psi_hat**2
    return float(v["observer_gain"])


@functools.cache
def table_law(grid: tuple[float, ...]) -> ca.Function:
    """(w_pll, values[K]) -> k_0: piecewise linear over |w_pll| on ``grid``, held beyond the ends."""
    w, v = ca.SX.sym("w_pll"), ca.SX.sym("k", len(grid))
    x = ca.fmin(ca.fmax(ca.fabs(w), grid[0]), grid[-1])
    out = 0 * w
    for k in range(len(grid)):
        up = (x - grid[k - 1]) / (grid[k] - grid[k - 1]) if k > 0 else 1
        down = (grid[k + 1] - x) / (grid[k + 1] - grid[k]) if k < len(grid) - 1 else 1
        out = out + v[k] * ca.fmax(0, ca.fmin(up, down))
    return ca.Function(f"k_schedule{len(grid)}", [w, v], [out], ["w_pll", "gain"], ["lam"])


@functools.cache
def constant_law() -> ca.Function:
    w, v = ca.SX.sym("w_pll"), ca.SX.sym("k", 1)
    return ca.Function("k_constant", [w, v], [v[0] + 0 * w], ["w_pll", "gain"], ["lam"])


def schedule_of(gains: GainSet, psi_hat: float) -> GainSchedule:
    """The runtime schedule of k_0: a constant, or the table over |w_pll|."""
    if gains.law == "schedule":
        grid = tuple(float(w) for w in gains.values["speeds"])
        vals = tuple(float(k) for k in gains.values["observer_gain"])
        fields = tuple(
            Field(f"k_0_{j}", "1/s", f"observer gain at |w_pll| = {w:.6g} rad/s") for j, w in enumerate(grid)
        )
        return GainSchedule("schedule", table_law(grid), vals, fields, grid, "gamma lambda^2 over |w_pll|")
    k_0 = base_gain(gains, psi_hat)
    text = "constant gamma lambda^2" if gains.law == "constant" else "4 gain lambda^2 (x VESC's factor)"
    return GainSchedule(gains.law, constant_law(), (k_0,), (Field("k_0", "1/s", "observer gain"),), (), text)


def runtime_params(drive: FluxObserverDrive, gains: GainSet) -> dict[str, float]:
    """The parameters of the runtime step (symbolic PARAMS)."""
    e = drive.estimate
    k_p, k_i = pll_gains(gains)
    v = gains.values
    return {
        "R_s": e.R_s,
        "L_d": e.L_d,
        "L_q": e.L_q,
        "psi_pm": e.psi_pm,
        "k_slow": float(v.get("foc_observer_gain_slow", 1.0)),
        "u_ref": SCALED_U_REF,
        "scheduled": 1.0 if gains.law == "voltage-scaled" else 0.0,
        "adapt": 1.0 if drive.observer.lambda_adaptation else 0.0,
        "k_p": k_p,
        "k_i": k_i,
        "T_s": drive.observer.T_obs,
        "w_max": 2 * max(drive.envelope.speed_max, drive.w_base),
        "u_max": drive.control.u_dc,
    }


def runtime_setup(
    drive: FluxObserverDrive, gains: GainSet, discretization: str | None = None
) -> RuntimeSetup:
    """The runtime observer of ``drive`` (its variant) with ``gains``."""
    o = drive.observer
    obs = runtime_observer(o.correction, o.inductance_rule)
    disc = discretization or obs.discretizations[0]
    if disc not in obs.discretizations:
        raise ValueError(f"unknown discretization {disc!r} (known: {', '.join(obs.discretizations)})")
    params = runtime_params(drive, gains)
    obs.check_params(params)
    notes: tuple[str, ...] = ()
    if o.correction == "box-clamp":
        notes = ("box-clamp: the observer gain is unused (pure integration, each axis clamped to +-lambda)",)
    return RuntimeSetup(obs, disc, params, gains, schedule_of(gains, drive.estimate.psi_pm), notes)


def law_misfit(drive: FluxObserverDrive, law: str) -> str:
    """Why gains of ``law`` cannot be tuned for the drive's observer variant ("" where they can): the
    box clamp has no observer gain and no linearization (nothing for a tuner to judge), and the
    voltage-scaled law's gain is VESC's ORTEGA_ORIGINAL (the clamped gradient), which its export writes
    and the other variants do not run (VESC has no unclamped gradient observer)."""
    o = drive.observer
    where = f"{drive.file}: [observer] firmware = {o.firmware!r}, correction = {o.correction!r}"
    if o.correction == "box-clamp":
        return (
            f"{where}: the box clamp (MXLEMMING) has no observer gain and no linearization, so there is "
            f"nothing to tune for law {law!r}; for VESC's tunable observer set correction = "
            '"clamped-gradient" (ORTEGA_ORIGINAL, foc_observer_type 0), or judge the box clamp by '
            "sensorless report"
        )
    if law == "voltage-scaled" and o.correction != "clamped-gradient":
        return (
            f"{where}: law 'voltage-scaled' tunes VESC's clamped-gradient observer (ORTEGA_ORIGINAL), which "
            "`export --target vesc` writes; this drive runs the unclamped gradient observer, which VESC "
            "does not have: write the drive for VESC (sensorless init --firmware vesc, or [observer] "
            'firmware = "vesc" with correction = "clamped-gradient"), or tune --law constant'
        )
    return ""
