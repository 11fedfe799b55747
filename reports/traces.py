"""Simulated traces as files: CSV with a commented header (units, bases, provenance) or NPZ, deterministic.

Both formats carry the same columns: ``t`` [s] and every recorded signal in SI units (speeds and angles
electrical). The CSV header names the drive, the scenario, the gains and the per-unit bases; each
column heading is ``name [unit]``. The NPZ archive holds one array per column plus ``columns``,
``units`` and ``meta`` (JSON). Equal inputs give byte-identical files (fixed number format, fixed zip
timestamps).
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from typing import TYPE_CHECKING

import numpy as np
from sensorless.design import registry

if TYPE_CHECKING:
    from sensorless.design.simulate import Traces

FMT = "%.10g"


def columns(traces: Traces, every: int = 1) -> tuple[list[str], list[str], np.ndarray]:
    """(names, units, matrix (N, n_cols)) of the traces, keeping every ``every``-th sample."""
    names = ["t", *traces.data]
    units = ["s", *(traces.units[n] for n in traces.data)]
    mat = np.column_stack([traces.t, *traces.data.values()])[::every]
    return names, units, mat


def header_lines(traces: Traces) -> list[str]:
    """Provenance and conventions, one line each."""
    m = traces.meta
    notes = "".join(f"{n}; " for n in registry.family(m["kind"]).trace_notes(m))
    return [
        f"sensorless simulate: scenario {m['scenario']} ({m['scenario_title']})",
        f"scenario source: {m['scenario_source']}",
        f"drive: {m['drive']} ({m['drive_file']}, sha256 {m['drive_sha256'][:16]}...), kind {m['kind']}",
        f"observer gains: {m['gain']} (law {m['gain_law']}); discretization {m['discretization']}; "
        f"{notes}controller feedback: {m['feedback']}",
        f"sampling period T_s = {m['T_s']:g} s; {m['samples']} samples at t = k T_s (values at the "
        "sampling instants)",
        f"units: SI; speeds in electrical rad/s, angles in electrical rad; per-unit bases: speed "
        f"1 p.u. = {m['base_w']:.6g} rad/s, torque T_N = {m['T_N']:g} N m, pole pairs {m['pole_pairs']}",
    ]


def csv_text(traces: Traces, every: int = 1) -> str:
    """The traces as CSV text with a '#' header."""
    names, units, mat = columns(traces, every)
    buf = io.StringIO()
    for line in header_lines(traces):
        buf.write(f"# {line}\n")
    buf.write(",".join(f"{n} [{u}]" for n, u in zip(names, units, strict=True)) + "\n")
    np.savetxt(buf, mat, fmt=FMT, delimiter=",")
    return buf.getvalue()


def npz_bytes(traces: Traces, every: int = 1) -> bytes:
    """The traces as a NumPy .npz archive (uncompressed, fixed timestamps: deterministic bytes)."""
    names, units, mat = columns(traces, every)
    arrays = {n: np.ascontiguousarray(mat[:, k]) for k, n in enumerate(names)}
    arrays["columns"] = np.array(names)
    arrays["units"] = np.array(units)
    arrays["meta"] = np.array(json.dumps({**traces.meta, "header": header_lines(traces)}, sort_keys=True))
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as zf:
        for n, a in arrays.items():
            info = zipfile.ZipInfo(f"{n}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            b = io.BytesIO()
            np.lib.format.write_array(b, a, allow_pickle=False)
            zf.writestr(info, b.getvalue())
    return out.getvalue()


def read_csv(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Read a traces CSV back: {name: column} (units dropped from the headings)."""
    with open(path, encoding="utf-8") as f:
        lines = [ln for ln in f if not ln.startswith("#")]
    names = [h.split(" [")[0] for h in lines[0].strip().split(",")]
    mat = np.loadtxt(io.StringIO("".join(lines[1:])), delimiter=",", ndmin=2)
    return {n: mat[:, k] for k, n in enumerate(names)}
