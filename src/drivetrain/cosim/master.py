"""The co-simulation loop: fixed-step Jacobi coupling of FMI 2.0 co-simulation FMUs on ``fmpy.fmi2.FMU2Slave``.

What it does, in order (see ``docs/MASTER.md``):

1. **Resolve FMUs** for the models in the :class:`~drivetrain.system.SystemSpec` (``fmus/<Model>.fmu``).
   A missing FMU, or one built from other package sources than the current ones (a SHA-256 of the
   package sources, recorded per model in the directory's stamp, ``fmus.stamp_path``), is (re)built with
   ``drivetrain.fmu_build.build.build_all`` under a file lock.
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
   The steps run in chunks of up to ``CHUNK_STEPS`` (one call into the C loop each, ``cosim/stepper``);
   between chunks, never per step, the loop calls its **observers** (:mod:`drivetrain.cosim.observers`:
   the hooks ``started``, ``next_call``, ``stepped``, ``finished``): the recorder (energy counters,
   ``final`` and ``snapshots`` reads, then the decimated signals), the progress bar, the loop's clock, and
   any the caller passes (``Master.run(observers=...)``); adding one touches no loop code.
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
from drivetrain.fmu_build.fmus import FMUInfo, ensure_fmus, fmu_dir_or_default, load_fmu_info
from drivetrain.cosim.observers import (
    NUMERIC_TYPES,
    Chunk,
    LoopClock,
    LoopEnd,
    LoopInfo,
    Observer,
    Progress,
    Recorder,
    read_guarded,
)
from drivetrain.cosim.plan import ExchangePlan, check_comm_step, check_system, is_profile
from drivetrain.cosim.slaves import FmiCallbacks, FmiSlave, InprocSlave, Slave
from drivetrain.cosim.stepper import CALLS, Stepper, load_stepper
from drivetrain.errors import FMI_STATUS, ConfigurationError, CosimError, RunInterrupted
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
    status: str = "ok"                     # "ok" | "failed" | "interrupted" (then: the completed part only)
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
    """Every numeric output (Real, and the Integer counters and Boolean flags) of an FMU."""
    return [n for n, v in info.variables.items() if v.causality == "output" and v.type in NUMERIC_TYPES]


# --------------------------------------------------------------------------------------------------
# The run's parts: time grid, exchange buffers, the loop (its observers: drivetrain.cosim.observers)
# --------------------------------------------------------------------------------------------------

#: steps per chunk of the loop: the observers (and the stop requests, stop_check) act between chunks
CHUNK_STEPS = 4096


class _StopRequest:
    """A process-wide request to end the running stepping loop at its next chunk of steps (the command line's
    SIGINT/SIGTERM handler, :func:`request_stop`): the run ends "interrupted" with what it computed. A
    KeyboardInterrupt raised inside an FMU's callback can be swallowed; this request cannot."""

    reason: str | None = None
    in_loop: bool = False


def request_stop(reason: str) -> bool:
    """Ask the running stepping loop to stop at its next chunk; False when no loop runs (then the caller
    interrupts as it would otherwise)."""
    if not _StopRequest.in_loop:
        return False
    _StopRequest.reason = reason
    return True


@dataclass(frozen=True)
class _Grid:
    """The run's time grid: communication step H, steps per output sample, steps (whole output samples)."""

    H: float
    steps_per_output: int
    n_steps: int
    output_rate_Hz: float

    @classmethod
    def covering(cls, duration_s: float, H: float, steps_per_output: int, output_rate_Hz: float) -> "_Grid":
        """The steps that cover ``duration_s`` (H apart), rounded up to whole output samples."""
        n_steps = int(round(duration_s / H))
        if abs(n_steps * H - duration_s) > 1e-9 * max(1.0, duration_s):
            n_steps = int(math.ceil(duration_s / H))
        n_steps = int(math.ceil(n_steps / steps_per_output) * steps_per_output)
        return cls(H, steps_per_output, n_steps, output_rate_Hz)

    @property
    def T(self) -> float:
        return self.n_steps * self.H


