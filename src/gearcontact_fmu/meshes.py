"""Triangle surface meshes of gear teeth: plain arrays (SI), OBJ/STL I/O (files in mm), validation.

``SurfaceMesh`` holds numpy arrays only (no trimesh object), in metres, in the gear's body frame
(see :mod:`gearcontact_fmu.geometry` for the frames: pinion teeth towards body +z, wheel teeth
towards body -z). Faces are counter-clockwise seen from outside (geometric normal points out of
the material).

Per-face annotations (optional, filled by :func:`geometry.build_gear_mesh`):

* ``face_points`` / ``face_normals`` (m, 3): exact surface point and unit outward normal at the
  element, from the analytic surface (None for meshes without them, e.g. loaded files);
* ``face_tooth`` (m,) int32: tooth index, -1 unknown;
* ``face_flank`` (m,) int8: +1 drive flank, -1 coast flank, 0 other (tip rounding, top land, void
  floor and walls, unknown);
* ``face_kind`` (m,) int8: ``KIND_*`` below, -1 unknown;
* ``face_profile`` (m,) float64: profile parameter of the element on its flank (arc length on the
  unit sphere from the root cone, rad), NaN unknown.

Files: OBJ and STL through trimesh, the unit is an explicit argument (default ``"mm"``). STL is
written as ASCII (full float64 precision) unless ``binary=True`` (float32: ~1e-7 relative).

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
import os
import warnings
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "SurfaceMesh", "MeshError", "load_mesh", "save_mesh", "validate_gear_mesh", "load_gear_mesh",
    "concatenate", "annotate_gear_mesh", "UNITS",
    "FLANK_DRIVE", "FLANK_COAST", "FLANK_OTHER",
    "KIND_UNKNOWN", "KIND_FLANK", "KIND_ROOT_RADIAL", "KIND_TIP_ROUND", "KIND_TOP_LAND", "KIND_VOID_FLOOR",
    "KIND_VOID_WALL",
]

FLANK_DRIVE, FLANK_COAST, FLANK_OTHER = 1, -1, 0
KIND_UNKNOWN = -1
KIND_FLANK = 0          # spherical involute
KIND_ROOT_RADIAL = 1    # radial continuation of the flank below the base cone
KIND_TIP_ROUND = 2
KIND_TOP_LAND = 3
KIND_VOID_FLOOR = 4
KIND_VOID_WALL = 5

UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "cm": 1e-2, "in": 0.0254}


class MeshError(ValueError):
    """A mesh is unusable for the gear contact (the message says which problem and why)."""


def _unit_scale(units: str) -> float:
    try:
        return UNITS[units]
    except KeyError:
        raise ValueError(f"units must be one of {sorted(UNITS)}, not {units!r}") from None


@dataclass
class SurfaceMesh:
    """Triangle surface mesh, SI (m), body frame. Arrays only; see the module docstring."""

    vertices: np.ndarray
    faces: np.ndarray
    face_points: np.ndarray | None = None
    face_normals: np.ndarray | None = None
    face_tooth: np.ndarray | None = None
    face_flank: np.ndarray | None = None
    face_kind: np.ndarray | None = None
    face_profile: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.vertices = np.ascontiguousarray(np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3))
        self.faces = np.ascontiguousarray(np.asarray(self.faces, dtype=np.int64).reshape(-1, 3))
        m = self.faces.shape[0]
        if self.face_points is not None:
            self.face_points = np.ascontiguousarray(self.face_points, dtype=np.float64).reshape(m, 3)
        if self.face_normals is not None:
            self.face_normals = np.ascontiguousarray(self.face_normals, dtype=np.float64).reshape(m, 3)
        if (self.face_points is None) != (self.face_normals is None):
            raise ValueError("give both face_points and face_normals, or neither")
        self.face_tooth = (np.full(m, -1, np.int32) if self.face_tooth is None
                           else np.asarray(self.face_tooth, dtype=np.int32).reshape(m))
        self.face_flank = (np.zeros(m, np.int8) if self.face_flank is None
                           else np.asarray(self.face_flank, dtype=np.int8).reshape(m))
        self.face_kind = (np.full(m, KIND_UNKNOWN, np.int8) if self.face_kind is None
                          else np.asarray(self.face_kind, dtype=np.int8).reshape(m))
        self.face_profile = (np.full(m, np.nan) if self.face_profile is None
                             else np.asarray(self.face_profile, dtype=np.float64).reshape(m))
        if m and (self.faces.min() < 0 or self.faces.max() >= self.vertices.shape[0]):
            raise ValueError("faces index outside the vertex array")

    # --- basic geometry
    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def has_exact(self) -> bool:
        return self.face_points is not None

    def triangles(self) -> np.ndarray:
        return self.vertices[self.faces]

    def centroids(self) -> np.ndarray:
        return self.triangles().mean(axis=1)

    def _cross(self):
        t = self.triangles()
        return np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])

    def areas(self) -> np.ndarray:
        return 0.5 * np.linalg.norm(self._cross(), axis=1)

    def area(self) -> float:
        return float(self.areas().sum())

    def normals(self) -> np.ndarray:
        """Geometric unit normals (right-hand rule on the winding); zero for degenerate faces."""
        c = self._cross()
        n = np.linalg.norm(c, axis=1)
        out = np.zeros_like(c)
        ok = n > 0
        out[ok] = c[ok] / n[ok, None]
        return out

    def element_points(self) -> np.ndarray:
        """Exact face points if present, else centroids."""
        return self.face_points if self.face_points is not None else self.centroids()

    def element_normals(self) -> np.ndarray:
        return self.face_normals if self.face_normals is not None else self.normals()

    def edge_lengths(self) -> np.ndarray:
        t = self.triangles()
        return np.stack([np.linalg.norm(t[:, 1] - t[:, 0], axis=1), np.linalg.norm(t[:, 2] - t[:, 1], axis=1),
                         np.linalg.norm(t[:, 0] - t[:, 2], axis=1)], axis=1)

    # --- editing
    def subset(self, face_mask) -> "SurfaceMesh":
        """Mesh of the selected faces (bool mask or index array); unused vertices are dropped."""
        idx = np.asarray(face_mask)
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        faces = self.faces[idx]
        used, inv = np.unique(faces.reshape(-1), return_inverse=True)
        return SurfaceMesh(
            vertices=self.vertices[used], faces=inv.reshape(-1, 3),
            face_points=None if self.face_points is None else self.face_points[idx],
            face_normals=None if self.face_normals is None else self.face_normals[idx],
            face_tooth=self.face_tooth[idx], face_flank=self.face_flank[idx], face_kind=self.face_kind[idx],
            face_profile=self.face_profile[idx], meta=dict(self.meta))

    def copy(self) -> "SurfaceMesh":
        return self.subset(np.arange(self.n_faces))

    def flipped(self) -> "SurfaceMesh":
        """All faces reversed (normals negated)."""
        m = self.copy()
        m.faces = np.ascontiguousarray(m.faces[:, ::-1])
        if m.face_normals is not None:
            m.face_normals = -m.face_normals
        return m

    def transformed(self, R, t=None) -> "SurfaceMesh":
        """Rigid transform x -> R x + t (R a rotation)."""
        R = np.asarray(R, dtype=float)
        t = np.zeros(3) if t is None else np.asarray(t, dtype=float)
        m = self.copy()
        m.vertices = m.vertices @ R.T + t
        if m.face_points is not None:
            m.face_points = m.face_points @ R.T + t
            m.face_normals = m.face_normals @ R.T
        return m

    @classmethod
    def concatenate(cls, meshes) -> "SurfaceMesh":
        return concatenate(meshes)

    def to_trimesh(self, process: bool = False):
        import trimesh
        return trimesh.Trimesh(vertices=self.vertices, faces=self.faces, process=process)

    def tooth_areas(self, flank: int | None = None) -> dict:
        """Area per tooth index (optionally only faces of one flank code)."""
        a = self.areas()
        m = np.ones(self.n_faces, bool) if flank is None else self.face_flank == flank
        return {int(k): float(a[m & (self.face_tooth == k)].sum()) for k in np.unique(self.face_tooth[m])}


def concatenate(meshes) -> SurfaceMesh:
    """One mesh of several (vertices are not merged). Exact face data kept only if all have it."""
    meshes = [m for m in meshes if m is not None]
    if not meshes:
        raise ValueError("nothing to concatenate")
    off = np.cumsum([0] + [m.n_vertices for m in meshes])
    exact = all(m.face_points is not None for m in meshes)
    meta = dict(meshes[0].meta)
    return SurfaceMesh(
        vertices=np.concatenate([m.vertices for m in meshes]),
        faces=np.concatenate([m.faces + o for m, o in zip(meshes, off)]),
        face_points=np.concatenate([m.face_points for m in meshes]) if exact else None,
        face_normals=np.concatenate([m.face_normals for m in meshes]) if exact else None,
        face_tooth=np.concatenate([m.face_tooth for m in meshes]),
        face_flank=np.concatenate([m.face_flank for m in meshes]),
        face_kind=np.concatenate([m.face_kind for m in meshes]),
        face_profile=np.concatenate([m.face_profile for m in meshes]), meta=meta)


# ----------------------------------------------------------------------------- files

def _fmt(path):
    ext = os.path.splitext(str(path))[1].lower().lstrip(".")
    if ext not in ("obj", "stl"):
        raise ValueError(f"mesh files must be .obj or .stl, not {path!r}")
    return ext


def save_mesh(mesh: SurfaceMesh, path, units: str = "mm", binary: bool = False) -> None:
    """Write vertices/faces to OBJ or STL in ``units`` (default mm). Annotations are not stored.

    STL is ASCII by default (float64 text); ``binary=True`` writes float32 binary STL."""
    import trimesh
    from trimesh.exchange.obj import export_obj
    from trimesh.exchange.stl import export_stl, export_stl_ascii

    ext = _fmt(path)
    scale = _unit_scale(units)
    tm = trimesh.Trimesh(vertices=mesh.vertices / scale, faces=mesh.faces, process=False)
    if ext == "obj":
        data = export_obj(tm, include_normals=False, include_color=False, include_texture=False, digits=15)
        with open(path, "w") as f:
            f.write(data)
    elif binary:
        with open(path, "wb") as f:
            f.write(export_stl(tm))
    else:
        with open(path, "w") as f:
            f.write(export_stl_ascii(tm))


def load_mesh(path, units: str = "mm") -> SurfaceMesh:
    """Read an OBJ or STL whose coordinates are in ``units`` (default mm) -> SurfaceMesh in m.

    STL vertices are merged (exactly coincident ones) so that the winding can be checked; the face
    order is kept."""
    import trimesh

    ext = _fmt(path)
    scale = _unit_scale(units)
    tm = trimesh.load(str(path), file_type=ext, force="mesh", process=False)
    v = np.asarray(tm.vertices, dtype=np.float64)
    f = np.asarray(tm.faces, dtype=np.int64)
    if f.size:
        # merge exactly equal vertices (STL has none shared), keep face order
        uniq, inv = np.unique(v, axis=0, return_inverse=True)
        v, f = uniq, inv.reshape(-1)[f]
    return SurfaceMesh(vertices=v * scale, faces=f.reshape(-1, 3),
                       meta={"source": str(path), "units": units})


# ----------------------------------------------------------------------------- validation

def _zone(params, role):
    from . import geometry
    g = geometry.gear_geometry(params, role)
    return g


def validate_gear_mesh(mesh: SurfaceMesh, params=None, role: str = "pinion", *, min_zone_fraction: float = 0.5,
                       rel_area_eps: float = 1e-12) -> SurfaceMesh:
    """Check that a mesh can be used as the pinion's or wheel's tooth surfaces; raise MeshError if not.

    Returns the mesh unchanged. See the module docstring for the checks and thresholds."""
    from . import geometry
    from .params import BevelGearParams

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
    from . import geometry

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
    validate_gear_mesh(mesh, params, role, min_zone_fraction=min_zone_fraction)
    if annotate:
        annotate_gear_mesh(mesh, params, role)
    mesh.meta.update({"role": role, "source": str(path), "units": units})
    return mesh
