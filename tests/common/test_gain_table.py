"""Gain tables are validated on load like drive files: encoding, JSON, types, finiteness, magnitudes and
the family's match with the drive; every error is one line that starts with the table's file name."""

from __future__ import annotations

import json

import pytest
from sensorless.design.drive import load_drive
from sensorless.design.gain_table import GainTable, GainTableError, read_gain_table
from sensorless.design.registry import family_of
from sensorless.reports.cli.main import main

LAW16 = {
    "format": "sensorless-gain-table/2",
    "drive": {"name": "piippo2008", "kind": "ipmsm-adaptive"},
    "law": "speed-dependent",
    "gains": {"lambda_p": 7.18, "w_lambda": 471.2, "alpha_fo": 314.16},
}
SCHEDULE = {
    **LAW16,
    "law": "schedule",
    "gains": {
        "w_hat": [-400.0, 0.0, 400.0],
        "lambda1": [1.0, 2.0, 1.0],
        "lambda2": [0.0, 1.0, 0.0],
        "alpha_fo": 314.0,
    },
}


def changed(doc, **gains):
    return {**doc, "gains": {**doc["gains"], **gains}}


CASES = [
    # (name, file bytes or document, drive, words after "<file>: ")
    (
        "latin1",
        json.dumps(LAW16).replace("piippo2008", "pi\u00e9ppo").encode("latin-1"),
        "piippo2008",
        "not UTF-8",
    ),
    ("not-json", b'{"format": ', "piippo2008", "not valid JSON"),
    ("nan-literal", json.dumps(changed(LAW16, lambda_p=float("nan"))), "piippo2008", "NaN is not a number"),
    ("huge-literal", json.dumps(LAW16).replace("7.18", "1e999"), "piippo2008", "number 1e999 is not finite"),
    (
        "1e308",
        changed(LAW16, lambda_p=1e308),
        "piippo2008",
        "key 'gains.lambda_p': value 1e+308 is out of range",
    ),
    (
        "1e-300",
        changed(LAW16, w_lambda=1e-300),
        "piippo2008",
        "key 'gains.w_lambda': value 1e-300 is out of range",
    ),
    ("string", changed(LAW16, lambda_p="7"), "piippo2008", "key 'gains.lambda_p': expected a number"),
    ("bool", changed(LAW16, alpha_fo=True), "piippo2008", "key 'gains.alpha_fo': expected a number"),
    (
        "w_hat-number",
        changed(SCHEDULE, w_hat=5),
        "piippo2008",
        "key 'gains.w_hat': expected a list of numbers",
    ),
    ("lambda-list", changed(LAW16, lambda_p=[1.0]), "piippo2008", "key 'gains.lambda_p': expected a number"),
    ("empty-list", changed(SCHEDULE, lambda1=[]), "piippo2008", "key 'gains.lambda1': an empty list"),
    (
        "short-list",
        changed(SCHEDULE, lambda1=[1.0]),
        "piippo2008",
        "key 'gains.lambda1': length 1 != len(w_hat) 3",
    ),
    ("unsorted", changed(SCHEDULE, w_hat=[0.0, -1.0, 1.0]), "piippo2008", "strictly increasing"),
    (
        "negative",
        changed(LAW16, w_lambda=-1.0),
        "piippo2008",
        "key 'gains.w_lambda': non-physical value -1.0",
    ),
    ("unknown-key", changed(LAW16, lambda_q=1.0), "piippo2008", "key 'gains.lambda_q': unknown key"),
    ("missing-key", {**LAW16, "gains": {"lambda_p": 1.0}}, "piippo2008", "key 'gains.w_lambda': missing"),
    ("no-name", {**LAW16, "drive": {"kind": "ipmsm-adaptive"}}, "piippo2008", "key 'drive'"),
    ("points", {**LAW16, "points": {"a": 1}}, "piippo2008", "key 'points': expected a list"),
    (
        "speed-dependent-to-reduced-order",
        LAW16,
        "deangelo2006",
        "key 'drive.kind': 'ipmsm-adaptive' does not match",
    ),
    (
        "speed-dependent-no-kind-to-reduced-order",
        {**LAW16, "drive": {"name": "piippo2008"}},
        "deangelo2006",
        "key 'law': 'speed-dependent' gains are not for extended reduced-order EMF",
    ),
    (
        "constant-to-adaptive",
        {**LAW16, "law": "constant", "drive": {"name": "x"}, "gains": {"g": 1, "Gamma": 1}},
        "piippo2008",
        "key 'law': 'constant' gains are not for",
    ),
    ("unknown-law", {**LAW16, "law": "pid"}, "piippo2008", "key 'law': unknown law 'pid'"),
]


