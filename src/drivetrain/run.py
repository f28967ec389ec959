"""Run one scene: assemble, co-simulate, post-process, write the result files.

``run_scene(scene, out_dir, backend="fmi", progress=True) -> RunResult``; the ``drivetrain run`` command
is a thin shell over it.
"""
from __future__ import annotations

import dataclasses
import json
import sys
import time as _time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drivetrain import __version__
from drivetrain.master import ConfigurationError, CosimResult, Master
from drivetrain.scenario import RIG_SENSORS, TORQUE_SENSORS, Scene
from drivetrain.signals import amplitude_near, amplitude_spectrum, characteristic_frequencies, stats, to_db
from drivetrain.system import SystemSpec

SUMMARY_KEYS = (
    "name", "wall_time_s", "sim_time_s", "real_time_factor", "torque", "f_DSH", "f_MSH", "f_PSH", "f_GMF",
    "energy_residual", "fmus",
)


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
        from drivetrain.assemble import assemble
    except ImportError as exc:
        raise ConfigurationError(f"the assembler (drivetrain.assemble) is not available: {exc}") from None
    return assemble(scene)


def run_scene(scene: Scene, out_dir: str | Path | None = None, backend: str = "fmi", progress: bool = True,
              *, fmu_dir: str | Path = "fmus", spec: SystemSpec | None = None,
              fmu_paths: dict | None = None, plots: bool | None = None, build: bool = True,
              log=None) -> RunResult:
    """Simulate a validated scene and (if out_dir) write signals.h5, summary.json, plots and CSV.

    ``spec``: use this system instead of ``assemble(scene)`` (tests, custom systems).
    ``fmu_paths``: explicit {model: path} (no building). ``plots``: override ``scene.outputs.plots``.
    Raises ConfigurationError before any step if the system cannot run as specified, CosimError if an
    FMU fails during the run.
    """
    t0 = _time.perf_counter()
    log = log or (lambda m: print(m, file=sys.stderr))
    warnings: list[str] = []
    if spec is None:
        spec = assemble_scene(scene)
    H = scene.numerics.comm_step_s
    if abs(spec.comm_step - H) > 1e-12 * H:
        warnings.append(f"the assembled system uses comm_step {spec.comm_step:.10g} s, the scene asks for {H:.10g} s")

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
    record = list(dict.fromkeys(sources.values()))

    master = Master(spec, fmu_dir=fmu_dir, backend=backend, fmu_paths=fmu_paths, build=build, log=log)
    res = master.run(scene.time.duration_s, scene.time.sample_rate_Hz, record,
                     progress=None if progress else False, anti_alias=scene.numerics.anti_alias)
    warnings += res.warnings

    signals = {name: res.signals[src] for name, src in sources.items()}
    units = {}
    for name, src in sources.items():
        u = res.units.get(src)
        if u is None and name in RIG_SENSORS:
            u = RIG_SENSORS[name][0]
        units[name] = u or ""
    t = res.time
    settle = scene.time.settle_s
    m = t >= settle

    cf = characteristic_frequencies(scene.operating_point.final_speed_rpm)
    fs = scene.time.sample_rate_Hz
    torque_stats, spectra, peaks = {}, {}, {}
    for name in TORQUE_SENSORS:
        if name not in signals:
            continue
        x = signals[name][m]
        torque_stats[name] = {**stats(x), "unit": units[name]}
        if len(x) > 16 and cf["f_GMF"] > 0:
            f, A = amplitude_spectrum(x, fs, lowpass_Hz=5.0 * cf["f_GMF"])
            spectra[name] = (f, A)
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
            peaks[name] = pk
    channel_stats = {name: {**stats(x[m]), "unit": units[name]} for name, x in signals.items() if m.any()}
    nonfinite = [n for n, x in signals.items() if not np.all(np.isfinite(x))]

    energy = res.energy
    fmus = [{"name": c.name, "model": c.model, "fidelity": _fidelity(c, spec)} for c in spec.components]
    wall = _time.perf_counter() - t0
    summary = {
        "name": scene.name,
        "description": scene.scenario.description,
        "source": str(scene.source) if scene.source else None,
        "overrides": list(scene.overrides),
        "backend": backend,
        "wall_time_s": wall,
        "sim_time_s": res.sim_time_s,
        "real_time_factor": res.sim_time_s / wall if wall > 0 else None,
        "loop_time_s": res.loop_time_s,
        "us_per_step": res.us_per_step,
        "us_per_step_steady": res.us_per_step_steady,
        "n_steps": res.n_steps,
        "comm_step_s": res.comm_step_s,
        "sample_rate_Hz": fs,
        "settle_s": settle,
        "n_fmus": len(spec.components),
        "operating_point": {"drive_speed_rpm": scene.operating_point.final_speed_rpm,
                            "load_torque_Nm": scene.operating_point.load_torque_Nm,
                            "profiles": bool(scene.operating_point.speed_profile_rpm
                                             or scene.operating_point.load_profile_Nm)},
        "health": scene.gear.health,
        "effects": dataclasses.asdict(scene.effects),
        "torque": torque_stats,
        "channels": channel_stats,
        "f_DSH": cf["f_DSH"], "f_MSH": cf["f_MSH"], "f_PSH": cf["f_PSH"], "f_GMF": cf["f_GMF"],
        "characteristic_frequencies": cf,
        "spectrum_peaks": peaks,
        "energy_residual": energy["relative_residual"],
        "energy": energy,
        "fmus": fmus,
        "nonfinite_channels": nonfinite,
        "warnings": warnings,
        "drivetrain_version": __version__,
    }
    result = RunResult(scene=scene, summary=summary, time=t, signals=signals, units=units, sources=sources,
                       cosim=res, spec=spec)
    if out_dir is not None:
        write_run(result, out_dir, plots=scene.outputs.plots if plots is None else plots, spectra=spectra)
    return result


def write_run(result: RunResult, out_dir: str | Path, plots: bool = True, spectra: dict | None = None) -> dict:
    """Write signals.h5, summary.json, plots and (if asked) sensors.csv into out_dir."""
    from drivetrain import outputs as O

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scene = result.scene
    files: dict[str, Any] = {"signals": str(out / "signals.h5"), "summary": str(out / "summary.json")}
    t_w = _time.perf_counter()
    plot_files = []
    cf = result.summary["characteristic_frequencies"]
    if plots:
        torques = {n: result.signals[n] for n in TORQUE_SENSORS if n in result.signals}
        if torques:
            plot_files.append(str(O.plot_torques(out / "torques.png", result.time, torques, scene.time.settle_s, cf,
                                                 title=f"{scene.name}: torque waveforms")))
        if spectra:
            plot_files.append(str(O.plot_spectra(out / "spectra.png", spectra, cf,
                                                 title=f"{scene.name}: spectra")))
    files["plots"] = plot_files
    if scene.outputs.aalto_csv:
        files["csv"] = str(O.write_aalto_csv(out / "sensors.csv", result.time, result.signals))
    result.summary["files"] = {k: (Path(v).name if isinstance(v, str) else [Path(x).name for x in v])
                               for k, v in files.items()}
    result.summary["write_time_s"] = _time.perf_counter() - t_w
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
    }
    O.write_hdf5(out / "signals.h5", result.time, result.signals, meta, attrs, dtype=scene.outputs.dtype)
    O.write_summary(out / "summary.json", result.summary)
    result.out_dir = out
    result.files = files
    return files
