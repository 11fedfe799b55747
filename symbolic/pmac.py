"""PM AC motor with arbitrary EMF harmonics in stationary alpha-beta coordinates, eqs. (2)-(5).

De Angelo, Bossio, Solsona, Garcia, Valla (2006).

The EMF waveform is data: the flux-derivative series (4) is a tuple of odd harmonic orders ``n`` with
amplitudes ``Phi_n`` (:class:`EmfSeries`). A negative order is a negative-sequence harmonic; the paper
prints (4) with every harmonic in positive sequence, and the preset follows the print.

Conventions (docs/families/pmac_reduced_order.md):
- ``theta`` and ``w`` are the **electrical** rotor angle and speed (rad, rad/s); (4) is a function of the
  electrical angle.
- The paper does not say whether omega, J, T_L in (2) are electrical or mechanical. The drive setting
  ``reading`` decides; here it is the factor ``p_r`` = speed in (2) per electrical speed: ``p_r = p``
  (pole pairs) for the mechanical reading, ``p_r = 1`` for the electrical (literal) reading. With it the
  paper's equations hold unchanged in the paper's own variables: omega_paper = w / p_r,
  e = phi(theta) omega_paper (3), T_e = phi . i (5), J d omega_paper/dt = T_e - T_L (2).
  ``Phi_n``, ``J``, ``B`` and torques are in the units of that reading.
- Vectors are 2x1 columns [alpha, beta]; the alpha-beta scaling is the one that makes (5) hold
  (power-invariant).
"""

from __future__ import annotations

from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.frames import Sym


class EmfSeries(NamedTuple):
    """Flux-derivative series of eq. (4): odd harmonic ``orders`` (static) and amplitudes ``Phi``.

    ``Phi`` is a vector (numbers or symbols) of the same length as ``orders``, in V s per radian of the
    reading's angle (mechanical or electrical, see the module docstring).
    """

    orders: tuple[int, ...]
    Phi: Sym

    def amplitude(self, k: int) -> Sym:
        """Phi of the k-th listed harmonic."""
        return self.Phi[k]


class PmacParams(NamedTuple):
    """Motor parameters: R [ohm], L [H], J [kg m^2], B [N m s], p_r (speed factor of the reading)."""

    R: Sym
    L: Sym
    J: Sym
    B: Sym
    p_r: Sym


def _harmonic_terms(theta: Sym, emf: EmfSeries, skip_fundamental: bool) -> tuple[Sym, Sym, Sym, Sym]:
    """Sums of Phi_n sin(n theta), Phi_n cos(n theta), n Phi_n sin(n theta), n Phi_n cos(n theta)."""
    s = c = ns = nc = 0
    for k, n in enumerate(emf.orders):
        if skip_fundamental and n == 1:
            continue
        Phi = emf.amplitude(k)
        sn, cn = ca.sin(n * theta), ca.cos(n * theta)
        s, c = s + Phi * sn, c + Phi * cn
        ns, nc = ns + n * Phi * sn, nc + n * Phi * cn
    return s, c, ns, nc


def flux_derivative(theta: Sym, emf: EmfSeries) -> Sym:
    """phi(theta) = sum_n Phi_n [-sin(n theta), cos(n theta)], eq. (4) (and (23) at theta_hat)."""
    s, c, _, _ = _harmonic_terms(theta, emf, skip_fundamental=False)
    return ca.vertcat(-s, c)


def harmonic_flux_derivative(theta: Sym, emf: EmfSeries) -> Sym:
    """The non-fundamental part of (4): the sum of (19) without the speed factor (orders n != 1)."""
    s, c, _, _ = _harmonic_terms(theta, emf, skip_fundamental=True)
    return ca.vertcat(-s, c)


def flux_derivative_slope(theta: Sym, emf: EmfSeries) -> Sym:
    """d phi / d theta = sum_n -n Phi_n [cos(n theta), sin(n theta)]: eq. (24) without the speed factor.

    (24) is d phi_hat/dt = w_hat * this, with w_hat the electrical speed because (4) is a function of the
    electrical angle.
    """
    _, _, ns, nc = _harmonic_terms(theta, emf, skip_fundamental=False)
    return ca.vertcat(-nc, -ns)


