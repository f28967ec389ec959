"""The ``drivetrain`` command line.

Each subcommand lives in its own module and is imported lazily, so that ``drivetrain --help`` stays fast
and a missing optional piece does not break the others.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _cmd_build_fmus(args: argparse.Namespace) -> int:
    from drivetrain.fmubuild import build_all

    paths = build_all(args.out, only=args.only)
    for p in paths:
        print(p)
    try:  # record the sources the FMUs were built from, so that `drivetrain run` sees them as fresh
        from drivetrain.master import record_built

        record_built(args.out, [p for p in paths])
    except Exception:  # pragma: no cover - stamping is an optimisation only
        pass
    return 0


def _scene_errors(exc: BaseException) -> int:
    print(f"error: {exc}", file=sys.stderr)
    return 2


def _cmd_run(args: argparse.Namespace) -> int:
    from drivetrain.master import ConfigurationError, CosimError
    from drivetrain.scenario import ScenarioError, load_scene

    try:
        scene = load_scene(args.scene, args.set or (), case=args.case)
    except ScenarioError as exc:
        return _scene_errors(exc)
    out = args.out or f"out/{scene.name}"
    from drivetrain.run import run_scene

    try:
        res = run_scene(scene, out, backend=args.backend, progress=not args.quiet, fmu_dir=args.fmu_dir,
                        plots=False if args.no_plots else None)
    except ConfigurationError as exc:
        return _scene_errors(exc)
    except CosimError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 3
    s = res.summary
    if not args.quiet:
        print(f"{scene.name}: {s['sim_time_s']:g} s simulated in {s['wall_time_s']:.3g} s "
              f"(real-time factor {s['real_time_factor']:.3g}, {s['us_per_step']:.1f} us/step, {s['n_fmus']} FMUs)")
        for name, st in s["torque"].items():
            print(f"  {name}: mean {st['mean']:.4g} N·m, RMS {st['rms']:.4g} N·m")
        print(f"  f_DSH {s['f_DSH']:.4g} Hz, f_MSH {s['f_MSH']:.4g} Hz, f_PSH {s['f_PSH']:.4g} Hz, "
              f"f_GMF {s['f_GMF']:.4g} Hz; energy residual {s['energy_residual']:.3g} (relative)")
        if s["energy_residual"] > 0.01:
            w = s["energy"]["worst_fmu"]
            print(f"  warning: energy residual above 1 %; largest in FMU {w!r} "
                  f"({s['energy']['per_fmu'][w]['residual_J']:.4g} J of {s['energy']['reference_J']:.4g} J)")
        for w in s["warnings"]:
            print(f"  warning: {w}")
        print(f"  wrote {out}/: " + ", ".join(Path(p).name for p in [res.files['signals'], res.files['summary'],
                                                                       *res.files.get('plots', []),
                                                                       *([res.files['csv']] if 'csv' in res.files else [])]))
    return 0


def _cmd_eigen(args: argparse.Namespace) -> int:
    import inspect

    from drivetrain.eigen import run_eigen_command

    kw = {}
    params = inspect.signature(run_eigen_command).parameters
    if args.set:
        if "overrides" not in params:
            print("error: --set is not supported by this eigen command", file=sys.stderr)
            return 2
        kw["overrides"] = args.set
    return int(run_eigen_command(args.scene, **kw) or 0)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from drivetrain.calibrate import run_calibrate_command

    return int(run_calibrate_command(args.measured, args.out) or 0)


def _cmd_sweep(args: argparse.Namespace) -> int:
    from drivetrain.master import ConfigurationError
    from drivetrain.scenario import ScenarioError, load_scenes

    try:
        scenes = [s for path in args.scenes for s in load_scenes(path, args.set or ())]
    except ScenarioError as exc:
        return _scene_errors(exc)
    if args.only:
        import fnmatch

        scenes = [s for s in scenes if any(fnmatch.fnmatch(s.name, pat) for pat in args.only)]
    from drivetrain.sweep import run_sweep

    try:
        manifest = run_sweep(scenes, args.out, workers=args.workers, address=args.scheduler,
                             backend=args.backend, fmu_dir=args.fmu_dir, skip_existing=args.skip_existing,
                             plots=not args.no_plots, progress=not args.quiet)
    except ConfigurationError as exc:
        return _scene_errors(exc)
    failed = [r for r in manifest["runs"] if r["status"] != "ok"]
    print(f"{len(manifest['runs']) - len(failed)}/{len(manifest['runs'])} runs ok; manifest: {manifest['path']}")
    for r in failed:
        print(f"  {r['name']}: {r['status']}: {r.get('error', '')}".rstrip(), file=sys.stderr)
    return 0 if not failed else 3


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="drivetrain", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("build-fmus", help="build every FMU of the project into fmus/ (or --out DIR)")
    p.add_argument("--out", default="fmus", help="output directory (default: fmus)")
    p.add_argument("--only", nargs="*", default=None, help="build only these FMUs (model names)")
    p.set_defaults(func=_cmd_build_fmus)

    p = sub.add_parser("run", help="run a scene: signals (HDF5), summary.json and plots into --out DIR")
    p.add_argument("scene", help="scene file (.toml); a grid file needs --case")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a scene key, e.g. --set time.duration_s=0.5 (repeatable)")
    p.add_argument("--out", default=None, help="output directory (default: out/<scene name>)")
    p.add_argument("--case", default=None, help="with a grid file: the name of the case to run")
    p.add_argument("--backend", choices=("fmi", "inprocess"), default="fmi",
                   help="fmi: FMUs through fmpy (default); inprocess: the same slave classes without FMI")
    p.add_argument("--fmu-dir", default="fmus", help="where the FMUs are (built on demand; default: fmus)")
    p.add_argument("--no-plots", action="store_true", help="do not write PNG plots")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no report")
    p.set_defaults(func=_cmd_run)

    p = sub.add_parser("eigen", help="natural frequencies of the assembled, linearised drivetrain")
    p.add_argument("scene")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a scene key")
    p.set_defaults(func=_cmd_eigen)

    p = sub.add_parser("calibrate", help="refit the loss parameters from a measured mean-torque table")
    p.add_argument("measured", help="CSV like measured_mean_torques.csv")
    p.add_argument("--out", default=None, help="where to write the fitted parameters")
    p.set_defaults(func=_cmd_calibrate)

    p = sub.add_parser("sweep", help="run many scenes (grid files expand) in parallel; one HDF5 per run + manifest")
    p.add_argument("scenes", nargs="+", help="scene or grid files")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a key of every scene")
    p.add_argument("--out", default="out/sweep", help="output directory (default: out/sweep)")
    p.add_argument("--only", nargs="*", default=None, help="run only cases whose name matches these patterns")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default: CPU count)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler address (tcp://host:8786); default: local process pool")
    p.add_argument("--backend", choices=("fmi", "inprocess"), default="fmi")
    p.add_argument("--fmu-dir", default="fmus")
    p.add_argument("--skip-existing", action="store_true", help="skip runs whose summary.json exists")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_sweep)

    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
