"""What the tuner reuses gives the bits it would compute: the global phase's candidate rows in the
tie-break's searches (tuning/search.py ``_poles``), the tuner's poles deciding stability in the noise
figure (design/noise.py ``noise_rms``), a batch's equilibria and its evaluation without the copies
that pad it to a bucket size (tuning/model.py ``evaluate``), and the equilibria kept where they do not
move with the gains (tuning/model.py ``fixed_equilibria``). On the example servo's law (16), its
default envelope."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from sensorless.design.drive import load_drive
from sensorless.design.noise import noise_rms
from sensorless.design.poles import eigvals_batched
from sensorless.tuning import model as tuning_model
from sensorless.tuning import search
from sensorless.tuning.conditions import candidates
from sensorless.tuning.family import tunable_for
from sensorless.tuning.model import _call, evaluate
from sensorless.tuning.result import figures

SERVO = Path(__file__).resolve().parents[2] / "docs" / "examples" / "motors" / "servo400.toml"


@pytest.fixture(scope="module")
def servo():
    drive = load_drive(str(SERVO))
    tunable = tunable_for(drive, "speed-dependent")
    settings = tunable.settings(drive)
    model = tunable.build(drive, settings, None)
    W, T = settings.envelope.grid()
    scale = float(np.abs(figures(model, np.asarray(model.theta0, float), W, T).poles).max())
    cand = candidates(model, settings, W, T, drive.w_base, scale, None)
    return model, settings, cand, scale


def test_kept_candidate_rows_give_the_bits_of_a_fresh_batch(servo, monkeypatch):
    model, _, cand, scale = servo
    starts = np.clip(np.asarray(model.starts(), float), model.lower, model.upper)
    search._ROWS.clear()
    first = search._margins(model, starts, cand, scale, None)  # the global phase's batch: kept
    # the tie-break's pool: most of the same gains in another order, and some new ones
    rng = np.random.default_rng(0)
    new = starts[:5] * np.array([1.01, 0.99])
    pool = np.vstack([starts[rng.permutation(len(starts))[:60]], new])
    points: list[int] = []

    def counted(m, theta, P, noise=False):
        points.append(P.shape[1])
        return evaluate(m, theta, P, noise)

    monkeypatch.setattr(search, "evaluate", counted)
    reused = search._margins(model, pool, cand, scale, None)
    assert sum(points) < len(pool) * len(cand.labels) / 2  # only the new gains were evaluated
    search._ROWS.clear()
    fresh = search._margins(model, pool, cand, scale, None)
    for a, b in zip(reused, fresh, strict=True):
        assert a.tobytes() == b.tobytes()
    again = search._margins(model, starts, cand, scale, None)  # the first batch from the kept rows
    for a, b in zip(first, again, strict=True):
        assert a.tobytes() == b.tobytes()
    search._ROWS.clear()


def test_the_tuners_poles_decide_stability_as_lapack_does(servo):
    model, settings, _, _ = servo
    Wd, Td = settings.envelope.grid(4, 4)
    P = model.make_points(Wd, Td, model.nominal_estimate)
    theta = np.asarray(model.theta0, float)
    x0 = model.equilibrium(theta, P)
    phi = _call(model.local, P.shape[1], [theta, P])[0][:, :, 0].T
    A = _call(model.linearization, P.shape[1], [phi, x0, P])[0]
    B, C, D = _call(model.noise, P.shape[1], [phi, x0, P])
    # some unstable matrices too: the same ones mirrored (every pole's real part negated)
    A2 = np.concatenate([A, -A])
    B2, C2, D2 = (np.concatenate([X, X]) for X in (B, C, D))
    poles = eigvals_batched(A2)
    with_poles = noise_rms(A2, B2, C2, D2, model.noise_sigma, model.T_s, poles=poles)
    without = noise_rms(A2, B2, C2, D2, model.noise_sigma, model.T_s)
    assert np.isinf(without).any() and np.isfinite(without).any()
    assert with_poles.tobytes() == without.tobytes()


@pytest.mark.parametrize("n_points", [17, 111])  # 3 x: 51 padded to 64 (LAPACK -> quartic path), 333
def test_a_batch_gives_the_bits_of_its_padded_batch(servo, n_points):
    model, settings, _, _ = servo
    W, T = settings.envelope.grid(4, 4)
    base = model.make_points(W, T, model.nominal_estimate)[:, :n_points]
    starts = np.clip(np.asarray(model.starts(), float), model.lower, model.upper)[:3]
    P = np.tile(base, (1, 3))  # three candidates on the same points: their equilibria solved once
    theta = np.repeat(starts, n_points, axis=0).T
    tuning_model._FIXED_X0.clear()
    e = evaluate(model, theta, P)
    pad = tuning_model._bucket(P.shape[1]) - P.shape[1]
    assert pad > 0
    Pp = np.concatenate([P, np.repeat(P[:, -1:], pad, axis=1)], axis=1)
    tp = np.concatenate([theta, np.repeat(theta[:, -1:], pad, axis=1)], axis=1)
    tuning_model._FIXED_X0.clear()
    padded = evaluate(model, tp, Pp)  # a bucket size: no copies added
    assert e.poles.tobytes() == padded.poles[: P.shape[1]].tobytes()
    assert e.bounded is not None and padded.bounded is not None
    assert e.bounded.tobytes() == padded.bounded[: P.shape[1]].tobytes()
    assert e.x0.tobytes() == np.asarray(model.equilibrium(theta, P), float).tobytes()


def test_the_fixed_equilibria_are_solved_once_a_point_with_the_bits_of_a_fresh_solve(servo):
    """tuning/model.py ``fixed_equilibria``: the points a model has solved (where the equilibrium does
    not move with the gains) are looked up in any subset, order or repetition (the pointwise bound's
    polls, a batch of candidates on the same points), only the others are solved, and each gets the bits
    the model's own equilibrium gives it in a batch of its own, at other gains."""
    model, settings, _, _ = servo
    solved: list[int] = []

    def counted(theta: np.ndarray, P: np.ndarray) -> np.ndarray:
        solved.append(P.shape[1])
        return model.equilibrium(theta, P)

    own = dataclasses.replace(model, equilibrium=counted)  # a model of its own: a table of its own
    W, T = settings.envelope.grid(4, 4)
    grid = model.make_points(W, T, model.nominal_estimate)
    n = grid.shape[1]
    assert model.fixed_equilibrium is not None and model.fixed_equilibrium(grid).all()
    half = tuning_model.fixed_equilibria(own, grid[:, : n // 2])
    rng = np.random.default_rng(1)
    P = grid[:, np.concatenate([rng.permutation(n), rng.integers(0, n, 2 * n)])]
    mixed = tuning_model.fixed_equilibria(own, P)
    again = tuning_model.fixed_equilibria(own, P[:, ::-1])
    assert solved == [n // 2, n - n // 2]  # each point once: the new ones of the mixed batch, then none
    wrong = np.hstack([grid[:, :3], model.make_points(W[:1], T[:1], 1.1 * model.nominal_estimate)])
    assert tuning_model.fixed_equilibria(own, wrong) is None  # an estimate error: moves with the gains
    theta = np.clip(np.asarray(model.starts(), float), model.lower, model.upper)[0]
    for x, Q in ((half, grid[:, : n // 2]), (mixed, P), (again, P[:, ::-1])):
        fresh = np.asarray(model.equilibrium(np.repeat(theta[:, None], Q.shape[1], axis=1), Q), float)
        assert np.isfinite(x).all() and x.tobytes() == fresh.tobytes()


def test_the_laws_of_a_drive_share_its_closed_loop_compiled_or_not(servo):
    """Every law's model on a drive has the drive's linearization, noise and lag Functions
    (tuning/ipmsm_adaptive/model.py ``_loop_functions``): a later law's evaluations may run on the
    library the first compiled, where a Function of its own would have started on CasADi's VM, so the
    two must give the same bits."""
    from sensorless.design.batch import evaluate_batch

    model, settings, _, _ = servo
    drive = load_drive(str(SERVO))
    tunable = tunable_for(drive, "schedule")
    other = tunable.build(drive, tunable.settings(drive), None)
    assert other.law != model.law
    assert other.linearization is model.linearization and other.noise is model.noise
    W, T = settings.envelope.grid(4, 4)
    P = model.make_points(W, T, model.nominal_estimate)
    theta = np.asarray(model.theta0, float)
    x0 = model.equilibrium(theta, P)
    phi = _call(model.local, P.shape[1], [theta, P])[0][:, :, 0].T
    for fn in (model.linearization, model.noise):
        on_vm = evaluate_batch(fn, P.shape[1], [phi, x0, P], jit=False)
        built = evaluate_batch(fn, P.shape[1], [phi, x0, P], jit=True)
        for a, b in zip(on_vm, built, strict=True):
            assert np.isfinite(a).all() and a.tobytes() == b.tobytes()


def test_a_sweeps_noise_figure_decided_by_its_poles_gives_the_bits_of_lapacks():
    """``PoleSweep.noise_rms`` hands its poles to design/noise.py (the report's noise over the envelope):
    the figure LAPACK's eigenvalues give, bit for bit, over speeds that cross the low-speed unstable
    band (both decisions taken)."""
    from sensorless.design.ipmsm_adaptive.linearize import linearize

    drive = load_drive(str(SERVO))
    w = np.linspace(-0.2, 0.2, 81) * drive.w_base
    T = np.array([-1.0, 0.0, 1.0]) * drive.T_N
    s = linearize(drive, w[:, None], T[None, :], noise=True)
    sigma, T_s = 0.05, float(drive.control.T_s)
    B, C, D = s.noise_input
    without = noise_rms(s.A, B, C, D, sigma, T_s)
    assert np.isinf(without).any() and np.isfinite(without).any()
    assert s.noise_rms(sigma, T_s).tobytes() == without.tobytes()
