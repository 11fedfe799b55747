"""Minimum sensorless speed versus load of any family's design, from its linearization.

Below some speed every sensorless observer stops being good enough: its linearized error dynamics lose
damping or decay (the adaptive flux observer's regenerating band near zero speed, Piippo et al. 2008
Sec. IV), or the rotor angle it derives from a vanishing back-EMF is biased by the parameter-estimate
errors or buried in the current sensor's noise (every EMF-based observer: the angle error of an EMF
estimate grows as 1/w). :func:`minimum_speed` finds that speed, w_min(T), over the torque range
[-T_N, T_N], with nothing but the family contract (design/family.py):

- the family's linearization (``ObserverFamily.linearize``) at the gains under review, with the
  options the family names for this analysis (``ObserverFamily.low_speed_options``: e.g. its HF
  injection where the drive injects, its noise model), at the drive file's estimates, or scaled by
  ``errors`` (factors on its ``estimate_keys``, ``ObserverFamily.with_estimate_errors``);
- per point, four criteria, each a limit the caller states: worst damping >= ``min_damping``;
  decay rate >= ``min_decay`` (default: a tenth of the speed-loop bandwidth of ``DriveScales``: an
  observer much slower than the speed loop it feeds drives that loop on a lagging estimate);
  |angle bias| <= ``max_bias`` (default 30 deg electrical: the torque still has cos 30 deg = 87 % of
  its command);
  RMS angle noise from the current-sensor noise <= ``max_bias / 3`` (three standard deviations within
  the same limit). On the whole sampled drive the damping and decay asked are no more than
  FLOOR_SHARE (90 %) of the drive's own at REFERENCE_PU (0.5 p.u.) and the same torque (a mode as
  weak at every speed is no low-speed limit), and no less than stability: where the drive is unstable
  at 0.5 p.u. each point must be stable (``WholeDrive.floors``). A criterion the family's
  linearization does not give (``Linearization.angle_bias`` or ``angle_noise`` None, or NaN at every
  point: e.g. the reduced-order family's bias, computed only where the estimates differ from the
  motor) is not applied, and the result says which were;
- w_min(T) = the lowest speed from which every speed up to the highest one that meets all four (at
  most 1 p.u.) meets all four (w_min = 1 p.u. where no speed does): a dense logarithmic grid
  (batched linearizations over speeds x torques, walked from the top speed down), then bisection of
  the highest failing grid interval (design/low_speed_search.py). Speeds are positive; the torques
  take both signs, so motoring (T > 0) and regenerating (T < 0) are both covered, as an observer of a
  PMSM is symmetric under (w, T) -> (-w, -T).

:func:`minimum_speed_under` judges a design under the estimate errors its family states for it
(``ObserverFamily.estimate_errors``, a box of +- errors): every criterion at the drive file's
estimates, and at every corner a stable equilibrium (damping, decay >= 0) with the bias and noise
within their limits; w_min is the highest of the cases (a corner's search leaves a torque once its w_min
is shown to be no higher than the cases' before it: it cannot change the highest, nor, ties going to
the earlier case, what limits it).

The rated-load value (``w_min_rated``) is the larger of the two at +T_N and -T_N. Where the criteria
hold down to the grid's floor (:data:`FLOOR_PU`), w_min = 0: no lower limit found (the headline says
"down to the analysis' floor", not that the observer holds zero speed). Where the family declares
that its observer does not run through zero speed (``DriveScales.zero_speed``, e.g. an EMF observer at
exact estimates: no bias, and the noise criterion met down to the floor), the headline says that the
floor is no verified minimum speed and quotes the family (``LowSpeed.declared``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypedDict, Unpack

import numpy as np
from numpy.typing import ArrayLike
from sensorless.design.family import (
    Drive,
    EstimateErrors,
    EstimateScaling,
    GainSet,
    Linearizable,
    Scaled,
    require,
)
from sensorless.design.linearization import Linearization
from sensorless.design.low_speed_search import CRITERIA, search
from sensorless.design.memo import by_content, uncached
from sensorless.design.registry import family_of
from sensorless.design.runtime import double_step_active

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.drive_analysis import DriveLinearization

MAX_BIAS_DEG = 30.0  # default angle-bias limit [deg electrical]
FLOOR_PU = 1e-3  # lowest speed analysed [p.u.]; criteria met down to it: the design holds zero speed
N_SPEEDS = 40  # logarithmic grid FLOOR_PU .. 1 p.u.
N_TORQUES = 9  # -T_N .. T_N
BISECTIONS = 8  # each halves the bracket in log speed: 3/39 decade (19 %) / 2^8, about 0.07 %


class SpeedOptions(TypedDict, total=False):
    """The keywords of :func:`minimum_speed` that :func:`minimum_speed_under` passes on to each case."""

    max_bias: float
    min_decay: float | None
    n_speeds: int
    n_torques: int
    bisections: int
    acceleration: bool
    observer_only: bool


# (w, T) -> the figures the criteria judge at those points
Analyse = Callable[[np.ndarray, np.ndarray], "Linearization | WholeDrive"]


QUICK: SpeedOptions = {"n_speeds": 16, "n_torques": 5, "bisections": 6}  # `sensorless report --quick`
DECAY_SHARE = 0.1  # default required decay: this share of the speed-loop bandwidth
REFERENCE_PU = 0.5  # the whole drive's own damping and decay, away from low speed, are taken here
FLOOR_SHARE = 0.9  # a point fails below this share of them


@dataclass(frozen=True)
class LowSpeed:
    """w_min(T) of a design and what limits it (module docstring)."""

    torque: np.ndarray  # (K,) [N m]
    w_min: np.ndarray  # (K,) [rad/s electrical]; 0: the criteria hold down to FLOOR_PU
    limited_by: tuple[str, ...]  # (K,) the criterion that fails just below w_min ("" where 0)
    w_base: float
    T_N: float
    pole_pairs: int
    min_damping: float
    min_decay: float
    max_bias: float  # [rad]
    max_noise: float  # [rad rms]
    applied: tuple[str, ...]  # the criteria the family's linearization gives
    holds_zero: bool = False  # the family says its observer holds zero speed by itself (HF injection)
    declared: str = ""  # the family's DriveScales.zero_speed: why it does not run through zero speed
    errors: str = ""  # the estimate errors judged (EstimateErrors.text; "": the drive file's estimates)
    errors_source: str = ""  # where they are stated
    basis: str = ""  # what was linearized: the whole drive, or the observer alone and why
    # [rad/s^2] the largest speed change at rated load, p (T_max + T_N) / J, whose lag the criteria
    # include (each load's own: braking_acceleration); 0: none
    acceleration: float = 0.0
    # ``acceleration`` is the speed reference's ramp (DriveScales.speed_ramp, below the full braking)
    ramped: bool = False

    @property
    def rated(self) -> int:
        """Index of the worse of +-T_N."""
        ends = [0, len(self.torque) - 1]
        return ends[int(np.argmax(self.w_min[ends]))]

    @property
    def w_min_rated(self) -> float:
        """w_min at rated load [rad/s]: the larger of motoring and regenerating."""
        return float(self.w_min[self.rated])

    @property
    def rated_limited_by(self) -> str:
        return self.limited_by[self.rated]

    def rpm(self, w: float) -> float:
        """Mechanical r/min of electrical speed ``w``."""
        return w / self.pole_pairs * 30 / np.pi

    def data(self) -> dict[str, Any]:
        """report.json's ``low_speed``."""
        return {
            "w_min_rated_pu": float(self.w_min_rated / self.w_base),
            "w_min_rated_rpm": float(self.rpm(self.w_min_rated)),
            "limited_by": self.rated_limited_by,
            "curve": [
                {
                    "T_Nm": float(t),
                    "T_pu": float(t / self.T_N),
                    "w_min_pu": float(w / self.w_base),
                    "limited_by": lim,
                }
                for t, w, lim in zip(self.torque, self.w_min, self.limited_by, strict=True)
            ],
            "criteria": {
                "min_damping": self.min_damping,
                "min_decay_per_s": self.min_decay,
                "max_bias_deg": float(np.degrees(self.max_bias)),
                "max_noise_deg_rms": float(np.degrees(self.max_noise)),
                "applied": list(self.applied),
            },
            "floor_pu": FLOOR_PU,
            "analysis": self.basis,
            "acceleration_rad_per_s2": self.acceleration,
            "declared_limit": self.declared,
            "estimate_errors": {"box": self.errors, "source": self.errors_source},
        }


