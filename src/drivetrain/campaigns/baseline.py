"""Baselines: a compact reference of a run to compare later runs of the same scene against.

A baseline file (HDF5, ``format = "drivetrain-baseline/1"``) holds, per case (one for a scene file, one
per expanded case for a grid file)::

    /                      attrs: format, created, source (scene file), versions_json
    /cases/<name>/         attrs: scene_json (resolved scene + overrides), scene_toml, summary_json (the
                                  whole summary.json), metrics_json ({metric: value}), status,
                                  decimation, sample_rate_Hz, settle_s, created, versions_json
    /cases/<name>/time                 [s] decimated output time
    /cases/<name>/signals/<channel>    decimated signal (linear-phase FIR anti-alias, <= 6000 samples;
                                       attrs unit)
    /cases/<name>/spectra/<channel>    amplitudes at the characteristic frequencies (attrs
                                       frequencies = JSON list of expressions, f_Hz)

Where: ``<scene stem>.baseline.h5`` beside the scene file, or the file named by ``[check] baseline``,
or ``<dir>/<scene stem>.baseline.h5`` with ``--baseline-dir`` (:func:`baseline_path`).

Comparison (:func:`compare`), tolerances from the scene's ``[check]`` section:

- metrics (torque and channel statistics, stability numbers, energy residual, simulated time, status):
  ``|a - b| <= baseline_rel · |b|`` (energy residual: or <= 1e-5 absolute);
- signals: RMS of the difference over the common samples after ``settle_s``, relative to the RMS of
  the baseline signal, <= ``baseline_signal_rel``;
- spectra: level difference at each characteristic frequency <= ``baseline_dB``, for the levels
  within 60 dB of the largest one (lower ones are numerical leakage).
"""
from __future__ import annotations

import json
import math
import platform
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drivetrain import __version__
from drivetrain.scene.expect import CheckOptions, Outcome, _fmt, freqs_of, frequency_value, spectrum_levels
from drivetrain.run.outputs import jsonable, new_figure, now_iso, place_axes, save_figure, suptitle, title_margin
from drivetrain.rig.data import TORQUE_SENSORS
from drivetrain.rig.signals import decimate

FORMAT = "drivetrain-baseline/1"
SUFFIX = ".baseline.h5"
MAX_SAMPLES = 6000              # decimated samples per stored signal (at most)
SPECTRUM_FLOOR_DB = 60.0        # levels this far below the largest are not compared
ENERGY_ABS = 1e-5               # absolute floor of the energy-residual comparison
_STATS = ("mean", "rms", "std", "min", "max")
_STABILITY = ("max_penetration_rel_umax", "min_substep_s", "n_refinements")
_RATTLE = ("n_separations", "separated_fraction")


def spectrum_frequencies(freqs: dict, fs: float, n_harmonics: int = 5, n_sidebands: int = 3) -> list[str]:
    """The frequency expressions stored in a baseline: shaft frequencies, k·f_GMF, f_GMF ± k·f_MSH
    (those below the Nyquist frequency)."""
    ex = ["f_DSH", "f_MSH", "f_PSH", "f_GMF"] + [f"{k}*f_GMF" for k in range(2, n_harmonics + 1)]
    for k in range(1, n_sidebands + 1):
        km = "" if k == 1 else f"{k}*"
        ex += [f"f_GMF-{km}f_MSH", f"f_GMF+{km}f_MSH"]

    return [e for e in ex if 0.0 < frequency_value(e, freqs) < 0.5 * fs]


def baseline_path(source: str | Path, options: CheckOptions | None = None,
                  baseline_dir: str | Path | None = None) -> Path:
    """Where the baseline of a scene file lives: ``baseline_dir/<stem>.baseline.h5`` if given, else the
    scene's ``[check] baseline``, else ``<stem>.baseline.h5`` beside the scene file."""
    source = Path(source)
    if baseline_dir is not None:
        return Path(baseline_dir) / f"{source.stem}{SUFFIX}"
    if options is not None and options.baseline is not None:
        return Path(options.baseline)
    return source.with_name(f"{source.stem}{SUFFIX}")


