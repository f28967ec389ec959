"""The upper 3:1 bevel gearbox as a component (no FMI): UpperTransmissionParams (its FMU parameters, each declared
once) and UpperTransmission, one rigid geared body (a one-node LineModel, drivetrain.models.line) with the
calibrated loss law."""
from __future__ import annotations

from dataclasses import dataclass

from drivetrain.models.line import Law, LineComponent, LineModel, Port, check_parameters, loss_torque
from drivetrain.models.parameters import max_substep_parameter, node_start_parameter, parameter, rig_parameter
from drivetrain.system import INERTIA


@dataclass
class UpperTransmissionParams:
    """The 3:1 upper bevel gearbox as one rigid geared body: input inertia J_in (drive frame, the
    drive-line parts lumped into it), output inertia J_out (middle-shaft frame), ratio; the loss law
    on the input shaft with T_trans = |flange_b_tau| / ratio (drive-referred output torque). Both
    flanges inertia side. ``J_sensor``: inertia of the body upstream of the drive-shaft transducer
    section (rigid shafts: the transducer sits inside this body; its torque is tau_a - J_sensor alpha)."""

    J_in: float = rig_parameter("UpperTransmission", "J_in", "kg.m2",
                     "inertia on the input (drive) shaft, the drive-line parts lumped into it")
    J_out: float = rig_parameter("UpperTransmission", "J_out", "kg.m2", "inertia on the output (middle) shaft")
    ratio: float = parameter(3.0, "1", "transmission ratio input speed / output speed (3 for the rig's upper gearbox)")
    loss_c: float = rig_parameter("UpperTransmission", "loss_c", "N.m.s/rad", "loss law: viscous coefficient on the input shaft")
    loss_Tc: float = rig_parameter("UpperTransmission", "loss_Tc", "N.m", "loss law: Coulomb torque level")
    loss_wc: float = rig_parameter("UpperTransmission", "loss_wc", "rad/s",
                        "loss law: speed below which the Coulomb torque is regularised")
    loss_a: float = rig_parameter("UpperTransmission", "loss_a", "1", "loss law: load-dependent share of the transmitted torque")
    J_sensor: float = parameter(0.0, "kg.m2", "inertia upstream of the drive-shaft transducer section (rigid shafts: the "
                                       "transducer sits inside this body); 0 = none")
    max_substep: float = max_substep_parameter()
    phi0: float = parameter(0.0, "rad", "initial angle of the input shaft")
    w0: float = parameter(0.0, "rad/s", "initial speed of the input shaft")
    node_phi_start: str = node_start_parameter("angle", "rad")
    node_w_start: str = node_start_parameter("speed", "rad/s")



class UpperTransmission(LineComponent):
    """Rigid 3:1 body with two inertia-side flanges and the calibrated loss (UpperTransmissionParams)."""

    model = "UpperTransmission"
    PORTS = {"flange_a": INERTIA, "flange_b": INERTIA}     #: port name -> kind (the FMU's flanges)

    def __init__(self, p: UpperTransmissionParams):
        check_parameters(p)
        self.p = p
        if not (p.ratio > 0 and p.J_in >= 0 and p.J_out >= 0):
            raise ValueError("ratio must be > 0 and J_in, J_out >= 0")
        Jtot = p.J_in + p.J_out / p.ratio ** 2
        if not Jtot > 0:
            raise ValueError("J_in + J_out / ratio^2 must be > 0")
        self.J = Jtot
        kind = self.PORTS
        ports = [Port("flange_a", 0, kind["flange_a"], 1.0), Port("flange_b", 0, kind["flange_b"], 1.0 / p.ratio)]
        laws = [Law("loss", 0, p.loss_c, p.loss_Tc, p.loss_wc if p.loss_wc > 0 else 1.0, p.loss_a)]
        self.line = LineModel([Jtot], [], [], None, ports, laws, max_substep=p.max_substep)
        self._parse_node_start()
        self.initialize()

    def initialize(self):
        self.line.set_state(*self._node_start([self.p.phi0], [self.p.w0]))
        self.torque_sensor = 0.0
        self._loss_at = None           # (w, loss level) at the end of the last step: loss_torque when read
        self._tau_a = 0.0

    def set_inputs(self, flange_a_tau, flange_b_tau):
        self._tau_a = float(flange_a_tau)
        self.line.set_input("flange_a", flange_a_tau)
        self.line.set_input("flange_b", flange_b_tau)
        p = self.p
        # loss level: T_c + a |T_trans|, T_trans = drive-referred output torque
        self.line.l_Tc[0] = p.loss_Tc + p.loss_a * abs(float(flange_b_tau)) / p.ratio

    def step(self, t, H):
        w0 = float(self.line.om[0])
        self.line.step(t, H)
        alpha = (float(self.line.om[0]) - w0) / H
        self.torque_sensor = self._tau_a - self.p.J_sensor * alpha
        # mean loss torque from the dissipated energy is not separable; report the law at the end speed
        # (evaluated when read: the master does not read it every step)
        self._loss_at = (self.line.om[0], self.line.l_Tc[0], self.line.l_wc[0])

    @property
    def loss_torque(self) -> float:
        if self._loss_at is None:
            return 0.0
        w, T_c, w_c = self._loss_at
        return float(loss_torque(w, 0.0, self.p.loss_c, T_c, w_c, 0.0))

    def step_outputs(self) -> dict:
        """The outputs every step changes, by FMU variable name (Python floats), read by the FMU shell after
        every step."""
        ln = self.line
        pa, wa = ln.flange("flange_a")
        pb, wb = ln.flange("flange_b")
        return {"flange_a_phi": pa, "flange_a_w": wa, "flange_b_phi": pb, "flange_b_w": wb,
                "torque_sensor": self.torque_sensor, "energy_dissipated": ln.energy_dissipated,
                "energy_supplied": ln.energy_supplied}

    def lazy_outputs(self) -> dict:
        return {"loss_torque": self.loss_torque, "energy_stored": self.line.stored_energy()}
