"""A measured time series as a scene input: a CSV file of time and one quantity (``operating_point.load_series_csv``).

The file: one header row naming both columns with their units, then one row per point, comma-separated;
lines starting with ``#`` are comments. A unit is given as ``name_<unit>``, ``name [<unit>]`` or
``name (<unit>)``, from the scene's unit table (drivetrain.scene.schema.UNITS: ``time_s``, ``time [ms]``,
``load_torque_Nm``, ``torque [N·m]``, ...). Times start at 0 (the run's start) and increase strictly; the
values are converted to the key's unit and must be finite. Between points the series is interpolated
linearly, after the last point held (as ``load_profile_Nm``).

:func:`read_series` collects every problem of a file and raises them together (:class:`SeriesError`); the
scene module turns each into a scene problem naming the key and the file. Pure: a file in, arrays out.
"""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import numpy as np

from drivetrain.scene.schema import BASE_UNIT, UNITS

#: the fewest points a series needs (two: a line)
MIN_ROWS = 2
#: problems listed per file before the rest are summarised
MAX_LISTED = 5
_UNIT_RE = (re.compile(r"^(?P<name>.*?)\s*\[(?P<unit>[^\]]+)\]$"), re.compile(r"^(?P<name>.*?)\s*\((?P<unit>[^)]+)\)$"),
            re.compile(r"^(?P<name>.*)_(?P<unit>[^_]+)$"))


class SeriesError(ValueError):
    """A series file cannot be used: ``path`` and ``problems`` (sentences)."""

    def __init__(self, path: Path, problems: list[str]):
        self.path, self.problems = Path(path), list(problems)
        super().__init__(f"{path}: " + "; ".join(problems))


def header_unit(column: str) -> str | None:
    """The unit a header column names (``time_s``, ``time [s]``, ``time (s)``), or None."""
    col = column.strip()
    for rx in _UNIT_RE:
        m = rx.match(col)
        if m and m.group("unit").strip():
            return m.group("unit").strip()
    return None


def _column_factor(column: str, dimension: str, what: str, problems: list[str]) -> float | None:
    unit = header_unit(column)
    base = BASE_UNIT[dimension]
    expected = (f"the {what} column's header names its unit, e.g. '{what}_{base.replace('·', '')}' or "
                f"'{what} [{base}]'")
    if unit is None:
        problems.append(f"header {column.strip()!r}: no unit ({expected})")
        return None
    if unit not in UNITS:
        problems.append(f"header {column.strip()!r}: unknown unit {unit!r} ({expected})")
        return None
    dim, factor = UNITS[unit]
    if dim != dimension:
        problems.append(f"header {column.strip()!r}: a {dim} unit {unit!r} where a {dimension} is expected ({expected})")
        return None
    return factor / UNITS[base][1]


