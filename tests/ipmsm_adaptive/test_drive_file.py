"""Strict drive-description loading: every error class names the file and the key."""

from importlib import resources

import pytest
from sensorless.design.drive import load_drive, load_drive_text, preset_names
from sensorless.design.units import DriveFileError

PRESET = (resources.files("sensorless.design.ipmsm_adaptive.presets") / "piippo2008.toml").read_text()


def edit(old: str, new: str) -> str:
    assert old in PRESET, old
    return PRESET.replace(old, new, 1)


def test_preset_loads_with_paper_values(drive):
    import math

    assert "piippo2008" in preset_names()
    m = drive.motor
    assert (m.p, m.R_s, m.L_d, m.L_q, m.psi_pm) == (3, 3.59, 0.036, 0.051, 0.545)
    assert drive.base.w == pytest.approx(2 * math.pi * 75)
    assert drive.observer.alpha_fo == pytest.approx(2 * math.pi * 50)
    assert drive.gain("constant").lambda1 == pytest.approx(-0.5 * 3.59)
    assert drive.gain("speed").lambda_p == pytest.approx(2 * 3.59)
    assert drive.gain("speed").w_lambda == pytest.approx(drive.base.w)
    assert drive.injection.w_Delta == pytest.approx(0.13 * drive.base.w)
    assert drive.injection.w_c == pytest.approx(2 * math.pi * 833)
    assert drive.control.T_s == pytest.approx(200e-6)
    assert drive.estimate.vector() == drive.motor.vector()


def test_loading_twice_gives_equal_drives_and_an_edit_changes_the_digest():
    """The drive a file describes is a value: the same text gives an equal drive with the same digest
    (gain tables and reports record it); any edit, even a comment, gives another digest."""
    a, b = load_drive_text(PRESET, "a.toml"), load_drive_text(PRESET, "a.toml")
    assert a == b and a.digest == b.digest and len(a.digest) == 64
    c = load_drive_text(PRESET + "\n# a comment\n", "a.toml")
    assert c.digest != a.digest and c.motor == a.motor


@pytest.mark.parametrize(
    ("text", "key", "words"),
    [
        (edit('R_s = "3.59 ohm"\nL_d', 'R_s = "3.59 ohm"\nR_x = 1\nL_d'), "motor.R_x", "unknown key"),
        (edit('psi_pm = "0.545 Vs"\nJ', "J"), "motor.psi_pm", "missing key"),
        (edit('L_d = "0.036 H"', 'L_d = "0.036 ohm"'), "motor.L_d", "not an inductance unit"),
        (edit('L_d = "0.036 H"', "L_d = true"), "motor.L_d", "boolean"),
        (edit('L_d = "0.036 H"', "L_d = [1, 2]"), "motor.L_d", "expected a number"),
        (edit('R_s = "3.59 ohm"', 'R_s = "1e999 ohm"'), "motor.R_s", "not finite"),
        (edit('R_s = "3.59 ohm"', "R_s = inf"), "motor.R_s", "not finite"),
        (edit('J = "0.015 kgm2"', 'J = "1e-300 kgm2"'), "motor.J", "out of range"),
        (edit('u_dc = "540 V"', 'u_dc = "1e300 V"'), "control.u_dc", "out of range"),
        (edit('w_Delta = "0.13 pu"', 'w_Delta = "1e12 pu"'), "injection.w_Delta", "out of range"),
        (edit("p = 3", "p = 3.5"), "motor.p", "integer"),
        (edit('R_s = "3.59 ohm"', 'R_s = "-3.59 ohm"'), "motor.R_s", "non-physical"),
        (edit('R_s = "3.59 ohm"', "R_s = 0"), "motor.R_s", "non-physical"),
        (edit('L_q = "0.051 H"', 'L_q = "0 H"'), "motor.L_q", "non-physical"),
        (edit('psi_pm = "0.545 Vs"', 'psi_pm = "-0.5 Vs"'), "motor.psi_pm", "non-physical"),
        (
            PRESET.replace(
                'L_d = "0.036 H"\nL_q = "0.051 H"\npsi_pm = "0.545 Vs"\n\n[control]',
                'L_d = "0 H"\nL_q = "0.051 H"\npsi_pm = "0.545 Vs"\n\n[control]',
            ),
            "estimate.L_d",
            "non-physical",
        ),
        (edit('kind = "ipmsm-adaptive"', 'kind = "induction"'), "drive.kind", "unknown drive kind"),
        (
            edit('lambda1 = "-0.5 R_s_hat"', 'lambda1 = "-1.5 R_s_hat"'),
            "observer.gains.constant.lambda1",
            "> -R̂s",
        ),
        (edit("[observer.gains.zero]", "[observer.gains.sliding]"), "observer.gains.sliding", "unknown gain"),
        (edit('gain = "speed"', 'gain = "fast"'), "observer.gain", "fast"),
        (edit('w_Delta = "0.13 pu"', 'w_Delta = "0.13 parsec"'), "injection.w_Delta", "unit 'parsec'"),
        (edit("[injection]", "[injektion]"), "injektion", "unknown key"),
        (PRESET + "\n[extra]\nx = 1\n", "extra", "unknown key"),
        ("[drive\n", "(syntax)", "not valid TOML"),
    ],
    ids=lambda v: v if isinstance(v, str) and len(v) < 40 else "",
)
def test_bad_input_names_file_and_key(text, key, words):
    with pytest.raises(DriveFileError) as e:
        load_drive_text(text, "mydrive.toml")
    msg = str(e.value)
    assert msg.startswith("mydrive.toml: key '")
    assert f"'{key}'" in msg, msg
    assert words in msg, msg


