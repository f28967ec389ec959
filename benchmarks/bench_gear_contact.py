"""Benchmark of the gear contact: online PCM vs table, and how cost follows the contact.

Prints, measured side by side in one run:
  * µs per online PCM evaluation of the loaded healthy pair at the converged resolution;
  * µs per table evaluation and the speed-up table/online;
  * the cost ratio when the teeth NOT in contact are refined 4x (the tree should make cost follow the
    contact, not the mesh size).

Run:  python benchmarks/bench_gear_contact.py [--torque 50] [--repeat 2000]
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

from gearcontact_fmu import geometry
from gearcontact_fmu.contact import engine
from gearcontact_fmu.contact_map import MapGrid, get_map
from gearcontact_fmu.mesh_models.table import make_table_data, table_eval
from gearcontact_fmu.mesh_models.base import N_OUT
from gearcontact_fmu.mesh_models.pcm import build_pcm_pair, static_deflection, PCMGearPair
from gearcontact_fmu.meshes import SurfaceMesh
from gearcontact_fmu.params import BevelGearParams, MeshResolution, PCMParams


def time_calls(fn, data, states, repeat):
    out = np.zeros(N_OUT)
    th_p, th_w, w_p, w_w = states
    fn(data, th_p[0], th_w[0], w_p, w_w, out)          # compile / warm
    n = len(th_p)
    best = math.inf
    for _ in range(3):
        t0 = time.perf_counter()
        for k in range(repeat):
            i = k % n
            fn(data, th_p[i], th_w[i], w_p, w_w, out)
        best = min(best, (time.perf_counter() - t0) / repeat)
    return best * 1e6, out


def loaded_states(pair: PCMGearPair, torque: float, n: int = 64):
    """Pinion/wheel angles over one pitch at the static deflection of ``torque``."""
    pitch = 2 * math.pi / pair.gear.z_pinion
    th = np.linspace(0.0, pitch, n, endpoint=False)
    s = np.array([static_deflection(pair, t, torque) for t in th])
    thw = (th - s) * pair.gear.z_pinion / pair.gear.z_wheel
    return th, thw


def mixed_resolution_mesh(gear, role, res_near, res_far, near_teeth):
    z = gear.z_pinion if role == "pinion" else gear.z_wheel
    far = [k for k in range(z) if k not in near_teeth]
    a = geometry.build_gear_mesh(gear, role, res_near, teeth=list(near_teeth))
    b = geometry.build_gear_mesh(gear, role, res_far, teeth=far)
    return SurfaceMesh.concatenate([a, b])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--torque", type=float, default=50.0, help="pinion torque [N·m]")
    ap.add_argument("--repeat", type=int, default=2000)
    ap.add_argument("--profile-mm", type=float, default=0.05)
    ap.add_argument("--face-mm", type=float, default=2.0)
    args = ap.parse_args(argv)

    gear = BevelGearParams()
    pcm = PCMParams()
    res = MeshResolution(profile=args.profile_mm * 1e-3, face=args.face_mm * 1e-3)
    t0 = time.perf_counter()
    pair = build_pcm_pair(gear, pcm, res)
    t_build = time.perf_counter() - t0
    th, thw = loaded_states(pair, args.torque)
    us_online, out = time_calls(engine.fixed_axis_eval, pair.data, (th, thw, 100.0, 25.0), args.repeat)
    print(f"mesh: pinion {pair.info['pinion_triangles']} + wheel {pair.info['wheel_triangles']} triangles "
          f"(profile {args.profile_mm} mm, face {args.face_mm} mm), built in {t_build:.1f} s")
    print(f"online PCM, loaded {args.torque:g} N·m: {us_online:8.2f} µs/eval "
          f"({int(out[2])} elements in contact; states jump over a pitch: full search each call)")
    # along a trajectory: the pinion turns at 500 rpm (drive 1500 rpm) at the mean static deflection;
    # consecutive calls differ by one integrator sub-step, so the engine's candidate list is reused
    omega = 500 * 2 * math.pi / 60
    s_mean = float(np.mean(th - thw * gear.z_wheel / gear.z_pinion))
    traj = {}
    for dt in (1e-6, 1e-5):
        t = np.arange(args.repeat) * dt
        th_t = omega * t + 0.013
        thw_t = (th_t - s_mean) * gear.z_pinion / gear.z_wheel
        engine.reset_cache(pair.data)
        out_t = np.zeros(N_OUT)
        t0 = time.perf_counter()
        for k in range(args.repeat):
            engine.fixed_axis_eval(pair.data, th_t[k], thw_t[k], omega, omega * gear.z_pinion / gear.z_wheel, out_t)
        traj[dt] = (time.perf_counter() - t0) / args.repeat * 1e6
        print(f"online PCM along a trajectory, sub-step {dt * 1e6:4.0f} µs at 500 rpm pinion: "
              f"{traj[dt]:8.2f} µs/eval")

    t0 = time.perf_counter()
    cmap = get_map(gear, pcm, res)
    print(f"contact map: {cmap.info['n_theta']} x {cmap.info['n_s']} nodes "
          f"({'cache' if cmap.info.get('from_cache') else f'built in {time.perf_counter() - t0:.1f} s'})")
    us_table, _ = time_calls(table_eval, make_table_data(cmap), (th, thw, 100.0, 25.0), args.repeat * 50)
    print(f"table:                        {us_table:8.3f} µs/eval   speed-up {us_online / us_table:7.0f}x "
          f"over the full search, {traj[1e-6] / us_table:5.0f}x over the trajectory at 1 µs steps")

    # refine the teeth that are not in contact 4x (profile and face)
    fine = MeshResolution(profile=res.profile / 4, face=res.face / 4)
    near_p = [gear.z_pinion - 2, gear.z_pinion - 1, 0, 1, 2]
    near_w = [gear.z_wheel - 2, gear.z_wheel - 1, 0, 1, 2]
    p_mix = mixed_resolution_mesh(gear, "pinion", res, fine, near_p)
    w_mix = mixed_resolution_mesh(gear, "wheel", res, fine, near_w)
    base = engine.PCMBody(p_mix.vertices, p_mix.faces, p_mix.face_points, p_mix.face_normals)
    target = engine.PCMBody(w_mix.vertices, w_mix.faces, w_mix.face_points, w_mix.face_normals)
    data_mix = engine.make_fixed_axis_data(base, target, geometry.pinion_R0(gear), geometry.wheel_R0(gear), pcm)
    # same states: only one pitch around theta = 0 is evaluated, so the refined teeth stay out of mesh
    us_mix, out_mix = time_calls(engine.fixed_axis_eval, data_mix, (th, thw, 100.0, 25.0), args.repeat)
    print(f"non-contact teeth refined 4x: pinion {len(p_mix.faces)} + wheel {len(w_mix.faces)} triangles, "
          f"{us_mix:8.2f} µs/eval   cost ratio {us_mix / us_online:5.2f}x (goal < 1.3x)")


if __name__ == "__main__":
    main()
