"""Minimal drive files of the reduced-order observer (design/pmac_reduced_order/derive.py, motor.py).

The paper's own motor, written as a minimal file, derives the paper's gains (numbers typed from
De Angelo et al. 2006, Section IV); the datasheet conventions give its Phi_1; the derived gains put the
observer's error-dynamics poles where the rule says, by the hand-derived closed form against the
family's linearization and against the runtime step fed by an exact motor written here in numpy; a
complete file passes through unchanged; bad input is one error naming the file and the key."""

from __future__ import annotations

import math
import tomllib
from importlib import resources

import numpy as np
import pytest
from sensorless.design.drive import load_drive_text
from sensorless.design.pmac_reduced_order import FAMILY
from sensorless.design.pmac_reduced_order.derive import document
from sensorless.design.units import DriveFileError
from sensorless.reports.cli.main import main

# Section IV: 16 poles, 4000 r/min, 30 kW, R = 10 mOhm, L = 100 uH, J = 0.78 kg m^2, Phi_1 = 0.5021,
# Phi_5 = Phi_1/25; "g = 400 and Gamma = 10 000"; RK2 "with a sampling period equal to 180 us"
PAPER_G, PAPER_GAMMA = 400.0, 10000.0
PAPER = """
[drive]
name = "paper-minimal"
kind = "pmac-reduced-order"

[motor]
poles = 16
R_s = "10 mohm"
L_s = "100 uH"
J = "0.78 kgm2"
{emf}

[rating]
n_N = "4000 rpm"
P_N = "30 kW"

[control]
T_s = "180 us"
"""
SERIES = 'harmonics = [1, 5]\nPhi = ["0.5021 Vs", "0.04 Phi_1"]'
SERVO = """
[drive]
name = "servo"
kind = "pmac-reduced-order"

[motor]
poles = 8
R_ll = "0.6 ohm"
L_ll = "8 mH"
connection = "wye"
kE = "100 V/krpm"
emf_convention = "line-line rms"
J = "12 kg cm2"

[rating]
n_N = "3000 rpm"
T_N = "16 Nm"

[inverter]
u_dc = "560 V"
f_s = "8 kHz"
"""


def paper(emf: str = SERIES):
    return load_drive_text(PAPER.format(emf=emf), "paper.toml")


def test_the_papers_motor_derives_the_papers_gains():
    d = paper()
    assert d.motor.p == 8 and d.motor.reading == "mechanical"
    assert d.motor.Phi == pytest.approx((0.5021, 0.5021 / 25))
    assert d.observer.g == pytest.approx(PAPER_G, rel=1e-9)
    # the rule's constant has 4 digits (48.55): Gamma within 0.01 % of the paper's
    assert d.observer.Gamma == pytest.approx(PAPER_GAMMA, rel=1e-4)
    assert d.control.discretization == "rk2-model" and d.control.T_s == pytest.approx(180e-6)
    assert d.estimate.Phi == d.motor.Phi and d.estimate.J == d.motor.J == 0.78
    assert d.motor.B == 0.0  # viscosity: part of the estimated load


@pytest.mark.parametrize(
    "emf",
    [
        # |e| of the power-invariant alpha-beta frame is the line-to-line rms voltage: at 1000 r/min
        # Phi_1 x 104.72 rad/s = 52.58 V
        'kE = "52.58 V/krpm"\nemf_convention = "line-line rms"',
        # T = Phi_1 |i| with |i| = sqrt(3) I_rms: 0.8697 N m per A rms
        'kT = "0.8697 Nm/A"\ntorque_convention = "rms"',
        # the phase peak flux linkage: Phi_1 / (sqrt(3/2) p) = 0.5021 / 9.798 = 51.245 mVs
        'psi_pm = "51.245 mVs"',
    ],
    ids=["kE", "kT", "psi_pm"],
)
def test_datasheet_constants_give_the_papers_phi_1(emf):
    d = paper(emf)
    assert d.motor.harmonics == (1,)
    assert d.motor.Phi[0] == pytest.approx(0.5021, rel=2e-4)
    assert d.observer.Gamma == pytest.approx(PAPER_GAMMA, rel=1e-3)


