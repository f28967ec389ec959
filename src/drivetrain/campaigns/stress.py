"""The stress campaign (``drivetrain stress``): hard cases must stay stable, with zero failures.

Two sets of runs go through the sweep machinery (:func:`drivetrain.campaigns.sweep.run_sweep`: local processes or
Dask, resumable with ``skip_existing``):

* ``paper``: the 54 scenes of ``scenarios/paper/paper.toml`` (6 speeds x 3 loads x 3 health states),
  full length (20 s);
* ``random``: ``n_random`` short randomized hard scenes drawn from a seeded distribution
  (:func:`draw_random`). Scene ``i`` depends only on ``(seed, i)`` and the distribution options
  (durations, allowed fidelities), never on ``n_random`` or on the other scenes, so a subset or a
  resumed campaign reproduces it exactly. The distribution covers drive speeds 0..3000 rpm (constant,
  held at standstill, start from standstill, ramps up and down, ramp to a stop), load torques from 0
  (rattle) to 2 x the paper's highest (2 x 1.31 N·m) with steps and reversals (negative load), all
  health states (healthy, mild, severe and ``mesh`` with a few random fault meshes,
  :func:`fault_mesh_params`), every fidelity (pcm only on short scenes; ideal and analytic model the
  healthy gear only), flexible
  and rigid shafts, 1..16 shaft elements, friction / contact damping / losses on and off, and
  communication steps H = 1/(3000 k), k in 1, 2, 4, 8, 16 (1/3000 .. 1/48000 s). A small share
  (``PROBE_FRACTION``) deliberately draws H = 1/1000 s, which the assembler's cut check refuses before
  running (predicted unstable): that refusal is the correct outcome and is counted as "refused", not as
  a failure.

Every ``halving_subset``-th random scene is also run with half the communication step (a *halving
pair*).

Judging (:func:`judge_run`, :func:`judge_halving`): a run passes when it completes (summary ``status``
"ok"), every channel is finite (``nonfinite_channels`` empty), the stability block is within its
limits (``stability.max_penetration_rel_umax`` < 1, i.e. below u_max; > 0.1 is flagged suspicious) and
the energy residual is < 1 %. A halving pair passes when both runs pass and the mean torque of the
drive-shaft and propeller-shaft sensors agree within 0.5 % and their RMS (``summary["torque"][sensor]
["rms"]``) within 2 %, relative to the half-step run. A draw that holds its drive at standstill with
friction or losses on is judged whole first; only when the whole runs differ beyond the limits is it compared
over the moving part before the standstill (the torque friction holds at rest is indeterminate within its band:
:func:`held_standstill_from_s`), and without a moving part its pair is "not comparable", with that reason.
Figures a run does not report (older summaries) are "not reported": they do not fail the run and the report
says how many runs lacked them.

Outputs in ``out_dir``: one directory per run (``<name>/summary.json``, ``signals.h5``), the sweep
manifest (``manifest.json``, ``manifest.csv``), the random fault meshes (``meshes/``), ``stress.json``
(every run with its classes, parameters, verdict and figures; the pairs; the class table) and
``stress.md`` (the class table with the worst figures per class, the failures with their cause, the
command line and the wall time). :func:`regenerate_report` re-judges an existing campaign directory and
rewrites both files (``drivetrain stress --report-only``).

This module never prints; progress goes to the ``log`` callable given by the caller.
"""
from __future__ import annotations

import dataclasses
import json
import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from drivetrain.campaigns.provenance import commit_line
from drivetrain.cosim import ConfigurationError
from drivetrain.run.outputs import jsonable, now_iso
from drivetrain.run.runner import assemble_scene
from drivetrain.rig.data import PAPER_MAX_LOAD_NM, TORQUE_SENSORS
from drivetrain.scene.load import FIDELITIES, Scene, load_scenes, scene_from_dict
from drivetrain.scene.schema import pair_keys
from drivetrain.campaigns.sweep import CACHED_FIDELITIES, prepare_caches, read_runs, run_sweep
from drivetrain.system import SystemSpec
from gearcontact_fmu import faults, geometry
from gearcontact_fmu.meshes import save_mesh
from gearcontact_fmu.mesh_models.base import PAPER_HEALTH
from gearcontact_fmu.pair_check import OTHER_PAIRS, other_pair
from gearcontact_fmu.params import BevelGearParams

# --------------------------------------------------------------------------------------------------
# The distribution
# --------------------------------------------------------------------------------------------------

MAX_LOAD_NM = 2.0 * PAPER_MAX_LOAD_NM          #: 2.62 N·m
MAX_SPEED_RPM = 3000.0
SAMPLE_RATE_HZ = 3000.0
STEP_DIVISORS = (1, 2, 4, 8, 16)               #: H = 1 / (SAMPLE_RATE_HZ * k): 1/3000 .. 1/48000 s
RATTLE_LOAD_NM = 0.1                           #: |load| below this: the rattle regime
HEALTHS = PAPER_HEALTH + ("mesh",)
HEALTH_WEIGHTS = {"healthy": 0.34, "mild": 0.22, "severe": 0.22, "mesh": 0.22}
SHAFT_ELEMENTS = {1: 0.15, 2: 0.15, 4: 0.4, 8: 0.15, 16: 0.15}     #: effects.shaft_elements: weight
#: fidelity weights given the health (ideal and analytic model the healthy gear only)
FIDELITY_WEIGHTS = {
    "healthy": {"table": 0.3, "analytic": 0.3, "ideal": 0.3, "pcm": 0.1},
    "mild": {"table": 0.92, "pcm": 0.08},
    "severe": {"table": 0.92, "pcm": 0.08},
    "mesh": {"table": 0.9, "pcm": 0.1},
}
SPEED_MODES = {"constant": 0.35, "hold_zero": 0.05, "standstill_start": 0.25, "ramp": 0.25, "ramp_to_stop": 0.10}
LOAD_MODES = {"constant": 0.35, "rattle": 0.15, "step": 0.25, "reversal": 0.25}
#: share of deliberately unstable draws: H = 1/PROBE_RATE_HZ (sample rate PROBE_RATE_HZ), refused by the
#: assembler's cut check (any shaft model) before running
PROBE_FRACTION = 0.03
PROBE_RATE_HZ = 1000.0
N_FAULT_MESHES = 4
DEFAULT_DURATION_S = 1.5
DEFAULT_DURATION_PCM_S = 0.1
DEFAULT_HALVING_SUBSET = 10
STEP_TIME_S = 1e-3                             #: a load step: two profile points 1 ms apart

# --------------------------------------------------------------------------------------------------
# Limits
# --------------------------------------------------------------------------------------------------

LIMITS = {
    "max_penetration_rel_umax": 1.0,   # the largest contact penetration stays below u_max
    "energy_residual": 0.01,           # relative energy-audit residual < 1 %
    "halving_mean": 0.005,             # mean torques agree within 0.5 % when H is halved
    "halving_rms": 0.02,               # torque RMS within 2 %
}
SUSPICIOUS_PENETRATION = 0.1           #: flagged (not failed) above 10 % of u_max
HALVING_SENSORS = tuple(TORQUE_SENSORS)  # drive_shaft_torque, propeller_shaft_torque
#: a mean or RMS torque below this [N·m] is zero for the relative halving comparison (a drivetrain at
#: rest without load has exactly zero torques); the deviation is then taken relative to this floor
ZERO_TORQUE_NM = 1e-3

# --------------------------------------------------------------------------------------------------
# Random draws
# --------------------------------------------------------------------------------------------------

_N_UNIFORMS = 32
_STREAM_SCENE, _STREAM_MESH = 0, 1


def _rng(seed: int, stream: int, i: int) -> np.random.Generator:
    """A generator that depends only on (seed, stream, i)."""
    return np.random.default_rng(np.random.SeedSequence(entropy=int(seed), spawn_key=(int(stream), int(i))))


def _pick(u: float, weights: dict) -> str:
    keys = list(weights)
    w = np.array([weights[k] for k in keys], dtype=float)
    c = np.cumsum(w / w.sum())
    return keys[min(int(np.searchsorted(c, u, side="right")), len(keys) - 1)]


def _t(x: float) -> float:
    return round(float(x), 6)


