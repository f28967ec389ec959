"""Result files of a run: signals (HDF5), summary.json, plots (PNG), Aalto-layout CSV.

HDF5 layout (``signals.h5``), format ``drivetrain-run/1``::

    /                 attrs: format, name, scene_json (the full resolved scene + overrides), scene_toml,
                             system_json (the SystemSpec that ran), summary_json, backend, created,
                             drivetrain_version, sample_rate_Hz, comm_step_s, settle_s, duration_s
    /time             [s] output sample times (t = m / sample_rate_Hz)
    /signals/<name>   one dataset per channel; attrs unit, source ("component.variable"), kind
                      ("sensor" or "variable"), description

Read back with :func:`read_hdf5`.
"""
from __future__ import annotations

import dataclasses
import datetime
import json
import math
import os
import textwrap
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "drivetrain-run/1"
AALTO_COLUMNS = ("time", "enc1", "enc2", "enc3", "enc4", "enc5", "Torq1", "Torq2")
AALTO_MAP = {"enc1": "enc1", "enc2": "enc2", "enc3": "enc3", "enc4": "enc4", "enc5": "enc5",
             "Torq1": "drive_shaft_torque", "Torq2": "propeller_shaft_torque"}


def jsonable(obj: Any) -> Any:
    """Plain JSON data: numpy scalars/arrays to Python, non-finite floats to None, paths to str."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    # numpy scalars before array-likes: np.float64 has __array__ and shape too, and is a number, not a profile
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if hasattr(obj, "__array__") and hasattr(obj, "shape"):
        # an input profile generated when read (rig.background.GeneratedProfile): its description, not its
        # samples (the scene, stored beside it, generates it again)
        return {"generated_profile": repr(obj)}
    if isinstance(obj, Path):
        return str(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return jsonable(dataclasses.asdict(obj))
    return obj


def spec_to_dict(spec) -> dict:
    return jsonable(dataclasses.asdict(spec))


def write_hdf5(path: Path, time: np.ndarray, channels: dict[str, np.ndarray], meta: dict[str, dict],
               attrs: dict[str, Any], dtype: str = "float64") -> Path:
    """channels: name -> samples; meta: name -> {unit, source, kind, description}."""
    import h5py

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".h5.part")
    with h5py.File(tmp, "w") as f:
        f.attrs["format"] = FORMAT
        for k, v in attrs.items():
            if v is None:
                continue
            f.attrs[k] = v if isinstance(v, (str, int, float, np.number)) else json.dumps(jsonable(v))
        dt = f.create_dataset("time", data=np.asarray(time, dtype="float64"))
        dt.attrs["unit"] = "s"
        g = f.create_group("signals")
        n = len(time)
        for name, x in channels.items():
            x = np.asarray(x)
            kw = {}
            if n > 4096:
                kw = dict(chunks=(min(n, 65536),), compression="gzip", compression_opts=4, shuffle=True)
            d = g.create_dataset(name, data=x.astype(dtype), **kw)
            for k, v in meta.get(name, {}).items():
                d.attrs[k] = "" if v is None else v
    tmp.replace(path)
    return path


def read_hdf5(path: Path | str) -> dict:
    """{"time", "signals": {name: array}, "units": {name: unit}, "attrs": {...}, "scene": dict}."""
    import h5py

    with h5py.File(path, "r") as f:
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
        out = {"time": f["time"][()], "signals": {}, "units": {}, "meta": {}, "attrs": attrs}
        for name, d in f["signals"].items():
            out["signals"][name] = d[()]
            out["units"][name] = d.attrs.get("unit", "")
            out["meta"][name] = dict(d.attrs)
    if "scene_json" in attrs:
        out["scene"] = json.loads(attrs["scene_json"])
    return out


def write_summary(path: Path, summary: dict) -> Path:
    """summary.json, written whole or not at all (a temporary file renamed: a kill never tears it)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}")
    tmp.write_text(json.dumps(jsonable(summary), indent=2, allow_nan=False) + "\n")
    os.replace(tmp, path)
    return path


