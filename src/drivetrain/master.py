"""Co-simulation master: fixed-step Jacobi coupling of FMI 2.0 co-simulation FMUs on ``fmpy.fmi2.FMU2Slave``.

What it does, in order (see ``docs/MASTER.md``):

1. **Resolve FMUs** for the models in the :class:`~drivetrain.system.SystemSpec` (``fmus/<Model>.fmu``).
   A missing FMU, or one built from other package sources than the current ones (a SHA-256 of the
   package sources, recorded per model in ``<fmu_dir>/.sources-hash.json``), is (re)built with
   ``drivetrain.fmubuild.build_all`` under a file lock.
2. **Check** everything from the model descriptions, before instantiating: every connection joins a
   spring-side port (inputs ``phi``, ``w``; output ``tau``) to an inertia-side port (input ``tau``;
   outputs ``phi``, ``w``) with identical, expected units (rad, rad/s, N.m); parameters exist, are
   settable and have the right type; every input is fed at most once; recorded variables exist; the
   communication step H divides the output period. All problems are raised together as
   :class:`ConfigurationError` naming both ports.
3. **Instantiate** exactly the components of the spec (nothing else): ``fmpy.extract`` once per FMU
   file and process, ``FMU2Slave`` per component, ``instantiate`` (log captured per instance),
   ``setupExperiment``, parameters set by value reference with their types, constant inputs,
   ``enterInitializationMode``, two exchange sweeps of the flange values, ``exitInitializationMode``.
4. **Step** with fixed H, Jacobi: all inputs are gathered from the outputs of the previous
   communication point with one ``numpy.take`` into a preallocated buffer; then per FMU one batched
   ``fmi2SetReal`` (preallocated value-reference array), ``fmi2DoStep``, one batched ``fmi2GetReal``
   (raw ctypes calls, no per-step allocation). Every output is recorded at the internal rate 1/H.
   A status >= discard from any call stops the run with :class:`CosimError` naming the FMU, the FMI
   function, the time and the FMU's log; what was computed is not lost: the error's ``partial`` is the
   :class:`CosimResult` of the completed part (``status "failed"``, ``failure``: time, FMU, function,
   cause, and every FMU's outputs read after the failure, each read guarded).
5. **Decimate** the recorded channels to the output rate (zero-phase anti-alias low-pass, see
   :mod:`drivetrain.signals`; after a failure the whole output samples before it) and run the
   **energy audit** (marked unavailable for a failed run). Variables asked for with ``final=`` (e.g.
   cumulative counters) are read once after the last step (and at a failure).
6. **Tear down** every instance (terminate unless the FMU failed fatally, freeInstance), also on errors.

The ``inprocess`` backend instantiates the same pythonfmu ``Fmi2Slave`` classes (imported from the FMU's
resources) directly in Python and calls their setters, ``do_step`` and getters in the same order with the
same exchange buffers: the same results without the FMI layer (benchmark ratio, debugging).
"""
from __future__ import annotations

import logging
import atexit
import collections
import ctypes
import functools
import hashlib
import importlib
import json
import math
import os
import re
import shutil
import sys
import tempfile
import time
import traceback
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from drivetrain.errors import FMI_STATUS, ConfigurationError, CosimError  # noqa: F401  (re-exported)
from drivetrain.system import INERTIA, SPRING, ComponentSpec, SystemSpec
from gearcontact_fmu.locks import file_lock
import drivetrain
import fmu_runtime
import gearcontact_fmu
from drivetrain.signals import decimate

#: messages for the user (progress, warnings); the CLI passes its own ``log``, a library caller sees them
#: through Python logging (on stderr when logging is not configured)
_LOG = logging.getLogger(__name__)

PORT_VARS = ("phi", "w", "tau")
PORT_UNITS = {"phi": "rad", "w": "rad/s", "tau": "N.m"}
ENERGY_VARS = ("energy_supplied", "energy_stored", "energy_dissipated")
#: smallest reference energy of the audit's relative residual [J]: 1 mJ, ~1e-5 of what the rig stores at speed (~100 J)
ENERGY_FLOOR_J = 1e-3
_UNIT_SYNONYMS = {"N·m": "N.m", "Nm": "N.m", "N*m": "N.m", "N m": "N.m", "rad.s-1": "rad/s", "1/s": "1/s"}

#: Modules of the two packages that never run inside an FMU (excluded from the staleness hash).
HOST_ONLY_MODULES = {
    "drivetrain": {"cli.py", "master.py", "run.py", "sweep.py", "outputs.py", "signals.py", "scenario.py",
                   "assemble.py", "eigen.py", "calibrate.py", "fmubuild.py", "stress.py", "expect.py",
                   "baseline.py", "check.py", "pytest_plugin.py", "dataset.py"},
    "gearcontact_fmu": set(),
}



# --------------------------------------------------------------------------------------------------
# Model descriptions, extraction and building (per-process caches)
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class VarInfo:
    name: str
    vr: int
    type: str                 # Real | Integer | Boolean | String | Enumeration
    causality: str
    variability: str
    unit: str | None
    initial: str | None


@dataclass
class FMUInfo:
    model: str
    path: Path
    guid: str
    model_identifier: str
    variables: dict[str, VarInfo]
    description: Any = None


_INFO_CACHE: dict[tuple[str, float], FMUInfo] = {}
_EXTRACT_CACHE: dict[tuple[str, float], str] = {}
_EXTRACT_ROOT: list[str] = []


def _norm_unit(u: str | None) -> str | None:
    return _UNIT_SYNONYMS.get(u, u) if u else u


def load_fmu_info(path: Path | str) -> FMUInfo:
    """Model description of an FMU (cached per file and modification time)."""
    import fmpy

    path = Path(path).resolve()
    key = (str(path), path.stat().st_mtime)
    info = _INFO_CACHE.get(key)
    if info is None:
        md = fmpy.read_model_description(str(path), validate=False)
        if md.coSimulation is None:
            raise ConfigurationError(f"{path.name}: not a co-simulation FMU")
        variables = {}
        for v in md.modelVariables:
            unit = v.unit
            if unit is None and v.declaredType is not None:
                unit = getattr(v.declaredType, "unit", None)
            variables[v.name] = VarInfo(v.name, v.valueReference, v.type, v.causality, v.variability,
                                        _norm_unit(unit), v.initial)
        info = FMUInfo(md.modelName, path, md.guid, md.coSimulation.modelIdentifier, variables, md)
        _INFO_CACHE[key] = info
    return info


def _cleanup_extracted() -> None:
    for d in _EXTRACT_ROOT:
        shutil.rmtree(d, ignore_errors=True)


def _extract_root() -> str:
    """A private directory for extracted FMUs whose path has no ``%``: pythonfmu 0.7.0's export library
    crashes the process in fmi2Instantiate when the resource path contains one (it is used as a printf
    format; measured: segmentation fault with TMPDIR=/tmp/a%n). The system temporary directory is used
    unless its path has a ``%``; then the user cache directory, then /tmp."""
    candidates = [None, os.path.join(os.path.expanduser("~"), ".cache", "drivetrain"), "/tmp"]
    for base in candidates:
        root = base if base is not None else tempfile.gettempdir()
        if "%" in os.path.abspath(root):
            continue
        try:
            os.makedirs(root, exist_ok=True)
            d = tempfile.mkdtemp(prefix="drivetrain_fmus_", dir=root)
        except OSError:
            continue
        if "%" not in d:
            return d
    raise ConfigurationError("no directory without '%' in its path to extract the FMUs into (pythonfmu "
                             "crashes on such resource paths); set TMPDIR to one")