def _speed(u: np.ndarray, D: float) -> dict:
    """Speed reference for uniforms u[10:15] and duration D."""
    mode = _pick(u[10], SPEED_MODES)
    n1 = float(u[11] * MAX_SPEED_RPM)
    n0 = float(u[12] * MAX_SPEED_RPM)
    if mode == "constant":
        return {"speed_mode": mode, "drive_speed_rpm": round(n1, 3)}
    if mode == "hold_zero":
        return {"speed_mode": mode, "drive_speed_rpm": 0.0}
    if mode == "standstill_start":
        n1 = 300.0 + u[11] * (MAX_SPEED_RPM - 300.0)
        tr = (0.1 + 0.4 * u[13]) * D
        return {"speed_mode": mode, "speed_profile_rpm": [[0.0, 0.0], [_t(tr), round(n1, 3)]]}
    ta = (0.05 + 0.25 * u[14]) * D
    tb = ta + (0.1 + 0.4 * u[13]) * D
    if mode == "ramp":
        return {"speed_mode": mode, "speed_profile_rpm": [[0.0, round(n0, 3)], [_t(ta), round(n0, 3)],
                                                          [_t(tb), round(n1, 3)]]}
    n0 = 300.0 + u[12] * (MAX_SPEED_RPM - 300.0)      # ramp_to_stop
    return {"speed_mode": mode, "speed_profile_rpm": [[0.0, round(n0, 3)], [_t(ta), round(n0, 3)], [_t(tb), 0.0]]}


def _load(u: np.ndarray, D: float) -> dict:
    """Load torque for uniforms u[15:22] and duration D."""
    mode = _pick(u[15], LOAD_MODES)
    L1 = RATTLE_LOAD_NM + u[16] * (MAX_LOAD_NM - RATTLE_LOAD_NM)
    L2 = u[17] * MAX_LOAD_NM
    ts = (0.3 + 0.35 * u[18]) * D
    ts2 = ts + (0.1 + 0.2 * u[19]) * D
    if mode == "constant":
        return {"load_mode": mode, "load_torque_Nm": round(L1, 4)}
    if mode == "rattle":
        L = 0.0 if u[17] < 0.25 else u[16] * RATTLE_LOAD_NM
        return {"load_mode": mode, "load_torque_Nm": round(L, 4)}
    if mode == "step":
        prof = [[0.0, round(L1, 4)], [_t(ts), round(L1, 4)], [_t(ts + STEP_TIME_S), round(L2, 4)]]
        if u[20] < 0.5:                     # and back
            prof += [[_t(ts2), round(L2, 4)], [_t(ts2 + STEP_TIME_S), round(L1, 4)]]
        return {"load_mode": mode, "load_profile_Nm": prof}
    # reversal: a constant negative load, or a step across zero (either way)
    neg = -(RATTLE_LOAD_NM + u[17] * (MAX_LOAD_NM - RATTLE_LOAD_NM))
    if u[20] < 0.3:
        return {"load_mode": mode, "load_torque_Nm": round(neg, 4)}
    a, b = (L1, neg) if u[21] < 0.7 else (neg, L1)
    return {"load_mode": mode, "load_profile_Nm": [[0.0, round(a, 4)], [_t(ts), round(a, 4)],
                                                   [_t(ts + STEP_TIME_S), round(b, 4)]]}


def draw_random(seed: int, i: int, *, duration_s: float = DEFAULT_DURATION_S,
                duration_pcm_s: float = DEFAULT_DURATION_PCM_S, fidelities=None,
                n_fault_meshes: int = N_FAULT_MESHES, probe_fraction: float = PROBE_FRACTION,
                pair: str | None = None) -> dict:
    """The parameters of random scene ``i`` (plain data; :func:`random_scene_dict` makes the scene).

    Depends only on (seed, i) and the options. A fixed vector of uniforms is drawn first and each
    decision uses its own entry, so that restricting one choice (``fidelities``) leaves the others as
    they were. ``fidelities``: allowed ``effects.mesh_contact`` values (default all); the health states
    are restricted to those some allowed fidelity can simulate. ``pair``: one of
    ``gearcontact_fmu.pair_check.OTHER_PAIRS`` for every scene (default the rig's); the draws are the same,
    the scenes and their fault meshes are of that pair (named ``rnd_<pair>_s<seed>_<i>``)."""
    if pair is not None:
        other_pair(pair)                            # KeyError naming the pairs there are
    u = _rng(seed, _STREAM_SCENE, i).random(_N_UNIFORMS)
    allowed = tuple(fidelities) if fidelities else FIDELITIES
    bad = [f for f in allowed if f not in FIDELITIES]
    if bad:
        raise ValueError(f"unknown fidelities {bad}; choose from {', '.join(FIDELITIES)}")
    healths = {h: w for h, w in HEALTH_WEIGHTS.items() if any(f in allowed for f in FIDELITY_WEIGHTS[h])}
    if not healths:
        raise ValueError(f"no health state can be simulated with the fidelities {allowed}")
    health = _pick(u[0], healths)
    fid = _pick(u[1], {f: w for f, w in FIDELITY_WEIGHTS[health].items() if f in allowed})
    probe = bool(u[8] < probe_fraction)
    k = STEP_DIVISORS[min(int(u[7] * len(STEP_DIVISORS)), len(STEP_DIVISORS) - 1)]
    if probe:
        fs, k = PROBE_RATE_HZ, 1
    else:
        fs = SAMPLE_RATE_HZ
    D = float(duration_pcm_s if fid == "pcm" else duration_s)
    p: dict[str, Any] = {
        "seed": int(seed), "index": int(i), "name": random_name(seed, i, pair),
        "health": health,
        "fault_mesh": (min(int(u[9] * n_fault_meshes), n_fault_meshes - 1) if health == "mesh" else None),
        "mesh_contact": fid,
        "shaft_flexibility": "flexible" if u[2] < 0.5 else "rigid",
        "shaft_elements": int(_pick(u[3], SHAFT_ELEMENTS)),
        "friction": bool(u[4] < 0.75), "contact_damping": bool(u[5] < 0.75), "losses": bool(u[6] < 0.75),
        "sample_rate_Hz": fs, "comm_step_divisor": int(k), "comm_step_s": 1.0 / (fs * k),
        "unstable_probe": probe,
        "duration_s": D,
    }
    p.update(_speed(u, D))
    p.update(_load(u, D))
    if pair is not None:            # the rig's draws keep their parameters as they were
        p["pair"] = pair
    return p


def random_name(seed: int, i: int, pair: str | None = None) -> str:
    return f"rnd_s{int(seed)}_{int(i):04d}" if pair is None else f"rnd_{pair}_s{int(seed)}_{int(i):04d}"


def halving_name(name: str) -> str:
    return f"{name}_halfH"


def random_scene_dict(p: dict, mesh_paths: list | None = None, *, halve_step: bool = False) -> dict:
    """The scene (file layout) of a draw. ``mesh_paths``: the fault mesh files (index = p["fault_mesh"]).
    ``halve_step``: the same scene with half the communication step (named ``<name>_halfH``)."""
    op = {k: p[k] for k in ("drive_speed_rpm", "speed_profile_rpm", "load_torque_Nm", "load_profile_Nm") if k in p}
    if "drive_speed_rpm" not in op:
        op["drive_speed_rpm"] = float(p["speed_profile_rpm"][-1][1])
    if "load_torque_Nm" not in op:
        op["load_torque_Nm"] = float(p["load_profile_Nm"][0][1])
    gear: dict[str, Any] = {"health": p["health"]}
    if p.get("pair") is not None:
        gear["pair"] = pair_keys(other_pair(p["pair"]))
    if p["health"] == "mesh":
        if not mesh_paths:
            raise ValueError(f"{p['name']}: health 'mesh' needs the fault mesh files (write_fault_meshes)")
        gear["pinion_mesh"] = str(mesh_paths[p["fault_mesh"]])
    H = p["comm_step_s"] / (2.0 if halve_step else 1.0)
    name = halving_name(p["name"]) if halve_step else p["name"]
    desc = (f"stress draw seed {p['seed']} #{p['index']}: {p['health']}/{p['mesh_contact']}/{p['shaft_flexibility']}, "
            f"speed {p['speed_mode']}, load {p['load_mode']}, H = 1/{1.0 / H:.0f} s"
            + (f", pair {p['pair']}" if p.get("pair") is not None else "")
            + (" (unstable probe)" if p["unstable_probe"] else ""))
    return {
        "scenario": {"name": name, "description": desc},
        "operating_point": op,
        "gear": gear,
        "time": {"duration_s": p["duration_s"], "sample_rate_Hz": p["sample_rate_Hz"]},
        "outputs": {"plots": False},
        "numerics": {"comm_step_s": H},
        "effects": {k: p[k] for k in ("mesh_contact", "shaft_flexibility", "shaft_elements", "friction",
                                      "contact_damping", "losses")},
    }


# --------------------------------------------------------------------------------------------------
# Random fault meshes
# --------------------------------------------------------------------------------------------------


def _pair_params(pair: str | None) -> BevelGearParams:
    """The gear data of a campaign's pair: the rig's (None) or one of ``OTHER_PAIRS``."""
    return BevelGearParams() if pair is None else other_pair(pair)


