"""The C printer (reports/codegen/c_emit.py) on small graphs: products of parameter-only factors folded
into one hoisted coefficient, and the branches on the runtime guard's selects computing exactly what
the selects compute (the built-in families' C is checked against Python in tests/*/test_codegen*.py)."""

import shutil
import subprocess

import casadi as ca
import numpy as np
import pytest
from sensorless.reports.codegen.c_emit import Precision, emit
from sensorless.symbolic.runtime import REJECTS, Field, guarded

CC = shutil.which("gcc") or shutil.which("cc")
DOUBLE = Precision("double")


def test_products_of_parameter_factors_are_one_coefficient():
    """p * (q * (r * x)): one multiplication in the step, by the product p q r computed at init."""
    x, p = ca.SX.sym("x"), ca.SX.sym("p", 3)
    y = p[0] * (p[1] * (p[2] * x))
    f = ca.Function("f", [x, p], [ca.vertcat(y, p[1] * x)])
    e = emit(
        f,
        prec=DOUBLE,
        runtime_in={0: ["x"]},
        param_in={1: ["p[0]", "p[1]", "p[2]"]},
        out={0: ["y[0]", "y[1]"]},
        coef="k",
    )
    assert sum(line.count("*") for line in e.body) == 2, e.body  # y[0] and y[1], one each
    assert e.n_coef == 2  # p q r and q


# a guarded toy step: a bounded field, an unbounded one, the counter
STATE = (Field("a", "1", "bounded", bound="a_max"), Field("b", "1", "free"), REJECTS)
PARAMS = (Field("a_max", "1", "bound of a", "positive"), Field("g", "1", "gain"))


def guarded_toy() -> ca.Function:
    x, m, p = ca.SX.sym("x", 3), ca.SX.sym("m"), ca.SX.sym("p", 2)
    cand = (ca.vertcat(x[0] + p[1] * m, x[1] * m + ca.sin(m)), ca.vertcat(x[0] * m, ca.cos(m) * x[1]))
    coast = (ca.vertcat(x[0], ca.fmin(ca.fmax(x[1] + 1, -4), 4)), ca.vertcat(x[0], 0))
    x_next, y = guarded(x, p, STATE, PARAMS, cand=cand, coast=coast, reset=ca.vertcat(p[0] / 2, 0, 0))
    return ca.Function("toy", [x, m, p], ca.cse([x_next, y]))


HARNESS = r"""
#include <math.h>
#include <stdio.h>
static void step(const double *x, double m, const double *p, double *xn, double *y)
{
    double k[@N_COEF@];
    {
@INIT@
    }
@BODY@
}
int main(void)
{
    double r[6], xn[3], y[4];
    while (fread(r, sizeof(double), 6, stdin) == 6) {
        step(r, r[3], r + 4, xn, y);
        fwrite(xn, sizeof(double), 3, stdout);
        fwrite(y, sizeof(double), 4, stdout);
    }
    return 0;
}
"""


@pytest.mark.skipif(CC is None, reason="no host C compiler (gcc/cc) on PATH")
def test_branches_on_the_guard_compute_what_the_selects_compute(tmp_path):
    f = guarded_toy()
    e = emit(
        f,
        prec=DOUBLE,
        runtime_in={0: ["x[0]", "x[1]", "x[2]"], 1: ["m"]},
        param_in={2: ["p[0]", "p[1]"]},
        out={0: ["xn[0]", "xn[1]", "xn[2]"], 1: ["y[0]", "y[1]", "y[2]", "y[3]"]},
        coef="k",
    )
    assert any(line.startswith("if (") for line in e.body), e.body  # accept / coast
    assert any(line.strip().startswith("if (") for line in e.body if line.startswith(" ")), e.body  # reset
    src = HARNESS.replace("@N_COEF@", str(max(e.n_coef, 1)))
    src = src.replace("@INIT@", "\n".join(" " * 8 + ln for ln in e.init))
    src = src.replace("@BODY@", "\n".join(" " * 4 + ln for ln in e.body))
    (tmp_path / "toy.c").write_text(src)
    exe = tmp_path / "toy"
    cmd = [CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-o", str(exe)]
    r = subprocess.run([*cmd, str(tmp_path / "toy.c"), "-lm"], capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr == "", r.stderr

    rng = np.random.default_rng(7)
    n = 20000
    rows = np.column_stack(
        [
            rng.uniform(-1.5, 1.5, n),  # a, bound 1 (rejected and coasting alike)
            rng.normal(0, 3, n),
            rng.choice([0.0, 1.0, 50.0, 98.0, 99.0, 100.0], n),  # the counter, about its bound
            rng.normal(0, 1, n),
            rng.choice([1.0, 0.5], n),
            rng.normal(0, 1, n),
        ]
    )
    rows[rng.random(n) < 0.1, 3] = np.nan
    rows[rng.random(n) < 0.05, 3] = np.inf
    rows[rng.random(n) < 0.05, 1] = 1e308
    c = subprocess.run([str(exe)], input=rows.tobytes(), capture_output=True, check=True).stdout
    got = np.frombuffer(c, "<f8").reshape(n, 7)
    xn, y = f.map(n)(rows[:, :3].T, rows[:, 3], rows[:, 4:].T)
    want = np.vstack([np.asarray(xn), np.asarray(y)]).T
    np.testing.assert_array_equal(got, want)
    valid, reset = want[:, 5], want[:, 6]
    assert 0 < valid.sum() < n and 0 < reset.sum()  # every path taken