def test_file_and_preset_lookup(tmp_path):
    p = tmp_path / "my.toml"
    p.write_text(PRESET)
    assert load_drive(p).motor.R_s == 3.59
    assert load_drive(str(p)).file == str(p)
    with pytest.raises(FileNotFoundError, match="not a preset"):
        load_drive("nosuchdrive")
    bad = tmp_path / "bad.toml"
    bad.write_text(edit('R_s = "3.59 ohm"', 'R_s = "3.59 H"'))
    with pytest.raises(DriveFileError, match=str(bad)):
        load_drive(bad)


def test_current_sensor_noise_is_optional_with_a_default():
    """[control] i_noise (A rms per axis and sample) is optional: 0.3 % of the base current by default
    (existing drive files load unchanged); given, it is read in A or mA; checked like every key."""
    d = load_drive_text(PRESET, "p.toml")
    assert d.control.i_noise == pytest.approx(0.003 * d.base.i)
    d = load_drive_text(edit('u_dc = "540 V"', 'u_dc = "540 V"\ni_noise = "20 mA"'), "p.toml")
    assert d.control.i_noise == pytest.approx(0.02)
    for bad, words in (('"-1 A"', "non-physical"), ('"1 V"', "not a current unit")):
        with pytest.raises(DriveFileError, match=rf"key 'control\.i_noise'.*{words}"):
            load_drive_text(edit('u_dc = "540 V"', f'u_dc = "540 V"\ni_noise = {bad}'), "p.toml")


def test_noise_limits_in_the_tuning_section():
    d = load_drive_text(
        edit("breakpoints = 11", 'breakpoints = 11\nmax_noise = { position = "0.05 deg" }'), "p.toml"
    )
    assert d.tuning.max_noise == (("position", pytest.approx(0.05 * 3.141592653589793 / 180)),)
    with pytest.raises(DriveFileError, match=r"tuning\.max_noise\.torque"):
        load_drive_text(
            edit("breakpoints = 11", 'breakpoints = 11\nmax_noise = { torque = "1 deg" }'), "p.toml"
        )
