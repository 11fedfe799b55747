"""How the adaptive observer judges its gains on the shared report frame (reports/envelope_review.py).

Piippo, Hinkkanen, Luomi (2008): pole maps over speed at +-T_N for each gain (Figs. 4-5 style) and with
the averaged HF injection (19)-(22); worst damping and decay rate over the speed x torque plane;
robustness maps under misestimated R̂s, L̂d, L̂q, ψ̂pm; the paper's experiments re-run (Figs. 9(b), 10,
6(b)); the discrete-time observer that runs (sampled_analysis.py); and a verdict that states where the gains
under review meet the required damping and where not. The frame (opening data, time-domain checks, the
verdict's status with them, the sections' order) is the shared one; the analysis, the gain sets (each
of the drive file's gain choices) and the verdict's form are this family's.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.gain_table import GainTable
from sensorless.design.ipmsm_adaptive import FAMILY, injection_off, with_alpha_fo
from sensorless.design.ipmsm_adaptive.carrier import coupling_limit, coupling_torque
from sensorless.design.ipmsm_adaptive.linearize import PoleSweep, unstable_speed_bands
from sensorless.design.ipmsm_adaptive.runtime import law_of
from sensorless.reports.document import (
    Figure,
    Paragraph,
    Report,
    Section,
    Table,
    Verdict,
    arr,
    f,
    num,
)
from sensorless.reports.envelope_review import Analysis, Checks, Judgement, Judging, report_with
from sensorless.reports.ipmsm_adaptive import tuning
from sensorless.reports.ipmsm_adaptive.causes import crossings
from sensorless.reports.ipmsm_adaptive.figures import plane_figure, robustness_figure
from sensorless.reports.ipmsm_adaptive.sampled_analysis import report_section as discrete_section
from sensorless.reports.review import Review, settle, verdict_box
from sensorless.reports.svg_render import svg_later
from sensorless.reports.time_domain import Finding

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.ipmsm_adaptive.schema import IpmsmDrive

TIME_DOMAIN = ("fig9b", "fig10", "fig6b")  # built-in scenarios re-run with the gains under review


def drive_label(drive: IpmsmDrive, name: str) -> str:
    """The label of the drive file's gain ``name``: "paper <name>" for a preset (its gains are the
    paper's, Fig. 4), else "drive file's <name>" (a user's drive: the baseline, not the paper's)."""
    return f"paper {name}" if drive.file.startswith("preset:") else f"drive file's {name}"


def gain_choices(drive: IpmsmDrive, table: Any | None, table_file: str) -> tuple[dict[str, GainSet], str]:
    """Label -> gains: the drive file's gain choices, plus the table's; and the label under review."""
    choices = {drive_label(drive, name): FAMILY.gains(drive, name=name) for name in drive.observer.gains}
    if table is None:
        return choices, drive_label(drive, drive.observer.gain)
    g = FAMILY.gains(drive, table=table, table_file=table_file)
    label = f"tuned {g.law}"
    choices[label] = g
    return choices, label


def _worst_point(s: PoleSweep, w_min: float, w_base: float) -> dict[str, Any]:
    """Least-damped point among those with |w| >= w_min (where the envelope starts)."""
    z = np.where(np.abs(s.w) >= w_min, s.worst_damping, np.inf)
    z = np.where(np.isnan(z), np.inf, z)
    k = int(np.argmin(z))
    return {
        "w_pu": f(s.w[k] / w_base),
        "T_Nm": f(s.torque[k]),
        "damping": f(s.worst_damping[k]),
        "decay_rate": f(s.decay_rate[k]),
    }


