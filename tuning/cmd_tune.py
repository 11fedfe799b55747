"""``sensorless tune``: NLP-optimal observer gains over an operating envelope, written as gain tables.

Envelope and constraints come from the drive's ``[tuning]`` section (defaults: |w_m| in [0.05, 1]
p.u., both directions, T_e in {-T_N, 0, T_N}); command-line options override it. Progress goes to
stderr; the summary and the written files to stdout. If IPOPT fails or the constraints cannot be
met, one line says so and the exit status is 2; nothing is written.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from typing import Any

from sensorless.design.drive import load_drive
from sensorless.design.envelope import ESTIMATE_KEYS, TuningSettings
from sensorless.design.units import parse_quantity
from sensorless.reports.files import OutputSet
from sensorless.tuning.cli import UsageError
from sensorless.tuning.cmd_analyze import parse_torques
from sensorless.tuning.families import DESCRIPTIONS, FamilyError
from sensorless.tuning.gain_table import table_csv
from sensorless.tuning.nlp import TuningError


def register(sub: Any) -> None:
    """Add the ``tune`` subcommand."""
    p = sub.add_parser(
        "tune",
        help="NLP-optimal observer gains over an operating envelope (gain tables CSV + JSON)",
        description="Maximize the worst-case damping ratio of the linearized motor+observer closed loop "
        "over an envelope of speeds x torques with IPOPT, re-verify on a denser grid, and write the gain "
        "table. Defaults come from the drive's [tuning] section.",
    )
    p.add_argument("drive", metavar="PRESET_OR_TOML", help="built-in preset name or drive TOML file")
    p.add_argument(
        "--family",
        default=None,
        choices=list(DESCRIPTIONS),
        help="gain family (default: law16 for ipmsm-adaptive drives, deangelo for pmac-reduced-order)",
    )
    p.add_argument("--out", default=None, help="output directory (default: tune-<drive name>)")
    p.add_argument("--force", action="store_true", help="overwrite existing output files")
    p.add_argument("--speed-min", type=float, default=None, help="smallest |w_m| of the envelope [p.u.]")
    p.add_argument("--speed-max", type=float, default=None, help="largest |w_m| of the envelope [p.u.]")
    p.add_argument("--speeds", type=int, default=None, help="optimization grid: speeds per direction")
    p.add_argument("--directions", choices=["both", "positive", "negative"], default=None)
    p.add_argument(
        "--torque", action="append", default=None, help="envelope torques, N m or e.g. -1T_N,0,1T_N"
    )
    p.add_argument("--dense-factor", type=int, default=None, help="re-verification refinement (>= 4)")
    p.add_argument("--min-decay", type=float, default=None, help="minimum decay rate -max Re(p) [1/s]")
    p.add_argument("--lambda-max", default=None, help="bound on |lambda1|, |lambda2|: ohm or e.g. 5R_s_hat")
    p.add_argument(
        "--errors",
        default=None,
        help="stay stable with estimates off by these fractions, e.g. R_s=30%%,L_q=10%% (all sign corners)",
    )
    p.add_argument("--tune-alpha-fo", action="store_true", help="also tune alpha_fo of eq. (10)")
    p.add_argument("--breakpoints", type=int, default=None, help="schedule: breakpoints per direction")
    p.add_argument(
        "--g-max", type=float, default=None, help="deangelo: upper bound on g [1/s] (default 2x the drive's)"
    )
    p.add_argument(
        "--Gamma-max",
        type=float,
        default=None,
        help="deangelo: upper bound on Gamma [A^2 s^2] (default 100x the drive's)",
    )
    p.add_argument(
        "--min-damping", type=float, default=None, help="deangelo: worst damping required (default 0.707)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


PAPER000_ONLY = ("speed_min", "speed_max", "speeds", "directions", "torque", "min_decay", "lambda_max")
PAPER000_ONLY += ("errors", "tune_alpha_fo", "breakpoints")
PAPER002_ONLY = ("g_max", "Gamma_max", "min_damping")


def _option(key: str) -> str:
    return "--" + key.replace("_", "-")


def _refuse(args: argparse.Namespace, keys: tuple[str, ...], kind: str) -> None:
    """Options of another drive kind have no meaning here: refuse them rather than ignore them."""
    for k in keys:
        if getattr(args, k) not in (None, False):
            raise UsageError(f"{_option(k)}: not an option for drive kind '{kind}'")


def settings_002(drive: Any, args: argparse.Namespace) -> Any:
    """deangelo settings: the drive's [envelope] and default bounds, with the overrides."""
    from sensorless.tuning.family_paper002 import default_settings

    _refuse(args, PAPER000_ONLY, drive.kind)
    s = default_settings(drive)
    out: dict[str, Any] = {}
    for key in ("g_max", "Gamma_max", "min_damping", "dense_factor"):
        v = getattr(args, key)
        if v is not None:
            out[key] = v
    s = dataclasses.replace(s, **out)
    try:
        s.check("command line")
    except TuningError as e:
        raise UsageError(str(e)) from None
    return s


