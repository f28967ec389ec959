"""The drivetrain components (no FMI) by model name: the registry the FMU shell (drivetrain.models.fmishell), the
assembler and the native build use, a component's snapshot (FMI get/set FMU state) and the steps of an FMU's
initialization (:func:`build` at enter, :func:`start_outputs`, :func:`initialize` and :func:`initial_outputs` at
exit: the shell runs them, drivetrain.models.fmu_variables.initial_dependencies runs them to find what each
output depends on).

Where each piece lives:
- drivetrain.models.line: the numerical core of all three, LineModel and its numba kernel line_step, the loss law;
- drivetrain.models.parameters: the parameter-field machinery (each FMU parameter declared once, with unit and
  description), params_from, the text parameters' parsers (node starts, profiles);
- drivetrain.models.shaft (FlexibleShaft), drivetrain.models.transmission (UpperTransmission),
  drivetrain.models.motors (MotorLoad, the PI drive): each component with its parameter dataclass.
"""
from __future__ import annotations

import copy
import math

import numpy as np

from drivetrain.errors import ComponentError
from drivetrain.models.line import LineModel
from drivetrain.models.motors import MotorLoad, MotorLoadParams
from drivetrain.models.parameters import params_from
from drivetrain.models.shaft import FlexibleShaft, FlexibleShaftParams
from drivetrain.models.transmission import UpperTransmission, UpperTransmissionParams
from drivetrain.system import SPRING

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


def build(model: str, params):
    """The component of ``model`` built from its parameter dataclass (an FMU at fmi2EnterInitializationMode)."""
    cls, _ = COMPONENTS[model]
    return cls(params)


def start_outputs(comp, outputs) -> dict:
    """The outputs among ``outputs`` that the component's state alone gives once built (the inertia side's
    angles and speeds, sensors; not the torques, which need the inputs), as floats."""
    out = comp.outputs()
    return {name: float(out[name]) for name in outputs
            if name in out and not name.endswith("_tau") and not name.endswith("_tau_mean")}


def initialize(model: str, comp, inputs: dict) -> None:
    """Hand the component its inputs at the end of initialization (``inputs``: name -> value, every input of
    the FMU: ``set_inputs`` takes them positionally in that order, drivetrain.models.fmu_variables.port_inputs);
    MotorLoad starts its load from the ``load_torque`` input and takes the inputs again."""
    values = tuple(inputs.values())
    comp.set_inputs(*values)
    if model == "MotorLoad":
        comp.initialize(load_torque=inputs["load_torque"])
        comp.set_inputs(*values)


def initial_outputs(comp, outputs) -> dict:
    """The outputs among ``outputs`` before the first step, as floats: the spring-side torques are the port
    springs against the inputs handed in (:func:`initialize`), the stored energy the ports' start state's.
    Refused with ComponentError when one is not finite."""
    ln = comp.line
    ln.start_ports()
    out = comp.outputs(energy=True)
    out["energy_stored"] = ln.stored_energy({p.name: ln.p_u0[ln.port_index[p.name]]
                                             for p in ln.ports if p.kind == SPRING})
    values = {name: float(out[name]) for name in outputs if name in out}
    if not all(map(math.isfinite, values.values())):
        bad = {n: v for n, v in values.items() if not math.isfinite(v)}
        raise ComponentError(f"the initial outputs are not finite: {bad} (check the parameters and start values)")
    return values
