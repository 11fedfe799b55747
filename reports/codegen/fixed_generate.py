"""The files of ``sensorless codegen --precision fixed``: integer-only C of the step (docs/codegen.md).

``<prefix>.h`` (API, every field's format), ``<prefix>.c`` (init, step, integer helpers),
``<prefix>_formats.json`` (the formats and their reasons, machine-readable), an example ``main.c``
(replays raw int32 samples) and a ``Makefile`` (host build; ``make <prefix>-m0.o``: Cortex-M0+).
The formats come from the drive: :func:`fixed_model` runs the family's scenarios and the generic
checks in closed loop (fixed_ranges.py).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from sensorless.design.family import Drive, GainSet
from sensorless.reports.codegen.fixed_c import body, format_text, formats_json
from sensorless.reports.codegen.fixed_helpers import helpers, lit
from sensorless.reports.codegen.fixed_lowering import QUOT_BITS
from sensorless.reports.codegen.fixed_model import FixedModel
from sensorless.reports.codegen.fixed_ops import ATAN2_STEPS, CORDIC_STEPS, NOMINAL_BITS
from sensorless.reports.codegen.fixed_params import params_from_si
from sensorless.reports.codegen.fixed_poles import pole_shift
from sensorless.reports.codegen.fixed_products import (
    COARSE_QUOT_BITS,
    COARSE_ROOT_BITS,
    LIMITED_BITS,
    SHORT_PRODUCTS,
    SHORT_SPAN,
)
from sensorless.reports.codegen.fixed_ranges import MARGIN

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.runtime import RuntimeSetup
    from sensorless.design.scenario import Scenario
    from sensorless.reports.codegen.generate import Provenance

# the product and quotient sentences follow the lowering's switches (the header and the JSON state
# the methods the C uses: with the short products off, no product is a short one by the range rule)
_PRODUCTS = (
    "products of two signals: "
    + (
        f"where both fill their range (median over the runs >= 2^-{SHORT_SPAN} of it) or "
        if SHORT_PRODUCTS
        else ""
    )
    + (
        "where the product only reaches a division or a square root, one 32-bit product of operands "
        "rounded to 15 bits of twice their range (relative error <= 2^-13 each); where one operand "
        f"carries at most {LIMITED_BITS} bits (a {COARSE_ROOT_BITS}-bit root's), that one rounded to 15 "
        "bits and the product exact; else four 32-bit products of 16-bit halves, within 3 LSB"
    )
)
ERRORS = (
    f"atan2: vectoring CORDIC, {ATAN2_STEPS} steps, error <= atan(2^-{ATAN2_STEPS - 1}) + 24 LSB / |v| rad "
    "(|v| the raw magnitude; tests/common/test_fixed_point.py); "
    "sin/cos: odd polynomial of degree 7 on the angle folded "
    "to [-pi/2, pi/2], error <= 1e-6; cos/sin of an atan2: the CORDIC's rotations applied to (1/K, 0), "
    f"{CORDIC_STEPS} steps, error <= atan(2^-{CORDIC_STEPS - 1}) + 24 LSB / |v| + 1.1e-7; "
    "sqrt: integer square root of a 32-bit word (floor, 16 bits), of a "
    f"radicand of short products a {2 * COARSE_ROOT_BITS}-bit word (floor, {COARSE_ROOT_BITS} bits: "
    f"within 2^-{COARSE_ROOT_BITS} of the root's range); "
    f"a gain table: bisection, its fraction in Q15 within 2^-13; {_PRODUCTS}; a quotient by a runtime "
    f"divisor (clamped at half its smallest simulated value): floor, {min(QUOT_BITS, NOMINAL_BITS)} "
    f"significant bits at its range, {COARSE_QUOT_BITS} at its median where its operands are short "
    "products"
)


def range_scenarios(drive: Drive) -> list[Scenario]:
    """The scenarios whose runs give the fixed-point formats: the family's and the generic checks'."""
    from sensorless.design.family import Scaled
    from sensorless.design.registry import family_of
    from sensorless.design.scenario import builtin_names, generic_scenarios, load_scenario

    scenarios = [load_scenario(n, drive) for n in builtin_names(drive.kind)]
    if isinstance(family_of(drive), Scaled):  # the generic checks where the family gives their scales
        # without the unloaded low_hold: the formats stay sized (and their pole-shift figures taken) on the
        # runs they were before it (the preset's fixed-point data unchanged)
        scenarios += generic_scenarios(drive, hold=False)
    return scenarios


def fixed_model(drive: Drive, gains: GainSet, setup: RuntimeSetup) -> FixedModel:
    """The fixed-point model of ``setup`` with ranges from the family's scenarios and the generic checks."""
    model = FixedModel.of(drive, gains, range_scenarios(drive))
    model.data(setup)  # ValueError if no run ran this observer
    return model


