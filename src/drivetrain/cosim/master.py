"""The co-simulation loop: fixed-step Jacobi coupling of FMI 2.0 co-simulation FMUs on ``fmpy.fmi2.FMU2Slave``.

What it does, in order (see ``docs/MASTER.md``):

1. **Resolve FMUs** for the models in the :class:`~drivetrain.system.SystemSpec` (``fmus/<Model>.fmu``).
   A missing FMU, or one built from other package sources than the current ones (a SHA-256 of the
   package sources, recorded per model in ``<fmu_dir>/.sources-hash.json``), is (re)built with
   ``drivetrain.cosim.build.build_all`` under a file lock.
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
   :mod:`drivetrain.rig.signals`; after a failure the whole output samples before it) and run the
   **energy audit** (marked unavailable for a failed run). Variables asked for with ``final=`` (e.g.
   cumulative counters) are read once after the last step (and at a failure).
6. **Tear down** every instance (terminate unless the FMU failed fatally, freeInstance), also on errors.

The ``inprocess`` backend instantiates the same pythonfmu ``Fmi2Slave`` classes (imported from the FMU's
resources) directly in Python and calls their setters, ``do_step`` and getters in the same order with the
same exchange buffers: the same results without the FMI layer (benchmark ratio, debugging).
"""
from __future__ import annotations

import dataclasses
import logging
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from drivetrain.cosim.energy import energy_audit, energy_unavailable
from drivetrain.cosim.fmus import FMUInfo, ensure_fmus, load_fmu_info
from drivetrain.cosim.plan import ExchangePlan, check_comm_step, check_system, is_profile, split_ref
from drivetrain.cosim.slaves import FmiCallbacks, FmiSlave, InprocSlave, Slave
from drivetrain.cosim.stepper import CALLS, Stepper, load_stepper
from drivetrain.errors import FMI_STATUS, ConfigurationError, CosimError
from drivetrain.rig.signals import decimate
from drivetrain.system import SystemSpec

#: messages for the user (progress, warnings); the CLI passes its own ``log``, a library caller sees them
#: through Python logging (on stderr when logging is not configured)
_LOG = logging.getLogger(__name__)


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
    loop_cpu_time_s: float | None = None   # the stepping loop's CPU time of this process (less sensitive to
    #                                        other processes on a shared machine than loop_time_s)
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


def _readable(plan: ExchangePlan, names: Sequence[str]) -> list[str]:
    """The "component.variable" names (Real) that exist in the plan's FMUs."""
    infos = {c.name: info for c, info in zip(plan.comps, plan.infos)}
    out = []
    for ref in dict.fromkeys(names):
        comp, vn = split_ref(ref)
        v = infos[comp].variables.get(vn) if comp in infos else None
        if v is not None and v.type == "Real":
            out.append(ref)
    return out


def _read_guarded(slave: Slave, names: Sequence[str]) -> dict[str, float] | None:
    """{name: value} read from one FMU, or None when it cannot answer (failed fatally, refuses, raises)."""
    if not names or slave.fatal:
        return None
    try:
        return {n: float(v) for n, v in zip(names, slave.get_reals(list(names)))}
    except Exception:  # noqa: BLE001 - reading after a failure must never mask the failure
        return None


def _read_values(slaves: Sequence[Slave], plan: ExchangePlan, names: Sequence[str]) -> dict[str, float]:
    """Values of "component.variable" names, one guarded read per component."""
    by_comp: dict[str, list[str]] = {}
    for ref in names:
        comp, vn = split_ref(ref)
        by_comp.setdefault(comp, []).append(vn)
    out = {}
    for s in slaves:
        if s.name in by_comp:
            got = _read_guarded(s, by_comp[s.name])
            for vn, v in (got or {}).items():
                out[f"{s.name}.{vn}"] = v
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
    build : build missing/stale FMUs with ``drivetrain.cosim.build.build_all``.
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

    def check(self, output_rate_Hz: float, record: Sequence[str] = ()) -> ExchangePlan:
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

        slaves: list[Slave] = []
        callbacks = FmiCallbacks() if self.backend == "fmi" else None
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
        loop_cpu = None
        setup_time = 0.0                   # checks, FMU loading, instantiation, initialisation (map builds)
        chunk_costs: list[float] = []
        try:
            # instantiate exactly the spec's components
            for comp, info in zip(plan.comps, plan.infos):
                if self.backend == "fmi":
                    s = FmiSlave(comp, info, callbacks)
                else:
                    s = InprocSlave(comp, info)
                slaves.append(s)
                s.setup(T)
            for comp, s in zip(plan.comps, slaves):
                if comp.parameters:
                    s.set_parameters(comp.parameters)
                consts = {k: v for k, v in comp.inputs.items() if not is_profile(v)}
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
            y_rec = y[:ny]
            take = np.take
            has_ext = ext_table is not None
            show = (n_steps > 50_000) if progress is None else bool(progress)
            bar = None
            if show:
                from tqdm import tqdm

                bar = tqdm(total=n_steps, unit="step", unit_scale=True, desc=f"co-sim {T:g} s",
                           mininterval=0.5, leave=False)
            # the C loop (drivetrain.cosim.stepper) for compiled-FMI slaves; else this Python loop
            stepper = None
            if all(isinstance(s, FmiSlave) for s in slaves):
                fn = load_stepper()
                if fn is not None:
                    stepper = Stepper(fn, slaves, H, y, u, gather, ext_idx, ext_table, rec, ny)

            def finish_step(kk: int, i: int, call: int, st: int):
                # the C loop stopped at a non-zero status: raise as the Python loop does (>= 2), or for
                # a warning do the rest of step kk here, the same calls in the same order
                t = kk * H
                self._status(slaves[i], CALLS[call], st, t + H if call == 2 else t)
                for j in range(i, nc):
                    for c in range(call + 1 if j == i else 0, 3):
                        fn = calls[j][c]
                        if fn is None:
                            continue
                        st = fn(t, H, 1) if c == 1 else fn()
                        if st:
                            self._status(slaves[j], CALLS[c], st, t + H if c == 2 else t)
                rec[kk + 1] = y_rec

            chunk = 4096
            t_loop0 = time.perf_counter()
            cpu_loop0 = time.process_time()
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
                    kk = k
                    while stepper is not None and kk < k_end:
                        hit = stepper.run(kk, k_end)       # None: the chunk is done
                        if hit is None:
                            break
                        kk = hit[0]
                        finish_step(*hit)
                        kk += 1
                    for kk in range(k, k_end if stepper is None else k):
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
                        rec[kk + 1] = y_rec
                    chunk_costs.append((time.perf_counter() - t_chunk) / (k_end - k))
                    if bar is not None:
                        bar.update(k_end - k)
                    k = k_end
                    if stop_check is not None and stop_check():
                        raise KeyboardInterrupt
                loop_done = True
                k_done = n_steps
                loop_time = time.perf_counter() - t_loop0
                loop_cpu = time.process_time() - cpu_loop0
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
                    loop_cpu = time.process_time() - cpu_loop0
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
                comp, vn = split_ref(r)
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
            setup_time_s=setup_time, loop_cpu_time_s=loop_cpu,
            backend=self.backend, energy=audit, fmus=fmus, warnings=list(plan.warnings), logs=logs, raw=raw,
            status="ok" if fail is None else "failed", failure=failure, final=final_values,
            snapshots=snap_values)
        if fail is not None:
            fail.partial = result
            raise fail
        return result

    def _status(self, slave: Slave, function: str, status: int, t: float) -> None:
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
