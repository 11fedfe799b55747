"""Tuning hooks of the PLL test family: its gain law ``pll``, one PLL bandwidth at every speed, tuned by
the shared pipeline (tuning/tune.py: global phase, max-min damping NLP, dense re-verification,
tie-break, pointwise bound).

What is the family's own is only its :class:`~sensorless.tuning.model.TuningModel` (``build``) and the
bandwidth box it adds to the shared settings (:class:`PllLawSettings`); the envelope is the drive's
``[envelope]``. The model's closed loop is the continuous observer (1)-(3) of symbolic.py on the
motor in steady state, in the rotor frame (design.rotor_frame_rates: the SX the analysis linearizes);
an operating point carries the speed, the torque and the observer's estimates R_s, L, psi_pm. With
exact estimates the equilibrium (the exact EMF, no angle error, w_i = w) does not move with w_pll.
The law is the same at every speed, so its model of the free gain at one operating point (the
pointwise bound's) is the model itself: the bound at a speed is the best worst damping over the
torques that any bandwidth reaches there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.batch import evaluate_batch
from sensorless.design.envelope import Envelope, TuningSettings
from sensorless.design.units import DriveFileError
from sensorless.tuning.family import Tunable, TuningHooks
from sensorless.tuning.model import TuningModel

from families.pll.design import (
    drive_gains,
    equilibrium_function,
    motor_vector,
    rotor_frame_rates,
    runtime_params,
)
from families.pll.symbolic import N_OBS, PARAMS

ESTIMATES = ("R_s", "L", "psi_pm")  # the estimates an operating point carries (PARAMS names)
BOX = (0.1, 20.0)  # default bandwidth box, in units of the drive file's w_pll
# Default decay floor, in units of the drive file's w_pll [1/s]: as fast as the drive file's PLL alone
# (its double pole at -w_pll). Without a floor the worst damping saturates at 1 (all poles real) for
# every bandwidth below about half the drive's and the tie-break takes the smallest, slowest of them,
# which loses the rotor position in the test scenario's load step; with it the tuned law is the best
# damped bandwidth that settles at least this fast.
FLOOR = 1.0
GRID = 41  # bandwidths of the global phase (log grid over the box)


@dataclass(frozen=True)
class PllLawSettings:
    """The bandwidth box of the ``pll`` law (``TuningSettings.law``)."""

    w_min: float  # [rad/s]
    w_max: float  # [rad/s]

    def check(self, file: str, prefix: str = "tuning.") -> None:
        """DriveFileError naming the bound."""
        if not 0 < self.w_min < self.w_max:
            raise DriveFileError(
                file, f"{prefix}bandwidth_max", f"need 0 < {self.w_min:g} < {self.w_max:g} rad/s"
            )

    def constraints(self) -> dict[str, Any]:
        return {"w_pll_min_rad_s": self.w_min, "w_pll_max_rad_s": self.w_max}


def default_settings(drive: Any) -> TuningSettings:
    """The drive's [envelope] as the shared envelope (p.u. speeds, torques in T_N), the decay floor
    FLOOR and the box BOX."""
    e, wb, w = drive.envelope, drive.w_base, drive.observer.w_pll
    env = Envelope(
        speed_min=e.speed_min / wb,
        speed_max=e.speed_max / wb,
        speeds=e.speeds,
        torques_TN=tuple(t / drive.T_N for t in e.torques),
    )
    return TuningSettings(envelope=env, min_decay=FLOOR * w, law=PllLawSettings(BOX[0] * w, BOX[1] * w))


def build(drive: Any, settings: TuningSettings, seed: np.ndarray | None = None) -> TuningModel:
    """The TuningModel of the ``pll`` law on ``drive`` (module docstring)."""
    law = settings.law
    assert isinstance(law, PllLawSettings)
    w0, wb, psi = float(drive.observer.w_pll), drive.w_base, drive.estimate.psi_pm
    fixed = runtime_params(drive, drive_gains(drive))  # every parameter but the gain and the estimates
    names = [f.name for f in PARAMS]
    motor = motor_vector(drive)
    nominal = np.array([fixed[k] for k in ESTIMATES])  # the runtime names of the estimates

    def params(w_pll: Any, est: Any) -> list[Any]:
        """The runtime parameters in PARAMS order, w_pll and the estimates given."""
        given = {"w_pll": w_pll, **{k: est[i] for i, k in enumerate(ESTIMATES)}}
        return [given[n] if n in given else fixed[n] for n in names]

    theta, phi = ca.SX.sym("theta", 1), ca.SX.sym("phi", 1)
    x, pt = ca.SX.sym("x", N_OBS), ca.SX.sym("point", 2 + len(ESTIMATES))
    f_r = rotor_frame_rates()(x, pt[0], pt[1], motor, ca.vertcat(*params(phi[0], pt[2:])))
    local = ca.Function("pll_local", [theta, pt], [theta], ["theta", "point"], ["phi"])
    linear = ca.Function(
        "pll_closed_loop", [phi, x, pt], [ca.jacobian(f_r, x), f_r], ["phi", "x", "point"], ["A", "x_dot"]
    )
    newton = equilibrium_function()

    def equilibrium(th: np.ndarray, P: np.ndarray) -> np.ndarray:
        """Equilibria (n_x, N) by Newton's method on the SX equations; NaN where it does not converge."""
        N = P.shape[1]
        w_pll = np.asarray(th, float)[0]  # theta (1,) or one per point (1, N)
        p = np.vstack([np.broadcast_to(np.asarray(r, float), (N,)) for r in params(w_pll, P[2:])])
        xs, _, res = evaluate_batch(newton, N, [P[0], P[1], motor, p])
        x0 = xs[:, :, 0].T
        ok = res[:, 0, 0] <= 1e-9 * np.maximum(np.abs(x0).max(axis=0), 1.0)
        return np.where(ok, x0, np.nan)

    def make_points(w: np.ndarray, T: np.ndarray, est: np.ndarray) -> np.ndarray:
        w_b, T_b = np.broadcast_arrays(np.asarray(w, float), np.asarray(T, float))
        return np.vstack([w_b.ravel(), T_b.ravel(), np.repeat(np.asarray(est, float)[:, None], w_b.size, 1)])

    model: TuningModel | None = None

    def itself() -> TuningModel:
        assert model is not None
        return model

    model = TuningModel(
        law="pll",
        names=("w_pll",),
        units=("rad/s",),
        theta0=np.array([w0]),
        lower=np.array([law.w_min]),
        upper=np.array([law.w_max]),
        typical=np.array([w0]),
        local=local,
        phi_typical=np.array([w0]),
        linearization=linear,
        x_typical=np.array([wb * psi, wb * psi, 1.0, wb]),
        point_names=("w", "T_e", *ESTIMATES),
        make_points=make_points,
        equilibrium=equilibrium,
        regularizer=None,
        table_gains=lambda th: {"w_pll": float(th[0])},
        point_gains=lambda th, w: {"w_pll": np.full(np.size(w), float(th[0]))},
        nominal_estimate=nominal,
        estimate_names=ESTIMATES,
        fixed_equilibrium=lambda P: np.all(P[2:] == nominal[:, None], axis=0),
        starts=lambda: np.geomspace(law.w_min, law.w_max, GRID)[:, None],
        pointwise=itself,
        pointwise_gains=lambda th, w: np.full((np.size(w), 1), float(th[0])),
        gain_size=lambda th: np.atleast_2d(np.asarray(th, float))[:, 0] / w0,
        gain_size_unit="drive w_pll",
        gain_size_meaning="the PLL bandwidth in units of the drive file's",
    )
    return model


_LEAD = (("w_m_pu", "w_m_pu"), ("w_m_rad_s", "w_m_rad_s"), ("T_e_Nm", "T_e_Nm"), ("w_pll_rad_s", "w_pll"))

HOOKS = TuningHooks(
    tunables=(
        Tunable(
            "pll",
            "back-EMF PLL observer: one PLL bandwidth w_pll at every speed",
            default_settings,
            build=build,
            columns=(_LEAD, (("w_pll_rad_s", "w_pll"),)),
        ),
    )
)
