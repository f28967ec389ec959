"""Dataset throughput: distinct-fault runs per core-hour of a ``[sweep.draw]`` grid, preparation included.

A user's dataset sweep from a cold start: ``drivetrain sweep GRID --backend native`` on local processes
(one per core), with an empty contact-map cache (the shipped healthy map only) and an empty FMU folder, so
every contact map, every native gear FMU and the shared line FMUs are built inside the measured wall time
(the numba kernels are compiled once per installation and are not counted: run the tree once before).
Every case draws its own fault (all seven families, either gear, any tooth, drawn sizes): no two cases
share a contact map.

    python benchmarks/bench_dataset_throughput.py                          # 8 runs of 20 s, this tree
    python benchmarks/bench_dataset_throughput.py --against REV            # the same grid in REV, side by side
    python benchmarks/bench_dataset_throughput.py --runs 16 --duration 20 --seed 11

Prints, per tree: runs, wall time, preparation (contact maps and FMU builds, from the sweep's manifest),
runs per core-hour = runs / (wall time x cores), and with ``--against`` the ratio of the two. The machines
are shared and noisy: absolute times vary; the ratio measured in one run holds.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

GRID = """
[scenario]
name = "throughput"
description = "distinct random faults, one per case (benchmarks/bench_dataset_throughput.py)"

[operating_point]
drive_speed_rpm = 1000.0
load_torque_Nm = 1.31

[time]
duration_s = {duration}

[outputs]
plots = false

[sweep.draw]
n = {runs}
seed = {seed}

[[sweep.draw.faults]]
kind = ["void", "missing_tooth", "pit", "spall", "chipped_tip", "crack", "wear"]
member = ["pinion", "wheel"]
tooth = "any"
radius_mm = {{ uniform = [0.5, 1.5] }}
depth_mm = {{ uniform = [0.05, 0.25] }}
length_mm = {{ uniform = [1.0, 4.0] }}
face_position = {{ uniform = [0.2, 0.8] }}
"""


def measure(tree: Path, runs: int, duration: float, seed: int, workers: int) -> dict:
    """One cold sweep in ``tree`` (its own caches in a temporary folder); wall time and the manifest's
    preparation time."""
    with tempfile.TemporaryDirectory(prefix="bench_throughput_") as tmp:
        tmp = Path(tmp)
        grid = tmp / "grid.toml"
        grid.write_text(GRID.format(runs=runs, duration=duration, seed=seed))
        # the compiled numba kernels are the installation's (compiled once, not per dataset)
        env = dict(os.environ, PYTHONPATH=str(Path(tree) / "src"), BEVEL_CACHE_DIR=str(tmp / "cache"))
        cmd = [sys.executable, "-m", "drivetrain", "sweep", str(grid), "--out", str(tmp / "out"), "--backend",
               "native", "--fmu-dir", str(tmp / "fmus"), "--workers", str(workers), "--quiet"]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, env=env, cwd=tmp, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            raise SystemExit(f"the sweep in {tree} failed (rc {proc.returncode}):\n{proc.stderr[-3000:]}")
        manifest = json.loads((tmp / "out" / "manifest.json").read_text())
        ok = sum(1 for r in manifest.get("runs", []) if r.get("status") == "ok")
        prep = manifest.get("preparation_s")
        return {"runs": ok, "wall_s": wall, "preparation_s": prep,
                "runs_per_core_hour": ok * 3600.0 / (wall * workers)}


def row(label: str, m: dict) -> str:
    prep = f"{m['preparation_s']:.0f}" if isinstance(m.get("preparation_s"), (int, float)) else "n/a"
    return (f"| {label} | {m['runs']} | {m['wall_s']:.0f} | {prep} | {m['runs_per_core_hour']:.0f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=8, help="distinct-fault cases (default 8)")
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds per run (default 20)")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="local processes (default: cores)")
    ap.add_argument("--against", metavar="REV", help="git revision to measure side by side")
    args = ap.parse_args()
    from _trees import ROOT, worktree

    print(f"{args.runs} distinct-fault runs of {args.duration:g} s, {args.workers} local processes, cold caches")
    print("| tree | runs ok | wall [s] | preparation [s] | runs per core-hour |")
    print("|---|---|---|---|---|")
    here = measure(ROOT, args.runs, args.duration, args.seed, args.workers)
    print(row("this tree", here), flush=True)
    if args.against:
        with worktree(args.against) as wt:
            there = measure(wt, args.runs, args.duration, args.seed, args.workers)
        print(row(args.against[:12], there))
        print(f"\nthis tree / {args.against[:12]}: {here['runs_per_core_hour'] / there['runs_per_core_hour']:.2f}x "
              "the runs per core-hour")


if __name__ == "__main__":
    main()
