"""Sweeps: many scenes in parallel, one result directory (one HDF5) per run plus a manifest.

One picklable ``simulate(case)`` function runs a case in whatever process it lands in. FMUs are never
pickled: each worker process extracts and loads them once (the master's per-process caches) and reuses
them for every case it runs. The executor is a local ``concurrent.futures.ProcessPoolExecutor`` by
default, or ``distributed.Client(address).get_executor()`` when a Dask scheduler address is given (or a
``LocalCluster`` the sweep starts and stops, for the address ``"local"``); the same function runs unchanged
on both. Before any case is dispatched the parent assembles every scene
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

Nothing is lost to a kill: each finished run's record is appended to the journal
``<out>/manifest.jsonl`` the moment it ends (one JSON line, one ``write`` on an append-only file, then
``fsync``: a kill leaves whole lines, at most a torn last one, which readers skip). The full manifest is
rewritten atomically (temporary file + rename) at the start, at most every ``MANIFEST_EVERY_S`` while
runs finish, and at the end, with ``complete = false`` until the last run: a sweep of thousands of runs
does not rewrite a growing manifest after each one. :func:`read_runs` gives every record of a sweep
directory, the manifest's updated by the journal's, so a killed sweep's last runs are never missing
(the dataset export and ``--only``/``--resume`` read it).

Each run directory holds ``case.json``: the resolved scene and the fingerprint of scene, project
version, model sources and any explicitly given FMU files. ``skip_existing`` reuses a finished run only
when that fingerprint matches (otherwise it runs again and says why), and a reused run keeps its
metrics in the manifest.
``grid_names`` (all cases of the sweep, of which ``scenes`` may be a selection, e.g. ``--only``): records
of other cases already in the manifest are kept, not dropped. A run directory is cleared of earlier
outputs before its run writes.
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import csv
import functools
import json
import logging
import os
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivetrain import __version__

from drivetrain.run import cost as runcost
from drivetrain.campaigns.provenance import code_commit
from drivetrain.cosim import ConfigurationError
from drivetrain.errors import FileFormatError, StartStateError
from drivetrain.cosim import simulate as simulate_system
from drivetrain.fmu_build.fmus import sources_hash
from drivetrain.fmu_build.fmus import fmu_dir_or_default
from drivetrain.run.lock import output_lock
from drivetrain.run.files import RUN_RECORD_SCHEMA, check_fields, read_manifest
from drivetrain.run.outputs import check_output_dir, clear_run_files, jsonable
from drivetrain.run.runner import RunFailedError, assemble_scene, run_scene
from drivetrain.run.assemble import start_with_map
from drivetrain.scene.load import Scene, resolve
from drivetrain.system import SystemSpec
from gearcontact_fmu.params import file_sha256

#: messages for the user (progress, warnings); the CLI passes its own ``log``, a library caller sees them
#: through Python logging (on stderr when logging is not configured)
_LOG = logging.getLogger(__name__)


def make_case(scene: Scene, out_dir: Path, *, backend: str = "fmi", fmu_dir: str | Path | None = None,
              plots: bool | None = None, spec=None, fmu_paths: dict | None = None, force: bool = False) -> dict:
    """A picklable description of one run (the scene as plain data, not the Scene object). ``plots``:
    None = as the scene says (``outputs.plots``), False = never."""
    return {
        "name": scene.name,
        "scene": scene.to_dict(),
        "source": str(scene.source) if scene.source else None,
        "overrides": list(scene.overrides),
        "out_dir": str(out_dir),
        "backend": backend,
        "fmu_dir": str(fmu_dir_or_default(fmu_dir).resolve()),
        "plots": plots,
        "fingerprint": fingerprint(scene, fmu_paths),
        "spec": spec,
        "fmu_paths": {k: str(v) for k, v in (fmu_paths or {}).items()} or None,
        "force": bool(force),
    }


def labels(scene: dict) -> dict:
    """The labels of a run for dataset users: the gear's health and its faults (each with every default
    filled in, random draws included), from the resolved scene."""
    gear = scene.get("gear", {})
    return {"health": gear.get("health"), "faults": list(gear.get("faults") or [])}


#: the sweep's own file in a run's directory, beside the run's (run.outputs.RUN_FILES): cleared before the run
CASE_FILE = "case.json"


def fingerprint(scene: Scene, fmu_paths: dict | None = None) -> str:
    """Identity of what a run computes: the resolved scene, the project version, the sources of the models
    and FMUs, and the content of explicitly given FMUs (a swapped-in FMU is another computation)."""
    import hashlib

    text = json.dumps(jsonable(scene.to_dict()), sort_keys=True, default=str)
    h = hashlib.sha256(f"{text}|{__version__}|{sources_hash()}".encode())
    table = scene.drivetrain.parameters          # the machine's lumped table: its content, not only its path
    if table is not None:
        st = os.stat(table)
        h.update(f"|table:{_content_digest(str(table), st.st_mtime_ns, st.st_size)}".encode())
    for model, path in sorted((fmu_paths or {}).items()):
        st = os.stat(path)
        h.update(f"|{model}:{_content_digest(str(path), st.st_mtime_ns, st.st_size)}".encode())
    return h.hexdigest()[:24]


@functools.lru_cache(maxsize=64)
def _content_digest(path: str, mtime_ns: int, size: int) -> str:
    """SHA-256 of a file, once per (path, modification time, size) in a process."""
    return file_sha256(path)


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
        "nonfinite_samples": sum((s.get("nonfinite_samples") or {}).values()),
    }


#: set in a local worker process once it got SIGINT or SIGTERM: it starts no further run
_WORKER_STOPPING = False


def _worker_signals() -> None:
    """Initializer of a local sweep worker: SIGINT (a Ctrl-C reaches every process of the terminal) and
    SIGTERM end the run it is stepping as "interrupted", with what it computed written; a worker that is
    not stepping (between runs, reading or writing) exits at once (its run directory says "running", and
    ``--resume`` runs it again). Either way no traceback: the parent stops the sweep and says so."""
    import signal

    from drivetrain.cosim.master import request_stop

    def handler(signum, frame):
        global _WORKER_STOPPING
        _WORKER_STOPPING = True
        if not request_stop(f"{signal.Signals(signum).name} received"):
            os._exit(128 + signum)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)


def simulate(case: dict) -> dict:
    """Run one case in this process; never raises (errors are reported in the returned record)."""

    t0 = time.perf_counter()
    rec: dict[str, Any] = {"name": case["name"], "out_dir": case["out_dir"], "pid": os.getpid(),
                           "labels": labels(case["scene"])}
    if _WORKER_STOPPING:                  # this worker was told to stop: no new run
        return {**rec, "status": "interrupted", "error": "the sweep was interrupted before this run started"}
    try:
        scene = _scene_of(case)
        d = Path(case["out_dir"])
        d.mkdir(parents=True, exist_ok=True)
        clear_run_files(d, extra=(CASE_FILE,))
        (d / CASE_FILE).write_text(json.dumps({"name": case["name"], "fingerprint": case.get("fingerprint"),
                                                 "scene": case["scene"], "source": case.get("source"),
                                                 "overrides": case.get("overrides", [])}, indent=1, default=str))
        plots = case.get("plots")
        res = run_scene(scene, case["out_dir"], backend=case.get("backend", "fmi"), progress=False,
                        fmu_dir=case.get("fmu_dir"), spec=case.get("spec"),
                        fmu_paths=case.get("fmu_paths"), plots=None if plots is None else bool(plots),
                        build=False, log=lambda m: None, force=bool(case.get("force")))
        rec.update({
            "status": res.summary["status"],          # "failed" for a run with non-finite samples
            **({"error": res.summary["failure"]["cause"]} if res.summary["status"] != "ok" else {}),
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


#: ``address`` that starts a Dask cluster on this machine for the sweep (and stops it at the end)
LOCAL_DASK = "local"


def _executor(workers: int | None, address: str | None):
    """(executor, what to close after it: a Dask client, and the cluster the sweep started, or None)."""
    if address == LOCAL_DASK:
        from distributed import Client, LocalCluster

        # one single-threaded worker process per core, no dashboard: a sweep's own cluster
        closing = contextlib.ExitStack()          # closed in reverse: the client, then the cluster
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        closing.callback(cluster.close)
        client = Client(cluster)
        closing.callback(client.close)
        return client.get_executor(), closing
    if address:
        from distributed import Client

        client = Client(address)
        return client.get_executor(), client
    import multiprocessing as mp

    workers = workers or os.cpu_count() or 1
    return cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                  initializer=_worker_signals), None


def _shut_down(executor, interrupted: bool) -> None:
    """End the sweep's own executor: after the last run, waiting for it; after an interruption, cancelling the
    runs not started instead of waiting for them (a local worker ends the run it is stepping: it got the
    signal too). Dask's executor cancels on ``wait=False``; it has no ``cancel_futures``."""
    if not interrupted:
        executor.shutdown(wait=True)
    elif isinstance(executor, cf.ProcessPoolExecutor):
        executor.shutdown(wait=True, cancel_futures=True)
    else:
        executor.shutdown(wait=False)


