"""The bevel pair under the polygonal contact method at fixed axes ("pcm" fidelity).

The pinion is the base body, the wheel the target body (notes §5). Both rotate about fixed axes
through the common apex, so the contact response depends on two angles only. This module builds the
contact data for the engine's fixed-axis kernel and offers the static analyses the issue asks for:
static transmission error and mesh stiffness against pinion angle, and the unloaded no-contact
windows of a faulty pinion.

Sign conventions (docs/ARCHITECTURE.md): s = theta_pinion - (z2/z1) theta_wheel; the drive flanks
close at s = +s_b/2. A driving pinion torque T > 0 is balanced by a mesh torque -T on the pinion.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gearcontact_fmu import faults, geometry
from gearcontact_fmu.contact import engine
from gearcontact_fmu.mesh_check import load_gear_mesh
from gearcontact_fmu.mesh_models.base import N_OUT, OUT_STATUS, OUT_TAU_PINION, MeshModel
from gearcontact_fmu.meshes import SurfaceMesh
from gearcontact_fmu.elastic_layer import pair_pcm
from gearcontact_fmu.params import BevelGearParams, MeshResolution, PCMParams


@dataclass
class PCMGearPair:
    """Everything the fixed-axis PCM kernel needs, plus the meshes it was built from."""

    gear: BevelGearParams
    pcm: PCMParams
    resolution: MeshResolution
    health: str
    pinion: SurfaceMesh
    wheel: SurfaceMesh
    data: tuple
    bodies: tuple = ()          # (base PCMBody, target PCMBody, R0 pinion, R0 wheel)
    info: dict = field(default_factory=dict)

    def data_with(self, friction: bool, damping: bool) -> tuple:
        """Kernel data of the same meshes with friction and/or damping switched (no pitch atlas: the
        contact map, its user, sweeps one pitch and would only fill it)."""
        base, target, r0p, r0w = self.bodies
        return engine.make_fixed_axis_data(base, target, r0p, r0w, self.pcm, friction=friction, damping=damping)

    def evaluate(self, theta_pinion, theta_wheel, omega_pinion=0.0, omega_wheel=0.0, out=None):
        if out is None:
            out = np.zeros(N_OUT)
        engine.fixed_axis_eval(self.data, float(theta_pinion), float(theta_wheel),
                               float(omega_pinion), float(omega_wheel), out)
        return out

    # --- mesh coordinate helpers -------------------------------------------------------------
    def wheel_angle(self, theta_pinion: float, s: float) -> float:
        """Wheel angle that puts the pair at mesh coordinate s for a given pinion angle."""
        return (theta_pinion - s) * self.gear.z_pinion / self.gear.z_wheel

    def mesh_torque(self, theta_pinion: float, s: float, out=None) -> float:
        """Mesh torque on the pinion [N·m] at pinion angle and mesh coordinate s (static)."""
        out = self.evaluate(theta_pinion, self.wheel_angle(theta_pinion, s), 0.0, 0.0, out)
        if out[OUT_STATUS] != 0:
            raise engine.PenetrationError(
                f"penetration beyond u_max = {self.pcm.u_max:g} m at theta_pinion = {theta_pinion:g} rad, "
                f"s = {s:g} rad")
        return float(out[OUT_TAU_PINION])


def resolve_meshes(gear: BevelGearParams, resolution: MeshResolution, health: str = "healthy",
                   pinion_mesh_file: str | None = None, wheel_mesh_file: str | None = None,
                   mesh_units: str = "mm", pinion_teeth=None, wheel_teeth=None,
                   fault_kwargs: dict | None = None) -> tuple[SurfaceMesh, SurfaceMesh]:
    """Pinion and wheel surface meshes for a health state or user mesh files (body frames, SI)."""
    if pinion_mesh_file:
        pinion = load_gear_mesh(pinion_mesh_file, gear, "pinion", units=mesh_units)
    else:
        specs = (fault_kwargs or {}).get("faults", []) if health == "faults" else []
        pinion = geometry.build_gear_mesh(gear, "pinion", resolution, teeth=pinion_teeth,
                                          face_bands=faults.partner_face_bands(gear, specs, "pinion"),
                                          profile_bands=faults.partner_profile_bands(gear, specs, "pinion"))
        pinion = faults.apply_health(pinion, gear, health, "pinion", **(fault_kwargs or {}))
    if wheel_mesh_file:
        wheel = load_gear_mesh(wheel_mesh_file, gear, "wheel", units=mesh_units)
    else:
        wheel = geometry.build_gear_mesh(gear, "wheel", resolution, teeth=wheel_teeth)
        wheel = faults.apply_health(wheel, gear, health, "wheel", **(fault_kwargs or {}))
    return pinion, wheel


def _bodies(pinion: SurfaceMesh, wheel: SurfaceMesh, threads: int = 1) -> tuple:
    """The two meshes' contact bodies (trees and kernel arrays); with ``threads`` >= 2 built side by side in two
    threads (the tree kernels run without the GIL): a new fault's map builds both, the wheel's 400,000
    triangles in 0.8 s, the pinion's in 0.3 s."""
    def body(m):
        return engine.PCMBody(m.vertices, m.faces, m.face_points, m.face_normals)

    if threads < 2:
        return body(pinion), body(wheel)
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(1) as pool:
        base = pool.submit(body, pinion)
        target = body(wheel)
        return base.result(), target


