"""Bit-identity of results across a code change: hash the signals of short runs.

    python benchmarks/bit_identity.py                    # hashes of this tree's runs
    python benchmarks/bit_identity.py --against REV      # and of git revision REV, side by side

Each case is a short run of a scene (several fidelities, faults, both backends); its hash is the
SHA-256 of the time vector and every signal array (name, dtype, bytes) in signals.h5. Timestamps
and wall times are not hashed. With --against, REV is checked out in a temporary git worktree and
the same cases run there in a fresh process; the script prints both hashes and exits 1 if any differ.
The in-process hashes are also stored in tests/data/bit_identity.json for the default test suite
(``--store``).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _trees import ROOT, run_in_tree, worktree  # noqa: E402

STORE = ROOT / "tests" / "data" / "bit_identity.json"

# name: (scene file relative to the root, --set overrides, backend)
CASES = {
    "table_healthy_inproc": ("scenarios/example.toml", ["time.duration_s=0.12"], "inprocess"),
    "table_severe_fmi": ("scenarios/example.toml", ["time.duration_s=0.12", "gear.health=\"severe\""], "fmi"),
    "pcm_mild_inproc": ("scenarios/example.toml", ["time.duration_s=0.02", "gear.health=\"mild\"",
                                                   "effects.mesh_contact=\"pcm\""], "inprocess"),
    "analytic_rigid_inproc": ("scenarios/example.toml", ["time.duration_s=0.12", "effects.mesh_contact=\"analytic\"",
                                                         "effects.shaft_flexibility=\"rigid\""], "inprocess"),
}

_RUNNER = r"""
import hashlib, json, sys, tempfile
from pathlib import Path
import numpy as np
try:                                   # the layout since issue 32 (wings), else the flat one before it
    from drivetrain.scene.load import load_scene
    from drivetrain.run.runner import run_scene
    from drivetrain.run.outputs import read_hdf5
except ImportError:
    from drivetrain.scenario import load_scene
    from drivetrain.run import run_scene
    from drivetrain.outputs import read_hdf5
cases = json.loads(sys.argv[1]); root = Path(sys.argv[2]); fmu_dir = sys.argv[3]
out = {}
for name, (scene_file, sets, backend) in cases.items():
    sets = list(sets) + ["outputs.plots=false", "outputs.aalto_csv=false"]
    scene = load_scene(root / scene_file, sets)
    with tempfile.TemporaryDirectory() as d:
        run_scene(scene, d, backend=backend, progress=False, fmu_dir=fmu_dir, log=lambda m: None)
        data = read_hdf5(Path(d) / "signals.h5")
    h = hashlib.sha256()
    for key, arr in [("time", data["time"])] + sorted(data["signals"].items()):
        arr = np.ascontiguousarray(arr)
        h.update(key.encode()); h.update(str(arr.dtype).encode()); h.update(arr.tobytes())
    out[name] = {"sha256": h.hexdigest(), "samples": int(len(data["time"])), "signals": len(data["signals"])}
print("RESULT " + json.dumps(out))
"""


def platform_key() -> dict:
    """What the bits of a result depend on besides the code: the builds of numpy and numba, and the processor
    LLVM compiles the kernels for (another CPU generation vectorises reductions differently: the last bits
    of a contact map move, measured ~1e-12 relative between a znver4 and the machine that stored first)."""
    import platform

    import llvmlite.binding as llvm
    import numba
    import numpy as np
    return {"machine": platform.machine(), "python": platform.python_version(), "numpy": np.__version__,
            "numba": numba.__version__, "cpu": llvm.get_host_cpu_name()}


def stored_entries() -> list[dict]:
    """The stored hashes, one entry per platform (:func:`platform_key`) they were computed on."""
    if not STORE.is_file():
        return []
    data = json.loads(STORE.read_text())
    return data["platforms"] if "platforms" in data else [data]


def hashes(src_root: Path, cases: dict, fmu_dir: str) -> dict:
    return run_in_tree(src_root, _RUNNER, [json.dumps(cases), str(src_root), fmu_dir])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", help="git revision to compare with")
    ap.add_argument("--store", action="store_true", help="write the in-process hashes to " + str(STORE.relative_to(ROOT)))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        here = hashes(ROOT, CASES, str(Path(tmp) / "fmus_here"))
        rows = {name: [h["sha256"]] for name, h in here.items()}
        if args.against:
            with worktree(args.against) as wt:
                there = hashes(wt, CASES, str(Path(tmp) / "fmus_there"))
            for name in rows:
                rows[name].append(there[name]["sha256"])
    print(f"{'case':26s} {'this tree':18s}" + (f" {args.against[:16]:18s} same" if args.against else ""))
    differ = 0
    for name, hs in rows.items():
        same = len(set(hs)) == 1
        differ += not same
        print(f"{name:26s} {hs[0][:16]:18s}" + (f" {hs[1][:16]:18s} {'yes' if same else 'NO'}" if len(hs) > 1 else ""))
    if args.store:
        entry = {"platform": platform_key(), "cases": {n: dict(zip(("scene", "set", "backend"), CASES[n]), **here[n])
                                                       for n in CASES if CASES[n][2] == "inprocess"}}
        others = [e for e in stored_entries() if e["platform"] != entry["platform"]]
        STORE.parent.mkdir(parents=True, exist_ok=True)
        STORE.write_text(json.dumps({"platforms": others + [entry]}, indent=1) + "\n")
        print(f"stored {STORE.relative_to(ROOT)} for {entry['platform']} ({len(others)} other platform(s) kept)")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
