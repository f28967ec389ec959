"""The drivetrain command line.

Each subcommand lives in its own module and is imported lazily, so that ``drivetrain --help`` stays fast
and a missing optional piece does not break the others.
"""
from __future__ import annotations

import argparse
import contextlib
import errno
import json
import math
import os
import shutil
import sys
import time
from pathlib import Path

from drivetrain.system import BACKENDS
from drivetrain.errors import Refused


def _cmd_build_fmus(args: argparse.Namespace) -> int:
    from drivetrain.fmu_build.build import build_all
    from drivetrain.fmu_build.fmus import fmu_dir_or_default

    paths = build_all(fmu_dir_or_default(args.out), only=args.only)
    for p in paths:
        print(p)
    try:  # record the sources the FMUs were built from, so that `drivetrain run` sees them as fresh
        from drivetrain.fmu_build.fmus import record_built

        record_built(args.out, [p for p in paths])
    except Exception:  # pragma: no cover - stamping is an optimisation only
        pass
    return 0


def _scene_errors(exc: BaseException) -> int:
    print(f"error: {exc}", file=sys.stderr)
    return 2


def _write_from_scene(args: argparse.Namespace, write, what: str) -> int:
    """The export and build commands: load the scene of ``args``, ``write(scene, log)`` returns the lines
    to print; a scene or system refusal exits 2 with its problems, a file system error 2 naming ``what``."""
    from drivetrain.errors import ConfigurationError, ScenarioError
    from drivetrain.scene.load import load_scene

    try:
        scene = load_scene(args.scene, args.set or (), case=args.case)
        lines = write(scene, lambda m: print(m, file=sys.stderr))
    except (ScenarioError, ConfigurationError) as exc:
        return _scene_errors(exc)
    except OSError as exc:
        print(f"error: cannot write {what}: {exc}", file=sys.stderr)
        return 2
    for line in lines:
        print(line)
    return 0


def _cmd_export_ssp(args: argparse.Namespace) -> int:
    from drivetrain.interop.ssp import export_ssp

    def write(scene, log):
        path = export_ssp(scene, args.out or f"{scene.name}.ssp", fmu_dir=args.fmu_dir, log=log, native=args.native)
        return [f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB): {scene.name}, stop time "
                f"{scene.time.duration_s:g} s"]

    return _write_from_scene(args, write, "the archive")


def _cmd_build_native_gear(args: argparse.Namespace) -> int:
    from drivetrain.fmu_build.native_gear import build_native_gear
    from drivetrain.run.assemble import gear_parameters

    def write(scene, log):
        path = build_native_gear(gear_parameters(scene), args.out or _native_dir() / "GearContact.fmu", log=log)
        return [f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB): native GearContact of {scene.name} (table, stage)"]

    return _write_from_scene(args, write, "the FMU")


def _cmd_build_native(args: argparse.Namespace) -> int:
    from drivetrain.fmu_build.native_line import build_native_fmus
    from drivetrain.run.runner import assemble_scene

    def write(scene, log):
        paths = build_native_fmus(assemble_scene(scene), args.out or _native_dir(), log=log)
        return [f"wrote {path}: native {model}" for model, path in paths.items()]

    return _write_from_scene(args, write, "the FMUs")


_FORCE_HELP = ("run even when the run is predicted to take more than 10x its simulated time (and over 10 min), "
               "or its contact model longer than numerics.max_contact_hours")


@contextlib.contextmanager
def _stop_on_signals():
    """While a run runs, SIGINT (Ctrl-C) and SIGTERM end its stepping loop at the next chunk of steps: the run
    is written as "interrupted" with what it computed (exit 130). Outside the loop (preparation, writing) they
    interrupt at once, and the output directory says "running", not "ok". A process forked meanwhile (a map
    builder's pool worker) gets the signals' default action, as its parent expects; the handlers before are
    restored afterwards."""
    import signal
    import threading

    from drivetrain.cosim.master import request_stop

    if threading.current_thread() is not threading.main_thread():     # only the main thread takes signals
        yield
        return
    owner = os.getpid()

    def handler(signum, frame):
        if os.getpid() != owner:                  # a forked child: die as the default says
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        if not request_stop(f"{signal.Signals(signum).name} received"):
            raise KeyboardInterrupt

    before = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, h in before.items():
            signal.signal(sig, h)


def _cmd_run(args: argparse.Namespace) -> int:
    from drivetrain.cosim import ConfigurationError, CosimError
    from drivetrain.scene.load import ScenarioError, load_scene

    overrides = list(args.set or ())
    if args.tolerance is not None:
        overrides.append(f"numerics.tolerance_pct={args.tolerance!r}")
    try:
        scene = load_scene(args.scene, overrides, case=args.case)
    except ScenarioError as exc:
        return _scene_errors(exc)
    out = args.out or f"out/{scene.name}"
    from drivetrain.run.runner import RunFailedError, run_scene

    fmu_paths, problems = {}, []
    for item in args.fmu or ():
        model, sep, path = item.partition("=")
        if not (sep and model and path):
            problems.append(f"--fmu {item!r}: expected MODEL=PATH, e.g. GearContact=fmus/native/GearContact.fmu")
        elif not Path(path).is_file():
            problems.append(f"--fmu {item!r}: no such file {path}")
        else:
            fmu_paths[model] = Path(path)
    if problems:
        print("error: " + "\n  ".join(problems), file=sys.stderr)
        return 2
    if args.native:
        if args.backend not in ("fmi", "native"):
            print("error: --native (= --backend native) runs compiled FMUs through FMI: not with --backend "
                  f"{args.backend!r}", file=sys.stderr)
            return 2
        args.backend = "native"
    said = _Said()
    try:
        with _stop_on_signals():
            res = run_scene(scene, out, backend=args.backend, progress=not args.quiet, fmu_dir=args.fmu_dir,
                            plots=False if args.no_plots else None, force=args.force, fmu_paths=fmu_paths or None,
                            started=args.started, log=said)
    except ConfigurationError as exc:
        return _scene_errors(exc)
    except RunFailedError as exc:
        r = exc.result
        f = r.summary["failure"]
        if r.summary.get("status") == "interrupted":
            print(f"interrupted at t = {f['time_s']:.9g} s ({f['cause']}); partial results (up to t = "
                  f"{f['last_sample_time_s']:.9g} s, status \"interrupted\") written to {r.out_dir}/", file=sys.stderr)
            return 130
        print(f"error: {exc}", file=sys.stderr)
        names = [Path(p).name for p in [r.files.get("signals"), r.files.get("summary"), *r.files.get("plots", []),
                                         r.files.get("csv")] if p]
        print(f"  failed at t = {f['time_s']:.9g} s in FMU {f['component']!r} ({f['model']}, {f['function']}): "
              f"{f['cause']}", file=sys.stderr)
        print(f"  partial results (up to t = {f['last_sample_time_s']:.9g} s, status \"failed\") written to "
              f"{r.out_dir}/: {', '.join(names)}", file=sys.stderr)
        return 3
    except CosimError as exc:
        print(f"error: {exc}", file=sys.stderr)
        print("  nothing was written (the run failed before its first step)", file=sys.stderr)
        return 3
    s = res.summary
    if s.get("status") != "ok":          # completed, but with what no run may claim (non-finite samples)
        print(f"error: {scene.name}: {s['failure']['cause']}; results written to {res.out_dir}/ with status "
              f"\"{s['status']}\"", file=sys.stderr)
        return 3
    if not args.quiet:
        print(f"{scene.name}: {s['sim_time_s']:g} s simulated in {s['wall_time_s']:.3g} s wall: "
              + _run_time_parts(s))
        from drivetrain.run.outputs import load_text

        op = scene.operating_point
        print(f"  operating point: {op.final_speed_rpm:g} rpm, "
              + (load_text(op.load_profile_Nm[-1][1], profile=True, ratio=scene.drivetrain.load_gear_ratio)
                 if op.load_profile_Nm else load_text(op.load_torque_Nm, ratio=scene.drivetrain.load_gear_ratio)))
        for name, st in s["torque"].items():
            print(f"  {name}: mean {st['mean']:.4g} N·m, RMS {st['rms']:.4g} N·m")
        print(f"  f_DSH {s['f_DSH']:.4g} Hz, f_MSH {s['f_MSH']:.4g} Hz, f_PSH {s['f_PSH']:.4g} Hz, "
              f"f_GMF {s['f_GMF']:.4g} Hz; energy residual {s['energy_residual']:.3g} (relative)")
        st = s.get("stability") or {}
        if all(st.get(k) is not None for k in ("max_penetration_rel_umax", "min_substep_s", "n_refinements")):
            rt = st["rattle"]
            print(f"  gear stage: max penetration {st['max_penetration_m']:.3g} m "
                  f"({st['max_penetration_rel_umax']:.3g} of u_max), smallest sub-step {st['min_substep_s']:.3g} s, "
                  f"{st['n_refinements']} refinements; after settling {rt['n_separations']} tooth separations "
                  f"({100 * (rt['separated_fraction'] or 0.0):.3g} % of the time out of contact)")
        if s["energy_residual"] > 0.01:
            w = s["energy"]["worst_fmu"]
            print(f"  warning: energy residual above 1 %; largest in FMU {w!r} "
                  f"({s['energy']['per_fmu'][w]['residual_J']:.4g} J of {s['energy']['reference_J']:.4g} J)")
        for w in s["warnings"]:
            if f"warning: {w}" not in said.lines:          # each warning once: not again if said while running
                print(f"  warning: {w}")
        print(f"  wrote {out}/: " + ", ".join(Path(p).name for p in [res.files['signals'], res.files['summary'],
                                                                       *res.files.get('plots', []),
                                                                       *([res.files['csv']] if 'csv' in res.files else [])]))
    return 0


