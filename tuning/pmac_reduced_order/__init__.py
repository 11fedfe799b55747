"""Tuning hooks of the reduced-order observer: the gain law constant (g, Gamma), by a tuner of its own.

De Angelo et al. (2006). Its poles are Floquet exponents of the sampled observer, so it does not go
through the shared NLP: tuner.py has a closed form and a compass search on the discrete poles.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from sensorless.design.family import later
from sensorless.tuning.family import Tunable, TuningHooks
from sensorless.tuning.pmac_reduced_order.settings import default_settings

# the tuner, imported where it runs: every `tune` lists every family's laws
if TYPE_CHECKING:
    from sensorless.tuning.pmac_reduced_order.tuner import tune_constant_gains
else:
    tune_constant_gains = later(f"{__name__}.tuner", "tune_constant_gains")

HOOKS = TuningHooks(
    tunables=(
        Tunable(
            "constant",
            "constant gains g, Gamma of the reduced-order EMF/load-torque observer, eqs. (9)-(10) of "
            "De Angelo et al. (2006)",
            default_settings,
            tuner=tune_constant_gains,
            columns=(
                (
                    ("n_rpm", "n_rpm"),
                    ("w_rad_s", "w_rad_s"),
                    ("T_L_Nm", "T_L_Nm"),
                    ("g_1_s", "g"),
                    ("Gamma_A2s2", "Gamma"),
                ),
                (("g_1_s", "g"), ("Gamma_A2s2", "Gamma")),
            ),
        ),
    )
)
