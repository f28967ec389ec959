"""Run one scene: assemble, co-simulate, post-process, write the result files.

``run_scene(scene, out_dir, backend="fmi", progress=True) -> RunResult``; the ``drivetrain run`` command
is a thin shell over it.

Every summary has ``status`` ("ok" | "failed") and a ``stability`` block (:func:`stability_summary`,
from the gear stage's cumulative counters read once at the end). When an FMU fails during the run,
nothing computed is lost: the completed part is post-processed and written like a normal run (signals
up to the last whole output sample before the failure, summary with ``status = "failed"`` and a
``failure`` block) and :class:`RunFailedError` (a CosimError) is raised carrying that RunResult.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import time as _time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drivetrain import __version__
from drivetrain.cosim import CosimResult, Master
from drivetrain.cosim.plan import split_ref
from drivetrain.fmu_build.fmu_check import fmu_archive_problems
from drivetrain.fmu_build.fmus import load_fmu_info
from drivetrain.errors import ConfigurationError, CosimError, RunFailedError, RunInterrupted  # noqa: F401  (re-exported)
from drivetrain.models import stability
from drivetrain.rig import instruments
from drivetrain.rig.data import RIG_SENSORS, TORQUE_SENSORS
from drivetrain.rig.signals import (amplitude_near, characteristic_frequencies, run_spectrum, spectrum_lowpass_Hz, stats,
                                    to_db)
from drivetrain.run import accuracy
from drivetrain.run import cost as runcost
from drivetrain.run import outputs as O
from drivetrain.run.files import nonfinite_counts, nonfinite_text
from drivetrain.run.lock import output_lock
from drivetrain.scene.expect import RUN_SUMMARY_TREE, SUMMARY_TREE
from drivetrain.scene.load import Scene
from drivetrain.system import BACKENDS, SystemSpec
from gearcontact_fmu.fault_specs import FaultGeometryError, health_faults
from gearcontact_fmu.params import FLANGE_QUANTITIES, GEAR_MODEL
from gearcontact_fmu.progress import reporter

#: messages for the user (progress, warnings); the CLI passes its own ``log``, a library caller sees them
#: through Python logging (on stderr when logging is not configured)
_LOG = logging.getLogger(__name__)

#: the top-level keys of summary.json (declared once, with their subtrees, in scene.expect.SUMMARY_TREE)
SUMMARY_KEYS = tuple(SUMMARY_TREE)

#: What is read from the gear stage FMU (GEAR_MODEL) once at the end of a run (and at a failure) for
#: ``summary["stability"]``: its cumulative stability counters (docs/FMU.md) and two parameters.
#: read from every FMU that has it (ours with spring-side ports): the work mismatch of its cuts still
#: pending at the end of the run (gearcontact_fmu.coupling)
COUPLING_VAR = "coupling_energy_error"
GEAR_FINAL_VARS = ("peak_penetration", "min_substep", "n_substeps", "n_refinements", "separated_time",
                   "n_separations", "u_max", "max_substep")


@dataclass
class RunResult:
    """What a run produced (files only when ``out_dir`` was given)."""

    scene: Scene
    summary: dict                           # the content of summary.json
    time: np.ndarray                        # output sample times [s]
    signals: dict[str, np.ndarray]          # sensor name or "component.variable" -> samples
    units: dict[str, str]
    sources: dict[str, str]                 # channel -> "component.variable" it came from
    cosim: CosimResult                      # master result (energy audit, timing, logs)
    spec: SystemSpec
    out_dir: Path | None = None
    files: dict[str, Any] = field(default_factory=dict)   # signals, summary, plots (list), csv

    @property
    def status(self) -> str:
        """"ok", or "failed" (an FMU failed; the result holds the completed part)."""
        return self.summary.get("status", "ok")

    @property
    def wall_time_s(self) -> float:
        return self.summary["wall_time_s"]

    @property
    def real_time_factor(self) -> float:
        return self.summary["real_time_factor"]

    @property
    def energy(self) -> dict:
        return self.cosim.energy

    def settled(self, name: str) -> np.ndarray:
        """Samples of a channel after the settling time."""
        return self.signals[name][self.time >= self.scene.time.settle_s]

    def to_dataframe(self, settled_only: bool = False):
        """The channels as a pandas DataFrame: index ``time_s`` (the output sample times), one column per
        channel (sensor name or "component.variable", as in ``signals``); every column's unit, and the
        index's ("s"), in ``df.attrs["units"]`` (the units as the FMUs spell them, e.g. "N.m", "rad/s").
        ``settled_only``: the samples after ``time.settle_s`` only."""
        import pandas as pd

        keep = self.time >= self.scene.time.settle_s if settled_only else slice(None)
        df = pd.DataFrame({name: np.asarray(x)[keep] for name, x in self.signals.items()},
                          index=pd.Index(np.asarray(self.time)[keep], name="time_s"))
        df.attrs["units"] = {"time_s": "s", **{name: self.units.get(name, "") for name in self.signals}}
        df.attrs["scene"] = self.scene.name
        return df

    def spectrum(self, channel: str):
        """The amplitude spectrum of a channel as the run's plots and summary read it (rig.signals.run_spectrum:
        settled samples, mean removed, low-pass at 5 x f_GMF, Hann window, single-sided peak amplitude: a sine
        of amplitude a reads a) as a DataFrame ``frequency_Hz``, ``amplitude``; its attrs: ``units``,
        ``convention``, ``characteristic_frequencies`` (f_DSH, f_MSH, f_PSH, f_GMF, harmonics, sidebands),
        ``lowpass_Hz``, ``bin_Hz``, ``channel``."""
        if channel not in self.signals:
            raise KeyError(f"no channel {channel!r} in the run (it has {', '.join(self.signals)})")
        pair = self.scene.gear.pair.params()
        return spectrum_frame(self.time, self.signals[channel], self.scene.time.settle_s,
                              self.scene.time.sample_rate_Hz, self.scene.operating_point.final_speed_rpm,
                              channel, self.units.get(channel, ""), teeth=(pair.z_pinion, pair.z_wheel),
                              upper_ratio=_upper_ratio(self.spec))


def _upper_ratio(spec: SystemSpec | None) -> float:
    """The upper gearbox's ratio of an assembled system (its machine's lumped table; the rig's for a custom spec)."""
    from drivetrain.rig.data import UPPER_RATIO

    return float(((spec.metadata if spec is not None else {}).get("characteristic") or {}).get("upper_ratio", UPPER_RATIO))


