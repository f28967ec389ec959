"""The measured background: the record's figures, the background generators against
closed forms, the record couplings' modes, and "off" leaving a scene's system untouched."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import signal

from drivetrain.rig import background as bgm
from drivetrain.rig import record as rec
from drivetrain.rig.signals import amplitude_spectrum
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
    f, a = amplitude_spectrum(0.3 + 0.7 * np.sin(2 * np.pi * f0 * t), fs)
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
    """Constant speed: the ripple's spectrum has exactly its order lines with their amplitudes (propeller-shaft
    orders 4, 8, 12 and the planetary's ring teeth), nothing else."""
    bg = bgm.Background(order_msh_1x_Nm=0.2, order_msh_2x_Nm=0.1, order_dsh_1x_Nm=0.05, order_dsh_2x_Nm=0.0,
                        planetary_mesh_Nm=0.3, planetary_ring_teeth=84)
    fs, T = 3000.0, 18.0                       # 18 s: whole periods of every order at 500 rpm
    t = np.arange(int(fs * T)) / fs
    x = bgm.order_ripple(t, 500.0, bg, 3.0, 4.0)
    f = np.fft.rfftfreq(len(t), 1 / fs)
    a = np.abs(np.fft.rfft(x)) * 2 / len(t)
    f_psh = 500 / 60 / 12
    for k, amp in ((4, 0.2), (8, 0.1), (12, 0.05), (84, 0.3)):
        assert a[np.argmin(abs(f - k * f_psh))] == pytest.approx(amp, rel=1e-6)
    assert math.sqrt(np.sum(a ** 2) / 2) == pytest.approx(math.sqrt((0.2 ** 2 + 0.1 ** 2 + 0.05 ** 2 + 0.3 ** 2) / 2),
                                                          rel=1e-6)


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
    sc = _scene("effects.drive_torque_noise=true", "effects.load_torque_noise=true", "effects.shaft_orders=true")
    inputs = assemble(sc, check=False).components[0].inputs
    p, load = inputs["motor_torque_disturbance"], inputs["load_torque"]
    H = sc.numerics.comm_step_s
    for prof in (p, load):
        assert prof.shape[1] == 2 and prof[-1, 0] >= sc.time.duration_s and np.allclose(np.diff(prof[:, 0]), H)
    # the load motor's setting carries 1/8 of the torque on the propeller mass, about its setting
    assert np.mean(load[:, 1]) == pytest.approx(sc.operating_point.load_torque_Nm, abs=0.01)
    q = assemble(sc, check=False).components[0].inputs["motor_torque_disturbance"]
    assert np.array_equal(p, q)                                         # one scene, one record
    r = assemble(dataclasses.replace(sc, scenario=dataclasses.replace(sc.scenario, name="other")),
                 check=False).components[0].inputs["motor_torque_disturbance"]
    assert not np.array_equal(p[:, 1], r[:, 1])                         # another run, another record


def test_a_load_step_stays_under_the_background():
    sc = _scene("effects.shaft_orders=true", "operating_point.load_profile_Nm=[[0.0, 1.31], [0.2, 1.31], [0.21, 0.12]]")
    load = assemble(sc, check=False).components[0].inputs["load_torque"]
    early, late = load[load[:, 0] < 0.2, 1], load[load[:, 0] > 0.25, 1]
    assert abs(np.mean(early) - 1.31) < 0.02 and abs(np.mean(late) - 0.12) < 0.02