def extracted_dir(path: Path | str) -> str:
    """``fmpy.extract`` once per FMU file (and modification time) per process."""
    import fmpy

    path = Path(path).resolve()
    key = (str(path), path.stat().st_mtime)
    d = _EXTRACT_CACHE.get(key)
    if d is None or not os.path.isdir(d):
        if not _EXTRACT_ROOT:
            _EXTRACT_ROOT.append(_extract_root())
            atexit.register(_cleanup_extracted)
        target = os.path.join(_EXTRACT_ROOT[0], f"{path.stem}_{len(_EXTRACT_CACHE)}")
        d = fmpy.extract(str(path), unzipdir=target)
        _EXTRACT_CACHE[key] = d
    return d


def _package_dirs() -> dict[str, Path]:

    return {"drivetrain": Path(drivetrain.__file__).parent, "gearcontact_fmu": Path(gearcontact_fmu.__file__).parent,
            "fmu_runtime": Path(fmu_runtime.__file__).parent}


@functools.lru_cache(maxsize=1)
def _sources_hash_cached(stamp: tuple) -> str:
    h = hashlib.sha256()
    for pkg, d in sorted(_package_dirs().items()):
        for f in sorted(d.rglob("*.py")):
            rel = f.relative_to(d)
            if len(rel.parts) == 1 and rel.name in HOST_ONLY_MODULES.get(pkg, ()):
                continue
            if "__pycache__" in rel.parts:
                continue
            h.update(f"{pkg}/{rel.as_posix()}\0".encode())
            h.update(f.read_bytes())
            h.update(b"\0")
    return h.hexdigest()


def sources_hash() -> str:
    """SHA-256 of the package sources that end up in (and run inside) the FMUs."""
    stamp = []
    for pkg, d in sorted(_package_dirs().items()):
        for f in sorted(d.rglob("*.py")):
            st = f.stat()
            stamp.append((str(f), st.st_mtime_ns, st.st_size))
    return _sources_hash_cached(tuple(stamp))


STAMP_FILE = ".sources-hash.json"
_CHECKED: dict[str, set] = {}     # fmu_dir -> models found fresh (or built) in this process


def _read_stamp(fmu_dir: Path) -> dict:
    try:
        return json.loads((fmu_dir / STAMP_FILE).read_text())
    except (OSError, ValueError):
        return {}


def stale_models(models: Sequence[str], fmu_dir: Path | str) -> list[str]:
    """Models whose FMU is missing in fmu_dir or was built from other package sources."""
    fmu_dir = Path(fmu_dir)
    current = sources_hash()
    stamp = _read_stamp(fmu_dir)
    return [m for m in dict.fromkeys(models)
            if not (fmu_dir / f"{m}.fmu").is_file() or stamp.get(m) != current]


def ensure_fmus(models: Sequence[str], fmu_dir: Path | str = "fmus", build: bool = True,
                log: Callable[[str], None] | None = None) -> dict[str, Path]:
    """Paths of the FMUs of ``models``, building missing or stale ones with ``build_all``."""
    fmu_dir = Path(fmu_dir)
    models = list(dict.fromkeys(models))
    if build:
        # checked once per process and directory: the package code this process runs (FMUs use the
        # installed packages in a Python host) does not change under it, so neither should its FMUs
        key = str(fmu_dir.resolve())
        fresh = _CHECKED.setdefault(key, set())
        todo_check = [m for m in models if m not in fresh or not (fmu_dir / f"{m}.fmu").is_file()]
    if build and todo_check:
        with file_lock(fmu_dir / ".build.lock"):
            todo = stale_models(todo_check, fmu_dir)
            if todo:
                current = sources_hash()
                try:
                    from drivetrain.fmubuild import build_all
                except ImportError as exc:
                    missing = [m for m in todo if not (fmu_dir / f"{m}.fmu").is_file()]
                    if missing:
                        raise ConfigurationError(
                            [f"FMU {fmu_dir / (m + '.fmu')} is missing and cannot be built "
                             f"(drivetrain.fmubuild unavailable: {exc})" for m in missing]) from None
                    if log:
                        log(f"FMUs {todo} may be stale; cannot rebuild ({exc}); using them as they are")
                else:
                    if log:
                        log(f"building FMUs {todo} into {fmu_dir} (missing or built from other sources)")
                    build_all(str(fmu_dir), only=todo)
                    stamp = _read_stamp(fmu_dir)
                    stamp.update({m: current for m in todo if (fmu_dir / f"{m}.fmu").is_file()})
                    tmp = fmu_dir / (STAMP_FILE + f".{os.getpid()}")
                    tmp.write_text(json.dumps(stamp, indent=1, sort_keys=True))
                    os.replace(tmp, fmu_dir / STAMP_FILE)
            fresh.update(m for m in todo_check if (fmu_dir / f"{m}.fmu").is_file())
    paths = {}
    missing = []
    for m in models:
        p = fmu_dir / f"{m}.fmu"
        if p.is_file():
            paths[m] = p.resolve()
        else:
            missing.append(f"FMU for model {m!r} not found: {p}")
    if missing:
        raise ConfigurationError(missing)
    return paths


# --------------------------------------------------------------------------------------------------
# Checking the system against the model descriptions
# --------------------------------------------------------------------------------------------------


def _split(ref: str) -> tuple[str, str]:
    comp, _, rest = ref.partition(".")
    return comp, rest


def _type_ok(vtype: str, value) -> str | None:
    """None if value fits the FMI type, else what was expected."""
    if vtype == "Real":
        return None if isinstance(value, (int, float)) and not isinstance(value, bool) else "a real number"
    if vtype in ("Integer", "Enumeration"):
        return None if isinstance(value, (int, np.integer)) and not isinstance(value, bool) else "an integer"
    if vtype == "Boolean":
        return None if isinstance(value, (bool, np.bool_)) else "a boolean"
    if vtype == "String":
        return None if isinstance(value, (str, os.PathLike)) else "a string"
    return f"a supported type (not {vtype})"


def _is_profile(value) -> bool:
    return (isinstance(value, (list, tuple)) and len(value) > 0
            and all(isinstance(p, (list, tuple)) and len(p) == 2 for p in value))


@dataclass
class _Plan:
    comps: list[ComponentSpec]
    infos: list[FMUInfo]
    in_names: list[list[str]]          # per component: Real inputs set every step (connected or profiles)
    out_names: list[list[str]]         # per component: Real variables read every step
    gather: np.ndarray                 # u = y[gather]
    ext: list[tuple[int, Any]]         # (y index of the external slot, profile)
    y_names: list[str]                 # "comp.var" for every y entry (ext slots: "comp.var" of the input)
    u_names: list[str]
    energy: list[dict[str, int]]       # per component: energy var -> vr
    warnings: list[str]
    conn_index: list[tuple[int, int, int, int, int]]  # per connection: (ci_spring, ci_inertia, y_tau, y_phi, y_w)
    ext_work: list = dataclasses.field(default_factory=list)  # (ci, "comp.port", tau const | None, y_tau | None, y_phi)