def write(tmp_path, name, content):
    p = tmp_path / f"{name}.json"
    if isinstance(content, bytes):
        p.write_bytes(content)
    else:
        p.write_text(content if isinstance(content, str) else json.dumps(content))
    return p


@pytest.mark.parametrize(("name", "content", "drive", "words"), CASES, ids=[c[0] for c in CASES])
def test_bad_tables_are_one_line_naming_the_file(tmp_path, capsys, name, content, drive, words):
    table = write(tmp_path, name, content)
    out = tmp_path / "o"
    code = main(["codegen", drive, "--gains", str(table), "--out", str(out)])
    cap = capsys.readouterr()
    assert code == 2 and cap.err.count("\n") == 1 and "Traceback" not in cap.err, cap.err
    assert cap.err.startswith(f"sensorless codegen: error: {table}: ") and words in cap.err, cap.err
    assert cap.out == "" and not out.exists()


@pytest.mark.parametrize(
    ("content", "drive"),
    [
        (json.dumps(changed(LAW16, lambda_p=float("nan"))), "piippo2008"),
        (changed(LAW16, lambda_p=1e308), "piippo2008"),
        (LAW16, "deangelo2006"),
        (changed(SCHEDULE, w_hat="0, 1"), "piippo2008"),
    ],
)
def test_report_refuses_bad_tables_before_computing(tmp_path, capsys, content, drive):
    """The audited cases that broke `sensorless report` (a NaN gain, lambda' = 1e308, a speed-dependent table
    for the reduced-order drive, w_hat not a list): one line, at once."""
    table = write(tmp_path, "t", content)
    code = main(["report", drive, "--gains", str(table), "--quick", "--out", str(tmp_path / "r")])
    cap = capsys.readouterr()
    assert code == 2 and cap.err.count("\n") == 1, cap.err
    assert cap.err.startswith(f"sensorless report: error: {table}: "), cap.err
    assert cap.out == "" and not (tmp_path / "r").exists()


def test_a_directory_or_a_missing_file_is_named(tmp_path):
    with pytest.raises(GainTableError, match=f"^{tmp_path}: is a directory"):
        read_gain_table(tmp_path)
    with pytest.raises(FileNotFoundError, match=r"nope\.json: no such gain table"):
        read_gain_table(tmp_path / "nope.json")


def test_a_good_table_reads_and_names_its_file(tmp_path):
    p = write(tmp_path, "good", SCHEDULE)
    t = read_gain_table(p)
    assert t.file == str(p) and t.where() == str(p) and t.where("other.json") == "other.json"
    d = load_drive("piippo2008")
    g = family_of(d).gains(d, table=t)  # no table_file given: messages and the source still name it
    assert str(p) in g.source
    mem = GainTable("speed-dependent", {"name": "x", "kind": "pmac-reduced-order"}, LAW16["gains"])
    with pytest.raises(GainTableError, match=r"^gain table \(in memory\): key 'drive.kind'"):
        family_of(d).gains(d, table=mem)


def test_format_1_tables_and_former_law_names_still_read(tmp_path, capsys):
    """A `sensorless-gain-table/1` table (key "family", the laws' former names law16 and deangelo, and
    "family" in its seed records) reads for one release as the same table in format /2, with a note
    on stderr (one line) naming the new names; the gains are the same gains."""
    seed = {"family": "law16", "damping": 0.5}
    old = {
        **LAW16,
        "format": "sensorless-gain-table/1",
        "summary": {"seed": {**seed, "parameters": {}}},
        "points": [{"seed": dict(seed)}],
    }
    del old["law"]
    old["family"] = "law16"
    t = read_gain_table(write(tmp_path, "old", old))
    new = read_gain_table(write(tmp_path, "new", LAW16))
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"{tmp_path / 'old.json'}: note: "), err
    assert "sensorless-gain-table/1 read" in err[0] and "key 'law'" in err[0], err
    assert "law 'law16' is now called 'speed-dependent'" in err[0], err
    assert t.law == new.law == "speed-dependent" and t.gains == new.gains
    assert t.summary["seed"]["law"] == t.points[0]["seed"]["law"] == "speed-dependent"
    assert "family" not in t.summary["seed"] and "family" not in t.points[0]["seed"]
    d = load_drive("piippo2008")
    assert family_of(d).gains(d, table=t).values == family_of(d).gains(d, table=new).values
    dean = {"format": "sensorless-gain-table/1", "drive": {"name": "x"}, "family": "deangelo"}
    t = read_gain_table(write(tmp_path, "dean", {**dean, "gains": {"g": 400.0, "Gamma": 1e4}}))
    assert t.law == "constant" and "'deangelo' is now called 'constant'" in capsys.readouterr().err
    # the new format has no "family" key: a /2 table that names its law there is refused
    bad = {k: v for k, v in LAW16.items() if k != "law"} | {"family": "speed-dependent"}
    with pytest.raises(GainTableError, match="key 'law': unknown law None"):
        read_gain_table(write(tmp_path, "bad", bad))
    assert json.loads(new.to_json())["format"] == "sensorless-gain-table/2"