def spectrum_frame(time_s, x, settle_s: float, fs: float, drive_speed_rpm: float, channel: str = "", unit: str = "",
                   teeth: tuple[int, int] | None = None, upper_ratio: float | None = None):
    """:func:`drivetrain.rig.signals.run_spectrum` as a DataFrame (``RunResult.spectrum``, ``drivetrain.spectrum``)."""
    import pandas as pd

    from drivetrain.rig.signals import AMPLITUDE_CONVENTION

    f, A, cf = run_spectrum(time_s, x, settle_s, fs, drive_speed_rpm, *([teeth] if teeth else []),
                            **({} if upper_ratio is None else {"upper_ratio": upper_ratio}))
    df = pd.DataFrame({"frequency_Hz": f, "amplitude": A})
    df.attrs.update(units={"frequency_Hz": "Hz", "amplitude": unit}, convention=AMPLITUDE_CONVENTION,
                    characteristic_frequencies=cf, lowpass_Hz=spectrum_lowpass_Hz(cf["f_GMF"]),
                    bin_Hz=float(f[1] - f[0]), channel=channel, settle_s=float(settle_s))
    return df


def stability_summary(res: CosimResult, spec: SystemSpec, time_s: float, energy_residual,
                      settle_s: float = 0.0) -> dict:
    """``summary["stability"]`` from the gear stage's counters (``res.final``, and ``res.snapshots`` at
    ``settle_s``); keys (None where they do not apply: no gear FMU, or it could not be read after a
    failure):

    - ``gear``: the GearContact component the numbers are from; ``time_s``: the time they cover;
    - ``max_penetration_m``: largest element penetration over the run (every sub-step point), ``u_max_m``
      the gear's u_max, ``max_penetration_rel_umax`` their ratio (>= 1 means the mesh error state);
    - ``min_substep_s``: smallest sub-step the stage took, ``max_substep_s`` its nominal sub-step,
      ``n_substeps`` accepted sub-steps, ``n_refinements`` sub-step halvings (contact events);
    - ``energy_residual``: the relative energy residual of the run (None for a failed run);
    - ``coupling_energy_pending_J``: per FMU with spring-side ports, the work mismatch of its cuts not
      yet returned by the energy correction at the end (with ``numerics.energy_correction = false``: the
      whole mismatch, i.e. that FMU's share of the audit's residual);
    - ``rattle``: tooth separation while running, i.e. after the settling time (the start-up transient
      from the assembled initial state may bounce the teeth once or twice): ``window_s`` = [settle_s,
      time_s] (the part of the run it covers), ``separated`` (the teeth lost contact at least once in
      it), ``separated_time_s`` (time out of contact), ``separated_fraction`` (of the window),
      ``n_separations`` (contact-loss events); ``whole_run``: the same three numbers from t = 0.
      (None when the window is empty, e.g. a run that failed before settle_s.)
    """
    g = next((c.name for c in spec.components_of(GEAR_MODEL)), None)

    def val(name):
        return res.final.get(f"{g}.{name}") if g is not None else None

    def count(name):
        v = val(name)
        return int(round(v)) if v is not None and np.isfinite(v) else None

    def fraction(t_sep, span):
        return float(min(max(t_sep / span, 0.0), 1.0)) if t_sep is not None and span > 0 else None

    pen, umax = val("peak_penetration"), val("u_max")
    n_sub = count("n_substeps")
    tsep, nsep = val("separated_time"), count("n_separations")
    # the running part: counters at the end minus the counters read at settle_s
    t0 = max(float(settle_s), 0.0)
    w_tsep, w_nsep = (tsep, nsep) if t0 == 0.0 else (None, None)      # None: window empty or unread
    if t0 > 0.0 and g is not None and res.snapshots and tsep is not None and nsep is not None:
        ts = min(res.snapshots, key=lambda x: abs(x - t0))
        snap = res.snapshots[ts]
        a, b = snap.get(f"{g}.separated_time"), snap.get(f"{g}.n_separations")
        if abs(ts - t0) <= 0.5 * res.comm_step_s + 1e-12 and a is not None and b is not None:
            w_tsep, w_nsep = tsep - a, nsep - int(round(b))
    window = max(time_s - t0, 0.0)
    return {
        "gear": g,
        "time_s": float(time_s),
        "max_penetration_m": pen,
        "u_max_m": umax,
        "max_penetration_rel_umax": (pen / umax) if pen is not None and umax else None,
        "min_substep_s": val("min_substep") if n_sub else None,
        "max_substep_s": val("max_substep"),
        "n_substeps": n_sub,
        "n_refinements": count("n_refinements"),
        "energy_residual": energy_residual,
        "coupling_energy_pending_J": {c.name: res.final[f"{c.name}.{COUPLING_VAR}"] for c in spec.components
                                      if f"{c.name}.{COUPLING_VAR}" in res.final},
        "rattle": {
            "window_s": [t0, float(time_s)],
            "separated": (bool(w_nsep > 0 or w_tsep > 0) if w_nsep is not None and w_tsep is not None else None),
            "separated_time_s": w_tsep,
            "separated_fraction": fraction(w_tsep, window),
            "n_separations": w_nsep,
            "whole_run": {"separated_time_s": tsep, "separated_fraction": fraction(tsep, time_s),
                          "n_separations": nsep},
        },
    }


