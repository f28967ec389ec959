"""What the realism effects cost: the example scene (1500 rpm, 1.31 N·m, table) with every effect off and
with manufacturing errors, rig sensors and tooth compliance on, run alternately in one process (in-process backend, so
the ratio is the models', not the FMU calls'); prints the loop time per simulated second of each and
their ratio (the target is <= 1.3).

    python benchmarks/bench_realism.py [--duration 2] [--rounds 5]     # about 3 minutes on 2 cores
"""
import argparse
import statistics
import time
from pathlib import Path

from drivetrain.run.runner import run_scene
from drivetrain.scene.load import load_scene

ROOT = Path(__file__).resolve().parents[1]
ap = argparse.ArgumentParser()
ap.add_argument("--duration", type=float, default=2.0)
ap.add_argument("--rounds", type=int, default=5)
args = ap.parse_args()

base = [f"time.duration_s={args.duration}", "time.settle_s=0.5", "outputs.plots=false"]
variants = {"effects off": [],
            "manufacturing errors": ["effects.manufacturing_errors=true"],
            "errors + rig sensors": ["effects.manufacturing_errors=true", "effects.sensors=rig"],
            "all three (+ tooth compliance)": ["effects.manufacturing_errors=true", "effects.sensors=rig",
                                                "effects.tooth_compliance=true"]}
scenes = {k: load_scene(ROOT / "scenarios" / "example.toml", overrides=base + v) for k, v in variants.items()}
for s in scenes.values():                 # warm-up: JIT, map cache
    run_scene(s, out_dir=None, progress=False, backend="inprocess")
loop = {k: [] for k in scenes}
wall = {k: [] for k in scenes}
for _ in range(args.rounds):
    for k, s in scenes.items():
        t0 = time.perf_counter()
        r = run_scene(s, out_dir=None, progress=False, backend="inprocess")
        wall[k].append(time.perf_counter() - t0)
        loop[k].append(r.summary["loop_time_s"] / args.duration)
ref = min(loop["effects off"])
print(f"| variant | loop s per simulated s (best of {args.rounds}: the least disturbed by other jobs) | ratio to effects off | wall s |")
print("|---|---|---|---|")
for k in scenes:
    m = min(loop[k])
    print(f"| {k} | {m:.3f} | {m / ref:.2f} | {statistics.median(wall[k]):.1f} |")
