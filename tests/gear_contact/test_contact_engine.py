"""Contact engine: BVH, broad phase against brute force, force/moment balance, frame invariance,
the fixed-axis kernel against evaluate_pair, the u_max error state, cost following the contact."""
from __future__ import annotations

import time

import numba as nb
import numpy as np
import pytest
from numba import types
from _shared import through_pointer
from scipy.spatial.transform import Rotation

from gearcontact_fmu.contact import primitives as P
from gearcontact_fmu.contact.bvh import build_bvh
from gearcontact_fmu.contact.engine import (PCMBody, PenetrationError, cache_stats,
                                            evaluate_pair, fixed_axis_eval, make_fixed_axis_data,
                                            reset_cache, rot_z)
from gearcontact_fmu.mesh_models.base import (N_OUT, OUT_CONTACT_AREA, OUT_DISSIPATED_POWER,
                                      OUT_ELASTIC_ENERGY, OUT_MAX_PENETRATION, OUT_N_CONTACT,
                                      OUT_NORMAL_FORCE, OUT_PEAK_PRESSURE, OUT_STATUS,
                                      OUT_TAU_PINION, OUT_TAU_WHEEL)
from gearcontact_fmu.params import PCMParams

PCM = PCMParams(u_max=1e-4)
I3 = np.eye(3)
Z3 = np.zeros(3)


# ---------------------------------------------------------------------------------------------
# BVH
# ---------------------------------------------------------------------------------------------
def test_bvh_structure():
    V, F, _, _ = P.sphere_cap(0.01, 0.004, 30)
    tri = V[F]
    node_box, node_int, order, depth = build_bvh(tri, leaf_size=4)
    m = len(F)
    assert sorted(order.tolist()) == list(range(m))
    leaves = node_int[:, 0] < 0
    assert np.all(node_int[leaves, 3] <= 4) and node_int[leaves, 3].sum() == m
    for k in range(len(node_int)):
        s, c = node_int[k, 2], node_int[k, 3]
        t = tri[order[s:s + c]].reshape(-1, 3)
        assert np.all(t >= node_box[k, :3] - 1e-15) and np.all(t <= node_box[k, 3:] + 1e-15)
        if node_int[k, 0] >= 0:
            l, r = node_int[k, 0], node_int[k, 1]
            assert l > k and r > k
            assert node_int[l, 2] == s and node_int[r, 2] == s + node_int[l, 3]
            assert node_int[l, 3] + node_int[r, 3] == c
    assert depth <= 2 * np.log2(m) + 2


# ---------------------------------------------------------------------------------------------
# broad phase: no contact missed (brute-force reference of the narrow phase)
# ---------------------------------------------------------------------------------------------
def brute_force_u(base, target, Rb, tb, Rt, tt, L):
    """Per base triangle, the smallest accepted penetration over ALL target triangles."""
    p = base.points @ Rb.T + tb
    d = -(base.normals @ Rb.T)
    tri = target.tri @ Rt.T + tt
    ng = target.geo_normals @ Rt.T
    pe = target.points @ Rt.T + tt
    ne = target.normals @ Rt.T
    a = tri[:, 0]
    e1 = tri[:, 1] - a
    e2 = tri[:, 2] - a
    best = np.full(len(p), np.inf)
    for i in range(len(p)):
        dne = ne @ d[i]
        den = ng @ d[i]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.einsum("ij,ij->i", a - p[i], ng) / den
            q = p[i] + s[:, None] * d[i] - a
            # barycentric by least squares in the plane
            d11 = np.einsum("ij,ij->i", e1, e1)
            d12 = np.einsum("ij,ij->i", e1, e2)
            d22 = np.einsum("ij,ij->i", e2, e2)
            q1 = np.einsum("ij,ij->i", q, e1)
            q2 = np.einsum("ij,ij->i", q, e2)
            det = d11 * d22 - d12 * d12
            beta = (d22 * q1 - d12 * q2) / det
            gamma = (d11 * q2 - d12 * q1) / det
            u = np.einsum("ij,ij->i", pe - p[i], ne) / dne
        ok = ((dne > 1e-9) & (np.abs(den) > 1e-9) & (np.abs(s) <= L) & (beta >= -1e-9)
              & (gamma >= -1e-9) & (beta + gamma <= 1 + 1e-9) & (u > 0) & (u <= L))
        if np.any(ok):
            best[i] = u[ok].min()
    return best


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_search_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    R1, R2, u0 = 0.010, 0.020, 3e-5
    s1 = PCMBody(*P.sphere_cap(R1, 0.0015, 24, centre=(0, 0, R1)))
    s2 = PCMBody(*P.sphere_cap(R2, 0.0020, 18, centre=(0, 0, -R2), lower=False))
    G = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    Rb = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    Rt = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    c = rng.normal(size=3) * 0.05
    # world scene: s1 above s2 with overlap u0, both rotated by G, shifted by c; pick body frames
    wb = G @ np.array([1e-4, -5e-5, -u0]) + c
    wt = c
    base = PCMBody(s1.vertices @ G.T @ Rb, s1.faces)       # body-frame vertices: Rb^T G x
    target = PCMBody(s2.vertices @ G.T @ Rt, s2.faces)
    L = 2 * PCM.u_max
    r = evaluate_pair(base, target, (Rb, wb), (Rt, wt), pcm=PCM)
    ref = brute_force_u(base, target, Rb, wb, Rt, wt, L)
    got = np.full(base.n_faces, np.inf)
    got[r.base_idx] = r.u
    assert r.n_contact > 50
    assert np.array_equal(np.isfinite(ref), np.isfinite(got))
    fin = np.isfinite(ref)
    assert np.allclose(got[fin], ref[fin], rtol=1e-9, atol=1e-15)


