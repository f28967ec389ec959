"""Contact-map build cost by where the faults sit (default converged meshes and grid), built without the
disk cache (a faulty map starts from the healthy one, which ships with the package); prints the table of
docs/GEAR-CONTACT.md ("Map cost by where the faults sit").

    python benchmarks/bench_map_build.py                          # about 1 minute on 2 cores
    python benchmarks/bench_map_build.py --against REV [--rounds 2] [--cases healthy "pinion void (tooth 0)"]

``--against REV``: the same builds in this tree and in git revision REV, side by side (each build in a
fresh process of its tree, the trees taking turns), and the ratio of the build times (best of the rounds):
the machines are shared and noisy, ratios taken in one run hold.
"""
import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

CASES = {"healthy": ("healthy", None),
         "pinion void (tooth 0)": ("faults", [{"kind": "void", "member": "pinion", "tooth": 0}]),
         "wheel void (tooth 38)": ("faults", [{"kind": "void", "member": "wheel", "tooth": 38}]),
         "wheel pit (tooth 38, R 1.5 mm)": ("faults", [{"kind": "pit", "member": "wheel", "tooth": 38}]),
         "pinion pit (tooth 5)": ("faults", [{"kind": "pit", "member": "pinion", "tooth": 5}]),
         "wheel missing tooth (38)": ("faults", [{"kind": "missing_tooth", "member": "wheel", "tooth": 38}]),
         "pinion crack (tooth 11, coast)": ("faults", [{"kind": "crack", "member": "pinion", "tooth": 11,
                                                         "flank": "coast"}]),
         "pinion + wheel void": ("faults", [{"kind": "void", "member": "pinion", "tooth": 0},
                                            {"kind": "void", "member": "wheel", "tooth": 38}])}

_BUILD = r"""
import json, sys, time
from gearcontact_fmu import contact_map as cm
health, faults = json.loads(sys.argv[1])
cm.get_map(health="healthy", use_cache=False, grid=cm.MapGrid(points_per_pitch=2, s_points=2))   # compile
t0 = time.perf_counter()
m = cm.get_map(health=health, use_cache=False, fault_kwargs={"faults": faults} if faults else None)
print("RESULT " + json.dumps({"seconds": time.perf_counter() - t0, "rows": len(m.theta)}))
"""


def table() -> None:
    import numpy as np

    from gearcontact_fmu import contact_map as cm

    print("| faults | pinion revolutions | built | flank rows computed | of | build [s] | file [MB] |")
    print("|---|---|---|---|---|---|---|")
    for label, (health, faults) in CASES.items():
        t0 = time.perf_counter()
        m = cm.get_map(health=health, use_cache=False, fault_kwargs={"faults": faults} if faults else None)
        t = time.perf_counter() - t0
        with tempfile.TemporaryDirectory() as tmp:             # the file as the cache writes it
            path = Path(tmp) / "map.npz"
            cm.save_map(m, path)
            size = path.stat().st_size
        print(f"| {label} | {m.info['pinion_revolutions']} | {m.info['built']} | {m.info['flank_rows_computed']} | "
              f"{2 * len(m.theta)} | {t:.1f} | {size/1e6:.2f} |", flush=True)


def against(rev: str, cases: list[str], rounds: int) -> None:
    from _trees import ROOT, run_in_tree, worktree

    with worktree(rev) as wt:
        print(f"| faults | this tree [s] | {rev[:12]} [s] | {rev[:12]} / this tree |")
        print("|---|---|---|---|")
        for label in cases:
            times = {"here": [], "there": []}
            for _ in range(rounds):
                for key, tree in (("here", ROOT), ("there", wt)):
                    times[key].append(run_in_tree(tree, _BUILD, [json.dumps(CASES[label])])["seconds"])
            here, there = min(times["here"]), min(times["there"])
            print(f"| {label} | {here:.2f} | {there:.2f} | {there / here:.3f} |", flush=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", metavar="REV", help="git revision to compare with (side by side)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--cases", nargs="*", default=["healthy"], choices=list(CASES),
                    help="with --against: the cases (default: healthy)")
    args = ap.parse_args()
    if args.against:
        against(args.against, args.cases, args.rounds)
    else:
        table()
