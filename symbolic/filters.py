"""Digital second-order filters (biquads) for the runtime signal chains, built in SX from their design data.

The HF-injection chain of Piippo, Hinkkanen, Luomi (2008) (Section V, eq. (18)) needs a band-pass and a
low-pass filter that the paper does not specify; the choices are documented in
docs/families/ipmsm_adaptive.md ("HF injection chain"). Both are analog prototypes mapped
to discrete time by the bilinear transform *prewarped at the frequency that matters* (the band-pass centre,
the low-pass cut-off), so that the digital filter has exactly the prototype's response there: the
band-pass has unit gain and zero phase at the carrier frequency, whatever the sampling period.

Coefficients are SX expressions of the design data (frequencies, sampling period), so a parameter change
needs no regeneration; the C generator hoists them into the ``*_init`` function (docs/codegen.md).
The filter runs in transposed direct form II (two states per biquad, well conditioned in float).
"""

from __future__ import annotations

from typing import NamedTuple

import casadi as ca
from sensorless.symbolic.pmsm import Sym


class Biquad(NamedTuple):
    """H(z) = (b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2)."""

    b0: Sym
    b1: Sym
    b2: Sym
    a1: Sym
    a2: Sym


def bilinear(num: tuple[Sym, Sym, Sym], den: tuple[Sym, Sym, Sym], w_warp: Sym, T_s: Sym) -> Biquad:
    """Bilinear transform of (n2 s^2 + n1 s + n0) / (d2 s^2 + d1 s + d0), prewarped at w_warp [rad/s].

    s = K (z - 1)/(z + 1) with K = w_warp / tan(w_warp T_s / 2), so that s = j w_warp maps to
    z = exp(j w_warp T_s) exactly.
    """
    K = w_warp / ca.tan(w_warp * T_s / 2)
    n2, n1, n0 = num
    d2, d1, d0 = den
    KK = K * K
    a0 = d2 * KK + d1 * K + d0
    return Biquad(
        (n2 * KK + n1 * K + n0) / a0,
        2 * (n0 - n2 * KK) / a0,
        (n2 * KK - n1 * K + n0) / a0,
        2 * (d0 - d2 * KK) / a0,
        (d2 * KK - d1 * K + d0) / a0,
    )


def band_pass(w_0: Sym, B: Sym, T_s: Sym) -> Biquad:
    """Second-order band-pass B s / (s^2 + B s + w_0^2): centre w_0, -3 dB bandwidth B [rad/s].

    Prewarped at w_0: unit gain and zero phase at w_0; zeros at DC and at the Nyquist frequency.
    """
    return bilinear((0, B, 0), (1, B, w_0 * w_0), w_0, T_s)


def low_pass(w_0: Sym, T_s: Sym) -> Biquad:
    """Second-order Butterworth low-pass w_0^2 / (s^2 + sqrt(2) w_0 s + w_0^2), unit DC gain."""
    return bilinear((0, 0, w_0 * w_0), (1, ca.sqrt(2) * w_0, w_0 * w_0), w_0, T_s)


class BiquadStep(NamedTuple):
    """Output of one filter sample and the filter's next state."""

    y: Sym
    z_next: Sym  # 2x1


def biquad_step(f: Biquad, z: Sym, u: Sym) -> BiquadStep:
    """One sample in transposed direct form II.

    y = b0 u + z1;  z1' = b1 u - a1 y + z2;  z2' = b2 u - a2 y.
    """
    y = f.b0 * u + z[0]
    return BiquadStep(y, ca.vertcat(f.b1 * u - f.a1 * y + z[1], f.b2 * u - f.a2 * y))
