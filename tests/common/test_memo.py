"""The content-keyed memo of analyses (design/memo.py): a hit only on equal content, results no caller
can change, nothing memoized where the state outside the arguments says so."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from sensorless.design.memo import LABEL, by_content


@dataclasses.dataclass(frozen=True)
class Labelled:
    values: tuple
    source: str = dataclasses.field(default="", metadata=LABEL)


@dataclasses.dataclass(frozen=True)
class Result:
    values: np.ndarray


def counted(maxsize=2, when=lambda: True):
    calls = []

    @by_content(maxsize=maxsize, when=when)
    def f(spec, scale=1.0):
        calls.append(spec)
        return Result(np.array(spec["x"], float) * scale)

    return f, calls


def test_equal_content_is_one_computation_and_different_content_another():
    f, calls = counted()
    a = f({"x": [1.0, 2.0]})
    assert f({"x": [1.0, 2.0]}) is a  # another dict, the same content
    assert f({"x": [1.0, 2.0]}, scale=2.0).values.tolist() == [2.0, 4.0]  # a keyword is content too
    assert f({"x": [1.0, 3.0]}).values.tolist() == [1.0, 3.0]
    assert len(calls) == 3 and f.cache_info() == (1, 3)


def test_equal_content_is_one_computation_whichever_of_its_objects_are_one_object():
    # pickle writes an object met twice as a reference to the first: the key must not depend on
    # whether two equal strings or lists are the same object (a gain table read back from its file)
    f, calls = counted()
    name = "".join(["la", "mbda"])  # equal to the literal, another object
    literal = "lambda"
    assert name == literal and name is not literal
    values = [1.0, 2.0]
    a = f({"x": values, literal: values})  # one list twice, one string object
    assert f({"x": [1.0, 2.0], name: [1.0, 2.0]}) is a
    assert len(calls) == 1
    cyclic: list = []
    cyclic.append(cyclic)
    f({"x": [1.0], "cycle": cyclic})  # a cycle: not keyed (computed), never an error
    f({"x": [1.0], "cycle": cyclic})
    assert len(calls) == 3


def test_the_oldest_result_is_dropped_past_maxsize():
    f, calls = counted(maxsize=2)
    for x in (1.0, 2.0, 3.0, 1.0):
        f({"x": [x]})
    assert len(calls) == 4  # 1.0 was dropped when 3.0 came


def test_a_memoized_result_is_read_only():
    f, _ = counted()
    r = f({"x": [1.0]})
    with pytest.raises(ValueError):
        r.values[0] = 5.0


def test_nothing_is_memoized_where_when_says_no_or_the_arguments_do_not_pickle():
    f, calls = counted(when=lambda: False)
    f({"x": [1.0]})
    f({"x": [1.0]})
    assert len(calls) == 2
    g, calls = counted()
    g({"x": [1.0], "fn": lambda: 0})  # a lambda does not pickle
    g({"x": [1.0], "fn": lambda: 0})
    assert len(calls) == 2


def test_a_label_field_is_not_content_as_an_argument_or_a_keyword():
    calls = []

    @by_content()
    def total(g, scale=Labelled((1.0,))):
        calls.append(g)
        return Result(np.array(g.values) * scale.values[0])

    a = total(Labelled((1.0, 2.0), "tune/gains.json"))
    assert total(Labelled((1.0, 2.0), "/abs/tune/gains.json")) is a  # the same values, another name
    assert total(Labelled((1.0, 2.0), "x"), scale=Labelled((2.0,), "a")) is total(
        Labelled((1.0, 2.0), "y"), scale=Labelled((2.0,), "b")
    )
    assert total(Labelled((1.0, 3.0), "tune/gains.json")) is not a  # other values under the same name
    assert len(calls) == 3 and total.cache_info() == (2, 3)


def disk_counted():
    """A disk memo as a new process makes it: a fresh wrapper of the same function (same name)."""
    calls = []

    @by_content(disk=True)
    def kept(spec):
        calls.append(spec)
        return Result(np.array(spec["x"], float))

    return kept, calls


def test_a_result_kept_on_disk_serves_the_next_process_and_only_for_the_same_code(tmp_path, monkeypatch):
    from sensorless.design import memo

    monkeypatch.setenv("SENSORLESS_CACHE", str(tmp_path))
    monkeypatch.delenv("SENSORLESS_NO_DISK_MEMO", raising=False)
    first, calls1 = disk_counted()
    first({"x": [1.0, 2.0]})
    (kept,) = (tmp_path / "memo").iterdir()
    second, calls2 = disk_counted()  # "the next process": its own memo, empty
    b = second({"x": [1.0, 2.0]})
    assert calls1 == [{"x": [1.0, 2.0]}] and calls2 == [] and second.cache_info() == (1, 0)
    assert b.values.tolist() == [1.0, 2.0] and not b.values.flags.writeable
    assert second({"x": [1.0, 3.0]}).values.tolist() == [1.0, 3.0] and len(calls2) == 1  # other content
    kept.write_bytes(b"not a pickle")  # a damaged file: computed again, and written again
    third, calls3 = disk_counted()
    assert third({"x": [1.0, 2.0]}).values.tolist() == [1.0, 2.0] and len(calls3) == 1
    assert memo._disk_get(kept)[0]
    monkeypatch.setattr(memo, "fingerprint", lambda: b"other source")  # changed code: not reused
    fourth, calls4 = disk_counted()
    fourth({"x": [1.0, 2.0]})
    assert len(calls4) == 1
    monkeypatch.setenv("SENSORLESS_NO_DISK_MEMO", "1")
    fifth, calls5 = disk_counted()
    fifth({"x": [1.0, 2.0]})
    assert len(calls5) == 1


def test_the_fingerprint_changes_with_any_source_file(tmp_path, monkeypatch):
    import importlib.util
    import types

    from sensorless.design import memo

    for layer in ("symbolic", "design", "tuning", "reports"):
        (tmp_path / layer / "sub").mkdir(parents=True)
        (tmp_path / layer / "sub" / "m.py").write_text("x = 1\n")
    spec = lambda name: types.SimpleNamespace(submodule_search_locations=[str(tmp_path / name.split(".")[1])])  # noqa: E731
    monkeypatch.setattr(importlib.util, "find_spec", spec)

    def fp():
        memo.fingerprint.cache_clear()
        return memo.fingerprint()

    try:
        before = fp()
        assert fp() == before
        (tmp_path / "tuning" / "sub" / "m.py").write_text("x = 2\n")
        assert fp() != before
    finally:
        monkeypatch.undo()
        memo.fingerprint.cache_clear()


def test_kept_runs_quote_each_callers_label_and_run_once(monkeypatch):
    """design/simulate.py ``simulated``: the same drive, scenario and gains read under another label (the
    table's path as ``report`` names it, not as ``tune`` did) is one run, and its traces quote the label
    of the caller that asked, not of the first one."""
    from sensorless.design import simulate as sim
    from sensorless.design.gain_set import GainSet

    runs = []

    def fake(drive, scenario, gains):
        runs.append(gains.source)
        t = np.arange(3.0)
        meta = {"gain": gains.source, "startup": f"gains of {gains.source}", "scenario": scenario}
        return sim.Traces(t=t, data={"w": t * 2}, units={}, docs={}, meta=meta, wall_time=1.5)

    monkeypatch.setattr(sim, "simulate", fake)
    sim._kept.cache_clear()
    a = sim.simulated({"drive": 1}, "steps", GainSet("constant", {"k": 1.0}, "tune/gains.json"))
    b = sim.simulated({"drive": 1}, "steps", GainSet("constant", {"k": 1.0}, "/abs/tune/gains.json"))
    c = sim.simulated({"drive": 1}, "steps", GainSet("constant", {"k": 2.0}, "tune/gains.json"))
    assert runs == ["tune/gains.json", "tune/gains.json"]  # b was a's run, c another
    assert a.meta["gain"] == "tune/gains.json" and b.meta["gain"] == "/abs/tune/gains.json"
    assert b.meta["startup"] == "gains of /abs/tune/gains.json" and b.meta["scenario"] == "steps"
    assert b.data is a.data and a.wall_time == 0.0 and c.data["w"].tolist() == [0.0, 2.0, 4.0]
    sim._kept.cache_clear()


def built_loop(calls):
    """A builder as design/memo.py ``kept_function`` takes: a CasADi Function of structural arguments."""
    import casadi as ca
    from sensorless.design.memo import kept_function

    @kept_function
    def step_map(gain: float, n: int) -> ca.Function:
        calls.append((gain, n))
        x = ca.SX.sym("x", 2)
        step = ca.Function("step", [x], [ca.vertcat(ca.sin(x[1]) * gain, x[0] - x[1] / 3)])
        return step.mapaccum(n)

    return step_map


def test_a_kept_function_is_read_back_by_the_next_process_with_the_same_bits_and_code(tmp_path, monkeypatch):
    import casadi as ca

    monkeypatch.setenv("SENSORLESS_CACHE", str(tmp_path))
    monkeypatch.delenv("SENSORLESS_NO_DISK_MEMO", raising=False)
    calls1, calls2 = [], []
    first = built_loop(calls1)
    built = first(0.7, 5)
    assert first(0.7, 5) is built and calls1 == [(0.7, 5)]
    second = built_loop(calls2)  # "the next process": the first one's Function, from disk
    read = second(0.7, 5)
    assert calls2 == [] and read is not built and second(0.7, 5) is read
    assert read.name() == built.name() and read.name_in() == built.name_in()
    x0 = np.array([0.3, -1.1])
    assert np.array_equal(np.asarray(read(x0)), np.asarray(built(x0)))  # the same evaluation, bit for bit
    gen = [ca.CodeGenerator("f.c") for _ in range(2)]
    gen[0].add(built)
    gen[1].add(read)
    assert gen[0].dump() == gen[1].dump()  # the same C (design/compiled.py keys its libraries by it)
    assert np.asarray(second(0.8, 5)(x0)).shape == (2, 5) and calls2 == [(0.8, 5)]  # other arguments: built


def test_a_result_kept_by_its_content_is_computed_once_per_content(tmp_path, monkeypatch):
    # kept_result: for a computation whose own inputs do not pickle; keyed by the content the caller
    # names (its labels left out), read back by the next caller, recomputed for other content or code
    from sensorless.design import memo

    monkeypatch.setenv("SENSORLESS_CACHE", str(tmp_path))
    monkeypatch.delenv("SENSORLESS_NO_DISK_MEMO", raising=False)
    calls = []

    def compute(x):
        def run():
            calls.append(x)
            return Result(np.array(x, float))

        return run

    a = memo.kept_result("m", "f", (Labelled((1.0,), "a.toml"), [1.0]), compute([1.0]))
    b = memo.kept_result("m", "f", (Labelled((1.0,), "/abs/a.toml"), [1.0]), compute([9.0]))
    assert calls == [[1.0]] and b.values.tolist() == [1.0] and not b.values.flags.writeable
    memo.kept_result("m", "f", (Labelled((2.0,), "a.toml"), [1.0]), compute([2.0]))  # other content
    memo.kept_result("m", "g", (Labelled((1.0,), "a.toml"), [1.0]), compute([3.0]))  # another name
    assert calls == [[1.0], [2.0], [3.0]] and a.values.tolist() == [1.0]
    monkeypatch.setattr(memo, "fingerprint", lambda: b"other source")  # changed code: not reused
    memo.kept_result("m", "f", (Labelled((1.0,), "a.toml"), [1.0]), compute([4.0]))
    assert calls[-1] == [4.0]
    monkeypatch.setenv("SENSORLESS_NO_DISK_MEMO", "1")  # no disk memo: always computed
    c = memo.kept_result("m", "f", (Labelled((1.0,), "a.toml"), [1.0]), compute([5.0]))
    assert calls[-1] == [5.0] and not c.values.flags.writeable  # read-only whichever way it came
    lam = lambda: None  # noqa: E731  (content that cannot be pickled: computed)
    monkeypatch.delenv("SENSORLESS_NO_DISK_MEMO")
    memo.kept_result("m", "f", (lam,), compute([6.0]))
    memo.kept_result("m", "f", (lam,), compute([7.0]))
    assert calls[-2:] == [[6.0], [7.0]]
