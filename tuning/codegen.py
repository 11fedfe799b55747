"""C code generation of a runtime observer: typed C99 API around the printed CasADi step (docs/codegen.md).

``generate(setup, ...)`` returns the files of one observer as text: ``<prefix>.h`` (types and API),
``<prefix>.c`` (init, step, gain schedule), an example ``main.c`` (also a trajectory replayer) and a
``Makefile``. The arithmetic of the step, of the parameter-derived coefficients and of a closed-form gain
law comes from the observer's registered ``casadi.Function`` (symbolic/runtime.py) through
:mod:`sensorless.tuning.c_emit`; the only C written here by hand is plumbing (structs, calls, checks)
and the generic linear interpolation of a tuned gain table. No heap, no globals, no CasADi at runtime.
Output is a pure function of the inputs (no dates), so two runs give byte-identical files.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import casadi as ca
import numpy as np
from sensorless.design.runtime import RuntimeSetup
from sensorless.symbolic.runtime import Field, RuntimeObserver
from sensorless.tuning.c_emit import Precision, emit

PRECISIONS = ("double", "float")


@dataclass(frozen=True)
class Provenance:
    """What the generated files say about where they come from (no dates: deterministic)."""

    drive_name: str
    drive_file: str
    drive_sha256: str
    generator: str  # "sensorless <version>"


def c_identifier(name: str) -> str:
    """A C identifier from a drive name: lower case, non-alphanumerics to '_', no leading digit."""
    s = re.sub(r"[^0-9a-zA-Z_]", "_", name).lower().strip("_") or "observer"
    return f"obs_{s}" if s[0].isdigit() else s


def _comment(text: str) -> str:
    return text.replace("*/", "* /")


def _struct(name: str, fields: list[tuple[str, str, str]], real: str, what: str) -> str:
    lines = [f"/** {what} */", "typedef struct {"]
    width = max((len(n) for n, _, _ in fields), default=0)
    for n, unit, doc in fields:
        lines.append(f"    {real} {n};{' ' * (width - len(n))} /**< [{unit}] {_comment(doc)} */")
    if not fields:
        lines.append(f"    {real} unused_; /**< (no fields) */")
    lines.append(f"}} {name};")
    return "\n".join(lines)


def _f(fields: tuple[Field, ...]) -> list[tuple[str, str, str]]:
    return [(f.name, f.unit, f.doc) for f in fields]


def _gain_param_fields(setup: RuntimeSetup) -> list[tuple[str, str, str]]:
    """Parameters of a closed-form gain law (law16: lambda_p, w_lambda) as params-struct fields."""
    if setup.family in ("schedule", "none"):
        return []
    law = setup.law
    docs = {
        "lambda_p": "lambda' of the speed-dependent gain, eq. (16)",
        "w_lambda": "omega_lambda of the speed-dependent gain, eq. (16)",
        "lambda1": "constant gain lambda1, eq. (7)",
        "lambda2": "constant gain lambda2, eq. (7)",
    }
    return [
        (n, u, docs.get(n, "gain law parameter"))
        for n, u in zip(law.param_names, law.param_units, strict=True)
    ]


def _indent(lines: list[str], n: int = 4) -> list[str]:
    return [" " * n + ln for ln in lines]


def _gain_function(setup: RuntimeSetup) -> ca.Function:
    """(w_hat, gain params) -> [lambda1, lambda2]: the law's own SX expression, eq. (7)/(16)."""
    w = ca.SX.sym("w_hat")
    g = ca.SX.sym("gain", setup.law.n_params)
    return ca.Function("gains", [w, g], [ca.vertcat(*setup.law.expr(w, g))], ["w_hat", "gain"], ["lam"])