# ---------------------------------------------------------------------------------------------
# 3. force and moment balance; frame invariance
# ---------------------------------------------------------------------------------------------
def curved_pair(n1=40, n2=30, exact=True):
    R1, R2 = 0.010, 0.030
    V1, F1, p1, q1 = P.sphere_cap(R1, 0.0018, n1, centre=(0, 0, R1))
    V2, F2, p2, q2 = P.cylinder_patch(R2, 0.0025, 0.006, n2, 12, centre=(0, 0, -R2), lower=False)
    if exact:
        return PCMBody(V1, F1, p1, q1), PCMBody(V2, F2, p2, q2)
    return PCMBody(V1, F1), PCMBody(V2, F2)


def test_force_moment_balance_generic_pose():
    base, target = curved_pair()
    rng = np.random.default_rng(7)
    Rb = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    Rt = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    # body frames: vertices given in the frames defined by Rb, tb (scene built in the world)
    G = Rotation.from_rotvec([0.2, -0.4, 0.3]).as_matrix()
    c = np.array([0.03, -0.02, 0.05])
    tb = G @ np.array([2e-4, 1e-4, -2e-5]) + c
    tt = c
    # world: base = G x0 + tb, target = G y0 + tt; body frames rotated by Rb, Rt
    base = PCMBody(base.vertices @ G.T @ Rb, base.faces, base.points @ G.T @ Rb,
                   base.normals @ G.T @ Rb)
    target = PCMBody(target.vertices @ G.T @ Rt, target.faces, target.points @ G.T @ Rt,
                     target.normals @ G.T @ Rt)
    vb = (np.array([0.01, -0.02, 0.03]), np.array([1.0, -2.0, 0.5]))
    vt = (np.array([-0.02, 0.01, 0.0]), np.array([-0.5, 0.3, 1.5]))
    r = evaluate_pair(base, target, (Rb, tb), (Rt, tt), vb, vt, pcm=PCM,
                      friction=True, damping=True)
    assert r.n_contact > 100 and r.dissipated_power > 0
    F = np.linalg.norm(r.force_target)
    M = np.linalg.norm(r.moment_target)
    # body sums from the element arrays
    fe = r.F_n[:, None] * r.normal + r.F_t
    assert np.allclose(fe.sum(0), r.force_target, rtol=0, atol=1e-12 * F)
    assert np.allclose(np.cross(r.point, fe).sum(0), r.moment_target, rtol=0, atol=1e-12 * M)
    # balance between the bodies (about the world origin and about any point)
    assert np.allclose(r.force_base + r.force_target, 0.0, atol=1e-12 * F)
    assert np.allclose(r.moment_base + r.moment_target, 0.0, atol=1e-12 * M)
    Mo = np.linalg.norm(r.moment_target_origin)
    assert np.allclose(r.moment_target_origin,
                       np.cross(r.point - tt, fe).sum(0), atol=1e-12 * Mo)
    assert np.allclose(r.moment_base_origin,
                       np.cross(r.point - tb, -fe).sum(0), atol=1e-12 * Mo)
    # the moments about the two origins are those of one wrench moved between the points
    assert np.allclose(r.moment_base_origin + r.moment_target_origin,
                       np.cross(tb - tt, r.force_target), atol=1e-9 * Mo)
    # frame invariance: move the whole scene rigidly (pose and velocities)
    H = Rotation.from_rotvec([-0.7, 0.1, 0.9]).as_matrix()
    h = np.array([0.1, 0.2, -0.3])

    def moved(R, t, v, w):
        # the scene is moved, not set in motion: origin velocity and omega rotate with it
        return (H @ R, H @ t + h), (H @ v, H @ w)

    (pb, vb2), (pt, vt2) = moved(Rb, tb, *vb), moved(Rt, tt, *vt)
    r2 = evaluate_pair(base, target, pb, pt, vb2, vt2, pcm=PCM, friction=True, damping=True)
    assert r2.n_contact == r.n_contact
    assert np.allclose(r2.force_target, H @ r.force_target, rtol=0, atol=1e-9 * F)
    assert np.allclose(r2.moment_target_origin, H @ r.moment_target_origin, rtol=0,
                       atol=1e-9 * Mo)
    assert abs(r2.dissipated_power / r.dissipated_power - 1) < 1e-9
    assert abs(r2.elastic_energy / r.elastic_energy - 1) < 1e-9


