"""``sensorless tune`` options of the adaptive observer: the envelope and constraints of the shared NLP.

The drive's ``[tuning]`` section (design/envelope.py) with the command-line overrides applied and
checked (one-line errors naming the option).
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

from sensorless.design.envelope import DIRECTIONS, ESTIMATE_KEYS, NOISE_OUTPUTS, RANGES, TuningSettings
from sensorless.design.ipmsm_adaptive.law_settings import BREAKPOINTS
from sensorless.design.units import DriveFileError, parse_quantity
from sensorless.reports.cli.common import Number, UsageError, option_error, parse_max_noise, parse_torques
from sensorless.reports.family import Option

# the same ranges as the drive file's [tuning] keys (design/envelope.py RANGES)
SPEED = Number(*RANGES["speed"], lo_open=True, unit="p.u.")
DENSE_FACTOR = Number(*RANGES["dense_factor"], integer=True)

OPTIONS = (
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
    Option(("--lambda-max",), {"help": "bound on |lambda1|, |lambda2|: ohm or e.g. 5R_s_hat"}),
    Option(
        ("--errors",),
        {
            "help": "stay stable with estimates off by these fractions, e.g. R_s=30%%,L_q=10%% "
            "(all sign corners)"
        },
    ),
    Option(("--tune-alpha-fo",), {"action": "store_true", "help": "also tune alpha_fo of eq. (10)"}),
    Option(
        ("--breakpoints",),
        {
            "type": Number(*BREAKPOINTS, integer=True),
            "help": "schedule: breakpoints per direction ({}..{})".format(*BREAKPOINTS),
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


def settings(drive: Any, args: argparse.Namespace, tunable: Any) -> TuningSettings:
    """The drive's [tuning] settings with the command-line overrides applied and checked."""
    s = drive.tuning
    env: dict[str, Any] = {}
    for key in ("speed_min", "speed_max", "speeds", "directions", "dense_factor"):
        v = getattr(args, key)
        if v is not None:
            env[key] = v
    if args.torque:
        env["torques_TN"] = tuple(t / drive.T_N for t in parse_torques(args.torque, drive.T_N))
    out: dict[str, Any] = {"envelope": dataclasses.replace(s.envelope, **env)}
    law: dict[str, Any] = {}  # the gain laws' own settings (design/ipmsm_adaptive/law_settings.py)
    if args.min_decay is not None:
        out["min_decay"] = args.min_decay
    if args.lambda_max is not None:
        txt = args.lambda_max.replace("R_s_hat", " R_s_hat").strip()
        try:
            x, rel = parse_quantity(txt, "resistance", file="", key="--lambda-max")
        except DriveFileError as e:
            raise option_error("--lambda-max", e.problem) from None
        law["lambda_max"] = x * drive.estimate.R_s if rel else x
    if args.errors:
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
    if args.tune_alpha_fo:
        law["tune_alpha_fo"] = True
    if args.breakpoints is not None:
        law["breakpoints"] = args.breakpoints
    if args.max_noise:
        out["max_noise"] = parse_max_noise(args.max_noise, drive.w_base)
    if args.pareto is not None:
        out["pareto"] = args.pareto
    if args.pareto_output:
        out["pareto_output"] = args.pareto_output
    result = dataclasses.replace(s, law=dataclasses.replace(s.law, **law), **out)
    try:
        result.check("", prefix="")
    except DriveFileError as e:  # name the option, not the drive file's key
        key = e.key.split(".")[0]
        raise option_error(
            {"torques": "--torque"}.get(key, f"--{key.replace('_', '-')}"), e.problem
        ) from None
    return result


def describe(drive: Any, settings: TuningSettings) -> str:
    """One line: the envelope."""
    return f"envelope: {settings.envelope.describe()}; 1 p.u. = {drive.w_base:.2f} rad/s electrical"
