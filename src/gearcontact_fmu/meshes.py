"""Triangle surface meshes of gear teeth: plain arrays (SI) and OBJ/STL I/O (files in mm).

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

Validation against the gear geometry (:func:`gearcontact_fmu.mesh_check.validate_gear_mesh`,
``load_gear_mesh``) lives in :mod:`gearcontact_fmu.mesh_check`: it needs the geometry, which needs this module.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "SurfaceMesh", "MeshError", "load_mesh", "save_mesh", "concatenate", "UNITS",
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
    if not Path(path).is_file():
        raise MeshError(f"{path}: no such mesh file")
    try:
        tm = trimesh.load(str(path), file_type=ext, force="mesh", process=False)
        v = np.asarray(tm.vertices, dtype=np.float64).reshape(-1, 3)
        f = np.asarray(tm.faces, dtype=np.int64).reshape(-1, 3)
    except Exception as exc:  # noqa: BLE001 - whatever the reader meets in a file, the file is named
        raise MeshError(f"{path}: not a readable {ext.upper()} file ({type(exc).__name__}: {exc})") from None
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise MeshError(f"{path}: a face refers to vertex {int(f.max()) + 1 if f.max() >= len(v) else int(f.min())} "
                        f"of {len(v)} (the file is truncated or its face indices are wrong)")
    if not np.isfinite(v).all():
        raise MeshError(f"{path}: vertex coordinates that are not finite numbers")
    if f.size:
        # merge exactly equal vertices (STL has none shared), keep face order
        uniq, inv = np.unique(v, axis=0, return_inverse=True)
        v, f = uniq, inv.reshape(-1)[f]
    return SurfaceMesh(vertices=v * scale, faces=f.reshape(-1, 3),
                       meta={"source": str(path), "units": units})
