"""Fixed-axis contact map of the bevel pair ("table" fidelity).

In a torsional model the pair has two rotational degrees of freedom, so the contact response is a
function of the pinion angle theta (a full revolution: a fault sits on one tooth) and the mesh
coordinate s = theta_pinion - (z2/z1) theta_wheel. The map is precomputed with the online PCM
engine on a grid and interpolated at run time:

* elastic torques on pinion and wheel and the diagnostics, bilinear in (theta, s), periodic in theta;
* contact damping as a torsional damping coefficient D(theta, s) = sum_k A_k w_k h_k^2 (h_k the
  element's normal moment arm about the pinion axis, w_k = min(u_k/t_d, 1)), multiplied at run time
  by c_compression or c_expansion depending on whether the flank in contact approaches or separates;
* friction torques tabulated at a reference rotation (full regularisation) and scaled by the
  regularised sign of the pinion speed.

The s grid is dense near the contact onset of each flank and covers the drive flank up to
``max_torque`` (and the coast flank the same); between the flanks (the backlash) the map is zero. Beyond
the grid the torque is extrapolated linearly; a penetration beyond u_max sets the error status.

The map is cached on disk keyed by a hash of geometry, PCM parameters, resolution, health, mesh files
and grid (``$BEVEL_CACHE_DIR`` or ``~/.cache/bevel-drivetrain``).
"""
from __future__ import annotations

import hashlib
import math
import os
import time
from dataclasses import dataclass, asdict
from pathlib import Path

import numpy as np
from numba import njit

from gearcontact_fmu import geometry
from gearcontact_fmu.fidelity import (N_OUT, OUT_CONTACT_AREA, OUT_DISSIPATED_POWER, OUT_ELASTIC_ENERGY,
                                      OUT_MAX_PENETRATION, OUT_N_CONTACT, OUT_NORMAL_FORCE,
                                      OUT_PEAK_PRESSURE, OUT_STATUS, OUT_TAU_PINION, OUT_TAU_WHEEL)
from gearcontact_fmu.params import BevelGearParams, MeshResolution, PCMParams, params_hash

MAP_VERSION = 1
# channels stored per grid node
CH_TAU_P, CH_TAU_W, CH_N, CH_AREA, CH_PEAK, CH_PEN, CH_FN, CH_EEL, CH_DAMP, CH_FRIC_P, CH_FRIC_W = range(11)
N_CH = 11


@dataclass(frozen=True)
class MapGrid:
    points_per_pitch: int = 48          # pinion-angle nodes per pinion pitch (full revolution stored)
    s_points: int = 48                  # nodes per flank along the mesh coordinate
    max_torque: float = 200.0           # pinion torque [N·m] the drive/coast range must cover
    reference_speed: float = 100.0      # pinion speed [rad/s] at which friction is tabulated
    omega_regularisation: float = 1.0   # pinion speed [rad/s] below which friction is ramped out


