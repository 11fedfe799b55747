"""Angles stay in (-pi, pi] in the generated C of either precision (symbolic/frames.py).

Every angle a runtime observer stores or outputs is wrapped by ``wrap_angle`` or comes from atan2
through ``half_open``. Their C, printed by the code generator, is run on every value within a few
thousand ulps of -5 pi, -3 pi, ..., 5 pi and on random values in (-4.5 pi, 4.5 pi), in float and in
double: the result is in (-pi, pi] with pi of that precision and represents the same angle. (The
plain ``theta - 2 pi ceil((theta - pi) / (2 pi))`` gives pi plus an ulp for theta an ulp above -pi
in double, or at -3 pi in float: the quotient rounds to an integer.)
"""

import math
import shutil
import subprocess

import casadi as ca
import numpy as np
import pytest
from sensorless.reports.codegen.c_emit import Precision, emit
from sensorless.symbolic.frames import half_open, wrap_angle

CC = shutil.which("gcc") or shutil.which("cc")

PROGRAM = r"""
#include <math.h>
#include <stdio.h>
typedef @REAL@ real;
static real wrap(real th)
{
    real r;
@WRAP@
    return r;
}
static real half(real th)
{
    real r;
@HALF@
    return r;
}
static long bad;
static double worst;
static void check(real th, real r)
{
    const real pi = (real)3.14159265358979323846;
    double d = remainder((double)r - (double)th, 2 * 3.14159265358979323846);
    if (!(-pi < r && r <= pi)) {
        if (bad++ < 5) printf("%.17g -> %.17g\n", (double)th, (double)r);
    }
    if (fabs(d) > worst) worst = fabs(d);
}
int main(void)
{
    const double pi = 3.14159265358979323846;
    unsigned long long s = 12345;
    long n = 0;
    int c, k;
    for (c = -5; c <= 5; c += 2) {
        real up = (real)(c * pi), down = up;
        for (k = 0; k < 4000; ++k, n += 2) {
            check(up, wrap(up));
            check(down, wrap(down));
            up = NEXT(up, (real)INFINITY);
            down = NEXT(down, -(real)INFINITY);
        }
    }
    for (k = 0; k < 2000000; ++k, ++n) {
        real th;
        s = s * 6364136223846793005ULL + 1442695040888963407ULL;
        th = (real)((double)(s >> 11) * (1.0 / 9007199254740992.0) * 9 * pi - 4.5 * pi);
        check(th, wrap(th));
    }
    check(-(real)pi, half(-(real)pi));
    check((real)pi, half((real)pi));
    check(ATAN2(-(real)0.0, -(real)1), half(ATAN2(-(real)0.0, -(real)1)));
    printf("%ld %ld %.3g\n", n, bad, worst);
    return 0;
}
"""


def _body(expr, prec):
    th = ca.SX.sym("th")
    f = ca.Function("f", [th], [expr(th)])
    lines = emit(f, prec=prec, runtime_in={0: ["th"]}, param_in={}, out={0: ["r"]}, coef="k").body
    return "\n".join("    " + ln for ln in lines)


@pytest.mark.skipif(CC is None, reason="no host C compiler (gcc/cc) on PATH")
@pytest.mark.parametrize("real", ["double", "float"])
def test_wrapped_angles_are_in_the_half_open_range_in_c(tmp_path, real):
    prec = Precision(real)
    text = PROGRAM.replace("@REAL@", real).replace("@WRAP@", _body(wrap_angle, prec))
    text = text.replace("@HALF@", _body(half_open, prec))
    single = real == "float"
    src = tmp_path / "angles.c"
    src.write_text(text)
    exe = tmp_path / "angles"
    cmd = [CC, "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-o", str(exe), str(src), "-lm"]
    defs = ["-DNEXT=nextafterf", "-DATAN2=atan2f"] if single else ["-DNEXT=nextafter", "-DATAN2=atan2"]
    r = subprocess.run([*cmd[:1], *defs, *cmd[1:]], capture_output=True, text=True)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.split()
    n, bad, worst = int(out[-3]), int(out[-2]), float(out[-1])
    assert n > 2_000_000 and bad == 0, out
    # the same angle: to the rounding of 2 pi k in the precision (k <= 2)
    assert worst <= 4 * 2 * math.pi * (np.finfo(np.float32 if single else float).eps)
