"""A labelled dataset from a sweep directory: every run's signals with its labels, in one file set.

``drivetrain dataset SWEEP_DIR --format parquet|hdf5|aalto [--out PATH]`` reads the sweep's
records (``manifest.json``, with the journal ``manifest.jsonl`` of a killed sweep) and each listed run's ``signals.h5`` (completed runs, and the completed part of
failed runs, marked by ``status``) and writes:

- ``parquet``: one table, one row per sample: ``run``, ``time_s``, ``settled`` (the sample is at or after
  the run's ``time.settle_s``: outside the start-up transient), one column per channel (NaN where a run
  did not record it), and the run's labels repeated on every row (pyarrow; written run by run, parquet's
  dictionary encoding stores the repetition once); every column's unit in the schema metadata
  ``drivetrain.units``. ``pandas.read_parquet("dataset.parquet")`` (pandas comes with the base install).
- ``hdf5``: ``/labels/<label>`` (one entry per run, in run order; strings UTF-8) and
  ``/runs/<run>/time``, ``/runs/<run>/settled`` and ``/runs/<run>/<channel>``; every array has its unit in
  its ``unit`` attribute ("1" dimensionless, "" text or switches). ``h5py.File("dataset.h5")``.
- ``aalto``: a directory with ``<run>.csv`` in the Aalto Gear Fault Dataset layout (time, enc1..enc5,
  Torq1, Torq2) and ``labels.csv`` (one row per run). ``pandas.read_csv("labels.csv")``.

``--settled-only`` leaves the transient's samples out of every format.

Labels of a run: ``run``, ``status``, ``failure_time_s``, ``energy_residual`` and every key of its
resolved scene as ``section.key`` (operating point, gear health and fault mesh files, effects,
numerics, time; lists such as speed profiles as JSON text), so a label names the setting exactly as a
scene file does. A setting that does not act in the run (drivetrain.scene.schema.ACTS_WHEN: the
manufacturing draw without ``effects.manufacturing_errors``, the instruments with ideal sensors, a
background constant whose effect is off) is empty (null), not its unused value. Each fault is
``fault<i>.<key>`` (kind, member, tooth, flank, sizes), the paper's ``mild`` and ``severe`` as the fault
specifications of their geometry (gearcontact_fmu.fault_specs.PRESET_FAULTS), with how much contact it gets at
the run's load: ``fault<i>.contact_share`` (the share of its flank area inside the loaded contact region over a
mesh cycle), ``fault<i>.mesh_torque_drop`` (the largest relative drop of mesh torque at fixed mesh coordinate)
and ``fault<i>.loaded_flank`` (gearcontact_fmu.fault_contact). The condition indicators
of the run (campaigns.features) are per-run columns too.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from drivetrain.errors import DatasetError  # noqa: F401  (re-exported)
from drivetrain.run.files import nonfinite_text, read_signals
from drivetrain.run.outputs import write_aalto_csv
from drivetrain.campaigns.loaders import schema_metadata
from drivetrain.campaigns.splits import DEFAULT_FRACTIONS, DEFAULT_SPLIT_SEED, class_columns
from drivetrain.campaigns.sweep import read_runs
from drivetrain.scene.schema import NAME_RE, NAME_RULE, setting_acts
from gearcontact_fmu.fault_specs import health_faults

FORMATS = ("parquet", "hdf5", "aalto")
#: the labels of a fault's contact a run's summary gives (summary["fault_contact"]), as ``fault<i>.<key>``
CONTACT_LABELS = ("contact_share", "mesh_torque_drop", "loaded_flank")
#: the Aalto layout's note of the runs not exported, and why (parquet: metadata drivetrain.left_out; HDF5: attribute
#: left_out)
LEFT_OUT_FILE = "left_out.json"
DEFAULT_NAMES = {"parquet": "dataset.parquet", "hdf5": "dataset.h5", "aalto": "dataset_aalto"}


def _label_value(v: Any):
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    return json.dumps(v, sort_keys=True, default=str)


def run_labels(name: str, record: dict, scene: dict, summary: dict | None) -> dict:
    """The labels of one run (see the module docstring)."""
    labels: dict[str, Any] = {"run": name, "status": record.get("status", "ok"),
                              "nonfinite_samples": record.get("nonfinite_samples"),
                              "failure_time_s": record.get("failure_time_s"),
                              "energy_residual": record.get("energy_residual")}
    for section, keys in sorted(scene.items()):
        if section in ("expect", "check") or not isinstance(keys, dict):
            continue
        for key, value in sorted(keys.items()):
            if section == "gear" and key == "pair" and isinstance(value, dict):     # [gear.pair]: a column per key
                labels.update({f"gear.pair.{k}": _label_value(v) for k, v in value.items()})
                continue
            labels[f"{section}.{key}"] = _label_value(value) if setting_acts(section, key, scene) else None
    # each fault also as columns of its own (fault0.kind, fault0.member, fault0.tooth, its sizes ...), the
    # paper's mild and severe as the specifications of their geometry
    gear = scene.get("gear") or {}
    contact = list((summary or {}).get("fault_contact") or [])
    for i, fault in enumerate(health_faults(gear.get("health", "healthy"), gear.get("faults") or ())):
        for key, value in fault.items():
            labels[f"fault{i}.{key}"] = _label_value(value)
        # how much contact the fault gets at the run's load (gearcontact_fmu.fault_contact; None: not known)
        c = contact[i] if i < len(contact) and isinstance(contact[i], dict) else {}
        for key in CONTACT_LABELS:
            labels[f"fault{i}.{key}"] = _label_value(c.get(key))
    return labels


def run_records(sweep_dir: Path | str) -> list[dict]:
    """The run records of a sweep directory (the manifest, with the journal's runs of a killed sweep)."""
    d = Path(sweep_dir)
    try:
        return read_runs(d)
    except OSError as exc:
        raise DatasetError(f"{d}: no readable manifest.json or manifest.jsonl ({exc}); is it a sweep "
                           "directory?") from None


def load_run(sweep_dir: Path | str, rec: dict, why: list | None = None) -> dict | None:
    """One run of a sweep as {"name", "labels", "time", "signals", "units"}; None if it wrote no signals (then
    ``why``, if given, gets the reason). A record's name becomes a path (the run's folder, an exported file's
    name): one that is not a valid scene name (``..``, a slash, an absolute path) is refused, so whoever hands
    over a sweep directory cannot make us read or write outside it."""
    name = rec.get("name")
    if not name:
        return None
    if not isinstance(name, str) or not NAME_RE.fullmatch(name):
        raise DatasetError(f"{sweep_dir}: a manifest record names its run {str(name)[:80]!r}: not a valid run name "
                           f"({NAME_RULE}); nothing is read or written for it")
    sig = Path(sweep_dir) / name / "signals.h5"
    if not sig.is_file():
        if why is not None:
            status = rec.get("status", "ok")
            why.append(f"listed as {status}, but its signals.h5 is missing" if status == "ok" else
                       f"{status} before it wrote signals" + (f" ({str(rec['error'])[:160]})" if rec.get("error") else ""))
        return None
    return read_run(sig, rec)


def read_run(sig: Path, rec: dict) -> dict:
    """A run's ``signals.h5`` as {"name", "labels", "time", "signals", "units"}, checked (run.files.read_signals:
    every channel as long as time, the JSON it keeps readable); the name is the record's, else the one its
    scene has; the status is the record's, else its summary's. A run with non-finite samples is labelled
    ``failed`` whatever its record says, with their count in ``nonfinite_samples`` (0 for a clean run)."""
    h = read_signals(sig)
    stored = h.get("scene") or {}
    scene = stored.get("scene", stored) if isinstance(stored, dict) else None
    if not isinstance(scene, dict):
        raise DatasetError(f"{sig}: attribute scene_json: expected a scene (a JSON object)")
    summary = h["summary"]
    scenario = scene.get("scenario") if isinstance(scene.get("scenario"), dict) else {}
    name = rec.get("name") or scenario.get("name") or Path(sig).parent.name
    rec = {"status": (summary or {}).get("status", "ok"), **rec}
    bad = h["nonfinite_samples"]
    rec["nonfinite_samples"] = sum(bad.values())
    if bad:
        rec["status"] = "failed"
        rec["nonfinite_text"] = nonfinite_text(bad, len(h["time"]))
    return {"name": str(name), "labels": run_labels(str(name), rec, scene, summary), "time": h["time"],
            "signals": h["signals"], "units": h["units"], "nonfinite": rec.get("nonfinite_text")}


def collect(sweep_dir: Path | str, split_fractions=DEFAULT_FRACTIONS, split_seed: int = DEFAULT_SPLIT_SEED,
            left_out: dict | None = None) -> list[dict]:
    """[{"name", "labels", "units", "channels"}] of every run of the sweep that wrote signals, without the
    signals: a dataset of thousands of runs is never held in memory. The labels include the class columns
    ``label``, ``faulty``, ``gearbox`` and ``split`` (campaigns.splits: the split drawn per gearbox with
    ``split_fractions`` and ``split_seed``), the condition indicators and, for a faulty run with a healthy twin
    ([sweep.draw] paired_healthy), the fault's signal-to-background ratio, each computed from the run's signals
    as it is read. :func:`run_data` reads a run's samples again when a writer needs them. ``left_out`` (if
    given) gets {run: why} of every listed run that is not exported, and {run: what} of every run exported as
    failed for its non-finite samples."""
    d = Path(sweep_dir)
    runs = []
    left_out = {} if left_out is None else left_out
    for rec in run_records(d):
        why: list = []
        r = load_run(d, rec, why)
        if r is None:
            if why:
                left_out[str(rec.get("name"))] = f"left out: {why[0]}"
            continue
        if r["nonfinite"]:
            left_out[r["name"]] = f"exported as failed: {r['nonfinite']}"
        r["labels"].update(_indicators(r))
        runs.append({"name": r["name"], "labels": r["labels"], "units": r["units"], "channels": sorted(r["signals"]),
                     "_source": (d, rec)})
    if not runs:
        raise DatasetError(f"{d}: the manifest lists no run with signals")
    _add_paired_sbr(runs)
    for r, cls in zip(runs, class_columns([r["labels"] for r in runs], split_fractions, split_seed)):
        r["labels"] = {"run": r["labels"]["run"], **cls, **{k: v for k, v in r["labels"].items() if k != "run"}}
    return runs


def _samples(run: dict, settled_only: bool) -> tuple:
    """(time, signals, settled mask) of a loaded run, only its settled samples if ``settled_only``."""
    time_s = np.asarray(run["time"])
    settled = time_s >= float(run["labels"].get("time.settle_s") or 0.0)
    signals = {k: np.asarray(v) for k, v in run["signals"].items()}
    if settled_only:
        return time_s[settled], {k: v[settled] for k, v in signals.items()}, np.ones(int(settled.sum()), dtype=bool)
    return time_s, signals, settled


def run_data(run: dict, settled_only: bool = False) -> tuple:
    """(time, signals, settled mask) of a collected run, read from its signals.h5 again."""
    sweep_dir, rec = run["_source"]
    loaded = load_run(sweep_dir, rec)
    if loaded is None:
        raise DatasetError(f"{sweep_dir / run['name']}: its signals.h5 disappeared while the dataset was written")
    return _samples(loaded, settled_only)


def _add_paired_sbr(runs: list[dict]) -> None:
    """The SBR labels of the runs with a healthy twin (only those pairs' signals are read, a pair at a time)."""
    from drivetrain.rig.indicators import TORQUES, paired_sbr, twin_groups

    for members in twin_groups(runs):
        if len(members) < 2:
            continue
        loaded = []
        for r in members:
            time_s, signals, _ = run_data(r)
            loaded.append({"name": r["name"], "labels": r["labels"], "time": time_s, "signals": signals})
        try:
            sbr = paired_sbr(loaded, TORQUES)
        except ValueError as exc:
            raise DatasetError(f"{run_source_dir(members[0])}: {exc} (one noise record: one time axis)") from None
        for r in members:
            r["labels"].update({f"SBR_dB.{sig}": v for sig, v in sbr.get(r["name"], {}).items()})


def run_source_dir(run: dict) -> Path:
    """The sweep directory a collected run was read from."""
    return Path(run["_source"][0])


def _indicators(run: dict) -> dict:
    """The run's condition indicators (rig.indicators.run_features: the columns of ``drivetrain features``),
    per-run columns of the dataset; none for a run without a constant drive speed (a speed profile moves
    the characteristic frequencies) or too short to judge."""
    from drivetrain.rig.indicators import label_teeth, run_features

    lab = run["labels"]
    try:
        speed = float(lab.get("operating_point.drive_speed_rpm") or 0.0)
        if not speed > 0 or lab.get("operating_point.speed_profile_rpm"):
            return {}
        return run_features(run["time"], run["signals"], float(lab.get("time.settle_s") or 0.0), speed,
                            teeth=label_teeth(lab))
    except (TypeError, ValueError):
        return {}


#: units of label names by their suffix (scene keys carry theirs in the schema)
_SUFFIX_UNITS = {"_mm": "mm", "_um": "um", "_s": "s", "_Hz": "Hz", "_rpm": "rpm", "_Nm": "N.m", "_dB": "dB",
                 "_rad": "rad"}


#: the scene schema's spelling of a unit -> the one the signals (and FMUs) use
_SIGNAL_SPELLING = {"N·m": "N.m", "mN·m": "mN.m", "kN·m": "kN.m"}


def label_unit(name: str, channel_units: dict, numeric: bool = False) -> str:
    """The unit of a label column: a scene key's from the schema; a fault size's or another suffixed name's
    from its suffix; a condition indicator's from its signal (RMS and line amplitudes in the signal's unit,
    SBR in dB, the other metrics dimensionless "1"); else "1" for a ``numeric`` column, "" for text."""
    unit = _named_unit(name, channel_units)
    # one spelling per unit in a dataset: the signals' (the FMUs' "N.m"), also for the scene's "N·m"
    unit = _SIGNAL_SPELLING.get(unit, unit)
    return unit or ("1" if numeric else "")


def _named_unit(name: str, channel_units: dict) -> str:
    from drivetrain.scene.schema import SCHEMA

    head, _, tail = name.partition(".")
    key = SCHEMA.get(head, {}).get(tail) if tail else None
    if key is not None:
        return key.unit or ("1" if key.type in ("float", "int") else "")
    if tail and tail in channel_units and not head.startswith("fault"):        # an indicator of a signal
        if head == "SBR_dB":
            return "dB"
        return channel_units[tail] if head.startswith(("amp_", "RMS_")) else "1"
    leaf = tail or head
    if leaf == "energy_residual":
        return "1"
    return next((u for suffix, u in _SUFFIX_UNITS.items() if leaf.endswith(suffix)), "")


def _label_columns(runs: list[dict]) -> list[str]:
    cols: list[str] = []
    for r in runs:
        cols += [k for k in r["labels"] if k not in cols]
    return cols


def _arrow_type(values: list):
    """One Arrow type for a label column from its values over all runs (None: null), text if they mix kinds."""
    import pyarrow as pa

    try:
        return pa.array(values).type
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        return pa.string()


def _arrow_label(v, n: int, t):
    import pyarrow as pa

    if v is None:
        return pa.nulls(n, type=t)
    return pa.array([str(v) if pa.types.is_string(t) and not isinstance(v, str) else v] * n, type=t)


def write_parquet(runs: list[dict], path: Path, settled_only: bool = False, left_out: dict | None = None) -> Path:
    """One row per sample, written run by run (one row group each: a run's repeated labels are built for that
    run only, and parquet's dictionary encoding stores them once)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    channels = sorted({c for r in runs for c in r["channels"]})
    label_cols = [k for k in _label_columns(runs) if k != "run"]
    types = {k: _arrow_type([r["labels"].get(k) for r in runs]) for k in label_cols}
    names = {k: f"label.{k}" if k in channels or k in ("time_s", "settled") else k for k in label_cols}
    units = {c: next((r["units"].get(c, "") for r in runs if c in r["units"]), "") for c in channels}
    units.update({"run": "", "time_s": "s", "settled": "", **{names[k]: label_unit(
        k, units, numeric=pa.types.is_integer(types[k]) or pa.types.is_floating(types[k])) for k in label_cols}})
    schema = pa.schema([("run", pa.dictionary(pa.int32(), pa.string())), ("time_s", pa.float64()),
                        ("settled", pa.bool_()), *((c, pa.float64()) for c in channels),
                        *((names[k], types[k]) for k in label_cols)],
                       metadata={**schema_metadata(units, ["run", *label_cols]),
                                 "drivetrain.left_out": json.dumps(left_out or {})})
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with pq.ParquetWriter(tmp, schema) as writer:
        for r in runs:
            time_s, signals, settled = run_data(r, settled_only)
            n = len(time_s)
            cols = [pa.DictionaryArray.from_arrays(pa.array(np.zeros(n, dtype=np.int32)), pa.array([r["name"]])),
                    pa.array(np.asarray(time_s, dtype=float)), pa.array(settled)]
            for c in channels:
                x = signals.get(c)
                cols.append(pa.array(np.asarray(x, dtype=float) if x is not None else np.full(n, np.nan)))
            cols += [_arrow_label(r["labels"].get(k), n, types[k]) for k in label_cols]
            writer.write_table(pa.Table.from_arrays(cols, schema=schema))
    tmp.replace(path)
    return path


def write_hdf5(runs: list[dict], path: Path, settled_only: bool = False, left_out: dict | None = None) -> Path:
    import h5py

    label_cols = _label_columns(runs)
    channel_units = {c: u for r in runs for c, u in r["units"].items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with h5py.File(tmp, "w") as f:
        f.attrs["format"] = "drivetrain-dataset/1"
        f.attrs["runs"] = json.dumps([r["name"] for r in runs])
        f.attrs["left_out"] = json.dumps(left_out or {})
        lab = f.create_group("labels")
        for k in label_cols:
            vals = [r["labels"].get(k) for r in runs]
            if all(isinstance(v, (int, float)) and not isinstance(v, bool) or v is None for v in vals) and \
                    any(v is not None for v in vals):
                lab.create_dataset(k, data=np.array([np.nan if v is None else float(v) for v in vals]))
            elif all(isinstance(v, bool) for v in vals):
                lab.create_dataset(k, data=np.array(vals, dtype=bool))
            else:
                lab.create_dataset(k, data=["" if v is None else str(v) for v in vals],
                                   dtype=h5py.string_dtype("utf-8"))
            lab[k].attrs["unit"] = label_unit(k, channel_units, numeric=lab[k].dtype.kind in "fiu")
        grp = f.create_group("runs")
        for r in runs:
            time_s, signals, settled = run_data(r, settled_only)
            g = grp.create_group(r["name"])
            g.create_dataset("time", data=time_s).attrs["unit"] = "s"
            g.create_dataset("settled", data=settled).attrs["unit"] = ""
            for c, x in signals.items():
                ds = g.create_dataset(c, data=x)
                ds.attrs["unit"] = r["units"].get(c, "")
    tmp.replace(path)
    return path


def write_aalto(runs: list[dict], path: Path, settled_only: bool = False, left_out: dict | None = None) -> Path:
    import csv

    path.mkdir(parents=True, exist_ok=True)
    label_cols = _label_columns(runs)
    for r in runs:
        time_s, signals, _ = run_data(r, settled_only)
        write_aalto_csv(path / f"{r['name']}.csv", time_s, signals)
    with open(path / "labels.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=label_cols)
        w.writeheader()
        for r in runs:
            w.writerow({k: r["labels"].get(k) for k in label_cols})
    (path / LEFT_OUT_FILE).write_text(json.dumps(left_out or {}, indent=1) + "\n")
    return path


def written_columns(runs: list[dict], data_path: Path, fmt: str) -> dict:
    """Every column of the written data with its unit (parquet: from the file's own metadata)."""
    if fmt == "parquet":
        from drivetrain.campaigns.loaders import units_of
        import pyarrow.parquet as pq

        units = units_of(data_path)
        return {c: units.get(c, "") for c in pq.read_schema(data_path).names}
    channel_units = {c: u for r in runs for c, u in r["units"].items()}
    cols = {"run": "", "time_s": "s", "settled": "", **{c: channel_units.get(c, "") for c in sorted(channel_units)}}
    for k in _label_columns(runs):
        if k != "run":
            v = next((r["labels"].get(k) for r in runs if r["labels"].get(k) is not None), None)
            cols[k] = label_unit(k, channel_units, numeric=isinstance(v, (int, float)) and not isinstance(v, bool))
    return cols


WRITERS = {"parquet": write_parquet, "hdf5": write_hdf5, "aalto": write_aalto}


def contact_counts(runs: list[dict]) -> dict:
    """How many of the runs' faults carry contact: ``faulty`` runs (with a ``fault0``), of them ``with_contact``
    (``fault0.contact_share`` > 0), ``without_contact`` (= 0: the fault sits where the load never runs) and
    ``unknown`` (no share computed)."""
    shares = [r["labels"].get("fault0.contact_share") for r in runs if r["labels"].get("fault0.kind") is not None]
    known = [s for s in shares if isinstance(s, (int, float))]
    return {"faulty": len(shares), "with_contact": sum(s > 0 for s in known),
            "without_contact": sum(s <= 0 for s in known), "unknown": len(shares) - len(known)}


def contact_line(counts: dict) -> str:
    """The sentence the dataset's writers say about :func:`contact_counts`."""
    return (f"{counts['with_contact']} of {counts['faulty']} faulty runs carry contact (fault0.contact_share > 0); "
            f"{counts['without_contact']} have none, {counts['unknown']} unknown")


def export(sweep_dir: Path | str, fmt: str = "parquet", out: Path | str | None = None,
           settled_only: bool = False, log=None, split_fractions=DEFAULT_FRACTIONS,
           split_seed: int = DEFAULT_SPLIT_SEED, card: bool = True) -> Path:
    """Write the dataset of a sweep directory; returns the written path. ``settled_only``: leave out each run's
    samples before its ``time.settle_s``. ``log``: told how many faulty runs carry contact
    (:func:`contact_counts`). ``split_fractions`` (train, validation, test) and ``split_seed``: the gearbox-level
    split (campaigns.splits). ``card``: also write the dataset card ``DATASET.md`` beside the data
    (campaigns.card)."""
    if fmt not in WRITERS:
        raise DatasetError(f"format {fmt!r}: expected one of {', '.join(FORMATS)}")
    path = Path(out) if out else Path(sweep_dir) / DEFAULT_NAMES[fmt]
    if fmt != "aalto" and path.is_dir():
        raise DatasetError(f"{path}: a directory; the {fmt} dataset is one file (give its file name)")
    left_out: dict = {}
    try:
        runs = collect(sweep_dir, split_fractions, split_seed, left_out)
    except ValueError as exc:                  # the split's fractions
        raise DatasetError(str(exc)) from None
    if log is not None:
        log(contact_line(contact_counts(runs)))
        for name, why in left_out.items():
            log(f"warning: run {name}: {why}")
    try:
        written = WRITERS[fmt](runs, path, settled_only, left_out)
        if card:
            from drivetrain.campaigns.card import write_card

            write_card(runs, written, fmt, sweep_dir, written_columns(runs, written, fmt),
                       contact_line(contact_counts(runs)), settled_only=settled_only,
                       split=(tuple(split_fractions), split_seed))
        return written
    except OSError as exc:                     # a read-only place, a full disk: named, and no stray temporary
        try:
            path.with_name(path.name + ".tmp").unlink(missing_ok=True)
        except OSError:
            pass
        raise DatasetError(f"{path}: the dataset cannot be written there ({exc.strerror or exc})") from None


__all__ = ["run_records", "load_run", "read_run", "run_data", "FORMATS", "DatasetError", "collect", "export", "run_labels",
           "contact_counts", "CONTACT_LABELS", "write_parquet", "write_hdf5",
           "write_aalto"]
