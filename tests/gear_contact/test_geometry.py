"""Straight bevel geometry: spherical involute, cones, placement, conjugacy (unloaded TE), contact ratio."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from gearcontact_fmu import geometry as G
from gearcontact_fmu.meshes import KIND_FLANK, KIND_ROOT_RADIAL, KIND_TIP_ROUND, KIND_TOP_LAND
from gearcontact_fmu.params import BevelGearParams, MeshResolution

P = BevelGearParams()


def test_pitch_cones_and_cone_distance():
    gp, gw = G.gear_geometry(P, "pinion"), G.gear_geometry(P, "wheel")
    assert math.degrees(gp.delta) == pytest.approx(14.036, abs=5e-4)
    assert math.degrees(gw.delta) == pytest.approx(75.964, abs=5e-4)
    assert gp.Re * 1e3 == pytest.approx(92.77, abs=5e-3)
    # base cones: sin db = sin d cos a; tip/root from the addendum/dedendum at the outer end
    for g, x in ((gp, 0.43), (gw, -0.43)):
        assert math.sin(g.delta_b) == pytest.approx(math.sin(g.delta) * math.cos(math.radians(20)), rel=1e-14)
        assert g.addendum == pytest.approx(3e-3 * (1 + x), rel=1e-12)
        assert g.dedendum == pytest.approx(3e-3 * (1.25 - x), rel=1e-12)
    assert gp.virtual_teeth == pytest.approx(15.46, abs=0.01)
    assert gw.virtual_teeth == pytest.approx(247.4, abs=0.1)


def _brief_involute(db, phi):
    """The spherical involute exactly as written in the brief (independent of the module's code)."""
    sdb, cdb = math.sin(db), math.cos(db)
    g = np.stack([sdb * np.cos(phi), sdb * np.sin(phi), np.full_like(phi, cdb)], -1)
    t = np.stack([-np.sin(phi), np.cos(phi), np.zeros_like(phi)], -1)
    psi = phi * sdb
    return np.cos(psi)[:, None] * g - np.sin(psi)[:, None] * t, g, t, psi


@pytest.mark.parametrize("role", ["pinion", "wheel"])
def test_spherical_involute_point_and_normal(role):
    g = G.gear_geometry(P, role)
    phi = np.linspace(0.0, 1.2 * g.psi_t / math.sin(g.delta_b), 400)
    Q, gg, t, psi = _brief_involute(g.delta_b, phi)
    n = np.sin(psi)[:, None] * gg + np.cos(psi)[:, None] * t       # lies in the generating plane
    # dQ/dphi by the product rule (psi' = sin db, g' = sin db (-sin phi, cos phi, 0), t' = -(cos phi, sin phi, 0))
    sdb = math.sin(g.delta_b)
    dg = sdb * np.stack([-np.sin(phi), np.cos(phi), 0 * phi], -1)
    dt = -np.stack([np.cos(phi), np.sin(phi), 0 * phi], -1)
    c, s_ = np.cos(psi)[:, None], np.sin(psi)[:, None]
    dQ = -sdb * s_ * gg + c * dg - sdb * c * t - s_ * dt
    # and by central differences where the curve is regular (away from the cusp on the base cone)
    h = 1e-6
    Qp, *_ = _brief_involute(g.delta_b, phi + h)
    Qm, *_ = _brief_involute(g.delta_b, phi - h)
    reg = phi > 0.05 * phi[-1]
    assert np.allclose(dQ[reg], (Qp - Qm)[reg] / (2 * h), atol=1e-9)
    assert np.allclose(np.linalg.norm(Q, axis=1), 1.0, atol=1e-14)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-14)
    assert np.max(np.abs(np.einsum("ij,ij->i", n, Q))) < 1e-14
    tang = dQ[1:] / np.linalg.norm(dQ[1:], axis=1)[:, None]
    assert np.max(np.abs(np.einsum("ij,ij->i", n[1:], tang))) < 1e-12
    # the generating-plane normal g x t is the *tangent* direction, not the surface normal
    gxt = np.cross(gg, t)
    assert np.min(np.abs(np.einsum("ij,ij->i", gxt[1:], tang))) > 1 - 1e-12

    # the module's involute piece is this curve, rotated by omega0, with outward normal -n
    s = np.linspace(g.L_radial + 1e-9, g.L_radial + g.L_inv, 300)
    u, nm, kind = g.profile_minus(s)
    assert np.all(kind == KIND_FLANK)
    si = g.s_inv0 + s - g.L_radial
    psi_m = np.arccos(1 - si * math.tan(g.delta_b))
    Qb, gb, tb, _ = _brief_involute(g.delta_b, psi_m / math.sin(g.delta_b))
    Rz = G.rot_z(g.omega0)
    assert np.allclose(u, Qb @ Rz.T, atol=1e-13)
    nb = -(np.sin(psi_m)[:, None] * gb + np.cos(psi_m)[:, None] * tb) @ Rz.T
    assert np.allclose(nm, nb, atol=1e-13)
    # profile parameter is the arc length: |du/ds| = 1
    ss = np.linspace(g.L_radial, g.L_radial + g.L_inv, 200001)
    uu, _, _ = g.profile_minus(ss)
    chords = np.linalg.norm(np.diff(uu, axis=0), axis=1)
    assert chords.sum() == pytest.approx(g.L_inv, rel=1e-8)
    assert np.allclose(chords[100:] / np.diff(ss)[100:], 1.0, atol=1e-6)


