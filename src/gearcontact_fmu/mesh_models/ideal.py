"""The rigid mesh ("ideal" fidelity): exact ratio, no compliance, no backlash.

The rigid constraint has no constitutive law: the gear stage treats pinion and wheel as one body
(``MeshModel.kind == "rigid"``) and computes the constraint torque itself, so the kernel below is a
placeholder that the stage never calls. Faults and manufacturing errors do not apply (no mesh coordinate).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from gearcontact_fmu.mesh_models.base import MeshModel
from gearcontact_fmu.params import BevelGearParams


@njit(cache=True)
def ideal_eval(data, theta_pinion, theta_wheel, omega_pinion, omega_wheel, out):
    """Placeholder kernel of the ideal mesh: the rigid constraint has no constitutive law, the stage
    computes the constraint torque itself. Fills zeros (status ok)."""
    for i in range(out.shape[0]):
        out[i] = 0.0


def make_ideal_model(gear_params=None, pcm_params=None, resolution=None, **kw) -> MeshModel:
    """The rigid mesh: exact ratio, no compliance or backlash (faults do not apply)."""
    gear = gear_params or BevelGearParams()
    return MeshModel(eval=ideal_eval, data=(np.zeros(1),), fidelity="ideal", kind="rigid",
                     info={"ratio": gear.z_wheel / gear.z_pinion})
