"""Tooth faults as changed surface meshes (the point of the PCM: a fault is just another mesh).

* :func:`mild_flank_fracture` - mild tooth flank fracture: a void across the full face width on the
  DRIVE flank of one tooth (default pinion tooth 0). Defaults (project choices, RIG.md leaves them
  open): width 1 mm measured along the profile, depth 0.3 mm measured along the flank normal, the
  strip centred on the pitch cone (``position = 0``; ``position`` > 0 moves it towards the tip, a
  profile distance in m). Like the teeth (tapered depth, all cones through the apex) the void scales
  with the cone distance: width, depth and position are the values at the mean cone distance R_m,
  so the removed flank area is exactly ``width * face_width``. The void is built properly: the
  tooth is re-meshed with the strip edges as mesh lines, the flank elements inside the strip are
  replaced by the void's floor (the flank offset by ``depth`` into the tooth; a parallel surface with
  the same exact normal) and two walls (planar sectors through the apex; exact normals along the
  profile tangent, pointing into the void). Floor and walls carry ``face_flank = 0`` and
  ``face_kind = KIND_VOID_FLOOR / KIND_VOID_WALL``; all outward, consistently wound, sharing the
  strip-edge vertices with the flank.
* :func:`missing_tooth` - severe fault: all surfaces of one tooth removed.
* :func:`apply_health` - ``"healthy" | "mild" | "severe" | "faults"`` for one member (pinion or wheel);
  ``"faults"`` applies a list of fault specifications (:data:`FAULT_KINDS`, :func:`apply_faults`), each
  on either gear, any tooth and flank, several at once.
* A user mesh (a faulty gear from CAD etc.) for pinion or wheel goes through
  :func:`gearcontact_fmu.mesh_check.load_gear_mesh` (also available here as :func:`user_mesh`).
"""
from __future__ import annotations

from . import geometry
from .mesh_check import load_gear_mesh
from .fault_specs import DEFAULT_DEPTH, DEFAULT_POSITION, DEFAULT_WIDTH, FAULT_KINDS, FLANKS, normalised_spec
from .mesh_model import GENERATED_HEALTH
from .meshes import SurfaceMesh, concatenate
from .params import BevelGearParams, MeshResolution

__all__ = ["mild_flank_fracture", "missing_tooth", "apply_health", "apply_faults", "user_mesh",
           "GENERATED_HEALTH", "FAULT_KINDS", "void_strip"]




def _analytic_role(mesh: SurfaceMesh) -> str:
    if mesh.meta.get("source") != "analytic" or "role" not in mesh.meta:
        raise ValueError("mild_flank_fracture needs a mesh from geometry.build_gear_mesh (a user mesh carries "
                         "its own faults: load it with mesh_check.load_gear_mesh)")
    return mesh.meta["role"]


def void_strip(params: BevelGearParams | None, role: str = "pinion", width: float = DEFAULT_WIDTH,
               position: float = DEFAULT_POSITION):
    """Profile parameters (s_a, s_b) [rad on the unit sphere] of the void strip on a flank."""
    g = geometry.gear_geometry(params, role)
    s_c = g.s_pitch_param + position / g.Rm
    half = 0.5 * width / g.Rm
    return s_c - half, s_c + half