def check_system(spec: SystemSpec, infos: dict[str, FMUInfo], record: Sequence[str] = ()) -> _Plan:
    """Validate the spec against the model descriptions; raise ConfigurationError listing every problem."""
    problems: list[str] = []
    warnings: list[str] = []
    names = [c.name for c in spec.components]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        problems.append(f"component names are not unique: {', '.join(dup)}")
    comps = {c.name: c for c in spec.components}
    for c in spec.components:
        if c.model not in infos:
            problems.append(f"component {c.name!r}: no FMU for model {c.model!r}")
    if problems:
        raise ConfigurationError(problems)
    var = {c.name: infos[c.model].variables for c in spec.components}

    # parameters and constant/profile inputs
    for c in spec.components:
        for pname, value in c.parameters.items():
            v = var[c.name].get(pname)
            if v is None:
                problems.append(f"{c.name}.{pname}: no such variable in {c.model} (parameters: "
                                + ", ".join(n for n, x in var[c.name].items() if x.causality == "parameter") + ")")
                continue
            if v.causality != "parameter" or v.variability == "constant":
                problems.append(f"{c.name}.{pname}: not a settable parameter (causality {v.causality}, "
                                f"variability {v.variability})")
                continue
            exp = _type_ok(v.type, value)
            if exp:
                problems.append(f"{c.name}.{pname} = {value!r}: expected {exp} (FMI type {v.type})")
        for iname, value in c.inputs.items():
            v = var[c.name].get(iname)
            if v is None or v.causality != "input":
                problems.append(f"{c.name}.{iname}: not an input of {c.model}")
                continue
            if _is_profile(value):
                if v.type != "Real":
                    problems.append(f"{c.name}.{iname}: a time profile needs a Real input (is {v.type})")
                else:
                    ts = [float(p[0]) for p in value]
                    if any(b <= a for a, b in zip(ts, ts[1:])):
                        problems.append(f"{c.name}.{iname}: profile times must increase strictly")
            else:
                exp = _type_ok(v.type, value)
                if exp:
                    problems.append(f"{c.name}.{iname} = {value!r}: expected {exp} (FMI type {v.type})")

    # connections
    fed: dict[str, str] = {}
    conn_vars = []
    for conn in spec.connections:
        sc, sp = _split(conn.spring)
        ic, ip = _split(conn.inertia)
        label = f"connection spring={conn.spring} <-> inertia={conn.inertia}"
        bad = False
        for ref, comp in ((conn.spring, sc), (conn.inertia, ic)):
            if comp not in comps:
                problems.append(f"{label}: component {comp!r} of {ref} is not in the system "
                                f"(components: {', '.join(names)})")
                bad = True
        if bad:
            continue
        for side, comp, port, want_in, want_out in ((SPRING, sc, sp, ("phi", "w"), ("tau",)),
                                                    (INERTIA, ic, ip, ("tau",), ("phi", "w"))):
            for q in PORT_VARS:
                vn = f"{port}_{q}"
                v = var[comp].get(vn)
                if v is None:
                    problems.append(f"{label}: {comp}.{port} is not a flange of {comps[comp].model} "
                                    f"(no variable {vn})")
                    bad = True
                    continue
                need = "input" if q in want_in else "output"
                if v.causality != need:
                    other = conn.inertia if side == SPRING else conn.spring
                    problems.append(
                        f"{label}: wrong causality: {comp}.{port} is not a {side}-side port "
                        f"({vn} is {v.causality}, a {side}-side port needs {vn} as {need}); "
                        f"it cannot be joined to {other}")
                    bad = True
                if v.type != "Real":
                    problems.append(f"{label}: {comp}.{vn} is {v.type}, expected Real")
                    bad = True
        if bad:
            continue
        for q in PORT_VARS:
            us = var[sc][f"{sp}_{q}"].unit
            ui = var[ic][f"{ip}_{q}"].unit
            exp = PORT_UNITS[q]
            if us != ui or us != exp:
                problems.append(f"{label}: unit mismatch: {conn.spring}_{q} [{us or 'no unit'}] vs "
                                f"{conn.inertia}_{q} [{ui or 'no unit'}], expected {exp} on both")
                bad = True
        for tgt, src in ((f"{sc}.{sp}_phi", f"{ic}.{ip}_phi"), (f"{sc}.{sp}_w", f"{ic}.{ip}_w"),
                         (f"{ic}.{ip}_tau", f"{sc}.{sp}_tau")):
            if tgt in fed:
                problems.append(f"{label}: input {tgt} is already fed by {fed[tgt]}")
                bad = True
            fed[tgt] = src
        if not bad:
            conn_vars.append((sc, sp, ic, ip))
    for c in spec.components:
        for iname, value in c.inputs.items():
            ref = f"{c.name}.{iname}"
            if ref in fed:
                problems.append(f"{ref}: given as a component input and also fed by connection from {fed[ref]}")

    # recorded variables
    for ref in record:
        comp, vn = _split(ref)
        if comp not in comps:
            problems.append(f"recorded variable {ref}: no component {comp!r} in the system "
                            f"(components: {', '.join(names)})")
        elif vn not in var[comp]:
            problems.append(f"recorded variable {ref}: {comps[comp].model} has no variable {vn!r}")
        elif var[comp][vn].type != "Real":
            problems.append(f"recorded variable {ref}: is {var[comp][vn].type}; only Real variables are recorded")

    if problems:
        raise ConfigurationError(problems)

    # unconnected flanges (allowed: a free end / a clamped spring; reported)
    for c in spec.components:
        vs = var[c.name]
        ports = {n[:-4] for n in vs if n.endswith("_tau") and f"{n[:-4]}_phi" in vs and f"{n[:-4]}_w" in vs}
        for p in sorted(ports):
            if not any(f"{c.name}.{p}_{q}" in fed or f"{c.name}.{p}_{q}" in fed.values() for q in PORT_VARS):
                warnings.append(f"flange {c.name}.{p} is not connected")

    # ---- layout of the exchange buffers ---------------------------------------------------------
    in_names = [[] for _ in spec.components]
    out_names = [[] for _ in spec.components]
    idx = {c.name: i for i, c in enumerate(spec.components)}

    def want_out(ref):
        comp, vn = _split(ref)
        lst = out_names[idx[comp]]
        if vn not in lst:
            lst.append(vn)

    for sc, sp, ic, ip in conn_vars:
        want_out(f"{sc}.{sp}_tau")
        want_out(f"{ic}.{ip}_phi")
        want_out(f"{ic}.{ip}_w")
    for ref in record:
        want_out(ref)
    # torques applied from outside (constant or profile inputs) on unconnected inertia-side flanges:
    # their work enters the energy audit as external work
    ext_torques = []
    for c in spec.components:
        for iname, value in c.inputs.items():
            port = iname[:-4] if iname.endswith("_tau") else None
            v_phi = var[c.name].get(f"{port}_phi") if port else None
            if v_phi is not None and v_phi.causality == "output" and v_phi.type == "Real":
                want_out(f"{c.name}.{port}_phi")
                ext_torques.append((c.name, port, iname, value))
    for tgt in fed:
        comp, vn = _split(tgt)
        in_names[idx[comp]].append(vn)
    profiles = []
    for c in spec.components:
        for iname, value in c.inputs.items():
            if _is_profile(value):
                in_names[idx[c.name]].append(iname)
                profiles.append((f"{c.name}.{iname}", value))

    y_names = [f"{c.name}.{n}" for c, outs in zip(spec.components, out_names) for n in outs]
    ypos = {n: i for i, n in enumerate(y_names)}
    ext = []
    for ref, prof in profiles:
        ypos[f"ext:{ref}"] = len(y_names)
        ext.append((len(y_names), prof))
        y_names.append(f"ext:{ref}")
    u_names = [f"{c.name}.{n}" for c, ins in zip(spec.components, in_names) for n in ins]
    gather = np.array([ypos[fed[u]] if u in fed else ypos[f"ext:{u}"] for u in u_names], dtype=np.intp)

    energy = []
    for c in spec.components:
        energy.append({e: var[c.name][e].vr for e in ENERGY_VARS if e in var[c.name]})
    conn_index = [(idx[sc], idx[ic], ypos[f"{sc}.{sp}_tau"], ypos[f"{ic}.{ip}_phi"], ypos[f"{ic}.{ip}_w"])
                  for sc, sp, ic, ip in conn_vars]
    ext_work = []
    for cname, port, iname, value in ext_torques:
        if _is_profile(value):
            ext_work.append((idx[cname], f"{cname}.{port}", None, ypos[f"ext:{cname}.{iname}"],
                             ypos[f"{cname}.{port}_phi"]))
        else:
            ext_work.append((idx[cname], f"{cname}.{port}", float(value), None, ypos[f"{cname}.{port}_phi"]))
    return _Plan(list(spec.components), [infos[c.model] for c in spec.components], in_names, out_names,
                 gather, ext, y_names, u_names, energy, warnings, conn_index, ext_work)


