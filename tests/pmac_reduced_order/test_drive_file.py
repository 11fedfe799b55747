"""Drive files of the reduced-order observer family: the preset, both readings, every error class."""

from importlib import resources

import numpy as np
import pytest
from sensorless.design.drive import load_drive_text
from sensorless.design.units import DriveFileError

PRESET = (resources.files("sensorless.design.pmac_reduced_order.presets") / "deangelo2006.toml").read_text()


def edit(old: str, new: str) -> str:
    assert old in PRESET, old
    return PRESET.replace(old, new, 1)


def test_preset_has_the_papers_values(deangelo2006):
    d = deangelo2006
    m = d.motor
    assert d.kind == "pmac-reduced-order"
    assert (m.p, m.R, m.J, m.B) == (8, 0.01, 0.78, 0.0015)
    assert m.L == pytest.approx(100e-6)
    assert m.harmonics == (1, 5)
    assert m.Phi == pytest.approx((0.5021, 0.5021 / 25))
    assert (d.observer.g, d.observer.Gamma) == (400.0, 10000.0)
    assert d.control.T_s == pytest.approx(180e-6)
    assert d.control.discretization == "rk2-model"
    assert m.reading == "mechanical" and m.p_r == 8.0
    assert d.estimate.Phi == m.Phi and d.estimate.J == m.J
    assert d.T_N == pytest.approx(30e3 / (4000 * np.pi / 30))
    # speeds: 250 r/min mechanical is 8 x 26.18 = 209.4 rad/s electrical in either reading
    assert d.rpm_to_w(250.0) == pytest.approx(250 * np.pi / 30 * 8)
    assert d.w_base == pytest.approx(4000 * np.pi / 30 * 8)


def test_electrical_reading_and_arbitrary_harmonics():
    d = load_drive_text(
        edit('reading = "mechanical"', 'reading = "electrical"').replace(
            "harmonics = [1, 5]        # eq. (4): odd orders (printed in positive sequence)\n"
            'Phi = ["0.5021 Vs", "0.04 Phi_1"]',
            'harmonics = [1, -5, 7, 11, 13]\nPhi = ["0.5 Wb", "-0.04 Phi_1", "20 mVs", "0.005 Nm/A", 0.001]',
        ),
        "x.toml",
    )
    assert d.motor.reading == "electrical" and d.motor.p_r == 1.0
    assert d.motor.harmonics == (1, -5, 7, 11, 13)
    assert d.motor.Phi == pytest.approx((0.5, -0.02, 0.02, 0.005, 0.001))
    # the observer's params vector follows the estimate's own series
    assert d.observer_params().size == 8 + 2


