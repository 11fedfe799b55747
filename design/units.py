"""Unit-checked quantities for drive descriptions: parse "3.59 ohm", "400 Hz", "1 pu" to SI.

A value in a drive TOML is either a bare number, read as the SI unit of the key's dimension, or a
string "<number> <unit>". The unit must belong to the key's dimension, so a resistance given in henry
is rejected instead of silently mis-scaled. Angular speeds and bandwidths are in electrical rad/s;
"Hz" on an angular quantity means 2*pi*f, and "pu" means a multiple of the drive's base angular speed.
"""

from __future__ import annotations

import math
import re

# dimension -> {unit spelling: factor to SI}; "pu" and "R_s_hat" are resolved by the caller.
UNITS: dict[str, dict[str, float]] = {
    "resistance": {"ohm": 1.0, "Ohm": 1.0, "Ω": 1.0, "mohm": 1e-3, "mOhm": 1e-3, "mΩ": 1e-3},
    "inductance": {"H": 1.0, "mH": 1e-3, "uH": 1e-6, "µH": 1e-6, "μH": 1e-6},
    "flux": {"Vs": 1.0, "V s": 1.0, "Wb": 1.0, "mVs": 1e-3, "mWb": 1e-3},
    "voltage": {"V": 1.0, "kV": 1e3},
    "current": {"A": 1.0, "mA": 1e-3},
    "angle": {"rad": 1.0, "mrad": 1e-3, "deg": math.pi / 180},  # electrical angles
    "power": {"W": 1.0, "kW": 1e3},
    "torque": {"Nm": 1.0, "N m": 1.0, "N·m": 1.0},
    "inertia": {"kgm2": 1.0, "kg m^2": 1.0, "kgm^2": 1.0, "kg·m^2": 1.0},
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6},
    "frequency": {"Hz": 1.0, "kHz": 1e3},
    # electrical angular speed or bandwidth
    "angular": {"rad/s": 1.0, "Hz": 2 * math.pi, "kHz": 2e3 * math.pi},
    "mech_speed": {"rpm": 1.0, "r/min": 1.0},
    "viscous": {
        "Nms": 1.0,
        "N m s": 1.0,
        "Nm/(rad/s)": 1.0,
        "kgm2/s": 1.0,  # De Angelo et al. (2006) write B in kg m^2/s
        "kg m^2/s": 1.0,
        "kg·m^2/s": 1.0,
    },
    # flux derivative d lambda / d theta, eq. (4) of De Angelo et al. (2006) (= torque per ampere)
    "flux_derivative": {
        "Vs": 1.0,
        "V s": 1.0,
        "Wb": 1.0,
        "Vs/rad": 1.0,
        "V s/rad": 1.0,
        "Nm/A": 1.0,
        "N m/A": 1.0,
        "mVs": 1e-3,
        "mWb": 1e-3,
    },
    "rate": {"1/s": 1.0, "/s": 1.0, "s^-1": 1.0},  # observer gain g of De Angelo et al. (2006); decay rates
    # load-torque adaptation gain Gamma of De Angelo et al. (2006), eq. (10): N m kg m^2 / (V s)^2 = A^2 s^2
    "adaptation": {"A^2 s^2": 1.0, "A2s2": 1.0, "A²s²": 1.0},
    "fraction": {"%": 0.01},  # bare numbers are fractions (0.2 = 20 %)
    "dimensionless": {},
    "integer": {},
}

# Units that scale with a property of the drive: resolved after the base/estimates are known.
RELATIVE_UNITS: dict[str, tuple[str, ...]] = {
    "angular": ("pu",),
    "resistance": ("R_s_hat", "Rs_hat"),
    "flux_derivative": ("Phi_1",),  # a multiple of the fundamental, e.g. Phi_5 = "0.04 Phi_1"
}

_QTY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*$")


class DriveFileError(ValueError):
    """A drive description is malformed; the message names the file and the key."""

    def __init__(self, file: str, key: str, problem: str) -> None:
        self.file, self.key, self.problem = file, key, problem
        super().__init__(f"{file}: key '{key}': {problem}")


def parse_quantity(value: object, dim: str, *, file: str, key: str) -> tuple[float, str | None]:
    """Return (number, relative unit or None); the number is SI unless a relative unit is given.

    Raises DriveFileError naming ``file`` and ``key`` for a wrong type or a unit of another dimension.
    """
    if isinstance(value, bool):
        raise DriveFileError(file, key, f"expected a {dim} quantity, got a boolean")
    if dim == "integer":
        if not isinstance(value, int):
            raise DriveFileError(file, key, f"expected an integer, got {value!r}")
        return float(value), None
    if isinstance(value, int | float):
        x = float(value)
        if not math.isfinite(x):
            raise DriveFileError(file, key, f"value {value!r} is not finite")
        return x, None
    if not isinstance(value, str):
        raise DriveFileError(file, key, f"expected a number or a '<number> <unit>' string, got {value!r}")
    m = _QTY.match(value)
    if not m:
        raise DriveFileError(file, key, f"cannot read {value!r} as '<number> <unit>'")
    x, unit = float(m.group(1)), m.group(2)
    if unit == "":
        return x, None
    table = UNITS[dim]
    if unit in table:
        return x * table[unit], None
    if unit in RELATIVE_UNITS.get(dim, ()):
        return x, unit
    allowed = list(table) + list(RELATIVE_UNITS.get(dim, ()))
    other = [d for d, t in UNITS.items() if unit in t]
    hint = f" ('{unit}' is a unit of {other[0]})" if other else ""
    accepted = ", ".join(allowed) if allowed else "a bare number"
    raise DriveFileError(file, key, f"unit '{unit}' is not a {dim} unit{hint}; use one of: {accepted}")
