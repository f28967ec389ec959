"""Identification from the 2004 rpm excitation records (rig.excitation, campaigns.excitation_fit), checked against
synthetic records whose mode, damping and controller are known (independent oracles: closed-form responses)."""
import math
import shutil

import numpy as np
import pytest
from scipy import signal

from drivetrain.rig import excitation as ex
from drivetrain.rig import record as rec

FS = 1004.0
F_MSH = 2004.0 / 60.0 / 3.0


def _oscillator_noise(fn, zeta, seconds, seed):
    """A one-mode torque driven by white noise: x'' + 2 zeta wn x' + wn^2 x = wn^2 u (exact discretisation)."""
    wn = 2 * math.pi * fn
    sys = signal.cont2discrete(([wn * wn], [1.0, 2 * zeta * wn, wn * wn]), 1.0 / FS, method="zoh")
    u = np.random.default_rng(seed).normal(0.0, 1.0, int(seconds * FS))
    return signal.lfilter(sys[0].ravel(), sys[1], u)


def _lines(t, amps=(0.15, 0.7, 0.5, 0.15)):
    return sum(a * np.sin(2 * math.pi * k * F_MSH * t + k) for a, k in zip(amps, ex.ORDER_LINES.values()))


@pytest.mark.parametrize("fn, zeta", [(27.0, 0.12), (30.0, 0.05)])
def test_the_noise_driven_ring_gives_the_mode_beside_strong_lines(fn, zeta):
    x = _oscillator_noise(fn, zeta, 8.0, seed=1)
    t = np.arange(len(x)) / FS
    x = x / np.std(x) * 0.3 + _lines(t) + np.random.default_rng(2).normal(0, 0.01, len(x))
    m = ex.noise_mode(x, FS, F_MSH)
    assert m["f_Hz"] == pytest.approx(fn, rel=0.04)
    assert 1 / 1.35 < m["zeta"] / zeta < 1.35


def test_the_damped_sine_fit_reads_a_clean_ring_down_beside_lines():
    t = np.arange(0, 1.0, 1 / FS)
    f, z = 28.0, 0.06
    wd = 2 * math.pi * f
    wn = wd / math.sqrt(1 - z * z)
    x = 5.0 + 2.0 * np.exp(-z * wn * t) * np.sin(wd * t + 0.3) + _lines(t)
    r = ex.ring_down(t, x, 0.0, [k * F_MSH for k in ex.ORDER_LINES.values()])
    assert r["f_Hz"] == pytest.approx(f, rel=1e-3)
    assert r["zeta"] == pytest.approx(z, rel=1e-2)
    assert r["overshoot_Nm"] == pytest.approx(2.0, rel=1e-2)


def _synthetic_impulse(kp, ti, offset_s=0.18):
    """A record of a triangular load pulse on a drive held by a PI (Kp, Ti) on an inertia J: the speed and the
    drive torque from the closed loop, integrated exactly here (not by the code under test)."""
    J = 0.0085                                              # drive-side inertia [kg m^2]
    tm = np.arange(0, 4.0, 1e-3)
    setp = np.interp(tm, [0, 1.0, 1.1, 1.2, 4.0], [0.119, 0.119, 1.309, 0.119, 0.119])
    load = 8 * (setp - 0.119) / 12.0                        # the pulse at the drive side (x8 / 12)
    # J dw/dt = T - load; T = -Kp (w + I / Ti); dI/dt = w: a linear system, stepped by its exact propagator
    A = np.array([[-kp / J, -kp / (J * ti)], [1.0, 0.0]])
    B = np.array([-1.0 / J, 0.0])
    dt = 1e-3
    Ad = signal.cont2discrete((A, B[:, None], np.eye(2), np.zeros((2, 1))), dt)
    s = np.zeros(2)
    w, T = [], []
    for u in load:
        w.append(s[0])
        T.append(-kp * (s[0] + s[1] / ti))
        s = Ad[0] @ s + Ad[1].ravel() * u
    w, T = np.array(w), np.array(T)
    ts = np.arange(0, 4.0 - offset_s, 1 / FS)
    psh = 6.0 + 8 * np.interp(ts + offset_s, tm, setp - 0.119) + _lines(ts)
    enc = 209.86 + np.interp(ts + offset_s, tm, w)
    ch = {"enc1_w": enc, "enc2_w": enc, "drive_shaft_torque": np.full_like(ts, 1.5), "propeller_shaft_torque": psh}
    mo = {"drive_motor_torque_set": 0 * tm, "drive_motor_torque": 2.3 + T, "load_motor_torque_set": setp,
          "load_motor_torque": setp}
    return rec.Record(FS, ts, ch, 1000.0, mo, "impulse_2004rpm", tm)


