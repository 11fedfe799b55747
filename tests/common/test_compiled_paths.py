"""The analyses that run compiled Functions whatever their batch size (design/batch.py ``jit=True``,
design/compiled.py) give the same numbers, bit for bit, as CasADi's virtual machine: the whole
sampled drive's Newton solve as the reduced-order tuner runs it (design/drive_analysis.py), the
reduced-order observer's orbit and one-step maps (design/pmac_reduced_order/linearize.py). Each is
run twice, the second time with compilation switched off."""

from __future__ import annotations

import numpy as np
import pytest
from sensorless.design import batch, compiled, discrete
from sensorless.design.compiled import compiler
from sensorless.design.drive import load_drive
from sensorless.design.drive_analysis import linearize_drive
from sensorless.design.pmac_reduced_order.linearize import analyze
from sensorless.design.registry import family_of

pytestmark = pytest.mark.skipif(compiler() is None, reason="no C compiler: both paths are the VM")


def _vm(monkeypatch) -> None:
    """Compilation off from here on (the Functions cached with a compiled step rebuilt)."""
    monkeypatch.setattr(batch, "_compiled", lambda fn: fn)
    monkeypatch.setattr(discrete, "compiled", lambda fn: fn)
    monkeypatch.setattr(compiled, "compiled", lambda fn: fn)
    discrete.orbit_function.cache_clear()


def test_whole_drive_newton_compiled_is_the_vm(monkeypatch):
    drive = load_drive("deangelo2006")
    gains = family_of(drive).gains(drive)
    w = np.array([-0.3, 0.2, 0.5]) * drive.w_base
    t = np.array([0.5, -1.0, 0.0]) * drive.T_N
    fast = linearize_drive(drive, gains, w, t, jit=True)
    _vm(monkeypatch)
    slow = linearize_drive(drive, gains, w, t, jit=True)
    assert np.isfinite(fast.y).all()
    np.testing.assert_array_equal(fast.y, slow.y)
    np.testing.assert_array_equal(fast.J, slow.J)


def test_reduced_order_orbit_and_maps_compiled_are_the_vm(monkeypatch):
    drive = load_drive("deangelo2006")  # EMF harmonics: a window of one-step maps per point
    w, t = drive.rpm_to_w(np.array([-250.0, 1000.0])), np.array([5.0, -7.0])
    fast = analyze(drive, w, t, noise=True)
    _vm(monkeypatch)
    slow = analyze(drive, w, t, noise=True)
    assert np.isfinite(fast.poles_discrete).all()
    for a, b in (
        (fast.poles_discrete, slow.poles_discrete),
        (fast.noise, slow.noise),
        (fast.err_theta, slow.err_theta),
        (fast.ripple_w, slow.ripple_w),
    ):
        np.testing.assert_array_equal(a, b)


def test_a_library_two_processes_need_at_once_is_compiled_once(tmp_path, monkeypatch):
    """Two callers (here threads; pytest-xdist's workers on an empty cache) need one library at once: the
    first compiles it holding the library's lock, the second waits on that lock (seen in /proc/locks)
    and loads the first's library. The compiler is held until the second caller has either called it
    too or is waiting on the lock."""
    import threading
    import time
    from pathlib import Path

    import casadi as ca

    locks = Path("/proc/locks")
    if not locks.exists():
        pytest.skip("no /proc/locks: the second caller's wait cannot be seen")
    calls, release = tmp_path / "calls", tmp_path / "release"
    cc = tmp_path / "cc"
    hold = f'while [ ! -e "{release}" ]; do sleep 0.01; done'
    cc.write_text(f'#!/bin/sh\necho x >> "{calls}"\n{hold}\nexec {compiler()} "$@"\n')
    cc.chmod(0o755)
    monkeypatch.setenv("CC", str(cc))
    monkeypatch.setenv("SENSORLESS_CACHE", str(tmp_path / "cache"))
    x = ca.SX.sym("x")
    fn = ca.Function("needed_twice", [x], [2 * ca.sin(x)])
    done = []
    threads = [threading.Thread(target=lambda: done.append(compiled.compiled.__wrapped__(fn))) for _ in "ab"]

    def until(what, ready):  # (a deadline only so that a broken build cannot hang the suite)
        end = time.monotonic() + 120
        while not ready():
            assert time.monotonic() < end, what
            time.sleep(0.01)

    def n_calls():
        return len(calls.read_text().splitlines()) if calls.exists() else 0

    def waiting():  # a blocked lock request ("->") on the library's lock file
        lock = next((tmp_path / "cache" / "jit").glob("needed_twice_*.lock"), None)
        if lock is None:
            return False
        ino = f":{lock.stat().st_ino} "
        return any("->" in ln and ino in ln for ln in locks.read_text().splitlines())

    threads[0].start()
    until("the first caller runs the compiler", lambda: n_calls() == 1)
    threads[1].start()
    until("the second caller compiles or waits", lambda: n_calls() == 2 or waiting())
    release.touch()
    for t in threads:
        t.join()
    assert n_calls() == 1
    assert len(done) == 2 and all(f.is_a("External") for f in done)
    assert [float(f(0.3)) for f in done] == [float(fn(0.3))] * 2


