"""`sensorless codegen deangelo2006`: the C of the reduced-order EMF and load-torque observer (De Angelo
et al. 2006) against the Python evaluation of the same CasADi step on a trajectory of the independent
plant (helpers/plant_pmac.py); gains and EMF series as runtime parameters; genuine float; strict
compilers, sanitizers, Cortex-M4F symbols, determinism; recovery from glitches."""

import dataclasses
import math
import os
import re
import shutil
import subprocess

import numpy as np
import pytest
from helpers.cbuild import build as cbuild
from helpers.fuzz import SANITIZE_O0
from helpers.hash_seed import here_and_fresh
from helpers.plant_pmac import codegen_trajectory
from sensorless.design.gain_table import GainTable, read_gain_table
from sensorless.design.pmac_reduced_order import FAMILY
from sensorless.design.runtime import run_trajectory
from sensorless.reports.cli.main import main
from sensorless.symbolic.pmac_reduced_order.step import OUTPUTS, STATE
from sensorless.tuning.pmac_reduced_order.settings import closed_form

CC = shutil.which("gcc") or shutil.which("cc")
ARM = shutil.which("arm-none-eabi-gcc")
STRICT = ["-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic"]
ARM_FLAGS = ["-mthumb", "-mcpu=cortex-m4", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard"]
P = "deangelo2006"  # the prefix: the drive's name
Y = {f.name: k for k, f in enumerate(OUTPUTS)}
X = {f.name: len(OUTPUTS) + k for k, f in enumerate(STATE)}
N_Y, N_X = len(OUTPUTS), len(STATE)
NAMES = [f.name for f in OUTPUTS] + [f"x.{f.name}" for f in STATE]
ANGLES = [Y["theta_hat"], X["theta"]]

pytestmark = pytest.mark.skipif(CC is None, reason="no host C compiler (gcc/cc) on PATH")


# ------------------------------------------------------------------------------------------ helpers
def runtime_setup(drive, *, table=None, table_file="", discretization=None):
    """The runtime set-up the command builds, through the family contract."""
    gains = FAMILY.gains(drive, table=table, table_file=table_file)
    return FAMILY.runtime(drive, gains, discretization=discretization)


def codegen(out, *args):
    assert main(["codegen", P, "--out", str(out), *map(str, args)]) == 0
    return out


def build(src, exe, extra=(), files=("main.c", f"{P}.c")):
    """``exe`` built warning-free (once per process for the same C: tests/helpers/cbuild.py)."""
    return cbuild([CC, *STRICT, *extra, "-o", str(exe), *[str(src / f) for f in files], "-lm"], exe)


def replay(exe, meas, tmp_path, *args):
    """Outputs then state after each sample (N x (n_y + n_x)), as main.c's replay mode writes them."""
    f = tmp_path / "samples.bin"
    np.ascontiguousarray(meas, dtype="<f8").tofile(f)
    r = subprocess.run([str(exe), str(f), *map(str, args)], capture_output=True)
    assert r.returncode == 0 and r.stderr == b"", r.stderr.decode()
    return np.frombuffer(r.stdout, "<f8").reshape(len(meas), N_Y + N_X)


def python_reference(setup, meas):
    xs, ys = run_trajectory(setup, meas)
    return np.hstack([ys, xs])


def deviation(c, ref):
    """|C - Python| per element, angles compared modulo 2 pi."""
    d = np.abs(c - ref)
    for j in ANGLES:
        d[:, j] = np.abs(np.angle(np.exp(1j * (c[:, j] - ref[:, j]))))
    return d


def relative(c, ref, scale=None):
    """Largest deviation of each column over the run, relative to the column's largest magnitude."""
    scale = np.abs(ref).max(axis=0) if scale is None else scale
    return deviation(c, ref).max(axis=0) / np.maximum(scale, 1e-300)


def rpm_error(drive, w_hat, w):
    return np.abs(drive.w_to_rpm(w_hat - w))


@pytest.fixture(scope="module")
def trajectory(deangelo2006):
    """>= 10^4 samples (2.6 s) of the plant under a sensored speed PI: load steps of both signs,
    ramps 250 -> 400 r/min and 400 -> -300 r/min (through zero), the observer starting from its
    initial state (w_hat = 0) while the motor runs."""
    tr = codegen_trajectory(deangelo2006)
    rpm = deangelo2006.w_to_rpm(tr["w"])
    assert len(tr["meas"]) >= 10_000
    assert rpm.max() > 390 and rpm.min() < -290  # both directions
    assert tr["T_L"].max() > 15 and tr["T_L"].min() < -10  # load steps of both signs
    return tr


# Negative speeds only, for the tuned gains: with their fast load-torque adaptation (Gamma ~ 4e5
# A^2 s^2) the estimates swing wildly while the speed crosses zero (the EMF, the observer's only
# information, vanishes there), which amplifies rounding differences past 1e-12.
NEGATIVE_SEGMENTS = (
    (0.25, -250, -250, 0.0),
    (0.3, -250, -250, 20.0),
    (0.3, -250, -400, 20.0),
    (0.3, -400, -400, -10.0),
    (0.4, -400, -150, -10.0),
    (0.3, -150, -150, 15.0),
    (0.2, -150, -250, -15.0),
)


@pytest.fixture(scope="module")
def negative_trajectory(deangelo2006):
    tr = codegen_trajectory(deangelo2006, NEGATIVE_SEGMENTS)
    assert len(tr["meas"]) >= 10_000 and deangelo2006.w_to_rpm(tr["w"]).max() < -100
    return tr


@pytest.fixture(scope="module")
def tuned_table(tmp_path_factory, deangelo2006):
    """A `deangelo` gain table as `sensorless tune` writes it, with the closed-form optimum for the
    bounds g <= 2 g0, Gamma <= 100 Gamma0 (non-round numbers, far from the drive file's g0 = 400,
    Gamma0 = 10^4; larger gains make the run more sensitive to rounding than this test is about)."""
    o = deangelo2006.observer
    g, Gamma = closed_form(deangelo2006, 2 * o.g, 100 * o.Gamma)
    assert (g, Gamma) != (deangelo2006.observer.g, deangelo2006.observer.Gamma)
    t = GainTable(
        law="constant",
        drive={"name": deangelo2006.name, "kind": deangelo2006.kind, "sha256": deangelo2006.digest},
        gains={"g": g, "Gamma": Gamma},
    )
    path = tmp_path_factory.mktemp("tables") / "deangelo.json"
    path.write_text(t.to_json())
    return path


# -------------------------------------------------------------------------------- C == Python
@pytest.mark.parametrize(
    "disc,gains", [("rk2-model", None), ("euler", None), ("rk2", None), ("rk2-model", "tuned")]
)
def test_double_matches_python_on_the_trajectory(
    deangelo2006, trajectory, negative_trajectory, tuned_table, tmp_path, disc, gains
):
    """Every output and state of every sample to 1e-12 of that signal's largest magnitude (angles
    modulo 2 pi), for the default scheme, forward Euler, the literal RK2, and tuned gains (on negative
    speeds). The generated code differs from CasADi's evaluation only by hoisted reciprocals
    (x * (1/L) for x / L) and the order of some operations."""
    args = ["--precision", "double", "--discretization", disc]
    if gains == "tuned":
        args += ["--gains", tuned_table]
        setup = runtime_setup(deangelo2006, table=read_gain_table(tuned_table), discretization=disc)
        assert setup.params["g"] == read_gain_table(tuned_table).gains["g"]
        trajectory = negative_trajectory
    else:
        setup = runtime_setup(deangelo2006, discretization=disc)
    src = codegen(tmp_path / "c", *args)
    c = replay(build(src, tmp_path / "ex"), trajectory["meas"], tmp_path)
    ref = python_reference(setup, trajectory["meas"])
    rel = relative(c, ref)
    assert rel.max() < 1e-12, {n: f"{r:.1e}" for n, r in zip(NAMES, rel, strict=True)}
    # a real run: every sample accepted, and the estimate follows the motor through both directions
    assert np.all(ref[:, Y["valid"]] == 1)
    settled = np.arange(len(c)) * deangelo2006.T_s > 0.1
    assert (
        rpm_error(deangelo2006, c[settled, Y["w_hat"]], trajectory["w"][settled]).max() < 10
    )  # of 400 r/min
    running = settled & (np.abs(trajectory["w"]) >= 30)  # the EMF, hence the angle, vanishes at zero
    th = np.angle(np.exp(1j * (c[running, Y["theta_hat"]] - trajectory["theta"][running])))
    assert np.abs(th).max() < 0.05


def test_gains_and_emf_series_are_runtime_parameters(deangelo2006, trajectory, tuned_table, tmp_path):
    """The tuned g and Gamma and the drive's Phi_n are fields of the generated default parameter struct
    (exactly, every field), and nothing of them is baked into the step: the code generated with the
    tuned table, initialized at run time with other gains and another EMF series, matches the Python
    step evaluated with those parameters to 1e-12."""
    setup = runtime_setup(deangelo2006, table=read_gain_table(tuned_table))
    src = codegen(tmp_path / "c", "--gains", tuned_table, "--precision", "double")
    text = (src / f"{P}.c").read_text()
    block = re.search(r"_default_params = \{(.*?)\};", text, re.S).group(1)
    defaults = {n: float(v) for n, v in re.findall(r"\.(\w+) = \(?([-+0-9.e]+)\)?,", block)}
    assert defaults == setup.params
    t = read_gain_table(tuned_table).gains
    assert defaults["g"] == t["g"] and defaults["Gamma"] == t["Gamma"]
    assert [defaults["Phi_1"], defaults["Phi_5"]] == list(deangelo2006.estimate.Phi)
    step = text[text.index(f"void {P}_step(") :]
    literals = {float(x) for x in re.findall(r"(?<![\w.])\d+\.\d*(?:e[-+]?\d+)?", step)}
    baked = {t["g"], t["Gamma"], *deangelo2006.estimate.Phi, t["g"] * deangelo2006.estimate.L}
    assert not (literals & baked), literals & baked

    (src / "replay_params.c").write_text(REPLAY_PARAMS)
    exe = build(src, tmp_path / "rp", files=("replay_params.c", f"{P}.c"))
    other = dict(setup.params, g=400.0, Gamma=1e4, Phi_1=0.9 * setup.params["Phi_1"], Phi_5=-0.01)
    changed = dataclasses.replace(setup, params=other)
    c = replay(exe, trajectory["meas"], tmp_path, *[repr(other[f.name]) for f in setup.observer.params])
    ref = python_reference(changed, trajectory["meas"])
    assert relative(c, ref).max() < 1e-12
    c_default = replay(build(src, tmp_path / "ex"), trajectory["meas"], tmp_path)
    assert relative(c_default, ref).max() > 1e-3  # the parameters changed the run


REPLAY_PARAMS = r"""
#include <stdio.h>
#include <stdlib.h>
#include "deangelo2006.h"
/* replay samples.bin with the parameters given on the command line (struct order) */
int main(int argc, char **argv)
{
    deangelo2006_observer o;
    deangelo2006_params p;
    deangelo2006_input in;
    deangelo2006_output out;
    double m[4], v[DEANGELO2006_N_OUTPUT + DEANGELO2006_N_STATE];
    const int np = (int)(sizeof p / sizeof(deangelo2006_real));
    FILE *f;
    int j;
    if (argc != 2 + np || (f = fopen(argv[1], "rb")) == NULL) return 2;
    for (j = 0; j < np; ++j) ((deangelo2006_real *)&p)[j] = (deangelo2006_real)strtod(argv[2 + j], NULL);
    if (deangelo2006_init(&o, &p) != 0) return 3;
    while (fread(m, sizeof m[0], 4, f) == 4) {
        in.i_alpha = m[0];
        in.i_beta = m[1];
        in.u_alpha = m[2];
        in.u_beta = m[3];
        deangelo2006_step(&o, &in, &out);
        for (j = 0; j < DEANGELO2006_N_OUTPUT; ++j) v[j] = ((deangelo2006_real *)&out)[j];
        for (j = 0; j < DEANGELO2006_N_STATE; ++j)
            v[DEANGELO2006_N_OUTPUT + j] = ((deangelo2006_real *)&o.x)[j];
        fwrite(v, sizeof v[0], DEANGELO2006_N_OUTPUT + DEANGELO2006_N_STATE, stdout);
    }
    fclose(f);
    return 0;
}
"""


def test_float_matches_python_within_float_resolution(deangelo2006, trajectory, tmp_path):
    """Float build against the double Python evaluation (eps_f = 2^-24 = 6e-8). Tolerances:

    - samples stored in the state: one rounding each, |error| <= eps_f |value|, element by element;
    - EMF state zeta: each period rounds it by a few eps_f of |zeta|, and the EMF error decays by
      (1 - g T_s) = 0.93 per period, so the error is the sum of the last ~1/(g T_s) = 14 roundings:
      at most ~14 x 4 eps_f = 3e-6 of zeta's scale. Tolerance 1e-5 for zeta, the EMF estimate
      e = zeta - g L i and the speed |e| / |phi| (observed ~1e-6);
    - load state tau: the slow pole (10.7 1/s) keeps ~520 periods of roundings: 4e-6 as a random
      walk, 1.2e-4 if they all added up. Tolerance 1e-4 (observed ~4e-6);
    - angle: atan2 of the EMF, so its error is ~ (|zeta| / |e|) x 3e-6 rad. While |w| >= 30 rad/s,
      |e| = Phi_1 |w| / p_r >= 1.9 V and |zeta| <= |e| + g L |i| <= |e| + 9 V: 2e-5 rad, tolerance
      3e-5 rad (observed ~1e-6). Where the speed ramp crosses zero the EMF vanishes and each build
      follows its own rounding for a few periods: tolerance 1e-3 rad there (observed ~2e-4);
    - phi_hat(theta_hat) moves by at most (Phi_1 + 5 Phi_5) = 1.2 |phi|_max per radian of angle:
      4e-5 and 2e-3 of its largest magnitude; T_L_hat = tau + (Gamma L / J) phi_hat . i adds
      1.28 |i| (<= 226 A) times that: 1e-4 running, 1e-3 of its largest magnitude anywhere.
    """
    setup = runtime_setup(deangelo2006)
    src = codegen(tmp_path / "c", "--precision", "float")
    meas = trajectory["meas"]
    c = replay(build(src, tmp_path / "ex"), meas, tmp_path)
    ref = python_reference(setup, meas)
    assert np.array_equal(c[:, Y["valid"]], ref[:, Y["valid"]])
    samples = [X[n] for n in ("i_a_prev", "i_b_prev", "u_a_prev", "u_b_prev")]
    assert np.all(np.abs(c[:, samples] - ref[:, samples]) <= 2.0**-24 * np.abs(ref[:, samples]))
    running = np.abs(trajectory["w"]) >= 30
    assert 0 < (~running).sum() < 0.05 * len(meas)
    tol_all = {"theta_hat": 1e-3 / math.pi, "x.theta": 1e-3 / math.pi, "T_L_hat": 1e-3, "x.tau": 1e-4}
    tol_all |= {"phi_alpha": 2e-3, "phi_beta": 2e-3}
    tol_run = {"theta_hat": 3e-5 / math.pi, "x.theta": 3e-5 / math.pi, "T_L_hat": 1e-4, "x.tau": 1e-4}
    tol_run |= {"phi_alpha": 4e-5, "phi_beta": 4e-5}
    scale = np.abs(ref).max(axis=0)
    scale[ANGLES] = math.pi
    for mask, tol in ((slice(None), tol_all), (running, tol_run)):
        rel = relative(c[mask], ref[mask], scale)
        lim = np.array([tol.get(n, 1e-5) for n in NAMES])
        lim[[Y["valid"], *samples]] = np.inf  # checked exactly above
        assert np.all(rel <= lim), {n: f"{r:.1e}" for n, r, t in zip(NAMES, rel, lim, strict=True) if r > t}
    assert relative(c, ref, scale)[Y["theta_hat"]] > 1e-9  # it is the float build


# ---------------------------------------------------------------- glitches: C == Python, recovery
def test_glitches_are_rejected_identically_and_the_observer_recovers(deangelo2006, trajectory, tmp_path):
    """Absurd and non-finite samples on every channel, at positive and negative speed: the C rejects
    exactly the samples the Python step rejects and coasts identically (1e-12 of the clean run's
    scale); non-finite samples give valid = 0; 200 periods (36 ms) after each glitch the estimates
    are back with those of the clean run. (The step before this test existed latched for good on
    the 1e5 and 1e20 glitches: it accepted a speed estimate beyond |w| T_s = pi/2, then rejected
    every later period.)"""
    setup = runtime_setup(deangelo2006)
    meas = trajectory["meas"].copy()
    glitches = [  # (first sample, samples, channel, value)
        (1500, 1, 0, np.nan),
        (3000, 1, 1, 1e5),
        (4500, 1, 2, np.inf),
        (6000, 20, 3, -1e20),
        (10000, 3, 0, 1e300),
        (11500, 1, 2, 1e6),
        (12500, 1, 1, -np.inf),
    ]
    for k, n, ch, v in glitches:
        meas[k : k + n, ch] = v
    src = codegen(tmp_path / "c", "--precision", "double")
    c = replay(build(src, tmp_path / "ex"), meas, tmp_path)
    ref = python_reference(setup, meas)
    clean = python_reference(setup, trajectory["meas"])
    assert np.all(np.isfinite(c)) and np.array_equal(c[:, Y["valid"]], ref[:, Y["valid"]])
    assert np.all(deviation(c, ref).max(axis=0) <= 1e-12 * np.abs(clean).max(axis=0))
    bad = ~np.isfinite(meas).all(axis=1)
    assert np.all(c[bad, Y["valid"]] == 0)
    for k, n, _, _ in glitches:
        assert c[k, Y["valid"]] == 0  # rejected, coasted
        after = slice(k + n + 200, k + n + 400)
        assert np.all(c[after, Y["valid"]] == 1)
        assert rpm_error(deangelo2006, c[after, Y["w_hat"]], clean[after, Y["w_hat"]]).max() < 2
    assert np.abs(c[:, ANGLES]).max() <= math.pi  # the documented range, coasting included


# ---------------------------------------------------------------------- robustness, sanitizers
HARNESS = r"""
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "deangelo2006.h"
#define CHECK(c) do { if (!(c)) { printf("FAIL line %d: %s\n", __LINE__, #c); return 1; } } while (0)
#define PI_ 3.14159265358979323846
typedef deangelo2006_real real;
int main(void)
{
    deangelo2006_observer a, b, fresh;
    deangelo2006_params p = deangelo2006_default_params;
    deangelo2006_input in;
    deangelo2006_output out;
    /* NaN, Inf, the largest finite values of the precision, absurd and subnormal magnitudes */
    const int single = sizeof(real) == sizeof(float);
    const real big = (real)(single ? 3.0e38 : 1.0e300);
    const real tiny = (real)(single ? 1e-40 : 1e-310);
    const real bad[] = {NAN, INFINITY, -INFINITY, big, -big, (real)1e30, (real)-1e20, (real)1e5,
                        tiny, -tiny, 0};
    const int nb = (int)(sizeof bad / sizeof bad[0]);
    const real w = (real)209.43951023931953; /* 250 r/min, electrical */
    int k, j, rc;
    memset(&in, 0, sizeof in);
    CHECK(fpclassify(tiny) == FP_SUBNORMAL);
    CHECK(deangelo2006_init(&a, &p) == 0);
    CHECK(deangelo2006_init(&fresh, &p) == 0);
    /* every parameter field: NaN is refused with its 1-based index; so are non-physical values */
    for (j = 0; j < (int)(sizeof p / sizeof(real)); ++j) {
        p = deangelo2006_default_params;
        ((real *)&p)[j] = NAN;
        rc = deangelo2006_init(&b, &p);
        CHECK(rc == j + 1);
    }
    p = deangelo2006_default_params;
    p.L = (real)-1e-4;
    CHECK(deangelo2006_init(&b, &p) == 2);
    p = deangelo2006_default_params;
    p.Gamma = (real)-1;
    CHECK(deangelo2006_init(&b, &p) == 6);
    p.Gamma = 0; /* no load-torque estimation: allowed */
    CHECK(deangelo2006_init(&b, &p) == 0);
    p = deangelo2006_default_params;
    p.T_s = 0;
    CHECK(deangelo2006_init(&b, &p) == 7);
    p = deangelo2006_default_params;
    p.T_max = 0;
    CHECK(deangelo2006_init(&b, &p) == 8);
    p = deangelo2006_default_params;
    p.Phi_1 = 0;
    CHECK(deangelo2006_init(&b, &p) == 9);
    p = deangelo2006_default_params;
    p.Phi_5 = INFINITY;
    CHECK(deangelo2006_init(&b, &p) == 10);
    p.Phi_5 = -p.Phi_1 / 10; /* a negative harmonic amplitude is data, not an error */
    CHECK(deangelo2006_init(&b, &p) == 0);
    /* hostile samples: no UB (sanitizers), state and outputs finite, valid = 0 on non-finite ones */
    CHECK(deangelo2006_init(&a, &deangelo2006_default_params) == 0);
    CHECK(deangelo2006_init(&b, &deangelo2006_default_params) == 0);
    for (k = 0; k < nb * 4 * 5; ++k) { /* every value on every channel, repeatedly */
        real v = bad[k % nb];
        in.i_alpha = (k / nb) % 4 == 0 ? v : (real)1;
        in.i_beta = (k / nb) % 4 == 1 ? v : (real)-2;
        in.u_alpha = (k / nb) % 4 == 2 ? v : (real)30;
        in.u_beta = (k / nb) % 4 == 3 ? v : (real)5;
        deangelo2006_step(&a, &in, &out);
        for (j = 0; j < DEANGELO2006_N_STATE; ++j) CHECK(isfinite(((real *)&a.x)[j]));
        for (j = 0; j < DEANGELO2006_N_OUTPUT; ++j) CHECK(isfinite(((real *)&out)[j]));
        CHECK(fabs(out.theta_hat) <= (real)PI_ && (out.valid == 0 || out.valid == 1));
        if (!isfinite(v)) CHECK(out.valid == 0);
    }
    /* and back: a motor at 250 r/min without current (u = e, eq. (3)); the observer, wherever the
       burst left it, locks on again (speed and angle) */
    p = deangelo2006_default_params;
    for (k = 1; k <= 6000; ++k) {
        const double th = fmod(0.3 + (double)w * (double)p.T_s * k, 2 * PI_);
        const double s = (double)w / (double)p.p_r;
        in.i_alpha = in.i_beta = 0;
        in.u_alpha = (real)(-s * ((double)p.Phi_1 * sin(th) + (double)p.Phi_5 * sin(5 * th)));
        in.u_beta = (real)(s * ((double)p.Phi_1 * cos(th) + (double)p.Phi_5 * cos(5 * th)));
        deangelo2006_step(&a, &in, &out);
        if (k > 5000) {
            CHECK(out.valid == 1);
            CHECK(fabs(out.w_hat - w) < (real)0.01 * w);
            CHECK(fabs(remainder((double)out.theta_hat - th, 2 * PI_)) < 0.01);
        }
    }
    /* instances are independent: b never stepped, still equals a fresh instance */
    CHECK(memcmp(&b, &fresh, sizeof b) == 0);
    /* init recovers the exact initial state */
    CHECK(deangelo2006_init(&a, &deangelo2006_default_params) == 0);
    CHECK(memcmp(&a, &fresh, sizeof a) == 0);
    printf("ok\n");
    return 0;
}
"""


@pytest.mark.parametrize("precision", ["double", "float"])
def test_sanitized_hostile_inputs_params_and_instances(tmp_path, precision):
    """Under -fsanitize=address,undefined (all checks fatal): NaN/Inf/huge/subnormal samples on every
    channel leave a finite state and finite outputs (valid = 0 on non-finite ones, the angle in
    [-pi, pi]), and the observer locks on a motor again afterwards; a NaN in any parameter field is
    refused naming the field, as are non-physical values; two instances share nothing; *_init
    restores the exact initial state."""
    src = codegen(tmp_path / "c", "--precision", precision)
    (src / "harness.c").write_text(HARNESS)
    exe = build(src, tmp_path / "h", SANITIZE_O0, files=("harness.c", f"{P}.c"))
    r = subprocess.run([str(exe)], capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr == "" and r.stdout == "ok\n", r.stdout[-2000:] + r.stderr[-2000:]


# ------------------------------------------------------------------------ float, Cortex-M4F
def test_float_build_is_genuinely_single_precision(tmp_path):
    """No double literal, no double libm call in the float observer; the host compiler with
    -Wdouble-promotion -Wfloat-conversion agrees."""
    src = codegen(tmp_path / "c", "--precision", "float")
    text = (src / f"{P}.c").read_text()
    body = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    literals = re.findall(r"(?<![\w.])(\d+\.\d*(?:e[-+]?\d+)?|\d+e[-+]?\d+)(f?)", body)
    assert literals and all(s == "f" for _, s in literals), [x for x in literals if not x[1]]
    calls = set(re.findall(r"\b([a-z0-9]+)\(", body))
    assert not (calls & DOUBLE_LIBM), calls & DOUBLE_LIBM
    assert {"sinf", "cosf", "atan2f", "sqrtf", "floorf", "ceilf", "fabsf"} <= calls
    assert "double" not in body
    cmd = [
        CC,
        *STRICT,
        "-Wdouble-promotion",
        "-Wfloat-conversion",
        "-c",
        "-o",
        os.devnull,
        str(src / f"{P}.c"),
    ]
    r = subprocess.run(cmd, capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr == "", r.stderr


DOUBLE_LIBM = {
    "sin", "cos", "tan", "atan2", "atan", "sqrt", "fabs", "floor", "ceil", "fmin", "fmax", "pow", "exp",
    "log", "fmod", "hypot", "copysign",
}  # fmt: skip


def arm_undefined(src, tmp_path, name):
    if ARM is None:
        pytest.skip("arm-none-eabi-gcc not installed (Debian: gcc-arm-none-eabi libnewlib-dev)")
    obj = tmp_path / f"{name}.o"
    cmd = [ARM, *STRICT, *ARM_FLAGS, "-c", "-o", str(obj), str(src / f"{P}.c")]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if "math.h: No such file" in r.stderr:
        pytest.skip("arm-none-eabi-gcc has no C library headers (Debian: libnewlib-dev)")
    assert r.returncode == 0 and r.stderr == "", r.stderr
    nm = subprocess.run(
        [ARM.replace("gcc", "nm"), "-u", str(obj)], capture_output=True, text=True, check=True
    )
    return {ln.split()[-1] for ln in nm.stdout.splitlines() if ln.strip()}


def test_cortex_m4f_float_object_has_no_double_arithmetic(tmp_path):
    """arm-none-eabi-gcc for the Cortex-M4F (single-precision FPU): the float step needs no
    double-precision runtime (__aeabi_d*) and no double libm; the double build, compiled the same
    way, does (so the check can fail)."""
    undef_f = arm_undefined(codegen(tmp_path / "f", "--precision", "float"), tmp_path, "f")
    assert not any(s.startswith("__aeabi_d") for s in undef_f), undef_f
    assert not (undef_f & DOUBLE_LIBM), undef_f
    assert {"sinf", "cosf", "atan2f"} <= undef_f
    undef_d = arm_undefined(codegen(tmp_path / "d", "--precision", "double"), tmp_path, "d")
    assert any(s.startswith("__aeabi_d") for s in undef_d) and {"sin", "cos", "atan2"} <= undef_d


# ------------------------------------------------------------------------------- the command
def test_codegen_is_deterministic_across_processes(tmp_path, tuned_table):
    """Two runs (separate processes, different hash seeds) give byte-identical files: this process's
    run (its module caches warm from the tests before) and a fresh process's, with another hash seed."""
    outs = here_and_fresh(tmp_path, ["codegen", P, "--gains", str(tuned_table)])
    assert outs[0] == outs[1]
    assert sorted(outs[0]) == sorted(["Makefile", "main.c", f"{P}.c", f"{P}.h"])
    assert b"casadi" not in outs[0][f"{P}.c"] + outs[0][f"{P}.h"]


@pytest.mark.parametrize("precision", ["double", "float"])
def test_example_builds_with_its_makefile_and_runs(tmp_path, precision):
    """`make` builds the example with the generated Makefile (-std=c99 -Wall -Wextra -Werror
    -pedantic): it initializes and steps at standstill (finite estimates, samples accepted); the
    Makefile's Cortex-M4F target builds where the cross compiler is installed."""
    if shutil.which("make") is None:
        pytest.skip("make not installed")
    src = codegen(tmp_path / "c", "--precision", precision)
    r = subprocess.run(["make", "-C", str(src), f"CC={CC}"], capture_output=True, text=True)
    assert r.returncode == 0 and "warning" not in r.stderr, r.stdout + r.stderr
    r = subprocess.run([str(src / "example")], capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    lines = r.stdout.splitlines()
    assert [ln.split()[0] for ln in lines] == [f"k={k}" for k in range(8)]
    for ln in lines:
        vals = dict(item.split("=") for item in ln.split()[1:] if "=" in item)
        assert vals.keys() >= {"w_hat", "theta_hat", "T_L_hat", "valid"}
        assert all(math.isfinite(float(re.match(r"[-+0-9.einf]+", v).group())) for v in vals.values())
        assert vals["valid"] == "1"
    if ARM is not None:
        r = subprocess.run(["make", "-C", str(src), f"{P}-m4.o"], capture_output=True, text=True)
        if "math.h: No such file" not in r.stderr:
            assert r.returncode == 0 and (src / f"{P}-m4.o").is_file(), r.stderr


def test_cli_errors_exit_2_and_write_nothing(tmp_path, capsys, tuned_table):
    out = tmp_path / "o"
    assert main(["codegen", P, "--gain-set", "speed", "--out", str(out)]) == 2
    assert "one set of gains" in capsys.readouterr().err
    law16 = tmp_path / "law16.json"
    doc = read_gain_table(tuned_table)
    law16.write_text(
        GainTable(
            "speed-dependent", doc.drive, {"lambda_p": 5.0, "w_lambda": 300.0, "alpha_fo": 1.0}
        ).to_json()
    )
    assert main(["codegen", P, "--gains", str(law16), "--out", str(out)]) == 2
    assert "law16.json: key 'law'" in capsys.readouterr().err
    assert main(["codegen", P, "--discretization", "rk4", "--out", str(out)]) == 2
    assert "rk4" in capsys.readouterr().err
    assert not out.exists()