@dataclass(frozen=True)
class WholeDrive:
    """The low-speed criteria's figures from the whole sampled drive (design/drive_analysis.py): its
    poles (damping and decay, each no worse than required or than 90 % of the drive's own at 0.5 p.u.
    where that is less, and stable: :meth:`floors`), its steady angle error (the bias) and its lag
    under ``acceleration``; the angle noise from the family's observer-only linearization (None: not
    applied)."""

    lin: DriveLinearization
    mid: tuple[np.ndarray, np.ndarray]  # worst damping and decay of the drive at REFERENCE_PU, same torques
    observer: Linearization | None  # the family's (for the noise)
    acceleration: np.ndarray | float  # [rad/s^2], per point (or one for all)

    @property
    def worst_damping(self) -> np.ndarray:
        return self.lin.worst_damping

    def low_speed_decay(self) -> np.ndarray:
        return self.lin.decay

    def floors(self) -> tuple[np.ndarray, np.ndarray]:
        """The damping and decay below which a point fails where they are below the required ones: a
        share FLOOR_SHARE of the drive's own at REFERENCE_PU and the same torque (a mode as weak at
        every speed, e.g. of the controllers, is no low-speed limit: the report's pole sections judge
        it), and never below 0. Where the drive is unstable at REFERENCE_PU (its figure there negative,
        or NaN: no fixed point) that figure is no reference (a share of a negative one would be
        stricter than the figure itself, failing every speed, and would let a point unstable by less
        pass): each point must then be stable (damping and decay not below 0) besides meeting the bias,
        noise and acceleration criteria; the instability at REFERENCE_PU is the report's pole
        sections' to judge, and a band of it above w_min lifts w_min no more than any failing band
        (:func:`minimum_speed` takes the highest passing speed)."""
        z, d = (np.nan_to_num(FLOOR_SHARE * np.asarray(x, float), nan=0.0) for x in self.mid)
        return np.maximum(z, 0.0), np.maximum(d, 0.0)

    def angle_bias(self) -> np.ndarray:
        return self.lin.theta_err

    def angle_noise(self) -> np.ndarray | None:
        return None if self.observer is None else self.observer.angle_noise()

    def angle_lag(self) -> np.ndarray:
        return self.lin.lag(self.acceleration)