def fault_mesh_params(seed: int, j: int, pair: str | None = None) -> dict:
    """Parameters of random fault mesh ``j`` (depends only on (seed, j)). Meshes 0, 1, 2 (mod 4): a
    flank-fracture void of random tooth, width 0.5..2 mm, depth 0.1..0.5 mm and position -0.8..1.5 mm
    from the pitch cone (:func:`gearcontact_fmu.faults.mild_flank_fracture`); mesh 3 (mod 4): a random
    missing tooth plus a void on another tooth. ``pair``: on the pinion of that other pair (default the rig's)."""

    P = _pair_params(pair)
    g = geometry.gear_geometry(P, "pinion")
    rng = _rng(seed, _STREAM_MESH, j)
    for _ in range(1000):
        void = {"tooth": int(rng.integers(g.z)), "width": float(rng.uniform(0.5e-3, 2.0e-3)),
                "depth": float(rng.uniform(0.1e-3, 0.5e-3)), "position": float(rng.uniform(-0.8e-3, 1.5e-3))}
        s_a, s_b = faults.void_strip(P, "pinion", void["width"], void["position"])
        if (s_a > g.L_radial and s_b < g.L_radial + g.L_inv and void["depth"] < 0.5 * g.s_pitch):
            break
    else:  # pragma: no cover - the ranges above are inside the flank
        raise RuntimeError("no valid void drawn")
    out = {"seed": int(seed), "index": int(j), "void": void, "missing_tooth": None}
    if pair is not None:
        out["pair"] = pair
    if j % 4 == 3:
        out["missing_tooth"] = int((void["tooth"] + rng.integers(1, g.z)) % g.z)
    return out


def build_fault_mesh(params: dict):
    """The pinion SurfaceMesh (body frame, m) of :func:`fault_mesh_params`."""

    P = _pair_params(params.get("pair"))
    mesh = geometry.build_gear_mesh(P, "pinion")
    mesh = faults.mild_flank_fracture(mesh, P, **params["void"])
    if params.get("missing_tooth") is not None:
        mesh = faults.missing_tooth(mesh, params["missing_tooth"])
    return mesh


def fault_mesh_path(mesh_dir: Path | str, seed: int, j: int, pair: str | None = None) -> Path:
    return Path(mesh_dir) / (f"fault_s{int(seed)}_{int(j)}.obj" if pair is None else f"fault_{pair}_s{int(seed)}_{int(j)}.obj")


def write_fault_meshes(mesh_dir: Path | str, seed: int, indices, log=None, pair: str | None = None) -> dict[int, Path]:
    """Write the fault meshes ``indices`` as OBJ (mm) into ``mesh_dir`` (kept when the file and its
    parameter sidecar exist with the same parameters: the contact-map cache is keyed by the content)."""

    mesh_dir = Path(mesh_dir)
    mesh_dir.mkdir(parents=True, exist_ok=True)
    out = {}
    for j in sorted(set(int(x) for x in indices)):
        path = fault_mesh_path(mesh_dir, seed, j, pair)
        side = path.with_suffix(".json")
        params = fault_mesh_params(seed, j, pair)
        if path.is_file() and side.is_file():
            try:
                if json.loads(side.read_text()) == params:
                    out[j] = path
                    continue
            except ValueError:
                pass
        if log:
            log(f"writing fault mesh {path.name}: {describe_fault(params)}")
        tmp = path.with_name(path.stem + ".tmp.obj")
        save_mesh(build_fault_mesh(params), tmp, units="mm")
        tmp.replace(path)
        side.write_text(json.dumps(params, indent=1))
        out[j] = path
    return out


def describe_fault(params: dict) -> str:
    v = params["void"]
    s = (f"void on tooth {v['tooth']}, {v['width'] * 1e3:.2f} mm wide, {v['depth'] * 1e3:.2f} mm deep at "
         f"{v['position'] * 1e3:+.2f} mm from the pitch cone")
    if params.get("missing_tooth") is not None:
        s = f"tooth {params['missing_tooth']} missing + " + s
    return s


# --------------------------------------------------------------------------------------------------
# Cases and classes
# --------------------------------------------------------------------------------------------------


@dataclass
class StressCase:
    """One run of the campaign."""

    name: str
    set: str                        # paper | random | halving
    scene: Scene
    classes: list[str]
    parameters: dict
    pair_of: str | None = None      # for a half-step run: the name of the base run
    refused: str | None = None      # set when the assembler refused the scene before running
    spec: Any = None
    extra: dict = field(default_factory=dict)


def _load_values(p: dict) -> list[float]:
    return [v for _, v in p["load_profile_Nm"]] if p.get("load_profile_Nm") else [p["load_torque_Nm"]]


def is_rattle(p: dict) -> bool:
    """|load| < RATTLE_LOAD_NM held for a while: a constant, the end of a profile, or a segment of it."""
    if p.get("load_profile_Nm"):
        prof = p["load_profile_Nm"]
        if abs(prof[-1][1]) < RATTLE_LOAD_NM:
            return True
        return any(abs(a[1]) < RATTLE_LOAD_NM and abs(b[1]) < RATTLE_LOAD_NM for a, b in zip(prof, prof[1:]))
    return abs(p["load_torque_Nm"]) < RATTLE_LOAD_NM


def step_class(H: float) -> str:
    return f"H_1/{1.0 / H:.0f}"


def random_classes(p: dict) -> list[str]:
    """The classes of a random draw (a run belongs to several)."""
    if p["unstable_probe"]:
        return ["unstable_probe"]
    c = [f"random_{p['health']}_{p['mesh_contact']}", f"shafts_{p['shaft_flexibility']}"]
    sp = p.get("speed_profile_rpm")
    if (sp and sp[0][1] == 0.0) or p.get("speed_mode") == "hold_zero":
        c.append("standstill")
    if sp:
        c.append("speed_ramp")
    if p.get("load_profile_Nm") and p.get("load_mode") == "step":
        c.append("load_step")
    if any(v < 0 for v in _load_values(p)):
        c.append("load_reversal")
    if is_rattle(p):
        c.append("rattle")
    c.append(step_class(p["comm_step_s"]))
    return c


def paper_parameters(scene: Scene) -> dict:
    return {"health": scene.gear.health, "drive_speed_rpm": scene.operating_point.drive_speed_rpm,
            "load_torque_Nm": scene.operating_point.load_torque_Nm, "mesh_contact": scene.effects.mesh_contact,
            "shaft_flexibility": scene.effects.shaft_flexibility, "comm_step_s": scene.numerics.comm_step_s,
            "duration_s": scene.time.duration_s}


def default_paper_grid() -> Path:
    """scenarios/paper/paper.toml of this checkout (or of the working directory)."""
    here = Path(__file__).resolve().parents[3] / "scenarios" / "paper" / "paper.toml"
    return here if here.is_file() else Path("scenarios/paper/paper.toml")


def paper_cases(grid: Path | str | None = None, duration_s: float | None = None) -> list[StressCase]:
    """The paper's grid (54 scenes), full length unless ``duration_s`` shortens them (quick checks)."""
    ov = ["outputs.plots=false"]
    if duration_s is not None:
        ov += [f"time.duration_s={float(duration_s)!r}", f"time.settle_s={min(2.0, 0.2 * float(duration_s))!r}"]
    scenes = load_scenes(grid or default_paper_grid(), ov)
    return [StressCase(s.name, "paper", s, [f"paper_{s.gear.health}"], paper_parameters(s)) for s in scenes]


def random_draws(seed: int, n: int, **kw) -> list[dict]:
    return [draw_random(seed, i, **kw) for i in range(int(n))]


def random_cases(draws: list[dict], mesh_paths: dict | None = None, halving_subset: int = DEFAULT_HALVING_SUBSET,
                 base_dir: Path | str = ".") -> list[StressCase]:
    """Scenes of the draws, plus the half-step twin of every ``halving_subset``-th (index % K == 0, not
    an unstable probe)."""
    paths = [mesh_paths.get(j) for j in range(max(mesh_paths) + 1)] if mesh_paths else None
    cases = []
    for p in draws:
        sc = scene_from_dict(random_scene_dict(p, paths), base_dir=base_dir)
        cases.append(StressCase(p["name"], "random", sc, random_classes(p), p))
        if halving_subset and p["index"] % int(halving_subset) == 0 and not p["unstable_probe"]:
            sh = scene_from_dict(random_scene_dict(p, paths, halve_step=True), base_dir=base_dir)
            hp = dict(p, comm_step_s=sh.numerics.comm_step_s, name=sh.name, halving_root=p["name"], halving_level=1)
            cases.append(StressCase(sh.name, "halving", sh, ["halved_step_runs"], hp, pair_of=p["name"]))
    return cases


#: how many times the campaign halves a scene's step again when a halving pair's runs pass but their torques
#: differ beyond the limits (H/2 vs H/4, then H/4 vs H/8): the first pair within the limits names the converged
#: step, the coarser steps are refused with the deviation as the reason; none within them is a failure
MAX_REFINEMENTS = 2


