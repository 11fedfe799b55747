"""C code generation of a runtime observer: a typed C99 API around the printed CasADi step (docs/codegen.md).

``generate(setup, ...)`` returns the files of one observer as text: ``<prefix>.h`` (types and API),
``<prefix>.c`` (init, step, gain schedule), an example ``main.c`` (also a trajectory replayer) and a
``Makefile``, rendered from the Jinja2 templates in ``templates/`` (the way acados generates its C).
The arithmetic of the step, of the parameter-derived coefficients and of a closed-form gain schedule
comes from the observer's registered ``casadi.Function`` (symbolic/runtime.py) through
:mod:`sensorless.reports.codegen.c_emit`; the templates hold only plumbing (structs, calls, checks) and
the generic linear interpolation of a tuned gain table. Any family's runtime observer works the same
way. No heap, no globals, no CasADi at runtime. Output is a pure function of the inputs (no dates), so
two runs give byte-identical files.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from typing import Any

import jinja2
import numpy as np
from sensorless.design.runtime import RuntimeSetup
from sensorless.reports.codegen.c_emit import Precision, emit
from sensorless.symbolic.runtime import REJECTS, RESET, VALID, X_MAX, Field, RuntimeObserver

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


EXAMPLE_FILES = ("main.c", "Makefile")  # the example program and its build, beside the observer's files


def output_names(prefix: str) -> tuple[str, ...]:
    """The files :func:`generate` writes for ``prefix``."""
    return (f"{prefix}.h", f"{prefix}.c", *EXAMPLE_FILES)


PREFIX_MAX = 53  # the longest prefix: 63 significant characters of a C99 identifier, less its suffixes


def check_prefix(prefix: str) -> None:
    """ValueError unless ``prefix`` is a C identifier whose files do not collide with the example's."""
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", prefix):
        raise ValueError(f"prefix {prefix!r} is not a C identifier")
    if len(prefix) > PREFIX_MAX:
        raise ValueError(
            f"prefix of {len(prefix)} characters: at most {PREFIX_MAX} (C99 guarantees {PREFIX_MAX + 10} "
            "significant characters of an identifier, and the prefix gets suffixes such as _params)"
        )
    clash = sorted(set(output_names(prefix)[:2]) & set(EXAMPLE_FILES))
    if clash:
        raise ValueError(f"prefix {prefix!r}: {clash[0]} is also the example program's file; choose another")


@functools.cache
def _templates() -> jinja2.Environment:
    return jinja2.Environment(
        loader=jinja2.PackageLoader("sensorless.reports.codegen", "templates"),
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        undefined=jinja2.StrictUndefined,
        autoescape=False,  # C, not HTML
    )


def _comment(text: str) -> str:
    return text.replace("*/", "* /")


def _struct(name: str, fields: list[tuple[str, str, str]], what: str) -> dict[str, Any]:
    width = max((len(n) for n, _, _ in fields), default=0)
    rows = [{"name": n, "unit": u, "doc": _comment(d), "pad": " " * (width - len(n))} for n, u, d in fields]
    if not rows:
        rows = [{"name": "unused_", "unit": "1", "doc": "(no fields)", "pad": ""}]
    return {"name": name, "what": what, "fields": rows}


def _f(fields: tuple[Field, ...]) -> list[tuple[str, str, str]]:
    return [(f.name, f.unit, f.doc) for f in fields]


def _bounds(obs: RuntimeObserver, p: np.ndarray) -> list[dict[str, str]]:
    """The state's bounds for the header: field, expression, value with the default parameters."""
    values = np.asarray(obs.bounds()(p)).ravel()
    return [
        {"name": f.name, "text": f.bound, "value": f"{v:.6g}", "unit": f.unit}
        for f, v in zip(obs.state[:-1], values, strict=False)
        if f.bound
    ]


def _check(name: str, check: str, prec: Precision) -> str:
    v = f"prm->{name}"
    zero, one = prec.lit(0.0), prec.lit(1.0)
    return {
        "positive": f"!({v} > {zero})",
        "nonnegative": f"!({v} >= {zero})",
        "flag": f"!({v} == {zero} || {v} == {one})",
        "any": f"!isfinite({v})",
    }[check]


