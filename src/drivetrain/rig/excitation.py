"""The figures of the rig's 2004 rpm excitation records (drivetrain/data/rig_records: an impulse and a multi-sine
on the load motor), computed alike for a record and for a run of its scene (scenarios/validation/rig_*_2004rpm).

Nothing here needs the two clocks (sensors, motor drives) to agree: every time is read off the torque itself.

* **Pulse and ring-down** (:func:`pulse_times`, :func:`ring_down`). The propeller-shaft torque averaged over one
  middle-shaft revolution (which removes every line at a multiple of f_MSH: 2 f_MSH, f_DSH = 3 f_MSH, ...)
  peaks with the pulse; the pulse ends the setpoint's own fall time after the peak. From the end, over
  :data:`RING_WINDOW_S`, the torque is fitted as a damped sine + the shaft-order lines (f_MSH, 2 f_MSH, f_DSH,
  2 f_DSH at the measured speed, free amplitude and phase) + a straight line: the damped sine's frequency and
  damping ratio by least squares over (f, zeta) (variable projection: the rest is linear), started from a
  grid. ``overshoot_Nm`` is the damped sine's amplitude at the pulse's end: the first overshoot of the ring.
* **Ring frequency and damping** (:func:`noise_mode`): the rig's pulse (100 ms ramps, 3x the first mode's
  period) is followed quasi-statically and leaves a ring that the shaft-order lines and the load motor's
  broadband noise bury (on the record the damped-sine fit above explains only half the variance and its
  frequency moves 25-35 Hz with the window). The mode is read instead from the noise-driven ring after the
  pulse: the PSD of the propeller-shaft torque from :data:`MODE_AFTER_PULSE_S` after the pulse's end, fitted
  as one mode over a floor. ``overshoot``: the revolution-averaged propeller torque's rise at the pulse over
  the setpoint's, averaged alike and referred to the propeller shaft (1: the load followed statically).
* **Speed dip** (:func:`speed_dip`): the drive-side encoder's speed averaged over one middle-shaft revolution,
  its mean over the 0.3 s before the pulse minus its least value from the pulse's start to 0.3 s after its end.
* **Lines** (:func:`line_levels`): the Hann amplitude (rig.signals.amplitude_spectrum) of the propeller-shaft
  torque at f_MSH, 2 f_MSH, f_DSH, 2 f_DSH (largest bin within :data:`LINE_HALF_WIDTH_HZ`).
* **Load response** (:func:`load_response`): the multi-sine's propeller-shaft torque amplitude at each load line
  over the load's own (referred to the propeller shaft, x8): a point of the transfer function the first mode
  shapes. The setpoint is read on the rig's clock (rig.record.load_setpoint: the motor drive's log retimed by its
  32 Hz line, rig.clock); on the log's own index its lines are spread over several bins. Shown beside it:
  :func:`load_response_band` (``Hband_32.1Hz``, band powers, :func:`band_amplitude`, ±1.25 Hz),
  and ``psh_{32,64,96}Hz_Nm`` (the propeller torque's band amplitude at the line and its 2nd and 3rd harmonics).
* **Lines by windows** (:func:`line_levels_windowed`, shown): the shaft-order lines of the multi-sine read as
  check 11 reads the 500 rpm record's, over 1 s windows averaged in power (not f_DSH, which the 32 Hz response
  1.3 Hz away covers in so short a window).

Pure: arrays in, numbers out.
"""
from __future__ import annotations

import math

import numpy as np

from drivetrain.rig.data import PG_RATIO, UPPER_RATIO
from drivetrain.rig.signals import amplitude_spectrum