def build_pcm_pair(gear: BevelGearParams | None = None, pcm: PCMParams | None = None,
                   resolution: MeshResolution | None = None, health: str = "healthy",
                   pinion_mesh_file: str | None = None, wheel_mesh_file: str | None = None,
                   mesh_units: str = "mm", friction: bool = True, damping: bool = True,
                   pinion_teeth=None, wheel_teeth=None, fault_kwargs: dict | None = None,
                   threads: int = 1) -> PCMGearPair:
    """The pair's meshes, contact bodies and kernel data; ``threads``: how many threads may build the two bodies
    (the map build passes its contact_map.map_workers)."""
    gear = gear or BevelGearParams()
    pcm = pair_pcm(gear, pcm)
    resolution = resolution or MeshResolution()
    pinion, wheel = resolve_meshes(gear, resolution, health, pinion_mesh_file, wheel_mesh_file,
                                   mesh_units, pinion_teeth, wheel_teeth, fault_kwargs)
    base, target = _bodies(pinion, wheel, threads)
    r0p, r0w = geometry.pinion_R0(gear), geometry.wheel_R0(gear)
    data = engine.make_fixed_axis_data(base, target, r0p, r0w, pcm, friction=friction, damping=damping)
    info = {"pinion_triangles": int(len(pinion.faces)), "wheel_triangles": int(len(wheel.faces))}
    return PCMGearPair(gear, pcm, resolution, health, pinion, wheel, data, (base, target, r0p, r0w), info)


def fault_kwargs_of(health: str, faults=()) -> dict | None:
    """The fault keywords of a health state: the specification list for ``"faults"``, else none (the
    paper's faults use their defaults)."""
    return {"faults": [dict(f) for f in faults]} if health == "faults" else None


def make_pcm_model(gear_params=None, pcm_params=None, resolution=None, health="healthy",
                   mesh_files=None, mesh_units="mm", friction=True, damping=True, faults=(), **kw):
    """MeshModel of the online PCM engine (fidelity "pcm"). ``faults``: the fault specifications of
    ``health = "faults"`` (faults.FAULT_KINDS)."""
    mesh_files = mesh_files or {}
    pair = build_pcm_pair(gear_params, pcm_params, resolution, health,
                          mesh_files.get("pinion") or None, mesh_files.get("wheel") or None,
                          mesh_units, friction, damping, fault_kwargs=fault_kwargs_of(health, faults))
    # the online model runs along a trajectory that repeats pitch after pitch: the kernel keeps its
    # candidate lists in a pitch atlas when the meshes are rotated copies of one tooth (checked)
    base, target, r0p, r0w = pair.bodies
    data = engine.make_fixed_axis_data(base, target, r0p, r0w, pair.pcm, friction=friction, damping=damping,
                                       periods=(pair.gear.z_pinion, pair.gear.z_wheel))
    return MeshModel(eval=engine.fixed_axis_eval, data=data, fidelity="pcm", kind="mesh",
                     info={**pair.info, "health": health})


# --- static analyses ---------------------------------------------------------------------------

#: first step of the onset search's bracket away from the nominal flank position [rad of s]; each further
#: step is ONSET_GROWTH times longer
ONSET_FIRST_STEP = 1e-6
ONSET_GROWTH = 8.0


def contact_onset(pair: PCMGearPair, theta_pinion: float, flank: int = +1, tol: float = 1e-10,
                  max_approach: float = 30e-6) -> float:
    """Mesh coordinate s at which the drive (+1) or coast (-1) flanks first touch at this angle.

    The search covers the backlash centre to ``max_approach`` (line-of-action length beyond the
    nominal flank position; the default 30 µm is far beyond any static load). With a fault the
    next tooth may first touch much further on (early engagement at its tip after a missing tooth):
    give a larger ``max_approach`` to find it. Returns nan when nothing touches within the range.

    "Touching" only grows with s along the flank's direction, so the onset is bracketed first, from the
    nominal flank position (half the backlash from the centre) outward in steps growing from
    ONSET_FIRST_STEP by ONSET_GROWTH, towards the centre or towards the far end, and then bisected to
    ``tol``. Healthy teeth touch within a micro-radian of the nominal position: about 16 evaluations near
    it, where the older search from the centre to the far end took 30, four of them deep in the flank
    (the costliest, many elements in contact)."""
    s_b = geometry.backlash_angle(pair.gear)
    s_far = flank * (s_b / 2 + max_approach / geometry.mean_base_radius(pair.gear))
    out = np.zeros(N_OUT)
    touches = lambda s: _abs_torque(pair, theta_pinion, s, out) > 0.0  # noqa: E731
    nominal = flank * s_b / 2
    step = flank * ONSET_FIRST_STEP
    if touches(nominal):
        # already in contact: step back towards the backlash centre (s = 0) until free
        hi, lo = nominal, nominal - step
        while flank * lo > 0.0 and touches(lo):
            hi, lo, step = lo, lo - ONSET_GROWTH * step, ONSET_GROWTH * step
        if flank * lo <= 0.0:
            lo = 0.0
            if touches(lo):
                return 0.0                       # touching at the backlash centre: no free play
    else:
        lo, hi = nominal, nominal + step
        while flank * (hi - s_far) < 0.0 and not touches(hi):
            lo, hi, step = hi, hi + ONSET_GROWTH * step, ONSET_GROWTH * step
        if flank * (hi - s_far) >= 0.0:
            hi = s_far
            if not touches(hi):
                return math.nan
    # bisection on "any contact": lo free, hi touching
    for _ in range(200):
        if abs(hi - lo) < tol:
            break
        mid = 0.5 * (lo + hi)
        if touches(mid):
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


