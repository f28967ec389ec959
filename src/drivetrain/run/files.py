"""The files the project writes, read back checked (issue 45): one reader for JSON documents (manifests,
summaries, case files, JSON kept in HDF5 attributes) and one checker for signals files.

Whoever hands over a sweep or run directory may hand over anything: a manifest whose ``"runs"`` is a number,
a summary that is not JSON, a channel shorter than ``time``. Each is refused with a
:class:`~drivetrain.errors.FileFormatError` naming the file, the field and what was wrong, never a traceback
from deep inside a reader. Non-finite samples are not refused here (a failed run keeps what it computed):
:func:`nonfinite_counts` counts them, and the run, the manifest and the export carry the count.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from drivetrain.errors import FileFormatError

#: the largest JSON document read (a manifest of 100 000 runs is ~100 MB; a bigger one is not ours)
MAX_JSON_BYTES = 512 * 1024 * 1024

_TYPE_NAMES = {dict: "an object", list: "a list", str: "a string", bool: "true or false",
               int: "an integer", float: "a number", type(None): "null"}


def _type_text(types) -> str:
    return " or ".join(_TYPE_NAMES.get(t, t.__name__) for t in types)


def _is(value: Any, types: tuple) -> bool:
    if isinstance(value, bool):
        return bool in types
    if float in types and isinstance(value, (int, float)):
        return True
    return isinstance(value, types)


def check_fields(doc: Any, schema: Mapping[str, Any], where: str, required: tuple[str, ...] = ()) -> list[str]:
    """The problems of a JSON object against ``schema`` (field -> a type or a tuple of types; a field absent
    from the document is fine unless in ``required``; null is fine where the schema allows ``type(None)``)."""
    if not isinstance(doc, dict):
        return [f"{where}: expected a JSON object at the top, found {_type_text((type(doc),))}"]
    problems = [f"{where}: field {f!r} is missing" for f in required if f not in doc]
    for field, types in schema.items():
        types = types if isinstance(types, tuple) else (types,)
        if field in doc and not _is(doc[field], types):
            shown = json.dumps(doc[field], default=str)
            shown = shown if len(shown) <= 60 else shown[:57] + "..."
            problems.append(f"{where}: field {field!r} = {shown}: expected {_type_text(types)}")
    return problems


def parse_json(text: str | bytes, where: str, schema: Mapping[str, Any] | None = None,
               required: tuple[str, ...] = ()) -> dict:
    """A JSON object from text (a file's, an HDF5 attribute's), checked against ``schema``; ``where`` names
    it in the refusal (``"DIR/manifest.json"``, ``"RUN/signals.h5: attribute summary_json"``)."""
    try:
        doc = json.loads(text)
    except (ValueError, TypeError, RecursionError) as exc:
        raise FileFormatError([f"{where}: not JSON ({str(exc)[:120]})"]) from None
    problems = check_fields(doc, schema or {}, where, required)
    if problems:
        raise FileFormatError(problems)
    return doc


def read_json(path: Path | str, schema: Mapping[str, Any] | None = None, required: tuple[str, ...] = (),
              what: str = "file") -> dict:
    """A JSON file as an object checked against ``schema`` (see :func:`check_fields`). A missing file is
    an OSError (the callers tell "absent" from "broken"); anything else wrong is a FileFormatError naming
    the file and the field."""
    p = Path(path)
    size = p.stat().st_size
    if size > MAX_JSON_BYTES:
        raise FileFormatError([f"{p}: {size} bytes, larger than any {what} this project writes"])
    data = p.read_bytes()
    return parse_json(data, str(p), schema, required)


# --------------------------------------------------------------------------------------------------
# the documents, declared once
# --------------------------------------------------------------------------------------------------
#: a sweep's manifest.json (campaigns.sweep writes it)
MANIFEST_SCHEMA = {"runs": list, "n_runs": int, "complete": bool}
#: a record of a run in the manifest or its journal
RUN_RECORD_SCHEMA = {"name": str, "status": str, "labels": (dict, type(None)), "error": (str, type(None)),
                     "failure_time_s": (float, type(None)), "energy_residual": (float, type(None)),
                     "nonfinite_samples": (int, type(None))}
#: a run's summary.json (and the copy in signals.h5); its full layout is scene.expect.SUMMARY_TREE
SUMMARY_SCHEMA = {"status": str, "name": str, "failure": (dict, type(None)), "fault_contact": (list, type(None)),
                  "nonfinite_samples": (dict, type(None))}
#: the resolved scene kept in signals.h5 (``{"scene": {...}, "overrides": [...]}`` or the scene itself)
SCENE_SCHEMA = {"scene": dict}


def read_manifest(path: Path | str) -> dict:
    """A sweep's manifest.json, its records checked (each an object with a name)."""
    doc = read_json(path, MANIFEST_SCHEMA, required=("runs",), what="manifest")
    problems = []
    for i, r in enumerate(doc["runs"]):
        problems += check_fields(r, RUN_RECORD_SCHEMA, f"{path}: runs[{i}]", required=("name",))
    if problems:
        raise FileFormatError(problems)
    return doc