def cache_dir() -> Path:
    d = Path(os.environ.get("BEVEL_CACHE_DIR", Path.home() / ".cache" / "bevel-drivetrain"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def _file_digest(path) -> str:
    if not path:
        return ""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:16]


@dataclass
class ContactMap:
    theta: np.ndarray            # (n_theta,) uniform over [0, 2 pi)
    s: np.ndarray                # (n_s,) increasing
    values: np.ndarray           # (n_theta, n_s, N_CH)
    gear: BevelGearParams
    pcm: PCMParams
    grid: MapGrid
    info: dict

    def data(self, friction: bool = True, damping: bool = True) -> tuple:
        return make_table_data(self, friction, damping)

    def evaluate(self, theta_pinion, theta_wheel, omega_pinion=0.0, omega_wheel=0.0,
                 friction=True, damping=True, out=None):
        if out is None:
            out = np.zeros(N_OUT)
        table_eval(self.data(friction, damping), float(theta_pinion), float(theta_wheel),
                   float(omega_pinion), float(omega_wheel), out)
        return out


def _s_grid(pair, grid: MapGrid) -> tuple[np.ndarray, dict]:
    """Mesh-coordinate nodes: both flanks, dense near contact onset, plus the backlash gap."""
    from gearcontact_fmu.gearpair import _base_radius, static_deflection

    s_b = geometry.backlash_angle(pair.gear)
    # earliest onset over a pitch (the onset varies a little with angle for modified/faulty teeth)
    th_probe = np.linspace(0, 2 * math.pi, 4 * pair.gear.z_pinion, endpoint=False)
    from gearcontact_fmu.gearpair import contact_onset

    onsets_d = [contact_onset(pair, th, +1) for th in th_probe]
    onsets_c = [contact_onset(pair, th, -1) for th in th_probe]
    onset_d = np.nanmin(onsets_d)
    onset_c = np.nanmax(onsets_c)
    # load range: the deflection at max torque (at the stiffest angle this is the least, so take the
    # largest over a pitch and add 30 %)
    pitch = 2 * math.pi / pair.gear.z_pinion
    defl = [static_deflection(pair, th, grid.max_torque) - onset_d
            for th in np.linspace(0, pitch, 6, endpoint=False) + 0.5 * pitch]
    span = 1.3 * float(np.nanmax(defl))
    # quadratic spacing: fine near onset
    q = np.linspace(0.0, 1.0, grid.s_points) ** 2
    lead = 0.02 * span
    drive = onset_d - lead + (span + lead) * q
    coast = onset_c + lead - (span + lead) * q
    s = np.unique(np.concatenate([coast[::-1], [0.5 * (onset_c + onset_d)], drive]))
    return s, {"onset_drive": float(onset_d), "onset_coast": float(onset_c), "span": float(span),
               "s_backlash": float(s_b), "base_radius": float(_base_radius(pair.gear))}


def compute_map(pair, grid: MapGrid = MapGrid(), progress: bool = False) -> ContactMap:
    """Tabulate the online PCM engine over (theta, s)."""
    from gearcontact_fmu.contact import engine

    z1, z2 = pair.gear.z_pinion, pair.gear.z_wheel
    n_theta = grid.points_per_pitch * z1
    theta = np.linspace(0.0, 2 * math.pi, n_theta, endpoint=False)
    s, sinfo = _s_grid(pair, grid)
    t0 = time.perf_counter()
    vals = _tabulate(pair, theta, s, grid)
    info = {**sinfo, "build_seconds": time.perf_counter() - t0, "n_theta": n_theta, "n_s": len(s),
            "evaluations": 3 * n_theta * len(s), **pair.info, "health": pair.health}
    return ContactMap(theta, s, vals, pair.gear, pair.pcm, grid, info)


def _tabulate(pair, theta, s, grid: MapGrid, workers: int | None = None) -> np.ndarray:
    """Tabulate in parallel over pinion-angle chunks (fork: the workers inherit the built pair)."""
    import multiprocessing as mp

    if workers is None:
        workers = int(os.environ.get("BEVEL_MAP_WORKERS", os.cpu_count() or 1))
    workers = max(1, min(workers, len(theta)))
    if workers == 1 or "fork" not in mp.get_all_start_methods():
        return _tabulate_rows(pair, theta, s, grid)
    chunks = np.array_split(np.arange(len(theta)), 4 * workers)
    global _FORK_STATE
    _FORK_STATE = (pair, theta, s, grid)
    try:
        with mp.get_context("fork").Pool(workers) as pool:
            parts = pool.map(_tabulate_chunk, chunks)
    finally:
        _FORK_STATE = None
    return np.concatenate(parts, axis=0)


_FORK_STATE = None


def _tabulate_chunk(idx):
    pair, theta, s, grid = _FORK_STATE
    return _tabulate_rows(pair, theta[idx], s, grid)


def _tabulate_rows(pair, theta, s, grid: MapGrid) -> np.ndarray:
    from gearcontact_fmu.contact import engine

    z1, z2 = pair.gear.z_pinion, pair.gear.z_wheel
    pcm = pair.pcm
    # three engine configurations: elastic only, damping probe, friction at the reference speed
    data_el = pair.data_with(friction=False, damping=False)
    data_fr = pair.data_with(friction=True, damping=False)
    data_dm = pair.data_with(friction=False, damping=True)
    vals = np.zeros((len(theta), len(s), N_CH))
    out = np.zeros(N_OUT)
    w_ref = grid.reference_speed
    # a small probe rate of the mesh coordinate gives the damping coefficient (damping is linear in
    # the normal velocity, so D = -dT/d(s_dot) / c_compression exactly on the compressing side)
    sdot = 1e-6
    for i, th in enumerate(theta):
        for j, sj in enumerate(s):
            thw = (th - sj) * z1 / z2
            engine.fixed_axis_eval(data_el, th, thw, 0.0, 0.0, out)
            vals[i, j, CH_TAU_P] = out[OUT_TAU_PINION]
            vals[i, j, CH_TAU_W] = out[OUT_TAU_WHEEL]
            vals[i, j, CH_N] = out[OUT_N_CONTACT]
            vals[i, j, CH_AREA] = out[OUT_CONTACT_AREA]
            vals[i, j, CH_PEAK] = out[OUT_PEAK_PRESSURE]
            vals[i, j, CH_PEN] = out[OUT_MAX_PENETRATION]
            vals[i, j, CH_FN] = out[OUT_NORMAL_FORCE]
            vals[i, j, CH_EEL] = out[OUT_ELASTIC_ENERGY]
            if out[OUT_N_CONTACT] == 0:
                continue
            tp_el = out[OUT_TAU_PINION]
            tw_el = out[OUT_TAU_WHEEL]
            # damping: the pinion moves ahead at rate sdot, compressing the drive flank (s > 0) or
            # relieving the coast flank (s < 0); use the sign that compresses the flank in contact
            rate = sdot if sj > 0 else -sdot
            engine.fixed_axis_eval(data_dm, th, thw, rate, 0.0, out)
            d_tp = out[OUT_TAU_PINION] - tp_el
            vals[i, j, CH_DAMP] = abs(d_tp) / (pcm.c_compression * sdot) if pcm.c_compression > 0 else 0.0
            # friction at the reference speed with kinematic wheel speed
            engine.fixed_axis_eval(data_fr, th, thw, w_ref, w_ref * z1 / z2, out)
            vals[i, j, CH_FRIC_P] = out[OUT_TAU_PINION] - tp_el
            vals[i, j, CH_FRIC_W] = out[OUT_TAU_WHEEL] - tw_el
    return vals


def cache_key(gear, pcm, resolution, health, mesh_files, grid, fault_kwargs=None) -> str:
    mf = mesh_files or {}
    return params_hash(gear, pcm, resolution, health, {k: _file_digest(v) for k, v in mf.items()},
                       grid, fault_kwargs or {}, MAP_VERSION)


def save_map(cmap: ContactMap, path: Path) -> None:
    tmp = Path(str(path) + f".tmp{os.getpid()}")
    with open(tmp, "wb") as f:
        np.savez_compressed(f, theta=cmap.theta, s=cmap.s, values=cmap.values,
                            info=np.array(repr(cmap.info)))
    os.replace(tmp, path)


def load_map(path: Path, gear, pcm, grid) -> ContactMap:
    import ast

    with np.load(path, allow_pickle=False) as z:
        info = ast.literal_eval(str(z["info"]))
        return ContactMap(z["theta"].copy(), z["s"].copy(), z["values"].copy(), gear, pcm, grid, info)


def get_map(gear: BevelGearParams | None = None, pcm: PCMParams | None = None,
            resolution: MeshResolution | None = None, health: str = "healthy", mesh_files=None,
            grid: MapGrid | None = None, mesh_units: str = "mm", use_cache: bool = True,
            fault_kwargs: dict | None = None) -> ContactMap:
    """The contact map for this configuration, from the disk cache or computed (and cached)."""
    from gearcontact_fmu.gearpair import build_pcm_pair

    gear = gear or BevelGearParams()
    pcm = pcm or PCMParams()
    resolution = resolution or MeshResolution()
    grid = grid or MapGrid()
    mesh_files = {k: v for k, v in (mesh_files or {}).items() if v}
    key = cache_key(gear, pcm, resolution, health, mesh_files, grid, fault_kwargs)
    path = cache_dir() / f"contactmap-{key}.npz"
    if use_cache and path.exists():
        cmap = load_map(path, gear, pcm, grid)
        cmap.info["cache"] = str(path)
        cmap.info["from_cache"] = True
        return cmap
    pair = build_pcm_pair(gear, pcm, resolution, health, mesh_files.get("pinion"), mesh_files.get("wheel"),
                          mesh_units, friction=True, damping=True, fault_kwargs=fault_kwargs)
    cmap = compute_map(pair, grid)
    if use_cache:
        save_map(cmap, path)
    cmap.info["cache"] = str(path)
    cmap.info["from_cache"] = False
    return cmap


def make_table_data(cmap: ContactMap, friction: bool = True, damping: bool = True) -> tuple:
    z1, z2 = cmap.gear.z_pinion, cmap.gear.z_wheel
    return (np.ascontiguousarray(cmap.values), np.ascontiguousarray(cmap.s),
            float(cmap.theta[1] - cmap.theta[0]), float(z2) / float(z1),
            float(cmap.pcm.c_compression if damping else 0.0), float(cmap.pcm.c_expansion if damping else 0.0),
            float(cmap.pcm.u_max), 1.0 if friction else 0.0, float(cmap.grid.omega_regularisation),
            float(cmap.pcm.stiffness))


def make_table_model(gear_params=None, pcm_params=None, resolution=None, health="healthy",
                     mesh_files=None, mesh_units="mm", friction=True, damping=True, grid=None, **kw):
    """MeshModel of the precomputed contact map (fidelity "table")."""
    from gearcontact_fmu.fidelity import MeshModel

    cmap = get_map(gear_params, pcm_params, resolution, health, mesh_files, grid, mesh_units)
    return MeshModel(eval=table_eval, data=make_table_data(cmap, friction, damping), fidelity="table",
                     kind="mesh", info={**cmap.info})


@njit(cache=True)
def _locate(s_nodes, s):
    """Index j and weight w with s = (1-w) s[j] + w s[j+1]; w may leave [0, 1] outside the grid."""
    n = s_nodes.shape[0]
    if s <= s_nodes[0]:
        j = 0
    elif s >= s_nodes[n - 1]:
        j = n - 2
    else:
        lo = 0
        hi = n - 1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if s_nodes[mid] <= s:
                lo = mid
            else:
                hi = mid
        j = lo
    w = (s - s_nodes[j]) / (s_nodes[j + 1] - s_nodes[j])
    return j, w


@njit(cache=True)
def table_eval(data, theta_pinion, theta_wheel, omega_pinion, omega_wheel, out):
    values, s_nodes, dtheta, ratio, c_comp, c_exp, u_max, fric_on, w_reg, c_layer = data
    for k in range(out.shape[0]):
        out[k] = 0.0
    if not (math.isfinite(theta_pinion) and math.isfinite(theta_wheel)):
        out[OUT_STATUS] = 2.0
        return
    n_theta = values.shape[0]
    s = theta_pinion - ratio * theta_wheel
    sdot = omega_pinion - ratio * omega_wheel
    # periodic bilinear interpolation in theta
    two_pi = 2.0 * math.pi
    th = theta_pinion - two_pi * math.floor(theta_pinion / two_pi)
    x = th / dtheta
    i0 = int(math.floor(x))
    a = x - i0
    i0 = i0 % n_theta
    i1 = (i0 + 1) % n_theta
    j, w = _locate(s_nodes, s)
    inside = w >= 0.0 and w <= 1.0
    damp = 0.0
    # positive-definite channels are clamped outside the grid; torques extrapolate linearly
    for ch in range(9):
        v00 = values[i0, j, ch]
        v01 = values[i0, j + 1, ch]
        v10 = values[i1, j, ch]
        v11 = values[i1, j + 1, ch]
        v0 = v00 + w * (v01 - v00)
        v1 = v10 + w * (v11 - v10)
        val = v0 + a * (v1 - v0)
        if ch == 0:
            out[OUT_TAU_PINION] = val
        elif ch == 1:
            out[OUT_TAU_WHEEL] = val
        elif ch == 2:
            out[OUT_N_CONTACT] = max(val, 0.0)
        elif ch == 3:
            out[OUT_CONTACT_AREA] = max(val, 0.0)
        elif ch == 4:
            out[OUT_PEAK_PRESSURE] = max(val, 0.0)
        elif ch == 5:
            out[OUT_MAX_PENETRATION] = max(val, 0.0)
        elif ch == 6:
            out[OUT_NORMAL_FORCE] = max(val, 0.0)
        elif ch == 7:
            out[OUT_ELASTIC_ENERGY] = max(val, 0.0)
        else:
            damp = max(val, 0.0)
    # no contact: no force of any kind (the elastic torques interpolate to zero in the backlash)
    if out[OUT_TAU_PINION] == 0.0 and out[OUT_TAU_WHEEL] == 0.0:
        return
    # keep the elastic torques from changing sign through interpolation/extrapolation
    if s > 0.0:
        out[OUT_TAU_PINION] = min(out[OUT_TAU_PINION], 0.0)
        out[OUT_TAU_WHEEL] = max(out[OUT_TAU_WHEEL], 0.0)
    else:
        out[OUT_TAU_PINION] = max(out[OUT_TAU_PINION], 0.0)
        out[OUT_TAU_WHEEL] = min(out[OUT_TAU_WHEEL], 0.0)
    if not inside:
        # beyond the tabulated range: the penetration grows with the mesh approach
        pen = out[OUT_MAX_PENETRATION]
        if pen > u_max:
            out[OUT_STATUS] = 1.0
    # contact damping: compressing when the flank in contact closes
    closing = sdot > 0.0 if s > 0.0 else sdot < 0.0
    d = c_comp if closing else c_exp
    tau_d = -d * damp * sdot
    # the elastic force cannot be pulled below zero by expansion damping
    if s > 0.0:
        tau_d = min(tau_d, -out[OUT_TAU_PINION])
    else:
        tau_d = max(tau_d, -out[OUT_TAU_PINION])
    tau_fp = 0.0
    tau_fw = 0.0
    if fric_on > 0.0:
        fp0 = values[i0, j, 9] + w * (values[i0, j + 1, 9] - values[i0, j, 9])
        fp1 = values[i1, j, 9] + w * (values[i1, j + 1, 9] - values[i1, j, 9])
        fw0 = values[i0, j, 10] + w * (values[i0, j + 1, 10] - values[i0, j, 10])
        fw1 = values[i1, j, 10] + w * (values[i1, j + 1, 10] - values[i1, j, 10])
        scale = min(max(omega_pinion / w_reg, -1.0), 1.0)
        tau_fp = scale * (fp0 + a * (fp1 - fp0))
        tau_fw = scale * (fw0 + a * (fw1 - fw0))
    out[OUT_TAU_PINION] += tau_d + tau_fp
    out[OUT_TAU_WHEEL] += -ratio * tau_d + tau_fw
    p = -tau_d * sdot - (tau_fp * omega_pinion + tau_fw * omega_wheel)
    out[OUT_DISSIPATED_POWER] = max(p, 0.0)
    out[OUT_NORMAL_FORCE] = max(out[OUT_NORMAL_FORCE], 0.0)
