"""Micro-benchmark of the PCM contact engine's fixed-axis kernel.

    python benchmarks/bench_contact_engine.py [--gear] [--cones] [--margins 0,5e-5,1e-4,2e-4]

* ``--gear``: the project's bevel pair (geometry.build_pair, default resolution) loaded at a few
  mesh coordinates; calls along a trajectory (pinion 52 rad/s, i.e. 500 rpm, wheel kinematic plus a
  small mesh oscillation) at steps of 1 and 10 us;
* ``--cones``: a friction-cone pair (apex at the origin, 90 deg shaft angle) with ~200 k triangles
  each and a few thousand elements in contact (geometry-independent case).

Reports microseconds per call (best of several repeats; the machine may be shared), the number of
elements in contact and, with the cache, the rebuilds per call.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from numba import njit

from gearcontact_fmu.contact import primitives as P
from gearcontact_fmu.contact.engine import (PCMBody, cache_stats, fixed_axis_eval,
                                            make_fixed_axis_data, reset_cache)
from gearcontact_fmu.mesh_models.base import N_OUT
from gearcontact_fmu.params import PCMParams


@njit
def _loop(mesh_eval, data, thb, tht, wb, wt, out):
    """Calls from compiled code, as the gear stage's integrator makes them."""
    acc = 0.0
    for k in range(thb.shape[0]):
        mesh_eval(data, thb[k], tht[k], wb, wt, out)
        acc += out[0]
    return acc


def run_static(data, thb, tht, wb, wt, reps=200, repeat=5):
    out = np.zeros(N_OUT)
    a = np.full(reps, float(thb))
    b = np.full(reps, float(tht))
    _loop(fixed_axis_eval, data, a[:1], b[:1], wb, wt, out)
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        _loop(fixed_axis_eval, data, a, b, wb, wt, out)
        best = min(best, (time.perf_counter() - t0) / reps)
    return best * 1e6, out


def run_trajectory(data, thb0, tht0, wb, ratio, dt, n, amp=2e-5, f_osc=2000.0, repeat=2):
    """Calls along theta_b = thb0 + wb t, theta_t = tht0 + (wb t)/ratio + amp sin(2 pi f t)."""
    out = np.zeros(N_OUT)
    t = np.arange(n) * dt
    thb = thb0 + wb * t
    tht = tht0 + wb * t / ratio + amp * np.sin(2 * np.pi * f_osc * t)
    best = np.inf
    for _ in range(repeat):
        reset_cache(data)
        c0 = cache_stats(data)
        t0 = time.perf_counter()
        _loop(fixed_axis_eval, data, thb, tht, wb, wb / ratio, out)
        best = min(best, (time.perf_counter() - t0) / n)
        c1 = cache_stats(data)
    builds = c1["builds"] - c0["builds"]
    return best * 1e6, builds / n, out


def gear_case(margins, steps, u_max):
    from gearcontact_fmu import geometry as G
    t0 = time.perf_counter()
    pair = G.build_pair()
    pm, wm = pair.pinion, pair.wheel
    base = PCMBody(pm.vertices, pm.faces, pm.face_points, pm.face_normals)
    target = PCMBody(wm.vertices, wm.faces, wm.face_points, wm.face_normals)
    print(f"gear pair: pinion {base.n_faces} / wheel {target.n_faces} triangles, "
          f"bodies built in {time.perf_counter() - t0:.1f} s")
    pcm = PCMParams(u_max=u_max)
    ratio = pair.params.z_wheel / pair.params.z_pinion
    for margin in margins:
        data = make_fixed_axis_data(base, target, pair.pinion_R0, pair.wheel_R0, pcm,
                                    cache_margin=margin)
        for ds in (2e-5, 1e-4, 3e-4):
            s = pair.backlash_angle / 2 + ds
            thw = pair.wheel_angle(0.0, s)
            us, out = run_static(data, 0.0, thw, 52.0, 13.0)
            line = (f"  u_max {u_max * 1e3:g} mm margin {margin * 1e6:3.0f} um  s-s_b/2 = {ds * 1e6:4.0f} urad: "
                    f"tau_p = {out[0]:8.2f} N m, n_contact = {out[2]:5.0f}, static {us:8.1f} us")
            if margin > 0:
                for dt in steps:
                    ust, bpc, _ = run_trajectory(data, 0.0, thw, 52.0, ratio, dt,
                                                 1000 if dt < 5e-6 else 300)
                    line += f" | traj dt={dt * 1e6:.0f}us {ust:7.1f} us ({bpc:.3f} builds/call)"
            print(line)


def cone_case(margins, steps, u_max, n_circ=(4000, 1000), n_face=25):
    """Two cones touching along a generator: pinion-like half angle 14.04 deg, wheel 75.96 deg,
    cone distance 67.8 ... 92.8 mm; the wheel cone is widened by eps to load the contact."""
    d1 = np.arctan2(15, 60)
    d2 = np.pi / 2 - d1
    t0 = time.perf_counter()
    b = P.cone_band(d1, 0.0678, 0.0928, n_circ[0], n_face)
    base = PCMBody(*b)
    out_rows = []
    for eps in (2e-5, 1e-4):
        tgt = P.cone_band(d2 + eps, 0.0678, 0.0928, n_circ[1], n_face)
        target = PCMBody(*tgt)
        # base axis z (world z); target axis: world x, contact along the generator in the x-z
        # plane: base generator at phi = 0 (x > 0), target generator at phi = pi
        R0b = np.eye(3)
        R0t = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])   # local z -> +x
        pcm = PCMParams(u_max=u_max)
        for margin in margins:
            data = make_fixed_axis_data(base, target, R0b, R0t, pcm, cache_margin=margin)
            us, out = run_static(data, 0.0, 0.0, 52.0, 13.0)
            line = (f"  cones eps={eps:g} rad margin {margin * 1e6:4.0f} um: "
                    f"n_contact {out[2]:5.0f}, F_n {out[6]:9.1f} N, static {us:8.1f} us")
            if margin > 0:
                for dt in steps:
                    ust, bpc, _ = run_trajectory(data, 0.0, 0.0, 52.0, 4.0, dt,
                                                 1000 if dt < 5e-6 else 300, amp=0.0)
                    line += f" | traj dt={dt * 1e6:.0f}us {ust:7.1f} us ({bpc:.3f} builds/call)"
            out_rows.append(line)
    print(f"cones: base {base.n_faces} / target {target.n_faces} triangles "
          f"({time.perf_counter() - t0:.1f} s to build)")
    print("\n".join(out_rows))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--gear", action="store_true")
    ap.add_argument("--cones", action="store_true")
    ap.add_argument("--margins", default="0,1e-5,2e-5")
    ap.add_argument("--steps", default="1e-6,1e-5")
    ap.add_argument("--u-max", type=float, default=PCMParams().u_max)
    a = ap.parse_args()
    margins = [float(x) for x in a.margins.split(",")]
    steps = [float(x) for x in a.steps.split(",")]
    if not (a.gear or a.cones):
        a.gear = a.cones = True
    if a.gear:
        gear_case(margins, steps, a.u_max)
    if a.cones:
        cone_case(margins, steps, a.u_max)


if __name__ == "__main__":
    main()
