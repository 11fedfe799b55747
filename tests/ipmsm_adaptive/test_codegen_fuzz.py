"""Hostile input: the generated C of the adaptive observer keeps its promises on every step and recovers
(tests/helpers/fuzz.py). Seeded, >= 10^6 steps per run under -fsanitize=address,undefined, double and
float, with the HF injection on (the drive's default) and off (one build per precision: the injection
is a field of the parameter struct, set at run time)."""

import numpy as np
import pytest
from helpers.fuzz import CC, fuzz_and_check, fuzzer, pmsm_steady_segments, steady_rows
from sensorless.design.ipmsm_adaptive import FAMILY

pytestmark = pytest.mark.skipif(CC is None, reason="no host C compiler (gcc/cc) on PATH")

# The documented recovery time (docs/families/ipmsm_adaptive.md, "Bounds and recovery"): after any
# hostile burst, plausible samples of the motor at 0.3-1 p.u. bring the estimates back (valid, angle
# within 0.1 rad, speed within 5 % of the base speed) within this many samples (0.2 s at 200 us).
RECOVER = 1000
X_EPS_HELD = 10.0  # rad/s: the injection integral that only the injection corrects (below w_Delta)


@pytest.fixture(scope="module")
def segments(drive):
    """40 clean segments of the true motor in steady state: |w| 0.3-1 p.u. in both directions, torque
    -T_N..T_N (motoring and generating), random angle; RECOVER + 1000 samples each."""
    rows = steady_rows(np.random.default_rng(20080201), 40, (0.3, 1.0), drive.base.w, drive.T_N)
    m = drive.motor
    return pmsm_steady_segments((m.R_s, m.L_d, m.L_q, m.psi_pm, m.p), drive.control.T_s, rows, RECOVER + 1000)


@pytest.fixture(scope="module")
def harness(drive, tmp_path_factory):
    """``harness(precision)``: the fuzz harness of the drive's C (its gains, the injection on), built once
    per precision; x_eps held beyond X_EPS_HELD (with the injection off no segment may start so: the
    test requires none held)."""
    setup = FAMILY.runtime(drive, FAMILY.gains(drive))
    assert setup.params["injection"] == 1.0
    built = {}

    def get(precision):
        if precision not in built:
            work = tmp_path_factory.mktemp(f"fuzz_{precision}")
            built[precision] = fuzzer(setup, precision=precision, work=work, held={"x_eps": X_EPS_HELD})
        return setup, built[precision]

    return get


@pytest.mark.parametrize("precision", ["double", "float"])
@pytest.mark.parametrize("injection", [1.0, 0.0])
def test_hostile_samples_keep_every_range_and_bound_and_the_observer_recovers(
    drive, segments, harness, tmp_path, precision, injection
):
    """Every step: finite, angles in (-pi, pi], the state within its bounds, valid/reset flags, the
    counter below its bound (the harness). After every burst: back within RECOVER clean samples.
    With the injection on, the integral x_eps of the PI (21) keeps what the hostile samples wound into
    it while the speed stays above w_Delta (where nothing corrects it, by the family's design): the
    segments that start with |x_eps| > 10 rad/s are measured but not required to recover, and are a
    minority; with the injection off every segment is."""
    setup, exe = harness(precision)
    r = fuzz_and_check(
        setup,
        segments,
        precision=precision,
        recover=RECOVER,
        tol_theta=0.1,
        tol_w=0.05 * drive.base.w,
        seed=1 + int(injection) + 2 * (precision == "float"),
        work=tmp_path,
        exe=exe,
        params={"injection": injection},
    )
    assert r["held_segments"] <= (0.3 * r["segments"] if injection else 0)
