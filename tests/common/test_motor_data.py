"""design/motor_data.py and design/plausibility.py: datasheet terms to the per-phase model; plausibility.

Every expected value is a closed form typed here from the physics, not the code's output:
- the phase peak back-EMF is p psi_pm per mechanical rad/s; line-to-line = sqrt(3) x phase (sinusoidal,
  120 degrees apart), rms = peak / sqrt(2); 1 V/krpm = 1 V per (1000 x 2 pi / 60) rad/s;
- the torque at i_d = 0 is T = 1.5 p psi_pm i_peak (amplitude-invariant dq), i_peak = sqrt(2) i_rms;
- between two terminals a wye shows two phases in series, 2 R_Y; a delta of phase resistance R_D shows
  R_D parallel to 2 R_D = 2/3 R_D, and its equivalent wye is R_Y = R_D / 3: so R_ll = 2 R_Y for both.
"""

from __future__ import annotations

import math

import pytest
from sensorless.design.drive import load_drive
from sensorless.design.motor_data import read_motor
from sensorless.design.plausibility import plausibility
from sensorless.design.units import DriveFileError
from sensorless.reports.cli.main import main

F = "m.toml"
RPM = 2 * math.pi / 60  # rad/s per r/min
KRPM = 1000 * RPM
S2, S3 = math.sqrt(2), math.sqrt(3)

P, PSI = 4, 0.05  # the reference motor of the conversion tests
BASE = {"p": P, "R_s": "1 ohm", "L_s": "5 mH", "psi_pm": f"{PSI} Vs", "J": "1 kg cm2"}


def motor(**kw):
    """read_motor of BASE with the keys of ``kw`` added (a None value removes the key)."""
    t = {**BASE, **kw}
    return read_motor({k: v for k, v in t.items() if v is not None}, F)


def refused(*words, **kw):
    """The DriveFileError message of motor(**kw); it names the file and each of ``words``."""
    with pytest.raises(DriveFileError) as e:
        motor(**kw)
    msg = str(e.value)
    assert msg.startswith(F + ": "), msg
    for w in words:
        assert w in msg, (w, msg)
    return msg


# kE per mechanical rad/s in each convention, from the phase peak back-EMF p psi_pm
KE_SI = {
    "phase peak": P * PSI,
    "phase rms": P * PSI / S2,
    "line-line peak": S3 * P * PSI,
    "line-line rms": S3 * P * PSI / S2,
}


# ------------------------------------------------------------------------------------ flux linkage
@pytest.mark.parametrize("conv", list(KE_SI))
@pytest.mark.parametrize(("unit", "per_si"), [("V s/rad", 1.0), ("V/krpm", KRPM), ("mV/rpm", 1e3 * RPM)])
def test_every_emf_convention_and_unit_round_trips_to_psi_pm(conv, unit, per_si):
    m = motor(psi_pm=None, kE=f"{KE_SI[conv] * per_si:.12g} {unit}", emf_convention=conv)
    assert m.psi_pm == pytest.approx(PSI, rel=1e-9)
    assert m.source["psi_pm"] == "motor.kE"


def test_kE_spelled_as_datasheets_do():
    # 1 V/krpm = 1 mV/rpm; min^-1 is r/min
    for unit in ("V/1000rpm", "mV/min-1", "mV/min⁻¹", "V/kRPM", "mV/(r/min)"):
        m = motor(
            psi_pm=None, kE=f"{KE_SI['line-line rms'] * KRPM:.12g} {unit}", emf_convention="line-line rms"
        )
        assert m.psi_pm == pytest.approx(PSI, rel=1e-9), unit


@pytest.mark.parametrize("true", list(KE_SI))
@pytest.mark.parametrize("said", list(KE_SI))
def test_a_wrong_emf_convention_is_caught_by_a_second_flux_key(true, said):
    # any two conventions differ by a factor of at least sqrt(3/2) (22 %), beyond the 10 % tolerance
    kE = f"{KE_SI[true]:.12g} V s/rad"
    if true == said:
        assert motor(psi_pm=f"{PSI} Vs", kE=kE, emf_convention=said).psi_pm == pytest.approx(PSI)
    else:
        refused("motor.kE", "motor.psi_pm", psi_pm=f"{PSI} Vs", kE=kE, emf_convention=said)