def write_aalto_csv(path: Path, time: np.ndarray, sensors: dict[str, np.ndarray]) -> Path:
    """The sensors in the Aalto Gear Fault Dataset column layout: time, enc1..enc5, Torq1, Torq2
    (s, rad, N·m). Channels that were not simulated are empty columns."""
    path = Path(path)
    cols = [np.asarray(time, dtype=float)]
    present = [True]
    for c in AALTO_COLUMNS[1:]:
        x = sensors.get(AALTO_MAP[c])
        cols.append(np.asarray(x, dtype=float) if x is not None else None)
        present.append(x is not None)
    with open(path, "w") as fh:
        fh.write(",".join(AALTO_COLUMNS) + "\n")
        arr = np.column_stack([c for c in cols if c is not None])
        rows = np.char.mod("%.9g", arr)
        for r in rows:
            it = iter(r)
            fh.write(",".join(next(it) if p else "" for p in present) + "\n")
    return path


# --------------------------------------------------------------------------------------------------
# Plots
# --------------------------------------------------------------------------------------------------


def _mpl():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def check_output_dir(out: Path, expected_bytes: int = 0, create: bool = True) -> None:
    """Refuse an output directory that cannot take the results before any work, not after it: an existing
    file, /dev/null, a dangling symlink, a read-only place, a name too long all fail here, named; its file
    system must have ``expected_bytes`` free (twice, for the temporary files of atomic writes).
    ``create``: make it (parents too) and write and remove a probe file; else only look (nothing is
    written: the place it would be made in must be a writable directory)."""
    import shutil

    from drivetrain.cosim import ConfigurationError

    out = Path(out)

    def refuse(why):
        return ConfigurationError(f"output directory {str(out)[:300]}: not writable ({why})")

    try:
        if create:
            out.mkdir(parents=True, exist_ok=True)
            if not out.is_dir():
                raise NotADirectoryError(20, "not a directory")
            probe = out / f".write-test-{os.getpid()}"
            probe.write_text("")
            probe.unlink()
            where = out
        else:
            if out.is_symlink() and not out.exists():
                raise refuse("a symbolic link to nothing")
            if any(len(part.encode()) > 255 for part in out.parts):
                raise refuse("File name too long")
            where = out
            while not where.exists():
                where = where.parent
            if not where.is_dir():
                raise refuse(f"{where} is not a directory")
            if not os.access(where, os.W_OK | os.X_OK):
                raise refuse(f"{where} is not writable")
        free = shutil.disk_usage(where).free
    except OSError as exc:
        raise refuse(exc.strerror or exc) from None
    if expected_bytes and free < 2 * expected_bytes:
        raise ConfigurationError(f"output directory {out}: {free / 1e6:.0f} MB free, the run writes about "
                                 f"{expected_bytes / 1e6:.0f} MB (twice that is needed while files are replaced)")


#: what a run writes into its output directory (plots: *.png)
RUN_FILES = ("signals.h5", "summary.json", "sensors.csv")


def clear_run_files(out: Path, extra: tuple[str, ...] = ()) -> None:
    """Remove what an earlier run left in ``out``: :data:`RUN_FILES`, its plots and ``extra`` names (only our
    own file names)."""
    for f in (*RUN_FILES, *extra):
        (out / f).unlink(missing_ok=True)
    for png in out.glob("*.png"):
        png.unlink()


def mark_running(out: Path, name: str) -> None:
    """Clear what an earlier run left in ``out`` and say that this run has started: a run that never finishes
    (killed) leaves "running", never an earlier run's "ok" beside files of two runs."""
    out.mkdir(parents=True, exist_ok=True)
    clear_run_files(out)
    write_summary(out / "summary.json", {"name": name, "status": "running",
                                         "started": datetime.datetime.now().isoformat(timespec="seconds")})