def full_acceleration(drive: Drive) -> float:
    """a_max [rad/s^2 electrical]: what the torque margin over rated load gives the rotor, p (T_max -
    T_N) / J (the family's DriveScales); 0 where it gives none."""
    fam = family_of(drive)
    if not isinstance(fam, Scaled):
        return 0.0
    sc = fam.scales(drive)
    return float(sc.pole_pairs * max(0.0, sc.T_max - sc.T_N) / sc.J)


def required_decay(drive: Drive) -> float:
    """The decay rate [1/s] the low-speed criteria ask by default (:func:`minimum_speed`, and so the I-f
    handover's w_min, design/startup.py): DECAY_SHARE of the speed-loop bandwidth of the family's
    DriveScales (an observer much slower than the speed loop it feeds drives that loop on a lagging
    estimate); 0 without scales."""
    fam = family_of(drive)
    return DECAY_SHARE * float(fam.scales(drive).alpha_s) if isinstance(fam, Scaled) else 0.0


def handover_decay(drive: Drive) -> float:
    """The decay rate [1/s] the I-f handover's w_min asks (:func:`required_decay`); 0 where the drive has
    no I-f start: its family holds zero speed by itself (e.g. HF injection, design/pmsm_drive.py)."""
    return 0.0 if family_of(drive).holds_zero_speed(drive) else required_decay(drive)


