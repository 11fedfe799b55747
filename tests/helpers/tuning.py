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
    kw.setdefault("law", paper_law(drive.tuning))
    return dataclasses.replace(drive.tuning, envelope=env, **kw)


def paper_law(tuning):
    """The adaptive observer's law settings of ``tuning`` as the paper tunes law (16): alpha_fo fixed, no
    bound on the angle lag under acceleration (a drive of the user's own defaults to both on); the
    brute forces of the law-(16) tests are of the damping over lambda', omega_lambda."""
    law = tuning.law
    return dataclasses.replace(law, tune_alpha_fo=False, hold_lag=False) if hasattr(law, "hold_lag") else law
