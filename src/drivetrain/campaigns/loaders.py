"""Reading an exported dataset back: :func:`load_dataset` (a DataFrame with its units) and :func:`windows`
(fixed-length arrays for deep learning, read run by run).

Every parquet file the project writes (``dataset.parquet``, ``features.parquet``) carries each column's unit
twice in its schema metadata: ``drivetrain.units`` (column -> unit, "1" dimensionless, "" text or switches)
and pandas' own ``attributes``, so ``pandas.read_parquet(path).attrs["units"]`` has them as
:func:`load_dataset`'s DataFrame does. ``dataset.h5`` keeps a ``unit`` attribute on every array.

:func:`windows` cuts each run's settled samples into windows of ``length`` samples (``hop`` apart) and yields
one :class:`Windows` per run: never more than one run in memory (a parquet dataset is written one row group per
run and read a row group at a time; an HDF5 dataset a run's group at a time). A PyTorch
``IterableDataset`` or a Keras generator wraps it without this package needing either (docs/SCENARIOS.md,
"Reading a dataset back").
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from drivetrain.errors import DatasetError
from drivetrain.rig.indicators import label_teeth

UNITS_KEY = "drivetrain.units"
LABELS_KEY = "drivetrain.labels"


def schema_metadata(units: dict, labels: list[str] | None = None) -> dict:
    """The schema metadata of a parquet file the project writes: the units under ``drivetrain.units`` and as
    pandas' ``df.attrs["units"]`` (so ``pandas.read_parquet`` restores them); ``labels``: the label columns."""
    import pandas as pd

    meta = {UNITS_KEY: json.dumps(units),
            "pandas": json.dumps({"index_columns": [], "column_indexes": [], "columns": [],
                                  "attributes": {"units": units}, "creator": {"library": "drivetrain"},
                                  "pandas_version": pd.__version__})}
    if labels is not None:
        meta[LABELS_KEY] = json.dumps(labels)
    return meta


def _find(path: Path | str) -> Path:
    p = Path(path)
    if p.is_dir():
        for name in ("dataset.parquet", "dataset.h5", "features.parquet"):
            if (p / name).is_file():
                return p / name
        raise DatasetError(f"{p}: no dataset.parquet, dataset.h5 or features.parquet in it (write one with "
                           "`drivetrain dataset` or `drivetrain features`)")
    if not p.is_file():
        raise DatasetError(f"{p}: no such file")
    return p


def units_of(path: Path | str) -> dict:
    """The units a parquet file of the project carries (``drivetrain.units``), {} if it has none."""
    import pyarrow.parquet as pq

    meta = pq.read_schema(_find(path)).metadata or {}
    return json.loads(meta.get(UNITS_KEY.encode(), b"{}"))


def load_dataset(path: Path | str, columns: list[str] | None = None, settled_only: bool = False):
    """An exported dataset as a pandas DataFrame with every column's unit in ``df.attrs["units"]``: a
    ``dataset.parquet`` or ``features.parquet`` (or the directory holding one), or a ``dataset.h5`` (the same
    long layout: run, time_s, settled, channels, labels). ``columns``: only these (``run`` always);
    ``settled_only``: the samples after each run's ``time.settle_s``."""
    p = _find(path)
    if p.suffix in (".h5", ".hdf5"):
        return _load_hdf5(p, columns, settled_only)
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(p, columns=None if columns is None else _with_run(columns, pq.read_schema(p).names))
    except Exception as exc:  # noqa: BLE001 - name the file, whatever pyarrow says
        raise DatasetError(f"{p}: unreadable as parquet ({type(exc).__name__}: {exc})") from None
    units = json.loads((table.schema.metadata or {}).get(UNITS_KEY.encode(), b"{}"))
    df = table.to_pandas()
    if "run" in df and hasattr(df["run"], "cat"):
        df["run"] = df["run"].astype(str)
    if settled_only and "settled" in df:
        df = df[df["settled"]].reset_index(drop=True)
    df.attrs["units"] = {c: units.get(c, "") for c in df.columns}
    return df


def _with_run(columns: list[str], names: list[str]) -> list[str]:
    missing = [c for c in columns if c not in names]
    if missing:
        raise DatasetError(f"no column {', '.join(map(repr, missing))} in the dataset (it has e.g. "
                           f"{', '.join(names[:8])}, ...)")
    return (["run"] if "run" in names and "run" not in columns else []) + list(columns)


def _load_hdf5(p: Path, columns, settled_only: bool):
    import pandas as pd

    parts, units = [], {}
    for run in _hdf5_runs(p, columns, settled_only):
        n = len(run.time)
        cols = {"run": [run.name] * n, "time_s": run.time, "settled": run.settled, **run.signals}
        cols.update({k: [v] * n for k, v in run.labels.items() if k != "run"})
        parts.append(pd.DataFrame(cols))
        units.update(run.units)
    df = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()
    df.attrs["units"] = {c: units.get(c, "") for c in df.columns}
    return df


