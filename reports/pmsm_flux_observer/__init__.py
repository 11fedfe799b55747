"""Report hooks of the flux-observer family: ``analyze`` output, ``tune`` options, the stability report,
and its firmware formats (``init --from``, ``export``: firmware_io.py).

- analyze: poles of the continuous observer and of the sampled one at the firmware's period
  (ln(z)/T_obs), damping and the observer's steady angle error over the envelope; poles.csv and a
  figure. The box clamp has no linearization: analyze says so in one line (judged by simulation);
- tune: the estimate errors, the bias limit and the hold speed of the laws' criterion (tuning/);
- report: the gains under review beside the firmwares' defaults on this motor (ODrive's, VESC Tool's
  detection), each judged by the tuning criterion (damping, angle bias, the speed below which it
  loses the motor), pole and damping maps over speed, the angle bias under each estimate error, and
  the built-in scenario re-run (reports/time_domain.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.gain_table import read_gain_table
from sensorless.design.pmsm_flux_observer import FAMILY, corner_estimate
from sensorless.design.poles import MIN_DAMPING
from sensorless.reports import time_domain
from sensorless.reports.csv_cells import REASON
from sensorless.reports.csv_cells import row as csv_row
from sensorless.reports.document import (
    Figure,
    Paragraph,
    Report,
    Section,
    Table,
    drive_section,
    f,
    num,
    svg_uri,
)
from sensorless.reports.envelope_options import NOISE_OPTIONS
from sensorless.reports.family import Option, ReportHooks
from sensorless.reports.files import OutputSet
from sensorless.reports.options import Number, UsageError, parse_max_noise
from sensorless.reports.pmsm_flux_observer.findings import (
    damping_finding,
    failure_cause,
    holds_nowhere_finding,
    pll_finding,
    pll_fixed,
)
from sensorless.reports.pmsm_flux_observer.firmware_io import EXPORTERS, IMPORTERS
from sensorless.reports.review import (
    gains_under_review,
    opening,
    settle,
    status_class,
    time_domain_checks,
    verdict_box,
)
from sensorless.tuning.pmsm_flux_observer import (
    FluxTuneSettings,
    assess_any,
    check_variant,
    corners,
    figures,
    hold_speed,
    judged,
    odrive_gains,
    shortfalls,
    vesc_gains,
)

TIME_DOMAIN = ("torque_steps",)
MAX_RMS_THETA_DEG = 10.0


def poles_figure(lin: Any, drive: Any, title: str) -> Any:
    """Damping of the sampled observer (x) and the continuous one (o), and the steady angle error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams["svg.hashsalt"] = "sensorless"
    fig, (a1, a2) = plt.subplots(2, 1, sharex=True, figsize=(6.4, 5.0))
    for j, T in enumerate(np.unique(lin.torque)):
        m = lin.torque == T
        w = lin.w[m] / drive.w_base
        c = f"C{j}"
        a1.plot(w, lin.worst_damping[m], "o", ms=3, mfc="none", color=c)
        a1.plot(w, lin.worst_damping_discrete[m], "x-", ms=3, color=c, label=f"T_e = {T:.3g} N m")
        a2.plot(w, np.degrees(lin.theta_err_discrete[m]), "-", color=c)
    a1.set_ylabel("worst damping")
    a1.legend(fontsize=8, frameon=False)
    a2.set_ylabel("angle error (deg)")
    a2.set_xlabel("speed (p.u.)")
    for a in (a1, a2):
        a.grid(True, lw=0.3, color="0.8")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig


# why a row of poles.csv has empty cells: the continuous observer's (_c) values, or the sampled one's (_d)
NO_EQUILIBRIUM = "no equilibrium of the observer found here"
NO_FIXED_POINT = "no fixed point of the sampled observer found here (near the continuous equilibrium)"