def test_KV_is_rpm_per_volt_of_line_line_peak_back_emf():
    kv = 1 / (S3 * P * PSI)  # mechanical rad/s per volt of line-to-line peak back-EMF
    for text in (f"{kv / RPM:.12g} rpm/V", f"{kv:.12g} (rad/s)/V"):
        m = motor(psi_pm=None, KV=text)
        assert m.psi_pm == pytest.approx(PSI, rel=1e-9)
        assert m.source["psi_pm"] == "motor.KV"
    # 270 rpm/V with 7 pole pairs (a hobby outrunner): psi = 60 / (sqrt(3) 2 pi 270 7)
    assert motor(p=7, psi_pm=None, KV="270 rpm/V").psi_pm == pytest.approx(60 / (S3 * 2 * math.pi * 270 * 7))


@pytest.mark.parametrize("conv", list(KE_SI))
def test_KV_with_its_emf_convention_is_rpm_per_volt_of_that_measure(conv):
    # KV = w_m / e, e the back-EMF in the stated measure: per volt of it, 1/KE_SI mechanical rad/s
    kv_rpm = 1 / KE_SI[conv] / RPM
    m = motor(psi_pm=None, KV=f"{kv_rpm:.12g} rpm/V", emf_convention=conv)
    assert m.psi_pm == pytest.approx(PSI, rel=1e-9)
    assert m.source["psi_pm"] == "motor.KV"
    assert conv in m.rules["psi_pm"]
    # the stated default: line-line peak, 270 rpm/V and 7 pole pairs as in docs/motor_data.md
    explicit = motor(p=7, psi_pm=None, KV="270 rpm/V", emf_convention="line-line peak").psi_pm
    assert explicit == motor(p=7, psi_pm=None, KV="270 rpm/V").psi_pm
    # kE and KV given together share the convention; a KV of the other measure disagrees
    kE = f"{KE_SI[conv]:.12g} V s/rad"
    assert motor(psi_pm=None, kE=kE, KV=f"{kv_rpm:.12g} rpm/V", emf_convention=conv).psi_pm == pytest.approx(
        PSI
    )


@pytest.mark.parametrize("conv", list(KE_SI))
def test_minimal_drive_file_with_KV_and_its_convention_loads(tmp_path, conv):
    # a drone outrunner's datasheet: 270 rpm/V, 14 poles; psi = phase peak EMF per mechanical rad/s / p
    f = tmp_path / "kv.toml"
    f.write_text(
        MINIMAL.format(flux=f'KV = "270 rpm/V"\nemf_convention = "{conv}"')
        .replace("poles = 10", "poles = 14")
        .replace("1.27 Nm", "0.1 Nm")
    )
    e_per_rad_s = 1 / (270 * RPM)  # V of the stated measure per mechanical rad/s
    phase_peak = {"line-line peak": 1 / S3, "line-line rms": S2 / S3, "phase peak": 1.0, "phase rms": S2}[
        conv
    ]
    assert load_drive(f).motor.psi_pm == pytest.approx(e_per_rad_s * phase_peak / 7, rel=1e-5)  # 6 digits


@pytest.mark.parametrize(
    ("conv", "kT"), [("rms", 1.5 * P * PSI * S2), ("peak", 1.5 * P * PSI)]
)  # T = 1.5 p psi i_peak, per A rms: i_peak = sqrt(2) i_rms
def test_kT_per_ampere_rms_and_peak(conv, kT):
    for text in (f"{kT:.12g} Nm/A", f"{1e3 * kT:.12g} mNm/A", f"{kT:.12g} N·m/A"):
        m = motor(psi_pm=None, kT=text, torque_convention=conv)
        assert m.psi_pm == pytest.approx(PSI, rel=1e-9)


