"""Gain tables: tuned observer gains as data (JSON), shared by tuning, simulation, C generation and reports.

Format ``sensorless-gain-table/2`` (see docs/gain_tables.md)::

    {"format": "sensorless-gain-table/2",
     "drive": {"name": ..., "kind": ..., "sha256": ...},
     "law": "speed-dependent" | "schedule" | "constant" | ...,  # a gain law of an observer family
     "gains": {...},          # law-specific, SI units: the keys its observer family declares
     "envelope": {...},       # what was optimized over (free form, documented by the writer)
     "points": [{...}, ...],  # per operating point: gains, poles, damping, decay rate, baseline
     "summary": {...}}

Writing is deterministic (sorted keys, floats as repr) so equal inputs give byte-identical files.
Reading is strict like drive files: the text must be UTF-8 JSON without NaN or infinite numbers, every
section must have its type, and every gain must be a finite number (or a non-empty list of them) of a
magnitude the drive files accept (design/units.py); each error is a :class:`GainTableError` naming the
file and the key. Whether the gains suit a drive (its kind, its observer's gain laws, the
family's own checks) is the observer family's part (``ObserverFamily.gains``).

Format ``sensorless-gain-table/1`` (its ``family`` key, and ``family`` in the seed records, for the
law; the laws' former names) is still read, for one release, with a note on stderr.
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
from dataclasses import dataclass, field
from json.encoder import encode_basestring_ascii
from pathlib import Path
from typing import Any, NoReturn, TypeAlias

from sensorless.design.family import ObserverFamily
from sensorless.design.registry import families
from sensorless.design.units import MAGNITUDE

FORMAT = "sensorless-gain-table/2"
FORMAT_1 = "sensorless-gain-table/1"  # read for one release: "family" for "law", the laws' old names


def gain_keys(kind: str | None = None) -> dict[str, list[tuple[str, ...]]]:
    """Gain law -> the required keys of "gains" in each family that has the law (law names are the
    families' own: two families may both have a "schedule"), of the family of drive kind ``kind`` only
    where it is a registered kind, else of every registered family."""
    out: dict[str, list[tuple[str, ...]]] = {}
    for f in _families_of(kind):
        for g, keys in f.laws.items():
            out.setdefault(g, []).append(tuple(keys))
    return out


def law_aliases(kind: str | None = None) -> dict[str, str]:
    """Former law name -> its name now, of the family of drive kind ``kind`` (or of every family; a
    former name is its family's own, so where two families disagree the kind decides)."""
    return {old: new for f in _families_of(kind) for old, new in f.law_aliases.items()}


def _families_of(kind: str | None) -> list[ObserverFamily]:
    fams = families()
    own = [f for f in fams if f.kind == kind]
    return own or fams


# JSON data: what json.loads gives and :func:`dumps` writes (:func:`clean` makes any value so)
JsonValue: TypeAlias = "str | int | float | bool | list[JsonValue] | dict[str, JsonValue] | None"


class GainTableError(ValueError):
    """A gain table file is malformed; the message names the file and the key."""


@dataclass(frozen=True)
class GainTable:
    """A tuned gain table."""

    law: str
    drive: dict[str, str]
    gains: dict[str, Any]
    envelope: dict[str, Any] = field(default_factory=dict)
    points: list[dict[str, Any]] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)
    file: str = field(default="", compare=False)  # the file it was read from ("": built in memory)
    # sha256 of that file's bytes (format /2; "": built in memory or upgraded from /1): what a report
    # names the table by, without serializing megabytes again; for a table tune wrote, the digest of
    # its canonical JSON (to_json) since that is the file's text
    file_sha256: str = field(default="", compare=False)

    def where(self, table_file: str = "") -> str:
        """How messages name this table: ``table_file`` if given, else the file it was read from."""
        return table_file or self.file or "gain table (in memory)"

    def to_json(self) -> str:
        """Deterministic JSON text."""
        doc = {
            "format": FORMAT,
            "drive": self.drive,
            "law": self.law,
            "gains": self.gains,
            "envelope": self.envelope,
            "points": self.points,
            "summary": self.summary,
        }
        return _encode(doc, cleaning=True) + "\n"


class _Reprs(dict[float, str]):
    """float -> its text, computed once per value (a servo's table writes 100 800 floats, 19 300 distinct:
    the bound's and the seed's columns repeat per torque, pole pairs their real parts). 0.0 and -0.0 are
    one key with two texts: neither is kept. A value that is not finite is "null" where the document is
    cleaned (``cleaning``), else an error, as json.dumps(allow_nan=False) raises: so a float anywhere is
    one lookup, without a finiteness test of its own."""

    def __init__(self, cleaning: bool) -> None:
        super().__init__()
        self.cleaning = cleaning

    def __missing__(self, v: float) -> str:
        if not math.isfinite(v):
            if self.cleaning:
                return "null"
            raise ValueError("Out of range float values are not JSON compliant: " + float.__repr__(v))
        r = float.__repr__(v)
        if v:
            self[v] = r
        return r


class _Keys(dict[str, str]):
    """A key -> its text with ": ", computed once per key."""

    def __missing__(self, k: str) -> str:
        e = self[k] = encode_basestring_ascii(k) + ": "
        return e


class _Indents(dict[int, str]):
    """A level -> "\n" and its indent."""

    def __missing__(self, level: int) -> str:
        e = self[level] = "\n" + " " * level
        return e


def dumps(doc: JsonValue) -> str:
    """``json.dumps(doc, indent=1, sort_keys=True, allow_nan=False)`` of JSON data (dicts with str keys,
    lists, str, int, float, bool, None; :func:`clean`'s output), the same text, built by joins: the
    standard library's indented encoder is its pure-Python generator chain (0.48 s CPU for a servo's
    3.5-MB schedule table, against 0.1 s here; tune writes it, report hashes it). A list of floats only
    (a pole's [re, im], a schedule's breakpoints) is one join; each float's text is computed once."""
    return _encode(doc, cleaning=False)


def _encode(doc: object, cleaning: bool) -> str:
    """:func:`dumps` of ``doc``; ``cleaning``: of ``clean(doc)``, the same text without the copy (what
    clean changes is cleaned where it is met: a non-finite float is null, a dict with keys other than
    str, a tuple, a numpy value or anything else goes through clean; 0.06 s CPU of the README servo's
    table). The lookups are dicts' own (a miss computes the text once), and a pole's [re, im] in a list of
    them is written without a call of its own: 0.13 -> 0.11 s CPU for the README servo's table."""
    rep = _Reprs(cleaning).__getitem__
    key = _Keys().__getitem__
    nl = _Indents().__getitem__
    only_floats, only_str = {float}, {str}
    # a dict's keys (as inserted) -> its items' order and key texts: sorted once per set of str keys (a
    # table's 2618 points and the records in them share a few: 10 000 sorts before, 0.02 s CPU)
    orders: dict[tuple[object, ...], tuple[tuple[object, str], ...]] = {}

    def enc(x: object, level: int) -> str:
        t = type(x)
        if t is list:
            if not x:
                return "[]"
            up = level + 1
            inner = nl(up)
            if set(map(type, x)) == only_floats:
                return "[" + inner + ("," + inner).join(map(rep, x)) + nl(level) + "]"
            pair = nl(up + 1)
            items = []
            for v in x:
                if type(v) is float:
                    items.append(rep(v))
                elif type(v) is list and len(v) == 2 and type(v[0]) is float and type(v[1]) is float:
                    # a pole's [re, im], the bulk of a table: written here, without a call of its own
                    items.append("[" + pair + rep(v[0]) + "," + pair + rep(v[1]) + inner + "]")
                else:
                    items.append(enc(v, up))
            return "[" + inner + ("," + inner).join(items) + nl(level) + "]"
        if t is dict:
            if not x:
                return "{}"
            keys = tuple(x)
            order = orders.get(keys)
            if order is None:
                if set(map(type, x)) != only_str:
                    if cleaning:
                        return enc(clean(x), level)
                    order = tuple((k, key(k)) for k, _ in sorted(x.items()))  # (raises: not JSON keys)
                else:
                    order = orders[keys] = tuple((k, key(k)) for k in sorted(keys))
            up = level + 1
            inner = nl(up)
            return (
                "{"
                + inner
                + ("," + inner).join(
                    [text + (rep(v) if type(v := x[k]) is float else enc(v, up)) for k, text in order]
                )
                + nl(level)
                + "}"
            )
        if t is str:
            return encode_basestring_ascii(x)
        if t is float:
            return rep(x)
        if x is None:
            return "null"
        if x is True:
            return "true"
        if x is False:
            return "false"
        if t is int:
            return int.__repr__(x)
        if cleaning:
            c = clean(x)
            if c is not x:
                return enc(c, level)
        raise TypeError(f"Object of type {t.__name__} is not JSON serializable")

    return enc(doc, 0)


def clean(x: object) -> JsonValue:
    """JSON-safe copy: numpy scalars/arrays to lists, non-finite floats to None."""
    t = type(x)  # the common leaves first (a servo's table has 145 000 of them)
    if t is float:
        return x if math.isfinite(x) else None
    if t is str or t is int or t is bool or x is None:
        return x
    isfinite = math.isfinite  # (a finite float leaf is kept as it is, without a call)
    if t is list:
        return [v if type(v) is float and isfinite(v) else clean(v) for v in x]
    if isinstance(x, dict):
        return {str(k): v if type(v) is float and isfinite(v) else clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [clean(v) for v in x]
    if hasattr(x, "tolist"):
        return clean(x.tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


class _NotFinite(ValueError):
    pass


def _finite_float(text: str) -> float:
    x = float(text)
    if not math.isfinite(x):
        raise _NotFinite(f"number {text} is not finite")
    return x


def _no_constant(name: str) -> NoReturn:
    raise _NotFinite(f"{name} is not a number JSON allows")


def _gain_value(v: object, where: str, key: str) -> None:
    """A gain: a finite number, or a non-empty list of them, each zero or of a magnitude in MAGNITUDE."""
    items = v if isinstance(v, list) else [v]
    if isinstance(v, list) and not v:
        raise GainTableError(f"{where}: key 'gains.{key}': an empty list")
    lo, hi = MAGNITUDE
    for x in items:
        if isinstance(x, bool) or not isinstance(x, int | float):
            what = "a number or a list of numbers" if x is v else "a list of numbers"
            raise GainTableError(f"{where}: key 'gains.{key}': expected {what}, got {x!r}")
        if not math.isfinite(x) or (x != 0 and not lo <= abs(x) <= hi):
            raise GainTableError(
                f"{where}: key 'gains.{key}': value {x!r} is out of range: magnitudes from {lo:g} to {hi:g} "
                "(SI) or 0 are accepted"
            )


def read_gain_table(path: str | Path) -> GainTable:
    """Read and validate a gain table JSON file (module docstring); errors name the file and the key."""
    p = Path(path)
    if p.is_dir():
        raise GainTableError(f"{p}: is a directory, not a gain table")
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such gain table")
    try:
        raw = p.read_bytes()
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise GainTableError(f"{p}: not a gain table: not UTF-8 text (byte {e.start})") from None
    except OSError as e:
        raise GainTableError(f"{p}: cannot read: {e.strerror}") from None
    try:
        doc = json.loads(text, parse_float=_finite_float, parse_constant=_no_constant)
    except json.JSONDecodeError as e:
        raise GainTableError(f"{p}: not valid JSON: {e}") from None
    except _NotFinite as e:
        raise GainTableError(f"{p}: not a gain table: {e} (gains and figures must be finite)") from None
    except RecursionError:
        raise GainTableError(f"{p}: not a gain table: nested too deeply") from None
    if not isinstance(doc, dict) or doc.get("format") not in (FORMAT, FORMAT_1):
        raise GainTableError(f"{p}: key 'format': expected {FORMAT!r}")
    key = "law" if doc["format"] == FORMAT else "family"
    law = doc.get(key)
    kind = doc["drive"].get("kind") if isinstance(doc.get("drive"), dict) else None
    kind = kind if isinstance(kind, str) else None
    known = gain_keys(kind)  # the laws of the table's drive kind (its family's names)
    old = law_aliases(kind)
    notes = [f"format {FORMAT_1} read (tables are now {FORMAT}, key 'law')"] if key == "family" else []
    if isinstance(law, str) and law in old and law not in known:
        notes.append(f"law {law!r} is now called {old[law]!r}")
        law = old[law]
    if not isinstance(law, str) or law not in known:
        raise GainTableError(f"{p}: key '{key}': unknown law {law!r} (known: {', '.join(known)})")
    if notes:  # one line, for one release
        print(f"{p}: note: {'; '.join(notes)}", file=sys.stderr)
    if key == "family":
        _upgrade_seeds(doc, old)
    gains = doc.get("gains")
    if not isinstance(gains, dict):
        raise GainTableError(f"{p}: key 'gains': missing or not an object")
    # a law two families have (and a table that does not name its kind): the keys of either
    keys = next((ks for ks in known[law] if set(ks) == set(gains)), known[law][0])
    for k in keys:
        if k not in gains:
            raise GainTableError(f"{p}: key 'gains.{k}': missing for law {law}")
    for k in gains:
        if k not in keys:
            raise GainTableError(
                f"{p}: key 'gains.{k}': unknown key for law {law} (known: {', '.join(keys)})"
            )
        _gain_value(gains[k], str(p), k)
    drive = doc.get("drive")
    if not isinstance(drive, dict) or not isinstance(drive.get("name"), str):
        raise GainTableError(f"{p}: key 'drive': missing, or without a 'name' string")
    for k in ("kind", "sha256"):
        if k in drive and not isinstance(drive[k], str):
            raise GainTableError(f"{p}: key 'drive.{k}': expected a string, got {drive[k]!r}")
    for k, typ, what in (
        ("envelope", dict, "an object"),
        ("points", list, "a list"),
        ("summary", dict, "an object"),
    ):
        if k in doc and not isinstance(doc[k], typ):
            raise GainTableError(f"{p}: key '{k}': expected {what}")
    if any(not isinstance(pt, dict) for pt in doc.get("points", [])):
        raise GainTableError(f"{p}: key 'points': expected a list of objects")
    return GainTable(
        law=law,
        drive=drive,
        gains=gains,
        envelope=doc.get("envelope", {}),
        points=doc.get("points", []),
        summary=doc.get("summary", {}),
        file=str(p),
        file_sha256=hashlib.sha256(raw).hexdigest() if key == "law" else "",
    )


def _upgrade_seeds(doc: dict[str, Any], old: dict[str, str]) -> None:
    """A /1 table's seed records (``summary.seed``, ``points[].seed``) with ``law`` for ``family``."""
    summary = doc.get("summary")
    points = doc.get("points")
    seeds = [summary.get("seed")] if isinstance(summary, dict) else []
    seeds += [pt.get("seed") for pt in points if isinstance(pt, dict)] if isinstance(points, list) else []
    for seed in seeds:
        if isinstance(seed, dict) and "family" in seed:
            name = seed.pop("family")
            seed["law"] = old.get(name, name) if isinstance(name, str) else name
