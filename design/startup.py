"""The open-loop I-f start of a drive (symbolic/startup.py) with its numbers: rules and runtime set-up.

The rules (each with its reason; :func:`if_values`):

- current amplitude i_if = T_max / k_t (k_t: torque per ampere, peak): the torque limit's current, so
  that rated load is carried at a load angle acos(T_N/T_max) (48 deg at T_max = 1.5 T_N), well below
  the 90 deg at which the rotor falls out of step;
- acceleration a = ACC_SHARE p (T_max - T_N) / J: half what the torque margin over rated load gives
  the rotor, so that it follows the current vector with margin;
- handover speed w_on = ON_FACTOR (2) w_min and back to open loop below w_off = w_min, w_min the minimum
  sensorless speed at rated load (design/low_speed.py): the observer takes over only where its
  criteria hold with margin, and the band between is the hysteresis.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from sensorless.design.runtime import RuntimeSetup
from sensorless.symbolic.startup import with_startup

ACC_SHARE = 0.5
ON_FACTOR = 2.0


def if_values(T_N: float, T_max: float, J: float, p: int, k_t: float, w_min: float) -> dict[str, float]:
    """The I-f start's parameters (module docstring); speeds electrical [rad/s]."""
    return {
        "if_i": T_max / k_t,
        "if_acc": ACC_SHARE * p * (T_max - T_N) / J,
        "if_w_on": ON_FACTOR * w_min,
        "if_w_off": w_min,
    }


def with_if_start(setup: RuntimeSetup, values: dict[str, float]) -> RuntimeSetup:
    """``setup`` with its observer wrapped in the I-f start (symbolic/startup.py) and its parameters."""
    obs = with_startup(setup.observer)
    params: dict[str, Any] = {**setup.params, **values}
    obs.check_params(params)
    notes = (
        *setup.notes,
        f"I-f start: handover at {values['if_w_on']:.4g} rad/s, back below {values['if_w_off']:.4g} rad/s",
    )
    return dataclasses.replace(setup, observer=obs, params=params, notes=notes)