def braking_acceleration(drive: Drive, torque: ArrayLike) -> np.ndarray:
    """The largest speed change [rad/s^2 electrical] of the drive running at load ``torque`` [N m]: its
    speed loop at the torque limit against the load's direction, the load helping, p (T_max + |T|) / J
    (braking a motoring load, or driving against a regenerating one: the speed steps' approach to zero
    speed; accelerating against the load gives only p (T_max - |T|) / J), or the speed reference's ramp
    where the drive has one and it is lower (``DriveScales.braking``); 0 without scales."""
    fam = family_of(drive)
    if not isinstance(fam, Scaled):
        return np.zeros(np.shape(torque))
    return np.asarray(fam.scales(drive).braking(torque), float)


def _analysis(
    drive: Drive, gains: GainSet, opts: Mapping[str, Any], acceleration: bool, observer: bool = False
) -> tuple[Analyse, str]:
    """(w, T) -> the figures the criteria judge, and what is linearized (one line)."""
    from sensorless.design.drive_analysis import drive_loop, linearize_drive

    fam = family_of(drive)

    def observer_only(w: np.ndarray, T: np.ndarray) -> Linearization:
        return require(fam, Linearizable).linearize(drive, gains, w, T, **opts)

    if observer:
        return observer_only, "the observer alone (asked)"
    if fam.holds_zero_speed(drive):
        return (
            observer_only,
            "the observer alone (its own zero-speed means, e.g. HF injection, run at low speed)",
        )
    try:
        dl = drive_loop(drive, gains)
    except ValueError as e:  # CapabilityError, or a loop its scenario cannot be simulated on (said)
        return observer_only, f"the observer alone ({e})"

    # the drive at REFERENCE_PU, once per torque over the whole search (the grid's blocks and every
    # bisection step ask for the same torques; each point's Newton iteration is its own, so a point's
    # figures do not depend on the batch it is computed in)
    mid_of: dict[float, tuple[float, float]] = {}
    # the observer-only linearization serves only the noise criterion: where the family's linearization
    # (its class, the same at every call) keeps the base class's angle_noise, which gives none, it is
    # not computed again (the pmsm_flux_observer family: more than half of this analysis' time)
    noise: list[bool] = []

    def whole(w: np.ndarray, T: np.ndarray) -> WholeDrive:
        obs: Linearization | None
        if not noise:
            obs = observer_only(w, T)
            noise.append(type(obs).angle_noise is not Linearization.angle_noise)
        else:
            obs = observer_only(w, T) if noise[0] else None
        Tb = np.broadcast_arrays(np.asarray(w, float), np.asarray(T, float))[1].ravel()
        torques, back = np.unique(Tb, return_inverse=True)
        new = np.array([t for t in torques if float(t) not in mid_of])
        if new.size:
            mid = linearize_drive(drive, gains, REFERENCE_PU * drive.w_base, new, dl)
            pairs = zip(mid.worst_damping.tolist(), mid.decay.tolist(), strict=True)
            mid_of.update(zip(new.tolist(), pairs, strict=True))
        figs = np.array([mid_of[float(t)] for t in torques]).reshape(-1, 2)
        return WholeDrive(
            linearize_drive(drive, gains, w, T, dl),
            (figs[back, 0], figs[back, 1]),
            obs,
            braking_acceleration(drive, Tb) if acceleration else 0.0,
        )

    basis = "the whole sampled drive (design/drive_analysis.py)" + (f"; {dl.note}" if dl.note else "")
    return whole, basis