class AdaptiveJudge(Judging["IpmsmDrive"]):
    """The family's :class:`~sensorless.reports.envelope_review.Judge` (module docstring)."""

    def review(self, drive: IpmsmDrive, table: GainTable | None, table_file: str) -> Review:
        choices, review = gain_choices(drive, table, table_file)
        return Review(choices, review, table is not None, table)

    time_domain = TIME_DOMAIN

    def analyse(
        self,
        drive: IpmsmDrive,
        rev: Review,
        min_damping: float,
        resolution: str,
        progress: Callable[[str], None],
    ) -> Analysis:
        """Pole maps over speed, the damping maps over speed x torque, the robustness maps, the
        discrete-time observer that runs and the tuning's bound (sections 2-4, then 6 and 7)."""
        from sensorless.reports.pole_map import plot_pole_maps

        wb, T_N = drive.w_base, drive.T_N
        fine = resolution == "normal"
        w = np.linspace(-1, 1, 801 if fine else 201) * wb
        w_low = np.linspace(-0.05, 0.05, 401 if fine else 101) * wb
        w_env = 0.05 * wb  # where the tuning envelope starts by default
        choices, review = rev.choices, rev.label
        data: dict[str, Any] = {}
        pole_figs: list[Figure] = []

        def bands(g: GainSet, T: float, s: PoleSweep, injection: bool) -> list[list[Any]]:
            d = with_alpha_fo(drive, g)
            out = unstable_speed_bands(d, w, T, gain=law_of(g), injection=injection, sweep=s)
            return [[f(a / wb), f(b / wb)] for a, b in out]

        # 1. pole maps over speed at +-T_N, each gain; then the gain under review with injection
        steps = STEPS + 2  # and the time-domain checks and the verdict (reports/envelope_review.py)
        progress(f"[1/{steps}] pole maps over speed ({len(choices)} gains x 2 torques, {w.size} speeds)")
        pm: dict[str, Any] = {}
        for T in (T_N, -T_N):
            sweeps, lows = {}, {}
            for label, g in choices.items():
                s = FAMILY.linearize(drive, g, w, T)
                sweeps[label], lows[label] = s, FAMILY.linearize(drive, g, w_low, T)
                pm.setdefault(label, {})[f"{T:+g}"] = {
                    "T_Nm": f(T),
                    "rhp_bands_pu": bands(g, T, s, False),
                    "worst": _worst_point(s, w_env, wb),
                }
            title = f"{drive.name}: closed-loop poles at T_e = {T:g} N m"
            pole_figs.append(
                Figure(
                    svg_later(functools.partial(plot_pole_maps, sweeps, wb, title, lows)),
                    f"Closed-loop poles of G_c(s), eq. (15), at T_e = {T:+g} N m while the speed sweeps "
                    "-1…1 p.u. "
                    "(left, Fig. 4 style; upper half-plane), and magnified near the origin with a dense "
                    "low-speed sweep (right, Fig. 5 style). Crosses: right-half-plane poles; the RHP is "
                    "shaded.",
                )
            )
        g_rev = choices[review]
        if drive.injection.enabled:
            progress(f"[2/{steps}] pole maps with HF injection ({review})")
            inj_sweeps, inj_lows = {}, {}
            for T in (T_N, -T_N):
                s = FAMILY.linearize(drive, g_rev, w, T, injection=True)
                key = f"T = {T:+g} N m"
                inj_sweeps[key] = s
                inj_lows[key] = FAMILY.linearize(drive, g_rev, w_low, T, injection=True)
                pm.setdefault(f"{review} + injection", {})[f"{T:+g}"] = {
                    "T_Nm": f(T),
                    "rhp_bands_pu": bands(g_rev, T, s, True),
                    "worst": _worst_point(s, w_env, wb),
                }
            # the fastest growth with the injection (its RHP band, if any, is named in the verdict)
            growth = max(float(np.nanmax(np.real(x.poles))) for x in inj_sweeps.values())
            inj_title = f"{drive.name}: {review} with HF injection (averaged (19)-(22))"
            inj_block: Any = Figure(
                svg_later(functools.partial(plot_pole_maps, inj_sweeps, wb, inj_title, inj_lows)),
                "The gains under review with the averaged HF injection (19)-(22), at ±T_N, active for "
                "|ω| < ω_Δ: compare the right-half-plane bands with and without it in the table above.",
            )
        else:
            growth = float("nan")
            progress(f"[2/{steps}] no HF injection: {injection_off(drive)}")
            inj_block = Paragraph(
                f"No pole maps with HF injection: {injection_off(drive)}. Without it, a right-half-plane "
                "band at low speed (if the table above shows one) is where the drive cannot run sustained."
            )
        data["pole_maps"] = pm

        # 3. worst damping / decay rate over speed x torque: the drive file's default gains vs the review
        progress(f"[3/{steps}] damping and decay-rate maps over speed x torque")
        w_map = np.linspace(-1, 1, 161 if fine else 41) * wb
        T_map = np.linspace(-1.5, 1.5, 31 if fine else 7) * T_N
        default = drive_label(drive, drive.observer.gain)
        maps: dict[str, Any] = {}
        for label in dict.fromkeys([default, review]):
            s = FAMILY.linearize(drive, choices[label], w_map[:, None], T_map[None, :])
            maps[label] = {
                "damping": arr(s.worst_damping.reshape(w_map.size, T_map.size)),
                "decay_rate": arr(s.decay_rate.reshape(w_map.size, T_map.size)),
                "worst": _worst_point(s, w_env, wb),
                "unstable_points": int(np.sum(s.max_real > 0)),
            }
        data["plane"] = {"w_pu": arr(w_map / wb), "T_Nm": arr(T_map), "maps": maps}
        plane_fig = Figure(
            svg_later(functools.partial(plane_figure, maps, w_map / wb, T_map, T_N)),
            "Worst damping ratio (top) and decay rate (bottom) of the linearized closed loop over the speed "
            "× torque plane; hatched with a black outline: unstable; star: least-damped point with |ω| ≥ "
            "0.05 p.u.",
        )

        # 4. robustness under estimation errors (gains under review, nominal motoring torque)
        progress(f"[4/{steps}] robustness maps under parameter-estimate errors")
        errs = {"R_s": 50.0, "L_d": 20.0, "L_q": 20.0, "psi_pm": 20.0}
        idx = {"R_s": 0, "L_d": 1, "L_q": 2, "psi_pm": 3}
        w_rob = np.linspace(-1, 1, 121 if fine else 31) * wb
        rob: dict[str, Any] = {"T_Nm": f(T_N), "w_pu": arr(w_rob / wb), "params": {}}
        true = np.array(drive.motor.vector())
        for name, span in errs.items():
            e = np.linspace(-span, span, 21 if fine else 5)
            est = np.broadcast_to(true, (e.size, 1, 4)).copy()
            est[:, 0, idx[name]] *= 1 + e / 100
            s = FAMILY.linearize(drive, g_rev, w_rob[None, :], T_N, estimate=est)
            Z = s.worst_damping.reshape(e.size, w_rob.size)
            ok = np.isfinite(Z) & (Z > 0)
            rob["params"][name] = {
                "error_pct": arr(e),
                "damping": arr(Z),
                "stable_fraction": f(ok.mean()),
                "no_equilibrium_fraction": f(np.isnan(Z).mean()),
            }
        data["robustness"] = rob
        rob_fig = Figure(
            svg_later(functools.partial(robustness_figure, rob, w_rob / wb, review)),
            f"Worst damping of the gains under review at T_e = {num(rob['T_Nm'])} N m when one estimate "
            "(R̂s, L̂d, L̂q, ψ̂pm) is off by the given percentage; the equilibrium is followed from the exact "
            "estimates by continuation. Black outline: unstable; grey: no equilibrium (the observer cannot "
            "hold the rotor).",
        )

        # 6. and 7., after the time-domain checks (section 5)
        progress(f"[5/{steps}] the discrete-time observer that runs ({drive.run.discretization})")
        data["discrete"], disc_section = discrete_section(6, drive, choices, review, fine, progress)
        progress(f"[6/{steps}] tuning: the pointwise bound and noise over the envelope")
        tuning_data, tuning_section = tuning.compute(drive, rev.table, choices, review, progress, default)
        data["tuning"] = tuning_data
        sections = (
            Section("2. Pole maps over speed", (_pole_table(pm), *pole_figs, inj_block)),
            Section("3. Damping and decay rate over speed × torque", (plane_fig, _plane_table(maps))),
            Section("4. Robustness to parameter-estimate errors", (rob_fig, _robustness_table(rob))),
        )
        later = (disc_section, *([tuning_section] if tuning_section is not None else []))
        w1 = coupling_limit(drive.motor, T_N) / wb  # where the HF correction turns sign, regenerating
        # the regenerating torque at which it holds up to the fade-out (the band closes), and w_Delta
        t_c = coupling_torque(drive.motor, drive.injection.w_Delta, T_N)
        return Analysis(
            None, sections, data, (w1, growth, t_c, T_N, drive.injection.w_Delta / wb), later, STEPS
        )

    def verdict(
        self, drive: IpmsmDrive, rev: Review, found: Analysis, checks: Checks, min_damping: float
    ) -> Judgement:
        return judgement({**found.data, "time_domain": checks.td}, rev.label, min_damping, found.context)

    def conclude(
        self, v: Judgement, status: str, td_findings: list[Finding], limits: list[str]
    ) -> tuple[dict[str, Any], Verdict]:
        data = {**verdict_data(v, status, td_findings), "limitations": limits}
        return data, verdict_block(data)


