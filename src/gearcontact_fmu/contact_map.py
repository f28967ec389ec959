"""The fixed-axis contact map of the bevel pair: what it holds, how it is built, its disk cache.

The map is what the "table" fidelity interpolates (its kernel and model: ``gearcontact_fmu.mesh_models.table``);
this module builds it from the online PCM pair (``gearcontact_fmu.mesh_models.pcm``), keeps it in a disk
cache and ships the rig's healthy map as a seed. Kept apart from the table model, which only interpolates a
map: how a map is computed, tiled, cached, validated on load or seeded never touches the kernel a stage
steps with.

In a torsional model the pair has two rotational degrees of freedom, so the contact response is a
function of the pinion angle theta (a full revolution: a fault sits on one tooth) and the mesh
coordinate s = theta_pinion - (z2/z1) theta_wheel. The map is precomputed with the online PCM
engine on a grid and interpolated at run time:

* rows one pinion pitch apart are equal for healthy teeth, so only the pitch blocks where a faulty
  tooth is in mesh, and one healthy block, are computed; the rest is tiled (:func:`_tabulate_by_pitch`);
* per pinion angle the contact onset of each flank (searched far: after a missing tooth the pinion runs
  ahead and the next tooth first touches at its tip), and the elastic torques and diagnostics on a
  grid of the approach a beyond that onset; bilinear in (theta, a), the onset itself linear in theta,
  periodic in theta;
* contact damping as a torsional damping coefficient D(theta, s) = sum_k A_k w_k h_k^2 (h_k the
  element's normal moment arm about the pinion axis, w_k = min(u_k/t_d, 1)), multiplied at run time
  by c_compression or c_expansion depending on whether the flank in contact approaches or separates;
* friction torques tabulated at a reference rotation (full regularisation) and scaled by the
  regularised sign of the pinion speed.

The approach grid is dense near the onset and covers ``max_torque`` on each flank; between the flanks
(the backlash) the map is zero. Beyond the grid the torque is extrapolated linearly; a penetration
beyond u_max there sets the error status.

The map is cached on disk keyed by a hash of geometry, PCM parameters, resolution, health, mesh files
and grid (``$BEVEL_CACHE_DIR`` or ``~/.cache/bevel-drivetrain``). The package ships the maps of the rig's
healthy gear at the default resolution and grid (``gearcontact_fmu/data/seed_maps``, the same files a
build writes, checked bit for bit against a fresh build by ``tests/gear_contact/test_contact_map.py``): a cache miss
for one of them copies it into the cache instead of building it, so a first run of a healthy scene pays
neither the map build nor the contact kernels' compilation (about a minute on 2 cores).
"""
from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import shutil
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numba as nb
import numpy as np
from numba import njit, types

from gearcontact_fmu import compile_notice, geometry
from gearcontact_fmu.contact import engine
from gearcontact_fmu.elastic_layer import pair_pcm
from gearcontact_fmu.fault_specs import normalised_spec
from gearcontact_fmu.locks import cache_dir  # noqa: F401  (the maps' cache; re-exported)
from gearcontact_fmu.mesh_models.pcm import build_pcm_pair, contact_onset, static_deflection
from gearcontact_fmu.mesh_models.base import (N_OUT, OUT_CONTACT_AREA, OUT_ELASTIC_ENERGY, OUT_MAX_PENETRATION,
                                        OUT_N_CONTACT, OUT_NORMAL_FORCE, OUT_PEAK_PRESSURE, OUT_TAU_PINION,
                                        OUT_TAU_WHEEL, eval_signature, read_only)
from gearcontact_fmu.params import BevelGearParams, MapGrid, MeshResolution, PCMParams, file_sha256, params_hash
from gearcontact_fmu.progress import Silent, reporter as progress_reporter

#: part of every cache key: raised when the map content or the file format changes (6: content digest; 7:
#: faulty maps built from the healthy map, on its approach nodes)
MAP_VERSION = 7
#: part of a faulty map's cache key: raised when a fault's mesh or its rows change (2: local surgery, the
#: fault rows chosen by the fault's patch; 3: partner bands for a wheel spall, crack, part-face chip)
FAULT_VERSION = 3
# channels stored per grid node
CH_TAU_P, CH_TAU_W, CH_N, CH_AREA, CH_PEAK, CH_PEN, CH_FN, CH_EEL, CH_DAMP, CH_FRIC_P, CH_FRIC_W = range(11)
N_CH = 11
SIDE_DRIVE, SIDE_COAST = 0, 1


#: maps shipped with the package (file names as in the cache); see the module docstring
SEED_DIR = Path(__file__).resolve().parent / "data" / "seed_maps"




def _file_digest(path) -> str:
    return file_sha256(path)[:16] if path else ""


@dataclass
class ContactMap:
    """Values on the grid (theta_i, side, a_j): side 0 = drive flank at s = onset_drive(theta) + a,
    side 1 = coast flank at s = onset_coast(theta) - a; a < a[0] is free flight (no contact)."""

    theta: np.ndarray            # (n_theta,) uniform over [0, 2 pi)
    a: np.ndarray                # (n_a,) approach beyond the contact onset [rad at the pinion], increasing
    onset: np.ndarray            # (n_theta, 2) contact onset s of the drive and coast flank [rad]
    values: np.ndarray           # (n_theta, 2, n_a, N_CH)
    gear: BevelGearParams
    pcm: PCMParams
    grid: MapGrid
    info: dict


