"""A motor drive's log on the rig's clock: the multi-sine record's load setpoint, retimed by its own line.

**What.** The 2004 rpm multi-sine record (drivetrain/data/rig_records, ``excitation_2004rpm_sin_motor.csv``) logs
the load motor's torque setpoint at a nominal 1 kHz. Read on the log's sample index, its 32 Hz line is no line:
its phase wanders by whole turns within a second (demodulated over 0.4 s windows its amplitude holds at 3.8,
file units, while its phase jumps by up to π), so its spectrum spreads the line over 31.8-32.5 Hz (peak bin
3.0 of a band amplitude 3.75). The rig's propeller torque, on the sensor clock, answers with one clean line at
32.1 Hz whose phase drifts by 1.2 rad in 9 s. A linear rig cannot narrow a line: the log's time base is not
the time the load was applied in. Its values say why: the setpoint repeats a table of 27 values every 30
samples, with a value held twice or skipped now and then, which is what a logger sampling a generator that
runs on another, slightly slower and jittering, clock records. The time column does not help: it is the
index times 1 ms with 59 gaps of 2-7 ms.

**How** (:func:`retime_by_line`). The log's fundamental is demodulated on its sample index and its phase
smoothed (a 2nd-order Butterworth, :data:`PHASE_CUTOFF_HZ`, forward and backward); each sample is placed at the
time its smoothed phase is reached by a line at the rig's frequency, measured on the propeller torque on the
sensor clock (:func:`line_frequency`). Only the fundamental is used; the evidence that the retimed clock is
the applied one is what it does to the lines it did not use (``tests/rig/test_clock.py``): the setpoint's
4 f line goes from a spread peak (peak bin over band amplitude 0.56, at 128.96 Hz on the index) to a clean line
(0.91) at 128.40 Hz, where the rig's propeller torque has its 129 Hz response (128.36 Hz); the 8 f line likewise
(0.63 to 0.95). The cutoff trades the slips' residual jitter (too low) against the retiming following the 4 f
and 8 f lines' own beat (too high). On the record 2, 3 and 4 Hz read alike (4 f 0.90-0.91, 8 f 0.94-0.95); on
the test's generator-and-logger (its logger's rate wandering by 3 %, 8 seeds) the retimed values land within
1.6-2.5 ms of their true times at 2 Hz, 0.96-1.42 ms at 3 Hz and 0.91-1.08 ms at 4 Hz. 3 Hz is kept. The
filter starts from Gustafsson's initial conditions: with the default padding the clock ran backwards near the
start for one seed.

**The trade-off.** The retimed series is the record's own values, in their own order, at other times: nothing
is added or smoothed. What the retiming cannot give back is which of two equal neighbouring values was a hold
of the logger and which the generator's, about one sample in 26: linear interpolation between them is a hold.

Pure: arrays in, arrays out.
"""
from __future__ import annotations

import math

import numpy as np

#: the smoothing of the log's line phase [Hz] (module docstring)
PHASE_CUTOFF_HZ = 3.0


class ClockError(ValueError):
    """A log cannot be retimed: the message says why."""


def _samples(x, what: str) -> np.ndarray:
    """``x`` as floats; ClockError unless it has at least 4 samples, all finite."""
    x = np.asarray(x, dtype=float)
    if len(x) < 4 or not np.all(np.isfinite(x)):
        raise ClockError(f"{what} needs at least 4 finite samples")
    return x


def _demodulated_phase(x: np.ndarray, fs: float, f_Hz: float, cutoff_Hz: float) -> np.ndarray:
    """The unwrapped phase [rad] of ``x``'s content near ``f_Hz`` against a carrier at ``f_Hz`` on ``x``'s
    sample times, low-passed at ``cutoff_Hz`` (forward and backward, no lag)."""
    from scipy.signal import butter, filtfilt

    x = np.asarray(x, dtype=float)
    tt = np.arange(len(x)) / fs
    z = (x - x.mean()) * np.exp(-2j * math.pi * f_Hz * tt)
    b, a = butter(2, cutoff_Hz / (fs / 2.0))
    zf = filtfilt(b, a, z.real, method="gust") + 1j * filtfilt(b, a, z.imag, method="gust")
    return np.unwrap(np.angle(zf))


def line_frequency(x: np.ndarray, fs: float, near_Hz: float, cutoff_Hz: float = PHASE_CUTOFF_HZ) -> float:
    """The frequency [Hz] of ``x``'s line near ``near_Hz``: the carrier plus the slope of its demodulated phase
    (least squares over the whole signal; far finer than a bin of the spectrum)."""
    x = _samples(x, "a line's frequency")
    ph = _demodulated_phase(x, fs, near_Hz, cutoff_Hz)
    tt = np.arange(len(x)) / fs
    slope = float(np.polyfit(tt, ph, 1)[0])
    return near_Hz + slope / (2.0 * math.pi)


def retime_by_line(x: np.ndarray, fs_log: float, near_Hz: float, true_Hz: float,
                   cutoff_Hz: float = PHASE_CUTOFF_HZ) -> np.ndarray:
    """The times [s, from 0] at which the samples of the log ``x`` (taken at ``fs_log`` by its own index) were
    applied, such that its line near ``near_Hz`` runs at ``true_Hz`` (module docstring). ClockError when the
    retimed clock would not run forward (the line is not there to follow)."""
    x = _samples(x, "retiming")
    if not (fs_log > 0 and true_Hz > 0 and 0 < cutoff_Hz < fs_log / 2):
        raise ClockError(f"bad clock figures: log rate {fs_log} Hz, line {true_Hz} Hz, cutoff {cutoff_Hz} Hz")
    ph = _demodulated_phase(x, fs_log, near_Hz, cutoff_Hz)
    phase = 2.0 * math.pi * near_Hz * np.arange(len(x)) / fs_log + ph
    tau = (phase - phase[0]) / (2.0 * math.pi * true_Hz)
    if np.any(np.diff(tau) <= 0):
        raise ClockError(f"the retimed clock runs backwards: the log has no steady line near {near_Hz} Hz to follow")
    return tau


__all__ = ["ClockError", "PHASE_CUTOFF_HZ", "line_frequency", "retime_by_line"]
