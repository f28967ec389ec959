"""Faults as surface meshes: missing tooth, flank-fracture void (area, floor, walls, orientation)."""
from __future__ import annotations

import numpy as np
import pytest

from gearcontact_fmu import faults
from gearcontact_fmu import geometry as G
from gearcontact_fmu.mesh_check import load_gear_mesh, validate_gear_mesh
from gearcontact_fmu.meshes import (FLANK_COAST, FLANK_DRIVE, KIND_VOID_FLOOR, KIND_VOID_WALL, MeshError, save_mesh)
from gearcontact_fmu.params import BevelGearParams, MeshResolution

P = BevelGearParams()
RES = MeshResolution(profile=0.05e-3, face=1e-3)


@pytest.fixture(scope="module")
def pinion():
    return G.build_gear_mesh(P, "pinion", RES)


@pytest.fixture(scope="module")
def mild(pinion):
    return faults.mild_flank_fracture(pinion, P)


def _consistent(m):
    tm = m.to_trimesh()
    tm.merge_vertices()
    return tm.is_winding_consistent


def test_missing_tooth_removes_exactly_one_tooth(pinion):
    for k in (0, 7):
        m = faults.missing_tooth(pinion, k)
        assert m.n_faces == pinion.n_faces - np.count_nonzero(pinion.face_tooth == k)
        assert k not in m.face_tooth
        before, after = pinion.tooth_areas(), m.tooth_areas()
        assert set(after) == set(before) - {k}
        assert all(after[j] == pytest.approx(before[j], rel=1e-12) for j in after)
        assert m.meta["faults"][-1] == {"type": "missing_tooth", "tooth": k}
        validate_gear_mesh(m, P, "pinion")
    with pytest.raises(ValueError):
        faults.missing_tooth(faults.missing_tooth(pinion, 3), 3)


def test_void_removes_one_mm_strip_from_drive_flank_of_one_tooth(pinion, mild):
    width, depth = faults.DEFAULT_WIDTH, faults.DEFAULT_DEPTH
    b = P.face_width
    d_drive = {k: pinion.tooth_areas(FLANK_DRIVE)[k] - mild.tooth_areas(FLANK_DRIVE)[k] for k in range(15)}
    d_coast = {k: pinion.tooth_areas(FLANK_COAST)[k] - mild.tooth_areas(FLANK_COAST)[k] for k in range(15)}
    removed = d_drive[0]
    print(f"\n void: removed {removed * 1e6:.4f} mm^2 of drive flank (1 mm x {b * 1e3:g} mm = {width * b * 1e6:g} mm^2)")
    assert removed == pytest.approx(width * b, rel=1e-3)
    assert all(abs(d_drive[k]) < 1e-15 for k in range(1, 15))
    assert all(abs(d_coast[k]) < 1e-15 for k in range(15))
    # floor and walls added on tooth 0 only, outward, consistently wound, exact normals agree
    a = mild.areas()
    floor = mild.face_kind == KIND_VOID_FLOOR
    walls = mild.face_kind == KIND_VOID_WALL
    assert set(mild.face_tooth[floor | walls]) == {0}
    assert np.all(mild.face_flank[floor | walls] == 0)
    print(f" floor {a[floor].sum() * 1e6:.3f} mm^2, walls {a[walls].sum() * 1e6:.3f} mm^2")
    assert a[walls].sum() == pytest.approx(2 * depth * b, rel=1e-3)
    assert 0.85 * width * b < a[floor].sum() < width * b           # offset into the convex flank: shorter
    dots = np.einsum("ij,ij->i", mild.normals(), mild.face_normals)
    assert dots.min() > 0.99
    assert _consistent(mild.subset(mild.face_tooth == 0))
    validate_gear_mesh(mild, P, "pinion")


