"""design/forked.py: a function's value computed by a forked child is the value computed here; a child
that fails leaves the computation (and its exception) to this process; a value no longer wanted is
killed with its child."""

from __future__ import annotations

import os
import select

import numpy as np
import pytest
from sensorless.design import forked
from sensorless.design.poles import eigvals_batched

pytestmark = pytest.mark.skipif(not forked.forking(), reason="no fork here")


def _poles(seed: int) -> np.ndarray:
    # enough matrices for the poles' thread pool (design/poles.py): a child forked after the parent
    # started the pool's threads must start its own
    A = np.random.default_rng(seed).normal(size=(9000, 4, 4))
    return eigvals_batched(A)


def test_the_childs_value_is_the_value_computed_here():
    here = _poles(1)  # the pool's threads now run in this process
    p = forked.later(lambda: (os.getpid(), _poles(1), _poles(2)))
    assert p.forked
    # (a child waiting for the parent's pool threads, which a fork does not copy, would never write)
    assert select.select([p._child[1]], [], [], 60)[0], "the child hangs"
    pid, a, b = p.result()
    assert pid != os.getpid()  # computed elsewhere...
    np.testing.assert_array_equal(a, here)  # ...to the same bits
    np.testing.assert_array_equal(b, _poles(2))
    assert p.done() and p.result()[0] == pid  # kept


def test_a_failed_child_leaves_the_computation_here():
    calls = []

    def boom():
        calls.append(os.getpid())
        raise ValueError("bad input")

    p = forked.later(boom)
    with pytest.raises(ValueError, match="bad input"):
        p.result()  # the child failed: computed again here, whose exception is the caller's
    assert calls == [os.getpid()]  # (the child's own call was in the child)


def test_a_value_no_longer_wanted_is_killed_with_its_child():
    import time

    p = forked.later(lambda: time.sleep(60))
    pid = p._child[0]
    assert not p.done()
    p.cancel()
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # reaped


def test_without_fork_the_value_is_computed_here(monkeypatch):
    monkeypatch.setenv("SENSORLESS_NO_FORK", "1")
    p = forked.later(os.getpid)
    assert not p.forked and p.result() == os.getpid()


def test_a_computation_in_steps_keeps_the_childs_state_for_its_requests():
    """The child stays for follow-up requests (``then``), answered in order with what its first step
    built: here a pid and a counter only the child's copy of ``seen`` holds."""
    seen: list[int] = []

    def first():
        seen.append(0)
        return os.getpid()

    def then(x):
        seen.append(x)
        return os.getpid(), list(seen)

    p = forked.later(first, then=then)
    a, b = p.ask(5), p.ask(7)
    pid = p.result()
    assert pid != os.getpid()
    assert b() == (pid, [0, 5, 7]) and a() == (pid, [0, 5])  # in the child, in order, whatever is read first
    assert seen == []  # nothing ran here
    p.close()
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # ended and reaped
    # a child gone before a request: the reply is computed here
    q = forked.later(first, then=then)
    q.result()
    q.cancel()
    assert q.ask(3)() == (os.getpid(), [3])