@dataclass
class _Run:
    name: str
    time: np.ndarray
    settled: np.ndarray
    signals: dict
    labels: dict
    units: dict = field(default_factory=dict)


def _hdf5_runs(p: Path, channels, settled_only: bool) -> Iterator[_Run]:
    import h5py

    with h5py.File(p, "r") as f:
        names = json.loads(f.attrs["runs"])
        lab = {k: f["labels"][k][()] for k in f["labels"]}
        lab_units = {k: str(f["labels"][k].attrs.get("unit", "")) for k in f["labels"]}
        for i, name in enumerate(names):
            g = f["runs"][name]
            keep_ch = [c for c in g if c not in ("time", "settled") and (channels is None or c in channels)]
            time_s, settled = g["time"][()], g["settled"][()].astype(bool)
            m = settled if settled_only else slice(None)
            labels = {k: _py(v[i]) for k, v in lab.items()}
            yield _Run(name, time_s[m], settled[m], {c: g[c][()][m] for c in keep_ch}, labels,
                       {"time_s": "s", "settled": "", **{c: str(g[c].attrs.get("unit", "")) for c in keep_ch},
                        **lab_units})


def _py(v):
    if isinstance(v, bytes):
        return v.decode()
    if isinstance(v, np.generic):
        return v.item()
    return v


@dataclass
class Windows:
    """The windows of one run: ``x`` float32 of shape (windows, length, channels) (``channels_first``:
    (windows, channels, length)), the run's name, class columns and all its labels."""

    x: np.ndarray
    run: str
    label: str
    faulty: bool
    split: str
    labels: dict
    channels: tuple

    @property
    def y(self) -> np.ndarray:
        """``faulty`` per window (int64 0/1), the binary target."""
        return np.full(len(self.x), int(bool(self.faulty)), dtype=np.int64)


def _parquet_runs(p: Path, channels: list[str]) -> Iterator[_Run]:
    """A parquet dataset's runs, one row group (a run, as the writer stores it) at a time; a run split over
    consecutive row groups is joined."""
    import pyarrow.parquet as pq

    pf = pq.ParquetFile(p)
    names = pf.schema_arrow.names
    missing = [c for c in channels if c not in names]
    if missing:
        raise DatasetError(f"{p}: no channel {', '.join(map(repr, missing))} (it has "
                           f"{', '.join(n for n in names if not '.' in n and n not in ('run', 'time_s', 'settled'))})")
    label_cols = [c for c in json.loads((pf.schema_arrow.metadata or {}).get(LABELS_KEY.encode(), b"[]"))
                  if c in names and c != "run"]
    cols = ["run", "time_s", "settled", *channels, *label_cols]
    pending: list = []

    def finish(tables) -> _Run:
        import pyarrow as pa

        t = pa.concat_tables(tables)
        first = {c: t.column(c)[0].as_py() for c in label_cols}
        return _Run(str(t.column("run")[0].as_py()), t.column("time_s").to_numpy(),
                    t.column("settled").to_numpy(zero_copy_only=False).astype(bool),
                    {c: t.column(c).to_numpy(zero_copy_only=False) for c in channels}, first)

    for i in range(pf.num_row_groups):
        t = pf.read_row_group(i, columns=cols)
        if not t.num_rows:
            continue
        name = t.column("run")[0].as_py()
        if pending and pending[0].column("run")[0].as_py() != name:
            yield finish(pending)
            pending = []
        pending.append(t)
    if pending:
        yield finish(pending)


