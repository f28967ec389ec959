"""The common FMI 2.0 co-simulation shell (pythonfmu) of the drivetrain components.

A slave script (rendered by ``drivetrain.fmu_build.build`` from ``fmu_runtime.slave_template``) defines ``class <Model>(Fmi2Slave):`` (literally: pythonfmu
0.7.0's loader finds the slave class by that pattern in the script's source, a class deriving from an
intermediate base is not found on a second instantiation and corrupted the host process) and
delegates to the functions here; everything else is here:
parameters (the fields of the component's parameter dataclass: Real, Integer or String, causality
parameter, variability fixed), inputs (the flange inputs of its ports and extra inputs), outputs
(Real, initial exact: flanges, sensors, energies), units (read by ``drivetrain.fmu_build.build``).

Life cycle: the component is built in
``enter_initialization_mode`` (after the parameters are set: the parameter-dependent setup never runs
at instantiation), so the inertia-side flange outputs are valid while the master exchanges initial
values; a host reading outputs in initialization mode after changing a parameter there (FMI 2.0
allows it; Ecos does it) gets them from a new build (``refresh_init``), and
``exit_initialization_mode`` builds it again if a parameter changed since, takes the final inputs and
publishes the spring-side torques. ``do_step`` checks the inputs (NaN/inf -> logged error and status error, the
instance refuses further steps; the host never crashes), advances the component and publishes.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import operator
import weakref

from pythonfmu import Boolean, DefaultExperiment, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.enums import Fmi2Status

from drivetrain.errors import ComponentError
from drivetrain.models import components as C
from drivetrain.models.motors import RPM
from drivetrain.models.parameters import parameter_bounds, parameter_description, parameter_unit, params_from
from drivetrain.system import INERTIA, SPRING
from fmu_runtime.guard import enter_error_state, fmi_text, guard_value_references, restore_shell_state, shell_state
from gearcontact_fmu.params import DEFAULT_COMM_STEP_S, flange_variables

#: per model: the modelDescription's DefaultExperiment (the step the FMUs are validated at), long enough for the shipped example input (drivetrain.fmu_build.fmu_docs: the
#: operating point ramped in over 0.25 s) to settle: UpperTransmission, driven by torques alone, reaches its speed
#: through its loss law (time constant about 0.2 s at speed). No tolerance: the models integrate with fixed sub-steps.
DEFAULT_EXPERIMENTS = {
    "FlexibleShaft": DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=DEFAULT_COMM_STEP_S),
    "UpperTransmission": DefaultExperiment(start_time=0.0, stop_time=2.0, step_size=DEFAULT_COMM_STEP_S),
    "MotorLoad": DefaultExperiment(start_time=0.0, stop_time=2.0, step_size=DEFAULT_COMM_STEP_S),
}

#: per model: ports (name -> drivetrain.system.SPRING | INERTIA, as the component declares them), extra
#: inputs, outputs, parameter units
PORTS = {model: dict(cls.PORTS) for model, (cls, _) in C.COMPONENTS.items()}
EXTRA_INPUTS = {
    "FlexibleShaft": (),
    "UpperTransmission": (),
    "MotorLoad": ("speed_ref_rpm", "load_torque", "motor_torque_disturbance"),
}
#: extra inputs that a parameter of the same FMU can carry as a time profile ('t0:v0; t1:v1; ...',
#: linear between points, held outside; parameters.parse_profile): a host without input signals sets
#: the parameter instead (drivetrain.interop.ssp)
INPUT_PROFILES = {
    "MotorLoad": {"speed_ref_rpm": "speed_profile", "load_torque": "load_profile"},
}
#: per model: its own outputs, each declared once: name -> (unit, description); then the energies every
#: drivetrain FMU has (ENERGY). Parameters are declared in the component's parameter dataclass (name,
#: default, unit, description: drivetrain.models.parameters); the flange variables follow from the port kinds.
OWN_OUTPUTS = {
    "FlexibleShaft": {
        "flange_b_tau_mean": ("N.m", "exact mean over the last step of the torque at flange_b"),
        "torque_sensor": ("N.m", "drive-shaft torque transducer reading (the section between its hubs)"),
        "shaft_torque": ("N.m", "torque in the thin shaft at its flange_b end"),
        "hub_b_phi": ("rad", "angle of transducer hub B"),
        "hub_b_w": ("rad/s", "speed of transducer hub B"),
        "coupling_energy_error": ("J", "work mismatch of the spring-side cut since t = 0 not yet corrected "
                                       "(energy audit)"),
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
        "coupling_energy_error": ("J", "work mismatch of the spring-side cut since t = 0 not yet corrected "
                                       "(energy audit)"),
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


def initial_dependencies(slave_cls) -> dict:
    """Output -> the knowns it is computed from in initialization mode (modelDescription InitialUnknowns,
    drivetrain.fmu_build.build): every parameter, and the inputs that move it, found by running the slave's
    initialization (enter, inputs set, exit) once with the inputs at their start values and once per input
    with that one moved: what the code does, not a second declaration. E.g. a spring-side flange torque
    depends on the flange's angle and speed inputs, an inertia-side angle on the parameters only."""
    import tempfile

    def initial_outputs(moved: str | None):
        """The outputs after initialization with ``moved`` moved, and the instance."""
        s = slave_cls(instance_name="initial-dependencies", resources=tempfile.gettempdir())
        s.enter_initialization_mode()
        if moved is not None:
            setattr(s, moved, float(getattr(s, moved)) + 0.37 * (1 + s._inputs.index(moved)))
        s.exit_initialization_mode()
        if s._failed is not None:
            raise RuntimeError(f"{slave_cls.__name__}: initialization failed while probing its dependencies: "
                               f"{s._failed}")
        return {n: getattr(s, n) for n in s._outputs}, s

    base, probe = initial_outputs(None)
    moved = {n: initial_outputs(n)[0] for n in probe._inputs}
    return {out: [n for n, vals in moved.items() if vals[out] != value] + list(probe._param_names)
            for out, value in base.items()}


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