def failure_summary(res: CosimResult, spec: SystemSpec) -> dict | None:
    """``summary["failure"]`` of a failed run: the master's failure record (``time_s``, ``component``,
    ``model``, ``function``, ``status``, ``cause``, ``log``, ``steps_completed``,
    ``last_sample_time_s``) with ``outputs`` = the failed FMU's numeric outputs read after the failure
    (None if it could not answer) and ``gear_state`` = the gear FMU's outputs (pinion/wheel angle and
    speed, max_penetration, the stability counters, ...; None without a readable gear FMU)."""
    if res.failure is None:
        return None
    f = dict(res.failure)
    outs = f.pop("outputs", None) or {}
    gear = next((c.name for c in spec.components_of(GEAR_MODEL)), None)
    f["outputs"] = outs.get(f["component"])
    f["gear"] = gear
    f["gear_state"] = outs.get(gear) if gear is not None else None
    return f


def nonfinite_failure(ch: Channels, counts: dict) -> dict:
    """``summary["failure"]`` of a run that completed with non-finite samples (no FMU failed): where the first
    one is, and how many there are per channel (drivetrain.run.files.nonfinite_text)."""
    first = min(int(np.argmax(~np.isfinite(np.asarray(ch.signals[k], dtype=float)))) for k in counts)
    t_first = float(ch.time[first]) if len(ch.time) else None
    return {"time_s": t_first, "component": None, "model": None, "function": None, "status": None,
            "cause": "non-finite samples: " + nonfinite_text(counts, len(ch.time)), "log": [],
            "steps_completed": None, "last_sample_time_s": float(ch.time[-1]) if len(ch.time) else None,
            "outputs": None, "gear": None, "gear_state": None}


def _fidelity(c, spec: SystemSpec):
    meta = spec.metadata.get("fidelity") or spec.metadata.get("fidelities") or {}
    if isinstance(meta, dict) and c.name in meta:
        return meta[c.name]
    for k in ("fidelity", "mesh_contact", "mode", "model_fidelity"):
        if k in c.parameters:
            return c.parameters[k]
    return None


def assemble_scene(scene: Scene) -> SystemSpec:
    try:
        from drivetrain.run.assemble import assemble
    except ImportError as exc:
        raise ConfigurationError(f"the assembler (drivetrain.run.assemble) is not available: {exc}") from None
    return assemble(scene)


def _natural_frequencies(spec: SystemSpec, n: int = 6) -> list[float] | None:
    """The lowest elastic natural frequencies [Hz] of the assembled, linearised drivetrain (free-free,
    undamped, ISO mean mesh stiffness; as ``drivetrain eigen``): a few ms. None for a system the linear
    model does not know (custom FMUs)."""
    try:
        from drivetrain.models.eigen import natural_frequencies

        return [float(f) for f in natural_frequencies(spec)[:n]]
    except Exception:  # noqa: BLE001 - a summary entry, never a reason to lose a run
        return None


@dataclass
class RunPlan:
    """What a run is, decided before any step (:func:`prepare_run`): the scene (after a tolerance's
    setting), its assembled system, the backend and FMUs that run it, what is recorded, the checks."""

    scene: Scene
    spec: SystemSpec
    backend: str                        # "fmi" | "inprocess" | "native" (native without a compiler: "fmi")
    fmu_paths: dict | None
    sources: dict[str, str]             # channel -> "component.variable" it comes from
    contact_cost: list                  # stability.check_contact_cost's reports
    contact_range: Any                  # stability.check_contact_range's report
    choice: Any = None                  # the accuracy choice of numerics.tolerance_pct (None without)
    warnings: list[str] = field(default_factory=list)
    t_start: float = 0.0                # perf_counter marks: the call, the native build, the master
    t_native: float = 0.0
    t_master: float = 0.0
    t_started: float = 0.0              # where the wall time starts: the process start (CLI) or t_start

    @property
    def record(self) -> list[str]:
        """The "component.variable"s the master records (each once)."""
        return list(dict.fromkeys(self.sources.values()))

    @property
    def final(self) -> list[str]:
        """What is read once at the end (and at a failure): the gear's counters, the pending coupling work."""
        names = [f"{c.name}.{v}" for c in self.spec.components_of(GEAR_MODEL) for v in GEAR_FINAL_VARS]
        return names + [f"{c.name}.{COUPLING_VAR}" for c in self.spec.components]


@dataclass
class Channels:
    """The output channels of a run as the summary and the files see them (after the rig's instruments)."""

    time: np.ndarray
    signals: dict[str, np.ndarray]
    units: dict[str, str]


@dataclass
class Spectra:
    """The torque channels' statistics, spectra and peaks at the characteristic frequencies."""

    cf: dict                            # characteristic frequencies (rig.signals.characteristic_frequencies)
    torque: dict = field(default_factory=dict)      # sensor -> stats
    spectra: dict = field(default_factory=dict)     # sensor -> (f, A) (for the plots)
    peaks: dict = field(default_factory=dict)       # sensor -> harmonics and sidebands


