"""The elastic layer of any pair: the rig's calibrated layer carried to another pair by a similarity law.

What. The polygonal contact gives each flank an elastic layer (``PCMParams``: E, nu and the depth b); the
teeth's bending and foundation are a series factor on top (``params.TOOTH_COMPLIANCE_FACTOR``). Both were
calibrated together on the rig's 15/60 pair of module 3 against ISO 6336's c_gamma (docs/GEAR-CONTACT.md,
"Tooth compliance"). :func:`pair_pcm` is the layer of another pair when its scene does not give one:
the rig's layer with the depth ``b = b_rig * sqrt(rho / rho_rig)``, ``rho`` the relative radius of curvature
of the flanks at the pitch point of the virtual spur gears at the mean cone distance (ISO 10300),
``1/rho = 1/rho_1 + 1/rho_2``, ``rho_i = r_vi sin(alpha)``.

Why this law. The layers (pressure per penetration k = K / (2 b) for two equal layers in series) on
flanks of relative radius rho carry a line load w (force per face width) on the strip |x| < a around the
contact line, with the pressure ``k (delta - x^2 / (2 rho))`` and ``a = sqrt(2 rho delta)``, so that
``w = (4/3) k a delta`` and the approach is ``delta = (3 w / (4 sqrt(2) k sqrt(rho)))^(2/3)``: at a
fixed b the mesh stiffens as ``rho^(1/3)``. A solid does not: the approach of an elastic half-space in
line contact depends on rho only through a logarithm (Hertz), and ISO 6336's single-pair stiffness c' of
the virtual spur gears depends on the numbers of teeth and the profile shifts, not on the size. The layer
stands in for the solid, so it must not bring a size effect the solid does not have: ``b / sqrt(rho)``
fixed keeps the approach at a given line load, and with it the calibration, what it was on the rig. The
figures behind it (the loaded stiffness of four pairs against ISO 6336, with the fixed and the scaled
layer) are in docs/GEAR-CONTACT.md, "Other pairs".

Trade-offs. The law scales the layer, not the tooth compliance factor: ISO 6336's c' changes with the
numbers of teeth by a few per cent between the pairs tried, and that change is left to the standard's
own spread (the check is within 10 %). A scene that names ``layer_depth_mm`` gets that depth as given.
The rig's pair (any pair with the rig's rho, e.g. another backlash) keeps the rig's layer exactly, so
its results are bit-identical.
"""
from __future__ import annotations

import dataclasses
import math

from gearcontact_fmu.mesh_models.analytic import virtual_spur_gears
from gearcontact_fmu.params import BevelGearParams, PCMParams

__all__ = ["pitch_curvature_radius", "layer_depth", "pair_pcm"]


def pitch_curvature_radius(gear: BevelGearParams) -> float:
    """Relative radius of curvature of the flanks [m] at the pitch point of the virtual spur gears at the
    mean cone distance: ``rho_1 rho_2 / (rho_1 + rho_2)``, ``rho_i = r_vi sin(alpha)``."""
    v = virtual_spur_gears(gear)
    r1, r2 = v["rho1_pitch"], v["rho2_pitch"]
    return r1 * r2 / (r1 + r2)


def layer_depth(gear: BevelGearParams | None = None, rig_layer_depth: float | None = None) -> float:
    """The layer depth [m] of ``gear``: the rig's (``rig_layer_depth``, default ``PCMParams().layer_depth``)
    times ``sqrt(rho / rho_rig)`` (module docstring). Exactly the rig's for a pair with the rig's rho. A pair
    whose virtual gears cannot be formed (a refused pair: ``pair_check`` says why) gets the rig's depth."""
    b_rig = PCMParams().layer_depth if rig_layer_depth is None else rig_layer_depth
    if gear is None:
        return b_rig
    try:
        ratio = pitch_curvature_radius(gear) / pitch_curvature_radius(BevelGearParams())
    except (ArithmeticError, ValueError):
        return b_rig
    if not (math.isfinite(ratio) and ratio > 0.0) or ratio == 1.0:
        return b_rig
    return b_rig * math.sqrt(ratio)


def pair_pcm(gear: BevelGearParams | None = None, pcm: PCMParams | None = None) -> PCMParams:
    """``pcm`` when given, else the elastic layer of ``gear`` (default the rig's pair): ``PCMParams()`` with
    the depth :func:`layer_depth`. The rig's pair gets ``PCMParams()`` itself."""
    if pcm is not None:
        return pcm
    base = PCMParams()
    b = layer_depth(gear, base.layer_depth)
    return base if b == base.layer_depth else dataclasses.replace(base, layer_depth=b)
