"""The common FMI 2.0 co-simulation shell (pythonfmu) of the drivetrain components.

A slave script (rendered by ``drivetrain.fmu_build.build`` from ``fmu_runtime.slave_template``) defines ``class <Model>(Fmi2Slave):`` (literally: pythonfmu
0.7.0's loader finds the slave class by that pattern in the script's source, a class deriving from an
intermediate base is not found on a second instantiation and corrupted the host process) and
delegates to the functions here. What the FMU declares (model information, variables, units, descriptions,
bounds, initial dependencies) is plain data in ``drivetrain.models.fmu_variables``, which the native build
reads too: :func:`init_slave` registers its variables (parameters: the fields of the component's parameter
dataclass, variability fixed; inputs: the flange inputs of its ports and extra inputs; outputs, initial exact:
flanges, sensors, energies, ``error``). The ports and the input and output names are re-exported here for the
shell's readers (the order in which ``set_inputs`` takes the inputs is :func:`port_inputs`).

Life cycle: the component is built in
``enter_initialization_mode`` (after the parameters are set: the parameter-dependent setup never runs
at instantiation), so the inertia-side flange outputs are valid while the master exchanges initial
values; a host reading outputs in initialization mode after changing a parameter there (FMI 2.0
allows it; Ecos does it) gets them from a new build (``refresh_init``), and
``exit_initialization_mode`` builds it again if a parameter changed since, takes the final inputs and
publishes the spring-side torques (the steps of ``drivetrain.models.components``: ``build``,
``start_outputs``, ``initialize``, ``initial_outputs``; the initial dependencies are found by running them).
``do_step`` checks the inputs (NaN/inf -> logged error and status error, the
instance refuses further steps; the host never crashes), advances the component and publishes.
"""
from __future__ import annotations

import functools
import math
import operator
import weakref

from pythonfmu import Boolean, Fmi2Causality, Fmi2Initial, Fmi2Variability, Integer, Real, String
from pythonfmu.enums import Fmi2Status

from drivetrain.errors import ComponentError
from drivetrain.models import components as C
from drivetrain.models.fmu_variables import PORTS, port_inputs, port_outputs, variable_descriptions  # noqa: F401
from drivetrain.models.fmu_variables import variables
from drivetrain.models.parameters import params_from
from fmu_runtime.guard import enter_error_state, fmi_text, guard_value_references, restore_shell_state, shell_state

_TYPES = {"Real": Real, "Integer": Integer, "Boolean": Boolean, "String": String}


def init_slave(slave, model: str, slave_kwargs: dict | None = None) -> None:
    """Register the variables of ``model`` (drivetrain.models.fmu_variables.variables) on a pythonfmu slave,
    each at its start value (called from its ``__init__``)."""
    if slave_kwargs is not None:
        from fmu_runtime.guard import pin_export_library_state

        # pythonfmu 0.7.0 releases its interpreter state twice at process exit: see fmu_runtime.guard
        pin_export_library_state(slave_kwargs, model)
    slave.MODEL = model
    _, slave._pcls = C.COMPONENTS[model]
    rows = variables(model)
    slave._param_names = [v.name for v in rows if v.causality == "parameter"]
    slave._inputs = port_inputs(model)
    slave._outputs = port_outputs(model)
    ref = weakref.ref(slave)
    for v in rows:
        setattr(slave, v.name, v.start)
        extra = {} if v.variability is None else {"variability": Fmi2Variability[v.variability]}
        if v.causality == "output":
            extra["initial"] = Fmi2Initial.exact
            if v.name in LAZY_OUTPUTS:
                extra["getter"] = functools.partial(_lazy_output, ref, v.name)
        var = _TYPES[v.type](v.name, causality=Fmi2Causality[v.causality], **extra)
        if v.type == "Integer" and v.causality == "parameter":
            # refused when set outside (fmu_runtime.guard); the modelDescription's min/max come from bounds()
            var.min, var.max = v.min, v.max
        slave.register_variable(var)
    slave._lazy_pending = False
    # all input values in one call (a tuple), for the per-step finiteness check
    slave._in_values = (operator.attrgetter(*slave._inputs) if len(slave._inputs) > 1
                        else lambda s, _n=tuple(slave._inputs): tuple(getattr(s, n) for n in _n))
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
    values = C.initial_outputs(slave._comp, slave._outputs)
    slave._lazy_pending = False
    for name, v in values.items():
        setattr(slave, name, v)


def enter_init(slave):
    """Build the component (parameters are set by now); publish the state-only outputs."""
    try:
        slave._built_with = _params(slave)
        slave._comp = C.build(slave.MODEL, slave._built_with)
        for name, v in C.start_outputs(slave._comp, slave._outputs).items():
            setattr(slave, name, v)
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
            slave._built_with = params
            slave._comp = C.build(slave.MODEL, params)
        _check_inputs(slave, 0.0)
        C.initialize(slave.MODEL, slave._comp, dict(zip(slave._inputs, slave._in_values(slave))))
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