def _tolerance_setting(scene: Scene, log):
    """The cheapest studied setting within ``numerics.tolerance_pct`` -> (scene, choice); as is without."""
    if scene.numerics.tolerance_pct is None:
        return scene, None
    try:
        scene, choice = accuracy.apply_tolerance(scene)
    except (FileNotFoundError, ValueError) as exc:
        raise ConfigurationError([f"numerics.tolerance_pct = {scene.numerics.tolerance_pct:g}: {exc}"]) from None
    log(f"tolerance {choice.tolerance_pct:g} %: setting {choice.setting!r}: {choice.why}")
    return scene, choice


def _check_cost(plan: RunPlan, force: bool, log) -> None:
    """Refuse before any step a contact model too costly for the scene's budget, a u_max the static load
    alone would pass, or a run predicted far beyond its simulated time (unless ``force``)."""
    scene, spec = plan.scene, plan.spec
    try:
        plan.contact_cost = stability.check_contact_cost(
            spec, scene.time.duration_s, float("inf") if force else scene.numerics.max_contact_hours)
        plan.contact_range = stability.check_contact_range(spec)
    except (stability.ContactCostError, stability.ContactRangeError) as exc:
        raise ConfigurationError(exc.problems) from None
    except FaultGeometryError as exc:
        raise ConfigurationError([str(exc)]) from None
    too_costly = runcost.refusal(runcost.predict(spec, scene.time.duration_s, plan.backend, plan.contact_cost))
    if too_costly and not force:
        raise ConfigurationError([too_costly])
    if too_costly:
        plan.warnings.append(f"forced: {too_costly}")
        log(f"warning: forced: {too_costly}")
    for rep in plan.contact_cost:
        if rep.get("warning"):
            plan.warnings.append(rep["warning"])
            log(f"warning: {rep['warning']}")
    H = scene.numerics.comm_step_s      # what the scene asked, against what a given system fixes
    if abs(spec.comm_step - H) > 1e-12 * H:
        plan.warnings.append(f"the assembled system uses comm_step {spec.comm_step:.10g} s, the scene asks for {H:.10g} s")


def _sources(scene: Scene, spec: SystemSpec, warnings: list[str]) -> dict[str, str]:
    """Channel -> "component.variable": the scene's sensors the system provides, and its variables."""
    sensor_map = dict(spec.metadata.get("sensors", {}))
    sources: dict[str, str] = {}
    for s in scene.outputs.sensors:
        if s in sensor_map:
            sources[s] = sensor_map[s]
        else:
            warnings.append(f"sensor {s!r} is not provided by the assembled system "
                            f"(available: {', '.join(sensor_map) or 'none'}); skipped")
    for v in scene.outputs.variables:
        sources[v] = v
    return sources


def _choose_backend(plan: RunPlan, fmu_dir, log) -> None:
    """Check the backend; for "native", the compiled FMUs (built once, kept in <fmu_dir>/native; an explicit
    fmu_paths entry wins), or without a compiler the pythonfmu FMUs (backend "fmi"), said so."""
    if plan.backend not in BACKENDS:
        raise ConfigurationError([f"backend {plan.backend!r}: expected one of {', '.join(BACKENDS)}"])
    if plan.backend != "native":
        return
    from drivetrain.fmu_build.fmus import fmu_dir_or_default
    from drivetrain.fmu_build.native_line import native_fmus, toolchain_problems

    missing = toolchain_problems()
    if missing:
        note = f"{'; '.join(missing)}: the run uses the pythonfmu FMUs (backend fmi)"
        plan.backend = "fmi"
    else:
        native, note = native_fmus(plan.spec, fmu_dir_or_default(fmu_dir) / "native", log=log)
        plan.fmu_paths = {**native, **(plan.fmu_paths or {})}
    if note:
        plan.warnings.append(f"backend native: {note}")
        log(f"warning: backend native: {note}")


def prepare_run(scene: Scene, spec: SystemSpec | None, backend: str, fmu_paths: dict | None, *, fmu_dir,
                force: bool, log, started: float | None = None) -> RunPlan:
    """Everything before the first step: the tolerance's setting, the assembly (unless ``spec`` is given),
    the cost and contact checks, the channels, the backend and its FMUs. Raises ConfigurationError.
    ``started``: the perf_counter reading the wall time counts from (default: now)."""
    t_start = _time.perf_counter()
    choice = None
    assembled = spec is None
    if assembled:
        scene, choice = _tolerance_setting(scene, log)
        spec = assemble_scene(scene)
    plan = RunPlan(scene=scene, spec=spec, backend=backend, fmu_paths=fmu_paths, sources={}, contact_cost=[],
                   contact_range=None, choice=choice, t_start=t_start,
                   t_started=t_start if started is None else min(started, t_start))
    _check_cost(plan, force, log)
    if assembled:            # past the cost checks the table map may be built (the run needs it): the start only
        from drivetrain.run.assemble import start_with_map

        plan.spec = spec = start_with_map(scene, spec)
    plan.sources = _sources(scene, spec, plan.warnings)
    check_given_fmus(spec, fmu_paths)
    plan.t_native = _time.perf_counter()
    _choose_backend(plan, fmu_dir, log)
    plan.t_master = _time.perf_counter()
    return plan