def emf(theta: Sym, w: Sym, emf_series: EmfSeries, p_r: Sym) -> Sym:
    """e = phi(theta) omega_paper = phi(theta) w / p_r, eq. (3) [V]."""
    return flux_derivative(theta, emf_series) * (w / p_r)


def torque(phi: Sym, i: Sym) -> Sym:
    """T_e = phi_alpha i_alpha + phi_beta i_beta, eq. (5) [N m in the reading's units]."""
    return ca.dot(phi, i)


def current_derivative(i: Sym, e: Sym, v: Sym, R: Sym, L: Sym) -> Sym:
    """di/dt = -(R/L) i - e/L + v/L, eq. (2) (the same expression gives (11) with e_hat)."""
    return (-R * i - e + v) / L


def speed_derivative(T_e: Sym, T_load: Sym, J: Sym, p_r: Sym) -> Sym:
    """dw/dt of the electrical speed: J d(w/p_r)/dt = T_e - T_load, eq. (2) [rad/s^2].

    ``T_load`` is everything that opposes T_e; the paper counts viscosity as load (T_L + B omega).
    """
    return p_r * (T_e - T_load) / J


def viscous_torque(w: Sym, B: Sym, p_r: Sym) -> Sym:
    """B omega_paper = B w / p_r: the viscous part of the load the observer estimates (Section II)."""
    return B * w / p_r


def ripple_free_current(T: Sym, phi: Sym) -> Sym:
    """i = T phi / |phi|^2: the minimum-copper-loss current that produces the smooth torque T, eq. (25).

    (25) writes it with the torque reference plus the load feedforward and phi_hat; the plant-side
    analysis uses it with the true phi to hold a constant torque.
    """
    return T * phi / ca.dot(phi, phi)


def pmac_rhs(i: Sym, theta: Sym, w: Sym, v: Sym, T_L: Sym, p: PmacParams, emf_series: EmfSeries) -> Sym:
    """[di/dt; dtheta/dt; dw/dt] of the motor, eqs. (2)-(5), load T_L plus viscosity B omega."""
    phi = flux_derivative(theta, emf_series)  # eq. (4)
    e = emf(theta, w, emf_series, p.p_r)  # eq. (3)
    T_load = T_L + viscous_torque(w, p.B, p.p_r)
    return ca.vertcat(
        current_derivative(i, e, v, p.R, p.L),  # eq. (2)
        w,
        speed_derivative(torque(phi, i), T_load, p.J, p.p_r),  # eqs. (2), (5)
    )


class CurrentControlled(NamedTuple):
    """Current, its rate, EMF and voltage of the motor when its current is the ripple-free (25)."""

    i: Sym  # [A]
    di: Sym  # [A/s]
    e: Sym  # [V]
    v: Sym  # [V]


def ideal_current_control(
    theta: Sym, w: Sym, T_e: Sym, dT_e: Sym, p: PmacParams, emf_series: EmfSeries
) -> CurrentControlled:
    """The motor with ideal (exact, instantaneous) current control producing the smooth torque T_e.

    The current is (25) with the true phi; its rate follows from the chain rule with dtheta/dt = w and
    the torque rate dT_e; the voltage that makes it so is (2): v = R i + L di/dt + e.
    """
    phi = flux_derivative(theta, emf_series)
    slope = flux_derivative_slope(theta, emf_series)
    n2 = ca.dot(phi, phi)
    i = ripple_free_current(T_e, phi)  # eq. (25)
    di_dtheta = T_e * (slope * n2 - 2 * phi * ca.dot(phi, slope)) / n2**2
    di = dT_e * phi / n2 + w * di_dtheta
    e = emf(theta, w, emf_series, p.p_r)  # eq. (3)
    return CurrentControlled(i, di, e, p.R * i + p.L * di + e)  # eq. (2)


def operating_point_signals(theta: Sym, w: Sym, T_L: Sym, p: PmacParams, emf_series: EmfSeries):
    """Signals at an operating point: constant speed w, load T_L, T_e = T_L + B omega (dw/dt = 0)."""
    T_e = T_L + viscous_torque(w, p.B, p.p_r)
    return ideal_current_control(theta, w, T_e, 0, p, emf_series), T_e
