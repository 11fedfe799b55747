"""Settings, constants and candidate gain sets of the flux-observer tuners: the estimate errors, the
firmwares' defaults on a motor (the baselines), the constant law's candidates and the PLL's floor."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from sensorless.design.family import CapabilityError, GainSet
from sensorless.design.pmsm_flux_observer import ERRORS  # default estimate errors (+-)
from sensorless.design.pmsm_flux_observer.gains import law_misfit
from sensorless.design.pmsm_flux_observer.schema import PLL_SPEED_LOOP

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive

KP_T = 0.5  # T k_p at most (ODrive flags T k_p >= 1 as unstable; half of it leaves a margin)


K_GRID = 24  # candidate observer gains (log grid: 1.33 apart on the outrunner)


# points per batched evaluation (a bound on memory, ~1 kB per point): the voltage-scaled law's 112
# candidates x 9 estimate cases x the README skate's 48 points in one batch. The sampled observer's
# damped Newton ends on a few dozen points that take its 200 iterations, at ~1 ms each whatever their
# number: in chunks of 4000 the README skate's tune paid them 13 times (1.8 s of its 10.9 s CPU)
CHUNK = 1 << 16


REFINE = 9  # candidates between the best grid point's neighbours


K_MIN = 20.0  # [1/s] smallest candidate


K_T_MAX = 1.9  # T k at most (the Euler bound is 2)


SLOW_GRID = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0)  # foc_observer_gain_slow candidates


BIAS_MAX_DEG = 15.0


# the observer's own modes decay at least this multiple of the drive's speed-loop bandwidth alpha_s (it
# settles at least as fast as the speed loop it feeds); the PLL's slower root at least PLL_SPEED_LOOP x
DECAY_SHARE = 1.0


NOISE_INDEX = {"position": 0, "speed": 1}  # --max-noise outputs: the PLL's angle and speed


VESC_DEFAULT = {"foc_observer_gain_slow": 0.05, "foc_pll_kp": 2000.0, "foc_pll_ki": 30000.0}


ODRIVE_DEFAULT = {"observer_gain": 1000.0, "pll_bandwidth": 1000.0}


@dataclass(frozen=True)
class FluxTuneSettings:
    """Envelope (the drive's), estimate errors and the bias limit."""

    errors: dict[str, float] = field(default_factory=lambda: dict(ERRORS))
    bias_max_deg: float = BIAS_MAX_DEG
    hold_speed: float | None = None  # [rad/s]; None: the firmware defaults' best limit
    bound: bool = False
    pareto: int = 0  # points of the damping-versus-bias front (``pareto_<law>.csv``); 0: none
    # RMS noise of the PLL's estimates at most, ((output, limit), ...): position [rad], speed [rad/s]
    max_noise: tuple[tuple[str, float], ...] = ()
    decay_share: float = DECAY_SHARE  # observer decay >= decay_share x alpha_s
    min_damping: float = 0.0  # worst damping required (``--min-damping``); 0: none (not the criterion's)


def default_settings(drive: FluxObserverDrive) -> FluxTuneSettings:
    return FluxTuneSettings()


def corners(errors: dict[str, float]) -> list[dict[str, float]]:
    """Nominal and every corner of the error box: factors on R_s, psi_pm, L_d = L_q."""
    out = [{"R_s": 1.0, "psi_pm": 1.0, "L": 1.0}]
    for r, f, L in itertools.product((-1, 1), repeat=3):
        out.append(
            {"R_s": 1 + r * errors["R_s"], "psi_pm": 1 + f * errors["psi_pm"], "L": 1 + L * errors["L"]}
        )
    return out


def vesc_detection(drive: FluxObserverDrive) -> GainSet:
    """VESC Tool's detection on this motor: gain 1e-3/lambda^2 stored x1e6, its PLL and slow gain."""
    raw = 1e3 / drive.estimate.psi_pm**2
    values = {"foc_observer_gain": raw, **VESC_DEFAULT}
    return GainSet("voltage-scaled", values, "VESC Tool detection defaults")


def odrive_defaults() -> GainSet:
    """ODrive's default gains (a firmware baseline), in the ``constant`` law."""
    return GainSet("constant", dict(ODRIVE_DEFAULT), "ODrive defaults")


def constant_candidate(drive: FluxObserverDrive, k: float) -> GainSet:
    """The ``constant`` law's candidate of observer gain ``k`` [1/s], its PLL at the tuners' rule."""
    T = drive.observer.T_obs
    bw = min(max(k, pll_floor(drive)), KP_T / (2 * T))
    return GainSet("constant", {"observer_gain": k, "pll_bandwidth": bw}, "candidate")


def pll_floor(drive: FluxObserverDrive) -> float:
    """The slowest PLL root [1/s] the drive's speed loop allows: PLL_SPEED_LOOP x its bandwidth."""
    return PLL_SPEED_LOOP * float(drive.control.alpha_s)


def k_grid(drive: FluxObserverDrive) -> np.ndarray:
    return np.geomspace(K_MIN, K_T_MAX / drive.observer.T_obs, K_GRID)


def check_variant(drive: FluxObserverDrive, law: str) -> None:
    """CapabilityError (one line, before any work) where ``law`` cannot be tuned for the drive's observer
    variant (design/pmsm_flux_observer/gains.py ``law_misfit``): never a table its export refuses."""
    why = law_misfit(drive, law)
    if why:
        raise CapabilityError(why)