# ---------------------------------------------------------------------------------------------
# 7. fixed-axis kernel vs evaluate_pair; u_max error state
# ---------------------------------------------------------------------------------------------
def fixed_axis_scene(u0=2e-5, pcm=PCM):
    """Sphere cap (base) against a plate (target), each body rotating about its own axis through
    the world origin; built in the world, then expressed in generic body frames."""
    R = 0.01
    V, F, fp, fn = P.sphere_cap(R, 0.003, 50, centre=(0, 0, R))
    Vp, Fp = P.plate(24, 24, 0.02, 0.02, up=True)
    G = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    c = np.array([0.03, 0.02, 0.04])
    off = np.array([0.0, 0.0, -u0])
    Vw, fpw, fnw = (V + off) @ G.T + c, (fp + off) @ G.T + c, fn @ G.T
    Vpw = Vp @ G.T + c
    R0b = Rotation.from_rotvec([0.1, 0.7, -0.3]).as_matrix()
    R0t = Rotation.from_rotvec([-0.9, 0.2, 0.4]).as_matrix()
    base = PCMBody(Vw @ R0b, F, fpw @ R0b, fnw @ R0b)
    target = PCMBody(Vpw @ R0t, Fp)
    return base, target, R0b, R0t


@pytest.mark.parametrize("friction,damping", [(True, True), (False, False)])
def test_fixed_axis_matches_evaluate_pair(friction, damping):
    base, target, R0b, R0t = fixed_axis_scene()
    data = make_fixed_axis_data(base, target, R0b, R0t, PCM, friction, damping)
    out = np.zeros(N_OUT)
    cases = [(0.0, 0.0, 0.0, 0.0), (1e-4, -2e-4, 3.0, -1.0), (-1e-4, 1e-4, -5.0, 2.0),
             (5e-5, 8e-5, 0.5, 0.7)]
    for tb_, tt_, wb_, wt_ in cases:
        fixed_axis_eval(data, tb_, tt_, wb_, wt_, out)
        Rb = R0b @ rot_z(tb_)
        Rt = R0t @ rot_z(tt_)
        r = evaluate_pair(base, target, (Rb, Z3), (Rt, Z3), (Z3, wb_ * R0b[:, 2]),
                          (Z3, wt_ * R0t[:, 2]), pcm=PCM, friction=friction, damping=damping)
        tau_b = R0b[:, 2] @ r.moment_base
        tau_t = R0t[:, 2] @ r.moment_target
        assert r.n_contact > 100
        assert abs(out[OUT_TAU_PINION] - tau_b) <= 1e-9 * abs(tau_b)
        assert abs(out[OUT_TAU_WHEEL] - tau_t) <= 1e-9 * abs(tau_t)
        assert out[OUT_N_CONTACT] == r.n_contact
        for k, v in [(OUT_CONTACT_AREA, r.contact_area), (OUT_PEAK_PRESSURE, r.peak_pressure),
                     (OUT_MAX_PENETRATION, r.max_penetration),
                     (OUT_NORMAL_FORCE, r.normal_force), (OUT_ELASTIC_ENERGY, r.elastic_energy),
                     (OUT_DISSIPATED_POWER, r.dissipated_power)]:
            assert abs(out[k] - v) <= 1e-9 * abs(v) + 1e-300
        assert out[OUT_STATUS] == 0.0
        if not damping:
            assert out[OUT_DISSIPATED_POWER] == 0.0


