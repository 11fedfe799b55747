"""The fixed-point parameter struct from SI values: the host (commissioning) side of `P_params`.

A field of the generated `P_params` is a coefficient that combines parameters (T_s k_p, 6 psi_pm,
T_s 2^18 / pi, ...) in the field's own Q format. A user who changes a motor constant or a gain calls
:func:`params_from_si` with the new SI values and gets every field's raw word, computed from the same
graph the C was generated from (each field's recipe: a parameter node of the double step's graph,
times a scale or its reciprocal), in the formats of the generated C. A value outside a field's
admissible range (0 to twice the generated value: what the program's worst cases were proven for) is
refused with the field named: regenerate the C for that drive instead.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from sensorless.reports.codegen.fixed_format import word
from sensorless.reports.codegen.fixed_program import FixedStep, step_graph
from sensorless.reports.codegen.fixed_ranges import evaluate

if TYPE_CHECKING:  # typed by name only
    from sensorless.design.runtime import RuntimeSetup


def params_from_si(
    setup: RuntimeSetup, fx: FixedStep, values: dict[str, float] | None = None, gain: np.ndarray | None = None
) -> list[int]:
    """The raw words of ``fx``'s parameter struct (struct order) for the parameters of ``setup`` with
    ``values`` (SI, by the observer's parameter names) replacing the drive's, and the schedule's gain
    vector ``gain`` (default: the set-up's). ``fx`` is the program the C was generated from
    (``fixed_model(...).program(setup)``). Raises ValueError naming a field out of its range or an
    unknown parameter name."""
    obs = setup.observer
    p = np.array(setup.p, dtype=float).ravel()
    names = [f.name for f in obs.params]
    for name, v in (values or {}).items():
        if name not in names:
            raise ValueError(f"params_from_si: unknown parameter {name!r} (known: {', '.join(names)})")
        p[names.index(name)] = float(v)
    g = np.array(setup.gain if gain is None else gain, dtype=float).ravel()
    nodes, _ = step_graph(setup)
    want = {int(d["recipe"][0]) for d in fx.params}
    val = evaluate(nodes, {2: p, 3: g}, want) if want else {}
    raws = []
    for d in fx.params:
        node, scale, inverse = d["recipe"]
        v = float(np.asarray(val[node]).ravel()[0])
        c = scale / v if inverse else scale * v
        raw = word(c, d["kind"], d["f"])
        if not d["lo"] <= raw <= d["hi"]:
            raise ValueError(
                f"params_from_si: field {d['name']} = {d['expr']} = {c:.6g} is outside the range the "
                f"generated C was proven for (raw {d['lo']}..{d['hi']}, Q{d['f']}): regenerate the C"
            )
        raws.append(int(raw))
    return raws