def _pole_table(pm: dict[str, Any]) -> Table:
    rows = []
    for label, per_T in pm.items():
        for v in per_T.values():
            b = ", ".join(f"{a:+.4f} … {c:+.4f}" for a, c in v["rhp_bands_pu"]) or "none"
            wk = v["worst"]
            rows.append(
                (
                    label,
                    num(v["T_Nm"]),
                    b,
                    num(wk["damping"], 3),
                    f"{num(wk['w_pu'], 3)}, {num(wk['T_Nm'], 3)}",
                )
            )
    header = (
        "gains",
        "torque (N m)",
        "RHP speed bands (p.u.)",
        "worst damping, |ω| ≥ 0.05 p.u.",
        "at (p.u., N m)",
    )
    return Table(header, tuple(rows), numeric=frozenset({1, 3, 4}))


def _plane_table(maps: dict[str, Any]) -> Table:
    rows = []
    for label, m in maps.items():
        wk = m["worst"]
        rows.append(
            (
                label,
                num(wk["damping"], 3),
                num(wk["w_pu"], 3),
                num(wk["T_Nm"], 3),
                num(wk["decay_rate"], 3),
                str(m["unstable_points"]),
            )
        )
    header = (
        "gains",
        "worst damping",
        "at ω (p.u.)",
        "at T_e (N m)",
        "decay rate there (1/s)",
        "unstable grid points",
    )
    return Table(header, tuple(rows), numeric=frozenset({1, 2, 3, 4, 5}))