def test_void_floor_depth_and_position(pinion, mild):
    g = G.gear_geometry(P, "pinion")
    floor = mild.face_kind == KIND_VOID_FLOOR
    fp, fs = mild.face_points[floor], mild.face_profile[floor]
    rho = np.linalg.norm(fp, axis=1)
    p, n = G.flank_point_normal(g, +1, fs, 1.0, tooth=0)
    # the floor is the flank offset along -n by depth (at R_m; tapered with rho like the teeth)
    depth = -np.einsum("ij,ij->i", fp, n)
    assert np.allclose(depth, faults.DEFAULT_DEPTH * rho / g.Rm * (1 - 1e-12), rtol=1e-6)
    # strip centred on the pitch cone, 1 mm wide at R_m
    s_a, s_b = faults.void_strip(P, "pinion")
    assert fs.min() >= s_a - 1e-15 and fs.max() <= s_b + 1e-15
    assert (s_b - s_a) * g.Rm == pytest.approx(1e-3, rel=1e-12)
    assert 0.5 * (s_a + s_b) == pytest.approx(g.s_pitch_param, abs=1e-15)
    # the drive-flank elements of tooth 0 left all lie outside the strip
    keep = (mild.face_tooth == 0) & (mild.face_flank == FLANK_DRIVE)
    s_keep = mild.face_profile[keep]
    assert not np.any((s_keep > s_a) & (s_keep < s_b))
    # position moves it towards the tip
    m2 = faults.mild_flank_fracture(pinion, P, tooth=3, position=0.5e-3, depth=0.2e-3)
    f2 = m2.face_kind == KIND_VOID_FLOOR
    assert set(m2.face_tooth[f2]) == {3}
    assert m2.face_profile[f2].mean() == pytest.approx(g.s_pitch_param + 0.5e-3 / g.Rm, rel=1e-3)


def test_apply_health_and_errors(pinion):
    assert faults.apply_health(pinion, P, "healthy") is pinion
    sev = faults.apply_health(pinion, P, "severe", tooth=2, width=1e-3)
    assert 2 not in sev.face_tooth
    mild = faults.apply_health(pinion, P, "mild", tooth=1)
    assert np.any(mild.face_kind == KIND_VOID_FLOOR)
    with pytest.raises(ValueError):
        faults.apply_health(pinion, P, "broken")
    with pytest.raises(ValueError, match="leaves the flank"):
        faults.mild_flank_fracture(pinion, P, position=5e-3)
    g = G.gear_geometry(P, "pinion")
    with pytest.raises(ValueError, match="base cone"):
        faults.mild_flank_fracture(pinion, P, position=(g.L_radial - g.s_pitch_param) * g.Rm)
    sub = G.build_gear_mesh(P, "pinion", RES, teeth=[1, 2])
    with pytest.raises(ValueError, match="not in the mesh"):
        faults.mild_flank_fracture(sub, P, tooth=0)
    # a fault list names the fault that does not fit (index, kind, member, tooth)
    bad = [{"kind": "pit", "tooth": 3}, {"kind": "void", "tooth": 4, "position_mm": 5.0}]
    with pytest.raises(faults.FaultGeometryError, match=r"gear.faults\[1\] \(void on pinion tooth 4\).*leaves the flank"):
        faults.apply_faults(pinion, P, bad, "pinion")
    with pytest.raises(faults.FaultGeometryError, match="the mild fault.*leaves the flank"):
        faults.apply_health(pinion, P, "mild", position=5e-3)


def test_a_fault_that_does_not_fit_refuses_the_run_naming_it():
    """Found when the meshes are built (the scene's keys are well formed): a refusal before any step,
    not a traceback."""
    from _shared import EXAMPLE

    from drivetrain.errors import ConfigurationError
    from drivetrain.run.runner import run_scene
    from drivetrain.scene.load import load_scene

    scene = load_scene(EXAMPLE, overrides=['gear.health="faults"', "time.duration_s=0.01", "time.settle_s=0",
                                           'gear.faults=[{kind="void", tooth=2, position_mm=-1.5}]'])
    with pytest.raises(ConfigurationError, match=r"gear.faults\[0\] \(void on pinion tooth 2\).*base cone"):
        run_scene(scene, out_dir=None, progress=False, build=False, fmu_paths={})