def poles_csv(lin: Any, drive: Any) -> str:
    """One row per operating point; an empty cell where the analysis has no value, said in the row."""
    lines = [
        f"# {drive.name}: flux observer + PLL poles; discrete at T_obs = {lin.T_s:g} s; speeds electrical",
        "w_rad_s,w_pu,T_e_Nm,damping_c,decay_c_1_s,damping_d,decay_d_1_s,theta_err_c_rad,theta_err_d_rad,"
        + REASON,
    ]
    cols = (lin.w, lin.w / drive.w_base, lin.torque, lin.worst_damping, lin.decay_rate)
    cols += (lin.worst_damping_discrete, lin.decay_rate_discrete, lin.theta_err, lin.theta_err_discrete)
    for k, row in enumerate(zip(*cols, strict=True)):
        lines.append(csv_row(row, NO_EQUILIBRIUM if not np.isfinite(lin.theta_err[k]) else NO_FIXED_POINT))
    return "\n".join(lines) + "\n"


def _shown(v: float, spec: str) -> str:
    """``v`` in ``spec``, or '-' where the analysis has no value (poles.csv says why)."""
    return (
        format(float(v), spec)
        if np.isfinite(v)
        else format("-", spec[0] + spec[1:].rstrip("fgs").split(".")[0])
    )


def not_finite(lin: Any) -> str | None:
    """The warning line of an analysis with points without a value (their rows say why), or None."""
    lost = ~np.isfinite(lin.worst_damping_discrete) | ~np.isfinite(lin.worst_damping)
    if not lost.any():
        return None
    return (
        f"poles.csv: no value at {int(lost.sum())} of {lost.size} operating points (empty cells; the row "
        f"says why): no equilibrium of the observer, or of the sampled observer, found there"
    )


def _close(fig: Any) -> None:
    import matplotlib.pyplot as plt

    plt.close(fig)


# ------------------------------------------------------------------------------------------ analyze
def analyze(drive: Any, args: argparse.Namespace, out: OutputSet) -> None:
    table = read_gain_table(args.gains) if args.gains else None
    gains = FAMILY.gains(drive, table=table, table_file=args.gains or "")
    W, T = drive.grid(2)
    lin = FAMILY.linearize(drive, gains, W, T)
    o = drive.observer
    print(f"{drive.name}: {drive.source}")
    print(f"{FAMILY.title} ({FAMILY.citation}); gains: {gains.source}")
    print(f"{o.firmware}: {o.correction}, {o.inductance_rule} inductance; T_obs = {o.T_obs * 1e6:g} us")
    head = f"{'speed [pu]':>10} {'worst damping c/d':>18} {'slowest decay c/d [1/s]':>24} "
    head += f"{'angle err [deg]':>16}"
    for T_e in drive.envelope.torques:
        print(f"T_e = {T_e:.4g} N m:\n  {head}")
        for k in np.flatnonzero(lin.torque == T_e)[::2]:
            print(
                f"  {lin.w[k] / drive.w_base:>10.3f} {_shown(lin.worst_damping[k], '>8.3f')}/"
                f"{_shown(lin.worst_damping_discrete[k], '<9.3f')} "
                f"{_shown(lin.decay_rate[k], '>11.4g')}/{_shown(lin.decay_rate_discrete[k], '<12.4g')} "
                f"{_shown(np.degrees(lin.theta_err_discrete[k]), '>16.4f')}"
            )
    print(
        f"worst over {lin.w.size} points: damping {np.nanmin(lin.worst_damping_discrete):.4f}, slowest decay "
        f"{np.nanmin(lin.decay_rate_discrete):.4g} 1/s (sampled observer)"
    )
    out.add_text("poles.csv", poles_csv(lin, drive))
    lost = not_finite(lin)
    if lost:  # not a result there: said, exit status 3 (as the other families' analyses)
        out.warnings.append(lost)
    fig = poles_figure(lin, drive, f"{drive.name}: damping (o continuous, x sampled) and angle error")
    out.add_figures("poles", fig)
    _close(fig)


def analyze_check(drive: Any, args: argparse.Namespace) -> None:
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


def tune_settings(drive: Any, args: argparse.Namespace, tunable: Any) -> FluxTuneSettings:
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
        if tunable.name not in ("odrive", "vesc"):
            raise UsageError(
                f"--pareto: the {tunable.name} law has no damping-versus-bias front (odrive, vesc)"
            )
        s = dataclasses.replace(s, pareto=int(args.pareto))
    return s