class _Exchange:
    """The exchange buffers of one run, bound to the slaves: ``y`` every output read (then one slot per
    external time profile, from a table at the step times), ``u`` every input set; ``u = y[gather]``."""

    def __init__(self, plan: ExchangePlan, grid: _Grid):
        self.plan = plan
        self.ny, self.nu = len(plan.y_names), len(plan.u_names)
        self.y = np.zeros(max(self.ny, 1))
        self.u = np.zeros(max(self.nu, 1))
        self.ext_idx = np.array([i for i, _ in plan.ext], dtype=np.intp)
        self.ext_table = None
        if plan.ext:
            tk = np.arange(grid.n_steps + 1) * grid.H
            self.ext_table = np.empty((grid.n_steps + 1, len(plan.ext)))
            for j, (_, prof) in enumerate(plan.ext):
                arr = np.asarray(prof, dtype=float)
                self.ext_table[:, j] = np.interp(tk, arr[:, 0], arr[:, 1])
        self.u_off = np.cumsum([0] + [len(x) for x in plan.in_names])
        self.y_off = np.cumsum([0] + [len(x) for x in plan.out_names])

    def bind(self, slaves: Sequence[Slave]) -> None:
        for i, s in enumerate(slaves):
            s.bind(self.plan.in_names[i], self.plan.out_names[i], self.u, int(self.u_off[i]), self.y,
                   int(self.y_off[i]))

    def exchange(self, k: int) -> None:
        """The inputs of step k from the outputs (and the profiles at t = k H)."""
        if self.ext_table is not None:
            self.y[self.ext_idx] = self.ext_table[k]
        np.take(self.y, self.plan.gather, out=self.u[:self.nu])

    def read_all(self, slaves: Sequence[Slave]) -> None:
        for i, s in enumerate(slaves):
            if self.plan.out_names[i]:
                self.y[self.y_off[i]:self.y_off[i + 1]] = s.get_reals(self.plan.out_names[i])

    def write_all(self, slaves: Sequence[Slave]) -> None:
        for i, s in enumerate(slaves):
            if self.plan.in_names[i]:
                s.set_values(self.plan.in_names[i], self.u[self.u_off[i]:self.u_off[i + 1]].tolist())

    def initialise(self, slaves: Sequence[Slave]) -> None:
        """Initialization mode: two exchange sweeps propagate the initial flange values; then the outputs
        at t = 0."""
        for s in slaves:
            s.enter_init()
        for _ in range(2):
            self.read_all(slaves)
            self.exchange(0)
            self.write_all(slaves)
        for s in slaves:
            s.exit_init()
        self.read_all(slaves)


# --------------------------------------------------------------------------------------------------
# Failure handling
# --------------------------------------------------------------------------------------------------


def _check_status(slave: Slave, function: str, status: int, t: float) -> None:
    """A non-zero FMI status: a warning goes on (the message is in the log); discard or worse stops the run
    with CosimError naming the FMU, the call, the time and the FMU's log (fatal: no more calls to it)."""
    if status == 1:     # warning: keep going, the message is in the log
        return
    if status >= 4:
        slave.fatal = True
    raise CosimError(slave.name, slave.model, function, int(status), t, list(slave.log.lines))


@dataclass
class _Stop:
    """How the stepping ended: the steps completed (rows ``rec[:k_done + 1]`` hold valid samples) and the
    FMU failure if any, with every FMU's outputs as read after it (each read guarded)."""

    k_done: int
    fail: CosimError | None = None
    outputs: dict[str, dict | None] = dataclasses.field(default_factory=dict)


def _failed_outputs(slaves: Sequence[Slave], plan: ExchangePlan) -> dict[str, dict | None]:
    """Every FMU's numeric outputs as it still exposes them after a failure (None where it cannot answer)."""
    return {s.name: read_guarded(s, _real_outputs(info)) for s, info in zip(slaves, plan.infos)}


def _finished(observers: Sequence[Observer], end: LoopEnd) -> None:
    """Every observer's ``finished``, the last registered first."""
    for o in reversed(observers):
        o.finished(end)