def test_record_couplings_put_the_modes_on_the_records_humps():
    """The shipped stiffness scales give the linearised drivetrain (record controller) modes at the record's
    humps (27.8 and 58.4 Hz, read from the record here); "fitted" keeps the paper's 24 Hz."""
    from drivetrain.campaigns.record_fit import MODE_PLACEMENT, hump_mode, mode_in

    r = rec.load_record()
    x = r.channels["propeller_shaft_torque"][int(rec.SKIP_S * r.fs):]
    f, a = amplitude_spectrum(x, r.fs)
    f27 = hump_mode(f, a, rec.HUMPS["hump_27"])["f_Hz"]
    f58 = hump_mode(f, a, rec.HUMPS["hump_58"])["f_Hz"]
    bg = bgm.Background()
    assert mode_in(bg, MODE_PLACEMENT[0][1])["f_Hz"] == pytest.approx(f27, abs=0.3)
    assert mode_in(bg, MODE_PLACEMENT[1][1])["f_Hz"] == pytest.approx(f58, abs=0.3)
    from drivetrain.models import eigen

    f_fitted = eigen.natural_frequencies(assemble(_scene(), check=False))
    assert f_fitted[0] == pytest.approx(24.0, rel=0.01)


def test_a_bad_background_value_is_named():
    from drivetrain.scene.load import ScenarioError

    with pytest.raises(ScenarioError, match="drive_noise_Nm_rtHz"):
        _scene("background.drive_noise_Nm_rtHz=-1")


def _grid(tmp_path, draw_text):
    from drivetrain.scene.load import load_scenes

    p = tmp_path / "grid.toml"
    p.write_text(f"""
[scenario]
name = "bg"
[operating_point]
drive_speed_rpm = 500.0
load_torque_Nm = 1.31
[effects]
load_torque_noise = true
[sweep.draw]
n = 4
seed = 3
{draw_text}
""")
    return load_scenes(p)


def test_sweep_draws_the_background(tmp_path):
    """[sweep.draw.background]: each case gets its own drawn values within the rules; the same file draws the
    same; with faults too, the faults' draws are those of the file without the background table."""
    scenes = _grid(tmp_path, """[sweep.draw.background]
seed = "any"
load_noise_Nm_rtHz = { uniform = [0.01, 0.04] }
coupling_damping_scale = [0.5, 1.0, 2.0]""")
    vals = [s.background.load_noise_Nm_rtHz for s in scenes]
    assert len(scenes) == 4 and all(0.01 <= v <= 0.04 for v in vals) and len(set(vals)) == 4
    assert all(s.background.coupling_damping_scale in (0.5, 1.0, 2.0) for s in scenes)
    assert len({s.background.seed for s in scenes}) == 4 and all(s.gear.health == "healthy" for s in scenes)
    assert [s.background for s in _grid(tmp_path, """[sweep.draw.background]
seed = "any"
load_noise_Nm_rtHz = { uniform = [0.01, 0.04] }
coupling_damping_scale = [0.5, 1.0, 2.0]""")] == [s.background for s in scenes]
    faults = """[[sweep.draw.faults]]
kind = ["pit", "void"]
tooth = "any"
"""
    plain = _grid(tmp_path, faults)
    both = _grid(tmp_path, faults + """[sweep.draw.background]
load_noise_Nm_rtHz = { uniform = [0.01, 0.04] }""")
    assert [s.gear.faults for s in plain] == [s.gear.faults for s in both]


def test_sweep_background_rules_are_checked(tmp_path):
    from drivetrain.scene.load import ScenarioError

    with pytest.raises(ScenarioError) as e:
        _grid(tmp_path, """[sweep.draw.background]
load_noise = { uniform = [0.01, 0.04] }
drive_Kp = { uniform = [2.0, 1.0] }
coupling_damping_scale = "any"
load_noise_Nm_rtHz = { uniform = [-1.0, -0.5] }""")
    text = str(e.value)
    for k in ("background.load_noise", "drive_Kp", "coupling_damping_scale", "load_noise_Nm_rtHz"):
        assert k in text, text


@pytest.fixture(scope="module")
def identified():
    """The identification run once on the shipped record (campaigns.record_fit.identify), for the tests that
    compare what it gives with what is shipped (they read it, never change it); the rig pair's contact map read
    once for its ~300 assemblies (_shared.contact_map_read_once)."""
    from _shared import contact_map_read_once
    from drivetrain.campaigns.record_fit import identify

    with contact_map_read_once():
        return identify()


