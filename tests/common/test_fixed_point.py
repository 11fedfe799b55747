"""`codegen --precision fixed` (reports/codegen/fixed_*.py) on the flux observer's outrunner270: the C
against the integer-numpy model bit for bit, no floating point on a Cortex-M0+, the integer methods
against numpy's float functions, and the fixed-point step in closed loop against the double one."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
from helpers.cbuild import build as cbuild
from helpers.figures_off import figures_off
from helpers.fuzz import CC, pmsm_steady_segments, steady_rows
from sensorless.design.drive import load_drive
from sensorless.design.registry import family_of
from sensorless.design.runtime import run_trajectory, step_variant
from sensorless.design.scenario import load_scenario
from sensorless.design.simulate import simulate
from sensorless.reports.codegen import fixed_ops
from sensorless.reports.codegen.fixed_generate import fixed_model, generate_fixed, range_scenarios
from sensorless.reports.codegen.fixed_model import run_raw, step_raw
from sensorless.reports.codegen.fixed_params import params_from_si
from sensorless.reports.codegen.generate import Provenance

pytestmark = [
    pytest.mark.skipif(CC is None, reason="no host C compiler (gcc/cc) on PATH"),
    # CPU seconds of this file, measured (30 on a machine loaded ~5x, 36 there before the suite-time
    # work, which the suite's profile read as 30): scheduled first (tests/conftest.py)
    pytest.mark.long(25),
]
STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]
ARM = shutil.which("arm-none-eabi-gcc")


def compile_replay(d, setup, model, out):
    """The generated fixed-point files of ``setup`` written to ``out`` and its replay program built
    warning-free (STRICT); returns the executable."""
    files = generate_fixed(setup, model, Provenance(d.name, d.file, d.digest, "sensorless test"), d.name)
    for name, text in files.items():
        (out / name).write_text(text)
    exe = out / "replay"  # once per process for the same C (tests/helpers/cbuild.py)
    return cbuild([CC, *STRICT, "-o", str(exe), str(out / "main.c"), str(out / f"{d.name}.c")], exe)


def codegen_model(d):
    """The fixed-point model `codegen --precision fixed` builds for ``d`` at its drive file's gains
    (fixed_generate.fixed_model: the runs of range_scenarios), its runs on CasADi's VM: for the flux
    family's short scenarios 3-4x cheaper than compiling them (0.7 against 2.6 s for outrunner270 on an
    empty compile cache), and the same runs bit for bit (checked on outrunner270, hubmotor48 and
    piippo2008). test_with_the_formats_codegen_generates_... calls fixed_model itself."""
    from sensorless.reports.codegen.fixed_model import FixedModel

    return FixedModel.of(d, None, range_scenarios(d), compile=False)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    d = load_drive("outrunner270")
    fam = family_of(d)
    setup = fam.runtime(d, fam.gains(d))
    model = codegen_model(d)
    out = tmp_path_factory.mktemp("fixed")
    exe = compile_replay(d, setup, model, out)
    return d, setup, model, model.program(setup), out, exe


def the_clis_model_is(monkeypatch, d, model):
    """The commands' fixed-point model of ``d`` at its drive file's gains is ``model`` (``built``'s: the
    ranges of every scenario and check, seconds to run again in each command); any other drive or
    gains go to fixed_generate.fixed_model as they do without this. Returns the drives asked for."""
    from sensorless.reports.codegen import fixed_generate

    real, asked = fixed_generate.fixed_model, []

    def fixed_model(drive, gains, setup):
        asked.append(drive.name)
        mine = drive.digest == d.digest and (gains is None or gains == family_of(d).gains(d))
        return model if mine else real(drive, gains, setup)

    monkeypatch.setattr(fixed_generate, "fixed_model", fixed_model)
    return asked


def replay(exe, out, raw, x0=None, params=None, code=0):
    """The C on raw samples, from *_init or from the raw state ``x0``, with the drive's parameter
    struct or the raw words ``params``; ``code``: the exit status expected."""
    f = out / "samples.bin"
    np.ascontiguousarray(raw, dtype="<i4").tofile(f)
    args = [str(exe), str(f)]
    if x0 is not None:
        np.ascontiguousarray(x0, dtype="<i4").tofile(out / "x0.bin")
        args.append(str(out / "x0.bin"))
    if params is not None:
        np.ascontiguousarray(params, dtype="<i4").tofile(out / "params.bin")
        args.append(str(out / "params.bin"))
    r = subprocess.run(args, capture_output=True)
    assert r.returncode == code, r.stderr
    return np.frombuffer(r.stdout, "<i4").reshape(len(raw), -1) if code == 0 else r.stderr.decode()


def glitched_replay(exe, out, fx, x, meas, start, stop, burst, seed):
    """The C and the integer model on samples ``start:stop`` of a run (states ``x``, measurements
    ``meas``) from its state at ``start``, rows ``burst`` replaced by any int32 words: they agree bit
    for bit; returns the C's rows."""
    raw = fx.to_raw(meas[:, start:stop], "meas").T
    n = burst.stop - burst.start
    raw[burst] = np.random.default_rng(seed).integers(-(2**31), 2**31, size=(n, raw.shape[1]))
    x0 = fx.to_raw(x[:, start], "x")
    c = replay(exe, out, raw, x0)
    model_equals_c(fx, c, raw, x0)
    return c


def model_equals_c(fx, c, raw, x0, params=None):
    """Assert that the C's rows ``c`` (outputs, then states, per sample) on the raw samples ``raw`` from
    the raw state ``x0`` are the integer model's bit for bit; returns the model's (states, outputs).

    The model steps from each of the C's states (``x0``, then the C's own) on that sample's words, all
    samples at once (columns of one vectorized step): if every step gives the C's next state and
    outputs, then by induction from the same ``x0`` the model's trajectory is the C's (one step per
    sample in a Python loop, run_raw, was most of this file's time and checks the same)."""
    ny = len(fx.outputs)
    prev = np.vstack([np.asarray(x0, np.int64)[None], c[:-1, ny:]]).T
    xn, y = step_raw(fx, prev, np.asarray(raw, np.int64).T, params)
    xs, ys = xn.T, y.T
    assert int((c != np.hstack([ys, xs])).sum()) == 0
    return xs, ys


