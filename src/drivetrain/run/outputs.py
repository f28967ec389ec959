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
    if hasattr(obj, "__array__") and hasattr(obj, "shape"):
        # an input profile generated when read (rig.background.GeneratedProfile): its description, not its
        # samples (the scene, stored beside it, generates it again)
        return {"generated_profile": repr(obj)}
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
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


def _finish(plt, fig, path, title: str) -> Path:
    """Title, layout, write the PNG and free the figure."""
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_torques(path: Path, time: np.ndarray, torques: dict[str, np.ndarray], settle_s: float, cf: dict,
                 title: str = "") -> Path:
    """Torque waveforms: whole run (settling shaded) and a zoom on the last two middle-shaft revolutions."""
    plt = _mpl()
    n = max(1, len(torques))
    fig, axes = plt.subplots(n, 2, figsize=(13, 3.2 * n), squeeze=False,
                             gridspec_kw={"width_ratios": [1.4, 1]})
    t = np.asarray(time)
    T = t[-1] if len(t) else 0.0
    zoom = min(2.0 / cf["f_MSH"] if cf.get("f_MSH", 0) > 0 else 0.25, max(T - settle_s, T * 0.5))
    for i, (name, x) in enumerate(torques.items()):
        ax = axes[i, 0]
        ax.plot(t, x, lw=0.6)
        ax.axvspan(0, settle_s, color="0.9", label="settling (excluded)")
        m = t >= settle_s
        if m.any():
            ax.axhline(float(np.mean(x[m])), color="C3", lw=0.8, ls="--", label=f"mean {np.mean(x[m]):.4g} N·m")
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
    return _finish(plt, fig, path, title)


def plot_spectra(path: Path, spectra: dict[str, tuple[np.ndarray, np.ndarray]], cf: dict, title: str = "",
                 n_sidebands: int = 3) -> Path:
    """Amplitude spectra (Hann, low-pass 5 × GMF) with the characteristic frequencies and the
    sidebands f_GMF ± k·f_MSH marked."""
    plt = _mpl()
    n = max(1, len(spectra))
    fig, axes = plt.subplots(n, 2, figsize=(13, 3.4 * n), squeeze=False, gridspec_kw={"width_ratios": [1.5, 1]})
    gmf, fm = cf["f_GMF"], cf["f_MSH"]
    fmax = 5.5 * gmf
    for i, (name, (f, A)) in enumerate(spectra.items()):
        for j, (lo, hi) in enumerate(((0.0, fmax), (gmf - (n_sidebands + 1.5) * fm, gmf + (n_sidebands + 1.5) * fm))):
            ax = axes[i, j]
            m = (f >= max(lo, 0.0)) & (f <= hi)
            ax.semilogy(f[m], np.maximum(A[m], 1e-12), lw=0.6, color="k")
            first = True
            for k, h in enumerate(cf["harmonics"], start=1):
                if lo <= h <= hi:
                    ax.axvline(h, color="C3", lw=0.8, ls="--", alpha=0.8,
                               label="k·f_GMF" if first else None)
                    first = False
            first = True
            for sb in cf["sidebands"][:n_sidebands]:
                for fs_ in (sb["lower"], sb["upper"]):
                    if lo <= fs_ <= hi:
                        ax.axvline(fs_, color="C2", lw=0.7, ls=":", label="f_GMF ± k·f_MSH" if first else None)
                        first = False
            for key, col in (("f_DSH", "C0"), ("f_MSH", "C1"), ("f_PSH", "C4")):
                if lo <= cf[key] <= hi:
                    ax.axvline(cf[key], color=col, lw=0.8, ls="-.", label=f"{key} = {cf[key]:.3g} Hz")
            ax.set_xlim(max(lo, 0.0), hi)
            ax.set_xlabel("frequency [Hz]")
            ax.grid(alpha=0.3, which="both")
            if j == 0:
                ax.set_ylabel(f"{name} [N·m]")
                ax.set_title(f"Hann window, low-pass 5 × GMF; GMF = {gmf:.4g} Hz", fontsize=9)
            else:
                ax.set_title("around GMF: sidebands ± k·f_MSH", fontsize=9)
            ax.legend(loc="upper right", fontsize=7)
    return _finish(plt, fig, path, title)


def now_iso() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
