"""Tuning hooks of the PLL test family: its gain law ``pll``, one PLL bandwidth at every speed, tuned by
the shared pipeline (tuning/tune.py: global phase, max-min damping NLP, dense re-verification,
tie-break, pointwise bound).

A law of constant gains that are runtime parameters: constant_law.py (beside this) builds its model
from the continuous observer in the rotor frame (design.rotor_loop, the SX the analysis linearizes)
and the box. What is the family's own: which estimates an operating point carries, the box and the
decay floor. With exact estimates the equilibrium (the exact EMF, no angle error, w_i = w) does not
move with w_pll. The envelope is the drive's ``[tuning]`` (design/envelope.py).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from sensorless.design.envelope import TuningSettings
from sensorless.design.rotor_frame import pmsm_plant
from sensorless.tuning.family import Tunable, TuningHooks
from sensorless.tuning.model import TuningModel

from families.pll.constant_law import GainBox, constant_law_model
from families.pll.design import drive_gains, rotor_loop, runtime_params

ESTIMATES = ("R_s", "L", "psi_pm")  # the estimates an operating point carries (PARAMS names)
BOX = (0.1, 20.0)  # default bandwidth box, in units of the drive file's w_pll
# Default decay floor, in units of the drive file's w_pll [1/s]: as fast as the drive file's PLL alone
# (its double pole at -w_pll). Without a floor the worst damping saturates at 1 (all poles real) for
# every bandwidth below about half the drive's and the tie-break takes the smallest, slowest of them,
# which loses the rotor position in the test scenario's load step; with it the tuned law is the best
# damped bandwidth that settles at least this fast.
FLOOR = 1.0


def default_settings(drive: Any) -> TuningSettings:
    """The drive's [tuning] with the box BOX and, unless it sets one, the decay floor FLOOR."""
    s, w = drive.tuning, drive.observer.w_pll
    box = GainBox(("w_pll",), ("rad/s",), (BOX[0] * w,), (BOX[1] * w,))
    return dataclasses.replace(s, min_decay=s.min_decay or FLOOR * w, law=box)


def build(drive: Any, settings: TuningSettings, seed: np.ndarray | None = None) -> TuningModel:
    """The TuningModel of the ``pll`` law on ``drive`` (module docstring)."""
    wb, psi = drive.w_base, drive.estimate.psi_pm
    params = runtime_params(drive, drive_gains(drive))
    x_typical = np.array([wb * psi, wb * psi, 1.0, wb])
    return constant_law_model(
        "pll", rotor_loop(), pmsm_plant(drive.motor), params, settings.law, ESTIMATES, x_typical, True
    )


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