def _executor_name(address: str | None, executor) -> str:
    """How the runs execute, for the manifest."""
    if address:
        return "dask (local cluster)" if address == LOCAL_DASK else "dask"
    return "custom" if executor is not None else "local processes"


def _specs_of(scenes: list[Scene], specs: dict | None, assemble=assemble_scene) -> tuple[list, dict[str, str]]:
    """(the SystemSpec of each scene, None where it has no start state; {name: why} of those): a caller's spec
    (``specs``) as given, else ``assemble(scene)``. A gearbox whose mesh carries the start load at no position
    (:class:`drivetrain.errors.StartStateError`) is one failed case, named in the manifest: the others go on.
    Every other refusal stops the sweep, as before."""
    out, refused = [], {}
    for s in scenes:
        try:
            out.append((specs or {}).get(s.name) or assemble(s))
        except StartStateError as exc:
            out.append(None)
            refused[s.name] = str(exc)
    return out, refused


def _runnable(scenes: list[Scene], all_specs: list) -> tuple[list[Scene], list]:
    """The scenes that have a start state, with their specs."""
    kept = [(s, sp) for s, sp in zip(scenes, all_specs) if sp is not None]
    return [s for s, _ in kept], [sp for _, sp in kept]


def _start_failures(refused: dict[str, str], scenes: list[Scene], out: Path) -> list[dict]:
    """The records of the cases that have no start state: failed before any step, nothing written."""
    by_name = {s.name: s for s in scenes}
    return [{"name": name, "out_dir": str(out / name), "labels": labels(by_name[name].to_dict()),
             "status": "failed", "error": f"StartStateError: {why}", "failure_cause": "no start state",
             "partial": False, "elapsed_s": 0.0} for name, why in refused.items()]


