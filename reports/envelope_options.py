"""``sensorless tune`` options of the shared envelope and constraints (design/envelope.py), for any family.

A family whose tunables take the shared :class:`~sensorless.design.envelope.TuningSettings` declares
:data:`ENVELOPE_OPTIONS` among its tune options and only its laws' own options beside them; its
``tune_settings`` hook is :func:`tune_settings` with a function applying those law options (or none).
Every override is checked (one-line errors naming the option, not the drive file's key).
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable
from typing import Any

from sensorless.design.envelope import (
    DIRECTIONS,
    ESTIMATE_KEYS,
    NOISE_OUTPUTS,
    RANGES,
    LawSettings,
    TuningSettings,
    with_tuning_keys,
)
from sensorless.design.family import Drive, DriveT
from sensorless.design.units import DriveFileError, parse_quantity
from sensorless.reports.family import Option
from sensorless.reports.options import Number, UsageError, option_error, parse_max_noise, parse_torques
from sensorless.tuning.family import Tunable

# the same ranges as the drive file's [tuning] keys (design/envelope.py RANGES)
SPEED = Number(*RANGES["speed"], lo_open=True, unit="p.u.")
DENSE_FACTOR = Number(*RANGES["dense_factor"], integer=True)

ENVELOPE_OPTIONS = (
    Option(("--speed-min",), {"type": SPEED, "help": "smallest |w_m| of the envelope [p.u.]"}),
    Option(("--speed-max",), {"type": SPEED, "help": "largest |w_m| of the envelope [p.u.]"}),
    Option(
        ("--speeds",),
        {
            "type": Number(*RANGES["speeds"], integer=True),
            "help": "optimization grid: speeds per direction ({}..{})".format(*RANGES["speeds"]),
        },
    ),
    Option(("--directions",), {"choices": list(DIRECTIONS), "help": "envelope directions"}),
    Option(("--torque",), {"action": "append", "help": "envelope torques, N m or e.g. -1T_N,0,1T_N"}),
    Option(("--dense-factor",), {"type": DENSE_FACTOR, "help": "re-verification refinement (4..64)"}),
    Option(
        ("--min-decay",),
        {"type": Number(*RANGES["min_decay"], unit="1/s"), "help": "minimum decay rate -max Re(p) [1/s]"},
    ),
    Option(
        ("--no-bound",),
        {
            "action": "store_true",
            "help": "skip the pointwise bound (the optimality certificate and speeds_<law>.csv; about a "
            "quarter of the tuning's time)",
        },
    ),
)
NOISE_OPTIONS = (
    Option(
        ("--errors",),
        {
            "help": "stay stable with estimates off by these fractions, e.g. R_s=30%%,L_q=10%% "
            "(all sign corners)"
        },
    ),
    Option(
        ("--max-noise",),
        {
            "help": "limit the RMS noise of the estimates from the drive's current-sensor noise, e.g. "
            "position=0.05deg,speed=0.002pu (an angle alone limits the position, a speed the speed)"
        },
    ),
    Option(
        ("--pareto",),
        {
            "type": Number(*RANGES["pareto"], integer=True),
            "nargs": "?",
            "const": 8,
            "metavar": "N",
            "help": "also compute the damping-versus-noise front at N noise limits (2..100; default 8)",
        },
    ),
    Option(
        ("--pareto-output",),
        {
            "choices": list(NOISE_OUTPUTS),
            "help": "noise output of the front (default: the limited one, else position)",
        },
    ),
)

# (drive, args, the law's settings) -> its settings with the law's own options applied
LawOptions = Callable[[DriveT, argparse.Namespace, LawSettings], LawSettings]


def apply_options(s: TuningSettings, drive: Drive, args: argparse.Namespace) -> TuningSettings:
    """``s`` with the shared options the user gave (those of the family's options absent from ``args``
    count as not given)."""
    env: dict[str, Any] = {}
    for key in ("speed_min", "speed_max", "speeds", "directions", "dense_factor"):
        v = getattr(args, key, None)
        if v is not None:
            env[key] = v
    if getattr(args, "torque", None):
        env["torques_TN"] = tuple(t / drive.T_N for t in parse_torques(args.torque, drive.T_N))
    out: dict[str, Any] = {"envelope": with_tuning_keys(s.envelope, **env)}
    if getattr(args, "min_decay", None) is not None:
        out["min_decay"] = args.min_decay
    if getattr(args, "no_bound", None):
        out["bound"] = False
    if getattr(args, "errors", None):
        errs = [0.0] * 4
        for item in args.errors.split(","):
            k, _, v = item.partition("=")
            if k.strip() not in ESTIMATE_KEYS or not v:
                raise UsageError(f"--errors: expected NAME=PERCENT% with NAME in {', '.join(ESTIMATE_KEYS)}")
            try:
                x, _ = parse_quantity(v.strip(), "fraction", file="", key="--errors")
            except DriveFileError as e:
                raise option_error("--errors", e.problem) from None
            errs[ESTIMATE_KEYS.index(k.strip())] = x
        out["errors"] = tuple(errs)
    if getattr(args, "max_noise", None):
        out["max_noise"] = parse_max_noise(args.max_noise, drive.w_base)
    if getattr(args, "pareto", None) is not None:
        out["pareto"] = args.pareto
    if getattr(args, "pareto_output", None):
        out["pareto_output"] = args.pareto_output
    return dataclasses.replace(s, **out)


def checked(s: TuningSettings) -> TuningSettings:
    """``s`` after its consistency check, an error naming the option (not the drive file's key)."""
    try:
        s.check("", prefix="")
    except DriveFileError as e:
        key = e.key.split(".")[0]
        raise option_error(
            {"torques": "--torque"}.get(key, f"--{key.replace('_', '-')}"), e.problem
        ) from None
    return s


def tune_settings(
    law_options: LawOptions[DriveT] | None = None,
) -> Callable[[DriveT, argparse.Namespace, Tunable[DriveT]], TuningSettings]:
    """A ``tune_settings`` hook (reports/family.py): the tunable's default settings (``Tunable.settings``)
    with the shared options and the law's own (``law_options``) applied, checked."""

    def settings(drive: DriveT, args: argparse.Namespace, tunable: Tunable[DriveT]) -> TuningSettings:
        own = tunable.settings(drive)
        assert isinstance(own, TuningSettings), own  # a tunable on the shared envelope's settings
        s = apply_options(own, drive, args)
        if law_options is not None:
            s = dataclasses.replace(s, law=law_options(drive, args, s.law))
        return checked(s)

    return settings


def describe(drive: Drive, settings: TuningSettings) -> str:
    """A ``describe_envelope`` hook: one line, the envelope."""
    return f"envelope: {settings.envelope.describe()}; 1 p.u. = {drive.w_base:.2f} rad/s electrical"