def _run_path(mesh_eval, data, thb, tht, wb, wt, outs):
    """The kernel along a path, one call per point (from Python: the same compiled kernel and the same
    cache updates as from a jitted loop, without compiling that loop for every test session, ~3 s; the
    first-class-function call from jitted code is test_fixed_axis_callable_from_njit's)."""
    for k in range(thb.shape[0]):
        mesh_eval(data, thb[k], tht[k], wb[k], wt[k], outs[k])


def test_candidate_cache_is_exact():
    """The cached kernel gives the exact search's result along a path that starts out of contact,
    sweeps the contact across the target, with small steps and some jumps."""
    base, target, R0b, R0t = fixed_axis_scene(u0=2e-5)
    exact = make_fixed_axis_data(base, target, R0b, R0t, PCM, cache_margin=0.0)
    cached = make_fixed_axis_data(base, target, R0b, R0t, PCM, cache_margin=5e-6,
                                  cache_far=2e-5)
    n = 600
    k = np.arange(n)
    thb = -1.5e-3 + 5e-6 * k                   # the cap (r ~ 5 cm) enters and crosses contact
    thb[350:360] += 3e-4                        # a jump
    tht = 2e-4 * np.sin(k / 50.0)
    wb = np.full(n, 2.0)
    wt = -np.cos(k / 30.0)
    o1 = np.zeros((n, N_OUT))
    o2 = np.zeros((n, N_OUT))
    _run_path(fixed_axis_eval, exact, thb, tht, wb, wt, o1)
    _run_path(fixed_axis_eval, cached, thb, tht, wb, wt, o2)
    st = cache_stats(cached)
    print("cache stats", st, "calls in contact", int((o1[:, OUT_N_CONTACT] > 0).sum()))
    assert (o1[:, OUT_N_CONTACT] == 0).sum() > 20 and (o1[:, OUT_N_CONTACT] > 100).sum() > 100
    assert np.array_equal(o1[:, OUT_N_CONTACT], o2[:, OUT_N_CONTACT])
    scale = np.abs(o1).max(axis=0) + 1e-300
    assert np.all(np.abs(o1 - o2) <= 1e-12 * scale)
    assert st["builds"] + st["exact_calls"] < n / 2 and st["cached_calls"] > n / 2
    # large steps: the adaptive fallback turns to the exact search (still exact results)
    reset_cache(cached)
    thb2 = -1.5e-3 + 2e-4 * np.arange(15)
    z = np.zeros(15)
    o3 = np.zeros((15, N_OUT))
    o4 = np.zeros((15, N_OUT))
    _run_path(fixed_axis_eval, exact, thb2, z, z, z, o3)
    _run_path(fixed_axis_eval, cached, thb2, z, z, z, o4)
    assert np.all(np.abs(o3 - o4) <= 1e-12 * (np.abs(o3).max(axis=0) + 1e-300))
    assert cache_stats(cached)["exact_calls"] > 0


def test_penetration_beyond_u_max():
    pcm = PCMParams(u_max=1e-5)
    base, target, R0b, R0t = fixed_axis_scene(u0=1.5e-5)   # deeper than u_max, within 2 u_max
    data = make_fixed_axis_data(base, target, R0b, R0t, pcm)
    out = np.zeros(N_OUT)
    fixed_axis_eval(data, 0.0, 0.0, 0.0, 0.0, out)
    assert out[OUT_STATUS] == 1.0
    assert out[OUT_MAX_PENETRATION] > pcm.u_max
    with pytest.raises(PenetrationError):
        evaluate_pair(base, target, (R0b, Z3), (R0t, Z3), pcm=pcm)
    r = evaluate_pair(base, target, (R0b, Z3), (R0t, Z3), pcm=pcm, check_penetration=False)
    assert r.status == 1 and r.max_penetration > pcm.u_max
    # within u_max: ok
    base, target, R0b, R0t = fixed_axis_scene(u0=0.8e-5)
    data = make_fixed_axis_data(base, target, R0b, R0t, pcm)
    fixed_axis_eval(data, 0.0, 0.0, 0.0, 0.0, out)
    assert out[OUT_STATUS] == 0.0


def _integrator_like(mesh_eval, data, n):
    """A caller that receives the kernel as a first-class function (as the gear stage does)."""
    out = np.zeros(10)
    acc = 0.0
    for i in range(n):
        mesh_eval(data, 1e-5 * i, 0.0, 1.0, 0.0, out)
        acc += out[0]
    return acc, out[2]