def against_double(d, sc, model):
    """``sc`` on ``d`` with the double step and with ``model``'s fixed-point step: (the double run, the
    fixed run, the difference of their angle errors [deg electrical], wrapped)."""
    ref = simulate(d, sc, compile=False)
    with step_variant(model.variant):
        fix = simulate(d, sc, compile=False)
    return ref, fix, np.degrees(np.angle(np.exp(1j * (fix["theta_err"] - ref["theta_err"]))))


def test_c_equals_the_integer_model_and_recovers_from_a_glitch(built):
    """A hostile burst (any int32 words) amid 400 consecutive closed-loop samples: the C equals the
    model bit for bit, the guard keeps its meaning (rejects, flags 0/1), and the estimates are back
    with the double step's within the flux observer's documented recovery (200 periods: 0.1 rad, 2 %
    of the base speed; docs/families/pmsm_flux_observer.md)."""
    d, setup, model, fx, out, exe = built
    x, meas_all = model.data(setup)
    c = glitched_replay(exe, out, fx, x, meas_all, 1000, 1700, slice(150, 210), 3)
    meas = meas_all[:, 1000:1700]
    names = [o["name"] for o in fx.outputs]
    valid = c[:, names.index("valid")]
    assert set(np.unique(valid).tolist()) <= {0, 1}
    assert valid[150:210].min() == 0 and valid[:150].min() == 1
    _, ys_d = run_trajectory(setup, meas.T, x[:, 1000])
    th = c[:, names.index("theta_hat")] * np.pi / 2**31
    w = c[:, names.index("w_hat")] * 2.0 ** -fx.outputs[names.index("w_hat")]["f"]
    late = slice(210 + 200, None)
    assert np.abs(np.angle(np.exp(1j * (th[late] - ys_d[late, names.index("theta_hat")])))).max() < 0.1
    assert np.abs(w[late] - ys_d[late, names.index("w_hat")]).max() < 0.02 * d.w_base


def test_sx_twin_equals_the_integer_model(built):
    _d, setup, model, fx, _out, _exe = built
    meas = model.data(setup)[1][:, :150]
    _, ys_r = run_raw(fx, fx.to_raw(meas, "meas").T)
    F = model.function(setup).mapaccum(meas.shape[1])
    _, ys = F(setup.initial_state(), meas, setup.p, setup.gain)
    ys = np.asarray(ys)
    for k, o in enumerate(fx.outputs):
        scale = np.pi / 2**31 if o["kind"] == "ang" else 2.0 ** -o["f"]
        assert np.array_equal(ys[k], ys_r[:, k] * scale), o["name"]


# what an integer-only object may call on a Cortex-M0+ (no divide instruction, no 64-bit shifts or
# multiply in the core): libgcc's integer routines; a soft-float call (__aeabi_f*, __aeabi_d*) or a libm
# function (sinf, sqrt, ...) is anything else
INTEGER_CALLS = {
    "__aeabi_idiv", "__aeabi_idivmod", "__aeabi_uidiv", "__aeabi_uidivmod", "__aeabi_ldivmod",
    "__aeabi_uldivmod", "__aeabi_lmul", "__aeabi_llsl", "__aeabi_llsr", "__aeabi_lasr", "__divsi3",
    "__udivsi3", "__modsi3", "__umodsi3", "memcpy", "memset",
}  # fmt: skip


def m0plus_calls(c_file, obj, strict=True):
    """The undefined symbols (the calls out) of ``c_file`` compiled for a Cortex-M0+ (-Os, Thumb), read
    from its symbol table (arm-none-eabi-nm); ``strict``: warning-free under STRICT and no writable
    static data (no data, bss or common symbol: instances share nothing), asserted."""
    cmd = [ARM, *(STRICT if strict else []), "-Os", "-mcpu=cortex-m0plus", "-mthumb", "-c", "-o", str(obj)]
    r = subprocess.run([*cmd, str(c_file)], capture_output=True, text=True)
    assert r.returncode == 0 and (r.stderr == "" or not strict), r.stderr
    table = subprocess.run(["arm-none-eabi-nm", str(obj)], capture_output=True, text=True).stdout.splitlines()
    kinds = [line.split()[-2:] for line in table]
    if strict:
        assert not [n for k, n in kinds if k in "DdBbCcGgSs"], table  # no global or static state
    return {n for k, n in kinds if k == "U"}


@pytest.mark.skipif(ARM is None, reason="arm-none-eabi-gcc not installed")
def test_no_floating_point_on_cortex_m0plus(built, tmp_path):
    """outrunner270's fixed-point C builds warning-free for a Cortex-M0+, has no writable static data and
    calls nothing but libgcc's integer routines (no __aeabi_f*/__aeabi_d* soft-float call, no libm); the
    float C of the same drive, compiled the same way, calls soft-float routines (the check can fail).
    piippo2008 and deangelo2006: test_the_other_families_c_equals_the_model."""
    from sensorless.reports.codegen.generate import generate

    d, setup, *_, out, _ = built
    calls = m0plus_calls(out / f"{d.name}.c", tmp_path / "m0.o")
    assert calls <= INTEGER_CALLS, calls - INTEGER_CALLS
    for name, text in generate(setup, Provenance(d.name, d.file, d.digest, "t"), precision="float").items():
        (tmp_path / name).write_text(text)
    float_calls = m0plus_calls(tmp_path / f"{d.name}.c", tmp_path / "f.o", strict=False)
    assert any(c.startswith("__aeabi_f") for c in float_calls) and not float_calls <= INTEGER_CALLS