def check_given_fmus(spec: SystemSpec, fmu_paths: dict | None) -> None:
    """The FMUs a caller hands over ({model: path}, ``--fmu``), checked before they are used or the output
    folder says "running": the archive (drivetrain.fmu_build.fmu_check: a zip, safe entries, a bounded model
    description without a DTD, FMI 2.0 co-simulation, the model asked for, its GUID) and every variable the
    system needs of it (parameters, inputs, the flanges of its connections). Raises ConfigurationError."""
    problems: list[str] = []
    for model, path in (fmu_paths or {}).items():
        problems += fmu_archive_problems(path, model)
    if problems:
        raise ConfigurationError(problems)
    for model, path in (fmu_paths or {}).items():
        have = load_fmu_info(path).variables
        for c in spec.components:
            if c.model != model:
                continue
            ports = [split_ref(ref)[1] for conn in spec.connections for ref in (conn.spring, conn.inertia)
                     if split_ref(ref)[0] == c.name]
            need = [*c.parameters, *c.inputs, *(f"{p}_{q}" for p in ports for q in FLANGE_QUANTITIES)]
            missing = sorted({n for n in need if n not in have})
            if missing:
                problems.append(f"{path}: the FMU given for {model} lacks variables the system needs of "
                                f"{c.name}: {', '.join(missing[:12])}" + (" ..." if len(missing) > 12 else ""))
    if problems:
        raise ConfigurationError(problems)


def simulate_plan(plan: RunPlan, *, fmu_dir, build: bool, progress: bool, log):
    """Co-simulate -> (CosimResult, None), or after an FMU failure (the completed part, its CosimError);
    a failure before the first step raises the master's CosimError."""
    scene = plan.scene
    master = Master(plan.spec, fmu_dir=fmu_dir, backend="fmi" if plan.backend == "native" else plan.backend,
                    fmu_paths=plan.fmu_paths, build=build, log=log)
    failed: CosimError | None = None
    try:
        res = master.run(scene.time.duration_s, scene.time.sample_rate_Hz, plan.record,
                         progress=None if progress else False, anti_alias=scene.numerics.anti_alias,
                         final=plan.final, snapshots=(scene.time.settle_s,))
    except CosimError as exc:
        if exc.partial is None:
            raise
        failed, res = exc, exc.partial
    plan.warnings.extend(res.warnings)
    if isinstance(failed, RunInterrupted):
        plan.warnings.append(f"the run was {failed}; results up to t = {res.time[-1]:.9g} s")
    elif failed is not None:
        plan.warnings.append(f"the run failed at t = {failed.time:.9g} s ({failed.component}: "
                             f"{res.failure['cause']}); results up to t = {res.time[-1]:.9g} s")
    return res, failed


def measured_channels(plan: RunPlan, res: CosimResult) -> Channels:
    """The recorded variables as the scene's channels: through the rig's instruments when
    ``effects.sensors = "rig"``, with their units."""
    scene = plan.scene
    signals = {name: res.signals[src] for name, src in plan.sources.items()}
    if scene.effects.sensors == "rig":      # what the rig's instruments would have reported
        signals = instruments.measure(signals, scene.time.sample_rate_Hz, scene.instruments, scene.noise_name)
        if abs(scene.time.sample_rate_Hz - instruments.RIG_SAMPLE_RATE_HZ) > 1e-9:
            plan.warnings.append(f"rig sensors sampled at time.sample_rate_Hz = {scene.time.sample_rate_Hz:g} Hz; the "
                                 f"rig's clock is {instruments.RIG_SAMPLE_RATE_HZ:g} Hz (with numerics.comm_step_s = "
                                 f"1/12048 s)")
    units = {}
    for name, src in plan.sources.items():
        u = res.units.get(src)
        if u is None and name in RIG_SENSORS:
            u = RIG_SENSORS[name][0]
        units[name] = u or ""
    return Channels(time=res.time, signals=signals, units=units)


def _peaks(f: np.ndarray, A: np.ndarray, cf: dict, fs: float) -> dict:
    """The amplitudes of a spectrum at the GMF harmonics and its sidebands (dB re GMF)."""
    pk = {"bin_Hz": float(f[1] - f[0]),
          "GMF_harmonics": [{"k": k, "f_Hz": h, "amplitude": amplitude_near(f, A, h)}
                            for k, h in enumerate(cf["harmonics"], start=1) if h < fs / 2],
          "sidebands": [{"k": sb["k"], "lower_Hz": sb["lower"], "upper_Hz": sb["upper"],
                         "lower_amplitude": amplitude_near(f, A, sb["lower"]),
                         "upper_amplitude": amplitude_near(f, A, sb["upper"])}
                        for sb in cf["sidebands"]]}
    g = pk["GMF_harmonics"][0]["amplitude"] if pk["GMF_harmonics"] else float("nan")
    for sb in pk["sidebands"]:
        sb["lower_dB_re_GMF"] = float(to_db(sb["lower_amplitude"] / g)) if g > 0 else None
        sb["upper_dB_re_GMF"] = float(to_db(sb["upper_amplitude"] / g)) if g > 0 else None
    return pk