def _robustness_table(rob: dict[str, Any]) -> Table:
    rows = tuple(
        (
            name,
            f"±{num(max(v['error_pct']), 3)}",
            num(v["stable_fraction"], 3),
            num(v["no_equilibrium_fraction"], 3),
        )
        for name, v in rob["params"].items()
    )
    return Table(
        ("estimate", "error range (%)", "stable fraction", "no-equilibrium fraction"),
        rows,
        numeric=frozenset({1, 2, 3}),
    )


def judgement(
    data: dict[str, Any],
    label: str,
    min_damping: float,
    coupling: tuple[float, ...] = (float("inf"), float("nan")),
) -> Judgement:
    """Where the reviewed gains are stable with the required damping, where not, and why;
    ``coupling``: the speed [p.u.] below which the HF correction holds regenerating at T_N with zero
    gain (design/ipmsm_adaptive/carrier.py ``coupling_limit``) and the fastest growth [1/s] with the
    injection, named where the injection's RHP band is regenerating only; optionally then the
    regenerating torque [N m] at which the correction holds up to the fade-out (``coupling_torque``),
    T_N [N m] and w_Delta [p.u.]: what to change, said with the reason."""
    plane = data["plane"]
    m = plane["maps"][label]
    w_pu = np.array(plane["w_pu"], float)
    T = np.array(plane["T_Nm"], float)
    Z = np.array(m["damping"], float)
    bad_unstable = Z < 0
    bad_damped = (Z >= 0) & (Z < min_damping)
    findings = []
    for what, mask in (("unstable", bad_unstable), (f"damping below {min_damping:g}", bad_damped)):
        if not mask.any():
            continue
        ii, jj = np.nonzero(mask)
        for sign, mode_pos in ((1, "motoring"), (-1, "regenerating")):
            sel = np.sign(w_pu[ii] * T[jj]) == sign
            if not sel.any():
                continue
            wsel = np.abs(w_pu[ii][sel])
            findings.append(
                {
                    "issue": what,
                    "mode": mode_pos,
                    "speed_pu_min": f(wsel.min()),
                    "speed_pu_max": f(wsel.max()),
                    "points": int(sel.sum()),
                }
            )
    pm = data["pole_maps"]
    inj = pm.get(f"{label} + injection", {})
    rhp = {k: v["rhp_bands_pu"] for k, v in pm[label].items()}
    rhp_inj = {k: v["rhp_bands_pu"] for k, v in inj.items()}
    reasons, notes = [], []
    # w_Delta [p.u.]: the speed below which the drive injects (unknown: the injection's whole analysis
    # decides)
    w_delta = coupling[4] if len(coupling) >= 5 else float("inf")
    if any(rhp.values()):
        edge = max(abs(b) for bands in rhp.values() for band in bands for b in band)
        if not inj:  # the drive does not inject: nothing holds the observer there
            reasons.append(
                f"RHP real pole below {edge:.3g} p.u. (rotor saliency, Section IV-B) and no HF injection "
                "([injection] u_c = 0): the observer alone cannot hold sustained operation there; the HF "
                "injection of Section V (19)-(22) stabilizes it, or the drive must not dwell below it."
            )
        elif not any(rhp_inj.values()) and edge <= w_delta:
            # the drive that runs injects there (Section V: "the low-speed operation can be stabilized by
            # augmenting the adaptive observer with an HF signal injection"): judged with the injection
            notes.append(
                f"The observer alone has a real RHP pole below {edge:.3g} p.u. (rotor saliency, Section "
                f"IV-B); the drive injects there (|ω| < ω_Δ = {w_delta:.3g} p.u.), and the loop that runs, "
                "the observer with the averaged HF injection (19)-(22), has no RHP pole at any analysed "
                "speed: the verdict judges that loop (Section V)."
            )
        elif not any(rhp_inj.values()):
            reasons.append(
                f"RHP real pole below {edge:.3g} p.u. (rotor saliency, Section IV-B), above the injection's "
                f"fade-out ω_Δ = {w_delta:.3g} p.u.: the observer alone runs there."
            )
        elif _regenerating_only(rhp_inj):
            a = min(abs(b) for bands in rhp_inj.values() for band in bands for b in band)
            b = max(abs(b) for bands in rhp_inj.values() for band in bands for b in band)
            reasons.append(
                f"HF-injection coupling limit: regenerating at ±T_N the injection leaves a real RHP pole for "
                f"{a:.3g} ≤ |ω| ≤ {b:.3g} p.u. (growth up to {coupling[1]:.2g} 1/s), where the observer's "
                "answer to the HF correction (20) turns sign (below (R̂s + λ1) ψ_d / (L_d L_q |i_q|) = "
                f"{coupling[0]:.3g} p.u. at T_N with λ1 = 0: "
                f"design/ipmsm_adaptive/carrier.py); {crossings(data.get('time_domain') or [])}"
                f"{_coupling_change(coupling)}"
            )
        else:
            reasons.append(f"RHP pole below {edge:.3g} p.u. remains even with the injection.")
    ok = np.isfinite(Z) & (Z >= min_damping)
    envelope = {"fraction_ok": f(ok.mean()), "abs_speed_pu_from": None}
    absw = np.abs(w_pu)
    for thr in np.unique(absw):  # smallest |w| above which every torque row is fine
        if ok[absw >= thr].all():
            envelope["abs_speed_pu_from"] = f(thr)
            break
    if not findings and not reasons:
        status = "pass"
    elif envelope["abs_speed_pu_from"] is not None:
        status = "warn"
    else:
        status = "fail"
    more = {
        "gains": label,
        "min_damping": min_damping,
        "envelope": envelope,
        "reasons": reasons,
        "notes": notes,
        "rhp_bands_pu": rhp,
        "rhp_bands_pu_injection": rhp_inj,
    }
    return Judgement(status, findings, "", data=more)


