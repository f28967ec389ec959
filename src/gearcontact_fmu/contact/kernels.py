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
  int64 candidate pairs (base slot, target slot) sorted by base slot; ``nstamp`` (N_base_nodes,) int64, ``icount`` (1,) int64; far-check
  nodes of the base tree ``fnode`` (F,) int64 and ``fc`` (N_base_nodes, 2) int64 (range of
  far-check nodes under each node); ``minsep`` (F,), ``nbox`` (F, 6), ``close`` (F,) int64;
  ``dR`` (3, 3), ``dt`` (3,) scratch; clearances (:func:`candidate_clearances`) ``cand_c``,
  ``cand_s``, ``cand_d``, ``cand_h`` (C,), ``cand_g``, ``cand_f`` (C,) int64, ``ndisp`` (F + 1,)
  motion bounds of the far-check nodes' near leaves (last: bound of the line directions' change),
  ``slot_f`` (m_base,) int64 far-check node of each base slot; skip thresholds
  (:func:`search_candidates_skip`) ``cand_x`` (C,) per pair, ``elem_q`` (C,) int64 first pair,
  ``elem_x`` (C,) threshold and ``elem_hit`` (C,) bool per element of the list.
* pitch atlas (fixed-axis kernel, see :func:`cached_search`): ``period`` (4,) = (base pitch angle,
  base triangles per tooth, target pitch angle, target triangles per tooth), zeros when off;
  ``b_inv``/``t_inv`` inverse slot orders; ``Rc`` (3, 3) scratch; snapshots ``atlas_meta`` (S,
  N_SNAP) (see ``S_*``), pool ``atlas_pairs`` (P, 2) int32 (slots at the build),
  ``atlas_c``/``atlas_s``/``atlas_d``/``atlas_h``/``atlas_x`` (P,) float32 (rounded to the safe
  side; ``atlas_x`` the pair's skip allowance for a turn up to R_SNAP + R_LIFE),
  ``atlas_minsep`` (S, F), ``atlas_nbox`` (S, F, 6), ``atlas_close`` (S, F) int64.
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

# kernel data: named tuples declared in records.py (see there why)
from gearcontact_fmu.contact.records import Collect, ListBounds

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
SKIP_COS = 0.87     # the plane clearance of a candidate counts only if n_exact . n_facet >= this
SKIP_EPS = 1e-12    # [m] rounding allowance of the clearance skips (see candidate_clearances)


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
@njit(cache=True, nogil=True)
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
@njit(cache=True, inline="always")
def _obb_overlap(b_obb, i, t_obb, j, rt, infl):
    """Separating-axis test of base node i (its oriented box mapped by (R, t) into the target
    frame, half extents grown by ``infl``) and target node j on the 6 face axes of the two boxes
    (conservative: True may be a false overlap, False proves a distance > infl). ``rt`` = (r00,
    r01, r02, r10, ..., r22, t0, t1, t2): the pose as a tuple of 12 scalars (numba passes it as
    12 registers, as loose arguments)."""
    return _obb_gap(b_obb, i, t_obb, j, rt, infl) <= 0.0


@njit(cache=True, inline="always")
def _obb_gap(b_obb, i, t_obb, j, rt, infl):
    """Largest separation of the two oriented boxes over the 6 face axes (> 0: separated, and the
    distance between the boxes is larger than this + infl). See :func:`_obb_overlap`."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22, t0, t1, t2 = rt
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


@njit(cache=True, inline="always")
def _descend(stack, sp, i, j, bl, tl, b_int, t_int, t_box, sb):
    """Push the children of the node pair (i, j) (base i's children ``bl``/``b_int[i, 1]``, target
    j's ``tl``/``t_int[j, 1]``): the base if the target is a leaf, else the larger box (``sb`` the
    base box's half extents summed). Returns the stack (grown when full) and its new top."""
    split_base = False
    if tl < 0:
        split_base = True
    elif bl >= 0:
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
    return stack, sp + 2


@njit(cache=True, inline="always")
def _near_leaf(col, i, b_seg, cid):
    """Mode 1 of :func:`_traverse`: base leaf i is near (first time this call): counted, and its
    segment box added to the near box of its far-check node."""
    if col.nstamp[i] != cid:
        col.nstamp[i] = cid
        col.icount[0] += 1
        nbox = col.nbox
        f = col.fc[i, 0]
        for a in range(3):
            lo = b_seg[i, a] - b_seg[i, 3 + a]
            hi = b_seg[i, a] + b_seg[i, 3 + a]
            if lo < nbox[f, a]:
                nbox[f, a] = lo
            if hi > nbox[f, 3 + a]:
                nbox[f, 3 + a] = hi


@njit(cache=True, inline="always")
def _first_crossing(n_out, active, best_u, best_j, line):
    """First-crossing rule: drop the elements whose line enters the target before the hit.
    Returns the number kept (``active[:n]``)."""
    n_keep = 0
    for q in range(n_out):
        k = active[q]
        if best_u[k] < line[k, 6]:
            active[n_keep] = k
            n_keep += 1
        else:
            best_j[k] = -1
    return n_keep


# Arguments that select a branch are passed as these typed values, not as literals: numba compiles a
# kernel once per distinct literal argument it is called with (``_traverse(0, ...)`` and ``_traverse(1,
# ...)`` were two compilations of the largest kernel), and once for one typed value.
_EXACT = np.int64(0)        # _traverse: exact search
_COLLECT = np.int64(1)      # _traverse: candidate collection for the cache
_ROOT = np.int64(0)         # the root node of a tree
_AABB = np.bool_(False)     # _max_disp_box: the axis-aligned box
_OBB = np.bool_(True)       # _max_disp_box: the oriented box


@njit(cache=True)
def _traverse(mode, bm, tm, Rbt, tbt, L, s_neg, infl, delta, ws, col):
    """Dual-tree traversal of base ``bm`` and target ``tm`` (:class:`BaseMesh`,
    :class:`TargetMesh`). mode 0: exact search (fills the base workspace ``ws``, returns the
    number of base elements with a hit). mode 1: candidate collection for the cache (pairs (base
    slot, target slot) into ``col.cand``; returns the number of pairs, or -1 when it overflows).
    Node volumes are grown by ``infl``. Mode 1 also records, per far-check node f of the base
    (``col.fc[i] = [f_lo, f_hi)`` the far-check nodes under base node i), a lower bound of the
    distance of its non-near elements to the target (``col.minsep[f]``) and the box of its near
    leaves (``col.nbox[f] = [lo, hi]``, base frame); ``col.icount[0]`` = number of near leaves.

    Long kernel: the node-pair loop keeps the pose's 21 scalars and the stack top in registers;
    its box tests, leaf loop and narrow phase share them, so they stay in one function (the
    descent and the bookkeeping are helpers)."""
    b_int, b_seg, b_obb, belem = bm.node_int, bm.seg, bm.obb, bm.elem
    t_int, t_box, t_obb, ttri = tm.node_int, tm.box, tm.obb, tm.tri
    stamp, call, best_u, best_j = ws.stamp, ws.call, ws.best_u, ws.best_j
    line, active, stack = ws.line, ws.active, ws.stack
    cand, fc, minsep = col.cand, col.fc, col.minsep
    call[0] += 1
    cid = call[0]
    r00, r01, r02 = Rbt[0, 0], Rbt[0, 1], Rbt[0, 2]
    r10, r11, r12 = Rbt[1, 0], Rbt[1, 1], Rbt[1, 2]
    r20, r21, r22 = Rbt[2, 0], Rbt[2, 1], Rbt[2, 2]
    a00, a01, a02 = abs(r00), abs(r01), abs(r02)
    a10, a11, a12 = abs(r10), abs(r11), abs(r12)
    a20, a21, a22 = abs(r20), abs(r21), abs(r22)
    t0, t1, t2 = tbt[0], tbt[1], tbt[2]
    rt = (r00, r01, r02, r10, r11, r12, r20, r21, r22, t0, t1, t2)
    n_out = 0
    cap = cand.shape[0]
    col.icount[0] = 0
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
            if not _obb_overlap(b_obb, i, t_obb, j, rt, infl):
                continue
        else:
            g = max(cx - ex - t_box[j, 3], t_box[j, 0] - cx - ex,
                    cy - ey - t_box[j, 4], t_box[j, 1] - cy - ey,
                    cz - ez - t_box[j, 5], t_box[j, 2] - cz - ez)
            if g <= 0.0:
                g = _obb_gap(b_obb, i, t_obb, j, rt, infl)
            if g > 0.0:
                dist = g + infl
                for f in range(fc[i, 0], fc[i, 1]):
                    if dist < minsep[f]:
                        minsep[f] = dist
                continue
        bl = b_int[i, 0]
        tl = t_int[j, 0]
        if bl >= 0 or tl >= 0:
            stack, sp = _descend(stack, sp, i, j, bl, tl, b_int, t_int, t_box, ex + ey + ez)
            continue
        # leaf pair: base elements x target triangles
        bs = b_int[i, 2]
        be = bs + b_int[i, 3]
        ts = t_int[j, 2]
        te = ts + t_int[j, 3]
        if mode == 1:
            _near_leaf(col, i, b_seg, cid)
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
        n_out = _first_crossing(n_out, active, best_u, best_j, line)
    return n_out


@njit(cache=True)
def search_pair(bm, tm, Rbt, tbt, L, s_neg, ws):
    """Exact contact search (dual-tree traversal + penetration lines) of base ``bm`` against
    target ``tm`` (:class:`BaseMesh`, :class:`TargetMesh`; ``ws`` a :class:`Workspace` of the
    base). ``Rbt``, ``tbt``: pose of the base frame in the target frame (x_target = Rbt x_base +
    tbt). Returns the number of base elements with a hit; their slots are ``ws.active[:n]``,
    penetration ``ws.best_u[slot]``, target slot ``ws.best_j[slot]``, line ``ws.line[slot] = [p',
    d']`` (target frame; d' = inward base normal)."""
    dummy_c = np.empty((0, 2), dtype=np.int64)
    dummy_i = np.zeros(1, dtype=np.int64)
    col = Collect(dummy_c, dummy_i, dummy_i, dummy_c, np.empty(0), np.empty((0, 6)))
    return _traverse(_EXACT, bm, tm, Rbt, tbt, L, s_neg, s_neg, 0.0, ws, col)


@njit(cache=True)
def edge_clearance(ox, oy, oz, dx, dy, dz, ttri, l):
    """(c, s0, den) of the line o + s d and triangle slot l (first vertex v, facet normal n_g, dual
    edge vectors g1, g2): den = d.n_g, the line meets the plane at s0 = (v - o).n_g / den, and c
    is how far outside the triangle (in its plane, by the inside test's three edge functions
    beta, gamma, 1 - beta - gamma, each over its gradient's length) it meets it; c = -inf (and
    s0 = 0) when the line is nearly parallel to the plane (|den| <= 1e-3)."""
    ngx, ngy, ngz = ttri[l, 3], ttri[l, 4], ttri[l, 5]
    den = dx * ngx + dy * ngy + dz * ngz
    if not abs(den) > 1e-3:
        return -np.inf, 0.0, den
    vx, vy, vz = ttri[l, 0], ttri[l, 1], ttri[l, 2]
    s0 = ((vx - ox) * ngx + (vy - oy) * ngy + (vz - oz) * ngz) / den
    wx = ox + s0 * dx - vx
    wy = oy + s0 * dy - vy
    wz = oz + s0 * dz - vz
    g1x, g1y, g1z = ttri[l, 6], ttri[l, 7], ttri[l, 8]
    g2x, g2y, g2z = ttri[l, 9], ttri[l, 10], ttri[l, 11]
    beta = wx * g1x + wy * g1y + wz * g1z
    gamma = wx * g2x + wy * g2y + wz * g2z
    ng1 = math.sqrt(g1x * g1x + g1y * g1y + g1z * g1z)
    ng2 = math.sqrt(g2x * g2x + g2y * g2y + g2z * g2z)
    sx, sy, sz = g1x + g2x, g1y + g2y, g1z + g2z
    ns = math.sqrt(sx * sx + sy * sy + sz * sz)
    if not (ng1 > 0.0 and ng2 > 0.0 and ns > 0.0):
        return -np.inf, s0, den
    return max((-BARY_EPS - beta) / ng1, (-BARY_EPS - gamma) / ng2,
               (beta + gamma - 1.0 - BARY_EPS) / ns), s0, den


@njit(cache=True)
def candidate_clearances(n, cands, ttri, belem, slot_f, Rbt, tbt, s_neg):
    """Clearances of the candidate pairs ``cand[:n]`` (``cands``, :class:`Candidates`; sorted by
    base slot) at the current pose, for :func:`search_candidates_skip`. Per pair (k, l), with the line o + s d of element k and
    triangle l (first vertex v, facet normal n_g, dual edge vectors g1, g2):

    * edge clearance ``cand_c[q]``: how far outside the triangle (in its plane, by the inside
      test's three edge functions beta, gamma, 1 - beta - gamma, each over its gradient's length)
      the line meets the plane, at s0 = (v - o).n_g / den, den = d.n_g; ``cand_s[q]`` = |s0|,
      ``cand_d[q]`` = |den| (-inf / 0 when the line is nearly parallel to the plane). If later o
      moved by at most D and d by at most rho (|den| - rho > DOT_EPS, so den keeps its sign), the
      meeting point q = o + s d moved by at most (D + |s0| rho)(1 + (t + rho)/(|den| - rho)),
      t = sqrt(1 - den^2) the in-plane part of d (q' - q = do + s0 dd + (s' - s) d', with
      |s' - s| <= (D + |s0| rho)/|den'| from the plane equation and |d'_in-plane| <= t + rho);
      while that is below cand_c the inside test fails: the pair gives neither a hit nor an entry.
    * element clearance ``cand_h[q]`` at the first pair of each element: the smallest over its
      pairs of (a - v).n_g, a = o - s_neg d the start of the segment, or -inf when a pair's exact
      normal is more than ~30 deg from its facet normal (n_e.n_g < SKIP_COS). A hit needs
      d.n_e >= FACING_COS, hence d.n_g > 0, and s >= -s_neg, i.e. (v - a).n_g >= 0; so while the
      segment moved by less than cand_h the element has no hit (its entries then do not matter).
    * ``cand_g[q]`` the number of pairs of the element and ``cand_f[q]`` its far-check node
      (whose motion bound applies), at the element's first pair."""
    cand, cand_c, cand_s, cand_d = cands.pairs, cands.c, cands.s, cands.d
    cand_h, cand_g, cand_f = cands.h, cands.g, cands.f
    r00, r01, r02 = Rbt[0, 0], Rbt[0, 1], Rbt[0, 2]
    r10, r11, r12 = Rbt[1, 0], Rbt[1, 1], Rbt[1, 2]
    r20, r21, r22 = Rbt[2, 0], Rbt[2, 1], Rbt[2, 2]
    t0, t1, t2 = tbt[0], tbt[1], tbt[2]
    q = 0
    while q < n:
        k = cand[q, 0]
        px, py, pz = belem[k, 0], belem[k, 1], belem[k, 2]
        nx, ny, nz = belem[k, 3], belem[k, 4], belem[k, 5]
        ox = r00 * px + r01 * py + r02 * pz + t0
        oy = r10 * px + r11 * py + r12 * pz + t1
        oz = r20 * px + r21 * py + r22 * pz + t2
        dx = -(r00 * nx + r01 * ny + r02 * nz)
        dy = -(r10 * nx + r11 * ny + r12 * nz)
        dz = -(r20 * nx + r21 * ny + r22 * nz)
        ax, ay, az = ox - s_neg * dx, oy - s_neg * dy, oz - s_neg * dz
        h = np.inf
        q1 = q
        while q1 < n and cand[q1, 0] == k:
            l = cand[q1, 1]
            vx, vy, vz = ttri[l, 0], ttri[l, 1], ttri[l, 2]
            ngx, ngy, ngz = ttri[l, 3], ttri[l, 4], ttri[l, 5]
            c, s0, den = edge_clearance(ox, oy, oz, dx, dy, dz, ttri, l)
            cand_c[q1] = c
            cand_s[q1] = abs(s0)
            cand_d[q1] = abs(den) if c > -np.inf else 0.0
            e = -np.inf
            if ngx * ttri[l, 15] + ngy * ttri[l, 16] + ngz * ttri[l, 17] >= SKIP_COS:
                e = (ax - vx) * ngx + (ay - vy) * ngy + (az - vz) * ngz
            if e < h:
                h = e
            q1 += 1
        cand_h[q] = h
        cand_g[q] = q1 - q
        cand_f[q] = slot_f[k]
        q = q1


R_LIFE = 2.5e-3     # [rad] largest turn of the line directions (|dR|_F summed over the calls) for
                    # which the skip thresholds hold; beyond it they are set again (init_thresholds)
REANCHOR_LIFE = 8.0  # lists that live this many calls (on average, or this one so far) re-anchor
                     # the thresholds of the pairs they test
R_SNAP = 2e-3       # [rad] turn between a kept list's pose and the pose it is served at, up to
                    # which its stored allowances (atlas_x) apply; beyond, they are computed


@njit(cache=True)
def _allowance(c, s0, den, r):
    """Largest motion D of a segment for which a pair with edge clearance ``c`` (line meeting the
    plane at |s0|, |den| = |d.n_g|, see :func:`candidate_clearances`) stays outside its triangle
    while the line directions turn by at most ``r``: (D + |s0| r)(1 + (t + r)/(|den| - r)) < c,
    t = sqrt(1 - den^2); -inf when none (den may change sign, or no clearance)."""
    dd = den - r
    if not (dd > DOT_EPS and c > -np.inf):
        return -np.inf
    return c / (1.0 + (math.sqrt(max(0.0, 1.0 - den * den)) + r) / dd) - s0 * r


@njit(cache=True)
def _retest_threshold(ox, oy, oz, dx, dy, dz, ttri, l, sum_d):
    """Skip threshold of a pair tested at this pose without a hit: the pair cannot hit or enter
    while the running motion sum stays below it (:func:`search_candidates_skip`). The larger of
    two allowances from this pose: the edge clearance (:func:`_allowance`, with R_LIFE), and the
    gap (o - v_e).n_e by which the origin stands in front of the element's exact tangent plane
    (point v_e, normal n_e; fixed in the target frame) when the line meets the plane from the
    front with a margin of R_LIFE: while o moved by less, u = (v_e - o).n_e / (d.n_e) is not
    positive (or d.n_e < FACING_COS): no hit; and den keeps its sign: no entry."""
    c, s0, den = edge_clearance(ox, oy, oz, dx, dy, dz, ttri, l)
    w = _allowance(c, abs(s0), abs(den), R_LIFE)
    if den - R_LIFE > DOT_EPS:
        gap = ((ox - ttri[l, 12]) * ttri[l, 15] + (oy - ttri[l, 13]) * ttri[l, 16]
               + (oz - ttri[l, 14]) * ttri[l, 17])
        if gap > w:
            w = gap
    return sum_d + w


@njit(cache=True)
def init_thresholds(n_cand, cands, ndisp, fresh):
    """Skip thresholds of a list just set (``cands``, :class:`Candidates`) (built at this pose, ``fresh``, or served from the atlas):
    per pair ``cand_x[q]``, per element ``elem_x[i]`` (its first pair ``elem_q[i]``, in base-slot
    order), in units of the running motion sum, which starts at 0 (:func:`search_candidates_skip`).
    From the list's clearances at its own pose (:func:`candidate_clearances`): the allowance less
    the motion since that pose (``ndisp[f]`` for the near leaves of far-check node f, the turn
    ``ndisp[-1]``; 0 when fresh). Returns the number of elements."""
    cand_c, cand_s, cand_d, cand_h = cands.c, cands.s, cands.d, cands.h
    cand_g, cand_f, cand_x = cands.g, cands.f, cands.x
    elem_q, elem_x, elem_hit = cands.elem_q, cands.elem_x, cands.elem_hit
    r = R_LIFE if fresh else ndisp[ndisp.shape[0] - 1] + R_LIFE
    ne = 0
    q = 0
    while q < n_cand:
        g = cand_g[q]
        d0 = 0.0 if fresh else ndisp[cand_f[q]]
        xm = np.inf
        for q1 in range(q, q + g):
            x = _allowance(cand_c[q1], cand_s[q1], cand_d[q1], r) - d0
            cand_x[q1] = x
            if x < xm:
                xm = x
        elem_q[ne] = q
        elem_x[ne] = max(cand_h[q] - d0, xm)
        elem_hit[ne] = False
        ne += 1
        q += g
    return ne


@njit(cache=True, inline="always")
def _pair_clear(c, s0, den, dref, rho):
    """The second chance of :func:`search_candidates_skip`: True when a pair's own clearances at
    its list's pose (edge clearance ``c``, |s0|, |den|) exceed the motion since (``dref``, the
    turn ``rho``): its line still meets the plane outside the triangle (see
    :func:`candidate_clearances`)."""
    dd = den - rho
    return dd > DOT_EPS and c > (dref + s0 * rho) * (
        1.0 + (math.sqrt(max(0.0, 1.0 - den * den)) + rho) / dd)


@njit(cache=True, inline="always")
def _plane_clearance(h, ttri, l, ax, ay, az):
    """The element clearance ``h`` so far, lowered to the segment start a's height over triangle
    l's plane, or -inf when l's exact normal is more than ~30 deg from its facet normal (see
    :func:`candidate_clearances`)."""
    ngx, ngy, ngz = ttri[l, 3], ttri[l, 4], ttri[l, 5]
    if ngx * ttri[l, 15] + ngy * ttri[l, 16] + ngz * ttri[l, 17] >= SKIP_COS:
        e = ((ax - ttri[l, 0]) * ngx + (ay - ttri[l, 1]) * ngy
             + (az - ttri[l, 2]) * ngz)
        if e < h:
            h = e
        return h
    return -np.inf


@njit(cache=True, inline="always")
def _set_hit(ws, k, ox, oy, oz, dx, dy, dz, u, j):
    """Base slot k hits target slot j at penetration u along the line o + s d (target frame):
    written to the workspace ``ws`` as :func:`search_pair` does (not yet listed as active)."""
    line = ws.line
    line[k, 0] = ox
    line[k, 1] = oy
    line[k, 2] = oz
    line[k, 3] = dx
    line[k, 4] = dy
    line[k, 5] = dz
    ws.best_u[k] = u
    ws.best_j[k] = j


@njit(cache=True)
def search_candidates_skip(n_elem, cands, far, reanchor, rho, belem, ttri, L, s_neg, ps, ws,
                           stats):
    """Exact narrow phase over the cached candidate pairs ``cands`` (:class:`Candidates`, sorted
    by base slot; same outputs in ``ws`` as :func:`search_pair`), skipping what cannot hit or enter (the criteria below, and as a second
    chance for what they do not skip, the list's own clearances ``cand_c``, ``cand_s``,
    ``cand_d``, ``cand_h`` against the motion since the list's pose, ``nd0[f]`` at the sums'
    start + ``nsum[f]`` (``far``, :class:`FarCheck`), and the turn since it, ``rho``). ``nsum[f]`` is the running sum of the
    per-call motion bounds of far-check node f's near leaves since the list was set
    (:func:`_advance_motion`): by the triangle inequality the motion between two calls is at most
    the difference of their sums. Every element and pair carries a threshold in these units (the
    sum of its element's node ``cand_f``): while the sum + SKIP_EPS stays below it the pair
    cannot hit or enter, and below the element's threshold none of its pairs can, or its segment
    cannot reach any plane it could hit (element clearance, :func:`candidate_clearances`). A
    skipped element or pair would give no hit and no entry: the result is the same, bit for bit.

    With ``reanchor`` (running sums) the thresholds follow the run: a pair tested without a hit
    gets a new one from its clearances at this pose (:func:`_retest_threshold`), a pair with a
    hit -inf (tested again next call), and a visited element the larger of its clearance at
    this pose (skipped when it had a hit at its last visit: then it is <= 0) and its pairs'
    smallest threshold. Without (direct bounds, for lists that live too few calls to use new
    thresholds; a difference of direct bounds bounds no motion) a tested pair keeps its
    threshold, a hit gets -inf, and an element its pairs' smallest. So along a trajectory a pair
    is tested again only when the motion since its last test could have closed its gap: a call costs about the elements in contact and
    their near neighbours, not the list's size or age. ``stats`` (4,): elements skipped, pairs
    tested, thresholds re-anchored, elements visited."""
    elem_q, elem_x, elem_hit, cand = cands.elem_q, cands.elem_x, cands.elem_hit, cands.pairs
    cand_c, cand_s, cand_d, cand_h = cands.c, cands.s, cands.d, cands.h
    cand_g, cand_f, cand_x = cands.g, cands.f, cands.x
    nsum, nd0, Rbt, tbt, active = far.nsum, far.nd0, ps.Rbt, ps.tbt, ws.active

    r00, r01, r02 = Rbt[0, 0], Rbt[0, 1], Rbt[0, 2]
    r10, r11, r12 = Rbt[1, 0], Rbt[1, 1], Rbt[1, 2]
    r20, r21, r22 = Rbt[2, 0], Rbt[2, 1], Rbt[2, 2]
    t0, t1, t2 = tbt[0], tbt[1], tbt[2]
    n_active = 0
    n_skip = 0
    n_test = 0
    for i in range(n_elem):
        q = elem_q[i]
        f = cand_f[q]
        sum_d = nsum[f]
        now = sum_d + SKIP_EPS
        if now < elem_x[i]:
            n_skip += 1
            continue
        # second chance: the list's own clearances against the motion since its pose (the bound
        # at the sums' start plus the sum), with the turn since it (the thresholds assume more)
        dref = nd0[f] + sum_d + SKIP_EPS
        if cand_h[q] > dref:
            n_skip += 1
            continue
        k = cand[q, 0]
        px, py, pz = belem[k, 0], belem[k, 1], belem[k, 2]
        nx, ny, nz = belem[k, 3], belem[k, 4], belem[k, 5]
        ox = r00 * px + r01 * py + r02 * pz + t0
        oy = r10 * px + r11 * py + r12 * pz + t1
        oz = r20 * px + r21 * py + r22 * pz + t2
        dx = -(r00 * nx + r01 * ny + r02 * nz)
        dy = -(r10 * nx + r11 * ny + r12 * nz)
        dz = -(r20 * nx + r21 * ny + r22 * nz)
        ax, ay, az = ox - s_neg * dx, oy - s_neg * dy, oz - s_neg * dz
        best = np.inf
        bj = -1
        entry = np.inf
        # element clearance at this pose, unless the element had a hit at its last visit (then it
        # is <= 0: the hit pair's plane is behind the segment start, or its normals disagree)
        h = -np.inf if (elem_hit[i] or not reanchor) else np.inf
        xm = np.inf
        qe = q + cand_g[q]
        while q < qe:
            l = cand[q, 1]
            if h > -np.inf:
                h = _plane_clearance(h, ttri, l, ax, ay, az)
            if now < cand_x[q]:
                if cand_x[q] < xm:
                    xm = cand_x[q]
                q += 1
                continue
            if _pair_clear(cand_c[q], cand_s[q], cand_d[q], dref, rho):
                if cand_x[q] < xm:
                    xm = cand_x[q]
                q += 1
                continue
            n_test += 1
            u = tri_hit(ox, oy, oz, dx, dy, dz, ttri, l, L, s_neg)
            x = -np.inf
            if u > 0.0:
                if u < best:
                    best = u
                    bj = l
            else:
                e = tri_entry(ox, oy, oz, dx, dy, dz, ttri, l, L)
                if e < entry:
                    entry = e
                # a threshold from this pose, or the one the pair had (still valid)
                if reanchor:
                    x = _retest_threshold(ox, oy, oz, dx, dy, dz, ttri, l, sum_d)
                    stats[2] += 1
                else:
                    x = cand_x[q]
            cand_x[q] = x
            if x < xm:
                xm = x
            q += 1
        elem_x[i] = max(sum_d + h, xm) if reanchor else xm
        elem_hit[i] = bj >= 0
        stats[3] += 1
        if bj >= 0 and best < entry:
            _set_hit(ws, k, ox, oy, oz, dx, dy, dz, best, bj)
            active[n_active] = k
            n_active += 1
    stats[0] = n_skip
    stats[1] = n_test
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
C_SKIPPED = 24     # statistics: elements skipped by their clearance (last call)
C_TESTED = 25      # statistics: candidate pairs tested (last call)
C_NSNAP = 26       # pitch atlas: number of snapshots
C_ATOP = 27        # pitch atlas: end of the used part of the pair pool
C_DB = 28          # base pitches between the current pose and the pose of the list in use
C_DT = 29          # target pitches, likewise
C_AHITS = 30       # statistics: lists served from the atlas
C_ACLEAR = 31      # statistics: times the atlas was full and emptied
C_SUMD = 32        # largest bound of a list's near-leaf motion since its pose (nd0[f] + nsum[f])
C_SUMR = 33        # running sum of the per-call bounds of the line directions' turn
C_PREV = 34        # 12: the pose (R, t; shifted by the list's pitches) of the previous call
C_NELEM = 46       # elements of the list (search_candidates_skip)
C_SUMROOT = 47     # running sum of the per-call motion bounds of the whole base
C_R0 = 48          # bound of the turn since the list's pose when the sums started
C_ROOT0 = 49       # bound of the whole base's motion since the list's pose when the sums started
C_SEP0 = 50        # smallest distance the list's far checks allow (minsep of its close nodes, gfar)
C_RETESTS = 51     # statistics: thresholds computed at the pose (last call)
C_VISITED = 52     # statistics: elements visited (last call)
C_LIFE = 53        # calls a list serves, exponential average over the lists set
C_TESTED_ALL = 54  # statistics: candidate pairs tested, all calls
C_RETESTS_ALL = 55  # statistics: thresholds re-anchored, all calls
C_SUMS = 56        # 1.0: the list keeps running sums and re-anchors; 0.0: direct bounds (short lives)
N_CACHE = 57
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
                      b_seg[i, 1] + b_seg[i, 4], b_seg[i, 2] + b_seg[i, 5], _AABB, grow)
    if d < limit:
        return d
    return min(d, _max_disp_box(dR, dt, b_obb[i], 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, _OBB, grow))


# snapshot metadata layout of the pitch atlas (float64 rows of size N_SNAP)
S_THB = 0          # base angle of the build
S_THT = 1          # target angle of the build
S_RREF = 2         # 9: Rbt at the build
S_TREF = 11        # 3: tbt at the build
S_NCLOSE = 14
S_GFAR = 15
S_NNEAR = 16
S_START = 17       # first pair in the atlas pool
S_N = 18           # number of pairs
N_SNAP = 20
ATLAS_EPS = 1e-12  # [m] allowance for the congruence of the teeth (measured ~1e-16 m, checked <= 1e-13)
ATLAS_TRIES = 4    # snapshots checked per lookup (nearest in the two angles first) ...
ATLAS_NEAR = 0.01  # [rad] ... among those within this sum of the two angles' differences
ATLAS_BUILD_EVERY = 2  # during a cool-down with an atlas, every 2nd call builds and keeps a list


@njit(cache=True)
def _f32_down(x):
    """A float32 not above x (clearances are stored in float32: rounding must not raise them)."""
    if not (abs(x) < 1e30):
        return np.float32(x)
    return np.float32(x - abs(x) * 1e-6 - 1e-15)


@njit(cache=True)
def _rbt_of(M, theta_b, theta_t, R):
    """R = Rz(-theta_t) M Rz(theta_b): the base's pose in the target's frame (fixed axes)."""
    cb = math.cos(theta_b)
    sb = math.sin(theta_b)
    ct = math.cos(theta_t)
    st = math.sin(theta_t)
    for r in range(3):
        m0 = M[r, 0]
        m1 = M[r, 1]
        R[r, 0] = m0 * cb + m1 * sb
        R[r, 1] = -m0 * sb + m1 * cb
        R[r, 2] = M[r, 2]
    for col in range(3):
        x0 = R[0, col]
        x1 = R[1, col]
        R[0, col] = ct * x0 + st * x1
        R[1, col] = -st * x0 + ct * x1


@njit(cache=True)
def _cache_check(ps, lb, bm, fnode, s_neg, delta, cphi, margin, ndisp):
    """Validity of a candidate list (``lb``, :class:`ListBounds`) built at the pose
    ``ref[o:o+9]`` (R), ``ref[o+9:o+12]`` (t) for the pose (``ps.Rc``, ``ps.tbt``): relative
    rotation below the cache angle, the far group (root box) within ``gfar``, and per close
    far-check node f (of ``fnode``) its near leaves within ``delta`` and the node within
    ``minsep[f]`` (all less ``margin``). Writes the near-leaf motion bounds ``ndisp[f]`` (and
    ``ps.dR``, ``ps.dt``); returns the largest of them, or -1.0 when the list is not valid."""
    Rc, tc, dR, dt, b_seg, b_obb = ps.Rc, ps.tbt, ps.dR, ps.dt, bm.seg, bm.obb
    ref, o, gfar, nclose, close = lb.ref, lb.o, lb.gfar, lb.nclose, lb.close
    nbox, minsep = lb.nbox, lb.minsep
    tr = 0.0
    for r in range(3):
        for c in range(3):
            dR[r, c] = Rc[r, c] - ref[o + 3 * r + c]
            tr += Rc[r, c] * ref[o + 3 * r + c]
        dt[r] = tc[r] - ref[o + 9 + r]
    if 0.5 * (tr - 1.0) < cphi:
        return -1.0
    fro = 0.0
    for r in range(3):
        for c in range(3):
            fro += dR[r, c] * dR[r, c]
    # bound of |dR n| (|n| = 1) for the meeting points of the pair clearances; 1e-11 covers the
    # teeth's congruence (normals within 2 PITCH_TOL_NORMAL) for lists served from the atlas
    ndisp[ndisp.shape[0] - 1] = math.sqrt(fro) * (1.0 + 1e-12) + 1e-11
    # motion bound of the whole base (root box): covers every node whose minsep exceeds it
    droot = _node_disp(dR, dt, b_seg, b_obb, _ROOT, s_neg, np.inf)
    if gfar < np.inf and droot + margin >= gfar:
        if _node_disp(dR, dt, b_seg, b_obb, _ROOT, s_neg, gfar) + margin >= gfar:
            return -1.0
    dmax = 0.0
    for q in range(nclose):
        f = close[q]
        if nbox[f, 0] <= nbox[f, 3]:
            d = _max_disp_box(dR, dt, ref, 0, nbox[f, 0], nbox[f, 1], nbox[f, 2], nbox[f, 3],
                              nbox[f, 4], nbox[f, 5], _AABB, s_neg)
            ndisp[f] = d + margin
            if d + margin >= delta:
                return -1.0
            if d > dmax:
                dmax = d
        if minsep[f] < np.inf and droot + margin >= minsep[f]:
            if _node_disp(dR, dt, b_seg, b_obb, fnode[f], s_neg, minsep[f]) + margin >= minsep[f]:
                return -1.0
    return dmax


@njit(cache=True)
def _atlas_store(theta_b, theta_t, d, n):
    """Store the list just built (``d.cands``, n pairs in this pose's slots, and its validity
    data ``d.far``) as a snapshot of ``d.atlas``; when the atlas is full it is emptied first (no
    eviction policy: a run soon refills what it visits)."""
    Rbt, tbt, cache, at = d.poses.Rbt, d.poses.tbt, d.cache, d.atlas
    cands = d.cands
    cand, cand_c, cand_s, cand_d, cand_h = cands.pairs, cands.c, cands.s, cands.d, cands.h
    minsep, nbox, close = d.far.minsep, d.far.nbox, d.far.close
    atlas_meta, atlas_pairs, atlas_c, atlas_s, atlas_d = at.meta, at.pairs, at.c, at.s, at.d
    atlas_h, atlas_x, atlas_minsep, atlas_nbox, atlas_close = at.h, at.x, at.minsep, at.nbox, at.close
    ns = int(cache[C_NSNAP])
    top = int(cache[C_ATOP])
    if n > atlas_pairs.shape[0]:
        return
    if ns >= atlas_meta.shape[0] or top + n > atlas_pairs.shape[0]:
        ns = 0
        top = 0
        cache[C_ACLEAR] += 1.0
    row = atlas_meta[ns]
    row[S_THB] = theta_b
    row[S_THT] = theta_t
    for r in range(3):
        for c in range(3):
            row[S_RREF + 3 * r + c] = Rbt[r, c]
        row[S_TREF + r] = tbt[r]
    nclose = int(cache[C_NCLOSE])
    row[S_NCLOSE] = nclose
    row[S_GFAR] = cache[C_GFAR]
    row[S_NNEAR] = cache[C_NNEAR]
    row[S_START] = top
    row[S_N] = n
    for q in range(n):
        atlas_pairs[top + q, 0] = cand[q, 0]
        atlas_pairs[top + q, 1] = cand[q, 1]
        atlas_c[top + q] = _f32_down(cand_c[q])
        atlas_s[top + q] = -_f32_down(-cand_s[q])
        atlas_d[top + q] = _f32_down(cand_d[q])
        atlas_h[top + q] = _f32_down(cand_h[q])
        atlas_x[top + q] = _f32_down(_allowance(cand_c[q], cand_s[q], cand_d[q], R_SNAP + R_LIFE))
    for f in range(minsep.shape[0]):
        atlas_minsep[ns, f] = minsep[f]
        for a in range(6):
            atlas_nbox[ns, f, a] = nbox[f, a]
    for q in range(nclose):
        atlas_close[ns, q] = close[q]
    cache[C_NSNAP] = ns + 1
    cache[C_ATOP] = top + n


@njit(cache=True)
def _atlas_lookup(theta_b, theta_t, d, cphi):
    """A snapshot of ``d.atlas`` valid at the current pose shifted by whole pitches (the pose of
    the same tooth pairs the snapshot was built for): returns (snapshot, base pitches, target
    pitches), or snapshot -1. Checks the ATLAS_TRIES snapshots nearest in the two shifted
    angles (writes ``d.poses.Rc`` and the motion bounds ``d.far.ndisp``)."""
    cache, M, at, params = d.cache, d.M, d.atlas, d.params
    period, atlas_meta, Rc = at.period, at.meta, d.poses.Rc
    ns = int(cache[C_NSNAP])
    pb = period[0]
    pt = period[2]
    best_s = -1
    best_db = 0
    best_dt = 0
    tried = np.zeros(ns, dtype=np.bool_)
    for attempt in range(ATLAS_TRIES):
        sel = -1
        sel_m = np.inf
        sel_db = 0
        sel_dt = 0
        for s in range(ns):
            if tried[s]:
                continue
            db = int(math.floor((atlas_meta[s, S_THB] - theta_b) / pb + 0.5))
            dtt = int(math.floor((atlas_meta[s, S_THT] - theta_t) / pt + 0.5))
            m = (abs(theta_b + db * pb - atlas_meta[s, S_THB])
                 + abs(theta_t + dtt * pt - atlas_meta[s, S_THT]))
            if m < sel_m:
                sel_m = m
                sel = s
                sel_db = db
                sel_dt = dtt
        if sel < 0 or sel_m > ATLAS_NEAR:
            break
        tried[sel] = True
        _rbt_of(M, theta_b + sel_db * pb, theta_t + sel_dt * pt, Rc)
        lb = ListBounds(atlas_meta[sel], S_RREF, atlas_meta[sel, S_GFAR],
                        int(atlas_meta[sel, S_NCLOSE]), at.close[sel], at.nbox[sel],
                        at.minsep[sel])
        dmax = _cache_check(d.poses, lb, d.base, d.far.fnode, params[P_SNEG], params[P_DELTA],
                            cphi, ATLAS_EPS, d.far.ndisp)
        if dmax >= 0.0:
            best_s = sel
            best_db = sel_db
            best_dt = sel_dt
            break
    return best_s, best_db, best_dt


@njit(cache=True)
def _atlas_activate(s, db, dtt, d):
    """Make snapshot s of ``d.atlas`` the current list (``d.cands``, ``d.far``), its pairs mapped to the tooth pairs of the current pose
    (base triangle id + db teeth, target id + dtt teeth), sorted by the mapped base slot. The
    validity data stay the snapshot's (checked at the shifted pose, which left the motion bounds
    since the snapshot's pose in ``ndisp``); ``cand_f`` is the far-check node of the snapshot's
    element (its motion bound applies). Sets the skip thresholds as :func:`init_thresholds` does,
    from the stored allowances when the turn since the snapshot's pose is within R_SNAP."""
    cache, at, cands, far = d.cache, d.atlas, d.cands, d.far
    period, atlas_meta, atlas_pairs, atlas_c, atlas_s = at.period, at.meta, at.pairs, at.c, at.s
    atlas_d, atlas_h, atlas_x = at.d, at.h, at.x
    b_order, b_inv, t_order, t_inv = d.base.order, d.base.inv, d.target.order, d.target.inv
    slot_f, minsep, nbox, close, ndisp = far.slot_f, far.minsep, far.nbox, far.close, far.ndisp
    cand, cand_c, cand_s, cand_d, cand_h = cands.pairs, cands.c, cands.s, cands.d, cands.h
    cand_g, cand_f, cand_x = cands.g, cands.f, cands.x
    elem_q, elem_x, elem_hit = cands.elem_q, cands.elem_x, cands.elem_hit
    row = atlas_meta[s]
    p0 = int(row[S_START])
    n = int(row[S_N])
    mb = b_order.shape[0]
    mt = t_order.shape[0]
    shb = ((db * int(period[1])) % mb + mb) % mb
    sht = ((dtt * int(period[3])) % mt + mt) % mt
    # element groups of the snapshot and their mapped base slots
    ng = 0
    gq = np.empty(n, dtype=np.int64)
    gk = np.empty(n, dtype=np.int64)
    q = 0
    while q < n:
        k = atlas_pairs[p0 + q, 0]
        gq[ng] = q
        gk[ng] = b_inv[(b_order[k] + shb) % mb]
        ng += 1
        while q < n and atlas_pairs[p0 + q, 0] == k:
            q += 1
    order = np.argsort(gk[:ng])
    rho0 = ndisp[ndisp.shape[0] - 1]
    stored = rho0 <= R_SNAP
    w = 0
    for gi in range(ng):
        g = order[gi]
        q0 = gq[g]
        q1 = gq[g + 1] if g + 1 < ng else n
        k_new = gk[g]
        f = slot_f[atlas_pairs[p0 + q0, 0]]
        d0 = ndisp[f]
        xm = np.inf
        w0 = w
        for q in range(q0, q1):
            l_new = t_inv[(t_order[atlas_pairs[p0 + q, 1]] + sht) % mt]
            cand[w, 0] = k_new
            cand[w, 1] = l_new
            cand_c[w] = atlas_c[p0 + q]
            cand_s[w] = atlas_s[p0 + q]
            cand_d[w] = atlas_d[p0 + q]
            if stored:
                x = atlas_x[p0 + q] - d0
            else:
                x = _allowance(cand_c[w], cand_s[w], cand_d[w], rho0 + R_LIFE) - d0
            cand_x[w] = x
            if x < xm:
                xm = x
            w += 1
        cand_h[w0] = atlas_h[p0 + q0]
        cand_g[w0] = q1 - q0
        cand_f[w0] = f
        elem_q[gi] = w0
        elem_x[gi] = max(cand_h[w0] - d0, xm)
        elem_hit[gi] = False
    cache[C_NELEM] = ng
    for f in range(minsep.shape[0]):
        minsep[f] = at.minsep[s, f]
        for a in range(6):
            nbox[f, a] = at.nbox[s, f, a]
    nclose = int(row[S_NCLOSE])
    for q in range(nclose):
        close[q] = at.close[s, q]
    for a in range(12):
        cache[C_RREF + a] = row[S_RREF + a]
    cache[C_NCLOSE] = nclose
    cache[C_GFAR] = row[S_GFAR]
    cache[C_NNEAR] = row[S_NNEAR]
    cache[C_NCAND] = n
    cache[C_DB] = db
    cache[C_DT] = dtt


@njit(cache=True)
def _atlas_serve(theta_b, theta_t, d, cphi):
    """A kept list that fits the current pose (:func:`_atlas_lookup`) made the current list
    (:func:`_atlas_activate`); False when none fits."""
    cache = d.cache
    if cache[C_NSNAP] <= 0.0:
        return False
    s, sdb, sdt = _atlas_lookup(theta_b, theta_t, d, cphi)
    if s < 0:
        return False
    _atlas_activate(s, sdb, sdt, d)
    cache[C_VALID] = 1.0
    cache[C_SINCE] = 0.0
    cache[C_AHITS] += 1.0
    return True


@njit(cache=True)
def _shifted_pose(theta_b, theta_t, M, period, Rbt, cache, Rc):
    """Rc = the base's pose in the target frame with both angles shifted by the list's pitches
    (``cache[C_DB]``, ``cache[C_DT]``): the pose of the teeth the list's data were made for."""
    if cache[C_DB] != 0.0 or cache[C_DT] != 0.0:
        _rbt_of(M, theta_b + cache[C_DB] * period[0], theta_t + cache[C_DT] * period[2], Rc)
    else:
        for r in range(3):
            for c in range(3):
                Rc[r, c] = Rbt[r, c]


@njit(cache=True)
def _keep_pose(Rc, tbt, cache):
    """The pose of this call (shifted), for the next call's motion bounds."""
    for r in range(3):
        for c in range(3):
            cache[C_PREV + 3 * r + c] = Rc[r, c]
        cache[C_PREV + 9 + r] = tbt[r]


@njit(cache=True)
def _start_motion(ps, fresh, s_neg, bm, cache, far):
    """Running motion sums of a list (re)started at this call (pose ``ps.Rc``, shifted): zero (per
    far-check node with near leaves ``nsum[f]``, the whole base, the turn), the pose kept for the
    next call, and what :func:`_valid_by_sums` needs: the near-leaf bounds and the turn since the
    list's pose (this call's check, ``ndisp``; 0 when ``fresh``; each kept as ``nd0[f]``, the
    largest as the start of ``cache[C_SUMD]``), the whole base's bound since it, and the
    smallest distance its far checks allow (``minsep``, the far group's ``C_GFAR``). The arrays
    named are those of ``far`` (:class:`FarCheck`)."""
    Rc, tbt, dR, dt, b_seg, b_obb = ps.Rc, ps.tbt, ps.dR, ps.dt, bm.seg, bm.obb
    nbox, minsep, close = far.nbox, far.minsep, far.close
    ndisp, nd0, nsum = far.ndisp, far.nd0, far.nsum
    d0 = 0.0
    sep = cache[C_GFAR]
    for q in range(int(cache[C_NCLOSE])):
        f = close[q]
        nsum[f] = 0.0
        nd0[f] = 0.0 if fresh else ndisp[f]
        if nbox[f, 0] <= nbox[f, 3] and nd0[f] > d0:
            d0 = nd0[f]
        if minsep[f] < sep:
            sep = minsep[f]
    root = 0.0
    if not fresh:
        for r in range(3):
            for c in range(3):
                dR[r, c] = Rc[r, c] - cache[C_RREF + 3 * r + c]
            dt[r] = tbt[r] - cache[C_TREF + r]
        root = _node_disp(dR, dt, b_seg, b_obb, _ROOT, s_neg, np.inf)
    cache[C_R0] = 0.0 if fresh else ndisp[ndisp.shape[0] - 1]
    cache[C_ROOT0] = root
    cache[C_SEP0] = sep
    cache[C_SUMD] = d0
    cache[C_SUMR] = 0.0
    cache[C_SUMROOT] = 0.0
    _keep_pose(Rc, tbt, cache)


@njit(cache=True)
def _advance_motion(ps, s_neg, bm, cache, far):
    """Add the motion since the previous call to the running sums: per far-check node f with near
    leaves the largest |dR x + dt| over their box to ``nsum[f]``; over the whole base to
    ``cache[C_SUMROOT]``; |dR|_F (a bound of the turn of every direction) to ``cache[C_SUMR]``.
    ``cache[C_SUMD]`` becomes the largest nd0[f] + nsum[f] (a bound of the near leaves' motion
    since the list's pose). The poses are shifted by the list's pitches (the teeth the list was
    made for): a fixed isometry away from the true poses, so the same motion. Poses ``ps``
    (:class:`Poses`), arrays of ``far`` (:class:`FarCheck`)."""
    Rc, tbt, dR, dt, b_seg, b_obb = ps.Rc, ps.tbt, ps.dR, ps.dt, bm.seg, bm.obb
    nbox, close, nd0, nsum = far.nbox, far.close, far.nd0, far.nsum
    fro = 0.0
    for r in range(3):
        for c in range(3):
            dR[r, c] = Rc[r, c] - cache[C_PREV + 3 * r + c]
            fro += dR[r, c] * dR[r, c]
        dt[r] = tbt[r] - cache[C_PREV + 9 + r]
    dmax = 0.0
    for q in range(int(cache[C_NCLOSE])):
        f = close[q]
        if nbox[f, 0] <= nbox[f, 3]:
            d = _max_disp_box(dR, dt, cache, 0, nbox[f, 0], nbox[f, 1], nbox[f, 2], nbox[f, 3],
                              nbox[f, 4], nbox[f, 5], _AABB, s_neg)
            nsum[f] += d * (1.0 + 1e-12) + SKIP_EPS
            if nd0[f] + nsum[f] > dmax:
                dmax = nd0[f] + nsum[f]
    cache[C_SUMD] = dmax
    cache[C_SUMROOT] += _node_disp(dR, dt, b_seg, b_obb, _ROOT, s_neg, np.inf) * (1.0 + 1e-12) \
        + SKIP_EPS
    cache[C_SUMR] += math.sqrt(fro) * (1.0 + 1e-12) + 1e-15
    _keep_pose(Rc, tbt, cache)


@njit(cache=True)
def _valid_by_sums(cache, delta, margin, phi_tol):
    """True when the running sums alone prove what :func:`_cache_check` checks (the triangle
    inequality: the motion since the list's pose is at most the bound at the sums' start plus
    the sums since): near leaves within ``delta`` (``cache[C_SUMD]``, see :func:`_advance_motion`),
    the whole base within the smallest far-check distance, and the turn below ``phi_tol``
    (|R1 - R2|_F = 2 sqrt(2) sin(angle / 2)). False means "not proven": the full check decides."""
    if cache[C_SUMD] + margin >= delta:
        return False
    if cache[C_ROOT0] + cache[C_SUMROOT] + margin >= cache[C_SEP0]:
        return False
    lim = 2.0 * math.sqrt(2.0) * math.sin(0.5 * phi_tol) * (1.0 - 1e-9)
    return cache[C_R0] + cache[C_SUMR] < lim


@njit(cache=True)
def _direct_sums(cache, far):
    """For a list without running sums: the motion since the sums' start bounded by the full
    check's direct bounds since the list's pose (``ndisp``) less those at the start (``nd0``), so
    that the thresholds (:func:`init_thresholds`: allowance less the start bound) compare as the
    list's own clearances against the direct bound; the turn likewise. Arrays of ``far``."""
    nbox, close, ndisp, nd0, nsum = far.nbox, far.close, far.ndisp, far.nd0, far.nsum
    for q in range(int(cache[C_NCLOSE])):
        f = close[q]
        if nbox[f, 0] <= nbox[f, 3]:
            nsum[f] = ndisp[f] - nd0[f]
    cache[C_SUMR] = ndisp[ndisp.shape[0] - 1] - cache[C_R0]


@njit(cache=True, inline="always")
def _exact(d):
    """The exact search of the fixed-axis pair ``d`` at its pose (:func:`search_pair`)."""
    p = d.params
    return search_pair(d.base, d.target, d.poses.Rbt, d.poses.tbt, p[P_L], p[P_SNEG], d.work)


@njit(cache=True, inline="always")
def _cool_down(theta_b, theta_t, d, periodic, cphi):
    """A call during a cool-down (:func:`cached_search`): -1 for the exact search, 1 when a kept
    list that fits ends it (set from the atlas), 0 when this call builds (and keeps) a list."""
    cache = d.cache
    cache[C_COOL] -= 1.0
    if not periodic:
        cache[C_EXACT] += 1.0
        return -1
    # cool-down with an atlas: a kept list that fits ends it; every ATLAS_BUILD_EVERY-th call
    # builds (and keeps) a list, so that large steps fill the atlas too; else the exact search
    if _atlas_serve(theta_b, theta_t, d, cphi):
        cache[C_COOL] = 0.0
        return 1
    if int(cache[C_COOL]) % ATLAS_BUILD_EVERY != 0:
        cache[C_EXACT] += 1.0
        return -1
    cache[C_COOL] = 0.0           # a build below
    cache[C_VALID] = 0.0
    cache[C_SINCE] = CACHE_MIN_REUSE
    return 0


@njit(cache=True, inline="always")
def _still_valid(theta_b, theta_t, d, cphi):
    """Is the list in use valid at this pose (:func:`cached_search`)? Returns (valid, init):
    init when its thresholds are to be set again from its own pose (running sums whose turn
    exceeds R_LIFE, or a short-lived list that switches to running sums)."""
    cache, ps, far, p = d.cache, d.poses, d.far, d.params
    s_neg, delta, phi_tol = p[P_SNEG], p[P_DELTA], p[P_PHI]
    _shifted_pose(theta_b, theta_t, d.M, d.atlas.period, ps.Rbt, cache, ps.Rc)
    margin = ATLAS_EPS if (cache[C_DB] != 0.0 or cache[C_DT] != 0.0) else 0.0
    lb = ListBounds(cache, C_RREF, cache[C_GFAR], int(cache[C_NCLOSE]), far.close, far.nbox,
                    far.minsep)
    valid = True
    init = False
    if cache[C_SUMS] != 0.0:
        _advance_motion(ps, s_neg, d.base, cache, far)
        # the turn since the thresholds were set may exceed what they allow for: the same
        # list then gets them set again from its own pose (with the bounds of the full check)
        init = cache[C_SUMR] > R_LIFE
        if init or not _valid_by_sums(cache, delta, margin, phi_tol):
            dmax = _cache_check(ps, lb, d.base, far.fnode, s_neg, delta, cphi, margin, far.ndisp)
            valid = dmax >= 0.0
            init = init and valid
    else:
        # a short-lived list: the full check every call, its direct bounds as the "sums";
        # once it has lived REANCHOR_LIFE calls it switches to running sums (a restart)
        dmax = _cache_check(ps, lb, d.base, far.fnode, s_neg, delta, cphi, margin, far.ndisp)
        valid = dmax >= 0.0
        if valid:
            _direct_sums(cache, far)
            init = cache[C_SINCE] + 1.0 >= REANCHOR_LIFE
    return valid, init


@njit(cache=True)
def _build_list(theta_b, theta_t, d, periodic):
    """Build a candidate list at this pose (:func:`cached_search`): collecting traversal, pairs
    sorted by base slot, clearances, far-check groups, the pose kept; and the list kept in the
    atlas when ``periodic``. False when the list overflowed (the list is then invalid)."""
    cache, ps, far, cands, p = d.cache, d.poses, d.far, d.cands, d.params
    Rbt, tbt, minsep, nbox, close = ps.Rbt, ps.tbt, far.minsep, far.nbox, far.close
    s_neg, far_m = p[P_SNEG], p[P_FAR]
    cache[C_SINCE] = 0.0
    cache[C_DB] = 0.0
    cache[C_DT] = 0.0
    nf = far.fnode.shape[0]
    for f in range(nf):
        minsep[f] = np.inf
        for a in range(3):
            nbox[f, a] = np.inf
            nbox[f, 3 + a] = -np.inf
    col = Collect(cands.pairs, far.nstamp, far.icount, far.fc, minsep, nbox)
    n = _traverse(_COLLECT, d.base, d.target, Rbt, tbt, p[P_L], s_neg, far_m + s_neg, p[P_DELTA],
                  d.work, col)
    cache[C_BUILDS] += 1.0
    if n < 0:
        cache[C_VALID] = 0.0
        cache[C_OVERFLOW] += 1.0
        return False
    # sort the pairs by base slot (stable)
    cand = cands.pairs
    order = np.argsort(cand[:n, 0], kind="mergesort")
    tmp = cand[:n].copy()
    for q in range(n):
        cand[q, 0] = tmp[order[q], 0]
        cand[q, 1] = tmp[order[q], 1]
    candidate_clearances(n, cands, d.target.tri, d.base.elem, far.slot_f, Rbt, tbt, s_neg)
    cache[C_NNEAR] = far.icount[0]
    # far-check nodes checked one by one: those with near leaves or within 16 far; the
    # others together through the root box against the smallest of their distances
    nclose = 0
    gfar = np.inf
    for f in range(nf):
        if nbox[f, 0] <= nbox[f, 3] or minsep[f] < 16.0 * far_m:
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
    if periodic:
        _atlas_store(theta_b, theta_t, d, n)
    return True


@njit(cache=True, inline="always")
def _set_motion(theta_b, theta_t, d, set_list, init, fresh, prev_life):
    """A list was set at this call (``set_list``) or its thresholds are to be set again
    (``init``): its lifetime statistics, the running sums started (:func:`_start_motion`) and
    the skip thresholds set (:func:`init_thresholds`)."""
    cache, ps, far = d.cache, d.poses, d.far
    if set_list:
        # lifetime of the lists (calls served, exponential average): re-anchoring pays
        # only when a list lives long enough to use the thresholds
        life = cache[C_LIFE]
        cache[C_LIFE] = prev_life if life == 0.0 else 0.75 * life + 0.25 * prev_life
        _shifted_pose(theta_b, theta_t, d.M, d.atlas.period, ps.Rbt, cache, ps.Rc)
    _start_motion(ps, fresh, d.params[P_SNEG], d.base, cache, far)
    # running sums (and re-anchored thresholds) for lists that live long enough to use them
    cache[C_SUMS] = 1.0 if (init and not set_list) or cache[C_LIFE] >= REANCHOR_LIFE else 0.0
    if init:
        cache[C_NELEM] = init_thresholds(int(cache[C_NCAND]), d.cands, far.ndisp, fresh)


@njit(cache=True, inline="always")
def _narrow_phase(d):
    """The narrow phase on the list in use (:func:`search_candidates_skip`), its statistics kept
    in the cache state."""
    cache, p = d.cache, d.params
    stats = np.zeros(4, dtype=np.int64)
    n_act = search_candidates_skip(int(cache[C_NELEM]), d.cands, d.far, cache[C_SUMS] != 0.0,
                                   cache[C_R0] + cache[C_SUMR] + 1e-11, d.base.elem,
                                   d.target.tri, p[P_L], p[P_SNEG], d.poses, d.work, stats)
    cache[C_SKIPPED] = stats[0]
    cache[C_TESTED] = stats[1]
    cache[C_RETESTS] = stats[2]
    cache[C_VISITED] = stats[3]
    cache[C_TESTED_ALL] += stats[1]
    cache[C_RETESTS_ALL] += stats[2]
    return n_act


@njit(cache=True, inline="always")
def cached_search(d, theta_b, theta_t):
    """Exact contact search through a candidate cache (temporal coherence) of the fixed-axis
    pair ``d`` (:class:`FixedAxisData`) at the pose ``d.poses`` (angles ``theta_b``, ``theta_t``);
    the search length, the margins ``delta`` and ``far`` and the angle ``phi_tol`` are
    ``d.params``' (``P_*``). Returns the number of base elements with a hit (``d.work`` as
    :func:`search_pair`).

    Build (at the current pose): a traversal with node volumes grown by ``far`` finds the base
    leaves within ``far`` of the target ("near" leaves); for their elements every (element,
    triangle) pair whose penetration segment comes within ``delta`` of the triangle is stored
    (sorted by element). Every other part of the base is proven farther from
    the target than a recorded distance, per far-check node f (a cut of the base tree, ~256 nodes):
    ``minsep[f]``. A later pose reuses the list when, relative to the target, (i) the near leaves
    of every far-check node moved by less than ``delta``, (ii) every far-check node moved by less
    than its ``minsep``, (iii) the relative rotation is below ``phi_tol``; otherwise it rebuilds
    (:func:`_cache_check`). The motion bounds are exact maxima over boxes (|dR x + dt| is convex
    in x). The result is identical to :func:`search_pair` (the same exact narrow phase on a
    superset of the hits). Adaptive fallback: when a list served fewer than CACHE_MIN_REUSE
    calls, the next CACHE_COOLDOWN calls use the exact search instead (with an atlas, a kept list
    that fits ends the cool-down, and every ATLAS_BUILD_EVERY-th call builds and keeps one: large
    steps, 10 us at 500 rpm, fill the atlas in a few pitches at ~1.5x the exact search's cost).

    Clearances and skip thresholds (:func:`candidate_clearances` at the build,
    :func:`init_thresholds`): each element and pair gets the motion its clearance allows, less
    the motion since the list's pose. From then on, running sums of per-call motion bounds (per
    far-check node, :func:`_advance_motion`) measure the motion since; the narrow phase skips the
    elements and pairs whose threshold the sum has not reached, and a pair it tests gets a new
    threshold from its clearances at this pose (:func:`search_candidates_skip`). So a call costs
    about the elements in contact and their near neighbours, not the list's size or age. The
    same sums prove check (i)-(iii) most calls without the per-node check (:func:`_valid_by_sums`).

    Pitch atlas (``d.atlas``, ``period[1] > 0``: both meshes are invariant under a turn by one pitch, checked
    by :func:`engine.pitch_symmetry`): every list built is kept as a snapshot (pairs, clearances,
    validity data, angles). Turning the base by one pitch (angle ``period[0]``) maps the mesh
    onto itself with triangle ids shifted by ``period[1]`` (target: ``period[2]``, ``period[3]``),
    so the pose (theta_b + i pb, theta_t + j pt) meets the same geometry as (theta_b, theta_t)
    with the tooth pairs renumbered. When the list expires, a snapshot whose checks (i)-(iii) pass
    at the current pose shifted by whole pitches to it (with ATLAS_EPS for the teeth's congruence)
    is mapped to the current tooth pairs (:func:`_atlas_activate`) instead of a build. The narrow
    phase runs at the true pose on the mapped pairs: results as without the atlas, bit for bit.
    In a steady run every pitch repeats the previous one and builds stop after the first pitch."""
    cache = d.cache
    periodic = d.atlas.period[1] > 0.0 and d.atlas.meta.shape[0] > 1
    cphi = math.cos(d.params[P_PHI])
    prev_life = cache[C_SINCE] if cache[C_VALID] != 0.0 else 0.0
    set_list = False    # a list was set at this call (the atlas sets its thresholds)
    init = False        # thresholds to set from the list's clearances (a build, or a restart)
    fresh = False
    if cache[C_COOL] > 0.0:
        go = _cool_down(theta_b, theta_t, d, periodic, cphi)
        if go < 0:
            return _exact(d)
        set_list = go > 0
    valid = cache[C_VALID] != 0.0 and not set_list
    if valid:
        valid, init = _still_valid(theta_b, theta_t, d, cphi)
    if not valid and not set_list:
        set_list = periodic and _atlas_serve(theta_b, theta_t, d, cphi)
        if not set_list:
            if cache[C_VALID] != 0.0 and cache[C_SINCE] < CACHE_MIN_REUSE:
                # the motion between calls is too large for the margins: exact search for a while
                cache[C_VALID] = 0.0
                cache[C_COOL] = CACHE_COOLDOWN - 1
                cache[C_EXACT] += 1.0
                return _exact(d)
            if not _build_list(theta_b, theta_t, d, periodic):
                return _exact(d)
            fresh = True
            set_list = True
            init = True
    else:
        cache[C_CALLS] += 1.0
        cache[C_SINCE] += 1.0
    if set_list or init:
        _set_motion(theta_b, theta_t, d, set_list, init, fresh, prev_life)
    return _narrow_phase(d)


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
def pair_forces(n_active, ws, bm, tm, motion, params, out):
    """Element and body forces for the generic pair (base ``bm``, target ``tm``, the search's
    workspace ``ws``). Inputs in the target frame (``ws.line``) are mapped to the world with
    ``motion.Rt``, ``motion.tt`` (:class:`Motion`). Velocities (v of the body origin, omega) in
    the world. Writes to ``out`` (:class:`ElementForces`) the per-element arrays (first n_active
    rows), the force on the target ``force`` and its moment about the world origin ``moment``,
    and ``diag`` (N_DIAG)."""
    active, best_u, best_j, line = ws.active, ws.best_u, ws.best_j, ws.line
    belem, b_order, t_order = bm.elem, bm.order, tm.order
    Rt, tt, tb = motion.Rt, motion.tt, motion.tb
    vb, wb, vt_, wt = motion.vb, motion.wb, motion.vt, motion.wt
    e_base, e_target, e_u, e_point, e_normal = out.base, out.target, out.u, out.point, out.normal
    e_fn, e_ft, e_area = out.fn, out.ft, out.area
    force_t, moment_t, diag = out.force, out.moment, out.diag
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
@njit(cache=True, nogil=True)
def fixed_axis_eval(data, theta_base, theta_target, omega_base, omega_target, out):
    """Fixed-axis pair: pose = R0 @ Rz(theta), both axes through the world origin.

    ``data`` (:class:`FixedAxisData`) from
    :func:`gearcontact_fmu.contact.engine.make_fixed_axis_data`. Writes ``out``
    (mesh_model.OUT_* layout): out[0] torque on the base about its axis, out[1] torque on the target
    about its axis, out[2..8] diagnostics, out[9] status (1 = penetration beyond u_max).
    """
    M, ab0, params, Rbt = data.M, data.ab0, data.params, data.poses.Rbt
    belem, active, best_u, line = data.base.elem, data.work.active, data.work.best_u, data.work.line
    _rbt_of(M, theta_base, theta_target, Rbt)       # Rbt = Rz(-theta_t) M Rz(theta_b), M = R0_t^T R0_b
    ct = math.cos(theta_target)
    st = math.sin(theta_target)
    if params[P_DELTA] > 0.0:
        n = cached_search(data, theta_base, theta_target)
    else:
        n = _exact(data)
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
