"""The co-simulation loop's observers, as libcosim's: the interface, and the three the master registers.

The loop (:class:`drivetrain.cosim.master.Master`, ``_Loop``) does exchange, step and status and nothing else,
in chunks of up to ``CHUNK_STEPS`` communication steps (one call into the C stepping loop per chunk,
:mod:`drivetrain.cosim.stepper`). It writes the outputs of every communication point into one buffer,
``LoopInfo.rows`` (row k: the exchanged outputs at t = k H; the C loop does it per step), and calls its
observers between chunks, never per step. An observer implements any of these hooks (:class:`Observer`
has them all, doing nothing):

``started(info: LoopInfo)``
    once, after initialisation and before the first step: the FMUs initialised, ``info.rows[0]`` holds the
    t = 0 outputs; ``info`` (the time grid, the exchange plan, the slaves, ``rows``) stays valid for the
    run. Not called when the run fails before the loop (instantiation, initialisation).
``next_call(k: int) -> int | None``
    before each chunk, from step count ``k``: the step count after which the observer must be called next
    (the chunk then ends there, e.g. at a snapshot time), or None (any chunk length will do).
``stepped(chunk: Chunk)``
    after each chunk that completed: steps ``chunk.k0 .. chunk.k - 1`` were done, the FMUs are at
    ``chunk.time_s = k H`` and ``rows[k0 + 1 .. k]`` hold the new samples. The chunks are contiguous and
    the last ends at ``info.n_steps`` (unless the run stopped early). An FMU failure inside a chunk
    ends the loop without a ``stepped`` call for that chunk.
``finished(end: LoopEnd)``
    once, when the loop ended: ``end.k_done`` steps completed (``rows[:k_done
    + 1]`` are valid; at a failure, the failed step's index), ``end.time_s`` their time, ``end.failure``
    the :class:`CosimError` that ended it (an FMU failure, or :class:`RunInterrupted`) or None, and
    ``end.aborted`` when an exception other than a CosimError (a KeyboardInterrupt) leaves the run
    without a result (release what you hold, read nothing from the FMUs).

Order: ``started`` in the order of registration, ``stepped`` and ``finished`` in the reverse order, so
the observers nest like context managers: the master registers the recorder first, then the progress
bar, then the caller's observers (``Master.run(observers=...)``), then the clock, which is innermost and
times the loop alone. Adding an observer touches no loop code.

The three the master registers:

- :class:`Recorder`: the results: the internal-rate rows, the energy counters at the start and the end,
  the ``final`` names after the last step (or at a failure) and at the ``snapshots`` times; then the
  recorded names at the output rate (zero-phase anti-alias low-pass and decimation,
  :func:`drivetrain.rig.signals.decimate`) and the raw records;
- :class:`Progress`: the tqdm bar;
- :class:`LoopClock`: the loop's wall and CPU time and its cost per step in each chunk (the steady
  ``us_per_step``).

The guarded reads of FMU values by name (:func:`read_values`, :func:`read_guarded`) live here too: the
recorder's reads, which the master's failure report uses as well.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from drivetrain.cosim.plan import ExchangePlan, split_ref
from drivetrain.cosim.slaves import Slave
from drivetrain.errors import CosimError
from drivetrain.rig.signals import decimate

#: the FMI types read as numbers (Slave.get_values): measurements, counters, switches
NUMERIC_TYPES = ("Real", "Integer", "Boolean")


# --------------------------------------------------------------------------------------------------
# The interface
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LoopInfo:
    """What an observer is told when the loop starts (valid for the whole run)."""

    H: float                      # communication step [s]
    n_steps: int                  # steps the loop will take (whole output samples)
    steps_per_output: int         # communication steps per output sample
    output_rate_Hz: float
    plan: ExchangePlan            # the FMUs, their exchanged names (plan.y_names: the columns of rows)
    slaves: Sequence[Slave]       # the instances, in the order of plan.comps (read between chunks only)
    rows: np.ndarray              # (n_steps + 1, len(plan.y_names)): row k = the outputs at t = k H

    @property
    def T(self) -> float:
        """The simulated time the loop covers [s]."""
        return self.n_steps * self.H


@dataclass(frozen=True)
class Chunk:
    """Steps ``k0 .. k - 1`` done: the FMUs are at communication point ``k`` (``time_s = k H``)."""

    k0: int
    k: int
    time_s: float

    @property
    def n(self) -> int:
        return self.k - self.k0


@dataclass(frozen=True)
class LoopEnd:
    """How the loop ended (see the module docstring, ``finished``)."""

    k_done: int
    time_s: float
    failure: CosimError | None = None
    aborted: bool = False


class Observer:
    """The observer interface: every hook does nothing; override those you need (module docstring)."""

    def started(self, info: LoopInfo) -> None:
        pass

    def next_call(self, k: int) -> int | None:
        return None

    def stepped(self, chunk: Chunk) -> None:
        pass

    def finished(self, end: LoopEnd) -> None:
        pass


# --------------------------------------------------------------------------------------------------
# Reading FMU values by name (between chunks, guarded)
# --------------------------------------------------------------------------------------------------


def readable(plan: ExchangePlan, names: Sequence[str]) -> list[str]:
    """The "component.variable" names (numeric: Real, Integer, Boolean) that exist in the plan's FMUs."""
    infos = {c.name: info for c, info in zip(plan.comps, plan.infos)}
    out = []
    for ref in dict.fromkeys(names):
        comp, vn = split_ref(ref)
        v = infos[comp].variables.get(vn) if comp in infos else None
        if v is not None and v.type in NUMERIC_TYPES:
            out.append(ref)
    return out