#: the ring-down fit's window after the pulse's end [s], and the grid it starts from
RING_WINDOW_S = 0.4
RING_BAND_HZ = (12.0, 60.0)
RING_ZETA = (0.005, 0.4)
#: the noise-driven mode fit: band [Hz], Welch segment, gap around lines [Hz]; its part of an impulse record
#: starts this long after the pulse's end [s]
MODE_BAND_HZ = (12.0, 60.0)
MODE_NPERSEG = 1024
LINE_GAP_HZ = 1.2
MODE_AFTER_PULSE_S = 0.3
#: the speed dip's windows [s]: the mean before the pulse, the search after its end
DIP_BEFORE_S = 0.3
DIP_AFTER_S = 0.3
LINE_HALF_WIDTH_HZ = 0.6
#: the band [Hz either side] of a load line's power in :func:`band_amplitude`
BAND_HALF_WIDTH_HZ = 1.25
#: the shaft-order lines [lines per middle-shaft revolution]
ORDER_LINES = {"f_MSH": 1, "2f_MSH": 2, "f_DSH": UPPER_RATIO, "2f_DSH": 2 * UPPER_RATIO}
#: the multi-sine's load lines, looked for near [Hz] (the logged setpoint's; README of the records)
SINE_LINES_HZ = (32.1, 129.0, 256.0)
#: the filter start-up at the beginning of a record's sensor file [s]
SKIP_S = 0.2


def msh_hz(enc1_w: np.ndarray) -> float:
    """The middle shaft's rotation frequency [Hz] from the drive-side encoder speed [rad/s]."""
    return float(np.mean(enc1_w)) / (2.0 * math.pi) / UPPER_RATIO


def revolution_mean(x: np.ndarray, fs: float, f_rev: float) -> np.ndarray:
    """``x`` averaged over one period 1/f_rev (centred moving average; the ends over what there is)."""
    n = max(1, int(round(fs / f_rev)))
    k = np.ones(n)
    return np.convolve(x, k, mode="same") / np.convolve(np.ones_like(x), k, mode="same")


def setpoint_pulse(t_set: np.ndarray, setpoint: np.ndarray) -> dict:
    """The pulse of a load setpoint: the times [s] it leaves its base, peaks and returns (on its own clock)."""
    base = float(np.median(setpoint))
    top = int(np.argmax(setpoint))
    thr = base + 0.05 * (setpoint[top] - base)
    above = np.flatnonzero(setpoint > thr)
    return {"start_s": float(t_set[above[0]]), "peak_s": float(t_set[top]), "end_s": float(t_set[above[-1]]),
            "base": base, "peak": float(setpoint[top])}


def pulse_times(t: np.ndarray, psh: np.ndarray, fs: float, f_msh: float, pulse: dict) -> dict:
    """The pulse on the torque's clock: the revolution-averaged propeller torque's peak, and the start and end
    the setpoint's own rise and fall times away from it."""
    sm = revolution_mean(psh, fs, f_msh)
    i = int(np.argmax(sm))
    tp = float(t[i])
    return {"start_s": tp - (pulse["peak_s"] - pulse["start_s"]), "peak_s": tp,
            "end_s": tp + (pulse["end_s"] - pulse["peak_s"])}


def _basis(tt: np.ndarray, lines_hz) -> np.ndarray:
    cols = [np.ones_like(tt), tt]
    for f in lines_hz:
        cols += [np.cos(2 * math.pi * f * tt), np.sin(2 * math.pi * f * tt)]
    return np.column_stack(cols)