def _approach_grid(pair, grid: MapGrid) -> tuple[np.ndarray, dict]:
    """Approach nodes beyond the contact onset, dense near it (quadratic), covering max_torque."""

    s_b = geometry.backlash_angle(pair.gear)
    pitch = 2 * math.pi / pair.gear.z_pinion
    # deflection at max torque where the healthy teeth carry (half a turn from tooth 0, where faults
    # sit); the largest over a pitch, plus 30 %
    defl = []
    for th in math.pi + np.linspace(0, pitch, 6, endpoint=False):
        on = contact_onset(pair, th, +1)
        defl.append(static_deflection(pair, th, grid.max_torque, s_onset=on) - on)
    span = 1.3 * float(np.nanmax(defl))
    lead = 0.02 * span
    a = -lead + (span + lead) * np.linspace(0.0, 1.0, grid.s_points) ** 2
    return a, {"span": float(span), "s_backlash": float(s_b), "base_radius": float(geometry.mean_base_radius(pair.gear))}


def compute_map(pair, grid: MapGrid = MapGrid(), progress: bool = False,
                healthy: ContactMap | None = None) -> ContactMap:
    """Tabulate the online PCM engine over (theta, flank, approach beyond each angle's onset).

    Only what differs from a healthy pitch is computed (:func:`_tabulate_by_pitch`): the healthy rows
    (``healthy``, the map of the same gear, PCM parameters, resolution and grid with healthy teeth, or
    else one pitch block of this pair far from its faults, tiled), and the flank rows in which a faulty
    tooth meets its partner. With ``healthy`` the approach nodes are its own (a property of the healthy
    teeth at max_torque). ``progress``: report the rows as they are computed (:mod:`.progress`)."""
    n_rev = pairing_revolutions(pair.gear, wheel_periodic=_faulty_teeth(pair, "wheel") == [])
    n_theta = grid.points_per_pitch * pair.gear.z_pinion * n_rev
    theta = np.linspace(0.0, 2 * math.pi * n_rev, n_theta, endpoint=False)
    t0 = time.perf_counter()
    if healthy is not None:
        a = healthy.a
        ainfo = {k: healthy.info[k] for k in ("span", "s_backlash", "base_radius")}
    else:
        a, ainfo = _approach_grid(pair, grid)
    onset, vals, pinfo = _tabulate_by_pitch(pair, theta, a, grid, n_rev, progress, healthy)
    info = {**ainfo, "build_seconds": time.perf_counter() - t0, "n_theta": n_theta, "n_s": len(a),
            "pinion_revolutions": n_rev,
            "onset_drive": float(np.min(onset[:, SIDE_DRIVE])), "onset_coast": float(np.max(onset[:, SIDE_COAST])),
            "onset_drive_max": float(np.max(onset[:, SIDE_DRIVE])),
            "evaluations": 3 * pinfo["flank_rows_computed"] * len(a), **pinfo, **pair.info, "health": pair.health}
    return ContactMap(theta, a, onset, vals, pair.gear, pair.pcm, grid, info)


def pairing_revolutions(gear: BevelGearParams, wheel_periodic: bool) -> int:
    """Pinion revolutions the map spans: 1 when every wheel tooth is a rotated copy of one tooth (the
    pinion angle alone then fixes the response), else the tooth-pairing period z2 / gcd(z1, z2)
    (4 for 15/60: the same pair of teeth meets again after one wheel revolution)."""
    return 1 if wheel_periodic else gear.z_wheel // math.gcd(gear.z_pinion, gear.z_wheel)


def _faulty_teeth(pair, member: str) -> list[int] | None:
    """Teeth of ``member`` ("pinion" | "wheel") whose geometry differs from the healthy tooth, or None
    when that gear is not built from rotated copies of one tooth (a user mesh): then its teeth cannot
    be told apart without comparing them, and every block is computed."""
    mesh = pair.pinion if member == "pinion" else pair.wheel
    if mesh.meta.get("source") != "analytic":
        return None
    z = pair.gear.z_pinion if member == "pinion" else pair.gear.z_wheel
    present = set(np.unique(mesh.face_tooth).tolist())
    listed = {int(f["tooth"]) % z for f in mesh.meta.get("faults", [])}
    if present | listed != set(range(z)):
        return None                      # a subset of the teeth (a test mesh): no periodicity to use
    return sorted(listed)


def _wheel_block(tooth: int, n_blocks: int) -> int:
    """Pitch block in which wheel ``tooth`` meets the pinion at the centre of the mesh (block b
    spans pinion angles [b, b + 1) pitches; the wheel turns one wheel pitch per block)."""
    return int(tooth) % n_blocks


#: the contact table of an incremental build looks this much beyond the deepest approach node (a fault's
#: patch is re-meshed, so its elements may meet the partner a little before the healthy ones would)
TOUCH_MARGIN = 1.05


def _contact_faces(pair, theta_pinion: float, s: float) -> tuple[np.ndarray, np.ndarray]:
    """The pinion faces and the wheel faces in contact at pinion angle ``theta_pinion`` and mesh coordinate
    ``s`` (static): the elements the engine found in contact (pinion) and the triangles they hit (wheel),
    mapped from its tree order to the meshes' faces."""
    out = np.zeros(N_OUT)
    pair.evaluate(theta_pinion, pair.wheel_angle(theta_pinion, s), 0.0, 0.0, out)
    n = int(out[OUT_N_CONTACT])
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    base, target = pair.bodies[0], pair.bodies[1]
    slots = pair.data.work.active[:n]
    return np.unique(base.order[slots]), np.unique(target.order[pair.data.work.best_j[slots]])