def mark_failed(out: Path, name: str, exc: BaseException) -> None:
    """A run that ended by an exception before it wrote its results: summary.json says ``failed`` (or
    ``interrupted``) with the cause, never "running" for good. A summary the run wrote itself (its completed
    part, ``failed``) is kept."""
    try:
        cur = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        cur = None
    if isinstance(cur, dict) and cur.get("status") not in (None, "running"):
        return
    interrupted = isinstance(exc, KeyboardInterrupt)
    write_summary(out / "summary.json", {
        "name": name, "status": "interrupted" if interrupted else "failed",
        "started": (cur or {}).get("started"), "ended": datetime.datetime.now().isoformat(timespec="seconds"),
        "failure": {"cause": f"{type(exc).__name__}: {str(exc)[:2000]}", "time_s": None,
                    "where": "before any result was written"}})


#: resolution of the plots (PNG)
PLOT_DPI = 110


def _finish(plt, fig, path, title: str) -> Path:
    """Title, layout, write the PNG and free the figure."""
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=PLOT_DPI)
    plt.close(fig)
    return Path(path)


def new_figure(width_in: float, height_in: float):
    """A matplotlib Figure outside pyplot's global state (nothing to close; pyplot is not imported)."""
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=PLOT_DPI)


def place_axes(fig, axes, *, left: float, right: float = 0.25, top: float, bottom: float = 0.5,
               wgap: float = 0.7, hgap: float = 0.8) -> None:
    """Margins and gaps of a grid of Axes in inches, set once: a fixed layout instead of ``tight_layout``,
    which draws the whole figure once more only to measure it (half the time a plot took)."""
    W, H = fig.get_size_inches()
    nr, nc = np.shape(axes)
    aw = (W - left - right - (nc - 1) * wgap) / nc
    ah = (H - top - bottom - (nr - 1) * hgap) / nr
    fig.subplots_adjust(left=left / W, right=1 - right / W, top=1 - top / H, bottom=bottom / H,
                        wspace=wgap / aw if nc > 1 else 0.2, hspace=hgap / ah if nr > 1 else 0.2)


def title_margin(title: str) -> float:
    """The top margin [in] a figure title of this many lines needs (9.5 pt)."""
    return 0.3 + 0.17 * (title.count("\n") + 1 if title else 0)


def suptitle(fig, title: str) -> None:
    """The figure's title at its top (the axes leave :func:`title_margin` for it)."""
    if title:
        fig.suptitle(title, fontsize=9.5, y=1 - 0.08 / fig.get_figheight(), va="top")


def save_figure(fig, path) -> Path:
    """Write the PNG (the layout is the figure's own: :func:`place_axes`)."""
    fig.savefig(path, dpi=PLOT_DPI)
    return Path(path)


def pixel_columns(ax) -> int:
    """How many pixel columns the Axes ``ax`` spans in the saved PNG."""
    fig = ax.figure
    return max(16, int(ax.get_position().width * fig.get_figwidth() * PLOT_DPI))