def _schedule_c(setup: RuntimeSetup, P: str, prec: Precision) -> list[str]:
    """Const table + linear interpolation, held beyond the ends: schedule_law of symbolic/gains.py."""
    grid = np.asarray(setup.law.grid, dtype=float)
    n = grid.size
    l1, l2 = np.asarray(setup.gain[:n], dtype=float), np.asarray(setup.gain[n:], dtype=float)
    r = prec.real

    def arr(name: str, v: np.ndarray, unit: str) -> str:
        body = ", ".join(prec.lit(float(x)) for x in v)
        return f"static const {r} {name}[{v.size}] = {{ /* [{unit}] */\n    {body}\n}};"

    inv = 1.0 / np.diff(grid)
    return [
        f"/* Tuned gain schedule ({setup.gain_source}): lambda1, lambda2 at the breakpoints of the speed",
        " * estimate, linear in between, held beyond the ends (docs/gain_tables.md). */",
        f"#define {P.upper()}_GAIN_N {n}",
        arr(f"{P}_gain_w", grid, "rad/s"),
        arr(f"{P}_gain_l1", l1, "ohm"),
        arr(f"{P}_gain_l2", l2, "ohm"),
        arr(f"{P}_gain_inv_dw", inv, "s/rad; 1 / (w[j+1] - w[j])"),
        "",
        f"static void {P}_gains_impl(const {r} *k, {r} w_hat, {r} *lambda1, {r} *lambda2)",
        "{",
        "    size_t lo = 0, hi = " + f"{P.upper()}_GAIN_N - 1;",
        f"    {r} t;",
        "    (void)k;",
        f"    if (!(w_hat > {P}_gain_w[0])) {{ /* below the table, or NaN */",
        f"        *lambda1 = {P}_gain_l1[0];",
        f"        *lambda2 = {P}_gain_l2[0];",
        "        return;",
        "    }",
        f"    if (!(w_hat < {P}_gain_w[hi])) {{",
        f"        *lambda1 = {P}_gain_l1[hi];",
        f"        *lambda2 = {P}_gain_l2[hi];",
        "        return;",
        "    }",
        "    while (hi - lo > 1) { /* bisection: w[lo] <= w_hat < w[hi] */",
        "        const size_t mid = lo + (hi - lo) / 2;",
        f"        if (w_hat < {P}_gain_w[mid]) {{",
        "            hi = mid;",
        "        } else {",
        "            lo = mid;",
        "        }",
        "    }",
        f"    t = (w_hat - {P}_gain_w[lo]) * {P}_gain_inv_dw[lo];",
        f"    *lambda1 = {P}_gain_l1[lo] + t * ({P}_gain_l1[hi] - {P}_gain_l1[lo]);",
        f"    *lambda2 = {P}_gain_l2[lo] + t * ({P}_gain_l2[hi] - {P}_gain_l2[lo]);",
        "}",
    ]


def _check(f: tuple[str, str], prec: Precision) -> str:
    name, check = f
    v = f"prm->{name}"
    zero, one = prec.lit(0.0), prec.lit(1.0)
    return {
        "positive": f"!({v} > {zero})",
        "nonnegative": f"!({v} >= {zero})",
        "flag": f"!({v} == {zero} || {v} == {one})",
        "any": f"!isfinite({v})",
    }[check]


