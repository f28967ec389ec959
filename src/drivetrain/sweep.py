"""Sweeps: many scenes in parallel, one result directory (one HDF5) per run plus a manifest.

One picklable ``simulate(case)`` function runs a case in whatever process it lands in. FMUs are never
pickled: each worker process extracts and loads them once (the master's per-process caches) and reuses
them for every case it runs. The executor is a local ``concurrent.futures.ProcessPoolExecutor`` by
default, or ``distributed.Client(address).get_executor()`` when a Dask scheduler address is given; the
same function runs unchanged on both. Before any case is dispatched the parent assembles every scene
(the workers run exactly these SystemSpecs), builds missing or stale FMUs once, and prepares the disk
caches that component initialisation would build (contact maps of ``table`` gears: Dask workers are
daemonic processes and cannot start the map builder's process pool). Never do several processes write one HDF5: each run writes its own directory.

Manifest: ``<out>/manifest.json`` (full) and ``<out>/manifest.csv`` (one row per run: name, status,
paths, wall time, real-time factor, mean torques, energy residual, the swept scene values, failure time
and FMU, the main stability numbers). Every record has ``status`` ("ok" | "failed") and, when the run got
as far as stepping, ``stability`` (= its summary's stability block). A run whose FMU failed mid-run
wrote its partial files: its record has ``status = "failed"``, ``error``, ``failure_time_s``,
``failed_fmu``, ``failure_cause``, ``failure`` (time_s, component, model, function, status, cause),
``partial = true`` and the paths ``signals``/``summary``; the sweep
goes on with the other runs.
"""
from __future__ import annotations

import concurrent.futures as cf
import csv
import json
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Any

from drivetrain.scenario import Scene, resolve


def make_case(scene: Scene, out_dir: Path, *, backend: str = "fmi", fmu_dir: str | Path = "fmus",
              plots: bool = True, spec=None, fmu_paths: dict | None = None) -> dict:
    """A picklable description of one run (the scene as plain data, not the Scene object)."""
    return {
        "name": scene.name,
        "scene": scene.to_dict(),
        "source": str(scene.source) if scene.source else None,
        "overrides": list(scene.overrides),
        "out_dir": str(out_dir),
        "backend": backend,
        "fmu_dir": str(Path(fmu_dir).resolve()),
        "plots": plots,
        "spec": spec,
        "fmu_paths": {k: str(v) for k, v in (fmu_paths or {}).items()} or None,
    }


def _scene_of(case: dict) -> Scene:
    base = Path(case["source"]).parent if case.get("source") else Path.cwd()
    sc = resolve(case["scene"], base_dir=base, source=case.get("source"), overrides=tuple(case.get("overrides", ())))
    return sc


def _summary_fields(s: dict) -> dict:
    """The manifest fields a run's summary gives (ok or failed)."""
    return {
        "wall_time_s": s["wall_time_s"], "sim_time_s": s["sim_time_s"],
        "real_time_factor": s["real_time_factor"], "us_per_step": s["us_per_step"],
        "energy_residual": s["energy_residual"],
        "torque_mean": {k: v["mean"] for k, v in s["torque"].items()},
        "torque_rms": {k: v["rms"] for k, v in s["torque"].items()},
        "warnings": s["warnings"],
        "stability": s.get("stability"),
    }