def _abs_torque(pair, theta_pinion, s, out):
    pair.evaluate(theta_pinion, pair.wheel_angle(theta_pinion, s), 0.0, 0.0, out)
    return abs(out[OUT_TAU_PINION])


def static_deflection(pair: PCMGearPair, theta_pinion: float, torque: float, s_onset: float | None = None,
                      rtol: float = 1e-6, flank: int = +1) -> float:
    """Mesh coordinate s at which the static mesh torque balances a pinion torque ``torque`` (> 0) carried by
    ``flank``: +1 the drive flank (a driving pinion), -1 the coast flank (s decreasing from its onset)."""
    from scipy.optimize import brentq

    if s_onset is None:
        s_onset = contact_onset(pair, theta_pinion, flank)
    if not math.isfinite(s_onset):
        return math.nan
    out = np.zeros(N_OUT)

    def resid(s):
        return -flank * pair.mesh_torque(theta_pinion, s, out) - torque

    step = 1e-6
    hi = s_onset + flank * step
    while resid(hi) < 0:
        step *= 2.0
        hi = s_onset + flank * step
        if step > 0.05:
            raise RuntimeError("no static equilibrium found within 0.05 rad of mesh approach")
    return brentq(resid, *sorted((s_onset, hi)), rtol=rtol, xtol=1e-13)


def static_transmission_error(pair: PCMGearPair, thetas, torque: float, ds: float = 2e-7):
    """Static TE and mesh stiffness along pinion angle at a driving pinion torque.

    Returns dict with theta [rad], s [rad], te [m] (line-of-action length at the mean base radius,
    measured from the unloaded contact position with the backlash taken up), k_torsional
    [N·m/rad at the pinion], k_mesh [N/m along the line of action]."""
    s_b = geometry.backlash_angle(pair.gear)
    rb = geometry.mean_base_radius(pair.gear)
    thetas = np.asarray(thetas, dtype=float)
    s = np.empty_like(thetas)
    k = np.empty_like(thetas)
    out = np.zeros(N_OUT)
    for i, th in enumerate(thetas):
        si = static_deflection(pair, th, torque)
        s[i] = si
        t_hi = -pair.mesh_torque(th, si + ds, out)
        t_lo = -pair.mesh_torque(th, si - ds, out)
        k[i] = (t_hi - t_lo) / (2 * ds)
    te = (s - s_b / 2) * rb
    return {"theta": thetas, "s": s, "te": te, "k_torsional": k, "k_mesh": k / rb**2, "base_radius": rb}


def no_contact_windows(pair: PCMGearPair, torque: float = 5.0, n: int = 1500, approach=None):
    """Fraction of a pinion revolution without drive-flank contact at a fixed mesh approach.

    The approach (s beyond the backlash-closed position) defaults to the healthy static deflection
    at ``torque``. Returns (thetas, contact mask, list of windows as (start, length) in pitches)."""
    s_b = geometry.backlash_angle(pair.gear)
    if approach is None:
        # reference angle half a revolution away from tooth 0 (where a fault sits by default)
        approach = 0.5 * (static_deflection(pair, math.pi, torque) - s_b / 2)
    if not math.isfinite(approach):
        raise ValueError("no contact at the reference angle: cannot choose a mesh approach")
    thetas = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    out = np.zeros(N_OUT)
    mask = np.empty(n, dtype=bool)
    for i, th in enumerate(thetas):
        pair.evaluate(th, pair.wheel_angle(th, s_b / 2 + approach), 0.0, 0.0, out)
        if out[OUT_STATUS] != 0:
            raise engine.PenetrationError(f"penetration beyond u_max at theta_pinion = {th:g} rad")
        mask[i] = out[OUT_TAU_PINION] != 0.0
    pitch = 2 * math.pi / pair.gear.z_pinion
    windows = []
    i = 0
    # rotate so we start in contact
    start = int(np.argmax(mask)) if mask.any() else 0
    m = np.roll(mask, -start)
    th_r = np.roll(thetas, -start)
    while i < n:
        if not m[i]:
            j = i
            while j < n and not m[j]:
                j += 1
            windows.append((float(th_r[i]), (j - i) * (2 * math.pi / n) / pitch))
            i = j
        else:
            i += 1
    return thetas, mask, windows
