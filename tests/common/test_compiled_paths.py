"""The analyses that run compiled Functions whatever their batch size (design/batch.py ``jit=True``,
design/compiled.py) give the same numbers, bit for bit, as CasADi's virtual machine: the whole
sampled drive's Newton solve as the reduced-order tuner runs it (design/drive_analysis.py), the
reduced-order observer's orbit and one-step maps (design/pmac_reduced_order/linearize.py). Each is
run twice, the second time with compilation switched off."""

from __future__ import annotations

import numpy as np
import pytest
from sensorless.design import batch, compiled, discrete
from sensorless.design.compiled import compiler
from sensorless.design.drive import load_drive
from sensorless.design.drive_analysis import linearize_drive
from sensorless.design.pmac_reduced_order.linearize import analyze
from sensorless.design.registry import family_of

pytestmark = pytest.mark.skipif(compiler() is None, reason="no C compiler: both paths are the VM")


def _vm(monkeypatch) -> None:
    """Compilation off from here on (the Functions cached with a compiled step rebuilt)."""
    monkeypatch.setattr(batch, "_compiled", lambda fn: fn)
    monkeypatch.setattr(discrete, "compiled", lambda fn: fn)
    monkeypatch.setattr(compiled, "compiled", lambda fn: fn)
    discrete.orbit_function.cache_clear()


def test_whole_drive_newton_compiled_is_the_vm(monkeypatch):
    drive = load_drive("deangelo2006")
    gains = family_of(drive).gains(drive)
    w = np.array([-0.3, 0.2, 0.5]) * drive.w_base
    t = np.array([0.5, -1.0, 0.0]) * drive.T_N
    fast = linearize_drive(drive, gains, w, t, jit=True)
    _vm(monkeypatch)
    slow = linearize_drive(drive, gains, w, t, jit=True)
    assert np.isfinite(fast.y).all()
    np.testing.assert_array_equal(fast.y, slow.y)
    np.testing.assert_array_equal(fast.J, slow.J)


def test_reduced_order_orbit_and_maps_compiled_are_the_vm(monkeypatch):
    drive = load_drive("deangelo2006")  # EMF harmonics: a window of one-step maps per point
    w, t = drive.rpm_to_w(np.array([-250.0, 1000.0])), np.array([5.0, -7.0])
    fast = analyze(drive, w, t, noise=True)
    _vm(monkeypatch)
    slow = analyze(drive, w, t, noise=True)
    assert np.isfinite(fast.poles_discrete).all()
    for a, b in (
        (fast.poles_discrete, slow.poles_discrete),
        (fast.noise, slow.noise),
        (fast.err_theta, slow.err_theta),
        (fast.ripple_w, slow.ripple_w),
    ):
        np.testing.assert_array_equal(a, b)
