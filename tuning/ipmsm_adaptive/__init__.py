"""Tuning hooks of the adaptive observer: the laws speed-dependent (eq. (16)) and schedule, by the shared NLP.

The speed-dependent law is the default on the preset (the paper's law), schedule on a drive of the user's own.

Piippo, Hinkkanen, Luomi (2008). Builders of the TuningModels: laws.py. Settings: the drive's
``[tuning]`` section (design/envelope.py; the laws' own keys in design/ipmsm_adaptive/law_settings.py).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

from sensorless.design.family import later
from sensorless.design.ipmsm_adaptive.law_settings import law_settings
from sensorless.tuning.family import Tunable, TuningHooks

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive

# the builders, imported where a law is tuned: every `tune` lists every family's laws
if TYPE_CHECKING:
    from sensorless.tuning.ipmsm_adaptive.laws import build_schedule, build_speed_dependent
else:
    build_schedule, build_speed_dependent = later(
        f"{__name__}.laws", "build_schedule", "build_speed_dependent"
    )

_POINTS = (
    ("w_m_pu", "w_m_pu"),
    ("w_m_rad_s", "w_m_rad_s"),
    ("T_e_Nm", "T_e_Nm"),
    ("lambda1_ohm", "lambda1"),
    ("lambda2_ohm", "lambda2"),
)
_BASELINE = (("lambda1_ohm", "lambda1"), ("lambda2_ohm", "lambda2"))


def _full_range(drive: IpmsmDrive) -> Any:
    """The drive's [tuning] settings, their torques widened to the drive's torque limit +-T_max where
    they stop short of it: the speed loop applies +-T_max in every acceleration (motoring and
    regenerating), and gains tuned at +-T_N only were unstable just beyond it (piippo2008's schedule:
    max Re +1.5 .. +11 1/s at T_max = 1.57 T_N for |w| >= 0.3 p.u., the rotor lost in fig9b)."""
    s = drive.tuning
    return dataclasses.replace(s, envelope=s.resolved.widened(drive.control.T_max))


def _paper_or_full(drive: IpmsmDrive) -> Any:
    """The paper's law on its own preset keeps the preset's envelope and tunes as the paper does (it
    reproduces Piippo et al. 2008: tuned at +-T_N, alpha_fo fixed, no bound on the angle lag); on any
    other drive it tunes over the full range too (``_full_range``), with the law's defaults."""
    s = dataclasses.replace(drive.tuning, envelope=drive.envelope)
    if str(drive.file).startswith("preset:"):
        paper = dataclasses.replace(law_settings(s), tune_alpha_fo=False, hold_lag=False)
        s = dataclasses.replace(s, law=paper)
    return s


HOOKS = TuningHooks(
    tunables=(
        Tunable(
            "speed-dependent",
            "the speed-dependent gain, eq. (16) of Piippo, Hinkkanen, Luomi (2008): lambda', "
            "omega_lambda (optionally alpha_fo)",
            _paper_or_full,
            build=build_speed_dependent,
            columns=(_POINTS, _BASELINE),
        ),
        Tunable(
            "schedule",
            "free speed schedule: (lambda1, lambda2) at speed breakpoints, linear in between",
            _full_range,
            build=build_schedule,
            seed="speed-dependent",
            columns=(_POINTS, _BASELINE),
        ),
    ),
    # on a drive of the user's own the schedule is the default: never worse than the speed-dependent
    # law on the dense grid, it reaches the pointwise bound where that law leaves damping
    # (docs/tuning.md); the preset keeps the speed-dependent law, the paper's
    own_default="schedule",
)
