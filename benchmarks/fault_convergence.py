"""Convergence of each fault family's own effect with the element size (issue 40, item 2): the table of
docs/GEAR-CONTACT.md ("A fault changes only the fault").

The effect is the label ``mesh_torque_drop`` (gearcontact_fmu.fault_contact: the largest relative drop of the
mesh torque at fixed mesh coordinate, read from the healthy and the faulty contact map of the default grid),
for every family at its default size on pinion tooth 0's drive flank (and the wheel's with ``--wheel``), at
the lightest and the heaviest load a scene runs (0.12 and 11.9 N·m at the load motor; the pinion torque is
the scene's own steady state), at the default element size and at half of it (profile and face). Fault-local
refinements (a pit's face rows every radius/4, a spall's every width/8) are the faults' own and stay.

Pass rule, stated before computing: a family passes at a load when its drops at the two element sizes agree
within 5 % of the finer one's, |d_default - d_half| <= 0.05 d_half.

The largest drop saturates at 1 for a fault that takes a tooth's whole load off in single contact (void,
wear, missing tooth), where it cannot show a mesh error. So the table also gives the drop integrated over the
three pitches around the largest, in pinion pitches (:func:`integrated_drop`: the load the fault takes off
over its passage, as a share of one pitch's), with the same 5 % rule (stated with the first, before the
wheel's faults and the integral were computed).

    python benchmarks/fault_convergence.py [--wheel] [--json out.json]     # ~20-40 min on 2 busy cores

Maps go through the disk cache ($BEVEL_CACHE_DIR): a rerun reads them; build times are printed.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from gearcontact_fmu import fault_contact as fc, faults
from gearcontact_fmu.contact_map import get_map
from gearcontact_fmu.fault_specs import FAULT_KINDS
from gearcontact_fmu.params import BevelGearParams, MapGrid, MeshResolution, PCMParams

LOADS_NM = (0.12, 11.9)
RULE = 0.05


def pinion_torque(load_Nm: float) -> float:
    """The pinion torque [N m] of the rig's scene at this load-motor torque (its steady state)."""
    from drivetrain.run.runner import assemble_scene
    from drivetrain.scene.load import resolve

    scene = resolve({"scenario": {"name": "load"}, "operating_point": {"load_torque_Nm": load_Nm},
                     "outputs": {"plots": False}})
    return float(assemble_scene(scene).metadata["steady_state"]["T_msh"])


def integrated_drop(healthy, faulty, torque: float, gear) -> float:
    """The row drops (fault_contact.row_drops) summed over the three pinion pitches centred on the largest,
    times the row spacing, in pitches: the load the fault takes off over its passage (contact ratio 1.55).
    Only there: a wheel fault's partner bands give every pinion tooth extra face rows, whose own small
    deviation from the healthy pinion would add up over the map's 60 pitches."""
    theta, drops = fc.row_drops(healthy, faulty, torque)
    pitch = 2 * np.pi / gear.z_pinion
    d = np.nan_to_num(drops)
    span = theta.size * (theta[1] - theta[0])                  # the map is periodic over its span
    off = np.abs(theta - theta[int(np.argmax(d))]) % span
    near = np.minimum(off, span - off) <= 1.5 * pitch
    return float(np.sum(d[near]) * (theta[1] - theta[0]) / pitch)


