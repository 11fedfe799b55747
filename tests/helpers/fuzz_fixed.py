"""Test helper: fuzzing the fixed-point C (`codegen --precision fixed`) of any runtime observer under
sanitizers, and its recovery - the counterpart of tests/helpers/fuzz.py (the float and double C).

:func:`fixed_fuzz` builds the generated replayer (main.c + the step, raw int32 samples in, outputs and
state out) with ``-fsanitize=address,undefined`` (every finding fatal: a signed overflow, which the
lowering's worst-case analysis rules out, ends it) and runs clean segments of a motor (rows i_alpha,
i_beta, u_alpha, u_beta, theta, w), each after a hostile burst: any int32 words, plausible-looking
garbage within 3x the clean samples' words, the extreme words (+-2^31, 0, -1), or one channel at an
extreme with the others clean. An int32 word has no NaN or Inf: the float fuzz's non-finite samples
are the extreme words here (what a saturated ADC or a wrong scale gives). It checks on every step the
header's promises (valid and reset 0 or 1, the state's bounded fields within their bounds) and in every
clean segment, from ``recover`` samples on to its end, valid = 1 with the angle and the speed back
(not required where a ``held`` state field starts the segment beyond its threshold, as in fuzz.py);
and that the C equals the integer model (fixed_model.step_raw) bit for bit on the whole run.

:func:`segment_model`: the fixed-point model whose formats come from the double step's run over the
clean segments (fixed_ranges: the runs' ranges x 2, the state bounds), a cheap stand-in for the
scenarios' runs that ``codegen`` takes (fixed_generate.fixed_model), for a test that needs the formats
to cover the segments' operating points.
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import numpy as np
from sensorless.design.runtime import run_trajectory
from sensorless.reports.codegen.fixed_model import step_raw

from helpers.fuzz import CC, SANITIZE_O0

STRICT = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic"]


def segment_model(setup: Any, segments: np.ndarray) -> Any:
    """The fixed-point model of ``setup`` with its formats from the double step over ``segments``
    (n_seg x n x 6), run back to back from the initial state (the jumps between segments are
    recoveries: their transients are in the ranges too)."""
    from sensorless.reports.codegen.fixed_model import FixedModel

    meas = np.concatenate(list(segments[:, :, :4]), axis=0)
    xs, _ = run_trajectory(setup, meas)
    x_before = np.vstack([np.asarray(setup.initial_state(), float).ravel()[None], xs[:-1]])
    return FixedModel({setup.observer.name: (x_before.T, meas.T)})


def fixed_fuzz(
    drive: Any,
    setup: Any,
    fx: Any,
    src: Path,
    segments: np.ndarray,
    *,
    recover: int,
    tol_theta: float,
    tol_w: float,
    seed: int,
    held: dict[str, float] | None = None,
    params: list[int] | None = None,
) -> dict[str, Any]:
    """Fuzz the fixed-point C written to ``src`` (the program ``fx`` of ``setup``) with ``segments``
    (module docstring); returns {"segments", "held_segments", "steps", "rejected", "resets",
    "worst_recovery"}. Asserts every promise; a segment not held must recover. ``params``: the
    parameter struct's raw words (the replayer's third file; default the drive's). The replayer is
    built once per directory."""
    P = drive.name
    exe = src / "fuzz"
    if not exe.exists():
        r = subprocess.run(
            [CC, *STRICT, *SANITIZE_O0, "-o", str(exe), str(src / "main.c"), str(src / f"{P}.c")],
            capture_output=True,
            text=True,
        )
        assert r.returncode == 0 and r.stderr == "", r.stderr
    rng = np.random.default_rng(seed)
    clean = [fx.to_raw(s[:, :4].T, "meas").T for s in segments]
    top = int(np.abs(np.vstack(clean)).max())
    parts, truth, starts, n = [], [], [], 0
    for k, c in enumerate(clean):
        kind, length = k % 4, int(rng.choice([1, 5, 20, 150, 400]))
        if kind == 0:
            b = rng.integers(-(2**31), 2**31, size=(length, 4))
        elif kind == 1:
            b = rng.integers(-3 * top, 3 * top + 1, size=(length, 4))
        elif kind == 2:
            b = rng.choice([-(2**31), 2**31 - 1, 0, -1], size=(length, 4))
        else:
            b = np.repeat(c[:1], length, axis=0)
            b[:, rng.integers(4)] = rng.choice([-(2**31), 2**31 - 1])
        parts += [b, c]
        truth.append(np.full((length, 2), np.nan))
        truth.append(segments[k][:, 4:6])
        starts.append(n + length)
        n += length + len(c)
    raw = np.vstack(parts)
    f = src / "fuzz.bin"
    np.ascontiguousarray(raw, dtype="<i4").tofile(f)
    args = [str(exe), str(f)]
    if params is not None:  # the initial state (*_init's) and the struct
        np.ascontiguousarray(fx.x0, dtype="<i4").tofile(src / "fuzz_x0.bin")
        np.ascontiguousarray(params, dtype="<i4").tofile(src / "fuzz_params.bin")
        args += [str(src / "fuzz_x0.bin"), str(src / "fuzz_params.bin")]
    r = subprocess.run(args, capture_output=True)
    assert r.returncode == 0, r.stderr.decode()[-3000:]
    y = np.frombuffer(r.stdout, "<i4").reshape(len(raw), -1)
    names = [o["name"] for o in fx.outputs]
    n_y = len(names)
    # the C is the integer model bit for bit on the whole hostile trajectory: each of its steps, from
    # its own previous state (fx.x0, *_init's, first), is the model's step (all at once, vectorized)
    prev = np.vstack([np.asarray(fx.x0, np.int64)[None], y[:-1, n_y:]]).T
    xn, yn = step_raw(fx, prev, np.asarray(raw, np.int64).T, params)
    assert int((y != np.hstack([yn.T, xn.T])).sum()) == 0, "the C differs from the integer model"
    valid, reset = y[:, names.index("valid")], y[:, names.index("reset")]
    assert set(np.unique(valid).tolist()) <= {0, 1} and set(np.unique(reset).tolist()) <= {0, 1}
    bounds = np.asarray(setup.observer.bounds()(setup.p), float).ravel()
    state = setup.observer.state
    for j, (fl, i) in enumerate(zip(state, fx.inputs, strict=False)):
        if fl.bound and i["kind"] == "fix":
            assert np.abs(y[:, n_y + j]).max() <= bounds[j] * 2.0 ** i["f"] * (1 + 1e-6) + 1, fl.name
    j_w = names.index("w_hat")
    th = y[:, names.index("theta_hat")] * np.pi / 2**31
    w = y[:, j_w] * 2.0 ** -fx.outputs[j_w]["f"]
    tr = np.vstack(truth)
    held_at = {state[k].name: k for k in range(len(state))}
    n_held, worst = 0, 0
    for s0, seg in zip(starts, segments, strict=True):
        x_start = y[s0 - 1, n_y:] if s0 > 0 else None
        is_held = x_start is not None and any(
            abs(x_start[held_at[h]] * 2.0 ** -fx.inputs[held_at[h]]["f"]) > thr
            for h, thr in (held or {}).items()
        )
        end = s0 + len(seg)
        e_th = np.abs(np.angle(np.exp(1j * (th[s0:end] - tr[s0:end, 0]))))
        ok = (valid[s0:end] == 1) & (e_th < tol_theta) & (np.abs(w[s0:end] - tr[s0:end, 1]) < tol_w)
        bad = np.flatnonzero(~ok)
        rec = 0 if bad.size == 0 else int(bad[-1]) + 1
        if is_held:
            n_held += 1
            continue
        assert rec <= recover, (s0, rec)
        worst = max(worst, rec)
    return {
        "segments": len(starts),
        "held_segments": n_held,
        "steps": len(raw),
        "rejected": int((valid == 0).sum()),
        "resets": int(reset.sum()),
        "worst_recovery": worst,
    }
