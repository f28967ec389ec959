"""What accuracy costs in time: the settings a run can choose, their error against a converged reference
per scene, their cost, and the cheapest setting within a tolerance (``numerics.tolerance_pct``).

The study (``drivetrain accuracy-cost``) runs every studied scene (:data:`STUDY_SCENES`: healthy, mild
and severe at 250 and 1500 rpm, and a wheel fault) with every setting (:data:`SETTINGS`: mesh size,
fidelity, communication step and sub-step, shaft elements, energy correction, realism effects) through
the sweep machinery (local processes or Dask, resumable), and compares each run with the same scene's
``reference`` run (:func:`compare`). Metrics, per torque channel and reported as the worse channel:

* errors of the mean torque, of the fluctuation (standard deviation) and of the peak-to-peak [%];
* level differences at f_GMF and at the first sidebands f_GMF ± f_MSH (± f_PSH for a wheel fault) [dB],
  where the reference's sideband stands at least ``RESOLVED_DB`` above the numerical floor (a healthy
  gear's sidebands are numerical noise, -150 dB re GMF: a difference of noise is no error);
* a spectral distance over 0..5 f_GMF: the L2 norm of the amplitude difference over the reference's [%];
* the run's energy residual; cost: loop seconds per simulated second, and the one-off build time
  (contact map, FMU set-up) apart.

The reference is the ``table`` gear on the converged mesh (0.025 mm profile elements, where the
stiffness moved 0.15 % from 0.05 mm: docs/GEAR-CONTACT.md), with the communication step and sub-step
halved and more shaft elements: a step beyond the defaults in every setting at once. Online PCM at those
settings would cost hours per simulated second (:mod:`drivetrain.run.cost`); the table gear reproduces
online PCM at the same mesh (``pcm`` row; docs/ACCURACY-COST.md). The results ship with the package
(:data:`RESULTS_FILE`), so :func:`choose` needs no re-run. Pure: no printing. The study itself (runs,
evaluation, report, plots) is :mod:`drivetrain.campaigns.accuracy_study`.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivetrain.rig.data import PAPER_MAX_LOAD_NM, PAPER_MAX_SPEED_RPM, PAPER_SPEEDS_RPM, TORQUE_SENSORS
from drivetrain.rig.signals import (amplitude_near, amplitude_spectrum, characteristic_frequencies, spectrum_lowpass_Hz,
                                    to_db)
from drivetrain.scene.load import parse_override, with_overrides
from drivetrain.scene.schema import default_of
from gearcontact_fmu.mesh_models.base import PAPER_HEALTH

ROOT = Path(__file__).resolve().parents[3]
RESULTS_FILE = Path(__file__).resolve().parents[1] / "data" / "accuracy_cost.json"
CHANNELS = TORQUE_SENSORS
STUDY_DURATION_S = 4.5
STUDY_SETTLE_S = 0.5
#: a reference sideband counts (and constrains a setting) only this far above the spectrum's floor [dB]
RESOLVED_DB = 20.0
REFERENCE = "reference"
DEFAULT = "default"


@dataclass(frozen=True)
class Setting:
    """One way to run a scene: ``overrides`` of numerics/effects keys (never of the scene's physics)."""

    name: str
    group: str
    overrides: tuple[str, ...]
    what: str
    #: False: it changes what is simulated (a realism effect), so it is a cost of realism, not an
    #: approximation a tolerance may pick
    choosable: bool = True


_H6000, _H24000, _H48000, _H96000 = 1.0 / 6000.0, 1.0 / 24000.0, 1.0 / 48000.0, 1.0 / 96000.0
SETTINGS: dict[str, Setting] = {s.name: s for s in (
    Setting(REFERENCE, "reference", ("numerics.profile_element_mm=0.025", "numerics.face_element_mm=1.0",
                                     "numerics.map_points_per_pitch=192",
                                     f"numerics.comm_step_s={_H48000!r}", "numerics.max_substep_s=1e-06",
                                     "effects.shaft_elements=8"),
            "table gear, converged mesh 0.025 x 1 mm, contact map 192 nodes per pitch, H = 1/48000 s, "
            "sub-step 1 us, 8 shaft elements"),
    Setting("reference_refined", "reference", ("numerics.profile_element_mm=0.025", "numerics.face_element_mm=1.0",
                                               "numerics.map_points_per_pitch=192",
                                               f"numerics.comm_step_s={_H96000!r}", "numerics.max_substep_s=5e-07",
                                               "effects.shaft_elements=16"),
            "the reference refined once more in time and shafts: H = 1/96000 s, sub-step 0.5 us, 16 shaft "
            "elements (the mesh and the map stay: 0.15 % from 0.05 mm in stiffness; 192 -> 384 map nodes 0.22 % "
            "in the fluctuation of the healthy gear at 250 rpm; a 384-node map of a faulty pair takes 10-16 min "
            "to build on 2 cores)"),
    Setting(DEFAULT, "default", (), "the defaults: table gear, mesh 0.05 x 2 mm, H = 1/12000 s, sub-step "
                                    "5 us, 4 shaft elements"),
    Setting("mesh_0.025mm", "mesh", ("numerics.profile_element_mm=0.025", "numerics.face_element_mm=1.0"),
            "converged mesh 0.025 x 1 mm (other settings default)"),
    Setting("mesh_0.1mm", "mesh", ("numerics.profile_element_mm=0.1",), "profile elements 0.1 mm"),
    Setting("mesh_0.2mm", "mesh", ("numerics.profile_element_mm=0.2",), "profile elements 0.2 mm"),
    Setting("mesh_0.5mm", "mesh", ("numerics.profile_element_mm=0.5",), "the paper's 0.5 mm profile elements"),
    Setting("map_24", "map", ("numerics.map_points_per_pitch=24",),
            "contact map: 24 nodes per pinion pitch (half the default)"),
    Setting("map_96", "map", ("numerics.map_points_per_pitch=96",),
            "contact map: 96 nodes per pinion pitch (twice the default)"),
    Setting("map_192", "map", ("numerics.map_points_per_pitch=192",),
            "contact map: 192 nodes per pinion pitch (4x the default; the reference's)"),
    Setting("map_approach_24", "map", ("numerics.map_approach_points=24",),
            "contact map: 24 nodes along the approach per flank (half the default)"),
    Setting("pcm", "fidelity", ("effects.mesh_contact=pcm",), "online PCM (default mesh and steps)"),
    Setting("analytic", "fidelity", ("effects.mesh_contact=analytic",), "ISO 6336 analytic mesh (healthy only)"),
    Setting("ideal", "fidelity", ("effects.mesh_contact=ideal",), "ideal gear: a ratio (healthy only)"),
    Setting("H_24000", "steps", (f"numerics.comm_step_s={_H24000!r}",), "communication step 1/24000 s"),
    Setting("H_6000", "steps", (f"numerics.comm_step_s={_H6000!r}",), "communication step 1/6000 s"),
    Setting("substep_1us", "steps", ("numerics.max_substep_s=1e-06",), "gear sub-step 1 us"),
    Setting("substep_20us", "steps", ("numerics.max_substep_s=2e-05",), "gear sub-step 20 us"),
    Setting("rk4", "integrator", ("numerics.mesh_integrator=rk4",),
            "explicit RK4 gear sub-steps instead of the Rosenbrock scheme (sub-step 5 us)"),
    Setting("rk4_1us", "integrator", ("numerics.mesh_integrator=rk4", "numerics.max_substep_s=1e-06"),
            "explicit RK4 gear sub-steps of 1 us"),
    Setting("no_energy_correction", "steps", ("numerics.energy_correction=false",),
            "no energy-conserving correction at the cuts"),
    Setting("shaft_1", "shafts", ("effects.shaft_elements=1",), "1 element per long shaft"),
    Setting("shaft_2", "shafts", ("effects.shaft_elements=2",), "2 elements per long shaft"),
    Setting("shaft_8", "shafts", ("effects.shaft_elements=8",), "8 elements per long shaft"),
    Setting("rigid_shafts", "shafts", ("effects.shaft_flexibility=rigid",), "rigid shafts (no shaft FMU)"),
    Setting("fast", "combined", (f"numerics.comm_step_s={_H6000!r}", "numerics.max_substep_s=2e-05",
                                 "effects.shaft_elements=2"),
            "H = 1/6000 s, sub-step 20 us, 2 shaft elements"),
    Setting("tooth_compliance", "realism", ("effects.tooth_compliance=true",),
            "realism: tooth bending compliance (changes the physics)", choosable=False),
    Setting("manufacturing_errors", "realism", ("effects.manufacturing_errors=true",),
            "realism: pitch errors and runout (changes the physics)", choosable=False),
    Setting("rig_sensors", "realism", ("effects.sensors=rig",),
            "realism: the rig's instruments (changes the signals)", choosable=False),
)}

_EXAMPLE = "scenarios/example.toml"
#: name -> (scene file relative to the repository, overrides, what)
STUDY_SCENES: dict[str, tuple[str, tuple[str, ...], str]] = {
    f"{h}_{n}rpm": (_EXAMPLE, (f"operating_point.drive_speed_rpm={n}", f"gear.health={h}",
                               f"operating_point.load_torque_Nm={PAPER_MAX_LOAD_NM}"),
                     f"{h}, {n} rpm, {PAPER_MAX_LOAD_NM} N·m")
    for h in PAPER_HEALTH for n in (int(PAPER_SPEEDS_RPM[0]), int(PAPER_MAX_SPEED_RPM))   # 250, 1500
}
STUDY_SCENES["wheel_void_1500rpm"] = ("scenarios/faults/wheel_void_1500rpm.toml", (),
                                      "void on wheel tooth 38, 1500 rpm, 1.31 N·m")
#: another pair (issue 42): its errors answer ``numerics.tolerance_pct`` for scenes of that pair only
STUDY_SCENES["pair20x40_healthy_1500rpm"] = ("scenarios/other_gearboxes/pair_20_40_m4.toml", (),
                                             "20/40 pair of module 4 mm (scenarios/other_gearboxes), healthy, "
                                             "1500 rpm, 1.31 N·m")

_COMMON = (f"time.duration_s={STUDY_DURATION_S}", f"time.settle_s={STUDY_SETTLE_S}", "outputs.plots=false",
           f"outputs.sensors={json.dumps(list(TORQUE_SENSORS))}")


def run_name(scene: str, setting: str) -> str:
    return f"{scene}__{setting}"


def study_overrides(scene: str, setting: str, extra: tuple[str, ...] = ()) -> tuple[str, list[str]]:
    """(scene file, overrides) of one run of the study."""
    path, over, _ = STUDY_SCENES[scene]
    return str(ROOT / path), [*_COMMON, *over, *SETTINGS[setting].overrides, *extra,
                              f"scenario.name={run_name(scene, setting)}"]


# ------------------------------------------------------------------------------------------------
# Metrics
# ------------------------------------------------------------------------------------------------


def _sideband_freqs(cf: dict, wheel: bool) -> list[float]:
    f_mod = cf["f_PSH"] if wheel else cf["f_MSH"]
    return [cf["f_GMF"] - f_mod, cf["f_GMF"] + f_mod]


def compare(ref: dict, run: dict, fs: float, settle_s: float, speed_rpm: float, wheel: bool = False) -> dict:
    """Errors of ``run`` against ``ref`` (each {"time": t, channel: samples}), per channel and worst."""
    cf = characteristic_frequencies(speed_rpm)
    per = {}
    for ch in CHANNELS:
        if ch not in ref or ch not in run:
            continue
        r = np.asarray(ref[ch], float)[np.asarray(ref["time"]) >= settle_s]
        x = np.asarray(run[ch], float)[np.asarray(run["time"]) >= settle_s]
        n = min(len(r), len(x))
        if n < 32:
            continue
        r, x = r[:n], x[:n]
        mr, mx, sr, sx = r.mean(), x.mean(), r.std(), x.std()
        pr, px = np.ptp(r), np.ptp(x)
        f, Ar = amplitude_spectrum(r, fs, lowpass_Hz=spectrum_lowpass_Hz(cf["f_GMF"]))
        _, Ax = amplitude_spectrum(x, fs, lowpass_Hz=spectrum_lowpass_Hz(cf["f_GMF"]))
        band = (f > 0) & (f <= spectrum_lowpass_Hz(cf["f_GMF"]))
        floor = float(np.median(Ar[band])) if band.any() else 0.0
        g_r, g_x = amplitude_near(f, Ar, cf["f_GMF"]), amplitude_near(f, Ax, cf["f_GMF"])
        sb = []
        for fsb in _sideband_freqs(cf, wheel):
            a_r, a_x = amplitude_near(f, Ar, fsb), amplitude_near(f, Ax, fsb)
            if a_r > 0 and floor > 0 and float(to_db(a_r / floor)) >= RESOLVED_DB:
                sb.append(float(to_db(max(a_x, 1e-300) / a_r)))
        per[ch] = {
            "mean_err_pct": 100.0 * abs(mx - mr) / abs(mr) if mr else float("nan"),
            "std_err_pct": 100.0 * abs(sx - sr) / sr if sr > 0 else float("nan"),
            "ptp_err_pct": 100.0 * abs(px - pr) / pr if pr > 0 else float("nan"),
            "gmf_dB": float(to_db(g_x / g_r)) if g_r > 0 and g_x > 0 else float("nan"),
            "sideband_dB": max(sb, key=abs) if sb else None,
            "spectral_distance_pct": 100.0 * float(np.linalg.norm(Ax[band] - Ar[band]) / np.linalg.norm(Ar[band]))
            if band.any() and np.any(Ar[band]) else float("nan"),
        }
    worst = {}
    for k in ("mean_err_pct", "std_err_pct", "ptp_err_pct", "gmf_dB", "sideband_dB", "spectral_distance_pct"):
        vals = [p[k] for p in per.values() if p.get(k) is not None and math.isfinite(p[k])]
        worst[k] = max(vals, key=abs) if vals else None
    return {"worst": worst, "channels": per}


# ------------------------------------------------------------------------------------------------
# Choosing a setting from the shipped results
# ------------------------------------------------------------------------------------------------


@dataclass
class Choice:
    setting: str
    studied_scene: str
    tolerance_pct: float
    overrides: tuple[str, ...]
    errors: dict
    loop_s_per_s: float
    why: str
    candidates: list = field(default_factory=list)
    #: the studied setting the scene runs as it is (None: its numerics are none of the studied ones; then
    #: ``own_loop_s_per_s`` is the studied defaults')
    own_setting: str | None = None
    own_loop_s_per_s: float | None = None

    @property
    def cost_vs_own(self) -> float | None:
        """The chosen setting's cost over the scene's own setting's (> 1: the choice costs more)."""
        own = self.own_loop_s_per_s
        return self.loop_s_per_s / own if own else None

    def to_dict(self) -> dict:
        return {"setting": self.setting, "studied_scene": self.studied_scene, "tolerance_pct": self.tolerance_pct,
                "overrides": list(self.overrides), "errors": self.errors, "loop_s_per_s": self.loop_s_per_s,
                "own_setting": self.own_setting, "own_loop_s_per_s": self.own_loop_s_per_s,
                "cost_vs_own": self.cost_vs_own, "why": self.why}


def load_results(path: Path | str | None = None) -> dict:
    """The study's results ({"meta", "scenes": {scene: {"rows": {setting: row}}}}); shipped with the package."""
    p = Path(path) if path else RESULTS_FILE
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise FileNotFoundError(f"accuracy-cost results {p}: not readable ({exc}); run `drivetrain "
                                f"accuracy-cost` to produce them") from None


def health_class(scene) -> str:
    h = scene.gear.health
    if h == "faults":
        members = {str(f.get("member", "pinion")) for f in scene.gear.faults}
        return "wheel" if members == {"wheel"} else "severe"
    return h if h in PAPER_HEALTH else "severe"


def pair_of(scene) -> dict | None:
    """The scene's ``[gear.pair]`` keys (a studied scene's record keeps them), None for the rig's pair."""
    return None if scene.gear.pair.is_rig else dict(scene.gear.pair.as_dict())


def closest_scene(scene, results: dict) -> str:
    """The studied scene nearest to ``scene`` among those of its gear pair (the rig's, or another pair's
    with every ``[gear.pair]`` key equal): the same health class (healthy, mild, severe, wheel fault; other
    faults count as severe), then the nearest speed on a log scale. ValueError when the study ran no scene
    of the pair."""
    want = health_class(scene)
    rpm = max(float(scene.operating_point.final_speed_rpm), 1.0)
    pair = pair_of(scene)
    best = None
    for name, rec in results.get("scenes", {}).items():
        if rec.get("pair") != pair:
            continue
        cls, speed = rec.get("health_class"), float(rec.get("speed_rpm", 0.0)) or 1.0
        key = (cls != want, abs(math.log(rpm / speed)))
        if best is None or key < best[0]:
            best = (key, name)
    if best is None:
        if pair is not None:
            raise ValueError("the accuracy-cost study ran no scene of this [gear.pair] (its errors are measured "
                             "per pair); set the scene's numerics yourself (remove numerics.tolerance_pct), or "
                             "add a studied scene of the pair to drivetrain.run.accuracy.STUDY_SCENES and run "
                             "drivetrain accuracy-cost --scenes NAME")
        raise ValueError("the accuracy-cost results hold no scene")
    return best[1]


def within(errors: dict, tolerance_pct: float) -> bool:
    """Mean torques and fluctuation within T %, GMF and resolved sidebands within T dB (1 % -> 1 dB)."""
    T = float(tolerance_pct)
    for k, lim in (("mean_err_pct", T), ("std_err_pct", T), ("gmf_dB", T), ("sideband_dB", T)):
        v = errors.get(k)
        if v is None:
            continue
        if not math.isfinite(v) or abs(v) > lim:
            return False
    return True


def _setting_values(s: Setting) -> dict:
    """{"section.key": value} of a setting's overrides."""
    return {".".join(parts): value for parts, value in map(parse_override, s.overrides)}


def _same(a, b) -> bool:
    numbers = all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in (a, b))
    if numbers:
        return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=0.0)
    return a == b