def test_a_loop_runs_on_the_vm_until_compiling_pays_and_gives_the_same_bits_compiled(monkeypatch):
    """simulate runs a loop on CasADi's VM until the process has run it for JIT_MIN_STEPS periods in
    all (an empty cache here), then compiled: the traces are the same bits either way."""
    import dataclasses

    from sensorless.design import simulate as sim
    from sensorless.design.scenario import load_scenario

    drive = load_drive("deangelo2006")
    sc = dataclasses.replace(load_scenario("fig3", drive), duration=0.05)
    calls = []
    real = sim.compiled_chunk
    monkeypatch.setattr(sim, "compiled_chunk", lambda loop, n: calls.append(n) or real(loop, n))
    monkeypatch.setattr(sim, "is_cached", lambda fn: False)
    monkeypatch.setattr(sim, "wanted_elsewhere", lambda fn: False)  # (no other process has run it)
    monkeypatch.setattr(sim, "indexed", lambda key: None)  # (nor compiled it)
    monkeypatch.setattr(sim, "_STEPS", {})
    vm = sim.simulate(drive, sc)
    n = vm.meta["samples"]
    assert calls == [] and n < sim.JIT_MIN_STEPS
    monkeypatch.setattr(sim, "JIT_MIN_STEPS", 2 * n)  # the second run reaches it
    fast = sim.simulate(drive, sc)
    assert calls and set(calls) == {sim.CHUNK}
    assert np.isfinite(vm["w_hat"]).all() and set(vm.data) == set(fast.data)
    for k in vm.data:
        np.testing.assert_array_equal(vm[k], fast[k])


def test_a_function_another_process_asked_for_is_wanted_elsewhere(tmp_path, monkeypatch):
    """The first asking is recorded with its process; asking again from that process is not another's;
    a record left by another process is."""
    import casadi as ca

    monkeypatch.setenv("SENSORLESS_CACHE", str(tmp_path))
    x = ca.SX.sym("x")
    fn = ca.Function("asked_for", [x], [3 * x])
    assert not compiled.wanted_elsewhere(fn) and not compiled.wanted_elsewhere(fn)
    (mark,) = (tmp_path / "jit").glob("asked_for_*.wanted")
    mark.write_text("1")  # (pid 1: init, not this process)
    assert compiled.wanted_elsewhere(fn)


def test_a_compiled_function_recorded_under_a_key_is_loaded_by_it_without_building_it(tmp_path, monkeypatch):
    """design/compiled.py ``index``/``indexed`` (a simulation's chunk in the next process): the record
    gives the same library, so the same bits; another key, or a library since removed, gives None."""
    import casadi as ca

    monkeypatch.setenv("SENSORLESS_CACHE", str(tmp_path))
    x = ca.SX.sym("x")
    fn = ca.Function("recorded", [x], [ca.sin(x) / 3])
    assert compiled.indexed(b"key") is None
    compiled.index(b"key", fn)  # not compiled yet: nothing to record
    assert compiled.indexed(b"key") is None
    lib = compiled.compiled(fn)
    compiled.index(b"key", fn)
    got = compiled.indexed(b"key")
    assert got is not None and got.is_a("External") and got.name() == "recorded"
    assert float(got(0.7)) == float(lib(0.7)) == float(fn(0.7))
    assert compiled.indexed(b"other key") is None
    (so,) = (tmp_path / "jit").glob("recorded_*.so")
    so.unlink()
    assert compiled.indexed(b"key") is None