def mild_flank_fracture(mesh: SurfaceMesh, params: BevelGearParams | None = None, tooth: int = 0,
                        width: float = DEFAULT_WIDTH, depth: float = DEFAULT_DEPTH,
                        position: float = DEFAULT_POSITION, flank: str = "drive") -> SurfaceMesh:
    """Mesh with a flank-fracture void on the ``flank`` ("drive" | "coast") of ``tooth`` (see module
    docstring).

    ``mesh`` must come from :func:`geometry.build_gear_mesh` (any role, any tooth subset containing
    ``tooth``); the tooth is re-meshed at the same resolution with the void."""
    params = params or BevelGearParams()
    role = _analytic_role(mesh)
    g = geometry.gear_geometry(params, role)
    mp = mesh.meta.get("params")
    if mp is not None and mp != params:
        raise ValueError("mesh was built with other gear parameters than the ones given")
    tooth = int(tooth) % g.z
    sel = mesh.face_tooth == tooth
    if not sel.any():
        raise ValueError(f"tooth {tooth} is not in the mesh")
    if not (width > 0 and depth > 0):
        raise ValueError("width and depth must be > 0")
    s_a, s_b = void_strip(params, role, width, position)
    s_top = g.L_radial + g.L_inv
    if s_a < 0 or s_b > s_top:
        raise ValueError(f"the void ({width * 1e3:g} mm at {position * 1e3:g} mm from the pitch cone) leaves the "
                         f"flank between the root cone and the tip rounding")
    if g.L_radial > 0 and s_a < g.L_radial < s_b:
        raise ValueError("the void must not straddle the base cone (radial root part / involute)")
    if depth > 0.5 * g.s_pitch:
        raise ValueError("void deeper than half the tooth thickness")
    if flank not in FLANKS:
        raise ValueError(f"flank must be one of {tuple(FLANKS)}, not {flank!r}")
    res = MeshResolution(profile=mesh.meta["profile"], face=mesh.meta["face"])
    faulty = geometry.build_gear_mesh(params, role, res, teeth=[tooth], top_land=mesh.meta.get("top_land", False),
                                      notch={tooth: (geometry._side_of_flank(FLANKS[flank]), s_a, s_b, depth / g.Rm)})
    out = concatenate([mesh.subset(~sel), faulty])
    out.meta = dict(mesh.meta)
    out.meta["faults"] = list(mesh.meta.get("faults", [])) + [
        {"type": "flank_fracture", "tooth": tooth, "width": width, "depth": depth, "position": position,
         "flank": flank}]
    return out


def missing_tooth(mesh: SurfaceMesh, tooth: int = 0) -> SurfaceMesh:
    """Mesh without any surface of ``tooth`` (severe fault)."""
    sel = mesh.face_tooth == int(tooth)
    if not sel.any():
        z = mesh.meta.get("params")
        raise ValueError(f"tooth {tooth} is not in the mesh (face_tooth has no such index)"
                         + ("" if z is None else ""))
    out = mesh.subset(~sel)
    out.meta["faults"] = list(mesh.meta.get("faults", [])) + [{"type": "missing_tooth", "tooth": int(tooth)}]
    return out


def apply_faults(mesh: SurfaceMesh, params: BevelGearParams | None, specs, member: str) -> SurfaceMesh:
    """The mesh of ``member`` with every specification of that member applied, in order."""
    for spec in specs:
        spec = normalised_spec(spec)
        if spec["member"] != member:
            continue
        if spec["kind"] == "missing_tooth":
            mesh = missing_tooth(mesh, spec["tooth"])
        else:
            mesh = mild_flank_fracture(mesh, params, tooth=spec["tooth"], width=spec["width_mm"] * 1e-3,
                                       depth=spec["depth_mm"] * 1e-3, position=spec["position_mm"] * 1e-3,
                                       flank=spec["flank"])
    return mesh


def apply_health(mesh: SurfaceMesh, params: BevelGearParams | None = None, health: str = "healthy",
                 member: str = "pinion", **kw) -> SurfaceMesh:
    """The generated mesh of ``member`` in a health state. ``healthy`` and ``mesh`` (a user mesh file
    replaces the other gear, or this one before it gets here): unchanged; ``mild``:
    :func:`mild_flank_fracture` (kw: tooth, width, depth, position); ``severe``: :func:`missing_tooth`
    (kw: tooth; other keys ignored) - both on the pinion only, as in the paper; ``faults``:
    :func:`apply_faults` with ``kw["faults"]``."""
    if health in ("healthy", "mesh"):
        return mesh
    if health == "faults":
        return apply_faults(mesh, params, kw.get("faults", []), member)
    if health not in GENERATED_HEALTH:
        raise ValueError(f"health must be one of {GENERATED_HEALTH + ('mesh',)}, not {health!r}")
    if member != "pinion":
        return mesh
    if health == "mild":
        return mild_flank_fracture(mesh, params, **kw)
    return missing_tooth(mesh, tooth=kw.get("tooth", 0))


def user_mesh(path, params: BevelGearParams | None = None, role: str = "pinion", units: str = "mm",
              **kw) -> SurfaceMesh:
    """A user's (possibly faulty) gear mesh file, loaded and validated (see mesh_check.load_gear_mesh)."""
    return load_gear_mesh(path, params, role, units=units, **kw)
