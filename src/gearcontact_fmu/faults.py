"""Tooth faults as changed surface meshes (the point of the PCM: a fault is just another mesh).

* :func:`mild_flank_fracture` - mild tooth flank fracture: a void across the full face width on the
  DRIVE flank of one tooth (default pinion tooth 0). Defaults (project choices, RIG.md leaves them
  open): width 1 mm measured along the profile, depth 0.3 mm measured along the flank normal, the
  strip centred on the pitch cone (``position = 0``; ``position`` > 0 moves it towards the tip, a
  profile distance in m). Like the teeth (tapered depth, all cones through the apex) the void scales
  with the cone distance: width, depth and position are the values at the mean cone distance R_m,
  so the removed flank area is exactly ``width * face_width``. The void is built properly: a patch
  of the flank around it is re-meshed with the strip edges as mesh lines, the flank elements inside the strip are
  replaced by the void's floor (the flank offset by ``depth`` into the tooth; a parallel surface with
  the same exact normal) and two walls (planar sectors through the apex; exact normals along the
  profile tangent, pointing into the void). Floor and walls carry ``face_flank = 0`` and
  ``face_kind = KIND_VOID_FLOOR / KIND_VOID_WALL``; all outward, consistently wound, sharing the
  strip-edge vertices with the flank.
* :func:`missing_tooth` - severe fault: all surfaces of one tooth removed.
* :func:`pit`, :func:`spall`, :func:`chipped_tip`, :func:`wear` - material removed from a flank along
  its normal by a depth field (a spherical cap; a flat-bottomed patch; a 45° chamfer at the tip; a
  uniform or sliding-weighted layer), re-meshed finely where the fault is (:func:`_dent`).
* :func:`crack` - a tooth-root crack grown through: the flank missing over part of the face width.
* Every fault but the missing tooth is cut in by local surgery (:func:`_surgery`): only a patch of its flank
  around the fault is meshed anew, every other element of the gear stays as it was, bit for bit and in
  order (a fault changes only the fault; issue 40).
* :func:`apply_health` - ``"healthy" | "mild" | "severe" | "faults"`` for one member (pinion or wheel);
  ``"faults"`` applies a list of fault specifications (:data:`FAULT_KINDS`, :func:`apply_faults`), each
  on either gear, any tooth and flank, several at once.
* A user mesh (a faulty gear from CAD etc.) for pinion or wheel goes through
  :func:`gearcontact_fmu.mesh_check.load_gear_mesh` (also available here as :func:`user_mesh`).
"""
from __future__ import annotations

import math

import numpy as np

from . import geometry
from .fault_specs import (DEFAULT_DEPTH, DEFAULT_POSITION, DEFAULT_WIDTH, FAULT_KINDS, FLANKS, WEAR_PROFILES,
                          FaultGeometryError, normalised_spec)
from .mesh_check import load_gear_mesh
from .mesh_models.base import GENERATED_HEALTH
from .meshes import KIND_TIP_ROUND, SurfaceMesh, concatenate
from .params import BevelGearParams, MeshResolution

__all__ = ["mild_flank_fracture", "missing_tooth", "pit", "spall", "chipped_tip", "crack", "wear", "partner_profile_bands", "apply_health", "apply_faults", "user_mesh",
           "GENERATED_HEALTH", "FAULT_KINDS", "FAMILIES", "void_strip", "fault_footprint"]


