"""Axis-aligned bounding-volume tree over the triangles of one body, in its body frame (numba).

The tree is a set of plain arrays (no Python objects), built once per body:

* ``node_box``  (N, 6) float64: ``[min_x, min_y, min_z, max_x, max_y, max_z]`` of each node;
* ``node_int``  (N, 4) int64:   ``[left, right, start, count]``; ``left = right = -1`` for a leaf.
  Every node (leaf or not) covers the contiguous range ``order[start:start+count]`` of primitives;
* ``order``     (m,)   int64:   primitive (triangle) index of each slot.

Nodes are stored in pre-order (a parent has a smaller index than its children, node 0 is the
root), so a reversed loop over the nodes is a bottom-up pass (used by :func:`refit_segment_boxes`).
The split is a median split of the primitive centres along the longest axis of their bounds.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

LEAF_SIZE = 4


@njit(cache=True, nogil=True)
def _build(centres, prim_box, leaf_size):
    m = centres.shape[0]
    order = np.arange(m).astype(np.int64)
    cap = max(1, 2 * ((m + leaf_size - 1) // leaf_size) + 1)
    cap = 2 * cap + 8
    node_box = np.empty((cap, 6))
    node_int = -np.ones((cap, 4), dtype=np.int64)
    # explicit stack of nodes to split: (node, depth)
    stack = np.empty((128, 2), dtype=np.int64)
    n_nodes = 1
    node_int[0, 2] = 0
    node_int[0, 3] = m
    stack[0, 0] = 0
    stack[0, 1] = 0
    sp = 1
    max_depth = 0
    while sp > 0:
        sp -= 1
        node = stack[sp, 0]
        depth = stack[sp, 1]
        if depth > max_depth:
            max_depth = depth
        start = node_int[node, 2]
        count = node_int[node, 3]
        # bounds of the primitives and of their centres
        bmin = np.full(3, np.inf)
        bmax = np.full(3, -np.inf)
        cmin = np.full(3, np.inf)
        cmax = np.full(3, -np.inf)
        for k in range(start, start + count):
            p = order[k]
            for a in range(3):
                if prim_box[p, a] < bmin[a]:
                    bmin[a] = prim_box[p, a]
                if prim_box[p, 3 + a] > bmax[a]:
                    bmax[a] = prim_box[p, 3 + a]
                if centres[p, a] < cmin[a]:
                    cmin[a] = centres[p, a]
                if centres[p, a] > cmax[a]:
                    cmax[a] = centres[p, a]
        for a in range(3):
            node_box[node, a] = bmin[a]
            node_box[node, 3 + a] = bmax[a]
        if count <= leaf_size:
            continue
        ext = cmax - cmin
        axis = 0
        if ext[1] > ext[axis]:
            axis = 1
        if ext[2] > ext[axis]:
            axis = 2
        seg = order[start:start + count].copy()
        key = np.empty(count)
        for k in range(count):
            key[k] = centres[seg[k], axis]
        srt = np.argsort(key, kind="mergesort")
        for k in range(count):
            order[start + k] = seg[srt[k]]
        half = count // 2
        left = n_nodes
        right = n_nodes + 1
        n_nodes += 2
        node_int[node, 0] = left
        node_int[node, 1] = right
        node_int[left, 2] = start
        node_int[left, 3] = half
        node_int[right, 2] = start + half
        node_int[right, 3] = count - half
        if sp + 2 > stack.shape[0]:
            new = np.empty((2 * stack.shape[0], 2), dtype=np.int64)
            new[:sp] = stack[:sp]
            stack = new
        # push right first so that the left subtree is split first (pre-order indices are
        # not required for correctness, only parent < child, which holds by construction)
        stack[sp, 0] = right
        stack[sp, 1] = depth + 1
        sp += 1
        stack[sp, 0] = left
        stack[sp, 1] = depth + 1
        sp += 1
    return node_box[:n_nodes].copy(), node_int[:n_nodes].copy(), order, max_depth


@njit(cache=True, nogil=True)
def _tri_boxes(tri):
    m = tri.shape[0]
    box = np.empty((m, 6))
    cen = np.empty((m, 3))
    for i in range(m):
        for a in range(3):
            lo = min(tri[i, 0, a], tri[i, 1, a], tri[i, 2, a])
            hi = max(tri[i, 0, a], tri[i, 1, a], tri[i, 2, a])
            box[i, a] = lo
            box[i, 3 + a] = hi
            cen[i, a] = (tri[i, 0, a] + tri[i, 1, a] + tri[i, 2, a]) / 3.0
    return box, cen


def build_bvh(tri_vertices, leaf_size: int = LEAF_SIZE, extra_points=None):
    """Build the AABB tree of triangles ``tri_vertices`` (m, 3, 3) [m] in their (body) frame.

    ``extra_points`` (m, 3), optional: one more point per triangle the primitive box must enclose
    (e.g. an exact face point off the flat triangle).
    Returns ``(node_box (N,6), node_int (N,4), order (m,), max_depth)``.
    """
    tri = np.ascontiguousarray(tri_vertices, dtype=np.float64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3) or tri.shape[0] == 0:
        raise ValueError("tri_vertices must have shape (m, 3, 3) with m > 0")
    box, cen = _tri_boxes(tri)
    if extra_points is not None:
        ep = np.asarray(extra_points, dtype=np.float64)
        box[:, :3] = np.minimum(box[:, :3], ep)
        box[:, 3:] = np.maximum(box[:, 3:], ep)
    node_box, node_int, order, max_depth = _build(cen, box, int(leaf_size))
    return node_box, node_int, order, int(max_depth)


@njit(cache=True, nogil=True)
def refit_segment_boxes(node_int, order_points, order_normals, length):
    """Boxes of the penetration-line segments ``[p, p - length*n]`` of every node, as centre and
    half extents ``(N, 6) = [c, e]``. ``order_points``/``order_normals`` are in slot order
    (slot k holds primitive ``order[k]``)."""
    n = node_int.shape[0]
    lo = np.empty((n, 3))
    hi = np.empty((n, 3))
    for node in range(n - 1, -1, -1):
        left = node_int[node, 0]
        if left < 0:
            start = node_int[node, 2]
            count = node_int[node, 3]
            for a in range(3):
                lo[node, a] = np.inf
                hi[node, a] = -np.inf
            for k in range(start, start + count):
                for a in range(3):
                    p0 = order_points[k, a]
                    p1 = p0 - length * order_normals[k, a]
                    if p0 < lo[node, a]:
                        lo[node, a] = p0
                    if p1 < lo[node, a]:
                        lo[node, a] = p1
                    if p0 > hi[node, a]:
                        hi[node, a] = p0
                    if p1 > hi[node, a]:
                        hi[node, a] = p1
        else:
            right = node_int[node, 1]
            for a in range(3):
                lo[node, a] = min(lo[left, a], lo[right, a])
                hi[node, a] = max(hi[left, a], hi[right, a])
    out = np.empty((n, 6))
    for node in range(n):
        for a in range(3):
            out[node, a] = 0.5 * (lo[node, a] + hi[node, a])
            out[node, 3 + a] = 0.5 * (hi[node, a] - lo[node, a])
    return out


@njit(cache=True)
def _node_frame(sx, sy, sz, pts, npts):
    """Orthonormal rows (t1, t2, n): n the normalised normal sum (sx, sy, sz) (or z when it
    vanishes), t1 the principal direction of the points in the plane normal to n."""
    nn = math.sqrt(sx * sx + sy * sy + sz * sz)
    if nn > 0.0:
        nx, ny, nz = sx / nn, sy / nn, sz / nn
    else:
        nx, ny, nz = 0.0, 0.0, 1.0
    # any tangent basis (u, v)
    if abs(nx) < 0.9:
        ux, uy, uz = 0.0, -nz, ny          # e_x x n
    else:
        ux, uy, uz = nz, 0.0, -nx          # e_y x n
    un = math.sqrt(ux * ux + uy * uy + uz * uz)
    ux, uy, uz = ux / un, uy / un, uz / un
    vx = ny * uz - nz * uy
    vy = nz * ux - nx * uz
    vz = nx * uy - ny * ux
    # 2x2 covariance of the points in (u, v)
    mu = 0.0
    mv = 0.0
    for k in range(npts):
        mu += pts[k, 0] * ux + pts[k, 1] * uy + pts[k, 2] * uz
        mv += pts[k, 0] * vx + pts[k, 1] * vy + pts[k, 2] * vz
    mu /= npts
    mv /= npts
    cuu = 0.0
    cuv = 0.0
    cvv = 0.0
    for k in range(npts):
        a = pts[k, 0] * ux + pts[k, 1] * uy + pts[k, 2] * uz - mu
        b = pts[k, 0] * vx + pts[k, 1] * vy + pts[k, 2] * vz - mv
        cuu += a * a
        cuv += a * b
        cvv += b * b
    ang = 0.5 * math.atan2(2.0 * cuv, cuu - cvv)
    ca = math.cos(ang)
    sa = math.sin(ang)
    t1x, t1y, t1z = ca * ux + sa * vx, ca * uy + sa * vy, ca * uz + sa * vz
    t2x = ny * t1z - nz * t1y
    t2y = nz * t1x - nx * t1z
    t2z = nx * t1y - ny * t1x
    return t1x, t1y, t1z, t2x, t2y, t2z, nx, ny, nz


@njit(cache=True, nogil=True)
def node_obbs(node_int, order, tri, seg_points, seg_normals, length):
    """Oriented box of every node: ``(N, 15) = [axes (3 rows: t1, t2, n), centre(3), half(3)]``.

    The axes follow the surface patch of the node (n the mean facet normal, t1 its principal
    tangent direction), so thin nearly planar patches get thin boxes whatever their orientation in
    the body frame. Extents enclose the triangle vertices (``length`` = 0, target role) or the
    penetration-line segments ``[p, p - length*n_e]`` of the elements (``length`` > 0, base role;
    ``seg_points``/``seg_normals`` in slot order)."""
    n = node_int.shape[0]
    out = np.empty((n, 15))
    m = order.shape[0]
    buf = np.empty((3 * m, 3))
    for node in range(n):
        start = node_int[node, 2]
        count = node_int[node, 3]
        sx = 0.0
        sy = 0.0
        sz = 0.0
        npts = np.int64(0)   # typed, not the literal 0: numba would also compile _node_frame for Literal[int](0)
        for k in range(start, start + count):
            p = order[k]
            e1x = tri[p, 1, 0] - tri[p, 0, 0]
            e1y = tri[p, 1, 1] - tri[p, 0, 1]
            e1z = tri[p, 1, 2] - tri[p, 0, 2]
            e2x = tri[p, 2, 0] - tri[p, 0, 0]
            e2y = tri[p, 2, 1] - tri[p, 0, 1]
            e2z = tri[p, 2, 2] - tri[p, 0, 2]
            sx += e1y * e2z - e1z * e2y
            sy += e1z * e2x - e1x * e2z
            sz += e1x * e2y - e1y * e2x
            if length > 0.0:
                for a in range(3):
                    buf[npts, a] = seg_points[k, a]
                    buf[npts + 1, a] = seg_points[k, a] - length * seg_normals[k, a]
                npts += 2
            else:
                for v in range(3):
                    for a in range(3):
                        buf[npts, a] = tri[p, v, a]
                    npts += 1
        f = _node_frame(sx, sy, sz, buf, npts)
        for r in range(3):
            lo = np.inf
            hi = -np.inf
            ax, ay, az = f[3 * r], f[3 * r + 1], f[3 * r + 2]
            for k in range(npts):
                d = ax * buf[k, 0] + ay * buf[k, 1] + az * buf[k, 2]
                if d < lo:
                    lo = d
                if d > hi:
                    hi = d
            out[node, 3 * r] = ax
            out[node, 3 * r + 1] = ay
            out[node, 3 * r + 2] = az
            mid = 0.5 * (lo + hi)
            out[node, 12 + r] = 0.5 * (hi - lo)
            # centre accumulates mid * axis
            if r == 0:
                out[node, 9] = mid * ax
                out[node, 10] = mid * ay
                out[node, 11] = mid * az
            else:
                out[node, 9] += mid * ax
                out[node, 10] += mid * ay
                out[node, 11] += mid * az
    return out