def read_guarded(slave: Slave, names: Sequence[str]) -> dict[str, float] | None:
    """{name: value} read from one FMU, or None when it cannot answer (failed fatally, refuses, raises)."""
    if not names or slave.fatal:
        return None
    try:
        return {n: float(v) for n, v in zip(names, slave.get_values(list(names)))}
    except Exception:  # noqa: BLE001 - reading after a failure must never mask the failure
        return None


def read_values(slaves: Sequence[Slave], names: Sequence[str]) -> dict[str, float]:
    """Values of "component.variable" names, one guarded read per component."""
    by_comp: dict[str, list[str]] = {}
    for ref in names:
        comp, vn = split_ref(ref)
        by_comp.setdefault(comp, []).append(vn)
    out = {}
    for s in slaves:
        if s.name in by_comp:
            got = read_guarded(s, by_comp[s.name])
            for vn, v in (got or {}).items():
                out[f"{s.name}.{vn}"] = v
    return out


def energy_reads(plan: ExchangePlan, slaves: Sequence[Slave]) -> list[dict]:
    """Every FMU's energy counters now (per component: {name: value})."""
    return [dict(zip(plan.energy[i], s.get_reals(list(plan.energy[i])))) if plan.energy[i] else {}
            for i, s in enumerate(slaves)]


# --------------------------------------------------------------------------------------------------
# The master's three observers
# --------------------------------------------------------------------------------------------------