def own_setting(scene) -> str | None:
    """The studied setting the scene runs as it is: the one whose values of every key a setting changes
    (the others at their defaults) are the scene's; None when the scene's are none of them."""
    raw = scene.to_dict()
    values = {name: _setting_values(s) for name, s in SETTINGS.items()}
    keys = sorted({k for v in values.values() for k in v})
    current = {k: raw.get(k.split(".", 1)[0], {}).get(k.split(".", 1)[1], default_of(k)) for k in keys}
    for name, v in values.items():
        if all(_same(current[k], v.get(k, default_of(k))) for k in keys):
            return name
    return None


def _cost_words(cost: float, own: str | None, own_cost: float | None, ref_cost: float | None) -> str:
    """The chosen setting's cost against the scene's own setting (and the reference's, for scale)."""
    words = f"{cost:.3g} s per simulated s"
    if own_cost:
        whose = (f"the scene's own setting ({own}: {own_cost:.3g} s per simulated s)" if own else
                 f"the studied defaults ({own_cost:.3g} s per simulated s; the scene's own numerics were not studied)")
        ratio = cost / own_cost
        words += f", {ratio:.2g}x {whose}" + (": it costs more, for accuracy" if ratio > 1.0 else "")
    if ref_cost:
        words += f"; the converged reference costs {ref_cost:.3g}"
    return words