def versions() -> dict:
    """Versions of what produced a run: this package, Python, the numerical libraries, the FMU sources."""
    import importlib.metadata as md


    out: dict[str, Any] = {"drivetrain": __version__, "python": platform.python_version(),
                           "platform": platform.platform()}
    for pkg in ("numpy", "scipy", "numba", "fmpy", "pythonfmu", "h5py"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            out[pkg] = None
    try:
        from drivetrain.fmu_build.fmus import sources_hash

        out["fmu_sources_sha256"] = sources_hash()
    except Exception:  # noqa: BLE001 - informational only
        out["fmu_sources_sha256"] = None
    return out


# --------------------------------------------------------------------------------------------------
# The compact reference of one run
# --------------------------------------------------------------------------------------------------


@dataclass
class Entry:
    """The compact reference of one run (what a baseline stores per case)."""

    name: str
    scene: dict                            # {"scene": resolved scene dict, "source", "overrides"}
    summary: dict
    metrics: dict[str, Any]                # flattened metrics compared against the baseline
    time: np.ndarray                       # decimated time [s]
    signals: dict[str, np.ndarray]         # decimated channels
    units: dict[str, str]
    spectra: dict[str, dict[str, float]]   # channel -> {frequency expression: amplitude}
    decimation: int
    sample_rate_Hz: float
    settle_s: float
    versions: dict = field(default_factory=dict)
    scene_toml: str = ""


def summary_metrics(summary: dict) -> dict[str, Any]:
    """The summary's metrics a baseline compares (flattened dotted paths -> value)."""
    m: dict[str, Any] = {"status": summary.get("status"), "sim_time_s": summary.get("sim_time_s"),
                         "energy_residual": summary.get("energy_residual")}
    torque = summary.get("torque") or {}
    for group in ("torque", "channels"):
        for ch, st in (summary.get(group) or {}).items():
            if group == "channels" and ch in torque:        # the same numbers as torque.<ch>
                continue
            for k in _STATS:
                if k in st:
                    m[f"{group}.{ch}.{k}"] = st[k]
    st = summary.get("stability") or {}
    for k in _STABILITY:
        if st.get(k) is not None:
            m[f"stability.{k}"] = st[k]
    for k in _RATTLE:
        v = (st.get("rattle") or {}).get(k)
        if v is not None:
            m[f"stability.rattle.{k}"] = v
    return m


def default_channels(scene, signals: dict) -> list[str]:
    opt = scene.expect.options if scene.expect is not None else CheckOptions()
    if opt.baseline_signals is not None:
        return [c for c in opt.baseline_signals if c in signals]

    return [c for c in signals if c in TORQUE_SENSORS or c in scene.outputs.variables]


def make_entry(scene, summary: dict, time: np.ndarray, signals: dict, units: dict | None = None,
               decimation: int | None = None, channels: list[str] | None = None) -> Entry:
    """The compact reference of a run. ``decimation``: keep every D-th sample after the anti-alias
    filter (default: the smallest D giving <= MAX_SAMPLES samples)."""

    time = np.asarray(time, dtype=float)
    n = len(time)
    fs = float(summary.get("sample_rate_Hz") or scene.time.sample_rate_Hz)
    settle = float(summary.get("settle_s", scene.time.settle_s))
    d = int(decimation) if decimation else max(1, math.ceil(n / MAX_SAMPLES))
    chans = channels if channels is not None else default_channels(scene, signals)
    sig = {}
    for c in chans:
        if c not in signals:
            continue
        x = np.asarray(signals[c], dtype=float)
        sig[c] = decimate(x, fs, fs / d, "fir") if d > 1 and len(x) > 1 else x[::d].copy()
    t_d = time[::d].copy()
    fr = freqs_of(summary)
    spectra: dict[str, dict[str, float]] = {}
    m = time >= settle
    if fr.get("f_GMF", 0) > 0:
        ex = spectrum_frequencies(fr, fs)
        for c in chans:
            if c in signals and int(m.sum()) > 16:
                try:
                    spectra[c] = spectrum_levels(np.asarray(signals[c])[m], fs, fr, ex)
                except ValueError:          # too short for the spectrum's low-pass
                    pass
    return Entry(name=scene.name, scene=json.loads(scene.to_json()), summary=summary,
                 metrics=summary_metrics(summary), time=t_d, signals=sig,
                 units={c: (units or {}).get(c, "") for c in sig}, spectra=spectra, decimation=d,
                 sample_rate_Hz=fs, settle_s=settle, scene_toml=scene.to_toml())


# --------------------------------------------------------------------------------------------------
# File I/O
# --------------------------------------------------------------------------------------------------


def write_baseline(path: str | Path, entries: list[Entry], source: str | Path | None = None,
                   replace: bool = False) -> Path:
    """Write (or update: cases of the same name are replaced, others kept) a baseline file.
    ``replace``: start a new file."""
    import h5py


    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ver = versions()
    mode = "w" if replace or not path.is_file() else "a"
    with h5py.File(path, mode) as f:
        f.attrs["format"] = FORMAT
        f.attrs["created"] = now_iso()
        f.attrs["versions_json"] = json.dumps(ver)
        if source is not None:
            f.attrs["source"] = str(source)
        cases = f.require_group("cases")
        for e in entries:
            if e.name in cases:
                del cases[e.name]
            g = cases.create_group(e.name)
            g.attrs["scene_json"] = json.dumps(jsonable(e.scene))
            g.attrs["scene_toml"] = e.scene_toml
            g.attrs["summary_json"] = json.dumps(jsonable(e.summary))
            g.attrs["metrics_json"] = json.dumps(jsonable(e.metrics))
            g.attrs["status"] = str(e.summary.get("status", "ok"))
            g.attrs["decimation"] = int(e.decimation)
            g.attrs["sample_rate_Hz"] = float(e.sample_rate_Hz)
            g.attrs["settle_s"] = float(e.settle_s)
            g.attrs["created"] = now_iso()
            g.attrs["versions_json"] = json.dumps(ver)
            g.create_dataset("time", data=e.time)
            gs = g.create_group("signals")
            for c, x in e.signals.items():
                ds = gs.create_dataset(c, data=np.asarray(x, dtype="float64"), compression="gzip",
                                       compression_opts=4, shuffle=True)
                ds.attrs["unit"] = e.units.get(c, "")
            gp = g.create_group("spectra")
            for c, lv in e.spectra.items():
                ds = gp.create_dataset(c, data=np.array([lv[k] for k in lv], dtype="float64"))
                ds.attrs["frequencies"] = json.dumps(list(lv))
    return path


def read_baseline(path: str | Path) -> dict:
    """{"attrs": {...}, "versions": {...}, "cases": {name: Entry}}. A file that is not a readable baseline
    raises ValueError naming it (whatever h5py or the JSON reader met)."""
    path = Path(path)
    try:
        return _read_baseline(path)
    except ValueError as exc:
        if str(path) in str(exc):
            raise
        raise ValueError(f"{path}: not a readable baseline file ({exc})") from None
    except (OSError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a readable baseline file ({type(exc).__name__}: {exc})") from None


def _read_baseline(path: Path) -> dict:
    import h5py

    with h5py.File(path, "r") as f:
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
        if attrs.get("format") != FORMAT:
            raise ValueError(f"{path}: not a baseline file (format {attrs.get('format')!r}, expected {FORMAT!r})")
        cases = {}
        for name, g in f.get("cases", {}).items():
            a = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in g.attrs.items()}
            sig = {c: d[()] for c, d in g["signals"].items()}
            units = {c: str(d.attrs.get("unit", "")) for c, d in g["signals"].items()}
            spectra = {}
            for c, d in g["spectra"].items():
                ex = json.loads(d.attrs["frequencies"])
                spectra[c] = dict(zip(ex, (float(v) for v in d[()])))
            cases[name] = Entry(name=name, scene=json.loads(a["scene_json"]), summary=json.loads(a["summary_json"]),
                                metrics=json.loads(a["metrics_json"]), time=g["time"][()], signals=sig, units=units,
                                spectra=spectra, decimation=int(a["decimation"]),
                                sample_rate_Hz=float(a["sample_rate_Hz"]), settle_s=float(a["settle_s"]),
                                versions=json.loads(a.get("versions_json", "{}")), scene_toml=a.get("scene_toml", ""))
    return {"attrs": attrs, "versions": json.loads(attrs.get("versions_json", "{}")), "cases": cases}


# --------------------------------------------------------------------------------------------------
# Comparison
# --------------------------------------------------------------------------------------------------


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flat(v, key + "."))
        else:
            out[key] = v
    return out


