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
    # moment of inertia: kg m2, kg cm2 (datasheets of servos), g cm2 (small motors); other spellings
    # (kg m^2, kg·cm², kgcm2, ...) are found by :func:`normalized_unit`
    "inertia": {
        "kgm2": 1.0,
        "kg m^2": 1.0,
        "kgm^2": 1.0,
        "kg·m^2": 1.0,
        "kgcm2": 1e-4,
        "gcm2": 1e-7,
        "kgmm2": 1e-6,
        "gmm2": 1e-9,
    },
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "μs": 1e-6},
    "frequency": {"Hz": 1.0, "kHz": 1e3},
    # electrical angular speed or bandwidth
    "angular": {"rad/s": 1.0, "Hz": 2 * math.pi, "kHz": 2e3 * math.pi},
    "mech_speed": {"rpm": 1.0, "r/min": 1.0},
    # electrical angular acceleration (a speed reference's rate limit)
    "acceleration": {"rad/s^2": 1.0},
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
    # back-EMF constant kE per mechanical speed (docs/motor_data.md): SI V s/rad = V/(rad/s)
    "emf_constant": {
        "Vs/rad": 1.0,
        "V/(rad/s)": 1.0,
        "mVs/rad": 1e-3,
        "V/krpm": 60 / (2e3 * math.pi),
        "V/kRPM": 60 / (2e3 * math.pi),
        "V/1000rpm": 60 / (2e3 * math.pi),
        "V/1000r/min": 60 / (2e3 * math.pi),
        "V/kr/min": 60 / (2e3 * math.pi),
        "V/rpm": 60 / (2 * math.pi),
        "V/(r/min)": 60 / (2 * math.pi),
        "mV/rpm": 60e-3 / (2 * math.pi),
        "mV/(r/min)": 60e-3 / (2 * math.pi),
        "mV/min-1": 60e-3 / (2 * math.pi),
    },
    # speed constant KV: mechanical speed per volt; SI (rad/s)/V
    "speed_constant": {
        "rpm/V": 2 * math.pi / 60,
        "r/min/V": 2 * math.pi / 60,
        "(rad/s)/V": 1.0,
        "rad/s/V": 1.0,
    },
    # torque constant kT
    "torque_constant": {"Nm/A": 1.0, "mNm/A": 1e-3},
    "rate": {"1/s": 1.0, "/s": 1.0, "s^-1": 1.0},
    "rate_squared": {
        "1/s2": 1.0,
        "/s2": 1.0,
        "rad/s2": 1.0,
    },  # PLL integral gains  # observer gain g of De Angelo et al. (2006); decay rates
    # load-torque adaptation gain Gamma of De Angelo et al. (2006), eq. (10): N m kg m^2 / (V s)^2 = A^2 s^2
    "adaptation": {"A^2 s^2": 1.0, "A2s2": 1.0, "A²s²": 1.0},
    "fraction": {"%": 0.01},  # bare numbers are fractions (0.2 = 20 %)
    "dimensionless": {},
    "integer": {},
}

# Units that scale with a property of the drive: resolved after the base/estimates are known.
RELATIVE_UNITS: dict[str, tuple[str, ...]] = {
    "angular": ("pu", "w_min"),  # w_min: the design's minimum sensorless speed ([startup], design/startup.py)
    "acceleration": ("pu/s",),  # per unit of the base speed (1 p.u., electrical) per second
    "resistance": ("R_s_hat", "Rs_hat"),
    "flux_derivative": ("Phi_1",),  # a multiple of the fundamental, e.g. Phi_5 = "0.04 Phi_1"
}


def normalized_unit(unit: str) -> str:
    """A unit's spelling without spaces, middle dots, '*' and '^', with superscripts as digits:
    "kg cm^2", "kg·cm²" and "kgcm2" are one unit; "mV/min⁻¹" is "mV/min-1"."""
    for a, b in (
        (" ", ""),
        ("·", ""),
        ("*", ""),
        ("^", ""),
        ("²", "2"),
        ("⁻¹", "-1"),
        ("⁻", "-"),
        ("¹", "1"),
    ):
        unit = unit.replace(a, b)
    return unit


def article(word: str) -> str:
    """'a' or 'an' before ``word``."""
    return "an" if word[:1] in "aeiou" else "a"