def init_slave(slave, model: str, slave_kwargs: dict | None = None) -> None:
    """Register the variables of ``model`` on a pythonfmu slave (called from its ``__init__``)."""
    if slave_kwargs is not None:
        from fmu_runtime.guard import pin_export_library_state

        # pythonfmu 0.7.0 releases its interpreter state twice at process exit: see fmu_runtime.guard
        pin_export_library_state(slave_kwargs, model)
    slave.MODEL = model
    cls, pcls = C.COMPONENTS[model]
    slave._pcls = pcls
    defaults = pcls()
    P, F = Fmi2Causality.parameter, Fmi2Variability.fixed
    slave._param_names = []
    for f in dataclasses.fields(pcls):
        v = getattr(defaults, f.name)
        slave._param_names.append(f.name)
        if isinstance(v, bool):
            setattr(slave, f.name, v)
            slave.register_variable(Boolean(f.name, causality=P, variability=F))
        elif isinstance(v, int):
            setattr(slave, f.name, v)
            var = Integer(f.name, causality=P, variability=F)
            # refused when set outside (fmu_runtime.guard); the modelDescription's min/max come from bounds()
            var.min, var.max = parameter_bounds(f)
            slave.register_variable(var)
        elif isinstance(v, str):
            setattr(slave, f.name, v)
            slave.register_variable(String(f.name, causality=P, variability=F))
        else:
            setattr(slave, f.name, float(v))
            slave.register_variable(Real(f.name, causality=P, variability=F))
    slave._inputs = port_inputs(model)
    slave._outputs = port_outputs(model)
    for name in slave._inputs:
        setattr(slave, name, 0.0)
        slave.register_variable(Real(name, causality=Fmi2Causality.input))
    if model == "MotorLoad":
        slave.speed_ref_rpm = float(defaults.w0) / RPM
    ref = weakref.ref(slave)
    for name in slave._outputs:
        setattr(slave, name, 0.0)
        getter = functools.partial(_lazy_output, ref, name) if name in LAZY_OUTPUTS else None
        slave.register_variable(Real(name, causality=Fmi2Causality.output, initial=Fmi2Initial.exact,
                                     getter=getter))
    slave._lazy_pending = False
    # all input values in one call (a tuple), for the per-step finiteness check
    slave._in_values = (operator.attrgetter(*slave._inputs) if len(slave._inputs) > 1
                        else lambda s, _n=tuple(slave._inputs): tuple(getattr(s, n) for n in _n))
    slave.error = ""
    slave.register_variable(String("error", causality=Fmi2Causality.output, variability=Fmi2Variability.discrete,
                                   initial=Fmi2Initial.exact))
    slave.NAN_ON_FAILURE = tuple(slave._outputs)
    slave._comp = None
    slave._built_with = None
    slave._failed = None
    guard_value_references(slave, model, exported="logger" in (slave_kwargs or {}))


#: outputs computed when a host reads them, not at every step (the master reads them at the start and
#: the end of a run): the component state they depend on does not change between two do_step calls
LAZY_OUTPUTS = ("energy_stored", "coupling_energy_error", "loss_torque")


def _lazy_output(ref, name):
    slave = ref()
    if slave._lazy_pending:
        slave._lazy_pending = False
        out = slave._comp.outputs()
        for n in LAZY_OUTPUTS:
            if n in out:
                setattr(slave, n, float(out[n]))
    return getattr(slave, name)


def _params(slave):
    return params_from(slave._pcls, {n: getattr(slave, n) for n in slave._param_names})


def _fail(slave, msg: str):
    """Enter the error state (fmu_runtime.guard.enter_error_state): every Real output becomes NaN."""
    slave._lazy_pending = False
    enter_error_state(slave, f"{slave.MODEL}: {msg}")


def get_fmu_state(slave) -> dict:
    """fmi2GetFMUstate: the inputs, outputs and ``error``, the component (components.get_state) and the
    shell's own flags. Parameters are fixed after initialization and not part of it."""
    names = slave._inputs + slave._outputs
    return {"values": {n: getattr(slave, n) for n in names}, "lazy_pending": slave._lazy_pending,
            "component": None if slave._comp is None else C.get_state(slave._comp),
            "shell": shell_state(slave)}


