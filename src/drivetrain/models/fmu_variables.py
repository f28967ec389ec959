"""The drivetrain FMUs' declarations (FlexibleShaft, UpperTransmission, MotorLoad), once, as plain data (nothing
of pythonfmu): model information (description, author, version, default experiment), variables in
value-reference order (:func:`variables`), units, descriptions, bounds and initial dependencies.

Both builds read them here: the pythonfmu slaves (rendered from ``fmu_runtime.slave_template``, their FMI
plumbing ``drivetrain.models.fmishell``) register the variables and take their class attributes from
:func:`declaration`; the native builder (``drivetrain.fmu_build.native_line``) writes its variable table and
modelDescription.xml from it without a slave. The parameters are the fields of the component's parameter
dataclass (drivetrain.models.parameters: name, default, unit, description); the flange variables follow from
the port kinds (``gearcontact_fmu.params.flange_variables``); each model's own inputs and outputs are declared
here (:data:`OWN_INPUTS`, :data:`OWN_OUTPUTS`). The initial dependencies are found by running the
initialization the shell runs (``drivetrain.models.components.start_outputs``, ``initialize``,
``initial_outputs``), not declared a second time.
"""
from __future__ import annotations

import dataclasses

from drivetrain.models import components as C
from drivetrain.models.motors import RPM
from drivetrain.models.parameters import parameter_bounds, parameter_description, parameter_unit, params_from
from drivetrain.system import INERTIA, SPRING
from fmu_runtime.declaration import Experiment, FmuDeclaration, Variable
from gearcontact_fmu.params import DEFAULT_COMM_STEP_S, flange_variables

#: the model information every drivetrain FMU shares
AUTHOR = "bevel-drivetrain"
VERSION = "0.1.0"

#: per model: the modelDescription's DefaultExperiment (the step the FMUs are validated at), long enough for the shipped example input (drivetrain.fmu_build.fmu_docs: the
#: operating point ramped in over 0.25 s) to settle: UpperTransmission, driven by torques alone, reaches its speed
#: through its loss law (time constant about 0.2 s at speed). No tolerance: the models integrate with fixed sub-steps.
DEFAULT_EXPERIMENTS = {
    "FlexibleShaft": Experiment(start_time=0.0, stop_time=1.0, step_size=DEFAULT_COMM_STEP_S),
    "UpperTransmission": Experiment(start_time=0.0, stop_time=2.0, step_size=DEFAULT_COMM_STEP_S),
    "MotorLoad": Experiment(start_time=0.0, stop_time=2.0, step_size=DEFAULT_COMM_STEP_S),
}

#: per model: ports (name -> drivetrain.system.SPRING | INERTIA, as the component declares them)
PORTS = {model: dict(cls.PORTS) for model, (cls, _) in C.COMPONENTS.items()}
#: extra inputs that a parameter of the same FMU can carry as a time profile ('t0:v0; t1:v1; ...',
#: linear between points, held outside; parameters.parse_profile): a host without input signals sets
#: the parameter instead (drivetrain.interop.ssp)
INPUT_PROFILES = {
    "MotorLoad": {"speed_ref_rpm": "speed_profile", "load_torque": "load_profile"},
}
#: per model: its own outputs, each declared once: name -> (unit, description); then the energies every
#: drivetrain FMU has (ENERGY). Parameters are declared in the component's parameter dataclass (name,
#: default, unit, description: drivetrain.models.parameters); the flange variables follow from the port kinds.
#: the output of every FMU with a spring-side cut (its port's energy correction)
COUPLING_ENERGY_ERROR = ("J", "work mismatch of the spring-side cut since t = 0 not yet corrected (energy audit)")
OWN_OUTPUTS = {
    "FlexibleShaft": {
        "flange_b_tau_mean": ("N.m", "exact mean over the last step of the torque at flange_b"),
        "torque_sensor": ("N.m", "drive-shaft torque transducer reading (the section between its hubs)"),
        "shaft_torque": ("N.m", "torque in the thin shaft at its flange_b end"),
        "hub_b_phi": ("rad", "angle of transducer hub B"),
        "hub_b_w": ("rad/s", "speed of transducer hub B"),
        "coupling_energy_error": COUPLING_ENERGY_ERROR,
    },
    "UpperTransmission": {
        "torque_sensor": ("N.m", "drive-shaft transducer torque (rigid shafts: flange_a torque minus J_sensor "
                                 "acceleration)"),
        "loss_torque": ("N.m", "loss torque of the gearbox on the input shaft"),
    },
    "MotorLoad": {
        "drive_tau_mean": ("N.m", "exact mean over the last step of the torque at flange drive"),
        "motor_phi": ("rad", "drive motor angle (encoder 1)"),
        "motor_w": ("rad/s", "drive motor speed"),
        "flywheel_phi": ("rad", "drive flywheel angle"),
        "flywheel_w": ("rad/s", "drive flywheel speed"),
        "motor_torque": ("N.m", "drive motor air-gap torque (step mean: the PI controller's torque plus "
                                "motor_torque_disturbance)"),
        "load_motor_torque": ("N.m", "load motor torque at the propeller shaft"),
        "load_motor_w": ("rad/s", "load motor speed"),
        "coupling_torque": ("N.m", "torque in coupling C1"),
        "coupling_energy_error": COUPLING_ENERGY_ERROR,
    },
}
#: per model: its extra inputs (beside the flange inputs): name -> (unit, description)
OWN_INPUTS = {
    "FlexibleShaft": {},
    "UpperTransmission": {},
    "MotorLoad": {
        "speed_ref_rpm": ("rpm", "drive motor speed reference"),
        "load_torque": ("N.m", "load motor torque setting (at the load motor; times ratio_pg at the propeller "
                               "shaft)"),
        "motor_torque_disturbance": ("N.m", "torque added to the drive motor's controlled torque on its rotor, after "
                                            "the PI controller and its torque limit (the drive's torque noise and "
                                            "ripple; 0 = none)"),
    },
}
ENERGY = {
    "energy_stored": ("J", "kinetic and elastic energy inside the FMU"),
    "energy_dissipated": ("J", "energy dissipated inside the FMU since t = 0 (dampers, losses)"),
    "energy_supplied": ("J", "work done by sources inside the FMU since t = 0 (motors)"),
}
#: per model: its own outputs and extra inputs (beside the flanges), by name in declaration order
OUTPUTS = {model: tuple(table) for model, table in OWN_OUTPUTS.items()}
EXTRA_INPUTS = {model: tuple(table) for model, table in OWN_INPUTS.items()}
#: the ``error`` output of every FMU (fmu_runtime.guard)
ERROR_DESCRIPTION = "empty while the instance works; after a failure, why it failed (every Real output is then NaN)"
_FLANGE_DESCRIPTIONS = {
    SPRING: ("angle of the body connected to flange {p} (input, spring side)",
             "speed of the body connected to flange {p} (input, spring side)",
             "torque flange {p} applies to the connected body (output, spring side)"),
    INERTIA: ("angle of the body at flange {p} (output, inertia side)",
              "speed of the body at flange {p} (output, inertia side)",
              "torque the connected neighbour applies at flange {p} (input, inertia side)"),
}

