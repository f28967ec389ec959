"""Tooth surface meshes: resolution, orientation, areas, OBJ/STL round trip, validation refusals."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gearcontact_fmu import geometry as G
from gearcontact_fmu.mesh_check import load_gear_mesh, validate_gear_mesh
from gearcontact_fmu.meshes import (FLANK_COAST, FLANK_DRIVE, KIND_FLANK, KIND_ROOT_RADIAL, MeshError, SurfaceMesh, concatenate, load_mesh, save_mesh)
from gearcontact_fmu.params import BevelGearParams, MeshResolution

P = BevelGearParams()
RES = MeshResolution(profile=0.1e-3, face=2e-3)


@pytest.fixture(scope="module")
def pinion():
    return G.build_gear_mesh(P, "pinion", RES)


@pytest.fixture(scope="module")
def wheel3():
    return G.build_gear_mesh(P, "wheel", RES, teeth=[59, 0, 1])


def _is_winding_consistent(mesh):
    tm = mesh.to_trimesh()
    tm.merge_vertices()
    return tm.is_winding_consistent


@pytest.mark.parametrize("role", ["pinion", "wheel"])
@pytest.mark.parametrize("res", [MeshResolution(profile=0.05e-3, face=1e-3), MeshResolution(profile=0.2e-3, face=3e-3)])
def test_element_sizes_follow_resolution(role, res):
    m = G.build_gear_mesh(P, role, res, teeth=[0])
    g = G.gear_geometry(P, role)
    t = m.triangles()
    # first triangle of each quad: edge 0->1 along the profile at rho_j, edge 1->2 along the face width
    rho0 = np.linalg.norm(t[::2, 0], axis=1)
    prof = np.linalg.norm(t[::2, 1] - t[::2, 0], axis=1) * g.Rm / rho0      # scaled to the mean cone distance
    face = np.linalg.norm(t[::2, 2] - t[::2, 1], axis=1)
    nf = math.ceil(g.b / res.face - 1e-9)
    assert np.allclose(face, g.b / nf, rtol=1e-9)
    assert face.max() <= res.face * (1 + 1e-9)
    assert prof.max() <= res.profile * (1 + 1e-6)
    assert np.median(prof) > 0.7 * res.profile
    # along the profile the element is much finer than along the face width
    print(f"\n {role} {res}: {m.n_faces} triangles/tooth, profile edge at R_m {1e3 * np.median(prof):.4f} mm, "
          f"face edge {1e3 * face[0]:.3f} mm")


@pytest.mark.parametrize("role", ["pinion", "wheel"])
def test_normals_consistent_outward_and_exact(role, pinion, wheel3):
    m = pinion if role == "pinion" else wheel3
    d = np.einsum("ij,ij->i", m.normals(), m.face_normals)
    assert d.min() > 0.99
    assert np.allclose(np.linalg.norm(m.face_normals, axis=1), 1.0)
    assert _is_winding_consistent(m)
    # exact face points lie on the exact surface: same point from flank_point_normal
    sel = np.flatnonzero(np.isin(m.face_kind, [KIND_FLANK, KIND_ROOT_RADIAL]))[::97]
    for i in sel:
        rho = np.linalg.norm(m.face_points[i])
        p, n = G.flank_point_normal(G.gear_geometry(P, role), int(m.face_flank[i]), m.face_profile[i], rho,
                                    tooth=int(m.face_tooth[i]))
        assert np.allclose(p, m.face_points[i], atol=1e-12) and np.allclose(n, m.face_normals[i], atol=1e-12)
    # the exact point is near the centroid: within the sag of a chord on the tightest curvature
    # (tip rounding, radius tip_radius * Ri/Re at the inner end)
    g = G.gear_geometry(P, role)
    sag = RES.profile ** 2 / (8 * P.tip_radius * g.Ri / g.Re)
    assert np.linalg.norm(m.face_points - m.centroids(), axis=1).max() < sag
    validate_gear_mesh(m, P, role)


@pytest.mark.parametrize("role", ["pinion", "wheel"])
@pytest.mark.parametrize("res", [MeshResolution(), MeshResolution(profile=0.5e-3, face=5e-3)])
@pytest.mark.parametrize("top_land", [False, True])
def test_area_matches_analytic(role, res, top_land):
    teeth = [0, 1]
    m = G.build_gear_mesh(P, role, res, teeth=teeth, top_land=top_land)
    assert _is_winding_consistent(m)
    assert np.einsum("ij,ij->i", m.normals(), m.face_normals).min() > 0.99
    a_exact = G.analytic_area(P, role, n_teeth=len(teeth), top_land=top_land)
    assert m.area() == pytest.approx(a_exact, rel=5e-3)
    if res.profile <= 0.05e-3:
        assert m.area() == pytest.approx(a_exact, rel=2e-4)
    # flank-only area: (Re^2 - Ri^2)/2 * (radial + involute arc length) per flank
    g = G.gear_geometry(P, role)
    a_fl = m.areas()[m.face_flank == FLANK_DRIVE].sum()
    assert a_fl == pytest.approx(0.5 * (g.Re ** 2 - g.Ri ** 2) * (g.L_radial + g.L_inv) * len(teeth), rel=5e-3)


def test_teeth_subset_and_annotations(pinion):
    m = G.build_gear_mesh(P, "pinion", RES, teeth=[0, -1, 16])
    assert sorted(np.unique(m.face_tooth)) == [0, 1, 14]
    assert set(np.unique(m.face_flank)) == {-1, 0, 1}
    per = pinion.tooth_areas()
    assert len(per) == 15 and np.allclose(list(per.values()), per[0], rtol=1e-9)


@pytest.mark.parametrize("ext", ["obj", "stl"])
def test_file_round_trip_in_mm(tmp_path, ext, wheel3):
    path = tmp_path / f"wheel.{ext}"
    save_mesh(wheel3, path)                           # mm
    back = load_mesh(path)                            # mm -> m
    assert back.n_faces == wheel3.n_faces
    ext_len = np.linalg.norm(wheel3.vertices, axis=1).max()
    err = np.abs(back.triangles() - wheel3.triangles()).max() / ext_len
    assert err < 1e-9
    # the file really is in millimetres
    txt = path.read_text()
    assert "92." in txt or "91." in txt or "90." in txt
    # validated and annotated load
    m = load_gear_mesh(path, P, "wheel")
    assert m.face_points is None
    fl = np.isin(wheel3.face_kind, [KIND_FLANK])
    assert np.array_equal(m.face_tooth, wheel3.face_tooth)
    assert np.array_equal(m.face_flank[fl], wheel3.face_flank[fl])


def test_metres_file_read_as_mm_is_refused(tmp_path, wheel3):
    path = tmp_path / "wheel_in_m.stl"
    save_mesh(wheel3, path, units="m")
    with pytest.raises(MeshError, match="1000x") as e:
        load_gear_mesh(path, P, "wheel", units="mm")
    assert "metres" in str(e.value)
    assert load_gear_mesh(path, P, "wheel", units="m").n_faces == wheel3.n_faces
    path2 = tmp_path / "x.obj"
    save_mesh(wheel3, path2, units="mm")
    with pytest.raises(MeshError, match="1000x"):
        load_gear_mesh(path2, P, "wheel", units="m")


def test_binary_stl(tmp_path, wheel3):
    path = tmp_path / "b.stl"
    save_mesh(wheel3, path, binary=True)
    back = load_gear_mesh(path, P, "wheel")
    assert np.abs(back.triangles() - wheel3.triangles()).max() < 1e-8       # float32 in mm: ~6e-6 mm


def test_empty_mesh_refused(tmp_path):
    with pytest.raises(MeshError, match="empty"):
        validate_gear_mesh(SurfaceMesh(np.zeros((0, 3)), np.zeros((0, 3), int)), P, "pinion")


def test_flipped_normals_refused(pinion):
    with pytest.raises(MeshError, match="into the material"):
        validate_gear_mesh(pinion.flipped(), P, "pinion")


def test_random_flipped_faces_refused(pinion):
    rng = np.random.default_rng(1)
    m = pinion.copy()
    idx = rng.choice(m.n_faces, size=20, replace=False)
    m.faces[idx] = m.faces[idx][:, ::-1]
    with pytest.raises(MeshError, match="inconsistent"):
        validate_gear_mesh(m, P, "pinion")


def test_degenerate_faces(tmp_path, wheel3):
    m = wheel3.copy()
    f = np.vstack([m.faces, [[0, 0, 1]]])
    bad = SurfaceMesh(m.vertices, f)
    with pytest.raises(MeshError, match="degenerate"):
        validate_gear_mesh(bad, P, "wheel")
    path = tmp_path / "deg.obj"
    save_mesh(bad, path)
    with pytest.warns(UserWarning, match="dropped 1 degenerate"):
        assert load_gear_mesh(path, P, "wheel").n_faces == wheel3.n_faces


def test_mesh_away_from_mesh_zone_refused(pinion, wheel3):
    # tilted by 90 deg: same scale, teeth no longer on the pitch cone around the axis
    with pytest.raises(MeshError, match="does not face its partner"):
        validate_gear_mesh(pinion.transformed(np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0.0]])), P, "pinion")
    # shifted by 30 mm along the axis (apex not at the origin)
    with pytest.raises(MeshError, match="does not face its partner"):
        validate_gear_mesh(pinion.transformed(np.eye(3), [0, 0, 0.03]), P, "pinion")
    # the wheel given as the pinion
    with pytest.raises(MeshError, match="does not face its partner"):
        validate_gear_mesh(wheel3, P, "pinion")
    # a wheel with its teeth on the wrong side of its body frame: message says so
    with pytest.raises(MeshError, match="towards -z"):
        validate_gear_mesh(wheel3.transformed(np.diag([1.0, -1.0, -1.0])), P, "wheel")
    # far away: refused (scale)
    with pytest.raises(MeshError):
        validate_gear_mesh(pinion.transformed(np.eye(3), [1.0, 0, 0]), P, "pinion")


def test_concatenate_and_subset(wheel3):
    a = wheel3.subset(wheel3.face_tooth == 0)
    b = wheel3.subset(wheel3.face_tooth != 0)
    c = SurfaceMesh.concatenate([a, b])
    assert c.n_faces == wheel3.n_faces and c.area() == pytest.approx(wheel3.area(), rel=1e-12)
    assert c.face_points is not None
    d = concatenate([a, SurfaceMesh(b.vertices, b.faces)])
    assert d.face_points is None and d.n_faces == wheel3.n_faces
    assert a.n_vertices < wheel3.n_vertices