def closed_form_poles(d):
    """-g and the roots of s^2 + g s + Gamma (Phi_1/J)^2 (the family's hand derivation), sorted."""
    g, c = d.observer.g, d.observer.Gamma * (d.estimate.Phi[0] / d.estimate.J) ** 2
    return np.sort([-g, *np.roots([1.0, g, c]).real])


def rule_slow_pole(d):
    """The documented rule: min(48.55/tau_m, g/4), tau_m = J w_N / T_N (mechanical)."""
    tau_m = d.motor.J * d.rating.n_N * math.pi / 30 / d.T_N
    return min(48.55 / tau_m, d.observer.g / 4)


@pytest.fixture(scope="module", params=["paper", "servo"])
def sinusoidal(request):
    """The paper's motor with a sinusoidal EMF (slow pole from tau_m) and a 5-kW servo (at g/4)."""
    if request.param == "paper":
        return paper('Phi = ["0.5021 Vs"]')
    return load_drive_text(SERVO, "servo.toml")


def test_the_linearization_puts_the_poles_where_the_rule_says(sinusoidal):
    d = sinusoidal
    s_T = rule_slow_pole(d)
    rule = np.sort([-d.observer.g, -(d.observer.g - s_T), -s_T])
    want = closed_form_poles(d)
    assert want == pytest.approx(rule, rel=1e-5)  # Gamma is written with 6 digits
    w = d.rpm_to_w(np.array([-0.25, 0.1, 1.0]) * d.rating.n_N)
    r = FAMILY.linearize(d, FAMILY.gains(d), w[:, None], np.array([0.0, d.T_N])[None, :])
    got = np.sort(r.poles.real, axis=1)
    assert np.abs(r.poles.imag).max() < 1e-6 * d.observer.g
    assert got == pytest.approx(np.broadcast_to(want, got.shape), rel=1e-6)
    # the discrete observer at the real sampling period: within 1 % (g T_s <= 0.2)
    got_d = np.sort(r.poles_discrete.real, axis=1)[:, -3:]
    assert got_d == pytest.approx(np.broadcast_to(want, got_d.shape), rel=0.01)


def test_the_runtime_step_forgets_a_load_error_at_the_slow_pole(sinusoidal):
    """The step that runs, fed by the exact motor of eqs. (2)-(5) at constant speed (numpy, here), starts
    from exact EMF and speed estimates and T_L_hat = 0 under load: the load error then decays at s_T."""
    d = sinusoidal
    rs = FAMILY.runtime(d, FAMILY.gains(d))
    step, p = rs.step_function(), rs.p
    m, o, T_s = d.motor, d.observer, d.control.T_s
    s_T = rule_slow_pole(d)
    w, T0 = float(d.rpm_to_w(0.1 * d.rating.n_N)), d.T_N
    k = np.arange(round(10 / (s_T * T_s)) + 1)
    th = w * k * T_s
    r, dr = np.stack([-np.sin(th), np.cos(th)]), np.stack([-np.cos(th), -np.sin(th)])
    i = T0 / m.Phi[0] * r  # the ripple-free current (25) of the load
    e = m.Phi[0] * r * w / m.p_r
    u = m.R * i + m.L * T0 / m.Phi[0] * w * dr + e  # eq. (2)
    # eq. (15): zeta = e_hat + g L i, tau = T_L_hat - (Gamma L / J) phi . i, with T_L_hat = 0
    x = np.array([*(e[:, 0] + o.g * m.L * i[:, 0]), -o.Gamma * m.L / m.J * T0, 0.0, w, *i[:, 0], *u[:, 0], 0])
    err = []
    for j in k[1:]:
        x, y = step(x, [*i[:, j], *u[:, j]], p, rs.gain)
        err.append(T0 - float(y[2]))
    k1, k2 = round(5 / (s_T * T_s)), len(err)
    rate = -math.log(err[k2 - 1] / err[k1 - 1]) / ((k2 - k1) * T_s)
    assert rate == pytest.approx(s_T, rel=0.01)
    assert 0 < err[k1 - 1] < T0  # decaying, not oscillating through zero