def test_disagreeing_kE_and_kT_name_both_keys_and_the_flux_each_implies():
    kE = f"{KE_SI['line-line rms'] * KRPM:.12g} V/krpm"
    kT_rms = 1.5 * S2 * P * PSI
    # the rms kT read as per A peak: psi = kT_rms / (1.5 p) = sqrt(2) psi
    msg = refused(
        "motor.kT",
        "motor.kE",
        f"{S2 * PSI:.5g} Vs",
        f"{PSI:.5g} Vs",
        psi_pm=None,
        kE=kE,
        emf_convention="line-line rms",
        kT=f"{kT_rms:.12g} Nm/A",
        torque_convention="peak",
    )
    assert "41 %" in msg  # sqrt(2) - 1
    # within the tolerance (10 %): accepted; the first in the order psi_pm, kE, KV, kT is used
    for factor in (1.05, 0.95, 1.09, 0.91):
        m = motor(
            psi_pm=None,
            kE=kE,
            emf_convention="line-line rms",
            kT=f"{factor * kT_rms:.12g} Nm/A",
            torque_convention="rms",
        )
        assert m.psi_pm == pytest.approx(PSI, rel=1e-9)
        assert m.source["psi_pm"] == "motor.kE"
    for factor in (1.11, 0.89):
        refused(
            "motor.kT",
            "motor.kE",
            psi_pm=None,
            kE=kE,
            emf_convention="line-line rms",
            kT=f"{factor * kT_rms} Nm/A",
            torque_convention="rms",
        )
    m = motor(psi_pm="0.051 Vs", kT=f"{kT_rms:.12g} Nm/A", torque_convention="rms")
    assert (m.psi_pm, m.source["psi_pm"]) == (pytest.approx(0.051), "motor.psi_pm")


def test_missing_conventions_are_errors_naming_the_missing_key():
    refused("motor.emf_convention", "motor.kE", psi_pm=None, kE="30 V/krpm")
    refused("motor.torque_convention", "motor.kT", psi_pm=None, kT="0.5 Nm/A")
    refused("motor.connection", "motor.R_ll", R_s=None, R_ll="3.6 ohm")
    refused("motor.connection", "motor.L_ll", L_s=None, L_ll="10 mH")
    # a convention without its constant, and a convention that is none of the allowed
    refused("motor.emf_convention", "motor.kE", "motor.KV", emf_convention="line-line rms")
    refused("motor.emf_convention", "'line-line rms'", psi_pm=None, KV="270 rpm/V", emf_convention="ll rms")
    refused("motor.emf_convention", "'line-line rms'", psi_pm=None, kE="30 V/krpm", emf_convention="line rms")
    refused("motor.torque_convention", "'rms'", psi_pm=None, kT="0.5 Nm/A", torque_convention="amplitude")


def test_unknown_keys_and_missing_flux_are_errors():
    refused("motor.Ke", Ke="30 V/krpm")  # kE is the key
    refused("motor.psi_pm", "kE", psi_pm=None)


# --------------------------------------------------------------------------- windings and poles
@pytest.mark.parametrize("connection", ["wye", "delta", " Delta "])
def test_line_to_line_R_and_L_are_twice_the_equivalent_wye_per_phase(connection):
    m = motor(R_s=None, L_s=None, R_ll="3.6 ohm", L_ll="10 mH", connection=connection)
    assert (m.R_s, m.L_d, m.L_q) == (pytest.approx(1.8), pytest.approx(5e-3), pytest.approx(5e-3))
    assert m.source["R_s"] == "motor.R_ll" and m.source["L_d"] == "motor.L_ll"


def test_delta_phase_values_are_three_times_the_equivalent_wye():
    R_D = 5.4  # a delta's own phase resistance; between two terminals: R_D || 2 R_D
    R_ll = R_D * 2 * R_D / (R_D + 2 * R_D)
    m = motor(R_s=None, R_ll=f"{R_ll:.12g} ohm", connection="delta")
    assert m.R_s == pytest.approx(R_D / 3)