def test_faulty_user_mesh_round_trip(tmp_path, mild):
    """A faulty gear as a file (the PCM point): save, load, validate."""
    path = tmp_path / "pinion_mild.obj"
    save_mesh(mild, path)
    m = faults.user_mesh(path, P, "pinion")
    assert m.n_faces == mild.n_faces
    assert m.area() == pytest.approx(mild.area(), rel=1e-9)
    with pytest.raises(MeshError):
        load_gear_mesh(path, P, "pinion", units="m")


@pytest.mark.parametrize("role, tooth, radius, depth, face_position, position", [
    ("pinion", 3, 1.5e-3, 0.25e-3, 0.5, 0.0), ("pinion", 0, 0.5e-3, 0.1e-3, 0.1, 0.5e-3),
    ("wheel", 38, 1.5e-3, 0.25e-3, 0.5, 0.0), ("wheel", 7, 0.5e-3, 0.2e-3, 0.95, -1.0e-3)])
def test_pit_removes_the_spherical_cap_volume(role, tooth, radius, depth, face_position, position):
    """Oracle: the cap volume pi h (3 R^2 + h^2) / 6; the removed volume is the change of the tooth
    surface's enclosed-volume integral (1/6) sum a . (b - a) x (c - a) (the re-meshed tooth keeps
    its boundary), within 5 %. The deepest point is the cap depth, at the requested place."""
    coarse = MeshResolution(profile=0.1e-3, face=2e-3)
    m = G.build_gear_mesh(P, role, coarse)
    p = faults.pit(m, P, tooth=tooth, radius=radius, depth=depth, face_position=face_position, position=position)
    validate_gear_mesh(p, P, role)

    def enclosed(mesh):
        tri = mesh.vertices[mesh.faces[mesh.face_tooth == tooth]]
        return np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])).sum() / 6

    removed = enclosed(m) - enclosed(p)
    assert removed == pytest.approx(faults.pit_volume(radius, depth), rel=0.05)
    assert p.meta["faults"][-1]["type"] == "pit" and p.meta["faults"][-1]["tooth"] == tooth
    # other teeth untouched
    others = p.face_tooth != tooth
    assert p.tooth_areas()[(tooth + 1) % G.gear_geometry(P, role).z] == pytest.approx(
        m.tooth_areas()[(tooth + 1) % G.gear_geometry(P, role).z], rel=1e-12)
    assert np.count_nonzero(others) == np.count_nonzero(m.face_tooth != tooth)
    g = G.gear_geometry(P, role)
    pc, nc = G.flank_point_normal(g, +1, g.s_pitch_param + position / g.Rm, g.Ri + face_position * g.b, tooth=tooth)
    v = p.vertices[np.unique(p.faces[p.face_tooth == tooth])]
    v = v[np.linalg.norm(v - pc, axis=1) < radius]                 # the pit's own vertices
    depth_v = -(v - pc) @ nc
    assert depth_v.max() == pytest.approx(depth, rel=0.05)
    assert np.linalg.norm(v[np.argmax(depth_v)] - (pc - depth * nc)) < 0.2 * radius


def test_pit_errors():
    m = G.build_gear_mesh(P, "pinion", MeshResolution(profile=0.2e-3, face=2e-3), teeth=[0, 1])
    with pytest.raises(ValueError, match="leaves the drive flank"):
        faults.pit(m, P, tooth=0, radius=1.5e-3, face_position=0.0)
    with pytest.raises(ValueError, match="0 < depth < radius"):
        faults.pit(m, P, tooth=0, radius=0.5e-3, depth=0.6e-3)
    with pytest.raises(ValueError, match="not in the mesh"):
        faults.pit(m, P, tooth=5)
    with pytest.raises(ValueError, match="flank must be one of"):
        faults.pit(m, P, tooth=0, flank="left")