def scene_changes(base: Entry, scene) -> list[str]:
    """The resolved scene keys that differ between the baseline and this scene: 'key: old -> new'."""
    old = _flat(base.scene.get("scene", {}))
    new = _flat(scene.to_dict())
    out = []
    for k in sorted(set(old) | set(new)):
        if k == "scenario.name":
            continue
        if old.get(k) != new.get(k):
            out.append(f"{k}: {_fmt(old.get(k)) if k in old else '(absent)'} -> {_fmt(new.get(k)) if k in new else '(absent)'}")
    return out


def version_changes(base: Entry) -> list[str]:
    now = versions()
    return [f"{k}: {base.versions.get(k)} -> {now.get(k)}" for k in sorted(set(base.versions) | set(now))
            if k != "platform" and base.versions.get(k) != now.get(k)]


def _rel_text(d: float, b: float) -> str:
    return f"{d:+.4g}" + (f" ({100 * d / abs(b):+.3g} %)" if b else "")


def compare(base: Entry, cur: Entry, options: CheckOptions | None = None) -> list[Outcome]:
    """Outcomes of the current run's compact reference against the baseline's, one per metric, signal
    and spectral level (source "baseline")."""
    o = options or CheckOptions()
    name = cur.name
    out: list[Outcome] = []
    # metrics
    for k, b in base.metrics.items():
        a = cur.metrics.get(k)
        if isinstance(b, str) or isinstance(a, str) or isinstance(b, bool):
            out.append(Outcome(name, k, "baseline", a == b, _fmt(b), a, "exact"))
            continue
        if b is None:
            continue
        tol = o.baseline_rel * abs(b)
        tol_txt = f"rel {_fmt(o.baseline_rel)}"
        if k == "energy_residual":
            tol = max(tol, ENERGY_ABS)
            tol_txt += f" or abs {_fmt(ENERGY_ABS)}"
        if a is None:
            out.append(Outcome(name, k, "baseline", False, _fmt(float(b)), None, tol_txt, note="missing in this run"))
            continue
        d = float(a) - float(b)
        ok = math.isfinite(float(a)) and abs(d) <= tol * (1 + 1e-12)
        out.append(Outcome(name, k, "baseline", ok, _fmt(float(b)), float(a), tol_txt, _rel_text(d, float(b)),
                           channel=k.split(".")[1] if k.startswith(("torque.", "channels.")) else None))
    # signals, on the common samples after the settling time
    for c, xb in base.signals.items():
        key = f"signal.{c}"
        if c not in cur.signals:
            out.append(Outcome(name, key, "baseline", False, "the baseline signal", None,
                               f"rel {_fmt(o.baseline_signal_rel)}", note="not in this run", channel=c))
            continue
        tb = base.time
        lo = max(base.settle_s, cur.settle_s)
        hi = min(tb[-1] if len(tb) else 0.0, cur.time[-1] if len(cur.time) else 0.0)
        m = (tb >= lo) & (tb <= hi + 1e-12)
        if m.sum() < 2:
            out.append(Outcome(name, key, "baseline", False, "the baseline signal", None,
                               f"rel {_fmt(o.baseline_signal_rel)}", note="no common samples after settling",
                               channel=c))
            continue
        xa = np.interp(tb[m], cur.time, cur.signals[c])
        ref = float(np.sqrt(np.mean(np.square(xb[m]))))
        diff = float(np.sqrt(np.mean(np.square(xa - xb[m]))))
        r = diff / ref if ref > 0 else (0.0 if diff == 0 else math.inf)
        out.append(Outcome(name, key, "baseline", bool(r <= o.baseline_signal_rel), "RMS difference 0",
                           r, f"rel {_fmt(o.baseline_signal_rel)}",
                           f"RMS diff {diff:.4g} {base.units.get(c, '')} of RMS {ref:.4g}".rstrip(), channel=c))
    # spectral levels at the characteristic frequencies
    for c, lv in base.spectra.items():
        cur_lv = cur.spectra.get(c, {})
        top = max([v for v in lv.values() if np.isfinite(v)] + [v for v in cur_lv.values() if np.isfinite(v)] + [0.0])
        floor = top * 10 ** (-SPECTRUM_FLOOR_DB / 20.0)
        for ex, b in lv.items():
            key = f"spectrum.{c}@{ex}.dB"
            a = cur_lv.get(ex)
            if a is None:
                out.append(Outcome(name, key, "baseline", False, f"{20 * math.log10(max(b, 1e-300)):.2f} dB", None,
                                   f"{_fmt(o.baseline_dB)} dB", note="not in this run", channel=c))
                continue
            if max(a, b) < floor or top <= 0:
                continue
            la, lb = 20 * math.log10(max(a, 1e-300)), 20 * math.log10(max(b, 1e-300))
            out.append(Outcome(name, key, "baseline", bool(abs(la - lb) <= o.baseline_dB), f"{lb:.2f}", la,
                               f"±{_fmt(o.baseline_dB)} dB", f"{la - lb:+.2f} dB", channel=c))
    return out


