"""The multi-sine record's load log on the rig's clock (drivetrain.rig.clock, rig.record.load_setpoint).

Oracles: a logger built here that samples a generator on another, slower and jittering, clock (the true time of
every logged value is known by construction); and, on the record, the lines the retiming does not use (the
setpoint's 4 f and 8 f lines) against the rig's own propeller-torque response on the sensor clock."""
import math

import numpy as np
import pytest

from drivetrain.rig import clock
from drivetrain.rig import record as rec
from drivetrain.rig.signals import amplitude_spectrum

F_TRUE = 32.09


def _generator_and_logger(seed=3, n_log=9000):
    """A multi-sine table played by a generator at 962.5 Hz with 30 µs jitter, sampled (zero-order hold) by a
    logger whose rate wanders by a few per cent over fractions of a second about 1004 Hz (the record's
    log reads its 32.09 Hz line at 32.24 Hz on its index, with the phase wandering by turns within a second):
    it holds a value twice or skips one now and then, and its index is no clock. Returns the logged values and
    the true time at which each logged value started to apply."""
    from scipy.signal import butter, filtfilt

    rng = np.random.default_rng(seed)
    wander = filtfilt(*butter(2, 1.5 / 500.0), rng.normal(0.0, 1.0, n_log + 200))[100:-100]
    rate = 1004.0 * (1.0 + 0.03 * wander / np.std(wander))
    t_log = np.concatenate([[0.0], np.cumsum(1.0 / rate[:-1])]) + 0.5 / 962.5
    n_gen = int(t_log[-1] * 962.5) + 50
    t_gen = np.cumsum(np.full(n_gen, 1 / 962.5) + rng.normal(0.0, 30e-6, n_gen))
    t_gen -= t_gen[0]
    w = 2 * math.pi * F_TRUE
    values = 10 + 4 * np.sin(w * t_gen) + 3.5 * np.sin(4 * w * t_gen + 1.0) + 2 * np.sin(8 * w * t_gen + 2.0)
    k = np.searchsorted(t_gen, t_log, side="right") - 1
    return values[k], t_gen[k]


def _line(x, fs, f0):
    """Frequency, peak-bin amplitude and peak over band amplitude of the line near ``f0``."""
    f, a = amplitude_spectrum(np.asarray(x) - np.mean(x), fs)
    sel = np.abs(f - f0) <= 3.0
    i = int(np.flatnonzero(sel)[np.argmax(a[sel])])
    band = math.sqrt(np.sum(a[np.abs(f - f[i]) <= 1.25] ** 2) / 1.5)
    return f[i], a[i], a[i] / band


def _uniform(t, x, fs=1000.0):
    tu = np.arange(t[0], t[-1], 1 / fs)
    return np.interp(tu, t, x)


def test_a_line_frequency_is_read_far_finer_than_a_bin():
    fs = 1000.0
    t = np.arange(9000) / fs
    x = 3 * np.sin(2 * math.pi * 32.0937 * t + 0.4) + np.random.default_rng(0).normal(0, 0.5, t.size)
    assert clock.line_frequency(x, fs, 32.1) == pytest.approx(32.0937, abs=1e-3)     # a bin is 0.11 Hz


@pytest.mark.parametrize("seed", range(8))
def test_the_retimed_log_puts_each_value_where_the_generator_applied_it(seed):
    """The logger's index puts values 27-133 ms from their true time (8 seeds); retimed by the fundamental
    alone, every value away from the ends lands within 1.5 ms of it (measured 0.96-1.42 ms; a generator step is
    1.04 ms), and the 4 f line, not used, turns from a spread (peak over band 0.40-0.55) into a clean line
    (0.88-0.99)."""
    x, t_true = _generator_and_logger(seed)
    index_err = np.abs(np.arange(len(x)) / 1000.0 - (t_true - t_true[0]))
    tau = clock.retime_by_line(x, 1000.0, 32.1, F_TRUE)
    err = tau - (t_true - t_true[0])
    err -= np.median(err)                              # the retimed clock starts at the first sample's time
    core = slice(300, -300)                           # the phase filter's ends
    assert np.max(index_err) > 0.02                    # the index is no clock: twenty samples off and more
    assert np.max(np.abs(err[core])) < 1.5e-3
    f4, _, clean_index = _line(x, 1000.0, 4 * F_TRUE)
    f4r, _, clean_retimed = _line(_uniform(tau, x), 1000.0, 4 * F_TRUE)
    assert clean_retimed > 0.85 and abs(f4r - 4 * F_TRUE) < 0.06
    assert clean_index < 0.7                           # on the index it is spread


def test_the_records_setpoint_retimed_lines_up_with_the_rigs_response():
    """The multi-sine record: retimed by its 32 Hz line onto the propeller torque's response frequency (sensor
    clock), the setpoint's 4 f line (not used by the retiming) becomes a clean line at the frequency where the
    rig's propeller torque answers near 128.4 Hz; on the log's own index it is spread and a bin or more off."""
    r = rec.load_record(name="sine_2004rpm")
    psh = r.channels["propeller_shaft_torque"][int(0.2 * r.fs):]
    t, x = rec.load_setpoint(r)
    f1_rig = clock.line_frequency(psh, r.fs, 32.1)
    f4_rig = clock.line_frequency(psh, r.fs, 128.4)
    assert f4_rig == pytest.approx(4 * f1_rig, abs=0.02)          # the rig answers the load's 4th harmonic
    xu = _uniform(t, x)
    assert clock.line_frequency(xu, 1000.0, 32.1) == pytest.approx(f1_rig, abs=0.005)
    f4, _, clean = _line(xu, 1000.0, 128.4)
    assert clean > 0.85 and f4 == pytest.approx(f4_rig, abs=0.06)
    f4_index, _, clean_index = _line(x, r.fs_motor, 128.4)
    assert clean_index < 0.7 and abs(f4_index - f4_rig) > 0.3
    assert np.all(np.diff(t) > 0) and t[-1] == pytest.approx(len(x) / 1000.0, rel=0.01)


def test_only_the_multisine_log_is_retimed():
    r = rec.load_record(name="impulse_2004rpm")
    t, x = rec.load_setpoint(r)
    assert t is r.t_motor and np.array_equal(x, r.motor["load_motor_torque_set"])
    with pytest.raises(rec.RecordError, match="no load-torque setpoint"):
        rec.load_setpoint(rec.load_record(name="baseline_500rpm"))


@pytest.mark.parametrize("x, match", [(np.array([1.0, np.nan, 2.0, 3.0, 4.0]), "finite"),
                                      (np.ones(3), "at least 4")])
def test_a_log_that_cannot_be_retimed_is_refused(x, match):
    with pytest.raises(clock.ClockError, match=match):
        clock.retime_by_line(x, 1000.0, 32.1, 32.09)


def test_bad_clock_figures_are_refused():
    with pytest.raises(clock.ClockError, match="bad clock figures"):
        clock.retime_by_line(np.sin(np.arange(100.0)), 1000.0, 32.1, -1.0)
