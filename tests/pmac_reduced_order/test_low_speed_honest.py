"""The reduced-order preset's minimum speed (design/low_speed.py) is honest about what it does not see.

De Angelo et al. (2006), Sec. V: the observer "cannot be used at very low or zero speed". At the
preset's estimates (the motor's own, as in the paper) the family's linearization gives no angle bias
(NaN: the error window is simulated only where the estimates differ), and the angle noise from the
current sensor is checked here, directly from the linearization, to stay under the limit (30/3 deg) at
the analysis' floor: no criterion bites. The analysis must then not list the bias as applied, and its
headline must quote the family's declared zero-speed limitation instead of reading as a clean bill."""

from __future__ import annotations

import numpy as np
from sensorless.design.drive import load_drive
from sensorless.design.low_speed import FLOOR_PU, QUICK, headline, minimum_speed
from sensorless.design.registry import family_of


def test_no_criterion_bites_and_the_headline_says_the_family_limit():
    drive = load_drive("deangelo2006")
    fam = family_of(drive)
    gains = fam.gains(drive)
    lin = fam.linearize(
        drive,
        gains,
        drive.w_base * np.array([FLOOR_PU]),
        np.array([drive.T_N]),
        **fam.low_speed_options(drive),
    )
    assert np.isnan(lin.angle_bias()).all()  # not given at exact estimates
    assert 0 < np.degrees(lin.angle_noise()[0]) < 10.0  # under the noise limit even at the floor
    # the observer-only analysis (the paper's; the whole drive's, design/drive_analysis.py, gives the
    # steady angle error of the sampled loop at every point, so the bias applies there)
    ls = minimum_speed(drive, gains, min_damping=0.3, observer_only=True, **QUICK)
    assert ls.w_min_rated == 0.0
    assert "bias" not in ls.applied and "noise" in ls.applied
    declared = fam.scales(drive).zero_speed
    assert declared and ls.data()["declared_limit"] == declared
    line = headline(ls)
    assert "no verified minimum speed" in line and "De Angelo et al. (2006), Sec. V" in line
    assert "not bias" in line