def simulate(case: dict) -> dict:
    """Run one case in this process; never raises (errors are reported in the returned record)."""
    from drivetrain.run import RunFailedError, run_scene

    t0 = time.perf_counter()
    rec: dict[str, Any] = {"name": case["name"], "out_dir": case["out_dir"], "pid": os.getpid()}
    try:
        scene = _scene_of(case)
        res = run_scene(scene, case["out_dir"], backend=case.get("backend", "fmi"), progress=False,
                        fmu_dir=case.get("fmu_dir", "fmus"), spec=case.get("spec"),
                        fmu_paths=case.get("fmu_paths"), plots=case.get("plots", True),
                        build=False, log=lambda m: None)
        rec.update({
            "status": "ok",
            "signals": str(Path(case["out_dir"]) / "signals.h5"),
            "summary": str(Path(case["out_dir"]) / "summary.json"),
            **_summary_fields(res.summary),
        })
    except RunFailedError as exc:
        # an FMU failed mid-run: the completed part was written; record where and why
        s = exc.result.summary
        f = s.get("failure") or {}
        files = exc.result.files or {}
        rec.update({
            "status": "failed", "error": f"{type(exc).__name__}: {exc}", "partial": True,
            "failure_time_s": f.get("time_s"), "failed_fmu": f.get("component"),
            "failed_model": f.get("model"), "failure_cause": f.get("cause"),
            "failure": {k: f.get(k) for k in ("time_s", "component", "model", "function", "status", "cause")},
            "signals": files.get("signals"), "summary": files.get("summary"),
            **_summary_fields(s),
        })
    except Exception as exc:
        rec.update({"status": "failed", "error": f"{type(exc).__name__}: {exc}",
                    "traceback": traceback.format_exc(limit=8)})
        if hasattr(exc, "component") and hasattr(exc, "time"):     # a CosimError before the first step
            rec.update({"failure_time_s": exc.time, "failed_fmu": exc.component, "partial": False})
    rec["elapsed_s"] = time.perf_counter() - t0
    return rec


def _executor(workers: int | None, address: str | None):
    if address:
        from distributed import Client

        client = Client(address)
        return client.get_executor(), client
    import multiprocessing as mp

    workers = workers or os.cpu_count() or 1
    return cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")), None


def _specs_of(scenes: list[Scene], specs: dict | None) -> list:
    from drivetrain.run import assemble_scene

    return [(specs or {}).get(s.name) or assemble_scene(s) for s in scenes]


#: component parameter values whose initialisation builds a disk cache worth preparing in the parent
CACHED_FIDELITIES = ("table",)


def prepare_caches(specs: list, fmu_dir: str | Path = "fmus", fmu_paths: dict | None = None,
                   log=None) -> int:
    """Initialise once, in this (non-daemonic) process, every distinct component configuration whose
    initialisation builds a disk cache (GearContact ``fidelity = "table"``: the contact map), so that
    worker processes only read caches. Dask worker processes are daemonic and cannot start the map
    builder's process pool. Returns the number of configurations prepared; failures are left to the runs
    (they report them with the FMU's log)."""
    from drivetrain.master import simulate
    from drivetrain.system import SystemSpec

    seen, todo = set(), []
    for spec in specs:
        for c in spec.components:
            if c.parameters.get("fidelity") in CACHED_FIDELITIES:
                key = json.dumps({"model": c.model, "p": c.parameters}, sort_keys=True, default=str)
                if key not in seen:
                    seen.add(key)
                    todo.append((c, spec.comm_step))
    for comp, H in todo:
        if log:
            log(f"preparing {comp.model} ({comp.name}: fidelity {comp.parameters.get('fidelity')}, "
                f"health {comp.parameters.get('health', '?')})")
        one = SystemSpec(components=[comp], connections=[], comm_step=H)
        try:
            simulate(one, H, 1.0 / H, backend="inprocess", fmu_dir=fmu_dir, fmu_paths=fmu_paths, build=False,
                     progress=False)
        except Exception as exc:  # the run of the case will report it properly
            if log:
                log(f"  preparation failed ({type(exc).__name__}); the runs will report it")
    return len(todo)