def envelope(x: np.ndarray, y: np.ndarray, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """The samples a plot of ``y`` over ``columns`` pixel columns needs: per column of consecutive samples its
    smallest and largest value, in their order (a min/max envelope: a single-sample peak is kept, at most
    2 · columns points are drawn). NaN samples are skipped; a column of NaN stays a gap. Short traces as
    they are."""
    x, y = np.asarray(x), np.asarray(y, dtype=float)
    n = len(y)
    if n <= 4 * columns:
        return x, y
    k = -(-n // columns)
    rows = -(-n // k)
    yy = np.full(rows * k, np.nan)
    yy[:n] = y
    yy = yy.reshape(rows, k)
    nan = np.isnan(yy)
    i_lo = np.where(nan, np.inf, yy).argmin(axis=1)
    i_hi = np.where(nan, -np.inf, yy).argmax(axis=1)
    base = np.arange(rows) * k
    idx = np.column_stack([np.minimum(i_lo, i_hi), np.maximum(i_lo, i_hi)]) + base[:, None]
    idx = idx.ravel()
    idx = idx[idx < n]
    return x[idx], y[idx]


def _fault_text(health: str, faults) -> str:
    from gearcontact_fmu.fault_specs import health_faults

    found = health_faults(health, faults or ())
    words = [f"{f['kind']} {f['member']} tooth {f['tooth']}" + (f" {f['flank']}" if f.get("flank") else "")
             for f in found]
    return f"{health}: " + "; ".join(words) if words else health


def load_text(load_Nm: float | None, profile: bool = False, ratio: float | None = None) -> str:
    """A load as the rig has it: the load motor's setting and the torque it makes on the propeller shaft through
    its gear (``ratio``; default the rig's 1:8 planetary, rig.data.PG_RATIO; losses aside): "load motor 1.31 N·m
    (propeller shaft ≈ 10.5 N·m)"."""
    from drivetrain.rig.data import PG_RATIO

    if load_Nm is None:
        return "load motor (profile)"
    tail = ", profile end" if profile else ""
    r = PG_RATIO if ratio is None else float(ratio)
    return f"load motor {float(load_Nm):g} N·m (propeller shaft ≈ {r * float(load_Nm):.3g} N·m{tail})"


def run_title(scene, what: str, failed_at_s: float | None = None) -> str:
    """A run's plot title: the scene and what the plot shows, then the operating point (final speed, load),
    the gear's health and faults and the active effects by their scene keys (switches that are on; the
    settings of the others that act)."""
    from drivetrain.scene.schema import setting_acts

    d = scene.to_dict()
    op = scene.operating_point
    speed = f"{op.final_speed_rpm:g} rpm" + (" (profile)" if op.speed_profile_rpm else "")
    r = scene.drivetrain.load_gear_ratio
    load = (load_text(op.load_profile_Nm[-1][1], profile=True, ratio=r) if op.load_profile_Nm
            else load_text(op.load_torque_Nm, ratio=r))
    g = scene.gear
    health = _fault_text(g.health, g.faults)
    if g.health == "mesh":
        health += ": " + ", ".join(Path(str(m)).name for m in (g.pinion_mesh, g.wheel_mesh) if m)
    effects = []
    for key, value in (d.get("effects") or {}).items():
        if not setting_acts("effects", key, d) or value is False:
            continue
        effects.append(key if value is True else f"{key}={value}")
    head = f"{scene.name}: {what}"
    if failed_at_s is not None:
        head += f" (FAILED at t = {failed_at_s:.6g} s)"
    effects_line = textwrap.fill(", ".join(effects) or "none", 120, initial_indent="effects: ", break_long_words=False,
                                 break_on_hyphens=False)
    return f"{head}\n{speed}, {load} · {health}\n{effects_line}"


def torques_figure(time: np.ndarray, torques: dict[str, np.ndarray], settle_s: float, cf: dict, title: str = ""):
    """Torque waveforms: whole run (settling shaded; a min/max envelope per pixel column, :func:`envelope`) and
    a zoom on the last two middle-shaft revolutions (every sample). Returns the Figure."""
    n = max(1, len(torques))
    fig = new_figure(13, 2.6 * n + 0.5 + title_margin(title))
    axes = fig.subplots(n, 2, squeeze=False, gridspec_kw={"width_ratios": [1.4, 1]})
    place_axes(fig, axes, left=0.85, top=title_margin(title), wgap=0.8, hgap=0.85)
    t = np.asarray(time)
    T = t[-1] if len(t) else 0.0
    zoom = min(2.0 / cf["f_MSH"] if cf.get("f_MSH", 0) > 0 else 0.25, max(T - settle_s, T * 0.5))
    for i, (name, x) in enumerate(torques.items()):
        x = np.asarray(x)
        ax = axes[i, 0]
        ax.plot(*envelope(t, x, pixel_columns(ax)), lw=0.6)
        ax.axvspan(0, settle_s, color="0.9", label="settling (excluded)")
        m = t >= settle_s
        if m.any():
            mean = float(np.mean(x[m]))
            ax.axhline(mean, color="C3", lw=0.8, ls="--", label=f"mean {mean:.4g} N·m")
        ax.set_ylabel(f"{name} [N·m]")
        ax.set_xlabel("time [s]")
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
        ax = axes[i, 1]
        mz = t >= T - zoom
        ax.plot(t[mz], x[mz], lw=0.8)
        ax.set_title(f"last {zoom:.3g} s (2 middle-shaft revolutions)" if cf.get("f_MSH") else f"last {zoom:.3g} s",
                     fontsize=9)
        ax.set_xlabel("time [s]")
        ax.grid(alpha=0.3)
    suptitle(fig, title)
    return fig


def plot_torques(path: Path, time: np.ndarray, torques: dict[str, np.ndarray], settle_s: float, cf: dict,
                 title: str = "") -> Path:
    """:func:`torques_figure` written to ``path`` (PNG)."""
    return save_figure(torques_figure(time, torques, settle_s, cf, title), path)


#: the shaft orders the shaft-order panel marks: k = 1..4 of f_PSH and f_MSH, 1..3 of f_DSH
SHAFT_ORDERS = (("f_PSH", "C4", 4), ("f_MSH", "C1", 4), ("f_DSH", "C0", 3))


def shaft_order_band(cf: dict, df: float) -> tuple[float, float]:
    """The shaft-order panel's frequency range [Hz] (a log axis): from a quarter of f_PSH (not below one
    frequency bin) to 3.5 drive-shaft orders (at least ten bins), below the mesh frequency."""
    lo = max(df, 0.25 * cf["f_PSH"])
    return lo, max(min(max(3.5 * cf["f_DSH"], 10.0 * df), 0.8 * cf["f_GMF"]), 2.0 * lo)


def _mark(ax, freqs, lo, hi, label, **style):
    first = True
    for f in freqs:
        if lo <= f <= hi:
            ax.axvline(f, label=label if first else None, **style)
            first = False


def _log_limits(ax, A: np.ndarray) -> None:
    """y-limits of a log axis from the data drawn (its smallest and largest positive value, a margin each
    side; down to the double-precision resolution of the largest, 1e-16 of it)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullLocator

    ax.yaxis.set_major_locator(LogLocator(numticks=7))
    ax.yaxis.set_minor_locator(NullLocator())   # 8 minor ticks a decade over 15 decades: most of a plot's time
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.0e}"))      # 1e-12: plain text, no mathtext
    pos = A[np.isfinite(A) & (A > 0)]
    if not len(pos):
        return
    top = float(pos.max())
    ax.set_ylim(max(float(pos.min()), top * 1e-16) / 3.0, top * 3.0)


def spectra_figure(spectra: dict[str, tuple[np.ndarray, np.ndarray]], cf: dict, title: str = "",
                   n_sidebands: int = 3, lowpass_Hz: float | None = None):
    """Amplitude spectra as :func:`drivetrain.rig.signals.amplitude_spectrum` computes them (the axis says the
    convention), per channel three panels: 0 to 5.5 × f_GMF (the low-pass edge marked; a min/max envelope per
    pixel column), the shaft orders on a log frequency axis (k·f_PSH, k·f_MSH, k·f_DSH: :data:`SHAFT_ORDERS`)
    and the sidebands f_GMF ± k·f_MSH. Nothing is
    clipped: bins that are exactly zero are left out (a log axis has no zero), the y-limits follow the
    data. Returns the Figure."""
    from drivetrain.rig.signals import AMPLITUDE_CONVENTION, SPECTRUM_LOWPASS_GMF, spectrum_lowpass_Hz

    n = max(1, len(spectra))
    fig = new_figure(17, 2.9 * n + 0.5 + title_margin(title))
    axes = fig.subplots(n, 3, squeeze=False, gridspec_kw={"width_ratios": [1.5, 1, 1]})
    place_axes(fig, axes, left=1.15, top=title_margin(title), wgap=0.65, hgap=0.85)
    gmf, fm = cf["f_GMF"], cf["f_MSH"]
    lowpass_Hz = spectrum_lowpass_Hz(gmf) if lowpass_Hz is None else lowpass_Hz
    for i, (name, (f, A)) in enumerate(spectra.items()):
        f = np.asarray(f, dtype=float)
        A = np.where(np.asarray(A, dtype=float) > 0, A, np.nan)     # a zero has no logarithm: left out, not raised
        df = f[1] - f[0] if len(f) > 1 else 1.0
        bands = ((0.0, 5.5 * gmf), shaft_order_band(cf, df),
                 (gmf - (n_sidebands + 1.5) * fm, gmf + (n_sidebands + 1.5) * fm))
        for j, (lo, hi) in enumerate(bands):
            ax = axes[i, j]
            lo = max(lo, 0.0)
            m = (f >= lo) & (f <= hi)
            fx, Ax = (envelope(f[m], A[m], pixel_columns(ax)) if j == 0 else (f[m], A[m]))
            ax.plot(fx, Ax, lw=0.6, color="k")
            ax.set_yscale("log")
            if j == 1:
                from matplotlib.ticker import FuncFormatter

                ax.set_xscale("log")
                ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
            _log_limits(ax, A[m])
            _mark(ax, cf["harmonics"], lo, hi, "k·f_GMF", color="C3", lw=0.8, ls="--", alpha=0.8)
            sb = [s[e] for s in cf["sidebands"][:n_sidebands] for e in ("lower", "upper")]
            _mark(ax, sb, lo, hi, "f_GMF ± k·f_MSH", color="C2", lw=0.7, ls=":")
            if j == 1:
                for key, col, k_max in SHAFT_ORDERS:
                    _mark(ax, [k * cf[key] for k in range(1, k_max + 1)], lo, hi,
                          f"k·{key}, k ≤ {k_max} ({key} = {cf[key]:.3g} Hz)", color=col, lw=0.8, ls="-.", alpha=0.7)
            else:
                for key, col in (("f_DSH", "C0"), ("f_MSH", "C1"), ("f_PSH", "C4")):
                    _mark(ax, [cf[key]], lo, hi, f"{key} = {cf[key]:.3g} Hz", color=col, lw=0.8, ls="-.")
            if j == 0:
                _mark(ax, [lowpass_Hz], lo, hi, f"low-pass edge {lowpass_Hz:.4g} Hz", color="0.5", lw=1.0, ls="-")
            ax.set_xlim(lo, hi)
            ax.set_xlabel("frequency [Hz]")
            ax.grid(alpha=0.3)
            ax.set_title((f"Hann window, low-pass {SPECTRUM_LOWPASS_GMF:g} × f_GMF; " if j == 0 else "shaft orders; " if j == 1
                          else "around f_GMF: sidebands ± k·f_MSH; ") + f"f_GMF = {gmf:.4g} Hz, bin {df:.3g} Hz",
                         fontsize=8.5)
            if j == 0:
                ax.set_ylabel(f"{name} [N·m]\n" + textwrap.fill(AMPLITUDE_CONVENTION, 34, break_on_hyphens=False), fontsize=8)
            ax.legend(loc="upper right", fontsize=6.5)
    suptitle(fig, title)
    return fig


def plot_spectra(path: Path, spectra: dict[str, tuple[np.ndarray, np.ndarray]], cf: dict, title: str = "",
                 n_sidebands: int = 3) -> Path:
    """:func:`spectra_figure` written to ``path`` (PNG)."""
    return save_figure(spectra_figure(spectra, cf, title, n_sidebands=n_sidebands), path)


def now_iso() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