def refinement_case(half: StressCase) -> StressCase:
    """The next refinement of a halving chain: the scene of ``half`` (a half-step run) at half its step again,
    named ``<root>_H<2^level>``, paired with ``half``."""
    p = half.parameters
    level = int(p.get("halving_level", 1)) + 1
    H = float(half.scene.numerics.comm_step_s) / 2.0
    name = f"{p.get('halving_root', half.pair_of)}_H{2 ** level}"
    sc = half.scene
    sc = dataclasses.replace(sc, scenario=dataclasses.replace(sc.scenario, name=name),
                             numerics=dataclasses.replace(sc.numerics, comm_step_s=H))
    hp = dict(p, comm_step_s=H, name=name, halving_level=level)
    return StressCase(name, "halving", sc, ["halved_step_runs"], hp, pair_of=half.name)


def resolve_halving(pairs: list[dict]) -> None:
    """The halving chains of a campaign (pairs of one ``halving_root``, by level): when the first pair fails
    on the deviation of its torques alone and a finer pair passes, the coarser steps are refused with their
    deviation as the reason (``outcome = "refined"``) and the finer pair names the converged step
    (``converged_step_s``). A chain with no pair within the limits keeps its failures. Never a silent pass."""
    chains: dict[str, list[dict]] = {}
    for p in pairs:
        chains.setdefault(p.get("root") or p["base"], []).append(p)
    for chain in chains.values():
        chain.sort(key=lambda p: p.get("level") or 1)
        ok = next((i for i, p in enumerate(chain) if p["outcome"] == "pass"), None)
        if ok is None:
            continue
        for p in chain[:ok]:
            if p["outcome"] == "fail" and p.get("deviation"):
                p["outcome"] = "refined"
                p["reasons"] = [f"step refused by the halving rule (H = {p.get('step_s', float('nan')):.6g} s): "
                                + "; ".join(p["reasons"])]
        chain[ok]["converged_step_s"] = chain[ok].get("step_s")
        for p in chain:
            p["converged_step_s"] = chain[ok].get("step_s")


# --------------------------------------------------------------------------------------------------
# Judging
# --------------------------------------------------------------------------------------------------


def _finite(x) -> bool:
    try:
        return x is not None and math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def _is_refusal(error: str | None) -> bool:
    e = (error or "").lower()
    return e.startswith("configurationerror") and ("unstable" in e or "spectral radius" in e)


def judge_run(summary: dict | None, record: dict | None = None, *, refused: str | None = None,
              expected_duration_s: float | None = None) -> dict:
    """The verdict of one run from its summary.json (``None`` if none was written) and its sweep-manifest
    record. Returns ``{"outcome": "pass"|"fail"|"refused", "reasons": [...], "flags": [...],
    "not_reported": [...], "figures": {...}}``. ``refused``: the cause when the scene was refused before
    running (predicted unstable)."""
    record = record or {}
    reasons: list[str] = []
    flags: list[str] = []
    missing: list[str] = []
    fig: dict[str, Any] = {}
    if refused is not None:
        return {"outcome": "refused", "reasons": [refused], "flags": [], "not_reported": [], "figures": {}}
    if summary is None:
        err = record.get("error") or "no summary.json written"
        if _is_refusal(err):
            return {"outcome": "refused", "reasons": [err.splitlines()[0]], "flags": [], "not_reported": [],
                    "figures": {}}
        f = record.get("failure")
        cause = _failure_text(f) if isinstance(f, dict) else err.splitlines()[0] if err else "failed"
        return {"outcome": "fail", "reasons": [f"did not complete: {cause}"], "flags": [], "not_reported": [],
                "figures": {}}
    # completes
    status = summary.get("status")
    if status is None:
        missing.append("status")
        rs = record.get("status")
        if rs not in (None, "ok"):
            reasons.append(f"did not complete: {record.get('error', rs)}")
        elif expected_duration_s is not None and _finite(summary.get("sim_time_s")) and \
                summary["sim_time_s"] < expected_duration_s * (1 - 1e-6):
            reasons.append(f"did not complete: simulated {summary['sim_time_s']:.6g} s of {expected_duration_s:.6g} s")
    elif status != "ok":
        f = summary.get("failure")
        reasons.append("did not complete: " + (_failure_text(f) if isinstance(f, dict) else str(status)))
    # finite
    nf = summary.get("nonfinite_channels")
    if nf is None:
        missing.append("nonfinite_channels")
    elif nf:
        reasons.append("non-finite channels: " + ", ".join(map(str, nf)))
    tq = summary.get("torque") or {}
    bad = [f"{n}.{k}" for n, st in tq.items() for k in ("mean", "rms") if k in st and not _finite(st[k])]
    if bad:
        reasons.append("non-finite torque statistics: " + ", ".join(bad))
    fig["torque_mean"] = {n: st.get("mean") for n, st in tq.items()}
    fig["torque_rms"] = {n: st.get("rms") for n, st in tq.items()}
    # stability block
    stab = summary.get("stability")
    if not isinstance(stab, dict):
        stab = record.get("stability") if isinstance(record.get("stability"), dict) else None
    if stab is None:
        missing.append("stability")
    else:
        pen = stab.get("max_penetration_rel_umax")
        if pen is None:
            missing.append("stability.max_penetration_rel_umax")
        elif not _finite(pen):
            reasons.append(f"penetration/u_max not finite ({pen})")
        else:
            fig["max_penetration_rel_umax"] = float(pen)
            if pen >= LIMITS["max_penetration_rel_umax"]:
                reasons.append(f"penetration {pen:.3g} u_max >= u_max")
            elif pen > SUSPICIOUS_PENETRATION:
                flags.append(f"penetration {pen:.3g} u_max > {SUSPICIOUS_PENETRATION:g} u_max (suspicious)")
        for k in ("min_substep_s", "n_refinements"):
            if stab.get(k) is None:
                missing.append(f"stability.{k}")
            else:
                fig[k] = stab[k]
        rat = stab.get("rattle")
        if isinstance(rat, dict):
            for k in ("separated_time_s", "separated_fraction", "n_separations"):
                if rat.get(k) is not None:
                    fig[k] = rat[k]
        else:
            missing.append("stability.rattle")
    # energy
    er = summary.get("energy_residual", (stab or {}).get("energy_residual"))
    if er is None:
        if status in (None, "ok"):          # a failed run has no energy balance
            missing.append("energy_residual")
    elif not _finite(er):
        reasons.append(f"energy residual not finite ({er})")
    else:
        fig["energy_residual"] = float(er)
        if er >= LIMITS["energy_residual"]:
            reasons.append(f"energy residual {100 * er:.3g} % >= {100 * LIMITS['energy_residual']:g} %")
    for k in ("wall_time_s", "sim_time_s", "real_time_factor"):
        if summary.get(k) is not None:
            fig[k] = summary[k]
    return {"outcome": "fail" if reasons else "pass", "reasons": reasons, "flags": flags, "not_reported": missing,
            "figures": fig}


def _failure_text(f: dict) -> str:
    t = f.get("time_s")
    where = f" in {f['component']}" if f.get("component") else ""
    when = f" at t = {t:.6g} s" if _finite(t) else ""
    return f"{f.get('cause', 'failed')}{where}{when}"


def _rel(a, b) -> float:
    return abs(float(a) - float(b)) / max(abs(float(b)), ZERO_TORQUE_NM)


def held_standstill_from_s(p: dict) -> float | None:
    """When a draw holds its drive at standstill with friction or losses on: the time from which the speed
    reference stays 0 (0.0 for a scene held from the start), else None.

    Why it matters. The loss law ``(T_c + a |T|) tanh(w / w_c)`` and the regularised mesh friction are
    Coulomb laws smoothed at zero speed: a drivetrain held still under a load creeps at a speed well below
    ``w_c``, and the torque the friction holds is whatever that creep speed makes of the band
    ``+-(T_c + a |T|)``. Physically that torque is indeterminate (static friction holds anything inside the
    band); numerically the creep speed, and with it the held torque, depends on the step. So a halving pair
    whose whole runs differ beyond the limits compares a held standstill's torques over the part of the run
    before it (:func:`judge_halving`'s ``window_s``) and reports the held part's means without judging them; a
    scene held from the start has no part to compare and its pair is "not comparable", with that reason, never
    a pass. A pair whose whole runs agree within the limits passes as any pair does."""
    if not (p.get("friction") or p.get("losses")):
        return None
    if p.get("speed_mode") == "hold_zero" or p.get("drive_speed_rpm") == 0.0:
        return 0.0
    prof = p.get("speed_profile_rpm") or []
    if not prof or float(prof[-1][1]) != 0.0:
        return None
    i = len(prof) - 1
    while i > 0 and float(prof[i - 1][1]) == 0.0:
        i -= 1
    return float(prof[i][0])


#: the shortest moving part [s] a halving pair of a held standstill is compared over (a tenth of a second:
#: over a hundred mesh periods above 300 rpm); shorter, the pair is "not comparable"
MIN_MOVING_WINDOW_S = 0.1