def test_integer_methods_within_their_stated_bounds():
    B = fixed_ops.NUMPY
    rng = np.random.default_rng(0)
    a = rng.integers(-(2**31), 2**31, size=20000)
    s = fixed_ops.sin_binary(B, a) * 2.0**-fixed_ops.SIN_F
    assert np.abs(s - np.sin(a * np.pi / 2**31)).max() < 1e-6  # the stated bound
    r = 2.0 ** rng.uniform(8, 30.9, size=20000)  # any magnitude of an int32 vector from 2^8 up
    th = rng.uniform(-np.pi, np.pi, size=20000)
    x, y = np.round(r * np.cos(th)).astype(np.int64), np.round(r * np.sin(th)).astype(np.int64)
    z = fixed_ops.cordic_atan2(B, y, x) * np.pi / 2**31
    err = np.abs(np.angle(np.exp(1j * (z - np.arctan2(y, x)))))
    assert np.all(err <= 4.89e-4 + 24 / r)  # the stated bound: atan(2^-11) + 24 LSB / |v| (12 steps)
    assert err.max() > 1.23e-4  # and no better than 13 steps' bound: the steps are as stated
    # cos and sin of an atan2 from the CORDIC's own rotations: the atan2's bound, and within 1e-6 of
    # cos and sin of the angle the CORDIC returns
    c, sn = (v * 2.0**-fixed_ops.SIN_F for v in fixed_ops.cordic_cos_sin(B, y, x))
    t = np.arctan2(y, x)
    assert np.all(np.abs(c - np.cos(t)) <= 1.23e-4 + 24 / r) and np.all(
        np.abs(sn - np.sin(t)) <= 1.23e-4 + 24 / r
    )
    z = fixed_ops.cordic_atan2(B, y, x, fixed_ops.CORDIC_STEPS) * np.pi / 2**31  # its 14 steps
    assert np.abs(c - np.cos(z)).max() < 1e-6 and np.abs(sn - np.sin(z)).max() < 1e-6
    v = rng.integers(0, 2**32, size=20000)
    q = B.isqrt(v)
    assert np.all(q * q <= v) and np.all((q + 1) * (q + 1) > v)
    # a product of two signals (fixed_ops.mulw, four 32-bit products of 16-bit halves): within 3 LSB
    # of the exact floor(a b 2^-s), any int32 words (the header's stated bound)
    a, b = rng.integers(-(2**31), 2**31, size=(2, 20000))
    for sh in (16, 21, 26, 31, 32):
        exact = (a * b) >> sh  # |a b| < 2^62: exact in int64, >> floors
        err = exact - fixed_ops.mulw(B, a, b, sh)
        assert err.min() >= -3 and err.max() <= 3, (sh, err.min(), err.max())


def test_closed_loop_angle_error_within_0p2_deg_of_the_double_step(built):
    d, _setup, model, *_ = built
    sc = load_scenario("torque_steps", d)
    _ref, fix, e = against_double(d, sc, model)
    steady = fix.t > 0.8 * fix.t[-1]
    assert np.abs(e[steady]).max() <= 0.2, np.abs(e[steady]).max()
    assert not fix.problems()


@pytest.mark.parametrize(("preset", "scenario"), [("piippo2008", None), ("deangelo2006", "fig2")])
def test_the_other_families_c_equals_the_model(tmp_path, request, preset, scenario):
    """The adaptive observer (sin/cos, filters with unbounded states) and the reduced-order one (its
    harmonic EMF, a division by a magnitude proven positive): C == model on 150 closed-loop samples
    and 30 hostile words. piippo2008 in the formats `codegen` generates (piippo_codegen, which the
    tests below need anyway), deangelo2006 with ranges from 0.3 s of one scenario to keep the test
    short. The C builds warning-free for a Cortex-M0+ and calls only libgcc's integer routines (no
    float operation)."""
    import dataclasses

    from sensorless.reports.codegen.fixed_model import FixedModel

    if scenario is None:
        d, setup, model = request.getfixturevalue("piippo_codegen")
    else:
        d = load_drive(preset)
        fam = family_of(d)
        setup = fam.runtime(d, fam.gains(d))
        model = FixedModel.of(
            d, None, [dataclasses.replace(load_scenario(scenario, d), duration=0.3)], compile=False
        )
    fx = model.program(setup)
    exe = compile_replay(d, setup, model, tmp_path)
    x, meas = model.data(setup)
    glitched_replay(exe, tmp_path, fx, x, meas, 500, 650, slice(50, 80), 5)
    # no division but by a divisor proven non-zero: each DIV's divisor is clamped below by a positive
    # constant (half the runs' smallest divisor); the reduced-order observer has three
    divs = [i for i in fx.prog if i.op == "DIV"]
    for i in divs:
        dv = fx.prog[i.args[1]]
        floor = [fx.prog[a].imm[0] for a in dv.args if fx.prog[a].op == "CONST"]
        assert dv.op == "MAX" and len(floor) == 1 and floor[0] > 0, (i, dv)
    assert len(divs) >= (1 if preset == "deangelo2006" else 0)
    if ARM is not None:  # warning-free on a Cortex-M0+, no soft-float call (test_no_floating_point_...)
        calls = m0plus_calls(tmp_path / f"{d.name}.c", tmp_path / "m0.o")
        assert calls <= INTEGER_CALLS, calls - INTEGER_CALLS


def test_stored_constants_move_the_poles_little(built):
    """The quantization's effect on the observer's poles, as the header and the JSON report it: not
    zero (the constants are rounded) and far below what would matter (1e-4 of the unit circle)."""
    import json

    d, _setup, _model, _fx, out, _ = built
    poles = json.loads((out / f"{d.name}_formats.json").read_text())["poles"]
    assert 0 < poles["max_pole_shift"] < 1e-4
    assert abs(poles["spectral_radius_stored"] - poles["spectral_radius_double"]) < 1e-4