def _analytic_role(mesh: SurfaceMesh) -> str:
    if mesh.meta.get("source") != "analytic" or "role" not in mesh.meta:
        raise ValueError("a generated fault needs a mesh from geometry.build_gear_mesh (a user mesh carries "
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
    params, role, g, tooth = _check_tooth(mesh, params, tooth, flank)
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
    notch = (geometry._side_of_flank(FLANKS[flank]), s_a, s_b, depth / g.Rm)
    return _surgery(mesh, params, role, g, tooth, flank, (s_a, s_b), (g.Ri, g.Re), mesh.meta["profile"], [],
                    {"type": "flank_fracture", "tooth": tooth, "width": width, "depth": depth,
                     "position": position, "flank": flank}, f"void ({width * 1e3:g} mm)", notch=notch)


def missing_tooth(mesh: SurfaceMesh, tooth: int = 0) -> SurfaceMesh:
    """Mesh without any surface of ``tooth`` (severe fault)."""
    tooth = int(tooth)
    if not np.any(mesh.face_tooth == tooth):
        raise ValueError(f"tooth {tooth} is not in the mesh (face_tooth has no such index)")
    return _with_tooth(mesh, tooth, None, {"type": "missing_tooth", "tooth": tooth})


def pit_depth(r, radius: float, depth: float):
    """Depth [m] of a spherical-cap pit (base radius ``radius``, depth ``depth`` at its centre) at the
    distance r from its centre; 0 outside."""
    rs = (radius * radius + depth * depth) / (2.0 * depth)          # radius of the sphere
    r = np.minimum(np.asarray(r, dtype=float), radius)
    # sqrt(rs^2 - r^2) - (rs - depth), written without cancellation (a shallow pit has a huge sphere)
    return np.where(r < radius, depth - r * r / (rs + np.sqrt(rs * rs - r * r)), 0.0)


def pit_volume(radius: float, depth: float) -> float:
    """Volume [m^3] of the spherical cap (the closed form the geometry test checks against)."""
    return math.pi * depth * (3.0 * radius * radius + depth * depth) / 6.0


def pit_band(rho_c: float, radius: float) -> tuple:
    """Face band ``(rho_lo, rho_hi, fine)`` resolving a pit of ``radius`` at cone distance ``rho_c``."""
    return (rho_c - 1.25 * radius, rho_c + 1.25 * radius, radius / 4.0)


def _wheel_specs_for(member: str, specs) -> list[dict]:
    """The wheel's faults (normalised) whose edges ``member``'s mesh must follow: the pinion follows the wheel's
    faults (it probes the wheel's surface); the wheel, as the target, follows none."""
    if member != "pinion":
        return []
    return [s for s in map(normalised_spec, specs) if s["member"] == "wheel"]


def partner_face_bands(params: BevelGearParams | None, specs, member: str) -> list:
    """Face bands the ``member`` needs because the other gear has faults with edges across the face (a
    pit; a spall, a crack, a chipped tip over part of the face): the pinion's elements probe the wheel's
    surface, so a wheel fault's face edges fall between the pinion's face rows wherever they happen to sit
    (a pit narrower than the rows: a blind spot; a 4 mm spall or a 5 mm crack: 2 or 3 of the 2 mm rows,
    a drop 15 % off the converged one, issue 40). The band puts the pinion's rows as the fault's own
    patch has them. Both cones share the apex, so the fault's cone distance is where the pinion meets
    it; every pinion tooth gets the band (the teeth stay rotated copies of one tooth and the contact map
    keeps computing one healthy pitch). The wheel, as the target, needs none."""
    params = params or BevelGearParams()
    g = geometry.gear_geometry(params, "wheel")
    out = []
    for spec in _wheel_specs_for(member, specs):
        rho_c = g.Ri + spec.get("face_position", 0.5) * (g.Re - g.Ri)
        if spec["kind"] == "pit":
            out.append(pit_band(rho_c, spec["radius_mm"] * 1e-3))
        elif spec["kind"] == "spall":
            w = spec["width_mm"] * 1e-3
            out.append((rho_c - 0.5 * w - w / 8.0, rho_c + 0.5 * w + w / 8.0, w / 8.0))
        elif spec["kind"] == "crack":
            L = spec["length_mm"] * 1e-3
            out.append((rho_c - 0.5 * L, rho_c + 0.5 * L, L / 4.0))
        elif spec["kind"] == "chipped_tip" and 0.0 < spec["length_mm"] * 1e-3 < g.b:
            L = spec["length_mm"] * 1e-3
            out.append((rho_c - 0.5 * L - L / 8.0, rho_c + 0.5 * L + L / 8.0, L / 8.0))
    return out


def conjugate_profile_param(params: BevelGearParams | None, role: str, s) -> np.ndarray:
    """Profile parameter [rad] of the other gear's involute that meets ``role``'s involute at its profile
    parameter ``s`` (in the plane of action). Both spherical involutes are drawn by points of that plane,
    at the angles psi from the two base cones' generators; the two angles add up to the same total at
    every contact, the sum of the pitch cones' psi (where the two meet at the pitch cone)."""
    params = params or BevelGearParams()
    g = geometry.gear_geometry(params, role)
    h = geometry.gear_geometry(params, "wheel" if role == "pinion" else "pinion")

    def psi_pitch(q):
        return math.acos(math.cos(q.delta) / math.cos(q.delta_b))

    sdb, cdb = math.sin(g.delta_b), math.cos(g.delta_b)
    si = g.s_inv0 + (np.asarray(s, dtype=float) - g.L_radial)
    psi = np.arccos(np.clip(1.0 - si * sdb / cdb, -1.0, 1.0))
    psi_h = psi_pitch(g) + psi_pitch(h) - psi
    shb, chb = math.sin(h.delta_b), math.cos(h.delta_b)
    return h.L_radial + chb * (1.0 - np.cos(psi_h)) / shb - h.s_inv0


def partner_profile_bands(params: BevelGearParams | None, specs, member: str) -> list:
    """Profile bands ``[(s_lo, s_hi, fine), ...]`` [rad] the ``member`` needs because the other gear has a
    chipped tip: the chamfer's edge (the wheel's new tip) runs across the pinion's flank where the two
    involutes stop being conjugate, and where it sits between the pinion's profile nodes decides a light
    load's drop (issue 40: the wheel's chipped tip at 0.12 N·m, 0.430 at 0.05 mm and 0.382 at 0.025 mm).
    The band covers the pinion's involute from its start (the healthy wheel's tip rounding touches it
    below the conjugate of the wheel's involute end: measured, that light contact is what the chip takes
    away at the largest drop) to a quarter of the chamfer height beyond the edge's conjugate point, with
    nodes every height/32 (the chamfer's own spacing is height/16). Every pinion tooth, both flanks, gets
    it (the teeth stay rotated copies of one tooth), so the faulty map's own healthy pitch is the healthy
    pair at that refinement: the drop's reference (benchmarks/fault_convergence.py). The wheel needs none
    (the pinion's chipped tip converges without it)."""
    params = params or BevelGearParams()
    g = geometry.gear_geometry(params, "wheel")
    out = []
    for spec in _wheel_specs_for(member, specs):
        if spec["kind"] != "chipped_tip":
            continue
        h = spec["height_mm"] * 1e-3
        s_end = g.L_radial + g.L_inv
        edge = float(conjugate_profile_param(params, "wheel", s_end - h / g.Rm))
        out.append((geometry.gear_geometry(params, "pinion").L_radial, edge + 0.25 * h / g.Rm, h / 32.0 / g.Rm))
    return out


def _check_tooth(mesh, params, tooth, flank):
    """The checks every fault on a generated gear shares: (params, role, geometry, tooth mod z)."""
    params = params or BevelGearParams()
    role = _analytic_role(mesh)
    g = geometry.gear_geometry(params, role)
    mp = mesh.meta.get("params")
    if mp is not None and mp != params:
        raise ValueError("mesh was built with other gear parameters than the ones given")
    tooth = int(tooth) % g.z
    if not np.any(mesh.face_tooth == tooth):
        raise ValueError(f"tooth {tooth} is not in the mesh")
    if flank not in FLANKS:
        raise ValueError(f"flank must be one of {tuple(FLANKS)}, not {flank!r}")
    return params, role, g, tooth


def _with_tooth(mesh: SurfaceMesh, tooth: int, new_tooth: SurfaceMesh | None, record: dict) -> SurfaceMesh:
    """``mesh`` with ``tooth`` replaced by ``new_tooth`` (None: removed) and ``record`` added to its faults."""
    kept = mesh.subset(mesh.face_tooth != tooth)
    out = kept if new_tooth is None else concatenate([kept, new_tooth])
    out.meta = dict(mesh.meta)
    out.meta["faults"] = list(mesh.meta.get("faults", [])) + [record]
    return out


def _side_faces(mesh: SurfaceMesh, tooth: int, flank: str) -> np.ndarray:
    """The faces of ``tooth`` on the strip of ``flank``: the flank itself (root part, involute) and the tip
    rounding next to it (the outward normals of a side point the same way round the gear axis, body z)."""
    on_tooth = mesh.face_tooth == tooth
    side = on_tooth & (mesh.face_flank == FLANKS[flank])
    pts = mesh.element_points()
    az = np.einsum("ij,ij->i", mesh.element_normals(), np.stack([-pts[:, 1], pts[:, 0], np.zeros(len(pts))], axis=1))
    sign = np.sign(np.mean(az[side]))
    return side | (on_tooth & (mesh.face_kind == KIND_TIP_ROUND) & (az * sign > 0.0))


def _dent_patch(patch: SurfaceMesh, flank: str, depth_field) -> tuple:
    """The vertices of ``patch`` (all on one side's strip) moved inward along their exact normals by
    ``depth_field(vertices, profile_param, rho)`` [m] (0 = untouched): (moved patch, which vertices moved).
    Elements with a moved vertex become flat facets (point = centroid, normal = facet normal), as in a mesh
    file: the exact flank no longer describes them. (The exact point of a rim element, whose centroid
    parameter lies just outside a pit while two of its vertices moved in, stands proud of its facet by tens
    of um: measured, it made the pair touch 0.6 mrad early.)"""
    t = patch
    side = t.face_flank == FLANKS[flank]
    nv = len(t.vertices)
    # per vertex: the profile parameter and exact normal averaged over its faces
    cnt = np.zeros(nv)
    s_v = np.zeros(nv)
    n_v = np.zeros((nv, 3))
    n_side = np.zeros((nv, 3))              # the normal of the flank itself where a vertex has one
    for c in range(3):
        idx = t.faces[:, c]
        np.add.at(cnt, idx, 1.0)
        np.add.at(s_v, idx, t.face_profile)
        np.add.at(n_v, idx, t.face_normals)
        np.add.at(n_side, t.faces[side, c], t.face_normals[side])
    used = cnt > 0
    s_v[used] /= cnt[used]
    has_side = np.linalg.norm(n_side, axis=1) > 0.0
    n_v[has_side] = n_side[has_side]
    n_v[used] /= np.linalg.norm(n_v[used], axis=1)[:, None]
    rho_v = np.linalg.norm(t.vertices, axis=1)
    d_v = np.where(used, depth_field(t.vertices, s_v, rho_v), 0.0)
    moved = d_v > 0.0
    V = t.vertices - d_v[:, None] * n_v
    touched = np.any(moved[t.faces], axis=1)
    fp = t.face_points.copy()
    fn = t.face_normals.copy()
    tri = V[t.faces[touched]]
    geo = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fp[touched] = tri.mean(axis=1)
    fn[touched] = geo / np.linalg.norm(geo, axis=1)[:, None]
    return SurfaceMesh(vertices=V, faces=t.faces, face_points=fp, face_normals=fn, face_tooth=t.face_tooth,
                       face_flank=t.face_flank, face_kind=t.face_kind, face_profile=t.face_profile), moved


def _surgery(mesh: SurfaceMesh, params, role, g, tooth: int, flank: str, s_box, rho_box, profile_step: float,
             bands, record: dict, what: str, depth_field=None, notch=None, cut=None) -> SurfaceMesh:
    """``mesh`` with the fault cut into ``tooth`` by local surgery: every element outside the fault's patch
    stays as it is, bit for bit (vertices, faces, face data, order); only the healthy elements of the patch
    are taken out and replaced at the end of the face list.

    The patch is the rectangle of ``flank``'s strip (root part, involute, tip rounding on that side) whose
    edges are the tooth's own mesh lines just outside ``s_box`` (profile parameters [rad]) and ``rho_box``
    (cone distances [m]). It is meshed anew with the profile spacing at most ``profile_step`` [m] and the
    face rows refined in ``bands`` (as well as in the mesh's own face bands); the healthy rows and nodes on
    its edges are kept, so the patch meets its neighbours along their edges (finer nodes on those edges
    lie on the exact flank, a few 1e-11 m from the healthy chord: hanging nodes, which the element-wise
    contact does not mind). Then ``notch`` (a void: walls and floor in place of the flank), or
    ``depth_field`` (:func:`_dent_patch`; a field that still moves a vertex on the patch's edge widens the
    patch by one element that way), and ``cut(patch)`` -> faces to drop (a crack). A patch that overlaps an
    earlier fault's on the same tooth refuses (the earlier one would be lost)."""
    side_code = FLANKS[flank]
    side = geometry._side_of_flank(side_code)
    top_land = mesh.meta.get("top_land", False)
    nodes = geometry.flank_profile_nodes(g, mesh.meta["profile"], side, mesh.meta.get("profile_bands", ()))
    mesh_bands = list(mesh.meta.get("face_bands", []))
    rows = np.asarray(geometry.graded_face_nodes(g, mesh.meta["face"], mesh_bands))
    fine_rows = np.asarray(geometry.graded_face_nodes(g, mesh.meta["face"], mesh_bands + list(bands)))
    i0 = max(int(np.searchsorted(nodes, s_box[0] + 1e-15, side="right")) - 1, 0)
    i1 = min(int(np.searchsorted(nodes, s_box[1] - 1e-15, side="left")), nodes.size - 1)
    j0 = max(int(np.searchsorted(rows, rho_box[0] + 1e-12, side="right")) - 1, 0)
    j1 = min(int(np.searchsorted(rows, rho_box[1] - 1e-12, side="left")), rows.size - 1)
    for _ in range(64):
        s_lo, s_hi, r_lo, r_hi = nodes[i0], nodes[i1], rows[j0], rows[j1]
        inner = fine_rows[(fine_rows > r_lo + 1e-9) & (fine_rows < r_hi - 1e-9)]
        rho_p = np.concatenate([[r_lo], inner, [r_hi]])
        patch = geometry.flank_patch(params, role, side, s_lo, s_hi, rho_p, profile_step, tooth=tooth, notch=notch,
                                     nodes=nodes)
        if depth_field is None:
            break
        patch, moved = _dent_patch(patch, flank, depth_field)
        if not np.any(moved):
            raise ValueError(f"the {what} leaves the {flank} flank of tooth {tooth}")
        # which edges of the patch moved: widen it that way (an edge at the strip's free end may move)
        grid = moved.reshape(-1, rho_p.size)          # (profile nodes in the strip's direction, rows)
        first, last = (grid[-1], grid[0]) if side == 1 else (grid[0], grid[-1])     # low s, high s
        grow = [bool(first.any()) and i0 > 0, bool(last.any()) and i1 < nodes.size - 1,
                bool(grid[:, 0].any()) and j0 > 0, bool(grid[:, -1].any()) and j1 < rows.size - 1]
        if (last.any() and i1 == nodes.size - 1 and top_land) or (first.any() and i0 == 0 and s_lo > 0.0):
            raise ValueError(f"the {what} leaves the {flank} flank of tooth {tooth}")
        if not any(grow):
            break
        i0, i1, j0, j1 = i0 - grow[0], i1 + grow[1], j0 - grow[2], j1 + grow[3]
    else:
        raise ValueError(f"the {what} does not fit a patch of the {flank} flank of tooth {tooth}")
    if cut is not None:
        patch = patch.subset(~cut(patch))
    # the healthy elements of the rectangle
    strip = _side_faces(mesh, tooth, flank)
    cent_rho = np.linalg.norm(mesh.centroids(), axis=1)
    out = strip & (mesh.face_profile > s_lo) & (mesh.face_profile < s_hi) & (cent_rho > r_lo) & (cent_rho < r_hi)
    expected = 2 * (i1 - i0) * (j1 - j0)
    later = [p for p in mesh.meta.get("patches", []) if p[0] == tooth and p[1] == flank
             and p[2] < s_hi and s_lo < p[3] and p[4] < r_hi and r_lo < p[5]]
    if later or int(out.sum()) != expected:
        raise FaultGeometryError(f"the {what} on the {flank} flank of tooth {tooth} overlaps another fault on that "
                                 f"tooth: put one fault per place (the patches may not overlap)")
    res = concatenate([mesh.subset(~out), patch])
    res.meta = dict(mesh.meta)
    res.meta["faults"] = list(mesh.meta.get("faults", [])) + [{"tooth": tooth, "flank": flank, **record}]
    res.meta["patches"] = list(mesh.meta.get("patches", [])) + [(tooth, flank, float(s_lo), float(s_hi),
                                                                  float(r_lo), float(r_hi))]
    return res


def _dent(mesh: SurfaceMesh, params, role, g, tooth: int, flank: str, depth_field, s_box, rho_box, bands,
          profile_step: float, record: dict, what: str) -> SurfaceMesh:
    """``mesh`` with the material of ``depth_field`` removed from ``flank`` of ``tooth`` by local surgery
    (:func:`_surgery`) over the patch around ``s_box`` x ``rho_box``."""
    return _surgery(mesh, params, role, g, tooth, flank, s_box, rho_box, profile_step, bands, record, what,
                    depth_field=depth_field)


def _face_rho(g, face_position: float, half: float, what: str, flank: str, tooth: int) -> float:
    if not 0.0 <= face_position <= 1.0:
        raise ValueError("face_position must be within 0 (toe) .. 1 (heel)")
    rho_c = g.Ri + face_position * (g.Re - g.Ri)
    if rho_c - half < g.Ri - 1e-12 or rho_c + half > g.Re + 1e-12:
        raise ValueError(f"the {what} at face position {face_position:g} leaves the {flank} flank of tooth {tooth} "
                         f"across the face ends: keep face_position within {half / g.b:.3g} .. {1 - half / g.b:.3g}")
    return rho_c


def pit(mesh: SurfaceMesh, params: BevelGearParams | None = None, tooth: int = 0, flank: str = "drive",
        radius: float = 1.5e-3, depth: float = 0.25e-3, face_position: float = 0.5,
        position: float = DEFAULT_POSITION) -> SurfaceMesh:
    """Mesh with a pit on ``flank`` of ``tooth``: a spherical cap of base radius ``radius`` and depth
    ``depth`` pressed into the flank, centred ``position`` from the pitch cone towards the tip and at
    ``face_position`` of the face width (0 toe, 1 heel). The tooth is re-meshed with face rows every
    radius/4 across the pit (a pit between two of the default 2 mm rows would otherwise be invisible)
    and the profile spacing at most radius/8."""
    params, role, g, tooth = _check_tooth(mesh, params, tooth, flank)
    if not (radius > 0 and 0 < depth < radius):
        raise ValueError("a pit needs radius > 0 and 0 < depth < radius")
    what = f"pit (radius {radius * 1e3:g} mm, {position * 1e3:g} mm from the pitch cone)"
    rho_c = _face_rho(g, face_position, radius, what, flank, tooth)
    record = {"type": "pit", "radius": radius, "depth": depth, "face_position": face_position,
              "position": position, "volume": pit_volume(radius, depth)}
    s_c, half_s = g.s_pitch_param + position / g.Rm, 1.25 * radius / (rho_c - radius)
    band = pit_band(rho_c, radius)
    return _dent(mesh, params, role, g, tooth, flank, _pit_field(g, flank, tooth, radius, depth, rho_c, position),
                 (s_c - half_s, s_c + half_s), band[:2], [band], radius / 8.0, record, what)


def _pit_field(g, flank: str, tooth: int, radius: float, depth: float, rho_c: float, position: float):
    """The pit's depth field (V, s, rho) -> depth [m]: a spherical cap about its centre on the flank."""
    pc, _ = geometry.flank_point_normal(g, FLANKS[flank], g.s_pitch_param + position / g.Rm, rho_c, tooth=tooth)
    return lambda V, s, rho: pit_depth(np.linalg.norm(V - pc, axis=-1), radius, depth)


def spall(mesh: SurfaceMesh, params: BevelGearParams | None = None, tooth: int = 0, flank: str = "drive",
          length: float = 2.0e-3, width: float = 4.0e-3, depth: float = 0.1e-3, face_position: float = 0.5,
          position: float = DEFAULT_POSITION) -> SurfaceMesh:
    """Mesh with a spall on ``flank`` of ``tooth``: a flat-bottomed patch ``length`` along the profile
    (at the mean cone distance, tapered with the teeth like the void) by ``width`` along the face, the
    flank moved ``depth`` inward inside it, centred ``position`` from the pitch cone and at
    ``face_position`` of the face width. Face rows land on its two face edges (every width/8 between),
    the profile spacing is at most length/32: the walls are one element wide."""
    params, role, g, tooth = _check_tooth(mesh, params, tooth, flank)
    if not (length > 0 and width > 0 and depth > 0):
        raise ValueError("a spall needs length, width and depth > 0")
    what = f"spall ({length * 1e3:g} x {width * 1e3:g} mm, {position * 1e3:g} mm from the pitch cone)"
    rho_c = _face_rho(g, face_position, 0.5 * width, what, flank, tooth)
    lo, hi = rho_c - 0.5 * width, rho_c + 0.5 * width
    record = {"type": "spall", "length": length, "width": width, "depth": depth, "face_position": face_position,
              "position": position, "volume": length * width * depth * (rho_c / g.Rm) ** 2}

    el_s = min(mesh.meta["profile"], length / 32.0) / g.Rm       # the profile spacing [rad]
    el_f = width / 8.0                                            # the face rows inside the spall
    field = _spall_field(g, length, width, depth, rho_c, position, el_s, el_f)
    s_c, half_s = g.s_pitch_param + position / g.Rm, 0.5 * length / g.Rm + el_s
    return _dent(mesh, params, role, g, tooth, flank, field, (s_c - half_s, s_c + half_s), (lo - el_f, hi + el_f),
                 [(lo - el_f, hi + el_f, el_f)], length / 32.0, record, what)


def _spall_field(g, length: float, width: float, depth: float, rho_c: float, position: float, el_s: float,
                 el_f: float):
    """The spall's depth field: the patch, its walls linear ramps ``el_s`` [rad] along the profile and ``el_f``
    [m] along the face wide, centred on its edges (the volume is the patch's)."""
    s_c = g.s_pitch_param + position / g.Rm
    half_s = 0.5 * length / g.Rm

    def field(V, s, rho):
        ramp_s = np.clip((half_s - np.abs(s - s_c)) / el_s + 0.5, 0.0, 1.0)
        ramp_f = np.clip((0.5 * width - np.abs(rho - rho_c)) / el_f + 0.5, 0.0, 1.0)
        return depth * ramp_s * ramp_f * rho / g.Rm

    return field


def chipped_tip(mesh: SurfaceMesh, params: BevelGearParams | None = None, tooth: int = 0, flank: str = "drive",
                height: float = 0.5e-3, length: float | None = None, face_position: float = 0.5) -> SurfaceMesh:
    """Mesh with the tip corner of ``flank`` chipped off: a 45° chamfer ``height`` deep along the profile
    from the end of the flank (its tip rounding included) at the mean cone distance (tapered with the
    teeth), over ``length`` of the face width (None or 0: the whole face) centred at ``face_position``."""
    params, role, g, tooth = _check_tooth(mesh, params, tooth, flank)
    length = length or g.b
    if not (height > 0 and length > 0):
        raise ValueError("a chipped tip needs height and length > 0")
    what = f"chipped tip ({height * 1e3:g} mm high, {length * 1e3:g} mm long)"
    rho_c = _face_rho(g, face_position, 0.5 * length, what, flank, tooth)
    lo, hi = rho_c - 0.5 * length, rho_c + 0.5 * length
    if height / g.Rm >= g.L_inv:
        raise ValueError(f"the {what} is higher than the involute flank")
    record = {"type": "chipped_tip", "height": height, "length": length, "face_position": face_position,
              "volume": 0.5 * height * height * length * ((rho_c / g.Rm) ** 2 if length < g.b else
                                                            (g.Re ** 3 - g.Ri ** 3) / (3.0 * g.Rm ** 2 * g.b))}

    el_f = min(length / 8.0, mesh.meta["face"])
    field = _chip_field(g, height, length, rho_c, el_f)
    bands = [] if length >= g.b else [(lo - el_f, hi + el_f, el_f)]
    s_box = (g.L_radial + g.L_inv - height / g.Rm, math.inf)            # up to the end of the tip rounding
    rho_box = (lo - el_f, hi + el_f) if bands else (g.Ri, g.Re)
    return _dent(mesh, params, role, g, tooth, flank, field, s_box, rho_box, bands, height / 16.0, record, what)


def _chip_field(g, height: float, length: float, rho_c: float, el_f: float):
    """The chipped tip's depth field: the 45° chamfer from ``height`` below the end of the involute, over
    ``length`` of the face about ``rho_c`` (its ends linear ramps ``el_f`` [m] wide), or the whole face."""
    s_end = g.L_radial + g.L_inv                    # end of the involute: the tip rounding starts

    def field(V, s, rho):
        over = (s - (s_end - height / g.Rm)) * rho         # arc length beyond the chamfer start [m]
        ramp_f = np.clip((0.5 * length - np.abs(rho - rho_c)) / el_f + 0.5, 0.0, 1.0) if length < g.b else 1.0
        return np.where(over > 0.0, over, 0.0) * ramp_f

    return field


def crack(mesh: SurfaceMesh, params: BevelGearParams | None = None, tooth: int = 0, flank: str = "drive",
          length: float = 5.0e-3, face_position: float = 0.5) -> SurfaceMesh:
    """Mesh with a tooth-root crack grown through: the ``flank`` of ``tooth`` missing over ``length`` of
    the face width centred at ``face_position`` (root part and involute; the segment beyond the crack
    no longer carries load). Face rows land on the segment's two edges. The alternative model, a
    reduced tooth stiffness, needs a tooth-bending compliance the PCM layer does not have yet."""
    params, role, g, tooth = _check_tooth(mesh, params, tooth, flank)
    if not length > 0:
        raise ValueError("a crack needs length > 0")
    what = f"crack ({length * 1e3:g} mm of the face)"
    rho_c = _face_rho(g, face_position, 0.5 * length, what, flank, tooth)
    lo, hi = rho_c - 0.5 * length, rho_c + 0.5 * length
    side_code = FLANKS[flank]

    def cut(patch):
        rho_f = np.linalg.norm(patch.centroids(), axis=1)
        return (patch.face_flank == side_code) & (rho_f > lo) & (rho_f < hi)

    return _surgery(mesh, params, role, g, tooth, flank, (0.0, g.L_radial + g.L_inv), (lo, hi), mesh.meta["profile"],
                    [(lo, hi, min(length / 4.0, mesh.meta["face"]))],
                    {"type": "crack", "length": length, "face_position": face_position,
                     "area": 0.5 * (hi * hi - lo * lo) * (g.L_radial + g.L_inv)}, what, cut=cut)


def wear(mesh: SurfaceMesh, params: BevelGearParams | None = None, tooth: int = 0, flank: str = "drive",
         depth: float = 20e-6, profile: str = "uniform") -> SurfaceMesh:
    """Mesh with worn ``flank`` of ``tooth``: material ``depth`` removed along the normal over the whole
    involute flank and face width, ``profile`` = "uniform" (everywhere) or "sliding" (growing linearly
    with the distance from the pitch cone, where sliding vanishes, to ``depth`` at the farther end of
    the flank, zero at the pitch cone: the usual wear pattern)."""
    params, role, g, tooth = _check_tooth(mesh, params, tooth, flank)
    if not depth > 0:
        raise ValueError("wear needs depth > 0")
    if profile not in WEAR_PROFILES:
        raise ValueError(f"wear profile must be one of {WEAR_PROFILES}, not {profile!r}")
    s0, s1 = g.L_radial, g.L_radial + g.L_inv         # the involute
    far = max(g.s_pitch_param - s0, s1 - g.s_pitch_param)
    record = {"type": "wear", "depth": depth, "profile": profile,
              # depth scales with rho (tapered): V = depth/Rm int rho^2 drho int w(s) ds
              "volume": depth / g.Rm * (g.Re ** 3 - g.Ri ** 3) / 3.0 * ((s1 - s0) if profile == "uniform" else
                        ((g.s_pitch_param - s0) ** 2 + (s1 - g.s_pitch_param) ** 2) / (2.0 * far))}
    return _dent(mesh, params, role, g, tooth, flank, _wear_field(g, depth, profile), (s0, s1), (g.Ri, g.Re), [],
                 mesh.meta["profile"], record, f"{profile} wear")


def _wear_field(g, depth: float, profile: str):
    """The wear's depth field over the involute: ``depth`` everywhere ("uniform") or growing linearly from 0
    at the pitch cone to ``depth`` at the farther end of the flank ("sliding")."""
    s0, s1 = g.L_radial, g.L_radial + g.L_inv
    far = max(g.s_pitch_param - s0, s1 - g.s_pitch_param)

    def field(V, s, rho):
        on = (s >= s0) & (s <= s1)
        d = depth if profile == "uniform" else depth * np.abs(s - g.s_pitch_param) / far
        return np.where(on, d * rho / g.Rm, 0.0)

    return field


#: the ramps of a footprint's edges [rad, m]: none (the nominal shape)
_SHARP = 1e-15


def fault_footprint(params: BevelGearParams | None, spec: dict, flank: str | None = None,
                    samples: tuple[int, int] = (640, 200)) -> tuple:
    """Where a fault removes material from its flank, sampled: ``(s, rho, w, inside)``, flat arrays over a
    ``samples`` = (profile, face) grid of the flank of tooth 0 of its gear (s the profile parameter from the
    root cone to the end of the tip rounding [rad], rho the cone distance [m], w the area weight rho, inside
    where the fault's own depth field is positive; the nominal shape: a spall's and a chipped tip's edge
    ramps, one mesh element wide, are left out). Healthy teeth are alike, so tooth 0 stands for the fault's
    tooth. ``flank``: the flank sampled (default the fault's; a missing tooth's is the caller's choice: the
    whole flank is its footprint). Raises ValueError for a fault that does not fit its tooth."""
    params = params or BevelGearParams()
    spec = normalised_spec(spec)
    kind, member = spec["kind"], spec["member"]
    flank = flank or spec.get("flank", "drive")
    g = geometry.gear_geometry(params, member)
    n_s, n_r = samples
    s = (np.arange(n_s) + 0.5) / n_s * g.L_flank
    rho = g.Ri + (np.arange(n_r) + 0.5) / n_r * (g.Re - g.Ri)
    S, R = (a.ravel() for a in np.meshgrid(s, rho, indexing="ij"))
    if kind == "missing_tooth":
        return S, R, R.copy(), np.ones(S.shape, dtype=bool)
    kw = _si_keywords(spec)
    what = f"{kind} on {member} tooth {spec['tooth']}"
    if kind == "void":
        s_a, s_b = void_strip(params, member, kw["width"], kw["position"])
        inside = (S >= s_a) & (S <= s_b)
    elif kind == "crack":
        rho_c = _face_rho(g, kw["face_position"], 0.5 * kw["length"], what, flank, 0)
        inside = np.abs(R - rho_c) < 0.5 * kw["length"]
    else:
        if kind == "pit":
            rho_c = _face_rho(g, kw["face_position"], kw["radius"], what, flank, 0)
            field = _pit_field(g, flank, 0, kw["radius"], kw["depth"], rho_c, kw["position"])
        elif kind == "spall":
            rho_c = _face_rho(g, kw["face_position"], 0.5 * kw["width"], what, flank, 0)
            field = _spall_field(g, kw["length"], kw["width"], kw["depth"], rho_c, kw["position"], _SHARP, _SHARP)
        elif kind == "chipped_tip":
            length = kw["length"] or g.b
            rho_c = _face_rho(g, kw["face_position"], 0.5 * length, what, flank, 0)
            field = _chip_field(g, kw["height"], length, rho_c, _SHARP)
        else:                                               # wear
            field = _wear_field(g, kw["depth"], kw["profile"])
        V, _ = geometry.flank_point_normal(g, FLANKS[flank], S, R, tooth=0)
        inside = field(V, S, R) > 0.0
    return S, R, R.copy(), inside


FAMILIES = {"void": mild_flank_fracture, "missing_tooth": missing_tooth, "pit": pit, "spall": spall,
            "chipped_tip": chipped_tip, "crack": crack, "wear": wear}
"""fault kind -> the function that builds it (``FAULT_KINDS`` holds its scene keys and defaults)."""
assert set(FAMILIES) == set(FAULT_KINDS)
_SCENE_UNITS = {"_mm": 1e-3, "_um": 1e-6}


def _si_keywords(spec: dict) -> dict:
    """The size keys of a normalised specification as the keywords of its function, in SI: a key with a
    unit suffix loses it and is scaled (``radius_mm`` 1.5 -> ``radius`` 1.5e-3), the others pass."""
    kw = {}
    for key in FAULT_KINDS[spec["kind"]]:
        name, value = key, spec[key]
        for suffix, scale in _SCENE_UNITS.items():
            if key.endswith(suffix):
                name, value = key[:-len(suffix)], value * scale
        kw[name] = value
    return kw


def apply_faults(mesh: SurfaceMesh, params: BevelGearParams | None, specs, member: str) -> SurfaceMesh:
    """The mesh of ``member`` with every specification of that member applied, in order. A fault that
    does not fit its tooth raises :class:`FaultGeometryError` naming it (``gear.faults[i]``)."""
    for i, spec in enumerate(specs):
        spec = normalised_spec(spec)
        if spec["member"] != member:
            continue
        try:
            if spec["kind"] == "missing_tooth":             # a whole tooth: no flank, no sizes
                mesh = missing_tooth(mesh, spec["tooth"])
            else:
                mesh = FAMILIES[spec["kind"]](mesh, params, tooth=spec["tooth"], flank=spec["flank"],
                                              **_si_keywords(spec))
        except FaultGeometryError:
            raise
        except ValueError as exc:
            raise FaultGeometryError(f"gear.faults[{i}] ({spec['kind']} on {member} tooth {spec['tooth']}): {exc}") \
                from None
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
        try:
            return mild_flank_fracture(mesh, params, **kw)
        except ValueError as exc:
            raise FaultGeometryError(f"the mild fault: {exc}") from None
    return missing_tooth(mesh, tooth=kw.get("tooth", 0))


def user_mesh(path, params: BevelGearParams | None = None, role: str = "pinion", units: str = "mm",
              **kw) -> SurfaceMesh:
    """A user's (possibly faulty) gear mesh file, loaded and validated (see mesh_check.load_gear_mesh)."""
    return load_gear_mesh(path, params, role, units=units, **kw)
