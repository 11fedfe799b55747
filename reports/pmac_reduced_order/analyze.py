"""``sensorless analyze`` for the reduced-order observer: poles (continuous and discrete) and steady errors.

De Angelo et al. (2006). Operating points are the drive's ``[envelope]`` (or ``--speed``/``--load``);
both observers are analysed: with load-torque estimation and without it (Gamma = 0, the observer of
their [11]). ``--study`` adds the discretization study.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.pmac_reduced_order import FAMILY
from sensorless.reports.family import Option
from sensorless.reports.files import OutputSet
from sensorless.reports.options import RELATIVE_LIMIT, option_error, quantities
from sensorless.symbolic.pmac_reduced_order.step import DISCRETIZATIONS

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.linearize import ObserverPoles
    from sensorless.design.pmac_reduced_order.schema import PmacDrive

OPTIONS = (
    Option(
        ("--speed",),
        {
            "action": "append",
            "help": "mechanical speeds, e.g. --speed=250rpm,-400rpm (default: the drive's [envelope] speeds)",
        },
    ),
    Option(
        ("--load",),
        {"action": "append", "help": "load torques in N m, e.g. --load=0,5Nm (default: [envelope] loads)"},
    ),
    Option(
        ("--discretization",), {"help": "observer scheme (default: the drive's [control] discretization)"}
    ),
    Option(
        ("--study",), {"action": "store_true", "help": "also the discretization study (schemes x 45..360 us)"}
    ),
)

STUDY_SAMPLING = (45e-6, 90e-6, 180e-6, 360e-6)  # [s]
STUDY_SPEEDS = (250.0, 1000.0)  # [r/min]
STUDY_LOADS = (5.0,)  # [N m]


def _print_block(r: ObserverPoles, drive: PmacDrive, title: str) -> None:
    from sensorless.reports.pmac_reduced_order.figures import format_poles

    print(title)
    print(
        f"  {'speed':>7} {'load':>6}  {'continuous poles [1/s]':<30} {'discrete poles ln(z)/T_s [1/s]':<30} "
        f"{'damping c/d':>11} {'e_w [rad/s]':>11} {'e_th [rad]':>10} {'e_TL [N m]':>10}"
    )
    zc, zd = np.nanmin(r.damping, axis=1), np.nanmin(r.damping_discrete, axis=1)
    rpm = drive.w_to_rpm(r.w)
    # a steady T_L_hat bias above 10 % of the load (at least 0.1 N m) means T_s is too long for the speed
    load = np.abs(r.T_L + drive.motor.B * r.w / drive.motor.p_r)
    flag = r.load_estimation & (np.abs(r.err_T) > np.maximum(0.1 * load, 0.1))
    for k in range(r.w.size):
        print(
            f"  {rpm[k]:>7.0f} {r.T_L[k]:>6.3g}  {format_poles(r.poles[k]):<30} "
            f"{format_poles(r.poles_discrete[k]):<30} {f'{zc[k]:.2f}/{zd[k]:.2f}':>11} "
            f"{r.err_w[k]:>+11.2e} {r.err_theta[k]:>+10.1e} "
            f"{r.err_T[k]:>+10.2e}{' *' if flag[k] else ''}"
        )
    if flag.any():
        print(
            "  * steady T_L_hat bias above 10 % of the load: the sampling is too slow for the EMF harmonics "
            "at this speed (docs/families/pmac_reduced_order.md, Discretization)"
        )


def options(drive: PmacDrive, args: argparse.Namespace) -> tuple[list[float], list[float], str]:
    """(speeds [r/min], loads [N m], scheme) from the options or the drive, checked (one-line errors)."""
    rpm_max = drive.w_to_rpm(RELATIVE_LIMIT * drive.w_base)
    rpm = quantities(
        args.speed,
        "mech_speed",
        "--speed",
        (rpm_max, f"|speed| <= {RELATIVE_LIMIT:g} p.u. = {rpm_max:.4g} r/min"),
    ) or list(drive.envelope.rule.listed)
    T_max = RELATIVE_LIMIT * drive.T_N
    loads = quantities(
        args.load, "torque", "--load", (T_max, f"|load| <= {RELATIVE_LIMIT:g} T_N = {T_max:.4g} N m")
    ) or list(drive.envelope.torque_values)
    if any(n == 0 for n in rpm):
        raise option_error("--speed", "zero speed: the EMF observer is undefined there")
    n_max = max(abs(n) for n in rpm)
    if drive.rpm_to_w(n_max) * drive.control.T_s >= np.pi / 2:  # as the drive file's [envelope]
        raise option_error(
            "--speed",
            f"{n_max:g} r/min is too fast for T_s = {drive.control.T_s * 1e6:g} us: the speed sign (14) "
            "needs |w| T_s < pi/2",
        )
    method = args.discretization or drive.control.discretization
    if method not in DISCRETIZATIONS:
        raise option_error(
            "--discretization", f"unknown scheme {method!r} (known: {', '.join(DISCRETIZATIONS)})"
        )
    return rpm, loads, method


def check(drive: PmacDrive, args: argparse.Namespace) -> None:
    """The options and the gain table against the drive, before anything is computed."""
    FAMILY.gains(drive, table=_table(args), table_file=args.gains or "")
    options(drive, args)


def analyze(drive: PmacDrive, args: argparse.Namespace, out: OutputSet) -> None:
    """Poles at the operating points, with and without load-torque estimation; stage CSV and figures."""
    gains = FAMILY.gains(drive, table=_table(args), table_file=args.gains or "")
    rpm, loads, method = options(drive, args)
    m, c = drive.motor, drive.control
    g, Gamma = gains.values["g"], gains.values["Gamma"]
    print(f"{drive.name}: {drive.source}")
    print(f"gains: {gains.source}")
    print(
        f"reduced-order EMF + load observer ({FAMILY.citation}): g = {g:g} 1/s, Gamma = {Gamma:g} A^2 s^2; "
        f"EMF orders {', '.join(map(str, drive.estimate.harmonics))}; reading '{m.reading}' (p_r = {m.p_r:g})"
    )
    print(
        f"discrete observer: {method} at T_s = {c.T_s * 1e6:g} us; errors = true - estimate in steady state "
        "(speed and angle electrical)"
    )
    if len(set(m.harmonics) | set(drive.estimate.harmonics)) > 1:
        print("EMF harmonics: poles are Floquet exponents over one period of the rotor-frame dynamics")
    w = drive.rpm_to_w(np.asarray(rpm, float))
    results: dict[str, ObserverPoles] = {}
    for est, key, title in (
        (True, "TL", "with load-torque estimation, eqs. (9)-(17):"),
        (False, "noTL", "without load-torque estimation (Gamma = 0, [11]):"),
    ):
        r = FAMILY.linearize(
            drive, gains, w[:, None], np.asarray(loads, float)[None, :], load_estimation=est, method=method
        )
        results[title.rstrip(":")] = r
        _print_block(r, drive, title)
        from sensorless.reports.pmac_reduced_order.figures import poles_csv

        out.add_text(f"poles_{key}.csv", poles_csv(r, drive))
        lost = ~(np.isfinite(r.poles).all(axis=1) & np.isfinite(r.poles_discrete).all(axis=1))
        if lost.any():  # an overflow (units, gains), not a result: every written number finite or said
            out.warnings.append(
                f"poles_{key}.csv: no finite poles at {int(lost.sum())} of {lost.size} operating points "
                "(nan in their rows): the linearized observer overflows there; check the drive's units "
                "(e.g. an inductance in H for uH) and the gains"
            )
    if args.study:
        from sensorless.reports.pmac_reduced_order.figures import study_csv

        print("discretization study (load-torque estimation on): steady errors vs scheme and T_s")
        from sensorless.design.pmac_reduced_order.discretization import discretization_study

        rows = discretization_study(
            drive,
            list(DISCRETIZATIONS),
            STUDY_SAMPLING,
            STUDY_SPEEDS,
            STUDY_LOADS,
            progress=lambda s: print(f"  ... {s}", file=sys.stderr, flush=True),
        )
        print(
            f"  {'scheme':<13} {'T_s':>6} {'speed':>6} {'e_w [rad/s]':>12} {'e_w/effect':>10} "
            f"{'e_TL [N m]':>11} {'slow pole c/d [1/s]':>20}"
        )
        for s in rows:
            print(
                f"  {s.method:<13} {s.T_s * 1e6:>4.0f}us {s.rpm:>6.0f} {s.err_w:>+12.2e} "
                f"{100 * s.err_w / s.effect_w:>+9.2f}% {s.err_T:>+11.2e} {s.slow_c:>9.3f}/{s.slow_d:<9.3f}"
            )
        out.add_text("discretization_study.csv", study_csv(rows, drive))
    from sensorless.reports.pmac_reduced_order.figures import plot_poles

    fig = plot_poles(
        results, drive, f"{drive.name}: observer error-dynamics poles ({method}, {c.T_s * 1e6:g} us)"
    )
    out.add_figures("poles", fig)
    import matplotlib.pyplot as plt

    plt.close(fig)


def _table(args: argparse.Namespace) -> Any:
    if not args.gains:
        return None
    from sensorless.design.gain_table import read_gain_table

    return read_gain_table(args.gains)