def test_the_speed_controller_is_identified_from_a_synthetic_pulse():
    from drivetrain.campaigns import excitation_fit as xf

    r = _synthetic_impulse(kp=0.8, ti=0.03)
    figs = ex.impulse_figures(r.t, r.channels["propeller_shaft_torque"], r.channels["drive_shaft_torque"],
                              r.channels["enc1_w"], r.fs, r.t_motor, r.motor["load_motor_torque_set"])
    assert figs["times"]["peak_s"] == pytest.approx(1.1 - 0.18, abs=0.01)
    assert figs["overshoot"] == pytest.approx(1.0, rel=0.05)     # a static load: no overshoot
    c = xf.controller(r, figs)
    assert c["drive_Kp"] / c["drive_Ti_s"] == pytest.approx(0.8 / 0.03, rel=0.1)   # the integral gain
    assert c["drive_Kp"] == pytest.approx(0.8, rel=0.25)
    assert c["clock_offset_s"] == pytest.approx(-0.18, abs=0.01)     # sensor time = motor time - 0.18 s here


def test_the_identification_refuses_a_bad_record_naming_it(tmp_path):
    from drivetrain.campaigns import excitation_fit as xf

    for n in xf.RECORD_NAMES:
        for f in (rec.RECORDS[n].sensor_csv, rec.RECORDS[n].motor_csv):
            shutil.copy(rec.RECORD_DIR / f, tmp_path / f)
    bad = tmp_path / rec.RECORDS["sine_2004rpm"].motor_csv
    lines = bad.read_text().splitlines()
    lines[9] = lines[9].rsplit(",", 1)[0] + ",nan"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(rec.RecordError, match="non-finite"):
        xf.identify(tmp_path)


def test_a_non_finite_value_is_refused_not_written():
    from drivetrain.campaigns import excitation_fit as xf

    with pytest.raises(xf.ExcitationFitError, match="non-finite"):
        xf._finite("the ring frequency", float("nan"), "impulse_2004rpm")


