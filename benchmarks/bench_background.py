"""What the measured background costs: the record scene (500 rpm, 1.31 N·m, table, rig sensors, errors and
compliance on) with every background effect off and with each on, then all on, run alternately in one
process; prints the loop time per simulated second of each, its ratio to "background off" (the target for
all on is <= 1.3) and the wall time (which adds the background's generation before the run).

    python benchmarks/bench_background.py [--duration 4] [--rounds 5] [--backend native inprocess]
"""
import argparse
import time
from pathlib import Path

from drivetrain.run.runner import run_scene
from drivetrain.scene.load import load_scene

ROOT = Path(__file__).resolve().parents[1]
ap = argparse.ArgumentParser()
ap.add_argument("--duration", type=float, default=4.0)
ap.add_argument("--rounds", type=int, default=5)
ap.add_argument("--backend", nargs="+", default=["native", "inprocess"])
args = ap.parse_args()

OFF = ["effects.drive_torque_noise=false", "effects.load_torque_noise=false", "effects.shaft_orders=false",
       'effects.drive_control="assumed"', 'effects.couplings="fitted"']
base = [f"time.duration_s={args.duration}", "time.settle_s=0.5", "outputs.plots=false"]
variants = {"background off": OFF,
            "drive control record": [o for o in OFF if "drive_control" not in o] + ['effects.drive_control="record"'],
            "couplings record": [o for o in OFF if "couplings" not in o] + ['effects.couplings="record"'],
            "load torque noise": [o for o in OFF if "load_torque" not in o] + ["effects.load_torque_noise=true"],
            "drive torque noise": [o for o in OFF if "drive_torque" not in o] + ["effects.drive_torque_noise=true"],
            "shaft orders": [o for o in OFF if "shaft_orders" not in o] + ["effects.shaft_orders=true"],
            "all on (the record scene)": []}
scene_file = ROOT / "scenarios" / "validation" / "rig_record_500rpm.toml"
scenes = {k: load_scene(scene_file, overrides=base + v) for k, v in variants.items()}
for backend in args.backend:
    for s in scenes.values():                 # warm-up: JIT, map cache, native builds
        run_scene(s, out_dir=None, progress=False, backend=backend)
    loop = {k: [] for k in scenes}
    wall = {k: [] for k in scenes}
    for _ in range(args.rounds):
        for k, s in scenes.items():
            t0 = time.perf_counter()
            r = run_scene(s, out_dir=None, progress=False, backend=backend)
            wall[k].append(time.perf_counter() - t0)
            loop[k].append(r.summary["loop_time_s"] / args.duration)
    ref = min(loop["background off"])
    print(f"\nbackend {backend}, {args.duration:g} s runs, best of {args.rounds} (the least disturbed by other jobs)")
    print("| variant | loop s per simulated s | ratio to background off | wall s |")
    print("|---|---|---|---|")
    for k in scenes:
        print(f"| {k} | {min(loop[k]):.4f} | {min(loop[k]) / ref:.2f} | {min(wall[k]):.2f} |")