@pytest.mark.parametrize("role", ["pinion", "wheel"])
@pytest.mark.parametrize("flank", [1, -1])
def test_whole_profile_exact_normals(role, flank):
    """All pieces (radial root part, involute, tip rounding, top land): unit point, unit normal,
    normal perpendicular to the point and to the profile tangent, tangent continuous."""
    g = G.gear_geometry(P, role)
    s = np.linspace(1e-7, g.L_half - 1e-7, 6001)
    p, n = G.flank_point_normal(g, flank, s, 1.0, tooth=3)
    _, _, kind = g.profile_minus(s)
    expected = {KIND_FLANK, KIND_TIP_ROUND, KIND_TOP_LAND} | ({KIND_ROOT_RADIAL} if role == "pinion" else set())
    assert set(np.unique(kind)) == expected
    assert np.allclose(np.linalg.norm(p, axis=1), 1.0, atol=1e-13)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-13)
    assert np.max(np.abs(np.einsum("ij,ij->i", p, n))) < 1e-13
    dp = np.gradient(p, s, axis=0)
    tl = np.linalg.norm(dp, axis=1)
    assert np.allclose(tl[1:-1], 1.0, atol=2e-3)           # arc-length parameter, continuous curve
    assert np.max(np.abs(np.einsum("ij,ij->i", dp[1:-1], n[1:-1]))) < 2e-3   # incl. the piece joints
    # rho scales the point, not the normal
    p2, n2 = G.flank_point_normal(g, flank, s[::100], 0.08, tooth=3)
    assert np.allclose(p2, 0.08 * p[::100]) and np.allclose(n2, n[::100])


@pytest.mark.parametrize("role", ["pinion", "wheel"])
def test_half_tooth_angle_at_pitch_cone(role):
    """At the outer pitch circle the tooth is s = m(pi/2 + 2 x tan a) - j/2 thick (angle s/r)."""
    g = G.gear_geometry(P, role)
    x = P.x_pinion if role == "pinion" else -P.x_pinion
    z = P.z_pinion if role == "pinion" else P.z_wheel
    s_out = P.module * (math.pi / 2 + 2 * x * math.tan(P.pressure_angle)) - P.backlash / 2
    half = s_out / (P.module * z)
    # find the profile point on the pitch cone, in the gear frame of tooth 0
    u, _, _ = g.profile_minus(np.array([g.s_pitch_param]))
    assert math.acos(u[0, 2]) == pytest.approx(g.delta, abs=1e-13)
    assert math.atan2(u[0, 1], u[0, 0]) == pytest.approx(-half, abs=1e-13)
    # the same through the public function (both flanks, body frame, tooth 0)
    ax = G.tooth_axis_body(role)
    for flank in (1, -1):
        p, _ = G.flank_point_normal(g, flank, g.s_pitch_param, g.Re)
        pol = math.acos(float(p @ ax) / np.linalg.norm(p))
        assert pol == pytest.approx(g.delta, abs=1e-12)
        az_tooth = float(G.tooth_azimuth(g, 0)) * (1 if role == "pinion" else -1)    # body azimuth
        az = math.atan2(p[1], p[0]) - az_tooth
        assert abs(az) == pytest.approx(half, abs=1e-12)
    # the two thicknesses plus the backlash fill the pitch
    gp, gw = G.gear_geometry(P, "pinion"), G.gear_geometry(P, "wheel")
    assert gp.s_pitch + gw.s_pitch + P.backlash == pytest.approx(math.pi * P.module, rel=1e-14)


