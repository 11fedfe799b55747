"""``sensorless tune`` options of the adaptive observer: the envelope and constraints of the shared NLP.

The drive's ``[tuning]`` section (design/envelope.py) with the command-line overrides applied and
checked (one-line errors naming the option).
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

from sensorless.design.envelope import DIRECTIONS, ESTIMATE_KEYS, NOISE_DIMS, NOISE_OUTPUTS, TuningSettings
from sensorless.design.units import DriveFileError, parse_quantity
from sensorless.reports.cli.common import UsageError, parse_torques
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


def parse_max_noise(text: str, w_base: float) -> tuple[tuple[str, float], ...]:
    """``position=0.05deg,speed=0.002pu`` (or a bare quantity: an angle limits the position, a speed
    the speed) -> ((output, SI limit), ...)."""
    out: dict[str, float] = {}
    for item in (p.strip() for p in text.split(",") if p.strip()):
        name, sep, val = item.partition("=")
        if not sep:
            val = name
            for cand in NOISE_OUTPUTS:
                try:
                    parse_quantity(_spaced(val), NOISE_DIMS[cand], file="command line", key="--max-noise")
                except DriveFileError:
                    continue
                name = cand
                break
            else:
                raise UsageError(
                    f"--max-noise: cannot read {item!r}: give an angle (e.g. 0.05deg: position) or a speed "
                    "(e.g. 0.002pu, 1rad/s: speed), or NAME=VALUE with NAME in " + ", ".join(NOISE_OUTPUTS)
                )
        name = name.strip()
        if name not in NOISE_OUTPUTS:
            raise UsageError(
                f"--max-noise: unknown noise output {name!r} (allowed: {', '.join(NOISE_OUTPUTS)})"
            )
        x, rel = parse_quantity(_spaced(val), NOISE_DIMS[name], file="command line", key="--max-noise")
        out[name] = x * w_base if rel == "pu" else x
    return tuple(out.items())


def _spaced(v: str) -> str:
    """'0.05deg' -> '0.05 deg' (a unit may follow the number without a space)."""
    v = v.strip()
    i = 0
    while (
        i < len(v)
        and (v[i].isdigit() or v[i] in "+-.eE")
        and not (v[i] in "eE" and i + 1 < len(v) and v[i + 1].isalpha())
    ):
        i += 1
    return f"{v[:i]} {v[i:]}".strip()


def describe(drive: Any, settings: TuningSettings) -> str:
    """One line: the envelope."""
    return f"envelope: {settings.envelope.describe()}; 1 p.u. = {drive.w_base:.2f} rad/s electrical"