def ring_down(t: np.ndarray, x: np.ndarray, t0: float, lines_hz, window_s: float = RING_WINDOW_S) -> dict:
    """A damped sine fitted to ``x`` over [t0, t0 + window_s] beside the given steady lines and a straight line
    (module docstring): frequency [Hz], damping ratio, amplitude at t0 [N·m], and the fit's residual RMS."""
    from scipy import optimize

    sel = (t >= t0) & (t <= t0 + window_s)
    tt, y = t[sel] - t0, x[sel]
    B = _basis(tt, lines_hz)

    def design(q):
        f, z = q
        wn = 2 * math.pi * f / math.sqrt(max(1e-9, 1 - z * z))
        env = np.exp(-z * wn * tt)
        return np.column_stack([B, env * np.cos(2 * math.pi * f * tt), env * np.sin(2 * math.pi * f * tt)])

    def resid(q):
        A = design(q)
        c, *_ = np.linalg.lstsq(A, y, rcond=None)
        return A @ c - y

    grid = [(f, z) for f in np.arange(RING_BAND_HZ[0], RING_BAND_HZ[1], 0.5)
            for z in np.geomspace(RING_ZETA[0], RING_ZETA[1], 12)]
    q0 = min(grid, key=lambda q: float(np.sum(resid(q) ** 2)))
    fit = optimize.least_squares(resid, q0, bounds=([RING_BAND_HZ[0], RING_ZETA[0]], [RING_BAND_HZ[1], 0.9]),
                                 x_scale=[1.0, 0.01])
    f, z = (float(v) for v in fit.x)
    c, *_ = np.linalg.lstsq(design(fit.x), y, rcond=None)
    return {"f_Hz": f, "zeta": z, "overshoot_Nm": float(math.hypot(c[-2], c[-1])),
            "residual_rms_Nm": float(np.sqrt(np.mean(fit.fun ** 2))), "signal_std_Nm": float(np.std(y)),
            "window_s": [float(t0), float(t0 + window_s)]}


def noise_mode(x: np.ndarray, fs: float, f_msh: float, band: tuple = MODE_BAND_HZ, nperseg: int = MODE_NPERSEG) -> dict:
    """The first mode from the broadband ring of a torque driven by noise: its Welch PSD over ``band`` (bins within
    :data:`LINE_GAP_HZ` of a multiple of f_MSH, the planetary's mesh or f_GMF left out) fitted in log as
    S0 / ((1 - r^2)^2 + (2 zeta r)^2) + floor, r = f / f_n (one mode over a white floor; started from a grid).
    The PSD of a noise-driven mode is the Fourier transform of its ring-down (its autocorrelation is a damped
    cosine of the same frequency and damping)."""
    from scipy import optimize, signal

    f, p = signal.welch(x - np.mean(x), fs=fs, nperseg=min(nperseg, len(x)))
    lines = np.array([k * f_msh for k in range(1, 60)] + [21.0 * f_msh, 15.0 * UPPER_RATIO * f_msh])
    sel = (f >= band[0]) & (f <= band[1]) & (np.min(np.abs(f[:, None] - lines[None, :]), axis=1) > LINE_GAP_HZ)
    ff, pp = f[sel], p[sel]

    def resid(q):
        r = ff / q[0]
        return np.log(np.exp(q[2]) / ((1 - r * r) ** 2 + (2 * q[1] * r) ** 2) + np.exp(q[3])) - np.log(pp)

    lo, hi = math.log(float(np.median(pp))), math.log(float(np.min(pp)))
    q0 = min(([fn, z, lo, hi] for fn in np.arange(band[0] + 1, band[1] - 1, 0.5) for z in (0.02, 0.05, 0.1, 0.2)),
             key=lambda q: float(np.sum(resid(q) ** 2)))
    fit = optimize.least_squares(resid, q0, bounds=([band[0], 0.002, -60, -60], [band[1], 1.0, 60, 60]))
    return {"f_Hz": float(fit.x[0]), "zeta": float(fit.x[1]), "residual_log": float(np.sqrt(np.mean(fit.fun ** 2))),
            "bins": int(len(ff)), "band_Hz": list(band)}


def speed_dip(t: np.ndarray, enc1_w: np.ndarray, fs: float, times: dict) -> float:
    """The drive-side speed's dip [rad/s] around the pulse (module docstring)."""
    sm = revolution_mean(enc1_w, fs, msh_hz(enc1_w))
    before = (t >= times["start_s"] - DIP_BEFORE_S) & (t < times["start_s"])
    after = (t >= times["start_s"]) & (t <= times["end_s"] + DIP_AFTER_S)
    return float(np.mean(sm[before]) - np.min(sm[after]))


