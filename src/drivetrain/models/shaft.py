"""The drive-shaft line as a component (no FMI): FlexibleShaftParams (its FMU parameters, each declared once)
and FlexibleShaft, a LineModel (drivetrain.models.line) of the transducer hubs, the stiff coupling and the thin
shaft in equal elements (docs/DRIVETRAIN.md)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from drivetrain.models.line import MAX_ELEMENTS, LineComponent, LineModel, Port, check_parameters
from drivetrain.models.parameters import (energy_correction_parameter, max_substep_parameter, node_start_parameter,
                                          output_torque_parameter, parameter, rig_parameter)
from drivetrain.system import INERTIA, SPRING


@dataclass
class FlexibleShaftParams:
    """The drive-shaft line from the elastomer coupling C2 to the upper gearbox (docs/DRIVETRAIN.md):

    flange_a (inertia side) -> hub A (J_a) -> transducer spring (k_t, d_t) -> hub B (J_b) -> stiff
    coupling (k_c, d_c; k_c <= 0: rigid) -> thin shaft (k_shaft, d_shaft, J_shaft, n_elements equal
    elements) -> flange_b (spring side: the last shaft element is the port spring).

    The distributed shaft inertia is lumped per element (mass_model 0: J_e/2 at each end) or consistent
    (1: J_e/6 [[2,1],[1,2]]; the port element stays lumped); the half element at the flange_b end
    belongs to the body across the port (the assembler adds J_shaft/(2 n) to the upper gearbox)."""

    J_a: float = rig_parameter("FlexibleShaft", "J_a", "kg.m2", "inertia of transducer hub A (flange_a side)")
    k_t: float = rig_parameter("FlexibleShaft", "k_t", "N.m/rad", "torsional stiffness of the transducer section")
    d_t: float = rig_parameter("FlexibleShaft", "d_t", "N.m.s/rad", "damping of the transducer section")
    J_b: float = rig_parameter("FlexibleShaft", "J_b", "kg.m2", "inertia of transducer hub B")
    k_c: float = rig_parameter("FlexibleShaft", "k_c", "N.m/rad",
                    "stiffness of the stiff coupling between hub B and the thin shaft (<= 0: rigid)")
    d_c: float = rig_parameter("FlexibleShaft", "d_c", "N.m.s/rad", "damping of the stiff coupling")
    k_shaft: float = rig_parameter("FlexibleShaft", "k_shaft", "N.m/rad", "torsional stiffness of the whole thin shaft")
    d_shaft: float = rig_parameter("FlexibleShaft", "d_shaft", "N.m.s/rad", "damping of the whole thin shaft")
    J_shaft: float = rig_parameter("FlexibleShaft", "J_shaft", "kg.m2",
                        "inertia of the whole thin shaft (distributed over its elements)")
    n_elements: int = parameter(4, None, "number of equal shaft elements", min=1, max=MAX_ELEMENTS)
    mass_model: int = parameter(0, None, "element inertia: 0 = lumped (J_e/2 at each end), 1 = consistent "
                                  "(J_e/6 [[2,1],[1,2]])", min=0, max=1)
    max_substep: float = max_substep_parameter()
    output_torque: str = output_torque_parameter()
    energy_correction: bool = energy_correction_parameter()
    #: the parameters the component refuses unless > 0 (its check and the FMU's declared min)
    POSITIVE_FIELDS: ClassVar[tuple] = ("J_a", "J_b", "k_shaft")
    phi0: float = parameter(0.0, "rad", "initial angle of the line (all nodes, before twist)")
    w0: float = parameter(0.0, "rad/s", "initial speed of the line")
    tau0: float = parameter(0.0, "N.m", "initial torque through the line (sets the initial twist of every spring)")
    node_phi_start: str = node_start_parameter("angle", "rad")
    node_w_start: str = node_start_parameter("speed", "rad/s")



class FlexibleShaft(LineComponent):
    """Drive-shaft line (see FlexibleShaftParams). Ports ``flange_a`` (inertia), ``flange_b`` (spring)."""

    model = "FlexibleShaft"
    PORTS = {"flange_a": INERTIA, "flange_b": SPRING}       #: port name -> kind (the FMU's flanges)

    def __init__(self, p: FlexibleShaftParams):
        check_parameters(p)
        self.p = p
        n = int(p.n_elements)
        if n < 1:
            raise ValueError(f"n_elements must be >= 1, got {n}")
        if n > MAX_ELEMENTS:
            raise ValueError(f"n_elements must be <= {MAX_ELEMENTS}, got {n}")
        if int(p.mass_model) not in (0, 1):
            raise ValueError(f"mass_model must be 0 (lumped) or 1 (consistent), got {p.mass_model}")
        for nm in FlexibleShaftParams.POSITIVE_FIELDS:
            if not getattr(p, nm) > 0:
                raise ValueError(f"{nm} must be > 0")
        ke = n * p.k_shaft
        ce = n * p.d_shaft
        Je = p.J_shaft / n
        J = [p.J_a]
        k, c = [], []
        names = ["hub_a"]
        if p.k_t > 0:
            J.append(p.J_b)
            k.append(p.k_t)
            c.append(p.d_t)
            names.append("hub_b")
        else:
            J[-1] += p.J_b
        self.i_hub_b = len(J) - 1
        # shaft nodes S0..S_{n-1}; S0 at hub B through the stiff coupling (or merged into hub B)
        shaft_nodes = []
        if p.k_c > 0:
            J.append(0.0)
            k.append(p.k_c)
            c.append(p.d_c)
            names.append("shaft_0")
        shaft_nodes.append(len(J) - 1)
        for i in range(1, n):
            J.append(0.0)
            k.append(ke)
            c.append(ce)
            names.append(f"shaft_{i}")
            shaft_nodes.append(len(J) - 1)
        J = np.array(J, dtype=float)
        Mo = np.zeros(max(len(J) - 1, 1))
        # element masses: elements 0..n-2 are internal (between shaft nodes), element n-1 is the port
        for e in range(n):
            i0 = shaft_nodes[e]
            if e < n - 1:
                i1 = shaft_nodes[e + 1]
                if int(p.mass_model) == 1:
                    J[i0] += Je / 3.0
                    J[i1] += Je / 3.0
                    Mo[i0] += Je / 6.0     # i1 = i0 + 1
                else:
                    J[i0] += Je / 2.0
                    J[i1] += Je / 2.0
            else:
                J[i0] += Je / 2.0          # the other half belongs to the body across flange_b
        self.shaft_nodes = shaft_nodes
        self.port_k = ke
        self.port_c = ce
        kind = self.PORTS
        ports = [Port("flange_a", 0, kind["flange_a"]), Port("flange_b", len(J) - 1, kind["flange_b"], 1.0, ke, ce)]
        self.line = LineModel(J, k, c, None, ports, (), max_substep=p.max_substep,
                              output_torque=p.output_torque, Mo=Mo, node_names=names,
                              energy_correction=bool(p.energy_correction))
        self.sensor_element = 0 if p.k_t > 0 else -1
        self._parse_node_start()
        self.initialize()

    def compliance_to_port(self) -> float:
        """Static twist per unit through-torque from hub A to the flange_b flange."""
        kk = [kv for kv in self.line.k[: self.line.n - 1]] + [self.port_k]
        return float(sum(1.0 / kv for kv in kk))

    def initialize(self):
        p = self.p
        th = np.empty(self.line.n)
        th[0] = p.phi0
        for i in range(1, self.line.n):
            th[i] = th[i - 1] - p.tau0 / self.line.k[i - 1]
        self.line.set_state(*self._node_start(th, np.full(self.line.n, p.w0)))
        self.torque_sensor = float(p.tau0) if self.sensor_element >= 0 else float(p.tau0)
        self.shaft_torque = float(p.tau0)

    def set_inputs(self, flange_a_tau, flange_b_phi, flange_b_w):
        self.line.set_input("flange_a", flange_a_tau)
        self.line.set_input("flange_b", flange_b_phi, flange_b_w)

    def step(self, t, H):
        self.line.step(t, H)
        em = self.line.el_mean
        self.torque_sensor = float(em[self.sensor_element]) if self.sensor_element >= 0 else float(
            self.line.tau_mean[1])
        self.shaft_torque = float(self.line.tau_mean[1])

    def step_outputs(self) -> dict:
        """The outputs every step changes, by FMU variable name (Python floats), read by the FMU shell after
        every step."""
        ln = self.line
        phi, w = ln.flange("flange_a")
        return {"flange_a_phi": phi, "flange_a_w": w, "flange_b_tau": float(ln.tau_out[1]),
                "flange_b_tau_mean": float(ln.tau_mean[1]), "torque_sensor": self.torque_sensor,
                "shaft_torque": self.shaft_torque, "hub_b_phi": float(ln.th[self.i_hub_b]),
                "hub_b_w": float(ln.om[self.i_hub_b]), "energy_dissipated": ln.energy_dissipated,
                "energy_supplied": ln.energy_supplied}
