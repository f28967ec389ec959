"""Co-simulation benchmark (printed, not a test).

1. Scene benchmark (default: the severe-fault scene at 1500 rpm, 1.31 N·m, 20 s, ``table`` fidelity):
   real-time factor of the co-simulated run (fmi backend: FMUs through fmpy), and the ratio of its
   stepping-loop time to the same components stepped in-process without FMI (inprocess backend).
   ``--native``: also (c) all four models as native FMUs (drivetrain.fmu_build.native_line, built once and cached in
   FMU_DIR/native) through FMI, and the ratios native-FMI / in-process and native-FMI / pythonfmu-FMI.
2. ``--overhead``: the master's per-step cost with N small pythonfmu FMUs (a chain of inertias and
   springs), fmi vs in-process, and the cost of the FMI calls themselves.

    python benchmarks/bench_cosim.py                      # 20 s severe scene, both backends
    python benchmarks/bench_cosim.py --duration 2         # shorter
    python benchmarks/bench_cosim.py --native             # + the four native FMUs through FMI
    python benchmarks/bench_cosim.py --overhead           # master overhead only (no drivetrain needed)
    python benchmarks/bench_cosim.py --against REV        # this tree vs git revision REV, side by side

3. ``--against REV``: the scene benchmark in this tree and in REV (a temporary git worktree), each in
   fresh processes taking turns (``--rounds``), after a warm-up run in each process (JIT, map cache):
   loop real-time factor (simulated time / stepping-loop time) per backend and tree, the fmi/in-process
   loop ratio, and the after/before ratios. The machines are shared: read the ratios, not the seconds.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SCENE = ROOT / "scenarios" / "hard" / "missing_tooth_1500rpm.toml"


def scene_benchmark(scene_path: Path, duration: float | None, overrides: list[str], backends: list[str],
                    fmu_dir: str, native: bool = False) -> None:
    from drivetrain.run.runner import assemble_scene, run_scene
    from drivetrain.scene.load import load_scene

    ov = list(overrides)
    if duration is not None:
        ov.append(f"time.duration_s={duration}")
    scene = load_scene(scene_path, ov)
    spec = assemble_scene(scene)
    print(f"scene {scene.name}: {scene.time.duration_s:g} s, {scene.operating_point.final_speed_rpm:g} rpm, "
          f"{scene.operating_point.load_torque_Nm:g} N·m, health {scene.gear.health}, "
          f"mesh_contact {scene.effects.mesh_contact}, shafts {scene.effects.shaft_flexibility}")
    print(f"system: {len(spec.components)} FMUs ({', '.join(c.name + ':' + c.model for c in spec.components)}), "
          f"{len(spec.connections)} connections, H = {spec.comm_step:.6g} s")
    results = {}
    runs = [(b, b, None) for b in backends]
    if native:
        from drivetrain.fmu_build.native_line import native_fmus

        paths, note = native_fmus(spec, Path(fmu_dir) / "native", log=lambda m: print("  " + m))
        if note:
            print(f"  note: {note}")
        runs.append(("native", "fmi", paths))
    for label, backend, fmu_paths in runs:
        t0 = time.perf_counter()
        res = run_scene(scene, None, backend=backend, progress=True, fmu_dir=fmu_dir, spec=spec, plots=False,
                        fmu_paths=fmu_paths)
        wall = time.perf_counter() - t0
        s = res.summary
        results[label] = s
        print(f"  {label:9s}: wall {wall:8.2f} s  loop {s['loop_time_s']:8.2f} s  "
              f"{s['us_per_step']:8.1f} us/step  loop RTF {s['sim_time_s'] / s['loop_time_s']:6.3f}  "
              f"energy residual {s['energy_residual']:.2e}")
    if "fmi" in results and "inprocess" in results:
        a, b = results["fmi"], results["inprocess"]
        print(f"  ratio co-simulated / in-process (stepping loop): {a['loop_time_s'] / b['loop_time_s']:.3f}"
              f"   (whole run: {a['wall_time_s'] / b['wall_time_s']:.3f})   goal <= 1.15")
        print(f"  loop real-time factor of the co-simulated run: {a['sim_time_s'] / a['loop_time_s']:.3f}   goal >= 2")
    if "native" in results:
        n = results["native"]
        print(f"  loop real-time factor of the native FMUs through FMI: {n['sim_time_s'] / n['loop_time_s']:.3f}   "
              f"goal >= 2")
        for other, label in (("inprocess", "in-process"), ("fmi", "pythonfmu-FMI")):
            if other in results:
                print(f"  ratio native-FMI / {label} (stepping loop): "
                      f"{n['loop_time_s'] / results[other]['loop_time_s']:.3f}")


_MEASURE = r"""
import json, sys
try:                                   # the layout since issue 32 (wings), else the flat one before it
    from drivetrain.run.runner import run_scene
    from drivetrain.scene.load import load_scene
except ImportError:
    from drivetrain.run import run_scene
    from drivetrain.scenario import load_scene
scene_path, sets, backends, fmu_dir = sys.argv[1], json.loads(sys.argv[2]), json.loads(sys.argv[3]), sys.argv[4]
quiet = lambda m: None
warm = load_scene(scene_path, sets + ["time.duration_s=0.05", "time.settle_s=0.01"])
for b in backends:
    run_scene(warm, None, backend=b, progress=False, fmu_dir=fmu_dir, plots=False, log=quiet)
scene = load_scene(scene_path, sets)
out = {}
for b in backends:
    s = run_scene(scene, None, backend=b, progress=False, fmu_dir=fmu_dir, plots=False, log=quiet).summary
    out[b] = {"loop_s": s["loop_time_s"], "sim_s": s["sim_time_s"], "us_per_step": s["us_per_step"]}