def _window_stats(run_dir: Path, t0: float, t1: float) -> dict | None:
    """Torque statistics of the halving sensors over t0 <= t < t1 from a run's signals (None if unreadable)."""
    from drivetrain.rig.signals import stats
    from drivetrain.run.files import FileFormatError, read_signals

    try:
        h = read_signals(run_dir / "signals.h5")
    except (FileFormatError, OSError):
        return None
    t = np.asarray(h["time"], dtype=float)
    m = (t >= t0) & (t < t1)
    out = {}
    for s in HALVING_SENSORS:
        x = h["signals"].get(s)
        if x is not None and m.any():
            out[s] = stats(np.asarray(x, dtype=float)[m])
    return out


def _settle_s(summary: dict | None, p: dict) -> float:
    """The settling time a random draw's run was judged from (its stability window, else the scene default
    min(2 s, 20 % of the duration))."""
    w = ((summary or {}).get("stability") or {}).get("window_s")
    if isinstance(w, (list, tuple)) and w and _finite(w[0]):
        return float(w[0])
    return min(2.0, 0.2 * float(p.get("duration_s") or 0.0))


def held_pair_statistics(base: dict, half: dict, summary_h: dict | None, summary_h2: dict | None,
                         out_dir: Path) -> dict | None:
    """For a halving pair whose draw holds a standstill (:func:`held_standstill_from_s`): {"window_s": [t0,
    t1], "moving": (stats at H, stats at H/2) or None, "held": (stats at H, stats at H/2)}; None when the
    draw holds no standstill."""
    p = base.get("parameters") or {}
    t_hold = held_standstill_from_s(p)
    if t_hold is None:
        return None
    t0 = _settle_s(summary_h2, p)
    D = float(p.get("duration_s") or 0.0)
    moving = None
    if t_hold - t0 >= MIN_MOVING_WINDOW_S:
        a, b = _window_stats(out_dir / base["name"], t0, t_hold), _window_stats(out_dir / half["name"], t0, t_hold)
        moving = (a, b) if a and b else None
    held = (_window_stats(out_dir / base["name"], max(t0, t_hold), D + 1.0),
            _window_stats(out_dir / half["name"], max(t0, t_hold), D + 1.0))
    return {"window_s": [t0, t_hold], "moving": moving, "held": held}


def judge_halving(run_h: dict, run_h2: dict, summary_h: dict | None, summary_h2: dict | None,
                  held: dict | None = None) -> dict:
    """Verdict of a halving pair: the verdicts of the run at H and at H/2 and their summaries. Deviations
    are relative to the H/2 run (denominators below ZERO_TORQUE_NM are taken as that floor). ``held``
    (:func:`held_pair_statistics`): the draw holds a standstill. Its pair is judged whole first, as every
    pair is; a pair within the limits passes (``compared`` "whole run"). One beyond them is compared over the
    moving part before the standstill (``compared`` "moving part"), or is "not comparable" when there is none."""
    outs = (run_h["outcome"], run_h2["outcome"])
    if "refused" in outs:
        return {"outcome": "refused", "reasons": ["a run of the pair was refused before running"], "deviation": {}}
    if "fail" in outs:
        return {"outcome": "fail", "reasons": ["a run of the pair failed"], "deviation": {}}
    torque_h = (summary_h or {}).get("torque") or {}
    torque_h2 = (summary_h2 or {}).get("torque") or {}
    reasons, dev = _compare_torques(torque_h, torque_h2)
    extra: dict[str, Any] = {}
    if held is not None:
        t0, t1 = held["window_s"]
        extra = {"window_s": [t0, t1], "held_means": {
            s: [((held["held"][0] or {}).get(s) or {}).get("mean"), ((held["held"][1] or {}).get(s) or {}).get("mean")]
            for s in HALVING_SENSORS}}
        if not reasons:
            # the whole run meets the rule every pair meets: judged whole, the held part included
            return _pair_verdict([], dev, {**extra, "compared": "whole run"})
        if held["moving"] is None:
            why = (f"held at standstill under friction/losses from t = {t1:.6g} s, the whole runs differ beyond the "
                   f"limits ({'; '.join(reasons)}), and the moving part after the settling time {t0:.6g} s is "
                   + ("unreadable" if t1 - t0 >= MIN_MOVING_WINDOW_S else f"shorter than {MIN_MOVING_WINDOW_S:g} s")
                   + ": the held torque is indeterminate within the friction band, so the step's convergence "
                     "cannot be judged from it")
            return {"outcome": "not_comparable", "reasons": [why], "deviation": {}, "compared": "–", **extra}
        reasons, dev = _compare_torques(*held["moving"])
        prefix = f"over the moving part {t0:.6g} <= t < {t1:.6g} s (held at standstill after it): "
        return _pair_verdict([prefix + r for r in reasons], dev, {**extra, "compared": "moving part"})
    return _pair_verdict(reasons, dev, extra)


def _compare_torques(torque_h: dict, torque_h2: dict) -> tuple[list[str], dict]:
    """The halving rule on two runs' torque statistics ({sensor: {"mean", "rms"}}): (reasons it fails, deviations
    per sensor); no reasons: within the limits."""
    reasons, dev = [], {}
    for s in HALVING_SENSORS:
        a = torque_h.get(s)
        b = torque_h2.get(s)
        if not a or not b:
            reasons.append(f"{s}: torque statistics missing")
            continue
        dm, dr = _rel(a["mean"], b["mean"]), _rel(a["rms"], b["rms"])
        dev[s] = {"mean": dm, "rms": dr, "mean_H": a["mean"], "mean_H2": b["mean"], "rms_H": a["rms"],
                  "rms_H2": b["rms"]}
        if not dm < LIMITS["halving_mean"]:
            reasons.append(f"{s}: mean {a['mean']:.6g} vs {b['mean']:.6g} N·m differs by {100 * dm:.3g} % "
                           f"(limit {100 * LIMITS['halving_mean']:g} %)")
        if not dr < LIMITS["halving_rms"]:
            reasons.append(f"{s}: RMS {a['rms']:.6g} vs {b['rms']:.6g} N·m differs by {100 * dr:.3g} % "
                           f"(limit {100 * LIMITS['halving_rms']:g} %)")
    return reasons, dev


def _pair_verdict(reasons: list[str], dev: dict, extra: dict) -> dict:
    return {"outcome": "fail" if reasons else "pass", "reasons": reasons, "deviation": dev,
            "max_mean_dev": max((d["mean"] for d in dev.values()), default=None),
            "max_rms_dev": max((d["rms"] for d in dev.values()), default=None), **extra}


# --------------------------------------------------------------------------------------------------
# The class table and the report
# --------------------------------------------------------------------------------------------------

_HEALTH_ORDER = {h: i for i, h in enumerate(HEALTHS)}
_FID_ORDER = {f: i for i, f in enumerate(FIDELITIES)}


def _class_key(c: str):
    if c.startswith("paper_"):
        return (0, _HEALTH_ORDER.get(c[6:], 9), 0, c)
    if c.startswith("random_"):
        h, _, f = c[7:].partition("_")
        return (1, _HEALTH_ORDER.get(h, 9), _FID_ORDER.get(f, 9), c)
    special = ["shafts_flexible", "shafts_rigid", "standstill", "speed_ramp", "load_step", "load_reversal", "rattle"]
    if c in special:
        return (2, special.index(c), 0, c)
    if c.startswith("H_1/"):
        try:
            return (3, float(c[4:]), 0, c)
        except ValueError:
            return (3, 0, 0, c)
    order = ["unstable_probe", "halved_step_runs", "halving_pairs"]
    return (4, order.index(c) if c in order else 9, 0, c)


def class_table(runs: list[dict], pairs: list[dict]) -> list[dict]:
    """Rows: class, runs, pass, fail, refused and the worst figures of the class; the last row is the
    total over unique runs (pairs are counted in their own row)."""
    by_class: dict[str, list[dict]] = {}
    for r in runs:
        for c in r["classes"]:
            by_class.setdefault(c, []).append(r)
    pair_of_base = {p["base"]: p for p in pairs}
    rows = []

    def worst(rs, prs):
        pen = [r["figures"]["max_penetration_rel_umax"] for r in rs if "max_penetration_rel_umax" in r["figures"]]
        sub = [r["figures"]["min_substep_s"] for r in rs if _finite(r["figures"].get("min_substep_s"))]
        er = [r["figures"]["energy_residual"] for r in rs if "energy_residual" in r["figures"]]
        hm = [p["max_mean_dev"] for p in prs if p.get("max_mean_dev") is not None]
        hr = [p["max_rms_dev"] for p in prs if p.get("max_rms_dev") is not None]
        ran = [r for r in rs if r["outcome"] != "refused"]
        return {"max_penetration_rel_umax": max(pen) if pen else None,
                "min_substep_s": min(sub) if sub else None,
                "max_energy_residual": max(er) if er else None,
                "max_halving_mean_dev": max(hm) if hm else None,
                "max_halving_rms_dev": max(hr) if hr else None,
                "n_not_reported_stability": sum(1 for r in ran if "stability" in r.get("not_reported", [])
                                                or "stability.max_penetration_rel_umax" in r.get("not_reported", [])),
                "n_ran": len(ran)}

    def count(items):
        return {k: sum(1 for x in items if x["outcome"] == k) for k in ("pass", "fail", "refused", "refined")}

    for c in sorted(by_class, key=_class_key):
        rs = by_class[c]
        prs = [pair_of_base[r["name"]] for r in rs if r["name"] in pair_of_base]
        rows.append({"class": c, "runs": len(rs), **count(rs), **worst(rs, prs)})
    if pairs:
        rows.append({"class": "halving_pairs", "runs": len(pairs), **count(pairs), **worst([], pairs)})
    rows.append({"class": "all runs", "runs": len(runs), **count(runs), **worst(runs, pairs)})
    return rows


