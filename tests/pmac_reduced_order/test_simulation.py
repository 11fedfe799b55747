"""Time-domain simulation of the reduced-order-observer drive (De Angelo et al. 2006): Figs. 2-5 claims."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from helpers.simulation import changed
from sensorless.design.drive import load_drive
from sensorless.design.scenario import load_scenario
from sensorless.design.simulate import simulate


@functools.cache
def deangelo2006():
    return load_drive("deangelo2006")


@functools.cache
def run(name: str, **changes):
    d = deangelo2006()
    return simulate(d, changed(load_scenario(name, d), **changes))


def rpm(d):
    return np.pi / 30 * d.motor.p  # electrical rad/s per mechanical r/min


def speed_error(tr, d):
    return (tr["w_m"] - tr["w_hat"]) / rpm(d)  # [r/min]


def test_without_load_estimation_the_error_stays_after_a_load_step_with_it_it_goes():
    """Figs. 2 and 3: the load step shifts the speed estimation error and the EMF error of the observer
    without load-torque estimation for good; with it, both return to their no-load values and T̂_L
    converges to the load (viscosity included).

    Both runs share a small sampling bias (0.06 r/min, second order in w T_s: docs/simulation.md), so
    the claim is checked on the change the load step causes."""
    d = deangelo2006()
    before, after = (0.3, 0.5), (1.5, 2.0)
    shift, emf_ratio = {}, {}
    for name in ("fig2", "fig3"):
        tr = run(name)
        e = speed_error(tr, d)
        shift[name] = e[tr.window(*after)].mean() - e[tr.window(*before)].mean()
        emf_ratio[name] = tr["emf_err"][tr.window(*after)].mean() / tr["emf_err"][tr.window(*before)].mean()
    # measured: fig2 -0.152 r/min and x1.7; fig3 +0.001 r/min and x1.0
    assert abs(shift["fig2"]) > 0.1
    assert abs(shift["fig3"]) < 0.1 * abs(shift["fig2"])
    assert emf_ratio["fig2"] > 1.4 and abs(emf_ratio["fig3"] - 1) < 0.1
    tr = run("fig3")
    m = tr.window(*after)
    assert tr["T_L_hat"][m].mean() == pytest.approx(tr["T_L_total"][m].mean(), abs=0.1)  # 2 % of 5 N m
    assert np.all(run("fig2")["T_L_hat"] == 0)  # no load-torque state: Gamma = 0


def test_viscous_load_is_estimated():
    """Fig. 4: viscosity is part of the unknown load. The paper's B = 0.0015 N m s gives only 0.047 N m
    at 300 r/min, half the sampling bias of T̂_L there (-0.09 N m, second order in w T_s:
    docs/simulation.md). So the run-up of Fig. 4 is made twice, with and without an extra viscous load
    of 0.05 N m s (1.57 N m at 300 r/min): the bias cancels in the difference, which must follow the
    difference of B omega through the run-up (measured: within 0.3 % at 300 r/min)."""
    d = deangelo2006()
    a, b = run("fig4", viscous=0.05), run("fig4")
    d_est = a["T_L_hat"] - b["T_L_hat"]
    d_true = a["T_L_total"] - b["T_L_total"]
    end = a.window(2.5, 3.0)
    assert d_true[end].mean() > 1.5
    assert abs(d_est[end].mean() - d_true[end].mean()) < 0.02  # (the estimate ripples by +-0.03 N m)
    # during the ramp (B omega rising at 1.6 N m/s) the estimate follows with a constant lag: the model
    # (8) takes the load as constant (measured lag 0.16 N m, i.e. 0.1 s)
    lag = [
        d_true[m].mean() - d_est[m].mean() for m in (a.window(t, t + 0.1) for t in (0.7, 0.8, 0.9, 1.0, 1.1))
    ]
    assert all(0 < x < 0.25 for x in lag)
    assert speed_error(a, d)[end].std() < 0.1


def test_feedforward_cuts_the_speed_tracking_error():
    """Fig. 5: sensorless at 300 r/min, 5 N m load step; the load-torque feedforward cuts the tracking
    error (the paper reports almost 75 % in the experiment of Fig. 8; measured here: peak 3.60 ->
    1.87 r/min, integral of |error| 1.58 -> 0.82 r/min s, with the speed-PI bandwidth of the preset)."""
    d = deangelo2006()
    res = {}
    for name in ("fig5a", "fig5b"):
        tr = run(name)
        e = (tr["w_ref"] - tr["w_m"]) / rpm(d)
        m = tr.window(0.5, 3.0)
        res[name] = (np.abs(e[m]).max(), np.abs(e[m]).sum() * tr.meta["T_s"])
        assert tr["T_L_hat"][tr.window(2.5, 3)].mean() == pytest.approx(5.0 + 0.047, abs=0.1)
        assert np.abs(np.degrees(tr["theta_err"][tr.window(1, 3)])).max() < 1  # sensorless throughout
    assert res["fig5b"][0] < 0.7 * res["fig5a"][0]
    assert res["fig5b"][1] < 0.7 * res["fig5a"][1]
