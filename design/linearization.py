"""The common result of every family's linearization: poles and their metrics at N operating points.

An operating point is an electrical speed ``w`` [rad/s] and a torque [N m] (``torque_name`` says which:
``T_e`` for families analysed at an electromagnetic torque, ``T_L`` for a load torque). ``poles`` are
the continuous-time poles of the observer's linearized (closed-loop) error dynamics; a family that
analyses the sampled observer that runs also gives ``poles_discrete`` = ln(z)/T_s of the eigenvalues z
of its one-step map. A point where no equilibrium exists has a NaN row. Families return subclasses
with their own extra data (state-space matrices, steady-state errors, ...); commands, tuning and
reports read only what is defined here, a subclass's own data included only as it declares it here:
per-point columns (:meth:`Linearization.point_columns`) and header notes (:meth:`Linearization.notes`)
of the pole tables (reports/pole_map.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sensorless.design.poles import damping_ratio, max_real, worst_damping


@dataclass(frozen=True)
class Linearization:
    """Poles at N operating points (arrays have leading dimension N); see the module docstring."""

    w: np.ndarray  # (N,) electrical speed [rad/s]
    torque: np.ndarray  # (N,) torque of the operating point [N m]
    poles: np.ndarray  # (N, n) continuous-time poles [1/s]; NaN row: no equilibrium
    poles_discrete: np.ndarray | None = None  # (N, n) ln(z)/T_s of the sampled observer [1/s]
    T_s: float | None = None  # sampling period of poles_discrete [s]
    torque_name: str = "T_e"  # "T_e" (electromagnetic) or "T_L" (load)

    def point_columns(self) -> dict[str, np.ndarray]:
        """A family's own per-point columns of the pole tables: heading (``name_unit``) -> (N,) values,
        in order, written after the operating point's speed and torque; none here."""
        return {}

    def notes(self) -> tuple[str, ...]:
        """A family's own header notes of the pole tables ("what: value", e.g. its gain law); none here."""
        return ()

    def angle_bias(self) -> np.ndarray | None:
        """(N,) steady rotor-angle error of the estimate [rad] at each point (under the estimates the
        family was linearized with); None where the family does not give it."""
        return None

    def low_speed_decay(self) -> np.ndarray:
        """(N,) decay rate [1/s] that the minimum-speed analysis requires (design/low_speed.py): that of
        the slowest mode, unless a family knows a mode that does not move its estimates."""
        return self.decay_rate

    def angle_noise(self) -> np.ndarray | None:
        """(N,) RMS rotor-angle error [rad] from the drive's current-sensor noise; None where the
        family was linearized without a noise model."""
        return None

    @property
    def equilibrium(self) -> np.ndarray:
        """(N,) bool: an equilibrium exists (the poles are defined) at the point."""
        return ~np.isnan(self.poles).all(axis=1)

    @property
    def damping(self) -> np.ndarray:
        """(N, n) damping ratio -Re(p)/|p| of each pole; a pole at the origin counts as 0."""
        return damping_ratio(self.poles)

    @property
    def worst_damping(self) -> np.ndarray:
        """(N,) smallest damping ratio (negative: unstable; NaN: no equilibrium)."""
        return worst_damping(self.poles)

    @property
    def max_real(self) -> np.ndarray:
        """(N,) largest real part of the poles [1/s]; > 0 means unstable."""
        return max_real(self.poles)

    @property
    def decay_rate(self) -> np.ndarray:
        """(N,) -max Re(p) [1/s]: the slowest mode's decay rate."""
        return -self.max_real

    def _discrete(self) -> np.ndarray:
        if self.poles_discrete is None:
            raise AttributeError("this linearization has no discrete-time poles")
        return self.poles_discrete

    @property
    def worst_damping_discrete(self) -> np.ndarray:
        """(N,) smallest damping ratio of the discrete-time poles mapped to s."""
        return worst_damping(self._discrete())

    @property
    def decay_rate_discrete(self) -> np.ndarray:
        """(N,) -max Re(ln(z)/T_s) [1/s]."""
        return -max_real(self._discrete())