def choose(scene, tolerance_pct: float, results: dict | None = None) -> Choice:
    """The cheapest choosable setting whose measured error for the closest studied scene is within the
    tolerance (the reference, which always is, when nothing cheaper is)."""
    results = results if results is not None else load_results()
    name = closest_scene(scene, results)
    rows = results["scenes"][name]["rows"]
    ok = [(r["loop_s_per_s"], s) for s, r in rows.items()
          if s in SETTINGS and SETTINGS[s].choosable and r.get("status") == "ok"
          and (s == REFERENCE or within(r.get("errors") or {}, tolerance_pct))]
    if not ok:
        raise ValueError(f"no studied setting of {name} ran")
    ok.sort()
    cost, s = ok[0]
    r = rows[s]
    ref_cost = rows.get(REFERENCE, {}).get("loop_s_per_s")
    own = own_setting(scene)
    own_cost = (rows.get(own if own is not None else DEFAULT) or {}).get("loop_s_per_s")
    why = (f"cheapest of {len(ok)} settings within {tolerance_pct:g} % (mean torques, fluctuation) and "
           f"{tolerance_pct:g} dB (GMF, sidebands) for the studied scene {name}: {SETTINGS[s].what}; "
           + _cost_words(cost, own, own_cost, ref_cost))
    return Choice(s, name, float(tolerance_pct), SETTINGS[s].overrides, r.get("errors") or {}, cost, why,
                  [x[1] for x in ok], own, own_cost)


def apply_tolerance(scene) -> tuple:
    """The scene with the chosen setting applied when ``numerics.tolerance_pct`` is set: (scene, Choice
    or None)."""
    T = getattr(scene.numerics, "tolerance_pct", None)
    if T is None:
        return scene, None
    c = choose(scene, T)
    return (with_overrides(scene, list(c.overrides)) if c.overrides else scene), c


__all__ = ["SETTINGS", "STUDY_SCENES", "Setting", "compare", "choose", "apply_tolerance", "closest_scene",
           "load_results", "within", "run_name", "study_overrides", "health_class", "RESULTS_FILE", "own_setting",
           "pair_of"]