def test_a_wheel_pit_refines_every_pinion_tooth_at_its_cone_distance():
    """The pinion's elements probe the wheel: a wheel pit narrower than the pinion's face rows would
    fall between them. The pinion gets rows every radius/4 across the pit's cone distance, on every
    tooth (they stay rotated copies of one tooth)."""
    from gearcontact_fmu.mesh_models.pcm import resolve_meshes

    res = MeshResolution(profile=0.3e-3, face=2e-3)
    spec = {"kind": "pit", "member": "wheel", "tooth": 38, "radius_mm": 0.5, "depth_mm": 0.1, "face_position": 0.46}
    pin, whl = resolve_meshes(P, res, "faults", fault_kwargs={"faults": [spec]})
    g = G.gear_geometry(P, "pinion")
    rho_c = g.Ri + 0.46 * g.b
    rho = np.linalg.norm(pin.face_points, axis=1)
    near = np.abs(rho - rho_c) < 0.5e-3
    per_tooth = [np.count_nonzero(near & (pin.face_tooth == k)) for k in range(15)]
    healthy = G.build_gear_mesh(P, "pinion", res)
    before = np.count_nonzero((np.abs(np.linalg.norm(healthy.face_points, axis=1) - rho_c) < 0.5e-3)
                              & (healthy.face_tooth == 0))
    assert len(set(per_tooth)) == 1 and per_tooth[0] >= 4 * before
    assert whl.meta["faults"][-1]["type"] == "pit"


def _depth_below_flank(g, tooth, side, V, n=20000):
    """Depth of points below the exact healthy flank (root part and involute) along its normal, and that
    normal: the nearest of n points of the flank's curve on the unit sphere (the teeth are cones through the
    apex), found by a k-d tree (exact nearest neighbour: the same points as a brute-force argmin, measured
    on every fault family, a hundred times faster). Independent of the fault code: analytic geometry only."""
    from scipy.spatial import cKDTree

    s = np.linspace(0.0, g.L_radial + g.L_inv, n)
    U, N = G.flank_point_normal(g, side, s, 1.0, tooth=tooth)
    rho = np.linalg.norm(V, axis=1)
    u = V / rho[:, None]
    _, j = cKDTree(U).query(u)
    d = -np.einsum("ij,ij->i", u - U[j], N[j]) * rho
    return d, N[j]


def _removed_volume(p, g, tooth, side):
    """Sum over the flank's elements of (area projected on the healthy flank) x (mean depth of its
    vertices below the healthy flank)."""
    sel = (p.face_tooth == tooth) & (p.face_flank == side)
    tri_idx = p.faces[sel]
    vids = np.unique(tri_idx)
    d = np.zeros(len(p.vertices))
    nv = np.zeros((len(p.vertices), 3))
    d[vids], nv[vids] = _depth_below_flank(g, tooth, side, p.vertices[vids])
    tri = p.vertices[tri_idx]
    cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n_avg = nv[tri_idx].mean(axis=1)
    a_proj = 0.5 * np.abs(np.einsum("ij,ij->i", cr, n_avg / np.linalg.norm(n_avg, axis=1)[:, None]))
    return float((a_proj * np.maximum(d[tri_idx], 0.0).mean(axis=1)).sum())


def _closed_form(kind, g, **kw):
    """Removed volume from the fault's parameters alone (lengths at the mean cone distance; the teeth
    taper, so a size at cone distance rho scales with rho / R_m)."""
    Rm, Ri, Re = g.Rm, g.Ri, g.Re
    rc = Ri + kw.get("face_position", 0.5) * (Re - Ri)
    if kind == "pit":
        R, h = kw["radius"], kw["depth"]
        return np.pi * h * (3 * R * R + h * h) / 6
    if kind == "spall":
        return kw["length"] * kw["width"] * kw["depth"] * (rc / Rm) ** 2
    if kind == "chipped_tip":
        L = kw.get("length")
        h = kw["height"]
        if L is None:                      # the whole face: int (rho/Rm)^2 drho
            return 0.5 * h * h * (Re ** 3 - Ri ** 3) / (3 * Rm * Rm)
        return 0.5 * h * h * L * (rc / Rm) ** 2
    if kind == "wear":                      # uniform: depth (rho/Rm) over the involute
        return kw["depth"] / Rm * (Re ** 3 - Ri ** 3) / 3 * g.L_inv
    raise ValueError(kind)


