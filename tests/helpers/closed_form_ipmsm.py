"""The adaptive observer's closed forms typed from Piippo, Hinkkanen, Luomi (2008): independent references.

Nothing here is taken from the package: eqs. (11), (16) and the textbook MTPA, written out by hand so
that tests can compare the automatic linearization, the gain laws and the MTPA solver against them.
"""

import numpy as np

Jm = np.array([[0.0, -1.0], [1.0, 0.0]])


def paper_matrices(w0, i0, R, Ld, Lq, psi_pm, lam1, lam2):
    """A1, B1, A2 of eq. (11), typed from the paper."""
    L = np.diag([Ld, Lq])
    Li = np.linalg.inv(L)
    lam = lam1 * np.eye(2) + lam2 * Jm
    psi = np.array([psi_pm, 0.0])
    A1 = -R * Li - w0 * Li @ Jm @ L - Li @ lam
    B1 = Jm @ i0 - Li @ Jm @ L @ i0 - Li @ Jm @ psi
    A2 = w0 * (Li @ Jm @ L @ Jm @ i0 + i0 + Li @ psi)
    return A1, B1, A2


def paper_gain(law, w, params):
    """(lambda1, lambda2) for the three gain choices; eq. (16) typed from the paper."""
    if law == "zero":
        return 0.0, 0.0
    if law == "constant":
        return params[0], params[1]
    lp, wl = params
    if abs(w) <= wl:
        return lp * abs(w) / wl, lp * w / wl
    return lp, lp * np.sign(w)


def mtpa_reference(T, Ld, Lq, psi_pm, p):
    """MTPA current from the textbook current-magnitude form (Jahns et al. [12]):
    i_d = psi/(4 dL) - sqrt(psi^2/(16 dL^2) + i^2/2), dL = Lq - Ld; magnitude i by brentq on torque.
    (The package solves a different form, in i_q, by Newton's method.)"""
    from scipy.optimize import brentq

    dL = Lq - Ld

    def currents(i):
        i_d = psi_pm / (4 * dL) - np.sqrt(psi_pm**2 / (16 * dL**2) + i**2 / 2) if dL > 0 else 0.0
        return i_d, np.sqrt(max(i**2 - i_d**2, 0.0))

    def torque(i):
        i_d, i_q = currents(i)
        return 1.5 * p * i_q * (psi_pm + (Ld - Lq) * i_d)

    i_mag = brentq(lambda i: torque(i) - abs(T), 0.0, 1000.0, xtol=1e-15, rtol=1e-15)
    i_d, i_q = currents(i_mag)
    return np.array([i_d, np.sign(T) * i_q])