def _check_finite(rec: np.ndarray, stop: _Stop, plan: ExchangePlan, H: float) -> _Stop:
    """The valid part of the records ends before the first non-finite value: a failure of the FMU that
    produced it (unless one failed already)."""
    valid = rec[:stop.k_done + 1]
    if np.all(np.isfinite(valid)):
        return stop
    bad = np.where(~np.isfinite(valid))
    kbad, jbad = int(bad[0][0]), int(bad[1][0])
    fail = stop.fail
    if fail is None:
        fail = CosimError(plan.y_names[jbad].split(".")[0], "?", "output check (NaN/Inf)", 3, kbad * H,
                          [f"{plan.y_names[jbad]} = {valid[kbad, jbad]} at t = {kbad * H:.9g} s"])
        comp_names = [c.name for c in plan.comps]
        if fail.component in comp_names:
            fail.model = plan.comps[comp_names.index(fail.component)].model
    return _Stop(kbad - 1, fail, stop.outputs)       # the samples before the first non-finite one


def _failure_record(stop: _Stop, last_sample_time_s: float) -> dict:
    """CosimResult.failure: when, where and why the run failed, and what the FMUs showed after it."""
    fail = stop.fail
    st = fail.status
    return {
        "time_s": float(fail.time), "component": fail.component, "model": fail.model,
        "function": fail.function,
        "status": FMI_STATUS[st] if 0 <= st < len(FMI_STATUS) else str(st),
        "cause": failure_cause(fail), "log": list(fail.log[-20:]),
        "steps_completed": int(stop.k_done), "last_sample_time_s": float(last_sample_time_s),
        "outputs": stop.outputs,
    }


# --------------------------------------------------------------------------------------------------
# The loop: exchange, step, status
# --------------------------------------------------------------------------------------------------


