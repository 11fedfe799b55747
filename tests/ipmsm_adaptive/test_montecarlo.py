"""Monte-Carlo of the adaptive-observer drive: the batched linearization of draws against the family's
own linearization, a marginal design's yield against the normal distribution's CDF at a boundary
found by a direct sweep, and a real two-worker local Dask cluster against the synchronous engine."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from sensorless.design import montecarlo as mc
from sensorless.design.drive import load_drive
from sensorless.design.envelope import with_tuning_keys
from sensorless.design.registry import family_of
from sensorless.reports import montecarlo as rmc
from sensorless.reports.engine import SYNCHRONOUS, Engine


@pytest.fixture(scope="module")
def small():
    """The preset with a coarse envelope (6 speeds per direction x 3 torques), its family and gains."""
    d = load_drive("piippo2008")
    env = with_tuning_keys(d.tuning.envelope, speeds=6)
    d = dataclasses.replace(d, tuning=dataclasses.replace(d.tuning, envelope=env))
    fam = family_of(d)
    return d, fam, fam.gains(d)


def test_batched_draws_equal_the_family_linearization(small):
    d, fam, g = small
    params = fam.montecarlo.parameters(d)
    spreads = mc.parse_spreads("R_s=10%,L_d=10%,L_q=10%,psi_pm=3%", "--spread", params, False)
    est = mc.parse_spreads("R_s=10%,L_q=5%u", "--estimate-error", params, True)
    draws = mc.draw(params, 6, 3, spreads, est)
    # speeds off 1 p.u.: the gain law (16) has a kink at |w_hat| = w_lambda = 1 p.u., where the
    # Jacobian depends on the side that rounding puts w_hat on; and inside the envelope (>= 0.05 p.u.):
    # nearer zero speed, where the observer barely sees the rotor, continuation paths that differ in
    # rounding (numpy's solves against the rootfinder's) can end on different equilibria
    mag = np.linspace(0.05, 0.97, 5)
    w = np.concatenate([-mag[::-1], mag]) * d.w_base
    T = np.array([-1.0, 0.3, 1.0]) * d.T_N
    W, TT = (a.ravel() for a in np.meshgrid(w, T))
    lin = fam.montecarlo.linearize_draws(d, g, draws.plant, draws.estimate, W, TT)
    k = len(W)
    compared = 0
    for i in range(6):
        di = fam.montecarlo.perturbed(d, dict(zip(draws.names, draws.plant[i], strict=True)), {})
        ref = fam.linearize(di, g, W, TT, estimate=draws.estimate[i, :4])
        got = lin.poles[i * k : (i + 1) * k]
        assert np.array_equal(np.isnan(got), np.isnan(ref.poles))
        ok = ~np.isnan(ref.poles).any(axis=1)
        # the same poles (a conjugate pair may come in either order): real parts and |imag| sorted
        for part in (np.real, lambda p: np.abs(np.imag(p))):
            np.testing.assert_allclose(
                np.sort(part(got[ok]), axis=1), np.sort(part(ref.poles[ok]), axis=1), rtol=1e-7, atol=1e-6
            )
        wd = lin.worst_damping[i * k : (i + 1) * k]
        np.testing.assert_allclose(wd[ok], ref.worst_damping[ok], rtol=1e-7, atol=1e-9)
        compared += ok.sum()
    assert compared > 25  # most points have an equilibrium: the comparison is not vacuous


def _damping(fam, d, g, w, T, factor):
    est = np.array(d.estimate.vector())
    est[2] *= factor  # L_q estimate
    wd = fam.linearize(d, g, w, T, estimate=est).worst_damping
    return -np.inf if np.isnan(wd).any() else float(wd.min())


def test_marginal_yield_is_the_normal_cdf_beyond_the_direct_boundary(small):
    """Spread only the L_q estimate (normal, 5 %): the worst damping over the envelope falls with the
    estimate (a direct sweep with family.linearize), so the draws that meet the required damping are
    those below the factor r* where it crosses it, and the yield is Phi((r* - 1) / 0.05)."""
    d, fam, g = small
    env = with_tuning_keys(d.tuning.envelope, speeds=3)  # 18 points: the test's time is the draws'
    d = dataclasses.replace(d, tuning=dataclasses.replace(d.tuning, envelope=env))
    w, T = rmc.envelope(d)
    required = 0.375
    grid = np.linspace(0.85, 1.15, 13)
    sweep = [_damping(fam, d, g, w, T, r) for r in grid]
    assert all(a >= b for a, b in itertools.pairwise(sweep)), sweep  # monotone: one boundary
    lo, hi = 0.85, 1.15
    assert _damping(fam, d, g, w, T, lo) > required > _damping(fam, d, g, w, T, hi)
    for _ in range(20):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _damping(fam, d, g, w, T, mid) >= required else (lo, mid)
    r_star = 0.5 * (lo + hi)
    expected = 0.5 * (1 + math.erf((r_star - 1) / 0.05 / math.sqrt(2)))
    assert 0.1 < expected < 0.9  # a marginal design, not a trivially sure one
    params = fam.montecarlo.parameters(d)
    est = mc.parse_spreads("L_q=5%", "--estimate-error", params, True)
    n = 2000
    with Engine(SYNCHRONOUS, quiet=True) as engine:
        res = rmc.run(d, g, params, {}, est, n, 11, 0, required, engine)
    y = res.summary["yield"]["damping"]["value"]
    se = math.sqrt(expected * (1 - expected) / n)
    assert abs(y - expected) < 4 * se, (y, expected, r_star)
    top = res.summary["sensitivity"][0]
    assert top["parameter"] == "estimate L_q" and top["spearman_rho"] < -0.9


def test_two_worker_local_cluster_equals_the_synchronous_engine(small, monkeypatch):
    """Two chunks (the last one short) and a time-domain draw, on two worker processes and in this
    one: the same summary. Chunks of 24 draws, not the product's 250: the draws are made and cut into
    chunks in this process (design/montecarlo.py), so the workers see chunks of any size alike, and
    the test's time is the cluster's start, not 500 linearized draws (twice). The time-domain draw
    runs the drive's two shortest generic scenarios (made here and sent to the workers with the
    draws), not all five (10.8 s of simulated drive per draw)."""
    d, fam, g = small
    monkeypatch.setattr(mc, "CHUNK", 24)
    scenarios = sorted(rmc.time_scenarios(d), key=lambda sc: sc.duration)[:2]
    monkeypatch.setattr(rmc, "time_scenarios", lambda drive: scenarios)
    params = fam.montecarlo.parameters(d)
    spreads = mc.parse_spreads("R_s=10%,L_q=10%,psi_pm=3%,J=30%", "--spread", params, False)
    est = mc.parse_spreads("R_s=10%u", "--estimate-error", params, True)
    n = 2 * mc.CHUNK - 5  # two chunks, the last one short
    args = (d, g, params, spreads, est, n, 5, 1, 0.2)
    with Engine(SYNCHRONOUS, quiet=True) as engine:
        sync = rmc.run(*args, engine)
    with Engine(None, workers=2, quiet=True) as engine:
        assert engine.size == 2
        dist = rmc.run(*args, engine)
    assert sync.draws.chunks == 2 and len(sync.td) == 1
    assert sync.summary == dist.summary  # the yield (key "yield") and everything else
    np.testing.assert_array_equal(sync.worst, dist.worst)
    assert 0 < sync.summary["yield"]["damping"]["value"] < 1


def test_report_section_states_the_yield_of_the_typical_spreads(small):
    from sensorless.reports.document import Section, Table

    d, fam, g = small
    params = fam.montecarlo.parameters(d)
    spreads = rmc.typical_spreads(params)
    assert set(spreads) == {p.name for p in params}  # the family declares a typical spread for each
    with Engine(SYNCHRONOUS, quiet=True) as engine:
        res = rmc.run(d, g, params, spreads, {}, 60, 0, 0, 0.2, engine)
    sec = rmc.report_section(7, res, params, 0.2)
    assert isinstance(sec, Section) and sec.title.startswith("7. Monte-Carlo")
    y = res.summary["yield"]["damping"]["value"]
    assert f"Yield: {y:.4g}" in sec.blocks[0].text
    tables = [b for b in sec.blocks if isinstance(b, Table)]
    assert [r[0] for r in tables[0].rows] == [r["parameter"] for r in res.summary["sensitivity"]]