@pytest.mark.parametrize(
    ("text", "key", "words"),
    [
        (edit('R = "10 mohm"\nL', 'R = "10 mohm"\nRx = 1\nL'), "motor.Rx", "unknown key"),
        (edit('J = "0.78 kgm2"\nB', "B"), "motor.J", "missing key"),
        (edit('R = "10 mohm"', 'R = "10 mH"'), "motor.R", "not a resistance unit"),
        (edit('L = "100 uH"', "L = true"), "motor.L", "boolean"),
        (edit("p = 8", "p = 8.5"), "motor.p", "integer"),
        (edit("p = 8", "p = 0"), "motor.p", "non-physical"),
        (edit('R = "10 mohm"', 'R = "-10 mohm"'), "motor.R", "non-physical"),
        (edit('J = "0.78 kgm2"', "J = 0"), "motor.J", "non-physical"),
        (edit('B = "0.0015 kg m^2/s"', "B = -1e-3"), "motor.B", "non-physical"),
        (edit('reading = "mechanical"', 'reading = "magnetic"'), "motor.reading", "unknown reading"),
        (edit('reading = "mechanical"', "reading = 1"), "motor.reading", "expected a string"),
        (edit("harmonics = [1, 5]  ", "harmonics = [1, 4]  "), "motor.harmonics", "odd integers"),
        (edit("harmonics = [1, 5]  ", "harmonics = [5, 1]  "), "motor.harmonics", "fundamental"),
        (edit("harmonics = [1, 5]  ", "harmonics = [1, 1]  "), "motor.harmonics", "repeated"),
        (edit("harmonics = [1, 5]  ", "harmonics = []  "), "motor.harmonics", "non-empty list"),
        (edit("harmonics = [1, 5]  ", "harmonics = [1, 5, 7]  "), "motor.Phi", "3 harmonic orders"),
        (
            edit('Phi = ["0.5021 Vs", "0.04 Phi_1"]   #', 'Phi = ["1 Phi_1", "0.04 Phi_1"]   #'),
            "motor.Phi[0]",
            "relative",
        ),
        (
            edit('Phi = ["0.5021 Vs", "0.04 Phi_1"]   #', 'Phi = ["0 Vs", "0.04 Phi_1"]   #'),
            "motor.Phi[0]",
            "non-physical",
        ),
        (
            edit('Phi = ["0.5021 Vs", "0.04 Phi_1"]   #', 'Phi = ["0.5021 Vs", "0.04 ohm"]   #'),
            "motor.Phi[1]",
            "unit 'ohm'",
        ),
        # phi = Phi (j e^{j th} + j e^{-j th}) = 2 Phi [0, cos th] vanishes at th = pi/2: (13) undefined
        (
            edit("harmonics = [1, 5]  ", "harmonics = [1, -1]  ").replace(
                '"0.04 Phi_1"]   #', '"1 Phi_1"]   #', 1
            ),
            "motor.Phi",
            "vanishes",
        ),
        (
            edit('Phi = ["0.5021 Vs", "0.04 Phi_1"]\n\n[observer]', 'Phi = ["0.5 Vs"]\n\n[observer]'),
            "estimate.Phi",
            "1 amplitudes",
        ),
        (edit('g = "400 1/s"', 'g = "400 Hz"'), "observer.g", "not a rate unit"),
        (edit('g = "400 1/s"', "g = 0"), "observer.g", "non-physical"),
        (edit("Gamma = 10000", "Gamma = -1"), "observer.Gamma", "non-physical"),
        (
            edit('discretization = "rk2-model"', 'discretization = "rk4"'),
            "control.discretization",
            "unknown scheme",
        ),
        (edit('T_s = "180 us"', 'T_s = "180 uH"'), "control.T_s", "not a time unit"),
        (edit('T_s = "180 us"', 'T_s = "1 ms"'), "control.T_s", "too long for the envelope"),
        (edit('"-250 rpm", ', '"0 rpm", '), "envelope.speeds[0]", "zero speed"),
        (
            edit('loads = ["0 Nm", "5 Nm", "-7 Nm"]', 'loads = ["0 Nm", "5 parsec"]'),
            "envelope.loads[1]",
            "unit 'parsec'",
        ),
        (edit("[envelope]", "[envelope]\nspeed = 1"), "envelope.speed", "unknown key"),
        (PRESET + "\n[injection]\nw_c = 1\n", "injection", "unknown key"),
        (edit('kind = "pmac-reduced-order"', 'kind = "pmac"'), "drive.kind", "unknown drive kind"),
    ],
    ids=lambda v: v if isinstance(v, str) and len(v) < 40 else "",
)
def test_bad_input_names_file_and_key(text, key, words):
    with pytest.raises(DriveFileError) as e:
        load_drive_text(text, "my002.toml")
    msg = str(e.value)
    assert msg.startswith("my002.toml: key '"), msg
    assert f"'{key}'" in msg, msg
    assert words in msg, msg


def test_current_sensor_noise_is_optional_with_a_default():
    """[control] i_noise is optional: 0.3 % of the current amplitude at the nominal torque and base speed
    (the analysis's own operating point); given, read in A; checked like every key."""
    d = load_drive_text(PRESET, "p.toml")
    assert d.control.i_noise == pytest.approx(0.003 * d.T_N / d.motor.Phi[0], rel=0.05)
    old = 'T_max = "143 Nm"'
    d = load_drive_text(edit(old, old + '\ni_noise = "0.2 A"'), "p.toml")
    assert d.control.i_noise == pytest.approx(0.2)
    with pytest.raises(DriveFileError, match=r"key 'control\.i_noise'.*non-physical"):
        load_drive_text(edit(old, old + '\ni_noise = "0 A"'), "p.toml")