# the same drive at the same gains is analysed again within a process (the I-f start's rules at every
# simulation set-up, the tune line and the report under the same errors) and in the next one (the
# README flow's report, for the gains its tune proved): design/memo.py
@by_content(maxsize=64, when=double_step_active, disk=True)
def minimum_speed(
    drive: Drive,
    gains: GainSet,
    *,
    min_damping: float,
    max_bias: float = np.radians(MAX_BIAS_DEG),
    min_decay: float | None = None,
    errors: Mapping[str, float] | None = None,
    n_speeds: int = N_SPEEDS,
    n_torques: int = N_TORQUES,
    bisections: int = BISECTIONS,
    acceleration: bool = False,
    observer_only: bool = False,
    bound: np.ndarray | None = None,
    known: frozenset[str] = frozenset(),
) -> LowSpeed:
    """w_min(T) of ``drive`` with ``gains`` (module docstring); ``max_bias`` [rad], ``errors``: factors
    on the family's estimate keys (None: the drive file's estimates); the grid (``n_speeds`` x
    ``n_torques``) and ``bisections`` set the resolution (:data:`QUICK`: previews and tests);
    ``acceleration``: the angle error under the drive's largest speed change at each load
    (:func:`braking_acceleration`) is judged too (the handover's w_min, design/startup.py);
    ``observer_only``: the family's observer-only linearization (the paper's analysis) instead of the
    whole drive; ``bound``, ``known``: a caller's pruning (:func:`minimum_speed_under`'s corners; see
    design/low_speed_search.py ``search``: w_min at or below ``bound`` is any value there, the
    criteria applied leave out ``known``'s)."""
    fam = family_of(drive)
    if errors:
        drive = require(fam, EstimateScaling).with_estimate_errors(drive, errors)
    scales = fam.scales(drive) if isinstance(fam, Scaled) else None
    if min_decay is None:
        min_decay = required_decay(drive)
    crit = {"damping": min_damping, "decay": min_decay, "bias": max_bias, "noise": max_bias / 3}
    # the acceleration at rated load (the headline's figure; each point is judged at its own load's)
    a_max = float(braking_acceleration(drive, drive.T_N)) if acceleration else 0.0
    if acceleration:
        crit["acceleration"] = a_max
    opts = fam.low_speed_options(drive)
    analyse, basis = _analysis(drive, gains, opts, acceleration, observer_only)
    wb, TN = drive.w_base, drive.T_N
    w = wb * np.logspace(np.log10(FLOOR_PU), 0.0, n_speeds)
    T = TN * np.linspace(-1.0, 1.0, n_torques)
    w_min, cause, given = search(analyse, w, T, crit, bisections, bound, known)
    return LowSpeed(
        torque=T,
        w_min=w_min,
        limited_by=tuple(CRITERIA[int(i)] if i >= 0 else "" for i in cause),
        w_base=wb,
        T_N=TN,
        pole_pairs=drive.pole_pairs,
        min_damping=min_damping,
        min_decay=min_decay,
        max_bias=max_bias,
        max_noise=max_bias / 3,
        applied=tuple(c for c in CRITERIA if c in given),
        holds_zero=fam.holds_zero_speed(drive),
        declared=scales.zero_speed if scales is not None else "",
        basis=basis,
        acceleration=a_max,
        ramped=scales is not None and 0 < scales.speed_ramp <= a_max,
    )


# the tune line and the report ask for the same drive under the same errors (design/memo.py)
@by_content(maxsize=16, when=double_step_active, disk=True)
def minimum_speed_under(
    drive: Drive, gains: GainSet, errors: EstimateErrors, *, min_damping: float, **kw: Unpack[SpeedOptions]
) -> LowSpeed:
    """:func:`minimum_speed` (keywords ``kw``) under the estimate errors ``errors`` (the family's
    ``estimate_errors``): every criterion at the drive file's estimates, and at every corner of the box
    the observer keeps a stable equilibrium (damping and decay >= 0, not the required values: the
    damping under errors is a robustness figure, not a low-speed limit) with its angle bias and noise
    within their limits, as the tuners judge gains under errors (tuning/conditions.py, the flux
    tuner's "holds"). Per torque the highest w_min of the cases and what limits it there ("stability"
    where a corner has no stable equilibrium)."""
    runs = [minimum_speed(drive, gains, min_damping=min_damping, **kw)]
    corner: SpeedOptions = {**kw, "min_decay": 0.0}
    # a corner matters only where its w_min is above every earlier case's (ties: the earlier case), and
    # for the criteria applied only where it gives one no earlier case gives: its search leaves a torque
    # once its w_min is shown to be at or below the cases' so far (search), with the same max and argmax.
    # Not memoized: a corner's search, pruned by the cases before it, is asked for once
    corner_speed = uncached(minimum_speed)
    for c in errors.cases()[1:]:
        top = np.max([r.w_min for r in runs], axis=0)
        known = frozenset(a for r in runs for a in r.applied)
        runs.append(corner_speed(drive, gains, min_damping=0.0, errors=c, bound=top, known=known, **corner))
    w = np.stack([r.w_min for r in runs])
    worst = np.argmax(w, axis=0)  # ties: the first, the drive file's estimates

    def cause(j: int, k: int) -> str:
        why = runs[j].limited_by[k]
        return "stability" if j > 0 and why in ("damping", "decay") else why

    return dataclasses.replace(
        runs[0],
        w_min=w.max(axis=0),
        limited_by=tuple(cause(int(j), k) for k, j in enumerate(worst)),
        applied=tuple(c for c in CRITERIA if any(c in r.applied for r in runs)),
        errors=errors.text(),
        errors_source=errors.source if errors else "",
    )


