"""A runtime observer wrapped into another one: the shared builder of the I-f start and the speed ramp.

symbolic/startup.py (the open-loop I-f start) and symbolic/speed_ramp.py (the speed reference's rate
limiter) each compose a :class:`~sensorless.symbolic.runtime.RuntimeObserver` with more state,
parameters, measurements and outputs. What is the same for both is here: the step built per
discretization around the wrapped observer's own step (called with the wrapper's first parameters and
the scheduled gains ``lam`` as given), the initial state and the steady state built from the wrapped
observer's, and the wrapped observer's fields passed through (its gain schedule, discretizations,
the C API's texts extended). What each wrapper adds is its own three expressions.
"""

from __future__ import annotations

from collections.abc import Callable

import casadi as ca
from sensorless.symbolic.frames import Sym
from sensorless.symbolic.runtime import Field, RuntimeObserver, core_function

# the wrapped observer's step on this period: (its state, its measurements) -> (x_next, y), with the
# wrapper's first parameters (the wrapped observer's) and the scheduled gains as given
InnerStep = Callable[[Sym, Sym], tuple[Sym, Sym]]


def wrap_observer(
    obs: RuntimeObserver,
    *,
    suffix: str,
    title: str,
    state: tuple[Field, ...],
    meas: tuple[Field, ...],
    params: tuple[Field, ...],
    outputs: tuple[Field, ...],
    step: Callable[[InnerStep, Sym, Sym, Sym], tuple[Sym, Sym]],
    initial: Callable[[Sym], Sym],
    steady: Callable[[Sym, Sym, Sym], Sym] | None,
    doc_init: str,
    doc_in: str | None,
    doc_out: str,
) -> RuntimeObserver:
    """The observer ``obs`` wrapped: named ``<obs.name>_<suffix>``, with the vectors given.

    ``step(inner, x, meas, p) -> (x_next, y)`` is the wrapper's step on its own vectors, ``inner`` the
    wrapped observer's (above); ``initial(x0) -> x0`` the wrapper's initial state from the wrapped
    observer's; ``steady(x, p, op) -> x`` its steady state at the operating point ``op`` from the
    wrapped observer's (not used where ``obs`` has none). ``title``, ``doc_init`` and ``doc_out`` extend
    the wrapped observer's texts; ``doc_in`` too (None: the measurements are the wrapped observer's)."""
    n_p = len(obs.params)

    def make(disc: str) -> ca.Function:
        core = obs.core(disc)

        def wrapped_step(x: Sym, m: Sym, p: Sym, lam: Sym | None = None) -> tuple[Sym, Sym]:
            lam_in = lam if lam is not None else ca.SX(0, 1)

            def inner(x_in: Sym, m_in: Sym) -> tuple[Sym, Sym]:
                return core(x_in, m_in, p[:n_p], lam_in)

            return step(inner, x, m, p)

        return core_function(f"{obs.name}_{suffix}_{disc}", wrapped_step, state, meas, params, obs.lam)

    def initial_fn() -> ca.Function:
        p = ca.SX.sym("p", len(params))
        x0 = initial(obs.initial_state()(p[:n_p]))
        return ca.Function(f"{obs.name}_{suffix}_init", [p], [x0], ["p"], ["x0"])

    steady_fn = None
    if obs.steady_state is not None and steady is not None:
        inner_steady = obs.steady_state

        def steady_fn() -> ca.Function:
            p, op = ca.SX.sym("p", len(params)), ca.SX.sym("op", 4)
            x = steady(inner_steady()(p[:n_p], op), p, op)
            return ca.Function(f"{obs.name}_{suffix}_steady", [p, op], [x])

    return RuntimeObserver(
        name=f"{obs.name}_{suffix}",
        title=f"{obs.title}, {title}",
        state=state,
        meas=meas,
        params=params,
        outputs=outputs,
        lam=obs.lam,
        schedule_state=obs.schedule_state,
        core=make,
        initial_state=initial_fn,
        discretizations=obs.discretizations,
        steady_state=steady_fn,
        doc_init=f"{obs.doc_init}; {doc_init}",
        doc_in=obs.doc_in if doc_in is None else f"{obs.doc_in}; {doc_in}",
        doc_out=f"{obs.doc_out}; {doc_out}",
    )
