"""`sensorless report`: the JSON holds what the API computes, the HTML is valid, self-contained, and
renders; two runs give identical JSON (the second run: tests/common/conftest.py's ``another_day``, which
tests/common/test_outputs.py compares on every command's outputs)."""

import json
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from sensorless.design.ipmsm_adaptive.one_step import linearize
from sensorless.reports.cli.common import version

pytestmark = pytest.mark.long(33)  # CPU seconds of this file, measured: scheduled first (tests/conftest.py)


@pytest.fixture(scope="module")
def report(report_piippo_quick):
    return report_piippo_quick  # one run per worker, shared with tests/common/test_outputs.py


def test_json_numbers_equal_the_api(report, drive):
    data = json.loads((report / "report.json").read_text())
    assert data["inputs"]["drive_sha256"] == drive.digest
    # which observer step the checks judged (`report --precision fixed` says "fixed", reports/fixed_review.py)
    assert data["inputs"]["precision"] == "double" and "fixed_point" not in data
    wb = drive.base.w
    # pole-map table: worst damping of the paper speed gain at +T_N equals a direct computation
    w = np.linspace(-1, 1, 201) * wb  # the --quick grid
    s = linearize(drive, w, drive.T_N, gain="speed")
    z = np.where(np.abs(w) >= 0.05 * wb, s.worst_damping, np.inf)
    entry = data["pole_maps"]["paper speed"]["+14"]
    assert entry["worst"]["damping"] == pytest.approx(z.min(), rel=1e-10)
    assert entry["worst"]["w_pu"] == pytest.approx(w[np.argmin(z)] / wb, rel=1e-10)
    lo, hi = entry["rhp_bands_pu"][0]
    assert lo == pytest.approx(0, abs=1e-6) and 0.01 < hi < 0.04
    assert data["pole_maps"]["paper speed + injection"]["+14"]["rhp_bands_pu"] == []
    # speed x torque map, one cell
    plane = data["plane"]
    i, j = 7, 2
    wi, Tj = plane["w_pu"][i] * wb, plane["T_Nm"][j]
    cell = linearize(drive, wi, Tj, gain="speed").worst_damping[0]
    assert plane["maps"]["paper speed"]["damping"][i][j] == pytest.approx(cell, rel=1e-10)
    # robustness: one cell with R̂s misestimated
    rob = data["robustness"]["params"]["R_s"]
    k, m = 0, 3
    est = np.array(drive.motor.vector())
    est[0] *= 1 + rob["error_pct"][k] / 100
    val = linearize(
        drive, data["robustness"]["w_pu"][m] * wb, drive.T_N, gain="speed", estimate=est
    ).worst_damping[0]
    got = rob["damping"][k][m]
    assert (got is None and np.isnan(val)) or got == pytest.approx(val, rel=1e-9)
    # the discrete-time observer that runs (the --quick grid: 41 speeds)
    disc = data["discrete"]
    assert disc["discretization"] == drive.runtime.discretization
    w41 = np.linspace(-1, 1, 41) * wb
    a = linearize(drive, w41, drive.T_N, gain="speed", discretization="zoh")
    entry = disc["gains"]["paper speed"]["+14"]
    err = np.abs(a.err_theta[np.abs(w41) >= 0.05 * wb]).max()
    assert entry["err_theta_max_deg"] == pytest.approx(np.degrees(err), rel=1e-9)
    assert entry["feedthrough_max"] == 0
    assert {r["discretization"] for r in disc["study"]} == {"zoh", "heun", "euler", "heun-model"}


def test_html_is_well_formed_self_contained_and_captioned(report):
    text = (report / "report.html").read_text()
    assert text.startswith("<!DOCTYPE html>")
    root = ET.fromstring(text[len("<!DOCTYPE html>") :])  # well-formed (XHTML-compatible) markup
    for el in root.iter():
        for attr in ("src", "href"):
            v = el.get(attr)
            assert v is None or v.startswith("data:") or v.startswith("#"), v
    figures = list(root.iter("figure"))
    assert len(figures) >= 5
    for fig in figures:
        assert fig.find("figcaption") is not None and fig.find("figcaption").text.strip()
        img = fig.find("img")
        assert img.get("src").startswith("data:image/svg+xml;base64,")
    assert not re.search(r"https?://(?!www\.w3\.org)", text.replace("data:image", ""))
    assert f"sensorless {version()}" in text  # the version that made it stated
    assert not re.search(
        r"\b(19|20)\d\d-[01]\d-[0-3]\d\b", text
    )  # and no date (tests/common/test_outputs.py)
    assert "Verdict" in text


def test_two_runs_give_identical_json(report, another_day):
    """The second run is the one of another day, in a fresh process (tests/helpers/another_day.py):
    byte-identical JSON from it is byte-identical JSON from two runs, whatever the day or the process."""
    again = another_day.report("piippo2008") / "report.json"
    assert again.read_bytes() == (report / "report.json").read_bytes()


def test_report_renders_in_headless_chromium(report, tmp_path):
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("Debian's chromium is not installed (.ci/run installs it)")
    shot = tmp_path / "shot.png"
    cmd = [
        exe,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={tmp_path / 'profile'}",
        "--window-size=1280,2400",
        f"--screenshot={shot}",
        (report / "report.html").as_uri(),
    ]
    subprocess.run(cmd, check=True, capture_output=True, timeout=120)
    data = shot.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20000  # a real, non-blank page


def test_time_domain_section_reruns_the_paper_experiments(report):
    data = json.loads((report / "report.json").read_text())
    td = {c["name"]: c for c in data["time_domain"]}
    assert list(td) == ["fig9b", "fig10", "fig6b"]
    # Fig. 9(b) with the speed-dependent gain and injection: the estimate follows the steps
    assert td["fig9b"]["metrics"]["max_abs_theta_err_deg"] < 20
    # each check says whether it passed, and the verdict agrees with the checks
    assert all(isinstance(c["passed"], bool) for c in td.values())
    if not all(c["passed"] for c in td.values()):
        assert data["verdict"]["status"] != "pass"
    text = (report / "report.html").read_text()
    assert text.count("<figure>") >= 5 + len(td)


@pytest.fixture(scope="module")
def report_pmac(report_deangelo_quick):
    return report_deangelo_quick  # one run per worker, shared with tests/common/test_outputs.py


def test_pmac_report_numbers_equal_the_api(report_pmac, another_day):
    from sensorless.design.drive import load_drive
    from sensorless.design.pmac_reduced_order.linearize import analyze

    d = load_drive("deangelo2006")
    data = json.loads((report_pmac / "report.json").read_text())
    pts = data["analysis"]["paper gains, with T_L estimation"]["points"]
    p = pts[4]
    r = analyze(d, d.rpm_to_w(p["speed_rpm"]), p["T_L_Nm"])
    assert p["decay_d"] == pytest.approx(-r.poles_discrete.real.max(), rel=1e-9)
    assert p["damping_c"] == pytest.approx(r.damping.min(), rel=1e-9)
    text = (report_pmac / "report.html").read_text()
    ET.fromstring(text[len("<!DOCTYPE html>") :])
    assert "Verdict" in text and [c["name"] for c in data["time_domain"]] == ["fig3", "fig5b"]
    # two runs give identical JSON: the second is another day's, in a fresh process (as above)
    again = another_day.report("deangelo2006") / "report.json"
    assert again.read_bytes() == (report_pmac / "report.json").read_bytes()
