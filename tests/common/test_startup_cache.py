"""design/pmsm_drive.py ``startup_values`` remembers its result per drive object and gain values (a
command builds several runs of one drive at one gain set): the same drive object and equal gains give
the computed result without computing again, any other drive object or gain value computes anew, and
a caller's changes to a returned dict do not reach the next caller."""

import numpy as np
from sensorless.design import pmsm_drive
from sensorless.design.family import GainSet


def test_cache_hits_only_the_same_drive_and_gain_values(monkeypatch):
    calls = []

    def compute(drive, gains):
        calls.append((drive, gains))
        return {"if_i": float(len(calls))}, f"line {len(calls)}", 1.5

    monkeypatch.setattr(pmsm_drive, "compute_startup_values", compute)
    monkeypatch.setattr(pmsm_drive, "_STARTUP_CACHE", {})
    a, b = object(), object()
    g = GainSet("schedule", {"lambda1": np.array([1.0, 2.0]), "w": [0.5, 1.0]})
    first = pmsm_drive.startup_values(a, g)
    first[0]["if_i"] = -1.0  # the caller's own copy
    same = pmsm_drive.startup_values(a, GainSet("schedule", {"w": [0.5, 1.0], "lambda1": [1.0, 2.0]}))
    assert len(calls) == 1 and same == ({"if_i": 1.0}, "line 1", 1.5)
    pmsm_drive.startup_values(a, GainSet("schedule", {"lambda1": [1.0, 2.0000001], "w": [0.5, 1.0]}))
    pmsm_drive.startup_values(b, g)
    pmsm_drive.startup_values(a, GainSet("constant", {"lambda1": [1.0, 2.0], "w": [0.5, 1.0]}))
    assert len(calls) == 4