class Recorder(Observer):
    """The observer that keeps the results: the internal-rate rows (``rec``, row k at t = k H: the loop's
    buffer), the energy counters at the start and the end, the ``final`` names after the last step (or at
    a failure) and at the ``snapshots`` (chunk boundaries: no cost per step); then the recorded names at
    the output rate (:meth:`signals`) and the raw records (:meth:`raw`)."""

    def __init__(self, record: Sequence[str], final: Sequence[str], snapshots: Sequence[float]):
        self.record, self._final_names, self._snapshot_times = list(record), list(final), list(snapshots)
        self.info: LoopInfo | None = None
        self.rec = np.empty((0, 0))
        self.final: list[str] = []
        self.snap_steps: list[int] = []
        self.snapshots: dict[float, dict[str, float]] = {}
        self.final_values: dict[str, float] = {}
        self.e0: list[dict] = []
        self.e1: list[dict] = []

    def started(self, info: LoopInfo) -> None:
        self.info, self.rec = info, info.rows
        self.final = readable(info.plan, self._final_names)
        H, T, n = info.H, info.T, info.n_steps
        # a snapshot is read at a chunk boundary before the last step (t = k H, 0 < k < n_steps)
        steps = {int(round(ts / H)) for ts in self._snapshot_times if 0 < ts < T} if self.final else set()
        self.snap_steps = sorted(k for k in steps if k < n)
        self.e0 = energy_reads(info.plan, info.slaves)

    def next_call(self, k: int) -> int | None:
        return self.snap_steps[0] if self.snap_steps else None

    def stepped(self, chunk: Chunk) -> None:
        snap = self.snap_steps
        if snap and snap[0] <= chunk.k:          # read after step k-1 (at t = k H)
            self.snapshots[chunk.k * self.info.H] = read_values(self.info.slaves, self.final)
            snap.pop(0)

    def finished(self, end: LoopEnd) -> None:
        if end.aborted:
            return
        if end.failure is None:
            self.e1 = energy_reads(self.info.plan, self.info.slaves)
        self.final_values = read_values(self.info.slaves, self.final)

    def signals(self, k_done: int, anti_alias: str) -> tuple[dict, dict]:
        """The recorded names at the output rate (anti-aliased, decimated) and their units."""
        info = self.info
        plan, valid = info.plan, self.rec[:k_done + 1]
        col = {n: j for j, n in enumerate(plan.y_names)}
        units, signals = {}, {}
        if self.record:
            cols = [col[r] for r in self.record]
            dec = decimate(valid[:, cols], 1.0 / info.H, info.output_rate_Hz, method=anti_alias)
            for j, r in enumerate(self.record):
                signals[r] = dec[:, j]
                comp, vn = split_ref(r)
                units[r] = plan.infos[[c.name for c in plan.comps].index(comp)].variables[vn].unit
        return signals, units

    def raw(self, k_done: int) -> dict[str, np.ndarray]:
        """The internal-rate records of the completed steps ("time" + every exchanged name)."""
        valid = self.rec[:k_done + 1]
        raw = {"time": np.arange(k_done + 1) * self.info.H}
        raw.update({n: valid[:, j].copy() for j, n in enumerate(self.info.plan.y_names)})
        return raw


class Progress(Observer):
    """The progress reporter: a tqdm bar, by default (``show`` None) for every run whose loop lasts more than
    2 s (it appears then); ``show`` True: from the start; False: none."""

    def __init__(self, show: bool | None):
        self.show = show
        self.bar = None

    def started(self, info: LoopInfo) -> None:
        if self.show is not False:
            from tqdm import tqdm

            self.bar = tqdm(total=info.n_steps, unit="step", unit_scale=True, desc=f"co-sim {info.T:g} s",
                            mininterval=0.5, leave=False, delay=0.0 if self.show else 2.0)

    def stepped(self, chunk: Chunk) -> None:
        if self.bar is not None:
            self.bar.update(chunk.n)

    def finished(self, end: LoopEnd) -> None:
        if self.bar is not None:
            self.bar.close()


class LoopClock(Observer):
    """The stepping loop's wall and CPU time (``loop_s``, ``cpu_s``; ``t0`` its start), and its cost per step
    in each chunk (the time since the previous chunk ended, over the chunk's steps)."""

    def __init__(self):
        self.t0 = self.cpu0 = 0.0
        self.loop_s = 0.0
        self.cpu_s: float | None = None
        self.chunk_costs: list[float] = []
        self._last = 0.0

    def started(self, info: LoopInfo) -> None:
        self.t0, self.cpu0 = time.perf_counter(), time.process_time()
        self._last = self.t0

    def stepped(self, chunk: Chunk) -> None:
        now = time.perf_counter()
        self.chunk_costs.append((now - self._last) / chunk.n)
        self._last = now

    def finished(self, end: LoopEnd) -> None:
        self.loop_s = time.perf_counter() - self.t0
        self.cpu_s = time.process_time() - self.cpu0

    def us_per_step_steady(self, k_done: int) -> float:
        """Median over the chunks, the first (JIT warm-up) excluded."""
        steady = self.chunk_costs[1:] if len(self.chunk_costs) > 1 else self.chunk_costs
        return 1e6 * float(np.median(steady)) if steady else 1e6 * self.loop_s / max(k_done, 1)
