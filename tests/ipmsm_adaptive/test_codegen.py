"""`sensorless codegen`: the generated C against the Python evaluation of the same CasADi step on a
simulated trajectory; strict compilers, sanitizers, genuine float, Cortex-M4F symbols, determinism."""

import json
import math
import os
import re
import shutil
import subprocess

import numpy as np
import pytest
from helpers.fuzz import SANITIZE_O0
from helpers.hash_seed import here_and_fresh
from helpers.runtime_loop import TRAJECTORY_SEGMENTS, profile_from_segments, simulate
from sensorless.design.gain_table import GainTable, read_gain_table
from sensorless.design.ipmsm_adaptive import FAMILY
from sensorless.design.runtime import run_trajectory
from sensorless.reports.cli.main import main
from sensorless.symbolic.ipmsm_adaptive.gains import LAWS, schedule_law
from sensorless.symbolic.ipmsm_adaptive.step import OUTPUTS, STATE

CC = shutil.which("gcc") or shutil.which("cc")
ARM = shutil.which("arm-none-eabi-gcc")
STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]
ARM_FLAGS = ["-mthumb", "-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"]
Y = {f.name: k for k, f in enumerate(OUTPUTS)}
N_Y, N_X = len(OUTPUTS), len(STATE)
ANGLES = [Y["theta_hat"], N_Y + STATE.index(next(f for f in STATE if f.name == "theta")), N_Y + 5]

pytestmark = pytest.mark.skipif(CC is None, reason="no host C compiler (gcc/cc) on PATH")


# ------------------------------------------------------------------------------------------ helpers
def runtime_setup(drive, *, gain=None, table=None, table_file="", discretization=None):
    """The runtime set-up the command builds, through the family contract."""
    gains = FAMILY.gains(drive, name=gain, table=table, table_file=table_file)
    return FAMILY.runtime(drive, gains, discretization=discretization)


def codegen(out, *args):
    assert main(["codegen", "piippo2008", "--out", str(out), *map(str, args)]) == 0
    return out


