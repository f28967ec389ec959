"""Sliding-pit study: a pit moved across the face width in small steps; the largest change of the static
mesh torque while the faulty tooth passes through the mesh, relative to the healthy pair.

    python benchmarks/sliding_pit.py [--member wheel|pinion] [--radius-mm 0.5] [--step-mm 0.25]
                                     [--from-mm A --to-mm B] [--no-partner-rows] [--plot FILE]

Oracle: physics says the effect varies smoothly with the load distribution along the face (the pit
takes a share of the contact line away), and never vanishes while the pit lies inside the contact. A
face sampling coarser than the pit would show zeros between sampling rows (a blind spot).
``--no-partner-rows`` builds the pinion without the face rows a wheel pit asks of it (the old meshes),
to show that blind spot. Default (converged) meshes;
the reference is the same pair with the pit 1e-12 m deep (the same re-meshed tooth: the
deviation is the pit's, not the re-meshing's).
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

from gearcontact_fmu import faults, geometry
from gearcontact_fmu.contact import engine
from gearcontact_fmu.mesh_models.pcm import PCMGearPair, contact_onset, static_deflection
from gearcontact_fmu.mesh_models.base import N_OUT, OUT_TAU_PINION
from gearcontact_fmu.params import BevelGearParams, MeshResolution, PCMParams

GEAR = BevelGearParams()
RES = MeshResolution()        # the converged default: profile 0.05 mm, face rows 2 mm
NO_DEPTH_MM = 1e-9            # the reference: the same re-meshed tooth, pit 1e-12 m deep


def pair_of(pinion, wheel, pcm=PCMParams(), res=RES):
    base = engine.PCMBody(pinion.vertices, pinion.faces, pinion.face_points, pinion.face_normals)
    target = engine.PCMBody(wheel.vertices, wheel.faces, wheel.face_points, wheel.face_normals)
    r0p, r0w = geometry.pinion_R0(GEAR), geometry.wheel_R0(GEAR)
    data = engine.make_fixed_axis_data(base, target, r0p, r0w, pcm, friction=False, damping=False)
    return PCMGearPair(GEAR, pcm, res, "faults", pinion, wheel, data, (base, target, r0p, r0w), {})


def torque_pass(pair, member: str, tooth: int, s_load: float, n: int = 48) -> np.ndarray:
    """Static pinion torque at a fixed mesh coordinate while the faulty tooth passes the mesh (pinion
    angles over the two pitch blocks where it is in mesh)."""
    pitch = 2 * math.pi / GEAR.z_pinion
    r = GEAR.z_wheel / GEAR.z_pinion
    x = (tooth - 1) * pitch + 2 * pitch * (np.arange(n) + 0.5) / n
    out = np.zeros(N_OUT)
    tau = np.empty(n)
    for i, xi in enumerate(x):
        thw = (xi - s_load) / r                 # over the pairing period when the wheel carries the fault
        engine.fixed_axis_eval(pair.data, xi, thw, 0.0, 0.0, out)
        tau[i] = out[OUT_TAU_PINION]
    return tau


def study(member="wheel", radius_mm=0.5, depth_mm=0.1, step_mm=0.25, lo_mm=None, hi_mm=None,
          partner_rows=True, tooth=None, load_Nm=20.0, res=RES):
    """[(pit centre along the face [mm], peak torque deviation relative to the largest torque)]."""
    g = geometry.gear_geometry(GEAR, member)
    tooth = (38 if member == "wheel" else 3) if tooth is None else tooth
    b_mm = g.b * 1e3
    lo_mm = radius_mm * 1.3 if lo_mm is None else lo_mm
    hi_mm = b_mm - radius_mm * 1.3 if hi_mm is None else hi_mm
    positions = np.arange(lo_mm, hi_mm + 1e-9, step_mm)
    rows = []
    healthy_cache = {}
    for pos in positions:
        spec = {"kind": "pit", "member": member, "tooth": tooth, "radius_mm": radius_mm, "depth_mm": depth_mm,
                "face_position": pos / b_mm}
        bands = faults.partner_face_bands(GEAR, [spec], "pinion") if partner_rows else []
        pin = geometry.build_gear_mesh(GEAR, "pinion", res, face_bands=bands)
        whl = geometry.build_gear_mesh(GEAR, "wheel", res)
        if "s_load" not in healthy_cache:       # the mesh coordinate of the load, from the healthy pair
            hp = pair_of(pin, whl)
            th0 = (tooth - 0.5) * 2 * math.pi / GEAR.z_pinion
            on = contact_onset(hp, th0, +1)
            healthy_cache["s_load"] = static_deflection(hp, th0, load_Nm, s_onset=on)
        s_load = healthy_cache["s_load"]
        taus = []
        for d_mm in (NO_DEPTH_MM, depth_mm):    # the reference has the same meshes (re-meshed tooth, rows)
            sp = dict(spec, depth_mm=d_mm)
            p_, w_ = ((pin, faults.apply_faults(whl, GEAR, [sp], "wheel")) if member == "wheel"
                      else (faults.apply_faults(pin, GEAR, [sp], "pinion"), whl))
            taus.append(torque_pass(pair_of(p_, w_), member, tooth, s_load))
        tau_h, tau = taus
        dev = float(np.max(np.abs(tau - tau_h)) / np.max(np.abs(tau_h)))
        rows.append((float(pos), dev))
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--member", default="wheel", choices=("wheel", "pinion"))
    ap.add_argument("--radius-mm", type=float, default=0.5)
    ap.add_argument("--depth-mm", type=float, default=0.1)
    ap.add_argument("--step-mm", type=float, default=0.25)
    ap.add_argument("--from-mm", type=float, default=None)
    ap.add_argument("--to-mm", type=float, default=None)
    ap.add_argument("--no-partner-rows", action="store_true")
    ap.add_argument("--plot", default=None)
    a = ap.parse_args()
    t0 = time.perf_counter()
    variants = [("with the partner's face rows", True)]
    if a.member == "wheel":
        variants.append(("pinion rows every 2 mm (before)", False))
    if a.no_partner_rows:
        variants = [v for v in variants if not v[1]]
    results = {}
    for label, partner in variants:
        results[label] = study(a.member, a.radius_mm, a.depth_mm, a.step_mm, a.from_mm, a.to_mm, partner)
        devs = [d for _, d in results[label]]
        print(f"{a.member} pit r = {a.radius_mm:g} mm, {label}: {len(devs)} positions, deviation min "
              f"{min(devs) * 100:.3f} %  median {np.median(devs) * 100:.3f} %  max {max(devs) * 100:.3f} %")
        for pos, d in results[label]:
            print(f"  face {pos:6.2f} mm  peak torque deviation {d * 100:7.3f} %")
    print(f"({time.perf_counter() - t0:.0f} s)")
    if a.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 3.2))
        for label, rows in results.items():
            ax.plot([p for p, _ in rows], [100 * d for _, d in rows], "o-", ms=3, label=label)
        for rr in np.arange(0.0, 25.0 + 1e-9, 2.0):
            ax.axvline(rr, color="0.85", lw=0.8, zorder=0)
        ax.set_xlabel("pit centre along the face width [mm] (grey: default 2 mm face rows)")
        ax.set_ylabel("peak torque deviation [%]")
        ax.set_title(f"{a.member} pit, radius {a.radius_mm:g} mm, depth {a.depth_mm:g} mm, {a.step_mm:g} mm steps")
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(a.plot, dpi=120)
        print("wrote", a.plot)


if __name__ == "__main__":
    main()