def test_calibrate_record_writes_nothing_from_a_bad_record(tmp_path, capsys):
    from drivetrain.cli import main

    for f in (rec.RECORDS["baseline_500rpm"].sensor_csv, rec.RECORDS["baseline_500rpm"].motor_csv):
        shutil.copy(rec.RECORD_DIR / f, tmp_path / f)
    (tmp_path / rec.SENSOR_CSV).write_text("")
    out = tmp_path / "bg.toml"
    assert main(["calibrate", "--record", str(tmp_path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "empty record" in err and rec.SENSOR_CSV in err
    assert not out.exists()


def test_the_lines_speed_law_leaves_the_500rpm_record_scene_unchanged():
    """Every exponent scales (speed / 500 rpm): at the 500 rpm record's speed any exponents give the same ripple, so
    check 11 is untouched by the laws calibrated at 2004 rpm; at 2004 rpm each line alone is its 500 rpm amplitude
    times 4.008^(its own exponent) (closed form), the planetary's mesh times 4.008^orders_speed_exponent."""
    import dataclasses

    from drivetrain.rig import background as bgm

    bg = bgm.Background()
    t = np.arange(0, 1.0, 1 / 3012.0)
    a = bgm.order_ripple(t, 500.0, bg, 3.0, 4.0)
    other = dataclasses.replace(bg, orders_speed_exponent=2.0, **{k: 2.0 for k in bgm.EXPONENT_KEYS.values()})
    assert np.array_equal(a, bgm.order_ripple(t, 500.0, other, 3.0, 4.0))
    zero = {k: 0.0 for k in bgm.ORDERS}
    assert len(set(getattr(bg, k) for k in bgm.EXPONENT_KEYS.values()) | {bg.orders_speed_exponent}) == 5
    for key in bgm.ORDERS:
        one = dataclasses.replace(bg, **{**zero, key: 0.1})
        x = bgm.order_ripple(t, 2004.0, one, 3.0, 4.0)
        p = getattr(bg, bgm.EXPONENT_KEYS[key]) if key in bgm.EXPONENT_KEYS else bg.orders_speed_exponent
        assert np.max(np.abs(x)) == pytest.approx(0.1 * (2004 / 500) ** p, rel=1e-3), key


def test_each_lines_law_is_recovered_from_its_calibration_levels_and_judged_on_the_other():
    """order_law on synthetic levels made with known exponents (level = A_500 4.008^p |H|, |H| the model's own)
    returns those exponents (exactly determined from two speeds); a judging record with the same levels reads
    0 dB, one 6 dB lower +6 dB."""
    from drivetrain.campaigns import excitation_fit as ef, record_fit
    from drivetrain.rig import background as bgm
    from drivetrain.rig.data import LOWER_RATIO, UPPER_RATIO

    bg = bgm.Background()
    truth = {"f_MSH": 0.3, "2f_MSH": 1.1, "f_DSH": 1.9, "2f_DSH": 1.5}
    f_psh = 2004.0 / 60.0 / (UPPER_RATIO * LOWER_RATIO)
    keys = list(ef.LINE_KEYS.values())
    freqs = np.array([bgm.propeller_order(k, bg, UPPER_RATIO, LOWER_RATIO) * f_psh for k in keys])
    h = record_fit.response(bg, freqs, "load", 2004.0, 1.309)["propeller_shaft_torque"]
    levels = {line: getattr(bg, key) * (2004 / 500) ** truth[line] * hk
              for (line, key), hk in zip(ef.LINE_KEYS.items(), h)}
    law = ef.order_law(levels, bg, judge={k: v / 10 ** (6 / 20) for k, v in levels.items()})
    for key, row in law["lines"].items():
        assert row["own_exponent"] == pytest.approx(truth[row["line"]], abs=1e-9)
        assert row["judge_dB"] == pytest.approx(6.0, abs=1e-9)
    assert law["exponent"] == pytest.approx(np.mean(list(truth.values())), abs=1e-9)


def test_the_shipped_line_laws_are_the_impulse_records_calibration():
    """The shipped per-line exponents are what `calibrate --record` identifies from the impulse record (and only
    it: the multi-sine judges them), each within its physical range."""
    from drivetrain.campaigns import excitation_fit as ef
    from drivetrain.rig import background as bgm

    out = ef.identify()
    bg = bgm.Background()
    for key, ek in bgm.EXPONENT_KEYS.items():
        v = out["values"][ek]
        assert v["value"] == pytest.approx(getattr(bg, ek), abs=2e-3) and v["within"], ek
        assert "impulse record" in v["source"] and v["source"].startswith("calibration")
        row = out["order_law"]["lines"][key]
        assert row["measured_Nm"] == out["figures"]["impulse_2004rpm"][row["line"]]
    assert out["values"]["orders_speed_exponent"]["value"] == pytest.approx(bg.orders_speed_exponent, abs=2e-3)
    # the other way round: calibrated on the multi-sine, judged on the impulse record; the judgements mirror
    for key, row in out["order_law_reverse"]["lines"].items():
        assert row["judge_dB"] == pytest.approx(-out["order_law"]["lines"][key]["judge_dB"], abs=1e-9)
        assert row["measured_Nm"] == out["figures"]["sine_2004rpm"][row["line"]]