def generate(
    setup: RuntimeSetup,
    provenance: Provenance,
    *,
    precision: str = "double",
    prefix: str | None = None,
) -> dict[str, str]:
    """The C files of ``setup``'s observer: {file name: text}. See the module docstring."""
    if precision not in PRECISIONS:
        raise ValueError(f"unknown precision {precision!r} (known: {', '.join(PRECISIONS)})")
    obs: RuntimeObserver = setup.observer
    prec = Precision(precision)
    r = prec.real
    P = prefix or c_identifier(provenance.drive_name)
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", P):
        raise ValueError(f"prefix {P!r} is not a C identifier")
    R = f"{P}_real"
    PU = P.upper()

    core = obs.core(setup.discretization)
    n_x, n_y, n_lam = len(obs.state), len(obs.outputs), len(obs.lam)
    step = emit(
        core,
        prec=prec,
        runtime_in={
            0: [f"obs->x.{f.name}" for f in obs.state],
            1: [f"in->{f.name}" for f in obs.meas],
            3: [f"lam[{j}]" for j in range(n_lam)],
        },
        param_in={2: [f"prm->{f.name}" for f in obs.params]},
        out={0: [f"obs->x.{f.name}" for f in obs.state], 1: [f"out->{f.name}" for f in obs.outputs]},
        coef="k",
    )
    gain_fields = _gain_param_fields(setup)
    has_gains = n_lam > 0 and setup.family != "none"
    if has_gains and setup.family != "schedule":
        gain = emit(
            _gain_function(setup),
            prec=prec,
            runtime_in={0: ["w_hat"]},
            param_in={1: [f"prm->{n}" for n, _, _ in gain_fields]},
            out={0: ["*lambda1", "*lambda2"]},
            coef="k",
            coef_offset=step.n_coef,
            prefix="g",
        )
    else:
        gain = None
    n_coef = step.n_coef + (gain.n_coef if gain else 0)
    x0 = emit(
        obs.initial_state(),
        prec=prec,
        runtime_in={0: [f"prm->{f.name}" for f in obs.params]},
        param_in={},
        out={0: [f"obs->x.{f.name}" for f in obs.state]},
        coef="k",
        prefix="x",
    )

    law_text = {
        "law16": "speed-dependent gain, eq. (16), closed form",
        "schedule": "tuned gain schedule, const table with linear interpolation",
        "constant": "constant gain, eq. (7)",
        "zero": "zero gain",
        "none": "no gain schedule",
    }[setup.family]
    banner = [
        f"/* {P}: {obs.title}.",
        f" * Generated by {provenance.generator} (`sensorless codegen`); do not edit, regenerate.",
        f" * Drive: {provenance.drive_name} ({provenance.drive_file}, "
        f"sha256 {provenance.drive_sha256[:16]}).",
        f" * Gains: {_comment(setup.gain_source)}; {law_text}.",
        f" * Discretization: {setup.discretization}; precision: {r}. Plain C99, no heap, no globals.",
        " */",
    ]

    # ---------------------------------------------------------------------------------------- header
    param_fields = _f(obs.params) + gain_fields
    h: list[str] = [
        *banner,
        f"#ifndef {PU}_H",
        f"#define {PU}_H",
        "",
        "#ifdef __cplusplus",
        'extern "C" {',
        "#endif",
        "",
        f"/** Floating-point type of this build ({r}). */",
        f"typedef {r} {R};",
        "",
        f"#define {PU}_N_STATE {n_x}",
        f"#define {PU}_N_OUTPUT {n_y}",
        f"#define {PU}_N_COEF {max(n_coef, 1)}",
        "",
        _struct(
            f"{P}_params", param_fields, R, "Parameters, SI units. Fill from the drive: see the defaults."
        ),
        "",
        _struct(
            f"{P}_state", _f(obs.state), R, "Observer state (public: read it freely; set theta after init)."
        ),
        "",
        _struct(
            f"{P}_input", _f(obs.meas), R, "Measurements of one sampling period (docs/runtime.md, timing)."
        ),
        "",
        _struct(f"{P}_output", _f(obs.outputs), R, "Estimates and signals of one sampling period."),
        "",
        "/** One observer instance: its state and the coefficients derived from its parameters.",
        " *  Allocate as many as needed (static, stack, struct member); instances share nothing. */",
        "typedef struct {",
        f"    {P}_state x;",
        f"    {R} coef[{PU}_N_COEF]; /**< computed by {P}_init from the parameters */",
        f"}} {P}_observer;",
        "",
        f"/** Parameters of {provenance.drive_name} with the gains named in the banner. */",
        f"extern const {P}_params {P}_default_params;",
        "",
        "/** Check the parameters, derive the coefficients and reset the state (theta_hat = 0,",
        " *  psi_hat = [psi_pm, 0], everything else 0). Also the way back after any fault.",
        " *  Returns 0 on success; k > 0 if the k-th parameter field (1-based, struct order) is",
        " *  invalid; -1 if a derived coefficient is not finite (e.g. injection on a non-salient motor).",
        " *  On failure the observer must be initialized again before use. */",
        f"int {P}_init({P}_observer *obs, const {P}_params *prm);",
        "",
        "/** One sampling period (call it from the PWM/ADC interrupt, every T_s):",
        " *  in:  current sampled now, voltage applied over the coming period (stationary frame);",
        " *  out: speed and angle estimates now, carrier voltage for the next reference, ...",
        " *  Bounded time (no division, no data-dependent loop but a gain table's bisection).",
        " *  Never fails: a non-finite result is rejected (out->valid = 0) and the observer",
        " *  coasts (docs/runtime.md). */",
        f"void {P}_step({P}_observer *obs, const {P}_input *in, {P}_output *out);",
        "",
        *(
            [
                "/** Observer gain (7) at speed estimate w_hat [rad/s]: lambda1, lambda2 [ohm]. The step",
                f" *  calls it once per period with the stored estimate obs->x.{obs.schedule_state}. */",
                f"void {P}_gains(const {P}_observer *obs, {R} w_hat, {R} *lambda1, {R} *lambda2);",
                "",
            ]
            if has_gains
            else []
        ),
        "#ifdef __cplusplus",
        "}",
        "#endif",
        "",
        f"#endif /* {PU}_H */",
        "",
    ]

    # ---------------------------------------------------------------------------------------- source
    pvals = dict(setup.params)
    if gain_fields:
        pvals.update(zip(setup.law.param_names, setup.gain, strict=True))
    defaults = [f"    .{n} = {prec.lit(float(pvals[n]))}," for n, _, _ in param_fields]
    checks = [(f.name, f.check) for f in obs.params] + [(n, "any") for n, _, _ in gain_fields]
    c: list[str] = [
        *banner,
        f'#include "{P}.h"',
        "",
        "#include <math.h>",
        "#include <stddef.h>",
        "",
        f"const {P}_params {P}_default_params = {{",
        *defaults,
        "};",
        "",
    ]
    if gain is not None:
        c += [
            "/* Gain law (7)/(16): printed from its CasADi expression (symbolic/gains.py). */",
            f"static void {P}_gains_impl(const {r} *k, {r} w_hat, {r} *lambda1, {r} *lambda2)",
            "{",
            "    (void)k; /* a law may use neither coefficients nor the speed (zero, constant gain) */",
            "    (void)w_hat;",
            *_indent(gain.body),
            "}",
        ]
    elif has_gains:
        c += _schedule_c(setup, P, prec)
    if has_gains:
        c += [
            "",
            f"void {P}_gains(const {P}_observer *obs, {R} w_hat, {R} *lambda1, {R} *lambda2)",
            "{",
            f"    {P}_gains_impl(obs->coef, w_hat, lambda1, lambda2);",
            "}",
        ]
    c += [
        "",
        f"int {P}_init({P}_observer *obs, const {P}_params *prm)",
        "{",
        f"    {r} *const k = obs->coef;",
        "    int j;",
    ]
    for j, ch in enumerate(checks, start=1):
        c.append(f"    if ({_check(ch, prec)}) {{")
        c.append(f"        return {j}; /* {ch[0]} */")
        c.append("    }")
    c += [
        "    { /* coefficients of the step: parameter-only parts of its expression graph */",
        *_indent(step.init, 8),
        "    }",
    ]
    if gain is not None and gain.init:
        c += ["    { /* coefficients of the gain law */", *_indent(gain.init, 8), "    }"]
    c += [
        f"    for (j = {n_coef}; j < {PU}_N_COEF; ++j) {{",
        f"        k[j] = {prec.lit(0.0)};",
        "    }",
        f"    for (j = 0; j < {PU}_N_COEF; ++j) {{",
        "        if (!isfinite(k[j])) {",
        "            return -1;",
        "        }",
        "    }",
        "    { /* initial state */",
        *_indent(x0.body, 8),
        "    }",
        "    return 0;",
        "}",
        "",
        f"void {P}_step({P}_observer *obs, const {P}_input *in, {P}_output *out)",
        "{",
        f"    const {r} *const k = obs->coef;",
    ]
    if has_gains:
        c += [
            f"    {r} lam[{n_lam}];",
            f"    {P}_gains_impl(k, obs->x.{obs.schedule_state}, &lam[0], &lam[1]);",
        ]
    c += [*_indent(step.body), "}", ""]

    return {
        f"{P}.h": "\n".join(h),
        f"{P}.c": "\n".join(c),
        "main.c": _example_main(P, obs, provenance),
        "Makefile": _makefile(P),
    }