def check_comm_step(comm_step: float, output_rate_Hz: float) -> int:
    """Steps per output sample; ConfigurationError unless H divides the output period."""
    if not (comm_step > 0 and math.isfinite(comm_step)):
        raise ConfigurationError(f"communication step H = {comm_step!r} s: expected a positive finite step")
    period = 1.0 / output_rate_Hz
    r = period / comm_step
    n = round(r)
    if n < 1 or abs(r - n) > 1e-6 * r:
        m = max(1, math.ceil(r - 1e-9))
        raise ConfigurationError(
            f"communication step H = {comm_step:.10g} s does not divide the output period 1/{output_rate_Hz:g} Hz "
            f"= {period:.10g} s (period/H = {r:.8g}); use e.g. H = {period / m:.16g} (period/{m})")
    return int(n)


# --------------------------------------------------------------------------------------------------
# Slave adapters: the same four calls for both backends
# --------------------------------------------------------------------------------------------------


class _Log:
    """Per-instance log buffer, filled by the FMI logger callback or the in-process log queue."""

    def __init__(self, maxlen: int = 500):
        self.lines: collections.deque[str] = collections.deque(maxlen=maxlen)
        self.n_warnings = 0

    def add(self, status: int, category: str, message: str) -> None:
        st = FMI_STATUS[status] if 0 <= status < len(FMI_STATUS) else str(status)
        if status >= 1:
            self.n_warnings += 1
        self.lines.append(f"[{st}] {category + ': ' if category else ''}{message}")


class _FmiCallbacks:
    """One fmi2CallbackFunctions struct for all instances; routes log messages by instance name."""

    def __init__(self):
        from fmpy import calloc, free
        from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2StepFinishedTYPE)

        self.logs: dict[str, _Log] = {}
        self._cb = fmi2CallbackFunctions()
        self._logger = fmi2CallbackLoggerTYPE(self._log)
        self._cb.logger = self._logger
        self._cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self._cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._cb.stepFinished = fmi2StepFinishedTYPE()
        try:
            from fmpy.logging import addLoggerProxy

            addLoggerProxy(ctypes.byref(self._cb))   # formats printf-style messages in C
        except Exception:  # pragma: no cover
            pass

    def _log(self, env, instance, status, category, message):
        name = instance.decode("utf-8", "replace") if instance else "?"
        log = self.logs.setdefault(name, _Log())
        log.add(int(status), category.decode("utf-8", "replace") if category else "",
                message.decode("utf-8", "replace") if message else "")

    @property
    def struct(self):
        return self._cb


class _Slave:
    """Common interface: ``set_fn() -> status``, ``step_fn(t, H, 1) -> status``, ``get_fn() -> status``."""

    name: str
    model: str
    log: _Log
    initialized: bool = False
    fatal: bool = False

    def set_parameters(self, params: dict) -> None: ...
    def set_values(self, names: list[str], values: list) -> None: ...
    def get_reals(self, names: list[str]) -> list[float]: ...
    def setup(self, stop_time: float) -> None: ...
    def enter_init(self) -> None: ...
    def exit_init(self) -> None: ...
    def teardown(self) -> None: ...


class _FmiSlave(_Slave):
    def __init__(self, comp: ComponentSpec, info: FMUInfo, callbacks: _FmiCallbacks):
        from fmpy.fmi2 import FMU2Slave

        self.name, self.model, self.info = comp.name, comp.model, info
        self.log = callbacks.logs.setdefault(comp.name, _Log())
        unzip = extracted_dir(info.path)
        self.fmu = FMU2Slave(guid=info.guid, unzipDirectory=unzip, modelIdentifier=info.model_identifier,
                             instanceName=comp.name)
        self.instantiated = False
        self._callbacks = callbacks
        self.fmu.instantiate(visible=False, callbacks=callbacks.struct, loggingOn=True)
        self.instantiated = True
        self.c = self.fmu.component
        f = self.fmu._functions
        self._sr, self._ds, self._gr = f["fmi2SetReal"], f["fmi2DoStep"], f["fmi2GetReal"]

    def _call(self, what: str, fn, *args, t: float = 0.0):
        try:
            return fn(*args)
        except Exception as exc:   # fmpy raises FMICallException for status > warning
            status = getattr(exc, "status", 3)
            if status >= 4:
                self.fatal = True
            raise CosimError(self.name, self.model, what, status, t, list(self.log.lines)) from None

    def setup(self, stop_time):
        self._call("fmi2SetupExperiment", self.fmu.setupExperiment, None, 0.0, stop_time)

    def set_parameters(self, params):
        by_type: dict[str, tuple[list, list]] = {}
        for n, v in params.items():
            vi = self.info.variables[n]
            by_type.setdefault(vi.type, ([], []))
            by_type[vi.type][0].append(vi.vr)
            by_type[vi.type][1].append(v)
        for typ, (vrs, vals) in by_type.items():
            if typ == "Real":
                self._call("fmi2SetReal", self.fmu.setReal, vrs, [float(v) for v in vals])
            elif typ in ("Integer", "Enumeration"):
                self._call("fmi2SetInteger", self.fmu.setInteger, vrs, [int(v) for v in vals])
            elif typ == "Boolean":
                self._call("fmi2SetBoolean", self.fmu.setBoolean, vrs, [bool(v) for v in vals])
            elif typ == "String":
                self._call("fmi2SetString", self.fmu.setString, vrs, [os.fspath(v) for v in vals])

    set_values = lambda self, names, values: self.set_parameters(dict(zip(names, values)))  # noqa: E731

    def get_reals(self, names):
        return self._call("fmi2GetReal", self.fmu.getReal, [self.info.variables[n].vr for n in names])

    def enter_init(self):
        self._call("fmi2EnterInitializationMode", self.fmu.enterInitializationMode)
        self.initialized = True

    def exit_init(self):
        self._call("fmi2ExitInitializationMode", self.fmu.exitInitializationMode)

    def bind(self, in_names, out_names, u: np.ndarray, u_off: int, y: np.ndarray, y_off: int):
        """Raw per-step calls on preallocated buffers (no allocation, no Python-level conversion)."""
        dp = ctypes.POINTER(ctypes.c_double)
        n_in, n_out = len(in_names), len(out_names)
        self._vin = (ctypes.c_uint * max(n_in, 1))(*[self.info.variables[n].vr for n in in_names])
        self._vout = (ctypes.c_uint * max(n_out, 1))(*[self.info.variables[n].vr for n in out_names])
        uptr = ctypes.cast(u.ctypes.data + 8 * u_off, dp)
        yptr = ctypes.cast(y.ctypes.data + 8 * y_off, dp)
        self.set_fn = functools.partial(self._sr, self.c, self._vin, n_in, uptr) if n_in else None
        self.step_fn = functools.partial(self._ds, self.c)
        self.get_fn = functools.partial(self._gr, self.c, self._vout, n_out, yptr) if n_out else None

    def teardown(self):
        errors = []
        if self.instantiated:
            if self.initialized and not self.fatal:
                try:
                    self.fmu.terminate()
                except Exception as exc:
                    errors.append(f"terminate: {exc}")
            if self.fatal:
                # pythonfmu 0.7.0: freeing an instance after a fatal error (a Python exception inside the
                # FMU) corrupts the interpreter and crashes the process at a later garbage collection.
                # The broken instance is never called again; it is kept alive and not freed.
                _LEAKED.append((self.fmu, self._callbacks))
                self.instantiated = False
                errors.append("instance not freed after a fatal error (pythonfmu would crash the process)")
                return errors
            try:
                # fmi2FreeInstance only: fmpy's freeInstance() also dlclose()s the shared library, and a
                # pythonfmu library unloaded while Python objects it created are still alive crashes the
                # process at the next garbage collection. Libraries stay loaded for the process.
                self.fmu.fmi2FreeInstance(self.c)
            except Exception as exc:
                errors.append(f"freeInstance: {exc}")
            self.instantiated = False
        return errors