DESCRIPTIONS = {
    "FlexibleShaft": ("Drive-shaft line of the azimuth-thruster rig: transducer hubs, stiff coupling and the thin "
                      "drive shaft in n_elements elements (implicit midpoint sub-stepping, numba). flange_a inertia "
                      "side, flange_b spring side (the last shaft element)."),
    "UpperTransmission": ("Upper 3:1 bevel gearbox as one rigid geared body with its inertias and the calibrated "
                          "speed-dependent loss; both flanges inertia side."),
    "MotorLoad": ("Drive motor under PI speed control (torque limit, LimPID anti-windup) with coupling C1 and the "
                  "flywheel (flange drive: spring side, coupling C2), and the load side: propeller flywheel, 1:8 "
                  "planetary with its calibrated loss, load motor torque setting (flange load: inertia side)."),
}


def variable_table(model: str) -> dict:
    """Every variable of a drivetrain FMU but ``error``: name -> (unit or None, description), from the
    declarations (parameter fields, flanges by port kind, own inputs and outputs, energies)."""
    _, pcls = C.COMPONENTS[model]
    out = {f.name: (parameter_unit(f), parameter_description(f)) for f in dataclasses.fields(pcls)}
    for p, kind in PORTS[model].items():
        for (name, unit, _), text in zip(flange_variables(p, kind), _FLANGE_DESCRIPTIONS[kind]):
            out[name] = (unit, text.format(p=p))
    out.update(OWN_INPUTS[model])
    out.update(OWN_OUTPUTS[model])
    out.update(ENERGY)
    return out


def _units() -> dict:
    units: dict[str, str] = {}
    for model in C.COMPONENTS:
        for name, (unit, _) in variable_table(model).items():
            if unit is None:
                continue
            if units.setdefault(name, unit) != unit:
                raise ValueError(f"variable {name} has unit {units[name]} in one drivetrain FMU and {unit} in "
                                 f"{model}: one name, one unit")
    return units


#: variable name -> unit, over all drivetrain FMUs (a name has one unit in every FMU that has it)
UNITS = _units()


def bounds(model: str) -> dict:
    """Parameter name -> (min, max) of a drivetrain FMU (the modelDescription's min/max, drivetrain.fmu_build.build):
    the bounds its parameter fields declare and the ones its component refuses unless > 0."""
    _, pcls = C.COMPONENTS[model]
    positive = getattr(pcls, "POSITIVE_FIELDS", ())
    out = {f.name: parameter_bounds(f, positive) for f in dataclasses.fields(pcls)}
    return {n: b for n, b in out.items() if b != (None, None)}


def variable_descriptions(model: str) -> dict:
    """Variable name -> description of a drivetrain FMU (modelDescription ``description``)."""
    out = {name: text for name, (_, text) in variable_table(model).items()}
    out["error"] = ERROR_DESCRIPTION
    return out


