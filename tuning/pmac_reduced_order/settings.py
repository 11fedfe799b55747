"""Settings and search box of the constant-gain tuner: envelope grids, gain bounds and the closed form.

The closed form and the Gamma box come from the hand-derived characteristic polynomial of the
sinusoidal continuous-time model, (s + g)(s^2 + g s + Gamma (Phi_1/J)^2) (tuner.py, step 1).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from sensorless.design.envelope import SpeedRule
from sensorless.tuning.family import TuningError

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive

G_MAX_FACTOR = 100.0  # search box g <= 100 g (drive): the noise limit decides, not this
NOISE_FACTOR = 2.0  # default noise limit: the position noise of the drive's gains times this
MIN_FACTOR = 0.01  # default lower bounds: 1 % of the drive's g (and of its Gamma, see gamma_box)


@dataclass(frozen=True)
class ConstantGainSettings:
    """Envelope, bounds and constraint of the constant law."""

    speeds_rpm: tuple[float, ...]  # mechanical speeds [r/min], nonzero
    loads_Nm: tuple[float, ...]  # load torques [N m]
    g_min: float  # [1/s]
    g_max: float  # [1/s]
    Gamma_min: float  # [A^2 s^2]
    Gamma_max: float  # [A^2 s^2]
    min_damping: float = 1 / math.sqrt(2)
    dense_factor: int = 4
    # (output, limit SI) pairs; None: NOISE_FACTOR x the drive's gains' position noise; (): no limit
    max_noise: tuple[tuple[str, float], ...] | None = None
    # the whole sampled drive's constraint (objective.py drive_check); False: the observer's poles alone
    # (what the paper's analysis judges; the tests of the observer-only search use it)
    whole_drive: bool = True
    # the tuner of its own computes neither a pointwise bound nor a damping-versus-noise front
    bound: ClassVar[bool] = False
    pareto: ClassVar[int] = 0

    def noise_limits(self) -> np.ndarray:
        """[position rad, speed rad/s] limits (inf: none); needs resolved ``max_noise``."""
        lim = dict(self.max_noise or ())
        return np.array([lim.get("position", np.inf), lim.get("speed", np.inf)], float)

    def check(self, file: str) -> None:
        """Clear errors naming the option."""
        if self.dense_factor < 4:
            raise TuningError(f"{file}: --dense-factor: must be >= 4, got {self.dense_factor}")
        if not 0 <= self.min_damping < 1:
            raise TuningError(f"{file}: --min-damping: must be in [0, 1), got {self.min_damping:g}")
        if not 0 < self.g_min < self.g_max:
            raise TuningError(
                f"{file}: --g-max: need 0 < g_min = {self.g_min:g} < g_max = {self.g_max:g} 1/s"
            )
        if not 0 < self.Gamma_min < self.Gamma_max:
            raise TuningError(
                f"{file}: --Gamma-max: need 0 < Gamma_min = {self.Gamma_min:g} < "
                f"Gamma_max = {self.Gamma_max:g}"
            )
        if not self.speeds_rpm or any(s == 0 for s in self.speeds_rpm) or not self.loads_Nm:
            raise TuningError(f"{file}: [envelope]: need nonzero speeds and at least one load")


def critical_gamma(drive: PmacDrive, g: float) -> float:
    """Gamma that makes s^2 + g s + Gamma (Phi_1/J)^2 critically damped: (g J / (2 Phi_1))^2."""
    return (g * drive.estimate.J / (2 * drive.estimate.Phi[0])) ** 2


def gamma_box(drive: PmacDrive, g_min: float, g_max: float, Gamma0: float) -> tuple[float, float]:
    """Default Gamma bounds for g in [g_min, g_max] (docs/families/pmac_reduced_order.md, "Tuning").

    Gamma acts through c = Gamma (Phi_1/J)^2 against g^2 (the quadratic s^2 + g s + c), so its
    scale is (J/Phi_1)^2 g^2, not the drive's Gamma (which may sit anywhere on 0 < c <= g^2/4):
    upper bound c = g_max^2 (the quadratic's damping 1/2 at g_max), lower bound critical damping at
    g_min (c = g_min^2/4); both widened to keep the drive's Gamma (1 % of it) inside.
    """
    lo = critical_gamma(drive, g_min)
    if Gamma0 > 0:
        lo = min(lo, MIN_FACTOR * Gamma0)
    return lo, max(4 * critical_gamma(drive, g_max), Gamma0)


def default_settings(drive: PmacDrive) -> ConstantGainSettings:
    """The drive's [envelope], bounds around its [observer] gains (g) and their scale (Gamma)."""
    o = drive.observer
    g_min, g_max = MIN_FACTOR * o.g, G_MAX_FACTOR * o.g
    Gamma_min, Gamma_max = gamma_box(drive, g_min, g_max, float(o.Gamma))
    return ConstantGainSettings(
        speeds_rpm=tuple(float(s) for s in drive.envelope.rule.listed),
        loads_Nm=tuple(float(t) for t in drive.envelope.torque_values),
        g_min=g_min,
        g_max=g_max,
        Gamma_min=Gamma_min,
        Gamma_max=Gamma_max,
    )


def speed_grid(speeds_rpm: tuple[float, ...], factor: int = 1) -> np.ndarray:
    """Sorted speeds [r/min]; ``factor`` > 1 refines each interval between speeds of the same sign
    (never across standstill, where the EMF observer is undefined)."""
    return SpeedRule(listed=speeds_rpm).native(factor)


def load_grid(loads_Nm: tuple[float, ...], factor: int = 1) -> np.ndarray:
    """Sorted loads [N m]; ``factor`` > 1 refines each interval."""
    T = np.unique(np.asarray(loads_Nm, float))
    if factor == 1 or T.size == 1:
        return T
    return np.concatenate([*(np.linspace(a, b, factor + 1)[:-1] for a, b in itertools.pairwise(T)), T[-1:]])


def grid(settings: ConstantGainSettings, factor: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Flat (speed [r/min], load [N m]) of the speed x load grid (load-major)."""
    n, T = np.meshgrid(speed_grid(settings.speeds_rpm, factor), load_grid(settings.loads_Nm, factor))
    return n.ravel(), T.ravel()


def closed_form(drive: PmacDrive, g_max: float, Gamma_max: float) -> tuple[float, float]:
    """(g*, Gamma*) of the sinusoidal continuous-time model (tuner.py docstring, step 1)."""
    k = drive.estimate.Phi[0] / drive.estimate.J  # Phi_1 / J: c = Gamma k^2
    g = min(g_max, 2 * math.sqrt(Gamma_max) * k)
    return g, (g / (2 * k)) ** 2


def limits_text(st: ConstantGainSettings) -> str:
    """The noise limits for messages: 'position <= 0.1 deg el.'."""
    parts = []
    assert st.max_noise is not None, "resolved settings"  # default_settings resolves it
    for name, v in st.max_noise:
        parts.append(
            f"{name} <= {math.degrees(v):.4g} deg el." if name == "position" else f"{name} <= {v:.4g} rad/s"
        )
    return ", ".join(parts) or "no limit"