def _fmt(x, kind: str) -> str:
    if x is None:
        return "n/r"
    if kind == "pct":
        return f"{100 * x:.3g} %"
    if kind == "s":
        return f"{x:.3g}"
    return f"{x:.3g}"


def _held_section(held: list[dict]) -> list[str]:
    """stress.md's section on the halving pairs of draws held at standstill."""
    lines = ["## Halving pairs held at standstill", "",
             "These draws hold the drive at standstill under friction or losses. Each pair is judged whole "
             "first, as every pair is: within the limits, it passes. Beyond them, the torque the regularised "
             "Coulomb laws hold at rest is indeterminate within the friction band and follows the creep speed, "
             "which depends on the step, so the pair is compared over the moving part before the standstill "
             f"(at least {MIN_MOVING_WINDOW_S:g} s after the settling time) and the held means are shown, not "
             "judged; a draw held from the start has no moving part and is not comparable (neither a pass nor "
             "a failure). The moving-part rule came after `rnd_s8_0000` failed the whole-run comparison at "
             "every step; judging whole first came after the ten-seed campaign left four pairs not comparable, "
             "three of them within the limits whole (docs/STABILITY.md).", "",
             "| pair | outcome | compared over [s] | max dev. mean / RMS there | held means at H / H/2 [N·m] |",
             "|---|---|---|---|---|"]
    for p in held:
        w = p["window_s"]
        hm = "; ".join(f"{s}: {_fmt(v[0], '')} / {_fmt(v[1], '')}" for s, v in (p.get("held_means") or {}).items())
        dv = ("–" if p.get("max_mean_dev") is None else
              f"{_fmt(p.get('max_mean_dev'), 'pct')} / {_fmt(p.get('max_rms_dev'), 'pct')}")
        span = ("whole run" if p.get("compared") == "whole run" else
                f"{w[0]:.3g}–{w[1]:.3g}" + (" (moving part)" if p.get("compared") == "moving part" else ""))
        lines.append(f"| `{p['base']}` / `{p['half']}` | {p['outcome']} | {span} | {dv} | {hm} |")
    lines.append("")
    for p in held:
        if p["outcome"] == "not_comparable":
            lines.append(f"- `{p['base']}` / `{p['half']}`: " + "; ".join(p["reasons"]))
    lines.append("")
    return lines


