"""A lumped torsional model as a table (the layout of ``data/testbench_lumped_parameters.csv``), read checked.

Layout: ``#`` comment lines, then a header with the columns :data:`COLUMNS` (any order), then one row per node
numbered 1, 2, ... N in order. Node i has inertia ``J_kgm2`` [kg m^2] and a damping to ground
``c_ext_Nms_per_rad``; element i joins node i and node i+1 with ``k_next_Nm_per_rad``, ``c_next_Nms_per_rad``
and ``ratio_next`` = speed(i+1)/speed(i); the last node's element fields are empty.

:func:`read_lumped_table` refuses a bad file with a :class:`~drivetrain.errors.FileFormatError` whose problems
each name the file, the line and node, the column and what was wrong: every problem of the file at once. It
returns plain arrays (``drivetrain.rig.data.load_public`` wraps them as the ``PublicModel``).
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from drivetrain.errors import FileFormatError

#: the node's columns, then the element's (to the next node)
NODE_COLUMNS = ("node", "J_kgm2", "c_ext_Nms_per_rad")
ELEMENT_COLUMNS = ("k_next_Nm_per_rad", "c_next_Nms_per_rad", "ratio_next")
COLUMNS = NODE_COLUMNS + ELEMENT_COLUMNS
#: what each value must be: (strictly positive?, the words)
_RULES = {"J_kgm2": (True, "a finite inertia > 0 kg m^2"),
          "c_ext_Nms_per_rad": (False, "a finite damping >= 0 N m s/rad"),
          "k_next_Nm_per_rad": (True, "a finite stiffness > 0 N m/rad"),
          "c_next_Nms_per_rad": (False, "a finite damping >= 0 N m s/rad"),
          "ratio_next": (True, "a finite speed ratio > 0")}
#: the largest table read (a chain of this many nodes is far beyond a lumped drivetrain model)
MAX_NODES = 2000
MAX_BYTES = 4 * 1024 * 1024


def _rows(path: Path) -> list[tuple[int, list[str]]]:
    """(line number, fields) of every line that is not blank or a comment."""
    try:
        if path.stat().st_size > MAX_BYTES:
            raise FileFormatError([f"{path}: larger than {MAX_BYTES // 1024 // 1024} MB: not a lumped parameter table"])
        with open(path, newline="", encoding="utf-8") as fh:
            lines = list(csv.reader(fh))
    except FileNotFoundError:
        raise FileFormatError([f"{path}: no such file (a lumped parameter table, the layout of "
                               "testbench_lumped_parameters.csv)"]) from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise FileFormatError([f"{path}: not a readable CSV text file ({exc})"]) from None
    return [(n, [x.strip() for x in r]) for n, r in enumerate(lines, start=1)
            if r and any(x.strip() for x in r) and not r[0].lstrip().startswith("#")]


def _value(text: str, column: str, where: str, problems: list) -> float:
    positive, words = _RULES[column]
    try:
        v = float(text)
    except ValueError:
        v = math.nan
        if not text:
            problems.append(f"{where}: {column} is empty; expected {words}")
            return v
    if not (math.isfinite(v) and (v > 0 if positive else v >= 0)):
        problems.append(f"{where}: {column} = {text!r}; expected {words}")
    return v


def read_lumped_table(path: str | Path) -> dict[str, np.ndarray]:
    """The table at ``path`` as arrays ``J``, ``c_ext`` (one per node), ``k``, ``c``, ``ratio`` (one per
    element, N - 1). FileFormatError listing every problem (file, line, node, column, what was wrong)."""
    path = Path(path)
    rows = _rows(path)
    if not rows:
        raise FileFormatError([f"{path}: no header and no rows (expected the columns {', '.join(COLUMNS)})"])
    (hline, header), body = rows[0], rows[1:]
    problems: list[str] = []
    missing = [c for c in COLUMNS if c not in header]
    unknown = [h for h in header if h not in COLUMNS]
    if missing or unknown or len(set(header)) != len(header):
        what = ([f"missing column(s) {', '.join(missing)}"] if missing else []) + \
               ([f"unknown column(s) {', '.join(map(repr, unknown))}"] if unknown else []) + \
               (["a column named twice"] if len(set(header)) != len(header) else [])
        raise FileFormatError([f"{path}: line {hline} (header): {'; '.join(what)}; expected the columns "
                               f"{', '.join(COLUMNS)}"])
    if len(body) < 2:
        raise FileFormatError([f"{path}: {len(body)} node row(s); a torsional chain needs at least 2 nodes"])
    if len(body) > MAX_NODES:
        raise FileFormatError([f"{path}: {len(body)} node rows; at most {MAX_NODES}"])
    col = {h: i for i, h in enumerate(header)}
    out = {"J": [], "c_ext": [], "k": [], "c": [], "ratio": []}
    n_nodes = len(body)
    for i, (line, r) in enumerate(body, start=1):
        where = f"{path}: line {line} (node {i})"
        if len(r) != len(header):
            problems.append(f"{where}: {len(r)} fields, the header has {len(header)}")
            continue
        if r[col["node"]] != str(i):
            problems.append(f"{path}: line {line}: unknown row: node {r[col['node']]!r} where node {i} was expected "
                            "(nodes are numbered 1, 2, ... in order, one row each)")
            continue
        out["J"].append(_value(r[col["J_kgm2"]], "J_kgm2", where, problems))
        out["c_ext"].append(_value(r[col["c_ext_Nms_per_rad"]], "c_ext_Nms_per_rad", where, problems))
        if i == n_nodes:
            given = [c for c in ELEMENT_COLUMNS if r[col[c]]]
            if given:
                problems.append(f"{where}: the last node has no next element; {', '.join(given)} must be empty")
            continue
        for key, c in zip(("k", "c", "ratio"), ELEMENT_COLUMNS):
            out[key].append(_value(r[col[c]], c, where, problems))
    if problems:
        raise FileFormatError(problems)
    return {k: np.array(v, dtype=float) for k, v in out.items()}