def describe(drive: Any, settings: FluxTuneSettings) -> str:
    e = drive.envelope
    err = settings.errors
    return (
        f"envelope: |speed| {e.speed_min / drive.w_base:.3g}..{e.speed_max / drive.w_base:.3g} p.u. "
        f"({e.speeds} per direction) x torques {', '.join(f'{t:.4g}' for t in e.torques)} N m; "
        "estimate errors "
        f"R_s +-{100 * err['R_s']:g} %, psi_pm +-{100 * err['psi_pm']:g} %, L +-{100 * err['L']:g} %; "
        f"angle bias at most {settings.bias_max_deg:g} deg"
    )


# ------------------------------------------------------------------------------------------- report
def compute(
    drive: Any,
    table: Any | None = None,
    table_file: str = "",
    min_damping: float = MIN_DAMPING,
    resolution: str = "normal",
    progress: Callable[[str], None] = lambda s: None,
    scenarios: Sequence[str] = (),
) -> Report:
    """The report's numbers, sections and verdict."""
    choices: dict[str, GainSet] = {"ODrive defaults": odrive_gains(), "VESC detection": vesc_gains(drive)}
    choices["drive file"] = FAMILY.gains(drive)
    rev = gains_under_review(FAMILY, drive, table, table_file, choices=choices)
    review = rev.label
    linearizable = drive.observer.correction != "box-clamp"
    settings = FluxTuneSettings()
    analysis: dict[str, Any] = {}
    sections: list[Any] = []
    figs: list[Any] = []
    if linearizable:
        progress("[1/3] the gains judged over the envelope under the estimate errors")
        labels = list(rev.choices)
        a = assess_any(drive, [rev.choices[k] for k in labels], settings)
        base = {
            k: figures(drive, a, j)
            for j, k in enumerate(labels)
            if k in ("ODrive defaults", "VESC detection")
        }
        w_hold = hold_speed(drive, settings, base)
        for j, k in enumerate(labels):
            fg = figures(drive, a, j)
            jd = judged(drive, a, j, settings)
            analysis[k] = {
                "worst_decay_1_s": f(jd["worst_decay_1_s"]) if math.isfinite(jd["worst_decay_1_s"]) else None,
                "pll_root_1_s": f(jd["pll_root_1_s"]),
                # what the gains under review miss of the family's criterion (the others: their row)
                "criterion_shortfalls": shortfalls(drive, rev.choices[k], jd, settings)
                if k == review
                else [],
                "gains": {n: f(v) for n, v in rev.choices[k].values.items() if not isinstance(v, list)},
                "law": rev.choices[k].law,
                "worst_damping": f(fg["worst_damping"]),
                "worst_bias_deg": f(fg["worst_bias_deg"]),
                "low_speed_limit_pu": f(fg["low_speed_limit_pu"])
                if math.isfinite(fg["low_speed_limit_pu"])
                else None,
                "stable_at_top": bool(a.holds[j, -1]),
            }
        rows = tuple(
            (
                k,
                x["law"],
                num(x["worst_damping"]),
                num(x["worst_bias_deg"]),
                num(x["low_speed_limit_pu"]) if x["low_speed_limit_pu"] is not None else "none holds",
                num(x["worst_decay_1_s"]),
                num(x["pll_root_1_s"]),
            )
            for k, x in analysis.items()
        )
        head = ("gains", "law", "worst damping", "worst angle bias (deg)", "holds down to (p.u.)")
        head += ("observer decay (1/s)", "PLL slow root (1/s)")
        cmp_table = Table(
            head,
            rows,
            "each gain set under every estimate error (sampled observer)",
            frozenset({2, 3, 4, 5, 6}),
        )
        W, T = drive.grid(1 if resolution == "quick" else 2)
        lin = FAMILY.linearize(drive, rev.gains, W, T)
        fig = Figure(
            svg_uri(poles_figure(lin, drive, f"{drive.name}: gains {review}")),
            "Worst damping of the continuous observer (o) and the sampled one at T_obs (x), and the sampled "
            "observer's steady angle error, over speed; colours: torque. Exact estimates.",
        )
        bias_fig = Figure(svg_uri(bias_figure(drive, rev.gains, settings)), bias_caption(settings))
        text = (
            "Judged as the tuner judges (tuning/pmsm_flux_observer): a speed holds when the sampled "
            "observer "
            f"is stable with an angle bias of at most {settings.bias_max_deg:g} deg under every estimate "
            f"error; the firmwares' defaults on this motor hold down to the speeds shown (the better: "
            f"{w_hold / drive.w_base:.3g} p.u.). The family's criterion (tuning/pmsm_flux_observer/"
            "criterion.py) asks the observer's decay from there up to reach the larger of the speed loop's "
            "bandwidth and what the full acceleration asks, and the PLL's slow root 4 x that bandwidth; "
            "damping is not its figure (k/(2|w|) falls with speed by design)."
        )
        items: tuple[Any, ...] = (Paragraph(text), cmp_table)
        pf = table.summary.get("pareto") if table is not None else None
        if pf is not None and pf.get("metric") == "bias":
            items += (
                Figure(
                    svg_uri(front_figure(pf, analysis.get(review, {}))),
                    f"Damping-versus-bias front of the {table.law} law (sensorless tune --pareto): the "
                    "candidates that hold down to the hold speed and that no other beats in both worst "
                    "damping and worst angle bias over the speeds from it up; x: the gains under review.",
                ),
            )
        sections.append(Section("2. The gains and the firmwares' defaults", items))
        sections.append(Section("3. Damping and angle error over speed", (fig, bias_fig)))
        figs = []
    else:
        sections.append(
            Section(
                "2. No linearization",
                (
                    Paragraph(
                        "The box-clamp observer (MXLEMMING) is not linearizable: it is judged by simulation."
                    ),
                ),
            )
        )
    progress("[2/3] time-domain check (the built-in scenario re-run)")
    runs = time_domain.scenarios(drive, TIME_DOMAIN, scenarios)
    td, td_figs = time_domain_checks(drive, rev, runs, progress)
    progress("[3/3] verdict")
    # the closed-loop error (None: a run the observer never had: not tested sensorless, said by its check)
    untested = [item["name"] for item in td if item.get("untested")]
    tracks = all((item["metrics"]["rms_theta_err_deg"] or 0.0) < MAX_RMS_THETA_DEG for item in td)
    mine = analysis.get(review, {})
    damped = not linearizable or (
        mine.get("worst_damping") is not None and mine["worst_damping"] >= min_damping
    )
    stable = not linearizable or mine.get("low_speed_limit_pu") is not None
    pll = pll_finding(rev.gains, drive.control.alpha_s, td)
    start, start_data = startup_findings(drive, rev.gains)
    # the family's criterion (tuning/pmsm_flux_observer/criterion.py) beyond holding somewhere and the
    # PLL (their own findings): holding only at the top speed, the observer's decay
    crit = (
        [
            x
            for x in mine.get("criterion_shortfalls", [])
            if "PLL" not in x and "at no envelope speed" not in x
        ]
        if linearizable and stable
        else []
    )
    clean = damped and tracks and not pll and not crit and not start
    status = "fail" if not stable else "pass" if clean else "warn"
    status, td_findings = settle(status, td)
    findings = []
    if linearizable and not stable:
        findings.append(holds_nowhere_finding(drive, rev.gains, settings))
    if not damped:
        findings.append(damping_finding(drive, a, labels.index(review), min_damping, rev.gains.law))
    findings += crit
    if not tracks:
        findings.append(f"a time-domain check exceeds {MAX_RMS_THETA_DEG:g} deg RMS position error")
    findings += [x["text"] for x in td_findings]
    if pll and not any("pll_root" in c.get("causes", ()) for c in td):  # else said as a check's cause
        findings.append(pll)
    findings += start
    findings += reversal_finding(drive, runs, td)
    limits = time_domain.limitations(drive)
    data = {
        **opening(FAMILY, drive, table, min_damping, review),
        "observer_period_s": f(drive.observer.T_obs),
        "analysis": analysis,
        "time_domain": td,
        "startup": start_data,
        "verdict": {
            "status": status,
            "damped": damped,
            "tracks": tracks,
            "findings": findings,
            "limitations": limits,  # what the generic checks leave out (e.g. an ODrive drive's zero speed)
        },
    }
    n = len(sections) + 2
    td_section = time_domain.section(n, td, td_figs, limits)
    all_sections = (drive_section(1, data["drive"]), *sections, td_section)
    summary = (
        f"Gains {review}: "
        + (
            f"worst damping {num(mine.get('worst_damping'))}, worst angle bias "
            f"{num(mine.get('worst_bias_deg'))} deg, "
            f"holds down to {num(mine.get('low_speed_limit_pu'))} p.u. (the lowest envelope speed from which "
            f"it is stable with an angle bias <= {settings.bias_max_deg:g} deg at every error corner); "
            if linearizable
            else "box clamp (not linearizable); "
        )
        + f"time-domain check {'within' if tracks else 'beyond'} {MAX_RMS_THETA_DEG:g} deg RMS "
        "position error in closed loop"
        + (f" ({len(untested)} not tested sensorless: {', '.join(untested)})." if untested else ".")
    )
    verdict = verdict_box(status, Paragraph(summary, status_class(status)), notes=limits, findings=findings)
    del figs
    return Report(drive.name, review, data, verdict, all_sections)