def port_inputs(model: str) -> list[str]:
    out = []
    for p, kind in PORTS[model].items():
        out += [name for name, _, causality in flange_variables(p, kind) if causality == "input"]
    return out + list(EXTRA_INPUTS[model])


def port_outputs(model: str) -> list[str]:
    out = []
    for p, kind in PORTS[model].items():
        out += [name for name, _, causality in flange_variables(p, kind) if causality == "output"]
    return out + list(OUTPUTS[model]) + list(ENERGY)


def variables(model: str) -> tuple[Variable, ...]:
    """Every variable of a drivetrain FMU in value-reference order, as its slave registers it: the parameters
    (the fields of the parameter dataclass, at their defaults: Boolean, Integer with the bounds its field
    declares, String or Real; variability fixed), the inputs (:func:`port_inputs`, at 0; MotorLoad's speed
    reference at the default drive speed), the outputs (:func:`port_outputs`, at 0) and ``error`` (discrete)."""
    _, pcls = C.COMPONENTS[model]
    defaults = pcls()
    rows = []
    for f in dataclasses.fields(pcls):
        v = getattr(defaults, f.name)
        if isinstance(v, bool):
            rows.append(("Boolean", f.name, "parameter", v, "fixed", None, None))
        elif isinstance(v, int):
            # refused when set outside (fmu_runtime.guard); the modelDescription's min/max come from bounds()
            rows.append(("Integer", f.name, "parameter", v, "fixed", *parameter_bounds(f)))
        elif isinstance(v, str):
            rows.append(("String", f.name, "parameter", v, "fixed", None, None))
        else:
            rows.append(("Real", f.name, "parameter", float(v), "fixed", None, None))
    for name in port_inputs(model):
        start = float(defaults.w0) / RPM if (model, name) == ("MotorLoad", "speed_ref_rpm") else 0.0
        rows.append(("Real", name, "input", start, None, None, None))
    rows += [("Real", name, "output", 0.0, None, None, None) for name in port_outputs(model)]
    rows.append(("String", "error", "output", "", "discrete", None, None))
    return tuple(Variable(vr, name, kind, causality, start, variability, lo, hi)
                 for vr, (kind, name, causality, start, variability, lo, hi) in enumerate(rows))


def initial_dependencies(model: str) -> dict:
    """Output -> the knowns it is computed from in initialization mode (modelDescription InitialUnknowns,
    drivetrain.fmu_build.build): every parameter, and the inputs that move it, found by running the
    initialization the FMU shell runs (drivetrain.models.components: the build at enter, the inputs at exit)
    once with the inputs at their start values and once per input with that one moved: what the code does,
    not a second declaration. E.g. a spring-side flange torque depends on the flange's angle and speed inputs,
    an inertia-side angle on the parameters only."""
    rows = variables(model)
    _, pcls = C.COMPONENTS[model]
    param_names = [v.name for v in rows if v.causality == "parameter"]
    starts = {v.name: v.start for v in rows}
    params = params_from(pcls, {n: starts[n] for n in param_names})
    inputs = port_inputs(model)
    outputs = port_outputs(model)

    def initial_values(moved: str | None) -> dict:
        """The outputs after initialization with the input ``moved`` moved."""
        values = {n: starts[n] for n in outputs}
        ins = {n: starts[n] for n in inputs}
        try:
            comp = C.build(model, params)                          # fmi2EnterInitializationMode
            values.update(C.start_outputs(comp, outputs))
            if moved is not None:
                ins[moved] = float(ins[moved]) + 0.37 * (1 + inputs.index(moved))
            C.initialize(model, comp, ins)                         # fmi2ExitInitializationMode
            values.update(C.initial_outputs(comp, outputs))
        except Exception as exc:  # noqa: BLE001 - named with the model
            raise RuntimeError(f"{model}: initialization failed while probing its dependencies: {model}: "
                               f"initialization failed: {type(exc).__name__}: {exc}") from exc
        return values

    base = initial_values(None)
    moved = {n: initial_values(n) for n in inputs}
    return {out: [n for n, vals in moved.items() if vals[out] != value] + param_names
            for out, value in base.items()}


def declaration(model: str) -> FmuDeclaration:
    """The declaration of drivetrain FMU ``model`` (module docstring); its initial dependencies are found when
    asked for (:meth:`FmuDeclaration.initial_dependency_map` runs the component's initialization)."""
    if model not in DESCRIPTIONS:
        raise ValueError(f"{model!r} is not a drivetrain FMU (one of {', '.join(DESCRIPTIONS)})")
    return FmuDeclaration(model=model, description=DESCRIPTIONS[model], author=AUTHOR, version=VERSION,
                          default_experiment=DEFAULT_EXPERIMENTS[model], variables=variables(model), units=UNITS,
                          variable_descriptions=variable_descriptions(model), bounds=bounds(model),
                          initial_dependencies=lambda: initial_dependencies(model))
