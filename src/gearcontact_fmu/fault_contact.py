"""How much contact a fault gets: the labels ``contact_share`` and ``mesh_torque_drop`` of a fault.

A fault label is only as good as the contact behind it. A pit on the coast flank of a gear that runs under
a driving load, or a chipped tip above the end of the active profile, changes the geometry and almost no
force: a dataset row that says "pit" then carries almost no physics. Two numbers say how much a fault
meets the load, both at the run's load, before any dynamics:

* ``contact_share`` [1]: the share of the fault's flank area inside the loaded contact region of its tooth
  over one mesh cycle. The region is found on the healthy pair (the online PCM at the run's geometry and
  mesh resolution): at ``N_ANGLES`` pinion angles across the engagement of tooth 0 the wheel sits at the
  pair's static deflection under the load, and the flank elements of tooth 0 in contact are recorded in
  the flank's own coordinates, the profile parameter s (arc length on the unit sphere from the root cone)
  and the cone distance rho. Per face row the path of contact sweeps a profile interval; the region is
  the union of those intervals, widened by half a profile element. Healthy teeth are alike, so tooth 0's
  region is every tooth's. The fault's footprint (:func:`gearcontact_fmu.faults.fault_footprint`, where it
  removes material) is sampled on a fine (s, rho) grid weighted by area (rho ds drho). A fault on the
  flank that does not carry the load gets 0; a missing tooth's footprint is its loaded flank, so its share
  is the active part of that flank. Left out: manufacturing errors (a rigid offset, the region stays) and
  tooth compliance.
* ``mesh_torque_drop`` [1]: the largest relative drop of the mesh torque at fixed mesh coordinate, read
  from the contact maps: at every pinion angle of the faulty map, the mesh coordinate where the healthy
  map carries the load (its static deflection), and there 1 - tau_faulty / tau_healthy. 1: at some angle
  the fault takes the whole load off (a missing tooth in single contact); 0: the fault never touches.

Contact search, element sets and shares are separate steps with plain arrays between them; the region,
which costs an online PCM pair (about 10 s on 2 cores), is cached on disk beside the contact maps, keyed
by the geometry, the PCM parameters, the resolution, the loaded flank and the load.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gearcontact_fmu import geometry
from gearcontact_fmu.elastic_layer import pair_pcm
from gearcontact_fmu.fault_specs import FLANKS, loaded_flank, normalised_spec
from gearcontact_fmu.locks import cache_dir, file_lock
from gearcontact_fmu.params import BevelGearParams, MeshResolution, PCMParams, params_hash

#: pinion angles at which the contact of tooth 0 is recorded, over ENGAGEMENT_PITCHES of the pinion
N_ANGLES = 48
#: the span of pinion angles around tooth 0's mesh [pinion pitches]: its engagement (epsilon_alpha = 1.55
#: pitches centred 0.06 pitch before theta = 0) with margin
ENGAGEMENT_PITCHES = (-1.3, 1.2)
#: the (s, rho) sampling of a fault's footprint
FOOTPRINT_SAMPLES = (640, 200)
#: part of the region cache's key: raised when the region's content changes
REGION_VERSION = 1


@dataclass(frozen=True)
class Region:
    """The loaded contact region of tooth 0's loaded flank of one gear: per face row (bins of the face
    element size from the inner cone distance ``rho0``) the profile interval [s_lo, s_hi] its elements in
    contact swept over the cycle (NaN: no contact in that row), widened by ``margin`` [rad]."""

    member: str
    flank: str
    rho0: float
    row: float
    s_lo: np.ndarray
    s_hi: np.ndarray
    margin: float

    def contains(self, s, rho, flank: str) -> np.ndarray:
        s, rho = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(rho, dtype=float))
        if flank != self.flank:
            return np.zeros(s.shape, dtype=bool)
        k = np.floor((rho - self.rho0) / self.row).astype(np.int64)
        ok = (k >= 0) & (k < self.s_lo.size)
        kk = np.clip(k, 0, max(self.s_lo.size - 1, 0))
        lo, hi = self.s_lo[kk] - self.margin, self.s_hi[kk] + self.margin
        with np.errstate(invalid="ignore"):
            return ok & (s >= lo) & (s <= hi)

    def to_dict(self) -> dict:
        return {"member": self.member, "flank": self.flank, "rho0": self.rho0, "row": self.row,
                "s_lo": self.s_lo.tolist(), "s_hi": self.s_hi.tolist(), "margin": self.margin}

    @classmethod
    def from_dict(cls, d: dict) -> "Region":
        return cls(d["member"], d["flank"], float(d["rho0"]), float(d["row"]),
                   np.array(d["s_lo"], dtype=float), np.array(d["s_hi"], dtype=float), float(d["margin"]))


def contact_points(gear: BevelGearParams, pcm: PCMParams, resolution: MeshResolution, torque: float,
                   n_angles: int = N_ANGLES) -> dict[str, np.ndarray]:
    """{member: (n, 3) array of (s, rho, theta_pinion)} of tooth 0's loaded-flank elements in contact on the
    healthy pair, at ``n_angles`` pinion angles across its engagement, the wheel at the static deflection
    (mesh_models.pcm.static_deflection on the loaded flank) under the pinion torque ``torque`` (> 0 driving)
    [N m]."""
    from gearcontact_fmu.contact import engine
    from gearcontact_fmu.mesh_models.pcm import build_pcm_pair, static_deflection

    pair = build_pcm_pair(gear, pcm, resolution, friction=False, damping=False)
    sign = FLANKS[loaded_flank(torque)]
    base, target, r0p, r0w = pair.bodies
    pitch = 2.0 * math.pi / gear.z_pinion
    found = {"pinion": [], "wheel": []}
    meshes = {"pinion": pair.pinion, "wheel": pair.wheel}
    for th in np.linspace(ENGAGEMENT_PITCHES[0] * pitch, ENGAGEMENT_PITCHES[1] * pitch, n_angles):
        try:          # the wheel at the static deflection under |torque| on the loaded flank
            s = static_deflection(pair, float(th), abs(torque), rtol=1e-10, flank=sign)
        except (RuntimeError, engine.PenetrationError):
            continue                  # no equilibrium within reach at this angle: it adds no contact
        if not math.isfinite(s):
            continue
        tw = pair.wheel_angle(float(th), s)
        res = engine.evaluate_pair(base, target, (geometry.pose(r0p, float(th)), np.zeros(3)),
                                   (geometry.pose(r0w, tw), np.zeros(3)), pcm=pcm, friction=False, damping=False,
                                   check_penetration=False)
        for member, idx in (("pinion", res.base_idx), ("wheel", res.target_idx)):
            m = meshes[member]
            idx = np.unique(idx)
            sel = idx[(m.face_tooth[idx] == 0) & (m.face_flank[idx] == sign)]
            found[member].append(np.c_[m.face_profile[sel], np.linalg.norm(m.face_points[sel], axis=1),
                                       np.full(sel.size, th)])
    return {k: (np.vstack(v) if v else np.zeros((0, 3))) for k, v in found.items()}


def region_from_points(points: np.ndarray, gear: BevelGearParams, resolution: MeshResolution, member: str,
                       flank: str) -> Region:
    """The region of the contact points (:func:`contact_points`) of one gear: per face row the interval they
    span, widened by half a profile element."""
    g = geometry.gear_geometry(gear, member)
    row = float(resolution.face)
    n = max(int(math.ceil((g.Re - g.Ri) / row)), 1)
    lo, hi = np.full(n, np.nan), np.full(n, np.nan)
    if len(points):
        k = np.clip(np.floor((points[:, 1] - g.Ri) / row).astype(np.int64), 0, n - 1)
        for i in range(n):
            s = points[k == i, 0]
            if s.size:
                lo[i], hi[i] = s.min(), s.max()
    return Region(member, flank, float(g.Ri), row, lo, hi, 0.5 * float(resolution.profile) / g.Rm)


def _region_path(gear, pcm, resolution, torque: float) -> Path:
    key = params_hash(gear, pcm, resolution, loaded_flank(torque), f"{abs(torque):.9g}", N_ANGLES,
                      ENGAGEMENT_PITCHES, REGION_VERSION)
    return cache_dir() / f"contactregion-{key}.json"


def loaded_regions(gear: BevelGearParams | None = None, pcm: PCMParams | None = None,
                   resolution: MeshResolution | None = None, torque: float = 3.7566,
                   use_cache: bool = True) -> dict[str, Region]:
    """{"pinion": Region, "wheel": Region} of the healthy pair under the pinion torque ``torque`` [N m]
    (> 0 driving), from the disk cache or computed (and cached; one computation per configuration when
    several processes ask at once)."""
    gear = gear or BevelGearParams()
    pcm, resolution = pair_pcm(gear, pcm), resolution or MeshResolution()
    if not (math.isfinite(torque) and torque != 0.0):
        raise ValueError(f"the loaded contact region needs a non-zero finite pinion torque, not {torque!r}")
    path = _region_path(gear, pcm, resolution, torque)

    def read():
        try:
            d = json.loads(path.read_text())
            return {m: Region.from_dict(d[m]) for m in ("pinion", "wheel")}
        except (OSError, ValueError, KeyError, TypeError):
            return None

    if use_cache and (got := read()) is not None:
        return got

    def compute():
        pts = contact_points(gear, pcm, resolution, torque)
        return {m: region_from_points(pts[m], gear, resolution, m, loaded_flank(torque)) for m in pts}

    if not use_cache:
        return compute()
    with file_lock(path.with_suffix(".lock")):
        if (got := read()) is not None:
            return got
        regions = compute()
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text(json.dumps({m: r.to_dict() for m, r in regions.items()}))
        tmp.replace(path)
    return regions


def contact_share(spec: dict, regions: dict[str, Region], gear: BevelGearParams | None = None) -> float:
    """The share of the fault's footprint (a fault specification, scene units) inside the loaded region of
    its gear: 0 .. 1."""
    from gearcontact_fmu.faults import fault_footprint

    gear = gear or BevelGearParams()
    spec = normalised_spec(spec)
    region = regions[spec["member"]]
    flank = spec.get("flank", region.flank)          # a missing tooth: its loaded flank
    s, rho, w, inside = fault_footprint(gear, spec, flank=flank, samples=FOOTPRINT_SAMPLES)
    area = float(np.sum(w[inside]))
    if area <= 0.0:
        return 0.0
    return float(np.sum(w[inside & region.contains(s, rho, flank)]) / area)


def row_drops(healthy, faulty, torque: float) -> tuple[np.ndarray, np.ndarray]:
    """(pinion angles of the faulty map's rows, the relative drop of the mesh torque at each): at the mesh
    coordinate where the healthy map (same grid) carries the pinion torque ``torque`` [N m] (> 0 driving),
    1 - tau_faulty / tau_healthy; NaN where the healthy map's range does not reach the load."""
    from gearcontact_fmu.contact_map import CH_TAU_P, SIDE_COAST, SIDE_DRIVE

    side = SIDE_DRIVE if torque >= 0.0 else SIDE_COAST
    sign = 1.0 if side == SIDE_DRIVE else -1.0
    T = abs(float(torque))
    n_h = healthy.theta.size
    if faulty.a.shape != healthy.a.shape or abs((faulty.theta[1] - faulty.theta[0])
                                                - (healthy.theta[1] - healthy.theta[0])) > 1e-12:
        raise ValueError("the healthy and the faulty map must share their grid")
    drops = np.full(faulty.theta.size, np.nan)
    for i in range(faulty.theta.size):
        ih = i % n_h
        tau_h = np.abs(healthy.values[ih, side, :, CH_TAU_P])
        if tau_h[-1] < T:
            continue                                   # beyond the map's range: not judged here
        j = min(max(int(np.searchsorted(tau_h, T)), 1), tau_h.size - 1)
        a_h = np.interp(T, tau_h[j - 1:j + 1], healthy.a[j - 1:j + 1])
        s = healthy.onset[ih, side] + sign * a_h       # the healthy static deflection at this angle
        a_f = sign * (s - faulty.onset[i, side])
        tau_f = 0.0 if not a_f > faulty.a[0] else float(np.interp(a_f, faulty.a,
                                                                  np.abs(faulty.values[i, side, :, CH_TAU_P])))
        drops[i] = 1.0 - tau_f / T
    return faulty.theta.copy(), drops


def mesh_torque_drop(healthy, faulty, torque: float) -> float:
    """The largest relative drop of the mesh torque at fixed mesh coordinate between the healthy and the
    faulty contact map (gearcontact_fmu.contact_map.ContactMap of the same grid) under the pinion torque
    ``torque`` [N m] (> 0 driving), over the faulty map's angles (:func:`row_drops`): 0 .. 1 (1: the fault
    takes the whole load off at some angle)."""
    _, drops = row_drops(healthy, faulty, torque)
    worst = float(np.nanmax(drops)) if np.any(np.isfinite(drops)) else 0.0
    return min(max(worst, 0.0), 1.0)


__all__ = ["Region", "loaded_flank", "contact_points", "region_from_points", "loaded_regions", "contact_share",
           "mesh_torque_drop", "row_drops", "N_ANGLES"]