def test_cli_writes_the_fixed_point_files_together(built, tmp_path, capsys, monkeypatch):
    """The files, and with --param the parameter struct's words for SI values (params_from_si's, in
    the formats of the C written beside them); a wrong --param is one line before anything is run.
    (The command's model is ``built``'s, the_clis_model_is.)"""
    import json

    from sensorless.reports.cli.main import main

    d, setup, model, fx, _out, _exe = built
    asked = the_clis_model_is(monkeypatch, d, model)
    out = tmp_path / "c"
    args = ["codegen", "outrunner270", "--precision", "fixed", "--out", str(out), "--param", "k_p=3000"]
    assert main(args) == 0
    names = sorted(p.name for p in out.iterdir())
    P = "outrunner270"
    assert names == sorted(["Makefile", "main.c", f"{P}.c", f"{P}.h", f"{P}_formats.json", f"{P}_params.bin"])
    words = np.fromfile(out / "outrunner270_params.bin", "<i4").tolist()
    assert words == params_from_si(setup, fx, {"k_p": 3000.0}) != [p["raw"] for p in fx.params]
    data = json.loads((out / "outrunner270_formats.json").read_text())
    assert [d["name"] for d in data["inputs"]][:2] == ["x_alpha", "x_beta"]
    assert all(d["reason"] for d in data["inputs"])
    assert "no floating point" in (out / "outrunner270.h").read_text()
    assert "Cortex-M0+" in capsys.readouterr().out
    assert asked == ["outrunner270"]
    for bad, why in [("psi=1", "unknown parameter 'psi'"), ("k_p", "'k_p' is not NAME=VALUE")]:
        assert main([*args[:-1], bad, "--force"]) == 2
        assert f"argument --param: {why}" in capsys.readouterr().err


def test_simulate_runs_the_fixed_point_step_and_says_so(built, tmp_path, capsys, monkeypatch):
    """`sensorless simulate --precision fixed`: the run is the fixed-point step of `codegen --precision
    fixed` (its traces those of the step variant of the same formats, not the double step's), the
    command says which step ran and the traces' metadata carry it. (The command's model is
    ``built``'s, the_clis_model_is; its figures, most of its CPU, are not drawn: the traces are read
    here, tests/common/test_cli_simulate.py checks the figures.)"""
    import dataclasses
    import json

    from matplotlib.figure import Figure
    from sensorless.reports import sim_figure
    from sensorless.reports.cli.main import main
    from sensorless.reports.files import OutputSet

    d, _setup, model, *_ = built
    asked = the_clis_model_is(monkeypatch, d, model)
    monkeypatch.setattr(sim_figure, "plot_traces", lambda *a: Figure())
    monkeypatch.setattr(OutputSet, "add_figures", lambda *a: None)
    out = tmp_path / "s"
    args = ["simulate", "outrunner270", "--scenario", "torque_steps", "--duration", "0.03", "--format", "npz"]
    assert main([*args, "--quiet", "--out", str(out), "--precision", "fixed"]) == 0
    assert "observer step: fixed precision" in capsys.readouterr().out and asked == ["outrunner270"]
    z = np.load(out / "traces.npz")
    assert json.loads(str(z["meta"]))["precision"] == "fixed"
    got = z["theta_hat"]
    sc = dataclasses.replace(load_scenario("torque_steps", d), duration=0.03)
    ref, fix, _e = against_double(d, sc, model)
    assert np.allclose(got, fix["theta_hat"], rtol=0, atol=1e-9)
    assert np.abs(got - ref["theta_hat"]).max() > 1e-6  # not the double step


def test_adaptive_observer_closed_loop_within_0p2_deg_of_the_double_step():
    """piippo2008's fig9b, first 0.8 s (a load step at 0.5 s): the fixed-point step in the loop, its
    ranges from this run alone; the angle error within 0.2 deg of the double step's, no rejection."""
    import dataclasses

    from sensorless.reports.codegen.fixed_model import FixedModel

    d = load_drive("piippo2008")
    sc = dataclasses.replace(load_scenario("fig9b", d), duration=0.8)
    model = FixedModel.of(d, None, [sc], compile=False)
    _ref, fix, e = against_double(d, sc, model)
    assert np.abs(e).max() <= 0.2, np.abs(e).max()
    assert not fix.problems()


@pytest.fixture(scope="module")
def piippo_codegen():
    """piippo2008 with the fixed-point model `codegen --precision fixed` builds (ranges from every
    scenario and check, fixed_model): (drive, set-up, model), shared by the two tests that need the
    preset's own formats."""
    d = load_drive("piippo2008")
    fam = family_of(d)
    setup = fam.runtime(d, fam.gains(d))
    return d, setup, fixed_model(d, None, setup)


def test_with_the_formats_codegen_generates_the_closed_loop_holds_0p2_deg(piippo_codegen):
    """piippo2008's fig6c with the formats `codegen --precision fixed` generates (ranges from every
    scenario and check, fixed_model): the angle error at steady state (the last 20 %) within 0.2 deg
    of the double step's. A run's own ranges (the test above) are tighter than these; 32-bit products
    of 15-bit operands with these formats left it 1.08 deg off (3.9 deg on fig6b). Every scenario of
    the three presets: benchmarks/bench_fixed_accuracy.py (a full scenario costs seconds per step).
    The scenario's first 3 s of 6 (the load step at 1 s): the difference has settled by 2 s (0.078-
    0.081 deg over the last 20 % of 3 s, 0.086 deg over those of 6 s)."""
    import dataclasses

    d, _setup, model = piippo_codegen
    sc = dataclasses.replace(load_scenario("fig6c", d), duration=3.0)
    _ref, fix, e = against_double(d, sc, model)
    steady = fix.t > 0.8 * fix.t[-1]
    assert np.abs(e[steady]).max() <= 0.2, np.abs(e[steady]).max()


