"""The tuner's tie-break (tuning/tiebreak.py): of the speed-dependent gains as well damped as the best (within
the tie tolerance), the smallest. On a 5.5 kW industrial IPMSM the worst damping saturates in lambda' and
does not move with omega_lambda below about 0.24 p.u.: damping alone put lambda' on its cap and
omega_lambda at the bottom of the global grid (a steep ramp that lost the rotor position in a
speed-step run). Checked against an independent brute force over (lambda', omega_lambda) through the
analysis path, with the gain size typed here from eq. (16) of Piippo, Hinkkanen, Luomi (2008)."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from helpers.tuning import paper_law
from sensorless.design.drive import load_drive
from sensorless.design.envelope import tuning_envelope
from sensorless.design.ipmsm_adaptive.linearize import drive_arguments, linearize
from sensorless.design.ipmsm_adaptive.operating_point import loop_parameters, rotor_frame_loop
from sensorless.design.poles import max_real, worst_damping
from sensorless.design.rotor_frame import equilibrium_points
from sensorless.tuning.tiebreak import TIE_TOL
from sensorless.tuning.tune import tune

IND5K5 = Path(__file__).parent / "drives" / "ind5k5_minimal.toml"


def speed_dependent_size(lp, wl, R, wb, w_max):
    """RMS over w_hat in [-w_max, w_max] of sqrt(lambda1^2 + lambda2^2 + wb^2 (lambda1'^2 + lambda2'^2))/R
    for eq. (16): lambda1 = lp min(|w|/wl, 1), lambda2 = lp sat(w/wl), so |lambda|^2 = 2 lp^2 min(|w|/wl,
    1)^2 and the slope^2 = 2 (lp/wl)^2 below wl, 0 above (the integrals in closed form)."""
    x = min(wl, w_max)
    mag2 = 2 * lp**2 * (x**3 / (3 * wl**2) + (w_max - x)) / w_max
    slope2 = 2 * (lp * wb / wl) ** 2 * x / w_max
    return np.sqrt(mag2 + slope2) / R


@pytest.fixture(scope="module")
def case():
    drive = load_drive(str(IND5K5))
    env = tuning_envelope(
        drive.w_base,
        drive.T_N,
        speed_min=0.05,
        speed_max=1.0,
        speeds=4,
        torques_TN=(-1.0, 1.0),
    )
    st = dataclasses.replace(drive.tuning, envelope=env, bound=False, law=paper_law(drive.tuning))
    r = tune(drive, "speed-dependent", st)
    R, wb = drive.estimate.R_s, drive.base.w
    Wd, Td = env.grid(env.dense_factor, env.dense_factor)
    # the brute force: worst damping and slowest decay on the dense grid, through the analysis path
    lps = np.geomspace(0.25, 20.0, 25) * R  # the box's cap is 20 R_s_hat
    wls = np.geomspace(0.01, 10.0, 25) * wb
    D, C = brute_force(drive, Wd, Td, lps, wls)
    # the batch is linearize's own path: the same figures as linearize, pair by pair (three pairs)
    for i, j in ((0, 0), (12, 7), (24, 24)):
        s = linearize(drive, Wd, Td, gain=("speed", [lps[i], wls[j]]))
        assert D[i, j] == pytest.approx(np.min(s.worst_damping), abs=1e-9)
        assert C[i, j] == pytest.approx(np.min(s.decay_rate), rel=1e-9)
    return drive, r, (Wd, Td), (lps, wls, D, C)


def brute_force(drive, Wd, Td, lps, wls):
    """Worst damping and slowest decay over the points (Wd, Td) for every pair (lps[i], wls[j]) of eq. (16):
    the analysis Function linearize evaluates at exact estimates, here once for all pairs and points
    (the pair a per-point gain input), and the poles of its matrices as linearize finds them."""
    law, args = drive_arguments(drive, ("speed", [lps[0], wls[0]]))
    assert np.array_equal(args["motor"], args["estimate"])  # linearize's exact-estimate path
    LP, WL = (a.ravel() for a in np.meshgrid(lps, wls, indexing="ij"))
    K, N = LP.size, Wd.size
    gain = np.zeros((args["gain"].size, K * N))
    gain[0], gain[1] = np.repeat(LP, N), np.repeat(WL, N)
    plant, p = loop_parameters(dict(args, gain=gain), K * N)
    poles = equilibrium_points(rotor_frame_loop(law, False), np.tile(Wd, K), np.tile(Td, K), plant, p).poles()
    D = np.min(worst_damping(poles).reshape(K, N), axis=1)  # np.min: a NaN (no equilibrium) stays NaN
    C = np.min(-max_real(poles).reshape(K, N), axis=1)
    return D.reshape(lps.size, wls.size), C.reshape(lps.size, wls.size)


def test_tie_break_keeps_the_smallest_gains_within_the_tolerance(case):
    drive, r, (Wd, Td), (lps, wls, D, C) = case
    R, wb = drive.estimate.R_s, drive.base.w
    tb = r.table.summary["selection"]["tie_break"]
    lp, wl = r.theta
    # the ridge: the brute force's best is on the cap row, and damping alone kept lambda' there
    assert D[-1].max() >= D.max() - 1e-9
    assert tb["before"]["parameters"]["lambda_p"] == pytest.approx(20 * R)
    # the tie-break moved off the cap, to a far gentler ramp ...
    assert tb["moved"] and lp < 20 * R * 0.99 and wl > 2 * tb["before"]["parameters"]["w_lambda"]
    # ... within the stated tolerance of the best, on the dense grid through the analysis path
    z = float(np.min(linearize(drive, Wd, Td, gain=("speed", [lp, wl])).worst_damping))
    assert z == pytest.approx(r.table.summary["worst_damping"], abs=1e-9)
    assert z >= tb["best_worst_damping"] - TIE_TOL - 1e-9
    assert tb["best_worst_damping"] >= D.max() - 1e-4  # the best is at least the brute force's best
    # the size the tuner minimizes is eq. (16)'s (closed form here; the tuner samples 201 speeds)
    w_max = 1.0 * wb
    s = speed_dependent_size(lp, wl, R, wb, w_max)
    assert tb["after"]["gain_size"] == pytest.approx(s, rel=0.02)
    # no brute-force pair that is as well damped and decays as fast is smaller (2 %: the sampling)
    ok = (D >= tb["best_worst_damping"] - TIE_TOL) & (C >= tb["floor_1_s"])
    sizes = np.array([[speed_dependent_size(a, b, R, wb, w_max) for b in wls] for a in lps])
    assert ok.any() and s <= sizes[ok].min() * 1.02
    assert s < 0.5 * speed_dependent_size(*tb["before"]["parameters"].values(), R, wb, w_max)
    # and the summary says it
    assert "tie-break" in " ".join(r.summary_lines(drive)) and "moved the gains" in tb["text"]