def test_fixed_axis_callable_from_njit():
    base, target, R0b, R0t = fixed_axis_scene()
    data = make_fixed_axis_data(base, target, R0b, R0t, PCM)
    kernel = through_pointer(_integrator_like, fixed_axis_eval, data,
                             types.UniTuple(types.float64, 2), types.int64)
    acc, n = kernel(fixed_axis_eval, data, 3)
    out = np.zeros(N_OUT)
    ref = 0.0
    for i in range(3):
        fixed_axis_eval(data, 1e-5 * i, 0.0, 1.0, 0.0, out)
        ref += out[0]
    assert acc == ref and n > 0


def test_input_validation():
    V, F = P.plate(2, 2, 0.01, 0.01)
    with pytest.raises(ValueError):
        PCMBody(V, F + 100)
    with pytest.raises(ValueError):
        PCMBody(V, F, face_points=V[F].mean(1))
    with pytest.raises(ValueError):                      # normals against the winding
        PCMBody(V, F, V[F].mean(1), np.tile([0.0, 0.0, -1.0], (len(F), 1)))


# ---------------------------------------------------------------------------------------------
# 8. cost follows the contact, not the mesh size
# ---------------------------------------------------------------------------------------------
def graded_edges(half, inner, n_inner, n_outer):
    """Edges over [-half, half]: n_inner cells in |x| <= inner, n_outer cells on each side."""
    return np.concatenate([np.linspace(-half, -inner, n_outer + 1)[:-1],
                           np.linspace(-inner, inner, n_inner + 1),
                           np.linspace(inner, half, n_outer + 1)[1:]])


def _repeat(mesh_eval, data, n, out):
    for _ in range(n):
        mesh_eval(data, 0.0, 0.0, 0.0, 0.0, out)


def time_interleaved(datas, reps=100, rounds=9):
    """Best time per call of each data tuple, measured in alternation (a busy machine slows all
    of them alike)."""
    out = np.zeros(N_OUT)
    best = [np.inf] * len(datas)
    outs = []
    repeat = through_pointer(_repeat, fixed_axis_eval, datas[0], types.none, types.int64, types.float64[::1])
    assert all(nb.typeof(d) == nb.typeof(datas[0]) for d in datas)
    for d in datas:
        repeat(fixed_axis_eval, d, 1, out)
        outs.append(out.copy())
    for _ in range(rounds):
        for q, d in enumerate(datas):
            t0 = time.perf_counter()
            repeat(fixed_axis_eval, d, reps, out)
            best[q] = min(best[q], (time.perf_counter() - t0) / reps)
    return best, outs


def plate_pair(refine):
    """Base plate 40 x 40 mm with a 2 x 2 mm fine centre; target sphere cap R = 20 mm touching at
    the centre; every cell outside the centre refined ``refine`` x in each direction."""
    xe = graded_edges(0.02, 0.001, 20, 19 * refine)
    base = PCMBody(*P.plate_graded(xe, xe, up=True))
    R, u = 0.02, 5e-6
    half = 0.006
    s = graded_edges(half, 0.001, 20, 5 * refine)
    X, Y = np.meshgrid(s, s, indexing="ij")
    Vs = np.c_[X.ravel(), Y.ravel(), R - u - np.sqrt(R * R - X.ravel() ** 2 - Y.ravel() ** 2)]
    Fs = P._grid_faces(len(s) - 1, len(s) - 1, flip=True)
    target = PCMBody(Vs, Fs)
    return base, target


def test_cost_follows_contact():
    pcm = PCMParams(u_max=5e-5)
    datas, sizes = [], []
    for refine in (1, 4):
        base, target = plate_pair(refine)
        # exact search every call (no candidate cache): the cost measured is the search's
        datas.append(make_fixed_axis_data(base, target, I3, I3, pcm, cache_margin=0.0))
        sizes.append((base.n_faces, target.n_faces))
    t, out = time_interleaved(datas)
    ratio = t[1] / t[0]
    print(f"cost follows contact: sizes {sizes}, n_contact {out[0][OUT_N_CONTACT]:.0f}, "
          f"{t[0] * 1e6:.1f} us -> {t[1] * 1e6:.1f} us, ratio {ratio:.2f}")
    assert out[0][OUT_N_CONTACT] == out[1][OUT_N_CONTACT] > 50
    assert abs(out[1][OUT_NORMAL_FORCE] / out[0][OUT_NORMAL_FORCE] - 1) < 1e-9
    assert sizes[1][0] > 8 * sizes[0][0] and sizes[1][1] > 3 * sizes[0][1]
    assert ratio < 2.0
