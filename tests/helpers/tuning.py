"""The small tuning envelope of the tuning tests (0.05..1 p.u., 8 speeds, -T_N and +T_N): small so
that the tests stay fast; one definition so that the tests that tune on it can share one run
(the session fixture ``speed_dependent_small`` of tests/conftest.py)."""

import dataclasses

from sensorless.design.envelope import tuning_envelope


def small(drive, **kw):
    """``drive.tuning`` on the small envelope, with the fields ``kw`` replaced; the adaptive observer's
    laws as the paper tunes them (alpha_fo fixed, no bound on the angle lag under acceleration: the
    brute forces of these tests are of the damping over lambda', omega_lambda) unless ``law`` is given."""
    env = tuning_envelope(
        drive.w_base,
        drive.T_N,
        speed_min=0.05,
        speed_max=1.0,
        speeds=8,
        torques_TN=(-1.0, 1.0),
    )
    law = drive.tuning.law
    if "law" not in kw and hasattr(law, "hold_lag"):
        kw["law"] = dataclasses.replace(law, tune_alpha_fo=False, hold_lag=False)
    return dataclasses.replace(drive.tuning, envelope=env, **kw)
