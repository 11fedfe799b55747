"""What a flux-observer tuner returns: the best candidate's gain table, its summary lines and the
firmwares' defaults judged beside it (baselines)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from sensorless.design.family import GainSet
from sensorless.design.gain_table import GainTable
from sensorless.design.poles import worst_damping
from sensorless.tuning.pmsm_flux_observer.assessment import Assessment, assess, figures
from sensorless.tuning.pmsm_flux_observer.settings import FluxTuneSettings, odrive_defaults, vesc_detection

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmsm_flux_observer.schema import FluxObserverDrive


@dataclass
class FluxOutcome:
    law: str
    table: GainTable
    lines: list[str]
    missed: list[str] = field(default_factory=list)  # the family criterion's shortfalls (criterion.py)

    def summary_lines(self, drive: FluxObserverDrive) -> list[str]:
        return self.lines

    def shortfalls(self, drive: FluxObserverDrive) -> list[str]:
        """What the tuned gains miss of the family's own criterion (tuning/pmsm_flux_observer/
        criterion.py), one line each with cause and change: ``tune`` exits 3 where there is any."""
        return self.missed


def baselines(drive: FluxObserverDrive, settings: FluxTuneSettings) -> tuple[list[str], dict[str, Any]]:
    from sensorless.tuning.pmsm_flux_observer.criterion import judged

    cands = [odrive_defaults(), vesc_detection(drive), drive_gains_or_none(drive)]
    a = assess(drive, cands, settings)
    lines, out = [], {}
    for j, (label, g) in enumerate(
        zip(("ODrive defaults", "VESC detection", "drive file"), cands, strict=False)
    ):
        f = figures(drive, a, j)
        jd = judged(drive, a, j, settings)
        met = all(jd["meets"].values()) and jd["low_speed_limit_rad_s"] < top_speed(drive)
        out[label] = {
            **f,
            "gains": dict(g.values),
            "worst_decay_1_s": jd["worst_decay_1_s"],
            "pll_root_1_s": jd["pll_root_1_s"],
            "meets_criterion": met,
        }
        lines.append(summary_line(label, f) + criterion_clause(jd, met))
    return lines, out


def top_speed(drive: FluxObserverDrive) -> float:
    W, _ = drive.envelope.grid()
    return float(np.max(np.abs(W))) * (1 - 1e-9)


def criterion_clause(j: dict[str, Any], met: bool) -> str:
    """The criterion's figures of a judged candidate (criterion.judged), for its summary line."""
    d = j["worst_decay_1_s"]
    dec = f"decay {d:.4g} 1/s" if math.isfinite(d) else "no decay figure"
    return f"; {dec}, PLL root {j['pll_root_1_s']:.4g} 1/s: {'meets' if met else 'misses'} the criterion"


def same_law(drive: FluxObserverDrive, law: str) -> list[GainSet]:
    """The drive file's gains where they are of ``law``."""
    g = drive_gains_or_none(drive)
    return [g] if g is not None and g.law == law else []


def drive_gains_or_none(drive: FluxObserverDrive) -> GainSet:
    from sensorless.design.pmsm_flux_observer.gains import drive_gains

    return drive_gains(drive)


def summary_line(label: str, f: dict[str, float], settings: FluxTuneSettings | None = None) -> str:
    """One summary line; with ``settings``, what "holds" means (the shared minimum-speed line printed
    after it judges other limits: design/low_speed.py)."""
    lim = f["low_speed_limit_pu"]
    if not math.isfinite(lim):
        return f"  {label:<16} loses the motor at every envelope speed (unstable or biased beyond the limit)"
    held = f"holds down to {lim:.3g} p.u."
    if settings is not None:
        held += (
            f" (the lowest envelope speed from which it is stable with an angle bias <= "
            f"{settings.bias_max_deg:g} deg at every error corner)"
        )
    return (
        f"  {label:<16} worst damping {f['worst_damping']:.3f}, worst angle bias "
        f"{f['worst_bias_deg']:.2f} deg{noise_clause(f)}; {held}"
    )


def noise_clause(f: dict[str, float]) -> str:
    n = f.get("worst_noise_deg", float("nan"))
    return f", angle noise {n:.3g} deg rms" if math.isfinite(n) else ""


def gain_table(
    drive: FluxObserverDrive, law: str, gains: dict[str, Any], a: Assessment, c: int, summary: dict[str, Any]
) -> GainTable:
    W, T = drive.envelope.grid()
    base = assess(drive, [drive_gains_or_none(drive)], FluxTuneSettings())
    points = []
    for j in range(W.size):
        points.append(
            {
                "w_m_pu": float(W[j] / drive.w_base),
                "T_e_Nm": float(T[j]),
                "damping": float(worst_damping(a.poles[c, j : j + 1])[0]),
                "decay_rate": float(-np.max(a.poles[c, j].real)),
                "poles": [[float(p.real), float(p.imag)] for p in a.poles[c, j]],
                "baseline": {
                    "damping": float(worst_damping(base.poles[0, j : j + 1])[0]),
                    "decay_rate": float(-np.max(base.poles[0, j].real)),
                },
            }
        )
    env = {"speed_base_rad_s": drive.w_base, "T_s_s": drive.observer.T_obs}
    head = {"name": drive.name, "kind": drive.kind, "sha256": drive.digest}
    return GainTable(law, head, gains, env, points, summary)


def summary_limits(settings: FluxTuneSettings, pf: dict[str, Any] | None) -> dict[str, Any]:
    """The summary's noise limit and front, where the run has them (preset tables stay as they were)."""
    out: dict[str, Any] = {}
    if settings.max_noise:
        out["max_noise"] = dict(settings.max_noise)
    if pf is not None:
        out["pareto"] = pf
    return out


def outcome(
    drive: FluxObserverDrive,
    law: str,
    header: Any,
    cands: list[Any],
    a: Any,
    baselines: tuple[Any, list[str]],
    settings: FluxTuneSettings,
    pf: Any,
) -> FluxOutcome:
    """The best candidate by the family's criterion (criterion.py), its table and summary: ``header``
    (gains) -> the summary's first line, in the law's own terms; ``baselines`` the firmware defaults
    and their lines."""
    from sensorless.tuning.pmsm_flux_observer.criterion import best, judged, shortfalls

    base, base_lines = baselines
    c = best(drive, a, settings)
    g = dict(cands[c].values)
    j = judged(drive, a, c, settings)
    f = figures(drive, a, c)
    w_hold = j["hold_from_rad_s"]
    need = j["requirements"]
    lines = [
        header(g),
        summary_line("tuned", f, settings),
        f"  observer decay >= {j['worst_decay_1_s']:.4g} 1/s (required {need['decay']:.4g}: the larger of "
        f"{settings.decay_share:g} x alpha_s and sqrt(a_max / 30 deg)), PLL root {j['pll_root_1_s']:.4g} "
        f"1/s (required {need['pll']:.4g}); the criterion: hold as low as possible, then the fastest decay",
        "baselines (the firmwares' defaults on this motor, same criterion):",
        *base_lines,
    ]
    summary = {
        **f,
        "worst_decay_1_s": j["worst_decay_1_s"],
        "pll_root_1_s": j["pll_root_1_s"],
        "required": need,
        "hold_speed_rad_s": w_hold,
        "baselines": base,
        "errors": settings.errors,
        "bias_max_deg": settings.bias_max_deg,
        **summary_limits(settings, pf),
    }
    missed = shortfalls(drive, cands[c], j, settings)
    return FluxOutcome(law, gain_table(drive, law, g, a, c, summary), lines, missed)