def test_a_complete_drive_file_passes_through_unchanged(deangelo2006):
    text = (resources.files("sensorless.design.pmac_reduced_order.presets") / "deangelo2006.toml").read_text()
    data = tomllib.loads(text)
    out = document(data, "preset").data()
    for section, values in data.items():
        for k, v in values.items():
            assert out[section][k] == v, (section, k)
    again = load_drive_text(text, "preset:deangelo2006")
    assert (again.motor, again.estimate, again.observer, again.control) == (
        deangelo2006.motor,
        deangelo2006.estimate,
        deangelo2006.observer,
        deangelo2006.control,
    )
    assert again.warnings == ()


def edit(old: str, new: str) -> str:
    assert old in SERVO, old
    return SERVO.replace(old, new, 1)


@pytest.mark.parametrize(
    ("text", "key", "words"),
    [
        (edit('n_N = "3000 rpm"\n', ""), "rating.n_N", "missing key"),
        (edit('T_N = "16 Nm"\n', ""), "rating.T_N", "or the rated current I_N"),
        (edit('T_N = "16 Nm"', 'T_N = "16 Nm"\nP_N = "6 kW"'), "rating.T_N", "give P_N or T_N"),
        (edit('R_ll = "0.6 ohm"', 'R_ll = "0.6 ohm"\nR = "0.3 ohm"'), "motor.R", "give one of"),
        (edit('R_ll = "0.6 ohm"\n', ""), "motor.R", "missing key"),
        (edit('L_ll = "8 mH"', 'L_d = "3 mH"\nL_q = "5 mH"'), "motor.L_q", "saliency"),
        (
            edit('emf_convention = "line-line rms"', 'emf_convention = "phase rms"'),
            "motor.kE, rating.n_N, inverter.u_dc",
            "back-EMF",
        ),
        (edit('J = "12 kg cm2"', 'J = "12 kg cm2"\nPhi = ["0.7 Vs"]'), "motor.kE", "motor.Phi[0]"),
        (edit('J = "12 kg cm2"', 'J = "12 kg cm2"\nharmonics = [1, 5]'), "motor.Phi", "missing key"),
        (edit('f_s = "8 kHz"', 'f_s = "0.7 kHz"'), "inverter.f_s, rating.n_N", "samples per electrical"),
        (edit('f_s = "8 kHz"', 'f_s = "8 kHz"\n[control]\nT_s = "100 us"'), "inverter.f_s", "give one"),
        (edit('u_dc = "560 V"', 'u_dc = "380 V"'), "motor.kE, rating.n_N, inverter.u_dc", "back-EMF"),
        (edit("[inverter]", "[inverter]\nf_pwm = 1"), "inverter.f_pwm", "unknown key"),
        (edit('connection = "wye"\n', ""), "motor.connection", "missing key"),
        # datasheet terms are the physical motor; the electrical reading's J would be J/p^2
        (edit('J = "12 kg cm2"', 'J = "12 kg cm2"\nreading = "electrical"'), "motor.reading", "physical"),
    ],
    ids=lambda v: v if isinstance(v, str) and len(v) < 40 else "",
)
def test_bad_minimal_files_name_file_and_key(text, key, words):
    with pytest.raises(DriveFileError) as e:
        load_drive_text(text, "my.toml")
    msg = str(e.value)
    assert msg.startswith(f"my.toml: key '{key}'") or msg.startswith(f"my.toml: keys '{key}'"), msg
    assert words in msg, msg


def test_init_of_a_bad_file_is_one_line_and_writes_nothing(tmp_path, capsys):
    src, out = tmp_path / "m.toml", tmp_path / "d.toml"
    src.write_text(edit('u_dc = "560 V"', 'u_dc = "380 V"'))
    assert main(["init", str(src), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("sensorless init: error: "), err
    assert "Traceback" not in err and not out.exists()