def torque_spectra(plan: RunPlan, ch: Channels) -> Spectra:
    """Statistics of the torque channels after the settling time, their spectra (low-passed at 5 x f_GMF)
    and the peaks at the characteristic frequencies of the final drive speed."""
    scene = plan.scene
    m = ch.time >= scene.time.settle_s
    fs = scene.time.sample_rate_Hz
    pair = scene.gear.pair.params()
    ur = _upper_ratio(plan.spec)
    out = Spectra(cf=characteristic_frequencies(scene.operating_point.final_speed_rpm, pair.z_pinion, pair.z_wheel,
                                                upper_ratio=ur))
    for name in TORQUE_SENSORS:
        if name not in ch.signals:
            continue
        x = ch.signals[name][m]
        if not len(x):               # a failed run that ended before settle_s
            continue
        out.torque[name] = {**stats(x), "unit": ch.units[name]}
        if len(x) > 16 and out.cf["f_GMF"] > 0:
            try:
                f, A, _ = run_spectrum(ch.time, ch.signals[name], scene.time.settle_s, fs,
                                       scene.operating_point.final_speed_rpm, (pair.z_pinion, pair.z_wheel), ur)
            except ValueError as exc:    # too short for the low-pass (a short or failed run)
                plan.warnings.append(f"no spectrum of {name}: {exc}")
                continue
            out.spectra[name] = (f, A)
            out.peaks[name] = _peaks(f, A, out.cf, fs)
    return out


def _timing(plan: RunPlan, res: CosimResult) -> dict:
    """The summary's timing entries: the wall time from ``plan.t_started`` (the process start when the
    command line runs it, else the call) to now, and its parts, which add up to it (``write`` and ``plots``
    are filled in, and the wall time extended by them, when the files are written: :func:`write_run`)."""
    now = _time.perf_counter()
    startup = plan.t_start - plan.t_started
    before = plan.t_master - plan.t_start
    run_part = now - plan.t_start
    wall = now - plan.t_started
    return {
        "wall_time_s": wall,
        "sim_time_s": res.sim_time_s,
        "requested_sim_time_s": plan.scene.time.duration_s,
        "real_time_factor": res.real_time_factor if res.loop_time_s > 0 else None,
        "real_time_factor_wall": res.sim_time_s / wall if wall > 0 else None,
        "loop_time_s": res.loop_time_s,
        "loop_cpu_time_s": res.loop_cpu_time_s,
        "time_breakdown_s": {"startup": startup,
                             "assemble_and_check": plan.t_native - plan.t_start,
                             "native_build": plan.t_master - plan.t_native,
                             "fmu_setup": res.setup_time_s,
                             "loop": res.loop_time_s,
                             "postprocess": max(0.0, run_part - before - res.setup_time_s - res.loop_time_s),
                             "write": None, "plots": None},
    }


def _scene_labels(plan: RunPlan) -> dict:
    """The summary's labels of what ran: operating point, health, effects, drawn errors, instruments."""
    scene, op = plan.scene, plan.scene.operating_point
    return {
        "operating_point": {"drive_speed_rpm": op.final_speed_rpm, "load_torque_Nm": op.load_torque_Nm,
                            "profiles": bool(op.speed_profile_rpm or op.load_profile_Nm)},
        "health": scene.gear.health,
        "fault_contact": fault_contact_labels(plan.spec, plan.warnings),
        "effects": dataclasses.asdict(scene.effects),
        # the drawn errors (per tooth, eccentricities, phases) and how they were drawn: the labels of the run
        "manufacturing_errors": plan.spec.metadata.get("manufacturing_errors"),
        "instruments": dataclasses.asdict(scene.instruments) if scene.effects.sensors == "rig" else None,
    }


def fault_contact_labels(spec: SystemSpec, warnings: list | None = None) -> list[dict]:
    """How much contact each fault of the system's gear gets at its start load
    (:mod:`gearcontact_fmu.fault_contact`): per fault of its health (the paper's mild and severe as their
    specifications) ``contact_share``, ``mesh_torque_drop`` and the ``loaded_flank``; [] for a healthy gear,
    a user's mesh files, an unloaded start or no GearContact. A label that cannot be computed is None, with
    the reason in ``warnings``: it never fails the run."""
    gears = spec.components_of("GearContact")
    steady = spec.metadata.get("steady_state") or {}
    if not gears or not steady.get("T_msh"):
        return []
    g = gears[0].parameters
    specs = health_faults(str(g.get("health", "healthy")), json.loads(str(g.get("faults") or "[]")))
    if not specs or g.get("pinion_mesh_file") or g.get("wheel_mesh_file"):
        return []
    from gearcontact_fmu import fault_contact as fc
    from gearcontact_fmu.contact_map import get_map
    from gearcontact_fmu.fmu_parameters import stage_arguments
    from gearcontact_fmu.fmu_variables import parameter_values
    from gearcontact_fmu.mesh_models.pcm import fault_kwargs_of
    from gearcontact_fmu.params import MapGrid

    torque = float(steady["T_msh"])
    out = [{"loaded_flank": fc.loaded_flank(torque), "contact_share": None, "mesh_torque_drop": None} for _ in specs]
    try:
        (_, gear, pcm, res), kw = stage_arguments(parameter_values({**g, "fidelity": "table"}))
        regions = fc.loaded_regions(gear, pcm, res, torque)
        for row, f in zip(out, specs):
            row["contact_share"] = fc.contact_share(f, regions, gear)
        grid = kw.get("grid") or MapGrid()
        healthy = get_map(gear, pcm, res, "healthy", None, grid)
        faulty = get_map(gear, pcm, res, kw["health"], None, grid, fault_kwargs=fault_kwargs_of(kw["health"],
                                                                                          kw.get("faults") or ()))
        drop = fc.mesh_torque_drop(healthy, faulty, torque)
        for row in out:                    # the maps hold every fault of the gear at once: one drop for all
            row["mesh_torque_drop"] = drop
    except Exception as exc:  # noqa: BLE001 - a label, not the run: say why it is missing
        if warnings is not None:
            warnings.append(f"fault contact labels not computed: {type(exc).__name__}: {exc}")
    return out


