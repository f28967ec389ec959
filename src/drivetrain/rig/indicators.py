"""Condition indicators of gear vibration: time-synchronous averages and the standard gear metrics.

What practice does to find a gear fault in a torque or vibration signal, on our signals:

* **Time-synchronous average (TSA)** per shaft (McFadden 1987; Lebold et al. 2000): the signal resampled at
  ``points`` equal angle steps per revolution of the shaft, using the shaft's encoder angle (linear
  interpolation of the signal at the sample times where the encoder angle crosses each step: angular
  resampling, numpy.interp), averaged over the whole revolutions. What is not locked to the shaft
  (the other shafts' orders, noise) averages out as 1/sqrt(revolutions).
* On the TSA, by shaft orders (the TSA's FFT bins are orders of the shaft; numpy.fft):
  ``regular`` = the mesh harmonics k z and their first sidebands k z +- 1; the **difference** signal
  d = TSA - regular - orders 1 and 2 (Lebold et al. 2000, "difference signal"); the **residual** signal
  r = TSA - mesh harmonics - orders 1 and 2 (Zakrajsek et al. 1993).

The metrics (x the TSA, N its points, A(k) the TSA's amplitude at order k, z the gear's teeth):

| metric | definition | source |
|---|---|---|
| RMS | sqrt(mean(x^2)) of x - mean | |
| CF | max abs(x - mean) / RMS | crest factor |
| kurtosis | N sum (x - mean)^4 / (sum (x - mean)^2)^2 (3 for a Gaussian, 1.5 for a sine) | |
| FM0 | (max x - min x) / sum_k A(k z) | Stewart 1977 |
| FM4 | N sum d^4 / (sum d^2)^2 | Stewart 1977 |
| NA4 | mean((r - mean r)^4) of the last record / (the mean over the run's M records of var(r))^2 | Zakrajsek, Townsend & Decker 1993 |
| NB4 | the same of the envelope (|Hilbert|) of the TSA band-passed to the mesh harmonic's sidebands z +- z/2 orders | Zakrajsek 1994 |
| M6A | N^2 sum d^6 / (sum d^2)^3 | Martin 1989 |
| M8A | N^3 sum d^8 / (sum d^2)^4 | Martin 1989 |
| ER | RMS(d) / RMS(regular) | energy ratio, Swansson 1980 |
| SLF | (A(z - 1) + A(z + 1)) / RMS(x) | sideband level factor, Lebold et al. 2000 |
| SER | sum_{i=1..6} (A(z - i) + A(z + i)) / A(z) | sideband energy ratio, Hanna et al. 2011 |

NA4 and NB4 need a run of records: a run's TSA is computed on ``records`` consecutive parts (each part a
TSA of its own); the numerator is the last part's, the denominator the mean of all parts' variances
(the "run ensemble" of the original, within one run). References: Lebold, McClintic, Campbell, Byington &
Maynard, "A review of vibration analysis methods for gearbox diagnostics and prognostics", 54th MFPT
(2000); Samuel & Pines, J. Sound Vib. 282 (2005) 475-508; Hanna, Hatch et al., "Detection of wind turbine
gear tooth defects using sideband energy ratio", China Wind Power (2011). Pure: arrays in, numbers out.

:func:`run_features` applies them to one run: per torque transducer and per shaft whose encoder was recorded,
the TSA records and their metrics, and the amplitudes at the characteristic frequencies: the columns of
``drivetrain features`` and ``drivetrain dataset``. The chance levels (:func:`chance_separability`,
:func:`chance_unpaired`) say what the best of many indicators reaches over a few gearboxes by chance.
"""
from __future__ import annotations

import math

import numpy as np

from drivetrain.rig.data import TORQUE_SENSORS, Z_PINION, Z_WHEEL
from drivetrain.rig.signals import amplitude_near, amplitude_spectrum, characteristic_frequencies

