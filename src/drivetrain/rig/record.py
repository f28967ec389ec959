"""The rig's measured record (500 rpm, 1.31 N·m; ``drivetrain/data/rig_records``) and the figures a run is
compared with it by.

The record (a later campaign of the same rig, 2023; provenance in its README) holds both torque
transducers and two encoder speeds at 3012.06 Hz for 1.99 s, and the motor drives' own signals at 1 kHz.
Its first samples are a filter's start-up: :data:`SKIP_S` is left out, leaving a window of
:data:`WINDOW_S`. Every figure is computed alike for the record and for a run (:func:`background_figures`):
the run is cut into windows of the record's length (the amplitude of a broadband floor per spectral bin
depends on the window length), each window's amplitude spectrum taken as every spectrum of the project
(rig.signals.amplitude_spectrum: Hann, amplitude-corrected), and the figures of the windows averaged
(amplitudes in power). The figures, per torque signal:

* ``std``: standard deviation [N·m];
* ``f_GMF``, ``f_MSH``, ``f_DSH``: the largest amplitude within ``LINE_HALF_WIDTH_HZ`` of the line [N·m];
* ``hump_27``, ``hump_58``: the largest amplitude in :data:`HUMPS` (the record's two broadband humps);
* ``floor``: the median amplitude in f_GMF ± :data:`FLOOR_HALF_WIDTH_HZ` (lines and humps count little
  in a median) [N·m].

The comparison of means needs a word: the record's mean torques (2.51 / 12.15 N·m) are not the paper's
campaign's (1.63 / 13.93 N·m at the same point: another state of the rig's losses). The figures above are
of the fluctuation about the mean, which the loss state changes little; the means are compared with the
paper's 18 points (check 1), not with the record. Pure: arrays in, numbers out.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivetrain.rig.data import PG_RATIO, TORQUE_SENSORS
from drivetrain.rig.signals import amplitude_spectrum, characteristic_frequencies

RECORD_DIR = Path(__file__).resolve().parents[1] / "data" / "rig_records"
SENSOR_CSV = "baseline_500rpm_constant_load_sensor.csv"
MOTOR_CSV = "baseline_500rpm_constant_load_motor.csv"
#: the record's operating point
RECORD_SPEED_RPM = 500.0
RECORD_LOAD_NM = 1.309
#: the filter start-up at the record's beginning, left out of every analysis [s]
SKIP_S = 0.15
#: the analysed length of the record (and of each window of a run) [s]
WINDOW_S = 1.84
HUMPS = {"hump_27": (24.0, 32.0), "hump_58": (54.0, 64.0)}
LINE_HALF_WIDTH_HZ = 0.6
FLOOR_HALF_WIDTH_HZ = 10.0
#: the transducers' white noise [N·m RMS at 3012 Hz] in the record: the median PSD over 300-1000 Hz, where the
#: torque spectra are flat (campaigns.record_fit, step 1); the record scene and the validation use them
MEASURED_TRANSDUCER_NOISE_NM = {"drive_torque_noise_Nm": 0.00048, "propeller_torque_noise_Nm": 0.0080}
FIGURES = ("std", "f_GMF", "f_MSH", "f_DSH", "hump_27", "hump_58", "floor")
TORQUES = TORQUE_SENSORS


@dataclass(frozen=True)
class Record:
    """A measured record: sensor time [s] and channels at ``fs`` [Hz]; the motor drives' signals at ``fs_motor``
    (their own clock, not synchronised with the sensors'); ``name`` one of :data:`RECORDS`."""

    fs: float
    t: np.ndarray
    channels: dict            # drive_shaft_torque, propeller_shaft_torque [N·m], enc1_w, enc2_w [rad/s]
    fs_motor: float
    motor: dict               # baseline: drive_motor_w, load_motor_w [rad/s], drive_motor_torque, load_motor_torque
    #                           excitations: drive_motor_torque, load_motor_torque_set, load_motor_torque [N·m]
    name: str = "baseline_500rpm"
    t_motor: np.ndarray | None = None


@dataclass(frozen=True)
class RecordSpec:
    """One shipped record: its files, the motor file's columns (after time) and the factor that brings each to
    the load motor (the excitation files give the load torque referred to the propeller shaft, x8), its
    operating point."""

    sensor_csv: str
    motor_csv: str
    motor_columns: tuple
    speed_rpm: float
    load_Nm: float
    #: the load line [Hz, near] by which the motor log is retimed onto the rig's clock (rig.clock), or None: the
    #: log's own clock holds (a slow setpoint, a constant load)
    retime_line_Hz: float | None = None


_EXCITATION_MOTOR = (("drive_motor_torque_set", 1.0), ("drive_motor_torque", 1.0),
                     ("load_motor_torque_set", 1.0 / PG_RATIO), ("load_motor_torque", 1.0 / PG_RATIO))
#: the shipped records (README in RECORD_DIR): name -> files and columns
RECORDS = {
    "baseline_500rpm": RecordSpec(SENSOR_CSV, MOTOR_CSV, (("drive_motor_w", 1.0), ("load_motor_w", 1.0),
                                                          ("drive_motor_torque", 1.0), ("load_motor_torque", 1.0)),
                                  RECORD_SPEED_RPM, RECORD_LOAD_NM),
    "impulse_2004rpm": RecordSpec("excitation_2004rpm_impulse_sensor.csv", "excitation_2004rpm_impulse_motor.csv",
                                  _EXCITATION_MOTOR, 2004.0, 0.119),
    "sine_2004rpm": RecordSpec("excitation_2004rpm_sin_sensor.csv", "excitation_2004rpm_sin_motor.csv",
                               _EXCITATION_MOTOR, 2004.0, 1.309, retime_line_Hz=32.1),
}
SENSOR_COLUMNS = ("enc1_w", "enc2_w", "drive_shaft_torque", "propeller_shaft_torque")


class RecordError(ValueError):
    """A record file cannot be used: the message names the file and the problem."""


def read_columns(path: str | Path, n_columns: int) -> np.ndarray:
    """The rows of a headerless numeric CSV record file with time first; refuses (RecordError naming the file):
    a missing or unreadable file, no rows, a single row, a row of another width than ``n_columns``, a
    non-numeric or non-finite value, time not increasing strictly."""
    p = Path(path)
    if not p.is_file():
        raise RecordError(f"{p}: no such record file")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise RecordError(f"{p}: unreadable ({exc})") from None
    rows = [(i + 1, ln) for i, ln in enumerate(text.splitlines()) if ln.strip()]
    if not rows:
        raise RecordError(f"{p}: empty record (no rows)")
    if len(rows) == 1:
        raise RecordError(f"{p}: a single row: a record needs at least two samples")
    out = np.empty((len(rows), n_columns))
    for k, (ln, line) in enumerate(rows):
        cells = line.split(",")
        if len(cells) != n_columns:
            raise RecordError(f"{p}: line {ln} has {len(cells)} columns, {n_columns} expected")
        try:
            out[k] = [float(c) for c in cells]
        except ValueError:
            raise RecordError(f"{p}: line {ln}: not a number ({line.strip()[:80]!r})") from None
        if not np.all(np.isfinite(out[k])):
            raise RecordError(f"{p}: line {ln}: a non-finite value ({line.strip()[:80]!r})")
    dt = np.diff(out[:, 0])
    if np.any(dt <= 0):
        i = int(np.flatnonzero(dt <= 0)[0])
        raise RecordError(f"{p}: time does not increase at line {rows[i + 1][0]} ({out[i + 1, 0]:g} s after {out[i, 0]:g} s)")
    return out


def load_record(directory: str | Path | None = None, name: str = "baseline_500rpm") -> Record:
    """Read a record's two CSV files (``name`` from :data:`RECORDS`; columns as in its README); RecordError
    naming the file when one cannot be used (:func:`read_columns`)."""
    if name not in RECORDS:
        raise RecordError(f"unknown record {name!r}: one of {', '.join(RECORDS)}")
    spec = RECORDS[name]
    d = Path(directory) if directory is not None else RECORD_DIR
    s = read_columns(d / spec.sensor_csv, 1 + len(SENSOR_COLUMNS))
    m = read_columns(d / spec.motor_csv, 1 + len(spec.motor_columns))
    fs = 1.0 / float(np.median(np.diff(s[:, 0])))
    fm = 1.0 / float(np.median(np.diff(m[:, 0])))
    ch = {k: s[:, i + 1] for i, k in enumerate(SENSOR_COLUMNS)}
    mo = {k: m[:, i + 1] * f for i, (k, f) in enumerate(spec.motor_columns)}
    return Record(fs, s[:, 0] - s[0, 0], ch, fm, mo, name, m[:, 0] - m[0, 0])


def load_setpoint(r: Record) -> tuple[np.ndarray, np.ndarray]:
    """The times [s, from 0] and values [N·m at the load motor] of an excitation record's load-torque setpoint,
    as applied: on the motor log's clock, or, for a record whose log slips against the rig
    (``RecordSpec.retime_line_Hz``), retimed so that its load line runs at the propeller torque's response line
    on the sensor clock (rig.clock). RecordError for a record without a setpoint."""
    from drivetrain.rig import clock

    if "load_motor_torque_set" not in r.motor:
        raise RecordError(f"record {r.name!r} holds no load-torque setpoint (a constant-load record)")
    x = np.asarray(r.motor["load_motor_torque_set"], dtype=float)
    near = RECORDS[r.name].retime_line_Hz if r.name in RECORDS else None
    if near is None:
        return r.t_motor, x
    try:
        true_Hz = clock.line_frequency(r.channels["propeller_shaft_torque"], r.fs, near)
        return clock.retime_by_line(x, r.fs_motor, near, true_Hz), x
    except clock.ClockError as exc:
        raise RecordError(f"record {r.name!r}: its load setpoint cannot be retimed ({exc})") from None


#: the scene of each excitation record and the load series file it names (scenarios/validation)
EXCITATION_SCENES = {"impulse_2004rpm": ("rig_impulse_2004rpm.toml", "rig_impulse_2004rpm_load.csv"),
                     "sine_2004rpm": ("rig_sine_2004rpm.toml", "rig_sine_2004rpm_load.csv")}


def windows(x: np.ndarray, fs: float, skip_s: float = SKIP_S, window_s: float = WINDOW_S) -> list[np.ndarray]:
    """Consecutive windows of ``window_s`` after ``skip_s`` (at least one: a shorter signal is one window)."""
    x = np.asarray(x, dtype=float)[int(round(skip_s * fs)):]
    n = int(round(window_s * fs))
    if len(x) <= n:
        return [x]
    return [x[i * n:(i + 1) * n] for i in range(len(x) // n)]


def _figures_one(x: np.ndarray, fs: float, speed_rpm: float) -> dict:
    f, a = amplitude_spectrum(x, fs)
    cf = characteristic_frequencies(speed_rpm)
    lines = {k: cf[k] for k in ("f_GMF", "f_MSH", "f_DSH")}
    out = {"std": float(np.std(x))}
    for name, fl in lines.items():
        sel = np.abs(f - fl) <= LINE_HALF_WIDTH_HZ
        out[name] = float(a[sel].max()) if sel.any() else float("nan")
    for name, (lo, hi) in HUMPS.items():
        sel = (f >= lo) & (f <= hi)
        out[name] = float(a[sel].max())
    sel = np.abs(f - lines["f_GMF"]) <= FLOOR_HALF_WIDTH_HZ
    out["floor"] = float(np.median(a[sel]))
    return out


def background_figures(x: np.ndarray, fs: float, speed_rpm: float = RECORD_SPEED_RPM,
                       skip_s: float = SKIP_S) -> dict:
    """The figures of one torque signal (module docstring), averaged over the record-length windows
    (std and amplitudes in power); ``n_windows`` says how many."""
    per = [_figures_one(w, fs, speed_rpm) for w in windows(x, fs, skip_s)]
    out = {k: float(np.sqrt(np.mean([p[k] ** 2 for p in per]))) for k in FIGURES}
    out["n_windows"] = len(per)
    return out


def record_figures(record: Record | None = None) -> dict:
    """The record's figures per torque transducer."""
    r = record or load_record()
    return {name: background_figures(r.channels[name], r.fs) for name in TORQUES}


def ratio_dB(sim: float, measured: float) -> float:
    """20 log10(sim / measured): amplitude ratio in dB."""
    return float(20.0 * np.log10(sim / measured)) if sim > 0 and measured > 0 else float("nan")


__all__ = ["MEASURED_TRANSDUCER_NOISE_NM", "Record", "RecordError", "RECORDS", "read_columns", "load_record", "load_setpoint", "EXCITATION_SCENES", "windows", "background_figures", "record_figures",
           "ratio_dB", "FIGURES", "HUMPS", "TORQUES", "SKIP_S", "WINDOW_S", "RECORD_SPEED_RPM", "RECORD_LOAD_NM"]