def line_levels(x: np.ndarray, fs: float, f_msh: float) -> dict:
    """The shaft-order lines' Hann amplitudes [N·m] (module docstring)."""
    f, a = amplitude_spectrum(x, fs)
    out = {}
    for name, k in ORDER_LINES.items():
        sel = np.abs(f - k * f_msh) <= LINE_HALF_WIDTH_HZ
        out[name] = float(a[sel].max())
    return out


#: the window of :func:`line_levels_windowed` [s], and the multi-sine's lines read so (not f_DSH: 1.3 Hz from the
#: 32 Hz response, inside a 1 s window's main lobe)
LINE_WINDOW_S = 1.0
SINE_WINDOWED_LINES = ("f_MSH", "2f_MSH", "2f_DSH")


def line_levels_windowed(x: np.ndarray, fs: float, f_msh: float, window_s: float = LINE_WINDOW_S,
                         keys=tuple(ORDER_LINES)) -> dict:
    """The shaft-order lines ``keys`` as check 11 reads the 500 rpm record's: :func:`line_levels` of consecutive
    windows of ``window_s``, averaged in power (``<line>_w``). A line whose level or phase wanders reads lower over
    the whole record than in its windows; a steady one reads alike."""
    from drivetrain.rig.record import windows

    per = [line_levels(w - np.mean(w), fs, f_msh) for w in windows(x, fs, skip_s=0.0, window_s=window_s)]
    return {f"{k}_w": float(np.sqrt(np.mean([p[k] ** 2 for p in per]))) for k in keys}


def load_lines(t_set: np.ndarray, setpoint: np.ndarray) -> dict:
    """The multi-sine setpoint's lines: frequency [Hz] and amplitude at the load motor [N·m] (Hann, on a uniform
    grid at the motor's median step)."""
    dt = float(np.median(np.diff(t_set)))
    tu = np.arange(t_set[0], t_set[-1], dt)
    f, a = amplitude_spectrum(np.interp(tu, t_set, setpoint), 1.0 / dt)
    out = {}
    for fl in SINE_LINES_HZ:
        sel = np.flatnonzero(np.abs(f - fl) <= 3.0)
        i = int(sel[np.argmax(a[sel])])
        out[f"{fl:g}"] = {"f_Hz": float(f[i]), "load_Nm": float(a[i])}
    return out


def band_amplitude(x: np.ndarray, fs: float, f_Hz: float, half_width_Hz: float = BAND_HALF_WIDTH_HZ) -> float:
    """The amplitude [unit] of the sine carrying the power of ``x`` within ``half_width_Hz`` of ``f_Hz``: the Hann
    amplitudes' squares summed over the band, over the window's noise bandwidth (1.5 bins); for a clean line
    the peak bin's amplitude, for one spread over several bins (a wandering frequency) still its whole power."""
    f, a = amplitude_spectrum(np.asarray(x, dtype=float) - np.mean(x), fs)
    sel = np.abs(f - f_Hz) <= half_width_Hz
    return float(math.sqrt(np.sum(a[sel] ** 2) / 1.5))


def load_response_band(x: np.ndarray, fs: float, t_set: np.ndarray, setpoint: np.ndarray, lines: dict) -> dict:
    """As :func:`load_response` with :func:`band_amplitude` on both sides (the setpoint on a uniform grid at the
    motor's median step): the response where the load's line is spread over several bins by the motor log's
    clock (module docstring)."""
    dt = float(np.median(np.diff(t_set)))
    tu = np.arange(t_set[0], t_set[-1], dt)
    su = np.interp(tu, t_set, setpoint)
    return {key: band_amplitude(x, fs, ln["f_Hz"]) / (PG_RATIO * band_amplitude(su, 1.0 / dt, ln["f_Hz"]))
            for key, ln in lines.items()}


def load_response(x: np.ndarray, fs: float, lines: dict) -> dict:
    """The propeller-shaft torque's amplitude at each load line over the load's, referred to the propeller
    shaft (x PG_RATIO): |H| [N·m per N·m]."""
    f, a = amplitude_spectrum(x, fs)
    out = {}
    for key, ln in lines.items():
        sel = np.abs(f - ln["f_Hz"]) <= 1.0
        out[key] = float(a[sel].max() / (PG_RATIO * ln["load_Nm"]))
    return out


