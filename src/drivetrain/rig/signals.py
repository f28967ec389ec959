"""Signal processing of simulated rig signals.

- :func:`decimate`: anti-alias low-pass and decimation from the master's internal rate (1/H) to the
  output rate (3000 or 3012 Hz). Zero phase, so output sample m is the filtered signal at t = m/fs_out.
  ``"fir"`` (default): linear-phase Kaiser FIR, pass band flat within ±0.03 % up to 0.7 × the output
  Nyquist frequency, >= 70 dB stop band from the output Nyquist frequency (everything that would alias).
  ``"butter"``: order-10 Butterworth at 0.75 × output Nyquist, applied forward-backward (sosfiltfilt):
  flat within 0.1 % up to 0.5 × Nyquist, >= 50 dB from the output Nyquist frequency on.
- :func:`amplitude_spectrum`: the paper's post-processing: mean removed, low-pass at 5 × GMF
  (Butterworth, sosfiltfilt), Hann window, single-sided amplitude spectrum (a sine of amplitude a reads
  a at its bin).
- :func:`characteristic_frequencies`: f_DSH, f_MSH, f_PSH, f_GMF, harmonics and sidebands from the
  drive speed and the gear data (z1 = 15, z2 = 60, upper ratio 3).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from drivetrain.rig.data import UPPER_RATIO, Z_PINION, Z_WHEEL


class _Scipy:
    """``scipy.signal``, imported when first used (its import costs 0.6 s, several seconds on a busy machine:
    a command that needs no filter, e.g. ``drivetrain run --help``, does not pay it)."""

    def __getattr__(self, name):
        from scipy import signal

        return getattr(signal, name)


_sig = _Scipy()

FIR_PASS_FRACTION = 0.7      # pass-band edge as a fraction of the output Nyquist frequency
FIR_ATTENUATION_DB = 70.0
BUTTER_ORDER = 10
BUTTER_CUT_FRACTION = 0.75   # Butterworth cut-off as a fraction of the output Nyquist frequency
SPECTRUM_LOWPASS_ORDER = 8
#: The spectrum rule (the paper's): a torque spectrum is low-passed at this many times f_GMF first ...
SPECTRUM_LOWPASS_GMF = 5.0
#: ... and a line's amplitude is the largest within ± this many bins of its frequency.
SPECTRUM_LINE_BINS = 2


def spectrum_lowpass_Hz(f_gmf: float) -> float:
    """The low-pass edge of a torque spectrum [Hz]: :data:`SPECTRUM_LOWPASS_GMF` × f_GMF."""
    return SPECTRUM_LOWPASS_GMF * f_gmf


# --------------------------------------------------------------------------------------------------
# Characteristic frequencies
# --------------------------------------------------------------------------------------------------


def characteristic_frequencies(drive_speed_rpm: float, z1: int = Z_PINION, z2: int = Z_WHEEL,
                               upper_ratio: float = UPPER_RATIO, n_harmonics: int = 5,
                               n_sidebands: int = 3) -> dict:
    """Shaft rotation frequencies, gear mesh frequency of the lower pair, its harmonics and sidebands [Hz].

    f_DSH = n/60 (drive shaft), f_MSH = f_DSH/upper_ratio (middle shaft, carries the pinion z1),
    f_PSH = f_MSH·z1/z2 (propeller shaft), f_GMF = z1·f_MSH = z2·f_PSH; harmonics k·f_GMF (k = 1..n);
    sidebands f_GMF ± k·f_MSH (k = 1..n_sidebands; the faulty pinion is on the middle shaft).
    """
    f_dsh = float(drive_speed_rpm) / 60.0
    f_msh = f_dsh / upper_ratio
    f_psh = f_msh * z1 / z2
    f_gmf = z1 * f_msh
    return {
        "f_DSH": f_dsh,
        "f_MSH": f_msh,
        "f_PSH": f_psh,
        "f_GMF": f_gmf,
        "harmonics": [k * f_gmf for k in range(1, n_harmonics + 1)],
        "sidebands": [{"k": k, "lower": f_gmf - k * f_msh, "upper": f_gmf + k * f_msh}
                      for k in range(1, n_sidebands + 1)],
        "z1": z1, "z2": z2, "upper_ratio": upper_ratio, "drive_speed_rpm": float(drive_speed_rpm),
    }


# --------------------------------------------------------------------------------------------------
# Anti-alias filtering and decimation
# --------------------------------------------------------------------------------------------------


def decimation_factor(fs_in: float, fs_out: float) -> int:
    """Integer ratio fs_in/fs_out; ValueError if it is not an integer (relative tolerance 1e-6)."""
    r = fs_in / fs_out
    d = int(round(r))
    if d < 1 or abs(r - d) > 1e-6 * r:
        raise ValueError(f"internal rate {fs_in:.10g} Hz is not an integer multiple of the output rate "
                         f"{fs_out:.10g} Hz (ratio {r:.8g})")
    return d


@lru_cache(maxsize=32)
def fir_antialias(fs_in: float, fs_out: float) -> np.ndarray:
    """Odd-length linear-phase Kaiser low-pass for decimating fs_in -> fs_out (unit DC gain)."""
    nyq_out = 0.5 * fs_out
    f_pass = FIR_PASS_FRACTION * nyq_out
    f_stop = nyq_out
    width = (f_stop - f_pass) / (0.5 * fs_in)
    numtaps, beta = _sig.kaiserord(FIR_ATTENUATION_DB, width)
    numtaps |= 1
    h = _sig.firwin(numtaps, 0.5 * (f_pass + f_stop), window=("kaiser", beta), fs=fs_in)
    h = h / h.sum()
    h.setflags(write=False)
    return h


@lru_cache(maxsize=32)
def butter_antialias(fs_in: float, fs_out: float) -> np.ndarray:
    return _sig.butter(BUTTER_ORDER, BUTTER_CUT_FRACTION * 0.5 * fs_out, fs=fs_in, output="sos")


def _odd_pad(x: np.ndarray, n: int) -> np.ndarray:
    """Odd (point-symmetric) extension by n samples at both ends along axis 0, as sosfiltfilt does."""
    n = min(n, x.shape[0] - 1)
    if n <= 0:
        return x, 0
    left = 2.0 * x[0] - x[n:0:-1]
    right = 2.0 * x[-1] - x[-2:-n - 2:-1]
    return np.concatenate([left, x, right], axis=0), n


def decimate(x: np.ndarray, fs_in: float, fs_out: float, method: str = "fir") -> np.ndarray:
    """Low-pass (zero phase) and keep every D-th sample along axis 0 (D = fs_in/fs_out, an integer).

    Sample 0 of the result is input sample 0 (time 0); the result has ``(n - 1)//D + 1`` samples.
    """
    x = np.asarray(x, dtype=float)
    d = decimation_factor(fs_in, fs_out)
    if d == 1:
        return x.copy()
    if x.shape[0] < 2:
        return x[::d].copy()
    if method == "fir":
        h = fir_antialias(float(fs_in), float(fs_out))
        xp, n = _odd_pad(x, len(h))
        hh = h.reshape((-1,) + (1,) * (x.ndim - 1))
        y = _sig.oaconvolve(xp, hh, mode="same", axes=0)
        y = y[n:n + x.shape[0]]
    elif method == "butter":
        sos = butter_antialias(float(fs_in), float(fs_out)).copy()
        y = _sig.sosfiltfilt(sos, x, axis=0)
    else:
        raise ValueError(f"anti-alias method {method!r}: expected 'fir' or 'butter'")
    return np.ascontiguousarray(y[::d])


# --------------------------------------------------------------------------------------------------
# Spectra
# --------------------------------------------------------------------------------------------------


def lowpass(x: np.ndarray, fs: float, f_cut: float, order: int = SPECTRUM_LOWPASS_ORDER) -> np.ndarray:
    """Zero-phase Butterworth low-pass (sosfiltfilt) along axis 0; no-op if f_cut >= 0.95·fs/2."""
    x = np.asarray(x, dtype=float)
    if f_cut >= 0.95 * 0.5 * fs or f_cut <= 0:
        return x
    sos = _sig.butter(order, f_cut, fs=fs, output="sos")
    return _sig.sosfiltfilt(sos, x, axis=0)


#: what :func:`amplitude_spectrum` computes, as its plots' axis says it
AMPLITUDE_CONVENTION = "single-sided peak amplitude, 2|X|/Σw (Hann window, amplitude-corrected)"


def amplitude_spectrum(x: np.ndarray, fs: float, lowpass_Hz: float | None = None,
                       detrend: str = "mean") -> tuple[np.ndarray, np.ndarray]:
    """Single-sided amplitude spectrum with a Hann window (amplitude-corrected).

    Returns (f [Hz], A [unit of x]). A sine of amplitude a at a bin frequency reads a; the bin width is
    fs/len(x). ``lowpass_Hz``: zero-phase Butterworth low-pass first (the paper uses 5 × GMF).
    """
    x = np.asarray(x, dtype=float)
    if lowpass_Hz:
        x = lowpass(x, fs, lowpass_Hz)
    if detrend == "mean":
        x = x - x.mean()
    elif detrend == "linear":
        x = _sig.detrend(x)
    n = len(x)
    w = _sig.windows.hann(n, sym=False)
    X = np.fft.rfft(x * w)
    A = 2.0 * np.abs(X) / w.sum()
    A[0] *= 0.5
    f = np.fft.rfftfreq(n, 1.0 / fs)
    return f, A


def run_spectrum(time_s: np.ndarray, x: np.ndarray, settle_s: float, fs: float,
                 drive_speed_rpm: float, teeth: tuple[int, int] = (Z_PINION, Z_WHEEL),
                 upper_ratio: float = UPPER_RATIO) -> tuple[np.ndarray, np.ndarray, dict]:
    """The spectrum of a run's channel as its plots, its summary and ``result.spectrum`` read it (the one
    place that rule is written): the samples at or after ``settle_s``, mean removed, low-passed at
    :func:`spectrum_lowpass_Hz` of the run's f_GMF, :func:`amplitude_spectrum` (Hann, :data:`AMPLITUDE_CONVENTION`).
    Returns (f [Hz], A [unit of x], the characteristic frequencies of ``drive_speed_rpm``; ``teeth``: the lower
    pair's (z_pinion, z_wheel), the scene's [gear.pair]; ``upper_ratio``: the machine's upper gearbox, the rig's 3
    unless its lumped table says otherwise). ValueError when too few samples are settled."""
    cf = characteristic_frequencies(drive_speed_rpm, *teeth, upper_ratio=upper_ratio)
    keep = np.asarray(time_s) >= settle_s
    xs = np.asarray(x, dtype=float)[keep]
    if len(xs) <= 16 or not cf["f_GMF"] > 0:
        raise ValueError(f"{len(xs)} settled samples at {drive_speed_rpm:g} rpm: too few for a spectrum "
                         "(or no mesh frequency)")
    f, A = amplitude_spectrum(xs, fs, lowpass_Hz=spectrum_lowpass_Hz(cf["f_GMF"]))
    return f, A, cf


def amplitude_near(f: np.ndarray, A: np.ndarray, f0: float, bins: int = SPECTRUM_LINE_BINS) -> float:
    """Largest amplitude within ±bins bins of f0 (for reading a peak whose frequency is known)."""
    df = f[1] - f[0]
    i = int(round(f0 / df))
    lo, hi = max(0, i - bins), min(len(A), i + bins + 1)
    return float(A[lo:hi].max()) if hi > lo else float("nan")


def local_floor(f: np.ndarray, A: np.ndarray, f0: float, half_width_Hz: float, lines_Hz: float,
                guard_bins: float = 2.5) -> float:
    """The spectrum's floor around f0: the median amplitude within ±half_width_Hz of f0 over the bins
    farther than ``guard_bins`` from every multiple of ``lines_Hz`` (the family of lines the drivetrain
    can have there: every characteristic frequency of the rig is a multiple of f_PSH)."""
    df = f[1] - f[0]
    m = np.abs(f - f0) <= half_width_Hz
    fm = f[m]
    k = np.round(fm / lines_Hz)
    off_line = np.abs(fm - k * lines_Hz) > guard_bins * df
    return float(np.median(A[m][off_line])) if np.any(off_line) else float("nan")


def peak_frequency(f: np.ndarray, A: np.ndarray, f_lo: float, f_hi: float) -> float:
    m = (f >= f_lo) & (f <= f_hi)
    return float(f[m][np.argmax(A[m])])


def to_db(a, ref: float = 1.0):
    return 20.0 * np.log10(np.maximum(np.asarray(a, dtype=float), 1e-300) / ref)


def stats(x: np.ndarray) -> dict:
    x = np.asarray(x, dtype=float)
    return {"mean": float(np.mean(x)), "rms": float(np.sqrt(np.mean(x * x))),
            "std": float(np.std(x)), "min": float(np.min(x)), "max": float(np.max(x))}


__all__ = ["characteristic_frequencies", "decimate", "decimation_factor", "fir_antialias", "butter_antialias",
           "SPECTRUM_LOWPASS_GMF", "SPECTRUM_LINE_BINS", "spectrum_lowpass_Hz", "lowpass", "amplitude_spectrum", "run_spectrum", "amplitude_near", "local_floor", "peak_frequency", "to_db", "stats"]