#: component parameter values whose initialisation builds a disk cache worth preparing in the parent
CACHED_FIDELITIES = ("table",)


def _cache_shaping(parameters: dict) -> dict:
    """The parameters a component's disk cache can depend on: all but the running state (``*_start``,
    ``initial_state``) and the manufacturing errors (applied to the contact map, not in it), so that a sweep
    over operating points and gearboxes prepares each contact map once."""
    return {k: v for k, v in parameters.items()
            if not (k.endswith("_start") or k in ("initial_state", "manufacturing_errors"))}


def prepare_caches(specs: list, fmu_dir: str | Path | None = None, fmu_paths: dict | None = None,
                   log=None, workers: int | None = None) -> int:
    """Initialise once, in this (non-daemonic) process or its children, every distinct component
    configuration whose initialisation builds a disk cache (GearContact ``fidelity = "table"``: the contact
    map), so that worker processes only read caches. Dask worker processes are daemonic and cannot start the
    map builder's process pool. Several configurations are prepared side by side, one per process of a
    pool of ``workers`` (default: the CPU count), each building its map on one core: a map build has serial
    parts (the meshes, the contact table, the pool start) that one build alone leaves the other cores idle
    for. Returns the number of configurations prepared; failures are left to the runs (they report them
    with the FMU's log)."""

    seen, todo = set(), []
    for spec in specs:
        for c in spec.components:
            if c.parameters.get("fidelity") in CACHED_FIDELITIES:
                key = json.dumps({"model": c.model, "p": _cache_shaping(c.parameters)}, sort_keys=True, default=str)
                if key not in seen:
                    seen.add(key)
                    todo.append((c, spec.comm_step))
    workers = max(1, min(workers or os.cpu_count() or 1, len(todo)))
    if workers == 1:
        for comp, H in todo:
            if log:
                log(f"preparing {comp.model} ({comp.name}: fidelity {comp.parameters.get('fidelity')}, "
                    f"health {comp.parameters.get('health', '?')})")
            problem = _prepare_one(comp, H, fmu_dir, fmu_paths)
            if problem and log:
                log(f"  preparation failed ({problem}); the runs will report it")
        return len(todo)
    import multiprocessing as mp

    t0 = time.perf_counter()
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    if ctx.get_start_method() == "fork":
        # the first configuration here, its map's rows on every core: on a fresh install its first call compiles
        # the contact kernels (numba) once, in this process, and the pool's forked processes inherit the compiled
        # code, where each of them compiled it again before, side by side on the same cores
        comp, H = todo.pop(0)
        from gearcontact_fmu.contact_map import compile_notice_text, kernels_cold

        if log and kernels_cold():
            log(compile_notice_text().capitalize())
        if log:
            log(f"preparing {comp.model} ({comp.name}: fidelity {comp.parameters.get('fidelity')}, health "
                f"{comp.parameters.get('health', '?')}), the first of {len(todo) + 1} configurations, on every core")
        problem = _prepare_one(comp, H, fmu_dir, fmu_paths)
        if log:
            log(f"  1/{len(todo) + 1} prepared ({time.perf_counter() - t0:.0f} s)"
                + (f"; {comp.name} failed ({problem}): the run will report it" if problem else ""))
        if not todo:
            return 1
        workers = max(1, min(workers, len(todo)))
    n_all = len(todo) + (1 if ctx.get_start_method() == "fork" else 0)
    if log:
        log(f"preparing {len(todo)} component configurations (contact maps) in {workers} processes")
    # a multiprocessing pool (its processes single-core map builders): on an interrupt it is terminated at
    # once, not waited for, and its processes ignore SIGINT (the parent reports the stop)
    pool = ctx.Pool(workers, initializer=_one_core_builder)
    try:
        jobs = [(comp, H, fmu_dir, fmu_paths) for comp, H in todo]
        for k, (name, problem) in enumerate(pool.imap_unordered(_prepare_job, jobs), n_all - len(todo) + 1):
            if log and (problem or k == n_all or k % max(1, n_all // 10) == 0):
                log(f"  {k}/{n_all} prepared ({time.perf_counter() - t0:.0f} s)"
                    + (f"; {name} failed ({problem}): the run will report it" if problem else ""))
        pool.close()
    except BaseException:
        pool.terminate()
        raise
    finally:
        pool.join()
    return n_all


def _prepare_job(job) -> tuple[str, str | None]:
    comp = job[0]
    return comp.name, _prepare_one(*job)


def _one_core_builder() -> None:
    """Initializer of a preparation process: its map builds run on its own core, without progress bars;
    SIGINT is the parent's to handle."""
    import signal

    from gearcontact_fmu import progress

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    os.environ["BEVEL_MAP_WORKERS"] = "1"
    progress.set_factory(None)


def _prepare_one(comp, H: float, fmu_dir, fmu_paths) -> str | None:
    """Initialise one component in this process (which builds its disk cache); None, or why it failed."""
    one = SystemSpec(components=[comp], connections=[], comm_step=H)
    try:
        simulate_system(one, H, 1.0 / H, backend="inprocess", fmu_dir=fmu_dir, fmu_paths=fmu_paths, build=False,
                        progress=False)
    except Exception as exc:  # the run of the case will report it properly
        return type(exc).__name__
    return None


MANIFEST_COLUMNS = ["name", "status", "health", "drive_speed_rpm", "load_torque_Nm", "mesh_contact",
                    "shaft_flexibility", "wall_time_s", "real_time_factor", "energy_residual",
                    "mean_drive_shaft_torque", "mean_propeller_shaft_torque", "failure_time_s", "failed_fmu",
                    "max_penetration_rel_umax", "min_substep_s", "n_refinements", "n_separations",
                    "separated_fraction", "signals", "summary", "error"]


def _reuse(scene: Scene, d: Path, fp: str) -> tuple[dict | None, str]:
    """The manifest record of a finished run in ``d`` when it computed the same thing (fingerprint), else
    (None, why it runs again)."""
    try:
        case = json.loads((d / CASE_FILE).read_text())
        old = json.loads((d / "summary.json").read_text())
    except (OSError, ValueError):
        return None, "no finished run with a case.json there"
    if case.get("fingerprint") != fp:
        return None, "the scene or the model sources changed since that run"
    if old.get("status") not in ("ok", "failed"):
        return None, f"that run did not finish (its summary says {old.get('status')!r})"
    rec = {"name": scene.name, "labels": labels(scene.to_dict()), "status": old.get("status", "ok"),
           "skipped": True, "out_dir": str(d),
           "signals": str(d / "signals.h5"), "summary": str(d / "summary.json")}
    try:
        rec.update(_summary_fields(old))
    except (KeyError, TypeError):
        return None, "its summary.json is incomplete"
    if old.get("failure"):
        f = old["failure"]
        rec.update(failure_time_s=f.get("time_s"), failed_fmu=f.get("component"), failure_cause=f.get("cause"),
                   partial=True)
    return rec, ""


#: the append-only journal of finished runs, beside manifest.json
JOURNAL = "manifest.jsonl"
#: while runs finish, manifest.json/csv are rewritten at most this often [s] (the journal: every run)
MANIFEST_EVERY_S = 30.0


def _journal_line(rec: dict) -> bytes:
    return (json.dumps(jsonable(rec), separators=(",", ":")) + "\n").encode("utf-8")


def _append_journal(out: Path, rec: dict) -> None:
    """One record, one write on an append-only file, then fsync: a kill leaves whole lines."""
    fd = os.open(out / JOURNAL, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, _journal_line(rec))
        os.fsync(fd)
    finally:
        os.close(fd)


def _start_journal(out: Path, records: list[dict]) -> None:
    """A new journal for this invocation holding the records it starts from (atomic replace)."""
    tmp = out / f".{JOURNAL}.{os.getpid()}"
    tmp.write_bytes(b"".join(_journal_line(r) for r in records))
    os.replace(tmp, out / JOURNAL)


def read_runs(out_dir: str | Path) -> list[dict]:
    """Every run record of a sweep directory: those of manifest.json, then the journal's (a later record
    of a name replaces an earlier one; a torn last line of a killed sweep is skipped). In manifest
    order, the journal's new names after. Raises OSError when the directory has neither file, and
    FileFormatError (naming the file and the field) when a manifest or a journal record is not one."""
    out = Path(out_dir)
    by_name: dict[str, dict] = {}
    found = False
    try:
        for r in read_manifest(out / "manifest.json")["runs"]:
            by_name[r["name"]] = r
        found = True
    except OSError:
        pass
    try:
        lines = (out / JOURNAL).read_bytes().splitlines()
        found = True
    except OSError:
        lines = []
    for i, ln in enumerate(lines):
        try:
            r = json.loads(ln)
        except ValueError:
            if i == len(lines) - 1 or not ln.strip():
                continue                 # a line torn by a kill
            raise FileFormatError([f"{out / JOURNAL}: line {i + 1}: not JSON"]) from None
        problems = check_fields(r, RUN_RECORD_SCHEMA, f"{out / JOURNAL}: line {i + 1}", required=("name",))
        if problems:
            raise FileFormatError(problems)
        by_name[r["name"]] = r
    if not found:
        raise OSError(f"{out}: neither manifest.json nor {JOURNAL}")
    return list(by_name.values())


def _write_manifest(out: Path, runs: list[dict], meta: dict, complete: bool) -> dict:
    """manifest.json and manifest.csv, each written to a temporary file and renamed (a kill never
    leaves a half-written manifest)."""

    manifest = {"path": str(out / "manifest.json"), "n_runs": len(runs), "complete": complete, **meta,
                "runs": runs}
    tmp = out / f".manifest.json.{os.getpid()}"
    tmp.write_text(json.dumps(jsonable(manifest), indent=1))
    os.replace(tmp, out / "manifest.json")
    tmp = out / f".manifest.csv.{os.getpid()}"
    with open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=MANIFEST_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in runs:
            row = dict(r)
            tm = r.get("torque_mean") or {}
            row["mean_drive_shaft_torque"] = tm.get("drive_shaft_torque")
            row["mean_propeller_shaft_torque"] = tm.get("propeller_shaft_torque")
            st = r.get("stability") or {}
            rattle = st.get("rattle") or {}
            for k in ("max_penetration_rel_umax", "min_substep_s", "n_refinements"):
                row[k] = st.get(k)
            row["n_separations"] = rattle.get("n_separations")
            row["separated_fraction"] = rattle.get("separated_fraction")
            w.writerow(row)
    os.replace(tmp, out / "manifest.csv")
    return manifest


def _refuse_costly(scenes: list[Scene], all_specs: list, backend: str) -> None:
    """Refuse, all at once and before anything runs, every case predicted to cost far more than its
    simulated time (:mod:`drivetrain.run.cost`, from its assembled system)."""
    too_costly = [f"{s.name}: {why}" for s, sp in zip(scenes, all_specs)
                  if (why := runcost.refusal(runcost.predict(sp, s.time.duration_s, backend))) is not None]
    if too_costly:
        raise ConfigurationError(too_costly)


def _prepare_fmus(scenes: list[Scene], all_specs: list, *, backend: str, fmu_dir, fmu_paths: dict | None,
                  prepare: bool, log) -> None:
    """In this process, once: missing or stale FMUs, the components' disk caches, the native FMUs."""
    if fmu_paths is None:
        from drivetrain.fmu_build.fmus import ensure_fmus

        needed = list(dict.fromkeys(c.model for sp in all_specs for c in sp.components))
        ensure_fmus(needed, fmu_dir, build=True, log=log or (lambda m: None))
    if prepare:
        prepare_caches(all_specs, fmu_dir, fmu_paths, log=log)
    if backend == "native" and fmu_paths is None:
        # compiled once here (one gear build per contact map), found in the cache by every worker (without a
        # compiler each run falls back to the pythonfmu FMUs and says so)
        from drivetrain.fmu_build.native_line import toolchain_problems

        if not toolchain_problems():
            _native_builds(all_specs, fmu_dir_or_default(fmu_dir) / "native", log)


def _native_builds(all_specs: list, cache_dir: Path, log) -> None:
    """The native FMUs of every distinct gear (one per contact map and manufacturing draw), the compilers
    side by side: the first system serially (it builds the line FMUs all share), the others in threads."""
    from drivetrain.fmu_build.native_line import build_fixed, native_fmus, system_gear

    distinct = {}
    for sp in all_specs:
        gear, _ = system_gear(sp)
        distinct.setdefault(json.dumps(build_fixed(gear) if gear else None, sort_keys=True, default=str), sp)
    specs = list(distinct.values())
    if not specs:
        return
    native_fmus(specs[0], cache_dir, log=log)
    if len(specs) > 1:
        t0, n = time.perf_counter(), len(specs) - 1
        with cf.ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as ex:
            for future in [ex.submit(native_fmus, sp, cache_dir) for sp in specs[1:]]:
                future.result()
        if log:
            log(f"native FMUs: {n + 1} distinct gears ready in {cache_dir} ({time.perf_counter() - t0:.1f} s)")


@dataclass
class _Manifest:
    """The records of a sweep as they come in, and the manifest written from them."""

    out: Path
    scenes: dict[str, Scene]            # name -> scene of this invocation (for the labels of a record)
    order: dict[str, int]               # name -> position in the grid
    meta: dict
    kept: list[dict] = field(default_factory=list)    # the other cases' records of an earlier invocation
    runs: list[dict] = field(default_factory=list)
    t0: float = field(default_factory=time.perf_counter)

    def annotate(self, r: dict) -> dict:
        s = self.scenes.get(r["name"])
        if s is not None:
            r.update(drive_speed_rpm=s.operating_point.final_speed_rpm, load_torque_Nm=s.operating_point.load_torque_Nm,
                     health=s.gear.health, mesh_contact=s.effects.mesh_contact,
                     shaft_flexibility=s.effects.shaft_flexibility)
        return r

    def write(self, complete: bool) -> dict:
        allr = sorted(self.kept + self.runs, key=lambda r: self.order.get(r["name"], len(self.order)))
        return _write_manifest(self.out, allr, {**self.meta, "wall_time_s": time.perf_counter() - self.t0}, complete)


def _kept_records(out: Path, grid_names: list[str] | None, names: list[str]) -> list[dict]:
    """Records of the other cases of the same sweep from an earlier invocation (--only)."""
    if not grid_names:
        return []
    others = set(grid_names) - set(names)
    try:
        old = read_runs(out)
    except OSError:
        old = []
    return [r for r in old if r.get("name") in others]


def _cases(scenes: list[Scene], all_specs: list, out: Path, *, skip_existing: bool,
           **case_args) -> tuple[list[dict], list[dict]]:
    """(the cases to run, the records of the finished runs reused as they are)."""
    cases, reused = [], []
    for s, sp in zip(scenes, all_specs):
        d = out / s.name
        case = make_case(s, d, spec=sp, **case_args)
        if skip_existing:
            prev, why = _reuse(s, d, case["fingerprint"])
            if prev is not None:
                reused.append(prev)
                continue
            case["rerun_reason"] = why
        cases.append(case)
    return cases, reused


def _run_cases(cases: list[dict], manifest: _Manifest, executor, progress: bool) -> None:
    """Submit every case, record each as it finishes (journal now, manifest at most every
    MANIFEST_EVERY_S); an interruption still writes the manifest."""
    last_write = time.monotonic()
    try:
        futures = {executor.submit(simulate, c): c for c in cases}
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(futures), unit="run", desc="sweep")
        for fut in cf.as_completed(futures):
            rec = fut.result()
            if futures[fut].get("rerun_reason"):
                rec["rerun_reason"] = futures[fut]["rerun_reason"]
            rec = manifest.annotate(rec)
            _append_journal(manifest.out, rec)
            manifest.runs.append(rec)
            if time.monotonic() - last_write >= MANIFEST_EVERY_S:
                manifest.write(False)
                last_write = time.monotonic()
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
    except BaseException:
        manifest.write(False)           # interrupted (Ctrl-C, an executor that died): the manifest catches up
        raise


def run_sweep(scenes: list[Scene], out_dir: str | Path, *, workers: int | None = None, address: str | None = None,
              backend: str = "fmi", fmu_dir: str | Path | None = None, skip_existing: bool = False,
              plots: bool | None = None, progress: bool = True, specs: dict[str, Any] | None = None,
              fmu_paths: dict | None = None, executor=None, prepare: bool = True,
              grid_names: list[str] | None = None, force: bool = False) -> dict:
    """Run every scene; returns the manifest (written to out_dir/manifest.json and .csv after every
    finished run, ``complete`` once all are done).

    ``workers``: local processes (default: CPU count); ``address``: Dask scheduler (then Dask's executor;
    ``"local"``: a Dask cluster of ``workers`` processes on this machine, started and stopped here);
    ``executor``: any concurrent.futures-style executor to use instead. ``specs``: {scene name: SystemSpec}
    to bypass the assembler (tests); ``fmu_paths``: explicit FMUs (no building). ``prepare``: build the
    components' disk caches (contact maps) in this process first (:func:`prepare_caches`). ``plots``:
    None = as each scene says, False = none. ``skip_existing``: reuse finished runs of the same
    fingerprint. ``grid_names``: every case name of the sweep when ``scenes`` is a selection of it; the
    manifest keeps the earlier records of the others. A case predicted to cost far more than its
    simulated time (:mod:`drivetrain.run.cost`) is refused, with every other such case, before anything
    runs; ``force`` runs them anyway.
    """
    t0 = time.perf_counter()                 # the wall time counts the preparation (map and FMU builds) too
    out = Path(out_dir)
    names = [s.name for s in scenes]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigurationError(f"scene names must be unique in a sweep: {', '.join(dup)}")
    all_scenes = scenes
    log = _LOG.warning if progress else None
    all_specs, refused = _specs_of(scenes, specs)
    scenes, all_specs = _runnable(scenes, all_specs)
    if not force:
        _refuse_costly(scenes, all_specs, backend)
    check_output_dir(out)
    with output_lock(out, takeover=skip_existing):     # a second writer into this folder is refused
        _prepare_fmus(scenes, all_specs, backend=backend, fmu_dir=fmu_dir, fmu_paths=fmu_paths, prepare=prepare, log=log)
        # the maps are there now: a table gear assembled before its map was cached starts at its own deflection, as
        # `drivetrain run` starts it (the specs a caller gave are theirs)
        by_spec = dict(zip([s.name for s in scenes], all_specs))
        all_specs, more = _specs_of(scenes, specs, lambda s: start_with_map(s, by_spec[s.name]))
        refused.update(more)
        scenes, all_specs = _runnable(scenes, all_specs)
        if refused and log:
            log(f"{len(refused)} of {len(all_scenes)} cases have no start state and are recorded as failed: "
                + "; ".join(refused.values()))
        preparation_s = time.perf_counter() - t0
        kept = _kept_records(out, grid_names, names)
        cases, reused = _cases(scenes, all_specs, out, skip_existing=skip_existing, backend=backend, fmu_dir=fmu_dir,
                               plots=plots, fmu_paths=fmu_paths, force=force)
        if skip_existing and log:
            log(f"resume: {len(reused)} of {len(scenes)} runs reused (finished, same fingerprint), {len(cases)} to run")
        manifest = _Manifest(out, scenes={s.name: s for s in all_scenes},
                             order={n: i for i, n in enumerate(grid_names or names)},
                             meta={"executor": _executor_name(address, executor), "backend": backend, "code_commit": code_commit(),
                                   "preparation_s": preparation_s, "reused_runs": len(reused),
                                   # where the scenes came from (the dataset card names them)
                                   "scene_files": sorted({str(s.source) for s in all_scenes if s.source}),
                                   "overrides": list(dict.fromkeys(o for s in all_scenes for o in s.overrides))},
                             kept=kept, t0=t0)
        manifest.runs = [manifest.annotate(r) for r in reused + _start_failures(refused, all_scenes, out)]
        _start_journal(out, kept + manifest.runs)
        manifest.write(not cases)
        if cases:
            client = None
            own = executor is None
            if own:
                executor, client = _executor(workers, address)
            interrupted = True
            try:
                _run_cases(cases, manifest, executor, progress)
                interrupted = False
            finally:
                if own:
                    _shut_down(executor, interrupted)
                if client is not None:
                    client.close()
        return manifest.write(True)


__all__ = ["simulate", "run_sweep", "make_case", "prepare_caches", "read_runs"]
