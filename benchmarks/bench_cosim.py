"""Co-simulation benchmark (printed, not a test).

1. Scene benchmark (default: the severe-fault scene at 1500 rpm, 1.31 N·m, 20 s, ``table`` fidelity):
   real-time factor of the co-simulated run (fmi backend: FMUs through fmpy), and the ratio of its
   stepping-loop time to the same components stepped in-process without FMI (inprocess backend).
2. ``--overhead``: the master's per-step cost with N small pythonfmu FMUs (a chain of inertias and
   springs), fmi vs in-process, and the cost of the FMI calls themselves.

    python benchmarks/bench_cosim.py                      # 20 s severe scene, both backends
    python benchmarks/bench_cosim.py --duration 2         # shorter
    python benchmarks/bench_cosim.py --overhead           # master overhead only (no drivetrain needed)
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
                    fmu_dir: str) -> None:
    from drivetrain.run import assemble_scene, run_scene
    from drivetrain.scenario import load_scene

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
    for backend in backends:
        t0 = time.perf_counter()
        res = run_scene(scene, None, backend=backend, progress=True, fmu_dir=fmu_dir, spec=spec, plots=False)
        wall = time.perf_counter() - t0
        s = res.summary
        results[backend] = s
        print(f"  {backend:9s}: wall {wall:8.2f} s  loop {s['loop_time_s']:8.2f} s  "
              f"{s['us_per_step']:8.1f} us/step  RTF {s['sim_time_s'] / wall:6.3f}  "
              f"energy residual {s['energy_residual']:.2e}")
    if "fmi" in results and "inprocess" in results:
        a, b = results["fmi"], results["inprocess"]
        print(f"  ratio co-simulated / in-process (stepping loop): {a['loop_time_s'] / b['loop_time_s']:.3f}"
              f"   (whole run: {a['wall_time_s'] / b['wall_time_s']:.3f})   goal <= 1.5")
        print(f"  real-time factor of the co-simulated run: {a['real_time_factor']:.3f}   goal >= 1")


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
    ap.add_argument("--overhead", action="store_true", help="only the master overhead table (test FMUs)")
    args = ap.parse_args(argv)
    if args.overhead:
        overhead_benchmark()
        return 0
    scene_benchmark(Path(args.scene), args.duration, args.set, args.backends, args.fmu_dir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