def test_placement_axes_pitch_line_and_kinematics():
    R0p, R0w = G.pinion_R0(P), G.wheel_R0(P)
    for R in (R0p, R0w):
        assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
    assert np.allclose(R0p[:, 2], G.pinion_axis()) and np.allclose(G.pinion_axis(), [0, 1, 0])
    assert np.allclose(R0w[:, 2], G.wheel_axis()) and np.allclose(G.wheel_axis(), [1, 0, 0])
    d1, d2 = P.delta_pinion, P.delta_wheel
    # pitch line: pinion body (polar d1, az 0), wheel body (polar pi - d2, az 0)
    Pp = R0p @ np.array([math.sin(d1), 0.0, math.cos(d1)])
    Pw = R0w @ np.array([math.sin(d2), 0.0, -math.cos(d2)])
    assert np.allclose(Pp, Pw, atol=1e-15)
    # pitch-point velocities equal with omega_w = omega_p z1/z2 (both positive)
    wp = 1.0
    ww = wp * P.z_pinion / P.z_wheel
    assert np.allclose(np.cross(wp * G.pinion_axis(), Pp), np.cross(ww * G.wheel_axis(), Pw), atol=1e-15)
    # pose = R0 Rz(theta): rotating about the axis
    th = 0.3
    assert np.allclose(G.pinion_pose(th) @ np.array([0, 0, 1.0]), G.pinion_axis())
    # pinion tooth 0 centred on the pitch line; wheel teeth 0 and 1 symmetric about it
    gp, gw = G.gear_geometry(P, "pinion"), G.gear_geometry(P, "wheel")
    pd, _ = G.flank_point_normal(gp, +1, gp.s_pitch_param, 1.0)
    pc, _ = G.flank_point_normal(gp, -1, gp.s_pitch_param, 1.0)
    mid = R0p @ (pd + pc) / 2          # in the plane of the axes (world XY), on the pitch line's side
    assert abs(mid[2]) < 1e-15 and mid @ Pp > 0.99 * np.linalg.norm(mid)
    w0, _ = G.flank_point_normal(gw, +1, gw.s_pitch_param, 1.0, tooth=0)   # drive flank of wheel tooth 0
    w1, _ = G.flank_point_normal(gw, -1, gw.s_pitch_param, 1.0, tooth=1)   # coast flank of tooth 1
    mid = R0w @ (w0 + w1) / 2
    assert abs(mid[2]) < 1e-15 and mid @ Pw > 0.99 * np.linalg.norm(mid)


@pytest.mark.parametrize("role", ["pinion", "wheel"])
def test_drive_flank_is_loaded_when_pinion_drives(role):
    """A contact force on the drive flank (along -n) resists the pinion's positive rotation and
    drives the wheel positively: axis . (p x n) > 0 on the pinion's, < 0 on the wheel's drive flank."""
    g = G.gear_geometry(P, role)
    s = np.linspace(0.0, g.L_radial + g.L_inv, 200)
    for k in (0, 5):
        p, n = G.flank_point_normal(g, +1, s, g.Rm, tooth=k)
        lever = np.cross(p, n)[:, 2]
        assert np.all(lever > 0) if role == "pinion" else np.all(lever < 0)
        p, n = G.flank_point_normal(g, -1, s, g.Rm, tooth=k)
        lever = np.cross(p, n)[:, 2]
        assert np.all(lever < 0) if role == "pinion" else np.all(lever > 0)