#: indicator names, in column order
METRICS = ("RMS", "CF", "kurtosis", "FM0", "FM4", "NA4", "NB4", "M6A", "M8A", "ER", "SLF", "SER")
#: sidebands counted by SER on each side of the mesh order
SER_SIDEBANDS = 6


def tsa(x: np.ndarray, angle: np.ndarray, points: int, revolutions: int | None = None) -> np.ndarray:
    """Time-synchronous average of ``x`` over the whole revolutions of ``angle`` [rad, increasing], at
    ``points`` equal angle steps per revolution (the first ``revolutions`` whole ones if given)."""
    x = np.asarray(x, dtype=float)
    a = np.asarray(angle, dtype=float)
    if x.shape != a.shape or x.ndim != 1:
        raise ValueError("the signal and the angle must be 1-d arrays of one length")
    if not np.all(np.diff(a) > 0):
        raise ValueError("the shaft angle must increase strictly (a turning shaft, its encoder unwrapped)")
    start = math.ceil(a[0] / (2 * math.pi)) * 2 * math.pi
    n_rev = int(math.floor((a[-1] - start) / (2 * math.pi)))
    if revolutions is not None:
        n_rev = min(n_rev, int(revolutions))
    if n_rev < 1:
        raise ValueError("the signal spans less than one whole revolution of the shaft")
    grid = start + 2 * math.pi * np.arange(n_rev * points) / points
    return np.interp(grid, a, x).reshape(n_rev, points).mean(axis=0)


def tsa_records(x: np.ndarray, angle: np.ndarray, points: int, records: int) -> list[np.ndarray]:
    """TSAs of ``records`` consecutive parts of the run with equally many whole revolutions each."""
    a = np.asarray(angle, dtype=float)
    start = math.ceil(a[0] / (2 * math.pi)) * 2 * math.pi
    n_rev = int(math.floor((a[-1] - start) / (2 * math.pi)))
    per = n_rev // records
    if per < 1:
        raise ValueError(f"{n_rev} whole revolutions cannot make {records} records")
    out = []
    for k in range(records):
        lo = start + 2 * math.pi * k * per
        m = (a >= lo - 1e-9) & (a <= lo + 2 * math.pi * per + 1e-9)
        i0, i1 = max(np.flatnonzero(m)[0] - 1, 0), min(np.flatnonzero(m)[-1] + 2, len(a))
        seg_a, seg_x = a[i0:i1], np.asarray(x, dtype=float)[i0:i1]
        grid = lo + 2 * math.pi * np.arange(per * points) / points
        out.append(np.interp(grid, seg_a, seg_x).reshape(per, points).mean(axis=0))
    return out


def _keep_orders(x: np.ndarray, orders) -> np.ndarray:
    """The part of a one-revolution signal at the given shaft orders (FFT bins)."""
    X = np.fft.rfft(x)
    mask = np.zeros(len(X), dtype=bool)
    for k in orders:
        if 0 < k < len(X):
            mask[k] = True
    return np.fft.irfft(np.where(mask, X, 0.0), n=len(x))


