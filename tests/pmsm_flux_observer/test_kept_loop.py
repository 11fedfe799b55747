"""The flux observer's rotor-frame loop (design/pmsm_flux_observer/linearize.py ``rotor_frame_loop``) is
kept on disk by its content: a second declaration from a gain law built again (as the next process
builds it: another Function object, the same graph) reads the first's back, the same pickled bytes (so
the Functions design/rotor_frame.py keeps by the loop's content are found too) and the same rates to the
bit; a loop of another gain law is another file."""

from __future__ import annotations

import pickle

import numpy as np
from sensorless.design.pmsm_flux_observer.gains import constant_law, table_law
from sensorless.design.pmsm_flux_observer.linearize import rotor_frame_loop


def test_the_loop_is_read_back_by_its_content(tmp_path, monkeypatch):
    monkeypatch.setenv("SENSORLESS_CACHE", str(tmp_path))
    monkeypatch.delenv("SENSORLESS_NO_DISK_MEMO", raising=False)
    memo = rotor_frame_loop.__wrapped__  # the by-content memo under the in-process cache
    memo.cache_clear()
    built = rotor_frame_loop("gradient", "interpolated", False, constant_law.__wrapped__())
    memo.cache_clear()  # the in-process memo emptied: "the next process"
    read = rotor_frame_loop("gradient", "interpolated", False, constant_law.__wrapped__())
    assert memo.cache_info() == (1, 0)  # read back from disk, not built
    assert read is not built
    assert pickle.dumps(read, protocol=pickle.HIGHEST_PROTOCOL) == pickle.dumps(
        built, protocol=pickle.HIGHEST_PROTOCOL
    )
    # x_r, w, torque, plant [R_s, L_d, L_q, psi_pm, p], p (runtime parameters, then the gain)
    args = (
        [0.01, -0.002, 0.05, 300.0],
        310.0,
        2.0,
        [0.1, 2e-4, 3e-4, 0.02, 7.0],
        np.linspace(1, 2, read.rates.size1_in(4)),
    )
    assert np.array_equal(np.asarray(read.rates(*args)), np.asarray(built.rates(*args)))
    rotor_frame_loop("gradient", "interpolated", False, table_law.__wrapped__((0.0, 100.0, 1000.0)))
    assert len(list((tmp_path / "memo").glob("rotor_frame_loop-*.pickle"))) == 2
