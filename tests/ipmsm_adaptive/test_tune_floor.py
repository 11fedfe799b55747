"""One rule for "meets the decay floor" in every step of the shared tuner (tuning/candidates.py).

The global phase counted a margin down to FEASIBILITY_TOL x the pole scale as met, the selection only
1e-6 of the floor: on the traction example (docs/examples/motors/prius.toml, derived [tuning] to
+-T_max) the schedule's best start (dense worst damping 0.4519, slowest decay 2.0885 1/s against the
seed's floor 2.0889 1/s, pole scale 8821 1/s) passed the one and was refused by the other, for the
seed's 0.0998. Here: the rule against that hand case, and the global phase's verdict against the
selection's on the same gains and points, just inside and just outside the tolerance.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from helpers.tuning import paper_law
from sensorless.design.drive import load_drive
from sensorless.design.envelope import tuning_envelope
from sensorless.tuning import search
from sensorless.tuning.candidates import FEASIBILITY_TOL, meets_floor
from sensorless.tuning.conditions import candidates
from sensorless.tuning.family import tunable_for
from sensorless.tuning.result import figures
from sensorless.tuning.selection import select

PRIUS = Path(__file__).resolve().parents[2] / "docs" / "examples" / "motors" / "prius.toml"


def test_the_floor_rule_on_the_measured_prius_case():
    scale = 8820.9  # the prius drive file's pole scale [1/s]: tolerance 8.8e-4 1/s
    assert meets_floor(2.0885, 2.0889, scale)  # 4e-4 1/s slower: within the NLP's tolerance
    assert not meets_floor(2.0263, 2.0889, scale)  # 3 % slower (the NLP's solution between its points)
    assert not meets_floor(2.0889 - 2 * FEASIBILITY_TOL * scale, 2.0889, scale)
    # no floor: stable is what is required, and NaN (no equilibrium) is never met
    assert meets_floor(1e-9, 0.0, scale) and not meets_floor(0.0, 0.0, scale)
    assert not meets_floor(float("nan"), 0.0, scale)
    # a floor below the tolerance still requires stability
    assert not meets_floor(-1e-6, 1e-5, scale)


@pytest.mark.parametrize("below", [0.5, 2.0])
def test_global_phase_and_selection_judge_the_floor_alike(below):
    """Gains whose slowest decay on a grid is ``below`` x the tolerance under the floor: the global
    phase (search.rank) and the selection (selection.select) give the same verdict on the same points,
    met at 0.5, not met at 2 (before, the selection refused at 0.5 what the global phase accepted)."""
    d = load_drive(PRIUS)
    env = tuning_envelope(
        d.w_base,
        d.T_N,
        speed_min=0.2,
        speed_max=1.0,
        speeds=4,
        torques_TN=(-1.5, 0.0, 1.5),
    )
    st = dataclasses.replace(d.tuning, envelope=env, law=paper_law(d.tuning))
    model = tunable_for(d, "speed-dependent").build(d, st, None)
    W, T = env.grid()
    theta = np.array([10 * d.estimate.R_s, 0.5 * d.w_base])  # stable on this envelope
    f = figures(model, theta, W, T)
    assert np.isfinite(f.damping).all() and f.decay.min() > 0
    scale = float(np.abs(f.poles).max())
    floor = float(f.decay.min()) + below * FEASIBILITY_TOL * scale
    cand = candidates(model, dataclasses.replace(st, min_decay=floor), W, T, d.w_base, scale, None)
    ranked = search.rank(model, theta[None], cand, scale)
    _, _, note, _ = select(
        model, [], [("drive file's gains", theta)], W, T, floor, None, lambda s: None, scale
    )
    assert bool(ranked.feasible[0]) == bool(note["admissible"]) == (below < 1)
