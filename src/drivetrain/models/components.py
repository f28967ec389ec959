"""The drivetrain components (no FMI) by model name: the registry the FMU shell (drivetrain.models.fmishell), the
assembler and the native build use, and a component's snapshot (FMI get/set FMU state).

Where each piece lives:
- drivetrain.models.line: the numerical core of all three, LineModel and its numba kernel line_step, the loss law;
- drivetrain.models.parameters: the parameter-field machinery (each FMU parameter declared once, with unit and
  description), params_from, the text parameters' parsers (node starts, profiles);
- drivetrain.models.shaft (FlexibleShaft), drivetrain.models.transmission (UpperTransmission),
  drivetrain.models.motors (MotorLoad, the PI drive): each component with its parameter dataclass.
"""
from __future__ import annotations

import copy

import numpy as np

from drivetrain.models.line import LineModel
from drivetrain.models.motors import MotorLoad, MotorLoadParams
from drivetrain.models.parameters import params_from
from drivetrain.models.shaft import FlexibleShaft, FlexibleShaftParams
from drivetrain.models.transmission import UpperTransmission, UpperTransmissionParams

COMPONENTS = {"FlexibleShaft": (FlexibleShaft, FlexibleShaftParams),
              "UpperTransmission": (UpperTransmission, UpperTransmissionParams),
              "MotorLoad": (MotorLoad, MotorLoadParams)}


def get_state(comp) -> dict:
    """A snapshot of a component (and its LineModel) for FMI fmi2GetFMUstate: every array copied,
    every other attribute deep-copied. :func:`set_state` writes the arrays back in place, so views
    into them (the LineModel's ``th``, ``om``, ... are views of its state vector) keep working."""
    state = {}
    for name, value in vars(comp).items():
        if isinstance(value, LineModel):
            state[name] = get_state(value)
        elif isinstance(value, np.ndarray):
            state[name] = value.copy()
        else:
            state[name] = copy.deepcopy(value)
    return state


def set_state(comp, state: dict) -> None:
    """Restore a :func:`get_state` snapshot into the same component (the same steps then repeat bit for
    bit; the snapshot stays usable for another restore)."""
    for name, value in state.items():
        current = getattr(comp, name)
        if isinstance(current, LineModel):
            set_state(current, value)
        elif isinstance(current, np.ndarray):
            current[...] = value
        else:
            setattr(comp, name, copy.deepcopy(value))


def make_component(model: str, parameters: dict | None = None):
    """Build a component from FMU-style parameter values (name -> value)."""
    cls, pcls = COMPONENTS[model]
    return cls(params_from(pcls, parameters))