def build_summary(plan: RunPlan, res: CosimResult, failed: CosimError | None, ch: Channels, sp: Spectra) -> dict:
    """summary.json of a run (``files`` and ``write_time_s`` are added when it is written): the keys of
    :data:`drivetrain.scene.expect.RUN_SUMMARY_TREE`, in its order (the tests check the subtrees)."""
    scene, spec = plan.scene, plan.spec
    m = ch.time >= scene.time.settle_s
    channel_stats = {name: {**stats(x[m]), "unit": ch.units[name]} for name, x in ch.signals.items() if m.any()}
    counts = nonfinite_counts(ch.signals)
    nonfinite = list(counts)
    energy_residual = res.energy.get("relative_residual")
    covered = res.sim_time_s if failed is None else max(float(failed.time), res.sim_time_s)
    status, failure = res.status, failure_summary(res, spec)
    if counts and status == "ok":            # a run whose samples are not all numbers did not succeed
        status, failure = "failed", nonfinite_failure(ch, counts)
    summary = {
        "name": scene.name, "status": status, "failure": failure,
        "description": scene.scenario.description,
        "source": str(scene.source) if scene.source else None,
        "overrides": list(scene.overrides),
        "backend": plan.backend,
        **_timing(plan, res),
        "us_per_step": res.us_per_step,
        "us_per_step_steady": res.us_per_step_steady,
        "n_steps": res.n_steps,
        "comm_step_s": res.comm_step_s,
        "sample_rate_Hz": scene.time.sample_rate_Hz,
        "settle_s": scene.time.settle_s,
        "n_fmus": len(spec.components),
        **_scene_labels(plan),
        "torque": sp.torque,
        "channels": channel_stats,
        "f_DSH": sp.cf["f_DSH"], "f_MSH": sp.cf["f_MSH"], "f_PSH": sp.cf["f_PSH"], "f_GMF": sp.cf["f_GMF"],
        "characteristic_frequencies": sp.cf,
        "spectrum_peaks": sp.peaks,
        "energy_residual": energy_residual,
        "energy": res.energy,
        "natural_frequencies_Hz": _natural_frequencies(spec),
        "stability": {**stability_summary(res, spec, covered, energy_residual, scene.time.settle_s),
                      "static_contact": plan.contact_range, "contact_cost": plan.contact_cost},
        "fmus": [{"name": c.name, "model": c.model, "fidelity": _fidelity(c, spec)} for c in spec.components],
        "nonfinite_channels": nonfinite,
        "nonfinite_samples": counts,
        "warnings": plan.warnings,
        "accuracy_choice": plan.choice.to_dict() if plan.choice is not None else None,
        "drivetrain_version": __version__,
    }
    assert list(summary) == list(RUN_SUMMARY_TREE), "summary.json and its declaration (scene.expect) differ"
    return summary


def run_scene(scene: Scene, out_dir: str | Path | None = None, backend: str = "fmi", progress: bool = True,
              *, fmu_dir: str | Path | None = None, spec: SystemSpec | None = None,
              fmu_paths: dict | None = None, plots: bool | None = None, build: bool = True,
              log=None, force: bool = False, started: float | None = None) -> RunResult:
    """Simulate a validated scene and (if out_dir) write signals.h5, summary.json, plots and CSV.

    ``started``: a ``time.perf_counter()`` reading the summary's wall time counts from (the command line
    passes its process start, :func:`drivetrain.run.timing.process_start`, so that ``time_breakdown_s``
    holds the start-up too); default: this call. The parts of ``time_breakdown_s`` add up to ``wall_time_s``.

    ``spec``: use this system instead of ``assemble(scene)`` (tests, custom systems).
    ``fmu_paths``: explicit {model: path} (no building). ``plots``: override ``scene.outputs.plots``.
    Raises ConfigurationError before any step if the system cannot run as specified, or is predicted to
    cost far more than its simulated time (:mod:`drivetrain.run.cost`; ``force=True`` runs it anyway, and
    lifts ``numerics.max_contact_hours``). If an FMU fails
    during the run, the completed part is post-processed (and written: signals up to the failure,
    summary with ``status = "failed"`` and ``failure``) and :class:`RunFailedError` is raised with it
    (a CosimError; a failure before the first step raises the master's CosimError, nothing written).

    The steps: :func:`prepare_run` (assemble, check, choose the backend) -> :func:`simulate_plan` ->
    :func:`measured_channels`, :func:`torque_spectra`, :func:`build_summary` -> :func:`write_run`.
    """
    log = log or _LOG.warning
    started = _time.perf_counter() if started is None else started
    if out_dir is not None:              # a bad --out is found now, not after the simulation
        O.check_output_dir(Path(out_dir), expected_output_bytes(scene), create=False)
    plan = prepare_run(scene, spec, backend, fmu_paths, fmu_dir=fmu_dir, force=force, log=log,
                       started=started)
    if out_dir is None:
        return _simulate_and_write(plan, None, fmu_dir, build, progress, log, plots)
    with output_lock(out_dir):            # a second writer into this folder is refused, naming this process
        O.mark_running(Path(out_dir), scene.name)  # refusals write nothing; from here on it says "running"
        try:
            return _simulate_and_write(plan, out_dir, fmu_dir, build, progress, log, plots)
        except BaseException as exc:     # whatever ended the run: its summary says so, never "running" for good
            O.mark_failed(Path(out_dir), scene.name, exc)
            raise