def test_the_shipped_background_is_what_the_record_gives(identified):
    """A calibration, not a validation: rerunning the identification on the shipped record gives the shipped
    [background] defaults (to their 4 significant digits), so they were not edited by hand."""
    import dataclasses as dc

    out = identified
    for k, v in dc.asdict(bgm.Background()).items():
        assert out["background"][k] == pytest.approx(v, rel=6e-4), k
    assert out["controller"]["drive_Kp"] > 10 * 0.1          # the rig's drive is far stiffer than the assumed PI


def test_record_controller_fit_recovers_a_known_pi():
    """Oracle: a synthetic record whose drive torque is -PI(speed) (Kp 1.2, Ti 0.08 s) with the speed logged
    20 ms late: the controller fit returns those three numbers."""
    import dataclasses as dc

    from scipy import signal as sg

    from drivetrain.campaigns.record_fit import controller

    r = rec.load_record()
    fs = r.fs_motor
    rng = np.random.default_rng(0)
    n = len(r.motor["drive_motor_w"])
    w = sg.lfilter(*sg.butter(2, 12.0, fs=fs), rng.normal(0, 0.01, n))
    kp, ti, lag = 1.2, 0.08, 20
    integ = np.cumsum(w) / fs
    torque = -kp * (w + integ / ti)
    logged = np.concatenate([np.zeros(lag), w[:-lag]])
    motor = dict(r.motor, drive_motor_w=logged, drive_motor_torque=torque)
    c = controller(dc.replace(r, motor=motor))
    assert c["drive_Kp"] == pytest.approx(kp, rel=0.05)
    assert c["drive_Ti_s"] == pytest.approx(ti, rel=0.15)
    assert c["logged_speed_delay_s"] == pytest.approx(lag / fs, rel=0.1)


def test_load_noise_gives_the_linearised_spectrum(tmp_path, fmu_dir):
    """Oracle: the co-simulated propeller- and drive-shaft torque PSDs of the record scene with only the load
    noise on (no errors, ideal sensors) equal S0 |H_load|^2 of the linearised drivetrain (models.eigen, an
    independent assembly of the same parameters) within a factor 2 (3 dB in amplitude) between 8 and 80 Hz
    (Welch over 8 s: +-25 % scatter per bin); measured 0.79-1.34 (propeller shaft) and 0.98-1.88 (drive
    shaft, whose torque above the first mode is the small difference of two motions). It also shows the
    torques on the propeller mass reach it as the load motor's setting."""
    import shutil

    from drivetrain.campaigns.record_fit import response
    from drivetrain.run.runner import run_scene

    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed")
    over = ["time.duration_s=10", "effects.shaft_orders=false", "effects.drive_torque_noise=false",
            'effects.sensors="ideal"', "effects.manufacturing_errors=false", "outputs.plots=false"]
    sc = load_scene(rec_scene(), overrides=over)
    res = run_scene(sc, None, backend="native", progress=False, plots=False, fmu_dir=fmu_dir)
    t = np.asarray(res.time)
    fs = 1.0 / float(np.median(np.diff(t)))
    keep = t >= sc.time.settle_s
    freqs = np.array([8.0, 15.0, 22.0, 27.8, 35.0, 50.0, 65.0, 80.0])
    for name in rec.TORQUES:
        x = np.asarray(res.signals[name])[keep]
        f, p = signal.welch(x - x.mean(), fs=fs, nperseg=2048)
        h = response(sc.background, freqs, "load")[name]
        want = sc.background.load_noise_Nm_rtHz ** 2 * h ** 2
        got = np.array([np.mean(p[np.abs(f - fr) <= 1.5]) for fr in freqs])
        ratio = got / want
        assert np.all((ratio > 0.5) & (ratio < 2.0)), (name, dict(zip(freqs, np.round(ratio, 2))))