class _Loop:
    """Fixed-step Jacobi stepping of the slaves: gather the inputs from the outputs of the previous
    communication point, then per FMU set inputs, do the step, get outputs, each status checked, and the
    outputs written into ``rec`` (row k at t = k H; row 0 the initialised FMUs' outputs). The observers
    (drivetrain.cosim.observers) are called between chunks, never per step. The C loop
    (drivetrain.cosim.stepper) runs the chunks of compiled-FMI slaves, else the Python loop does: the same
    calls in the same order, the same values."""

    def __init__(self, slaves: Sequence[Slave], xc: _Exchange, grid: _Grid):
        self.slaves, self.xc, self.H = slaves, xc, grid.H
        self.rec = rec = np.empty((grid.n_steps + 1, xc.ny))
        rec[0] = xc.y[:xc.ny]
        self.calls = [(s.set_fn, s.step_fn, s.get_fn, i) for i, s in enumerate(slaves)]
        self.k = 0                   # steps completed (at a failure: the failed step's index)
        self.stepper = None
        if all(isinstance(s, FmiSlave) for s in slaves):
            fn = load_stepper()
            if fn is not None:
                self.stepper = Stepper(fn, slaves, grid.H, xc.y, xc.u, xc.plan.gather, xc.ext_idx,
                                       xc.ext_table, rec, xc.ny)

    def run(self, n_steps: int, observers: Sequence[Observer], stop_check: Callable[[], bool] | None) -> None:
        """Steps 0 .. n_steps-1 in chunks; after each, every observer's ``stepped`` (last registered first)."""
        step_chunk = self._python_chunk if self.stepper is None else self._c_chunk
        k = 0
        late_first = observers[::-1]
        _StopRequest.reason, _StopRequest.in_loop = None, True
        try:
            while k < n_steps:
                k_end = min(n_steps, k + CHUNK_STEPS)
                for o in observers:
                    want = o.next_call(k)
                    if want is not None and k < want < k_end:
                        k_end = want
                step_chunk(k, k_end)
                self.k = k_end
                chunk = Chunk(k, k_end, k_end * self.H)
                for o in late_first:
                    o.stepped(chunk)
                k = k_end
                if _StopRequest.reason is not None and k < n_steps:
                    raise RunInterrupted(_StopRequest.reason, k * self.H)
                if stop_check is not None and stop_check():
                    raise KeyboardInterrupt
        finally:
            _StopRequest.reason, _StopRequest.in_loop = None, False

    def _python_chunk(self, k: int, k_end: int) -> None:
        H, y, rec, y_rec, u_in = self.H, self.xc.y, self.rec, self.xc.y[:self.xc.ny], self.xc.u[:self.xc.nu]
        take, gather, calls, slaves = np.take, self.xc.plan.gather, self.calls, self.slaves
        ext_idx, ext_table = self.xc.ext_idx, self.xc.ext_table
        has_ext = ext_table is not None
        kk = k
        try:
            for kk in range(k, k_end):
                t = kk * H
                if has_ext:
                    y[ext_idx] = ext_table[kk]
                take(y, gather, out=u_in)
                for set_fn, step_fn, get_fn, i in calls:
                    if set_fn is not None:
                        st = set_fn()
                        if st:
                            _check_status(slaves[i], "fmi2SetReal", st, t)
                    st = step_fn(t, H, 1)
                    if st:
                        _check_status(slaves[i], "fmi2DoStep", st, t)
                    if get_fn is not None:
                        st = get_fn()
                        if st:
                            _check_status(slaves[i], "fmi2GetReal", st, t + H)
                rec[kk + 1] = y_rec
        except CosimError:
            self.k = kk
            raise

    def _c_chunk(self, k: int, k_end: int) -> None:
        kk = k
        while kk < k_end:
            hit = self.stepper.run(kk, k_end)       # None: the chunk is done
            if hit is None:
                break
            self.k = kk = hit[0]
            self._finish_step(*hit)
            kk += 1

    def _finish_step(self, kk: int, i: int, call: int, st: int) -> None:
        """The C loop stopped at a non-zero status: raise as the Python loop does (>= 2), or for a warning
        do the rest of step kk here, the same calls in the same order."""
        H, slaves, calls = self.H, self.slaves, self.calls
        t = kk * H
        _check_status(slaves[i], CALLS[call], st, t + H if call == 2 else t)
        for j in range(i, len(slaves)):
            for c in range(call + 1 if j == i else 0, 3):
                fn = calls[j][c]
                if fn is None:
                    continue
                st = fn(t, H, 1) if c == 1 else fn()
                if st:
                    _check_status(slaves[j], CALLS[c], st, t + H if c == 2 else t)
        self.rec[kk + 1] = self.xc.y[:self.xc.ny]


# --------------------------------------------------------------------------------------------------
# The master
# --------------------------------------------------------------------------------------------------


