"""The default tuning keeps the decay the I-f handover's w_min asks (tuning/tune.py, design/low_speed.py).

On the gimbal example (docs/examples/motors/gimbal.toml) the speed-dependent law tuned without a decay
floor decays at about 1.4 1/s at 0.05 p.u., under the tenth of the speed-loop bandwidth (11.94 1/s)
that the low-speed criteria ask: its w_min, and so the handover, rose to 0.69 p.u., above the start's
and reversal's 0.5 p.u. Here: the tuned gains' decay, from their poles on the family's analysis path,
at every speed of the envelope (the low ones included) against that share of the file's bandwidth.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from helpers.tuning import paper_law
from sensorless.design.drive import load_drive
from sensorless.design.envelope import tuning_envelope
from sensorless.design.ipmsm_adaptive.linearize import linearize
from sensorless.symbolic.ipmsm_adaptive.gains import schedule_law
from sensorless.tuning.tune import tune

GIMBAL = Path(__file__).resolve().parents[2] / "docs" / "examples" / "motors" / "gimbal.toml"


def test_tuned_gains_decay_as_the_handover_asks():
    d = load_drive(GIMBAL)
    env = tuning_envelope(d.w_base, d.T_N, speed_min=0.05, speed_max=1.0, speeds=4, torques_TN=(-1.0, 1.0))
    # the law's two parameters (alpha_fo fixed: the poles below take lambda', omega_lambda); without the
    # pointwise bound, which this law's tuning computes after its gains are chosen (the same gains, a
    # third of the CPU; test_tune_global.py checks the bound)
    st = dataclasses.replace(d.tuning, envelope=env, law=paper_law(d.tuning), bound=False)
    assert st.min_decay == 0  # the file asks for no floor: the handover's is the tuner's own
    r = tune(d, "speed-dependent", st)
    need = 0.1 * d.control.alpha_s  # a tenth of the speed-loop bandwidth [rad/s] (design/low_speed.py)
    Wd, Td = env.grid(env.dense_factor, env.dense_factor)
    decay = -linearize(d, Wd, Td, gain=("speed", r.theta)).max_real  # from the poles, independently
    assert np.min(decay) >= need * (1 - 1e-6), (np.min(decay), need)
    low = np.abs(Wd) <= 0.2 * d.w_base  # the low-speed points, where the handover is placed
    assert low.any() and np.min(decay[low]) >= need * (1 - 1e-6)
    assert r.floor == need


def test_explicit_floor_the_seed_cannot_meet():
    """``--min-decay 12`` on the gimbal: the seed law (speed-dependent, lag held, alpha_fo tuned) has no
    gain meeting 12 1/s at 0.05 p.u. (it used to end the tuning, exit 2); the schedule it seeds does.
    The tuned schedule's decay, from its poles on the analysis path with its own alpha_fo, meets it."""
    d = load_drive(GIMBAL)
    env = tuning_envelope(d.w_base, d.T_N, speed_min=0.05, speed_max=1.0, speeds=4, torques_TN=(-1.0, 1.0))
    st = dataclasses.replace(d.tuning, envelope=env, min_decay=12.0)
    r = tune(d, "schedule", st)
    g = r.table.gains
    tuned = dataclasses.replace(d, observer=dataclasses.replace(d.observer, alpha_fo=float(g["alpha_fo"])))
    Wd, Td = env.grid(env.dense_factor, env.dense_factor)
    law = schedule_law(tuple(g["w_hat"]))
    s = linearize(tuned, Wd, Td, gain=(law, np.concatenate([g["lambda1"], g["lambda2"]])))
    assert np.min(-s.max_real) >= 12.0 * (1 - 1e-6), np.min(-s.max_real)
    assert r.floor >= 12.0
