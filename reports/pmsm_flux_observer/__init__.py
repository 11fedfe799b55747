"""Report hooks of the flux-observer family: ``analyze`` output, ``tune`` options, the stability report,
and its firmware formats (``init --from``, ``export``: firmware_io.py).

- analyze: the shared one (reports/envelope_review.py) over its envelope: poles of the continuous
  observer and of the sampled one at the firmware's period (ln(z)/T_obs), damping and the observer's
  steady angle error; poles.csv, poles_discrete.csv and a figure. The box clamp has no linearization:
  analyze says so in one line (judged by simulation);
- tune: the estimate errors, the bias limit and the hold speed of the laws' criterion (tuning/);
- report: the shared frame (reports/envelope_review.py) with the family's judge (review.py): the gains
  under review beside the firmwares' defaults on this motor, each judged by the tuning criterion, the
  poles over speed, the angle bias under each estimate error, and the built-in scenario re-run.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import later
from sensorless.design.pmsm_flux_observer import FAMILY
from sensorless.reports.envelope_options import NOISE_OPTIONS
from sensorless.reports.family import Option, ReportHooks
from sensorless.reports.options import Number, UsageError, parse_max_noise
from sensorless.reports.pmsm_flux_observer.firmware_io import EXPORTERS, IMPORTERS

# what computes is imported where it runs: every command reads these hooks for their options
if TYPE_CHECKING:
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive
    from sensorless.reports.pmsm_flux_observer.findings import failure_cause
    from sensorless.reports.pmsm_flux_observer.review import analyze, report
    from sensorless.reports.pmsm_flux_observer.startup import tune_startup
    from sensorless.tuning.pmsm_flux_observer import FluxTuneSettings
else:
    failure_cause = later(f"{__name__}.findings", "failure_cause")
    analyze, report = later(f"{__name__}.review", "analyze", "report")
    tune_startup = later(f"{__name__}.startup", "tune_startup")


# ------------------------------------------------------------------------------------------ analyze
def analyze_check(drive: FluxObserverDrive, args: argparse.Namespace) -> None:
    """The box clamp has no linearization: its CapabilityError, before anything is written."""
    if drive.observer.correction == "box-clamp":
        FAMILY.linearize(drive, FAMILY.gains(drive), np.array([drive.w_base]), np.zeros(1))


# --------------------------------------------------------------------------------------------- init
INIT_OPTIONS = (
    Option(
        ("--firmware",),
        {
            "choices": ("vesc", "odrive", "simplefoc"),
            "help": "the firmware the drive is for: its observer variant and default gains are written "
            "(default: the file's [observer] firmware, else the generic gradient observer)",
        },
    ),
)


def init_data(data: Any, args: argparse.Namespace, file: str) -> Any:
    """The minimal file's data with ``--firmware`` as its [observer] firmware (the file's own key where
    none is given; both given and different: one line naming both)."""
    fw = getattr(args, "firmware", None)
    if fw is None:
        return data
    obs = data.get("observer", {})
    if not isinstance(obs, dict):
        return data  # the schema names the bad section
    mine = obs.get("firmware")
    if mine is not None and mine != fw:
        raise UsageError(f"--firmware {fw}: {file} says [observer] firmware = {mine!r}; give one of the two")
    return {**data, "observer": {**obs, "firmware": fw}}


# --------------------------------------------------------------------------------------------- tune
TUNE_OPTIONS = (
    Option(("--bias-max",), {"type": Number(0.1, 90.0), "help": "largest angle bias that holds [deg]"}),
    Option(("--hold-speed",), {"type": Number(1e-3, 10.0), "help": "speed to hold down to [p.u.]"}),
    Option(("--r-error",), {"type": Number(0.0, 0.9), "help": "stator resistance error (fraction)"}),
    Option(("--flux-error",), {"type": Number(0.0, 0.9), "help": "PM flux estimate error (fraction)"}),
    Option(("--l-error",), {"type": Number(0.0, 0.9), "help": "inductance estimate error (fraction)"}),
    Option(
        ("--min-damping",),
        {
            "type": Number(0, 1, hi_open=True),
            "help": "worst damping required, in [0, 1) (default: none; the family judges decay, angle bias, "
            "angle noise and the PLL's lag instead): below it the tables are written with a warning and "
            "exit status 3",
        },
    ),
    # the shared noise limit and front options, as every family on the shared envelope declares them
    *(o for o in NOISE_OPTIONS if o.flags[0] in ("--max-noise", "--pareto")),
)


def tune_settings(drive: FluxObserverDrive, args: argparse.Namespace, tunable: Any) -> FluxTuneSettings:
    from sensorless.tuning.pmsm_flux_observer import check_variant

    check_variant(drive, tunable.name)  # up front: a law the drive's observer variant cannot run
    s = tunable.settings(drive)
    errors = dict(s.errors)
    for opt, key in (("r_error", "R_s"), ("flux_error", "psi_pm"), ("l_error", "L")):
        if getattr(args, opt, None) is not None:
            errors[key] = float(getattr(args, opt))
    s = dataclasses.replace(s, errors=errors)
    if args.bias_max is not None:
        s = dataclasses.replace(s, bias_max_deg=float(args.bias_max))
    if args.hold_speed is not None:
        s = dataclasses.replace(s, hold_speed=float(args.hold_speed) * drive.w_base)
    if args.min_damping is not None:
        s = dataclasses.replace(s, min_damping=float(args.min_damping))
    if args.max_noise:
        s = dataclasses.replace(s, max_noise=parse_max_noise(args.max_noise, drive.w_base))
    if args.pareto is not None:
        if tunable.name not in ("constant", "voltage-scaled"):
            raise UsageError(
                f"--pareto: the {tunable.name} law has no damping-versus-bias front (constant, "
                "voltage-scaled)"
            )
        s = dataclasses.replace(s, pareto=int(args.pareto))
    return s


def describe(drive: FluxObserverDrive, settings: FluxTuneSettings) -> str:
    e = drive.envelope
    err = settings.errors
    return (
        f"envelope: |speed| {e.rule.lo / drive.w_base:.3g}..{e.rule.hi / drive.w_base:.3g} p.u. "
        f"({e.rule.count} per direction) x torques {', '.join(f'{t:.4g}' for t in e.torque_values)} N m; "
        "estimate errors "
        f"R_s +-{100 * err['R_s']:g} %, psi_pm +-{100 * err['psi_pm']:g} %, L +-{100 * err['L']:g} %; "
        f"angle bias at most {settings.bias_max_deg:g} deg"
    )


HOOKS = ReportHooks(
    analyze=analyze,
    analyze_check=analyze_check,
    tune_options=TUNE_OPTIONS,
    tune_settings=tune_settings,
    describe_envelope=describe,
    startup_lines=tune_startup,
    report=report,
    failure_cause=failure_cause,
    settings_sections=("gains", "envelope", "control"),
    init_options=INIT_OPTIONS,
    init_data=init_data,
    importers=IMPORTERS,
    exporters=EXPORTERS,
)
