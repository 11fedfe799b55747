"""The whole sampled drive braking at its torque limit: the angle error as the rotor passes each speed.

The I-f start hands the drive back to the open loop below w_off (design/startup.py), so the observer
must hold the rotor while the speed loop brakes down to it at the torque limit with the load helping,
p (T_max + |T|) / J (a speed step towards zero under a motoring load: the generic speed steps). That
brake is short: from 1 p.u. it lasts w_base J / (p (T_max + |T|)), 8.4 ms on the 22-pole gimbal motor of
docs/examples/motors (T_max = 1.5 T_N, J = 2 kg cm2) against the 20-170 ms of its observer's slowest
mode below 0.5 p.u. The loop's steady error to a speed ramp (design/drive_analysis.py ``ramp_lag``),
the limit of an endless ramp, is then no measure of it: on that motor, with its tuned gains, it reads
36 deg at 1 p.u. and 90 deg at 0.5 p.u., where the drive braking from 1 p.u. holds the rotor within 9
deg at 0.5 p.u. and 13.5 deg down to 0.2 p.u. (the loop simulated as here).

So the brake itself is run: the drive's loop (the whole-drive analysis' ``DriveLoop``: the observer's
runtime step, the current PI in the estimated frame, the speed PI on the estimate, the delay and the
mechanics) from its fixed point at the top speed and the load, its speed reference stepped to minus
that speed (the speed PI at its torque limit until the rotor stops), sensorless throughout. Recorded
per sample: the speed estimate (the speed at which the drive drops back to the open loop: under the
brake it lags the rotor, by 0.14 p.u. on the gimbal motor at the drive file's gains) and the largest
angle error so far, read at each speed the estimate passes.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from sensorless.design.drive_analysis import DriveLoop, linearize_drive
from sensorless.design.family import Drive, GainSet, Scaled, require
from sensorless.design.registry import family_of
from sensorless.design.simulate import run_loop

SPAN = 2.0  # the run lasts this many times the brake's ideal duration (the current's rise, margins)
# the brake starts from the highest of these shares of the top speed where the drive has a steady state
# (a drive whose speed loop cannot hold its rated speed at a load, e.g. at its voltage limit, brakes
# from below it)
TOPS = np.linspace(1.0, 0.1, 10)


@dataclasses.dataclass(frozen=True)
class Brake:
    """A brake of the whole drive from ``w_top`` at load ``torque`` (module docstring)."""

    w_top: float  # where it starts [rad/s electrical]
    torque: float  # load [N m]
    speed: np.ndarray  # (K,) the speed estimate, running minimum (the speeds it has passed) [rad/s]
    error: np.ndarray  # (K,) the largest |angle error| so far [rad]

    def error_at(self, w: np.ndarray) -> np.ndarray:
        """The largest |angle error| [rad] until the speed estimate first passed each speed of ``w`` (>= 0)
        on the way down; NaN where it never got there (stopped above it, or no fixed point to start)."""
        w = np.asarray(w, float)
        if self.speed.size == 0:
            return np.full(w.shape, np.nan)
        k = np.searchsorted(-self.speed, -w, side="left")  # first sample at or below w
        out = np.where(k < self.speed.size, self.error[np.minimum(k, self.speed.size - 1)], np.nan)
        return np.where(w >= self.w_top, 0.0, out)


def brake(drive: Drive, gains: GainSet, dl: DriveLoop, torque: float, w_top: float | None = None) -> Brake:
    """The drive ``drive`` at ``gains`` (its analysed loop ``dl``) braking at its torque limit from
    ``w_top`` (default: 1 p.u.; :data:`TOPS`) with the load ``torque`` [N m] (module docstring)."""
    sc = require(family_of(drive), Scaled).scales(drive)
    s, c = dl.setup, dl.coordinates
    top = float(drive.w_base if w_top is None else w_top)
    assert c.start is not None  # drive_loop's check
    # from the highest of TOPS x the top speed where the drive holds a steady state (a fixed point)
    lin = linearize_drive(drive, gains, top * TOPS, torque, dl)
    held = np.flatnonzero(np.isfinite(lin.y).all(axis=1))
    if held.size == 0:
        return Brake(top, torque, np.zeros(0), np.zeros(0))
    w0, y0 = float(top * TOPS[held[0]]), lin.y[held[0]]
    a = sc.pole_pairs * (sc.T_max + abs(torque)) / sc.J
    n = max(2, math.ceil(SPAN * w0 / a / s.T_s))
    V = np.zeros((s.inputs.shape[0], n))
    V[c.w_ref], V[c.load] = -w0, torque
    z = c.start(V[:, :1], np.array([w0]))[:, 0]
    z[c.theta], z[dl.kept] = 0.0, y0
    rec = run_loop(dataclasses.replace(s, z0=z, inputs=V), compile=False)
    names = [f.name for f in s.record]
    # the speed the drop-back reads: the estimate (under braking it lags the rotor, which is then
    # slower: the error read at the estimate's speed is the one the open loop takes over)
    w = rec[names.index("w_hat")]
    err = np.abs(np.angle(np.exp(1j * rec[names.index("theta_err")])))
    stop = np.flatnonzero(w <= 0)
    end = int(stop[0]) + 1 if stop.size else n
    return Brake(w0, torque, np.minimum.accumulate(w[:end]), np.maximum.accumulate(err[:end]))