def _simulate_and_write(plan: RunPlan, out_dir, fmu_dir, build: bool, progress: bool, log, plots) -> RunResult:
    """The run after its checks: co-simulate, post-process, write (a failed run's completed part too)."""
    res, failed = simulate_plan(plan, fmu_dir=fmu_dir, build=build, progress=progress, log=log)
    ch = measured_channels(plan, res)
    sp = torque_spectra(plan, ch)
    summary = build_summary(plan, res, failed, ch, sp)
    result = RunResult(scene=plan.scene, summary=summary, time=ch.time, signals=ch.signals, units=ch.units,
                       sources=plan.sources, cosim=res, spec=plan.spec)
    if out_dir is not None:
        write_run(result, out_dir, plots=plan.scene.outputs.plots if plots is None else plots, spectra=sp.spectra,
                  progress=progress)
    if failed is not None:
        raise RunFailedError(failed, result) from failed
    return result


def expected_output_bytes(scene: Scene) -> int:
    """About what a run writes: its samples of every written channel as doubles (and as CSV text, if asked)."""
    n = int(scene.time.duration_s * scene.time.sample_rate_Hz) + 1
    channels = len(scene.outputs.sensors) + len(scene.outputs.variables) + 1
    return n * channels * 8 * (4 if scene.outputs.aalto_csv else 1)


def _account_writing(summary: dict, plots_s: float, write_s: float) -> None:
    """The writing's part of the summary's times: ``time_breakdown_s`` ``plots`` and ``write`` (the data
    files), ``write_time_s`` (both), and the wall time and its real-time factor grown by them (the
    computing part, ``wall_time_s`` without them, is kept from the first call)."""
    tb = summary["time_breakdown_s"]
    computed = summary["wall_time_s"] - (tb.get("plots") or 0.0) - (tb.get("write") or 0.0)
    tb["plots"], tb["write"] = plots_s, write_s
    summary["write_time_s"] = plots_s + write_s
    summary["wall_time_s"] = wall = computed + plots_s + write_s
    summary["real_time_factor_wall"] = summary["sim_time_s"] / wall if wall > 0 else None


def write_run(result: RunResult, out_dir: str | Path, plots: bool = True, spectra: dict | None = None,
              progress: bool = False) -> dict:
    """Write signals.h5, summary.json, plots and (if asked) sensors.csv into out_dir (``progress``: through
    gearcontact_fmu.progress, i.e. a bar when a front end installed one). Adds ``write`` and ``plots`` to the
    summary's ``time_breakdown_s`` and their time to its ``wall_time_s``."""

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scene = result.scene
    files: dict[str, Any] = {"signals": str(out / "signals.h5"), "summary": str(out / "summary.json")}
    t_w = _time.perf_counter()
    plot_files = []
    # a bar when the files take long (the command line's, shown after a few seconds)
    steps = reporter(f"writing {out}", 2 if plots else 1, unit=" files") if progress else None
    cf = result.summary["characteristic_frequencies"]
    failed = result.status != "ok"
    if plots:
        torques = {n: result.signals[n] for n in TORQUE_SENSORS if n in result.signals}
        failed_at = result.summary["failure"]["time_s"] if failed else None
        try:
            if torques:
                plot_files.append(str(O.plot_torques(out / "torques.png", result.time, torques, scene.time.settle_s,
                                                     cf, title=O.run_title(scene, "torque waveforms", failed_at))))
            if spectra:
                plot_files.append(str(O.plot_spectra(out / "spectra.png", spectra, cf,
                                                     title=O.run_title(scene, "amplitude spectra", failed_at))))
        except Exception as exc:    # noqa: BLE001 - a failed run's plots are optional: keep the data
            if not failed:
                raise
            result.summary["warnings"].append(f"plots of the failed run skipped: {type(exc).__name__}: {exc}")
        if steps is not None:
            steps.update(1)
    t_plots = _time.perf_counter() - t_w
    files["plots"] = plot_files
    if scene.outputs.aalto_csv:
        files["csv"] = str(O.write_aalto_csv(out / "sensors.csv", result.time, result.signals))
    result.summary["files"] = {k: (Path(v).name if isinstance(v, str) else [Path(x).name for x in v])
                               for k, v in files.items()}
    meta = {}
    for name, src in result.sources.items():
        kind = "sensor" if name in RIG_SENSORS else "variable"
        desc = RIG_SENSORS[name][1] if name in RIG_SENSORS else ""
        meta[name] = {"unit": result.units.get(name, ""), "source": src, "kind": kind, "description": desc}
    attrs = {
        "name": scene.name, "scene_json": scene.to_json(), "scene_toml": scene.to_toml(),
        "system_json": json.dumps(O.spec_to_dict(result.spec)),
        "summary_json": json.dumps(O.jsonable(result.summary)),
        "backend": result.summary["backend"], "created": O.now_iso(), "drivetrain_version": __version__,
        "sample_rate_Hz": scene.time.sample_rate_Hz, "comm_step_s": result.cosim.comm_step_s,
        "settle_s": scene.time.settle_s, "duration_s": result.cosim.sim_time_s,
        "status": result.status,
    }
    _account_writing(result.summary, t_plots, _time.perf_counter() - t_w - t_plots)
    O.write_hdf5(out / "signals.h5", result.time, result.signals, meta, attrs, dtype=scene.outputs.dtype)
    # summary.json counts the HDF5 file too (the copy inside signals.h5 is written before it is timed)
    _account_writing(result.summary, t_plots, _time.perf_counter() - t_w - t_plots)
    O.write_summary(out / "summary.json", result.summary)
    if steps is not None:
        steps.update(1)
        steps.close()
    result.out_dir = out
    result.files = files
    return files