def _coupling_change(coupling: tuple[float, ...]) -> str:
    """What to change where the injection's coupling band is regenerating (``judgement``'s ``coupling``
    with its torque, T_N and w_Delta; "" without them)."""
    if len(coupling) < 5 or not coupling[2] < coupling[3]:
        return ""
    t_c, T_N, w_d = coupling[2], coupling[3], coupling[4]
    return (
        f" To hold a regenerating speed below ω_Δ = {w_d:.3g} p.u.: keep the regenerating torque there "
        f"within {t_c:.4g} N m ({t_c / T_N:.3g} T_N), where the correction (with zero gain near zero "
        "speed, as law (16) has) holds up to ω_Δ, or run on a position sensor there."
    )


def verdict_data(v: Judgement, status: str, td_findings: list[Finding]) -> dict[str, Any]:
    """report.json "verdict" (without its limitations) of the judgement ``v`` settled with the
    time-domain checks: the findings as records, the analysis's first."""
    return {"status": status, **v.data, "findings": [*v.findings, *td_findings]}


def verdict(
    data: dict[str, Any],
    label: str,
    min_damping: float,
    coupling: tuple[float, ...] = (float("inf"), float("nan")),
) -> dict[str, Any]:
    """The verdict data (:func:`judgement`) settled with the time-domain checks of ``data``."""
    v = judgement(data, label, min_damping, coupling)
    return verdict_data(v, *settle(v.status, data.get("time_domain") or []))


