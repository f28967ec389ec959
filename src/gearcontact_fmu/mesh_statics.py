"""A mesh model at rest: its loaded stiffness, and the wheel angle at which it carries a start torque.

Static analyses of any compliant mesh model (``mesh_models``): root searches along the mesh coordinate
s = theta_pinion - (z2/z1) theta_wheel on the very kernel a stage steps with.
:func:`static_mesh_stiffness` is the loaded mesh stiffness over a pitch (the validation's and the tooth
compliance's comparison with ISO 6336); :func:`balanced_wheel_angle` is where a run starts: the mesh at its
own static deflection under the port spring's torque (``drivetrain.run.assemble``), manufacturing errors and
friction at the start speeds included. Separate from the fidelities: it needs only ``MeshModel.eval``.
"""
from __future__ import annotations

import math

import numpy as np

from gearcontact_fmu.mesh_models.base import N_OUT, OUT_TAU_PINION, MeshModel
from gearcontact_fmu.params import BevelGearParams


def static_mesh_stiffness(model: MeshModel, gear: BevelGearParams, torque_Nm: float, n: int = 12,
                          phase: float = 0.013) -> dict:
    """Loaded mesh stiffness of a compliant mesh model at a static pinion torque, over one pitch (``n``
    angles): per angle the mesh coordinates carrying 0.95 and 1.05 times the torque (root searches) and
    the secant stiffness between them (independent of how finely a table resolves its approach axis);
    returned per unit face width along the line of action [N/(mm um)] (``k``, array), with its mean and
    the double/single ratio (max/min)."""
    from scipy.optimize import brentq

    from gearcontact_fmu.geometry import mean_base_radius      # (the surface geometry: only for this analysis)

    r = gear.z_wheel / gear.z_pinion
    out = np.zeros(N_OUT)
    rb = mean_base_radius(gear)

    def tau(th, s):
        model.eval(model.data, th, (th - s) / r, 0.0, 0.0, out)
        return -out[OUT_TAU_PINION]

    ks = []
    for th in np.linspace(0.0, 2 * math.pi / gear.z_pinion, n, endpoint=False) + phase:
        lo, hi = (brentq(lambda x: tau(th, x) - f * torque_Nm, 0.0, 0.05, xtol=1e-16) for f in (0.95, 1.05))
        k_rot = 0.1 * torque_Nm / (hi - lo)                             # N m / rad
        ks.append(k_rot / rb ** 2 * 1e-6 / (gear.face_width * 1e3))     # N/(mm um)
    k = np.array(ks)
    return {"k": k, "mean": float(k.mean()), "double_single": float(k.max() / k.min())}


#: how often the start search doubles its step before it gives up (2**60 times the first step: far past any
#: mesh, so only a model that carries no load at all ends there)
_BRACKET_DOUBLINGS = 60


class StartStateError(ValueError):
    """No mesh position carries the asked start torque (:func:`balanced_wheel_angle`): the message says why."""


def balanced_wheel_angle(model: MeshModel, ratio: float, theta_pinion: float, tau_pinion: float,
                         omega_pinion: float = 0.0, omega_wheel: float = 0.0, s_guess: float | None = None) -> float:
    """The wheel angle at which this compliant mesh model, at ``theta_pinion`` and the given speeds, puts
    exactly ``tau_pinion`` [N m] on the pinion (the mesh's own static deflection at that angle: a root
    search along the mesh coordinate s = theta_pinion - ratio theta_wheel, on the very kernel a stage steps
    with, manufacturing errors and friction at these speeds included). ``tau_pinion`` < 0 loads the drive
    flank (the mesh resists a driving pinion), > 0 the coast flank; 0 puts the pinion at the backlash
    centre. ``s_guess``: where to start bracketing (e.g. the analytic T / K_mean)."""
    from scipy.optimize import brentq

    out = np.zeros(N_OUT)
    tp, wp, ww, target = float(theta_pinion), float(omega_pinion), float(omega_wheel), float(tau_pinion)

    def residual(s):
        model.eval(model.data, tp, (tp - s) / ratio, wp, ww, out)
        return out[OUT_TAU_PINION] - target

    if target == 0.0:
        return tp / ratio
    if not (np.isfinite(target) and np.isfinite(tp) and np.isfinite(ratio) and ratio != 0.0):
        raise StartStateError(f"no start state for a pinion torque of {target!r} N m at a pinion angle of {tp!r} rad"
                              f" and a ratio of {ratio!r}: not finite numbers")
    sign = 1.0 if target < 0.0 else -1.0            # the flank that carries it: drive (s > 0) or coast
    step = abs(s_guess) if s_guess and np.isfinite(s_guess) else 1e-3

    def short(s):
        """True where the loaded flank carries less than the load (inside the backlash, on the other flank)."""
        r = residual(s)
        if not np.isfinite(r):
            raise StartStateError(f"the mesh model gives a pinion torque that is not finite ({r!r}) at s = {s:.6g} rad")
        return r * -target > 0.0

    # the short side: the backlash centre s = 0, unless the errors close the backlash there so far that the
    # flank already carries more than the load (a gearbox with large runout at this angle): then back off
    # towards the other flank until it carries less
    free, back = 0.0, step
    for _ in range(_BRACKET_DOUBLINGS):
        if short(free):
            break
        free, back = -sign * back, back * 2.0
    else:
        raise StartStateError(f"the loaded flank carries more than {abs(target):.6g} N m at every mesh position"
                              f" back to s = {free:.3g} rad")
    far = free + sign * step                       # the loaded side: widen until the flank carries more
    for _ in range(_BRACKET_DOUBLINGS):
        if not short(far):
            break
        free, far = far, far + sign * step
        step *= 2.0
    else:
        raise StartStateError(f"the mesh model carries no {abs(target):.6g} N m on the {'drive' if sign > 0 else 'coast'}"
                              f" flank within s = {far:.3g} rad")
    s = brentq(residual, min(free, far), max(free, far), xtol=1e-16, rtol=4 * np.finfo(float).eps, maxiter=200)
    return (tp - s) / ratio