def windows(path: Path | str, channels: list[str], length: int, hop: int | None = None, *,
            settled_only: bool = True, splits: tuple[str, ...] | None = None, channels_first: bool = False,
            dtype=np.float32) -> Iterator[Windows]:
    """Fixed-length windows of ``channels`` from a ``dataset.parquet`` or ``dataset.h5``, one :class:`Windows`
    per run, read run by run (never the whole dataset in memory). ``length`` samples a window, ``hop`` samples
    between window starts (default ``length``: no overlap); ``settled_only``: from each run's settled samples
    only (after ``time.settle_s``); ``splits``: only runs of these splits (e.g. ``("train",)``). A run shorter
    than one window yields nothing."""
    if not channels:
        raise DatasetError("windows: name at least one channel")
    length = int(length)
    hop = int(hop or length)
    if length < 1 or hop < 1:
        raise DatasetError(f"windows: length {length} and hop {hop} must be positive sample counts")
    p = _find(path)
    runs = _hdf5_runs(p, channels, settled_only) if p.suffix in (".h5", ".hdf5") else _parquet_runs(p, list(channels))
    for run in runs:
        if splits is not None and run.labels.get("split") not in splits:
            continue
        m = run.settled if settled_only and p.suffix not in (".h5", ".hdf5") else slice(None)
        missing = [c for c in channels if c not in run.signals]
        if missing:
            raise DatasetError(f"{p}: run {run.name} has no channel {', '.join(missing)}")
        data = np.stack([np.asarray(run.signals[c])[m] for c in channels], axis=-1).astype(dtype, copy=False)
        n = (len(data) - length) // hop + 1 if len(data) >= length else 0
        if n <= 0:
            continue
        idx = np.arange(n)[:, None] * hop + np.arange(length)[None, :]
        x = data[idx]                                   # (windows, length, channels)
        if channels_first:
            x = np.ascontiguousarray(x.transpose(0, 2, 1))
        lab = run.labels
        yield Windows(x, run.name, str(lab.get("label", "")), bool(lab.get("faulty", False)),
                      str(lab.get("split", "")), lab, tuple(channels))


def _final_speed(value, profile) -> float:
    if profile:
        prof = json.loads(profile) if isinstance(profile, str) else profile
        return float(prof[-1][1])
    return float(value)


def _run_upper_ratio(h: dict) -> float | None:
    """The upper gearbox's ratio a stored run was made with (its summary's characteristic frequencies: the
    machine's lumped table, issue 42), None when the file does not say (the rig's)."""
    try:
        ratio = json.loads(h["attrs"].get("summary_json") or "{}")["characteristic_frequencies"]["upper_ratio"]
    except (ValueError, KeyError, TypeError):
        return None
    ok = isinstance(ratio, (int, float)) and not isinstance(ratio, bool) and 0 < ratio < float("inf")
    return float(ratio) if ok else None


def spectrum(source, channel: str, run: str | None = None):
    """The amplitude spectrum of a loaded run's channel, as ``RunResult.spectrum`` and the run's plots compute it
    (rig.signals.run_spectrum): ``source`` a run's directory or its ``signals.h5``, or a DataFrame of
    :func:`load_dataset` (``run`` names the run when it holds several). A DataFrame ``frequency_Hz``,
    ``amplitude`` with the units, the convention and the characteristic frequencies in its attrs."""
    from drivetrain.run.runner import spectrum_frame

    if isinstance(source, (str, Path)):
        from drivetrain.run.outputs import read_hdf5

        sig = Path(source) / "signals.h5" if Path(source).is_dir() else Path(source)
        if not sig.is_file():
            raise DatasetError(f"{source}: no signals.h5 (a run's directory or its signals.h5)")
        h = read_hdf5(sig)
        if channel not in h["signals"]:
            raise DatasetError(f"{sig}: no channel {channel!r} (it has {', '.join(h['signals'])})")
        scene = (h.get("scene") or {}).get("scene") or h.get("scene") or {}
        op = scene.get("operating_point") or {}
        pair = (scene.get("gear") or {}).get("pair") or {}
        return spectrum_frame(h["time"], h["signals"][channel], float(h["attrs"]["settle_s"]),
                              float(h["attrs"]["sample_rate_Hz"]),
                              _final_speed(op.get("drive_speed_rpm"), op.get("speed_profile_rpm")), channel,
                              str(h["units"].get(channel, "")),
                              teeth=label_teeth({f"gear.pair.{k}": v for k, v in pair.items()}),
                              upper_ratio=_run_upper_ratio(h))
    df = source
    if run is not None:
        df = df[df["run"] == run]
    elif "run" in df and df["run"].nunique() > 1:
        raise DatasetError(f"the DataFrame holds {df['run'].nunique()} runs: name one with run=")
    if not len(df):
        raise DatasetError(f"no samples of run {run!r}")
    first = df.iloc[0]
    need = ["time_s", channel, "time.settle_s", "time.sample_rate_Hz", "operating_point.drive_speed_rpm"]
    missing = [c for c in need if c not in df]
    if missing:
        raise DatasetError(f"the DataFrame has no column {', '.join(missing)} (a load_dataset DataFrame has them)")
    return spectrum_frame(df["time_s"].to_numpy(), df[channel].to_numpy(), float(first["time.settle_s"] or 0.0),
                          float(first["time.sample_rate_Hz"]),
                          _final_speed(first["operating_point.drive_speed_rpm"],
                                       first.get("operating_point.speed_profile_rpm")),
                          channel, (df.attrs.get("units") or {}).get(channel, ""), teeth=label_teeth(first))


__all__ = ["spectrum", "load_dataset", "windows", "Windows", "units_of", "schema_metadata", "UNITS_KEY", "LABELS_KEY"]
