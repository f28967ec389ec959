"""numba kernels of the polygonal contact method (PCM): dual-tree search, element penetration,
element forces, body forces. Plain arrays in and out, no Python objects in the hot loops.

Array layouts (all float64 unless stated; "slot order" = the order of the body's BVH leaves, slot k
holds triangle ``order[k]``):

* ``belem`` (m, 7), slot order, base role: ``[p(3), n(3), area]`` element point, unit outward
  element normal, triangle area (body frame).
* ``ttri`` (m, 18), slot order, target role: ``[a(3), ng(3), g1(3), g2(3), pe(3), ne(3)]`` first
  vertex, unit geometric normal of the flat triangle, dual edge vectors (barycentric coordinates of
  a point q of the plane: ``beta = g1.(q-a)``, ``gamma = g2.(q-a)``), exact element point and unit
  normal (the centroid and geometric normal when no exact data are given).
* tree: ``node_int`` (N, 4) int64 ``[left, right, start, count]``; target node boxes ``t_box``
  (N, 6) ``[min, max]`` and normal slabs ``t_slab`` (N, 5) ``[n, d_min, d_max]``; base node boxes ``b_seg`` (N, 6) ``[centre, half extents]`` of the
  penetration-line segments ``[p, p - L n]`` (see :func:`bvh.refit_segment_boxes`).
* ``params`` (N_PARAMS,): see the ``P_*`` indices.
* candidate cache (fixed-axis kernel): ``cache`` (N_CACHE,) state (see ``C_*``), ``cand`` (C, 2)
  int64 candidate pairs (base slot, target slot) sorted by base slot, ``cand_tri`` (C, 18) their
  target rows of ``ttri``; ``nstamp`` (N_base_nodes,) int64, ``icount`` (1,) int64; far-check
  nodes of the base tree ``fnode`` (F,) int64 and ``fc`` (N_base_nodes, 2) int64 (range of
  far-check nodes under each node); ``minsep`` (F,), ``nbox`` (F, 6), ``close`` (F,) int64;
  ``dR`` (3, 3), ``dt`` (3,) scratch.
* base workspace (per base body): ``stamp`` (m,) int64, ``call`` (1,) int64, ``best_u`` (m,),
  ``best_j`` (m,) int64 (target slot of the winning hit), ``line`` (m, 7) ``[p', d', s_entry]`` element point
  and inward direction in the target frame, ``active`` (m,) int64 (base slots with a hit),
  ``stack`` (S, 2) int64.

The stamp/call pair makes the per-element state valid only for the current call, so nothing of size
m is reset per call: the cost follows the number of elements near contact.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

# params layout
P_C = 0            # combined layer stiffness c [N/m^3]
P_CC = 1           # compression damping [N s/m^3]
P_CE = 2           # expansion damping [N s/m^3]
P_TD = 3           # transformation depth [m]
P_MU = 4           # friction coefficient
P_VF = 5           # friction regularisation velocity [m/s]
P_UMAX = 6         # maximum penetration [m]
P_L = 7            # search length (>= u_max) [m]
P_FRICTION = 8     # 1.0 on, 0.0 off
P_DAMPING = 9      # 1.0 on, 0.0 off
P_RATIO = 10       # force point on the penetration line: p + ratio*u*d (0.5 = mid-layer)
P_SNEG = 11        # outward reach of the line (target facet vs exact tangent plane) [m]
P_DELTA = 12       # candidate cache margin [m] (0: no cache, exact search every call)
P_FAR = 13         # cache: far margin [m] (base leaves within it bound the near region)
P_PHI = 14         # cache: largest relative rotation before a rebuild [rad]
N_PARAMS = 15

# diagnostics layout of the generic force kernel (matches mesh_model.OUT_* minus the torques)
D_N = 0
D_AREA = 1
D_PEAK_P = 2
D_UMAX = 3
D_FN = 4
D_EEL = 5
D_PDISS = 6
D_STATUS = 7
N_DIAG = 8

DOT_EPS = 1e-9      # |cos| below which a line and a plane count as parallel / normals as perpendicular
BARY_EPS = 1e-9     # tolerance of the inside test (shared edges: the smallest u wins, no double count)
# A hit counts only where the target faces the penetration line within 60 deg (d . n_target >= 0.5).
# Real contacts have nearly opposite normals (gear flanks, a sphere on a plane at u << R); a line that
# meets the partner at a grazing angle measures a length along the surface, not a penetration: e.g. a
# line from the wall of a flank void runs just under the flank and meets the partner's tip rounding
# ~1 mm away, which would report u ~ 1 mm for a contact that is micrometres deep.
# The cone alone does not catch that line: it leaves the pinion through its own flank ~0.45 mm on,
# ENTERS the wheel flank at a grazing angle and exits through the tip rounding at 57 deg (measured on
# the mild fault: 13 wall elements at u = 0.82 mm, +650 N·m of wrong-signed torque in the contact
# map). The decisive test is topological (first crossing): a hit counts only if no target surface is
# entered between the base point and the hit (:func:`tri_entry`), i.e. the base point lies inside
# the target. Candidate collection therefore keeps triangles of both orientations.
FACING_COS = 0.5


def make_params(pcm, search_length=None, friction=True, damping=True, ratio=0.5, s_neg=0.0,
                cache_margin=0.0, cache_far=None, cache_phi=0.02):
    """Parameter vector of the kernels from a :class:`~gearcontact_fmu.params.PCMParams`."""
    L = 2.0 * pcm.u_max if search_length is None else float(search_length)
    if L < pcm.u_max:
        raise ValueError(f"search length {L} must be >= u_max {pcm.u_max}")
    delta = float(cache_margin)
    far = 10.0 * delta if cache_far is None else float(cache_far)
    if delta < 0.0 or (delta > 0.0 and far <= delta):
        raise ValueError("cache margins must satisfy 0 < cache_margin < cache_far")
    p = np.zeros(N_PARAMS)
    p[P_C] = pcm.stiffness
    p[P_CC] = pcm.c_compression
    p[P_CE] = pcm.c_expansion
    p[P_TD] = pcm.transformation_depth
    p[P_MU] = pcm.mu
    p[P_VF] = pcm.v_friction
    p[P_UMAX] = pcm.u_max
    p[P_L] = L
    p[P_FRICTION] = 1.0 if friction else 0.0
    p[P_DAMPING] = 1.0 if damping else 0.0
    p[P_RATIO] = ratio
    p[P_SNEG] = min(float(s_neg), L)
    p[P_DELTA] = delta
    p[P_FAR] = far
    p[P_PHI] = float(cache_phi)
    return p


# ----------------------------------------------------------------------------------------------
# element data
# ----------------------------------------------------------------------------------------------
@njit(cache=True)
def element_data(tri, face_points, face_normals, has_exact):
    """Per triangle: geometric unit normal, area, centroid, and the target-role array ``ttri`` and
    base-role array ``belem`` (in triangle order). ``has_exact``: use face_points/face_normals as the
    element point and normal (they must be given with unit normals)."""
    m = tri.shape[0]
    belem = np.zeros((m, 7))
    ttri = np.zeros((m, 18))
    for i in range(m):
        ax, ay, az = tri[i, 0, 0], tri[i, 0, 1], tri[i, 0, 2]
        e1x, e1y, e1z = tri[i, 1, 0] - ax, tri[i, 1, 1] - ay, tri[i, 1, 2] - az
        e2x, e2y, e2z = tri[i, 2, 0] - ax, tri[i, 2, 1] - ay, tri[i, 2, 2] - az
        Nx = e1y * e2z - e1z * e2y
        Ny = e1z * e2x - e1x * e2z
        Nz = e1x * e2y - e1y * e2x
        nN = math.sqrt(Nx * Nx + Ny * Ny + Nz * Nz)
        area = 0.5 * nN
        cx = (tri[i, 0, 0] + tri[i, 1, 0] + tri[i, 2, 0]) / 3.0
        cy = (tri[i, 0, 1] + tri[i, 1, 1] + tri[i, 2, 1]) / 3.0
        cz = (tri[i, 0, 2] + tri[i, 1, 2] + tri[i, 2, 2]) / 3.0
        if nN > 0.0:
            nx, ny, nz = Nx / nN, Ny / nN, Nz / nN
            inv = 1.0 / nN
            # g1 = (e2 x n)/|N|, g2 = (n x e1)/|N|
            g1x = (e2y * nz - e2z * ny) * inv
            g1y = (e2z * nx - e2x * nz) * inv
            g1z = (e2x * ny - e2y * nx) * inv
            g2x = (ny * e1z - nz * e1y) * inv
            g2y = (nz * e1x - nx * e1z) * inv
            g2z = (nx * e1y - ny * e1x) * inv
        else:
            nx = ny = nz = 0.0
            g1x = g1y = g1z = g2x = g2y = g2z = 0.0
        if has_exact:
            px, py, pz = face_points[i, 0], face_points[i, 1], face_points[i, 2]
            qx, qy, qz = face_normals[i, 0], face_normals[i, 1], face_normals[i, 2]
        else:
            px, py, pz = cx, cy, cz
            qx, qy, qz = nx, ny, nz
        belem[i, 0] = px
        belem[i, 1] = py
        belem[i, 2] = pz
        belem[i, 3] = qx
        belem[i, 4] = qy
        belem[i, 5] = qz
        belem[i, 6] = area
        ttri[i, 0] = ax
        ttri[i, 1] = ay
        ttri[i, 2] = az
        ttri[i, 3] = nx
        ttri[i, 4] = ny
        ttri[i, 5] = nz
        ttri[i, 6] = g1x
        ttri[i, 7] = g1y
        ttri[i, 8] = g1z
        ttri[i, 9] = g2x
        ttri[i, 10] = g2y
        ttri[i, 11] = g2z
        ttri[i, 12] = px
        ttri[i, 13] = py
        ttri[i, 14] = pz
        ttri[i, 15] = qx
        ttri[i, 16] = qy
        ttri[i, 17] = qz
    return belem, ttri


# ----------------------------------------------------------------------------------------------
# contact search (broad + narrow phase)
# ----------------------------------------------------------------------------------------------
@njit(cache=True)
def _obb_overlap(b_obb, i, t_obb, j, r00, r01, r02, r10, r11, r12, r20, r21, r22, t0, t1, t2,
                 infl):
    """Separating-axis test of base node i (its oriented box mapped by (R, t) into the target
    frame, half extents grown by ``infl``) and target node j on the 6 face axes of the two boxes
    (conservative: True may be a false overlap, False proves a distance > infl)."""
    return _obb_gap(b_obb, i, t_obb, j, r00, r01, r02, r10, r11, r12, r20, r21, r22, t0, t1, t2,
                    infl) <= 0.0


@njit(cache=True)
def _obb_gap(b_obb, i, t_obb, j, r00, r01, r02, r10, r11, r12, r20, r21, r22, t0, t1, t2,
                 infl):
    """Largest separation of the two oriented boxes over the 6 face axes (> 0: separated, and the
    distance between the boxes is larger than this + infl). See :func:`_obb_overlap`."""
    a0x = r00 * b_obb[i, 0] + r01 * b_obb[i, 1] + r02 * b_obb[i, 2]
    a0y = r10 * b_obb[i, 0] + r11 * b_obb[i, 1] + r12 * b_obb[i, 2]
    a0z = r20 * b_obb[i, 0] + r21 * b_obb[i, 1] + r22 * b_obb[i, 2]
    a1x = r00 * b_obb[i, 3] + r01 * b_obb[i, 4] + r02 * b_obb[i, 5]
    a1y = r10 * b_obb[i, 3] + r11 * b_obb[i, 4] + r12 * b_obb[i, 5]
    a1z = r20 * b_obb[i, 3] + r21 * b_obb[i, 4] + r22 * b_obb[i, 5]
    a2x = r00 * b_obb[i, 6] + r01 * b_obb[i, 7] + r02 * b_obb[i, 8]
    a2y = r10 * b_obb[i, 6] + r11 * b_obb[i, 7] + r12 * b_obb[i, 8]
    a2z = r20 * b_obb[i, 6] + r21 * b_obb[i, 7] + r22 * b_obb[i, 8]
    cx = r00 * b_obb[i, 9] + r01 * b_obb[i, 10] + r02 * b_obb[i, 11] + t0 - t_obb[j, 9]
    cy = r10 * b_obb[i, 9] + r11 * b_obb[i, 10] + r12 * b_obb[i, 11] + t1 - t_obb[j, 10]
    cz = r20 * b_obb[i, 9] + r21 * b_obb[i, 10] + r22 * b_obb[i, 11] + t2 - t_obb[j, 11]
    eb0, eb1, eb2 = b_obb[i, 12] + infl, b_obb[i, 13] + infl, b_obb[i, 14] + infl
    et0, et1, et2 = t_obb[j, 12], t_obb[j, 13], t_obb[j, 14]
    g0x, g0y, g0z = t_obb[j, 0], t_obb[j, 1], t_obb[j, 2]
    g1x, g1y, g1z = t_obb[j, 3], t_obb[j, 4], t_obb[j, 5]
    g2x, g2y, g2z = t_obb[j, 6], t_obb[j, 7], t_obb[j, 8]
    # C[q][k] = target axis q . base axis k
    c00 = g0x * a0x + g0y * a0y + g0z * a0z
    c01 = g0x * a1x + g0y * a1y + g0z * a1z
    c02 = g0x * a2x + g0y * a2y + g0z * a2z
    c10 = g1x * a0x + g1y * a0y + g1z * a0z
    c11 = g1x * a1x + g1y * a1y + g1z * a1z
    c12 = g1x * a2x + g1y * a2y + g1z * a2z
    c20 = g2x * a0x + g2y * a0y + g2z * a0z
    c21 = g2x * a1x + g2y * a1y + g2z * a1z
    c22 = g2x * a2x + g2y * a2y + g2z * a2z
    d0 = g0x * cx + g0y * cy + g0z * cz
    d1 = g1x * cx + g1y * cy + g1z * cz
    d2 = g2x * cx + g2y * cy + g2z * cz
    ac00, ac01, ac02 = abs(c00), abs(c01), abs(c02)
    ac10, ac11, ac12 = abs(c10), abs(c11), abs(c12)
    ac20, ac21, ac22 = abs(c20), abs(c21), abs(c22)
    g = abs(d2) - (et2 + ac20 * eb0 + ac21 * eb1 + ac22 * eb2)
    g = max(g, abs(d0) - (et0 + ac00 * eb0 + ac01 * eb1 + ac02 * eb2))
    g = max(g, abs(d1) - (et1 + ac10 * eb0 + ac11 * eb1 + ac12 * eb2))
    g = max(g, abs(c02 * d0 + c12 * d1 + c22 * d2) - (eb2 + ac02 * et0 + ac12 * et1 + ac22 * et2))
    g = max(g, abs(c00 * d0 + c10 * d1 + c20 * d2) - (eb0 + ac00 * et0 + ac10 * et1 + ac20 * et2))
    g = max(g, abs(c01 * d0 + c11 * d1 + c21 * d2) - (eb1 + ac01 * et0 + ac11 * et1 + ac21 * et2))
    return g


@njit(cache=True)
def _segment_vs_leaf(ax, ay, az, bx, by, bz, t_box, t_obb, j, grow):
    """False if the segment a-b (target frame) is separated from target node j's boxes grown by
    ``grow`` (axis-aligned box, then the 3 axes of the oriented box)."""
    if min(ax, bx) > t_box[j, 3] + grow or max(ax, bx) < t_box[j, 0] - grow:
        return False
    if min(ay, by) > t_box[j, 4] + grow or max(ay, by) < t_box[j, 1] - grow:
        return False
    if min(az, bz) > t_box[j, 5] + grow or max(az, bz) < t_box[j, 2] - grow:
        return False
    for q in range(3):
        gx, gy, gz = t_obb[j, 3 * q], t_obb[j, 3 * q + 1], t_obb[j, 3 * q + 2]
        pa = gx * (ax - t_obb[j, 9]) + gy * (ay - t_obb[j, 10]) + gz * (az - t_obb[j, 11])
        pb = gx * (bx - t_obb[j, 9]) + gy * (by - t_obb[j, 10]) + gz * (bz - t_obb[j, 11])
        hw = t_obb[j, 12 + q] + grow
        if (pa > hw and pb > hw) or (pa < -hw and pb < -hw):
            return False
    return True


@njit(cache=True)
def tri_hit(ox, oy, oz, dx, dy, dz, ttri, l, L, s_neg):
    """Exact narrow phase of one penetration line (origin o, inward unit direction d, target
    frame) against target triangle slot l. Returns the penetration u > 0, or -1.0 when there is
    no accepted hit: the target must face the line within 60 deg (d.ne >= FACING_COS), the line must meet the flat
    triangle (inside test) at a line parameter s in [-s_neg, L], and u (distance along the line to
    the element's exact tangent plane) must lie in (0, L]."""
    dne = dx * ttri[l, 15] + dy * ttri[l, 16] + dz * ttri[l, 17]
    if dne < FACING_COS:
        return -1.0
    ngx, ngy, ngz = ttri[l, 3], ttri[l, 4], ttri[l, 5]
    den = dx * ngx + dy * ngy + dz * ngz
    if abs(den) <= DOT_EPS:
        return -1.0
    rax = ttri[l, 0] - ox
    ray = ttri[l, 1] - oy
    raz = ttri[l, 2] - oz
    s = (rax * ngx + ray * ngy + raz * ngz) / den
    if s > L or s < -s_neg:
        return -1.0
    wx = s * dx - rax
    wy = s * dy - ray
    wz = s * dz - raz
    beta = wx * ttri[l, 6] + wy * ttri[l, 7] + wz * ttri[l, 8]
    if beta < -BARY_EPS:
        return -1.0
    gamma = wx * ttri[l, 9] + wy * ttri[l, 10] + wz * ttri[l, 11]
    if gamma < -BARY_EPS or beta + gamma > 1.0 + BARY_EPS:
        return -1.0
    u = ((ttri[l, 12] - ox) * ttri[l, 15] + (ttri[l, 13] - oy) * ttri[l, 16]
         + (ttri[l, 14] - oz) * ttri[l, 17]) / dne
    if u <= 0.0 or u > L:
        return -1.0
    return u


@njit(cache=True)
def tri_entry(ox, oy, oz, dx, dy, dz, ttri, l, L):
    """Line parameter s in (0, L] where the penetration line (origin o, inward unit direction d)
    ENTERS the target through triangle slot l (the flat triangle's outward normal points against
    d), or +inf. A base point lies inside the target only if the first target surface its line
    crosses beyond it is an exit: a hit farther along the line than an entry is a line that left
    the base body, crossed the gap and went through part of the target (see :data:`FACING_COS`)."""
    ngx, ngy, ngz = ttri[l, 3], ttri[l, 4], ttri[l, 5]
    den = dx * ngx + dy * ngy + dz * ngz
    if den >= -DOT_EPS:
        return np.inf
    rax = ttri[l, 0] - ox
    ray = ttri[l, 1] - oy
    raz = ttri[l, 2] - oz
    s = (rax * ngx + ray * ngy + raz * ngz) / den
    if s <= 0.0 or s > L:
        return np.inf
    wx = s * dx - rax
    wy = s * dy - ray
    wz = s * dz - raz
    beta = wx * ttri[l, 6] + wy * ttri[l, 7] + wz * ttri[l, 8]
    if beta < -BARY_EPS:
        return np.inf
    gamma = wx * ttri[l, 9] + wy * ttri[l, 10] + wz * ttri[l, 11]
    if gamma < -BARY_EPS or beta + gamma > 1.0 + BARY_EPS:
        return np.inf
    return s


@njit(cache=True)
def tri_near(ax, ay, az, bx, by, bz, ttri, l, delta):
    """Candidate filter (superset of every hit after a rigid motion that moves each point of the
    segment a-b by less than ``delta``): False
    when the segment is farther than ``delta`` from the triangle's plane or from one of its edge
    lines on the outer side. Triangles of every orientation are kept: facing ones for hits, the
    others for the first-crossing rule (:func:`tri_entry`)."""
    ngx, ngy, ngz = ttri[l, 3], ttri[l, 4], ttri[l, 5]
    vx, vy, vz = ttri[l, 0], ttri[l, 1], ttri[l, 2]
    ha = (ax - vx) * ngx + (ay - vy) * ngy + (az - vz) * ngz
    hb = (bx - vx) * ngx + (by - vy) * ngy + (bz - vz) * ngz
    if (ha > delta and hb > delta) or (ha < -delta and hb < -delta):
        return False
    g1x, g1y, g1z = ttri[l, 6], ttri[l, 7], ttri[l, 8]
    g2x, g2y, g2z = ttri[l, 9], ttri[l, 10], ttri[l, 11]
    b_a = (ax - vx) * g1x + (ay - vy) * g1y + (az - vz) * g1z
    b_b = (bx - vx) * g1x + (by - vy) * g1y + (bz - vz) * g1z
    lim = -delta * math.sqrt(g1x * g1x + g1y * g1y + g1z * g1z) - BARY_EPS
    if b_a < lim and b_b < lim:
        return False
    c_a = (ax - vx) * g2x + (ay - vy) * g2y + (az - vz) * g2z
    c_b = (bx - vx) * g2x + (by - vy) * g2y + (bz - vz) * g2z
    lim = -delta * math.sqrt(g2x * g2x + g2y * g2y + g2z * g2z) - BARY_EPS
    if c_a < lim and c_b < lim:
        return False
    sx, sy, sz = g1x + g2x, g1y + g2y, g1z + g2z
    lim = -delta * math.sqrt(sx * sx + sy * sy + sz * sz) - BARY_EPS
    if 1.0 - b_a - c_a < lim and 1.0 - b_b - c_b < lim:
        return False
    return True


@njit(cache=True)
def _traverse(mode, b_int, b_seg, b_obb, belem, t_int, t_box, t_obb, ttri, Rbt, tbt, L, s_neg,
              infl, delta, stamp, call, best_u, best_j, line, active, stack,
              cand, nstamp, icount, fc, minsep, nbox):
    """Dual-tree traversal. mode 0: exact search (fills the base workspace, returns the number
    of base elements with a hit). mode 1: candidate collection for the cache (pairs (base slot,
    target slot) into ``cand``; returns the number of pairs, or -1 when ``cand`` overflows).
    Node volumes are grown by ``infl``. Mode 1 also records, per far-check node f of the base
    (``fc[i] = [f_lo, f_hi)`` the far-check nodes under base node i), a lower bound of the
    distance of its non-near elements to the target (``minsep[f]``) and the box of its near
    leaves (``nbox[f] = [lo, hi]``, base frame); ``icount[0]`` = number of near leaves."""
    call[0] += 1
    cid = call[0]
    r00, r01, r02 = Rbt[0, 0], Rbt[0, 1], Rbt[0, 2]
    r10, r11, r12 = Rbt[1, 0], Rbt[1, 1], Rbt[1, 2]
    r20, r21, r22 = Rbt[2, 0], Rbt[2, 1], Rbt[2, 2]
    a00, a01, a02 = abs(r00), abs(r01), abs(r02)
    a10, a11, a12 = abs(r10), abs(r11), abs(r12)
    a20, a21, a22 = abs(r20), abs(r21), abs(r22)
    t0, t1, t2 = tbt[0], tbt[1], tbt[2]
    n_out = 0
    cap = cand.shape[0]
    icount[0] = 0
    stack[0, 0] = 0
    stack[0, 1] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        i = stack[sp, 0]
        j = stack[sp, 1]
        c0, c1, c2 = b_seg[i, 0], b_seg[i, 1], b_seg[i, 2]
        e0, e1, e2 = b_seg[i, 3] + infl, b_seg[i, 4] + infl, b_seg[i, 5] + infl
        # base box in the target frame (centre R c + t, half extents |R| e)
        cx = r00 * c0 + r01 * c1 + r02 * c2 + t0
        ex = a00 * e0 + a01 * e1 + a02 * e2
        cy = r10 * c0 + r11 * c1 + r12 * c2 + t1
        ey = a10 * e0 + a11 * e1 + a12 * e2
        cz = r20 * c0 + r21 * c1 + r22 * c2 + t2
        ez = a20 * e0 + a21 * e1 + a22 * e2
        if mode == 0:
            if cx - ex > t_box[j, 3] or cx + ex < t_box[j, 0]:
                continue
            if cy - ey > t_box[j, 4] or cy + ey < t_box[j, 1]:
                continue
            if cz - ez > t_box[j, 5] or cz + ez < t_box[j, 2]:
                continue
            # oriented boxes (surface-patch frames)
            if not _obb_overlap(b_obb, i, t_obb, j, r00, r01, r02, r10, r11, r12, r20, r21,
                                r22, t0, t1, t2, infl):
                continue
        else:
            g = max(cx - ex - t_box[j, 3], t_box[j, 0] - cx - ex,
                    cy - ey - t_box[j, 4], t_box[j, 1] - cy - ey,
                    cz - ez - t_box[j, 5], t_box[j, 2] - cz - ez)
            if g <= 0.0:
                g = _obb_gap(b_obb, i, t_obb, j, r00, r01, r02, r10, r11, r12, r20, r21, r22,
                             t0, t1, t2, infl)
            if g > 0.0:
                dist = g + infl
                for f in range(fc[i, 0], fc[i, 1]):
                    if dist < minsep[f]:
                        minsep[f] = dist
                continue
        bl = b_int[i, 0]
        tl = t_int[j, 0]
        if bl >= 0 or tl >= 0:
            # descend: the base if the target is a leaf, else the larger box
            split_base = False
            if tl < 0:
                split_base = True
            elif bl >= 0:
                sb = ex + ey + ez
                st = (t_box[j, 3] - t_box[j, 0]) + (t_box[j, 4] - t_box[j, 1]) \
                    + (t_box[j, 5] - t_box[j, 2])
                split_base = 2.0 * sb > st
            if sp + 2 > stack.shape[0]:
                new = np.empty((2 * stack.shape[0], 2), dtype=np.int64)
                new[:sp] = stack[:sp]
                stack = new
            if split_base:
                stack[sp, 0] = b_int[i, 1]
                stack[sp, 1] = j
                stack[sp + 1, 0] = bl
                stack[sp + 1, 1] = j
            else:
                stack[sp, 0] = i
                stack[sp, 1] = t_int[j, 1]
                stack[sp + 1, 0] = i
                stack[sp + 1, 1] = tl
            sp += 2
            continue
        # leaf pair: base elements x target triangles
        bs = b_int[i, 2]
        be = bs + b_int[i, 3]
        ts = t_int[j, 2]
        te = ts + t_int[j, 3]
        if mode == 1 and nstamp[i] != cid:
            nstamp[i] = cid
            icount[0] += 1
            f = fc[i, 0]
            for a in range(3):
                lo = b_seg[i, a] - b_seg[i, 3 + a]
                hi = b_seg[i, a] + b_seg[i, 3 + a]
                if lo < nbox[f, a]:
                    nbox[f, a] = lo
                if hi > nbox[f, 3 + a]:
                    nbox[f, 3 + a] = hi
        for k in range(bs, be):
            if stamp[k] != cid:
                stamp[k] = cid
                px, py, pz = belem[k, 0], belem[k, 1], belem[k, 2]
                nx, ny, nz = belem[k, 3], belem[k, 4], belem[k, 5]
                line[k, 0] = r00 * px + r01 * py + r02 * pz + t0
                line[k, 1] = r10 * px + r11 * py + r12 * pz + t1
                line[k, 2] = r20 * px + r21 * py + r22 * pz + t2
                line[k, 3] = -(r00 * nx + r01 * ny + r02 * nz)
                line[k, 4] = -(r10 * nx + r11 * ny + r12 * nz)
                line[k, 5] = -(r20 * nx + r21 * ny + r22 * nz)
                best_u[k] = np.inf
                best_j[k] = -1
                line[k, 6] = np.inf
            ox, oy, oz = line[k, 0], line[k, 1], line[k, 2]
            dx, dy, dz = line[k, 3], line[k, 4], line[k, 5]
            # the line segment s in [-s_neg, L]
            ax, ay, az = ox - s_neg * dx, oy - s_neg * dy, oz - s_neg * dz
            bx, by, bz = ox + L * dx, oy + L * dy, oz + L * dz
            if mode == 0:
                if not _segment_vs_leaf(ax, ay, az, bx, by, bz, t_box, t_obb, j, 0.0):
                    continue
                for l in range(ts, te):
                    u = tri_hit(ox, oy, oz, dx, dy, dz, ttri, l, L, s_neg)
                    if u > 0.0 and u < best_u[k]:
                        if best_j[k] < 0:
                            active[n_out] = k
                            n_out += 1
                        best_u[k] = u
                        best_j[k] = l
                    elif u < 0.0:
                        e = tri_entry(ox, oy, oz, dx, dy, dz, ttri, l, L)
                        if e < line[k, 6]:
                            line[k, 6] = e
            else:
                if not _segment_vs_leaf(ax, ay, az, bx, by, bz, t_box, t_obb, j, delta):
                    continue
                for l in range(ts, te):
                    if tri_near(ax, ay, az, bx, by, bz, ttri, l, delta):
                        if n_out >= cap:
                            return -1
                        cand[n_out, 0] = k
                        cand[n_out, 1] = l
                        n_out += 1
    if mode == 0:
        # first-crossing rule: drop the elements whose line enters the target before the hit
        n_keep = 0
        for q in range(n_out):
            k = active[q]
            if best_u[k] < line[k, 6]:
                active[n_keep] = k
                n_keep += 1
            else:
                best_j[k] = -1
        n_out = n_keep
    return n_out


@njit(cache=True)
def search_pair(b_int, b_seg, b_obb, belem, t_int, t_box, t_obb, ttri, Rbt, tbt, L, s_neg,
                stamp, call, best_u, best_j, line, active, stack):
    """Exact contact search (dual-tree traversal + penetration lines). ``Rbt``, ``tbt``: pose of
    the base frame in the target frame (x_target = Rbt x_base + tbt). Returns the number of base
    elements with a hit; their slots are ``active[:n]``, penetration ``best_u[slot]``, target slot
    ``best_j[slot]``, line ``line[slot] = [p', d']`` (target frame; d' = inward base normal)."""
    dummy_c = np.empty((0, 2), dtype=np.int64)
    dummy_i = np.zeros(1, dtype=np.int64)
    return _traverse(0, b_int, b_seg, b_obb, belem, t_int, t_box, t_obb, ttri, Rbt, tbt, L,
                     s_neg, s_neg, 0.0, stamp, call, best_u, best_j, line, active,
                     stack, dummy_c, dummy_i, dummy_i, dummy_c, np.empty(0), np.empty((0, 6)))


@njit(cache=True)
def search_candidates(n_cand, cand, cand_tri, belem, L, s_neg, Rbt, tbt,
                      best_u, best_j, line, active):
    """Exact narrow phase over the cached candidate pairs (sorted by base slot, triangle data
    copied to ``cand_tri`` in the same order); same outputs as :func:`search_pair`."""
    r00, r01, r02 = Rbt[0, 0], Rbt[0, 1], Rbt[0, 2]
    r10, r11, r12 = Rbt[1, 0], Rbt[1, 1], Rbt[1, 2]
    r20, r21, r22 = Rbt[2, 0], Rbt[2, 1], Rbt[2, 2]
    t0, t1, t2 = tbt[0], tbt[1], tbt[2]
    n_active = 0
    q = 0
    while q < n_cand:
        k = cand[q, 0]
        px, py, pz = belem[k, 0], belem[k, 1], belem[k, 2]
        nx, ny, nz = belem[k, 3], belem[k, 4], belem[k, 5]
        ox = r00 * px + r01 * py + r02 * pz + t0
        oy = r10 * px + r11 * py + r12 * pz + t1
        oz = r20 * px + r21 * py + r22 * pz + t2
        dx = -(r00 * nx + r01 * ny + r02 * nz)
        dy = -(r10 * nx + r11 * ny + r12 * nz)
        dz = -(r20 * nx + r21 * ny + r22 * nz)
        best = np.inf
        bj = -1
        entry = np.inf
        while q < n_cand and cand[q, 0] == k:
            u = tri_hit(ox, oy, oz, dx, dy, dz, cand_tri, q, L, s_neg)
            if u > 0.0 and u < best:
                best = u
                bj = cand[q, 1]
            elif u < 0.0:
                e = tri_entry(ox, oy, oz, dx, dy, dz, cand_tri, q, L)
                if e < entry:
                    entry = e
            q += 1
        if bj >= 0 and best < entry:
            line[k, 0] = ox
            line[k, 1] = oy
            line[k, 2] = oz
            line[k, 3] = dx
            line[k, 4] = dy
            line[k, 5] = dz
            best_u[k] = best
            best_j[k] = bj
            active[n_active] = k
            n_active += 1
    return n_active


# cache state layout (float64 array of size N_CACHE)
C_VALID = 0        # 1.0 when the candidate list is valid
C_RREF = 1         # 9: Rbt at the build
C_TREF = 10        # 3: tbt at the build
C_NCAND = 13       # number of candidate pairs
C_BUILDS = 14      # statistics: number of builds
C_CALLS = 15       # statistics: number of calls served from the cache
C_OVERFLOW = 16    # statistics: builds that overflowed the candidate array
C_NNEAR = 17       # number of near base leaves at the last build
C_NCLOSE = 18      # number of far-check nodes checked individually
C_GFAR = 19        # distance bound of the other far-check nodes (checked with the root box)
C_SINCE = 20       # calls served since the last build
C_COOL = 21        # remaining calls of exact search after a too short reuse (adaptive fallback)
C_EXACT = 22       # statistics: calls served by the exact search during cool-downs
N_CACHE = 24
CACHE_MIN_REUSE = 8      # a list reused for fewer calls than this triggers a cool-down ...
CACHE_COOLDOWN = 64      # ... of this many exact-search calls before the next build


@njit(cache=True)
def _max_disp_box(dR, dt, obb, o, lo0, lo1, lo2, hi0, hi1, hi2, use_obb, grow):
    """Largest |dR x + dt| over a box (the maximum of a convex function is at a corner): the
    oriented box ``obb[o:o+15]`` (axes rows, centre, half) when ``use_obb``, else [lo, hi];
    half extents grown by ``grow``."""
    best = 0.0
    for c in range(8):
        if use_obb:
            s0 = 1.0 if (c & 1) else -1.0
            s1 = 1.0 if (c & 2) else -1.0
            s2 = 1.0 if (c & 4) else -1.0
            h0 = s0 * (obb[o + 12] + grow)
            h1 = s1 * (obb[o + 13] + grow)
            h2 = s2 * (obb[o + 14] + grow)
            x = obb[o + 9] + h0 * obb[o + 0] + h1 * obb[o + 3] + h2 * obb[o + 6]
            y = obb[o + 10] + h0 * obb[o + 1] + h1 * obb[o + 4] + h2 * obb[o + 7]
            z = obb[o + 11] + h0 * obb[o + 2] + h1 * obb[o + 5] + h2 * obb[o + 8]
        else:
            x = hi0 + grow if (c & 1) else lo0 - grow
            y = hi1 + grow if (c & 2) else lo1 - grow
            z = hi2 + grow if (c & 4) else lo2 - grow
        ex = dR[0, 0] * x + dR[0, 1] * y + dR[0, 2] * z + dt[0]
        ey = dR[1, 0] * x + dR[1, 1] * y + dR[1, 2] * z + dt[1]
        ez = dR[2, 0] * x + dR[2, 1] * y + dR[2, 2] * z + dt[2]
        d2 = ex * ex + ey * ey + ez * ez
        if d2 > best:
            best = d2
    return math.sqrt(best)


@njit(cache=True)
def _node_disp(dR, dt, b_seg, b_obb, i, grow, limit):
    """Bound of |dR x + dt| over base node i (axis-aligned box, then oriented box if needed)."""
    d = _max_disp_box(dR, dt, b_obb[i], 0, b_seg[i, 0] - b_seg[i, 3], b_seg[i, 1] - b_seg[i, 4],
                      b_seg[i, 2] - b_seg[i, 5], b_seg[i, 0] + b_seg[i, 3],
                      b_seg[i, 1] + b_seg[i, 4], b_seg[i, 2] + b_seg[i, 5], False, grow)
    if d < limit:
        return d
    return min(d, _max_disp_box(dR, dt, b_obb[i], 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, True, grow))


@njit(cache=True)
def cached_search(b_int, b_seg, b_obb, belem, t_int, t_box, t_obb, ttri, Rbt, tbt, L, s_neg,
                  delta, far, phi_tol, cache, cand, cand_tri, nstamp, icount, fnode, fc, minsep,
                  nbox, close, dR, dt, stamp, call, best_u, best_j, line, active, stack):
    """Exact contact search through a candidate cache (temporal coherence).

    Build (at the current pose): a traversal with node volumes grown by ``far`` finds the base
    leaves within ``far`` of the target ("near" leaves); for their elements every (element,
    triangle) pair whose penetration segment comes within ``delta`` of the triangle is stored
    (sorted by element, triangle data copied). Every other part of the base is proven farther from
    the target than a recorded distance, per far-check node f (a cut of the base tree, ~64 nodes):
    ``minsep[f]``. A later pose reuses the list when, relative to the target, (i) the near leaves
    of every far-check node moved by less than ``delta``, (ii) every far-check node moved by less
    than its ``minsep``, (iii) the relative rotation is below ``phi_tol`` (candidates keep targets
    facing within that angle); otherwise it rebuilds. The motion bounds are exact maxima over
    boxes (|dR x + dt| is convex in x). The result is identical to :func:`search_pair` (the same
    exact narrow phase on a superset of the hits). Adaptive fallback: when a list served fewer
    than CACHE_MIN_REUSE calls, the next CACHE_COOLDOWN calls use the exact search instead."""
    if cache[C_COOL] > 0.0:
        cache[C_COOL] -= 1.0
        cache[C_EXACT] += 1.0
        return search_pair(b_int, b_seg, b_obb, belem, t_int, t_box, t_obb, ttri, Rbt, tbt, L,
                           s_neg, stamp, call, best_u, best_j, line, active, stack)
    valid = cache[C_VALID] != 0.0
    if valid:
        tr = 0.0
        for r in range(3):
            for c in range(3):
                dR[r, c] = Rbt[r, c] - cache[C_RREF + 3 * r + c]
                tr += Rbt[r, c] * cache[C_RREF + 3 * r + c]
            dt[r] = tbt[r] - cache[C_TREF + r]
        if 0.5 * (tr - 1.0) < math.cos(phi_tol):
            valid = False
        if valid and cache[C_GFAR] < np.inf:
            if _node_disp(dR, dt, b_seg, b_obb, 0, s_neg, cache[C_GFAR]) >= cache[C_GFAR]:
                valid = False
        if valid:
            for q in range(int(cache[C_NCLOSE])):
                f = close[q]
                if nbox[f, 0] <= nbox[f, 3]:
                    d = _max_disp_box(dR, dt, cache, 0, nbox[f, 0], nbox[f, 1], nbox[f, 2],
                                      nbox[f, 3], nbox[f, 4], nbox[f, 5], False, s_neg)
                    if d >= delta:
                        valid = False
                        break
                if minsep[f] < np.inf:
                    if _node_disp(dR, dt, b_seg, b_obb, fnode[f], s_neg, minsep[f]) >= minsep[f]:
                        valid = False
                        break
    if not valid and cache[C_VALID] != 0.0 and cache[C_SINCE] < CACHE_MIN_REUSE:
        # the motion between calls is too large for the margins: exact search for a while
        cache[C_VALID] = 0.0
        cache[C_COOL] = CACHE_COOLDOWN - 1
        cache[C_EXACT] += 1.0
        return search_pair(b_int, b_seg, b_obb, belem, t_int, t_box, t_obb, ttri, Rbt, tbt, L,
                           s_neg, stamp, call, best_u, best_j, line, active, stack)
    if not valid:
        cache[C_SINCE] = 0.0
        nf = fnode.shape[0]
        for f in range(nf):
            minsep[f] = np.inf
            for a in range(3):
                nbox[f, a] = np.inf
                nbox[f, 3 + a] = -np.inf
        n = _traverse(1, b_int, b_seg, b_obb, belem, t_int, t_box, t_obb, ttri, Rbt, tbt, L,
                      s_neg, far + s_neg, delta, stamp, call,
                      best_u, best_j, line, active, stack, cand, nstamp, icount, fc, minsep, nbox)
        cache[C_BUILDS] += 1.0
        if n < 0:
            cache[C_VALID] = 0.0
            cache[C_OVERFLOW] += 1.0
            return search_pair(b_int, b_seg, b_obb, belem, t_int, t_box, t_obb, ttri, Rbt, tbt,
                               L, s_neg, stamp, call, best_u, best_j, line, active, stack)
        # sort the pairs by base slot (stable) and copy the triangle data in that order
        order = np.argsort(cand[:n, 0], kind="mergesort")
        tmp = cand[:n].copy()
        for q in range(n):
            cand[q, 0] = tmp[order[q], 0]
            cand[q, 1] = tmp[order[q], 1]
            l = cand[q, 1]
            for a in range(18):
                cand_tri[q, a] = ttri[l, a]
        cache[C_NNEAR] = icount[0]
        # far-check nodes checked one by one: those with near leaves or within 16 far; the
        # others together through the root box against the smallest of their distances
        nclose = 0
        gfar = np.inf
        for f in range(nf):
            if nbox[f, 0] <= nbox[f, 3] or minsep[f] < 16.0 * far:
                close[nclose] = f
                nclose += 1
            elif minsep[f] < gfar:
                gfar = minsep[f]
        cache[C_NCLOSE] = nclose
        cache[C_GFAR] = gfar
        cache[C_VALID] = 1.0
        for r in range(3):
            for c in range(3):
                cache[C_RREF + 3 * r + c] = Rbt[r, c]
            cache[C_TREF + r] = tbt[r]
        cache[C_NCAND] = n
    else:
        cache[C_CALLS] += 1.0
        cache[C_SINCE] += 1.0
    return search_candidates(int(cache[C_NCAND]), cand, cand_tri, belem, L, s_neg, Rbt, tbt,
                             best_u, best_j, line, active)


# ----------------------------------------------------------------------------------------------
# element force law
# ----------------------------------------------------------------------------------------------
@njit(cache=True)
def element_force(u, area, vn, vtx, vty, vtz, params):
    """Normal force, friction force on the target (vector) and dissipated power of one element.

    ``vn``: relative normal approach velocity (base minus target velocity along the base outward
    normal; > 0 approaching). ``vt*``: tangential part of the base-minus-target velocity.
    Returns ``(F_n, ftx, fty, ftz, P_diss)``; the friction force on the target is along +v_t (the
    base drags it), the one on the base opposite.
    """
    c = params[P_C]
    fel = c * area * u
    fn = fel
    pd = 0.0
    if params[P_DAMPING] != 0.0:
        d = params[P_CC] if vn > 0.0 else params[P_CE]
        td = params[P_TD]
        ramp = 1.0 if (td <= 0.0 or u >= td) else u / td
        fn = fel + d * area * vn * ramp
        if fn < 0.0:
            fn = 0.0
        pd = (fn - fel) * vn
    ftx = 0.0
    fty = 0.0
    ftz = 0.0
    if params[P_FRICTION] != 0.0 and fn > 0.0:
        vt = math.sqrt(vtx * vtx + vty * vty + vtz * vtz)
        if vt > 0.0:
            r = vt / params[P_VF]
            if r > 1.0:
                r = 1.0
            ft = params[P_MU] * fn * r
            ftx = ft * vtx / vt
            fty = ft * vty / vt
            ftz = ft * vtz / vt
            pd += ft * vt
    return fn, ftx, fty, ftz, pd


@njit(cache=True)
def pair_forces(n_active, active, best_u, best_j, line, belem, b_order, t_order,
                Rt, tt, tb, vb, wb, vt_, wt, params,
                e_base, e_target, e_u, e_point, e_normal, e_fn, e_ft, e_area,
                force_t, moment_t, diag):
    """Element and body forces for the generic pair. Inputs in the target frame (``line``) are
    mapped to the world with (Rt, tt). Velocities (v of the body origin, omega) in the world.
    Writes the per-element arrays (first n_active rows), the force on the target ``force_t`` and
    its moment about the world origin ``moment_t``, and ``diag`` (N_DIAG)."""
    ratio = params[P_RATIO]
    c = params[P_C]
    umax = params[P_UMAX]
    for a in range(3):
        force_t[a] = 0.0
        moment_t[a] = 0.0
    for a in range(N_DIAG):
        diag[a] = 0.0
    for q in range(n_active):
        k = active[q]
        u = best_u[k]
        area = belem[k, 6]
        # point and normal in the target frame
        xl = line[k, 0] + ratio * u * line[k, 3]
        yl = line[k, 1] + ratio * u * line[k, 4]
        zl = line[k, 2] + ratio * u * line[k, 5]
        nxl, nyl, nzl = -line[k, 3], -line[k, 4], -line[k, 5]
        x = Rt[0, 0] * xl + Rt[0, 1] * yl + Rt[0, 2] * zl + tt[0]
        y = Rt[1, 0] * xl + Rt[1, 1] * yl + Rt[1, 2] * zl + tt[1]
        z = Rt[2, 0] * xl + Rt[2, 1] * yl + Rt[2, 2] * zl + tt[2]
        nx = Rt[0, 0] * nxl + Rt[0, 1] * nyl + Rt[0, 2] * nzl
        ny = Rt[1, 0] * nxl + Rt[1, 1] * nyl + Rt[1, 2] * nzl
        nz = Rt[2, 0] * nxl + Rt[2, 1] * nyl + Rt[2, 2] * nzl
        # rigid-body velocities at the point
        rbx, rby, rbz = x - tb[0], y - tb[1], z - tb[2]
        rtx, rty, rtz = x - tt[0], y - tt[1], z - tt[2]
        vbx = vb[0] + wb[1] * rbz - wb[2] * rby
        vby = vb[1] + wb[2] * rbx - wb[0] * rbz
        vbz = vb[2] + wb[0] * rby - wb[1] * rbx
        vtx = vt_[0] + wt[1] * rtz - wt[2] * rty
        vty = vt_[1] + wt[2] * rtx - wt[0] * rtz
        vtz = vt_[2] + wt[0] * rty - wt[1] * rtx
        wx, wy, wz = vbx - vtx, vby - vty, vbz - vtz
        vn = wx * nx + wy * ny + wz * nz
        fn, ftx, fty, ftz, pd = element_force(u, area, vn, wx - vn * nx, wy - vn * ny,
                                              wz - vn * nz, params)
        fx = fn * nx + ftx
        fy = fn * ny + fty
        fz = fn * nz + ftz
        force_t[0] += fx
        force_t[1] += fy
        force_t[2] += fz
        moment_t[0] += y * fz - z * fy
        moment_t[1] += z * fx - x * fz
        moment_t[2] += x * fy - y * fx
        e_base[q] = b_order[k]
        e_target[q] = t_order[best_j[k]]
        e_u[q] = u
        e_point[q, 0] = x
        e_point[q, 1] = y
        e_point[q, 2] = z
        e_normal[q, 0] = nx
        e_normal[q, 1] = ny
        e_normal[q, 2] = nz
        e_fn[q] = fn
        e_ft[q, 0] = ftx
        e_ft[q, 1] = fty
        e_ft[q, 2] = ftz
        e_area[q] = area
        diag[D_N] += 1.0
        diag[D_AREA] += area
        if u > diag[D_UMAX]:
            diag[D_UMAX] = u
        diag[D_FN] += fn
        diag[D_EEL] += 0.5 * c * area * u * u
        diag[D_PDISS] += pd
    diag[D_PEAK_P] = c * diag[D_UMAX]
    if diag[D_UMAX] > umax:
        diag[D_STATUS] = 1.0


# ----------------------------------------------------------------------------------------------
# fixed-axis kernel (gear stage)
# ----------------------------------------------------------------------------------------------
@njit(cache=True)
def fixed_axis_eval(data, theta_base, theta_target, omega_base, omega_target, out):
    """Fixed-axis pair: pose = R0 @ Rz(theta), both axes through the world origin.

    ``data`` from :func:`gearcontact_fmu.contact.engine.make_fixed_axis_data`. Writes ``out``
    (mesh_model.OUT_* layout): out[0] torque on the base about its axis, out[1] torque on the target
    about its axis, out[2..8] diagnostics, out[9] status (1 = penetration beyond u_max).
    """
    (b_int, b_seg, b_obb, belem, b_order, t_int, t_box, t_obb, ttri, t_order, M, ab0, params,
     stamp, call, best_u, best_j, line, active, stack, Rbt, tbt, cache, cand, cand_tri, nstamp,
     icount, fnode, fc, minsep, nbox, close, dR, dt) = data
    # Rbt = Rz(-theta_t) M Rz(theta_b), M = R0_t^T R0_b
    cb = math.cos(theta_base)
    sb = math.sin(theta_base)
    ct = math.cos(theta_target)
    st = math.sin(theta_target)
    for r in range(3):
        m0 = M[r, 0]
        m1 = M[r, 1]
        Rbt[r, 0] = m0 * cb + m1 * sb
        Rbt[r, 1] = -m0 * sb + m1 * cb
        Rbt[r, 2] = M[r, 2]
    for col in range(3):
        x0 = Rbt[0, col]
        x1 = Rbt[1, col]
        Rbt[0, col] = ct * x0 + st * x1
        Rbt[1, col] = -st * x0 + ct * x1
    L = params[P_L]
    s_neg = params[P_SNEG]
    if params[P_DELTA] > 0.0:
        n = cached_search(b_int, b_seg, b_obb, belem, t_int, t_box, t_obb, ttri, Rbt, tbt, L,
                          s_neg, params[P_DELTA], params[P_FAR], params[P_PHI], cache, cand,
                          cand_tri, nstamp, icount, fnode, fc, minsep, nbox, close, dR, dt, stamp,
                          call, best_u, best_j, line, active, stack)
    else:
        n = search_pair(b_int, b_seg, b_obb, belem, t_int, t_box, t_obb, ttri, Rbt, tbt, L,
                        s_neg, stamp, call, best_u, best_j, line, active, stack)
    # base axis in the target frame: Rz(-theta_t) M e_z
    abx = ct * ab0[0] + st * ab0[1]
    aby = -st * ab0[0] + ct * ab0[1]
    abz = ab0[2]
    wbx, wby, wbz = omega_base * abx, omega_base * aby, omega_base * abz
    ratio = params[P_RATIO]
    c = params[P_C]
    mtz = 0.0          # moment on the target about its axis (target-frame z)
    mbx = 0.0          # moment on the target (x' x F) components for the base-axis projection
    mby = 0.0
    area_sum = 0.0
    umax_found = 0.0
    fn_sum = 0.0
    eel = 0.0
    pdiss = 0.0
    for q in range(n):
        k = active[q]
        u = best_u[k]
        area = belem[k, 6]
        dx, dy, dz = line[k, 3], line[k, 4], line[k, 5]
        x = line[k, 0] + ratio * u * dx
        y = line[k, 1] + ratio * u * dy
        z = line[k, 2] + ratio * u * dz
        nx, ny, nz = -dx, -dy, -dz
        # v_base - v_target at x (target frame): w_b x r - omega_t e_z x r
        vx = wby * z - wbz * y + omega_target * y
        vy = wbz * x - wbx * z - omega_target * x
        vz = wbx * y - wby * x
        vn = vx * nx + vy * ny + vz * nz
        fn, ftx, fty, ftz, pd = element_force(u, area, vn, vx - vn * nx, vy - vn * ny,
                                              vz - vn * nz, params)
        fx = fn * nx + ftx
        fy = fn * ny + fty
        fz = fn * nz + ftz
        mx = y * fz - z * fy
        my = z * fx - x * fz
        mz = x * fy - y * fx
        mtz += mz
        mbx += mx
        mby += my
        area_sum += area
        if u > umax_found:
            umax_found = u
        fn_sum += fn
        eel += 0.5 * c * area * u * u
        pdiss += pd
    out[0] = -(abx * mbx + aby * mby + abz * mtz)
    out[1] = mtz
    out[2] = n
    out[3] = area_sum
    out[4] = c * umax_found
    out[5] = umax_found
    out[6] = fn_sum
    out[7] = eel
    out[8] = pdiss
    out[9] = 1.0 if umax_found > params[P_UMAX] else 0.0