def test_the_adaptive_observers_fixed_c_keeps_its_promises_under_hostile_samples_and_recovers(
    piippo_codegen, tmp_path
):
    """The fixed-point counterpart of tests/ipmsm_adaptive/test_codegen_fuzz.py (the float and double
    C): piippo2008's C as `codegen --precision fixed` generates it, fuzzed by tests/helpers/fuzz_fixed.py
    (any int32 words, garbage within 3x the clean words, the extreme words, one channel extreme; under
    -fsanitize=address,undefined) between 12 clean steady-state segments of the motor (0.3-1 p.u. both
    ways, -T_N..T_N; the float fuzz's seed), the injection on (the drive's default) and off: every step
    keeps the header's promises, and every clean segment is back within the float fuzz's RECOVER = 1000
    samples (angle 0.1 rad, speed 5 % of base), x_eps held as there with the injection on. (With
    formats from the segments' runs alone, one segment's recovery transient left those ranges and was
    clamped, and the step locked on the wrong speed sign where the double step recovered: the formats
    must come from runs that contain transients, as codegen's do.)"""
    from helpers.fuzz_fixed import fixed_fuzz

    d, setup, model = piippo_codegen
    m = d.motor
    rows = steady_rows(np.random.default_rng(20080201), 40, (0.3, 1.0), d.base.w, d.T_N)[:12]
    seg = pmsm_steady_segments((m.R_s, m.L_d, m.L_q, m.psi_pm, m.p), d.T_s, rows, 2000)
    compile_replay(d, setup, model, tmp_path)
    r = fixed_fuzz(
        d,
        setup,
        model.program(setup),
        tmp_path,
        seg,
        recover=1000,
        tol_theta=0.1,
        tol_w=0.05 * d.base.w,
        seed=5,
        held={"x_eps": 10.0},
    )
    assert r["rejected"] > 0 and r["resets"] > 0 and r["held_segments"] <= 0.3 * r["segments"], r
    # the injection off at run time (a parameter: its fields in the struct, params_from_si): every
    # segment recovers, as the float fuzz without the injection requires
    off = params_from_si(setup, model.program(setup), {"injection": 0.0})
    r = fixed_fuzz(d, setup, model.program(setup), tmp_path, seg, recover=1000, tol_theta=0.1,
                   tol_w=0.05 * d.base.w, seed=6, params=off)  # fmt: skip
    assert r["rejected"] > 0 and r["held_segments"] == 0, r


def test_a_long_burst_resets_the_step_as_the_double_step_does(built):
    """More rejected samples in a row than the guard allows: the fixed-point step resets itself on the
    same sample as the double step (its counter counts: a format from runs that never reject would
    not), and the C equals the model through it."""
    _d, setup, model, fx, out, exe = built
    x0_si, meas = model.data(setup)[0][:, 1000], model.data(setup)[1][:, 1000:1300].copy()
    meas[:, 40:200] *= 50.0  # implausible: every one rejected
    raw = fx.to_raw(meas, "meas").T
    x0 = fx.to_raw(x0_si, "x")
    c = replay(exe, out, raw, x0)
    _, ys = model_equals_c(fx, c, raw, x0)
    names = [o["name"] for o in fx.outputs]
    _, ys_d = run_trajectory(setup, meas.T, x0_si)
    fixed_resets = np.nonzero(ys[:, names.index("reset")])[0]
    double_resets = np.nonzero(ys_d[:, names.index("reset")])[0]
    assert len(double_resets) > 0 and np.array_equal(fixed_resets, double_resets)


def test_a_pll_speed_at_its_bound_is_clamped_in_fixed_point_as_in_double(built):
    """The flux family clamps its PLL speed at the bound (symbolic/pmsm_flux_observer/observer.py): from
    the run's state with the speed at its bound and the PLL angle 2 rad behind, the C equals the model,
    every sample is used (the clamped word passes the guard's exact comparison with the same bound),
    the speed word is held at the bound (within 1 LSB) where the double step's is, and the estimates
    are back with the double step's within 200 periods (0.1 rad, 2 % of the base speed)."""
    d, setup, model, fx, out, exe = built
    obs = setup.observer
    j_th, j_w = obs.index("state", "theta_pll"), obs.index("state", "w_pll")
    b, T = float(np.asarray(obs.bounds()(setup.p)).ravel()[j_w]), setup.params["T_s"]
    x0_si, meas = model.data(setup)[0][:, 1000].copy(), model.data(setup)[1][:, 1000:1300]
    s = 1.0 if x0_si[j_w] >= 0 else -1.0
    x0_si[j_th] = (x0_si[j_th] - s * 2.0 - T * (s * b - x0_si[j_w]) + np.pi) % (2 * np.pi) - np.pi
    x0_si[j_w] = s * b
    raw, x0 = fx.to_raw(meas, "meas").T, fx.to_raw(x0_si, "x")
    c = replay(exe, out, raw, x0)
    xs, ys = model_equals_c(fx, c, raw, x0)
    names = [o["name"] for o in fx.outputs]
    xs_d, ys_d = run_trajectory(setup, meas.T, x0_si)
    assert ys[:, names.index("valid")].all() and ys_d[:, names.index("valid")].all()
    at_d = np.abs(xs_d[:, j_w]) == b
    held = np.abs(xs[:, j_w])  # the bound as the program stores it: within 1 LSB of the state's word
    assert at_d.sum() >= 1 and np.array_equal(held == held.max(), at_d) and abs(held.max() - s * x0[j_w]) <= 1
    th = c[:, names.index("theta_hat")] * np.pi / 2**31
    w = c[:, names.index("w_hat")] * 2.0 ** -fx.outputs[names.index("w_hat")]["f"]
    late = slice(200, None)
    assert np.abs(np.angle(np.exp(1j * (th[late] - ys_d[late, names.index("theta_hat")])))).max() < 0.1
    assert np.abs(w[late] - ys_d[late, names.index("w_hat")]).max() < 0.02 * d.w_base


