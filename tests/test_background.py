"""The measured background (issue 28, first part): the record's figures, the background generators against
closed forms, the record couplings' modes, and "off" leaving a scene's system untouched."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import signal

from drivetrain.rig import background as bgm
from drivetrain.rig import record as rec
from drivetrain.run.assemble import assemble
from drivetrain.scene.load import load_scene


def test_record_figures_are_the_records_readme():
    """Independent oracle: the record's README (measured there after 0.2 s) gives the means and stds."""
    r = rec.load_record()
    assert r.fs == pytest.approx(3012.06, abs=0.5) and r.fs_motor == pytest.approx(1000.0, rel=1e-6)
    cut = int(0.2 * r.fs)
    assert np.mean(r.channels["drive_shaft_torque"][cut:]) == pytest.approx(2.51, abs=0.01)
    assert np.mean(r.channels["propeller_shaft_torque"][cut:]) == pytest.approx(12.15, abs=0.01)
    assert np.std(r.channels["drive_shaft_torque"][cut:]) == pytest.approx(0.043, abs=0.001)
    assert np.std(r.channels["propeller_shaft_torque"][cut:]) == pytest.approx(0.431, abs=0.002)
    assert np.mean(r.motor["load_motor_torque"][200:]) == pytest.approx(1.309, abs=0.002)


def test_amplitude_spectrum_reads_a_sine_amplitude():
    fs, n = 3012.0, 5542
    t = np.arange(n) / fs
    f0 = 100 * fs / n                      # on a bin
    f, a = rec.amplitude_spectrum(0.3 + 0.7 * np.sin(2 * np.pi * f0 * t), fs)
    assert a[np.argmin(abs(f - f0))] == pytest.approx(0.7, rel=1e-3)


def test_broadband_noise_has_its_density():
    """Welch PSD of the generated noise equals asd^2 in the pass band (10 % over 2^18 samples), and falls
    -12 dB an octave over the 4th-order band edge (at 2x the edge: < -20 dB)."""
    rng = np.random.default_rng(1)
    fs, asd = 12000.0, 0.05
    x = bgm.broadband_noise(2 ** 18, fs, asd, 300.0, rng)
    f, p = signal.welch(x, fs=fs, nperseg=4096)
    band = (f > 10) & (f < 150)
    assert np.mean(p[band]) == pytest.approx(asd ** 2, rel=0.1)
    assert np.mean(p[(f > 580) & (f < 620)]) < asd ** 2 * 10 ** (-20 / 10)


def test_order_ripple_is_its_orders():
    """Constant speed: the ripple's spectrum has exactly the four order lines with their amplitudes."""
    bg = bgm.Background(order_dsh_1x_Nm=0.2, order_dsh_2x_Nm=0.1, order_msh_1x_Nm=0.05, order_msh_2x_Nm=0.0)
    fs, T = 3000.0, 18.0                       # 18 s: whole periods of every order at 500 rpm
    t = np.arange(int(fs * T)) / fs
    x = bgm.order_ripple(t, 500.0, bg, "run", 3.0)
    f = np.fft.rfftfreq(len(t), 1 / fs)
    a = np.abs(np.fft.rfft(x)) * 2 / len(t)
    for fl, amp in ((500 / 60, 0.2), (1000 / 60, 0.1), (500 / 180, 0.05)):
        assert a[np.argmin(abs(f - fl))] == pytest.approx(amp, rel=1e-6)
    assert math.sqrt(np.sum(a ** 2) / 2) == pytest.approx(math.sqrt((0.2 ** 2 + 0.1 ** 2 + 0.05 ** 2) / 2), rel=1e-6)


def test_drive_angle_integrates_a_ramp():
    t = np.linspace(0, 2, 2001)
    th = bgm.drive_angle(t, [[0.0, 0.0], [1.0, 600.0]])
    # 0..1 s: ramp to 600 rpm = 20 pi rad/s -> 10 pi rad; then 1 s at 20 pi rad/s
    assert th[-1] == pytest.approx(30 * math.pi, rel=1e-5)


def _scene(*sets):
    return load_scene("scenarios/example.toml", overrides=["operating_point.drive_speed_rpm=500",
                                                           "time.duration_s=0.5", *sets])


def test_background_off_leaves_the_system_untouched():
    a = assemble(_scene(), check=False)
    assert "motor_torque_disturbance" not in a.components[0].inputs
    b = assemble(_scene("background.drive_noise_Nm_rtHz=0.5", "background.coupling_stiffness_scale=2.0"),
                 check=False)
    assert a.components[0].parameters == b.components[0].parameters
    assert [c.parameters for c in a.components] == [c.parameters for c in b.components]


def test_background_on_gives_one_profile_per_run_and_seed():
    sc = _scene("effects.drive_torque_noise=true", "effects.shaft_orders=true")
    p = assemble(sc, check=False).components[0].inputs["motor_torque_disturbance"]
    H = sc.numerics.comm_step_s
    assert p.shape[1] == 2 and p[-1, 0] >= sc.time.duration_s and np.allclose(np.diff(p[:, 0]), H)
    q = assemble(sc, check=False).components[0].inputs["motor_torque_disturbance"]
    assert np.array_equal(p, q)                                         # one scene, one record
    r = assemble(dataclasses.replace(sc, scenario=dataclasses.replace(sc.scenario, name="other")),
                 check=False).components[0].inputs["motor_torque_disturbance"]
    assert not np.array_equal(p[:, 1], r[:, 1])                         # another run, another record


def test_record_couplings_put_the_modes_on_the_records_humps():
    """The identified stiffness scales give the linearised drivetrain modes at the record's humps (27.8 and
    58.4 Hz: tests.test_background reads them from the record); "fitted" keeps the paper's 24 Hz."""
    from drivetrain.campaigns.record_fit import first_modes, hump_mode

    r = rec.load_record()
    x = r.channels["propeller_shaft_torque"][int(rec.SKIP_S * r.fs):]
    f, a = rec.amplitude_spectrum(x, r.fs)
    f27 = hump_mode(f, a, rec.HUMPS["hump_27"])["f_Hz"]
    f58 = hump_mode(f, a, rec.HUMPS["hump_58"])["f_Hz"]
    m = first_modes(bgm.Background(), 3)
    assert m[0]["f_Hz"] == pytest.approx(f27, abs=0.3)
    assert m[2]["f_Hz"] == pytest.approx(f58, abs=0.3)
    from drivetrain.models import eigen

    f_fitted = eigen.natural_frequencies(assemble(_scene(), check=False))
    assert f_fitted[0] == pytest.approx(24.0, rel=0.01)


def test_a_bad_background_value_is_named():
    from drivetrain.scene.load import ScenarioError

    with pytest.raises(ScenarioError, match="drive_noise_Nm_rtHz"):
        _scene("background.drive_noise_Nm_rtHz=-1")
