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
* base workspace (per base body): ``stamp`` (m,) int64, ``call`` (1,) int64, ``best_u`` (m,),
  ``best_j`` (m,) int64 (target slot of the winning hit), ``line`` (m, 6) ``[p', d']`` element point
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
N_PARAMS = 11

# diagnostics layout of the generic force kernel (matches fidelity.OUT_* minus the torques)
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


def make_params(pcm, search_length=None, friction=True, damping=True, ratio=0.5):
    """Parameter vector of the kernels from a :class:`~gearcontact_fmu.params.PCMParams`."""
    L = 2.0 * pcm.u_max if search_length is None else float(search_length)
    if L < pcm.u_max:
        raise ValueError(f"search length {L} must be >= u_max {pcm.u_max}")
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
def search_pair(b_int, b_seg, belem, t_int, t_box, t_slab, ttri, Rbt, tbt, L,
                stamp, call, best_u, best_j, line, active, stack):
    """Dual-tree traversal + penetration lines. ``Rbt``, ``tbt``: pose of the base frame in the
    target frame (x_target = Rbt x_base + tbt). Returns the number of base elements with a hit;
    their slots are ``active[:n]``, penetration ``best_u[slot]``, target slot ``best_j[slot]``, line
    ``line[slot] = [p', d']`` (target frame; d' = inward base normal)."""
    call[0] += 1
    cid = call[0]
    r00, r01, r02 = Rbt[0, 0], Rbt[0, 1], Rbt[0, 2]
    r10, r11, r12 = Rbt[1, 0], Rbt[1, 1], Rbt[1, 2]
    r20, r21, r22 = Rbt[2, 0], Rbt[2, 1], Rbt[2, 2]
    a00, a01, a02 = abs(r00), abs(r01), abs(r02)
    a10, a11, a12 = abs(r10), abs(r11), abs(r12)
    a20, a21, a22 = abs(r20), abs(r21), abs(r22)
    t0, t1, t2 = tbt[0], tbt[1], tbt[2]
    n_active = 0
    sp = 0
    stack[0, 0] = 0
    stack[0, 1] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        i = stack[sp, 0]
        j = stack[sp, 1]
        c0, c1, c2 = b_seg[i, 0], b_seg[i, 1], b_seg[i, 2]
        e0, e1, e2 = b_seg[i, 3], b_seg[i, 4], b_seg[i, 5]
        # base box in the target frame (centre R c + t, half extents |R| e)
        cx = r00 * c0 + r01 * c1 + r02 * c2 + t0
        ex = a00 * e0 + a01 * e1 + a02 * e2
        if cx - ex > t_box[j, 3] or cx + ex < t_box[j, 0]:
            continue
        cy = r10 * c0 + r11 * c1 + r12 * c2 + t1
        ey = a10 * e0 + a11 * e1 + a12 * e2
        if cy - ey > t_box[j, 4] or cy + ey < t_box[j, 1]:
            continue
        cz = r20 * c0 + r21 * c1 + r22 * c2 + t2
        ez = a20 * e0 + a21 * e1 + a22 * e2
        if cz - ez > t_box[j, 5] or cz + ez < t_box[j, 2]:
            continue
        # slab of the target node vs the base box as an oriented box (axes = columns of Rbt)
        snx, sny, snz = t_slab[j, 0], t_slab[j, 1], t_slab[j, 2]
        sc = snx * cx + sny * cy + snz * cz
        sr = (e0 * abs(snx * r00 + sny * r10 + snz * r20)
              + e1 * abs(snx * r01 + sny * r11 + snz * r21)
              + e2 * abs(snx * r02 + sny * r12 + snz * r22))
        if sc - sr > t_slab[j, 4] or sc + sr < t_slab[j, 3]:
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
        bx0, by0, bz0 = t_box[j, 0], t_box[j, 1], t_box[j, 2]
        bx1, by1, bz1 = t_box[j, 3], t_box[j, 4], t_box[j, 5]
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
            ox, oy, oz = line[k, 0], line[k, 1], line[k, 2]
            dx, dy, dz = line[k, 3], line[k, 4], line[k, 5]
            # segment box vs target leaf box
            qx = ox + L * dx
            qy = oy + L * dy
            qz = oz + L * dz
            if min(ox, qx) > bx1 or max(ox, qx) < bx0:
                continue
            if min(oy, qy) > by1 or max(oy, qy) < by0:
                continue
            if min(oz, qz) > bz1 or max(oz, qz) < bz0:
                continue
            so = snx * ox + sny * oy + snz * oz
            sq = snx * qx + sny * qy + snz * qz
            if min(so, sq) > t_slab[j, 4] or max(so, sq) < t_slab[j, 3]:
                continue
            for l in range(ts, te):
                # facing: n_base . n_target < 0  <=>  d . ne > 0
                dne = dx * ttri[l, 15] + dy * ttri[l, 16] + dz * ttri[l, 17]
                if dne <= DOT_EPS:
                    continue
                ngx, ngy, ngz = ttri[l, 3], ttri[l, 4], ttri[l, 5]
                den = dx * ngx + dy * ngy + dz * ngz
                if abs(den) <= DOT_EPS:
                    continue
                rax = ttri[l, 0] - ox
                ray = ttri[l, 1] - oy
                raz = ttri[l, 2] - oz
                s = (rax * ngx + ray * ngy + raz * ngz) / den
                if s > L or s < -L:
                    continue
                # q - a = (o + s d) - a
                wx = s * dx - rax
                wy = s * dy - ray
                wz = s * dz - raz
                beta = wx * ttri[l, 6] + wy * ttri[l, 7] + wz * ttri[l, 8]
                if beta < -BARY_EPS:
                    continue
                gamma = wx * ttri[l, 9] + wy * ttri[l, 10] + wz * ttri[l, 11]
                if gamma < -BARY_EPS or beta + gamma > 1.0 + BARY_EPS:
                    continue
                # penetration measured to the (exact) tangent plane of the target element
                u = ((ttri[l, 12] - ox) * ttri[l, 15] + (ttri[l, 13] - oy) * ttri[l, 16]
                     + (ttri[l, 14] - oz) * ttri[l, 17]) / dne
                if u <= 0.0 or u > L:
                    continue
                if u < best_u[k]:
                    if best_j[k] < 0:
                        active[n_active] = k
                        n_active += 1
                    best_u[k] = u
                    best_j[k] = l
    return n_active


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
    (fidelity.OUT_* layout): out[0] torque on the base about its axis, out[1] torque on the target
    about its axis, out[2..8] diagnostics, out[9] status (1 = penetration beyond u_max).
    """
    (b_int, b_seg, belem, b_order, t_int, t_box, t_slab, ttri, t_order, M, ab0, params,
     stamp, call, best_u, best_j, line, active, stack, Rbt, tbt) = data
    # Rbt = Rz(-theta_t) M Rz(theta_b), M = R0_t^T R0_b
    cb = math.cos(theta_base)
    sb = math.sin(theta_base)
    ct = math.cos(theta_target)
    st = math.sin(theta_target)
    # M Rz(theta_b): columns 0, 1 rotated
    for r in range(3):
        m0 = M[r, 0]
        m1 = M[r, 1]
        Rbt[r, 0] = m0 * cb + m1 * sb
        Rbt[r, 1] = -m0 * sb + m1 * cb
        Rbt[r, 2] = M[r, 2]
    # Rz(-theta_t) (...): rows 0, 1 rotated
    for col in range(3):
        x0 = Rbt[0, col]
        x1 = Rbt[1, col]
        Rbt[0, col] = ct * x0 + st * x1
        Rbt[1, col] = -st * x0 + ct * x1
    n = search_pair(b_int, b_seg, belem, t_int, t_box, t_slab, ttri, Rbt, tbt, params[P_L],
                    stamp, call, best_u, best_j, line, active, stack)
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
