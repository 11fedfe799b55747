"""How the reduced-order observer's steady state depends on the discretization and the sampling period.

For each scheme (symbolic/pmac_reduced_order/step.DISCRETIZATIONS) and sampling period, the discrete
observer is run at the operating points until settled (linearize.analyze) and its
steady-state errors and dominant poles are compared with the continuous-time observer, which has no
steady-state error and the poles of the continuous linearization. The reference for "small" is the
error that load-torque estimation removes: the steady speed error of the observer without it,
e_w = -p_r (T_L + B omega) / (J g) (docs/families/pmac_reduced_order.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from sensorless.design.pmac_reduced_order.linearize import analyze

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive


@dataclass(frozen=True)
class StudyRow:
    """One scheme x sampling period x operating point."""

    method: str
    T_s: float  # [s]
    rpm: float  # mechanical speed [r/min]
    T_L: float  # load [N m]
    err_w: float  # steady speed error with load estimation [rad/s, electrical]
    err_theta: float  # steady position error [rad, electrical]
    err_T: float  # steady load-torque error (T_L + B omega - T_L_hat) [N m]
    ripple_w: float  # peak-to-peak speed error [rad/s]
    effect_w: float  # |speed error without load estimation|, continuous time [rad/s]
    slow_c: float  # slowest continuous pole, real part [1/s]
    slow_d: float  # slowest discrete pole ln(z)/T_s, real part [1/s]


def discretization_study(
    drive: PmacDrive,
    methods: Sequence[str],
    sampling: Sequence[float],
    rpm: Sequence[float],
    loads: Sequence[float],
    progress: Callable[[str], None] | None = None,
) -> list[StudyRow]:
    """Rows for every method x T_s x (speed, load); each (method, T_s) is one batched analysis."""
    rpm_g, T_g = (
        a.ravel() for a in np.meshgrid(np.asarray(rpm, float), np.asarray(loads, float), indexing="ij")
    )
    w = drive.rpm_to_w(rpm_g)
    T_tot = T_g + drive.motor.B * w / drive.motor.p_r
    effect = np.abs(drive.motor.p_r * T_tot / (drive.estimate.J * drive.observer.g))
    rows: list[StudyRow] = []
    for T_s in sampling:
        for m in methods:
            if progress:
                progress(f"{m} at {T_s * 1e6:g} us")
            r = analyze(drive, w, T_g, method=m, T_s=T_s)
            for k in range(w.size):
                rows.append(
                    StudyRow(
                        m,
                        T_s,
                        float(rpm_g[k]),
                        float(T_g[k]),
                        float(r.err_w[k]),
                        float(r.err_theta[k]),
                        float(r.err_T[k]),
                        float(r.ripple_w[k]),
                        float(effect[k]),
                        float(r.poles[k].real.max()),
                        float(r.poles_discrete[k].real.max()),
                    )
                )
    return rows