def own_healthy_pitch(faulty, healthy, per: int):
    """The faulty map's own healthy pitch tiled over one revolution (the healthy map's rows): for a wheel
    chipped tip, whose pinion carries the partner profile band (faults.partner_profile_bands), the healthy
    pair at that refinement. The block half a map away from the largest drop (the faulty wheel tooth meets
    the pinion once in the map's four revolutions)."""
    import dataclasses

    n = faulty.theta.size
    i = int(np.nanargmax(np.abs(faulty.values[:, 0, -1, 0] - np.roll(faulty.values[:, 0, -1, 0], per))))
    k = ((i + n // 2) % n) // per * per
    reps = healthy.theta.size // per
    return dataclasses.replace(healthy, values=np.tile(faulty.values[k:k + per], (reps, 1, 1, 1)),
                               onset=np.tile(faulty.onset[k:k + per], (reps, 1)))


def healthy_under_load(cmap, torque: float, per: int) -> tuple[float, float]:
    """(mean approach beyond the onset, amplitude of the GMF harmonic of the mesh coordinate) [rad] of a
    healthy map under the pinion torque ``torque`` over one pitch (``per`` rows): its stiffness and its
    static transmission error's mesh-frequency line."""
    from gearcontact_fmu.contact_map import CH_TAU_P, SIDE_DRIVE

    a = np.array([np.interp(torque, np.abs(cmap.values[i, SIDE_DRIVE, :, CH_TAU_P]), cmap.a) for i in range(per)])
    s = cmap.onset[:per, SIDE_DRIVE] + a
    return float(a.mean()), float(2.0 * abs(np.fft.rfft(s - s.mean())[1]) / per)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--wheel", action="store_true", help="the wheel's faults too")
    ap.add_argument("--families", nargs="*", default=sorted(FAULT_KINDS))
    ap.add_argument("--json", help="write the numbers here")
    ap.add_argument("--factors", nargs=2, type=float, default=(1.0, 0.5), metavar=("COARSE", "FINE"),
                    help="the two element sizes compared, as factors of the default (default 1 0.5)")
    args = ap.parse_args()
    gear, pcm, grid = BevelGearParams(), PCMParams(), MapGrid()
    base = MeshResolution()
    default, half = (MeshResolution(profile=f * base.profile, face=f * base.face) for f in args.factors)
    torques = {load: pinion_torque(load) for load in LOADS_NM}
    print("pinion torque at the load-motor torques:", {k: round(v, 4) for k, v in torques.items()})
    members = ["pinion", "wheel"] if args.wheel else ["pinion"]
    out = {"torques": torques, "rule": RULE, "rows": []}
    maps = {}
    for name, res in (("default", default), ("half", half)):
        t0 = time.perf_counter()
        maps[name] = get_map(gear, pcm, res, "healthy", None, grid)
        print(f"healthy map, {name} element size ({res.profile * 1e3:g} x {res.face * 1e3:g} mm): "
              f"{time.perf_counter() - t0:.1f} s", flush=True)
    for load, T in torques.items():
        (a0, g0), (a1, g1) = (healthy_under_load(maps[n], T, grid.points_per_pitch) for n in ("default", "half"))
        print(f"healthy at {load:g} N·m: approach under load {100 * (a0 / a1 - 1):+.2f} %, GMF line of the static "
              f"transmission error {100 * (g0 / g1 - 1):+.2f} % (coarse against fine)", flush=True)
    for member in members:
        for kind in args.families:
            spec = {"kind": kind, "member": member, "tooth": 0}
            row = {"kind": kind, "member": member}
            for name, res in (("default", default), ("half", half)):
                t0 = time.perf_counter()
                faulty = get_map(gear, pcm, res, "faults", None, grid, fault_kwargs={"faults": [spec]})
                row[f"build_s_{name}"] = time.perf_counter() - t0
                ref = maps[name]
                if faults.partner_profile_bands(gear, [spec], "pinion"):
                    ref = own_healthy_pitch(faulty, maps[name], grid.points_per_pitch)
                    for load, T in torques.items():
                        row[f"{name}_vs_shipped_healthy@{load}"] = fc.mesh_torque_drop(maps[name], faulty, T)
                for load, T in torques.items():
                    row[f"{name}@{load}"] = fc.mesh_torque_drop(ref, faulty, T)
                    row[f"{name}_int@{load}"] = integrated_drop(ref, faulty, T, gear)
            for load in LOADS_NM:
                for key in ("", "_int"):
                    d0, d1 = row[f"default{key}@{load}"], row[f"half{key}@{load}"]
                    row[f"rel{key}@{load}"] = abs(d0 - d1) / abs(d1) if d1 != 0 else (0.0 if d0 == 0 else float("inf"))
                    row[f"pass{key}@{load}"] = row[f"rel{key}@{load}"] <= RULE
            out["rows"].append(row)
            print(json.dumps(row), flush=True)
    print()
    print(f"| family | member | load-motor torque [N·m] | drop, size x{args.factors[0]:g} | drop, size "
          f"x{args.factors[1]:g} | difference | integrated [pitch], x{args.factors[0]:g} / x{args.factors[1]:g} | "
          f"difference | within 5 % (both) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for row in out["rows"]:
        for load in LOADS_NM:
            ok = row[f"pass@{load}"] and row[f"pass_int@{load}"]
            print(f"| {row['kind']} | {row['member']} | {load:g} | {row[f'default@{load}']:.4f} | "
                  f"{row[f'half@{load}']:.4f} | {100 * row[f'rel@{load}']:.1f} % | "
                  f"{row[f'default_int@{load}']:.4f} / {row[f'half_int@{load}']:.4f} | "
                  f"{100 * row[f'rel_int@{load}']:.1f} % | {'yes' if ok else '**no**'} |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
