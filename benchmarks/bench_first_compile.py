"""What a fresh install's first dataset sweep costs before its first run: numba's compile of the contact kernels.

Each measurement runs in a fresh process with an empty numba cache (NUMBA_CACHE_DIR) and an empty contact-map
cache (BEVEL_CACHE_DIR), as after ``pip install``: it loads ``scenarios/datasets/random_faults.toml`` with
``--set sweep.draw.n=N`` (4 N distinct faults), assembles the cases (the parent process) and prepares their
contact maps (``prepare_caches``: the sweep's pool) and prints the seconds of each phase. ``--cases 1`` is the
first distinct-fault run's share; then the same again on the warm numba cache (the maps cold), whose difference
is the compile.

    python benchmarks/bench_first_compile.py [--n 2] [--cases 8] [--tree PATH]

``--tree PATH`` measures another checkout (e.g. ``git worktree add /tmp/before REV``) the same way; run both
side by side, and read the CPU seconds when the machine is shared.
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

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
from drivetrain.scene.load import load_scenes
from drivetrain.campaigns import sweep as S
n, cases = int(sys.argv[1]), int(sys.argv[2])
scenes = load_scenes(sys.argv[3], ["time.duration_s=3"])[:cases]
t1 = time.perf_counter()
specs, _ = S._specs_of(scenes, None)
t2 = time.perf_counter()
S.prepare_caches([s for s in specs if s is not None], log=lambda m: print(m, file=sys.stderr, flush=True))
t3 = time.perf_counter()
print(json.dumps({"imports_and_scenes_s": t1 - t0, "assembly_s": t2 - t1, "prepare_s": t3 - t2, "total_s": t3 - t0,
                  "cases": len(scenes)}))
"""


def measure(root: Path, n: int, cases: int, numba_dir: str, cache_dir: str) -> dict:
    env = {**os.environ, "NUMBA_CACHE_DIR": numba_dir, "BEVEL_CACHE_DIR": cache_dir,
           "PYTHONPATH": str(root / "src"), "PYTHONDONTWRITEBYTECODE": "1"}
    # the grid with n draws, as a file (a revision before issue 43 has no --set sweep.draw.n)
    import re

    text = (root / "scenarios" / "datasets" / "random_faults.toml").read_text()
    grid = Path(cache_dir) / "random_faults.toml"
    grid.write_text(re.sub(r"(?m)^n = \d+", f"n = {n}", text))
    import resource

    t = time.perf_counter()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.run([sys.executable, "-c", CHILD, str(n), str(cases), str(grid)], env=env, capture_output=True,
                       text=True)
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise SystemExit(f"{root}: failed\n{p.stderr[-3000:]}")
    out = json.loads(p.stdout.strip().splitlines()[-1])
    out["wall_s"] = time.perf_counter() - t
    # CPU seconds of the process and every process it waited for (the pools' workers): what the cores spent,
    # whatever else ran on them (a busy machine stretches the wall time, not this)
    out["cpu_s"] = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2, help="draws per operating point (default 2: 8 cases)")
    ap.add_argument("--cases", type=int, default=8, help="cases prepared (default 8)")
    ap.add_argument("--tree", default=None, metavar="PATH", help="measure the checkout at PATH instead of this tree "
                    "(read only: no bytecode or numba cache is written there), e.g. a worktree of the revision before")
    args = ap.parse_args()
    label, root = (args.tree, Path(args.tree)) if args.tree else ("this tree", ROOT)
    tmp = tempfile.mkdtemp(prefix="bench_compile_")
    numba_dir = tempfile.mkdtemp(prefix="numba_", dir=tmp)
    cold = measure(root, args.n, args.cases, numba_dir, tempfile.mkdtemp(prefix="maps_", dir=tmp))
    warm = measure(root, args.n, args.cases, numba_dir, tempfile.mkdtemp(prefix="maps_", dir=tmp))
    print(f"{label}: {args.cases} cases, cold numba cache {cold['wall_s']:.1f} s wall, {cold['cpu_s']:.1f} "
          f"CPU-s (assembly {cold['assembly_s']:.1f} s, preparation {cold['prepare_s']:.1f} s); warm numba "
          f"cache {warm['wall_s']:.1f} s wall, {warm['cpu_s']:.1f} CPU-s (assembly {warm['assembly_s']:.1f} s, "
          f"preparation {warm['prepare_s']:.1f} s); compile ≈ {cold['wall_s'] - warm['wall_s']:.1f} s wall, "
          f"{cold['cpu_s'] - warm['cpu_s']:.1f} CPU-s", flush=True)


if __name__ == "__main__":
    main()
