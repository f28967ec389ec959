"""The drive motor and the load side as one component (no FMI): MotorLoadParams (its FMU parameters, each declared
once) and MotorLoad, a LineModel (drivetrain.models.line) of the PI speed-controlled drive motor (torque limit,
LimPID anti-windup), coupling C1, the drive flywheel, and the load body with the planetary loss and the load motor;
the speed reference and the load setting as inputs or as time profiles, and a torque disturbance of the drive
motor (its torque noise and ripple) as an input."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from drivetrain.errors import ComponentError
from drivetrain.models.line import Law, LineComponent, LineModel, Port, check_parameters
from drivetrain.models.parameters import (energy_correction_parameter, max_substep_parameter, node_start_parameter,
                                          output_torque_parameter, parameter, parse_profile, rig_parameter)
from drivetrain.rig.data import LOAD_LAWS, RAD_S_PER_RPM, RIG_DRIVE_LOAD as _DL
from drivetrain.system import INERTIA, SPRING

RPM = RAD_S_PER_RPM      #: rad/s per rpm (``rig.data.rpm_to_rad_s(1.0)``)


@dataclass
class MotorLoadParams:
    """Drive motor (PI speed control, torque limit, LimPID back-calculation anti-windup) with the
    elastomer coupling C1 and the drive flywheel, and the load side (flywheel/propeller mass, the
    1:8 planetary with its loss, the load motor).

    drive: motor (J_motor, bearing c_motor) -C1 (k_c1, d_c1)- flywheel (J_flywheel) -C2 (k_c2, d_c2,
    the port spring of flange ``drive``, spring side).
    load: one body in the propeller-shaft frame, J_load + ratio_pg^2 J_load_motor, flange ``load``
    (inertia side); planetary loss law (pg_*) with T_trans = ratio_pg |load_torque|; the load motor:
    load_mode 0 "torque" (the rig: a torque setting, ratio_pg * load_torque at the propeller shaft,
    regularised below load_w_reg so that it brakes but never drives), 1 "viscous" (the paper: a
    viscous torque equal to the setting at load_w_nom)."""

    J_motor: float = rig_parameter("MotorLoad", "J_motor", "kg.m2", "drive motor rotor inertia")
    c_motor: float = rig_parameter("MotorLoad", "c_motor", "N.m.s/rad", "drive motor bearing viscous loss")
    k_c1: float = rig_parameter("MotorLoad", "k_c1", "N.m/rad", "stiffness of elastomer coupling C1 (motor - drive flywheel)")
    d_c1: float = rig_parameter("MotorLoad", "d_c1", "N.m.s/rad", "damping of coupling C1")
    J_flywheel: float = rig_parameter("MotorLoad", "J_flywheel", "kg.m2", "drive flywheel inertia")
    k_c2: float = rig_parameter("MotorLoad", "k_c2", "N.m/rad",
                     "stiffness of elastomer coupling C2 (drive flywheel - flange drive; the port spring)")
    d_c2: float = rig_parameter("MotorLoad", "d_c2", "N.m.s/rad", "damping of coupling C2")
    Kp: float = parameter(_DL.drive_Kp, "N.m.s/rad", "speed controller proportional gain")
    Ti: float = parameter(_DL.drive_Ti_s, "s", "speed controller integral time")
    Ni: float = parameter(_DL.drive_Ni, "1", "anti-windup gain of the controller (LimPID back-calculation)")
    tau_max: float = parameter(_DL.drive_torque_limit_Nm, "N.m", "drive motor torque limit")
    J_load: float = rig_parameter("MotorLoad", "J_load", "kg.m2",
                       "propeller-shaft side inertia (flywheel / propeller mass), propeller-shaft frame")
    J_load_motor: float = parameter(_DL.load_motor_J_kgm2, "kg.m2", "load motor rotor inertia (referred through ratio_pg^2)")
    ratio_pg: float = parameter(_DL.load_gear_ratio, "1", "planetary gearbox ratio load motor speed / propeller-shaft speed (8 on the rig)")
    pg_c: float = rig_parameter("MotorLoad", "pg_c", "N.m.s/rad", "planetary loss law: viscous coefficient")
    pg_Tc: float = rig_parameter("MotorLoad", "pg_Tc", "N.m", "planetary loss law: Coulomb torque level")
    pg_wc: float = rig_parameter("MotorLoad", "pg_wc", "rad/s", "planetary loss law: regularisation speed")
    pg_a: float = rig_parameter("MotorLoad", "pg_a", "1", "planetary loss law: load-dependent share")
    load_mode: int = parameter(LOAD_LAWS.index(_DL.load_law), None, "load motor law: 0 = torque setting (the rig; regularised below load_w_reg so "
                                 "that it brakes but never drives), 1 = viscous torque equal to the setting at "
                                 "load_w_nom (the paper)", min=0, max=1)
    load_w_reg: float = parameter(_DL.load_w_reg_rad_s, "rad/s", "load_mode 0: speed below which the load torque is regularised")
    load_w_nom: float = parameter(1.0, "rad/s", "load_mode 1: speed at which the viscous load equals the setting")
    speed_profile: str = parameter("", None, "drive speed reference over time as 't0:v0; t1:v1; ...' [s:rpm], linear "
                                      "between points; empty = the speed_ref_rpm input")
    load_profile: str = parameter("", None, "load torque setting over time as 't0:v0; t1:v1; ...' [s:N.m]; empty = the "
                                     "load_torque input")
    max_substep: float = max_substep_parameter()
    output_torque: str = output_torque_parameter()
    energy_correction: bool = energy_correction_parameter()
    #: the parameters the component refuses unless > 0 (its check and the FMU's declared min)
    POSITIVE_FIELDS: ClassVar[tuple] = ("J_motor", "J_flywheel", "J_load", "ratio_pg", "k_c1")
    phi0_motor: float = parameter(0.0, "rad", "initial angle of the drive motor")
    w0: float = parameter(0.0, "rad/s", "initial speed of the drive side")
    tau0: float = parameter(0.0, "N.m", "initial torque through the drive couplings (sets their initial twist)")
    phi0_load: float = parameter(0.0, "rad", "initial angle of the load body")
    w0_load: float = parameter(0.0, "rad/s", "initial speed of the load body")
    node_phi_start: str = node_start_parameter("angle", "rad")
    node_w_start: str = node_start_parameter("speed", "rad/s")



class MotorLoad(LineComponent):
    """Drive motor + C1 + flywheel (flange ``drive``, spring side: C2) and the load side (flange
    ``load``, inertia side) with the planetary and the load motor (MotorLoadParams)."""

    model = "MotorLoad"
    PORTS = {"drive": SPRING, "load": INERTIA}              #: port name -> kind (the FMU's flanges)

    def __init__(self, p: MotorLoadParams):
        check_parameters(p)
        self.p = p
        for nm in MotorLoadParams.POSITIVE_FIELDS:
            if not getattr(p, nm) > 0:
                raise ValueError(f"{nm} must be > 0")
        if int(p.load_mode) not in (0, 1):
            raise ValueError(f"load_mode must be 0 (torque) or 1 (viscous), got {p.load_mode}")
        self.J_L = p.J_load + p.ratio_pg ** 2 * p.J_load_motor
        J = [p.J_motor, p.J_flywheel, self.J_L]
        k = [p.k_c1, 0.0]
        c = [p.d_c1, 0.0]
        cext = [p.c_motor, 0.0, 0.0]
        kind = self.PORTS
        ports = [Port("drive", 1, kind["drive"], 1.0, p.k_c2, p.d_c2), Port("load", 2, kind["load"], 1.0)]
        laws = [Law("planetary", 2, p.pg_c, p.pg_Tc, p.pg_wc if p.pg_wc > 0 else 1.0, p.pg_a),
                Law("load_motor", 2, 0.0, 0.0, p.load_w_reg if p.load_w_reg > 0 else 1e-3, 0.0, source=True)]
        self.line = LineModel(J, k, c, cext, ports, laws, motor_node=0,
                              motor_par=(p.Kp, p.Ti, p.Ni, p.tau_max), max_substep=p.max_substep,
                              output_torque=p.output_torque, node_names=["motor", "flywheel", "load"],
                              energy_correction=bool(p.energy_correction))
        self.speed_profile = parse_profile(p.speed_profile)
        self.load_profile = parse_profile(p.load_profile)
        self.speed_ref_rpm = p.w0 / RPM
        self.load_torque = 0.0
        self.motor_torque_disturbance = 0.0
        self._parse_node_start()
        self.initialize()

    # steady state of the drive side for a through torque tau0 at speed w0
    def initialize(self, load_torque: float | None = None):
        p = self.p
        if load_torque is not None:
            self.load_torque = float(load_torque)
        th = np.array([p.phi0_motor, p.phi0_motor - p.tau0 / p.k_c1, p.phi0_load])
        om = np.array([p.w0, p.w0, p.w0_load])
        # the PI integrator holds the motor torque of the parameters' start (tau0 at w0), node start or not
        Tm = p.tau0 + p.c_motor * p.w0
        self.line.set_state(*self._node_start(th, om), Tm / p.Kp)
        self.motor_torque = Tm
        self.load_motor_torque = self.load_torque
        self._set_load_level(self.load_torque)

    def speed_ref_at(self, t: float) -> float:
        """Speed reference [rad/s] at time t (profile parameter if set, else the input)."""
        if self.speed_profile is not None:
            return float(np.interp(t, *self.speed_profile)) * RPM
        return self.speed_ref_rpm * RPM

    def load_at(self, t: float) -> float:
        if self.load_profile is not None:
            return float(np.interp(t, *self.load_profile))
        return self.load_torque

    def _set_load_level(self, T_set: float):
        p = self.p
        T_prop = p.ratio_pg * T_set
        ln = self.line
        ln.l_Tc[0] = p.pg_Tc + p.pg_a * abs(T_prop)
        if int(p.load_mode) == 0:
            ln.l_cv[1] = 0.0
            ln.l_Tc[1] = T_prop
        else:
            ln.l_cv[1] = T_prop / p.load_w_nom if p.load_w_nom > 0 else 0.0
            ln.l_Tc[1] = 0.0

    def set_inputs(self, drive_phi, drive_w, load_tau, speed_ref_rpm=None, load_torque=None,
                   motor_torque_disturbance=None):
        self.line.set_input("drive", drive_phi, drive_w)
        self.line.set_input("load", load_tau)
        if speed_ref_rpm is not None:
            self.speed_ref_rpm = float(speed_ref_rpm)
        if load_torque is not None:
            self.load_torque = float(load_torque)
        if motor_torque_disturbance is not None:
            self.motor_torque_disturbance = float(motor_torque_disturbance)

    def step(self, t, H):
        T_set = self.load_at(t)
        if not math.isfinite(T_set):
            raise ComponentError(f"non-finite load torque {T_set!r} at t = {t:.9g} s")
        self._set_load_level(T_set)
        # the disturbance is held over the step; the kernel refuses a non-finite one (ComponentError)
        self.line.set_motor_disturbance(self.motor_torque_disturbance)
        self.line.step(t, H, self.speed_ref_at(t), self.speed_ref_at(t + H))
        self.motor_torque = self.line.motor_torque
        self.load_motor_torque = self.line.source_torque / self.p.ratio_pg

    def step_outputs(self) -> dict:
        """The outputs every step changes, by FMU variable name (Python floats), read by the FMU shell after
        every step."""
        ln = self.line
        pl, wl = ln.flange("load")
        th, om = ln.th, ln.om
        return {"load_phi": pl, "load_w": wl, "drive_tau": float(ln.tau_out[0]),
                "drive_tau_mean": float(ln.tau_mean[0]), "motor_phi": float(th[0]), "motor_w": float(om[0]),
                "flywheel_phi": float(th[1]), "flywheel_w": float(om[1]), "motor_torque": self.motor_torque,
                "load_motor_torque": self.load_motor_torque, "load_motor_w": self.p.ratio_pg * wl,
                "coupling_torque": float(ln.el_mean[0]), "energy_dissipated": ln.energy_dissipated,
                "energy_supplied": ln.energy_supplied}