def settings_from_args(drive: Any, args: argparse.Namespace) -> TuningSettings:
    """The drive's [tuning] settings with the command-line overrides applied and checked."""
    _refuse(args, PAPER002_ONLY, drive.kind)
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
    settings = dataclasses.replace(s, **out)
    settings.check("command line", prefix="")
    return settings


def run(args: argparse.Namespace) -> int:
    """Tune, print the summary, write the tables."""
    from sensorless.tuning.families import families_for
    from sensorless.tuning.tune import tune

    drive = load_drive(args.drive)
    fam = args.family or families_for(drive.kind)[0]
    paper002 = drive.kind == "pmac-reduced-order"
    settings = settings_002(drive, args) if paper002 else settings_from_args(drive, args)
    out = OutputSet(args.out or f"tune-{drive.name}", force=args.force)
    json_name, csv_name = f"gains_{fam}.json", f"gains_{fam}.csv"
    out.add_bytes(json_name, b"")  # reserve the names: refuse existing outputs before the work
    out.add_bytes(csv_name, b"")
    out.check_free()
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    print(f"{drive.name}: {drive.source}")
    print(f"family {fam}: {DESCRIPTIONS[fam]}")
    if paper002:
        print(
            f"envelope: speeds {', '.join(f'{v:g}' for v in settings.speeds_rpm)} r/min x loads "
            f"{', '.join(f'{v:g}' for v in settings.loads_Nm)} N m"
        )
    else:
        print(f"envelope: {settings.envelope.describe()}; 1 p.u. = {drive.base.w:.2f} rad/s electrical")
    try:
        r = tune(drive, fam, settings, progress=progress)
    except (TuningError, FamilyError) as e:
        raise UsageError(str(e)) from None
    if hasattr(r, "summary_lines"):
        print("\n".join(r.summary_lines()))
    else:
        print_summary(drive, r)
    out.add_text(json_name, r.table.to_json())
    out.add_text(csv_name, table_csv(r.table))
    for p in out.commit():
        print(f"wrote {p}")
    return 0


def print_summary(drive: Any, r: Any) -> None:
    """The terminal summary: parameters and worst damping before -> after, and where."""
    s = r.table.summary
    wb = drive.base.w
    env = r.table.envelope
    print(
        f"optimized over {env['optimization_points']} points in {s['exchange_rounds']} exchange rounds "
        f"({s['ipopt_iterations']} IPOPT iterations); re-verified on {env['dense_points']} points "
        f"({env['dense_factor']}x denser) in {r.seconds:.1f} s"
    )
    print(f"{'':<22}{'paper defaults':>18}{'tuned':>18}")
    for n, u, v0, v in zip(r.model.names, r.model.units, r.theta0, r.theta, strict=True):
        if u == "rad/s":
            print(f"{n + ' [p.u.]':<22}{v0 / wb:>18.4g}{v / wb:>18.4g}")
        elif r.model.n_theta <= 6:
            print(f"{n + ' [' + u + ']':<22}{v0:>18.4g}{v:>18.4g}")

    def where(key: str) -> str:
        a = s[key]
        return f"at {a['w_m_pu']:+.3f} p.u., {a['T_e_Nm']:+.3g} N m"

    print(f"{'worst damping':<22}{s['baseline_worst_damping']:>18.4f}{s['worst_damping']:>18.4f}")
    print(f"{'  where':<22}{where('baseline_worst_damping_at'):>36}")
    print(f"{'':<22}{where('worst_damping_at'):>36}")
    print(f"{'slowest decay [1/s]':<22}{s['baseline_min_decay_rate']:>18.4g}{s['min_decay_rate']:>18.4g}")
    print(
        f"worst damping on the optimization grid {s['optimization_grid_worst_damping']:.4f} "
        f"(NLP: {s['nlp_worst_damping']:.4f}); the table reports the dense re-verification"
    )
    if s.get("selection"):
        print(f"kept: {s['selection']['text']}")
    for rb in s["robust"]:
        print(
            f"estimates {rb['scenario']}: max Re(p) = {rb['max_real_1_s']:.4g} 1/s at "
            f"{rb['at_w_m_pu']:+.3f} p.u., {rb['at_T_e_Nm']:+.3g} N m "
            f"({'stable' if rb['stable'] else 'UNSTABLE'})"
        )
