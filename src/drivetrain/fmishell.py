"""The common FMI 2.0 co-simulation shell (pythonfmu) of the drivetrain components.

A slave script in ``drivetrain/slaves/`` only names its component; everything else is here:
parameters (the fields of the component's parameter dataclass: Real, Integer or String, causality
parameter, variability fixed), inputs (the flange inputs of its ports and extra inputs), outputs
(Real, initial exact: flanges, sensors, energies), units (read by ``drivetrain.fmubuild``).

Life cycle: the component is built in ``enter_initialization_mode`` (after the parameters are set:
heavy setup never runs at instantiation), so the inertia-side flange outputs are valid while the
master exchanges initial values; ``exit_initialization_mode`` takes the final inputs and publishes the
spring-side torques. ``do_step`` checks the inputs (NaN/inf -> logged error and status error, the
instance refuses further steps; the host never crashes), advances the component and publishes.
"""
from __future__ import annotations

import dataclasses
import math

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.enums import Fmi2Status

from drivetrain import components as C

#: per model: ports (name -> "spring" | "inertia"), extra inputs, outputs, parameter units
PORTS = {
    "FlexibleShaft": {"flange_a": "inertia", "flange_b": "spring"},
    "UpperTransmission": {"flange_a": "inertia", "flange_b": "inertia"},
    "MotorLoad": {"drive": "spring", "load": "inertia"},
}
EXTRA_INPUTS = {
    "FlexibleShaft": (),
    "UpperTransmission": (),
    "MotorLoad": ("speed_ref_rpm", "load_torque"),
}
OUTPUTS = {
    "FlexibleShaft": ("flange_b_tau_mean", "torque_sensor", "shaft_torque", "hub_b_phi", "hub_b_w"),
    "UpperTransmission": ("torque_sensor", "loss_torque"),
    "MotorLoad": ("drive_tau_mean", "motor_phi", "motor_w", "flywheel_phi", "flywheel_w", "motor_torque",
                  "load_motor_torque", "coupling_torque"),
}
ENERGY = ("energy_stored", "energy_dissipated", "energy_supplied")

UNITS = {
    "J_a": "kg.m2", "J_b": "kg.m2", "J_shaft": "kg.m2", "J_in": "kg.m2", "J_out": "kg.m2", "J_sensor": "kg.m2",
    "J_motor": "kg.m2", "J_flywheel": "kg.m2", "J_load": "kg.m2", "J_load_motor": "kg.m2",
    "k_t": "N.m/rad", "k_c": "N.m/rad", "k_shaft": "N.m/rad", "k_c1": "N.m/rad", "k_c2": "N.m/rad",
    "d_t": "N.m.s/rad", "d_c": "N.m.s/rad", "d_shaft": "N.m.s/rad", "d_c1": "N.m.s/rad", "d_c2": "N.m.s/rad",
    "c_motor": "N.m.s/rad", "loss_c": "N.m.s/rad", "pg_c": "N.m.s/rad", "Kp": "N.m.s/rad",
    "loss_Tc": "N.m", "pg_Tc": "N.m", "tau_max": "N.m", "tau0": "N.m",
    "loss_wc": "rad/s", "pg_wc": "rad/s", "load_w_reg": "rad/s", "load_w_nom": "rad/s", "w0": "rad/s",
    "w0_load": "rad/s", "phi0": "rad", "phi0_motor": "rad", "phi0_load": "rad",
    "loss_a": "1", "pg_a": "1", "ratio": "1", "ratio_pg": "1", "Ni": "1",
    "Ti": "s", "max_substep": "s",
    "speed_ref_rpm": "rpm", "load_torque": "N.m",
    "torque_sensor": "N.m", "shaft_torque": "N.m", "loss_torque": "N.m", "motor_torque": "N.m",
    "load_motor_torque": "N.m", "coupling_torque": "N.m", "flange_b_tau_mean": "N.m", "drive_tau_mean": "N.m",
    "motor_phi": "rad", "flywheel_phi": "rad", "hub_b_phi": "rad", "motor_w": "rad/s", "flywheel_w": "rad/s",
    "hub_b_w": "rad/s",
    "energy_stored": "J", "energy_dissipated": "J", "energy_supplied": "J",
}
for _m, _ports in PORTS.items():
    for _p in _ports:
        UNITS.update({f"{_p}_phi": "rad", f"{_p}_w": "rad/s", f"{_p}_tau": "N.m"})

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


def port_inputs(model: str) -> list[str]:
    out = []
    for p, kind in PORTS[model].items():
        out += [f"{p}_phi", f"{p}_w"] if kind == "spring" else [f"{p}_tau"]
    return out + list(EXTRA_INPUTS[model])


def port_outputs(model: str) -> list[str]:
    out = []
    for p, kind in PORTS[model].items():
        out += [f"{p}_tau"] if kind == "spring" else [f"{p}_phi", f"{p}_w"]
    return out + list(OUTPUTS[model]) + list(ENERGY)