def _contact_teeth(pair, theta_pinion: float, s: float) -> tuple[set, set]:
    """The pinion and wheel teeth with an element in contact at pinion angle ``theta_pinion`` and mesh
    coordinate ``s`` (static)."""
    pf, wf = _contact_faces(pair, theta_pinion, s)
    return (set(np.unique(pair.pinion.face_tooth[pf]).tolist()), set(np.unique(pair.wheel.face_tooth[wf]).tolist()))


class _FaultReach:
    """Where the faults of one gear sit, for the contact table of an incremental build: per faulty tooth
    either the whole tooth (a missing tooth, a fault without a patch) or the patches local surgery replaced
    (:func:`gearcontact_fmu.faults._surgery`: flank, profile and cone-distance ranges), widened by one
    element of the gear's own mesh each way (a finer element of the patch may meet the partner where the
    healthy element next to the patch's edge does). ``touches(faces, shift)``: whether an element among
    ``faces`` (of the block the table is read on), carried ``shift`` teeth on, lies in a fault's reach."""

    def __init__(self, mesh, z: int, faulty):
        from gearcontact_fmu.fault_specs import FLANKS

        self.mesh, self.z = mesh, z
        patches = mesh.meta.get("patches", [])
        patched = {int(p[0]) % z for p in patches}
        whole = {int(f["tooth"]) % z for f in mesh.meta.get("faults", []) if f.get("type") == "missing_tooth"}
        self.whole = set(faulty) - (patched - whole)
        g = geometry.gear_geometry(mesh.meta.get("params") or BevelGearParams(), mesh.meta["role"]) \
            if mesh.meta.get("source") == "analytic" else None
        self.boxes = {}
        if patches and g is not None:
            ds = 1.01 * float(mesh.meta["profile"]) / g.Rm
            rows = np.asarray(geometry.graded_face_nodes(g, mesh.meta["face"], list(mesh.meta.get("face_bands", []))))
            dr = 1.01 * float(np.max(np.diff(rows)))
            for tooth, flank, s_lo, s_hi, r_lo, r_hi in patches:
                self.boxes.setdefault(int(tooth) % z, []).append((FLANKS[flank], s_lo - ds, s_hi + ds, r_lo - dr,
                                                                  r_hi + dr))
            # the strip side of every face: a flank's code, the tip rounding by the way its normal turns
            pts, nrm = mesh.element_points(), mesh.element_normals()
            az = nrm[:, 1] * pts[:, 0] - nrm[:, 0] * pts[:, 1]
            drive = mesh.face_flank == FLANKS["drive"]
            sign = np.sign(np.mean(az[drive])) if np.any(drive) else 1.0
            self.side = np.where(mesh.face_flank != 0, mesh.face_flank,
                                 np.where(az * sign > 0.0, FLANKS["drive"], FLANKS["coast"])).astype(np.int8)
            self.rho = np.linalg.norm(mesh.centroids(), axis=1)

    def touching_shifts(self, faces: np.ndarray, shifts) -> set:
        """The ``shifts`` at which :meth:`touches` holds, the faces' teeth read once: a shift that carries
        none of them onto a faulty tooth is out at once."""
        if faces.size == 0:
            return set()
        faulty = self.whole | set(self.boxes)
        present = np.unique(self.mesh.face_tooth[faces]).tolist()
        return {d for d in shifts if any((t + d) % self.z in faulty for t in present) and self.touches(faces, d)}

    def touches(self, faces: np.ndarray, shift: int) -> bool:
        if faces.size == 0:
            return False
        teeth = self.mesh.face_tooth[faces]
        moved = (teeth + shift) % self.z
        if any(int(t) in self.whole for t in np.unique(moved)):
            return True
        for tooth, boxes in self.boxes.items():
            sel = faces[moved == tooth]
            if sel.size == 0:
                continue
            s, rho, side = self.mesh.face_profile[sel], self.rho[sel], self.side[sel]
            for code, s_lo, s_hi, r_lo, r_hi in boxes:
                if np.any((side == code) & (s > s_lo) & (s < s_hi) & (rho > r_lo) & (rho < r_hi)):
                    return True
        return False


def _fault_window(pair, n_blocks: int):
    """(pinion faulty teeth, wheel faulty teeth, the pitch blocks where they are in mesh, the block
    farthest from all of them, its distance in blocks); None when a gear is not made of rotated copies
    of one tooth (a user mesh)."""
    z1 = pair.gear.z_pinion
    n_rev = n_blocks // z1
    f_pin, f_whl = _faulty_teeth(pair, "pinion"), _faulty_teeth(pair, "wheel")
    if f_pin is None or f_whl is None:
        return None
    centres = [k + m * z1 for k in f_pin for m in range(n_rev)] + [_wheel_block(j, n_blocks) for j in f_whl]
    window = sorted({b % n_blocks for c in centres for b in (c - 1, c)})
    dist = lambda b: min(min((b - w) % n_blocks, (w - b) % n_blocks) for w in window) if window else 0  # noqa: E731
    far = max(range(n_blocks), key=lambda b: (dist(b), -b)) if window else 0
    return f_pin, f_whl, window, far, dist(far)