class Master:
    """Fixed-step Jacobi co-simulation of a :class:`SystemSpec`.

    Parameters
    ----------
    spec : the system (components, connections, comm_step).
    fmu_dir : where ``<Model>.fmu`` live and are built on demand (default None: ``fmus.default_fmu_dir()``).
    backend : ``"fmi"`` (fmpy FMU2Slave) or ``"inprocess"`` (the same slave classes without FMI).
    fmu_paths : explicit ``{model: path}``; these are used as they are (no building).
    build : build missing/stale FMUs with ``drivetrain.fmu_build.build.build_all``.
    """

    def __init__(self, spec: SystemSpec, fmu_dir: str | Path | None = None, backend: str = "fmi",
                 fmu_paths: dict[str, str | Path] | None = None, build: bool = True,
                 log: Callable[[str], None] | None = None):
        if backend not in ("fmi", "inprocess"):
            raise ConfigurationError(f"backend {backend!r}: expected 'fmi' or 'inprocess'")
        self.spec = spec
        self.backend = backend
        self.fmu_dir = fmu_dir_or_default(fmu_dir)
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
        check_comm_step(self.spec.comm_step, output_rate_Hz)
        return self._plan(record)

    def _plan(self, record: Sequence[str]) -> ExchangePlan:
        """The FMUs (built when missing or stale) and the spec checked against their model descriptions."""
        paths = self.resolve_fmus()
        infos = {m: load_fmu_info(p) for m, p in paths.items()}
        return check_system(self.spec, infos, record)

    def _instantiate(self, plan: ExchangePlan, slaves: list[Slave], T: float) -> None:
        """Exactly the spec's components, appended to ``slaves`` as they come (the caller tears them down),
        with their parameters and constant inputs set."""
        callbacks = FmiCallbacks() if self.backend == "fmi" else None
        for comp, info in zip(plan.comps, plan.infos):
            s = FmiSlave(comp, info, callbacks) if self.backend == "fmi" else InprocSlave(comp, info)
            slaves.append(s)
            s.setup(T)
        for comp, s in zip(plan.comps, slaves):
            if comp.parameters:
                s.set_parameters(comp.parameters)
            consts = {k: v for k, v in comp.inputs.items() if not is_profile(v)}
            if consts:
                s.set_values(list(consts), list(consts.values()))

    def _teardown(self, slaves: Sequence[Slave], report: bool) -> None:
        """Every instance torn down (last first); problems are logged after an otherwise clean run."""
        teardown_errors = []
        for s in reversed(slaves):
            try:
                teardown_errors += [f"{s.name}: {e}" for e in s.teardown()]
            except Exception as exc:  # pragma: no cover
                teardown_errors.append(f"{s.name}: {exc}")
        if teardown_errors and report:
            self._log("teardown problems: " + "; ".join(teardown_errors))

    # -- run ---------------------------------------------------------------------------------------
    def run(self, duration_s: float, output_rate_Hz: float, record: Sequence[str] = (), *,
            progress: bool | None = None, anti_alias: str = "fir", keep_raw: bool = False,
            stop_check: Callable[[], bool] | None = None, final: Sequence[str] = (),
            snapshots: Sequence[float] = (), observers: Sequence[Observer] = ()) -> CosimResult:
        """Simulate ``duration_s`` and return the recorded variables at ``output_rate_Hz``.

        ``record``: "component.variable" names (Real) to return. ``progress``: tqdm bar (default: shown
        once the loop has lasted 2 s; True: from the start; False: none). ``keep_raw``: also return the internal-rate records.
        ``final``: "component.variable" names (numeric: Real, Integer, Boolean; any causality) read once after the last step (and
        at a failure) into ``CosimResult.final``, e.g. cumulative counters; names the FMUs do not have
        are skipped. ``snapshots``: times [s] at which the same names are also read (at the
        communication point nearest each, chunk boundaries: no cost per step), into
        ``CosimResult.snapshots`` ({time: {name: value}}). ``observers``: the caller's
        :class:`~drivetrain.cosim.observers.Observer` objects, called by the loop between chunks beside
        the master's own (recorder, progress, clock; see :mod:`drivetrain.cosim.observers`).

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
        grid = _Grid.covering(duration_s, H, check_comm_step(H, output_rate_Hz), output_rate_Hz)
        plan = self._plan(record)
        xc = _Exchange(plan, grid)
        recorder, clock = Recorder(record, final, snapshots), LoopClock()
        # started in this order, stepped and finished in the reverse: the clock innermost (the loop alone)
        chain = [recorder, Progress(progress), *observers, clock]
        slaves: list[Slave] = []
        stop = None
        try:
            stop = self._step(plan, grid, slaves, xc, chain, stop_check)
        finally:
            self._teardown(slaves, report=stop is not None and stop.fail is None)
        return self._result(plan, grid, slaves, recorder, clock, stop, anti_alias, keep_raw, t_wall0)

    def _step(self, plan: ExchangePlan, grid: _Grid, slaves: list[Slave], xc: _Exchange,
              observers: list[Observer], stop_check: Callable[[], bool] | None) -> _Stop:
        """Instantiate, initialise and step, the observers told at the start, after every chunk and at the
        end. An FMU failure in the stepping loop keeps what was computed (rows up to the start of the failed
        step) and reads what the FMUs still expose (each read guarded: a broken FMU must not crash this);
        one before the loop raises."""
        self._instantiate(plan, slaves, grid.T)
        xc.bind(slaves)
        xc.initialise(slaves)
        loop = _Loop(slaves, xc, grid)
        info = LoopInfo(grid.H, grid.n_steps, grid.steps_per_output, grid.output_rate_Hz, plan, slaves, loop.rec)
        for o in observers:
            o.started(info)
        try:
            loop.run(grid.n_steps, observers, stop_check)
            stop = _Stop(grid.n_steps)
        except CosimError as exc:
            stop = _Stop(loop.k, exc)
        except BaseException:
            _finished(observers, LoopEnd(loop.k, loop.k * grid.H, aborted=True))
            raise
        _finished(observers, LoopEnd(stop.k_done, stop.k_done * grid.H, stop.fail))
        if stop.fail is not None:
            stop.outputs = _failed_outputs(slaves, plan)
        return stop

    def _result(self, plan: ExchangePlan, grid: _Grid, slaves: Sequence[Slave], recorder: Recorder,
                clock: LoopClock, stop: _Stop, anti_alias: str, keep_raw: bool, t_wall0: float) -> CosimResult:
        """The CosimResult of the completed part; after a failure it is the error's ``partial`` and the
        error is raised (without a partial when nothing was computed)."""
        stop = _check_finite(recorder.rec, stop, plan, grid.H)
        fail, k_done = stop.fail, stop.k_done
        if fail is not None and k_done < 0:
            raise fail                   # nothing was computed
        signals, units = recorder.signals(k_done, anti_alias)
        t_out = np.arange(k_done // grid.steps_per_output + 1) / grid.output_rate_Hz  # whole output samples
        if fail is None:
            audit = energy_audit(plan, recorder.rec, recorder.e0, recorder.e1)
        else:
            audit = energy_unavailable(f"the run failed at t = {fail.time:.9g} s: the FMUs' energy counters "
                                       "are not available at one common time")
        raw = recorder.raw(k_done) if keep_raw else None
        wall = time.perf_counter() - t_wall0
        logs = {s.name: list(s.log.lines) for s in slaves}
        fmus = [{"name": c.name, "model": c.model, "path": str(info.path), "parameters": dict(c.parameters)}
                for c, info in zip(plan.comps, plan.infos)]
        T_done, loop_time = k_done * grid.H, clock.loop_s
        result = CosimResult(
            time=t_out, signals=signals, units=units, output_rate_Hz=grid.output_rate_Hz, comm_step_s=grid.H,
            steps_per_output=grid.steps_per_output, n_steps=k_done, sim_time_s=T_done, wall_time_s=wall,
            loop_time_s=loop_time, us_per_step=1e6 * loop_time / max(k_done, 1),
            us_per_step_steady=clock.us_per_step_steady(k_done),
            real_time_factor=T_done / loop_time if loop_time > 0 else float("inf"),
            setup_time_s=clock.t0 - t_wall0, loop_cpu_time_s=clock.cpu_s,
            backend=self.backend, energy=audit, fmus=fmus, warnings=list(plan.warnings), logs=logs, raw=raw,
            status="ok" if fail is None else "interrupted" if isinstance(fail, RunInterrupted) else "failed",
            failure=None if fail is None else _failure_record(stop, t_out[-1]), final=recorder.final_values,
            snapshots=recorder.snapshots)
        if fail is not None:
            fail.partial = result
            raise fail
        return result


def simulate(spec: SystemSpec, duration_s: float, output_rate_Hz: float, record: Sequence[str] = (), *,
             backend: str = "fmi", fmu_dir: str | Path | None = None, fmu_paths=None, build: bool = True,
             progress: bool | None = None, anti_alias: str = "fir", keep_raw: bool = False,
             final: Sequence[str] = (), snapshots: Sequence[float] = (),
             observers: Sequence[Observer] = ()) -> CosimResult:
    """One-call form of :class:`Master`."""
    return Master(spec, fmu_dir=fmu_dir, backend=backend, fmu_paths=fmu_paths, build=build).run(
        duration_s, output_rate_Hz, record, progress=progress, anti_alias=anti_alias, keep_raw=keep_raw,
        final=final, snapshots=snapshots, observers=observers)
