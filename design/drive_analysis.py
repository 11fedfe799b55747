"""The whole sampled drive, linearized: its fixed point, one-step Jacobian and poles at operating points.

The observer-only analysis (each family's ``linearize``, design/discrete.py) closes the observer on a
motor under ideal current control in the true rotor frame. What runs is more: the plant sampled under
the inverter's hold with one period of computation delay, the current PI in the *estimated* frame, the
speed PI on the observer's (filtered) speed, the observer's runtime step and the mechanics with the
load. This module linearizes exactly that: the loop Function ``simulate`` runs (``LoopSetup.loop``,
from the family's ``drive_loop``, design/family.py), at the analysis' scenario (sensorless, speed
control, no noise).

The loop is invariant under a rotation of the stationary frame, so in rotor coordinates (the family's
``LoopCoordinates``: the rotor angle left out, the other angles taken relative to it, stationary-frame
vectors turned into the rotor frame) its one-step map y_k -> y_k+1 has a **fixed point** at each
(speed, load torque): the load an input, the speed reference equal to the speed to hold. Newton's
method from the loop at rest (design/discrete.py ``newton``) finds it for all points in one batched
evaluation per iteration (``Function.map``); ``casadi.jacobian`` of the same graph gives the one-step
Jacobian A, and its eigenvalues z the **poles** ln(z)/T_s.

Two linear properties follow from the same Jacobians:

- the **steady angle error** theta_m - theta_hat at the fixed point (the loop's recorded
  ``theta_err``): the bias the estimate errors leave, in the operating point the drive really settles
  at (the current turned by that error, the speed loop carrying the load);
- the **lag under acceleration**: with the speed reference a ramp of slope a the loop settles at
  y_k = y*(w_k) + d, with y*(w) the fixed point and (A - I) d = (dy*/dw) a T_s, (A - I) dy*/dw =
  -dF/dw_ref; the angle error's part of d per unit a is ``ramp_lag`` [rad per rad/s^2].
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike
from sensorless.design.batch import evaluate_batch
from sensorless.design.compiled import compiled
from sensorless.design.discrete import newton
from sensorless.design.family import CapabilityError, Drive, GainSet, require
from sensorless.design.memo import kept_function
from sensorless.design.poles import sort_poles
from sensorless.design.registry import family_of
from sensorless.design.scenario import Scenario, drive_units, load_scenario_text
from sensorless.design.simulate import AnalysedLoop, LoopCoordinates, LoopSetup, Simulatable
from sensorless.symbolic.frames import rot, wrap_angle

SLOW_SHARE = 0.25  # the drive's slow poles: |s| below this share of pi / T_s (the rest: delays, current PI)


def analysis_scenario(drive: Drive, extra: str = "") -> Scenario:
    """The scenario of the whole-drive analysis: sensorless speed control, no noise, no I-f start;
    ``extra``: more scenario TOML (e.g. a family's ``[control]`` option the drive may run with)."""
    text = (
        f'[scenario]\nname = "drive_analysis"\ntitle = "whole-drive linearization"\nkind = "{drive.kind}"\n'
        f'duration = "{10 * drive.T_s:.9g} s"\n{extra}'
    )
    return load_scenario_text(text, "drive analysis", drive_units(drive))


@dataclass(frozen=True)
class DriveLoop:
    """The loop the whole-drive analysis linearizes: its set-up, coordinates and what it leaves out."""

    setup: LoopSetup
    coordinates: LoopCoordinates
    note: str  # "" or one line: what the analysed loop leaves out of the loop as run

    @property
    def kept(self) -> np.ndarray:
        """Indices of z that are rotor coordinates (all but the angle and the held entries)."""
        c = self.coordinates
        out = {c.theta, *c.held}
        return np.array([k for k in range(self.setup.z0.size) if k not in out])

    @property
    def angles(self) -> tuple[int, ...]:
        """Entries of y that are angles."""
        kept = list(self.kept)
        return tuple(kept.index(a) for a in self.coordinates.angles)


def drive_loop(drive: Drive, gains: GainSet | None, scenario: Scenario | None = None) -> DriveLoop:
    """The family's drive loop at the analysis' scenario (or ``scenario``, one of
    :func:`analysis_scenario`); CapabilityError where it declares none."""
    fam = family_of(drive)
    sc = scenario or analysis_scenario(drive)
    if isinstance(fam, AnalysedLoop):  # a loop of its own to analyse, else the loop it runs
        setup = fam.drive_loop(drive, sc, gains)
    else:
        setup = require(fam, Simulatable).simulation(drive, sc, gains)
    if setup.coordinates is None or setup.coordinates.start is None:
        raise CapabilityError(
            f"observer family {fam.name!r}: its drive loop declares no rotor coordinates "
            "(LoopSetup.coordinates), so the whole drive cannot be linearized"
        )
    return DriveLoop(setup, setup.coordinates, str(setup.meta.get("drive_note", "")))


@kept_function
def map_function(loop: ca.Function, key: tuple, n_z: int, i_err: int) -> ca.Function:
    """(y, v, z_rest, q, p_obs, gain) -> (y_next, Jy, Jw, e, De): the loop's one-step map in rotor
    coordinates (``key`` = LoopCoordinates.key()), its Jacobians with respect to y and to the speed
    reference, the recorded angle error (record row ``i_err``) and its gradient in y."""
    theta, _, w_ref, _, angles, vectors, held = key
    kept = [k for k in range(n_z) if k != theta and k not in held]
    y = ca.SX.sym("y", len(kept))
    v = ca.SX.sym("v", loop.size1_in(1))
    z_rest = ca.SX.sym("z_rest", n_z)
    q, p_obs, gain = (ca.SX.sym(loop.name_in(k), loop.size1_in(k)) for k in (2, 3, 4))
    # the state at rotor angle 0: the coordinates where they are, the held entries at rest
    z = [z_rest[k] for k in range(n_z)]
    z[theta] = ca.SX(0)
    for j, k in enumerate(kept):
        z[k] = y[j]
    z_next, rec = loop(ca.vertcat(*z), v, q, p_obs, gain)
    th = z_next[theta]
    yn = [z_next[k] for k in range(n_z)]
    for a in angles:
        yn[a] = wrap_angle(z_next[a] - th)
    for a, b in vectors:
        r = rot(th).T @ ca.vertcat(z_next[a], z_next[b])
        yn[a], yn[b] = r[0], r[1]
    y_next = ca.vertcat(*(yn[k] for k in kept))
    e = rec[i_err]
    outs = [y_next, ca.jacobian(y_next, y), ca.jacobian(y_next, v[w_ref]), e, ca.jacobian(e, y).T]
    outs = ca.cse([ca.densify(o) for o in outs])
    return ca.Function(
        f"{loop.name()}_rotor_map",
        [y, v, z_rest, q, p_obs, gain],
        outs,
        ["y", "v", "z_rest", "q", "p_obs", "gain"],
        ["y_next", "Jy", "Jw", "e", "De"],
    )


WARM_STEPS = 512  # periods the loop runs from rest where Newton's method from rest finds no fixed point


@kept_function
def warm_function(fn: ca.Function, steps: int = WARM_STEPS) -> ca.Function:
    """(y, v, z_rest, q, p_obs, gain) -> y after ``steps`` periods of the one-step map ``fn`` (the loop
    run in rotor coordinates, i.e. simulated): a start for Newton's method near a stable fixed point;
    compiled to native code."""
    ins = [ca.SX.sym(fn.name_in(k), fn.sparsity_in(k)) for k in range(fn.n_in())]
    par = ca.vertcat(*ins[1:])
    one = ca.Function("one", [ins[0], par], [fn(*ins)[0]])
    P = ca.MX.sym("par", par.size1())
    Y = ca.MX.sym("y", ins[0].size1())
    y_end = one.fold(steps)(Y, ca.repmat(P, 1, steps))
    mx = [Y, *(ca.MX.sym(fn.name_in(k), fn.sparsity_in(k)) for k in range(1, fn.n_in()))]
    out = ca.Function("w", [Y, P], [y_end])(mx[0], ca.vertcat(*mx[1:]))
    # compiled (design/compiled.py, cached on disk; the VM without a compiler): the same numbers, bit
    # for bit, about 3x faster than the VM on the points that need it (half of a low-speed search
    # under estimate errors)
    return compiled(ca.Function(f"{fn.name()}_warm{steps}", mx, [out], fn.name_in(), ["y_end"]))


@dataclass(frozen=True)
class DriveLinearization:
    """The whole drive at N operating points (module docstring); NaN where no fixed point is found."""

    w: np.ndarray  # (N,) speed [rad/s electrical]
    torque: np.ndarray  # (N,) load torque [N m]
    names: tuple[str, ...]  # of the rotor coordinates
    y: np.ndarray  # (N, n) fixed point
    J: np.ndarray  # (N, n, n) one-step Jacobian there
    poles: np.ndarray  # (N, n) ln(z)/T_s, sorted (design/poles.py sort_poles)
    theta_err: np.ndarray  # (N,) steady angle error theta_m - theta_hat [rad]
    ramp_lag: np.ndarray  # (N,) angle error per unit acceleration [rad per rad/s^2]
    T_s: float
    note: str = ""
    torque_name: ClassVar[str] = "T_L"  # ``torque`` is the load's (the pole tables' heading)

    def slow(self) -> np.ndarray:
        """(N, n) the poles with |s| below SLOW_SHARE pi / T_s (the others NaN): the speed loop, the
        observer and the mechanics, not the delay and current-control poles near the sampling limit."""
        s = self.poles
        return np.where(np.abs(s) < SLOW_SHARE * np.pi / self.T_s, s, np.nan + 0j)

    @property
    def max_real(self) -> np.ndarray:
        """(N,) the largest real part of all poles [1/s] (> 0: unstable; NaN: no fixed point)."""
        bad = ~np.isfinite(self.y).all(axis=1)
        return np.where(
            bad, np.nan, np.nanmax(np.where(np.isnan(self.poles), -np.inf, self.poles.real), axis=1)
        )

    @property
    def decay(self) -> np.ndarray:
        """(N,) the slowest decay rate -max Re s over all poles [1/s]."""
        return -self.max_real

    @property
    def worst_damping(self) -> np.ndarray:
        """(N,) the lowest damping -Re s / |s| of the slow poles (1 where none is slow)."""
        s = self.slow()
        with np.errstate(invalid="ignore", divide="ignore"):
            zeta = np.where(np.isnan(s), np.inf, -s.real / np.abs(s))
        out = np.min(zeta, axis=1)
        out = np.where(np.isinf(out), 1.0, out)
        return np.where(~np.isfinite(self.y).all(axis=1), np.nan, out)

    def lag(self, acceleration: np.ndarray | float) -> np.ndarray:
        """(N,) the angle error's lag [rad] under a speed ramp of ``acceleration`` [rad/s^2]."""
        return self.ramp_lag * acceleration


def linearize_drive(
    drive: Drive,
    gains: GainSet | None,
    w: ArrayLike,
    torque: ArrayLike,
    loop: DriveLoop | None = None,
    jit: bool | None = None,
) -> DriveLinearization:
    """The whole drive of ``drive`` at ``gains`` (None: the drive file's) at the operating points (``w``
    [rad/s], ``torque`` [N m], broadcast together): one batched evaluation per Newton step. ``jit``: the
    one-step map compiled whatever the number of points (design/batch.py; the same bits): for a caller
    that linearizes one drive loop again and again (a tuner's constraint), where the first run's
    compilation (a few seconds, once per machine and loop structure) pays off."""
    dl = loop or drive_loop(drive, gains)
    s, c = dl.setup, dl.coordinates
    W, T = (np.asarray(a, float).ravel() for a in np.broadcast_arrays(np.asarray(w, float), torque))
    n = W.size
    V = np.zeros((s.inputs.shape[0], n))
    V[c.w_ref], V[c.load] = W, T
    assert c.start is not None  # drive_loop's check
    Z0 = c.start(V, W)
    kept = dl.kept
    y0 = Z0[kept].T.copy()
    for j in dl.angles:
        y0[:, j] = np.angle(np.exp(1j * y0[:, j]))
    i_err = [f.name for f in s.record].index("theta_err")
    fn = map_function(s.loop, c.key(), Z0.shape[0], i_err)
    args = [V, Z0, s.q, s.p_obs, s.gain]
    y, A, Jw, e, De = newton(fn, args, y0, dl.angles, jit=jit)
    lost = ~np.isfinite(y).all(axis=1)
    if lost.any():  # Newton from rest left the basin: run the loop from rest first (where it is stable)
        sub = [a[:, lost] if np.ndim(a) == 2 and a.shape[1] == n and n > 1 else a for a in args]
        m = int(lost.sum())
        (y_w,) = evaluate_batch(warm_function(fn), m, [y0[lost].T, *sub])
        found = newton(fn, sub, y_w[:, :, 0], dl.angles)
        for full, part in zip((y, A, Jw, e, De), found, strict=True):
            full[lost] = part
    # the lag under a ramp: (A - I) y' = -F_w, (A - I) d = y' T_s (per unit acceleration)
    eye = np.eye(y.shape[1])
    M = A - eye
    ok = np.isfinite(M).all(axis=(1, 2))
    lag = np.full(n, np.nan)
    solvable = np.array(ok)  # a copy
    with np.errstate(over="ignore", invalid="ignore"):  # a pole at z = 1: no steady lag
        solvable[ok] = np.abs(np.linalg.det(M[ok])) > 1e-300
    if solvable.any():
        ok_ = ok
        ok = solvable
        dy = np.linalg.solve(M[ok], -Jw[ok])
        d = np.linalg.solve(M[ok], dy * s.T_s)
        lag[ok] = np.einsum("ni,ni->n", De[ok, :, 0], d[:, :, 0])
        ok = ok_
    z = np.full((n, y.shape[1]), np.nan + 0j)
    if ok.any():
        z[ok] = np.linalg.eigvals(A[ok]).astype(complex)
    with np.errstate(divide="ignore", invalid="ignore"):
        poles = sort_poles(np.log(z) / s.T_s)
    names = tuple(s_name for s_name in _state_names(s, c, kept))
    return DriveLinearization(W, T, names, y, A, poles, e[:, 0, 0], lag, s.T_s, dl.note)


def _state_names(s: LoopSetup, c: LoopCoordinates, kept: np.ndarray) -> list[str]:
    """z_<k> names of the coordinates (the loop Functions carry no field names of their state)."""
    return [f"z{k}" for k in kept]