def test_a_tuned_gain_table_is_lowered_with_its_values_in_the_parameter_struct(built, tmp_path):
    """`codegen --precision fixed --gains TABLE` (the flux family's `schedule`: k_0 piecewise linear
    over |w_pll| on the table's speeds, held beyond them): the table's values are fields of the
    parameter struct (each proven for 0..2x, as every gain), the C equals the model bit for bit, the
    gain in effect (output k_obs) is the table interpolated at the stored PLL speed (numpy's interp)
    within 0.1 %, and the values doubled at run time double it. The formats come from the drive's own
    runs (the lowering, not the ranges, is under test here)."""
    import json

    from sensorless.design.gain_table import read_gain_table
    from sensorless.reports.codegen.fixed_model import FixedModel

    d, _setup, model, _fx, _out, _exe = built
    grid, vals = [100.0, 1500.0, 3050.0, 3800.0], [400.0, 600.0, 1000.0, 1500.0]
    doc = {
        "format": "sensorless-gain-table/2",
        "drive": {"name": d.name, "kind": d.kind, "sha256": d.digest},
        "law": "schedule",
        "gains": {"speeds": grid, "observer_gain": vals, "pll_bandwidth": 1000.0},
        "envelope": {},
        "points": [],
        "summary": {},
    }
    (tmp_path / "table.json").write_text(json.dumps(doc))
    fam = family_of(d)
    gains = fam.gains(d, table=read_gain_table(tmp_path / "table.json"), table_file="table.json")
    setup = fam.runtime(d, gains)
    tm = FixedModel(model.runs)
    fx = tm.program(setup)
    assert [p["name"] for p in fx.params if p["name"].startswith("k_0_")] == [f"k_0_{j}" for j in range(4)]
    exe = compile_replay(d, setup, tm, tmp_path)
    # one table lookup (bisection in C), not the law's hat per breakpoint
    assert [i.op for i in fx.prog].count("TABLE") == 1 and "fx_table(" in (
        tmp_path / f"{d.name}.c"
    ).read_text()
    x0, meas = fx.to_raw(model.data(setup)[0][:, 1000], "x"), model.data(setup)[1][:, 1000:1300]
    raw = fx.to_raw(meas, "meas").T
    c = replay(exe, tmp_path, raw, x0)
    xs, ys = model_equals_c(fx, c, raw, x0)
    names = [o["name"] for o in fx.outputs]
    j_w = setup.observer.index("state", "w_pll")
    w_prev = np.r_[x0[j_w], xs[:-1, j_w]] * 2.0 ** -fx.inputs[j_w]["f"]
    k_obs = ys[:, names.index("k_obs")] * 2.0 ** -fx.outputs[names.index("k_obs")]["f"]
    assert np.abs(w_prev).min() < grid[2] < np.abs(w_prev).max()  # the samples cross a breakpoint
    assert np.allclose(k_obs, np.interp(np.abs(w_prev), grid, vals), rtol=1e-3)
    prm = [p["raw"] for p in fx.params]
    for j, p in enumerate(fx.params):
        if p["name"].startswith("k_0_"):
            prm[j] *= 2
    k2 = replay(exe, tmp_path, raw, x0, prm)[:, names.index("k_obs")]
    assert abs(int(k2[0]) - 2 * int(c[0, names.index("k_obs")])) <= 2  # the same first sample: doubled


def test_gains_are_read_from_the_parameter_struct_at_run_time(built):
    """The gains and motor constants are fields of <prefix>_params (Q formats in the header): the PLL's
    gain doubled at run time changes the step, the C equals the model with that struct; init names a
    field beyond twice the drive's value (the range the formats are proven for) and refuses it."""
    _d, setup, model, fx, out, exe = built
    names = [p["name"] for p in fx.params]
    header = (out / f"{_d.name}.h").read_text()
    assert all(f"int32_t {n}; /* " in header for n in names)
    j = next(k for k, p in enumerate(fx.params) if p["expr"] == "T_s * k_p")
    x0, meas = fx.to_raw(model.data(setup)[0][:, 1000], "x"), model.data(setup)[1][:, 1000:1200]
    raw = fx.to_raw(meas, "meas").T
    prm = [p["raw"] for p in fx.params]
    prm[j] *= 2
    c = replay(exe, out, raw, x0, prm)
    model_equals_c(fx, c, raw, x0, prm)
    assert int((c != replay(exe, out, raw, x0)).sum()) > 0  # the gain took effect
    prm[j] = 3 * fx.params[j]["raw"]
    err = replay(exe, out, raw, x0, prm, code=2)
    assert f"field {j + 1} out of its range" in err


def test_params_from_si_fills_the_struct_from_si_values(built):
    """The host-side helper (the generator's defaults come through it): at the drive's values it gives
    the generated defaults; with psi_pm x 1.1 and k_p x 1.5 each field equals its expression typed
    here from the SI values (the flux family's fields), the C runs that struct equal to the model; a
    field beyond its proven range is refused."""
    _d, setup, model, fx, out, exe = built
    assert params_from_si(setup, fx) == [p["raw"] for p in fx.params]
    names = [f.name for f in setup.observer.params]
    si = dict(zip(names, (float(v) for v in np.ravel(setup.p)), strict=True))
    new = {"psi_pm": 1.1 * si["psi_pm"], "k_p": 1.5 * si["k_p"]}
    prm = params_from_si(setup, fx, new)
    v = {**si, **new}
    typed = {  # the field's expression (the header's comment), typed from the parameters
        "T_s * k_p": v["T_s"] * v["k_p"],
        "6 * psi_pm": 6 * v["psi_pm"],
        "2.5 * psi_pm": 2.5 * v["psi_pm"],
        "psi_pm": v["psi_pm"],
        "T_s * 1/psi_pm^2": v["T_s"] / v["psi_pm"] ** 2,
        "T_s * k_i * pi / 2^31": v["T_s"] * v["k_i"] * np.pi / 2**31,  # per LSB of the binary angle
    }
    seen = 0
    for d, raw in zip(fx.params, prm, strict=True):
        if d["expr"] in typed:
            assert raw == np.floor(typed[d["expr"]] * 2.0 ** d["f"] + 0.5), d["expr"]
            seen += 1
    assert seen == len(typed)
    x0, meas = fx.to_raw(model.data(setup)[0][:, 1000], "x"), model.data(setup)[1][:, 1000:1100]
    raw = fx.to_raw(meas, "meas").T
    c = replay(exe, out, raw, x0, prm)
    model_equals_c(fx, c, raw, x0, prm)
    # one rounding (fixed_format.word: half up, as the samples and the initial state are rounded) for
    # the generated defaults and the host's words: a value on a tie goes up to the odd word, where
    # Python's round() goes to the even one
    j = next(k for k, d in enumerate(fx.params) if d["expr"] == "psi_pm")
    f, k = fx.params[j]["f"], fx.params[j]["raw"] // 2 * 2
    assert params_from_si(setup, fx, {"psi_pm": (k + 0.5) * 2.0**-f})[j] == k + 1
    with pytest.raises(ValueError, match=r"psi_pm.*regenerate"):
        params_from_si(setup, fx, {"psi_pm": 3 * si["psi_pm"]})
    with pytest.raises(ValueError, match="unknown parameter"):
        params_from_si(setup, fx, {"psi": 1.0})


