"""Sweeps: many scenes in parallel, one result directory (one HDF5) per run plus a manifest.

One picklable ``simulate(case)`` function runs a case in whatever process it lands in. FMUs are never
pickled: each worker process extracts and loads them once (the master's per-process caches) and reuses
them for every case it runs. The executor is a local ``concurrent.futures.ProcessPoolExecutor`` by
default, or ``distributed.Client(address).get_executor()`` when a Dask scheduler address is given; the
same function runs unchanged on both. FMUs are built (if missing or stale) once in the parent before
any case is dispatched. Never do several processes write one HDF5: each run writes its own directory.

Manifest: ``<out>/manifest.json`` (full) and ``<out>/manifest.csv`` (one row per run: name, status,
paths, wall time, real-time factor, mean torques, energy residual, the swept scene values).
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


def simulate(case: dict) -> dict:
    """Run one case in this process; never raises (errors are reported in the returned record)."""
    from drivetrain.run import run_scene

    t0 = time.perf_counter()
    rec: dict[str, Any] = {"name": case["name"], "out_dir": case["out_dir"], "pid": os.getpid()}
    try:
        scene = _scene_of(case)
        res = run_scene(scene, case["out_dir"], backend=case.get("backend", "fmi"), progress=False,
                        fmu_dir=case.get("fmu_dir", "fmus"), spec=case.get("spec"),
                        fmu_paths=case.get("fmu_paths"), plots=case.get("plots", True),
                        build=False, log=lambda m: None)
        s = res.summary
        rec.update({
            "status": "ok",
            "signals": str(Path(case["out_dir"]) / "signals.h5"),
            "summary": str(Path(case["out_dir"]) / "summary.json"),
            "wall_time_s": s["wall_time_s"], "sim_time_s": s["sim_time_s"],
            "real_time_factor": s["real_time_factor"], "us_per_step": s["us_per_step"],
            "energy_residual": s["energy_residual"],
            "torque_mean": {k: v["mean"] for k, v in s["torque"].items()},
            "torque_rms": {k: v["rms"] for k, v in s["torque"].items()},
            "warnings": s["warnings"],
        })
    except Exception as exc:
        rec.update({"status": "failed", "error": f"{type(exc).__name__}: {exc}",
                    "traceback": traceback.format_exc(limit=8)})
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


def _models_needed(scenes: list[Scene]) -> list[str]:
    from drivetrain.run import assemble_scene

    models = []
    for s in scenes:
        for c in assemble_scene(s).components:
            models.append(c.model)
    return list(dict.fromkeys(models))


def run_sweep(scenes: list[Scene], out_dir: str | Path, *, workers: int | None = None, address: str | None = None,
              backend: str = "fmi", fmu_dir: str | Path = "fmus", skip_existing: bool = False, plots: bool = True,
              progress: bool = True, specs: dict[str, Any] | None = None, fmu_paths: dict | None = None,
              executor=None) -> dict:
    """Run every scene; returns the manifest (also written to out_dir/manifest.json and .csv).

    ``workers``: local processes (default: CPU count); ``address``: Dask scheduler (then Dask's executor);
    ``executor``: any concurrent.futures-style executor to use instead. ``specs``: {scene name: SystemSpec}
    to bypass the assembler (tests); ``fmu_paths``: explicit FMUs (no building).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = [s.name for s in scenes]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        from drivetrain.master import ConfigurationError

        raise ConfigurationError(f"scene names must be unique in a sweep: {', '.join(dup)}")
    if fmu_paths is None:
        from drivetrain.master import ensure_fmus

        needed = _models_needed(scenes) if specs is None else list(
            dict.fromkeys(c.model for sp in specs.values() for c in sp.components))
        ensure_fmus(needed, fmu_dir, build=True, log=lambda m: print(m, file=sys.stderr))
    cases, runs = [], []
    for s in scenes:
        d = out / s.name
        if skip_existing and (d / "summary.json").is_file():
            runs.append({"name": s.name, "status": "ok", "skipped": True, "out_dir": str(d),
                         "signals": str(d / "signals.h5"), "summary": str(d / "summary.json")})
            continue
        cases.append(make_case(s, d, backend=backend, fmu_dir=fmu_dir, plots=plots,
                               spec=(specs or {}).get(s.name), fmu_paths=fmu_paths))
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
            "mean_propeller_shaft_torque", "signals", "summary", "error"]
    with open(out / "manifest.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in runs:
            row = dict(r)
            tm = r.get("torque_mean", {})
            row["mean_drive_shaft_torque"] = tm.get("drive_shaft_torque")
            row["mean_propeller_shaft_torque"] = tm.get("propeller_shaft_torque")
            w.writerow(row)
    return manifest


__all__ = ["simulate", "run_sweep", "make_case"]
