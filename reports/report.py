"""Stability report of a drive's observer gains: one self-contained HTML file plus its data as JSON.

The report is computed once into a plain data dictionary (every number the HTML shows; written as
JSON), and the HTML is rendered from that dictionary and the figures. Figures are SVG embedded as
data URIs, so the file needs no network and element ids of different figures cannot collide. The JSON
carries no date, so two runs on the same inputs give identical JSON; the HTML states the date.
"""

from __future__ import annotations

import base64
import dataclasses
import datetime as _dt
import hashlib
import html
import io
import json
import re
import sys
from collections.abc import Callable
from typing import Any

import numpy as np
from sensorless.design.linearize import PoleSweep, linearize, unstable_speed_bands

Progress = Callable[[str], None]


def _stderr_progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# --------------------------------------------------------------------------------------------------
# Gains under review
# --------------------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class GainChoice:
    """A gain choice to analyse: a label, the drive (alpha_fo may differ) and the gain argument."""

    label: str
    drive: Any
    gain: Any  # name of [observer.gains.*] or (law, params)


def gain_choices(drive: Any, table: Any | None) -> tuple[list[GainChoice], GainChoice]:
    """The paper's gains of the drive, plus the tuned table's; and the one under review."""
    paper = [GainChoice(f"paper {g}", drive, g) for g in drive.observer.gains]
    if table is None:
        review = next(c for c in paper if c.gain == drive.observer.gain)
        return paper, review
    from sensorless.design.runtime import table_gain

    law, values, alpha_fo, family = table_gain(table, "gain table")
    d = dataclasses.replace(drive, observer=dataclasses.replace(drive.observer, alpha_fo=alpha_fo))
    tuned = GainChoice(f"tuned {family}", d, (law, list(values)))
    return [*paper, tuned], tuned


# --------------------------------------------------------------------------------------------------
# Figures
# --------------------------------------------------------------------------------------------------
def _svg_data_uri(fig: Any) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="svg", metadata={"Date": None})
    plt.close(fig)
    return "data:image/svg+xml;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _plane_figure(maps: dict[str, dict[str, Any]], w_pu: np.ndarray, T: np.ndarray, T_N: float) -> Any:
    import matplotlib.pyplot as plt

    cols = list(maps)
    fig, axes = plt.subplots(
        2, len(cols), figsize=(5.2 * len(cols), 7.4), squeeze=False, layout="constrained"
    )
    for c, label in enumerate(cols):
        m = maps[label]
        for r, (key, name, cmap, vmin, vmax) in enumerate(
            (
                ("damping", "worst damping ratio ζ", "RdYlGn", -0.2, 1.0),
                ("decay_rate", "decay rate −max Re(p) (1/s)", "viridis", 0.0, None),
            )
        ):
            ax = axes[r, c]
            Z = np.array(m[key], float)
            vmax_ = vmax if vmax is not None else np.nanpercentile(Z, 99)
            pc = ax.pcolormesh(
                w_pu, T / T_N, Z.T, cmap=cmap, vmin=vmin, vmax=vmax_, shading="nearest", rasterized=True
            )
            unstable = np.array(m["damping"], float) < 0
            if unstable.any():
                ax.contourf(
                    w_pu,
                    T / T_N,
                    unstable.T.astype(float),
                    levels=[0.5, 1.5],
                    colors="none",
                    hatches=["////"],
                )
                ax.contour(w_pu, T / T_N, unstable.T.astype(float), levels=[0.5], colors="k", linewidths=0.8)
            wk = m["worst"]
            ax.plot(wk["w_pu"], wk["T_Nm"] / T_N, marker="*", ms=14, mfc="w", mec="k")
            ax.set_xlabel("speed ω_m (p.u.)")
            ax.set_ylabel("torque T_e / T_N")
            ax.set_title(f"{label}: {name}", fontsize=9)
            fig.colorbar(pc, ax=ax)
    return fig


def _robustness_figure(rob: dict[str, Any], w_pu: np.ndarray, label: str) -> Any:
    import matplotlib.pyplot as plt

    names = list(rob["params"])
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.4), squeeze=False, layout="constrained")
    for ax, name in zip(axes.ravel(), names, strict=False):
        p = rob["params"][name]
        err = np.array(p["error_pct"], float)
        Z = np.array(p["damping"], float)
        cm = plt.get_cmap("RdYlGn").with_extremes(bad="0.6")  # no equilibrium: grey
        pc = ax.pcolormesh(w_pu, err, Z, cmap=cm, vmin=-0.2, vmax=1.0, shading="nearest", rasterized=True)
        uns = np.nan_to_num(Z, nan=1.0) < 0
        if uns.any():
            ax.contour(w_pu, err, uns.astype(float), levels=[0.5], colors="k", linewidths=0.8)
        ax.axhline(0, color="k", lw=0.5, ls=":")
        ax.set_xlabel("speed ω_m (p.u.)")
        ax.set_ylabel(f"error of estimate {name} (%)")
        ax.set_title(f"{label}: worst damping, {name} misestimated", fontsize=9)
        fig.colorbar(pc, ax=ax, label="ζ (grey: no equilibrium)")
    return fig


