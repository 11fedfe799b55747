"""The flux family's verdict over the drive's range (reports/drive_range.py): on hubmotor48 (VESC's PLL
defaults, k_p = 2000 1/s, k_i = 30000 1/s^2: a slow root at -15.1 1/s under a speed loop of 156 rad/s)
the whole drive is unstable, put down to the PLL root where the PLL's fix makes it stable; and the
simulated drive agrees: with the speed loop closed it oscillates, with the fixed PLL it settles."""

from __future__ import annotations

import numpy as np
import pytest
from sensorless.design.drive import load_drive_text, preset_text
from sensorless.design.registry import family_of
from sensorless.design.scenario import drive_units, load_scenario_text
from sensorless.design.simulate import simulate
from sensorless.reports import drive_range
from sensorless.reports.pmsm_flux_observer.review import JUDGE


@pytest.fixture(scope="module")
def hub():
    d = load_drive_text(preset_text("hubmotor48") or "", "hubmotor48")
    return d, family_of(d).gains(d)


def test_the_range_fails_on_the_pll_root_and_the_pll_fix_holds_it(hub):
    """112 of the 118 unstable points are the PLL's (stable with the PLL's fix); the other 6, regenerating
    at low speed, are an RHP band the fix does not remove; the verdict names both."""
    d, g = hub
    remedy = JUDGE.range_remedy(d, g, np.zeros(0), np.zeros(0))
    assert remedy is not None and remedy.cause == "pll_root"
    j = drive_range.judge(d, g, 0.2, lambda *w: JUDGE.range_remedy(d, g, *w))
    assert j.status == "fail"
    causes = [f["causes"] for f in j.findings if f["issue"].startswith("unstable")]
    assert causes == [["pll_root"], ["rhp_band"]]
    bad = int(j.data["points"]) - int(j.data["stable_points"])
    assert 0 < bad - int(j.data["remedied_points"]) < 0.1 * bad  # the PLL is most of it
    # with the fix, the points it cured are stable: the cause is counterfactual, not a label
    fixed = drive_range.judge(d, remedy.gains, 0.2)
    assert int(fixed.data["stable_points"]) == int(j.data["stable_points"]) + int(j.data["remedied_points"])


def test_the_simulated_drive_oscillates_with_the_pll_defaults_and_settles_with_the_fix(hub):
    """Independent of the linearization: at 0.8 p.u. unloaded, speed loop closed on the PLL's speed, a
    small speed-reference step; the drive file's gains keep the speed swinging (the limit cycle), the
    PLL's fix settles it."""
    d, g = hub
    text = (
        '[scenario]\nname = "hold"\ntitle = "hold 0.8 p.u."\nkind = "pmsm-flux-observer"\n'
        'duration = "0.6 s"\n[initial]\nw_m = "0.8 pu"\n'
        '[speed_reference]\nt = [0, 0.02]\nvalue = ["0.8 pu", "0.82 pu"]\n'
    )
    sc = load_scenario_text(text, "hold", drive_units(d))
    ptp = {}
    for label, gains in (("file", g), ("fixed", JUDGE.range_remedy(d, g, np.zeros(0), np.zeros(0)).gains)):
        tr = simulate(d, sc, gains)
        w = np.asarray(tr["w_m"]) / d.w_base
        n = round(0.2 / d.T_s)
        ptp[label] = float(np.ptp(w[-n:]))  # the last 0.2 s
        if label == "fixed":
            assert np.mean(w[-n:]) == pytest.approx(0.82, abs=1e-3)  # at the reference
    assert ptp["file"] > 0.2  # still swinging (1.3 p.u. peak to peak, the limit cycle)
    assert ptp["fixed"] < 0.02  # settled
