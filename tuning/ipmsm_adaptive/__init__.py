"""Tuning hooks of the adaptive observer: the laws speed-dependent (eq. (16)) and schedule, by the shared NLP.

The speed-dependent law is the default on the preset (the paper's law), schedule on a drive of the user's own.

Piippo, Hinkkanen, Luomi (2008). Builders of the TuningModels: laws.py. Settings: the drive's
``[tuning]`` section (design/envelope.py; the laws' own keys in design/ipmsm_adaptive/law_settings.py).
"""

from __future__ import annotations

from typing import Any

from sensorless.tuning.family import Tunable, TuningHooks
from sensorless.tuning.ipmsm_adaptive.laws import build_schedule, build_speed_dependent

_POINTS = (
    ("w_m_pu", "w_m_pu"),
    ("w_m_rad_s", "w_m_rad_s"),
    ("T_e_Nm", "T_e_Nm"),
    ("lambda1_ohm", "lambda1"),
    ("lambda2_ohm", "lambda2"),
)
_BASELINE = (("lambda1_ohm", "lambda1"), ("lambda2_ohm", "lambda2"))


def _settings(drive: Any) -> Any:
    """The drive's [tuning] settings (defaults where the section is absent)."""
    return drive.tuning


HOOKS = TuningHooks(
    tunables=(
        Tunable(
            "speed-dependent",
            "the speed-dependent gain, eq. (16) of Piippo, Hinkkanen, Luomi (2008): lambda', "
            "omega_lambda (optionally alpha_fo)",
            _settings,
            build=build_speed_dependent,
            columns=(_POINTS, _BASELINE),
        ),
        Tunable(
            "schedule",
            "free speed schedule: (lambda1, lambda2) at speed breakpoints, linear in between",
            _settings,
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