def impulse_figures(t: np.ndarray, psh: np.ndarray, dsh: np.ndarray, enc1_w: np.ndarray, fs: float,
                    t_set: np.ndarray, setpoint: np.ndarray, skip_s: float = SKIP_S) -> dict:
    """Every figure of an impulse record or run: ring frequency and damping, first overshoot, speed dip, torque
    std (both shafts), shaft-order lines; ``times`` where the pulse was found."""
    keep = t >= t[0] + skip_s
    t, psh, dsh, enc1_w = t[keep], psh[keep], dsh[keep], enc1_w[keep]
    fm = msh_hz(enc1_w)
    pulse = setpoint_pulse(t_set, setpoint)
    times = pulse_times(t, psh, fs, fm, pulse)
    mode = noise_mode(psh[t >= times["end_s"] + MODE_AFTER_PULSE_S], fs, fm)
    sm = revolution_mean(psh, fs, fm)
    before = (t >= times["start_s"] - DIP_BEFORE_S) & (t < times["start_s"])
    set_sm = revolution_mean(np.asarray(setpoint, dtype=float), 1.0 / float(np.median(np.diff(t_set))), fm)
    gain = (float(sm.max()) - float(np.mean(sm[before]))) / (PG_RATIO * (float(set_sm.max()) - pulse["base"]))
    return {"ring_Hz": mode["f_Hz"], "zeta": mode["zeta"], "overshoot": gain,
            "speed_dip_rad_s": speed_dip(t, enc1_w, fs, times), "std_psh_Nm": float(np.std(psh)),
            "std_dsh_Nm": float(np.std(dsh)), **line_levels(psh, fs, fm), "f_MSH_Hz": fm, "times": times,
            "mode_fit": mode}


def sine_figures(t: np.ndarray, psh: np.ndarray, dsh: np.ndarray, enc1_w: np.ndarray, fs: float,
                 t_set: np.ndarray, setpoint: np.ndarray, skip_s: float = SKIP_S) -> dict:
    """Every figure of a multi-sine record or run: torque std (both shafts), shaft-order lines, the load lines'
    response |H|."""
    keep = t >= t[0] + skip_s
    psh, dsh, enc1_w = psh[keep], dsh[keep], enc1_w[keep]
    fm = msh_hz(enc1_w)
    lines = load_lines(t_set, setpoint)
    resp = load_response(psh, fs, lines)
    band = load_response_band(psh, fs, t_set, setpoint, {k: v for k, v in lines.items() if k == "32.1"})
    return {"std_psh_Nm": float(np.std(psh)), "std_dsh_Nm": float(np.std(dsh)), **line_levels(psh, fs, fm),
            **{f"H_{k}Hz": v for k, v in resp.items()}, **{f"Hband_{k}Hz": v for k, v in band.items()},
            **{f"psh_{k * SINE_LINES_HZ[0]:.0f}Hz_Nm": band_amplitude(psh, fs, k * lines["32.1"]["f_Hz"])
               for k in (1, 2, 3)}, **line_levels_windowed(psh, fs, fm, keys=SINE_WINDOWED_LINES),
            "f_MSH_Hz": fm}


def speed_of(angle: np.ndarray, fs: float) -> np.ndarray:
    """An encoder's speed [rad/s] from its angle [rad], as the records' (np.gradient)."""
    return np.gradient(np.asarray(angle, dtype=float), 1.0 / fs)



__all__ = ["impulse_figures", "sine_figures", "ring_down", "speed_dip", "line_levels", "load_lines", "load_response",
           "load_response_band", "line_levels_windowed", "band_amplitude",
           "setpoint_pulse", "pulse_times", "revolution_mean", "msh_hz", "speed_of", "ORDER_LINES", "SINE_LINES_HZ",
           "RING_WINDOW_S", "SKIP_S"]