print("RESULT " + json.dumps(out))
"""


def against_benchmark(scene_path: Path, duration: float | None, overrides: list[str], backends: list[str],
                      rev: str, rounds: int) -> None:
    import json
    import statistics

    from _trees import run_in_tree, worktree

    sets = list(overrides) + ([f"time.duration_s={duration}"] if duration is not None else [])
    runs: dict[str, list[dict]] = {"this tree": [], rev: []}
    with tempfile.TemporaryDirectory(prefix="bench_against_") as tmp, worktree(rev) as wt:
        trees = {"this tree": ROOT, rev: wt}
        for r in range(rounds):
            for label, tree in trees.items():
                fmu_dir = str(Path(tmp) / f"fmus_{'a' if tree == ROOT else 'b'}")
                runs[label].append(run_in_tree(tree, _MEASURE, [str(scene_path), json.dumps(sets),
                                                                json.dumps(backends), fmu_dir]))
                print(f"  round {r + 1}, {label}: " + ", ".join(
                    f"{b} {v['us_per_step']:.1f} us/step" for b, v in runs[label][-1].items()), flush=True)
    best = {label: {b: min(x[b]["loop_s"] for x in rs) for b in backends} for label, rs in runs.items()}
    sim = runs["this tree"][0][backends[0]]["sim_s"]
    print(f"best of {rounds} rounds, {sim:g} s simulated (loop real-time factor = simulated / loop time):")
    print(f"{'tree':>16} " + " ".join(f"{b + ' RTF':>14}" for b in backends)
          + ("   fmi/inprocess" if {"fmi", "inprocess"} <= set(backends) else ""))
    for label, bt in best.items():
        row = f"{label[:16]:>16} " + " ".join(f"{sim / bt[b]:14.3f}" for b in backends)
        if {"fmi", "inprocess"} <= set(backends):
            row += f"   {bt['fmi'] / bt['inprocess']:15.3f}"
        print(row)
    for b in backends:
        ratios = [x[b]["loop_s"] / y[b]["loop_s"] for x, y in zip(runs["this tree"], runs[rev])]
        print(f"  {b}: loop time this tree / {rev} = {min(best['this tree'][b] / best[rev][b], 9e9):.3f} "
              f"(per round: {', '.join(f'{q:.3f}' for q in ratios)}; median {statistics.median(ratios):.3f})")


def overhead_benchmark(sizes=(3, 6, 9, 12), duration: float = 1.0) -> None:
    sys.path.insert(0, str(ROOT / "tests"))
    from _cosim_test_fmus import build_test_fmus

    from drivetrain.cosim import simulate
    from drivetrain.system import ComponentSpec, Connection, SystemSpec

    d = Path(tempfile.mkdtemp(prefix="bench_cosim_"))
    fmus = build_test_fmus(d)

    def chain(n):
        """n/3 independent two-inertia systems (inertia - spring - inertia); the test inertia has one flange."""
        comps, conns = [], []
        for g in range(n // 3):
            comps += [ComponentSpec(f"A{g}", "MTInertia", {"J": 0.01, "d": 0.001, "n_sub": 1, "tau_src": 1.0}),
                      ComponentSpec(f"K{g}", "MTSpring", {"k": 100.0, "c": 0.05}),
                      ComponentSpec(f"B{g}", "MTInertia", {"J": 0.02, "d": 0.01, "n_sub": 1})]
            conns += [Connection(f"K{g}.flange_a", f"A{g}.flange"), Connection(f"K{g}.flange_b", f"B{g}.flange")]
        return SystemSpec(comps, conns, comm_step=1.0 / 12000.0)

    print(f"master per-step cost, {duration:g} s at H = 1/12000 s (test FMUs: trivial Python do_step)")
    print(f"{'N FMUs':>7} {'fmi us/step':>12} {'inproc us/step':>15} {'fmi us/FMU':>11} {'ratio':>6}")
    for n in sizes:
        spec = chain(n)
        r = {}
        for backend in ("fmi", "inprocess"):
            best = None
            for _ in range(3):
                res = simulate(spec, duration, 3000.0, backend=backend, fmu_paths=fmus, progress=False)
                best = res.us_per_step if best is None else min(best, res.us_per_step)
            r[backend] = best
        print(f"{n:7d} {r['fmi']:12.1f} {r['inprocess']:15.1f} {r['fmi'] / n:11.2f} {r['fmi'] / r['inprocess']:6.2f}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(DEFAULT_SCENE))
    ap.add_argument("--duration", type=float, default=None, help="override time.duration_s")
    ap.add_argument("--set", action="append", default=[], help="scene override key=value")
    ap.add_argument("--backends", nargs="+", default=["fmi", "inprocess"])
    ap.add_argument("--fmu-dir", default=str(ROOT / "fmus"))
    ap.add_argument("--native", action="store_true", help="also run the four native FMUs through FMI")
    ap.add_argument("--overhead", action="store_true", help="only the master overhead table (test FMUs)")
    ap.add_argument("--against", metavar="REV", help="compare with git revision REV, side by side")
    ap.add_argument("--rounds", type=int, default=2, help="rounds of --against (default 2)")
    args = ap.parse_args(argv)
    if args.against:
        against_benchmark(Path(args.scene).resolve(), args.duration, args.set, args.backends, args.against, args.rounds)
        return 0
    if args.overhead:
        overhead_benchmark()
        return 0
    scene_benchmark(Path(args.scene), args.duration, args.set, args.backends, args.fmu_dir, native=args.native)
    return 0


if __name__ == "__main__":
    sys.exit(main())
