"""Hostile input: the generated C of the reduced-order observer keeps its promises on every step and
recovers (tests/helpers/fuzz.py). Seeded, >= 10^6 steps per build under -fsanitize=address,undefined,
double and float."""

import numpy as np
import pytest
from helpers.fuzz import CC, fuzz_and_check
from helpers.plant_pmac import Plant
from sensorless.design.pmac_reduced_order import FAMILY

pytestmark = pytest.mark.skipif(CC is None, reason="no host C compiler (gcc/cc) on PATH")

# The documented recovery time (docs/families/pmac_reduced_order.md, "Bounds and recovery"): after any
# hostile burst, plausible samples of the motor at 100-400 r/min bring the estimates back (valid, angle
# within 0.1 rad, speed within 10 r/min) within this many samples (0.18 s at 180 us).
RECOVER = 1000


@pytest.fixture(scope="module")
def segments(deangelo2006):
    """40 clean segments of the independent plant (helpers/plant_pmac.py) in steady state: 100-400
    r/min in both directions, load -20..20 N m, EMF harmonics, random angle; RECOVER + 1000 samples."""
    d, m, T_s = deangelo2006, deangelo2006.motor, deangelo2006.control.T_s
    plant = Plant(m.R, m.L, m.J, m.B, m.p_r, m.harmonics, m.Phi, 0.0)
    rng = np.random.default_rng(20060401)
    out = []
    for _ in range(40):
        w = rng.choice([-1, 1]) * float(d.rpm_to_w(rng.uniform(100, 400)))
        T_L = rng.uniform(-20, 20)
        th = rng.uniform(-np.pi, np.pi) + w * T_s * np.arange(RECOVER + 1000)
        i, v, _ = plant.current_voltage(th, w, T_L + m.B * w / m.p_r, 0.0, T_L)  # steady: dT_e = 0
        out.append(np.column_stack([i.T, v.T, th, np.full(th.size, w)]))
    return np.array(out)


@pytest.mark.parametrize("precision", ["double", "float"])
def test_hostile_samples_keep_every_range_and_bound_and_the_observer_recovers(
    deangelo2006, segments, tmp_path, precision
):
    """Every step: finite, angles in (-pi, pi], the state within its bounds (speed range, load
    state), valid/reset flags, the counter below its bound (the harness). After every burst: back
    within RECOVER clean samples. (Without a bound on the load state, a burst left tau at 3000 N m,
    from where the observer took 2000 samples; with the bound but a count of consecutive rejections,
    the clean samples held the state against that bound, most candidates rejected, for good.)"""
    setup = FAMILY.runtime(deangelo2006, FAMILY.gains(deangelo2006))
    r = fuzz_and_check(
        setup,
        segments,
        precision=precision,
        recover=RECOVER,
        tol_theta=0.1,
        tol_w=float(deangelo2006.rpm_to_w(10.0)),
        seed=11 + (precision == "float"),
        work=tmp_path,
    )
    assert r["held_segments"] == 0


def test_the_fixed_point_c_keeps_its_promises_under_hostile_samples_and_recovers(
    deangelo2006, segments, tmp_path
):
    """The fixed-point C's counterpart of the test above (tests/helpers/fuzz_fixed.py: any int32 words,
    garbage within 3x the clean words, the extreme words, one channel extreme; -fsanitize=address,
    undefined): every step keeps the header's promises and every clean segment recovers within RECOVER
    samples to the same tolerances. Formats from the double step over the segments' first 800 samples
    (helpers.fuzz_fixed.segment_model: each segment's jump from the last and its steady state; cheaper
    than the scenarios' runs `codegen` takes)."""
    from helpers.fuzz_fixed import fixed_fuzz, segment_model
    from sensorless.reports.codegen.fixed_generate import generate_fixed
    from sensorless.reports.codegen.generate import Provenance

    d = deangelo2006
    setup = FAMILY.runtime(d, FAMILY.gains(d))
    seg = segments[:12]  # 12 segments: each of the four burst kinds three times
    model = segment_model(setup, seg[:, :800])  # the jumps' transients and the steady states
    fx = model.program(setup)
    for name, text in generate_fixed(setup, model, Provenance(d.name, d.file, d.digest, "t"), d.name).items():
        (tmp_path / name).write_text(text)
    r = fixed_fuzz(
        d,
        setup,
        fx,
        tmp_path,
        seg,
        recover=RECOVER,
        tol_theta=0.1,
        tol_w=float(d.rpm_to_w(10.0)),
        seed=13,
    )
    assert r["rejected"] > 0 and r["held_segments"] == 0, r