_SLAVE_CLASS_CACHE: dict[str, type] = {}
_LEAKED: list = []     # instances deliberately not freed (see _FmiSlave.teardown)


def load_slave_class(info: FMUInfo) -> type:
    """The pythonfmu Fmi2Slave subclass inside an FMU (imported from its extracted resources)."""
    key = str(info.path)
    cls = _SLAVE_CLASS_CACHE.get(key)
    if cls is not None:
        return cls
    res = Path(extracted_dir(info.path)) / "resources"
    modname = (res / "slavemodule.txt").read_text().strip()
    if str(res) not in sys.path:
        sys.path.insert(0, str(res))
    mod = sys.modules.get(modname)
    if mod is None:
        mod = importlib.import_module(modname)
    cls = getattr(mod, info.model_identifier, None)
    if cls is None:
        from pythonfmu import Fmi2Slave

        cands = [v for v in vars(mod).values() if isinstance(v, type) and issubclass(v, Fmi2Slave)
                 and v is not Fmi2Slave and v.__module__ == mod.__name__]
        if len(cands) != 1:
            raise ConfigurationError(f"{info.path.name}: cannot find the slave class in module {modname}")
        cls = cands[0]
    _SLAVE_CLASS_CACHE[key] = cls
    return cls


class _InprocSlave(_Slave):
    """The pythonfmu slave object stepped directly: setters, do_step, getters (no FMI layer)."""

    def __init__(self, comp: ComponentSpec, info: FMUInfo):
        self.name, self.model, self.info = comp.name, comp.model, info
        self.log = _Log()
        cls = load_slave_class(info)
        res = Path(extracted_dir(info.path)) / "resources"
        self.time = 0.0
        self.obj = self._guard("instantiate", lambda: cls(instance_name=comp.name, resources=str(res),
                                                         visible=False))
        self._vars = self.obj.vars   # vr -> ScalarVariable

    def _drain_log(self):
        q = getattr(self.obj, "log_queue", None) if hasattr(self, "obj") else None
        if q:
            for m in q:
                # the slaves double every "%" for the FMI logger's printf format (fmu_runtime.guard.fmi_text)
                self.log.add(int(getattr(m.status, "value", m.status)), m.category or "",
                             str(m.msg).replace("%%", "%"))
            q.clear()

    def _guard(self, what, fn, status_on_false: int | None = None, t: float = 0.0):
        try:
            r = fn()
        except Exception as exc:
            self._drain_log()
            self.log.add(4, "", f"Python exception in {what}: {exc!r}\n{traceback.format_exc(limit=5)}")
            self.fatal = True
            raise CosimError(self.name, self.model, what, 4, t, list(self.log.lines)) from None
        self._drain_log()
        if status_on_false is not None and r is False:
            raise CosimError(self.name, self.model, what, status_on_false, t, list(self.log.lines))
        return r

    def _vr(self, n):
        return self.info.variables[n].vr

    def setup(self, stop_time):
        self._guard("setup_experiment", lambda: self.obj.setup_experiment(0.0, stop_time, None))

    def set_parameters(self, params):
        def do():
            for n, v in params.items():
                vi = self.info.variables[n]
                if vi.type == "Real":
                    self.obj.set_real([vi.vr], [float(v)])
                elif vi.type in ("Integer", "Enumeration"):
                    self.obj.set_integer([vi.vr], [int(v)])
                elif vi.type == "Boolean":
                    self.obj.set_boolean([vi.vr], [bool(v)])
                else:
                    self.obj.set_string([vi.vr], [os.fspath(v)])
        self._guard("set parameters", do)

    set_values = lambda self, names, values: self.set_parameters(dict(zip(names, values)))  # noqa: E731

    def get_reals(self, names):
        return self._guard("get_real", lambda: self.obj.get_real([self._vr(n) for n in names]))

    def enter_init(self):
        self._guard("enter_initialization_mode", self.obj.enter_initialization_mode)
        self.initialized = True

    def exit_init(self):
        self._guard("exit_initialization_mode", self.obj.exit_initialization_mode)

    def bind(self, in_names, out_names, u: np.ndarray, u_off: int, y: np.ndarray, y_off: int):
        setters = [self._vars[self._vr(n)].setter for n in in_names]
        getters = [self._vars[self._vr(n)].getter for n in out_names]
        n_in, n_out = len(in_names), len(out_names)
        u_view = u[u_off:u_off + n_in]
        y_view = y[y_off:y_off + n_out]
        obj = self.obj

        def set_fn():
            for s, v in zip(setters, u_view.tolist()):
                s(v)
            return 0

        def step_fn(t, h, _flag):
            try:
                ok = obj.do_step(t, h)
            except Exception as exc:
                self._drain_log()
                self.log.add(4, "", f"Python exception in do_step: {exc!r}\n{traceback.format_exc(limit=5)}")
                self.fatal = True
                return 4
            if obj.log_queue:
                self._drain_log()
            return 0 if ok else 2     # pythonfmu: do_step returning False -> fmi2Discard

        def get_fn():
            y_view[:] = [float(g()) for g in getters]
            return 0

        self.set_fn = set_fn if n_in else None
        self.step_fn = step_fn
        self.get_fn = get_fn if n_out else None

    def teardown(self):
        errors = []
        if hasattr(self, "obj") and self.initialized and not self.fatal:
            try:
                self.obj.terminate()
            except Exception as exc:
                errors.append(f"terminate: {exc}")
        return errors


# --------------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------------


@dataclass
class CosimResult:
    """Output of :meth:`Master.run`."""

    time: np.ndarray                       # output-rate sample times [s], from 0
    signals: dict[str, np.ndarray]         # "component.variable" -> samples at the output rate
    units: dict[str, str | None]           # "component.variable" -> unit from the model description
    output_rate_Hz: float
    comm_step_s: float
    steps_per_output: int
    n_steps: int
    sim_time_s: float
    wall_time_s: float                     # setup + loop + post-processing
    loop_time_s: float                     # the stepping loop only
    us_per_step: float                     # loop_time_s / n_steps
    us_per_step_steady: float              # median over chunks of 4096 steps, first chunk (JIT warm-up) excluded
    real_time_factor: float                # sim_time_s / loop_time_s: the co-simulation loop (setup apart)
    backend: str
    energy: dict                           # the energy audit (see energy_audit)
    fmus: list[dict]                       # [{name, model, path, parameters}]
    warnings: list[str]
    logs: dict[str, list[str]]             # per component: its log lines (last 500)
    raw: dict[str, np.ndarray] | None = None   # internal-rate records if requested ("time" + y names)
    status: str = "ok"                     # "ok" | "failed" (then: the completed part only)
    setup_time_s: float = 0.0              # checks + FMU loading + instantiation + initialisation (map builds)
    failure: dict | None = None            # time_s, component, model, function, status, cause, log,
    #                                        steps_completed, last_sample_time_s, outputs {comp: {var: v}}
    final: dict[str, float] = dataclasses.field(default_factory=dict)   # Master.run(final=...) values
    snapshots: dict[float, dict[str, float]] = dataclasses.field(default_factory=dict)  # time -> values


def failure_cause(exc: CosimError) -> str:
    """The FMU's own words for a failure: the last error/fatal line of its log (first line of it, without
    the status prefix), else its last log line, else what the master saw."""
    lines = [str(x) for x in exc.log]
    pick = next((x for x in reversed(lines) if x.startswith(("[error]", "[fatal]"))), None)
    if pick is None and lines:
        pick = lines[-1]
    if pick:
        text = pick.split("\nTraceback", 1)[0]               # the message, not the frames
        if text.startswith("[") and "] " in text:
            text = text.split("] ", 1)[1]                    # status prefix
        text = re.sub(r"^log\w*: ", "", text)                 # pythonfmu's category (logStatusError: ...)
        text = " ".join(x.strip() for x in text.splitlines() if x.strip())
        return text[:1000]
    st = FMI_STATUS[exc.status] if 0 <= exc.status < len(FMI_STATUS) else str(exc.status)
    return f"{exc.function} returned {st} (the FMU logged nothing)"