def _tabulate_by_pitch(pair, theta, a, grid: MapGrid, n_rev: int = 1, progress: bool = False,
                       healthy: ContactMap | None = None):
    """Onsets and values of every row, computing as few rows as the geometry allows.

    Turning the pinion by one pitch and the wheel by one wheel pitch leaves the mesh coordinate s
    unchanged, and generated teeth are rotated copies of one tooth, so a pair of healthy gears has the same
    rows a pitch apart: one block (``points_per_pitch`` rows) is computed and tiled. With faults, the
    healthy rows are the ``healthy`` map's or, without it, the block farthest from every fault, tiled; then
    the flank rows in which a fault's patch (:class:`_FaultReach`; a missing tooth: the tooth) meets its
    partner are computed again:

    Contact forces are sums over the elements in contact, and every fault removes material. Where the
    healthy tooth at a faulty tooth's place touches nothing over a row's whole approach range (its deepest
    node, ``TOUCH_MARGIN`` beyond), the faulty one touches nothing either: that row's onset and values are
    the healthy ones, element for element. Where it touches, the row is computed afresh with the faulty
    pair, exactly as a full build computes it (its onset may move: after a missing tooth the next tooth
    touches later). Which teeth touch in which row is read once, on the block far from every fault
    (:func:`_contact_teeth` at the healthy onsets), and carried to the other blocks by the pitch shift: a
    block later, pinion tooth t + 1 and wheel tooth w + 1 stand where t and w stood.

    Every row is computed when a gear is not made of rotated copies of one tooth (a mesh file) or when the
    faults leave no block two pitches away from all of them."""
    z1, z2 = pair.gear.z_pinion, pair.gear.z_wheel
    per = grid.points_per_pitch
    n_blocks = z1 * n_rev
    fw = _fault_window(pair, n_blocks)
    f_pin, f_whl, window, far, far_dist = fw if fw is not None else ((), (), (), 0, 0)
    if fw is None or (window and far_dist < 2):
        onset, vals = _tabulate(pair, theta, a, grid, progress=progress)
        return onset, vals, {"built": "every row", "rows_computed": len(theta), "flank_rows_computed": 2 * len(theta),
                             "tiled_from_block": None, "fault_blocks": None}
    info = {"rows_computed": 0, "flank_rows_computed": 0}
    if healthy is not None and healthy.values.shape[0] == per * z1:
        base_on, base_v = healthy.onset, healthy.values
        info.update(built="healthy map + fault rows", tiled_from_block=None)
    else:
        idx = np.arange(far * per, (far + 1) * per)
        on_b, v_b = _tabulate(pair, theta[idx], a, grid, progress=progress)
        base_on, base_v = np.tile(on_b, (z1, 1)), np.tile(v_b, (z1, 1, 1, 1))
        info.update(built="one pitch + fault rows" if window else "one pitch", tiled_from_block=far,
                    rows_computed=per, flank_rows_computed=2 * per)
    onset = np.tile(base_on, (n_rev, 1))
    vals = np.tile(base_v, (n_rev, 1, 1, 1))
    sides = np.zeros((len(theta), 2), dtype=bool)
    if window:
        depth = TOUCH_MARGIN * float(a[-1])
        reach_p, reach_w = _FaultReach(pair.pinion, z1, f_pin), _FaultReach(pair.wheel, z2, f_whl)
        for i in range(per):
            r = far * per + i
            for side, sign in ((SIDE_DRIVE, 1.0), (SIDE_COAST, -1.0)):
                pf, wf = _contact_faces(pair, float(theta[r]), float(onset[r, side]) + sign * depth)
                shifts = range(-far, n_blocks - far)          # block b = far + shift
                for d in reach_p.touching_shifts(pf, shifts) | reach_w.touching_shifts(wf, shifts):
                    sides[(far + d) * per + i, side] = True
    rows = np.flatnonzero(sides.any(axis=1))
    if len(rows):
        on_r, v_r = _tabulate(pair, theta[rows], a, grid, sides=sides[rows], progress=progress)
        keep = sides[rows]
        for side in (SIDE_DRIVE, SIDE_COAST):
            sel = rows[keep[:, side]]
            onset[sel, side] = on_r[keep[:, side], side]
            vals[sel, side] = v_r[keep[:, side], side]
    info["rows_computed"] += int(len(rows))
    info["flank_rows_computed"] += int(sides.sum())
    info.update(contact_table_block=far if window else None, fault_blocks=sorted({int(r) // per for r in rows}))
    return onset, vals, info


def map_workers() -> int:
    """Threads that tabulate a map (and build its two contact bodies): $BEVEL_MAP_WORKERS, else every CPU."""
    return max(1, int(os.environ.get("BEVEL_MAP_WORKERS", os.cpu_count() or 1)))


def _progress(pair, flank_rows: int, workers: int, enabled: bool):
    if not enabled:
        return Silent()
    return progress_reporter(f"contact map ({pair.health})", flank_rows, triangles=sum(pair.info.values()),
                             workers=workers)


def _tabulate(pair, theta, a, grid: MapGrid, workers: int | None = None, sides=None, progress: bool = False):
    """Tabulate in parallel over pinion-angle chunks, in ``workers`` threads of this process (the kernels run
    without the GIL; each chunk evaluates with kernel data of its own, the meshes' trees shared).
    ``sides`` (n, 2) bool: the flanks of each row to compute (default both; the others stay zero)."""
    from concurrent.futures import ThreadPoolExecutor

    if sides is None:
        sides = np.ones((len(theta), 2), dtype=bool)
    if workers is None:
        workers = map_workers()
    workers = max(1, min(workers, len(theta)))
    bar = _progress(pair, int(sides.sum()), workers, progress)
    try:
        if workers == 1:
            return _tabulate_rows(pair, theta, a, grid, sides, bar)
        # the chunks: the first row alone, the rest in chunks of about 6 (each chunk's kernel data start afresh, and
        # their candidate caches decide the last bits: these chunks give the maps the forked pool gave)
        parts = []
        n_chunks = min(len(theta) - 1, max(4 * workers, (len(theta) - 1) // 6))
        chunks = [np.arange(1)] + (np.array_split(np.arange(1, len(theta)), n_chunks) if n_chunks > 0 else [])
        with ThreadPoolExecutor(workers) as pool:
            futures = [pool.submit(_tabulate_rows, pair, theta[idx], a, grid, sides[idx]) for idx in chunks]
            try:
                for idx, fut in zip(chunks, futures):
                    parts.append(fut.result())
                    bar.update(int(sides[idx].sum()))
            except BaseException:
                for fut in futures:
                    fut.cancel()
                raise
        return (np.concatenate([p[0] for p in parts], axis=0), np.concatenate([p[1] for p in parts], axis=0))
    finally:
        bar.close()


def _tabulate_rows(pair, theta, a, grid: MapGrid, sides=None, bar=None):
    z1, z2 = pair.gear.z_pinion, pair.gear.z_wheel
    pcm = pair.pcm
    s_b = geometry.backlash_angle(pair.gear)
    s_far = s_b / 2 + grid.max_approach / geometry.mean_base_radius(pair.gear)
    # three engine configurations: elastic only, damping probe, friction at the reference speed
    data_el = pair.data_with(friction=False, damping=False)
    data_fr = pair.data_with(friction=True, damping=False)
    data_dm = pair.data_with(friction=False, damping=True)
    onset = np.zeros((len(theta), 2))
    vals = np.zeros((len(theta), 2, len(a), N_CH))
    a = read_only(a)            # as a map shared by load_map has them: one compilation of the kernel
    out = np.zeros(N_OUT)
    w_ref = grid.reference_speed
    # a small probe rate of the mesh coordinate gives the damping coefficient (damping is linear in
    # the normal velocity, so D = -dT/d(s_dot) / c_compression exactly on the compressing side)
    sdot = 1e-6
    consts = (float(z1), float(z2), sdot, float(w_ref), float(pcm.c_compression))
    datas = (data_el, data_dm, data_fr)
    kernel = _tabulator(nb.typeof(data_el))
    # the onset search on kernel data of its own: a thread may not share the pair's, and the data the rows are
    # evaluated with keep the history a fresh chunk gives them (their candidate cache decides the last bits)
    searching = dataclasses.replace(pair, data=pair.data_with(friction=False, damping=False))
    for i, th in enumerate(theta):
        for side, sign in ((SIDE_DRIVE, 1.0), (SIDE_COAST, -1.0)):
            if sides is not None and not sides[i, side]:
                continue
            on = contact_onset(searching, th, int(sign), max_approach=grid.max_approach)
            if not math.isfinite(on):
                on = sign * s_far                        # nothing touches within the range
            onset[i, side] = on
            kernel(engine.fixed_axis_eval, datas, th, on, sign, a, consts, vals[i, side], out)
            if bar is not None:
                bar.update(1)
    return onset, vals


_TABULATORS: dict = {}


def _tabulator(data_type):
    """:func:`_tabulate_side` compiled for the engine's data of numba type ``data_type``, the engine passed to it
    as a function pointer. Why not a direct call: numba links every kernel a kernel calls into the caller's
    machine code and optimises it all again, so a direct call compiled the contact engine (the longest compile)
    a second time into this kernel, about 7 s of a cold first map. Through the pointer the engine is compiled
    once; the cost is an indirect call per evaluation, nothing beside the engine's own work."""
    kernel = _TABULATORS.get(data_type)
    if kernel is None:
        f64 = types.float64
        sig = types.void(types.FunctionType(eval_signature(engine.fixed_axis_eval, data_type)),
                         types.UniTuple(data_type, 3), f64, f64, f64, types.Array(f64, 1, "C", readonly=True),
                         types.UniTuple(f64, 5), f64[:, ::1], f64[::1])
        kernel = _TABULATORS[data_type] = njit(sig, cache=True, nogil=True)(_tabulate_side)
    return kernel


def _tabulate_side(fixed_axis_eval, datas, th, on, sign, a, consts, rows, out):
    """The rows of one pinion angle and flank (``rows``: one per approach ``a[j]`` past the onset): the
    elastic torques and diagnostics, the damping coefficient from a probe rate ``sdot`` of the mesh
    coordinate, the friction torques at the reference speed. One call from Python per angle and flank:
    the kernel's data (a few hundred arrays in named tuples) is unboxed once, not three times per row."""
    data_el, data_dm, data_fr = datas
    z1, z2, sdot, w_ref, c_compression = consts
    for j in range(a.shape[0]):
        sj = on + sign * a[j]
        thw = (th - sj) * z1 / z2
        fixed_axis_eval(data_el, th, thw, 0.0, 0.0, out)
        row = rows[j]
        row[CH_TAU_P] = out[OUT_TAU_PINION]
        row[CH_TAU_W] = out[OUT_TAU_WHEEL]
        row[CH_N] = out[OUT_N_CONTACT]
        row[CH_AREA] = out[OUT_CONTACT_AREA]
        row[CH_PEAK] = out[OUT_PEAK_PRESSURE]
        row[CH_PEN] = out[OUT_MAX_PENETRATION]
        row[CH_FN] = out[OUT_NORMAL_FORCE]
        row[CH_EEL] = out[OUT_ELASTIC_ENERGY]
        if out[OUT_N_CONTACT] == 0:
            continue
        tp_el = out[OUT_TAU_PINION]
        tw_el = out[OUT_TAU_WHEEL]
        # damping: the pinion moves at a rate that compresses the flank in contact
        fixed_axis_eval(data_dm, th, thw, sign * sdot, 0.0, out)
        d_tp = out[OUT_TAU_PINION] - tp_el
        row[CH_DAMP] = abs(d_tp) / (c_compression * sdot) if c_compression > 0 else 0.0
        # friction at the reference speed with kinematic wheel speed
        fixed_axis_eval(data_fr, th, thw, w_ref, w_ref * z1 / z2, out)
        row[CH_FRIC_P] = out[OUT_TAU_PINION] - tp_el
        row[CH_FRIC_W] = out[OUT_TAU_WHEEL] - tw_el


def kernels_cold() -> bool:
    """True when the map builder's kernels are not compiled yet, here or in numba's cache (the next map build
    compiles them first: :mod:`gearcontact_fmu.compile_notice`)."""
    return compile_notice.kernels_cold(engine.fixed_axis_eval)


def compile_notice_text() -> str:
    """What is said while the map builder's kernels compile."""
    return compile_notice.notice_text(engine.fixed_axis_eval)


def cache_key(gear, pcm, resolution, health, mesh_files, grid, fault_kwargs=None, mesh_units: str = "mm") -> str:
    mf = mesh_files or {}
    files = {k: _file_digest(v) for k, v in mf.items()}
    if files and mesh_units != "mm":         # the same file read in other units is another geometry
        files["units"] = mesh_units
    if health == "healthy":        # the shipped healthy maps keep their names
        return params_hash(gear, pcm, resolution, health, files, grid, fault_kwargs or {}, MAP_VERSION)
    key = (gear, pcm, resolution, health, files, grid, fault_kwargs or {}, MAP_VERSION, FAULT_VERSION)
    bands = _partner_profile(gear, fault_kwargs) if health == "faults" and not files else []
    if bands:                    # a wheel chipped tip's pinion: the other keys stay as they were
        key += ("partner_profile_bands", [list(b) for b in bands])
    return params_hash(*key)


def _partner_profile(gear, fault_kwargs) -> list:
    from gearcontact_fmu import faults

    return faults.partner_profile_bands(gear, (fault_kwargs or {}).get("faults", []), "pinion")


_MAP_ARRAYS = ("theta", "a", "onset", "values")


def content_digest(arrays: dict, info: str) -> str:
    """SHA-256 over the map's arrays (dtype, shape and bytes, in a fixed order) and its info text: a
    file whose content was altered in any way no longer matches the digest stored with it."""
    h = hashlib.sha256()
    for k in _MAP_ARRAYS:
        arr = np.ascontiguousarray(arrays[k])
        h.update(f"{k}:{arr.dtype.str}:{arr.shape};".encode())
        h.update(arr.tobytes())
    h.update(info.encode("utf-8"))
    return h.hexdigest()


def distinct_rows(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, index)``: the distinct rows (first axis) of ``values`` in the order they first occur, and for
    every row of ``values`` the index of its copy among them (``rows[index]`` is ``values``, bit for bit).
    A map is mostly one pitch block tiled (every pitch of healthy teeth is the same), so a wheel fault's
    four-revolution map of 2,880 rows holds about 120 distinct ones."""
    flat = np.ascontiguousarray(values).reshape(len(values), -1)
    first: dict = {}
    index = np.empty(len(values), dtype=np.int64)
    for i, row in enumerate(flat):
        index[i] = first.setdefault(row.tobytes(), len(first))
    keep = np.unique(index, return_index=True)[1]             # each distinct row's first occurrence, in order
    return np.ascontiguousarray(values[keep]), index


def save_map(cmap: ContactMap, path: Path) -> None:
    """Write the map with its content digest to a temporary file, then rename (never half a file). The values
    are written as their distinct rows and each row's index among them (``value_rows``; :func:`distinct_rows`),
    the digest is over the whole arrays: a faulty map is a healthy pitch tiled with a few rows of its own, and
    writing the tiles again cost a four-revolution map 0.54 s and 18 MB (now about 1 MB)."""
    arrays = {k: getattr(cmap, k) for k in _MAP_ARRAYS}
    info = repr(cmap.info)
    tmp = Path(str(path) + f".tmp{os.getpid()}")
    rows, index = distinct_rows(arrays["values"])
    members = {**arrays, "values": rows, "value_rows": index, "info": np.array(info),
               "digest": np.array(content_digest(arrays, info))}
    # an .npz as np.savez_compressed writes it, at zlib's fastest level: a map's values are floats that
    # deflate hardly at all (24.3 MB to 18.1 at the default level, 18.4 at level 1, for a map written whole)
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for name, arr in members.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.asanyarray(arr), allow_pickle=False)
    os.replace(tmp, path)


class ContactMapFileError(ValueError):
    """A contact-map file that cannot be read or does not hold a map of the expected layout."""


#: maps read in this process: {(path, inode, mtime_ns, size, gear, pcm, grid, n_rev): (arrays, info)}, the arrays
#: read-only and shared by every ContactMap returned for that file state (at most LOADED_MAPS_KEPT, the latest)
_LOADED: dict = {}
LOADED_MAPS_KEPT = 4


def load_map(path: Path, gear, pcm, grid, n_rev: int = 1) -> ContactMap:
    """Read a cached map and check its layout against the gear, grid and pinion revolutions it was
    asked for (a truncated or altered file raises ContactMapFileError naming the file and the problem,
    never a wrong map). A file read before in this process, unchanged since (the same inode, modification time
    and size), is not read, decompressed and digested again: its checked arrays are shared, read-only (an
    assembly reads the same map for every start state it looks for; a record calibration hundreds of times)."""
    try:
        st = os.stat(path)
        key = (str(path), st.st_ino, st.st_mtime_ns, st.st_size, gear, pcm, grid, int(n_rev))
        hash(key)
    except (OSError, TypeError):
        key = None
    hit = _LOADED.get(key) if key is not None else None
    if hit is None:
        cmap = _read_map(path, gear, pcm, grid, n_rev)
        if key is None:
            return cmap
        arrays = (cmap.theta, cmap.a, cmap.onset, cmap.values)
        for arr in arrays:
            arr.flags.writeable = False
        hit = (arrays, dict(cmap.info))
        _LOADED.pop(key, None)
        _LOADED[key] = hit
        while len(_LOADED) > LOADED_MAPS_KEPT:
            _LOADED.pop(next(iter(_LOADED)))
    (theta, a, onset, values), info = hit
    return ContactMap(theta, a, onset, values, gear, pcm, grid, dict(info))


def _read_map(path: Path, gear, pcm, grid, n_rev: int = 1) -> ContactMap:
    """:func:`load_map` from the file itself."""
    import ast

    try:
        with np.load(path, allow_pickle=False) as z:
            info_text = str(z["info"])
            arrays = {k: z[k].copy() for k in _MAP_ARRAYS}
            stored = str(z["digest"]) if "digest" in z.files else None
            index = z["value_rows"] if "value_rows" in z.files else None      # a map written whole: none
        info = ast.literal_eval(info_text)
    except (OSError, EOFError, ValueError, KeyError, SyntaxError, zipfile.BadZipFile) as exc:
        raise ContactMapFileError(f"contact map {path}: unreadable ({type(exc).__name__}: {exc})") from None
    if index is not None:
        rows = arrays["values"]
        if not (index.ndim == 1 and index.dtype.kind in "iu" and rows.ndim >= 1 and len(rows)
                and (index.size == 0 or (int(index.min()) >= 0 and int(index.max()) < len(rows)))):
            raise ContactMapFileError(f"contact map {path}: its value_rows do not index its {len(rows)} distinct "
                                      "rows (altered or corrupted)")
        arrays["values"] = rows[index]
    if stored is None:
        raise ContactMapFileError(f"contact map {path}: no content digest (written by an older version)")
    if content_digest(arrays, info_text) != stored:
        raise ContactMapFileError(f"contact map {path}: its content does not match its digest (altered or "
                                  "corrupted)")
    theta, a, onset, values = (arrays[k] for k in _MAP_ARRAYS)
    n_theta = grid.points_per_pitch * gear.z_pinion * n_rev
    want = {"theta": (theta, (n_theta,)), "a": (a, (grid.s_points,)), "onset": (onset, (n_theta, 2)),
            "values": (values, (n_theta, 2, grid.s_points, N_CH))}
    problems = [f"{k} has shape {arr.shape}, expected {shape}" for k, (arr, shape) in want.items()
                if arr.shape != shape]
    problems += [f"{k} holds {int(np.size(arr) - np.isfinite(arr).sum())} non-finite values"
                 for k, (arr, _) in want.items() if arr.shape == want[k][1]
                 and not np.all(np.isfinite(arr))]
    if not problems and not (np.all(np.diff(theta) > 0) and np.all(np.diff(a) > 0)):
        problems.append("its angle or approach nodes are not increasing")
    if problems:
        raise ContactMapFileError(f"contact map {path}: " + "; ".join(problems))
    return ContactMap(theta, a, onset, values, gear, pcm, grid, info)


def wheel_faults(health: str, fault_kwargs: dict | None) -> list:
    """The generated faults of a configuration that sit on the wheel."""
    if health != "faults":
        return []
    return [f for f in (fault_kwargs or {}).get("faults", []) if normalised_spec(f)["member"] == "wheel"]


def incremental_from_healthy(gear, health: str, mesh_files, fault_kwargs) -> bool:
    """Whether a configuration's map is built from the healthy map (:func:`_tabulate_by_pitch`):
    generated gears with generated faults, whose healthy teeth are the healthy gear's. Not with a mesh
    file, nor with a wheel pit, for which every pinion tooth gets extra face rows
    (faults.partner_face_bands) and so differs from the healthy pinion, nor with a wheel chipped tip (extra
    profile nodes, faults.partner_profile_bands)."""
    from gearcontact_fmu import faults

    if health == "healthy" or any((mesh_files or {}).values()) or health not in faults.GENERATED_HEALTH:
        return False
    specs = (fault_kwargs or {}).get("faults", [])
    return not (faults.partner_face_bands(gear, specs, "pinion") or faults.partner_profile_bands(gear, specs, "pinion"))


def _build_map(gear, pcm, resolution, health, mesh_files, mesh_units, grid, fault_kwargs,
               healthy: ContactMap | None = None) -> ContactMap:
    pair = build_pcm_pair(gear, pcm, resolution, health, mesh_files.get("pinion"), mesh_files.get("wheel"),
                          mesh_units, friction=True, damping=True, fault_kwargs=fault_kwargs, threads=map_workers())
    return compute_map(pair, grid, progress=True, healthy=healthy)


def map_file_name(gear, pcm, resolution, health, mesh_files, grid, mesh_units, fault_kwargs) -> str:
    """The file name of a configuration's map, in the cache and among the shipped ones (SEED_DIR)."""
    return f"contactmap-{cache_key(gear, pcm, resolution, health, mesh_files, grid, fault_kwargs, mesh_units)}.npz"


def get_map(gear: BevelGearParams | None = None, pcm: PCMParams | None = None,
            resolution: MeshResolution | None = None, health: str = "healthy", mesh_files=None,
            grid: MapGrid | None = None, mesh_units: str = "mm", use_cache: bool = True,
            fault_kwargs: dict | None = None, build: bool = True) -> ContactMap | None:
    """The contact map for this configuration, from the disk cache or computed (and cached).
    ``build=False``: only from the cache (None when it is not there)."""
    gear = gear or BevelGearParams()
    pcm = pair_pcm(gear, pcm)
    resolution = resolution or MeshResolution()
    grid = grid or MapGrid()
    mesh_files = {k: v for k, v in (mesh_files or {}).items() if v}
    path = cache_dir() / map_file_name(gear, pcm, resolution, health, mesh_files, grid, mesh_units, fault_kwargs)
    n_rev = pairing_revolutions(gear, wheel_periodic=not (mesh_files.get("wheel") or wheel_faults(health, fault_kwargs)))

    def cached() -> ContactMap:
        cm = load_map(path, gear, pcm, grid, n_rev)
        cm.info["cache"] = str(path)
        cm.info["from_cache"] = True
        return cm

    problem = None
    seed = SEED_DIR / path.name
    if use_cache and not path.exists() and seed.exists():
        # a shipped map (the same bytes a build writes): copied in, then read and checked like any cached map
        tmp = Path(str(path) + f".tmp{os.getpid()}")
        shutil.copyfile(seed, tmp)
        os.replace(tmp, path)
    if use_cache and path.exists():
        try:
            return cached()
        except ContactMapFileError as exc:
            # a cache, not data: a damaged file is moved aside (kept for inspection) and rebuilt
            problem = f"{exc}; moved to {path.name}.damaged and rebuilt"
            if not build:
                return None
            os.replace(path, Path(str(path) + ".damaged"))
    if not build:
        return None
    healthy = None
    if incremental_from_healthy(gear, health, mesh_files, fault_kwargs):
        # a faulty map is the healthy one (shipped or cached, whatever ``use_cache`` says for this map)
        # with the faulty teeth's rows computed again
        healthy = get_map(gear, pcm, resolution, "healthy", None, grid)
    if use_cache:
        # one build per map: a second process asking for the same map waits and reads the first's
        from gearcontact_fmu.locks import file_lock

        with file_lock(path.with_suffix(".lock")):
            if path.exists():
                try:
                    return cached()
                except ContactMapFileError:
                    pass            # damaged meanwhile: built again below
            with compile_notice.compiling(engine.fixed_axis_eval):
                cmap = _build_map(gear, pcm, resolution, health, mesh_files, mesh_units, grid, fault_kwargs, healthy)
            save_map(cmap, path)
    else:
        with compile_notice.compiling(engine.fixed_axis_eval):
            cmap = _build_map(gear, pcm, resolution, health, mesh_files, mesh_units, grid, fault_kwargs, healthy)
    cmap.info["cache"] = str(path)
    cmap.info["from_cache"] = False
    if problem:
        cmap.info["cache_problem"] = problem
    return cmap


def seed_configurations() -> list[dict]:
    """The configurations whose maps ship in SEED_DIR: the rig's healthy gear at the default parameters,
    resolution and grid (the example scene and every healthy scene that keeps the defaults)."""
    return [dict(gear=BevelGearParams(), pcm=PCMParams(), resolution=MeshResolution(), health="healthy",
                 grid=MapGrid())]


def seed_path(config: dict) -> Path:
    """Where the shipped map of a seed configuration is (named by its cache key)."""
    key = cache_key(config["gear"], config["pcm"], config["resolution"], config["health"], {}, config["grid"])
    return SEED_DIR / f"contactmap-{key}.npz"


def refresh_seed_maps() -> list[Path]:
    """Build the seed maps afresh (no cache) and write them to SEED_DIR, removing stale ones (a
    maintainer's step after a change of the map code or of a default: MAP_VERSION, the key)."""
    SEED_DIR.mkdir(parents=True, exist_ok=True)
    paths = []
    for config in seed_configurations():
        cmap = _build_map(config["gear"], config["pcm"], config["resolution"], config["health"], {}, "mm",
                          config["grid"], None)
        path = seed_path(config)
        save_map(cmap, path)
        paths.append(path)
    for old in SEED_DIR.glob("contactmap-*.npz"):
        if old not in paths:
            old.unlink()
    return paths


def static_penetration(cmap: ContactMap, pinion_torque_Nm: float) -> tuple[float, float]:
    """Largest element penetration [m] over a pinion revolution when the mesh carries the static pinion
    torque ``pinion_torque_Nm`` (> 0 loads the drive flank, < 0 the coast flank), and the pinion angle
    [rad] where it occurs. Per pinion-angle row of the map, the approach at which the elastic torque
    balances the load is interpolated and the penetration read there; a row whose tabulated range
    does not reach the load counts as inf (the load is beyond the map). Used to refuse, before a run,
    a u_max that the static load alone would exceed."""
    side = SIDE_DRIVE if pinion_torque_Nm >= 0.0 else SIDE_COAST
    load = abs(float(pinion_torque_Nm))
    worst, at = 0.0, 0.0
    for i in range(cmap.values.shape[0]):
        carried = np.abs(cmap.values[i, side, :, CH_TAU_P])
        if carried.max() < load:
            return math.inf, float(cmap.theta[i])
        j = int(np.argmax(carried >= load))
        if j == 0:
            pen = float(cmap.values[i, side, 0, CH_PEN])
        else:
            w = (load - carried[j - 1]) / (carried[j] - carried[j - 1])
            pen = float((1 - w) * cmap.values[i, side, j - 1, CH_PEN] + w * cmap.values[i, side, j, CH_PEN])
        if pen > worst:
            worst, at = pen, float(cmap.theta[i])
    return worst, at
