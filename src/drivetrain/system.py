"""System description: which FMUs, their parameters, and which flanges are connected.

Plain data, produced by the assembler from a scene and consumed by the master. A flange is the triple
``<port>_phi`` [rad], ``<port>_w`` [rad/s], ``<port>_tau`` [N·m]. A port is either on the
``"spring"`` side (inputs phi, w; output tau = torque applied to the connected body) or the
``"inertia"`` side (input tau; outputs phi, w). A connection joins one spring-side port to one
inertia-side port.

Every component FMU also outputs the energy-audit variables ``energy_stored`` [J],
``energy_dissipated`` [J] (cumulative) and ``energy_supplied`` [J] (cumulative work of sources inside the
FMU, e.g. motors), so that the master can close the balance with the power through every connection.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from gearcontact_fmu.params import INERTIA, SPRING  # noqa: F401  (the flange sides; re-exported)

#: how a system runs: "fmi" (the pythonfmu FMUs through FMI, fmpy), "inprocess" (the same slave classes
#: called directly, no FMI), "native" (compiled FMUs through FMI: drivetrain.fmu_build.native_line; a gear that is not
#: fidelity table keeps its pythonfmu FMU)
BACKENDS = ("fmi", "inprocess", "native")


def steps_per_output(comm_step: float, output_rate_Hz: float) -> tuple[int, str | None]:
    """The one rule tying the communication step to the output rate: H divides the output period.
    Returns (steps per output sample, None), or (0, what H should be, with the nearest divisor)."""
    period = 1.0 / output_rate_Hz
    r = period / comm_step
    if not math.isfinite(r) or r > 1e15:
        # a step so short against the period (a subnormal step, say) that no integer ratio can be told apart
        return 0, (f"a step that divides the output period 1/{output_rate_Hz:g} Hz = {period:.10g} s into at most "
                   f"1e15 steps (period/H = {r:.3g})")
    n = round(r)
    if n >= 1 and abs(r - n) <= 1e-6 * max(r, 1.0):
        return int(n), None
    m = max(1, math.ceil(r - 1e-9))
    return 0, (f"a step that divides the output period 1/{output_rate_Hz:g} Hz = {period:.10g} s "
               f"(period/H = {r:.8g} is not an integer); e.g. H = {period / m:.16g} = period/{m}")


@dataclass
class ComponentSpec:
    name: str                      # instance name in the system, e.g. "gear"
    model: str                     # FMU model name, e.g. "GearContact" (file fmus/<model>.fmu)
    parameters: dict = field(default_factory=dict)   # FMU variable name -> value (real/int/bool/str)
    inputs: dict = field(default_factory=dict)       # non-flange input variable -> constant value


@dataclass
class Connection:
    spring: str                    # "component.port" on the spring side
    inertia: str                   # "component.port" on the inertia side


@dataclass
class SystemSpec:
    components: list[ComponentSpec]
    connections: list[Connection]
    comm_step: float               # communication step H [s]; must divide the output period
    metadata: dict = field(default_factory=dict)

    def components_of(self, model: str) -> list[ComponentSpec]:
        """The components of FMU model ``model``, in the system's order."""
        return [c for c in self.components if c.model == model]
