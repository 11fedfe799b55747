"""``sensorless tune`` options of the adaptive observer: the envelope and constraints of the shared NLP.

The drive's ``[tuning]`` section (design/envelope.py) with the command-line overrides applied and
checked (one-line errors naming the option).
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

from sensorless.design.envelope import DIRECTIONS, ESTIMATE_KEYS, NOISE_OUTPUTS, TuningSettings
from sensorless.design.units import parse_quantity
from sensorless.reports.cli.common import UsageError, parse_max_noise, parse_torques
from sensorless.reports.family import Option

OPTIONS = (
    Option(("--speed-min",), {"type": float, "help": "smallest |w_m| of the envelope [p.u.]"}),
    Option(("--speed-max",), {"type": float, "help": "largest |w_m| of the envelope [p.u.]"}),
    Option(("--speeds",), {"type": int, "help": "optimization grid: speeds per direction"}),
    Option(("--directions",), {"choices": list(DIRECTIONS), "help": "envelope directions"}),
    Option(("--torque",), {"action": "append", "help": "envelope torques, N m or e.g. -1T_N,0,1T_N"}),
    Option(("--dense-factor",), {"type": int, "help": "re-verification refinement (>= 4)"}),
    Option(("--min-decay",), {"type": float, "help": "minimum decay rate -max Re(p) [1/s]"}),
    Option(("--lambda-max",), {"help": "bound on |lambda1|, |lambda2|: ohm or e.g. 5R_s_hat"}),
    Option(
        ("--errors",),
        {
            "help": "stay stable with estimates off by these fractions, e.g. R_s=30%%,L_q=10%% "
            "(all sign corners)"
        },
    ),
    Option(("--tune-alpha-fo",), {"action": "store_true", "help": "also tune alpha_fo of eq. (10)"}),
    Option(("--breakpoints",), {"type": int, "help": "schedule: breakpoints per direction"}),
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
            "type": int,
            "nargs": "?",
            "const": 8,
            "metavar": "N",
            "help": "also compute the damping-versus-noise front at N noise limits (default 8)",
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
    if args.min_decay is not None:
        out["min_decay"] = args.min_decay
    if args.lambda_max is not None:
        txt = args.lambda_max.replace("R_s_hat", " R_s_hat").strip()
        x, rel = parse_quantity(txt, "resistance", file="command line", key="--lambda-max")
        out["lambda_max"] = x * drive.estimate.R_s if rel else x
    if args.errors:
        errs = [0.0] * 4
        for item in args.errors.split(","):
            k, _, v = item.partition("=")
            if k.strip() not in ESTIMATE_KEYS or not v:
                raise UsageError(f"--errors: expected NAME=PERCENT% with NAME in {', '.join(ESTIMATE_KEYS)}")
            x, _ = parse_quantity(v.strip(), "fraction", file="command line", key="--errors")
            errs[ESTIMATE_KEYS.index(k.strip())] = x
        out["errors"] = tuple(errs)
    if args.tune_alpha_fo:
        out["tune_alpha_fo"] = True
    if args.breakpoints is not None:
        out["breakpoints"] = args.breakpoints
    if args.max_noise:
        out["max_noise"] = parse_max_noise(args.max_noise, drive.w_base)
    if args.pareto is not None:
        out["pareto"] = args.pareto
    if args.pareto_output:
        out["pareto_output"] = args.pareto_output
    result = dataclasses.replace(s, **out)
    result.check("command line", prefix="")
    return result


def describe(drive: Any, settings: TuningSettings) -> str:
    """One line: the envelope."""
    return f"envelope: {settings.envelope.describe()}; 1 p.u. = {drive.w_base:.2f} rad/s electrical"
