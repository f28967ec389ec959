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
import math
from pathlib import Path

import numpy as np

from drivetrain.errors import DatasetError
from drivetrain.rig import indicators as ci
from drivetrain.rig.data import Z_PINION, Z_WHEEL
from drivetrain.rig.signals import amplitude_near, amplitude_spectrum, characteristic_frequencies

#: the shafts whose gear is judged: name -> (encoder sensor, teeth, characteristic frequency of its speed)
SHAFTS = {"pinion": ("enc4", Z_PINION, "f_MSH"), "wheel": ("enc5", Z_WHEEL, "f_PSH")}
TORQUES = ("propeller_shaft_torque", "drive_shaft_torque")
#: TSA records per run (NA4 and NB4 compare the last with the run's mean); fewer when the run is short
RECORDS = 4
#: the characteristic frequencies whose amplitude is a column (keys of rig.signals.characteristic_frequencies)
LINES = ("f_PSH", "f_MSH", "f_DSH", "f_GMF", "f_GMF-f_MSH", "f_GMF+f_MSH")
FEATURES_FILE = "features.parquet"


def _line(cf: dict, name: str) -> float:
    if "-" in name or "+" in name:
        sign = 1.0 if "+" in name else -1.0
        a, b = name.replace("+", "-").split("-")
        return cf[a] + sign * cf[b]
    return cf[name]


def run_features(time: np.ndarray, signals: dict, settle_s: float, drive_speed_rpm: float) -> dict:
    """The indicator columns of one run (module docstring); signals it lacks give no columns."""
    t = np.asarray(time, dtype=float)
    keep = t >= settle_s
    if keep.sum() < 16:
        raise ValueError(f"{int(keep.sum())} samples after the settling time {settle_s:g} s: too short")
    fs = 1.0 / float(np.median(np.diff(t)))
    cf = characteristic_frequencies(drive_speed_rpm)
    out: dict = {}
    for sig in TORQUES:
        if sig not in signals:
            continue
        x = np.asarray(signals[sig], dtype=float)[keep]
        f, a = amplitude_spectrum(x, fs)
        for ln in LINES:
            out[f"amp_{ln}.{sig}"] = amplitude_near(f, a, _line(cf, ln), 1)
        for shaft, (enc, teeth, f_key) in SHAFTS.items():
            if enc not in signals:
                continue
            angle = np.asarray(signals[enc], dtype=float)[keep]
            angle = angle + 1e-12 * np.arange(len(angle))     # a quantised encoder repeats a count: make it increase
            revs = (angle[-1] - angle[0]) / (2 * math.pi)
            n_rec = max(1, min(RECORDS, int(revs // 2)))
            pts = ci.points_per_revolution(fs, cf[f_key])
            try:
                recs = ci.tsa_records(x, angle, pts, n_rec)
            except ValueError:
                continue
            for metric, value in ci.indicators(recs, teeth).items():
                out[f"{metric}_{shaft}.{sig}"] = value
    return out


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


def features(directory: str | Path) -> list[dict]:
    """One row per run: its labels and its indicator columns. The runs are read one at a time (a study of
    thousands of runs never holds their signals together); a healthy run's torques are kept while a faulty
    run paired with it (one ``scenario.noise_name``) may follow."""
    d = Path(directory)
    rows = []
    twins: dict = {}
    for r in _iter_runs(d):
        lab = r["labels"]
        settle = float(lab.get("time.settle_s") or 0.0)
        speed = lab.get("operating_point.drive_speed_rpm")
        if speed is None or not float(speed) > 0:
            raise DatasetError(f"{d}: run {r['name']} has no constant drive speed (its characteristic frequencies "
                               "and shaft orders need one)")
        try:
            cols = run_features(r["time"], r["signals"], settle, float(speed))
        except ValueError as exc:
            raise DatasetError(f"{d}: run {r['name']}: {exc}") from None
        pair = lab.get("scenario.noise_name")
        if pair and lab.get("gear.health") == "healthy":
            twins[pair] = {"time": r["time"], "signals": {k: r["signals"][k] for k in TORQUES if k in r["signals"]}}
        elif pair and pair in twins:
            h = twins[pair]
            keep = np.asarray(r["time"]) >= settle
            for sig in TORQUES:
                if sig in r["signals"] and sig in h["signals"]:
                    cols[f"SBR_dB.{sig}"] = ci.signal_to_background_dB(np.asarray(r["signals"][sig])[keep],
                                                                       np.asarray(h["signals"][sig])[keep])
        rows.append({**lab, **cols})
    return rows


def write_features(directory: str | Path, out: str | Path | None = None) -> Path:
    """``DIR/features.parquet`` (or ``out``): the rows of :func:`features`, a column per label and indicator."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    rows = features(directory)
    cols: list[str] = []
    for r in rows:
        cols += [k for k in r if k not in cols]
    table = pa.table({c: [_cell(r.get(c)) for r in rows] for c in cols})
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