def run_sweep(scenes: list[Scene], out_dir: str | Path, *, workers: int | None = None, address: str | None = None,
              backend: str = "fmi", fmu_dir: str | Path = "fmus", skip_existing: bool = False, plots: bool = True,
              progress: bool = True, specs: dict[str, Any] | None = None, fmu_paths: dict | None = None,
              executor=None, prepare: bool = True) -> dict:
    """Run every scene; returns the manifest (also written to out_dir/manifest.json and .csv).

    ``workers``: local processes (default: CPU count); ``address``: Dask scheduler (then Dask's executor);
    ``executor``: any concurrent.futures-style executor to use instead. ``specs``: {scene name: SystemSpec}
    to bypass the assembler (tests); ``fmu_paths``: explicit FMUs (no building). ``prepare``: build the
    components' disk caches (contact maps) in this process first (:func:`prepare_caches`).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = [s.name for s in scenes]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        from drivetrain.master import ConfigurationError

        raise ConfigurationError(f"scene names must be unique in a sweep: {', '.join(dup)}")
    log = (lambda m: print(m, file=sys.stderr)) if progress else None
    all_specs = _specs_of(scenes, specs)
    if fmu_paths is None:
        from drivetrain.master import ensure_fmus

        needed = list(dict.fromkeys(c.model for sp in all_specs for c in sp.components))
        ensure_fmus(needed, fmu_dir, build=True, log=log or (lambda m: None))
    if prepare:
        prepare_caches(all_specs, fmu_dir, fmu_paths, log=log)
    cases, runs = [], []
    for s, sp in zip(scenes, all_specs):
        d = out / s.name
        if skip_existing and (d / "summary.json").is_file():
            try:        # a failed run's partial results are kept as they are, with their status
                old = json.loads((d / "summary.json").read_text())
            except (OSError, ValueError):
                old = {}
            prev = {"name": s.name, "status": old.get("status", "ok"), "skipped": True, "out_dir": str(d),
                    "signals": str(d / "signals.h5"), "summary": str(d / "summary.json"),
                    "stability": old.get("stability")}
            if old.get("failure"):
                prev.update(failure_time_s=old["failure"].get("time_s"), failed_fmu=old["failure"].get("component"),
                            failure_cause=old["failure"].get("cause"), partial=True)
            runs.append(prev)
            continue
        cases.append(make_case(s, d, backend=backend, fmu_dir=fmu_dir, plots=plots,
                               spec=sp, fmu_paths=fmu_paths))
    t0 = time.perf_counter()
    client = None
    own = executor is None
    if cases:
        if own:
            executor, client = _executor(workers, address)
        try:
            futures = [executor.submit(simulate, c) for c in cases]
            bar = None
            if progress:
                from tqdm import tqdm

                bar = tqdm(total=len(futures), unit="run", desc="sweep")
            for fut in cf.as_completed(futures):
                runs.append(fut.result())
                if bar is not None:
                    bar.update(1)
            if bar is not None:
                bar.close()
        finally:
            if own:
                executor.shutdown(wait=True)
            if client is not None:
                client.close()
    order = {n: i for i, n in enumerate(names)}
    runs.sort(key=lambda r: order.get(r["name"], 0))
    by_name = {s.name: s for s in scenes}
    for r in runs:
        s = by_name[r["name"]]
        r["drive_speed_rpm"] = s.operating_point.final_speed_rpm
        r["load_torque_Nm"] = s.operating_point.load_torque_Nm
        r["health"] = s.gear.health
        r["mesh_contact"] = s.effects.mesh_contact
        r["shaft_flexibility"] = s.effects.shaft_flexibility
    manifest = {"path": str(out / "manifest.json"), "n_runs": len(runs), "wall_time_s": time.perf_counter() - t0,
                "executor": "dask" if address else ("custom" if not own else "local processes"),
                "backend": backend, "runs": runs}
    from drivetrain.outputs import jsonable

    (out / "manifest.json").write_text(json.dumps(jsonable(manifest), indent=1))
    cols = ["name", "status", "health", "drive_speed_rpm", "load_torque_Nm", "mesh_contact", "shaft_flexibility",
            "wall_time_s", "real_time_factor", "energy_residual", "mean_drive_shaft_torque",
            "mean_propeller_shaft_torque", "failure_time_s", "failed_fmu", "max_penetration_rel_umax",
            "min_substep_s", "n_refinements", "n_separations", "separated_fraction", "signals", "summary", "error"]
    with open(out / "manifest.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in runs:
            row = dict(r)
            tm = r.get("torque_mean", {})
            row["mean_drive_shaft_torque"] = tm.get("drive_shaft_torque")
            row["mean_propeller_shaft_torque"] = tm.get("propeller_shaft_torque")
            st = r.get("stability") or {}
            rattle = st.get("rattle") or {}
            for k in ("max_penetration_rel_umax", "min_substep_s", "n_refinements"):
                row[k] = st.get(k)
            row["n_separations"] = rattle.get("n_separations")
            row["separated_fraction"] = rattle.get("separated_fraction")
            w.writerow(row)
    return manifest


__all__ = ["simulate", "run_sweep", "make_case", "prepare_caches"]