def read_summary(path: Path | str) -> dict:
    """A run's summary.json, checked."""
    return read_json(path, SUMMARY_SCHEMA, required=("status",), what="summary")


# --------------------------------------------------------------------------------------------------
# signals
# --------------------------------------------------------------------------------------------------
def check_signals(time_s: Any, signals: Mapping[str, Any], where: str) -> list[str]:
    """The problems of a signals file's arrays: ``time`` one-dimensional, finite and increasing; every
    channel one-dimensional, numeric and as long as ``time``."""
    problems = []
    t = np.asarray(time_s)
    if t.ndim != 1 or not np.issubdtype(t.dtype, np.number):
        problems.append(f"{where}: time: expected a one-dimensional numeric array, found shape {t.shape}, "
                        f"type {t.dtype}")
        return problems
    if not np.all(np.isfinite(t)):
        problems.append(f"{where}: time: {int(np.sum(~np.isfinite(t)))} samples are not finite")
    elif t.size > 1 and not np.all(np.diff(t) > 0):
        problems.append(f"{where}: time: not increasing")
    for name, x in signals.items():
        a = np.asarray(x)
        if a.ndim != 1 or not (np.issubdtype(a.dtype, np.number) or a.dtype == bool):
            problems.append(f"{where}: channel {name!r}: expected a one-dimensional numeric array, found shape "
                            f"{a.shape}, type {a.dtype}")
        elif a.size != t.size:
            problems.append(f"{where}: channel {name!r} has {a.size} samples, time has {t.size}")
    return problems


def nonfinite_counts(signals: Mapping[str, Any]) -> dict[str, int]:
    """{channel: how many of its samples are NaN or infinite}, only the channels that have any."""
    out = {}
    for name, x in signals.items():
        a = np.asarray(x)
        if np.issubdtype(a.dtype, np.floating):
            n = int(a.size - np.count_nonzero(np.isfinite(a)))
            if n:
                out[name] = n
    return out


def nonfinite_text(counts: Mapping[str, int], n_samples: int) -> str:
    """``"propeller_shaft_torque: 498 of 601 samples (83 %)"``, the channels joined."""
    return "; ".join(f"{k}: {v} of {n_samples} samples ({100.0 * v / max(n_samples, 1):.3g} %) not finite"
                     for k, v in counts.items())


def read_signals(path: Path | str) -> dict:
    """A run's signals.h5 read (run.outputs.read_hdf5) and checked: the arrays (:func:`check_signals`), the
    JSON it keeps (scene, summary) parsed with their names; ``"summary"`` holds the parsed summary (None
    without one) and ``"nonfinite_samples"`` the counts of :func:`nonfinite_counts`."""
    import h5py

    from drivetrain.run.outputs import read_hdf5

    p = Path(path)
    try:
        with h5py.File(p, "r") as f:
            problems = [f"{p}: no dataset {k!r}" for k in ("time", "signals") if k not in f]
            if not problems and not isinstance(f["signals"], h5py.Group):
                problems.append(f"{p}: 'signals' is not a group of channels")
        if problems:
            raise FileFormatError(problems)
        scene_text = None
        with h5py.File(p, "r") as f:
            scene_text = f.attrs.get("scene_json")
            if "scene_json" in f.attrs:
                # read_hdf5 parses it; a broken one is named here first
                parse_json(scene_text, f"{p}: attribute scene_json")
        h = read_hdf5(p)
    except FileFormatError:
        raise
    except Exception as exc:  # noqa: BLE001 - name the file, whatever h5py says
        raise FileFormatError([f"{p}: unreadable ({type(exc).__name__}: {str(exc)[:160]})"]) from None
    problems = check_signals(h["time"], h["signals"], str(p))
    if problems:
        raise FileFormatError(problems)
    scene = h.get("scene")
    if scene is not None and "scene" in scene and not isinstance(scene["scene"], dict):
        raise FileFormatError([f"{p}: attribute scene_json: field 'scene': expected an object"])
    summ = h["attrs"].get("summary_json")
    h["summary"] = (parse_json(summ, f"{p}: attribute summary_json", SUMMARY_SCHEMA)
                    if summ is not None else None)
    h["nonfinite_samples"] = nonfinite_counts(h["signals"])
    return h


__all__ = ["read_json", "parse_json", "check_fields", "read_manifest", "read_summary", "read_signals",
           "check_signals", "nonfinite_counts", "nonfinite_text", "MANIFEST_SCHEMA", "RUN_RECORD_SCHEMA",
           "SUMMARY_SCHEMA"]