def test_tooth_numbering_enters_mesh_k_pitches_later():
    for role, R0 in (("pinion", G.pinion_R0()), ("wheel", G.wheel_R0())):
        g = G.gear_geometry(P, role)
        for k in (1, 3):
            a, _ = G.flank_point_normal(g, +1, g.s_pitch_param, 1.0, tooth=k)
            b, _ = G.flank_point_normal(g, +1, g.s_pitch_param, 1.0, tooth=0)
            assert np.allclose(G.pose(R0, k * g.pitch_angle) @ a, R0 @ b, atol=1e-14)


def test_unloaded_transmission_error_is_conjugate():
    t0 = time.perf_counter()
    r = G.unloaded_transmission_error(P, n_theta=240)
    rc = G.unloaded_transmission_error(P, n_theta=120, flank=-1)
    sb = G.backlash_angle(P)
    print(f"\n unloaded TE p-p (drive) {r['te_pp'] * 1e9:.3f} nm, (coast) {rc['te_pp'] * 1e9:.3f} nm; "
          f"closure s_drive/(s_b/2) - 1 = {r['s_mean'] / (sb / 2) - 1:.2e}, "
          f"s_coast/(-s_b/2) - 1 = {rc['s_mean'] / (-sb / 2) - 1:.2e}  ({time.perf_counter() - t0:.2f} s)")
    assert r["te_pp"] < 1e-6 and rc["te_pp"] < 1e-6
    assert r["te_pp"] < 1e-9          # the exact geometry is conjugate to sampling accuracy
    # backlash-centred at s = 0: drive closes at +s_b/2, coast at -s_b/2
    assert r["s_mean"] == pytest.approx(sb / 2, rel=1e-6)
    assert rc["s_mean"] == pytest.approx(-sb / 2, rel=1e-6)
    assert G.backlash_angle_exact(P) == pytest.approx(sb, rel=1e-6)


@pytest.mark.parametrize("role,ddb", [("wheel", 0.05), ("pinion", -0.05), ("wheel", 0.01)])
def test_unloaded_te_detects_wrong_base_cone(role, ddb):
    g = G.gear_geometry(P, role, delta_b=G.gear_geometry(P, role).delta_b + math.radians(ddb))
    kw = {"wheel_geom": g} if role == "wheel" else {"pinion_geom": g}
    r = G.unloaded_transmission_error(P, n_theta=120, **kw)
    print(f"\n base cone of the {role} off by {ddb} deg: TE p-p = {r['te_pp'] * 1e6:.2f} um")
    assert r["te_pp"] > 1e-6 if abs(ddb) >= 0.05 else r["te_pp"] > 1e-7


def test_contact_ratio():
    t0 = time.perf_counter()
    eps = G.contact_ratio(P)
    eps_c = G.contact_ratio(P, flank=-1)
    eps_t = G.contact_ratio_tredgold(P)
    eps_tr = G.contact_ratio_tredgold(P, rounding=True)
    print(f"\n contact ratio: exact geometry {eps:.4f} (coast {eps_c:.4f}); Tredgold/virtual spur "
          f"{eps_t:.4f} (tip circle), {eps_tr:.4f} (rounding start)  ({time.perf_counter() - t0:.2f} s)")
    assert 1.45 <= eps <= 1.7
    assert 1.45 <= eps_t <= 1.7
    assert eps == pytest.approx(eps_c, abs=1e-6)          # symmetric teeth
    assert abs(eps - eps_tr) < 0.02                        # Tredgold with the same active tip
    assert eps < eps_t                                     # the rounding shortens the active profile


def test_summary_and_pair():
    s = G.summary(P, exact=False)
    assert s["pinion"]["top_land_outer_mm"] > 0.4          # not pointed despite x = +0.43
    t0 = time.perf_counter()
    pair = G.build_pair(P, MeshResolution())
    dt = time.perf_counter() - t0
    print(f"\n default pair: pinion {pair.info['pinion_triangles']} + wheel {pair.info['wheel_triangles']} "
          f"triangles in {dt:.2f} s")
    assert dt < 10.0
    Rp, Rw = pair.poses(0.1, pair.wheel_angle(0.1))
    assert np.allclose(Rp, G.pinion_pose(0.1)) and np.allclose(Rw, G.wheel_pose(0.1 * 15 / 60))
    assert pair.backlash_angle == pytest.approx(2 * P.backlash / (P.module * P.z_pinion))