_QTY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*$")

# The magnitudes a drive, scenario, gain table or command line may give, in SI (zero aside): wider than
# any drive's values by many orders of magnitude, narrow enough that products and squares of them stay
# finite in double precision (a value of 1e300 or 1e-300 otherwise turns into inf, 0 or NaN downstream).
MAGNITUDE = (1e-12, 1e12)
# The most pole pairs of any motor a drive file or an import may give (sensorless init --pole-pairs:
# the same range); large direct-drive motors have some tens.
MAX_POLE_PAIRS = 1000


class UnknownName(KeyError):
    """A name the user gave (a drive kind, a gain choice) that does not exist: a one-line error. Other
    KeyErrors are bugs and keep their traceback."""


class DriveFileError(ValueError):
    """A drive description is malformed; the message names the file and the key."""

    def __init__(self, file: str, key: str, problem: str) -> None:
        self.file, self.key, self.problem = file, key, problem
        label = "keys" if ", " in key else "key"
        super().__init__(f"{file}: {label} '{key}': {problem}")


def check_magnitude(x: float, raw: object, *, file: str, key: str) -> float:
    """``x`` if it is finite and zero or of a magnitude within :data:`MAGNITUDE`; else DriveFileError
    naming ``file`` and ``key`` (``raw`` is the value as written)."""
    if not math.isfinite(x):
        raise DriveFileError(file, key, f"value {raw!r} is not finite")
    lo, hi = MAGNITUDE
    if x != 0 and not lo <= abs(x) <= hi:
        shown = f"{raw:.6g}" if isinstance(raw, int) else repr(raw)  # not an integer of 301 digits
        raise DriveFileError(
            file,
            key,
            f"value {shown} is out of range: magnitudes from {lo:g} to {hi:g} (SI) or 0 are accepted",
        )
    return x


def parse_number(text: object, *, file: str, key: str) -> float:
    """A plain number (int, float or numeric string such as "-1.5e3"), finite and within :data:`MAGNITUDE`."""
    return parse_quantity(text, "dimensionless", file=file, key=key)[0]


def parse_quantity(value: object, dim: str, *, file: str, key: str) -> tuple[float, str | None]:
    """Return (number, relative unit or None); the number is SI unless a relative unit is given.

    Raises DriveFileError naming ``file`` and ``key`` for a wrong type, a unit of another dimension, or
    a value that is not finite or out of range (:func:`check_magnitude`; "1e999 ohm" is not infinity).
    """
    if isinstance(value, bool):
        raise DriveFileError(file, key, f"expected a {dim} quantity, got a boolean")
    if dim == "integer":
        if not isinstance(value, int):
            raise DriveFileError(file, key, f"expected an integer, got {value!r}")
        return check_magnitude(float(value), value, file=file, key=key), None
    if isinstance(value, int | float):
        return check_magnitude(float(value), value, file=file, key=key), None
    if not isinstance(value, str):
        raise DriveFileError(file, key, f"expected a number or a '<number> <unit>' string, got {value!r}")
    m = _QTY.match(value)
    if not m:
        raise DriveFileError(file, key, f"cannot read {value!r} as '<number> <unit>'")
    x, unit = check_magnitude(float(m.group(1)), value, file=file, key=key), m.group(2)
    if unit == "":
        return x, None
    table = UNITS[dim]
    if unit in table:
        return check_magnitude(x * table[unit], value, file=file, key=key), None
    loose = {normalized_unit(u): v for u, v in table.items()}
    if normalized_unit(unit) in loose:
        return check_magnitude(x * loose[normalized_unit(unit)], value, file=file, key=key), None
    if unit in RELATIVE_UNITS.get(dim, ()):
        return x, unit
    allowed = list(table) + list(RELATIVE_UNITS.get(dim, ()))
    other = [d for d, t in UNITS.items() if normalized_unit(unit) in {normalized_unit(u) for u in t}]
    hint = f" ('{unit}' is a unit of {other[0]})" if other else ""
    accepted = ", ".join(allowed) if allowed else "a bare number"
    what = dim.replace("_", " ")
    raise DriveFileError(
        file, key, f"unit '{unit}' is not {article(what)} {what} unit{hint}; use one of: {accepted}"
    )
