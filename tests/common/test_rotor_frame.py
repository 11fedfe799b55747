"""The shared continuous linearization (design/rotor_frame.py) against closed forms.

A rotating first-order system written in rotor coordinates, dx/dt = (-a I - w J) x + [k T, 0] with
a = p[0], k = plant[0], has the equilibrium x* = (a I + w J)^-1 [k T, 0] and the poles -a +- j w, for
any speed and torque; Newton's method starts far from it (x = [1, 1]) and meets it exactly (the
rates are linear, so one step suffices and the rest keep it). A nonlinear rate with a known root
checks the convergence flag. A loop whose equilibrium angle is atan(a) (every atan(a) + k pi a root too)
is continued from a = 0 along the branch Newton's method from 0 leaves (a fold, asin(a) past a = 1, is
NaN). And the PMSM steady state against hand formulas: i_d = 0 on a
non-salient motor, T = 1.5 p (psi_pm i_q - (L_q - L_d) i_d i_q) on a salient one, and u = R i + w J psi.
The Functions built from a loop are kept by its content: a second declaration reads them back from disk.
"""

from __future__ import annotations

from typing import ClassVar

import casadi as ca
import numpy as np
import pytest
from sensorless.design.pmsm_schema import PmsmMotor
from sensorless.design.rotor_frame import (
    Continuation,
    RotorFrameLoop,
    equilibrium_points,
    pmsm_plant,
    pmsm_steady,
    pmsm_steady_current,
)


def _loop(rates_of) -> RotorFrameLoop:
    x, w, T = ca.SX.sym("x", 2), ca.SX.sym("w"), ca.SX.sym("T")
    plant, p = ca.SX.sym("plant", 1), ca.SX.sym("p", 1)
    rates = ca.Function("f", [x, w, T, plant, p], [rates_of(x, w, T, plant, p)])
    start = ca.Function("s", [w, T, plant, p], [ca.DM([1.0, 1.0])])
    return RotorFrameLoop("test", rates, start)


def test_equilibria_and_poles_of_a_rotating_linear_system():
    loop = _loop(lambda x, w, T, k, a: ca.vertcat(-a * x[0] + w * x[1] + k * T, -w * x[0] - a * x[1]))
    W = np.array([-300.0, 0.0, 5.0, 1000.0])
    T = np.array([1.0, -2.0, 0.5, 3.0])
    a = np.array([[10.0, 20.0, 30.0, 40.0]])  # one parameter vector per point
    e = equilibrium_points(loop, W, T, [2.0], a)
    poles, x = e.poles(), e.x
    for j in range(W.size):
        M = np.array([[a[0, j], -W[j]], [W[j], a[0, j]]])
        assert np.allclose(x[j], np.linalg.solve(M, [2.0 * T[j], 0.0]), rtol=1e-12, atol=1e-12)
        want = np.sort_complex(np.array([-a[0, j] + 1j * W[j], -a[0, j] - 1j * W[j]]))
        assert np.allclose(np.sort_complex(poles[j]), want, rtol=1e-12, atol=1e-9)


def test_a_point_without_an_equilibrium_is_nan():
    # x0^2 + 1 = 0 has no real root; x0^2 - T = 0 has one for T > 0
    loop = _loop(lambda x, w, T, k, a: ca.vertcat(x[0] ** 2 - T, -a * x[1]))
    e = equilibrium_points(loop, [0.0, 0.0], [4.0, -1.0], [1.0], [3.0])
    x, A, ok = e.x, e.A, e.ok
    assert ok.tolist() == [True, False]
    assert x[0] == pytest.approx([2.0, 0.0]) and np.isnan(x[1]).all() and np.isnan(A[1]).all()
    poles = e.poles()
    assert np.sort(poles[0].real) == pytest.approx([-3.0, 4.0]) and np.isnan(poles[1]).all()