def test_fuzz_the_fixed_c_under_sanitizers(built):
    """The fuzz of tests/helpers/fuzz_fixed.py for the fixed-point C (the counterpart of
    tests/pmsm_flux_observer/test_codegen.py's float and double fuzz): hostile bursts (any int32 words,
    plausible-looking garbage within 3x the clean samples' words, the extreme words, one channel
    extreme) between clean steady-state segments of the motor, ~8 10^4 steps through the replayer built
    with -fsanitize=address,undefined (a signed overflow, which the worst-case analysis rules out,
    would end it); every step keeps the header's promises (valid and reset 0 or 1, the bounded state
    within its bounds) and every clean segment recovers within the flux family's documented 200
    periods (0.1 rad, 2 % of the base speed), as the float C does."""
    from helpers.fuzz_fixed import fixed_fuzz

    d, setup, _model, fx, out, _exe = built
    m = d.motor
    rows = steady_rows(np.random.default_rng(11), 120, (0.3, 1.0), d.w_base, d.T_N)
    seg = pmsm_steady_segments((m.R_s, m.L_d, m.L_q, m.psi_pm, m.p), d.T_s, rows, 200 + 300)
    r = fixed_fuzz(d, setup, fx, out, seg, recover=200, tol_theta=0.1, tol_w=0.02 * d.w_base, seed=11)
    # the bursts were rejected, and the long ones reset the step
    assert r["steps"] > 60_000 and r["rejected"] > 5000 and r["resets"] > 0, r


def test_report_judges_the_fixed_step_and_reruns_the_poles_with_stored_constants(built):
    """`report --precision fixed`'s parts (reports/fixed_review.py): the time-domain checks run the
    step given to ``judged_with`` (and only they: the analyses that set a run up keep the double
    step); the whole drive's slow poles re-run with the stored constants move, but little."""
    import dataclasses

    from sensorless.reports import time_domain
    from sensorless.reports.fixed_review import _drive_poles, judged_with

    d, _setup, model, *_ = built
    ran = []

    def spy(setup, step):
        ran.append(setup.observer.name)
        return model.variant(setup, step)

    sc = dataclasses.replace(load_scenario("torque_steps", d), duration=0.05)
    with judged_with(spy), figures_off():  # the checks' data (tests/helpers/figures_off.py)
        td, _ = time_domain.checks(d, None, [sc], "drive file", lambda m: None)
    assert ran and td[0]["name"] == "torque_steps"
    ran.clear()
    with figures_off():
        time_domain.checks(d, None, [sc], "drive file", lambda m: None)
    assert not ran  # outside the block the checks run the double step
    poles = _drive_poles(d, family_of(d).gains(d), model, quick=True)
    assert poles["points"] > 0 and 0 < poles["max_relative_pole_shift"] < 0.01
    assert abs(poles["worst_damping_stored"] - poles["worst_damping_double"]) < 1e-3


def test_the_i_f_start_in_fixed_point(tmp_path):
    """The I-f start (symbolic/startup.py) lowered: asin as the CORDIC atan2 of (v, sqrt(1 - v^2)),
    sign as two comparisons; thresholds a ramp reaches by its own rounding are reached (the handover at
    w_on). outrunner270's start (0.12 s, the handover at ~0.05 s): the C equals the model bit for bit
    on its samples with a hostile burst, and in closed loop the angle error ends within 0.2 deg of the
    double step's, the handover within 10 periods of its."""
    import dataclasses

    from sensorless.design.pmsm_drive import startup_setup
    from sensorless.reports.codegen.fixed_model import FixedModel

    d = load_drive("outrunner270")
    fam = family_of(d)
    setup, _ = startup_setup(d, fam.runtime(d, fam.gains(d)))
    sc = dataclasses.replace(load_scenario("start", d), duration=0.12)
    model = FixedModel.of(d, None, [sc], compile=False)
    fx = model.program(setup)
    exe = compile_replay(d, setup, model, tmp_path)
    x, meas = model.data(setup)
    glitched_replay(exe, tmp_path, fx, x, meas, 100, 900, slice(300, 330), 9)
    ref, fix, e = against_double(d, sc, model)
    assert np.abs(e[-100:]).max() <= 0.2, np.abs(e[-100:]).max()
    hand = [int(np.flatnonzero(np.diff(tr["startup_mode"]) < 0)[0]) for tr in (ref, fix)]
    assert abs(hand[0] - hand[1]) <= 10, hand  # the handover within 10 periods of the double step's


def test_the_vesc_variant_equals_its_model_and_stays_within_0p2_deg(tmp_path):
    """hubmotor48 (the flux family's VESC variant: interpolated inductance, clamped gradient): the C
    equals the model with a hostile burst, and in closed loop (torque_steps' first 0.2 s, with the
    formats `codegen` generates) its angle error stays within 0.2 deg of the double step's at steady
    state. Its inductance share i_q^2 / |i|^2 is a division by a divisor near zero at no current: a
    quotient format that held that worst case kept two bits of the share and left the step 0.35 deg
    off under load; its products reaching only that division or the gain's square root are short
    (fixed_program.coarse_nodes), the gain's root 12 bits."""
    import dataclasses

    d = load_drive("hubmotor48")
    fam = family_of(d)
    setup = fam.runtime(d, fam.gains(d))
    sc = dataclasses.replace(load_scenario("torque_steps", d), duration=0.2)  # loaded from 0.06 s
    model = codegen_model(d)
    fx = model.program(setup)
    exe = compile_replay(d, setup, model, tmp_path)
    x, meas = model.data(setup)
    glitched_replay(exe, tmp_path, fx, x, meas, 1000, 1400, slice(150, 210), 7)
    _ref, fix, e = against_double(d, sc, model)
    steady = fix.t > 0.8 * fix.t[-1]
    assert np.abs(e[steady]).max() <= 0.2, np.abs(e[steady]).max()
    assert not fix.problems()


