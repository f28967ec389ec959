"""The GearContact FMU's parameters -> the stage it steps, or that stage's mesh model alone.

One translation of the FMU's parameter values into the library's objects, used by both GearContact FMUs:
the pythonfmu slave (``slaves/GearContact.py``) builds its stage with :func:`build_stage` at the exit of
initialization; the Python-free build (``drivetrain.fmu_build.native_gear``) takes the contact map of
:func:`build_mesh_model`, so the native FMU carries the very map the slave would step with (the same map
cache, fault parsing and manufacturing errors).

``parameters``: a mapping from the FMU's parameter names (``fmu_variables.VARIABLES``) to their values
as the FMU holds them (String, Integer, Real, Boolean). Every parameter the builders read must be present:
a slave has them all; a caller with a subset starts from the declared defaults
(``fmu_variables.parameter_values``). Bad values raise
(ValueError, ...) with the reason; the slave turns that into its error state, the native build into a
refusal.
"""
from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from gearcontact_fmu.fault_specs import health_problems
from gearcontact_fmu.mesh_models.base import MeshModel
from gearcontact_fmu.params import BevelGearParams, MapGrid, MeshResolution, PCMParams
from gearcontact_fmu.stage import GearStage, StageParams, make_stage, stage_mesh_model


def fault_specs(parameters: Mapping[str, Any]) -> list:
    """The ``faults`` parameter (a JSON list of fault specifications), checked with the health against the
    tooth counts by the scene's own check (``fault_specs.health_problems``): every problem named at once
    (ValueError); ``health = "faults"`` needs at least one, the other states none. The FMU is used
    standalone too, so it guards its parameters itself."""
    try:
        specs = json.loads(str(parameters["faults"]) or "[]")
    except ValueError as exc:
        raise ValueError(f"parameter faults is not JSON ({exc})") from None
    if not isinstance(specs, list):
        raise ValueError("parameter faults must be a JSON list of fault specifications")
    problems = health_problems(str(parameters["health"]).strip(), specs, int(parameters["z_pinion"]),
                               int(parameters["z_wheel"]), faults_name="fault in the faults parameter")
    if problems:
        raise ValueError("; ".join(f"{k}{'' if v is None else f' = {v!r}'}: expected {e}" for k, v, e in problems))
    return specs


def stage_arguments(parameters: Mapping[str, Any]) -> tuple[tuple, dict]:
    """The positional and keyword arguments of :func:`gearcontact_fmu.stage.make_stage` (and of
    ``stage_mesh_model``) for these parameter values: (fidelity, gear, PCM, resolution) and health, mesh
    files, stage parameters and the fidelity's own keywords."""
    bad = [f"{k} = {v!r}" for k, v in parameters.items()
           if isinstance(v, float) and not math.isfinite(v)]
    if bad:                         # NaN fails every comparison: it would pass a check or choose a branch silently
        raise ValueError(f"parameters that are not finite numbers: {', '.join(bad)}")
    p = parameters
    gear = BevelGearParams(
        z_pinion=int(p["z_pinion"]), z_wheel=int(p["z_wheel"]), module=p["module"],
        pressure_angle=p["pressure_angle"], shaft_angle=p["shaft_angle"], face_width=p["face_width"],
        x_pinion=p["x_pinion"], addendum_coefficient=p["addendum_coefficient"],
        dedendum_coefficient=p["dedendum_coefficient"], backlash=p["backlash"], tip_radius=p["tip_radius"])
    pcm = PCMParams(E=p["E"], nu=p["nu"], layer_depth=p["layer_depth"], c_compression=p["c_compression"],
                    c_expansion=p["c_expansion"], transformation_depth=p["transformation_depth"], mu=p["mu"],
                    v_friction=p["v_friction"], u_max=p["u_max"])
    res = MeshResolution(profile=p["profile_element_size"], face=p["face_element_size"])
    sp = StageParams(J_pinion=p["J_pinion"], J_wheel=p["J_wheel"], k_a=p["k_a"], d_a=p["d_a"], k_b=p["k_b"],
                     d_b=p["d_b"], max_substep=p["max_substep"], scheme=p["scheme"], mode=p["mode"],
                     output_torque=p["output_torque"], energy_correction=bool(p["energy_correction"]))
    mesh_files = {k: v for k, v in (("pinion", p["pinion_mesh_file"]), ("wheel", p["wheel_mesh_file"])) if v}
    kw: dict[str, Any] = {}
    fidelity = p["fidelity"].strip().lower()
    friction, damping = bool(p["friction"]), bool(p["contact_damping"])
    if fidelity == "analytic":
        # the analytic reference takes its friction from mu (the PCM constant) as well
        kw = dict(damping_ratio=p["mesh_damping_ratio"] if damping else 0.0, mesh_phase=p["mesh_phase"],
                  mu=p["mu"] if friction else 0.0)
    elif fidelity in ("pcm", "table"):
        kw = dict(friction=friction, damping=damping, mesh_units=str(p["mesh_units"]).strip(),
                  faults=fault_specs(p))
        if fidelity == "table":
            kw["grid"] = MapGrid(points_per_pitch=int(p["map_points_per_pitch"]),
                                 s_points=int(p["map_approach_points"]))
    if float(p["tooth_compliance"]) != 1.0:          # table only: pcm and ideal refuse it
        kw["tooth_compliance"] = float(p["tooth_compliance"])
    if str(p["manufacturing_errors"]).strip():      # the ideal mesh refuses them (no mesh coordinate)
        kw["manufacturing_errors"] = str(p["manufacturing_errors"])
    return (p["fidelity"], gear, pcm, res), dict(health=p["health"], mesh_files=mesh_files or None,
                                                 stage_params=sp, **kw)


def build_stage(parameters: Mapping[str, Any]) -> GearStage:
    """The gear stage a GearContact FMU with these parameter values steps (what the pythonfmu slave builds
    at the exit of initialization)."""
    args, kw = stage_arguments(parameters)
    return make_stage(*args, **kw)


def build_mesh_model(parameters: Mapping[str, Any]) -> MeshModel:
    """The mesh model of :func:`build_stage`'s stage, without the stage (nothing of the stage's kernels is
    compiled): the contact map the native GearContact is built from."""
    args, kw = stage_arguments(parameters)
    return stage_mesh_model(*args, **kw)