def _real_outputs(info: FMUInfo) -> list[str]:
    return [n for n, v in info.variables.items() if v.causality == "output" and v.type == "Real"]


def _readable(plan: _Plan, names: Sequence[str]) -> list[str]:
    """The "component.variable" names (Real) that exist in the plan's FMUs."""
    infos = {c.name: info for c, info in zip(plan.comps, plan.infos)}
    out = []
    for ref in dict.fromkeys(names):
        comp, vn = _split(ref)
        v = infos[comp].variables.get(vn) if comp in infos else None
        if v is not None and v.type == "Real":
            out.append(ref)
    return out


def _read_guarded(slave: _Slave, names: Sequence[str]) -> dict[str, float] | None:
    """{name: value} read from one FMU, or None when it cannot answer (failed fatally, refuses, raises)."""
    if not names or slave.fatal:
        return None
    try:
        return {n: float(v) for n, v in zip(names, slave.get_reals(list(names)))}
    except Exception:  # noqa: BLE001 - reading after a failure must never mask the failure
        return None


def _read_values(slaves: Sequence[_Slave], plan: _Plan, names: Sequence[str]) -> dict[str, float]:
    """Values of "component.variable" names, one guarded read per component."""
    by_comp: dict[str, list[str]] = {}
    for ref in names:
        comp, vn = _split(ref)
        by_comp.setdefault(comp, []).append(vn)
    out = {}
    for s in slaves:
        if s.name in by_comp:
            got = _read_guarded(s, by_comp[s.name])
            for vn, v in (got or {}).items():
                out[f"{s.name}.{vn}"] = v
    return out


def energy_unavailable(reason: str) -> dict:
    """The energy audit of a run that has none (a failed run): same keys, no numbers."""
    return {"available": False, "reason": reason, "complete": False, "missing": [], "residual_J": None,
            "reference_J": None, "relative_residual": None, "supplied_J": None, "stored_change_J": None,
            "dissipated_J": None, "external_work_J": None, "worst_fmu": None, "per_fmu": {},
            "connections": [], "external": []}


def energy_audit(plan: _Plan, rec: np.ndarray, e0: list[dict], e1: list[dict]) -> dict:
    """Energy balance of the run.

    Work through connection c (from the spring-side FMU into the inertia-side FMU), with the rule of the
    inertia side under a zero-order-held torque: W_c = Σ_k τ_k (φ_{k+1} − φ_k).
    Per FMU i: r_i = supplied_i + W_in,i − Δstored_i − dissipated_i; global residual
    R = Σ supplied + W_ext − Σ Δstored − Σ dissipated = Σ r_i (connection works cancel), where W_ext is the
    work of torques given as constant/profile inputs on unconnected inertia-side flanges (same rule).
    Reference energy: the largest of the absolute work through any connection or external flange
    ∫|P|dt and any FMU's |supplied|, at least ENERGY_FLOOR_J (a run that moves no energy, e.g. a
    drivetrain held at standstill, has no meaningful relative residual: measured 0/0 = 102 %).
    """
    n = len(plan.comps)
    conns = []
    w_in = np.zeros(n)
    ref = 0.0
    for (cs, ci, yt, yp, yw), in_spec in zip(plan.conn_index, _conn_specs(plan)):
        tau = rec[:-1, yt]
        dphi = np.diff(rec[:, yp])
        p = tau * dphi
        w = float(p.sum())
        wabs = float(np.abs(p).sum())
        w_in[ci] += w
        w_in[cs] -= w
        ref = max(ref, wabs)
        conns.append({"spring": in_spec[0], "inertia": in_spec[1], "work_J": w, "abs_work_J": wabs})
    external = []
    w_ext_tot = 0.0
    for ci, port, tau_c, yt, yp in plan.ext_work:
        dphi = np.diff(rec[:, yp])
        tau = tau_c if yt is None else rec[:-1, yt]
        p = tau * dphi
        w = float(np.sum(p))
        w_in[ci] += w
        w_ext_tot += w
        ref = max(ref, float(np.abs(p).sum()))
        external.append({"port": port, "work_J": w, "abs_work_J": float(np.abs(p).sum())})
    per = {}
    tot = {"supplied_J": 0.0, "stored_change_J": 0.0, "dissipated_J": 0.0}
    missing = []
    for i, c in enumerate(plan.comps):
        have = e1[i]
        if len(have) < len(ENERGY_VARS):
            missing.append(f"{c.name}: no " + ", ".join(e for e in ENERGY_VARS if e not in have))
        sup = have.get("energy_supplied", 0.0) - e0[i].get("energy_supplied", 0.0)
        dst = have.get("energy_stored", 0.0) - e0[i].get("energy_stored", 0.0)
        dis = have.get("energy_dissipated", 0.0) - e0[i].get("energy_dissipated", 0.0)
        r = sup + w_in[i] - dst - dis
        per[c.name] = {"supplied_J": sup, "stored_change_J": dst, "dissipated_J": dis,
                       "port_work_in_J": float(w_in[i]), "residual_J": float(r),
                       "stored_start_J": e0[i].get("energy_stored", float("nan")),
                       "stored_end_J": have.get("energy_stored", float("nan"))}
        tot["supplied_J"] += sup
        tot["stored_change_J"] += dst
        tot["dissipated_J"] += dis
        ref = max(ref, abs(sup))
    resid = tot["supplied_J"] + w_ext_tot - tot["stored_change_J"] - tot["dissipated_J"]
    return {
        "available": True, "complete": not missing, "missing": missing,
        "residual_J": resid, "reference_J": ref,
        "relative_residual": abs(resid) / max(ref, ENERGY_FLOOR_J),
        **tot, "external_work_J": w_ext_tot,
        "worst_fmu": max(per, key=lambda k: abs(per[k]["residual_J"])) if per else None,
        "per_fmu": per, "connections": conns, "external": external,
        "rule": "W_c = sum_k tau_k*(phi_{k+1}-phi_k) (tau held over each step, inertia-side angle); "
                "residual = supplied + external work - delta stored - dissipated over all FMUs; "
                "reference = max(max_c sum|P_c dt|, max_i |supplied_i|, external sum|P dt|, 1 mJ)",
    }


def _conn_specs(plan: _Plan):
    out = []
    for cs, ci, yt, yp, yw in plan.conn_index:
        out.append((plan.y_names[yt].rsplit("_", 1)[0], plan.y_names[yp].rsplit("_", 1)[0]))
    return out


# --------------------------------------------------------------------------------------------------
# The master
# --------------------------------------------------------------------------------------------------


