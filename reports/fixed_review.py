"""`sensorless report --precision fixed`: the checks judge the fixed-point step; the quantization's effect
on the poles is reported (docs/codegen.md, "Fixed point").

- :func:`judged_with`: within the block, the time-domain checks (reports/time_domain.py) simulate the
  given step (the fixed-point one of ``codegen --precision fixed``, its SX twin) in closed loop; the
  analyses stay on the double step (a fixed-point step's floors have no derivative);
- :func:`add_to_report`: report.json's ``precision`` and ``fixed_point`` (the observer's poles with the
  constants as stored, reports/codegen/fixed_poles.py, and the whole sampled drive's poles re-run with
  the step whose constants are the stored ones, design/drive_analysis.py), and its section.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING

import numpy as np
from sensorless.design.family import Drive, GainSet
from sensorless.design.runtime import StepVariant, step_variant
from sensorless.reports import time_domain
from sensorless.reports.document import Paragraph, Report, Section, Table, num

if TYPE_CHECKING:  # typed by name only
    import casadi as ca
    from sensorless.design.runtime import RuntimeSetup
    from sensorless.reports.codegen.fixed_model import FixedModel


@contextlib.contextmanager
def judged_with(variant: StepVariant) -> Iterator[None]:
    """The time-domain checks within the block run ``variant`` (design/runtime.step_variant's)."""
    token = time_domain.JUDGED_STEP.set(variant)
    try:
        yield
    finally:
        time_domain.JUDGED_STEP.reset(token)


def _drive_poles(drive: Drive, gains: GainSet, model: FixedModel, quick: bool) -> dict[str, float | None]:
    """The whole drive's poles with the double step and with the stored constants' step, compared. Where
    the analysed loop runs an observer the model has no runs of (a family's AnalysedLoop: the drive
    without its EMF harmonics), that loop run on the model's scenarios gives its ranges."""
    from sensorless.reports.codegen.fixed_generate import range_scenarios
    from sensorless.reports.codegen.fixed_model import FixedModel
    from sensorless.reports.codegen.fixed_poles import stored_step
    from sensorless.reports.codegen.fixed_ranges import probe_runs
    from sensorless.reports.drive_analysis import N_SPEEDS, QUICK_SPEEDS, sweep

    n = QUICK_SPEEDS if quick else N_SPEEDS
    lin_d = sweep(drive, gains, n)
    held = model

    def stored(setup: RuntimeSetup, step: ca.Function) -> ca.Function:
        nonlocal held
        if setup.observer.name not in held.runs:
            # the loop the analysis linearizes runs an observer the checks do not (the family's
            # AnalysedLoop: the drive without its EMF harmonics): its ranges from that loop run on
            # the same scenarios
            runs = probe_runs(drive, gains, range_scenarios(drive), analysed=True)
            held = FixedModel({**runs, **held.runs})
        return stored_step(setup, held.program(setup))

    with step_variant(stored):
        lin_q = sweep(drive, gains, n)
    # the slow poles (|s| below a quarter of the sampling limit, the ones the report shows and judges)
    slow_d, slow_q = lin_d.slow(), lin_q.slow()
    shift, rel = 0.0, 0.0
    both = np.isfinite(lin_d.y).all(axis=1) & np.isfinite(lin_q.y).all(axis=1)
    for k in np.flatnonzero(both):
        a, b = slow_d[k][np.isfinite(slow_d[k])], slow_q[k][np.isfinite(slow_q[k])]
        if a.size and b.size:
            d = np.abs(a[:, None] - b[None, :]).min(axis=1)
            shift = max(shift, float(d.max()))
            rel = max(rel, float((d / np.abs(a)).max()))
    wd, wq = lin_d.worst_damping[both], lin_q.worst_damping[both]
    return {
        "points": int(both.sum()),
        "max_pole_shift_per_s": shift,
        "max_relative_pole_shift": rel,
        "worst_damping_double": float(np.min(wd)) if wd.size else None,
        "worst_damping_stored": float(np.min(wq)) if wq.size else None,
    }


def add_to_report(
    rep: Report, drive: Drive, gains: GainSet, setup: RuntimeSetup, model: FixedModel, quick: bool
) -> Report:
    """``rep`` with ``precision`` "fixed" and ``fixed_point`` (module docstring) and a section."""
    from sensorless.reports.codegen.fixed_poles import pole_shift

    obs = pole_shift(setup, model.program(setup), *model.data(setup))
    poles: dict[str, float | None] | None = None
    try:
        poles = _drive_poles(drive, gains, model, quick)
        drv: Mapping[str, float | str | None] = poles
    except ValueError as e:  # no drive loop for this family or drive (said)
        drv = {"not_analysed": str(e)}
    data = {"observer_poles": obs, "drive_poles": drv}
    text = (
        "The time-domain checks above ran the fixed-point step (`sensorless codegen --precision fixed`, "
        "its integer program run in the closed loop); the analyses ran the double step. The constants as "
        "the fixed-point step stores them (Q formats) move the observer's discrete poles and the whole "
        "sampled drive's poles by the amounts below (the analyses re-run with the stored values)."
    )
    rows = [
        ("observer: largest pole shift (z plane)", num(obs["max_pole_shift"], 3)),
        (
            "observer: spectral radius, double / stored",
            f"{obs['spectral_radius_double']:.6f} / {obs['spectral_radius_stored']:.6f}",
        ),
    ]
    if poles is not None:
        rows += [
            ("whole drive: largest shift of a slow pole (1/s)", num(poles["max_pole_shift_per_s"], 3)),
            ("whole drive: largest relative shift of a slow pole", num(poles["max_relative_pole_shift"], 3)),
            (
                "whole drive: worst damping, double / stored",
                f"{num(poles['worst_damping_double'], 4)} / {num(poles['worst_damping_stored'], 4)}",
            ),
        ]
    else:
        rows.append(("whole drive", str(drv["not_analysed"])))
    sec = Section(
        f"{len(rep.sections) + 1}. Fixed point: what was judged, the quantization's effect on the poles",
        (Paragraph(text), Table(("quantity", "value"), tuple(rows))),
    )
    inputs = {**rep.data.get("inputs", {}), "precision": "fixed"}
    return dataclasses.replace(
        rep, data={**rep.data, "inputs": inputs, "fixed_point": data}, sections=(*rep.sections, sec)
    )