def report_markdown(rec: dict) -> str:
    """stress.md from the campaign record (stress.json)."""
    L = LIMITS
    lines = ["# Stress campaign", ""]
    tot = rec["table"][-1] if rec.get("table") else {}
    npairs = len(rec.get("pairs", []))
    pf = sum(1 for p in rec.get("pairs", []) if p["outcome"] == "fail")
    nref = sum(1 for p in rec.get("pairs", []) if p["outcome"] == "refined")
    nnc = sum(1 for p in rec.get("pairs", []) if p["outcome"] == "not_comparable")
    nwin = sum(1 for p in rec.get("pairs", []) if p.get("window_s") and p["outcome"] != "not_comparable")
    seeds = rec.get("seeds") or [rec.get("seed")]
    seed_text = f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {', '.join(map(str, seeds))}"
    lines += [f"Command: `{rec.get('command', 'drivetrain stress')}`", "", commit_line(), "",
              f"Started {rec.get('started', '?')}; wall time {rec.get('wall_time_s', float('nan')):.0f} s "
              f"(this invocation; the runs' own wall times sum to {rec.get('runs_wall_time_s', float('nan')):.0f} s); "
              f"{seed_text}, sets {rec.get('set_name')}, {rec.get('n_random', 0)} random scenes per seed "
              f"({rec.get('duration_random_s', '?')} s each, pcm {rec.get('duration_pcm_s', '?')} s); "
              + (f"every {rec['halving_subset']}-th random scene also run at H/2." if rec.get("halving_subset")
                 else "no halving pairs."), "",
              f"**{tot.get('runs', 0)} runs: {tot.get('pass', 0)} pass, {tot.get('fail', 0)} fail, "
              f"{tot.get('refused', 0)} refused before running (predicted unstable); {npairs} halving pairs, "
              f"{pf} outside the limits"
              + (f", {nref} of them at a step refused by the halving rule, a converged step chosen (below)" if nref
                 else "")
              + (f"; {nnc} not comparable (held at standstill from the start, below)" if nnc else "") + ".**", "",
              f"A run passes when it completes (status ok), every channel is finite, the largest contact penetration "
              f"is below u_max (> {SUSPICIOUS_PENETRATION:g} u_max is flagged) and the energy residual is "
              f"< {100 * L['energy_residual']:g} %. A halving pair (the scene again at H/2) passes when both runs pass "
              f"and the mean torques of {' and '.join(HALVING_SENSORS)} agree within {100 * L['halving_mean']:g} % "
              f"and their RMS within {100 * L['halving_rms']:g} % (relative to the H/2 run; |values| below "
              f"{ZERO_TORQUE_NM:g} N·m count as that floor). \"n/r\": not reported by any run of the class.", "",
              "| class | runs | pass | fail | refused | max penetration / u_max | min sub-step [s] | "
              "max energy residual | max halving dev. mean / RMS | stability n/r |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rec.get("table", []):
        hd = ("–" if r.get("max_halving_mean_dev") is None and r.get("max_halving_rms_dev") is None else
              f"{_fmt(r.get('max_halving_mean_dev'), 'pct')} / {_fmt(r.get('max_halving_rms_dev'), 'pct')}")
        nr = r.get("n_not_reported_stability", 0)
        lines.append(f"| {r['class']} | {r['runs']} | {r['pass']} | {r['fail']} | {r['refused']} | "
                     f"{_fmt(r.get('max_penetration_rel_umax'), '')} | {_fmt(r.get('min_substep_s'), 's')} | "
                     f"{_fmt(r.get('max_energy_residual'), 'pct')} | {hd} | "
                     f"{nr if nr else '0'}/{r.get('n_ran', r['runs'])} |")
    lines.append("")
    fails = [r for r in rec.get("runs", []) if r["outcome"] == "fail"]
    pfails = [p for p in rec.get("pairs", []) if p["outcome"] == "fail"]
    lines += ["## Failures", ""]
    if not fails and not pfails:
        lines += ["None.", ""]
    for r in fails:
        lines.append(f"- `{r['name']}` ({', '.join(r['classes'])}): " + "; ".join(r["reasons"]))
    for p in pfails:
        lines.append(f"- halving pair `{p['base']}` / `{p['half']}`: " + "; ".join(p["reasons"]))
    if fails or pfails:
        lines.append("")
    refined = [p for p in rec.get("pairs", []) if p["outcome"] == "refined"]
    if refined:
        lines += ["## Steps refused by the halving rule (a converged step chosen)", "",
                  "The pair's runs passed, but their torques differ beyond the limits: the campaign halved the step "
                  f"again (up to {MAX_REFINEMENTS} times) and the first pair within the limits names the converged "
                  "step of the scene.", ""]
        for p in refined:
            conv = p.get("converged_step_s")
            lines.append(f"- `{p['base']}` / `{p['half']}`: " + "; ".join(p["reasons"])
                         + (f" -> converged at H = {conv:.6g} s" if _finite(conv) else ""))
        lines.append("")
    held = [p for p in rec.get("pairs", []) if p.get("window_s")]
    if held:
        lines += _held_section(held)
    refused = [r for r in rec.get("runs", []) if r["outcome"] == "refused"]
    if refused:
        lines += ["## Refused before running (predicted unstable)", ""]
        for r in refused:
            H = (r.get("parameters") or {}).get("comm_step_s")
            lines.append(f"- `{r['name']}` ({', '.join(r['classes'])}"
                         + (f", H = {H:.6g} s" if _finite(H) else "") + f"): {short_refusal(r['reasons'][0] if r['reasons'] else '')}")
        lines.append("")
    flagged = [r for r in rec.get("runs", []) if r.get("flags")]
    if flagged:
        lines += ["## Flagged (suspicious, not failed)", ""]
        for r in flagged:
            lines.append(f"- `{r['name']}`: " + "; ".join(r["flags"]))
        lines.append("")
    nr: dict[str, int] = {}
    for r in rec.get("runs", []):
        for k in r.get("not_reported", []):
            nr[k] = nr.get(k, 0) + 1
    if nr:
        lines += ["## Not reported", "",
                  "Figures missing from the runs' summaries (judged as not reported, not as failures):", ""]
        for k, n in sorted(nr.items()):
            lines.append(f"- `{k}`: {n} runs")
        lines.append("")
    if rec.get("fault_meshes"):
        lines += ["## Random fault meshes", ""]
        for m in rec["fault_meshes"]:
            lines.append(f"- `{Path(m['path']).name}`: {m['description']}")
        lines.append("")
    lines += [f"Regenerate this file from the run directories: `drivetrain stress --out {rec.get('out_dir', 'DIR')} "
              "--report-only` (or `drivetrain.campaigns.stress.regenerate_report(DIR)`).", ""]
    return "\n".join(lines)


def short_refusal(msg: str) -> str:
    """The unstable cuts (and/or the whole-system radius) of an assembler refusal, in one line."""
    import re

    parts = [f"cut {m.group(1)}: spectral radius {float(m.group(2)):.4g}"
             for m in re.finditer(r"cut (\S+ -> \S+):.*?spectral radius = ([0-9.eE+-]+) \(UNSTABLE\)", msg)]
    m = re.search(r"whole co-simulated system is unstable at H = ([0-9.eE+-]+) s: spectral radius of the "
                  r"one-step map ([0-9.eE+-]+)", msg)
    if m:
        parts.append(f"whole system: spectral radius {float(m.group(2)):.4g} at H = {float(m.group(1)):.4g} s")
    return ("predicted unstable: " + "; ".join(parts)) if parts else " ".join(msg.split())[:300]


def _read_summary(d: Path) -> dict | None:
    f = d / "summary.json"
    if not f.is_file():
        return None
    try:
        return json.loads(f.read_text())
    except (OSError, ValueError):
        return None


def judge_campaign(entries: list[dict], out_dir: Path, records: dict | None = None) -> tuple[list[dict], list[dict]]:
    """Judge every run (entries: name, set, classes, parameters, pair_of, refused) from its directory in
    out_dir and the manifest records; returns (runs, pairs)."""
    records = records or {}
    runs, summaries = [], {}
    for e in entries:
        s = None if e.get("refused") else _read_summary(out_dir / e["name"])
        summaries[e["name"]] = s
        v = judge_run(s, records.get(e["name"]), refused=e.get("refused"),
                      expected_duration_s=(e.get("parameters") or {}).get("duration_s"))
        runs.append({**{k: e.get(k) for k in ("name", "set", "classes", "parameters", "pair_of", "refused")},
                     "out_dir": str(out_dir / e["name"]), **v})
    by_name = {r["name"]: r for r in runs}
    pairs = []
    for r in runs:
        if r.get("pair_of") and r["pair_of"] in by_name:
            base = by_name[r["pair_of"]]
            held = held_pair_statistics(base, r, summaries.get(base["name"]), summaries.get(r["name"]), out_dir)
            v = judge_halving(base, r, summaries.get(base["name"]), summaries.get(r["name"]), held)
            par = r.get("parameters") or {}
            pairs.append({"base": base["name"], "half": r["name"], "classes": base["classes"],
                          "root": par.get("halving_root") or base["name"], "level": par.get("halving_level") or 1,
                          "step_s": (base.get("parameters") or {}).get("comm_step_s"), **v})
    resolve_halving(pairs)
    return runs, pairs


def to_refine(pairs: list[dict], cases: list[StressCase]) -> list[StressCase]:
    """The refinement runs a judged campaign needs next: for each chain whose finest pair failed on its
    torques' deviation alone (both runs passed), below :data:`MAX_REFINEMENTS`, its next step."""
    by_name = {c.name: c for c in cases}
    finest: dict[str, dict] = {}
    for p in pairs:
        root = p.get("root") or p["base"]
        if root not in finest or (p.get("level") or 1) > (finest[root].get("level") or 1):
            finest[root] = p
    out = []
    for p in finest.values():
        if (p["outcome"] == "fail" and p.get("deviation") and (p.get("level") or 1) <= MAX_REFINEMENTS
                and p["half"] in by_name):
            out.append(refinement_case(by_name[p["half"]]))
    return out


def _finish(rec: dict, entries: list[dict], out: Path, records: dict | None) -> dict:
    runs, pairs = judge_campaign(entries, out, records)
    rec["runs"], rec["pairs"] = runs, pairs
    rec["table"] = class_table(runs, pairs)
    rec["runs_wall_time_s"] = float(sum(r["figures"].get("wall_time_s") or 0.0 for r in runs))
    rec["n_fail"] = sum(1 for r in runs if r["outcome"] == "fail") + sum(1 for p in pairs if p["outcome"] == "fail")
    rec["limits"] = dict(LIMITS, suspicious_penetration=SUSPICIOUS_PENETRATION, zero_torque_Nm=ZERO_TORQUE_NM)

    (out / "stress.json").write_text(json.dumps(jsonable(rec), indent=1))
    (out / "stress.md").write_text(report_markdown(rec))
    return rec


_NP_SCALAR = re.compile(r"^np\.(?:float|int)\d*\((.*)\)$")


def _stored_numbers(obj):
    """Parameters as stress.json stored them, with the numbers that campaigns before the fix of
    ``run.outputs.jsonable`` wrote as ``{"generated_profile": "np.float64(2148.418)"}`` read back as numbers."""
    if isinstance(obj, dict):
        m = _NP_SCALAR.match(str(obj.get("generated_profile", ""))) if len(obj) == 1 else None
        return float(m.group(1)) if m else {k: _stored_numbers(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_stored_numbers(v) for v in obj]
    return obj


def regenerate_report(out_dir: Path | str) -> dict:
    """Re-judge an existing campaign directory (its stress.json lists the runs) from the run directories
    and rewrite stress.json and stress.md. Returns the record."""
    out = Path(out_dir)
    rec = json.loads((out / "stress.json").read_text())
    entries = [{k: (_stored_numbers(r.get(k)) if k == "parameters" else r.get(k))
                for k in ("name", "set", "classes", "parameters", "pair_of", "refused")} for r in rec["runs"]]
    try:
        records = {r["name"]: r for r in read_runs(out)}
    except OSError:
        records = {}
    return _finish(rec, entries, out, records)


# --------------------------------------------------------------------------------------------------
# The campaign
# --------------------------------------------------------------------------------------------------


def _cost(c: StressCase) -> float:
    """Rough relative cost, to submit the longest runs first (of an assembled case)."""
    from drivetrain.run.cost import predict

    return predict(c.spec, c.scene.time.duration_s).total_s


def _map_key(comp) -> str:
    p = comp.parameters
    keep = {k: p.get(k) for k in ("fidelity", "health", "pinion_mesh_file", "wheel_mesh_file",
                                  "profile_element_size", "face_element_size")}
    return json.dumps(keep, sort_keys=True, default=str)


def prepare_maps(cases: list[StressCase], fmu_dir, fmu_paths=None, log=None) -> int:
    """Build (once, in this process) the contact maps the ``table`` runs need; one preparation per
    distinct map (friction, damping and the sub-step do not change the map)."""

    seen, specs = set(), []
    for c in cases:
        if c.spec is None:
            continue
        for comp in c.spec.components:
            if comp.parameters.get("fidelity") in CACHED_FIDELITIES:
                k = _map_key(comp)
                if k not in seen:
                    seen.add(k)
                    specs.append(SystemSpec(components=[comp], connections=[], comm_step=c.spec.comm_step))
    if not specs:
        return 0
    return prepare_caches(specs, fmu_dir, fmu_paths, log=log)


def build_cases(*, set_name: str = "all", n_random: int = 200, seed: int = 0, out_dir: Path | str = "out/stress",
                duration_random_s: float = DEFAULT_DURATION_S, duration_pcm_s: float = DEFAULT_DURATION_PCM_S,
                halving_subset: int = DEFAULT_HALVING_SUBSET, fidelities=None, paper_grid=None,
                duration_paper_s: float | None = None, n_fault_meshes: int = N_FAULT_MESHES,
                log=None, seeds: list[int] | None = None, pair: str | None = None) -> tuple[list[StressCase], list[dict]]:
    """Every case of the campaign (scenes validated; fault meshes written when a scene needs one).
    ``seeds``: the random sets of these seeds (default: ``seed`` alone), ``n_random`` scenes each.
    ``pair``: the random scenes on that other pair (``OTHER_PAIRS``; the paper grid is the rig's, so only with
    ``set_name="random"``). Returns (cases, fault mesh descriptions)."""
    if set_name not in ("paper", "random", "all"):
        raise ValueError(f"set_name must be paper, random or all, not {set_name!r}")
    if pair is not None and set_name != "random":
        raise ValueError(f"--pair {pair} draws the random scenes on another pair; the paper grid is the rig's: "
                         f"use --set-name random")
    if pair is not None and pair not in OTHER_PAIRS:
        raise ValueError(f"no other pair {pair!r}; expected one of {', '.join(OTHER_PAIRS)}")
    out = Path(out_dir)
    cases: list[StressCase] = []
    meshes: list[dict] = []
    if set_name in ("paper", "all"):
        cases += paper_cases(paper_grid, duration_paper_s)
    for sd in (seeds if seeds is not None else [seed]) if set_name in ("random", "all") and n_random > 0 else ():
        draws = random_draws(sd, n_random, duration_s=duration_random_s, duration_pcm_s=duration_pcm_s,
                             fidelities=fidelities, n_fault_meshes=n_fault_meshes, pair=pair)
        need = sorted({p["fault_mesh"] for p in draws if p["fault_mesh"] is not None})
        paths = write_fault_meshes(out / "meshes", sd, need, log=log, pair=pair) if need else {}
        meshes += [{"index": j, "seed": sd, "path": str(paths[j]), "params": fault_mesh_params(sd, j, pair),
                    "description": describe_fault(fault_mesh_params(sd, j, pair))} for j in need]
        cases += random_cases(draws, paths, halving_subset, base_dir=out)
    return cases, meshes


def _entries(cases: list[StressCase]) -> list[dict]:
    return [{"name": c.name, "set": c.set, "classes": c.classes, "parameters": c.parameters,
             "pair_of": c.pair_of, "refused": c.refused} for c in cases]


def _refine_steps(cases: list[StressCase], runnable: list[StressCase], out: Path, records: dict, sweep_kw: dict,
                  log) -> dict | None:
    """Halving chains whose pair failed on its torques alone get their next step (:func:`to_refine`), run
    with the others reused (the sweep's skip_existing), until every chain is within the limits or at
    :data:`MAX_REFINEMENTS`; ``cases`` and ``runnable`` grow by the refinement runs. The last manifest, or
    None when nothing needed refining."""
    manifest = None
    for _ in range(MAX_REFINEMENTS):
        _, pairs = judge_campaign(_entries(cases), out, records)
        more = to_refine(pairs, cases)
        if not more:
            break
        if log:
            log(f"{len(more)} halving pairs outside the limits with both runs passing: their steps halved again "
                f"({', '.join(c.name for c in more)})")
        assemble_cases(more, log=log)
        cases += more
        runnable += [c for c in more if c.spec is not None and c.refused is None]
        for c in more:
            if c.extra.get("assembly_error"):
                records[c.name] = {"name": c.name, "status": "failed", "error": c.extra["assembly_error"]}
        order = sorted(runnable, key=_cost, reverse=True)
        manifest = run_sweep([c.scene for c in order], out, skip_existing=True,
                             specs={c.name: c.spec for c in order}, **sweep_kw)
        for r in manifest["runs"]:
            records[r["name"]] = r
    return manifest


def assemble_cases(cases: list[StressCase], log=None) -> None:
    """Assemble every scene (the runs use exactly these specs); a scene the cut check refuses before
    running is marked ``refused`` (predicted unstable); another refusal is left to the run to report."""

    for c in cases:
        try:
            c.spec = assemble_scene(c.scene)
        except ConfigurationError as exc:
            msg = str(exc)
            if getattr(exc, "reports", None) or "unstable" in msg.lower():
                c.refused = "refused before running (predicted unstable): " + " ".join(msg.split())
            else:
                c.extra["assembly_error"] = f"ConfigurationError: {msg}"
        except Exception as exc:  # reported as a failure of the run
            c.extra["assembly_error"] = f"{type(exc).__name__}: {exc}"


def run_stress(out_dir: Path | str = "out/stress", *, set_name: str = "all", n_random: int = 200, seed: int = 0,
               workers: int | None = None, address: str | None = None, resume: bool = False,
               halving_subset: int = DEFAULT_HALVING_SUBSET, duration_random_s: float = DEFAULT_DURATION_S,
               duration_pcm_s: float = DEFAULT_DURATION_PCM_S, duration_paper_s: float | None = None,
               fidelities=None, paper_grid=None, n_fault_meshes: int = N_FAULT_MESHES,
               fmu_dir: Path | str | None = None, backend: str = "fmi", progress: bool = False, only=None,
               command: str | None = None, log: Callable[[str], None] | None = None,
               seeds: list[int] | None = None, pair: str | None = None) -> dict:
    """Run the campaign into ``out_dir`` and return the record written to stress.json (see the module
    docstring). ``resume``: finished runs of the same scene and model sources are not rerun (the sweep's
    skip_existing, by fingerprint).
    ``only``: fnmatch patterns; run (and report) only the cases whose name matches one (a half-step
    run ``<name>_halfH`` is kept with its base run)."""

    t0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    started = now_iso()
    cases, meshes = build_cases(set_name=set_name, n_random=n_random, seed=seed, out_dir=out,
                                duration_random_s=duration_random_s, duration_pcm_s=duration_pcm_s,
                                halving_subset=halving_subset, fidelities=fidelities, paper_grid=paper_grid,
                                duration_paper_s=duration_paper_s, n_fault_meshes=n_fault_meshes, log=log,
                                seeds=seeds, pair=pair)
    if only:
        import fnmatch

        keep = {c.name for c in cases if any(fnmatch.fnmatch(c.name, pat) for pat in only)}
        cases = [c for c in cases if c.name in keep or (c.pair_of is not None and c.pair_of in keep)]
    if log:
        log(f"{len(cases)} runs ({sum(c.set == 'paper' for c in cases)} paper, {sum(c.set == 'random' for c in cases)} "
            f"random, {sum(c.set == 'halving' for c in cases)} half-step); assembling")
    assemble_cases(cases, log=log)
    records: dict[str, dict] = {}
    for c in cases:
        if c.extra.get("assembly_error"):
            records[c.name] = {"name": c.name, "status": "failed", "error": c.extra["assembly_error"]}
    runnable = [c for c in cases if c.spec is not None and c.refused is None]
    todo = [c for c in runnable if not (resume and (out / c.name / "summary.json").is_file())]
    if log:
        log(f"{len(runnable)} to run ({len(runnable) - len(todo)} already done), "
            f"{sum(c.refused is not None for c in cases)} refused before running")
    for c in todo:      # a stale summary of an earlier campaign must not judge a run that fails to write one
        (out / c.name / "summary.json").unlink(missing_ok=True)
    manifest = None
    if runnable:
        if todo:
            from drivetrain.fmu_build.fmus import ensure_fmus

            # the maps are prepared by instantiating GearContact in this process: its FMU must exist
            models = list(dict.fromkeys(comp.model for c in todo for comp in c.spec.components))
            ensure_fmus(models, fmu_dir, build=True, log=log or (lambda m: None))
            prepare_maps(todo, fmu_dir, log=log)
        order = sorted(runnable, key=_cost, reverse=True)
        manifest = run_sweep([c.scene for c in order], out, workers=workers, address=address, backend=backend,
                             fmu_dir=fmu_dir, skip_existing=resume, plots=False, progress=progress,
                             specs={c.name: c.spec for c in order}, prepare=False)
        for r in manifest["runs"]:
            records[r["name"]] = r
        manifest = _refine_steps(cases, runnable, out, records, dict(workers=workers, address=address, backend=backend,
                                 fmu_dir=fmu_dir, plots=False, progress=progress, prepare=False), log) or manifest
    entries = _entries(cases)
    rec = {
        "command": command or "drivetrain stress", "started": started, "out_dir": str(out),
        "set_name": set_name, "seed": int(seed), "seeds": list(seeds) if seeds is not None else [int(seed)],
        "n_random": int(n_random) if set_name != "paper" else 0,
        "duration_random_s": duration_random_s, "duration_pcm_s": duration_pcm_s,
        "duration_paper_s": duration_paper_s, "halving_subset": halving_subset, "fidelities": list(fidelities or FIDELITIES),
        "resume": bool(resume), "executor": "dask" if address else "local processes",
        "manifest": manifest["path"] if manifest else None, "fault_meshes": meshes,
    }
    if pair is not None:
        rec["pair"] = {"name": pair, "keys": pair_keys(other_pair(pair))}
    rec["wall_time_s"] = time.perf_counter() - t0
    return _finish(rec, entries, out, records)


__all__ = ["draw_random", "random_draws", "random_scene_dict", "random_classes", "fault_mesh_params",
           "build_fault_mesh", "write_fault_meshes", "paper_cases", "random_cases", "build_cases", "judge_run",
           "judge_halving", "judge_campaign", "class_table", "report_markdown", "regenerate_report", "run_stress",
           "LIMITS", "StressCase"]
