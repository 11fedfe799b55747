"""Gain tuning: exact sector conditions, law-(16) optimum vs an independent brute force, dense
re-verification, paper defaults, robustness constraints, CLI errors. Small envelopes keep it fast."""

import dataclasses
import json

import numpy as np
import pytest
from helpers.closed_form_ipmsm import mtpa_reference, paper_gain, paper_matrices
from helpers.tuning import paper_law, small
from sensorless.design.envelope import tuning_envelope
from sensorless.design.ipmsm_adaptive.linearize import linearize
from sensorless.reports.cli.main import main
from sensorless.symbolic.ipmsm_adaptive.gains import schedule_law
from sensorless.tuning.ipmsm_adaptive.laws import build_schedule, with_estimate
from sensorless.tuning.nlp import Solution
from sensorless.tuning.result import figures
from sensorless.tuning.sector import factors_from_poles
from sensorless.tuning.selection import select
from sensorless.tuning.tune import tune

pytestmark = pytest.mark.long(33)  # CPU seconds of this file, measured: scheduled first (tests/conftest.py)


def test_sector_factor_conditions_match_eigenvalues():
    """Every pole has damping >= zeta iff the quadratic factors satisfy a, b >= 0, a^2 >= 4 zeta^2 b."""
    rng = np.random.default_rng(3)
    for _ in range(2000):
        n = rng.choice([2, 3, 4, 5])
        A = rng.normal(size=(n, n))
        p = np.linalg.eigvals(A)
        zeta = rng.uniform(0, 0.95)
        f = factors_from_poles(p)
        a, b = f[0 : 2 * (n // 2) : 2], f[1 : 2 * (n // 2) : 2]
        ok = (a >= 0).all() and (b >= 0).all() and (a**2 >= 4 * zeta**2 * b).all()
        if n % 2:
            ok = ok and f[-1] >= 0
        truth = (-p.real / np.abs(p)).min() >= zeta
        assert ok == truth
        coeffs = np.array([1.0])
        for i in range(n // 2):
            coeffs = np.polymul(coeffs, [1, a[i], b[i]])
        if n % 2:
            coeffs = np.polymul(coeffs, [1, f[-1]])
        np.testing.assert_allclose(coeffs, np.poly(A), rtol=1e-8, atol=1e-8)


def closed_form_worst_damping(drive, W, T, lam_p, w_lam):
    """Worst damping over the points (W, T) with eq. (16), from the paper's (11)-(15) typed here."""
    return min(
        closed_form_damping(drive, w, t, *paper_gain("speed", w, (lam_p, w_lam)))
        for w, t in zip(W, T, strict=True)
    )


def closed_form_worst_damping_many(drive, W, T, params):
    """closed_form_worst_damping for each (lam_p, w_lam) of ``params``, batched: at each point the
    matrices of (11) at lambda = 0 and at the unit gains (paper_matrices: A1 is affine in lambda1,
    lambda2, B1 and A2 do not depend on them), every pair's closed loop of (15) and one batched
    eigenvalue call."""
    m, e = drive.motor, drive.estimate
    a = drive.observer.alpha_fo
    kp, ki = 2 * a / e.psi_pm, a**2 / e.psi_pm  # eq. (10)
    C = np.array([[0.0, e.L_q, 0.0]])
    i0s = {t: mtpa_reference(t, m.L_d, m.L_q, m.psi_pm, m.p) for t in np.unique(T)}
    gains = np.array([[paper_gain("speed", w, prm) for w in W] for prm in params])  # (pairs, points, 2)
    M = np.zeros((len(params), W.size, 4, 4))
    for j, (w, t) in enumerate(zip(W, T, strict=True)):
        base, unit1, unit2 = (
            paper_matrices(w, i0s[t], m.R_s, m.L_d, m.L_q, m.psi_pm, l1, l2)
            for l1, l2 in ((0, 0), (1, 0), (0, 1))
        )
        A1_0, B1, A2 = base
        B = np.append(B1, 1.0)[:, None]
        top = np.zeros((3, 3))
        top[:2, 2] = A2
        top += kp * B @ C
        M[:, j, :3, :3] = top
        M[:, j, :2, :2] += (
            A1_0
            + gains[:, j, 0, None, None] * (unit1[0] - A1_0)
            + gains[:, j, 1, None, None] * (unit2[0] - A1_0)
        )
        M[:, j, :3, 3] = -B[:, 0]
        M[:, j, 3, :3] = -ki * C[0]
    p = np.linalg.eigvals(M)
    return (-p.real / np.abs(p)).min(axis=(1, 2))


def closed_form_schedule(drive, w, t, w_hat, theta):
    """Worst damping of the closed form of (11)-(15) at one point with a schedule's gains there."""
    K = w_hat.size
    l1, l2 = np.interp(w, w_hat, theta[:K]), np.interp(w, w_hat, theta[K:])
    return closed_form_damping(drive, w, t, l1, l2)


def closed_form_damping(drive, w, t, l1, l2):
    """Worst damping from (11)-(15) at one point with gains (l1, l2) there: closed loop
    [[A + kp B C, -B], [-ki C, 0]]."""
    m, e = drive.motor, drive.estimate
    a = drive.observer.alpha_fo
    kp, ki = 2 * a / e.psi_pm, a**2 / e.psi_pm  # eq. (10)
    i0 = mtpa_reference(t, m.L_d, m.L_q, m.psi_pm, m.p)
    A1, B1, A2 = paper_matrices(w, i0, m.R_s, m.L_d, m.L_q, m.psi_pm, l1, l2)
    A = np.zeros((3, 3))
    A[:2, :2], A[:2, 2] = A1, A2
    B = np.append(B1, 1.0)[:, None]
    C = np.array([[0.0, e.L_q, 0.0]])
    p = np.linalg.eigvals(np.block([[A + kp * B @ C, -B], [-ki * C, np.zeros((1, 1))]]))
    return (-p.real / np.abs(p)).min()


@pytest.fixture(scope="module")
def speed_dependent(speed_dependent_small):
    return speed_dependent_small  # one run per worker, shared with test_tune_global.py (tests/conftest.py)


def test_speed_dependent_at_least_as_good_as_brute_force(drive, speed_dependent):
    """The NLP optimum beats (within 0.002) a coarse independent grid search on the same envelope."""
    W, T = small(drive).envelope.grid()
    R, wb = drive.estimate.R_s, drive.base.w
    grid = [(lp * R, wl * wb) for lp in np.linspace(0.5, 20, 12) for wl in np.linspace(0.1, 3, 12)]
    many = closed_form_worst_damping_many(drive, W, T, grid)
    # the batch is the point-by-point closed form (checked on two of its pairs)
    for k in (0, 77):
        assert many[k] == pytest.approx(closed_form_worst_damping(drive, W, T, *grid[k]), abs=1e-9)
    best = float(many.max())
    nlp_grid = closed_form_worst_damping(drive, W, T, speed_dependent.theta[0], speed_dependent.theta[1])
    assert nlp_grid >= best - 0.002, (nlp_grid, best)
    assert nlp_grid > closed_form_worst_damping(drive, W, T, 2 * R, wb) + 0.1  # and beats the paper


def test_table_reports_dense_reverification(drive, speed_dependent):
    s = speed_dependent.table.summary
    env = small(drive).envelope
    Wd, Td = env.grid(env.dense_factor, env.dense_factor)
    w_opt, w_den = env.speed_grid()[env.rule.count :], env.speed_grid(env.dense_factor)
    assert np.diff(w_den[w_den > 0]).max() <= np.diff(w_opt).max() / 4 + 1e-9  # >= 4x denser per axis
    assert np.diff(env.torque_grid(env.dense_factor)).max() <= np.diff(env.torque_grid()).max() / 4 + 1e-9
    pts = speed_dependent.table.points
    assert len(pts) == Wd.size
    assert s["worst_damping"] == min(p["damping"] for p in pts)
    ref = linearize(drive, Wd, Td, gain=("speed", speed_dependent.theta))  # the analysis path, independently
    assert s["worst_damping"] == pytest.approx(np.nanmin(ref.worst_damping), abs=1e-9)
    k = int(np.nanargmin(ref.worst_damping))
    assert s["worst_damping_at"]["w_m_rad_s"] == pytest.approx(Wd[k])
    doc = json.loads(speed_dependent.table.to_json())
    assert doc["format"] == "sensorless-gain-table/2" and doc["law"] == "speed-dependent"
    assert set(doc["gains"]) == {"lambda_p", "w_lambda", "alpha_fo"}


def test_paper_defaults_reproduce(drive, speed_dependent):
    b = speed_dependent.table.summary["baseline_parameters"]
    assert b["lambda_p"] == pytest.approx(2 * drive.estimate.R_s)
    assert b["w_lambda"] == pytest.approx(drive.base.w)
    env = small(drive).envelope
    Wd, Td = env.grid(env.dense_factor, env.dense_factor)
    ref = linearize(drive, Wd, Td, gain="speed")
    assert speed_dependent.table.summary["baseline_worst_damping"] == pytest.approx(
        np.nanmin(ref.worst_damping), abs=1e-9
    )


@pytest.fixture(scope="module")
def schedule(schedule_small):
    return schedule_small  # one run per worker, shared with test_tune_global.py (its conftest.py)


def test_schedule_at_least_as_good_as_speed_dependent(drive, speed_dependent, schedule):
    """The free schedule's dense-verified worst damping is >= law (16)'s, checked by the analysis
    path; its start reproduces the tuned law (16) exactly (a kink breakpoint at omega_lambda)."""
    s = schedule.table.summary
    env = small(drive).envelope
    Wd, Td = env.grid(env.dense_factor, env.dense_factor)
    g = schedule.table.gains
    law = schedule_law(tuple(g["w_hat"]))
    ref = linearize(drive, Wd, Td, gain=(law, np.concatenate([g["lambda1"], g["lambda2"]])))
    assert np.isfinite(ref.worst_damping).all()
    assert s["worst_damping"] == pytest.approx(np.min(ref.worst_damping), abs=1e-9)
    assert s["worst_damping"] >= speed_dependent.table.summary["worst_damping"] - 1e-9
    assert s["selection"]["start_worst_damping"] == pytest.approx(
        speed_dependent.table.summary["worst_damping"], abs=1e-6
    )
    # +-omega_lambda are breakpoints where they lie inside the envelope (outside it law (16) is linear
    # over each direction of the envelope and the schedule reproduces it anyway)
    e = small(drive).envelope
    inside = e.rule.lo * drive.base.w < speed_dependent.theta[1] < e.rule.hi * drive.base.w
    assert np.isclose(np.abs(g["w_hat"]), speed_dependent.theta[1]).sum() == (2 if inside else 0)
    assert s["worst_damping"] > speed_dependent.table.summary["worst_damping"] + 0.03  # and it does improve
    # without giving up decay rate (a pole creeping to the origin has damping 1)
    assert np.min(-ref.max_real) >= speed_dependent.table.summary["min_decay_rate"] * (1 - 1e-6)


def test_dense_reverification_rejects_between_grid_instability(drive, speed_dependent):
    """Gains that equal the start at every speed of the optimization grid but differ between them
    are judged by the dense grid: a schedule perturbed in the null space of grid interpolation is
    identical on the grid (checked with the closed form), worse between, and not selected."""
    # more breakpoints than grid speeds: such perturbations exist
    st = small(drive, law=dataclasses.replace(paper_law(drive.tuning), breakpoints=11))
    m = build_schedule(drive, st, speed_dependent.theta)
    env = st.envelope
    W, T = env.grid()
    Wd, Td = env.grid(env.dense_factor, env.dense_factor)
    w = np.array(m.table_gains(m.start)["w_hat"])
    K = w.size
    G = np.array([np.interp(x, w, np.eye(K)[k]) for x in np.unique(W) for k in range(K)]).reshape(-1, K)
    _, sv, Vt = np.linalg.svd(G)
    null = Vt[int(np.sum(sv > 1e-9)) :]
    assert null.shape[0] > 0
    d = null[0] / np.abs(null[0]).max() * 15 * drive.estimate.R_s
    bad = np.clip(m.start + np.concatenate([np.zeros(K), d]), m.lower, m.upper)  # perturb lambda2
    on_grid = [closed_form_schedule(drive, x, t, w, bad) for x, t in zip(W, T, strict=True)]
    on_grid_ok = [closed_form_schedule(drive, x, t, w, m.start) for x, t in zip(W, T, strict=True)]
    np.testing.assert_allclose(on_grid, on_grid_ok, atol=1e-9)  # identical at the optimization grid
    sol = Solution(bad, 0.9, (), 1, 1, (bad,))
    floor = float(np.min(figures(m, m.start, W, T).decay))
    scale = float(np.abs(figures(m, np.clip(m.theta0, m.lower, m.upper), W, T).poles).max())  # as tune()
    theta, _, note, _ = select(
        m, [sol], [(m.start_label, m.start)], Wd, Td, floor, None, lambda s: None, scale
    )
    assert note["nlp_solution_worst_damping"] < note["start_worst_damping"] - 0.02
    assert note["selected"] == m.start_label and np.array_equal(theta, m.start)


def test_stable_under_stated_estimate_errors(drive):
    """Tuned with R̂s +-20 % and L̂q +-10 % stated, the gains keep every corner stable on the dense
    grid, checked through the analysis path with the drive's estimates replaced. (From 0.3 p.u.:
    lower, the equilibrium itself is lost, see the next test. 4 speeds per direction, 16 on the dense
    grid: 8 cost a third more CPU for gains within 0.5 % of these.)"""
    env = tuning_envelope(
        drive.w_base,
        drive.T_N,
        speed_min=0.3,
        speed_max=1.0,
        speeds=4,
        torques_TN=(-1.0, 1.0),
    )
    # without the pointwise bound (half of this tuning's time; test_tune_global.py checks it): not
    # what this test is about
    st = dataclasses.replace(
        drive.tuning, envelope=env, errors=(0.2, 0.0, 0.1, 0.0), bound=False, law=paper_law(drive.tuning)
    )
    r = tune(drive, "speed-dependent", st)
    assert len(r.robust) == 4 and all(x["stable"] for x in r.robust)
    env = st.envelope
    Wd, Td = env.grid(env.dense_factor, env.dense_factor)
    nom = np.array(drive.estimate.vector())
    for s1 in (1, -1):
        for s3 in (1, -1):
            est = nom * np.array([1 + 0.2 * s1, 1, 1 + 0.1 * s3, 1])
            ref = linearize(with_estimate(drive, est), Wd, Td, gain=("speed", r.theta))
            assert np.isfinite(ref.max_real).all() and (ref.max_real < 0).all()


def test_estimate_errors_without_equilibrium_are_reported(drive):
    """At 0.05 p.u. and full torque a few percent of R̂s error end the equilibrium branch (a fold):
    the tuner says so, naming the scenario, instead of failing inside the NLP."""
    from sensorless.tuning.nlp import TuningError

    with pytest.raises(TuningError, match=r"infeasible under estimate errors R_s\+20%.*no equilibrium"):
        tune(drive, "speed-dependent", small(drive, errors=(0.2, 0.0, 0.0, 0.0)))


def test_default_law_is_the_papers_on_the_preset_and_the_best_on_a_users_drive(tmp_path):
    from sensorless.design.drive import load_drive, preset_text
    from sensorless.tuning.family import tunable_for

    assert tunable_for(load_drive("piippo2008")).name == "speed-dependent"  # reproduces the paper
    own = tmp_path / "mine.toml"
    own.write_text(preset_text("piippo2008"))
    assert tunable_for(load_drive(str(own))).name == "schedule"
    assert tunable_for(load_drive(str(own)), "speed-dependent").name == "speed-dependent"


def test_cli_errors_leave_no_files(tmp_path, capsys):
    out = tmp_path / "o"
    code = main(["tune", "piippo2008", "--speeds", "4", "--min-decay", "5000", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err  # one line, no traceback
    assert err.startswith("sensorless tune: error: the envelope is infeasible") and "decay >= 5000 1/s" in err
    assert not out.exists()
    code = main(["tune", "piippo2008", "--law", "constant", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "constant" in err and "cannot be tuned" in err and "kind 'ipmsm-adaptive'" in err
    assert not out.exists()


def test_former_flag_and_law_names_still_work_and_say_their_new_names(tmp_path, capsys):
    """`--family law16` (the names before "law"): accepted for one release, each with one note line
    naming its new name; the outputs are named after the new law name (here: refused as existing)."""
    out = tmp_path / "o"
    out.mkdir()
    (out / "gains_speed-dependent.json").write_text("{}")
    code = main(["tune", "piippo2008", "--family", "law16", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "sensorless tune: note: --family is now called --law", err
    assert err[1] == "sensorless tune: note: law 'law16' is now called 'speed-dependent'", err
    assert code == 2 and len(err) == 3 and "gains_speed-dependent.json" in err[2], err
    (out / "gains_constant.json").write_text("{}")
    code = main(["tune", "deangelo2006", "--law", "deangelo", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "sensorless tune: note: law 'deangelo' is now called 'constant'", err
    assert code == 2 and len(err) == 2 and "gains_constant.json" in err[1], err
    with pytest.raises(SystemExit):  # an unknown law is still refused by the parser
        main(["tune", "piippo2008", "--law", "law17", "--out", str(tmp_path / "y")])


def test_cli_tune_writes_tables_deterministically(tmp_path, capsys, tune_cli_small):
    # the first run: the session fixture (tune piippo2008 --speeds 5 --torque=-1T_N,1T_N), shared with
    # test_tune_global.py; the second here
    args, a, code, stdout = tune_cli_small
    assert code == 0
    assert "worst damping" in stdout and "wrote" in stdout
    assert main([*args, "--out", str(tmp_path / "b")]) == 0
    for name in ("gains_speed-dependent.json", "gains_speed-dependent.csv"):
        assert a.joinpath(name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert main([*args, "--out", str(tmp_path / "b")]) == 2  # refuses to overwrite
