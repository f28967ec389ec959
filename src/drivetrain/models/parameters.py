"""The parameters of the drivetrain components, each declared once as a field of its component's parameter
dataclass (FlexibleShaftParams in models.shaft, UpperTransmissionParams in models.transmission,
MotorLoadParams in models.motors): name, type, default, unit and description (the field's metadata). The FMU
shell registers its parameters from these fields and drivetrain.fmu_build.build writes their units and descriptions
into the modelDescription.

Here: the field makers (:func:`rig_parameter`: default from the rig's data; :func:`parameter`: a fixed default;
the parameters every line model has), the readers of a field's unit and description, :func:`params_from` (a
parameter set from FMU variable values) and the parsers of the text parameters (node start values, time
profiles).
"""
from __future__ import annotations

import math
from dataclasses import field, fields

import numpy as np

from drivetrain.rig import data as rig
from gearcontact_fmu.params import POSITIVE  # the FMI min of "> 0" (declared once there)


def _rig_default(model: str, name: str):
    return rig.default_parameters(model)[name]


def rig_parameter(model: str, name: str, unit: str | None, description: str):
    """A parameter whose default is the rig's (drivetrain.rig.data, read when an instance is made)."""
    return field(default_factory=lambda: _rig_default(model, name),
                 metadata={"unit": unit, "description": description})


def parameter(default, unit: str | None, description: str, *, min=None, max=None):
    """A parameter with a fixed default; ``min``/``max``: the bounds an Integer parameter's FMU variable
    declares and refuses a value outside of (when it is set)."""
    return field(default=default, metadata={"unit": unit, "description": description, "min": min, "max": max})


def parameter_bounds(f, positive=()) -> tuple:
    """(min, max) a parameter field declares (None: unbounded); a field named in ``positive`` (the parameter
    class's ``POSITIVE_FIELDS``, the ones its component refuses unless > 0) has min :data:`POSITIVE`."""
    lo, hi = f.metadata.get("min"), f.metadata.get("max")
    if f.name in positive and lo is None:
        lo = POSITIVE
    return lo, hi


def parameter_unit(f) -> str | None:
    """The unit a parameter field declares (None: dimensionless count, option or text)."""
    return f.metadata.get("unit")


def parameter_description(f) -> str:
    return f.metadata.get("description", "")


# parameters every line model has, declared once
def max_substep_parameter():
    return parameter(1e-5, "s", "largest internal sub-step; sub-steps per communication step = ceil(H / max_substep)",
                     min=POSITIVE)


def output_torque_parameter():
    return parameter("mean", None, "what the spring-side flange torque carries: mean (over the step) | end (value "
                                   "at the step end)")


def energy_correction_parameter():
    return parameter(True, None, "true: energy-conserving correction of the spring-side flange torque (returns "
                                 "the measured work mismatch of the cut over 10 ms); false: off")


def node_start_parameter(state: str, unit: str):
    """node_phi_start / node_w_start: a start value per node of the component's chain (one place)."""
    return parameter("", None, f"start {state} [{unit}] of every node of the chain as comma-separated numbers in "
                               "the node order (LineModel.node_names, docs/FMU.md); empty = the start from the "
                               "other start parameters")


def parse_node_values(text: str, name: str, node_names) -> np.ndarray | None:
    """A node start parameter (``node_phi_start``, ``node_w_start``): comma-separated numbers, one per node
    in the order ``node_names`` -> array, or None for an empty text. ValueError naming the parameter, the
    count expected and the nodes for a wrong count, a non-number or a non-finite value (the native FMUs
    give the same message, drivetrain/fmu_build/native/line_native.c)."""
    text = (text or "").strip()
    if not text:
        return None
    names = list(node_names)
    want = (f"expected {len(names)} comma-separated values, one per node ({', '.join(names)})")
    parts = [x.strip() for x in text.split(",")]
    if len(parts) != len(names):
        raise ValueError(f"{name}: got {len(parts)} values, {want}")
    out = np.empty(len(parts))
    for i, part in enumerate(parts):
        try:
            v = float(part)
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise ValueError(f"{name}: value {i + 1} of {len(names)} ('{part}') is not a finite number; {want}")
        out[i] = v
    return out


def params_from(cls, values: dict | None = None, **kw):
    """A parameter dataclass from a dict of FMU variable values (unknown names refused)."""
    names = {f.name for f in fields(cls)}
    vals = dict(values or {})
    vals.update(kw)
    bad = sorted(set(vals) - names)
    if bad:
        raise ValueError(f"{cls.__name__}: unknown parameters {bad} (known: {sorted(names)})")
    return cls(**vals)


def parse_profile(text: str):
    """'t0:v0; t1:v1; ...' -> (times, values) arrays, or None for an empty string."""
    text = (text or "").strip()
    if not text:
        return None
    ts, vs = [], []
    for part in text.replace(",", ";").split(";"):
        part = part.strip()
        if not part:
            continue
        t, _, v = part.partition(":")
        ts.append(float(t))
        vs.append(float(v))
    ts, vs = np.array(ts), np.array(vs)
    if len(ts) == 0 or np.any(np.diff(ts) <= 0) or not (np.all(np.isfinite(ts)) and np.all(np.isfinite(vs))):
        raise ValueError(f"profile {text!r}: expected 't0:v0; t1:v1; ...' with increasing times")
    return ts, vs