def mesh_orders(points: int, teeth: int) -> list[int]:
    """The mesh harmonics k z below the TSA's Nyquist order."""
    return [k * teeth for k in range(1, points // 2 // teeth + 1) if k * teeth < points // 2]


def split(x: np.ndarray, teeth: int) -> dict:
    """The TSA's parts: ``regular`` (mesh harmonics and first sidebands), ``difference`` (TSA less regular
    and orders 1, 2), ``residual`` (TSA less the mesh harmonics and orders 1, 2), each about its mean."""
    x = np.asarray(x, dtype=float) - np.mean(x)
    n = len(x)
    mesh = mesh_orders(n, teeth)
    regular_orders = sorted({o + s for o in mesh for s in (-1, 0, 1)})
    regular = _keep_orders(x, regular_orders)
    low = _keep_orders(x, (1, 2))
    return {"regular": regular, "difference": x - regular - low,
            "residual": x - _keep_orders(x, mesh) - low}


def order_amplitudes(x: np.ndarray) -> np.ndarray:
    """Amplitude of each shaft order of a one-revolution signal (rectangular window: the TSA is periodic)."""
    X = np.fft.rfft(np.asarray(x, dtype=float))
    a = 2.0 * np.abs(X) / len(x)
    a[0] *= 0.5
    return a


def _moment_ratio(d: np.ndarray, p: int) -> float:
    """N^(p/2 - 1) sum d^p / (sum d^2)^(p/2): the normalised p-th moment (kurtosis for p = 4)."""
    d = np.asarray(d, dtype=float)
    s2 = float(np.sum(d * d))
    if s2 <= 0.0:
        return float("nan")
    n = len(d)
    return float(n ** (p / 2 - 1) * np.sum(d ** p) / s2 ** (p / 2))


def envelope_band(x: np.ndarray, teeth: int) -> np.ndarray:
    """Envelope (|analytic signal|) of the TSA band-passed to the mesh order's sidebands, z +- z/2."""
    from scipy.signal import hilbert

    n = len(x)
    lo, hi = teeth - teeth // 2, teeth + teeth // 2
    band = _keep_orders(np.asarray(x, dtype=float) - np.mean(x), range(max(lo, 1), min(hi, n // 2 - 1) + 1))
    return np.abs(hilbert(band))


def indicators(records: list[np.ndarray], teeth: int) -> dict:
    """The metrics of :data:`METRICS` of a shaft's TSA records (the last one is judged, the others are the
    run ensemble of NA4 and NB4; with one record NA4 and NB4 are the residual's and the envelope's kurtosis)."""
    x = np.asarray(records[-1], dtype=float)
    xc = x - x.mean()
    n = len(x)
    rms = float(np.sqrt(np.mean(xc * xc)))
    parts = split(x, teeth)
    amp = order_amplitudes(x)
    mesh = mesh_orders(n, teeth)
    r_all = [split(r, teeth)["residual"] for r in records]
    r_var = float(np.mean([np.var(r) for r in r_all]))
    r = r_all[-1] - r_all[-1].mean()
    e_all = [envelope_band(rec_, teeth) for rec_ in records]
    e_var = float(np.mean([np.var(e) for e in e_all]))
    e = e_all[-1] - e_all[-1].mean()
    sb = [amp[teeth + i] + amp[teeth - i] for i in range(1, SER_SIDEBANDS + 1) if teeth + i < len(amp)]
    return {
        "RMS": rms,
        "CF": float(np.max(np.abs(xc)) / rms) if rms > 0 else float("nan"),
        "kurtosis": _moment_ratio(xc, 4),
        "FM0": float(np.ptp(x) / sum(amp[k] for k in mesh)) if mesh else float("nan"),
        "FM4": _moment_ratio(parts["difference"], 4),
        "NA4": float(np.mean(r ** 4) / r_var ** 2) if r_var > 0 else float("nan"),
        "NB4": float(np.mean(e ** 4) / e_var ** 2) if e_var > 0 else float("nan"),
        "M6A": _moment_ratio(parts["difference"], 6),
        "M8A": _moment_ratio(parts["difference"], 8),
        "ER": float(np.std(parts["difference"]) / np.std(parts["regular"])) if np.std(parts["regular"]) > 0
        else float("nan"),
        "SLF": float((amp[teeth - 1] + amp[teeth + 1]) / rms) if rms > 0 else float("nan"),
        "SER": float(sum(sb) / amp[teeth]) if amp[teeth] > 0 else float("nan"),
    }


def auc(healthy, faulty) -> float:
    """Unpaired AUC: the probability that a faulty gearbox's indicator exceeds a healthy one's, ties counted
    half (the area under the ROC curve, = Mann-Whitney U / (n_h n_f); scipy.stats.mannwhitneyu). 0.5: no
    separation; 1 or 0: complete (an indicator that falls with the fault reads below 0.5)."""
    from scipy.stats import mannwhitneyu

    h = np.asarray(healthy, dtype=float)
    f = np.asarray(faulty, dtype=float)
    h, f = h[np.isfinite(h)], f[np.isfinite(f)]
    if not (len(h) and len(f)):
        return float("nan")
    return float(mannwhitneyu(f, h, alternative="two-sided").statistic / (len(h) * len(f)))


def paired_auc(healthy, faulty) -> float:
    """Paired AUC: over gearboxes, the fraction whose indicator rose with the fault (faulty > healthy of the
    same gearbox, ties half): what a monitoring system that knows the gearbox's own baseline sees."""
    h = np.asarray(healthy, dtype=float)
    f = np.asarray(faulty, dtype=float)
    if h.shape != f.shape:
        raise ValueError("paired indicators need one healthy and one faulty value per gearbox")
    ok = np.isfinite(h) & np.isfinite(f)
    if not ok.any():
        return float("nan")
    d = f[ok] - h[ok]
    return float((np.sum(d > 0) + 0.5 * np.sum(d == 0)) / len(d))


def change_auc(baseline, healthy, faulty) -> float:
    """Two-sided detectability of a change: over gearboxes, the probability that a faulty gearbox's change
    from its own baseline, |faulty - baseline|, exceeds a healthy gearbox's, |healthy - baseline| (the
    healthy-vs-baseline spread: what the indicator does between two days without a fault), ties half
    (Mann-Whitney AUC of the two sets of absolute changes). 0.5: the fault changes the indicator no more than
    a day does; 1: every fault's change, of either sign, exceeds every healthy change. A line that moves
    +-10 dB depending on the gearbox scores 1 here and 0.5 in :func:`paired_auc`."""
    b = np.asarray(baseline, dtype=float)
    h = np.asarray(healthy, dtype=float)
    f = np.asarray(faulty, dtype=float)
    if not (b.shape == h.shape == f.shape):
        raise ValueError("a change needs one baseline, one healthy and one faulty value per gearbox")
    ok = np.isfinite(b) & np.isfinite(h) & np.isfinite(f)
    if not ok.any():
        return float("nan")
    return auc(np.abs(h[ok] - b[ok]), np.abs(f[ok] - b[ok]))


def chance_change(gearboxes: int, indicators: int, level: float = 0.05) -> float:
    """The best-of-``indicators`` :func:`change_auc` that ``gearboxes`` gearboxes without a fault reach with
    probability ``level`` (the Mann-Whitney AUC's null law, normal about 1/2 with variance (2n + 1) / (12 n^2),
    one-sided: only a larger change counts; the indicators taken as independent). With ``indicators`` the
    count over every cell of a study it is the family-wise level."""
    from scipy.stats import norm

    if gearboxes < 1:
        return 1.0
    sigma = math.sqrt((2 * gearboxes + 1) / (12.0 * gearboxes * gearboxes))
    p_one = 1.0 - (1.0 - level) ** (1.0 / max(indicators, 1))
    return float(min(1.0, 0.5 + sigma * norm.isf(p_one)))


def separability(a: float) -> float:
    """max(AUC, 1 - AUC): how well an indicator separates, whichever way it moves."""
    return float(max(a, 1.0 - a)) if math.isfinite(a) else float("nan")


def chance_separability(gearboxes: int, indicators: int, level: float = 0.05) -> float:
    """The best-of-``indicators`` separability that healthy-vs-healthy comparisons (each gearbox's indicator a
    coin flip) exceed with probability ``level`` over ``gearboxes`` gearboxes, the indicators taken as
    independent (correlated ones reach less): the chance level of paired separability (drivetrain
    detectability's paired rise; validate's check 6 shows it beside its two-sided score)."""
    from scipy.stats import binom

    for k in range(gearboxes // 2, gearboxes + 1):        # separability >= k / n: at least k one way
        p_one = min(1.0, 2.0 * binom.sf(k - 1, gearboxes, 0.5)) if k > gearboxes / 2 else 1.0
        if 1.0 - (1.0 - p_one) ** indicators <= level:
            return k / gearboxes
    return 1.0


def chance_unpaired(healthy: int, faulty: int, indicators: int, level: float = 0.05) -> float:
    """The best-of-``indicators`` unpaired separability that two samples of one population (``healthy`` and
    ``faulty`` runs) reach with probability ``level``: the Mann-Whitney AUC's null law, normal about 1/2 with
    variance (n1 + n2 + 1) / (12 n1 n2), the indicators taken as independent."""
    from scipy.stats import norm

    if healthy < 1 or faulty < 1:
        return 1.0
    sigma = math.sqrt((healthy + faulty + 1) / (12.0 * healthy * faulty))
    p_one = 1.0 - (1.0 - level) ** (1.0 / max(indicators, 1))
    return float(min(1.0, 0.5 + sigma * norm.isf(p_one / 2.0)))


def signal_to_background_dB(faulty: np.ndarray, healthy: np.ndarray) -> float:
    """The fault's signal-to-background ratio [dB]: the energy of (faulty - healthy) over the healthy run's own
    variability (its variance), for two runs of one gearbox, operating point and noise record sample by sample
    ([sweep.draw] paired_healthy): 10 log10(mean((f - h)^2) / var(h))."""
    f = np.asarray(faulty, dtype=float)
    h = np.asarray(healthy, dtype=float)
    n = min(len(f), len(h))
    if n < 2:
        return float("nan")
    f, h = f[:n], h[:n]
    var = float(np.var(h))
    diff = float(np.mean((f - h) ** 2))
    if var <= 0.0 or diff <= 0.0:
        return float("-inf") if var > 0.0 else float("nan")
    return float(10.0 * math.log10(diff / var))


def twin_groups(runs: list[dict]) -> list[list[dict]]:
    """The runs measured with one noise record (sharing a ``scenario.noise_name`` label: a faulty run and its
    healthy twin), group by group; only the labels are read."""
    by_pair: dict = {}
    for r in runs:
        key = r["labels"].get("scenario.noise_name")
        if key:
            by_pair.setdefault(key, []).append(r)
    return list(by_pair.values())


def twin_mismatch(run: dict, twin: dict) -> str | None:
    """Why a faulty run cannot be compared with its healthy twin sample by sample (one noise record: one time
    axis), or None: ``"run a has 601 samples, its healthy twin b 50"``."""
    t, h = np.asarray(run["time"]), np.asarray(twin["time"])
    if t.shape != h.shape:
        return f"run {run['name']} has {t.size} samples, its healthy twin {twin['name']} {h.size}"
    if t.size and not np.allclose(t, h, rtol=1e-9, atol=0.0):
        return f"run {run['name']} and its healthy twin {twin['name']} were sampled at other times"
    return None


def paired_sbr(runs: list[dict], signals: tuple[str, ...]) -> dict:
    """{faulty run name: {signal: SBR dB}} of the runs with a healthy twin (:func:`twin_groups`, one of them
    healthy), compared after the settling time (``time.settle_s``). A twin of another length or time axis is
    a ValueError (:func:`twin_mismatch`)."""
    out = {}
    for members in twin_groups(runs):
        healthy = [r for r in members if r["labels"].get("gear.health") == "healthy"]
        if len(healthy) != 1:
            continue
        h = healthy[0]
        for r in members:
            if r is h:
                continue
            why = twin_mismatch(r, h)
            if why:
                raise ValueError(why)
            keep = np.asarray(r["time"]) >= float(r["labels"].get("time.settle_s") or 0.0)
            out[r["name"]] = {sig: signal_to_background_dB(np.asarray(r["signals"][sig])[keep],
                                                           np.asarray(h["signals"][sig])[keep])
                              for sig in signals if sig in r["signals"] and sig in h["signals"]}
    return out


def points_per_revolution(fs: float, f_shaft: float) -> int:
    """TSA points per revolution: the power of two at or below the samples per revolution (no upsampling
    beyond what was measured), at least 64."""
    return max(64, 2 ** int(math.floor(math.log2(fs / f_shaft))))


# --------------------------------------------------------------------------------------------------
# the indicators of one run (the columns of drivetrain features and drivetrain dataset)
# --------------------------------------------------------------------------------------------------

#: the shafts whose gear is judged: name -> (encoder sensor, teeth, characteristic frequency of its speed)
SHAFTS = {"pinion": ("enc4", Z_PINION, "f_MSH"), "wheel": ("enc5", Z_WHEEL, "f_PSH")}
TORQUES = tuple(reversed(TORQUE_SENSORS))  # propeller shaft first (the order of the features and tables)
#: TSA records per run (NA4 and NB4 compare the last with the run's mean); fewer when the run is short
RECORDS = 4
#: the characteristic frequencies whose amplitude is a column (keys of rig.signals.characteristic_frequencies)
LINES = ("f_PSH", "f_MSH", "f_DSH", "f_GMF", "f_GMF-f_MSH", "f_GMF+f_MSH")


def _line(cf: dict, name: str) -> float:
    if "-" in name or "+" in name:
        sign = 1.0 if "+" in name else -1.0
        a, b = name.replace("+", "-").split("-")
        return cf[a] + sign * cf[b]
    return cf[name]


def label_teeth(labels: dict) -> tuple[int, int]:
    """(z_pinion, z_wheel) of a run's labels (a dict or a dataset row): its [gear.pair] columns, the rig's where
    it has none (a run of the rig's pair, or an empty cell of a dataset that mixes pairs)."""
    out = []
    for key, rig_z in (("z_pinion", Z_PINION), ("z_wheel", Z_WHEEL)):
        try:
            out.append(int(labels.get(f"gear.pair.{key}")))
        except (TypeError, ValueError):         # absent (None) or an empty cell (NaN)
            out.append(rig_z)
    return tuple(out)


def run_features(time: np.ndarray, signals: dict, settle_s: float, drive_speed_rpm: float,
                 teeth: tuple[int, int] = (Z_PINION, Z_WHEEL)) -> dict:
    """The indicator columns of one run (module docstring); signals it lacks give no columns. ``teeth``: the
    lower pair's (z_pinion, z_wheel) (the scene's [gear.pair]; the rig's by default)."""
    t = np.asarray(time, dtype=float)
    keep = t >= settle_s
    if keep.sum() < 16:
        raise ValueError(f"{int(keep.sum())} samples after the settling time {settle_s:g} s: too short")
    fs = 1.0 / float(np.median(np.diff(t)))
    cf = characteristic_frequencies(drive_speed_rpm, *teeth)
    out: dict = {}
    for sig in TORQUES:
        if sig not in signals:
            continue
        x = np.asarray(signals[sig], dtype=float)[keep]
        f, a = amplitude_spectrum(x, fs)
        for ln in LINES:
            out[f"amp_{ln}.{sig}"] = amplitude_near(f, a, _line(cf, ln), 1)
        for shaft, (enc, _rig_teeth, f_key) in SHAFTS.items():
            z = teeth[0] if shaft == "pinion" else teeth[1]
            if enc not in signals:
                continue
            angle = np.asarray(signals[enc], dtype=float)[keep]
            angle = angle + 1e-12 * np.arange(len(angle))     # a quantised encoder repeats a count: make it increase
            revs = (angle[-1] - angle[0]) / (2 * math.pi)
            n_rec = max(1, min(RECORDS, int(revs // 2)))
            pts = points_per_revolution(fs, cf[f_key])
            try:
                recs = tsa_records(x, angle, pts, n_rec)
            except ValueError:
                continue
            for metric, value in indicators(recs, z).items():
                out[f"{metric}_{shaft}.{sig}"] = value
    return out


__all__ = ["run_features", "SHAFTS", "TORQUES", "RECORDS", "LINES", "auc", "paired_auc", "separability", "chance_separability", "chance_unpaired", "signal_to_background_dB", "twin_groups", "paired_sbr", "METRICS", "tsa", "tsa_records", "split", "order_amplitudes", "mesh_orders", "indicators",
           "envelope_band", "points_per_revolution", "SER_SIDEBANDS"]
