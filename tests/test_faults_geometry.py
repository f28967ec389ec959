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


def test_faulty_user_mesh_round_trip(tmp_path, mild):
    """A faulty gear as a file (the PCM point): save, load, validate."""
    path = tmp_path / "pinion_mild.obj"
    save_mesh(mild, path)
    m = faults.user_mesh(path, P, "pinion")
    assert m.n_faces == mild.n_faces
    assert m.area() == pytest.approx(mild.area(), rel=1e-9)
    with pytest.raises(MeshError):
        load_gear_mesh(path, P, "pinion", units="m")