def startup_findings(drive: Any, gains: GainSet) -> tuple[list[str], dict[str, Any] | None]:
    """The drive's I-f start judged at the gains under review (design/startup_check.py): one finding per
    value that does not hold, naming the firmware's field and the value that fixes it, and the data of
    report.json; nothing where the drive needs no start or has no minimum-speed analysis."""
    from sensorless.design.family import CapabilityError
    from sensorless.design.pmsm_flux_observer.firmware import stored
    from sensorless.design.pmsm_flux_observer.firmware.startup import change_lines, fields
    from sensorless.design.startup_check import judge_startup

    try:
        judged = judge_startup(drive, gains)
    except CapabilityError:
        return [], None
    if judged is None:
        return [], None
    fw = drive.observer.firmware
    lead: list[str] = []
    fixed = None if judged.fixable else pll_fixed(gains, drive.control.alpha_s)
    again = None if fixed is None else judge_startup(drive, fixed)
    if again is not None and again.fixable:  # the PLL holds w_min at rated speed: the start at its fix
        lead = [x for x in change_lines(fw, judged, drive.w_base) if "no start-up value fixes it" in x]
        named = ", ".join(
            f"{k} = {stored(float(v))}" for k, v in fixed.values.items() if v != gains.values[k]
        )
        judged = again
        if judged.shortfalls:
            lead.append(f"start-up with the PLL's fix ({named}; the PLL's finding):")
    data = {
        "at_gains": "the PLL's fix" if lead else "under review",
        "w_min_rad_s": f(judged.w_min),
        "values": {k: f(v) for k, v in sorted(judged.values.items())},
        "firmware_fields": {k: f(v) for k, (v, _) in fields(fw, judged.values).items()}
        if judged.fixable
        else {},
        "shortfalls": [
            {"key": s.key, "value": f(s.value), "needed": f(s.needed), "cause": s.cause, "why": s.why}
            for s in judged.shortfalls
        ],
    }
    return lead + change_lines(fw, judged, drive.w_base), data


