"""The test family's gain law of constant gains (the same at every speed) that are runtime parameters, for
the shared NLP. (No production family tunes such a law on the NLP: the flux family's constant laws have a
tuner of their own, so this lives with the one family that uses it.)

For a family whose continuous observer is a design/rotor_frame.py :class:`RotorFrameLoop` over its
runtime parameter vector, a law whose gains are some of those parameters, unchanged over the speed
range, needs nothing but their names and box: :func:`constant_law_model` builds its
:class:`~sensorless.tuning.model.TuningModel` (the linearization is the Jacobian of the loop's SX rates,
the equilibria the shared Newton's method, an operating point carries the speed, the torque and the
estimates the family names), and :class:`GainBox` is its law settings (``TuningSettings.law``: the
box, checked, and the gain table's constraints). Because the gains are the same at every speed, the
model of the free gains at one operating point (the pointwise bound's) is the model itself; the
global phase is a log grid over the box; the tie-break prefers gains small against the drive file's.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from sensorless.design.rotor_frame import RotorFrameLoop, equilibrium_points
from sensorless.design.units import DriveFileError
from sensorless.tuning.model import TuningModel

GRID = 41  # points per gain of the global phase's log grid over the box


@dataclass(frozen=True)
class GainBox:
    """The box of a constant law's gains (SI): ``TuningSettings.law``."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]

    def check(self, file: str, prefix: str = "tuning.") -> None:
        """DriveFileError naming ``<gain>_max`` where the box is empty or not positive."""
        for n, lo, hi in zip(self.names, self.lower, self.upper, strict=True):
            if not 0 < lo < hi:
                raise DriveFileError(file, f"{prefix}{n}_max", f"need 0 < {lo:g} < {hi:g}")

    def constraints(self) -> dict[str, Any]:
        """``<gain>_min_<unit>``, ``<gain>_max_<unit>`` of each gain."""
        out: dict[str, Any] = {}
        for n, u, lo, hi in zip(self.names, self.units, self.lower, self.upper, strict=True):
            unit = u.replace("/", "_")
            out |= {f"{n}_min_{unit}": lo, f"{n}_max_{unit}": hi}
        return out


def constant_law_model(
    law: str,
    loop: RotorFrameLoop,
    plant: np.ndarray,
    params: Mapping[str, float],
    box: GainBox,
    estimates: tuple[str, ...],
    x_typical: np.ndarray,
    fixed_equilibrium: bool = False,
) -> TuningModel:
    """The TuningModel of ``law`` (module docstring). ``params``: the drive's runtime parameters by name,
    in the order of the loop's ``p`` (the gains' values are the drive file's, the baseline);
    ``estimates``: the parameters an operating point carries (the estimates, varied by error
    scenarios); ``fixed_equilibrium``: the equilibrium with exact estimates does not move with the
    gains."""
    names, gains = list(params), box.names
    theta0 = np.array([params[g] for g in gains], float)
    nominal = np.array([params[k] for k in estimates], float)

    def p_of(th: Any, est: Any) -> list[Any]:
        given = {**{g: th[i] for i, g in enumerate(gains)}, **{k: est[i] for i, k in enumerate(estimates)}}
        return [given.get(n, params[n]) for n in names]

    n_th = len(gains)
    theta, phi = ca.SX.sym("theta", n_th), ca.SX.sym("phi", n_th)
    x, pt = ca.SX.sym("x", loop.n_x), ca.SX.sym("point", 2 + len(estimates))
    f_r = loop.rates(x, pt[0], pt[1], plant, ca.vertcat(*p_of(phi, pt[2:])))
    local = ca.Function(f"{law}_local", [theta, pt], [theta], ["theta", "point"], ["phi"])
    linear = ca.Function(
        f"{law}_closed_loop", [phi, x, pt], [ca.jacobian(f_r, x), f_r], ["phi", "x", "point"], ["A", "x_dot"]
    )

    def equilibrium(th: np.ndarray, P: np.ndarray) -> np.ndarray:
        N = P.shape[1]
        th = np.asarray(th, float).reshape(n_th, -1)  # one theta, or one per point
        p = np.vstack([np.broadcast_to(np.asarray(r, float), (N,)) for r in p_of(th, P[2:])])
        return equilibrium_points(loop, P[0], P[1], plant, p).x.T

    def make_points(w: np.ndarray, T: np.ndarray, est: np.ndarray) -> np.ndarray:
        w_b, T_b = np.broadcast_arrays(np.asarray(w, float), np.asarray(T, float))
        return np.vstack([w_b.ravel(), T_b.ravel(), np.repeat(np.asarray(est, float)[:, None], w_b.size, 1)])

    def starts() -> np.ndarray:
        axes = [np.geomspace(lo, hi, GRID) for lo, hi in zip(box.lower, box.upper, strict=True)]
        return np.array(list(itertools.product(*axes)), float)

    def per_speed(th: np.ndarray, w: np.ndarray) -> np.ndarray:
        return np.tile(np.asarray(th, float).reshape(1, n_th), (np.size(w), 1))

    model: TuningModel | None = None

    def itself() -> TuningModel:
        assert model is not None
        return model

    model = TuningModel(
        law=law,
        names=gains,
        units=box.units,
        theta0=theta0,
        lower=np.array(box.lower, float),
        upper=np.array(box.upper, float),
        typical=np.abs(theta0),
        local=local,
        phi_typical=np.abs(theta0),
        linearization=linear,
        x_typical=np.asarray(x_typical, float),
        point_names=("w", "T_e", *estimates),
        make_points=make_points,
        equilibrium=equilibrium,
        regularizer=None,
        table_gains=lambda th: {g: float(th[i]) for i, g in enumerate(gains)},
        point_gains=lambda th, w: {g: np.full(np.size(w), float(th[i])) for i, g in enumerate(gains)},
        nominal_estimate=nominal,
        estimate_names=estimates,
        fixed_equilibrium=(lambda P: np.all(P[2:] == nominal[:, None], axis=0))
        if fixed_equilibrium
        else None,
        starts=starts,
        pointwise=itself,
        pointwise_gains=per_speed,
        gain_size=lambda th: np.max(np.abs(np.atleast_2d(np.asarray(th, float))) / np.abs(theta0), axis=1),
        gain_size_unit="drive file's gains",
        gain_size_meaning="the largest gain in units of the drive file's",
    )
    return model