def test_the_loops_output_is_read_at_the_equilibrium_and_nan_where_there_is_none():
    # the output |x|^2 at the closed-form equilibrium of the rotating linear system; NaN at the point
    # without an equilibrium (the second rate has no real root there)
    x, w, T = ca.SX.sym("x", 2), ca.SX.sym("w"), ca.SX.sym("T")
    k, a = ca.SX.sym("plant", 1), ca.SX.sym("p", 1)
    f_r = ca.vertcat(-a * x[0] + w * x[1] + k * T, x[1] ** 2 + w * x[1] + 1.0)  # real roots for |w| >= 2
    args = [x, w, T, k, a]
    loop = RotorFrameLoop(
        "test",
        ca.Function("f", args, [f_r]),
        ca.Function("s", args[1:], [ca.vertcat(0.0, -w / 2 - 0.1 * ca.sign(w))]),
        ca.Function("y", args, [ca.sumsqr(x)]),
    )
    eq = equilibrium_points(loop, [5.0, 0.0], [1.0, 1.0], [2.0], [3.0])
    assert eq.ok.tolist() == [True, False] and np.isnan(eq.y[1]).all() and np.isnan(eq.x[1]).all()
    x1 = (-5.0 - np.sqrt(21.0)) / 2  # the root of x1^2 + 5 x1 + 1 that Newton reaches from -2.6
    x0 = (2.0 * 1.0 + 5.0 * x1) / 3.0
    assert eq.x[0] == pytest.approx([x0, x1], rel=1e-12)
    assert eq.y[0, 0] == pytest.approx(x0**2 + x1**2, rel=1e-12)
    assert equilibrium_points(_loop(lambda *z: z[0]), [0.0], [0.0], [1.0], [1.0]).y is None


def _angle_loop(rate_of, continued: bool) -> RotorFrameLoop:
    """x = [angle, z]: d angle/dt = rate_of(angle, a), dz/dt = angle - z; start 0, exact at a = 0."""
    x, w, T = ca.SX.sym("x", 2), ca.SX.sym("w"), ca.SX.sym("T")
    plant, p = ca.SX.sym("plant", 1), ca.SX.sym("p", 1)
    rates = ca.Function("f", [x, w, T, plant, p], [ca.vertcat(rate_of(x[0], p[0]), x[0] - x[1])])
    start = ca.Function("s", [w, T, plant, p], [ca.DM([0.0, 0.0])])
    anchor = ca.Function("a0", [plant, p], [ca.DM([0.0])])
    return RotorFrameLoop("angle", rates, start, continuation=Continuation(anchor, 0) if continued else None)


def test_the_continuation_follows_the_branch_newton_from_the_start_leaves(monkeypatch):
    monkeypatch.setenv("SENSORLESS_NO_JIT", "1")  # a toy loop: CasADi's VM, no compiler run on a cold cache

    def rate(th, a):
        return a * ca.cos(th) - ca.sin(th)

    a = np.tan([1.3, -1.2, 0.2, 0.0])  # one parameter per point
    e = equilibrium_points(_angle_loop(rate, True), np.zeros(4), np.zeros(4), [0.0], a[None, :])
    assert e.ok.all()
    assert e.x[:, 0] == pytest.approx(np.arctan(a), abs=1e-12) and e.x[:, 1] == pytest.approx(np.arctan(a))
    # d rate/d angle = -(cos + a sin) = -sqrt(1 + a^2) on this branch; dz/dt's pole -1
    poles = equilibrium_points(_angle_loop(rate, True), np.zeros(4), np.zeros(4), [0.0], a[None, :]).poles()
    want = np.sort(np.stack([-np.sqrt(1 + a**2), -np.ones(4)], axis=1), axis=1)
    assert np.sort(poles.real, axis=1) == pytest.approx(want) and np.abs(poles.imag).max() < 1e-12
    # without the continuation Newton's method from 0 leaves the branch at a = tan(1.3) (another root)
    e = equilibrium_points(_angle_loop(rate, False), [0.0], [0.0], [0.0], a[:1])
    assert not (e.ok[0] and abs(e.x[0, 0] - 1.3) < 1e-6)


def test_the_continuation_ends_at_a_fold(monkeypatch):
    monkeypatch.setenv("SENSORLESS_NO_JIT", "1")
    # a - sin(angle) = 0: the branch asin(a) from a = 0 ends at a = 1
    e = equilibrium_points(
        _angle_loop(lambda th, a: a - ca.sin(th), True), np.zeros(2), np.zeros(2), [0.0], [[0.5, 1.5]]
    )
    assert e.ok.tolist() == [True, False]
    assert e.x[0, 0] == pytest.approx(np.arcsin(0.5), abs=1e-12) and np.isnan(e.x[1]).all()