def reversal_finding(drive: Any, runs: Sequence[Any], td: Sequence[dict[str, Any]]) -> list[str]:
    """Where the firmware cannot run a failed check: ODrive's sensorless mode "does not support stopping
    or changing direction" (ODrive's documentation, sensorless mode), so a check through zero speed
    judges the I-f start's fall-back below w_off, which ODrive does not have."""
    from sensorless.design.scenario import crosses_zero

    if drive.observer.firmware != "odrive":
        return []
    through = {sc.name for sc in runs if crosses_zero(sc)}
    names = [c["name"] for c in td if not c["passed"] and c["name"] in through]
    if not names:
        return []
    return [
        f"{', '.join(names)}: through zero speed, which ODrive's sensorless mode does not support (its "
        'documentation: it "does not support stopping or changing direction"; no fall-back to open loop, no '
        "field for w_off); the check judges the I-f start's fall-back of the generated code, not ODrive: "
        "with ODrive, stop and reverse in closed loop with a sensor, or not at all"
    ]


def tune_startup(drive: Any, gains: GainSet) -> list[str]:
    """What ``tune`` says of the start at the tuned gains: the firmware's start-up fields it proposes
    (``export`` writes them), and one line per value of the drive file's that it changes, with why."""
    from sensorless.design.family import CapabilityError
    from sensorless.design.pmsm_flux_observer.firmware import stored
    from sensorless.design.pmsm_flux_observer.firmware.startup import change_lines, fields
    from sensorless.design.startup_check import judge_startup

    try:
        judged = judge_startup(drive, gains)
    except CapabilityError:
        return []
    if judged is None:
        return []
    fw = drive.observer.firmware
    lines = change_lines(fw, judged, drive.w_base)
    if judged.fixable:
        kept = "the drive file's kept where they hold" if judged.given else "by the rules"
        shown = ", ".join(f"{k} = {stored(v)} {u}" for k, (v, u) in fields(fw, judged.values).items())
        lines.insert(0, f"start-up at these gains ({kept}; sensorless export writes it): {shown}")
    return lines


