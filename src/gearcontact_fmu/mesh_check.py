"""Is a triangle mesh usable as the pinion's or wheel's tooth surfaces? Load, validate, annotate.

Validation (:func:`validate_gear_mesh`) refuses with :class:`MeshError` and says which problem:
empty mesh; wrong scale (max distance from the apex vs. the outer cone distance outside
[0.5, 2]x; ~1000x / ~0.001x are reported as a metres-vs-millimetres mix-up); degenerate
(zero-area) faces — **refused** by :func:`validate_gear_mesh`; :func:`load_gear_mesh` drops them
first by default (``drop_degenerate=True``) and warns with the count; inconsistent winding
(trimesh ``is_winding_consistent`` after merging coincident vertices); closed meshes with volume
<= 0 (inside out); not facing the partner (less than ``min_zone_fraction`` = 50 % of the area in
the mesh zone: cone distance in ``[R_i - 0.1 b, R_e/cos(theta_a) + 0.1 b]`` and polar angle from
the tooth axis within the root..tip cone range widened by 25 % of its span each side; a wheel whose
teeth point to +z is recognised and the message says so); open meshes with normals into the
material (area-weighted mean of n . e_radial must be > 0, as for involute flanks whose outward
normal has a component away from the axis; checked after the zone so that it is meaningful).
Checks run in this order and the first failure is reported.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from . import geometry
from .meshes import MeshError, SurfaceMesh, load_mesh
from .params import BevelGearParams

__all__ = ["validate_gear_mesh", "annotate_gear_mesh", "load_gear_mesh"]


def _zone(params, role):
    g = geometry.gear_geometry(params, role)
    return g


def validate_gear_mesh(mesh: SurfaceMesh, params=None, role: str = "pinion", *, min_zone_fraction: float = 0.5,
                       rel_area_eps: float = 1e-12) -> SurfaceMesh:
    """Check that a mesh can be used as the pinion's or wheel's tooth surfaces; raise MeshError if not.

    Returns the mesh unchanged. See the module docstring for the checks and thresholds."""
    params = params or BevelGearParams()
    geometry._check_role(role)
    g = geometry.gear_geometry(params, role)
    name = f"{role} mesh"
    if mesh is None or mesh.n_faces == 0 or mesh.n_vertices == 0:
        raise MeshError(f"{name} is empty: no faces")
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshError(f"{name} has non-finite vertex coordinates")
    # scale: max distance from the apex vs. the outer cone distance (incl. the tip cone)
    r_max = float(np.linalg.norm(mesh.vertices, axis=1).max())
    r_exp = g.Re / math.cos(g.delta_a - g.delta)
    ratio = r_max / r_exp
    if not (0.5 <= ratio <= 2.0):
        hint = ""
        if 300 <= ratio <= 3000:
            hint = (" - it is ~1000x too large: it looks like a file in millimetres read as metres "
                    "(or micrometres read as millimetres); check the units argument")
        elif 1 / 3000 <= ratio <= 1 / 300:
            hint = (" - it is ~1000x (0.001x) too small: it looks like a file in metres read as "
                    "millimetres; check the units argument")
        raise MeshError(f"{name} is wrongly scaled: its largest distance from the apex (origin) is "
                        f"{r_max * 1e3:.6g} mm, expected about {r_exp * 1e3:.6g} mm (outer cone distance); "
                        f"ratio {ratio:.4g}{hint}. The body frame must have the cone apex at the origin.")
    # degenerate faces
    a = mesh.areas()
    eps = rel_area_eps * r_exp ** 2
    nbad = int(np.count_nonzero(~(a > eps)))
    if nbad:
        raise MeshError(f"{name} has {nbad} degenerate (zero-area) faces: they have no normal; "
                        "remove them (load_gear_mesh(drop_degenerate=True) does)")
    tm = mesh.to_trimesh(process=False)
    tm.merge_vertices()
    if not tm.is_winding_consistent:
        raise MeshError(f"{name} has inconsistent normals: the face winding is not consistent between "
                        "neighbouring faces, so some normals point into the material")
    # orientation: closed -> volume > 0; open -> area-weighted mean n . e_radial > 0
    closed = tm.is_watertight
    if closed:
        vol = float(tm.volume)
        if not vol > 0:
            raise MeshError(f"{name} is closed but its volume is {vol:.3g} m^3 <= 0: the normals point into "
                            "the material (faces are wound inside out)")
    # faces its partner: area in the mesh zone
    c = mesh.centroids()
    rho = np.linalg.norm(c, axis=1)
    ax = geometry.tooth_axis_body(role)
    pol = np.arccos(np.clip((c @ ax) / np.maximum(rho, 1e-300), -1, 1))
    tol_r = 0.1 * g.b
    tol_p = 0.25 * (g.delta_a - g.delta_f)
    in_zone = ((rho >= g.Ri - tol_r) & (rho <= r_exp + tol_r) & (pol >= g.delta_f - tol_p)
               & (pol <= g.delta_a + tol_p))
    frac = float(a[in_zone].sum() / a.sum())
    if frac < min_zone_fraction:
        pol_m = np.arccos(np.clip((c @ -ax) / np.maximum(rho, 1e-300), -1, 1))
        mirrored = ((rho >= g.Ri - tol_r) & (rho <= r_exp + tol_r) & (pol_m >= g.delta_f - tol_p)
                    & (pol_m <= g.delta_a + tol_p))
        hint = ""
        if a[mirrored].sum() / a.sum() >= min_zone_fraction:
            hint = (f" Its teeth point along {'-z' if role == 'pinion' else '+z'}: in the body frame the "
                    f"{role}'s teeth point towards {'+z' if role == 'pinion' else '-z'} (see geometry docs).")
        raise MeshError(
            f"{name} does not face its partner: only {100 * frac:.1f} % of its area lies in the mesh zone "
            f"(cone distance {1e3 * (g.Ri - tol_r):.2f}..{1e3 * (r_exp + tol_r):.2f} mm, polar angle from the "
            f"tooth axis {math.degrees(g.delta_f - tol_p):.2f}..{math.degrees(g.delta_a + tol_p):.2f} deg), "
            f"need {100 * min_zone_fraction:.0f} %. The body frame must have the apex at the origin and "
            f"the rotation axis along z.{hint}")
    if not closed:
        c = mesh.centroids()
        er = c.copy()
        er[:, 2] = 0.0
        rn = np.linalg.norm(er, axis=1)
        ok = rn > 0
        er[ok] /= rn[ok, None]
        mean = float(np.sum(a * np.einsum("ij,ij->i", mesh.normals(), er)) / a.sum())
        if not mean > 0:
            raise MeshError(f"{name}: normals point into the material (area-weighted mean of n . e_radial = "
                            f"{mean:.3g} <= 0; outward flank normals have a component away from the axis)")
    return mesh


def annotate_gear_mesh(mesh: SurfaceMesh, params=None, role: str = "pinion") -> SurfaceMesh:
    """Fill face_tooth (from the centroid azimuth) and face_flank (+1/-1 from the normal's azimuthal
    component) of a mesh without annotations (e.g. a loaded file). In place; returns the mesh."""
    g = geometry.gear_geometry(params, role)
    c = mesh.centroids()
    az_body = np.arctan2(c[:, 1], c[:, 0])
    az_gear = az_body if role == "pinion" else -az_body
    # tooth k centred at gear azimuth tooth_azimuth(k)
    a0 = float(geometry.tooth_azimuth(g, 0))
    step = geometry.tooth_azimuth(g, 1) - a0          # signed pitch in gear azimuth
    k = np.rint((az_gear - a0) / step).astype(np.int64) % g.z
    mesh.face_tooth = k.astype(np.int32)
    # flank side: azimuthal component of the normal relative to the tooth centre (gear frame)
    n = mesh.normals()
    if role == "wheel":
        n = n * np.array([1.0, -1.0, -1.0])
        c = c * np.array([1.0, -1.0, -1.0])
    az_c = np.arctan2(c[:, 1], c[:, 0])
    e_az = np.stack([-np.sin(az_c), np.cos(az_c), np.zeros_like(az_c)], axis=1)
    na = np.einsum("ij,ij->i", n, e_az)
    flank = np.where(na > 0.5, 1, np.where(na < -0.5, -1, 0)).astype(np.int8)
    mesh.face_flank = flank
    return mesh


def load_gear_mesh(path, params=None, role: str = "pinion", units: str = "mm", *, drop_degenerate: bool = True,
                   annotate: bool = True, min_zone_fraction: float = 0.5) -> SurfaceMesh:
    """Load an OBJ/STL of the pinion's or wheel's tooth surfaces (body frame, ``units``) and validate it.

    Degenerate faces are dropped (with a warning) unless ``drop_degenerate=False``; ``annotate``
    fills tooth indices and drive/coast flags from the geometry (:func:`annotate_gear_mesh`)."""
    mesh = load_mesh(path, units=units)
    if mesh.n_faces == 0:
        raise MeshError(f"{role} mesh {path!s} is empty: no faces")
    if drop_degenerate:
        a = mesh.areas()
        scale = float(np.linalg.norm(mesh.vertices, axis=1).max()) or 1.0
        bad = ~(a > 1e-12 * scale ** 2)
        if bad.any():
            warnings.warn(f"{path}: dropped {int(bad.sum())} degenerate (zero-area) faces", stacklevel=2)
            mesh = mesh.subset(~bad)
    try:
        validate_gear_mesh(mesh, params, role, min_zone_fraction=min_zone_fraction)
    except MeshError as exc:                     # the problem, and which file has it
        raise MeshError(f"{path!s}: {exc}") from None
    if annotate:
        annotate_gear_mesh(mesh, params, role)
    mesh.meta.update({"role": role, "source": str(path), "units": units})
    return mesh