@pytest.mark.parametrize("role, tooth", [("pinion", 3), ("wheel", 38)])
@pytest.mark.parametrize("kind, kw", [
    ("pit", {"radius": 1.5e-3, "depth": 0.25e-3}),
    ("spall", {"length": 2e-3, "width": 4e-3, "depth": 0.1e-3, "face_position": 0.35}),
    ("chipped_tip", {"height": 0.5e-3}),
    ("chipped_tip", {"height": 0.4e-3, "length": 5e-3, "face_position": 0.3}),
    ("wear", {"depth": 20e-6})])
def test_fault_family_removes_its_closed_form_volume(role, tooth, kind, kw):
    """Every fault family, either gear: the volume removed below the exact healthy flank (measured on
    the mesh vertices against the analytic flank) matches the closed form of its parameters within 5 %
    (measured: 0.97-1.005), the mesh stays a valid gear mesh and the other teeth are untouched."""
    g = G.gear_geometry(P, role)
    m = G.build_gear_mesh(P, role, MeshResolution(profile=0.1e-3, face=2e-3))
    p = getattr(faults, kind)(m, P, tooth, **kw)
    validate_gear_mesh(p, P, role)
    assert _removed_volume(p, g, tooth, +1) == pytest.approx(_closed_form(kind, g, **kw), rel=0.05)
    other = (tooth + 1) % g.z
    assert p.tooth_areas()[other] == pytest.approx(m.tooth_areas()[other], rel=1e-12)
    assert p.meta["faults"][-1]["type"] == kind and p.meta["faults"][-1]["tooth"] == tooth


def test_sliding_wear_is_zero_at_the_pitch_cone():
    g = G.gear_geometry(P, "pinion")
    m = G.build_gear_mesh(P, "pinion", MeshResolution(profile=0.1e-3, face=2e-3))
    p = faults.wear(m, P, 2, depth=20e-6, profile="sliding")
    sel = (p.face_tooth == 2) & (p.face_flank == 1)
    d, _ = _depth_below_flank(g, 2, +1, p.face_points[sel])
    s = p.face_profile[sel]
    near = np.abs(s - g.s_pitch_param) < 0.02 * g.L_inv
    far = np.abs(s - g.s_pitch_param) > 0.9 * max(g.s_pitch_param - g.L_radial, g.L_radial + g.L_inv - g.s_pitch_param)
    assert np.all(d[near] < 2e-6) and d[far].max() > 15e-6


@pytest.mark.parametrize("role, tooth", [("pinion", 3), ("wheel", 38)])
def test_crack_removes_the_flank_over_its_length(role, tooth):
    """A root crack grown through: the drive flank of the tooth missing over 5 mm of the face. Oracle:
    the flank area over that face length, (rho_2^2 - rho_1^2)/2 x the flank's profile angle."""
    g = G.gear_geometry(P, role)
    m = G.build_gear_mesh(P, role, MeshResolution(profile=0.1e-3, face=2e-3))
    p = faults.crack(m, P, tooth, length=5e-3, face_position=0.4)
    validate_gear_mesh(p, P, role)
    rc = g.Ri + 0.4 * g.b
    closed = 0.5 * ((rc + 2.5e-3) ** 2 - (rc - 2.5e-3) ** 2) * (g.L_radial + g.L_inv)
    removed = m.tooth_areas(FLANK_DRIVE)[tooth] - p.tooth_areas(FLANK_DRIVE)[tooth]
    assert removed == pytest.approx(closed, rel=0.01)
    assert p.tooth_areas(FLANK_COAST)[tooth] == pytest.approx(m.tooth_areas(FLANK_COAST)[tooth], rel=1e-9)