def generate_fixed(
    setup: RuntimeSetup, model: FixedModel, provenance: Provenance, prefix: str
) -> dict[str, str]:
    """{file name: text} of the fixed-point C of ``setup`` (module docstring)."""
    fx = model.program(setup)
    obs = setup.observer
    poles = pole_shift(setup, fx, *model.data(setup))
    P, PU = prefix, prefix.upper()
    n_x = len(obs.state)

    def fields(ds: list[dict[str, Any]], what: str) -> list[str]:
        rows = []
        for d in ds:
            unit = next((f.unit for f in (*obs.state, *obs.meas, *obs.outputs) if f.name == d["name"]), "")
            why = f"; range {d['range']:.6g} {unit}: {d['reason']}" if "range" in d else f" [{unit}]"
            rows.append(f"    int32_t {d['name']}; /* {format_text(d['kind'], d['f'])}{why} */")
        return [f"typedef struct {{ /* {what} */", *rows, "}"]

    params_struct = ["typedef struct { /* gains and motor constants, raw int32 (value = raw * 2^-f) */"]
    params_struct += [
        f"    int32_t {d['name']}; /* {'binary angle' if d['kind'] == 'ang' else 'Q' + str(d['f'])}: "
        f"{d['expr']} = {d['value']:.6g} (raw {d['raw']}); range [{d['lo']}, {d['hi']}] */"
        for d in fx.params
    ] or ["    int32_t unused; /* the step reads no parameter */"]
    params_struct.append("}")
    banner = "\n".join(
        [
            f"/* {P}: {obs.title}, fixed point (32-bit integers, no floating point).",
            f" * Generated by {provenance.generator} (`sensorless codegen --precision fixed`); do not edit.",
            f" * Drive: {provenance.drive_name} ({provenance.drive_file}, "
            f"sha256 {provenance.drive_sha256[:16]}).",
            f" * Gains: {setup.gain_source}; discretization: {setup.discretization}. Gains and motor",
            f" * constants: {P}_params at run time (each field's Q format and admissible range below; "
            f"{P}_init",
            " * names a field outside its range); the variant's flags are compiled in.",
            " * Formats: raw int32 words; Qf: value = raw * 2^-f; binary angle: value = raw * pi / 2^31.",
            f" * Ranges: the state's bounds (runtime guard) and the checks' closed-loop runs x {MARGIN:g};",
            " * measurements and unbounded state are clamped at twice their range where they enter (bounded",
            " * state is the step's own: P_step writes only what its guard accepted, within them); results",
            f" * that a worst case could overflow saturate. Every format: {P}_formats.json. {ERRORS}.",
            " */",
        ]
    )
    h = [
        banner,
        f"#ifndef {PU}_H",
        f"#define {PU}_H",
        "#include <stdint.h>",
        "",
        *fields(fx.inputs[:n_x], "observer state"),
        f"{P}_state;",
        *fields(fx.inputs[n_x:], "measurements of one period"),
        f"{P}_input;",
        *fields(fx.outputs, "estimates of one period"),
        f"{P}_output;",
        *params_struct,
        f"{P}_params;",
        f"extern const {P}_params {P}_default_params;",
        f"typedef struct {{ {P}_state x; {P}_params prm; }} {P}_observer;",
        "",
        "/* Checks every field of *prm (0 to twice the drive's value: the formats are proven for that",
        " * range), copies them and sets the initial state. Returns 0, or k > 0 if the k-th field of",
        f" * {P}_params (1-based, struct order) is out of its range (the observer is then not set). */",
        f"int {P}_init({P}_observer *obs, const {P}_params *prm);",
        f"void {P}_step({P}_observer *obs, const {P}_input *in, {P}_output *out);",
        "",
        f"#endif /* {PU}_H */",
        "",
    ]
    init = []
    for j, d in enumerate(fx.params):
        if d["kind"] == "ang":
            continue  # a binary angle: every word is one
        init += [
            f"    if (prm->{d['name']} < {lit(d['lo'])} || prm->{d['name']} > {lit(d['hi'])}) {{",
            f"        return {j + 1};",
            "    }",
        ]
    init.append("    obs->prm = *prm;")
    init += [f"    obs->x.{d['name']} = {lit(v)};" for d, v in zip(fx.inputs[:n_x], fx.x0, strict=True)]
    init.append("    return 0;")
    # the defaults as a user's commissioning computes them (fixed_params: from the drive's SI values,
    # through the same graph): what the program was proven with, word for word
    words = params_from_si(setup, fx)
    if words != [d["raw"] for d in fx.params]:
        raise RuntimeError(f"{P}: params_from_si disagrees with the program's parameter words (a bug)")
    defaults = ", ".join(lit(w) for w in words) or "0"
    step = ["    " + line for line in body(fx, "obs->x", "in", "out", fx.wr)]
    c = [
        banner,
        f'#include "{P}.h"',
        "",
        helpers("\n".join(step)),
        f"const {P}_params {P}_default_params = {{{defaults}}};",
        "",
        f"int {P}_init({P}_observer *obs, const {P}_params *prm)",
        "{",
        *init,
        "}",
        "",
        f"void {P}_step({P}_observer *obs, const {P}_input *in, {P}_output *out)",
        "{",
        *step,
        "}",
        "",
    ]
    meas = [d["name"] for d in fx.inputs[n_x:]]
    values = [f"out.{o['name']}" for o in fx.outputs] + [f"obs.x.{d['name']}" for d in fx.inputs[:n_x]]
    main = "\n".join(
        [
            f"/* Example and replayer of {P}: `./example samples.bin [x0.bin [params.bin]] > y.bin` reads",
            f" * rows of {len(meas)} int32",
            " * (little-endian raw measurements) and writes, per row, the outputs then the state (int32). */",
            "#include <stdio.h>",
            f'#include "{P}.h"',
            "",
            "int main(int argc, char **argv)",
            "{",
            f"    {P}_observer obs;",
            f"    {P}_input in;",
            f"    {P}_output out;",
            f"    int32_t row[{len(meas)}];",
            f"    {P}_params prm = {P}_default_params;",
            "    int rc;",
            "    if (argc > 3) { /* the parameter struct: raw words in the struct's order */",
            '        FILE *h = fopen(argv[3], "rb");',
            "        if (h == NULL || fread(&prm, sizeof prm, 1, h) != 1) {",
            "            return 1;",
            "        }",
            "        fclose(h);",
            "    }",
            f"    rc = {P}_init(&obs, &prm);",
            "    if (rc != 0) {",
            '        fprintf(stderr, "init: parameter field %d out of its range\\n", rc);',
            "        return 2;",
            "    }",
            "    if (argc > 1) {",
            '        FILE *f = fopen(argv[1], "rb");',
            "        if (f == NULL) {",
            "            return 1;",
            "        }",
            "        if (argc > 2) { /* the initial state: raw words in the state's order */",
            '            FILE *g = fopen(argv[2], "rb");',
            f"            int32_t x[{n_x}];",
            "            if (g == NULL || fread(x, sizeof x, 1, g) != 1) {",
            "                return 1;",
            "            }",
            "            fclose(g);",
            *[f"            obs.x.{d['name']} = x[{k}];" for k, d in enumerate(fx.inputs[:n_x])],
            "        }",
            "        while (fread(row, sizeof row, 1, f) == 1) {",
            *[f"            in.{n} = row[{k}];" for k, n in enumerate(meas)],
            f"            {P}_step(&obs, &in, &out);",
            "            {",
            f"                const int32_t v[{len(values)}] = {{{', '.join(values)}}};",
            "                fwrite(v, sizeof v, 1, stdout);",
            "            }",
            "        }",
            "        fclose(f);",
            "        return 0;",
            "    }",
            *[f"    in.{n} = 0;" for n in meas],
            f"    {P}_step(&obs, &in, &out);",
            f'    printf("valid %d\\n", (int)out.{fx.outputs[-2]["name"]});',
            "    return 0;",
            "}",
            "",
        ]
    )
    make = "\n".join(
        [
            "CC ?= cc",
            "CFLAGS ?= -std=c99 -O2 -Wall -Wextra -Werror -pedantic",
            "example: main.c " + f"{P}.c {P}.h",
            f"\t$(CC) $(CFLAGS) -o $@ main.c {P}.c",
            f"{P}-m0.o: {P}.c {P}.h",
            f"\tarm-none-eabi-gcc $(CFLAGS) -Os -mcpu=cortex-m0plus -mthumb -c -o $@ {P}.c",
            "",
        ]
    )
    meta = {
        "params": [{k: v for k, v in d.items() if k != "recipe"} for d in fx.params],
        "format": "sensorless-fixed-point/1",
        "observer": obs.name,
        "drive": provenance.drive_name,
        "drive_sha256": provenance.drive_sha256,
        "generator": provenance.generator,
        "margin": MARGIN,
        "methods": ERRORS,
        "poles": poles,
    }
    return {
        f"{P}.h": "\n".join(h),
        f"{P}.c": "\n".join(c),
        f"{P}_formats.json": formats_json(fx, meta),
        "main.c": main,
        "Makefile": make,
    }
