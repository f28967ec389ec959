"""The energy balance of one LineModel step, for the tests that audit it (test_components, test_motor_disturbance)."""
from __future__ import annotations

import numpy as np

from drivetrain.system import SPRING


def step_energy_residual(comp, t: float, H: float) -> tuple[float, float]:
    """Step ``comp`` (its inputs set) over [t, t + H] and return (residual, scale) of supplied = delta stored +
    dissipated + work out through the ports; the stored energy at the step start is taken with the step's
    inputs (the port springs against phi_n)."""
    ln = comp.line
    e_start = ln.stored_energy({p.name: ln.p_u0[ln.port_index[p.name]] for p in ln.ports if p.kind == SPRING})
    d0, s0 = ln.energy_dissipated, ln.energy_supplied
    comp.step(t, H)
    e_end = ln.stored_energy()
    dd, ds = ln.energy_dissipated - d0, ln.energy_supplied - s0
    work_out = float(np.sum(ln.work_out))
    res = ds - (e_end - e_start) - dd - work_out
    return res, abs(ds) + abs(dd) + abs(work_out) + abs(e_end - e_start) + 1e-12
