"""Space vectors and reference frames: the 90-degree rotation J, rotation by an angle, angle wrapping.

Every model in this package writes a space vector as a 2x1 column, ``[d, q]`` in a rotating frame or
``[alpha, beta]`` in the stationary frame. ``J`` is the rotation by +90 degrees of Piippo, Hinkkanen,
Luomi (2008) eq. (1); ``rot(theta)`` rotates by +theta (their Appendix, eq. (24)). A frame at angle
``theta_f`` sees a vector of the frame at angle ``theta`` as ``rot(theta - theta_f) @ x``.
"""

from __future__ import annotations

import math
from typing import TypeAlias

import casadi as ca

Sym: TypeAlias = ca.SX | ca.MX | ca.DM | float  # an argument: a CasADi expression or a number
Expr: TypeAlias = ca.SX | ca.MX | ca.DM  # a result: a CasADi expression

J = ca.DM([[0.0, -1.0], [1.0, 0.0]])
I2 = ca.DM.eye(2)


def rot(theta: Sym) -> Expr:
    """T = cos(theta) I + sin(theta) J: rotates a vector by +theta."""
    c, s = ca.cos(theta), ca.sin(theta)
    return ca.vertcat(ca.horzcat(c, -s), ca.horzcat(s, c))


def wrap_angle(theta: Sym) -> Sym:
    """theta mapped to (-pi, pi]: r = theta - 2 pi ceil((theta - pi) / (2 pi)), then r - 2 pi if r > pi.

    Keeping angles small keeps a float build exact to its resolution (an unwrapped angle loses a bit
    of resolution each time it doubles). Uses ceil, never a float-to-integer conversion, so NaN and Inf
    stay well defined (they propagate as NaN) and the generated C needs no branch. The last step
    catches the rounding of the quotient: for theta within an ulp above -pi (or -3 pi, ...) it rounds
    to the integer and r lands an ulp above pi, in double and in float; r - 2 pi is then exact
    (Sterbenz) and in range. So for |theta| < 5 pi (every use here: a wrapped angle plus at most
    pi/2) the result is in (-pi, pi] in the arithmetic of either precision, pi being that precision's.
    """
    r = theta - 2 * math.pi * ca.ceil((theta - math.pi) * (1 / (2 * math.pi)))
    return ca.if_else(r > math.pi, r - 2 * math.pi, r)


def half_open(theta: Sym) -> Sym:
    """An angle in [-pi, pi] (the range of atan2) in (-pi, pi]: -pi becomes pi (one comparison)."""
    return ca.if_else(theta > -math.pi, theta, math.pi)