# --------------------------------------------------------------------------------------------------
# Plot of a failure
# --------------------------------------------------------------------------------------------------


def time_overlap(a: np.ndarray, b: np.ndarray) -> tuple[float, float] | None:
    """The time span two time bases share, (start, end) [s], or None if they share none."""
    if not len(a) or not len(b):
        return None
    lo, hi = max(float(a[0]), float(b[0])), min(float(a[-1]), float(b[-1]))
    return (lo, hi) if hi >= lo else None


def _span(t: np.ndarray) -> str:
    fs = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else float("nan")
    return f"{t[0]:.4g}–{t[-1]:.4g} s" + (f" at {fs:.5g} Hz" if math.isfinite(fs) else "") if len(t) else "no samples"


def difference_on_overlap(cur_t: np.ndarray, cur_x: np.ndarray, base_t: np.ndarray, base_x: np.ndarray):
    """(t, this run − baseline, note) on the baseline's samples inside the time both runs cover: nothing is
    extrapolated (``np.interp`` would hold this run's last value past its end). ``note`` says how the time
    bases differ, "" when they are the same."""
    cur_t, base_t = np.asarray(cur_t, dtype=float), np.asarray(base_t, dtype=float)
    same = len(cur_t) == len(base_t) and np.allclose(cur_t, base_t, rtol=0, atol=1e-9)
    if same:
        return base_t, np.asarray(cur_x) - np.asarray(base_x), ""
    note = f"time bases differ: this run {_span(cur_t)}, baseline {_span(base_t)}"
    span = time_overlap(cur_t, base_t)
    if span is None:
        return base_t[:0], base_t[:0], note + "; no common time"
    m = (base_t >= span[0] - 1e-12) & (base_t <= span[1] + 1e-12)
    xa = np.interp(base_t[m], cur_t, cur_x)
    return base_t[m], xa - np.asarray(base_x)[m], note + f"; difference over the common {span[0]:.4g}–{span[1]:.4g} s only"