def read_series(path: str | Path, dimension: str = "torque", what: str = "torque") -> tuple[np.ndarray, np.ndarray]:
    """Time [s] and values [the base unit of ``dimension``] of a series file (module docstring); raises
    :class:`SeriesError` listing what is wrong (missing or unreadable file, header, non-numeric or non-finite
    values, wrong number of columns, time not starting at 0 or not increasing, fewer than MIN_ROWS rows)."""
    p = Path(path)
    if not p.is_file():
        raise SeriesError(p, ["no such file"])
    try:
        with open(p, newline="", encoding="utf-8") as fh:
            lines = [(i + 1, row) for i, row in enumerate(csv.reader(fh))
                     if row and not (len(row) == 1 and not row[0].strip()) and not row[0].lstrip().startswith("#")]
    except UnicodeDecodeError:
        raise SeriesError(p, ["not a UTF-8 text file (CSV expected)"]) from None
    except (OSError, csv.Error) as exc:
        raise SeriesError(p, [f"unreadable ({exc})"]) from None
    if not lines:
        raise SeriesError(p, ["empty: a header row (time and torque with units) and data rows expected"])
    problems: list[str] = []
    (hline, header), rows = lines[0], lines[1:]
    if len(header) != 2:
        problems.append(f"line {hline}: the header has {len(header)} columns, 2 expected (time, {what})")
        f_t = f_v = None
    else:
        f_t = _column_factor(header[0], "time", "time", problems)
        f_v = _column_factor(header[1], dimension, what, problems)
    data, bad = [], []
    for ln, row in rows:
        if len(row) != 2:
            bad.append(f"line {ln}: {len(row)} columns, 2 expected")
            continue
        try:
            t, v = float(row[0]), float(row[1])
        except ValueError:
            bad.append(f"line {ln}: not a number ({','.join(row)!r})")
            continue
        if not (math.isfinite(t) and math.isfinite(v)):
            bad.append(f"line {ln}: a non-finite value ({','.join(row)!r})")
            continue
        data.append((t, v))
    problems += bad[:MAX_LISTED] + ([f"... and {len(bad) - MAX_LISTED} more bad lines"] if len(bad) > MAX_LISTED else [])
    if not bad and len(data) < MIN_ROWS:
        problems.append(f"{len(data)} data row{'s' if len(data) != 1 else ''}: at least {MIN_ROWS} expected")
    if problems:
        raise SeriesError(p, problems)
    arr = np.asarray(data, dtype=float)
    t = arr[:, 0] * f_t
    v = arr[:, 1] * f_v
    if t[0] != 0.0:
        problems.append(f"time starts at {t[0]:g} s: a series starts at 0 s (the run's start)")
    back = np.flatnonzero(np.diff(t) <= 0.0)
    if back.size:
        i = int(back[0])
        problems.append(f"time does not increase strictly: {t[i + 1]:g} s after {t[i]:g} s (data row {i + 2}"
                        + (f", and {back.size - 1} more" if back.size > 1 else "") + ")")
    if problems:
        raise SeriesError(p, problems)
    return t, v


def write_load_series(name: str, path: str | Path, directory: str | Path | None = None) -> Path:
    """Write the load-motor torque setpoint of the excitation record ``name`` as a load series file
    (scene.series; ``operating_point.load_series_csv``): the motor file's column 3 over the planetary's
    ratio (the file refers it to the propeller shaft), at the times it was applied (rig.record.load_setpoint:
    the motor clock, or the log retimed onto the rig's by its load line), from 0."""
    from drivetrain.rig.record import RECORDS, load_record, load_setpoint

    r = load_record(directory, name)
    spec = RECORDS[name]
    t, x = load_setpoint(r)
    clock = ("on the motor clock." if spec.retime_line_Hz is None else
             f"retimed onto the rig's clock by its {spec.retime_line_Hz:g} Hz line (drivetrain.rig.clock: the log's "
             "index slips against the applied load).")
    return write_series(path, t, x, ("time_s", "load_motor_torque_Nm"), comments=(
        f"The load-motor torque setpoint of the rig record {name} (drivetrain/data/rig_records/{spec.motor_csv}, "
        "column 3,", f"referred there to the propeller shaft: divided here by the planetary's 8 to the load motor), {clock}",
        "Written by drivetrain.scene.series.write_load_series; read by operating_point.load_series_csv."))


def write_series(path: str | Path, t: np.ndarray, values: np.ndarray, header: tuple[str, str] = ("time_s", "torque_Nm"),
                 comments: tuple[str, ...] = ()) -> Path:
    """Write a series file :func:`read_series` reads (``comments`` as ``#`` lines first)."""
    p = Path(path)
    with open(p, "w", encoding="utf-8") as fh:
        for c in comments:
            fh.write(f"# {c}\n")
        fh.write(",".join(header) + "\n")
        for a, b in zip(np.asarray(t, dtype=float), np.asarray(values, dtype=float)):
            fh.write(f"{a:.9g},{b:.9g}\n")
    return p


__all__ = ["SeriesError", "read_series", "write_series", "write_load_series", "header_unit", "MIN_ROWS"]