def test_pmsm_steady_state_against_hand_formulas():
    for L_q in (5e-3, 9e-3):  # non-salient, salient
        m = PmsmMotor(p=3, R_s=0.5, L_d=5e-3, L_q=L_q, psi_pm=0.1, J=1e-3)
        plant = pmsm_plant(m)
        T = np.array([-4.0, 0.0, 2.5, 6.0])
        i = pmsm_steady_current(T, plant)
        torque = 1.5 * m.p * (m.psi_pm * i[:, 1] + (m.L_d - m.L_q) * i[:, 0] * i[:, 1])
        assert torque == pytest.approx(T, rel=1e-12, abs=1e-12)
        if L_q == m.L_d:
            assert np.all(i[:, 0] == 0)
        else:
            assert np.all(i[:, 0] <= 0)  # MTPA weakens the flux on a salient motor
        w, T_e, P = ca.SX.sym("w"), ca.SX.sym("T"), ca.SX.sym("plant", 5)
        fn = ca.Function("ss", [w, T_e, P], list(pmsm_steady(w, T_e, P)))
        i_r, u_r = (np.asarray(v).ravel() for v in fn(300.0, 2.5, plant))
        psi = np.array([m.L_d * i_r[0] + m.psi_pm, m.L_q * i_r[1]])
        assert u_r == pytest.approx(m.R_s * i_r + 300.0 * np.array([-psi[1], psi[0]]), rel=1e-12)


# ------------------------------------------------------------------ gains from the laws' keys
def test_gains_from_a_section_and_from_tables_with_one_line_errors():
    from types import SimpleNamespace

    from sensorless.design.family import ObserverFamily
    from sensorless.design.gain_table import GainTable, GainTableError
    from sensorless.design.law_gains import section_gains, table_gains

    class Fam(ObserverFamily):
        kind, name, title, citation = "k-test", "k_test", "a test observer", ""
        laws: ClassVar = {"two": ("a", "b")}

    fam, drive = Fam(), SimpleNamespace(kind="k-test")
    g = section_gains("two", ("a", "b"), SimpleNamespace(a=1, b=2.5, c=9), "drive.toml [observer]")
    assert (g.law, dict(g.values), g.source) == ("two", {"a": 1.0, "b": 2.5}, "drive.toml [observer]")
    ok = GainTable("two", {"name": "d", "kind": "k-test"}, {"a": 3, "b": -1.5})
    assert dict(table_gains(fam, drive, ok, "t.json").values) == {"a": 3.0, "b": -1.5}
    bad = (
        (GainTable("two", {"kind": "other"}, {"a": 1, "b": 1}), "key 'drive.kind'"),
        (
            GainTable("three", {}, {"a": 1, "b": 1}),
            "key 'law': 'three' gains are not for a test observer drives (kind 'k-test'); its laws: two",
        ),
        (GainTable("two", {}, {"a": 1}), "key 'gains.b'"),
        (GainTable("two", {}, {"a": "x", "b": 1}), "key 'gains.a'"),
        (GainTable("two", {}, {"a": float("inf"), "b": 1}), "key 'gains.a': need a finite number"),
    )
    for table, words in bad:
        with pytest.raises(GainTableError) as e:
            table_gains(fam, drive, table, "t.json")
        assert str(e.value).startswith("t.json: ") and words in str(e.value) and "\n" not in str(e.value)


def test_a_loops_functions_are_kept_by_its_content(tmp_path, monkeypatch):
    """Two declarations of one loop (as two processes make them: equal content, other objects) share
    the Functions built from it: the second reads the first's back from disk, the same evaluations to
    the bit and the same C; a loop of other content gets its own."""
    from sensorless.design.rotor_frame import point_function

    monkeypatch.setenv("SENSORLESS_CACHE", str(tmp_path))
    monkeypatch.delenv("SENSORLESS_NO_DISK_MEMO", raising=False)

    def rotating(x, w, T, k, a):
        return ca.vertcat(-a * x[0] + w * x[1] + k * T, -w * x[0] - a * x[1])

    first, second = _loop(rotating), _loop(rotating)
    point_function.__wrapped__.cache_clear()  # not the one an earlier test built in this process
    built = point_function(first)
    point_function.__wrapped__.cache_clear()  # the in-process memo emptied: "the next process"
    read = point_function(second)
    assert point_function.__wrapped__.cache_info() == (1, 0)  # read back from disk, not built
    assert read is not built and read.name_out() == built.name_out()
    assert len(list((tmp_path / "memo").glob("point_function-*.pickle"))) == 1
    args = ([0.3, -1.1], 5.0, 2.0, 2.0, 10.0)
    assert all(
        np.array_equal(np.asarray(r), np.asarray(b)) for r, b in zip(read(*args), built(*args), strict=True)
    )
    gen = [ca.CodeGenerator("f.c") for _ in range(2)]
    gen[0].add(built)
    gen[1].add(read)
    assert gen[0].dump() == gen[1].dump()
    other = point_function(_loop(lambda x, w, T, k, a: ca.vertcat(-a * x[0] + k * T, -a * x[1])))
    assert len(list((tmp_path / "memo").glob("point_function-*.pickle"))) == 2
    assert not np.array_equal(np.asarray(other(*args)[0]), np.asarray(built(*args)[0]))
