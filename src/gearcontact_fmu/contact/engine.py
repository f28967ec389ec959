"""Polygonal contact method (PCM) between two rigid bodies with triangle surface meshes.

Python API over the numba kernels of :mod:`.kernels`:

* :class:`PCMBody` - one body: its mesh in the body frame, element data and AABB tree;
* :func:`evaluate_pair` - contact search, element forces and body forces of a base/target pair in
  a general pose, returning a :class:`ContactResult`;
* :func:`make_fixed_axis_data` + :func:`fixed_axis_eval` - the numba kernel of a pair whose bodies
  only rotate about fixed axes through the world origin (the gear stage's ``mesh_eval``).

Conventions (docs/ARCHITECTURE.md): SI units; pose ``(R, t)`` with R body->world and t the body
origin in the world; velocities ``(v, omega)`` with v the velocity of the body origin, both in the
world. The base body's elements probe the target surface: a penetration line runs from each base
element point along the base element's inward normal; the penetration u is its distance to the
smallest accepted hit: a target triangle facing the base (n_base . n_target < 0) whose flat
triangle the line meets at a line parameter s in [-s_neg, L] (L the search length, default
2 u_max; s_neg = 0 for facet targets, else the largest facet-to-exact-plane deviation of the target
x 2), with u in (0, L] measured to the hit element's exact tangent plane when the target has exact
face data (else u = s). An element deeper than u_max is an error state (PenetrationError /
status 1), never a clipped value. The element normal force acts along the base element's outward
normal at the point ``p - u/2 n`` (mid-layer): on the target with +, on the base with -.

Cost: the search touches only tree nodes near the target (surface-patch oriented boxes), so it
follows the number of elements within the search length of the contact, not the mesh size. The
fixed-axis kernel adds a candidate cache (temporal coherence, exact results): see
:func:`make_fixed_axis_data` and :func:`kernels.cached_search`. Three layers, each exact:

* candidate lists (pairs within 20 um, valid while the motion since their build stays below the
  margins), rebuilt by a tree traversal (~2-5 ms on the converged bevel pair) when they expire;
* skip thresholds: each list carries, per element and per pair, how far it may move before a hit
  (or an entry) becomes possible; running sums of per-call motion bounds say how far it moved,
  and a call tests only the pairs whose threshold the sum has reached, about the elements in
  contact and their near neighbours. A tested pair gets a new threshold from its clearance at
  that pose (re-anchored), so the thresholds do not age with the list
  (:func:`kernels.search_candidates_skip`); the same sums prove the list valid most calls;
* the pitch atlas (pairs whose meshes are rotated copies of one tooth, checked on the meshes,
  :func:`pitch_symmetry`): every list built is kept, and a later pitch, which meets the same
  geometry with other tooth pairs, is served from the kept lists, renumbered, instead of the tree.
  In a steady run the traversals stop after the first pitch. Faulty pairs and mesh files fail the
  check and keep the first two layers.

Measured (benchmarks/bench_pcm_trajectory.py, loaded healthy pair) in docs/GEAR-CONTACT.md. The
goal of issue 13 (<= 10 us per evaluation along a trajectory) is not reached: a call still tests
~1.5 pairs per element in contact (the hit itself, entries, the nearest neighbours) plus the
validity sums, and a kept list is mapped (renumbered, sorted) every ~30 sub-steps of 1 us.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..params import PCMParams
from . import kernels as K
from .records import Atlas, BaseMesh, Candidates, ElementForces, FarCheck, FixedAxisData, Motion, Poses, TargetMesh, Workspace
from .bvh import LEAF_SIZE, build_bvh, node_obbs, refit_segment_boxes
from .kernels import fixed_axis_eval  # noqa: F401  (re-exported: the gear stage imports it here)

__all__ = [
    "PCMBody", "ContactResult", "PenetrationError", "evaluate_pair", "make_fixed_axis_data",
    "fixed_axis_eval", "rot_z", "cache_stats", "reset_cache", "clear_atlas", "pitch_symmetry",
]

DEFAULT_CACHE_MARGIN = 2e-5   # [m] candidate cache margin of the fixed-axis kernel
DEFAULT_CACHE_FAR = 4e-5      # [m] far margin of the candidate cache (2 x the margin: builds half as costly as 0.1 mm, same reuse)
FAR_CHECK_NODES = 256         # size of the base-tree cut used by the cache validity check


class PenetrationError(RuntimeError):
    """An element penetrates deeper than PCMParams.u_max (an error state of the model)."""


def rot_z(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class PCMBody:
    """A rigid body's triangle surface mesh (body frame, m) prepared for PCM.

    ``vertices`` (n, 3) [m], ``faces`` (m, 3) int (counter-clockwise seen from outside: the
    geometric normal points out of the body). Optional ``face_points`` (m, 3) and ``face_normals``
    (m, 3): exact surface point and outward normal per element (e.g. from an analytic flank); they
    replace the centroid and the facet normal as element point/normal, and a target's penetration
    is measured to that exact tangent plane.

    Attributes (triangle order): ``tri`` (m,3,3), ``area`` (m,), ``points`` (m,3), ``normals``
    (m,3), ``geo_normals`` (m,3); tree ``node_box``, ``node_int``, ``order``; slot-ordered kernel
    arrays ``belem`` (m,7) and ``ttri`` (m,18), oriented node boxes ``node_obb`` (N,15) (see
    :mod:`.kernels`).
    """

    def __init__(self, vertices, faces, face_points=None, face_normals=None,
                 leaf_size: int = LEAF_SIZE):
        v = np.ascontiguousarray(vertices, dtype=np.float64)
        f = np.ascontiguousarray(faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError("vertices must have shape (n, 3)")
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
            raise ValueError("faces must have shape (m, 3), m > 0")
        if f.min() < 0 or f.max() >= v.shape[0]:
            raise ValueError("faces index outside the vertex array")
        self.vertices = v
        self.faces = f
        tri = np.ascontiguousarray(v[f])
        m = f.shape[0]
        has_exact = face_points is not None or face_normals is not None
        if has_exact:
            if face_points is None or face_normals is None:
                raise ValueError("give both face_points and face_normals, or neither")
            fp = np.ascontiguousarray(face_points, dtype=np.float64)
            fn = np.ascontiguousarray(face_normals, dtype=np.float64)
            if fp.shape != (m, 3) or fn.shape != (m, 3):
                raise ValueError("face_points/face_normals must have shape (m, 3)")
            nrm = np.linalg.norm(fn, axis=1)
            if np.any(nrm <= 0.0) or not np.all(np.isfinite(fn)) or not np.all(np.isfinite(fp)):
                raise ValueError("face_normals must be finite and non-zero")
            fn = fn / nrm[:, None]
        else:
            fp = np.zeros((1, 3))
            fn = np.zeros((1, 3))
        belem, ttri = K.element_data(tri, fp, fn, has_exact)
        if has_exact:
            geo = ttri[:, 3:6]
            ok = belem[:, 6] > 0.0
            bad = np.count_nonzero(np.einsum("ij,ij->i", geo[ok], fn[ok]) < 0.0)
            if bad:
                raise ValueError(f"{bad} face_normals point against the triangle winding "
                                 "(faces must be counter-clockwise seen from outside)")
        self.tri = tri
        self.has_exact = has_exact
        self.area = belem[:, 6].copy()
        self.points = belem[:, 0:3].copy()
        self.normals = belem[:, 3:6].copy()
        self.geo_normals = ttri[:, 3:6].copy()
        self.node_box, self.node_int, self.order, self.max_depth = build_bvh(
            tri, leaf_size=leaf_size, extra_points=self.points if has_exact else None)
        self.belem = np.ascontiguousarray(belem[self.order])
        self.node_obb = node_obbs(self.node_int, self.order, tri, np.zeros((1, 3)),
                                  np.zeros((1, 3)), 0.0)
        self._tri = tri
        # outward reach of a penetration line needed when u is measured to the exact tangent
        # plane: 2 x the largest distance of a triangle's vertices from its exact tangent plane
        if has_exact:
            dev = np.abs(np.einsum("ijk,ik->ij", tri - belem[:, None, 0:3], belem[:, 3:6]))
            self.s_neg = float(2.0 * dev.max())
        else:
            self.s_neg = 0.0
        self.ttri = np.ascontiguousarray(ttri[self.order])
        self.inv = _inverse(self.order)
        self._seg_boxes = {}
        self._ws = None
        self._target = None

    @property
    def n_faces(self) -> int:
        return self.faces.shape[0]

    def segment_boxes(self, length: float):
        """Base-role node volumes of the penetration lines of length ``length``: axis-aligned
        ``(N, 6) = [centre, half]`` and oriented ``(N, 15)`` (see :func:`bvh.node_obbs`)."""
        key = float(length)
        box = self._seg_boxes.get(key)
        if box is None:
            p = np.ascontiguousarray(self.belem[:, 0:3])
            n = np.ascontiguousarray(self.belem[:, 3:6])
            box = (refit_segment_boxes(self.node_int, p, n, key),
                   node_obbs(self.node_int, self.order, self._tri, p, n, key))
            self._seg_boxes[key] = box
        return box

    def base_mesh(self, length: float) -> BaseMesh:
        """The body in the base role for penetration lines of length ``length`` (kernel data)."""
        seg, obb = self.segment_boxes(length)
        return BaseMesh(self.node_int, seg, obb, self.belem, self.order, self.inv)

    def target_mesh(self) -> TargetMesh:
        """The body in the target role (kernel data)."""
        if self._target is None:
            self._target = TargetMesh(self.node_int, self.node_box, self.node_obb, self.ttri,
                                        self.order, self.inv)
        return self._target

    def far_check_nodes(self, n_target: int = FAR_CHECK_NODES):
        """A cut of the tree into about ``n_target`` subtrees (nodes at one depth, or shallower
        leaves), numbered in depth-first order: ``fnode`` (F,) their node indices, ``fc``
        (N, 2) the range [f_lo, f_hi) of cut nodes under (or above) each node."""
        key = ("fc", n_target)
        hit = self._seg_boxes.get(key)
        if hit is not None:
            return hit
        depth = max(0, int(np.ceil(np.log2(max(n_target, 1)))))
        ni = self.node_int
        fc = np.zeros((ni.shape[0], 2), dtype=np.int64)
        fnode = []
        # iterative DFS: (node, depth, state)
        stack = [(0, 0, 0)]
        while stack:
            node, d, state = stack.pop()
            if state == 0:
                fc[node, 0] = len(fnode)
                if d == depth or ni[node, 0] < 0:
                    fnode.append(node)
                    fc[node, 1] = len(fnode)
                    # the subtree below the cut maps to this cut node
                    sub = [ni[node, 0], ni[node, 1]] if ni[node, 0] >= 0 else []
                    while sub:
                        q = sub.pop()
                        fc[q, 0] = len(fnode) - 1
                        fc[q, 1] = len(fnode)
                        if ni[q, 0] >= 0:
                            sub += [ni[q, 0], ni[q, 1]]
                    continue
                stack.append((node, d, 1))
                stack.append((ni[node, 1], d + 1, 0))
                stack.append((ni[node, 0], d + 1, 0))
            else:
                fc[node, 1] = len(fnode)
        hit = (np.array(fnode, dtype=np.int64), fc)
        self._seg_boxes[key] = hit
        return hit

    def new_workspace(self) -> Workspace:
        """Base-role work arrays (:class:`kernels.Workspace`)."""
        m = self.n_faces
        return Workspace(stamp=np.zeros(m, dtype=np.int64), call=np.zeros(1, dtype=np.int64),
                           best_u=np.full(m, np.inf), best_j=-np.ones(m, dtype=np.int64),
                           line=np.zeros((m, 7)), active=np.zeros(m, dtype=np.int64),
                           stack=np.zeros((4 * (self.max_depth + 64), 2), dtype=np.int64))

    def workspace(self):
        if self._ws is None:
            self._ws = self.new_workspace()
        return self._ws


@dataclass
class ContactResult:
    """Result of :func:`evaluate_pair` (world frame, SI).

    Body forces: ``force_base`` = -``force_target``; ``moment_base``/``moment_target`` about the
    world origin; ``moment_base_origin``/``moment_target_origin`` about each body's origin t.
    Elements (one row per base element in contact): ``base_idx``, ``target_idx`` (triangle
    indices), ``u`` penetration, ``point`` force point, ``normal`` base outward normal, ``F_n``
    normal force (on the target along +normal), ``F_t`` friction force on the target, ``area``.
    """

    force_base: np.ndarray
    force_target: np.ndarray
    moment_base: np.ndarray
    moment_target: np.ndarray
    moment_base_origin: np.ndarray
    moment_target_origin: np.ndarray
    base_idx: np.ndarray
    target_idx: np.ndarray
    u: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    F_n: np.ndarray
    F_t: np.ndarray
    area: np.ndarray
    n_contact: int
    contact_area: float
    peak_pressure: float
    max_penetration: float
    normal_force: float
    elastic_energy: float
    dissipated_power: float
    status: int


def _pose(pose):
    R, t = pose
    R = np.ascontiguousarray(R, dtype=np.float64).reshape(3, 3)
    t = np.ascontiguousarray(t, dtype=np.float64).reshape(3)
    return R, t


def _vel(vel):
    if vel is None:
        return np.zeros(3), np.zeros(3)
    v, w = vel
    return (np.ascontiguousarray(v, dtype=np.float64).reshape(3),
            np.ascontiguousarray(w, dtype=np.float64).reshape(3))


def evaluate_pair(base: PCMBody, target: PCMBody, pose_base, pose_target, vel_base=None,
                  vel_target=None, pcm: PCMParams = PCMParams(), friction: bool = True,
                  damping: bool = True, search_length: float | None = None,
                  check_penetration: bool = True) -> ContactResult:
    """Contact of ``base`` against ``target`` in the given poses ``(R, t)`` and velocities
    ``(v_origin, omega)`` (world). ``search_length`` defaults to 2 u_max. Raises
    :class:`PenetrationError` when an element penetrates deeper than ``pcm.u_max`` (unless
    ``check_penetration`` is False: then ``status`` is 1 in the result)."""
    Rb, tb = _pose(pose_base)
    Rt, tt = _pose(pose_target)
    vb, wb = _vel(vel_base)
    vt, wt = _vel(vel_target)
    params = K.make_params(pcm, search_length, friction, damping, s_neg=target.s_neg)
    L = params[K.P_L]
    Rbt = np.ascontiguousarray(Rt.T @ Rb)
    tbt = Rt.T @ (tb - tt)
    ws = base.workspace()
    bm = base.base_mesh(L)
    tm = target.target_mesh()
    n = K.search_pair(bm, tm, Rbt, tbt, L, params[K.P_SNEG], ws)
    e = ElementForces(base=np.empty(n, dtype=np.int64), target=np.empty(n, dtype=np.int64),
                        u=np.empty(n), point=np.empty((n, 3)), normal=np.empty((n, 3)),
                        fn=np.empty(n), ft=np.empty((n, 3)), area=np.empty(n),
                        force=np.zeros(3), moment=np.zeros(3), diag=np.zeros(K.N_DIAG))
    K.pair_forces(n, ws, bm, tm, Motion(Rt=Rt, tt=tt, tb=tb, vb=vb, wb=wb, vt=vt, wt=wt),
                  params, e)
    diag, force_t, moment_t = e.diag, e.force, e.moment
    status = int(diag[K.D_STATUS])
    if status and check_penetration:
        raise PenetrationError(
            f"penetration {diag[K.D_UMAX]:.6g} m exceeds u_max = {pcm.u_max:.6g} m "
            f"({np.count_nonzero(e.u > pcm.u_max)} elements)")
    force_b = -force_t
    moment_b = -moment_t
    return ContactResult(
        force_base=force_b, force_target=force_t.copy(),
        moment_base=moment_b, moment_target=moment_t.copy(),
        moment_base_origin=moment_b - np.cross(tb, force_b),
        moment_target_origin=moment_t - np.cross(tt, force_t),
        base_idx=e.base, target_idx=e.target, u=e.u, point=e.point, normal=e.normal,
        F_n=e.fn, F_t=e.ft, area=e.area,
        n_contact=int(diag[K.D_N]), contact_area=float(diag[K.D_AREA]),
        peak_pressure=float(diag[K.D_PEAK_P]), max_penetration=float(diag[K.D_UMAX]),
        normal_force=float(diag[K.D_FN]), elastic_energy=float(diag[K.D_EEL]),
        dissipated_power=float(diag[K.D_PDISS]), status=status)


def make_fixed_axis_data(base_body: PCMBody, target_body: PCMBody, R0_base, R0_target,
                         pcm: PCMParams = PCMParams(), friction: bool = True,
                         damping: bool = True, *, search_length: float | None = None,
                         cache_margin: float | None = None, cache_far: float | None = None,
                         cache_phi: float = 0.02, cache_capacity: int | None = None,
                         periods: tuple[int, int] | None = None, atlas_snapshots: int = 1024,
                         atlas_pairs: int | None = None) -> FixedAxisData:
    """numba-typable data of :func:`fixed_axis_eval` (a :class:`kernels.FixedAxisData` named tuple
    of named tuples of arrays) for a pair rotating about fixed axes through the world origin:
    pose_base = (R0_base @ Rz(theta_base), 0), likewise the target; the axes are R0[:, 2]. The
    data own their work arrays and cache (one per concurrent user).

    Candidate cache (temporal coherence, results identical to the exact search): candidate pairs
    are collected with margin ``cache_margin`` [m] (default 20 um; 0 disables the cache) for the
    base parts within ``cache_far`` (default 0.04 mm, or 10 x a given margin) of the target and
    reused while the relative motion since the collection stays below the margins (see
    :func:`kernels.cached_search`; relative rotation below ``cache_phi`` rad). ``cache_capacity``: candidate pairs (default max(1e5, m_base/2)); on
    overflow the call falls back to the exact search (counted in the cache statistics).

    Pitch atlas: ``periods = (z_base, z_target)`` (tooth counts) declares that each mesh may be
    invariant under a turn by one pitch about its axis; :func:`pitch_symmetry` checks it on the
    meshes (rotated copies of one tooth within 1e-13 m, tooth after tooth in the face order), and
    only then the kernel keeps every candidate list it builds (up to ``atlas_snapshots`` lists
    and ``atlas_pairs`` pairs, default max(4e6, 40 per base triangle), then emptied) and serves later pitches from them, mapped to the
    current tooth pairs (bit-identical results, see :func:`kernels.cached_search`). Faulty pairs
    and mesh files fail the check and use the cache without the atlas.

    Fields (see :mod:`.kernels` for the array layouts): ``base`` (:class:`kernels.BaseMesh`, the
    base body for the search length), ``target`` (:class:`kernels.TargetMesh`), ``M = R0_target.T
    @ R0_base``, ``ab0 = M[:, 2]`` (base axis in the target's reference frame), ``params`` (see
    :func:`kernels.make_params`), ``cache`` (kernels.N_CACHE,) cache state and statistics (see
    ``kernels.C_*``), ``work`` (:class:`kernels.Workspace`), ``poses`` (:class:`kernels.Poses`,
    scratch), ``cands`` (:class:`kernels.Candidates`, the list in use), ``far``
    (:class:`kernels.FarCheck`, its validity data), ``atlas`` (:class:`kernels.Atlas`; its
    ``period`` = (pitch angle, triangles per tooth) of the base and the target, zeros: no atlas).
    Memory of the
    atlas: 24 bytes per pair of the pool and ~16 kB per snapshot (allocated, touched as used).
    """
    R0b = np.asarray(R0_base, dtype=np.float64).reshape(3, 3)
    R0t = np.asarray(R0_target, dtype=np.float64).reshape(3, 3)
    for R in (R0b, R0t):
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ValueError("R0 must be a rotation matrix")
    if cache_margin is None:
        cache_margin = DEFAULT_CACHE_MARGIN
        if cache_far is None:
            cache_far = DEFAULT_CACHE_FAR
    params = K.make_params(pcm, search_length, friction, damping, s_neg=target_body.s_neg,
                           cache_margin=cache_margin, cache_far=cache_far, cache_phi=cache_phi)
    L = params[K.P_L]
    M = np.ascontiguousarray(R0t.T @ R0b)
    ab0 = np.ascontiguousarray(M[:, 2].copy())
    if cache_capacity is None:
        cache_capacity = max(100_000, base_body.n_faces // 2)
    cap = int(cache_capacity) if cache_margin > 0 else 1
    nb = base_body.node_int.shape[0]
    fnode, fc = base_body.far_check_nodes()
    nf = fnode.shape[0]
    period = np.zeros(4)
    n_snap, n_pool = 1, 1
    if periods is not None and cache_margin > 0:
        sb = pitch_symmetry(base_body, int(periods[0]))
        st = pitch_symmetry(target_body, int(periods[1]))
        if atlas_pairs is None:
            # a pitch keeps ~300 lists of ~0.04 pairs per base triangle (measured at 0.05 x 2 and
            # 0.025 x 1 mm): room for about two pitches
            atlas_pairs = max(4_000_000, 40 * base_body.n_faces)
        if sb is not None and st is not None and atlas_snapshots > 0 and atlas_pairs > 0:
            period[:] = (sb[0], sb[1], st[0], st[1])
            n_snap, n_pool = int(atlas_snapshots), int(atlas_pairs)
    slot_f = np.zeros(base_body.n_faces, dtype=np.int64)      # far-check node of each base slot
    for f, node in enumerate(fnode):
        lo = base_body.node_int[node, 2]
        slot_f[lo:lo + base_body.node_int[node, 3]] = f
    i64 = np.int64
    return FixedAxisData(
        base=base_body.base_mesh(L), target=target_body.target_mesh(), M=M, ab0=ab0,
        params=params, cache=np.zeros(K.N_CACHE), work=base_body.new_workspace(),
        poses=Poses(Rbt=np.zeros((3, 3)), tbt=np.zeros(3), Rc=np.zeros((3, 3)),
                      dR=np.zeros((3, 3)), dt=np.zeros(3)),
        cands=Candidates(pairs=np.zeros((cap, 2), dtype=i64), c=np.zeros(cap),
                           s=np.zeros(cap), d=np.zeros(cap), h=np.zeros(cap),
                           g=np.zeros(cap, dtype=i64), f=np.zeros(cap, dtype=i64),
                           x=np.zeros(cap), elem_q=np.zeros(cap, dtype=i64),
                           elem_x=np.zeros(cap), elem_hit=np.zeros(cap, dtype=np.bool_)),
        far=FarCheck(fnode=fnode, fc=fc, slot_f=slot_f, nstamp=np.zeros(nb, dtype=i64),
                       icount=np.zeros(1, dtype=i64), minsep=np.full(nf, np.inf),
                       nbox=np.zeros((nf, 6)), close=np.zeros(nf, dtype=i64),
                       ndisp=np.zeros(nf + 1), nsum=np.zeros(nf), nd0=np.zeros(nf)),
        atlas=Atlas(period=period, meta=np.zeros((n_snap, K.N_SNAP)),
                      pairs=np.zeros((n_pool, 2), dtype=np.int32),
                      c=np.zeros(n_pool, dtype=np.float32), s=np.zeros(n_pool, dtype=np.float32),
                      d=np.zeros(n_pool, dtype=np.float32), h=np.zeros(n_pool, dtype=np.float32),
                      x=np.zeros(n_pool, dtype=np.float32), minsep=np.zeros((n_snap, nf)),
                      nbox=np.zeros((n_snap, nf, 6)), close=np.zeros((n_snap, nf), dtype=i64)))


def _inverse(order: np.ndarray) -> np.ndarray:
    inv = np.empty_like(order)
    inv[order] = np.arange(order.shape[0])
    return inv


PITCH_TOL = 1e-13      # [m] congruence of the teeth required by the pitch atlas (4x < kernels.ATLAS_EPS)
PITCH_TOL_NORMAL = 1e-12


def pitch_symmetry(body: PCMBody, z: int):
    """``(phi, shift)`` when turning ``body`` by phi = +-2 pi/z about its z axis maps triangle i
    onto triangle i + shift (mod m), shift = m/z: every tooth t (triangles t*shift ...) is tooth 0
    turned by t*phi, vertices and exact points within PITCH_TOL, exact normals within
    PITCH_TOL_NORMAL (so any two teeth are congruent within 2 PITCH_TOL). Generated healthy gears
    are built that way; faults, mesh files and other numberings give None."""
    m = body.n_faces
    if z < 2 or m % z:
        return None
    shift = m // z
    arrays = (body.tri.reshape(z, shift, 3, 3), body.points.reshape(z, shift, 1, 3),
              body.normals.reshape(z, shift, 1, 3))
    for sign in (-1.0, 1.0):
        phi = sign * 2.0 * np.pi / z
        ok = True
        for t in range(1, z):
            R = rot_z(t * phi)
            for arr, tol in zip(arrays, (PITCH_TOL, PITCH_TOL, PITCH_TOL_NORMAL)):
                if np.abs(arr[t] - arr[0] @ R.T).max() > tol:
                    ok = False
                    break
            if not ok:
                break
        if ok:
            return phi, shift
    return None


def cache_stats(data: FixedAxisData) -> dict:
    """Statistics of the candidate cache of fixed-axis data."""
    c = data.cache
    return {"builds": int(c[K.C_BUILDS]), "cached_calls": int(c[K.C_CALLS]),
            "overflows": int(c[K.C_OVERFLOW]), "n_candidates": int(c[K.C_NCAND]),
            "exact_calls": int(c[K.C_EXACT]), "near_leaves": int(c[K.C_NNEAR]),
            "skipped_elements": int(c[K.C_SKIPPED]), "tested_pairs": int(c[K.C_TESTED]),
            "visited_elements": int(c[K.C_VISITED]), "tested_pairs_total": int(c[K.C_TESTED_ALL]),
            "reanchored_total": int(c[K.C_RETESTS_ALL]),
            "atlas": bool(data.atlas.period[1] > 0), "atlas_snapshots": int(c[K.C_NSNAP]),
            "atlas_hits": int(c[K.C_AHITS]), "atlas_cleared": int(c[K.C_ACLEAR]),
            "valid": bool(c[K.C_VALID])}


def reset_cache(data: FixedAxisData) -> None:
    """Invalidate the candidate cache (the next call rebuilds it) and end any cool-down."""
    data.cache[K.C_VALID] = 0.0
    data.cache[K.C_COOL] = 0.0


def clear_atlas(data: FixedAxisData) -> None:
    """Forget the pitch atlas's snapshots (and invalidate the cache)."""
    reset_cache(data)
    data.cache[K.C_NSNAP] = 0.0
    data.cache[K.C_ATOP] = 0.0