class Master:
    """Fixed-step Jacobi co-simulation of a :class:`SystemSpec`.

    Parameters
    ----------
    spec : the system (components, connections, comm_step).
    fmu_dir : where ``<Model>.fmu`` live and are built on demand (default ``fmus``).
    backend : ``"fmi"`` (fmpy FMU2Slave) or ``"inprocess"`` (the same slave classes without FMI).
    fmu_paths : explicit ``{model: path}``; these are used as they are (no building).
    build : build missing/stale FMUs with ``drivetrain.fmubuild.build_all``.
    """

    def __init__(self, spec: SystemSpec, fmu_dir: str | Path = "fmus", backend: str = "fmi",
                 fmu_paths: dict[str, str | Path] | None = None, build: bool = True,
                 log: Callable[[str], None] | None = None):
        if backend not in ("fmi", "inprocess"):
            raise ConfigurationError(f"backend {backend!r}: expected 'fmi' or 'inprocess'")
        self.spec = spec
        self.backend = backend
        self.fmu_dir = Path(fmu_dir)
        self.fmu_paths = {k: Path(v) for k, v in (fmu_paths or {}).items()}
        self.build = build
        self._log = log or (_LOG.warning)

    # -- preparation -------------------------------------------------------------------------------
    def resolve_fmus(self) -> dict[str, Path]:
        models = list(dict.fromkeys(c.model for c in self.spec.components))
        paths = {m: self.fmu_paths[m] for m in models if m in self.fmu_paths}
        rest = [m for m in models if m not in paths]
        if rest:
            paths.update(ensure_fmus(rest, self.fmu_dir, build=self.build, log=self._log))
        missing = [f"FMU for model {m!r} not found: {p}" for m, p in paths.items() if not Path(p).is_file()]
        if missing:
            raise ConfigurationError(missing)
        return paths

    def check(self, output_rate_Hz: float, record: Sequence[str] = ()) -> _Plan:
        """Everything that can be checked without instantiating; raises ConfigurationError."""
        steps = check_comm_step(self.spec.comm_step, output_rate_Hz)
        del steps
        paths = self.resolve_fmus()
        infos = {m: load_fmu_info(p) for m, p in paths.items()}
        return check_system(self.spec, infos, record)

    # -- run ---------------------------------------------------------------------------------------
    def run(self, duration_s: float, output_rate_Hz: float, record: Sequence[str] = (), *,
            progress: bool | None = None, anti_alias: str = "fir", keep_raw: bool = False,
            stop_check: Callable[[], bool] | None = None, final: Sequence[str] = (),
            snapshots: Sequence[float] = ()) -> CosimResult:
        """Simulate ``duration_s`` and return the recorded variables at ``output_rate_Hz``.

        ``record``: "component.variable" names (Real) to return. ``progress``: tqdm bar (default: on
        when the run has more than 50 000 steps). ``keep_raw``: also return the internal-rate records.
        ``final``: "component.variable" names (Real, any causality) read once after the last step (and
        at a failure) into ``CosimResult.final``, e.g. cumulative counters; names the FMUs do not have
        are skipped. ``snapshots``: times [s] at which the same names are also read (at the
        communication point nearest each, chunk boundaries: no cost per step), into
        ``CosimResult.snapshots`` ({time: {name: value}}).

        An FMU failing during the stepping loop (or a non-finite output) raises :class:`CosimError`
        whose ``partial`` is the CosimResult of the completed part: ``status == "failed"``, the
        signals up to the last whole output sample before the failure, ``failure`` (time, FMU,
        function, cause, log, every FMU's outputs as read after the failure) and an energy audit marked
        unavailable. A failure before the first step raises with ``partial = None``.
        """

        t_wall0 = time.perf_counter()
        record = list(dict.fromkeys(record))
        if not (duration_s > 0 and math.isfinite(duration_s)):
            raise ConfigurationError(f"duration {duration_s!r} s: expected a positive finite time")
        H = float(self.spec.comm_step)
        d = check_comm_step(H, output_rate_Hz)
        plan = self.check(output_rate_Hz, record)
        n_steps = int(round(duration_s / H))
        if abs(n_steps * H - duration_s) > 1e-9 * max(1.0, duration_s):
            n_steps = int(math.ceil(duration_s / H))
        n_steps = int(math.ceil(n_steps / d) * d)    # whole output samples
        T = n_steps * H

        nc = len(plan.comps)
        ny, nu = len(plan.y_names), len(plan.u_names)
        y = np.zeros(max(ny, 1))
        u = np.zeros(max(nu, 1))
        rec = np.empty((n_steps + 1, ny))
        ext_idx = np.array([i for i, _ in plan.ext], dtype=np.intp)
        ext_table = None
        if plan.ext:
            tk = np.arange(n_steps + 1) * H
            ext_table = np.empty((n_steps + 1, len(plan.ext)))
            for j, (_, prof) in enumerate(plan.ext):
                arr = np.asarray(prof, dtype=float)
                ext_table[:, j] = np.interp(tk, arr[:, 0], arr[:, 1])

        slaves: list[_Slave] = []
        callbacks = _FmiCallbacks() if self.backend == "fmi" else None
        error: BaseException | None = None
        fail: CosimError | None = None     # an FMU failure inside the stepping loop (partial results kept)
        k_done = -1                        # steps completed: rows rec[:k_done + 1] hold valid samples
        e0: list[dict] = []
        e1: list[dict] = []
        final = _readable(plan, final)
        final_values: dict[str, float] = {}
        snap_steps = sorted({int(round(ts / H)) for ts in snapshots if final and 0 < ts < T}) if final else []
        snap_values: dict[float, dict[str, float]] = {}
        fail_outputs: dict[str, dict | None] = {}
        loop_time = 0.0
        setup_time = 0.0                   # checks, FMU loading, instantiation, initialisation (map builds)
        chunk_costs: list[float] = []
        try:
            # instantiate exactly the spec's components
            for comp, info in zip(plan.comps, plan.infos):
                if self.backend == "fmi":
                    s = _FmiSlave(comp, info, callbacks)
                else:
                    s = _InprocSlave(comp, info)
                slaves.append(s)
                s.setup(T)
            for comp, s in zip(plan.comps, slaves):
                if comp.parameters:
                    s.set_parameters(comp.parameters)
                consts = {k: v for k, v in comp.inputs.items() if not _is_profile(v)}
                if consts:
                    s.set_values(list(consts), list(consts.values()))
            # buffers
            u_off = np.cumsum([0] + [len(x) for x in plan.in_names])
            y_off = np.cumsum([0] + [len(x) for x in plan.out_names])
            for i, s in enumerate(slaves):
                s.bind(plan.in_names[i], plan.out_names[i], u, int(u_off[i]), y, int(y_off[i]))
            for s in slaves:
                s.enter_init()

            def exchange(k: int):
                if ext_table is not None:
                    y[ext_idx] = ext_table[k]
                np.take(y, plan.gather, out=u[:nu])

            def read_all():
                for i, s in enumerate(slaves):
                    if plan.out_names[i]:
                        y[y_off[i]:y_off[i + 1]] = s.get_reals(plan.out_names[i])

            def write_all():
                for i, s in enumerate(slaves):
                    if plan.in_names[i]:
                        s.set_values(plan.in_names[i], u[u_off[i]:u_off[i + 1]].tolist())

            for _ in range(2):           # propagate initial flange values in initialization mode
                read_all()
                exchange(0)
                write_all()
            for s in slaves:
                s.exit_init()
            read_all()
            rec[0] = y[:ny]
            e0 = [dict(zip(plan.energy[i], s.get_reals(list(plan.energy[i])))) if plan.energy[i] else {}
                  for i, s in enumerate(slaves)]
            k_done = 0

            # ---- the stepping loop ----
            calls = [(s.set_fn, s.step_fn, s.get_fn, i) for i, s in enumerate(slaves)]
            gather = plan.gather
            u_in = u[:nu]
            take = np.take
            has_ext = ext_table is not None
            show = (n_steps > 50_000) if progress is None else bool(progress)
            bar = None
            if show:
                from tqdm import tqdm

                bar = tqdm(total=n_steps, unit="step", unit_scale=True, desc=f"co-sim {T:g} s",
                           mininterval=0.5, leave=False)
            chunk = 4096
            t_loop0 = time.perf_counter()
            setup_time = t_loop0 - t_wall0
            chunk_costs = []
            k = 0
            kk = 0
            loop_done = False
            try:
                while k < n_steps:
                    t_chunk = time.perf_counter()
                    k_end = min(n_steps, k + chunk)
                    if snap_steps:
                        if snap_steps[0] <= k:                 # read after step k-1 (at t = k H)
                            snap_values[k * H] = _read_values(slaves, plan, final)
                            snap_steps.pop(0)
                        if snap_steps:
                            k_end = min(k_end, snap_steps[0])
                    for kk in range(k, k_end):
                        t = kk * H
                        if has_ext:
                            y[ext_idx] = ext_table[kk]
                        take(y, gather, out=u_in)
                        for set_fn, step_fn, get_fn, i in calls:
                            if set_fn is not None:
                                st = set_fn()
                                if st:
                                    self._status(slaves[i], "fmi2SetReal", st, t)
                            st = step_fn(t, H, 1)
                            if st:
                                self._status(slaves[i], "fmi2DoStep", st, t)
                            if get_fn is not None:
                                st = get_fn()
                                if st:
                                    self._status(slaves[i], "fmi2GetReal", st, t + H)
                        rec[kk + 1] = y[:ny]
                    chunk_costs.append((time.perf_counter() - t_chunk) / (k_end - k))
                    if bar is not None:
                        bar.update(k_end - k)
                    k = k_end
                    if stop_check is not None and stop_check():
                        raise KeyboardInterrupt
                loop_done = True
                k_done = n_steps
                loop_time = time.perf_counter() - t_loop0
                if bar is not None:
                    bar.close()
                e1 = [dict(zip(plan.energy[i], s.get_reals(list(plan.energy[i])))) if plan.energy[i] else {}
                      for i, s in enumerate(slaves)]
                final_values = _read_values(slaves, plan, final)
            except CosimError as exc:
                # an FMU failed: keep what was computed (rows up to the start of the failed step), read
                # what the FMUs still expose (each read guarded: a broken FMU must not crash this)
                fail = error = exc
                if not loop_done:
                    k_done = kk
                    loop_time = time.perf_counter() - t_loop0
                if bar is not None:
                    bar.close()
                final_values = _read_values(slaves, plan, final)
                fail_outputs = {s.name: _read_guarded(s, _real_outputs(info))
                                for s, info in zip(slaves, plan.infos)}
        except BaseException as exc:
            error = exc
            raise
        finally:
            teardown_errors = []
            for s in reversed(slaves):
                try:
                    teardown_errors += [f"{s.name}: {e}" for e in s.teardown()]
                except Exception as exc:  # pragma: no cover
                    teardown_errors.append(f"{s.name}: {exc}")
            if teardown_errors and error is None:
                self._log("teardown problems: " + "; ".join(teardown_errors))

        # ---- post-processing (of the completed part after a failure) ----
        valid = rec[:k_done + 1]
        if not np.all(np.isfinite(valid)):
            bad = np.where(~np.isfinite(valid))
            kbad, jbad = int(bad[0][0]), int(bad[1][0])
            if fail is None:
                fail = CosimError(plan.y_names[jbad].split(".")[0], "?", "output check (NaN/Inf)", 3, kbad * H,
                                  [f"{plan.y_names[jbad]} = {valid[kbad, jbad]} at t = {kbad * H:.9g} s"])
                comp_names = [c.name for c in plan.comps]
                if fail.component in comp_names:
                    fail.model = plan.comps[comp_names.index(fail.component)].model
            k_done = kbad - 1            # the samples before the first non-finite one
            valid = rec[:k_done + 1]
        if fail is not None and k_done < 0:
            raise fail                   # nothing was computed
        col = {n: j for j, n in enumerate(plan.y_names)}
        fs_in = 1.0 / H
        units = {}
        signals = {}
        if record:
            cols = [col[r] for r in record]
            dec = decimate(valid[:, cols], fs_in, output_rate_Hz, method=anti_alias)
            for j, r in enumerate(record):
                signals[r] = dec[:, j]
                comp, vn = _split(r)
                units[r] = plan.infos[[c.name for c in plan.comps].index(comp)].variables[vn].unit
        n_out = k_done // d + 1          # whole output samples (up to the failure)
        t_out = np.arange(n_out) / output_rate_Hz
        if fail is None:
            audit = energy_audit(plan, rec, e0, e1)
        else:
            audit = energy_unavailable(f"the run failed at t = {fail.time:.9g} s: the FMUs' energy counters "
                                       "are not available at one common time")
        raw = None
        if keep_raw:
            raw = {"time": np.arange(k_done + 1) * H}
            raw.update({n: valid[:, j].copy() for n, j in col.items()})
        wall = time.perf_counter() - t_wall0
        logs = {}
        for s in slaves:
            logs[s.name] = list(s.log.lines)
        fmus = [{"name": c.name, "model": c.model, "path": str(info.path), "parameters": dict(c.parameters)}
                for c, info in zip(plan.comps, plan.infos)]
        T_done = k_done * H
        failure = None
        if fail is not None:
            st = fail.status
            failure = {
                "time_s": float(fail.time), "component": fail.component, "model": fail.model,
                "function": fail.function,
                "status": FMI_STATUS[st] if 0 <= st < len(FMI_STATUS) else str(st),
                "cause": failure_cause(fail), "log": list(fail.log[-20:]),
                "steps_completed": int(k_done), "last_sample_time_s": float(t_out[-1]),
                "outputs": fail_outputs,
            }
        steady = chunk_costs[1:] if len(chunk_costs) > 1 else chunk_costs
        result = CosimResult(
            time=t_out, signals=signals, units=units, output_rate_Hz=output_rate_Hz, comm_step_s=H,
            steps_per_output=d, n_steps=k_done, sim_time_s=T_done, wall_time_s=wall, loop_time_s=loop_time,
            us_per_step=1e6 * loop_time / max(k_done, 1),
            us_per_step_steady=1e6 * float(np.median(steady)) if steady else 1e6 * loop_time / max(k_done, 1),
            real_time_factor=T_done / loop_time if loop_time > 0 else float("inf"),
            setup_time_s=setup_time,
            backend=self.backend, energy=audit, fmus=fmus, warnings=list(plan.warnings), logs=logs, raw=raw,
            status="ok" if fail is None else "failed", failure=failure, final=final_values,
            snapshots=snap_values)
        if fail is not None:
            fail.partial = result
            raise fail
        return result

    def _status(self, slave: _Slave, function: str, status: int, t: float) -> None:
        if status == 1:     # warning: keep going, the message is in the log
            return
        if status >= 4:
            slave.fatal = True
        raise CosimError(slave.name, slave.model, function, int(status), t, list(slave.log.lines))