def _table(setup: RuntimeSetup, P: str, prec: Precision, n_lam: int) -> dict[str, Any]:
    """Const arrays of a tabulated schedule: breakpoints, values of each scheduled gain, 1/spacing."""
    sch = setup.schedule
    grid = np.asarray(sch.grid, dtype=float)
    n = grid.size
    vals = np.asarray(sch.params, dtype=float).reshape(n_lam, n)
    unit = setup.observer.state[setup.observer.index("state", setup.observer.schedule_state)].unit

    def arr(name: str, v: np.ndarray, u: str, inv: bool = False) -> dict[str, Any]:
        return {"name": name, "unit": u, "data": ", ".join(prec.lit(float(x)) for x in v), "inv": inv}

    arrays = [arr(f"{P}_gain_w", grid, unit)]
    arrays += [arr(f"{P}_gain_l{j + 1}", vals[j], setup.observer.lam[j].unit) for j in range(n_lam)]
    arrays.append(arr(f"{P}_gain_inv_dw", 1.0 / np.diff(grid), f"1/({unit}); 1 / (w[j+1] - w[j])", inv=True))
    return {"n": n, "arrays": arrays, "magnitude": sch.interpolation() is True, "fabs": prec.fn("fabs")}


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
    P = prefix or c_identifier(provenance.drive_name)
    check_prefix(P)
    sch = setup.schedule
    n_lam = len(obs.lam)
    if (sch is None) != (n_lam == 0):
        raise ValueError(f"{obs.name}: a schedule is needed exactly when the observer has scheduled gains")
    table = sch is not None and len(sch.grid) > 0

    core = obs.core(setup.discretization)
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
    gain_fields = [] if sch is None or table else _f(sch.fields)
    law = None
    if sch is not None and not table:
        law = emit(
            sch.law,
            prec=prec,
            runtime_in={0: [obs.schedule_state]},
            param_in={1: [f"prm->{n}" for n, _, _ in gain_fields]},
            out={0: [f"*{f.name}" for f in obs.lam]},
            coef="k",
            coef_offset=step.n_coef,
            prefix="g",
        )
    n_coef = step.n_coef + (law.n_coef if law else 0)
    x0 = emit(
        obs.initial_state(),
        prec=prec,
        runtime_in={0: [f"prm->{f.name}" for f in obs.params]},
        param_in={},
        out={0: [f"obs->x.{f.name}" for f in obs.state]},
        coef="k",
        prefix="x",
    )
    banner = "\n".join(
        [
            f"/* {P}: {obs.title}.",
            f" * Generated by {provenance.generator} (`sensorless codegen`); do not edit, regenerate.",
            f" * Drive: {provenance.drive_name} ({provenance.drive_file}, "
            f"sha256 {provenance.drive_sha256[:16]}).",
            f" * Gains: {_comment(setup.gain_source)}"
            + (f"; {sch.text}." if sch is not None and sch.text else "."),
            f" * Discretization: {setup.discretization}; precision: {prec.real}. "
            "Plain C99, no heap, no globals.",
            " */",
        ]
    )
    pvals = dict(setup.params)
    if gain_fields:
        pvals.update(zip([n for n, _, _ in gain_fields], sch.params, strict=True))
    param_fields = _f(obs.params) + gain_fields
    checks = [(f.name, f.check) for f in obs.params] + [(n, "any") for n, _, _ in gain_fields]
    sched_state = obs.schedule_state or ""
    ctx: dict[str, Any] = {
        "banner": banner,
        "P": P,
        "PU": P.upper(),
        "R": f"{P}_real",
        "real": prec.real,
        "zero": prec.lit(0.0),
        "drive_name": provenance.drive_name,
        "generator": provenance.generator,
        "n_state": len(obs.state),
        "n_output": len(obs.outputs),
        "n_coef": max(n_coef, 1),
        "n_coef_used": n_coef,
        "structs": [
            _struct(
                f"{P}_params", param_fields, "Parameters, SI units. Fill from the drive: see the defaults."
            ),
            _struct(
                f"{P}_state",
                _f(obs.state),
                f"Observer state (public: read it freely; {P}_step keeps it within its bounds).",
            ),
            _struct(f"{P}_input", _f(obs.meas), "Measurements of one sampling period."),
            _struct(f"{P}_output", _f(obs.outputs), "Estimates and signals of one sampling period."),
        ],
        "reset_text": obs.doc_init,
        "input_text": obs.doc_in,
        "output_text": obs.doc_out,
        "schedule": sch is not None,
        "table": _table(setup, P, prec, n_lam) if table else None,
        "law": law,
        "schedule_text": sch.text if sch is not None else "",
        "schedule_doc": "Scheduled observer gains" if sch is None else f"Observer gains, {sch.text}",
        "sched_state": sched_state,
        "sched_unit": obs.state[obs.index("state", sched_state)].unit if sch is not None else "",
        "lam_names": [f.name for f in obs.lam],
        "gain_source": _comment(setup.gain_source),
        "defaults": [{"name": n, "value": prec.lit(float(pvals[n]))} for n, _, _ in param_fields],
        "checks": [{"name": n, "test": _check(n, c, prec)} for n, c in checks],
        "step": step,
        "x0": x0,
        "meas_names": [f.name for f in obs.meas],
        "output_names": [f.name for f in obs.outputs],
        "state_names": [f.name for f in obs.state],
        "n_values": len(obs.outputs) + len(obs.state),
        "show": [
            {"name": f.name, "unit": "" if f.unit == "1" else " " + f.unit}
            for f in obs.outputs[:5] + obs.outputs[-2:]
        ],
        "bounds": _bounds(obs, setup.p),
        "free": [f.name for f in obs.state[:-1] if not f.bound],
        "rejects": REJECTS.name,
        "reset_after": obs.state[-1].bound,
        "reset_define": obs.state[-1].bound if obs.state[-1].bound.isdigit() else "",
        "x_max": f"{X_MAX:g}",
        "valid": VALID.name,
        "reset": RESET.name,
    }
    env = _templates()
    return {
        f"{P}.h": env.get_template("observer.h.j2").render(ctx),
        f"{P}.c": env.get_template("observer.c.j2").render(ctx),
        "main.c": env.get_template("main.c.j2").render(ctx),
        "Makefile": env.get_template("Makefile.j2").render(ctx),
    }
