"""Result of the constant-gain tuner: the terminal summary and its gain table (docs/gain_tables.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from sensorless.design.gain_table import GainTable
from sensorless.tuning.pmac_reduced_order.objective import FEEDFORWARD, GAIN_MARGIN, Figures
from sensorless.tuning.pmac_reduced_order.settings import (
    ConstantGainSettings,
    grid,
    limits_text,
    load_grid,
    speed_grid,
)

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.pmac_reduced_order.schema import PmacDrive


@dataclass(frozen=True)
class ConstantGainResult:
    """What ``sensorless tune`` reports for the constant law."""

    law: str
    g: float
    Gamma: float
    g0: float  # the drive's gains (baseline)
    Gamma0: float
    closed_form: tuple[float, float]
    dense: Figures
    dense_baseline: Figures
    grid: Figures
    evaluations: int
    note: str  # which candidate was kept and why
    settings: ConstantGainSettings
    table: GainTable
    seconds: float

    def summary_lines(self, drive: PmacDrive | None = None) -> list[str]:
        """The terminal summary."""
        s = self.table.summary
        env = self.table.envelope
        z0, d0 = self.dense_baseline.worst()
        z1, d1 = self.dense.worst()
        n0, n1 = self.dense_baseline.worst_noise(), self.dense.worst_noise()
        lines = [
            f"optimized over {env['optimization_points']} points ({self.evaluations} discrete-pole "
            f"evaluations); re-verified on {env['dense_points']} points ({env['dense_factor']}x denser) "
            f"in {self.seconds:.1f} s; discrete poles at T_s = {env['T_s_s'] * 1e6:g} us "
            f"({env['discretization']})",
            f"{'':<26}{'drive gains':>16}{'tuned':>16}",
            f"{'g [1/s]':<26}{self.g0:>16.5g}{self.g:>16.5g}",
            f"{'Gamma [A^2 s^2]':<26}{self.Gamma0:>16.5g}{self.Gamma:>16.5g}",
            f"{'slowest decay [1/s]':<26}{d0:>16.4g}{d1:>16.4g}",
            f"{'worst damping':<26}{z0:>16.4f}{z1:>16.4f}",
            f"  slowest decay at {s['slowest_decay_at']['n_rpm']:+g} r/min, "
            f"{s['slowest_decay_at']['T_L_Nm']:+g} N m "
            f"(drive gains: {s['baseline_slowest_decay_at']['n_rpm']:+g} r/min, "
            f"{s['baseline_slowest_decay_at']['T_L_Nm']:+g} N m)",
            f"{'noise position [deg el.]':<26}{math.degrees(n0[0]):>16.4g}{math.degrees(n1[0]):>16.4g}",
            f"{'noise speed [rad/s el.]':<26}{n0[1]:>16.4g}{n1[1]:>16.4g}",
            f"  (worst RMS over the dense grid for {self.table.summary['noise']['sigma_A']:.4g} A rms "
            "current noise per axis and sample)",
            f"constraints: noise {limits_text(self.settings)}; damping >= {self.settings.min_damping:.3f}; "
            + (
                "the whole sampled drive stable with the load-torque feedforward off and on, also at "
                f"{GAIN_MARGIN:g} x the gains; "
                if self.settings.whole_drive
                else "the observer's poles alone (no whole-drive constraint); "
            )
            + f"search box g in [{self.settings.g_min:g}, {self.settings.g_max:g}] 1/s, Gamma in "
            f"[{self.settings.Gamma_min:g}, {self.settings.Gamma_max:g}] A^2 s^2; sinusoidal closed form "
            f"(at the g the noise limit allows): g = {self.closed_form[0]:.5g}, "
            f"Gamma = {self.closed_form[1]:.5g}",
            f"kept: {self.note}",
        ]
        return lines


def _where(f: Figures, k: int) -> dict[str, float]:
    return {"n_rpm": float(f.n_rpm[k]), "w_rad_s": float(f.w[k]), "T_L_Nm": float(f.T_L[k])}


def _pairs(p: np.ndarray) -> list[list[float]]:
    return [[float(z.real), float(z.imag)] for z in p]


def gain_table(drive: PmacDrive, r: ConstantGainResult) -> GainTable:
    """The gain table of a result: every dense-grid point with the tuned and the drive's gains."""
    st = r.settings
    d, d0 = r.dense, r.dense_baseline
    points = []
    for j in range(d.w.size):
        points.append(
            {
                "n_rpm": float(d.n_rpm[j]),
                "w_rad_s": float(d.w[j]),
                "T_L_Nm": float(d.T_L[j]),
                "g": r.g,
                "Gamma": r.Gamma,
                "poles": _pairs(d.poles[j]),
                "poles_continuous": _pairs(d.poles_c[j]),
                "noise": {"position": float(d.noise[j, 0]), "speed": float(d.noise[j, 1])},
                "damping": float(d.damping[j]),
                "decay_rate": float(d.decay[j]),
                "baseline": {
                    "g": r.g0,
                    "Gamma": r.Gamma0,
                    "poles": _pairs(d0.poles[j]),
                    "damping": float(d0.damping[j]),
                    "decay_rate": float(d0.decay[j]),
                },
            }
        )
    k, k0 = int(np.argmin(d.decay)), int(np.argmin(d0.decay))
    kz, kz0 = int(np.argmin(d.damping)), int(np.argmin(d0.damping))
    nd, _ = grid(st, st.dense_factor)
    n, _ = grid(st)
    summary = {
        "objective": "maximize the slowest decay rate of the discrete-time poles, damping >= min_damping",
        "slowest_decay_rate": float(d.decay[k]),
        "slowest_decay_at": _where(d, k),
        "baseline_slowest_decay_rate": float(d0.decay[k0]),
        "baseline_slowest_decay_at": _where(d0, k0),
        "worst_damping": float(d.damping[kz]),
        "worst_damping_at": _where(d, kz),
        "baseline_worst_damping": float(d0.damping[kz0]),
        "baseline_worst_damping_at": _where(d0, kz0),
        "min_decay_rate": float(d.decay[k]),
        "baseline_min_decay_rate": float(d0.decay[k0]),
        "optimization_grid_slowest_decay_rate": float(np.min(r.grid.decay)),
        "optimization_grid_worst_damping": float(np.min(r.grid.damping)),
        "closed_form": {"g": r.closed_form[0], "Gamma": r.closed_form[1]},
        "noise": {
            "outputs": ["position", "speed"],
            "units": ["rad", "rad/s"],
            "sigma_A": float(drive.control.i_noise),
            "T_s_s": float(drive.control.T_s),
            "convention": "per-axis rms sigma in each sample at T_s, the discrete observer's own map",
            "tuned": [float(v) for v in d.worst_noise()],
            "baseline": [float(v) for v in d0.worst_noise()],
        },
        "evaluations": r.evaluations,
        "selection": r.note,
        "parameters": {"g": r.g, "Gamma": r.Gamma},
        "baseline_parameters": {"g": r.g0, "Gamma": r.Gamma0},
    }
    assert st.max_noise is not None, "resolved settings"  # default_settings resolves it
    envelope = {
        "speeds_rpm": speed_grid(st.speeds_rpm).tolist(),
        "loads_Nm": load_grid(st.loads_Nm).tolist(),
        "optimization_points": int(n.size),
        "dense_factor": st.dense_factor,
        "dense_speeds_rpm": speed_grid(st.speeds_rpm, st.dense_factor).tolist(),
        "dense_loads_Nm": load_grid(st.loads_Nm, st.dense_factor).tolist(),
        "dense_points": int(nd.size),
        "T_s_s": float(drive.control.T_s),
        "discretization": drive.control.discretization,
        "constraints": {
            "min_damping": st.min_damping,
            "max_noise": dict(st.max_noise),
            "whole_drive_stable": (
                {"feedforward": list(FEEDFORWARD), "gain_margin": GAIN_MARGIN} if st.whole_drive else None
            ),
        },
        "bounds": {"g": [st.g_min, st.g_max], "Gamma": [st.Gamma_min, st.Gamma_max]},
    }
    return GainTable(
        law="constant",
        drive={"name": drive.name, "kind": drive.kind, "sha256": drive.digest},
        gains={"g": r.g, "Gamma": r.Gamma},
        envelope=envelope,
        points=points,
        summary=summary,
    )
