"""``drivetrain features DIR``: condition indicators of every run of a run or sweep directory.

For each run that wrote signals (a sweep's manifest, or one run's directory with its ``signals.h5``), after
its settling time: per torque transducer and per shaft whose encoder was recorded (the pinion's, enc4,
15 teeth; the wheel's, enc5, 60 teeth), the shaft's time-synchronous average in :data:`RECORDS`
consecutive records and the metrics of drivetrain.rig.indicators on them; and the amplitudes at the
characteristic frequencies of the raw signal (Hann spectrum). Columns are ``<METRIC>.<signal>`` with the
shaft in the metric's name (``FM4_pinion.propeller_shaft_torque``, ``kurtosis_wheel.drive_shaft_torque``,
``amp_f_GMF+f_MSH.propeller_shaft_torque``), the run's labels beside them (the columns of
``drivetrain dataset``: run, status, every scene key, the faults). A faulty run with a healthy twin
(``[sweep.draw] paired_healthy``: one ``scenario.noise_name``, the pair id) also gets ``SBR_dB.<signal>``, the
fault's signal-to-background ratio (rig.indicators.signal_to_background_dB). Written to
``DIR/features.parquet`` (pyarrow), one row per run. The same indicator columns are per-run columns of
``drivetrain dataset`` (campaigns.dataset), and :func:`features` / :func:`run_features` are the Python API.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from drivetrain.campaigns.splits import (CLASS_COLUMNS, DEFAULT_FRACTIONS, DEFAULT_SPLIT_SEED, check_fractions,
                                         class_columns)
from drivetrain.errors import DatasetError
from drivetrain.rig import indicators as ci

FEATURES_FILE = "features.parquet"
#: the per-run computation lives with the metrics (rig.indicators); its names stay importable from here
SHAFTS, TORQUES, RECORDS, LINES, run_features = ci.SHAFTS, ci.TORQUES, ci.RECORDS, ci.LINES, ci.run_features


def _iter_runs(directory: Path):
    """The runs of a sweep directory one at a time, the healthy ones first (their signals are kept for the
    faulty runs paired with them), or the one run of a run directory."""
    from drivetrain.campaigns.dataset import load_run, read_run, run_records

    if (directory / "signals.h5").is_file() and not (directory / "manifest.json").is_file():
        yield read_run(directory / "signals.h5", {})
        return
    records = run_records(directory)
    healthy_first = sorted(records, key=lambda rec: (rec.get("labels") or {}).get("health") != "healthy")
    found = False
    for rec in healthy_first:
        run = load_run(directory, rec)
        if run is not None:
            found = True
            yield run
    if not found:
        raise DatasetError(f"{directory}: the manifest lists no run with signals")


def indicator_columns(run: dict, where: Path | str) -> dict:
    """The indicator columns of one run read by ``dataset.read_run`` (its settled part, at its drive speed);
    a run without a constant drive speed or too short for its indicators is a DatasetError naming it."""
    lab = run["labels"]
    settle = float(lab.get("time.settle_s") or 0.0)
    speed = lab.get("operating_point.drive_speed_rpm")
    if speed is None or not float(speed) > 0:
        raise DatasetError(f"{where}: run {run['name']} has no constant drive speed (its characteristic frequencies "
                           "and shaft orders need one)")
    try:
        return run_features(run["time"], run["signals"], settle, float(speed), teeth=ci.label_teeth(lab))
    except ValueError as exc:
        raise DatasetError(f"{where}: run {run['name']}: {exc}") from None


def features(directory: str | Path, split_fractions=DEFAULT_FRACTIONS, split_seed: int = DEFAULT_SPLIT_SEED,
             channel_units: dict | None = None) -> list[dict]:
    """One row per run: its labels (with the class columns ``label``, ``faulty``, ``gearbox`` and ``split`` of
    campaigns.splits, the split as ``drivetrain dataset`` draws it with the same seed) and its indicator
    columns. The runs are read one at a time (a study of thousands of runs never holds their signals together);
    a healthy run's torques are kept while a faulty run paired with it (one ``scenario.noise_name``) may follow.
    ``channel_units``: a dict given is filled with the runs' channel units."""
    d = Path(directory)
    rows = []
    twins: dict = {}
    for r in _iter_runs(d):
        if channel_units is not None:
            channel_units.update(r["units"])
        lab = r["labels"]
        settle = float(lab.get("time.settle_s") or 0.0)
        cols = indicator_columns(r, d)
        pair = lab.get("scenario.noise_name")
        if pair and lab.get("gear.health") == "healthy":
            twins[pair] = {"name": r["name"], "time": r["time"], "signals": {k: r["signals"][k] for k in TORQUES if k in r["signals"]}}
        elif pair and pair in twins:
            h = twins[pair]
            why = ci.twin_mismatch(r, h)
            if why:
                raise DatasetError(f"{d}: {why} (one noise record: one time axis)")
            keep = np.asarray(r["time"]) >= settle
            for sig in TORQUES:
                if sig in r["signals"] and sig in h["signals"]:
                    cols[f"SBR_dB.{sig}"] = ci.signal_to_background_dB(np.asarray(r["signals"][sig])[keep],
                                                                       np.asarray(h["signals"][sig])[keep])
        rows.append({**lab, **cols})
    for row, cls in zip(rows, class_columns(rows, split_fractions, split_seed)):
        row.update(cls)
    return [{"run": row["run"], **{k: row[k] for k in CLASS_COLUMNS}, **row} for row in rows]


def write_features(directory: str | Path, out: str | Path | None = None, split_fractions=DEFAULT_FRACTIONS,
                   split_seed: int = DEFAULT_SPLIT_SEED) -> Path:
    """``DIR/features.parquet`` (or ``out``): the rows of :func:`features`, a column per label and indicator,
    every column's unit in the schema metadata (``load_dataset`` and ``pandas.read_parquet`` put them in
    ``df.attrs["units"]``)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from drivetrain.campaigns.dataset import label_unit
    from drivetrain.campaigns.loaders import schema_metadata

    try:
        check_fractions(split_fractions)
    except ValueError as exc:
        raise DatasetError(str(exc)) from None
    channel_units: dict = {}
    rows = features(directory, split_fractions, split_seed, channel_units)
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    table = pa.table({c: [_cell(r.get(c)) for r in rows] for c in cols})
    units = {c: label_unit(c, channel_units, numeric=pa.types.is_integer(table.schema.field(c).type)
                           or pa.types.is_floating(table.schema.field(c).type)) for c in cols}
    table = table.replace_schema_metadata(schema_metadata(units, cols))
    path = Path(out) if out else Path(directory) / FEATURES_FILE
    pq.write_table(table, path)
    return path


def _cell(v):
    if isinstance(v, (list, tuple, dict)):
        return json.dumps(v, sort_keys=True, default=str)
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return v


__all__ = ["features", "write_features", "run_features", "SHAFTS", "TORQUES", "LINES", "FEATURES_FILE"]
