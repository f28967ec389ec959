"""The PCM kernels' data as named tuples (numba types them as heterogeneous named tuples; a field access
compiles to the same code as a loose array argument).

A module of its own, importing nothing but the standard library: numba's on-disk cache of the gear stage
(``gearcontact_fmu.stage``) records the types of every mesh model it has compiled for, and unpickling that
index imports the module that defines them. Declared here, the types cost a run of another fidelity (an
``ideal`` or ``analytic`` gear) nothing; declared in :mod:`kernels`, they loaded the PCM kernels into it.
Fields as in the layouts of :mod:`gearcontact_fmu.contact.kernels`. Keep them here: that index pickles
the types by module and name, so a move breaks the stale cache of a module whose source did not change
("Can't get attribute ...") until its ``__pycache__/*.nbi`` files are deleted.
"""
from collections import namedtuple

#: base body in the base role for one search length: tree ``node_int``, segment boxes ``seg``
#: (b_seg), oriented boxes ``obb`` (b_obb), elements ``elem`` (belem), slot ``order`` and its ``inv``
BaseMesh = namedtuple("BaseMesh", "node_int seg obb elem order inv")
#: target body in the target role: tree ``node_int``, boxes ``box`` (t_box), ``obb`` (t_obb),
#: triangles ``tri`` (ttri), slot ``order`` and its ``inv``
TargetMesh = namedtuple("TargetMesh", "node_int box obb tri order inv")
#: base workspace (per base body and user)
Workspace = namedtuple("Workspace", "stamp call best_u best_j line active stack")
#: what a collecting traversal (mode 1 of :func:`_traverse`) writes: candidate pairs ``cand``,
#: near-leaf stamps ``nstamp`` and count ``icount``, far-check ranges ``fc``, ``minsep``, ``nbox``
Collect = namedtuple("Collect", "cand nstamp icount fc minsep nbox")
#: pose scratch of the fixed-axis kernel: ``Rbt``, ``tbt`` (base in the target frame), ``Rc`` (the
#: pose shifted by the list's pitches), ``dR``, ``dt`` (motion between two poses)
Poses = namedtuple("Poses", "Rbt tbt Rc dR dt")
#: the candidate list in use: ``pairs`` (cand), clearances ``c s d h`` (cand_c ...), per element
#: ``g f`` (cand_g, cand_f), skip thresholds ``x`` (cand_x), ``elem_q``, ``elem_x``, ``elem_hit``
Candidates = namedtuple("Candidates", "pairs c s d h g f x elem_q elem_x elem_hit")
#: the list's validity data over the far-check cut of the base tree (``fnode``, ``fc``, ``slot_f``),
#: near leaves (``nstamp``, ``icount``, ``nbox``), distances ``minsep``, ``close`` nodes, motion
#: bounds ``ndisp`` and running sums ``nsum`` from ``nd0``
FarCheck = namedtuple("FarCheck", "fnode fc slot_f nstamp icount minsep nbox close ndisp nsum nd0")
#: the pitch atlas: ``period`` and the snapshots ``meta`` (atlas_meta), pool ``pairs``, ``c s d h x``
#: (atlas_c ...), ``minsep``, ``nbox``, ``close``
Atlas = namedtuple("Atlas", "period meta pairs c s d h x minsep nbox close")
#: the fixed-axis kernel's data (:func:`fixed_axis_eval`, built by engine.make_fixed_axis_data):
#: ``M`` = R0_target^T R0_base, ``ab0`` = M[:, 2], ``params`` (N_PARAMS,), ``cache`` (N_CACHE,)
FixedAxisData = namedtuple("FixedAxisData",
                           "base target M ab0 params cache work poses cands far atlas")
#: rigid motion of the generic pair (:func:`pair_forces`): target pose ``Rt``, ``tt``, base origin
#: ``tb``, velocities (origin, omega) ``vb``, ``wb`` of the base and ``vt``, ``wt`` of the target
Motion = namedtuple("Motion", "Rt tt tb vb wb vt wt")
#: what :func:`pair_forces` writes: per element ``base target u point normal fn ft area``, the body
#: ``force`` and ``moment`` on the target, ``diag`` (N_DIAG,)
ElementForces = namedtuple("ElementForces", "base target u point normal fn ft area force moment diag")
#: a candidate list's validity data for :func:`_cache_check`: its pose ``ref[o:o+12]``, far group
#: bound ``gfar``, ``nclose`` close far-check nodes ``close``, their ``nbox`` and ``minsep``
ListBounds = namedtuple("ListBounds", "ref o gfar nclose close nbox minsep")

__all__ = ["BaseMesh", "TargetMesh", "Workspace", "Collect", "Poses", "Candidates",
           "FarCheck", "Atlas", "FixedAxisData", "Motion", "ElementForces", "ListBounds"]