def rec_scene():
    from drivetrain.campaigns.record_check import RECORD_SCENE

    return RECORD_SCENE


def test_the_measured_transducer_noise_is_the_records(identified):
    """The transducer noise the record scene and the validation use is what the identification measures."""
    from drivetrain.campaigns.record_check import RECORD_SCENE

    out = identified["instruments"]
    sc = load_scene(RECORD_SCENE)
    for k, v in rec.MEASURED_TRANSDUCER_NOISE_NM.items():
        assert out[k] == pytest.approx(v, rel=0.01), k
        assert getattr(sc.instruments, k) == v


def test_order_ripple_grows_as_the_speed_squared():
    """A kinematic error's torque: the same gearbox at 1000 rpm has 4x the record's line amplitudes (exponent 2),
    at 250 rpm a quarter; exponent 0 keeps them; along a speed ramp the amplitude follows the reference."""
    bg = bgm.Background(order_msh_1x_Nm=0.2, order_msh_2x_Nm=0.0, order_dsh_1x_Nm=0.0, order_dsh_2x_Nm=0.0,
                        planetary_mesh_Nm=0.0, order_msh_1x_exponent=2.0)
    fs = 3000.0
    for rpm, factor in ((1000.0, 4.0), (250.0, 0.25)):
        t = np.arange(int(fs * 3 * 60 / rpm * 3)) / fs          # whole middle-shaft revolutions
        x = bgm.order_ripple(t, rpm, bg, 3.0, 4.0)
        assert np.max(np.abs(x)) == pytest.approx(0.2 * factor, rel=1e-3)
        flat = bgm.order_ripple(t, rpm, dataclasses.replace(bg, order_msh_1x_exponent=0.0), 3.0, 4.0)
        assert np.max(np.abs(flat)) == pytest.approx(0.2, rel=1e-3)
    t = np.linspace(0.0, 2.0, 20001)
    ramp = bgm.order_ripple(t, [[0.0, 0.0], [2.0, 1000.0]], bg, 3.0, 4.0)
    late = np.abs(ramp[t > 1.9]).max()
    assert late == pytest.approx(0.2 * (1000 / 500) ** 2 * 0.975 ** 2, rel=0.06)


def test_paired_healthy_runs_share_gearbox_background_and_noise(tmp_path):
    """[sweep.draw] paired_healthy: each drawn fault gets a healthy twin right after it (name + "_healthy"), with
    the same operating point, background draws and seeds, and one noise_name (the pair id), so both are
    measured with one noise record; the faults are those of the same file without pairing."""
    faults = """paired_healthy = true
[[sweep.draw.faults]]
kind = ["pit", "void"]
tooth = "any"
[sweep.draw.background]
load_noise_Nm_rtHz = { uniform = [0.01, 0.04] }
"""
    scenes = _grid(tmp_path, faults)
    assert len(scenes) == 8
    plain = _grid(tmp_path, faults.replace("paired_healthy = true\n", ""))
    assert [s.gear.faults for s in scenes[0::2]] == [s.gear.faults for s in plain]
    for f, h in zip(scenes[0::2], scenes[1::2]):
        assert h.name == f.name + "_healthy" and h.gear.health == "healthy" and not h.gear.faults
        assert f.noise_name == h.noise_name == f.name
        assert f.background == h.background and f.operating_point == h.operating_point
        pf = assemble(dataclasses.replace(f, time=dataclasses.replace(f.time, duration_s=0.2, settle_s=0.0)),
                      check=False).components[0].inputs["load_torque"]
        ph = assemble(dataclasses.replace(h, time=dataclasses.replace(h.time, duration_s=0.2, settle_s=0.0)),
                      check=False).components[0].inputs["load_torque"]
        assert np.array_equal(pf, ph)
    assert len({s.noise_name for s in scenes}) == 4