def test_a_gain_table_lookup_is_the_linear_interpolation():
    """fixed_ops.table_lerp (op TABLE; the C bisects): on random words over and beyond a
    non-uniform grid, both signs (the flux family's table is over |w_pll|), within 2^-13 of the
    segment's values' difference (the Q15 fraction) + 2 LSB of numpy's interpolation; the ends held."""
    rng = np.random.default_rng(1)
    G = [3000, 40000, 41000, 900000, 2**26]
    V = [2**20, 3 * 2**20, 5, -(2**24), 2**25]
    R, S = [], []
    for h in np.diff(G).tolist():  # as fixed_lowering.table does
        s = int(np.floor(np.log2(h)))
        s -= round(2.0 ** (15 + s) / h) >= 2**15
        R.append(round(2.0 ** (15 + s) / h))
        S.append(s)
    u = np.r_[rng.integers(-(2**27), 2**27, 4000), G, [-g for g in G], 0]
    imm = (1, len(G), *G, *R, *S)
    got = fixed_ops.table_lerp(fixed_ops.NUMPY, u, [np.full_like(u, v) for v in V], imm)
    want = np.interp(np.abs(u), G, V)
    k = np.clip(np.searchsorted(G, np.abs(u), side="right") - 1, 0, len(G) - 2)
    tol = np.abs(np.diff(V))[k] * 2.0**-13 + 2
    assert np.all(np.abs(got - want) <= tol)
    assert np.all(got[np.abs(u) >= G[-1]] == V[-1]) and np.all(got[np.abs(u) <= G[0]] == V[0])


def test_the_interpolated_share_needs_no_angle():
    """symbolic/pmsm_flux_observer/observer.py `inductance` writes VESC's i_q^2/|i|^2 as (a x i)^2 /
    (|a|^2 (|i|^2 + eps)) (no atan2, cos or sin for the fixed-point step): against the form typed here
    with the angle, i_q = -sin(theta) i_alpha + cos(theta) i_beta, theta = atan2(a), on random frames
    and currents over six decades, within double rounding; a zero frame gives a finite inductance."""
    import casadi as ca
    from sensorless.symbolic.pmsm_flux_observer import observer as ob

    rng = np.random.default_rng(3)
    n = 2000
    a = rng.normal(size=(2, n)) * 10.0 ** rng.uniform(-4, 0, n)
    i = rng.normal(size=(2, n)) * 10.0 ** rng.uniform(-3, 3, n)
    L_d, L_q = 1.3e-4, 2.1e-4
    p = ob.Params(*([1.0, L_d, L_q] + [1.0] * (len(ob.PARAMS) - 3)))
    fr, cur = ca.SX.sym("a", 2), ca.SX.sym("i", 2)
    f = ca.Function("L", [fr, cur], [ob.inductance("interpolated", cur, fr, p)]).map(n)
    got = np.asarray(f(a, i)).ravel()
    th = np.arctan2(a[1], a[0])
    i_q = -np.sin(th) * i[0] + np.cos(th) * i[1]
    want = L_d + (L_q - L_d) * i_q**2 / (i[0] ** 2 + i[1] ** 2 + ob.CURRENT_EPS)
    assert np.abs(got - want).max() <= 1e-15 * L_q
    zero = float(
        ca.Function("L0", [cur], [ob.inductance("interpolated", cur, ca.DM.zeros(2), p)])([1.0, 2.0])
    )
    assert zero == L_d


def test_the_whole_drive_poles_are_rerun_where_the_analysed_loop_runs_another_observer():
    """deangelo2006's whole-drive analysis linearizes the drive without its EMF harmonics (the
    family's AnalysedLoop), an observer no check runs, so report.json's ``fixed_point.drive_poles``
    was ``not_analysed``. ``probe_runs(analysed=True)`` runs that loop on the scenarios (0.3 s of fig2
    here, through CasADi's VM), and with those ranges the slow poles are re-run with the stored
    constants: finite, on every point the double sweep has, the worst damping within 1e-3; that
    observer's own poles move by the Q15 rounding's order (< 1e-4 in the z plane, as the simulated
    observer's)."""
    import dataclasses

    from sensorless.design.drive_analysis import drive_loop
    from sensorless.design.runtime import step_variant
    from sensorless.reports.codegen.fixed_model import FixedModel
    from sensorless.reports.codegen.fixed_poles import pole_shift
    from sensorless.reports.codegen.fixed_ranges import probe_runs
    from sensorless.reports.fixed_review import _drive_poles

    d = load_drive("deangelo2006")
    fam = family_of(d)
    gains = fam.gains(d)
    sc = [dataclasses.replace(load_scenario("fig2", d), duration=0.3)]
    runs = probe_runs(d, gains, sc, compile=False)
    analysed = probe_runs(d, gains, sc, compile=False, analysed=True)
    assert set(analysed) and not set(analysed) & set(runs)  # another observer
    model = FixedModel({**analysed, **runs})
    poles = _drive_poles(d, gains, model, quick=True)
    assert poles["points"] > 0 and np.isfinite(poles["max_pole_shift_per_s"])
    assert abs(poles["worst_damping_stored"] - poles["worst_damping_double"]) < 1e-3
    seen = []

    def spy(setup, step):
        seen.append(setup)
        return step

    with step_variant(spy):
        drive_loop(d, gains)
    setup = next(s for s in seen if s.observer.name in analysed)
    assert pole_shift(setup, model.program(setup), *model.data(setup))["max_pole_shift"] < 1e-4