# --------------------------------------------------------------------------------------------------
# Computation
# --------------------------------------------------------------------------------------------------
def _f(x: Any) -> Any:
    """JSON-safe float (None for NaN/inf), rounded to 12 significant digits for stable text."""
    x = float(x)
    return float(f"{x:.12g}") if np.isfinite(x) else None


def _arr(a: np.ndarray) -> list:
    return [[_f(v) for v in row] for row in np.atleast_2d(a)] if np.ndim(a) == 2 else [_f(v) for v in a]


def _worst_point(s: PoleSweep, w_min: float, w_base: float) -> dict[str, Any]:
    """Least-damped point among those with |w| >= w_min (where the envelope starts)."""
    z = np.where(np.abs(s.w_m) >= w_min, s.worst_damping, np.inf)
    z = np.where(np.isnan(z), np.inf, z)
    k = int(np.argmin(z))
    return {
        "w_pu": _f(s.w_m[k] / w_base),
        "T_Nm": _f(s.T_e[k]),
        "damping": _f(s.worst_damping[k]),
        "decay_rate": _f(s.decay_rate[k]),
    }


def _unit_of(doc: str) -> str:
    """The unit in square brackets of a field's doc text ("stator resistance [ohm]" -> "ohm")."""
    m = re.search(r"\[([^\]]+)\]", doc)
    return m.group(1) if m else ""


def drive_tables(drive: Any) -> dict[str, list[dict[str, Any]]]:
    """Drive and observer data as rows (name, value, unit, per-unit where the drive has bases)."""
    b = getattr(drive, "base", None)
    pu = (
        {
            "angular": b.w,
            "voltage": b.u,
            "current": b.i,
            "resistance": b.Z,
            "inductance": b.Z / b.w,
            "flux": b.psi,
        }
        if b is not None
        else {}
    )
    tables: dict[str, list[dict[str, Any]]] = {}
    for sf in dataclasses.fields(drive):
        obj = getattr(drive, sf.name)
        if not dataclasses.is_dataclass(obj) or sf.name in ("observer", "runtime", "tuning"):
            continue
        tables[sf.name] = _rows(obj, pu)
    obs = drive.observer
    rows = []
    for f in dataclasses.fields(obs):
        v = getattr(obs, f.name)
        if f.name == "gains":
            for gname, g in v.items():
                for gf in dataclasses.fields(g):
                    doc = gf.metadata.get("doc", "")
                    rows.append(
                        {
                            "name": f"{gname}.{gf.name}",
                            "value": _f(getattr(g, gf.name)),
                            "unit": _unit_of(doc),
                            "what": f"gain law '{gname}': {doc}",
                            "pu": None,
                        }
                    )
        elif isinstance(v, int | float) and not isinstance(v, bool):
            doc = f.metadata.get("doc", "")
            dim = f.metadata.get("dim")
            rows.append(
                {
                    "name": f.name,
                    "value": _f(v),
                    "unit": _unit_of(doc),
                    "what": doc,
                    "pu": _f(v / pu[dim]) if dim in pu else None,
                }
            )
    tables["observer"] = rows
    return tables


def _rows(obj: Any, pu: dict[str, float]) -> list[dict[str, Any]]:
    rows = []
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        doc = f.metadata.get("doc", "")
        dim = f.metadata.get("dim")
        if isinstance(v, tuple | list):
            if not all(isinstance(x, int | float) for x in v):
                continue
            rows.append(
                {
                    "name": f.name,
                    "value": None,
                    "unit": _unit_of(doc),
                    "what": doc,
                    "pu": None,
                    "values": [_f(x) for x in v],
                }
            )
            continue
        if isinstance(v, bool) or not isinstance(v, int | float):
            rows.append({"name": f.name, "value": None, "unit": "", "what": f"{doc} = {v}", "pu": None})
            continue
        rows.append(
            {
                "name": f.name,
                "value": _f(v),
                "unit": _unit_of(doc),
                "what": doc,
                "pu": _f(v / pu[dim]) if dim in pu else None,
            }
        )
    return rows


TIME_DOMAIN = {  # built-in scenarios re-run with the gains under review, per drive kind
    "ipmsm-adaptive": ("fig9b", "fig10", "fig6b"),
    "pmac-reduced-order": ("fig3", "fig5b"),
}