class _Said:
    """The ``log`` of a run from the command line: each message once on stderr, remembered (the report after
    the run does not repeat a warning already said while it ran)."""

    def __init__(self):
        self.lines: set[str] = set()

    def __call__(self, message: str) -> None:
        if message not in self.lines:
            self.lines.add(message)
            print(message, file=sys.stderr)


def _run_time_parts(s: dict) -> str:
    """The parts of a run's wall time (summary.json ``time_breakdown_s``: they add up to ``wall_time_s``)."""
    tb = s["time_breakdown_s"]
    rtf = f"real-time factor {s['real_time_factor']:.3g}, " if s.get("real_time_factor") else ""
    parts = [f"start-up {tb['startup']:.3g} s (interpreter, imports, scene)",
             f"assembly and checks {tb['assemble_and_check']:.3g} s", f"native build {tb['native_build']:.3g} s",
             f"FMU setup {tb['fmu_setup']:.3g} s (loading, maps, initialisation)",
             f"co-simulation loop {tb['loop']:.3g} s ({rtf}{s['us_per_step']:.1f} us/step, {s['n_fmus']} FMUs)",
             f"post-processing {tb['postprocess']:.3g} s", f"writing files {tb['write'] or 0.0:.3g} s",
             f"plots {tb['plots'] or 0.0:.3g} s"]
    return ", ".join(parts)


def _cmd_eigen(args: argparse.Namespace) -> int:
    """``drivetrain eigen SCENE``: the natural frequencies of the scene's assembled drivetrain and the
    stability of every cut."""
    from drivetrain.run.assemble import assemble
    from drivetrain.models.eigen import describe_modes
    from drivetrain.scene.load import ScenarioError, load_scene
    from drivetrain.models.stability import check_cuts

    from drivetrain.errors import FileFormatError
    from drivetrain.models.eigen import chain_modes
    from drivetrain.rig.data import load_public

    table = Path(args.parameters).resolve() if args.parameters else None
    if args.scene is None and table is None:
        return _scene_errors(ValueError("drivetrain eigen: give a scene file, or --parameters TABLE (or both)"))
    try:
        if args.scene is None:                 # a table alone: its own chain, whatever its layout
            _print_chain_modes(table, chain_modes(load_public(table), args.modes))
            return 0
        sets = list(args.set or ()) + ([f"drivetrain.parameters={json.dumps(str(table))}"] if table else [])
        scene = load_scene(args.scene, overrides=sets)
    except (ScenarioError, FileFormatError) as exc:
        return _scene_errors(exc)
    if scene.drivetrain.parameters is not None:
        _print_chain_modes(scene.drivetrain.parameters, chain_modes(load_public(scene.drivetrain.parameters), args.modes))
    spec = assemble(scene, check=False)
    rows = describe_modes(spec, args.modes)
    eff = scene.effects
    print(f"natural frequencies of {scene.name}: shafts {eff.shaft_flexibility}"
          f"{f' ({eff.shaft_elements} elements)' if eff.shaft_flexibility == 'flexible' else ''}, gear "
          f"{eff.mesh_contact} ({'rigid mesh' if eff.mesh_contact == 'ideal' else 'ISO 6336 mean mesh stiffness'}); "
          "free-free mechanical system (PI controller and losses excluded)")
    print("f: undamped natural frequency; zeta: damping ratio of the mode with the shafts', mesh's and cuts' "
          "damping (overdamped: zeta >= 1, the mode does not oscillate)")
    print(f"{'mode':>4} {'f [Hz]':>10} {'zeta':>18}  dominant strain / kinetic energy")
    for r in rows:
        zeta = f"{r['zeta']:.3g} (overdamped)" if r["overdamped"] else f"{r['zeta']:.3f}"
        print(f"{r['mode']:>4} {r['f_Hz']:>10.2f} {zeta:>18}  {r['strain']} ({100 * r['strain_share']:.0f} %)"
              f" / {r['kinetic']} ({100 * r['kinetic_share']:.0f} %)")
    reps, rho = check_cuts(spec, raise_on_unstable=False)
    print(f"cuts at H = {spec.comm_step:.6g} s (stable if the spectral radius is <= 1):")
    for rep in reps:
        print("  " + rep.line())
    print(f"  whole co-simulated system: spectral radius {rho:.6f} "
          f"({'stable' if rho <= 1 + 1e-9 else 'UNSTABLE'})")
    return 0


def _print_chain_modes(table, rows: list[dict]) -> None:
    """``drivetrain eigen``: the modes of a lumped table's own chain (models.eigen.chain_modes)."""
    print(f"modes of the lumped table {table} (its chain as written, referred to node 1, free-free, gears rigid "
          "at their ratios; zeta: the table's dampings projected on the mode)")
    print(f"{'mode':>4} {'f [Hz]':>10} {'zeta':>8}  largest strain / kinetic energy")
    for r in rows:
        print(f"{r['mode']:>4} {r['f_Hz']:>10.2f} {r['zeta']:>8.3f}  element {r['strain_element']} "
              f"({100 * r['strain_share']:.0f} %) / node {r['kinetic_node']} ({100 * r['kinetic_share']:.0f} %)")