def test_per_phase_and_salient_inductances():
    m = motor(L_s=None, L_d="4 mH", L_q="8 mH")
    assert (m.L_d, m.L_q) == (pytest.approx(4e-3), pytest.approx(8e-3))
    refused("motor.L_q", L_s=None, L_d="4 mH")
    refused("motor.L_q", L_q="8 mH")  # with L_s
    refused("motor.L_ll", L_ll="10 mH", connection="wye")  # with L_s
    refused("motor.R_ll", R_ll="2 ohm", connection="wye")  # with R_s


def test_poles_and_pole_pairs():
    assert motor(p=None, poles=10).p == 5
    assert motor(p=5, poles=10).p == 5
    refused("motor.poles", "even", p=None, poles=9)
    refused("motor.poles", "motor.p = 10", "5 pole pairs", p=10, poles=10)
    refused("motor.p", p=None)
    refused("motor.p", p=2.5)
    # kE per mechanical speed: the same datasheet with poles or p gives the same flux
    kE = dict(psi_pm=None, kE=f"{KE_SI['phase peak']:.12g} V s/rad", emf_convention="phase peak")
    assert motor(p=None, poles=2 * P, **kE).psi_pm == pytest.approx(PSI)


@pytest.mark.parametrize(
    ("text", "si"),
    [
        ("0.6 kg cm2", 0.6e-4),
        ("0.6 kg·cm²", 0.6e-4),
        ("0.6 kgcm2", 0.6e-4),
        ("0.6 kg cm^2", 0.6e-4),
        ("600 g cm2", 600e-7),  # 1 g cm2 = 1e-3 kg x 1e-4 m2
        ("600 gcm²", 600e-7),
        ("6e-5 kg m^2", 6e-5),
        ("6e-5 kgm2", 6e-5),
        ("60 kg mm2", 60e-6),
        (6e-5, 6e-5),
    ],
)
def test_inertia_spellings(text, si):
    assert motor(J=text).J == pytest.approx(si, rel=1e-12)


def test_inertia_of_another_dimension_or_missing_is_an_error():
    refused("motor.J", "kg cm", J="0.6 kg cm")
    refused("motor.J", J=None)
    refused("motor.J", "> 0", J="-0.6 kg cm2")


# ----------------------------------------------------------------------------------- plausibility
# a 10-pole servo, psi 0.05 Vs, R 1.8 ohm, L 5 mH, at 3000 r/min (250 Hz electrical), 1.27 N m, 310 V, 10 kHz
SERVO = {"poles": 10, "R_ll": "3.6 ohm", "L_ll": "10 mH", "connection": "wye", "psi_pm": "0.05 Vs", "J": 6e-5}
KEYS = {
    "n_N": "rating.n_N",
    "T_N": "rating.T_N",
    "I_N": "rating.I_N",
    "f_N": "rating.f_N",
    "u_dc": "inverter.u_dc",
    "T_s": "inverter.f_s",
    "w_max": "runtime.w_max",
}
PS, PSI_S, R, L = 5, 0.05, 1.8, 5e-3
W_N = 2 * math.pi * 3000 / 60 * PS  # electrical rad/s at n_N
EMF_N = W_N * PSI_S  # no-load peak phase back-EMF at n_N
I_Q = 1.27 / (1.5 * PS * PSI_S)  # peak q current for T_N (non-salient: i_d = 0)
U_RATED = math.hypot(W_N * L * I_Q, R * I_Q + EMF_N)  # peak phase voltage at T_N and n_N
I_RMS = I_Q / S2  # the rms current that gives T_N exactly
OK = dict(n_N=3000.0, T_N=1.27, I_N=None, f_N=None, u_dc=310.0, T_s=1e-4, w_max=2 * W_N)


def findings(**kw):
    return plausibility(read_motor(SERVO, F), keys=KEYS, **{**OK, **kw})


def only(fs, level, keys):
    assert [(f.level, f.keys) for f in fs] == [(level, keys)], [f.line(F) for f in fs]
    assert fs[0].line(F).startswith(f"{F}: {', '.join(keys)}: ")
    return fs[0].text


def test_a_plausible_motor_gives_no_findings():
    assert findings() == []
    assert findings(I_N=I_RMS, f_N=250.0) == []