def front_figure(pf: dict[str, Any], mine: dict[str, Any]) -> Any:
    """Worst damping over worst angle bias along the front, the gains under review marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams["svg.hashsalt"] = "sensorless"
    fig, ax = plt.subplots(figsize=(6.4, 3.4))
    pts = pf["points"]
    ax.plot([p["bias"] for p in pts], [p["worst_damping"] for p in pts], "o-", ms=4, label="front")
    if mine.get("worst_bias_deg") is not None and mine.get("worst_damping") is not None:
        ax.plot(mine["worst_bias_deg"], mine["worst_damping"], "kx", ms=8, label="gains under review")
    ax.set_xlabel("worst angle bias (deg)")
    ax.set_ylabel("worst damping")
    ax.grid(True, lw=0.3, color="0.8")
    ax.legend(fontsize=8, frameon=False)
    fig.tight_layout()
    return fig


def bias_caption(settings: FluxTuneSettings) -> str:
    e = settings.errors
    return (
        "Steady angle bias of the sampled observer at rated torque over speed, for each estimate error "
        f"alone (R_s +-{100 * e['R_s']:g} %, psi_pm +-{100 * e['psi_pm']:g} %, L +-{100 * e['L']:g} %) "
        "and the worst "
        "corner of all three; gains under review."
    )


def bias_figure(drive: Any, gains: GainSet, settings: FluxTuneSettings) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams["svg.hashsalt"] = "sensorless"
    s = drive.speed_grid(2)
    s = s[s > 0]
    T = np.full(s.size, drive.T_N)
    e = drive.estimate
    cases = {}
    for key, rel in (("R_s", settings.errors["R_s"]), ("psi_pm", settings.errors["psi_pm"])):
        for sign in (-1, 1):
            cases[f"{key} {sign * 100 * rel:+g} %"] = {key: getattr(e, key) * (1 + sign * rel)}
    for sign in (-1, 1):
        r = 1 + sign * settings.errors["L"]
        cases[f"L {sign * 100 * settings.errors['L']:+g} %"] = {"L_d": e.L_d * r, "L_q": e.L_q * r}
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for label, est in cases.items():
        lin = FAMILY.linearize(drive, gains, s, T, estimate=est)
        ax.plot(s / drive.w_base, np.degrees(lin.theta_err_discrete), label=label)
    worst = np.zeros(s.size)
    for c in corners(settings.errors)[1:]:
        est = corner_estimate(e, c)
        lin = FAMILY.linearize(drive, gains, s, T, estimate=est)
        worst = np.fmax(worst, np.abs(np.degrees(lin.theta_err_discrete)))
    ax.plot(s / drive.w_base, worst, "k--", label="worst corner |bias|")
    ax.set_ylim(-45, 45)
    ax.set_xlabel("speed (p.u.)")
    ax.set_ylabel("angle bias (deg)")
    ax.grid(True, lw=0.3, color="0.8")
    ax.legend(fontsize=7, frameon=False, ncol=2)
    fig.tight_layout()
    return fig


HOOKS = ReportHooks(
    analyze=analyze,
    analyze_check=analyze_check,
    tune_options=TUNE_OPTIONS,
    tune_settings=tune_settings,
    describe_envelope=describe,
    startup_lines=tune_startup,
    report=compute,
    failure_cause=failure_cause,
    settings_sections=("gains", "envelope", "control"),
    init_options=INIT_OPTIONS,
    init_data=init_data,
    importers=IMPORTERS,
    exporters=EXPORTERS,
)