def _calibrate_record(args: argparse.Namespace) -> int:
    """``drivetrain calibrate --record [DIR]``: identify the background from the 500 rpm record (campaigns.record_fit)
    and, where DIR holds them, what the 2004 rpm excitation records add (campaigns.excitation_fit: the first mode, the
    speed control, the shaft-order lines and their speed law); print each value beside the shipped one with its
    source and physical range, and write them as a scene's [background] and [instruments] sections (every value
    finite, or nothing is written)."""
    import dataclasses

    from drivetrain.campaigns import excitation_fit, record_fit
    from drivetrain.rig import record as rec
    from drivetrain.rig.background import EXPONENT_KEYS, Background

    where = args.record or rec.RECORD_DIR
    t0 = time.perf_counter()
    try:
        r = rec.load_record(args.record or None)
        out = record_fit.identify(r)
    except (OSError, ValueError) as exc:
        print(f"error: the record {where}: {exc}", file=sys.stderr)
        return 2
    t_base = time.perf_counter() - t0
    d = Path(args.record) if args.record else rec.RECORD_DIR
    excitation = None
    if all((d / rec.RECORDS[n].sensor_csv).is_file() for n in excitation_fit.RECORD_NAMES):
        t1 = time.perf_counter()
        try:
            excitation = excitation_fit.identify(args.record or None, Background(**out["background"]))
        except (OSError, ValueError) as exc:
            print(f"error: the excitation records in {where}: {exc}", file=sys.stderr)
            return 2
        t_exc = time.perf_counter() - t1
    shipped = dataclasses.asdict(Background())
    background = dict(out["background"])
    if excitation is not None:
        for k in ("orders_speed_exponent", *EXPONENT_KEYS.values()):
            background[k] = excitation["values"][k]["value"]
    bad = [f"{k} = {v!r}" for k, v in {**background, **out["instruments"]}.items()
           if isinstance(v, float) and not math.isfinite(v)]
    if bad:
        print(f"error: the record {where} gives non-finite parameters ({', '.join(bad)}); nothing written",
              file=sys.stderr)
        return 2
    print(f"identified from {where} (docs/DRIVETRAIN.md, 'The measured background'; {t_base:.1f} s)")
    print(f"  {'[background]':28s} {'identified':>12s} {'shipped':>12s}")
    for k, v in background.items():
        print(f"  {k:28s} {v:12.5g} {shipped[k]:12.5g}")
    c = out["controller"]
    print(f"  speed controller: Kp {c['drive_Kp']:.4g} N·m·s/rad, Ti {c['drive_Ti_s']:.4g} s, logged speed delay "
          f"{1e3 * c['logged_speed_delay_s']:.1f} ms (residual {c['residual_rms']:.3f})")
    print("  modes: " + ", ".join(f"{m['f_Hz']:.2f} Hz (zeta {m['zeta']:.3f})" for m in out["modes"]))
    print(f"  broadband fit: {out['fit']['rms_log10']:.3f} decades rms over {out['fit']['bins']} bins "
          f"{out['fit']['band_Hz'][0]:g}-{out['fit']['band_Hz'][1]:g} Hz")
    comments = []
    if excitation is not None:
        print(f"identified from the 2004 rpm impulse and multi-sine records (campaigns.excitation_fit; {t_exc:.1f} s)")
        for k, v in excitation["values"].items():
            rng = (f"range {v['range'][0]:g}-{v['range'][1]:g}{'' if v['within'] else ' OUTSIDE'}"
                   if "range" in v else "")
            line = f"{k} = {v['value']:.5g} {v['unit']}  [{v['source']}] {rng} {v['note']}".rstrip()
            print("  " + line)
            comments.append("# " + line)
        for k, v in excitation["model"]["sine_H"].items():
            print(f"  multi-sine {k}: measured {v['measured']:.3g}, model (linear, 2004 rpm) {v['model']:.3g}")
        rev = excitation["order_law_reverse"]["lines"].values()
        print("  the other way (shown, not written): laws calibrated on the multi-sine, judged on the impulse record: "
              + ", ".join(f"{r['line']} p {r['own_exponent']:.3f} ({r['judge_dB']:+.1f} dB)" for r in rev))
        print("  not identified here: " + "; ".join(f"{k}: {v if isinstance(v, str) else v[1]}"
                                                  for k, v in excitation["assumed"].items()))
    path = Path(args.out or "background.toml")
    lines = ["# drivetrain calibrate --record: the background identified from measured records", *comments,
             "[background]"]
    lines += [f"{k} = {v!r}" for k, v in background.items()]
    lines += ["", "[instruments]"] + [f"{k} = {v!r}" for k, v in out["instruments"].items()]
    path.write_text("\n".join(lines) + "\n")
    print(f"wrote {path} ({time.perf_counter() - t0:.1f} s in all)")
    return 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    """``drivetrain calibrate MEASURED.csv [--out FILE]``: refit the losses, print the fit at every
    operating point, write the calibration JSON (default ./calibration.json; use it with
    ``assemble(scene, calibration=FILE)`` or the environment variable DRIVETRAIN_CALIBRATION). The
    coupling-stiffness factor is kept from the current calibration. ``--regenerate``: rewrite the shipped
    data/calibration.json (losses from the shipped table, then the coupling factor for 24 Hz)."""
    from drivetrain.campaigns import calibrate as C
    from drivetrain.rig import data as rig

    if args.record is not None:
        return _calibrate_record(args)
    if args.regenerate:
        r = C.regenerate_shipped()
        print(f"wrote {rig.CALIBRATION_JSON}: coupling_scale {r['coupling_scale']:.6g}, lowest mode "
              f"{r['lowest_Hz']:.3f} Hz ({r['lowest_Hz_unscaled']:.3f} Hz unscaled); max errors "
              f"{100 * r['errors']['max_abs_DSH']:.2f} % / {100 * r['errors']['max_abs_PSH']:.2f} %")
        return 0
    if not args.measured:
        print("error: give the measured table (MEASURED.csv) or --regenerate", file=sys.stderr)
        return 2
    try:
        res = C.calibrate(args.measured)
    except (OSError, ValueError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    cur = rig.load_calibration()
    print(f"loss law T = c_v w + (T_c + a |T_trans|) tanh(w / w_c), fitted to {args.measured}")
    for key, frame in (("upper", "drive frame, T_trans = T_PSH/12"), ("planetary", "propeller frame, T_trans = 8 T_set")):
        v = res[key]
        print(f"  {key:9s} ({frame}): c_v = {v['c_v']:.6g} N m s/rad, T_c = {v['T_c']:.6g} N m, "
              f"w_c = {v['w_c']:.6g} rad/s, a = {v['a']:.6g}")
    print(f"{'T_load':>7} {'n_DSH':>8} {'T_DSH meas':>10} {'model':>8} {'err %':>7} {'T_PSH meas':>10} "
          f"{'model':>8} {'err %':>7}")
    for pt in res["errors"]["points"]:
        print(f"{pt['T_load_Nm']:>7.2f} {pt['n_DSH_rpm']:>8.2f} {pt['T_DSH_meas']:>10.3f} {pt['T_DSH_model']:>8.3f} "
              f"{100 * pt['err_DSH']:>7.2f} {pt['T_PSH_meas']:>10.3f} {pt['T_PSH_model']:>8.3f} "
              f"{100 * pt['err_PSH']:>7.2f}")
    print(f"max |error|: drive shaft {100 * res['errors']['max_abs_DSH']:.2f} %, propeller shaft "
          f"{100 * res['errors']['max_abs_PSH']:.2f} %")
    out = Path(args.out) if args.out else Path("calibration.json")
    C.write_calibration(out, res, cur["coupling_scale"],
                        {k: v for k, v in cur.items() if k not in ("coupling_scale", "upper", "planetary", "law", "fit")})
    print(f"wrote {out} (coupling_scale {cur['coupling_scale']:.6g} kept)")
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from drivetrain.cosim import ConfigurationError
    from drivetrain.scene.load import ScenarioError, load_scenes

    try:
        scenes = [s for path in args.scenes for s in load_scenes(path, args.set or ())]
    except ScenarioError as exc:
        return _scene_errors(exc)
    grid_names = [s.name for s in scenes]
    if args.only:
        import fnmatch

        scenes = [s for s in scenes if any(fnmatch.fnmatch(s.name, pat) for pat in args.only)]
    from drivetrain.campaigns.sweep import run_sweep

    t_sweep = time.perf_counter()
    try:
        manifest = run_sweep(scenes, args.out, workers=args.workers, address=args.scheduler,
                             backend=args.backend, fmu_dir=args.fmu_dir, skip_existing=args.skip_existing,
                             plots=False if args.no_plots else None, progress=not args.quiet,
                             grid_names=grid_names, force=args.force)
    except ConfigurationError as exc:
        return _scene_errors(exc)
    failed = [r for r in manifest["runs"] if r["status"] != "ok"]
    print(f"{len(manifest['runs']) - len(failed)}/{len(manifest['runs'])} runs ok in {manifest['wall_time_s']:.1f} s "
          f"(preparation {manifest['preparation_s']:.1f} s: contact maps and FMU builds; {manifest['reused_runs']} "
          f"reused); manifest: {manifest['path']}")
    prep = manifest["preparation_s"]
    print("  " + _wall_line(args, [("scenes and imports", t_sweep - args.t_command), ("preparation", prep),
                                   ("runs", manifest["wall_time_s"] - prep)]))
    for r in failed:
        print(f"  {r['name']}: {r['status']}: {r.get('error', '')}".rstrip(), file=sys.stderr)
    return 0 if not failed else 3


def _command_line(subcommand: str) -> str:
    """This invocation as a user would type it (for a generated report's "regenerate with" line)."""
    import shlex

    argv = sys.argv[1:]
    if subcommand not in argv:
        return f"drivetrain {subcommand}"
    return "drivetrain " + " ".join(shlex.quote(a) for a in argv[argv.index(subcommand):])


def _shipped_docs(args: argparse.Namespace) -> Path | bool | None:
    """Where a report command writes: False without ``--update-shipped`` (its --out directory), else the
    source checkout's docs/ directory; None (after an error message) when the package is not a checkout."""
    if not args.update_shipped:
        return False
    from drivetrain.fmu_build.fmus import source_checkout

    root = source_checkout()
    if root is None or not (root / "docs").is_dir():
        print("error: --update-shipped rewrites the shipped reports of a source checkout; this package is "
              "installed (give --report/--results instead)", file=sys.stderr)
        return None
    return root / "docs"


def _native_dir() -> Path:
    """Where build-native and build-native-gear write by default: the FMU directory's native/ (never the current
    folder unless it is that directory)."""
    from drivetrain.fmu_build.fmus import default_fmu_dir

    return default_fmu_dir() / "native"


def _cmd_validate(args: argparse.Namespace) -> int:
    from drivetrain.campaigns import validation as V
    from drivetrain.cosim import ConfigurationError
    from drivetrain.scene.load import ScenarioError
    from drivetrain.campaigns.sweep import run_sweep

    shipped = _shipped_docs(args)       # refused before any run when there is no checkout to write into
    if shipped is None:
        return 2
    base = Path(args.scene) if args.scene else Path(__file__).resolve().parents[2] / "scenarios" / "example.toml"
    checks = tuple(sorted(set(args.checks))) if args.checks else V.ALL_CHECKS
    try:
        scenes = V.scenes(base, args.duration, args.settle if args.settle is not None else min(2.0, 0.2 * args.duration),
                          tuple(args.set or ()), gearboxes=args.gearboxes, checks=checks)
    except ScenarioError as exc:
        return _scene_errors(exc)
    t_runs = time.perf_counter()
    if args.judge_only:                 # the runs exist: judge them again (e.g. after a judge changed)
        try:
            manifest, repeat = (json.loads((Path(args.out) / d / "manifest.json").read_text())
                                if d == "grid" or 10 in checks else {} for d in ("grid", "repeat"))
        except (OSError, ValueError) as exc:
            print(f"error: --judge-only needs the runs of an earlier `drivetrain validate --out {args.out}` "
                  f"({exc})", file=sys.stderr)
            return 2
    else:
        try:
            manifest = run_sweep(scenes, Path(args.out) / "grid", workers=args.workers, address=args.scheduler,
                                 backend=args.backend, fmu_dir=args.fmu_dir, skip_existing=args.resume, plots=False,
                                 progress=not args.quiet)
            repeat = (run_sweep([s for s in scenes if s.name == V.REPEAT], Path(args.out) / "repeat", workers=1,
                                backend=args.backend, fmu_dir=args.fmu_dir, skip_existing=args.resume, plots=False,
                                progress=False) if 10 in checks else {})
        except ConfigurationError as exc:
            return _scene_errors(exc)
    t_eval = time.perf_counter()
    results = V.evaluate(manifest, [s.name for s in scenes], repeat, checks)
    t_plots = time.perf_counter()
    report = Path(args.report) if args.report else (shipped or Path(args.out)) / "VALIDATION.md"
    report.parent.mkdir(parents=True, exist_ok=True)
    fig_path = report.parent / "figures" / "validation_spectra.png"
    fig_path.parent.mkdir(parents=True, exist_ok=True)
    fig = V.plot_spectra(manifest, fig_path) if set(checks) & set(V.GRID_CHECKS) else None
    record_fig = (V.record_check.plot_record(V.Runs(manifest), fig_path.parent / "validation_record.png")
                  if 11 in checks else None)
    sep_fig = (V.plot_separability(next(r for r in results if r.number == 6),
                                   fig_path.parent / "validation_separability.png") if 6 in checks else None)
    exc_fig = None
    if 12 in checks:
        runs = V.Runs(manifest)
        exc_fig = V.excitation_check.plot(
            lambda rec_: runs.signals(V.excitation_check.case_name(rec_, 0))
            if runs.ok(V.excitation_check.case_name(rec_, 0)) else None, fig_path.parent / "validation_excitation.png")
    command = _command_line("validate")
    t_report = time.perf_counter()
    lengths = sorted({(s.time.duration_s, s.time.settle_s) for s in scenes})
    meta = {"command": command, "n_scenes": len(scenes), "duration_s": args.duration, "gearboxes": args.gearboxes,
            "durations": None if len(lengths) == 1 else ", ".join(f"{d:g} s (settle {st:g} s)" for d, st in lengths),
            "settle_s": scenes[0].time.settle_s, "wall_time_s": t_report - args.started,
            "workers": args.workers or os.cpu_count(), "judge_only": args.judge_only,
            "runs_cpu_s": sum(r.get("elapsed_s") or 0.0 for r in manifest.get("runs", []) + repeat.get("runs", []))}
    fig_rel = os.path.relpath(fig, report.parent) if fig else None
    record_rel = os.path.relpath(record_fig, report.parent) if record_fig else None
    sep_rel = os.path.relpath(sep_fig, report.parent) if sep_fig else None
    exc_rel = os.path.relpath(exc_fig, report.parent) if exc_fig else None
    report.write_text(V.report_markdown(results, meta, fig_rel, record_rel, sep_rel, exc_rel))
    for r in results:
        print(f"{r.number:2d} {r.status:8s} {r.title}: {r.figure}")
    print(f"wrote {report} ({meta['wall_time_s'] / 60:.1f} min)")
    print("  " + _wall_line(args, [("scenes", t_runs - args.t_command), ("runs", t_eval - t_runs),
                                   ("judging", t_plots - t_eval), ("plots", t_report - t_plots),
                                   ("report", time.perf_counter() - t_report)]))
    return 0 if all(r.status != "fail" for r in results) else 3


def _cmd_accuracy_cost(args: argparse.Namespace) -> int:
    from drivetrain.campaigns import accuracy_study as S
    from drivetrain.run.accuracy import RESULTS_FILE, STUDY_DURATION_S, STUDY_SETTLE_S
    from drivetrain.cosim import ConfigurationError
    from drivetrain.run.outputs import jsonable

    shipped = _shipped_docs(args)       # refused before any run when there is no checkout to write into
    if shipped is None:
        return 2
    command = _command_line("accuracy-cost")
    meta = {"command": command, "duration_s": STUDY_DURATION_S, "settle_s": STUDY_SETTLE_S,
            "workers": args.workers or os.cpu_count(), "backend": args.backend}
    try:
        results = S.run_study(args.out, args.scenes, args.settings, workers=args.workers, address=args.scheduler,
                              resume=args.resume, fmu_dir=args.fmu_dir, backend=args.backend,
                              progress=not args.quiet, meta=meta, evaluate_only=args.evaluate_only)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except ConfigurationError as exc:
        return _scene_errors(exc)
    t_study = time.perf_counter()
    results["meta"]["wall_time_s"] = t_study - args.started
    results_path = Path(args.results) if args.results else RESULTS_FILE if shipped else Path(args.out) / RESULTS_FILE.name
    if args.evaluate_only:              # the runs are the earlier study's: keep how they were made
        try:
            earlier = json.loads(results_path.read_text()).get("meta", {})
        except (OSError, ValueError):
            earlier = {}
        results["meta"].update({k: earlier[k] for k in ("command", "wall_time_s", "workers") if k in earlier})
        results["meta"]["evaluated_again_with"] = command
    try:                                # the scenes this study did not run keep their earlier rows
        S.keep_earlier(results, json.loads(results_path.read_text()))
    except FileNotFoundError:
        pass
    except (OSError, ValueError) as exc:
        print(f"error: cannot read the earlier results {results_path} to keep their other scenes: {exc}",
              file=sys.stderr)
        return 2
    report = Path(args.report) if args.report else (shipped or Path(args.out)) / "ACCURACY-COST.md"
    report.parent.mkdir(parents=True, exist_ok=True)
    figures = S.plot_pareto(results, report.parent / "figures")
    results_path.parent.mkdir(parents=True, exist_ok=True)
    results_path.write_text(json.dumps(jsonable(results), indent=1) + "\n")
    report.write_text(S.report_markdown(results, {k: f"figures/{v}" for k, v in figures.items()}))
    for name, sc in results["scenes"].items():
        ok = sum(r.get("status") == "ok" for r in sc["rows"].values())
        print(f"{name}: {ok}/{len(sc['rows'])} settings ran")
    print(f"wrote {report}, {results_path} ({results['meta']['wall_time_s'] / 60:.1f} min)")
    print("  " + _wall_line(args, [("runs and evaluation", t_study - args.t_command),
                                   ("plots and report", time.perf_counter() - t_study)]))
    return 0


def _cmd_dataset(args: argparse.Namespace) -> int:
    from drivetrain.campaigns.dataset import DatasetError, export

    try:
        path = export(args.sweep_dir, args.format, args.out, settled_only=args.settled_only, log=print,
                      split_fractions=args.split, split_seed=args.split_seed)
    except DatasetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from drivetrain.campaigns.card import CARD_FILE

    print(f"wrote {path} and its card {(path if args.format == 'aalto' else path.parent) / CARD_FILE}")
    return 0


def _cmd_features(args: argparse.Namespace) -> int:
    from drivetrain.campaigns.features import write_features
    from drivetrain.errors import DatasetError

    try:
        path = write_features(args.dir, args.out, split_fractions=args.split, split_seed=args.split_seed)
    except (DatasetError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


def _cmd_detectability(args: argparse.Namespace) -> int:
    from drivetrain.campaigns import detectability as D
    from drivetrain.campaigns.features import features
    from drivetrain.campaigns.sweep import run_sweep
    from drivetrain.cosim import ConfigurationError
    from drivetrain.errors import DatasetError
    from drivetrain.scene.load import ScenarioError

    shipped = _shipped_docs(args)       # refused before any run when there is no checkout to write into
    if shipped is None:
        return 2
    fams = D.families(args.kinds, tuple(args.members), tuple(args.sizes))
    study = D.Study(fams, tuple(args.speeds), tuple(args.loads), args.gearboxes, args.duration, args.settle,
                    args.background, tuple(args.set or ()))
    try:
        scenes = study.scenes()
    except ScenarioError as exc:
        return _scene_errors(exc)
    runs_dir = Path(args.out) / "runs"
    t_runs = time.perf_counter()
    try:
        manifest = run_sweep(scenes, runs_dir, workers=args.workers, address=args.scheduler, backend=args.backend,
                             fmu_dir=args.fmu_dir, skip_existing=args.resume, plots=False, progress=not args.quiet)
    except ConfigurationError as exc:
        return _scene_errors(exc)
    t_features = time.perf_counter()
    try:
        rows = features(runs_dir)
    except DatasetError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    t_report = time.perf_counter()
    table = D.auc_table(rows, study)
    verdicts = D.verdicts(table)
    report = Path(args.report) if args.report else (shipped or Path(args.out)) / "DETECTABILITY.md"
    report.parent.mkdir(parents=True, exist_ok=True)
    stem = report.stem.lower()
    csv_path = D.write_table_csv(table, report.parent / f"{stem}_auc.csv")
    (report.parent / "figures").mkdir(parents=True, exist_ok=True)
    fig = D.plot(verdicts, study, report.parent / "figures" / f"{stem}.png")
    meta = {"command": _command_line("detectability"), "n_runs": len(scenes), "workers": args.workers or os.cpu_count(),
            "wall_time_s": time.perf_counter() - args.started,
            "reused": sum(bool(r.get("skipped")) for r in manifest.get("runs", [])),
            "runs_time_s": sum(r.get("wall_time_s") or 0.0 for r in manifest.get("runs", []))}
    moved = None
    if args.compare:
        try:
            other = D.verdicts(D.read_table_csv(Path(args.compare)))
        except (OSError, KeyError, ValueError) as exc:
            print(f"error: --compare {args.compare}: not an AUC table of drivetrain detectability ({exc})",
                  file=sys.stderr)
            return 2
        moved = D.what_moved(verdicts, other, f"`{args.compare}`")
    report.write_text(D.report_markdown(verdicts, study, meta, os.path.relpath(fig, report.parent),
                                        os.path.relpath(csv_path, report.parent), moved))
    det = sum(v["detectable"] for v in verdicts)
    print(f"{det} of {len(verdicts)} cells carry a detectable signal (paired); wrote {report} "
          f"({meta['wall_time_s'] / 60:.1f} min)")
    print("  " + _wall_line(args, [("scenes", t_runs - args.t_command), ("runs", t_features - t_runs),
                                   ("indicators", t_report - t_features),
                                   ("statistics, plot and report", time.perf_counter() - t_report)]))
    return 0


def _stress_command(args: argparse.Namespace) -> str:
    """The command line of a stress campaign (the options that differ from their defaults)."""
    import shlex

    words = ["drivetrain", "stress"]
    for flag, attr, default in (("--set-name", "set_name", "all"), ("--n-random", "n_random", 200),
                                ("--seed", "seed", 0), ("--out", "out", "out/stress"), ("--workers", "workers", None),
                                ("--scheduler", "scheduler", None), ("--halving-subset", "halving_subset", 10),
                                ("--duration-random", "duration_random", 1.5), ("--duration-pcm", "duration_pcm", 0.1),
                                ("--duration-paper", "duration_paper", None), ("--fidelities", "fidelities", None),
                                ("--paper-grid", "paper_grid", None), ("--backend", "backend", "fmi"),
                                ("--fmu-dir", "fmu_dir", None), ("--pair", "pair", None)):
        v = getattr(args, attr)
        if v != default:
            words += [flag, str(v)]
    if args.seeds:
        words += ["--seeds", ",".join(map(str, args.seeds))]
    if args.only:
        words += ["--only", *args.only]
    if args.resume:
        words.append("--resume")
    return shlex.join(words)


def _cmd_stress(args: argparse.Namespace) -> int:
    from drivetrain.cosim import ConfigurationError
    from drivetrain.scene.load import ScenarioError
    from drivetrain.campaigns.stress import regenerate_report, run_stress

    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
    out = Path(args.out)
    try:
        if args.report_only:
            rec = regenerate_report(out)
        else:
            fids = [f.strip() for f in args.fidelities.split(",") if f.strip()] if args.fidelities else None
            rec = run_stress(out, set_name=args.set_name, n_random=args.n_random, seed=args.seed,
                             workers=args.workers, address=args.scheduler, resume=args.resume,
                             halving_subset=args.halving_subset, duration_random_s=args.duration_random,
                             duration_pcm_s=args.duration_pcm, duration_paper_s=args.duration_paper,
                             fidelities=fids, paper_grid=args.paper_grid, fmu_dir=args.fmu_dir,
                             backend=args.backend, progress=not args.quiet, only=args.only,
                             command=_stress_command(args), log=log, seeds=args.seeds, pair=args.pair)
    except (ScenarioError, ConfigurationError, ValueError, FileNotFoundError) as exc:
        return _scene_errors(exc)
    tot = rec["table"][-1]
    pairs = rec["pairs"]
    print(f"{tot['runs']} runs: {tot['pass']} pass, {tot['fail']} fail, {tot['refused']} refused before running "
          f"(predicted unstable); {len(pairs)} halving pairs, {sum(p['outcome'] == 'fail' for p in pairs)} outside "
          f"the limits, {sum(p['outcome'] == 'refined' for p in pairs)} steps refused with a converged step chosen; "
          f"report: {out / 'stress.md'}")
    for p in pairs:
        if p["outcome"] == "refined":
            print(f"  step refused {p['base']}: " + "; ".join(p["reasons"])
                  + (f" -> converged at H = {p['converged_step_s']:.6g} s" if p.get("converged_step_s") else ""),
                  file=sys.stderr)
    print("  " + _wall_line(args, [("campaign", time.perf_counter() - args.t_command)]))
    for r in rec["runs"]:
        if r["outcome"] == "fail":
            print(f"  FAIL {r['name']}: " + "; ".join(r["reasons"]), file=sys.stderr)
    for p in pairs:
        if p["outcome"] == "fail":
            print(f"  FAIL halving {p['base']}: " + "; ".join(p["reasons"]), file=sys.stderr)
    return 0 if rec["n_fail"] == 0 else 3


def _cmd_check(args: argparse.Namespace) -> int:
    """Run scenes and check them against their [expect] section and baseline (drivetrain.campaigns.check)."""
    from drivetrain.campaigns.check import CheckReport, check_scenes, format_table, select
    from drivetrain.cosim import ConfigurationError
    from drivetrain.scene.load import ScenarioError, load_scenes

    try:
        files = [(path, select(load_scenes(path, args.set or ()), args.only)) for path in args.scenes]
    except ScenarioError as exc:
        return _scene_errors(exc)
    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
    cases = []
    t_runs = time.perf_counter()
    try:
        for path, scenes in files:
            if scenes:
                cases += check_scenes(path, scenes, out_dir=args.out, baseline_dir=args.baseline_dir,
                                      fmu_dir=args.fmu_dir, backend=args.backend, workers=args.workers,
                                      address=args.scheduler, progress=not args.quiet, log=log).cases
    except (ConfigurationError, ValueError, OSError) as exc:
        return _scene_errors(exc)
    t_report = time.perf_counter()
    report = CheckReport(cases)
    print(format_table(report, all_rows=args.all))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(report.to_dict(), indent=1))
    print(_wall_line(args, [("scenes and imports", t_runs - args.t_command), ("runs and checks", t_report - t_runs),
                            ("report", time.perf_counter() - t_report)]))
    return 0 if report.ok else 1


def _cmd_baseline(args: argparse.Namespace) -> int:
    """Run scenes and store their compact references (drivetrain.campaigns.check.baseline_file)."""
    from drivetrain.campaigns.check import baseline_file
    from drivetrain.cosim import ConfigurationError
    from drivetrain.scene.load import ScenarioError

    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
    bad = 0
    t_runs = time.perf_counter()
    for path in args.scenes:
        try:
            r = baseline_file(path, args.set or (), only=args.only, baseline_dir=args.baseline_dir,
                              fmu_dir=args.fmu_dir, backend=args.backend, workers=args.workers,
                              address=args.scheduler, progress=not args.quiet, allow_failed=args.allow_failed,
                              log=log)
        except (ScenarioError, ConfigurationError, ValueError, OSError) as exc:
            return _scene_errors(exc)
        if r.stored:
            print(f"{path}: baseline of {len(r.stored)} case{'s' if len(r.stored) != 1 else ''} written to {r.path}")
        for name, why in r.failed.items():
            print(f"  {name}: not stored: {why}", file=sys.stderr)
        bad += len(r.failed)
    print(_wall_line(args, [("scenes, runs and baselines", time.perf_counter() - t_runs)]))
    return 0 if not bad else 3


#: the help of every --fmu-dir (its default: drivetrain.fmu_build.fmus.default_fmu_dir)
_FMU_DIR_HELP = ("where the FMUs are, built on demand (default: the source checkout's fmus/, or fmus/ in the "
                 "user-level cache $BEVEL_CACHE_DIR or ~/.cache/bevel-drivetrain; never the current folder)")


_BACKEND_HELP = ("how the FMUs run: fmi, the pythonfmu FMUs through fmpy (default); native, compiled C FMUs "
                 "(about 4x faster end to end; a gear that is not fidelity table keeps its pythonfmu FMU); inprocess, "
                 "the same models called without FMI")
_QUIET_HELP = "no progress bars and no report lines while it runs (errors and the final result are still printed)"
_NO_PLOTS_HELP = "do not write the PNG plots of each run (torques.png, spectra.png)"


def _add_execution_options(p: argparse.ArgumentParser,
                           workers_help: str = "local worker processes (default: CPU count)") -> None:
    """Where and how the runs of a many-run command execute: --workers, --scheduler, --backend, --fmu-dir."""
    p.add_argument("--workers", type=_positive_int, default=None, help=workers_help)
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler address (tcp://host:8786), or 'local' for a Dask cluster of --workers "
                        "processes started by the command; default: local process pool")
    p.add_argument("--backend", choices=BACKENDS, default="fmi", help=_BACKEND_HELP)
    p.add_argument("--fmu-dir", default=None, help=_FMU_DIR_HELP)


def _percent(text: str) -> float:
    """A tolerance in percent: "1%", "1" (both 1 %), "0.5 %"."""
    try:
        v = float(text.strip().rstrip("%").strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a percentage (e.g. 1%)") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: a tolerance must be a positive percentage")
    return v


def _int_at_least(minimum: int):
    """argparse type of a count that must be >= ``minimum`` (``--workers -1`` was a traceback from the pool,
    ``stress --n-random -5`` a report of "0 runs")."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number >= {minimum}, got {text!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"expected a whole number >= {minimum}, got {v}")
        return v
    parse.__name__ = f"whole number >= {minimum}"
    return parse


_positive_int = _int_at_least(1)
_count_or_zero = _int_at_least(0)


def _finite(positive: bool = False, nonnegative: bool = False):
    """argparse type of a finite number (a duration > 0, a settling time >= 0, a speed): NaN and infinities
    refused with the rule."""
    rule = "> 0" if positive else ">= 0" if nonnegative else "finite"

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number ({rule}), got {text!r}") from None
        if not math.isfinite(v) or (positive and not v > 0) or (nonnegative and not v >= 0):
            raise argparse.ArgumentTypeError(f"expected a finite number {rule if rule != 'finite' else ''}, got {text}"
                                             .replace("  ", " "))
        return v
    parse.__name__ = f"number {rule}"
    return parse


_duration = _finite(positive=True)
_settle = _finite(nonnegative=True)
_number = _finite()


def _seed_list(text: str) -> list[int]:
    """``--seeds``: ``0-9``, ``0,3,7`` or ``4``: whole numbers >= 0, a range inclusive."""
    out: list[int] = []
    try:
        for part in text.split(","):
            a, dash, b = part.strip().partition("-")
            lo, hi = int(a), int(b) if dash else int(a)
            if lo < 0 or hi < lo:
                raise ValueError
            out += range(lo, hi + 1)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seeds >= 0 as 0-9, 0,3,7 or 4, got {text!r}") from None
    if len(out) > 1000:
        raise argparse.ArgumentTypeError(f"{len(out)} seeds: at most 1000")
    return sorted(set(out))


def _parser_build_fmus(sub) -> None:
    p = sub.add_parser("build-fmus", help="build every FMU of the project into the FMU directory runs use (or --out DIR)")
    p.add_argument("--out", default=None, help="output directory, where only the FMUs are written (default: the "
                                               "FMU directory runs use; docs/MASTER.md)")
    p.add_argument("--only", nargs="*", default=None, help="build only these FMUs (model names)")
    p.set_defaults(func=_cmd_build_fmus)

def _parser_run(sub) -> None:
    p = sub.add_parser("run", help="run a scene: signals (HDF5), summary.json and plots into --out DIR")
    p.add_argument("scene", help="scene file (.toml); a grid file needs --case")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a scene key, e.g. --set time.duration_s=0.5 (repeatable)")
    p.add_argument("--out", default=None, help="output directory (default: out/<scene name>)")
    p.add_argument("--case", default=None, help="with a grid file: the name of the case to run")
    p.add_argument("--backend", choices=BACKENDS, default="fmi",
                   help="fmi: FMUs through fmpy (default); inprocess: the same slave classes without FMI")
    p.add_argument("--fmu-dir", default=None, help=_FMU_DIR_HELP)
    p.add_argument("--fmu", action="append", metavar="MODEL=PATH",
                   help="use this FMU file for a model instead of the one in --fmu-dir, e.g. "
                        "GearContact=fmus/native/GearContact.fmu (drivetrain build-native-gear; repeatable)")
    p.add_argument("--native", action="store_true",
                   help="the same as --backend native: Python-free FMUs for all four models (built once and cached "
                        "in FMU_DIR/native; a gear of another fidelity than table keeps its pythonfmu FMU, with a "
                        "message; docs/FMU.md)")
    p.add_argument("--no-plots", action="store_true", help="do not write PNG plots")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no report")
    p.add_argument("--force", action="store_true", help=_FORCE_HELP)
    p.add_argument("--tolerance", type=_percent, default=None, metavar="T%",
                   help="run with the cheapest studied setting within T %% on mean torques and fluctuation and "
                        "T dB on GMF and sidebands (numerics.tolerance_pct; docs/ACCURACY-COST.md)")
    p.set_defaults(func=_cmd_run)

def _parser_build_native_gear(sub) -> None:
    p = sub.add_parser("build-native-gear", help="the scene's GearContact (fidelity table) as a native FMU: "
                       "compiled C and the contact map as a resource, no Python needed (docs/FMU.md)")
    p.add_argument("scene", help="scene file (.toml); a grid file needs --case")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a scene key (repeatable)")
    p.add_argument("--case", default=None, help="with a grid file: the name of the case")
    p.add_argument("--out", default=None,
                   help="the FMU file (default: native/GearContact.fmu in the FMU directory, whatever the current "
                        "folder: a source checkout's fmus/, else the user-level cache)")
    p.set_defaults(func=_cmd_build_native_gear)

def _parser_build_native(sub) -> None:
    p = sub.add_parser("build-native", help="the scene's four FMUs (GearContact at fidelity table, FlexibleShaft, "
                       "UpperTransmission, MotorLoad) as native FMUs: compiled C, no Python needed (docs/FMU.md)")
    p.add_argument("scene", help="scene file (.toml); a grid file needs --case")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a scene key (repeatable)")
    p.add_argument("--case", default=None, help="with a grid file: the name of the case")
    p.add_argument("--out", default=None, help="the directory of the FMUs (default: native/ in the FMU directory, "
                                               "whatever the current folder: a source checkout's fmus/, else the "
                                               "user-level cache)")
    p.set_defaults(func=_cmd_build_native)

def _parser_export_ssp(sub) -> None:
    p = sub.add_parser("export-ssp", help="the scene's system (FMUs, connections, assembled parameters, "
                       "experiment) as an SSP 1.0 archive for other FMI tools")
    p.add_argument("scene", help="scene file (.toml); a grid file needs --case")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a scene key (repeatable)")
    p.add_argument("--case", default=None, help="with a grid file: the name of the case to export")
    p.add_argument("--out", default=None, help="the archive (default: <scene name>.ssp)")
    p.add_argument("--fmu-dir", default=None, help=_FMU_DIR_HELP)
    p.add_argument("--native", action="store_true",
                   help="the compiled FMUs (no Python needed in the host; built once in FMU_DIR/native; a gear "
                        "of another fidelity than table keeps its pythonfmu FMU, with a message)")
    p.set_defaults(func=_cmd_export_ssp)

def _parser_eigen(sub) -> None:
    p = sub.add_parser("eigen", help="natural frequencies of the assembled, linearised drivetrain")
    p.add_argument("scene", nargs="?", help="scene file (.toml); without it, --parameters alone")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a scene key")
    p.add_argument("--modes", type=_positive_int, default=12, help="how many modes to list (default 12)")
    p.add_argument("--parameters", metavar="TABLE", help="a lumped parameter table (the layout of "
                   "testbench_lumped_parameters.csv): its own modes; with a scene, the scene's drivetrain.parameters")
    p.set_defaults(func=_cmd_eigen)

def _parser_calibrate(sub) -> None:
    p = sub.add_parser("calibrate", help="refit the loss parameters from a measured mean-torque table")
    p.add_argument("measured", nargs="?", help="CSV like measured_mean_torques.csv")
    p.add_argument("--out", default=None, help="where to write the fitted parameters")
    p.add_argument("--regenerate", action="store_true",
                   help="rewrite the shipped data/calibration.json (losses, then the coupling factor for 24 Hz)")
    p.add_argument("--record", nargs="?", const="", default=None, metavar="DIR",
                   help="identify the measured background from a rig record (default: the shipped 500 rpm record) "
                        "and write it as [background] and [instruments] sections to --out (default background.toml)")
    p.set_defaults(func=_cmd_calibrate)

def _parser_sweep(sub) -> None:
    p = sub.add_parser("sweep", help="run many scenes (grid files expand) in parallel; one HDF5 per run + manifest")
    p.add_argument("scenes", nargs="+", help="scene or grid files")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a key of every scene (section.key=value), or of a grid's [sweep] table: "
                        "sweep.draw.n=2, sweep.draw.seed=7, sweep.axes.operating_point.drive_speed_rpm=[500.0] "
                        "(repeatable)")
    p.add_argument("--out", default="out/sweep", help="output directory (default: out/sweep)")
    p.add_argument("--only", nargs="*", default=None, help="run only cases whose name matches these patterns")
    _add_execution_options(p)
    p.add_argument("--resume", "--skip-existing", dest="skip_existing", action="store_true",
                   help="continue a sweep: reuse finished runs of the same scene and model sources "
                        "(fingerprint in case.json), run the rest")
    p.add_argument("--no-plots", action="store_true", help=_NO_PLOTS_HELP)
    p.add_argument("--quiet", action="store_true", help=_QUIET_HELP)
    p.add_argument("--force", action="store_true", help=_FORCE_HELP)
    p.set_defaults(func=_cmd_sweep)

def _parser_validate(sub) -> None:
    from drivetrain.campaigns import GEARBOXES

    p = sub.add_parser("validate", help="run the checks against the paper's findings and write their report "
                                        "(OUT/VALIDATION.md; docs/VALIDATION.md with --update-shipped)")
    p.add_argument("scene", nargs="?", default=None, help="base scene (default: scenarios/example.toml)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a key of every scene")
    p.add_argument("--out", default="out/validate", help="run directory (default: out/validate)")
    p.add_argument("--report", default=None,
                   help="the report (default: OUT/VALIDATION.md; with --update-shipped the checkout's docs/VALIDATION.md)")
    p.add_argument("--update-shipped", action="store_true",
                   help="write the shipped report, docs/VALIDATION.md of the source checkout, and its figures")
    p.add_argument("--duration", type=_duration, default=20.0, help="simulated seconds per run (default: 20, the paper's)")
    p.add_argument("--settle", type=_settle, default=None, help="settling time excluded (default: min(2 s, 20 %%))")
    p.add_argument("--gearboxes", type=_positive_int, default=GEARBOXES,
                   help=f"gearboxes (seeds 0..N-1) every check runs over (default: {GEARBOXES})")
    _add_execution_options(p)
    p.add_argument("--resume", action="store_true", help="reuse finished runs of the same scenes")
    p.add_argument("--checks", nargs="+", type=int, choices=range(1, 13), default=None, metavar="N",
                   help="run and judge only these checks (default: all; e.g. --checks 11 12: the measured records)")
    p.add_argument("--judge-only", action="store_true",
                   help="run nothing: judge the runs already in --out again and rewrite the report")
    p.add_argument("--quiet", action="store_true", help=_QUIET_HELP)
    p.set_defaults(func=_cmd_validate)

def _parser_accuracy_cost(sub) -> None:
    p = sub.add_parser("accuracy-cost", help="the accuracy-cost study: every setting against a converged reference "
                                             "per scene; writes its report, plots and results into OUT (the shipped "
                                             "docs/ACCURACY-COST.md and data file with --update-shipped)")
    p.add_argument("--scenes", nargs="*", default=None, metavar="NAME", help="studied scenes (default: all)")
    p.add_argument("--settings", nargs="*", default=None, metavar="NAME",
                   help="settings (default: all; the reference always runs)")
    p.add_argument("--out", default="out/accuracy", help="run directory (default: out/accuracy)")
    p.add_argument("--report", default=None, help="the report (default: OUT/ACCURACY-COST.md; with --update-shipped "
                                                   "the checkout's docs/ACCURACY-COST.md)")
    p.add_argument("--results", default=None, help="where the results go (default: OUT/accuracy_cost.json; with "
                                                    "--update-shipped the package's data file, which run --tolerance reads)")
    p.add_argument("--update-shipped", action="store_true",
                   help="write the shipped files: the package's results (read by run --tolerance) and the checkout's "
                        "docs/ACCURACY-COST.md with its figures")
    _add_execution_options(p)
    p.add_argument("--resume", action="store_true", help="reuse finished runs of the same scenes and settings")
    p.add_argument("--evaluate-only", action="store_true",
                   help="run nothing: evaluate every run found in --out (e.g. rows run separately)")
    p.add_argument("--quiet", action="store_true", help=_QUIET_HELP)
    p.set_defaults(func=_cmd_accuracy_cost)

def _parser_dataset(sub) -> None:
    p = sub.add_parser("dataset", help="one labelled dataset (signals + labels of every run) from a sweep directory")
    p.add_argument("sweep_dir", help="the --out directory of a sweep (with manifest.json)")
    p.add_argument("--format", choices=("parquet", "hdf5", "aalto"), default="parquet",
                   help="parquet: one table, a row per sample (default); hdf5: /labels and /runs/<run>/<channel>; "
                        "aalto: a CSV per run in the Aalto gear-fault layout and labels.csv")
    p.add_argument("--out", default=None, help="output file (directory for aalto); default: inside SWEEP_DIR")
    p.add_argument("--settled-only", action="store_true",
                   help="leave out each run's samples before its time.settle_s (the start-up transient); without "
                        "it they are kept and marked by the settled column")
    _add_split_options(p)
    p.set_defaults(func=_cmd_dataset)


def _add_split_options(p) -> None:
    """The gearbox-level split's options (campaigns.splits) of ``dataset`` and ``features``."""
    from drivetrain.campaigns.splits import DEFAULT_FRACTIONS, DEFAULT_SPLIT_SEED

    p.add_argument("--split", nargs=3, type=float, default=list(DEFAULT_FRACTIONS), metavar=("TRAIN", "VAL", "TEST"),
                   help="shares of the gearboxes in the train, validation and test sets of the split column "
                        f"(default: {' '.join(f'{x:g}' for x in DEFAULT_FRACTIONS)}); one gearbox is never in two sets")
    p.add_argument("--split-seed", type=int, default=DEFAULT_SPLIT_SEED, metavar="SEED",
                   help=f"seed of the split (default: {DEFAULT_SPLIT_SEED}); the same seed and gearboxes give the same split")

def _parser_features(sub) -> None:
    p = sub.add_parser("features", help="condition indicators (TSA per shaft, FM4, NA4, SER, ...) of every run of a "
                                        "run or sweep directory -> DIR/features.parquet")
    p.add_argument("dir", help="a run directory (with signals.h5) or a sweep directory (with manifest.json)")
    p.add_argument("--out", default=None, help="output file (default: DIR/features.parquet)")
    _add_split_options(p)
    p.set_defaults(func=_cmd_features)

def _parser_detectability(sub) -> None:
    from drivetrain.campaigns import GEARBOXES
    from drivetrain.campaigns import detectability as D
    from gearcontact_fmu.fault_specs import FAULT_KINDS

    p = sub.add_parser("detectability", help="the fault families over gearboxes: paired and unpaired AUC of every "
                                             "indicator -> OUT/DETECTABILITY.md (docs/ with --update-shipped)")
    p.add_argument("--out", default="out/detectability", help="run directory (default: out/detectability)")
    p.add_argument("--report", default=None, help="the report, its AUC table and figure beside it (default: "
                                                  "OUT/DETECTABILITY.md; with --update-shipped the checkout's docs/)")
    p.add_argument("--update-shipped", action="store_true",
                   help="write the shipped report, docs/DETECTABILITY.md of the source checkout, with its table and figure")
    p.add_argument("--gearboxes", type=_positive_int, default=GEARBOXES,
                   help=f"gearboxes (seeds) per cell (default: {GEARBOXES})")
    p.add_argument("--kinds", nargs="+", choices=tuple(FAULT_KINDS), default=None, help="fault kinds (default: all)")
    p.add_argument("--members", nargs="+", choices=D.MEMBERS, default=list(D.MEMBERS),
                   help="the gears that carry the fault (default: both)")
    p.add_argument("--sizes", nargs="+", choices=("default", "small"), default=["default", "small"],
                   help="fault sizes: each kind's default and half of it (default: both)")
    p.add_argument("--speeds", nargs="+", type=_number, default=list(D.SPEEDS_RPM), help="drive speeds [rpm]")
    p.add_argument("--loads", nargs="+", type=_number, default=list(D.LOADS_NM), help="load-motor torques [N·m]")
    p.add_argument("--duration", type=_duration, default=7.0, help="simulated seconds per run (default: 7)")
    p.add_argument("--settle", type=_settle, default=1.0, help="settling time left out (default: 1 s)")
    p.add_argument("--compare", default=None, metavar="CSV",
                   help="another study's AUC table (e.g. the same study with --background off): the report says "
                        "what moved between them")
    p.add_argument("--background", choices=("on", "off"), default="on",
                   help="the rig's measured background (default: on)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a key of every scene")
    _add_execution_options(p)
    p.add_argument("--resume", action="store_true", help="reuse finished runs of the same scenes")
    p.add_argument("--quiet", action="store_true", help=_QUIET_HELP)
    p.set_defaults(func=_cmd_detectability)

def _parser_frontier(sub) -> None:
    from drivetrain.campaigns import GEARBOXES
    from drivetrain.campaigns import detectability as D
    from drivetrain.campaigns import frontier as F
    from gearcontact_fmu.fault_specs import FAULT_KINDS

    p = sub.add_parser("frontier", help="the detectability frontier: per fault kind, member, speed and load the "
                                        "smallest detectable size (bisection over a size ladder, resumable) -> "
                                        "OUT/FRONTIER.md")
    p.add_argument("--out", default="out/frontier", help="run directory (default: out/frontier)")
    p.add_argument("--report", default=None, help="the report, figure beside it (default: OUT/FRONTIER.md)")
    p.add_argument("--gearboxes", type=_positive_int, default=GEARBOXES,
                   help=f"gearboxes (seeds) per size (default: {GEARBOXES})")
    p.add_argument("--kinds", nargs="+", choices=tuple(FAULT_KINDS), default=list(FAULT_KINDS),
                   help="fault kinds (default: all)")
    p.add_argument("--members", nargs="+", choices=D.MEMBERS, default=list(D.MEMBERS), help="gears (default: both)")
    p.add_argument("--speeds", nargs="+", type=_number, default=list(F.SPEEDS_RPM), help="drive speeds [rpm]")
    p.add_argument("--loads", nargs="+", type=_number, default=list(F.LOADS_NM),
                   help="load-motor torques [N·m] (default: " + " ".join(f"{x:g}" for x in F.LOADS_NM)
                        + ", the paper's lightest to the load "
                        "motor's nominal)")
    p.add_argument("--ladder", nargs="+", type=_duration, default=list(F.LADDER),
                   help="size factors of each kind's default sizes, smallest to severe (default: "
                        f"{' '.join(f'{x:g}' for x in F.LADDER)})")
    p.add_argument("--duration", type=_duration, default=20.0, help="simulated seconds per run (default: 20, as validate)")
    p.add_argument("--settle", type=_settle, default=2.0, help="settling time left out (default: 2 s)")
    p.add_argument("--background", choices=("on", "off"), default="on",
                   help="the rig's measured background (default: on)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a key of every scene")
    p.add_argument("--compare", metavar="AUC_CSV", default=None,
                   help="an earlier paired study's AUC table (e.g. docs/detectability_auc.csv): the report says "
                        "what moved, family by family, at the operating points both ran")
    _add_execution_options(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_frontier)


def _cmd_frontier(args: argparse.Namespace) -> int:
    from drivetrain.campaigns import frontier as F
    from drivetrain.cosim import ConfigurationError
    from drivetrain.errors import DatasetError
    from drivetrain.scene.load import ScenarioError

    if args.compare is not None and not Path(args.compare).is_file():
        print(f"error: --compare {args.compare}: no such file", file=sys.stderr)
        return 2
    ladder = sorted(set(args.ladder))
    if not ladder or any(not (x > 0 and math.isfinite(x)) for x in ladder):
        print(f"error: --ladder {args.ladder}: positive finite size factors", file=sys.stderr)
        return 2
    study = F.FrontierStudy(tuple(args.kinds), tuple(args.members), tuple(args.speeds), tuple(args.loads),
                            args.gearboxes, args.duration, args.settle, tuple(ladder), args.background,
                            tuple(args.set or ()))
    try:
        result = F.run_frontier(study, Path(args.out), workers=args.workers, address=args.scheduler,
                                backend=args.backend, fmu_dir=args.fmu_dir, progress=not args.quiet, log=print)
    except ScenarioError as exc:
        return _scene_errors(exc)
    except (ConfigurationError, DatasetError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    report = Path(args.report) if args.report else Path(args.out) / "FRONTIER.md"
    report.parent.mkdir(parents=True, exist_ok=True)
    (report.parent / "figures").mkdir(parents=True, exist_ok=True)
    fig = F.plot(result, study, report.parent / "figures" / f"{report.stem.lower()}.png")
    wall = time.perf_counter() - args.started
    workers = args.workers or os.cpu_count() or 1
    meta = {"command": _command_line("frontier"), "workers": workers, "wall_time_s": wall,
            "core_hours": wall * workers / 3600.0}
    (report.parent / f"{report.stem.lower()}.json").write_text(json.dumps({**result, "meta": meta}, indent=1,
                                                                          default=str))
    text = F.report_markdown(result, study, meta, os.path.relpath(fig, report.parent))
    if args.compare:
        try:
            text += "\n## What moved\n\n" + F.compare_markdown(result, args.compare)
        except (OSError, ValueError) as exc:
            print(f"warning: --compare {args.compare}: not compared ({exc})", file=sys.stderr)
    report.write_text(text)
    print(f"frontier of {len(result['cells'])} cells from {result['runs']} runs in {len(result['rounds'])} rounds; "
          f"wrote {report} ({wall / 60:.1f} min)")
    return 0


def _parser_check_and_baseline(sub) -> None:
    for name, helptext in (("check", "run scenes and check them against their [expect] section and baseline; "
                                     "prints what moved; exit code 0 only if everything holds"),
                           ("baseline", "run scenes and store a compact reference of each run (baseline file)")):
        p = sub.add_parser(name, help=helptext)
        p.add_argument("scenes", nargs="+", help="scene or grid files (a grid: every case)")
        p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a key of every scene")
        p.add_argument("--only", nargs="*", default=None, metavar="PATTERN", help="only the cases matching these")
        p.add_argument("--baseline-dir", default=None, metavar="DIR",
                       help="baseline files DIR/<scene>.baseline.h5 (default: beside each scene file, "
                            "or [check] baseline)")
        _add_execution_options(p, "local worker processes for several cases")
        p.add_argument("--quiet", action="store_true", help=_QUIET_HELP)
        if name == "check":
            p.add_argument("--out", default="out/check",
                           help="run results and failure plots, one directory per case (default: out/check)")
            p.add_argument("--all", action="store_true", help="list every check, not only the failing ones")
            p.add_argument("--json", default=None, metavar="FILE", help="also write the report as JSON")
            p.set_defaults(func=_cmd_check)
        else:
            p.add_argument("--allow-failed", action="store_true", help="also store runs whose FMU failed")
            p.set_defaults(func=_cmd_baseline)

def _parser_stress(sub) -> None:
    p = sub.add_parser("stress", help="stress campaign: the paper's 54 scenes and randomized hard scenes, judged "
                                      "(completes, finite, stable, energy, step halving); writes stress.md")
    p.add_argument("--set-name", choices=("paper", "random", "all"), default="all",
                   help="paper: the 54 paper scenes (20 s); random: the randomized scenes; all (default): both")
    p.add_argument("--n-random", type=_positive_int, default=200, help="number of random scenes (default 200)")
    p.add_argument("--seed", type=_count_or_zero, default=0, help="seed of the random scenes (scene i depends on (seed, i))")
    p.add_argument("--seeds", type=_seed_list, default=None, metavar="LIST",
                   help="several random sets, --n-random scenes each: 0-9, 0,3,7 or 4 (overrides --seed)")
    p.add_argument("--out", default="out/stress", help="output directory (default: out/stress)")
    p.add_argument("--workers", type=_positive_int, default=None, help="local worker processes (default: CPU count)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler address (tcp://host:8786), or 'local' for a Dask cluster of --workers "
                        "processes started by the command; default: local process pool")
    p.add_argument("--resume", action="store_true", help="do not rerun runs whose summary.json exists")
    p.add_argument("--halving-subset", type=_count_or_zero, default=10, metavar="K",
                   help="also run every K-th random scene with half the communication step (0: none; default 10)")
    p.add_argument("--duration-random", type=_duration, default=1.5, metavar="S",
                   help="simulated time of a random scene [s] (default 1.5)")
    p.add_argument("--duration-pcm", type=_duration, default=0.1, metavar="S",
                   help="simulated time of a random scene with online PCM contact [s] (default 0.1)")
    p.add_argument("--duration-paper", type=_duration, default=None, metavar="S",
                   help="shorten the paper scenes to S seconds (default: as in the grid, 20 s)")
    p.add_argument("--fidelities", default=None, metavar="LIST",
                   help="comma-separated mesh_contact fidelities the random scenes may use (default: all)")
    p.add_argument("--paper-grid", default=None, metavar="TOML", help="the paper grid (default: scenarios/paper/paper.toml)")
    p.add_argument("--pair", default=None, metavar="NAME",
                   help="draw the random scenes on another gear pair, one of gearcontact_fmu.pair_check.OTHER_PAIRS "
                        "(e.g. 20x40_m4, miter25_m3, 20x30_s70_m3; with --set-name random; default the rig's)")
    p.add_argument("--backend", choices=BACKENDS, default="fmi", help=_BACKEND_HELP)
    p.add_argument("--fmu-dir", default=None, help=_FMU_DIR_HELP)
    p.add_argument("--only", nargs="*", default=None, metavar="PATTERN",
                   help="run only the cases whose name matches (e.g. rnd_s0_0042 'paper_severe_*')")
    p.add_argument("--report-only", action="store_true",
                   help="re-judge the runs in --out and rewrite stress.json / stress.md without running")
    p.add_argument("--quiet", action="store_true", help=_QUIET_HELP)
    p.set_defaults(func=_cmd_stress)



#: what ``drivetrain --help`` says above and below the commands (plain text: a terminal shows no markup)
_DESCRIPTION = ("Simulate torsional vibrations of healthy and faulty bevel-gear drivetrains (the azimuth-thruster\n"
                "test rig) as co-simulated FMUs, and turn the runs into labelled datasets.")
_EPILOG = """first steps:
  drivetrain run scenarios/example.toml --native --out out/example     one run: signals, summary, plots
  drivetrain sweep GRID.toml --set sweep.draw.n=2 --out out/grid       a grid (any key, its [sweep] too)
  drivetrain dataset out/grid                                          dataset.parquet + DATASET.md card
  drivetrain COMMAND --help                                            every option of a command

docs/ of the source checkout: SCENARIOS.md (every scene key), MASTER.md, FMU.md, ARCHITECTURE.md."""

#: one function per command (or pair of commands sharing their options), in the order of --help
_PARSERS = (_parser_build_fmus, _parser_run, _parser_build_native_gear, _parser_build_native, _parser_export_ssp,
            _parser_eigen, _parser_calibrate, _parser_sweep, _parser_validate, _parser_accuracy_cost, _parser_dataset,
            _parser_features, _parser_detectability, _parser_frontier, _parser_check_and_baseline, _parser_stress)


def build_parser() -> argparse.ArgumentParser:
    from drivetrain import __version__

    parser = argparse.ArgumentParser(prog="drivetrain", description=_DESCRIPTION, epilog=_EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=(
        f"drivetrain {__version__} (Python {sys.version.split()[0]}, {Path(__file__).resolve().parent})"))
    sub = parser.add_subparsers(dest="command", required=True)
    for add in _PARSERS:
        add(sub)

    return parser


def _map_build_bar(desc: str, total: int, *, triangles: int | None = None, workers: int = 1, unit: str = " steps"):
    """The progress bar of a long library step: a contact-map build (``triangles`` given), with the cost
    model's estimate, shown after 1 s; any other (e.g. writing a run's files), shown after 2 s."""
    from tqdm import tqdm

    if triangles is None:
        return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, delay=2.0, leave=False)
    from gearcontact_fmu.cost import hours, map_row_seconds

    estimate_s = 0.5 * total * map_row_seconds(triangles) / max(1, workers)
    return tqdm(total=total, desc=f"{desc}, estimated {hours(estimate_s)}", unit=" flank rows", file=sys.stderr,
                delay=1.0, leave=False)


def _wall_line(args: argparse.Namespace, parts: list[tuple[str, float]]) -> str:
    """"wall time W s: start-up S s, <part> s, ..., other O s": where a command's wall time went, from the
    process start (args.started) to now; start-up runs to the command's start (args.t_command), ``parts``
    are the command's measured phases after it, ``other`` what none of them holds (shown from 0.01 s).
    The command's last step: the FMUs it unpacked are removed first (a part of its own), not at the exit."""
    items = [("start-up", args.t_command - args.started), *parts]
    fmus = sys.modules.get("drivetrain.fmu_build.fmus")       # loaded: FMUs may have been unpacked
    if fmus is not None and args.own_process:             # (not in a caller's process: its FMUs may be alive)
        t0 = time.perf_counter()
        fmus.remove_extracted()
        items.append(("removing unpacked FMUs", time.perf_counter() - t0))
    now = time.perf_counter()
    wall = now - args.started
    rest = wall - sum(v for _, v in items)
    if rest >= 0.005:
        items.append(("other", rest))
    return f"wall time {wall:.2f} s: " + ", ".join(f"{name} {v:.2f} s" for name, v in items)


def main(argv: list[str] | None = None) -> int:
    from drivetrain.run.timing import process_start

    # the wall time the commands print counts from the process start (start-up included) when this is the
    # process's command line; from this call when called with arguments (e.g. in a test's process)
    started = process_start() if argv is None else time.perf_counter()
    parser = build_parser()
    args = parser.parse_args(argv)
    from gearcontact_fmu import progress

    if not getattr(args, "quiet", False):
        progress.set_factory(_map_build_bar)
    args.started, args.own_process = started, argv is None
    args.t_command = time.perf_counter()
    rc = _run_command(args)
    if argv is None:                     # this process's command line: end it now (see _exit)
        _exit(rc)
    return rc


def _exit(rc: int) -> None:
    """End the process once the command is done: flush, run the atexit handlers (logging, multiprocessing,
    temporary directories, ...), then ``os._exit``, without the interpreter's module teardown, which costs
    0.5-1 s after a run (numba, matplotlib, fmpy, scipy; measured) and is not part of any result."""
    import atexit

    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(rc)


def _run_command(args: argparse.Namespace) -> int:
    """The subcommand, with the error exits every command shares."""
    from gearcontact_fmu.meshes import MeshError

    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130
    except MeshError as exc:             # a mesh file found unusable wherever it is read (the cost check, a build)
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except Refused as exc:               # any door's refusal (a file, a grid, a folder in use) that no command caught
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (OSError, shutil.Error) as exc:
        # the system refused a file operation (a full disk, a file-size limit, permissions) where no command
        # checks beforehand, e.g. while an FMU is built or unpacked: its own words, no traceback
        print(f"error: {_os_error_text(exc)}", file=sys.stderr)
        return 1


def _os_error_text(exc: BaseException) -> str:
    """What a failed file operation says, once (shutil.Error lists every file that failed)."""
    hints = {errno.EFBIG: " (a file-size limit: see ulimit -f)", errno.ENOSPC: " (the disk is full)",
             errno.EDQUOT: " (a disk quota)"}
    if isinstance(exc, shutil.Error) and exc.args and isinstance(exc.args[0], list) and exc.args[0]:
        src, dst, why = exc.args[0][0]        # shutil keeps each file's OSError as text: "[Errno 27] ..."
        more = len(exc.args[0]) - 1
        hint = next((h for n, h in hints.items() if f"[Errno {n}]" in str(why)), "")
        return f"could not copy {src} to {dst}: {why}{hint}" + (f" (and {more} more files)" if more else "")
    return f"{exc}{hints.get(getattr(exc, 'errno', None), '')}"


if __name__ == "__main__":
    sys.exit(main())
