"""The fixed-point step against the double one in closed loop, on every built-in scenario of a preset.

    python benchmarks/bench_fixed_accuracy.py [PRESET ...] [--generic] [--compile]

(default: piippo2008 deangelo2006 outrunner270 hubmotor48). For each preset the fixed-point model is built as
``codegen --precision fixed`` builds it (reports/codegen/fixed_generate.fixed_model: the formats from
every scenario and the generic checks), and every built-in scenario of the drive's kind
(``--generic``: the generic scenarios too) runs twice in closed loop, with the double step and with
the fixed-point step in its place (design/runtime.step_variant, the SX twin of the C: bit for bit the
integer model, tests/common/test_fixed_point.py). Printed per scenario, in degrees electrical, the
difference of the two runs' angle errors (wrapped): its largest value at steady state (the last 20 %
of the run, as the closed-loop tests take it; the limit is 0.2 deg) and over the whole run (the
transients), and each run's verdict by the time-domain checks' limits (reports/time_domain.judge:
peak angle error 30 deg, final speed error 2 % of base, no rejection, position held) with its peak
|theta_err|. A scenario on which the double step itself fails a check is marked: the comparison there
is between two runs that lost the position.

This is where every scenario is covered: a deangelo2006 paper scenario costs 2-8 s CPU (the two
runs), too much for the suite (150 s); the suite's closed-loop tests run one scenario (or a segment)
per family. CPU (measured, warm compile cache): the built-in scenarios piippo2008 ~20 s, deangelo2006
~25 s, outrunner270 ~2 s, hubmotor48 ~2 s; --generic adds ~5 s, ~65 s and ~2 s (piippo2008,
deangelo2006, outrunner270).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from sensorless.design.drive import load_drive
from sensorless.design.registry import family_of
from sensorless.design.runtime import step_variant
from sensorless.design.scenario import builtin_names, generic_scenarios, load_scenario
from sensorless.design.simulate import simulate
from sensorless.reports.codegen.fixed_generate import fixed_model
from sensorless.reports.time_domain import judge

PRESETS = ["piippo2008", "deangelo2006", "outrunner270", "hubmotor48"]
STEADY = 0.8  # steady state: t > STEADY * t_end
LIMIT = 0.2  # deg electrical: the fixed-point step's stated accuracy (docs/codegen.md)


def _verdict(tr, sc, base_w: float) -> tuple[str, float]:
    _metrics, failed, problems = judge(tr, sc, base_w)
    peak = float(np.degrees(np.max(np.abs(np.angle(np.exp(1j * np.asarray(tr["theta_err"])))))))
    return ("pass" if not failed and not problems else "fail: " + "; ".join([*failed, *problems])[:70]), peak


def preset_rows(name: str, generic: bool, compile: bool) -> list[dict]:
    d = load_drive(name)
    fam = family_of(d)
    t0 = time.process_time()
    model = fixed_model(d, None, fam.runtime(d, fam.gains(d)))
    cpu = time.process_time() - t0
    print(f"# {name}: fixed-point model (codegen's formats) built in {cpu:.1f} s CPU", flush=True)
    scenarios = [load_scenario(n, d) for n in builtin_names(d.kind)]
    if generic:
        scenarios += generic_scenarios(d, hold=False)
    rows = []
    for sc in scenarios:
        t0 = time.process_time()
        try:
            ref = simulate(d, sc, compile=compile)
            with step_variant(model.variant):
                fix = simulate(d, sc, compile=compile)
        except Exception as e:  # a scenario the drive cannot run (said, not hidden)
            print(f"{name:13s} {sc.name:12s} not run: {str(e)[:90]}", flush=True)
            continue
        e = np.degrees(np.angle(np.exp(1j * (np.asarray(fix["theta_err"]) - np.asarray(ref["theta_err"])))))
        steady = fix.t > STEADY * fix.t[-1]
        base_w = float(d.w_base)
        vd, pd = _verdict(ref, sc, base_w)
        vf, pf = _verdict(fix, sc, base_w)
        row = {
            "preset": name,
            "scenario": sc.name,
            "duration": float(fix.t[-1]),
            "steady": float(np.abs(e[steady]).max()),
            "whole": float(np.abs(e).max()),
            "double": vd,
            "fixed": vf,
            "peak_double": pd,
            "peak_fixed": pf,
            "cpu": time.process_time() - t0,
        }
        rows.append(row)
        ok = "ok" if row["steady"] <= LIMIT else "OVER"
        if vd != "pass":
            ok += " (double step fails)"
        print(
            f"{name:13s} {sc.name:12s} {row['duration']:5.2f} s  steady {row['steady']:8.4f}  whole "
            f"{row['whole']:8.4f}  peak |err| dbl {pd:6.2f} fix {pf:6.2f}  {ok:4s}  double: {vd[:40]}  "
            f"fixed: {vf[:40]}  ({row['cpu']:.0f} s CPU)",
            flush=True,
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("presets", nargs="*", default=PRESETS)
    ap.add_argument("--generic", action="store_true", help="the generic scenarios too")
    ap.add_argument("--compile", action="store_true", help="the loops as native code (else CasADi's VM)")
    a = ap.parse_args()
    rows = []
    for p in a.presets:
        rows += preset_rows(p, a.generic, a.compile)
    print()
    print("| preset | scenario | s | steady [deg] | whole run [deg] | double step | fixed step |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['preset']} | {r['scenario']} | {r['duration']:.2f} | {r['steady']:.4f} | "
            f"{r['whole']:.4f} | {r['double']} ({r['peak_double']:.2f} deg) | "
            f"{r['fixed']} ({r['peak_fixed']:.2f} deg) |"
        )
    over = [r for r in rows if r["steady"] > LIMIT and r["double"] == "pass"]
    print(f"\n{len(rows)} runs; over {LIMIT} deg at steady state where the double step passes: {len(over)}")


if __name__ == "__main__":
    main()
