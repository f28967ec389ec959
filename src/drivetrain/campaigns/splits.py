"""Class labels and a gearbox-level train/validation/test split of a dataset's runs.

Every run of ``drivetrain dataset`` and ``drivetrain features`` gets four columns from its labels:

- ``label``: ``healthy``, or the fault family and member of each fault, ``<kind>/<member>`` (``pit/wheel``;
  several faults joined by ``+``, in their order; a mesh-file gear ``mesh``);
- ``faulty``: ``label != "healthy"`` (bool);
- ``gearbox``: which physical gearbox the run is, the unit a split keeps together: ``manufacturing.seed``
  when the run draws its manufacturing errors (``gearbox = "seed<N>"``; a drawn fault and its paired healthy
  twin, or one gearbox at several operating points, share it); without manufacturing errors every run is the
  same ideal gearbox, and the unit is the run's noise pair (``scenario.noise_name``: a faulty run and its
  healthy twin), else the run itself (``run:<name>``);
- ``split``: ``train``, ``validation`` or ``test``, drawn per gearbox (never one gearbox in two sets),
  deterministic from ``seed`` and the set of gearboxes, with ``fractions`` of the gearboxes in each set
  (default :data:`DEFAULT_FRACTIONS`; the counts are the largest-remainder rounding of fractions × gearboxes).
"""
from __future__ import annotations

import zlib
from typing import Iterable

import numpy as np

#: the share of the gearboxes in train, validation and test when nothing else is asked
DEFAULT_FRACTIONS = (0.7, 0.15, 0.15)
#: the seed of the split when nothing else is asked
DEFAULT_SPLIT_SEED = 0
SPLITS = ("train", "validation", "test")
HEALTHY = "healthy"
#: the columns :func:`class_columns` adds, with their meaning (the dataset card lists them)
CLASS_COLUMNS = {
    "label": "healthy, or each fault as <kind>/<member> (several joined by +; a mesh-file gear: mesh)",
    "faulty": "the run has a fault (label != healthy)",
    "gearbox": "the physical gearbox (seed<manufacturing.seed>, else the noise pair or the run): a split's unit",
    "split": "train / validation / test, drawn per gearbox (one gearbox never in two sets)",
}


def class_label(labels: dict) -> str:
    """``healthy``, ``<kind>/<member>`` of each fault (``fault<i>.kind``, ``fault<i>.member``) joined by ``+``,
    or ``mesh`` for a gear given by mesh files."""
    faults = []
    i = 0
    while labels.get(f"fault{i}.kind") is not None:
        faults.append(f"{labels[f'fault{i}.kind']}/{labels.get(f'fault{i}.member') or 'pinion'}")
        i += 1
    if faults:
        return "+".join(faults)
    return "mesh" if labels.get("gear.health") == "mesh" else HEALTHY


def gearbox_of(labels: dict) -> str:
    """The gearbox a run is (see the module docstring)."""
    seed = labels.get("manufacturing.seed")
    if seed is not None:
        return f"seed{int(seed)}"
    pair = labels.get("scenario.noise_name")
    return f"pair:{pair}" if pair else f"run:{labels.get('run')}"


def check_fractions(fractions: Iterable[float]) -> tuple[float, float, float]:
    """Three non-negative shares (train, validation, test) that add up to 1 (within 1e-6); ValueError else."""
    try:
        f = tuple(float(x) for x in fractions)
    except (TypeError, ValueError):
        raise ValueError(f"split fractions {fractions!r}: expected three numbers (train, validation, test)") from None
    if len(f) != 3 or any(not np.isfinite(x) or x < 0 for x in f) or abs(sum(f) - 1.0) > 1e-6:
        raise ValueError(f"split fractions {f}: expected three non-negative shares (train, validation, test) "
                         "adding up to 1")
    return f  # type: ignore[return-value]


def assign_splits(gearboxes: Iterable[str], fractions=DEFAULT_FRACTIONS, seed: int = DEFAULT_SPLIT_SEED) -> dict:
    """{gearbox: split}: the distinct gearboxes in a seeded random order (independent of the order they come
    in), the first share to train, then validation, then test; the counts are fractions × gearboxes rounded by
    largest remainder (they add up to the number of gearboxes)."""
    f = check_fractions(fractions)
    boxes = sorted(set(gearboxes))
    n = len(boxes)
    exact = [x * n for x in f]
    counts = [int(np.floor(e)) for e in exact]
    for i in sorted(range(3), key=lambda i: exact[i] - counts[i], reverse=True)[:n - sum(counts)]:
        counts[i] += 1
    # a stable order from the seed and each gearbox's name: adding a gearbox does not reshuffle the others
    keyed = sorted(boxes, key=lambda b: (zlib.crc32(f"{int(seed)}:{b}".encode()), b))
    out, start = {}, 0
    for name, k in zip(SPLITS, counts):
        out.update({b: name for b in keyed[start:start + k]})
        start += k
    return out


def class_columns(labels_of_runs: list[dict], fractions=DEFAULT_FRACTIONS, seed: int = DEFAULT_SPLIT_SEED) -> list[dict]:
    """The four columns of :data:`CLASS_COLUMNS` for each run's labels, in order."""
    boxes = [gearbox_of(lab) for lab in labels_of_runs]
    split = assign_splits(boxes, fractions, seed)
    out = []
    for lab, box in zip(labels_of_runs, boxes):
        label = class_label(lab)
        out.append({"label": label, "faulty": label != HEALTHY, "gearbox": box, "split": split[box]})
    return out


__all__ = ["class_label", "gearbox_of", "assign_splits", "class_columns", "check_fractions", "DEFAULT_FRACTIONS",
           "DEFAULT_SPLIT_SEED", "SPLITS", "HEALTHY", "CLASS_COLUMNS"]
