"""The adaptive observer's own ``[tuning]`` keys: what its gain laws (16) and the free schedule add.

Piippo, Hinkkanen, Luomi (2008): ``lambda_max`` bounds |lambda1|, |lambda2| of eq. (16) and of the
schedule (ohm, or e.g. ``"5 R_s_hat"``; default the tuner's box), ``tune_alpha_fo`` also tunes the
adaptation bandwidth alpha_fo of eq. (10), ``hold_lag`` keeps the tuned gains' angle lag under
acceleration at most the drive file's gains' (both on by default: without them the tuned gains ran
peaks 2-7x the drive file's; the paper's law on its own preset keeps them off, tuning/ipmsm_adaptive;
docs/tuning.md), ``breakpoints`` is the schedule's
number of speed breakpoints per direction. The shared keys (envelope, decay floor, estimate errors,
noise limits) are read by design/envelope.py, which hands these to :data:`LAW_KEYS`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from sensorless.design.envelope import LawKeys, NoLawSettings, TuningSettings, parse_relative, read_int
from sensorless.design.units import DriveFileError

BREAKPOINTS = (2, 200)  # the range of [tuning] breakpoints, the same as the option --breakpoints


@dataclass(frozen=True)
class AdaptiveLawSettings:
    """Bounds and options of the adaptive observer's gain laws (``TuningSettings.law``)."""

    lambda_max: float | None = None  # bound on |lambda1|, |lambda2| [ohm]; None: the tuner's box
    # also tune the adaptation bandwidth alpha_fo (10), in 1-4x the drive file's: with the angle lag held
    # (hold_lag) it buys the damping the gains alone cannot (docs/tuning.md, "alpha_fo tuned")
    tune_alpha_fo: bool = True
    breakpoints: int = 11  # schedule: breakpoints per direction (plus one at zero speed)
    # the tuned gains' angle lag under acceleration at most the drive file's at every envelope point
    # (tuning/ipmsm_adaptive/model.py; docs/tuning.md "Tuned gains that run worse")
    hold_lag: bool = True

    def check(self, file: str, prefix: str = "tuning.") -> None:
        """Raise DriveFileError for an inconsistent value (the key named with ``prefix``)."""
        if self.lambda_max is not None and self.lambda_max <= 0:
            raise DriveFileError(file, f"{prefix}lambda_max", f"must be > 0, got {self.lambda_max:g}")
        if not BREAKPOINTS[0] <= self.breakpoints <= BREAKPOINTS[1]:
            raise DriveFileError(
                file,
                f"{prefix}breakpoints",
                "must be an integer in {}..{} (as --breakpoints), got {}".format(
                    *BREAKPOINTS, self.breakpoints
                ),
            )

    def constraints(self) -> dict[str, Any]:
        """The gain table's record of the gain bound."""
        return {"lambda_max_ohm": self.lambda_max}


def load(table: Mapping[str, Any], file: str, rel: Mapping[str, float]) -> AdaptiveLawSettings:
    """The keys of :data:`LAW_KEYS` in a ``[tuning]`` table (absent keys keep their defaults)."""
    out: dict[str, Any] = {}
    if "lambda_max" in table:
        out["lambda_max"] = parse_relative(table["lambda_max"], "resistance", rel, file, "tuning.lambda_max")
    if "tune_alpha_fo" in table:
        if not isinstance(table["tune_alpha_fo"], bool):
            raise DriveFileError(file, "tuning.tune_alpha_fo", "expected true or false")
        out["tune_alpha_fo"] = table["tune_alpha_fo"]
    if "hold_lag" in table:
        if not isinstance(table["hold_lag"], bool):
            raise DriveFileError(file, "tuning.hold_lag", "expected true or false")
        out["hold_lag"] = table["hold_lag"]
    if "breakpoints" in table:
        out["breakpoints"] = read_int(table["breakpoints"], file, "tuning.breakpoints")
    return AdaptiveLawSettings(**out)


LAW_KEYS = LawKeys(("lambda_max", "tune_alpha_fo", "hold_lag", "breakpoints"), load)


def law_settings(settings: TuningSettings) -> AdaptiveLawSettings:
    """This observer's part of ``settings`` (its defaults where the settings carry none)."""
    law = settings.law
    if isinstance(law, NoLawSettings):
        return AdaptiveLawSettings()
    if not isinstance(law, AdaptiveLawSettings):
        raise TypeError(f"tuning settings of another observer family: {type(law).__name__}")
    return law