def against_baseline_figure(cur: Entry, base: Entry | None, channels: list[str], title: str = "",
                            expectations: dict | None = None):
    """Each channel of this run against its baseline (left) and their difference (right) over the time both
    cover (:func:`difference_on_overlap`; the panel says so when the time bases differ); without a
    baseline, the channel alone with the expected values/ranges of its failed expectations
    (``expectations``: channel -> [(label, lo, hi)]) drawn as lines/bands. Returns the Figure."""
    channels = [c for c in channels if c in cur.signals] or list(cur.signals)[:2]
    n = max(1, len(channels))
    fig = new_figure(13, 2.6 * n + 0.5 + title_margin(title))
    axes = fig.subplots(n, 1 if base is None else 2, squeeze=False)
    place_axes(fig, axes, left=0.9, top=title_margin(title), wgap=0.9, hgap=0.85)
    for i, c in enumerate(channels):
        ax = axes[i, 0]
        x = cur.signals.get(c)
        if x is not None:
            ax.plot(cur.time, x, lw=0.8, color="C0", label="this run")
        if base is not None and c in base.signals:
            ax.plot(base.time, base.signals[c], lw=0.8, color="C3", ls="--", label="baseline")
            bx = axes[i, 1]
            note = ""
            if x is not None:
                td, d, note = difference_on_overlap(cur.time, x, base.time, base.signals[c])
                bx.plot(td, d, lw=0.8, color="k")
            if len(base.time):
                bx.set_xlim(float(base.time[0]), float(base.time[-1]))
            bx.axvspan(0, base.settle_s, color="0.9")
            bx.set_title("this run − baseline", fontsize=9)
            if note:
                bx.text(0.01, 0.97, textwrap.fill(note, 70), transform=bx.transAxes, va="top", fontsize=7,
                        color="C3", bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})
            bx.set_xlabel("time [s]")
            bx.set_ylabel(f"Δ {c} [{cur.units.get(c, '')}]", fontsize=8)
            bx.grid(alpha=0.3)
        for label, lo, hi in (expectations or {}).get(c, []):
            if lo is not None and hi is not None and lo != hi:
                ax.axhspan(lo, hi, color="C2", alpha=0.15, label=label)
            for v in {lo, hi} - {None}:
                ax.axhline(v, color="C2", lw=0.8, ls=":", label=None if (lo is not None and hi is not None
                                                                          and lo != hi) else label)
        ax.axvspan(0, cur.settle_s, color="0.92", label="settling")
        ax.set_ylabel(f"{c} [{cur.units.get(c, '')}]")
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    suptitle(fig, title)
    return fig


def plot_against_baseline(path: str | Path, cur: Entry, base: Entry | None, channels: list[str],
                          title: str = "", expectations: dict | None = None) -> Path:
    """:func:`against_baseline_figure` written to ``path`` (PNG)."""
    return save_figure(against_baseline_figure(cur, base, channels, title, expectations), path)


__all__ = ["FORMAT", "SUFFIX", "Entry", "make_entry", "write_baseline", "read_baseline", "compare",
           "baseline_path", "scene_changes", "version_changes", "summary_metrics", "spectrum_frequencies",
           "plot_against_baseline", "against_baseline_figure", "difference_on_overlap", "time_overlap", "versions"]