def set_fmu_state(slave, state: dict) -> None:
    """fmi2SetFMUstate: restore a :func:`get_fmu_state` snapshot of this instance."""
    for n, v in state["values"].items():
        setattr(slave, n, v)
    if state["component"] is not None:
        C.set_state(slave._comp, state["component"])
    slave._lazy_pending = state["lazy_pending"]
    restore_shell_state(slave, state["shell"])


def _check_inputs(slave, t: float):
    if all(map(math.isfinite, slave._in_values(slave))):     # the usual case: one pass, no dict
        return
    bad = {n: getattr(slave, n) for n in slave._inputs if not math.isfinite(float(getattr(slave, n)))}
    if bad:
        raise ComponentError(f"non-finite input at t = {t:.9g} s: {bad}")


def _apply_inputs(slave):
    """Hand the inputs to the component: ``set_inputs`` takes them positionally in the order of
    :func:`port_inputs` (the port inputs by port, then the extra inputs)."""
    slave._comp.set_inputs(*slave._in_values(slave))


def _publish(slave, initial: bool = False):
    if not initial:
        # every step: the component's step outputs by name, Python floats (LAZY_OUTPUTS are computed when read)
        values = slave._comp.step_outputs()
        if not all(map(math.isfinite, values.values())):
            bad = {n: v for n, v in values.items() if not math.isfinite(v)}
            raise ComponentError(f"the step produced non-finite outputs {bad} (inputs far out of range?)")
        slave._lazy_pending = True
        for name, v in values.items():
            setattr(slave, name, v)
        return
    # before the first step: the spring-side torques are the port springs against the current inputs
    ln = slave._comp.line
    ln.start_ports()
    out = slave._comp.outputs(energy=True)
    out["energy_stored"] = ln.stored_energy({p.name: ln.p_u0[ln.port_index[p.name]]
                                             for p in ln.ports if p.kind == SPRING})
    slave._lazy_pending = False
    values = {name: float(out[name]) for name in slave._outputs if name in out}
    if not all(map(math.isfinite, values.values())):
        bad = {n: v for n, v in values.items() if not math.isfinite(v)}
        raise ComponentError(f"the initial outputs are not finite: {bad} (check the parameters and start values)")
    for name, v in values.items():
        setattr(slave, name, v)


def enter_init(slave):
    """Build the component (parameters are set by now); publish the state-only outputs."""
    try:
        cls, _ = C.COMPONENTS[slave.MODEL]
        slave._built_with = _params(slave)
        slave._comp = cls(slave._built_with)
        out = slave._comp.outputs()
        for name in slave._outputs:
            if name in out and not name.endswith("_tau") and not name.endswith("_tau_mean"):
                setattr(slave, name, float(out[name]))
    except Exception as exc:  # noqa: BLE001 - never propagate into the host
        _fail(slave, f"initialization failed: {type(exc).__name__}: {exc}")


def refresh_init(slave):
    """Before a host reads outputs in initialization mode (fmu_runtime.guard): when a parameter changed
    since the build at enter (a host may set parameters after fmi2EnterInitializationMode; Ecos does),
    build again with the values set, so the state-only outputs the host passes on to the connected
    inputs are the ones the component starts from (else it passes the defaults' state, 0, and the
    spring-side ports compute their start torque from it at exit: -449 N.m for FlexibleShaft flange_b
    on the example scene instead of 1.9)."""
    if slave._failed is None and slave._comp is not None and _params(slave) != slave._built_with:
        enter_init(slave)


def exit_init(slave):
    if slave._failed is not None:
        return
    try:
        params = _params(slave)
        if slave._comp is None or params != slave._built_with:
            # FMI 2.0 lets a host set parameters in initialization mode, after the build at its start
            # (Ecos does): build again with the values the host set
            cls, _ = C.COMPONENTS[slave.MODEL]
            slave._built_with = params
            slave._comp = cls(params)
        _check_inputs(slave, 0.0)
        _apply_inputs(slave)
        if slave.MODEL == "MotorLoad":
            slave._comp.initialize(load_torque=slave.load_torque)
            _apply_inputs(slave)
        _publish(slave, initial=True)
    except Exception as exc:  # noqa: BLE001
        _fail(slave, f"initialization failed: {type(exc).__name__}: {exc}")


def do_step(slave, current_time, step_size) -> bool:
    """Advance one communication step; False (logged error, pythonfmu: fmi2Discard) on any failure."""
    if slave._failed is not None:
        slave.log(fmi_text(f"{slave.MODEL} is in the error state: {slave._failed}"), Fmi2Status.error)
        return False
    try:
        _check_inputs(slave, current_time)
        _apply_inputs(slave)
        slave._comp.step(current_time, step_size)
        _publish(slave)
    except Exception as exc:  # noqa: BLE001 - ComponentError and anything unexpected
        name = "" if isinstance(exc, ComponentError) else f"{type(exc).__name__}: "
        _fail(slave, f"do_step at t = {current_time:.9g} s failed: {name}{exc}")
        return False
    return True