def time_domain_checks(
    drive: Any, table: Any | None, progress: Progress
) -> tuple[dict[str, Any], dict[str, str]]:
    """Re-run the papers' experiments (built-in scenarios) with the gains under review."""
    from sensorless.design.scenario import load_scenario
    from sensorless.design.simulate import simulate
    from sensorless.reports.sim_figure import plot_traces

    data: dict[str, Any] = {}
    figs: dict[str, str] = {}
    for name in TIME_DOMAIN.get(drive.kind, ()):
        sc = load_scenario(name, drive)
        progress(f"      simulating {name}: {sc.title}")
        tr = simulate(drive, sc, table=table, table_file="gain table")
        m: dict[str, Any] = {"duration_s": _f(tr.t[-1]), "samples": int(tr.t.size)}
        if "theta_err" in tr.data:
            th = np.asarray(tr["theta_err"])
            m["rms_theta_err_deg"] = _f(np.degrees(np.sqrt(np.mean(th**2))))
            m["max_abs_theta_err_deg"] = _f(np.degrees(np.max(np.abs(th))))
        if "w_m" in tr.data and "w_hat" in tr.data:
            e = np.asarray(tr["w_m"]) - np.asarray(tr["w_hat"])
            m["max_abs_speed_err_rad_s"] = _f(np.max(np.abs(e)))
            m["final_speed_err_rad_s"] = _f(np.mean(e[-max(1, e.size // 20) :]))
        cap = (
            f"{sc.title} ({sc.source}), re-run with the gains under review "
            f"({'tuned table' if table is not None else 'paper gains'})."
        )
        data[name] = {"title": sc.title, "caption": cap, "metrics": m}
        figs[f"sim_{name}"] = _svg_data_uri(plot_traces(tr, sc.figure, f"{drive.name}: {sc.title}"))
    return data, figs


def compute_report_data(
    drive: Any,
    table: Any | None = None,
    min_damping: float = 0.2,
    progress: Progress = _stderr_progress,
    resolution: str = "normal",
) -> tuple[dict[str, Any], dict[str, Any]]:
    """All numbers of the report (JSON-ready) and the figures (data URIs) for a paper-000 drive."""
    wb, T_N = drive.base.w, drive.T_N
    fine = resolution == "normal"
    w = np.linspace(-1, 1, 801 if fine else 201) * wb
    w_low = np.linspace(-0.05, 0.05, 401 if fine else 101) * wb
    w_env = 0.05 * wb  # where the tuning envelope starts (issue default)
    choices, review = gain_choices(drive, table)
    data: dict[str, Any] = {
        "inputs": report_inputs(drive, table, min_damping),
        "drive": drive_tables(drive),
        "review": review.label,
    }
    figs: dict[str, Any] = {}
    from sensorless.reports.pole_map import plot_pole_maps

    # 1. pole maps over speed at +-T_N, each gain; then the gain under review with injection
    steps = 5
    progress(f"[1/{steps}] pole maps over speed ({len(choices)} gains x 2 torques, {w.size} speeds)")
    pm: dict[str, Any] = {}
    for T in (T_N, -T_N):
        sweeps, lows = {}, {}
        for c in choices:
            s = linearize(c.drive, w, T, gain=c.gain)
            sweeps[c.label], lows[c.label] = s, linearize(c.drive, w_low, T, gain=c.gain)
            bands = unstable_speed_bands(c.drive, w, T, gain=c.gain, sweep=s)
            pm.setdefault(c.label, {})[f"{T:+g}"] = {
                "T_Nm": _f(T),
                "rhp_bands_pu": [[_f(a / wb), _f(b / wb)] for a, b in bands],
                "worst": _worst_point(s, w_env, wb),
            }
        figs[f"poles_T{T:+g}"] = _svg_data_uri(
            plot_pole_maps(sweeps, wb, f"{drive.name}: closed-loop poles at T_e = {T:g} N m", lows)
        )
    progress(f"[2/{steps}] pole maps with HF injection ({review.label})")
    inj_sweeps, inj_lows = {}, {}
    for T in (T_N, -T_N):
        s = linearize(review.drive, w, T, gain=review.gain, injection=True)
        key = f"T = {T:+g} N m"
        inj_sweeps[key] = s
        inj_lows[key] = linearize(review.drive, w_low, T, gain=review.gain, injection=True)
        bands = unstable_speed_bands(review.drive, w, T, gain=review.gain, injection=True, sweep=s)
        pm.setdefault(f"{review.label} + injection", {})[f"{T:+g}"] = {
            "T_Nm": _f(T),
            "rhp_bands_pu": [[_f(a / wb), _f(b / wb)] for a, b in bands],
            "worst": _worst_point(s, w_env, wb),
        }
    figs["poles_injection"] = _svg_data_uri(
        plot_pole_maps(
            inj_sweeps, wb, f"{drive.name}: {review.label} with HF injection (averaged (19)-(22))", inj_lows
        )
    )
    data["pole_maps"] = pm

    # 3. worst damping / decay rate over speed x torque: paper default vs tuned
    progress(f"[3/{steps}] damping and decay-rate maps over speed x torque")
    w_map = np.linspace(-1, 1, 161 if fine else 41) * wb
    T_map = np.linspace(-1.5, 1.5, 31 if fine else 7) * T_N
    paper_default = next(c for c in choices if c.gain == drive.observer.gain)
    plane_choices = [paper_default] + ([review] if review is not paper_default else [])
    maps: dict[str, Any] = {}
    for c in plane_choices:
        s = linearize(c.drive, w_map[:, None], T_map[None, :], gain=c.gain)
        Z = s.worst_damping.reshape(w_map.size, T_map.size)
        D = s.decay_rate.reshape(w_map.size, T_map.size)
        maps[c.label] = {
            "damping": _arr(Z),
            "decay_rate": _arr(D),
            "worst": _worst_point(s, w_env, wb),
            "unstable_points": int(np.sum(s.max_real > 0)),
        }
    data["plane"] = {"w_pu": _arr(w_map / wb), "T_Nm": _arr(T_map), "maps": maps}
    figs["plane"] = _svg_data_uri(_plane_figure(maps, w_map / wb, T_map, T_N))

    # 4. robustness under estimation errors (gain under review, nominal motoring torque)
    progress(f"[4/{steps}] robustness maps under parameter-estimate errors")
    errs = {"R_s": 50.0, "L_d": 20.0, "L_q": 20.0, "psi_pm": 20.0}
    idx = {"R_s": 0, "L_d": 1, "L_q": 2, "psi_pm": 3}
    w_rob = np.linspace(-1, 1, 121 if fine else 31) * wb
    rob: dict[str, Any] = {"T_Nm": _f(T_N), "w_pu": _arr(w_rob / wb), "params": {}}
    true = np.array(drive.motor.vector())
    for name, span in errs.items():
        e = np.linspace(-span, span, 21 if fine else 5)
        est = np.broadcast_to(true, (e.size, 1, 4)).copy()
        est[:, 0, idx[name]] *= 1 + e / 100
        s = linearize(review.drive, w_rob[None, :], T_N, gain=review.gain, estimate=est)
        Z = s.worst_damping.reshape(e.size, w_rob.size)
        ok = np.isfinite(Z) & (Z > 0)
        rob["params"][name] = {
            "error_pct": _arr(e),
            "damping": _arr(Z),
            "stable_fraction": _f(ok.mean()),
            "no_equilibrium_fraction": _f(np.isnan(Z).mean()),
        }
    data["robustness"] = rob
    figs["robustness"] = _svg_data_uri(_robustness_figure(rob, w_rob / wb, review.label))

    progress(f"[5/{steps}] time-domain checks (paper experiments re-run)")
    td, td_figs = time_domain_checks(drive, table, progress)
    data["time_domain"] = td
    figs.update(td_figs)
    data["verdict"] = verdict(data, review.label, min_damping)
    return data, figs


def report_inputs(drive: Any, table: Any | None, min_damping: float) -> dict[str, Any]:
    """What a report describes: the drive, the hashes of its inputs, the required damping."""
    return {
        "drive": drive.name,
        "drive_sha256": drive.digest,
        "gains_sha256": table_digest(table),
        "min_damping": min_damping,
    }


def table_digest(table: Any | None) -> str | None:
    """sha256 of a gain table's canonical JSON, or None."""
    return None if table is None else hashlib.sha256(table.to_json().encode()).hexdigest()


def verdict(data: dict[str, Any], label: str, min_damping: float) -> dict[str, Any]:
    """Where the reviewed gains are stable with the required damping, where not, and why."""
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
                    "speed_pu_min": _f(wsel.min()),
                    "speed_pu_max": _f(wsel.max()),
                    "points": int(sel.sum()),
                }
            )
    pm = data["pole_maps"]
    inj = pm.get(f"{label} + injection", {})
    rhp = {k: v["rhp_bands_pu"] for k, v in pm[label].items()}
    rhp_inj = {k: v["rhp_bands_pu"] for k, v in inj.items()}
    reasons = []
    if any(rhp.values()):
        edge = max(abs(b) for bands in rhp.values() for band in bands for b in band)
        if not any(rhp_inj.values()):
            reasons.append(
                f"RHP real pole below {edge:.3g} p.u. in motoring (rotor saliency, Section IV-B): "
                "needs HF injection there; with the injection the linearized loop is stable."
            )
        else:
            reasons.append(f"RHP pole below {edge:.3g} p.u. remains even with the injection.")
    ok = np.isfinite(Z) & (Z >= min_damping)
    envelope = {"fraction_ok": _f(ok.mean()), "abs_speed_pu_from": None}
    # smallest |w| above which every torque row is fine
    absw = np.abs(w_pu)
    for thr in np.unique(absw):
        if ok[absw >= thr].all():
            envelope["abs_speed_pu_from"] = _f(thr)
            break
    return {
        "gains": label,
        "min_damping": min_damping,
        "envelope": envelope,
        "findings": findings,
        "reasons": reasons,
        "rhp_bands_pu": rhp,
        "rhp_bands_pu_injection": rhp_inj,
    }


# --------------------------------------------------------------------------------------------------
# HTML
# --------------------------------------------------------------------------------------------------
CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1180px;margin:2em auto;
color:#1a1a1a;line-height:1.45;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:.6em 0 1.2em 0;font-size:.9em}
td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left}th{background:#f3f3f3}
td.num{text-align:right;font-variant-numeric:tabular-nums}
figure{margin:1em 0;border:1px solid #e3e3e3;padding:.6em}figure img{max-width:100%;height:auto}
figcaption{font-size:.9em;color:#444;margin-top:.4em}
.meta{color:#555;font-size:.9em}.verdict{border:3px solid #444;padding:.8em 1.2em;border-radius:6px;
background:#fafafa}.ok{color:#176c2c}.bad{color:#a21d1d}.tables{display:flex;flex-wrap:wrap;gap:1.2em}
"""


def _e(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _num(v: Any, digits: int = 4) -> str:
    return "–" if v is None else f"{v:.{digits}g}"


def render_html(data: dict[str, Any], figs: dict[str, str], version: str, date: str) -> str:
    """The report page (well-formed XHTML-compatible HTML5, no external resources)."""
    p = _head(data, version, date)
    p.append(_verdict_html(data["verdict"]))

    _drive_section(p, data)
    p.append("<h2>2. Pole maps over speed</h2>")
    p.append(
        "<table><tr><th>gains</th><th>torque (N m)</th><th>RHP speed bands (p.u.)</th>"
        "<th>worst damping, |ω| ≥ 0.05 p.u.</th><th>at (p.u., N m)</th></tr>"
    )
    for label, per_T in data["pole_maps"].items():
        for v in per_T.values():
            bands = ", ".join(f"{a:+.4f} … {b:+.4f}" for a, b in v["rhp_bands_pu"]) or "none"
            wk = v["worst"]
            p.append(
                f'<tr><td>{_e(label)}</td><td class="num">{_num(v["T_Nm"])}</td><td>{_e(bands)}</td>'
                f'<td class="num">{_num(wk["damping"], 3)}</td>'
                f'<td class="num">{_num(wk["w_pu"], 3)}, {_num(wk["T_Nm"], 3)}</td></tr>'
            )
    p.append("</table>")
    for key in sorted(k for k in figs if k.startswith("poles_T")):
        T = key[len("poles_T") :]
        p.append(
            _figure(
                figs[key],
                f"Closed-loop poles of G_c(s), eq. (15), at T_e = {T} N m while the speed "
                "sweeps -1…1 p.u. (left, Fig. 4 style; upper half-plane), and magnified near the "
                "origin with a dense low-speed sweep (right, Fig. 5 style). Crosses: "
                "right-half-plane poles; the RHP is shaded.",
            )
        )
    p.append(
        _figure(
            figs["poles_injection"],
            "The gains under review with the averaged HF injection "
            "(19)-(22), at ±T_N: the low-speed RHP pole is removed while the injection is active "
            "(|ω| < ω_Δ).",
        )
    )

    p.append("<h2>3. Damping and decay rate over speed × torque</h2>")
    p.append(
        _figure(
            figs["plane"],
            "Worst damping ratio (top) and decay rate (bottom) of the linearized "
            "closed loop over the speed × torque plane; hatched with a black outline: unstable; "
            "star: least-damped point with |ω| ≥ 0.05 p.u.",
        )
    )
    p.append(
        "<table><tr><th>gains</th><th>worst damping</th><th>at ω (p.u.)</th><th>at T_e (N m)</th>"
        "<th>decay rate there (1/s)</th><th>unstable grid points</th></tr>"
    )
    for label, m in data["plane"]["maps"].items():
        wk = m["worst"]
        p.append(
            f'<tr><td>{_e(label)}</td><td class="num">{_num(wk["damping"], 3)}</td>'
            f'<td class="num">{_num(wk["w_pu"], 3)}</td><td class="num">{_num(wk["T_Nm"], 3)}</td>'
            f'<td class="num">{_num(wk["decay_rate"], 3)}</td>'
            f'<td class="num">{m["unstable_points"]}</td></tr>'
        )
    p.append("</table>")

    p.append("<h2>4. Robustness to parameter-estimate errors</h2>")
    rob = data["robustness"]
    p.append(
        _figure(
            figs["robustness"],
            f"Worst damping of the gains under review at T_e = "
            f"{_num(rob['T_Nm'])} N m when one estimate (R̂s, L̂d, L̂q, ψ̂pm) is off by the given "
            "percentage; the equilibrium is followed from the exact estimates by continuation. "
            "Black outline: unstable; grey: no equilibrium (the observer cannot hold the rotor).",
        )
    )
    p.append(
        "<table><tr><th>estimate</th><th>error range (%)</th><th>stable fraction</th>"
        "<th>no-equilibrium fraction</th></tr>"
    )
    for name, v in rob["params"].items():
        p.append(
            f'<tr><td>{_e(name)}</td><td class="num">±{_num(max(v["error_pct"]), 3)}</td>'
            f'<td class="num">{_num(v["stable_fraction"], 3)}</td>'
            f'<td class="num">{_num(v["no_equilibrium_fraction"], 3)}</td></tr>'
        )
    p.append("</table>")

    _time_domain_section(p, data, figs, 5)
    p.append("</body></html>")
    return "\n".join(p) + "\n"


def _head(data: dict[str, Any], version: str, date: str) -> list[str]:
    inp = data["inputs"]
    p = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8"/>',
        f"<title>sensorless stability report: {_e(inp['drive'])}</title>",
        f"<style>{CSS}</style></head><body>",
        f"<h1>Stability report: {_e(inp['drive'])}</h1>",
    ]
    p.append(
        f'<p class="meta">sensorless {_e(version)} &#183; generated {_e(date)} &#183; drive TOML sha256 '
        f"<code>{_e(inp['drive_sha256'][:16])}…</code> &#183; gains "
        + (f"<code>{_e(inp['gains_sha256'][:16])}…</code>" if inp["gains_sha256"] else "paper defaults")
        + f" &#183; gains under review: <b>{_e(data['review'])}</b></p>"
    )
    return p


def _drive_section(p: list[str], data: dict[str, Any]) -> None:
    p.append("<h2>1. Drive and observer data</h2>")
    p.append('<div class="tables">')
    for section, rows in data["drive"].items():
        p.append(
            f"<table><caption>[{_e(section)}]</caption><tr><th>name</th><th>value</th><th>unit</th>"
            "<th>p.u.</th><th>meaning</th></tr>"
        )
        for r in rows:
            p.append(
                f'<tr><td><code>{_e(r["name"])}</code></td><td class="num">{_cell(r)}</td>'
                f'<td>{_e(r["unit"])}</td><td class="num">{_num(r["pu"], 4)}</td>'
                f"<td>{_e(r['what'])}</td></tr>"
            )
        p.append("</table>")
    p.append("</div>")
    bases = "base" in data["drive"]
    p.append(
        '<p class="meta">SI units; speeds are electrical rad/s unless marked r/min (mechanical). '
        + (
            "Per-unit bases: speed = [base] w, voltage = [base] u, current = [base] i, impedance = u/i, "
            "flux = u/w.</p>"
            if bases
            else "This drive description defines no per-unit bases.</p>"
        )
    )


def _cell(r: dict[str, Any]) -> str:
    if "values" in r:
        return ", ".join(_num(v, 6) for v in r["values"])
    return _num(r["value"], 6)


def _time_domain_section(p: list[str], data: dict[str, Any], figs: dict[str, str], number: int) -> None:
    p.append(f"<h2>{number}. Time-domain checks</h2>")
    td = data.get("time_domain")
    if not td:
        p.append("<p>No time-domain simulation results are included in this report.</p>")
        return
    p.append(
        "<table><tr><th>scenario</th><th>simulated (s)</th><th>RMS position error (deg)</th>"
        "<th>max |position error| (deg)</th><th>max |speed error| (rad/s)</th>"
        "<th>final speed error (rad/s)</th></tr>"
    )
    for key, item in td.items():
        m = item["metrics"]
        p.append(
            f'<tr><td>{_e(key)}: {_e(item["title"])}</td><td class="num">{_num(m["duration_s"])}</td>'
            f'<td class="num">{_num(m.get("rms_theta_err_deg"))}</td>'
            f'<td class="num">{_num(m.get("max_abs_theta_err_deg"))}</td>'
            f'<td class="num">{_num(m.get("max_abs_speed_err_rad_s"))}</td>'
            f'<td class="num">{_num(m.get("final_speed_err_rad_s"))}</td></tr>'
        )
    p.append("</table>")
    for key, item in td.items():
        p.append(_figure(figs[f"sim_{key}"], item["caption"]))


def _figure(uri: str, caption: str) -> str:
    return (
        f'<figure><img src="{uri}" alt="{_e(caption[:80])}"/><figcaption>{_e(caption)}</figcaption></figure>'
    )


def _verdict_html(v: dict[str, Any]) -> str:
    env = v["envelope"]
    out = ['<div class="verdict"><h2 style="margin-top:0">Verdict</h2>']
    frm = env["abs_speed_pu_from"]
    if frm is not None:
        out.append(
            f'<p class="ok">Gains <b>{_e(v["gains"])}</b>: stable with damping ≥ {v["min_damping"]:g} '
            f"for |ω| ≥ {frm:.3g} p.u. at all analysed torques (±1.5 T_N); "
            f"{100 * env['fraction_ok']:.1f} % of the speed × torque grid meets it.</p>"
        )
    else:
        out.append(
            f'<p class="bad">Gains <b>{_e(v["gains"])}</b>: the required damping {v["min_damping"]:g} '
            "is not met at high speed for some torque.</p>"
        )
    if v["findings"]:
        out.append("<ul>")
        for f in v["findings"]:
            out.append(
                f'<li class="bad">{_e(f["issue"])} in {_e(f["mode"])} for '
                f"{f['speed_pu_min']:.3g} ≤ |ω| ≤ {f['speed_pu_max']:.3g} p.u. "
                f"({f['points']} grid points)</li>"
            )
        out.append("</ul>")
    for r in v["reasons"]:
        out.append(f"<p>{_e(r)}</p>")
    out.append("</div>")
    return "".join(out)


def report_json(data: dict[str, Any], version: str) -> str:
    """Deterministic JSON text of the report data."""
    doc = {"format": "sensorless-report/1", "toolbox": {"name": "sensorless", "version": version}, **data}
    return json.dumps(doc, indent=1, sort_keys=True, allow_nan=False) + "\n"


def today() -> str:
    """UTC date for the report header."""
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d")


# --------------------------------------------------------------------------------------------------
# Paper 002 (reduced-order EMF + load-torque observer): g, Gamma over speed x load
# --------------------------------------------------------------------------------------------------
def _pole_list(p: np.ndarray) -> list[list[Any]]:
    return [[_f(z.real), _f(z.imag)] for z in p]


def compute_report_data_pmac(
    drive: Any,
    table: Any | None = None,
    min_damping: float = 0.2,
    progress: Progress = _stderr_progress,
    resolution: str = "normal",
) -> tuple[dict[str, Any], dict[str, Any]]:
    """All numbers and figures of the report for a paper-002 drive (kind pmac-reduced-order)."""
    from sensorless.design.linearize_pmac import analyze
    from sensorless.reports.pmac_report import plot_poles

    env = drive.envelope
    rpm = np.array(env.speeds, float)
    loads = np.array(env.loads, float)
    w = drive.rpm_to_w(rpm)
    choices: list[tuple[str, float | None, float | None]] = [("paper gains", None, None)]
    if table is not None:
        if table.family != "deangelo":
            raise ValueError(f"a {table.family} gain table does not apply to a {drive.kind} drive")
        choices.append(("tuned", float(table.gains["g"]), float(table.gains["Gamma"])))
    review = choices[-1][0]
    data: dict[str, Any] = {
        "inputs": report_inputs(drive, table, min_damping),
        "drive": drive_tables(drive),
        "review": review,
        "sampling_period_s": _f(drive.control.T_s),
        "discretization": drive.control.discretization,
    }
    figs: dict[str, str] = {}
    progress(f"[1/3] observer poles over the envelope ({rpm.size} speeds x {loads.size} loads)")
    analysis: dict[str, Any] = {}
    for label, g, Gamma in choices:
        results = {}
        for le in (True, False):
            r = analyze(drive, w[:, None], loads[None, :], load_estimation=le, g=g, Gamma=Gamma)
            key = f"{label}, {'with' if le else 'without'} T_L estimation"
            results[key] = r
            zc, zd = r.damping_c.min(axis=1), r.damping_d.min(axis=1)
            dc, dd = -r.poles_c.real.max(axis=1), -r.poles_d.real.max(axis=1)
            k = int(np.argmin(dd))
            analysis[key] = {
                "g": _f(g if g is not None else drive.observer.g),
                "Gamma": _f(0.0 if not le else (Gamma if Gamma is not None else drive.observer.Gamma)),
                "points": [
                    {
                        "speed_rpm": _f(drive.w_to_rpm(r.w[j])),
                        "T_L_Nm": _f(r.T_L[j]),
                        "poles_c": _pole_list(r.poles_c[j]),
                        "poles_d": _pole_list(r.poles_d[j]),
                        "damping_c": _f(zc[j]),
                        "damping_d": _f(zd[j]),
                        "decay_c": _f(dc[j]),
                        "decay_d": _f(dd[j]),
                        "err_w_rad_s": _f(r.err_w[j]),
                        "err_T_Nm": _f(r.err_T[j]),
                    }
                    for j in range(r.w.size)
                ],
                "worst_discrete": {
                    "speed_rpm": _f(drive.w_to_rpm(r.w[k])),
                    "T_L_Nm": _f(r.T_L[k]),
                    "decay_rate": _f(dd[k]),
                    "damping": _f(zd.min()),
                },
                "max_abs_err_T_Nm": _f(np.max(np.abs(r.err_T))) if le else None,
            }
        figs[f"poles_{label}"] = _svg_data_uri(
            plot_poles(results, drive, f"{drive.name}: observer poles ({label}), continuous o, discrete x")
        )
    data["analysis"] = analysis
    progress("[2/3] time-domain checks (paper experiments re-run)")
    td, td_figs = time_domain_checks(drive, table, progress)
    data["time_domain"] = td
    figs.update(td_figs)
    progress("[3/3] verdict")
    key = f"{review}, with T_L estimation"
    a = analysis[key]
    stable = all(p["decay_d"] is not None and p["decay_d"] > 0 for p in a["points"])
    damped = all(p["damping_d"] is not None and p["damping_d"] >= min_damping for p in a["points"])
    biased = [p for p in a["points"] if p["err_T_Nm"] is not None and abs(p["err_T_Nm"]) > 1.0]
    reasons = []
    if biased:
        worst = max(biased, key=lambda p: abs(p["err_T_Nm"]))
        reasons.append(
            f"steady load-torque estimation bias up to {worst['err_T_Nm']:.3g} N m at "
            f"{worst['speed_rpm']:g} r/min: at this speed the EMF harmonics approach the Nyquist "
            f"frequency of T_s = {drive.control.T_s * 1e6:g} us (docs/paper002.md); sample faster there"
        )
    data["verdict"] = {
        "gains": key,
        "min_damping": min_damping,
        "stable": stable,
        "damped": damped,
        "worst_discrete": a["worst_discrete"],
        "reasons": reasons,
        "biased_points": [[p["speed_rpm"], p["T_L_Nm"]] for p in biased],
    }
    return data, figs


def render_html_pmac(data: dict[str, Any], figs: dict[str, str], version: str, date: str) -> str:
    """The report page of a paper-002 drive."""
    p = _head(data, version, date)
    v = data["verdict"]
    wd = v["worst_discrete"]
    cls = "ok" if v["stable"] and v["damped"] else "bad"
    p.append(
        f'<div class="verdict"><h2 style="margin-top:0">Verdict</h2><p class="{cls}">Gains '
        f"<b>{_e(v['gains'])}</b>: discrete-time observer at T_s = "
        f"{data['sampling_period_s'] * 1e6:g} us ({_e(data['discretization'])}) "
        f"{'stable' if v['stable'] else 'NOT stable'} over the envelope; damping "
        f"{'meets' if v['damped'] else 'does not meet'} {v['min_damping']:g} everywhere. "
        f"Slowest discrete mode: decay {_num(wd['decay_rate'], 4)} 1/s at {_num(wd['speed_rpm'])} r/min, "
        f"{_num(wd['T_L_Nm'])} N m.</p>"
    )
    for r in v["reasons"]:
        p.append(f'<p class="bad">{_e(r)}</p>')
    p.append("</div>")
    _drive_section(p, data)
    p.append("<h2>2. Observer poles over speed × load (g, Gamma)</h2>")
    for key in sorted(k for k in figs if k.startswith("poles_")):
        p.append(
            _figure(
                figs[key],
                "Real parts of the observer error-dynamics poles over speed, continuous "
                "time (o) and the discrete observer at the sampling period, ln(z)/T_s (x), with "
                "and without load-torque estimation; middle and bottom: the discrete observer's "
                "steady speed and load-torque errors. Colours: load torque.",
            )
        )
    p.append(
        "<table><tr><th>variant</th><th>g (1/s)</th><th>Gamma</th><th>slowest discrete decay (1/s)</th>"
        "<th>at (r/min, N m)</th><th>max |steady T_L error| (N m)</th></tr>"
    )
    for key, a in data["analysis"].items():
        wd = a["worst_discrete"]
        p.append(
            f'<tr><td>{_e(key)}</td><td class="num">{_num(a["g"])}</td>'
            f'<td class="num">{_num(a["Gamma"])}</td><td class="num">{_num(wd["decay_rate"])}</td>'
            f'<td class="num">{_num(wd["speed_rpm"])}, {_num(wd["T_L_Nm"])}</td>'
            f'<td class="num">{_num(a["max_abs_err_T_Nm"])}</td></tr>'
        )
    p.append("</table>")
    _time_domain_section(p, data, figs, 3)
    p.append("</body></html>")
    return "\n".join(p) + "\n"