FLUX_SCHEDULE = {
    "format": "sensorless-gain-table/2",
    "drive": {"name": "outrunner270", "kind": "pmsm-flux-observer"},
    "law": "schedule",
    "gains": {"speeds": [100.0, 1000.0], "observer_gain": [500.0, 2000.0], "pll_bandwidth": 600.0},
}


def test_law_names_are_each_familys_own(tmp_path, capsys):
    """Two families may name a law alike (the adaptive and the flux observer's "schedule"): a table
    is read with its drive kind's law and keys, the other family's keys are refused, and each family
    takes only its own table. The flux law's former name flux_schedule still reads, with a note."""
    flux, adaptive = load_drive("outrunner270"), load_drive("piippo2008")
    t = read_gain_table(write(tmp_path, "flux", FLUX_SCHEDULE))
    g = family_of(flux).gains(flux, table=t)
    assert (g.law, g.values["speeds"]) == ("schedule", [100.0, 1000.0])
    s = read_gain_table(write(tmp_path, "adaptive", SCHEDULE))
    assert family_of(adaptive).gains(adaptive, table=s).values["lambda1"] == [1.0, 2.0, 1.0]
    with pytest.raises(GainTableError, match=r"key 'drive\.kind'"):  # the other family's table
        family_of(flux).gains(flux, table=s)
    crossed = {**FLUX_SCHEDULE, "gains": SCHEDULE["gains"]}  # the adaptive keys under the flux kind
    with pytest.raises(GainTableError, match=r"key 'gains.speeds': missing for law schedule"):
        read_gain_table(write(tmp_path, "crossed", crossed))
    old = read_gain_table(write(tmp_path, "old", {**FLUX_SCHEDULE, "law": "flux_schedule"}))
    assert "law 'flux_schedule' is now called 'schedule'" in capsys.readouterr().err
    assert family_of(flux).gains(flux, table=old).values == g.values


def test_dumps_is_the_standard_librarys_indented_json():
    """design/gain_table.py ``dumps`` against ``json.dumps(indent=1, sort_keys=True, allow_nan=False)``
    on the value kinds a table holds (and non-ASCII text), and on a tuned table's document."""
    import json as _json

    from sensorless.design.gain_table import clean, dumps

    doc = {
        "b": [
            1,
            -0.0,
            1e-300,
            2.5e16,
            True,
            False,
            None,
            '\u00e9\u2013"x\\',
            [],
            {},
            [[1.5], {"z": 1, "a": [2]}],
        ],
        "a": {"k": 3, "nested": {"empty": [], "v": -7.125}},
        "\u00fc": 12345678901234567890,
    }
    ref = _json.dumps(doc, indent=1, sort_keys=True, allow_nan=False)
    assert dumps(doc) == ref
    with pytest.raises(ValueError):
        dumps({"x": [float("nan")]})
    table = clean({"points": [{"w": 0.1 * k, "poles": [[-1.0 * k, 2.0]], "n": k} for k in range(50)]})
    assert dumps(table) == _json.dumps(table, indent=1, sort_keys=True, allow_nan=False)


def test_to_json_is_the_indented_json_of_the_cleaned_document():
    """``to_json`` cleans while it encodes (design/gain_table.py ``_encode``): its text is
    ``json.dumps(clean(doc), indent=1, sort_keys=True)`` on what clean changes (numpy values, tuples,
    non-finite floats, keys other than str) and what it keeps."""
    import json as _json

    import numpy as np
    from sensorless.design.gain_table import clean

    nan, inf = float("nan"), float("inf")
    t = GainTable(
        drive={"name": "x", "sha256": "0" * 64},
        law="schedule",
        gains={"lambda1": np.array([1.0, np.nan, 2.5]), "lambda2": (0.5, -0.0)},
        envelope={"speeds": np.float64(3.25), "n": np.int64(7), 2: "two"},
        points=[{"poles": [[-1.0, 0.0], [nan, inf]], "damping": -inf, "w": [0.0, -0.0, 1e-300]}],
        summary={"ok": True, "none": None, "worst": [1, 2.5, nan], "nested": {"t": (np.float32(1.5),)}},
    )
    doc = {
        "format": "sensorless-gain-table/2",
        "drive": t.drive,
        "law": t.law,
        "gains": t.gains,
        "envelope": t.envelope,
        "points": t.points,
        "summary": t.summary,
    }
    assert t.to_json() == _json.dumps(clean(doc), indent=1, sort_keys=True, allow_nan=False) + "\n"
