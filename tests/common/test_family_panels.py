"""Each family's declared trace panels and [estimate_scale] keys: what its scenarios accept, and every
panel drawn from a run of its own drive (the test family included); another family's are refused."""

from __future__ import annotations

import dataclasses
from importlib import resources

import pytest
from families.pll.design import FAMILY as PLL
from sensorless.design.drive import load_drive
from sensorless.design.registry import families, registered
from sensorless.design.scenario import GENERIC_PANELS, load_scenario, load_scenario_text, panel_names
from sensorless.design.simulate import simulate
from sensorless.design.units import DriveFileError
from sensorless.reports.sim_figure import PANELS, panels_of, plot_traces


def _preset(fam):
    names = sorted(p.name[:-5] for p in resources.files(fam.presets).iterdir() if p.name.endswith(".toml"))
    return load_drive(names[0])


def test_shared_figure_code_draws_the_shared_panels():
    assert tuple(PANELS) == GENERIC_PANELS


@pytest.mark.parametrize("name", [*(f.name for f in families()), PLL.name])  # every registered family
def test_every_declared_panel_is_drawn_from_a_run_of_the_family(name):
    """A short run of a built-in scenario with every panel the family's scenarios may name: each is
    drawn (its traces exist), with its declared axis label."""
    import matplotlib.pyplot as plt

    with registered(PLL):
        fam = next(f for f in families() if f.name == name)
        drive = _preset(fam)
        names = panel_names(drive.kind)
        assert names[: len(GENERIC_PANELS)] == GENERIC_PANELS and len(set(names)) == len(names)
        sc = load_scenario(
            sorted(p.name[:-5] for p in resources.files(fam.scenarios).iterdir() if p.name.endswith(".toml"))[
                0
            ],
            drive,
        )
        sc = dataclasses.replace(sc, duration=20 * drive.T_s, figure=names)
        tr = simulate(drive, sc, None)
        assert set(panels_of(tr)) == set(names)
        fig = plot_traces(tr, names, "all panels")
        labels = [ax.get_ylabel() for ax in fig.axes]
        plt.close(fig)
        assert labels[len(GENERIC_PANELS) :] == [p.ylabel for p in fam.panels]


def test_a_panel_or_estimate_key_of_another_family_is_an_error_naming_the_key():
    """The reduced-order drive has no stator-current panel of the PMSM loop (it was a KeyError in the
    figure code), nor the HF-injection signal; the PLL family scales one inductance L, not L_d."""
    d = load_drive("deangelo2006")
    rel = {"pu": d.w_base, "T_N": d.T_N, "rpm": 1.0}
    head = '[scenario]\nname="x"\ntitle="x"\nkind="%s"\nduration="1 s"\n'
    for figure in ('["speed", "current"]', '["w_eps"]'):
        with pytest.raises(DriveFileError) as e:
            load_scenario_text(head % d.kind + f"figure = {figure}\n", "my.toml", rel)
        assert e.value.key == "scenario.figure" and "load_torque" in str(e.value)
    with pytest.raises(DriveFileError) as e:
        load_scenario_text(head % d.kind + "[estimate_scale]\npsi_pm = 1.1\n", "my.toml", rel)
    assert e.value.key == "estimate_scale.psi_pm"
    with registered(PLL):
        p = _preset(PLL)
        sc = load_scenario_text(head % p.kind + "[estimate_scale]\nL = 1.2\n", "my.toml", rel)
        assert dict(sc.estimate_scale) == {"R_s": 1.0, "L": 1.2, "psi_pm": 1.0, "J": 1.0}
        assert "L" not in sc.options
        with pytest.raises(DriveFileError) as e:
            load_scenario_text(head % p.kind + "[estimate_scale]\nL_q = 1.2\n", "my.toml", rel)
        assert e.value.key == "estimate_scale.L_q"