class ComponentSlave(Fmi2Slave):
    """Base of the three component slaves; a subclass sets ``MODEL``."""

    MODEL = ""
    author = "bevel-drivetrain"
    version = "0.1.0"
    units = UNITS            # read by drivetrain.fmubuild (modelDescription units)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        model = self.MODEL
        cls, pcls = C.COMPONENTS[model]
        self._pcls = pcls
        defaults = pcls()
        P, F = Fmi2Causality.parameter, Fmi2Variability.fixed
        self._param_names = []
        for f in dataclasses.fields(pcls):
            v = getattr(defaults, f.name)
            setattr(self, f.name, v)
            self._param_names.append(f.name)
            if isinstance(v, bool):
                raise TypeError(f"boolean parameter {f.name} not supported")
            if isinstance(v, int):
                self.register_variable(Integer(f.name, causality=P, variability=F))
            elif isinstance(v, str):
                self.register_variable(String(f.name, causality=P, variability=F))
            else:
                setattr(self, f.name, float(v))
                self.register_variable(Real(f.name, causality=P, variability=F))
        self._inputs = port_inputs(model)
        self._outputs = port_outputs(model)
        for name in self._inputs:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input))
        if model == "MotorLoad":
            self.speed_ref_rpm = float(defaults.w0) / C.RPM
        for name in self._outputs:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        self._comp = None
        self._failed = None

    # ---- helpers ----------------------------------------------------------------------------------
    def _params(self):
        vals = {}
        for n in self._param_names:
            vals[n] = getattr(self, n)
        return C.params_from(self._pcls, vals)

    def _fail(self, msg: str):
        self._failed = msg
        self.log(f"{self.MODEL}: {msg}", Fmi2Status.error)

    def _check_inputs(self, t: float):
        bad = {n: getattr(self, n) for n in self._inputs if not math.isfinite(float(getattr(self, n)))}
        if bad:
            raise C.ComponentError(f"non-finite input at t = {t:.9g} s: {bad}")

    def _apply_inputs(self):
        comp = self._comp
        m = self.MODEL
        if m == "FlexibleShaft":
            comp.set_inputs(self.flange_a_tau, self.flange_b_phi, self.flange_b_w)
        elif m == "UpperTransmission":
            comp.set_inputs(self.flange_a_tau, self.flange_b_tau)
        else:
            comp.set_inputs(self.drive_phi, self.drive_w, self.load_tau, self.speed_ref_rpm, self.load_torque)

    def _publish(self, initial: bool = False):
        out = self._comp.outputs()
        if initial:
            # spring-side torques before the first step: the port spring against the current inputs
            ln = self._comp.line
            for p in ln.ports:
                if p.kind == C.SPRING_PORT:
                    q = ln.port_index[p.name]
                    out[f"{p.name}_tau"] = ln.spring_torque(p.name, ln.p_u0[q], ln.p_u1[q])
                    out[f"{p.name}_tau_mean"] = out[f"{p.name}_tau"]
            out["energy_stored"] = ln.stored_energy({p.name: ln.p_u0[ln.port_index[p.name]]
                                                     for p in ln.ports if p.kind == C.SPRING_PORT})
        for name in self._outputs:
            setattr(self, name, float(out[name]))

    # ---- FMI callbacks ------------------------------------------------------------------------------
    def enter_initialization_mode(self):
        try:
            cls, _ = C.COMPONENTS[self.MODEL]
            self._comp = cls(self._params())
            out = self._comp.outputs()
            for name in self._outputs:
                if name in out and not name.endswith("_tau") and not name.endswith("_tau_mean"):
                    setattr(self, name, float(out[name]))
        except Exception as exc:  # noqa: BLE001 - never propagate into the host
            self._fail(f"initialization failed: {type(exc).__name__}: {exc}")

    def exit_initialization_mode(self):
        if self._failed is not None:
            return
        try:
            if self._comp is None:
                cls, _ = C.COMPONENTS[self.MODEL]
                self._comp = cls(self._params())
            self._check_inputs(0.0)
            self._apply_inputs()
            if self.MODEL == "MotorLoad":
                self._comp.initialize(load_torque=self.load_torque)
                self._apply_inputs()
            self._publish(initial=True)
        except Exception as exc:  # noqa: BLE001
            self._fail(f"initialization failed: {type(exc).__name__}: {exc}")

    def do_step(self, current_time, step_size):
        if self._failed is not None:
            self.log(f"{self.MODEL} is in the error state: {self._failed}", Fmi2Status.error)
            return False
        try:
            self._check_inputs(current_time)
            self._apply_inputs()
            self._comp.step(current_time, step_size)
            self._publish()
        except Exception as exc:  # noqa: BLE001 - ComponentError and anything unexpected
            name = "" if isinstance(exc, C.ComponentError) else f"{type(exc).__name__}: "
            self._fail(f"do_step at t = {current_time:.9g} s failed: {name}{exc}")
            return False
        return True