def test_f_N_against_n_N_and_pole_pairs():
    assert findings(f_N=250 * 1.009) == []
    keys = ("rating.f_N", "rating.n_N", "motor.poles")
    assert "250 Hz" in only(findings(f_N=250 * 1.02), "error", keys)
    only(findings(f_N=500.0), "error", keys)  # poles taken for pole pairs


def test_back_emf_at_rated_speed_against_the_inverter_voltage():
    # 4 % above u_dc/sqrt(3): no error, but T_N at n_N needs field weakening: a warning
    fs = findings(u_dc=S3 * EMF_N / 1.04)
    only(fs, "warning", ("rating.T_N", "rating.n_N", "inverter.u_dc"))
    text = only(findings(u_dc=S3 * EMF_N / 1.10), "error", ("motor.psi_pm", "rating.n_N", "inverter.u_dc"))
    assert f"{EMF_N:.4g} V" in text


def test_rated_point_voltage_warning():
    assert EMF_N < U_RATED
    fs = findings(u_dc=S3 * (EMF_N + U_RATED) / 2)  # the back-EMF fits, the rated point does not
    assert f"{U_RATED:.4g} V" in only(fs, "warning", ("rating.T_N", "rating.n_N", "inverter.u_dc"))
    assert findings(u_dc=S3 * U_RATED * 1.01) == []


def test_mechanical_time_constant_catches_an_inertia_unit():
    tau_m = 6e-5 * W_N / PS / 1.27  # J w_N / (p T_N) of the servo: 15 ms
    assert 1e-3 < tau_m < 60
    keys = ("motor.J", "rating.T_N", "rating.n_N")
    for J in (0.6, 6e-9):  # "0.6" meant kg cm2 but read as kg m2; g cm2 read as ... 1e-4 of it
        fs = plausibility(read_motor({**SERVO, "J": J}, F), keys=KEYS, **OK)
        assert f"{J * W_N / PS / 1.27:.3g} s" in only(fs, "warning", keys)


def test_inductive_voltage_of_the_rated_point_against_the_inverter():
    # w_N L i_q across the inductance alone: 3x the available voltage is an error (no field weakening
    # removes it); an inductance given as a bare number (henries) where mH was meant is 1000x
    u_avail = 310.0 / S3
    ratio = W_N * L * I_Q / u_avail
    assert ratio < 1  # the servo itself is fine (and no finding above)
    keys = ("motor.L_ll", "rating.T_N", "rating.n_N", "inverter.u_dc")
    bare = plausibility(read_motor({**SERVO, "L_ll": 10.0}, F), keys=KEYS, **OK)  # 10 H, not 10 mH
    text = only(bare, "error", keys)
    assert f"{1000 * ratio:.3g} times" in text and "henries" in text
    # just below and above the threshold: scale the inductance (the back-EMF stays as it is)
    for f, level in ((2.9, "warning"), (3.1, "error")):
        mh = 10 * f / ratio
        fs = plausibility(read_motor({**SERVO, "L_ll": f"{mh} mH"}, F), keys=KEYS, **OK)
        assert [x.level for x in fs] == [level], [x.line(F) for x in fs]


@pytest.mark.parametrize(
    ("I_N", "level"),
    [(I_RMS / 1.05, None), (I_RMS / 1.2, "warning"), (I_RMS * 1.25, "warning"), (I_RMS / 1.4, "error")],
)
def test_rated_torque_against_current_and_flux(I_N, level):
    fs = findings(I_N=I_N)
    if level is None:
        assert fs == []
    else:
        only(fs, level, ("rating.T_N", "rating.I_N", "motor.psi_pm"))


def test_samples_per_electrical_period_at_top_speed():
    def at(samples):
        return findings(w_max=2 * math.pi * 1e4 / samples)  # f_s = 10 kHz

    assert at(11) == []
    keys = ("inverter.f_s", "runtime.w_max")
    assert "9 samples" in only(at(9), "warning", keys)
    only(at(3), "error", keys)