def _example_main(P: str, obs: RuntimeObserver, prov: Provenance) -> str:
    R = f"{P}_real"
    put = [f"            v[{j}] = (double)out.{f.name};" for j, f in enumerate(obs.outputs)]
    n_y = len(obs.outputs)
    put += [f"            v[{n_y + j}] = (double)observer.x.{f.name};" for j, f in enumerate(obs.state)]
    get = [f"            in.{f.name} = ({R})m[{j}];" for j, f in enumerate(obs.meas)]
    n_m, n_v = len(obs.meas), len(obs.outputs) + len(obs.state)
    show = [
        f'            printf(" {f.name}=%g{"" if f.unit == "1" else " " + f.unit}", (double)out.{f.name});'
        for f in obs.outputs[:5] + obs.outputs[-1:]
    ]
    return "\n".join(
        [
            f"/* Example use of the generated observer {P} ({prov.drive_name});",
            f" * generated by {prov.generator}.",
            " *",
            " *   make && ./example             a few periods at standstill, printed",
            " *   ./example samples.bin > y.bin  replay: per sample read float64 "
            + ", ".join(f.name for f in obs.meas),
            " *                                 and write float64 outputs then state (struct order)",
            " *",
            " * The replay lets you compare your build bit for bit with the Python evaluation of the same",
            " * CasADi step (sensorless.design.runtime.run_trajectory). */",
            "#include <stdio.h>",
            "#include <string.h>",
            "",
            f'#include "{P}.h"',
            "",
            f"static {P}_observer observer; /* one instance; a second one is just another variable */",
            "",
            "/* What a drive's PWM/ADC interrupt does every sampling period (fill `in` from the ADC and",
            " * the previous voltage reference, then use out.theta_hat, out.w_hat, out.u_c_d). */",
            f"static void control_isr(const {P}_input *in, {P}_output *out)",
            "{",
            f"    {P}_step(&observer, in, out);",
            "}",
            "",
            "int main(int argc, char **argv)",
            "{",
            f"    {P}_input in;",
            f"    {P}_output out;",
            "    int rc;",
            "    memset(&in, 0, sizeof in);",
            f"    rc = {P}_init(&observer, &{P}_default_params);",
            "    if (rc != 0) {",
            '        fprintf(stderr, "init failed: %d\\n", rc);',
            "        return 1;",
            "    }",
            "    if (argc < 2) {",
            "        int n;",
            "        for (n = 0; n < 8; ++n) {",
            "            control_isr(&in, &out);",
            '            printf("k=%d", n);',
            *show,
            '            printf("\\n");',
            "        }",
            "        return 0;",
            "    } else {",
            '        FILE *f = fopen(argv[1], "rb");',
            f"        double m[{n_m}], v[{n_v}];",
            "        if (f == NULL) {",
            "            perror(argv[1]);",
            "            return 1;",
            "        }",
            f"        while (fread(m, sizeof m[0], {n_m}, f) == {n_m}) {{",
            *get,
            "            control_isr(&in, &out);",
            *put,
            f"            fwrite(v, sizeof v[0], {n_v}, stdout);",
            "        }",
            "        fclose(f);",
            "        return 0;",
            "    }",
            "}",
            "",
        ]
    )


def _makefile(P: str) -> str:
    return "\n".join(
        [
            "# Generated by sensorless codegen: host example, and the observer object for a Cortex-M4F.",
            "CC = cc",
            "CFLAGS = -std=c99 -O2 -Wall -Wextra -Werror -pedantic",
            "ARM_CC = arm-none-eabi-gcc",
            "ARM_CFLAGS = -std=c99 -O2 -mthumb -mcpu=cortex-m4 -mfpu=fpv4-sp-d16 -mfloat-abi=hard \\",
            "             -Wall -Wextra -Werror -pedantic",
            "",
            "all: example",
            "",
            f"example: main.c {P}.c {P}.h",
            f"\t$(CC) $(CFLAGS) -o $@ main.c {P}.c -lm",
            "",
            f"{P}-m4.o: {P}.c {P}.h",
            f"\t$(ARM_CC) $(ARM_CFLAGS) -c -o $@ {P}.c",
            "",
            "clean:",
            f"\trm -f example {P}-m4.o",
            "",
            ".PHONY: all clean",
            "",
        ]
    )