WHAT_TO_DO = {
    "damping": "run the open-loop start (I-f) below it, or retune for more damping at low speed",
    "decay": "run the open-loop start (I-f) below it, or retune for a faster observer at low speed",
    "bias": "run the open-loop start (I-f) below it, or measure the motor parameters more closely",
    "noise": "run the open-loop start (I-f) below it, or use a less noisy current sensor",
    "stability": "run the open-loop start (I-f) below it, or measure the motor parameters more closely",
    "acceleration": "run the open-loop start (I-f) below it, limit the acceleration (ramp the speed "
    "reference, lower T_max) or raise the observer's gains",
}


def headline(ls: LowSpeed) -> str:
    """One line: "sensorless down to X p.u. (Y rpm) at rated load; below: <what to do>"."""
    w = ls.w_min_rated
    if w <= 0 and ls.declared:  # the criteria it gives find no limit; the family states one
        missing = [c for c in CRITERIA if c not in ls.applied]
        return (
            f"no limit found by the linearization down to {FLOOR_PU:g} p.u., the analysis' floor, at rated "
            f"load (criteria it gives: {', '.join(ls.applied)}"
            + (f"; not {', '.join(missing)}" if missing else "")
            + "), which is no verified minimum speed: "
            + ls.declared[0].lower()
            + ls.declared[1:].rstrip(".")
        )
    if w <= 0:
        return (
            f"sensorless down to {FLOOR_PU:g} p.u., the analysis' floor, at rated load{_basis(ls)}: every "
            "criterion holds there, the linearization finds no lower limit"
        )
    why = ls.rated_limited_by
    todo = WHAT_TO_DO[why]
    if ls.holds_zero:  # no open-loop start: the family's own means (injection) carry it below
        todo = todo.replace("run the open-loop start (I-f) below it, or ", "") + (
            " (the observer's own zero-speed means, e.g. HF injection, carry it below: see the time-domain "
            "checks)"
        )
    return (
        f"sensorless down to {w / ls.w_base:.3g} p.u. ({ls.rpm(w):.4g} rpm) at rated load{_basis(ls)}, "
        f"limited by {_CRITERION_TEXT[why](ls)}; below: {todo}"
    )


def _basis(ls: LowSpeed) -> str:
    """Under which estimates the figure holds: the stated errors (every corner), or, where the drive file
    states none, its own estimates, which leave out the angle bias errors cause (a limit found under
    errors, e.g. by a tuner given some on its command line, may lie higher)."""
    if ls.errors:
        return f" under estimate errors {ls.errors} ({ls.errors_source}, every corner)"
    if ls.errors_source:
        return f" (at the drive file's estimates: {ls.errors_source})"
    return " (at the drive file's estimates: it states no estimate errors, so their angle bias is not in it)"


_CRITERION_TEXT = {
    "damping": lambda ls: f"damping < {ls.min_damping:g}",
    "decay": lambda ls: f"decay rate < {ls.min_decay:.4g} 1/s",
    "bias": lambda ls: f"angle bias > {np.degrees(ls.max_bias):.3g} deg",
    "noise": lambda ls: f"angle noise > {np.degrees(ls.max_noise):.3g} deg rms",
    "stability": lambda ls: "stability under the estimate errors (no stable equilibrium at a corner)",
    "acceleration": lambda ls: (
        (
            f"angle error under the speed reference's ramp ([control] speed_ramp = {ls.acceleration:.4g} "
            "rad/s^2, below the full braking) > "
            if ls.ramped
            else f"angle error under the full braking (p (T_max + T_N) / J = {ls.acceleration:.4g} rad/s^2 "
            "at rated load) > "
        )
        + f"{np.degrees(ls.max_bias):.3g} deg"
    ),
}