def test_electrical_time_constant_against_the_sampling_period():
    tau = L / R

    def at(periods):  # T_s = tau / periods, with 20 samples per period at the top speed
        T_s = tau / periods
        return findings(T_s=T_s, w_max=2 * math.pi / (20 * T_s))

    assert at(6) == []
    keys = ("motor.L_ll", "motor.R_ll", "inverter.f_s")
    only(at(4), "warning", keys)
    only(at(0.5), "error", keys)


def test_mtpa_torque_of_a_salient_motor():
    from sensorless.design.motor_data import mtpa_torque

    m = read_motor({"p": 3, "R_s": 1.0, "L_d": "4 mH", "L_q": "8 mH", "psi_pm": "0.1 Vs", "J": 1e-4}, F)
    i, a = 20.0, 4e-3  # peak current; L_q - L_d
    i_d = (0.1 - math.sqrt(0.1**2 + 8 * a**2 * i**2)) / (4 * a)  # MTPA angle, closed form
    i_q = math.sqrt(i**2 - i_d**2)
    assert mtpa_torque(i, m) == pytest.approx(1.5 * 3 * (0.1 - a * i_d) * i_q, rel=1e-6)


def test_steady_voltage_is_the_dq_model_at_rest():
    from sensorless.design.motor_data import steady_voltage

    m = read_motor({"p": 3, "R_s": 0.5, "L_d": "4 mH", "L_q": "8 mH", "psi_pm": "0.1 Vs", "J": 1e-4}, F)
    for w, i_d, i_q in ((300.0, -5.0, 12.0), (-800.0, 0.0, -3.0), (0.0, -2.0, 7.0)):
        # u = R i + w J psi with psi = (L_d i_d + psi_pm, L_q i_q), typed here from the model
        u_d = 0.5 * i_d - w * 8e-3 * i_q
        u_q = 0.5 * i_q + w * (4e-3 * i_d + 0.1)
        assert steady_voltage(m, w, i_d, i_q) == pytest.approx(math.hypot(u_d, u_q), rel=1e-12)


# ---------------------------------------------------------------------------- end to end: init
MINIMAL = """[drive]
name = "servo400"
kind = "ipmsm-adaptive"
source = "a 10-pole servo datasheet"

[motor]
poles = 10
{flux}
R_ll = "3.6 ohm"
L_ll = "10 mH"
connection = "wye"
J = "0.6 kg cm2"

[rating]
n_N = "3000 rpm"
T_N = "1.27 Nm"

[inverter]
u_dc = "310 V"
f_s = "10 kHz"
"""
PSI_33 = 33 / KRPM * S2 / S3 / 5  # 33 V/krpm line-line rms, 5 pole pairs


def test_init_converts_a_datasheet_motor(tmp_path, capsys):
    src, out = tmp_path / "servo.toml", tmp_path / "servo-drive.toml"
    src.write_text(MINIMAL.format(flux='kE = "33 V/krpm"\nemf_convention = "line-line rms"'))
    assert main(["init", str(src), "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    for d in (load_drive(out), load_drive(src)):
        m = d.motor
        assert m.p == 5
        assert m.psi_pm == pytest.approx(PSI_33, rel=1e-4)
        assert (m.R_s, m.L_d, m.L_q, m.J) == pytest.approx((1.8, 5e-3, 5e-3, 0.6e-4), rel=1e-4)


def test_init_refuses_a_flux_five_times_too_large(tmp_path, capsys):
    src, out = tmp_path / "servo.toml", tmp_path / "servo-drive.toml"
    src.write_text(MINIMAL.format(flux=f'psi_pm = "{5 * PSI_33:.6g} Vs"'))
    assert main(["init", str(src), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("sensorless init: error: ")
    for k in ("motor.psi_pm", "rating.n_N", "u_dc", "back-EMF"):
        assert k in err, (k, err)
    assert not out.exists()


def test_init_error_names_the_source_file_and_its_keys(tmp_path, capsys):
    src, out = tmp_path / "servo.toml", tmp_path / "servo-drive.toml"
    src.write_text(MINIMAL.format(flux='kE = "165 V/krpm"\nemf_convention = "line-line rms"'))
    assert main(["init", str(src), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"{src}: keys 'motor.kE, rating.n_N, inverter.u_dc'" in err, err
