"""A new bevel pair's healthy contact map from nothing, side by side with the rig's (issue 42: <= 60 s on 2 cores).

Each build runs in a fresh process with an empty contact-map cache (BEVEL_CACHE_DIR) and ``use_cache=False``
(the rig's shipped seed map is not used: its map is built like any other). Two conditions per pair:

- ``warm``: numba's compile cache already holds the contact kernels (any earlier map build on the machine);
- ``cold`` (``--cold``): an empty numba cache as well, as after ``pip install``: the kernels' compile included.

The pairs are the rig's and ``gearcontact_fmu.pair_check.OTHER_PAIRS``. Prints one row per pair and condition:
wall seconds of the process's ``get_map`` call, the map's own ``build_seconds`` (tabulation), the CPU seconds of
the process and its children (the map tabulates in a pool of ``$BEVEL_MAP_WORKERS`` = all CPUs), the rows and
triangles, and the load average (the machine is shared: read the CPU seconds too).

    python benchmarks/bench_other_pairs.py [--cold] [--pairs rig 20x40_m4 ...]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, os, resource, sys, time
t0 = time.perf_counter()
from gearcontact_fmu.contact_map import get_map
from gearcontact_fmu.pair_check import check_pair, other_pair
from gearcontact_fmu.params import BevelGearParams
name = sys.argv[1]
gear = check_pair(BevelGearParams() if name == "rig" else other_pair(name))
t1 = time.perf_counter()
cm = get_map(gear, use_cache=False)
t2 = time.perf_counter()
cpu = sum(getattr(resource.getrusage(w), f) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
          for f in ("ru_utime", "ru_stime"))
print("RESULT " + json.dumps({"map_s": t2 - t1, "import_s": t1 - t0, "build_seconds": cm.info["build_seconds"],
      "cpu_s": cpu, "rows": int(cm.info["n_theta"]), "pinion_triangles": cm.info.get("pinion_triangles"),
      "wheel_triangles": cm.info.get("wheel_triangles"), "load": os.getloadavg()[0]}))
"""


def measure(name: str, numba_dir: str) -> dict:
    with tempfile.TemporaryDirectory() as maps:
        env = {**os.environ, "NUMBA_CACHE_DIR": numba_dir, "BEVEL_CACHE_DIR": maps,
               "PYTHONPATH": str(ROOT / "src")}
        load0 = os.getloadavg()[0]
        p = subprocess.run([sys.executable, "-c", CHILD, name], env=env, capture_output=True, text=True)
        line = [x for x in p.stdout.splitlines() if x.startswith("RESULT ")]
        if p.returncode or not line:
            raise RuntimeError(f"{name}: build failed:\n{p.stderr[-3000:]}")
        return {**json.loads(line[0][7:]), "load0": load0}


def main() -> None:
    from gearcontact_fmu.pair_check import OTHER_PAIRS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cold", action="store_true", help="also build with an empty numba cache (compile included)")
    ap.add_argument("--pairs", nargs="*", default=["rig", *OTHER_PAIRS])
    args = ap.parse_args()
    print("| pair | numba cache | get_map [s] | tabulation [s] | CPU [s] | rows | triangles pinion / wheel | load |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as warm:
        measure(args.pairs[0], warm)                  # fills the warm numba cache
        for name in args.pairs:
            conds = [("warm", warm)]
            if args.cold:
                conds.insert(0, ("cold", None))
            for label, d in conds:
                if d is None:
                    with tempfile.TemporaryDirectory() as cold:
                        r = measure(name, cold)
                else:
                    r = measure(name, d)
                print(f"| {name} | {label} | {r['map_s']:.1f} | {r['build_seconds']:.1f} | {r['cpu_s']:.1f} | {r['rows']} | "
                      f"{r['pinion_triangles']} / {r['wheel_triangles']} | {r['load0']:.1f} -> {r['load']:.1f} |",
                      flush=True)


if __name__ == "__main__":
    main()
