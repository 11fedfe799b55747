"""`sensorless simulate` end to end: outputs with units, determinism, gain tables, strict scenarios."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest
from helpers.simulation import piippo2008
from sensorless.design.scenario import load_scenario, load_scenario_text
from sensorless.design.units import DriveFileError
from sensorless.reports.cli.main import main
from sensorless.reports.traces import read_csv

SHORT = ["--duration", "0.3", "--quiet"]
HEAD = '[scenario]\nname="x"\ntitle="x"\nkind="ipmsm-adaptive"\nduration="1 s"\n'


def run(args, capsys):
    code = main(args)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_writes_traces_with_units_and_figures_deterministically(tmp_path, capsys):
    out = tmp_path / "a"
    code, stdout, _ = run(
        ["simulate", "piippo2008", "--scenario", "fig9b", *SHORT, "--out", str(out)], capsys
    )
    assert code == 0
    assert sorted(p.name for p in out.iterdir()) == ["fig9b.png", "fig9b.svg", "traces.csv"]
    assert "us per control period" in stdout and "position error: RMS" in stdout
    text = (out / "traces.csv").read_text()
    head = [ln for ln in text.splitlines() if ln.startswith("#")]
    assert any("1 p.u. = 471.239 rad/s" in ln for ln in head)
    assert any("fig9b" in ln for ln in head)
    cols = text.splitlines()[len(head)]
    assert cols.startswith("t [s],w_ref [rad/s],w_m [rad/s],w_hat [rad/s]")
    assert "theta_err [rad]" in cols and "T_e [N m]" in cols and "eps [A]" in cols
    data = read_csv(out / "traces.csv")
    assert data["t"][-1] == pytest.approx(0.3)
    assert len(data["t"]) == round(0.3 / 2e-4) + 1
    out2 = tmp_path / "b"
    assert run(["simulate", "piippo2008", "--scenario", "fig9b", *SHORT, "--out", str(out2)], capsys)[0] == 0
    for p in out.iterdir():
        assert (out2 / p.name).read_bytes() == p.read_bytes(), p.name


def test_npz_format_and_decimation(tmp_path, capsys):
    args = ["simulate", "piippo2008", "--scenario", "fig6b", *SHORT, "--format", "npz", "--every", "10"]
    assert run([*args, "--out", str(tmp_path)], capsys)[0] == 0
    with np.load(tmp_path / "traces.npz") as z:
        cols = list(z["columns"])
        units = dict(zip(cols, z["units"], strict=True))
        assert units["w_m"] == "rad/s" and units["t"] == "s" and units["T_L"] == "N m"
        assert z["t"][1] == pytest.approx(10 * 2e-4)
        meta = json.loads(str(z["meta"]))
        assert meta["scenario"] == "fig6b" and meta["injection"] is False
    with zipfile.ZipFile(tmp_path / "traces.npz") as zf:
        assert {i.date_time for i in zf.infolist()} == {(1980, 1, 1, 0, 0, 0)}


def test_existing_outputs_are_refused_before_running(tmp_path, capsys):
    args = ["simulate", "piippo2008", "--scenario", "fig6c", *SHORT, "--out", str(tmp_path)]
    assert run(args, capsys)[0] == 0
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    code, stdout, err = run(args, capsys)
    assert code == 2 and "output exists" in err and "--force" in err
    assert "samples" not in stdout  # refused before simulating
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_gain_table_gives_the_same_run_as_the_same_gains_from_the_drive(tmp_path, capsys):
    d = piippo2008()
    g = d.gain("speed")
    table = {
        "format": "sensorless-gain-table/2",
        "drive": {"name": d.name, "kind": d.kind, "sha256": d.digest},
        "law": "speed-dependent",
        "gains": {"lambda_p": g.lambda_p, "w_lambda": g.w_lambda, "alpha_fo": d.observer.alpha_fo},
    }
    path = tmp_path / "table.json"
    path.write_text(json.dumps(table))
    # through the load step at 0.5 s (the gains shape the estimate's response to it)
    base = ["simulate", "piippo2008", "--scenario", "fig9b", "--duration", "0.6", "--quiet"]
    assert run([*base, "--out", str(tmp_path / "drive")], capsys)[0] == 0
    code, stdout, _ = run([*base, "--gains", str(path), "--out", str(tmp_path / "table")], capsys)
    assert code == 0 and "speed-dependent table" in stdout
    a = read_csv(tmp_path / "drive" / "traces.csv")
    b = read_csv(tmp_path / "table" / "traces.csv")
    assert np.array_equal(a["w_hat"], b["w_hat"]) and np.array_equal(a["theta_err"], b["theta_err"])
    # a doubled lambda' changes the run
    table["gains"]["lambda_p"] *= 2
    path.write_text(json.dumps(table))
    assert run([*base, "--gains", str(path), "--out", str(tmp_path / "t2")], capsys)[0] == 0
    c = read_csv(tmp_path / "t2" / "traces.csv")
    assert not np.array_equal(a["w_hat"], c["w_hat"])


def test_list_and_clear_errors(tmp_path, capsys):
    code, stdout, _ = run(["simulate", "piippo2008", "--list"], capsys)
    assert code == 0
    for name in ("fig6a", "fig6b", "fig6c", "fig9a", "fig9b", "fig10"):
        assert name in stdout
    code, _, err = run(["simulate", "piippo2008", "--scenario", "fig99", "--out", str(tmp_path)], capsys)
    assert code == 2 and "fig99" in err and "fig9b" in err
    bad = tmp_path / "bad.toml"
    bad.write_text(HEAD + '[noise]\ni_std="2 V"\n')
    code, _, err = run(
        ["simulate", "piippo2008", "--scenario", str(bad), "--out", str(tmp_path / "o")], capsys
    )
    assert code == 2 and str(bad) in err and "noise.i_std" in err and "'V'" in err
    assert not (tmp_path / "o").exists()
    table = tmp_path / "t.json"
    table.write_text('{"format": "sensorless-gain-table/2", "law": "speed-dependent", "gains": {}}')
    code, _, err = run(["simulate", "piippo2008", "--scenario", "fig6b", "--gains", str(table)], capsys)
    assert code == 2 and "gains.lambda_p" in err


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ('[scenario]\nname="x"\ntitle="x"\nkind="ipmsm-adaptive"\n', "scenario.duration"),
        (
            HEAD + 'speed="1"\n',
            "scenario.speed",
        ),
        ('[scenario]\nname="x"\ntitle="x"\nkind="ipmsm-adaptive"\nduration="-1 s"\n', "scenario.duration"),
        (
            HEAD + '[speed_reference]\nt=[0, 1]\nvalue=["1 pu"]\n',
            "speed_reference.value",
        ),
        (
            HEAD + '[load_torque]\nt=[1, 0]\nvalue=["1 T_N", "0 Nm"]\n',
            "load_torque.t",
        ),
        (
            HEAD + '[load_torque]\nt=[0]\nvalue=["3 ohm"]\n',
            "load_torque.value[0]",
        ),
        (
            HEAD + '[control]\nmode="fast"\n',
            "control.mode",
        ),
        (
            HEAD + "[control]\nstiff_load=true\n",
            "control.stiff_load",
        ),
        (
            HEAD + "[estimate_scale]\nR_s=0\n",
            "estimate_scale.R_s",
        ),
    ],
)
def test_scenario_loading_is_strict(text, key):
    d = piippo2008()
    with pytest.raises(DriveFileError) as e:
        load_scenario_text(text, "my.toml", {"pu": d.base.w, "T_N": d.T_N})
    assert e.value.file == "my.toml" and e.value.key == key


def test_builtin_scenarios_encode_the_papers_experiments():
    d = piippo2008()
    wb, T_N = d.base.w, d.T_N
    s = load_scenario("fig9a", d)
    t = np.array([0.5, 1.5, 2.5, 3.5])
    assert np.allclose(s.speed_reference.sample(t), np.array([0, 0.67, -0.67, 0]) * wb)  # Section VI
    assert s.options["gain"] == "constant" and load_scenario("fig9b", d).options["gain"] == "speed"
    s = load_scenario("fig10", d)
    assert np.allclose(s.speed_reference.sample(np.array([4.0, 15.0, 26.0])), np.array([0.67, 0, -0.67]) * wb)
    assert np.allclose(s.load_torque.sample(np.array([1.0, 2.0, 27.9, 28.0])), [0, T_N, T_N, 0])
    for name, w, T in (("fig6a", 0.01, 1), ("fig6b", 0.03, 1), ("fig6c", 0.01, -1)):
        s = load_scenario(name, d)
        assert not s.options["injection"] and s.options["gain"] == "speed"
        assert s.speed_reference.sample(np.array([2.0]))[0] == pytest.approx(w * wb)
        assert s.load_torque.sample(np.array([0.99, 1.0])) == pytest.approx([0, T * T_N])


def test_reduced_order_drive_lists_and_runs_its_scenarios(tmp_path, capsys):
    code, stdout, _ = run(["simulate", "deangelo2006", "--list"], capsys)
    assert code == 0
    for name in ("fig2", "fig3", "fig4", "fig5a", "fig5b"):
        assert name in stdout
    assert "fig9b" not in stdout
    table = tmp_path / "t.json"
    table.write_text(
        json.dumps(
            {
                "format": "sensorless-gain-table/2",
                "drive": {"name": "x"},
                "law": "constant",
                "gains": {"g": 300, "Gamma": 5000},
            }
        )
    )
    args = [
        "simulate",
        "deangelo2006",
        "--scenario",
        "fig5b",
        *SHORT,
        "--gains",
        str(table),
        "--out",
        str(tmp_path / "o"),
    ]
    code, stdout, _ = run(args, capsys)
    assert code == 0 and "g = 300 1/s, Gamma = 5000" in stdout and "r/min" in stdout
    assert "1 p.u. = " in (tmp_path / "o" / "traces.csv").read_text()
    # each family has its own built-in scenarios: another family's figure is not one of them
    code, _, err = run(["simulate", "deangelo2006", "--scenario", "fig9b"], capsys)
    assert code == 2 and "not a built-in one" in err and "fig5b" in err
    # a scenario file written for the other family is refused, naming its kind
    from importlib import resources

    other = tmp_path / "fig9b.toml"
    other.write_text(
        (resources.files("sensorless.design.ipmsm_adaptive.scenarios") / "fig9b.toml").read_text()
    )
    code, _, err = run(["simulate", "deangelo2006", "--scenario", str(other)], capsys)
    assert code == 2 and "written for 'ipmsm-adaptive' drives" in err