def simulate(spec: SystemSpec, duration_s: float, output_rate_Hz: float, record: Sequence[str] = (), *,
             backend: str = "fmi", fmu_dir: str | Path = "fmus", fmu_paths=None, build: bool = True,
             progress: bool | None = None, anti_alias: str = "fir", keep_raw: bool = False,
             final: Sequence[str] = (), snapshots: Sequence[float] = ()) -> CosimResult:
    """One-call form of :class:`Master`."""
    return Master(spec, fmu_dir=fmu_dir, backend=backend, fmu_paths=fmu_paths, build=build).run(
        duration_s, output_rate_Hz, record, progress=progress, anti_alias=anti_alias, keep_raw=keep_raw,
        final=final, snapshots=snapshots)


__all__ = ["Master", "simulate", "CosimResult", "ConfigurationError", "CosimError", "check_system",
           "check_comm_step", "ensure_fmus", "stale_models", "sources_hash", "load_fmu_info", "extracted_dir",
           "energy_audit", "energy_unavailable", "failure_cause", "load_slave_class"]


def record_built(fmu_dir: str | Path, paths: Sequence[str | Path]) -> None:
    """Record that these FMUs were just built from the current sources (staleness stamp)."""
    fmu_dir = Path(fmu_dir)
    current = sources_hash()
    with file_lock(fmu_dir / ".build.lock"):
        stamp = _read_stamp(fmu_dir)
        for p in paths:
            p = Path(p)
            if p.suffix == ".fmu" and p.is_file() and p.parent.resolve() == fmu_dir.resolve():
                stamp[p.stem] = current
        tmp = fmu_dir / (STAMP_FILE + f".{os.getpid()}")
        tmp.write_text(json.dumps(stamp, indent=1, sort_keys=True))
        os.replace(tmp, fmu_dir / STAMP_FILE)