def build(src, exe, extra=(), files=("main.c", "piippo2008.c")):
    cmd = [CC, *STRICT, *extra, "-o", str(exe), *[str(src / f) for f in files], "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    return exe


def replay(exe, meas, tmp_path):
    f = tmp_path / "samples.bin"
    np.ascontiguousarray(meas, dtype="<f8").tofile(f)
    r = subprocess.run([str(exe), str(f)], capture_output=True)
    assert r.returncode == 0 and r.stderr == b"", r.stderr.decode()
    return np.frombuffer(r.stdout, "<f8").reshape(len(meas), N_Y + N_X)


def python_reference(setup, meas):
    xs, ys = run_trajectory(setup, meas)
    return np.hstack([ys, xs])


def deviation(c, ref):
    """|C - Python| per column, angles compared modulo 2 pi."""
    d = np.abs(c - ref)
    for j in ANGLES:
        d[:, j] = np.abs(np.angle(np.exp(1j * (c[:, j] - ref[:, j]))))
    return d


@pytest.fixture(scope="module")
def trajectory(drive):
    """>= 10^4 samples of the simulated motor (helpers/runtime_loop.py) driving the observer: standstill
    with injection and an initial angle error, ramps through w_Delta and zero, +-0.8 p.u., low speed."""
    prof = profile_from_segments(TRAJECTORY_SEGMENTS, drive.control.T_s, drive.base.w, drive.T_N)
    r = simulate(runtime_setup(drive), drive, prof, theta0=0.2)
    assert len(r["meas"]) >= 10_000
    return r["meas"]


@pytest.fixture(scope="module")
def schedule_table(tmp_path_factory, drive):
    """A free schedule (docs/gain_tables.md) as `sensorless tune` writes it: 17 breakpoints over
    +-2 p.u., law (16) bent by a smooth perturbation so that it is not the law itself."""
    w = np.linspace(-2, 2, 17) * drive.base.w
    lp, wl = 2 * drive.estimate.R_s, drive.base.w
    l1 = lp * np.minimum(np.abs(w) / wl, 1) + 0.3 * np.cos(w / wl)
    l2 = lp * np.clip(w / wl, -1, 1) - 0.2 * np.sin(w / wl)
    t = GainTable(
        law="schedule",
        drive={"name": drive.name, "kind": drive.kind, "sha256": drive.digest},
        gains={"w_hat": w, "lambda1": l1, "lambda2": l2, "alpha_fo": 2 * math.pi * 40},
    )
    path = tmp_path_factory.mktemp("tables") / "schedule.json"
    path.write_text(t.to_json())
    return path


# -------------------------------------------------------------------------------- C == Python
@pytest.mark.parametrize(
    "disc,gains",
    [
        ("zoh", None),
        ("heun", None),
        ("euler", None),
        ("heun-model", None),
        ("zoh", "schedule"),
        ("zoh", "constant"),
        ("euler", "constant"),
    ],
)
def test_double_matches_python_on_the_trajectory(drive, trajectory, schedule_table, tmp_path, disc, gains):
    """Every output and state of every sample to 1e-12 of that signal's largest magnitude (angles
    modulo 2 pi). The generated code differs from CasADi's evaluation only by hoisted reciprocals
    (x * (1/L) for x / L) and by the table lookup's interpolation formula."""
    args = ["--precision", "double", "--discretization", disc]
    if gains == "schedule":
        args += ["--gains", schedule_table]
        setup = runtime_setup(drive, table=read_gain_table(schedule_table), discretization=disc)
    elif gains == "constant":
        args += ["--gain-set", "constant"]
        setup = runtime_setup(drive, gain="constant", discretization=disc)
    else:
        setup = runtime_setup(drive, discretization=disc)
    src = codegen(tmp_path / "c", *args)
    c = replay(build(src, tmp_path / "ex"), trajectory, tmp_path)
    ref = python_reference(setup, trajectory)
    scale = np.maximum(np.abs(ref).max(axis=0), 1e-300)
    rel = deviation(c, ref).max(axis=0) / scale
    assert rel.max() < 1e-12, dict(zip([f.name for f in OUTPUTS] + [f.name for f in STATE], rel, strict=True))
    assert np.all(ref[:, Y["valid"]] == 1) and np.ptp(ref[:, Y["w_hat"]]) > drive.base.w  # a real run


def test_float_matches_python_within_float_resolution(drive, trajectory, tmp_path):
    """Float build vs the double Python evaluation. Tolerances from float's resolution:
    - the observer's signals (speed, angle, flux, integrals, gains) pass through a contracting
      observer, so rounding (eps_f = 6e-8) does not accumulate beyond a few hundred eps_f: 1e-4 of
      each signal's scale (observed ~1e-6);
    - the carrier phase is a sum of N rounded increments; its drift is bounded by N ulp(pi)/2
      = 1.4e-3 rad after 12000 samples, and the HF chain (carrier, band-pass, eps) scales with it:
      2e-3 relative (observed ~1e-4). Both are far below anything that matters to a drive."""
    setup = runtime_setup(drive)
    src = codegen(tmp_path / "c", "--precision", "float")
    c = replay(build(src, tmp_path / "ex"), trajectory, tmp_path)
    ref = python_reference(setup, trajectory)
    scale = np.maximum(np.abs(ref).max(axis=0), 1e-300)
    rel = deviation(c, ref).max(axis=0) / scale
    names = [f.name for f in OUTPUTS] + [f"x.{f.name}" for f in STATE]
    hf = {"u_c_d", "eps", "x.phi_c", "x.bp_z1", "x.bp_z2", "x.lp_z1", "x.lp_z2"}
    tol = np.array([2e-3 if n in hf else 1e-4 for n in names])
    assert np.all(rel <= tol), {n: f"{r:.2e}" for n, r in zip(names, rel, strict=True) if r > 1e-6}
    assert np.array_equal(c[:, Y["valid"]], ref[:, Y["valid"]])


# ---------------------------------------------------------------------- robustness, sanitizers
HARNESS = r"""
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "piippo2008.h"
#define CHECK(c) do { if (!(c)) { printf("FAIL line %d: %s\n", __LINE__, #c); return 1; } } while (0)
typedef piippo2008_real real;
int main(void)
{
    piippo2008_observer a, b, fresh;
    piippo2008_params p = piippo2008_default_params;
    piippo2008_input in;
    piippo2008_output out;
    /* NaN, Inf, the largest finite values of the precision, absurd and subnormal magnitudes */
    const real big = (real)(sizeof(real) == sizeof(float) ? 3.0e38 : 1.0e300);
    const real bad[] = {NAN, INFINITY, -INFINITY, big, -big, (real)1e30, (real)1e-40, 0};
    const int nb = (int)(sizeof bad / sizeof bad[0]);
    real l1, l2, w;
    int k, j, rc;
    memset(&in, 0, sizeof in);
    CHECK(piippo2008_init(&a, &p) == 0);
    CHECK(piippo2008_init(&fresh, &p) == 0);
    /* every parameter field: NaN and a non-physical value are refused with its 1-based index */
    for (j = 0; j < (int)(sizeof p / sizeof(real)); ++j) {
        p = piippo2008_default_params;
        ((real *)&p)[j] = NAN;
        rc = piippo2008_init(&b, &p);
        CHECK(rc == j + 1);
    }
    p = piippo2008_default_params;
    p.L_d = (real)-0.036;
    CHECK(piippo2008_init(&b, &p) == 2);
    p = piippo2008_default_params;
    p.injection = (real)0.5;
    CHECK(piippo2008_init(&b, &p) == 7);
    p = piippo2008_default_params; /* non-salient motor: injection impossible, without it fine */
    p.L_q = p.L_d;
    CHECK(piippo2008_init(&b, &p) == -1);
    p.injection = 0;
    CHECK(piippo2008_init(&b, &p) == 0);
    /* hostile samples: no UB (sanitizers), state stays finite, valid = 0 */
    CHECK(piippo2008_init(&a, &piippo2008_default_params) == 0);
    CHECK(piippo2008_init(&b, &piippo2008_default_params) == 0);
    for (k = 0; k < nb * 4 * 5; ++k) { /* every value on every channel, repeatedly */
        real v = bad[k % nb];
        in.i_alpha = (k / nb) % 4 == 0 ? v : (real)1;
        in.i_beta = (k / nb) % 4 == 1 ? v : (real)-2;
        in.u_alpha = (k / nb) % 4 == 2 ? v : (real)30;
        in.u_beta = (k / nb) % 4 == 3 ? v : (real)5;
        piippo2008_step(&a, &in, &out);
        for (j = 0; j < PIIPPO2008_N_STATE; ++j) CHECK(isfinite(((real *)&a.x)[j]));
        for (j = 0; j < PIIPPO2008_N_OUTPUT; ++j) CHECK(isfinite(((real *)&out)[j]));
        if (!isfinite(v)) CHECK(out.valid == 0);
    }
    /* instances are independent: b never stepped, still equals a fresh instance */
    CHECK(memcmp(&b, &fresh, sizeof b) == 0);
    /* the gain schedule is total (NaN and Inf give finite gains) */
    for (k = 0; k < nb; ++k) {
        piippo2008_gains(&a, bad[k], &l1, &l2);
        CHECK(isfinite(l1) && isfinite(l2));
    }
    /* init recovers the exact initial state */
    CHECK(piippo2008_init(&a, &piippo2008_default_params) == 0);
    CHECK(memcmp(&a, &fresh, sizeof a) == 0);
    /* print the gain law on a sweep for the Python cross-check */
    for (k = 0; k <= 400; ++k) {
        w = (real)(-1200 + 6 * k);
        piippo2008_gains(&a, w, &l1, &l2);
        printf("%.17g %.17g %.17g\n", (double)w, (double)l1, (double)l2);
    }
    return 0;
}
"""


@pytest.mark.parametrize("precision", ["double", "float"])
@pytest.mark.parametrize("gains", ["speed-dependent", "schedule"])
def test_sanitized_hostile_inputs_params_instances_and_gains(tmp_path, schedule_table, precision, gains):
    """Under -fsanitize=address,undefined (all checks fatal): NaN/Inf/huge/subnormal samples leave a
    finite state (valid = 0), invalid parameters are refused naming the field, two instances share
    nothing, *_init restores the exact initial state; the C gain schedule equals the Python law."""
    args = ["--precision", precision] + (["--gains", schedule_table] if gains == "schedule" else [])
    src = codegen(tmp_path / "c", *args)
    (src / "harness.c").write_text(HARNESS)
    exe = build(src, tmp_path / "h", SANITIZE_O0, files=("harness.c", "piippo2008.c"))
    r = subprocess.run([str(exe)], capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr == "", r.stdout[-2000:] + r.stderr[-2000:]
    w, l1, l2 = np.loadtxt(r.stdout.splitlines()).T
    if gains == "schedule":
        g = json.loads(schedule_table.read_text())["gains"]
        law, par = schedule_law(tuple(g["w_hat"])), [*g["lambda1"], *g["lambda2"]]
    else:
        law, par = LAWS["speed"], [7.18, 2 * math.pi * 75]
    import casadi as ca

    ws = ca.SX.sym("w")
    f = ca.Function("g", [ws], [ca.vertcat(*law.expr(ws, ca.DM(par)))])
    ref = np.asarray(f.map(w.size)(w.reshape(1, -1)))
    tol = 1e-13 if precision == "double" else 2e-6
    assert np.abs(np.vstack([l1, l2]) - ref).max() < tol * np.abs(ref).max()


# ------------------------------------------------------------------------ float, Cortex-M4F
def test_float_build_is_genuinely_single_precision(tmp_path):
    """No double literal, no double libm call in the float observer; the host compiler with
    -Wdouble-promotion -Wfloat-conversion agrees."""
    src = codegen(tmp_path / "c", "--precision", "float")
    text = (src / "piippo2008.c").read_text()
    body = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    literals = re.findall(r"(?<![\w.])(\d+\.\d*(?:e[-+]?\d+)?|\d+e[-+]?\d+)(f?)", body)
    assert literals and all(s == "f" for _, s in literals), [x for x in literals if not x[1]]
    calls = set(re.findall(r"\b([a-z]+)\(", body))
    libm = {"sin", "cos", "tan", "sqrt", "fabs", "ceil", "floor", "fmin", "fmax", "pow", "atan2", "exp"}
    assert not (calls & libm), calls & libm
    assert {"sinf", "cosf", "ceilf"} <= calls
    assert "double" not in body
    r = subprocess.run(
        [
            CC,
            *STRICT,
            "-Wdouble-promotion",
            "-Wfloat-conversion",
            "-c",
            "-o",
            os.devnull,
            str(src / "piippo2008.c"),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0 and r.stderr == "", r.stderr


def arm_object(src, tmp_path):
    if ARM is None:
        pytest.skip("arm-none-eabi-gcc not installed (Debian: gcc-arm-none-eabi libnewlib-dev)")
    obj = tmp_path / "m4.o"
    cmd = [ARM, *STRICT, *ARM_FLAGS, "-c", "-o", str(obj), str(src / "piippo2008.c")]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if "math.h: No such file" in r.stderr:
        pytest.skip("arm-none-eabi-gcc has no C library headers (Debian: libnewlib-dev)")
    assert r.returncode == 0 and r.stderr == "", r.stderr
    nm = subprocess.run(
        [ARM.replace("gcc", "nm"), "-u", str(obj)], capture_output=True, text=True, check=True
    )
    return {ln.split()[-1] for ln in nm.stdout.splitlines() if ln.strip()}


DOUBLE_LIBM = {"sin", "cos", "tan", "ceil", "floor", "fmin", "fmax", "sqrt", "fabs", "pow", "atan2", "exp"}


def test_cortex_m4f_float_object_has_no_double_arithmetic(tmp_path):
    """arm-none-eabi-gcc for the Cortex-M4F (single-precision FPU): the float step needs no
    double-precision runtime (__aeabi_d*) and no double libm; the double build, compiled the same
    way, does (so the check can fail)."""
    undef_f = arm_object(codegen(tmp_path / "f", "--precision", "float"), tmp_path)
    assert not any(s.startswith("__aeabi_d") for s in undef_f), undef_f
    assert not (undef_f & DOUBLE_LIBM), undef_f
    assert {"sinf", "cosf"} <= undef_f
    undef_d = arm_object(codegen(tmp_path / "d", "--precision", "double"), tmp_path)
    assert any(s.startswith("__aeabi_d") for s in undef_d) and {"sin", "cos"} <= undef_d


# ------------------------------------------------------------------------------- the command
def test_codegen_is_deterministic_across_processes(tmp_path):
    """Two runs (separate processes, different hash seeds) give byte-identical files: this process's
    run (its module caches warm from the tests before) and a fresh process's, with another hash seed."""
    outs = here_and_fresh(tmp_path, ["codegen", "piippo2008"])
    assert outs[0] == outs[1]
    assert sorted(outs[0]) == ["Makefile", "main.c", "piippo2008.c", "piippo2008.h"]
    assert b"casadi" not in outs[0]["piippo2008.c"] + outs[0]["piippo2008.h"]


def test_cli_errors_exit_2_and_write_nothing(tmp_path, capsys, schedule_table):
    out = tmp_path / "o"
    assert main(["codegen", "piippo2008", "--gains", str(tmp_path / "none.json"), "--out", str(out)]) == 2
    assert "none.json" in capsys.readouterr().err
    bad = tmp_path / "dean.json"
    doc = json.loads(schedule_table.read_text())
    bad.write_text(json.dumps({**doc, "law": "constant", "gains": {"g": 400, "Gamma": 1e4}}))
    assert main(["codegen", "piippo2008", "--gains", str(bad), "--out", str(out)]) == 2
    assert "dean.json: key 'law'" in capsys.readouterr().err
    assert main(["codegen", "piippo2008", "--gain-set", "nope", "--out", str(out)]) == 2
    assert main(["codegen", "piippo2008", "--prefix", "9x-y", "--out", str(out)]) == 2
    assert not out.exists()
    assert main(["codegen", "piippo2008", "--out", str(out)]) == 0
    before = {p: p.read_bytes() for p in out.iterdir()}
    assert main(["codegen", "piippo2008", "--precision", "double", "--out", str(out)]) == 2
    assert "output exists" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in out.iterdir()} == before
    assert main(["codegen", "piippo2008", "--precision", "double", "--out", str(out), "--force"]) == 0


def test_table_from_another_drive_is_named(tmp_path, capsys, schedule_table):
    doc = json.loads(schedule_table.read_text())
    other = tmp_path / "other.json"
    other.write_text(json.dumps({**doc, "drive": {**doc["drive"], "name": "elsewhere"}}))
    assert main(["codegen", "piippo2008", "--gains", str(other), "--out", str(tmp_path / "o")]) == 0
    assert "tuned for drive 'elsewhere'" in capsys.readouterr().err


def test_a_second_observer_is_a_registration(tmp_path):
    """The generator knows nothing of any family: a toy observer (a PLL on a measured unit vector,
    no gain schedule) described by its fields, step and initial state generates, compiles
    warning-free and matches its Python evaluation."""
    import casadi as ca
    from sensorless.design.family import GainSet
    from sensorless.design.runtime import RuntimeSetup
    from sensorless.reports.codegen.generate import Provenance, generate
    from sensorless.symbolic.frames import wrap_angle
    from sensorless.symbolic.runtime import REJECTS, RESET, VALID, Field, RuntimeObserver, guarded

    state = (Field("theta", "rad", "angle", bound="pi"), Field("w", "rad/s", "speed", bound="k_p"), REJECTS)
    params = (
        Field("k_p", "rad/s", "", "positive"),
        Field("k_i", "rad/s^2", "", "positive"),
        Field("T_s", "s", "", "positive"),
    )

    def core(disc: str) -> ca.Function:
        x, m, p, lam = ca.SX.sym("x", 3), ca.SX.sym("meas", 2), ca.SX.sym("p", 3), ca.SX.sym("lam", 0)
        eps = m[1] * ca.cos(x[0]) - m[0] * ca.sin(x[0])
        w = x[1] + p[2] * p[1] * eps
        cand = ca.vertcat(wrap_angle(x[0] + p[2] * (w + p[0] * eps)), w), ca.vertcat(x[0], w, eps)
        coast = ca.vertcat(wrap_angle(x[0] + p[2] * x[1]), x[1]), ca.vertcat(x[0], x[1], 0)
        x_next, y = guarded(x, p, state, params, cand=cand, coast=coast, reset=ca.DM.zeros(3))
        return ca.Function("pll", [x, m, p, lam], [x_next, y])

    def x0() -> ca.Function:
        p = ca.SX.sym("p", 3)
        return ca.Function("x0", [p], [ca.DM.zeros(3)])

    toy = RuntimeObserver(
        name="pll",
        title="toy phase-locked loop",
        state=state,
        meas=(Field("a", "1", "cos"), Field("b", "1", "sin")),
        params=params,
        outputs=(Field("theta", "rad", ""), Field("w", "rad/s", ""), Field("eps", "1", ""), VALID, RESET),
        lam=(),
        schedule_state=None,
        core=core,
        initial_state=x0,
    )
    values = {"k_p": 200.0, "k_i": 1e4, "T_s": 1e-4}
    setup = RuntimeSetup(toy, "euler", values, GainSet("none", {}, "none"))
    files = generate(setup, Provenance("toy", "-", "0" * 64, "test"), precision="double", prefix="pll")
    assert "pll_gains" not in files["pll.h"]
    src = tmp_path / "c"
    src.mkdir()
    for n, t in files.items():
        (src / n).write_text(t)
    exe = build(src, tmp_path / "ex", files=("main.c", "pll.c"))
    t = np.arange(3000) * 1e-4
    meas = np.column_stack([np.cos(50 * t + 1), np.sin(50 * t + 1)])
    f = tmp_path / "m.bin"
    meas.astype("<f8").tofile(f)
    out = subprocess.run([str(exe), str(f)], capture_output=True, check=True).stdout
    c = np.frombuffer(out, "<f8").reshape(len(t), 8)
    xs, ys = core("euler").mapaccum(len(t))(np.zeros(3), meas.T, toy.pack_params(values), ca.DM(0, len(t)))
    ref = np.hstack([np.asarray(ys).T, np.asarray(xs).T])
    assert np.abs(c - ref).max() < 1e-12 * np.abs(ref).max()
    assert abs(c[-1, 1] - 50) < 1e-3  # and it locked on


def test_speed_dependent_table_fills_the_parameter_struct(tmp_path, drive):
    """A tuned law-(16) table: its lambda', omega_lambda and alpha_fo become the default parameters;
    the law stays closed form in C."""
    t = GainTable(
        law="speed-dependent",
        drive={"name": drive.name, "kind": drive.kind, "sha256": drive.digest},
        gains={"lambda_p": 5.5, "w_lambda": 300.0, "alpha_fo": 250.0},
    )
    path = tmp_path / "law16.json"
    path.write_text(t.to_json())
    src = codegen(tmp_path / "c", "--gains", path, "--precision", "double")
    text = (src / "piippo2008.c").read_text()
    for line in (".lambda_p = 5.5,", ".w_lambda = 300.0,", ".alpha_fo = 250.0,"):
        assert line in text
    assert "speed-dependent table" in text and "_gain_w[" not in text
    build(src, tmp_path / "ex")