def _regenerating_only(rhp: dict[str, list[list[float]]]) -> bool:
    """Whether every RHP band (torque key -> speed bands in p.u.) lies where the speed's sign is not the
    torque's (regenerating)."""
    ends = [(float(T), b) for T, bands in rhp.items() for band in bands for b in band]
    return bool(ends) and all(T * b <= 0 for T, b in ends)


def verdict_block(v: dict[str, Any]) -> Verdict:
    """The verdict box of the HTML from the verdict data."""
    env = v["envelope"]
    frm = env["abs_speed_pu_from"]
    if frm is not None:
        summary = Paragraph(
            f"Gains {v['gains']}, the observer alone (eq. (15) linearized): stable with damping ≥ "
            f"{v['min_damping']:g} for |ω| ≥ {frm:.3g} p.u. at all analysed torques (±1.5 T_N); "
            f"{100 * env['fraction_ok']:.1f} % of the speed × torque grid meets it"
            + ("." if v["status"] == "pass" else " (the verdict's other findings: below)."),
            "ok" if v["status"] == "pass" else "",
        )
    else:
        summary = Paragraph(
            f"Gains {v['gains']}, the observer alone (eq. (15) linearized): the required damping "
            f"{v['min_damping']:g} is not met at high speed for some torque.",
            "bad",
        )
    findings = tuple(
        x["text"]
        if "text" in x
        else f"{x['issue']} in {x['mode']} for {x['speed_pu_min']:.3g} ≤ |ω| ≤ {x['speed_pu_max']:.3g} "
        f"p.u. ({x['points']} grid points)"
        for x in v["findings"]
    )
    return verdict_box(v["status"], summary, v["reasons"], [*v.get("notes", ()), *v["limitations"]], findings)


STEPS = 6  # the progress steps of the analysis (AdaptiveJudge.analyse)
JUDGE = AdaptiveJudge()
# typed: its hooks (reports/ipmsm_adaptive/__init__.py) read it through an import cycle
compute: Callable[..., Report] = report_with(JUDGE)
