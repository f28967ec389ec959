"""The scene alone chooses what is simulated: every gear fidelity with flexible and rigid shafts runs,
and what a scene switches off is not loaded or evaluated."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from drivetrain.run.assemble import assemble
from drivetrain.run.runner import run_scene
from drivetrain.scene.load import load_scene

from _shared import EXAMPLE, SHORT


@pytest.mark.parametrize("shafts", ["flexible", "rigid"])
@pytest.mark.parametrize("fidelity", ["pcm", "table", "analytic", "ideal"])
def test_every_combination_runs_as_the_scene_says(fidelity, shafts, fmu_dir):
    scene = load_scene(EXAMPLE, overrides=SHORT + [f"effects.mesh_contact={fidelity}",
                                                   f"effects.shaft_flexibility={shafts}"])
    spec = assemble(scene)
    models = {c.name: c.model for c in spec.components}
    gear = next(c for c in spec.components if c.model == "GearContact")
    assert gear.parameters["fidelity"] == fidelity
    assert ("FlexibleShaft" in models.values()) == (shafts == "flexible")
    res = run_scene(scene, out_dir=None, progress=False, fmu_dir=fmu_dir)
    reported = {f["name"]: f for f in res.summary["fmus"]}
    assert {n: f["model"] for n, f in reported.items()} == models
    assert reported[gear.name]["fidelity"] == fidelity
    for name in ("drive_shaft_torque", "propeller_shaft_torque"):
        x = np.asarray(res.signals[name])
        assert np.all(np.isfinite(x)), name
    # the load is carried: the propeller-shaft torque is positive and of the rig's order (a few to
    # ~20 N·m at 1.31 N·m x 8 through the planetary plus losses; a short run from the assembled
    # steady state)
    psh = np.asarray(res.signals["propeller_shaft_torque"])
    assert 5.0 < float(np.mean(psh)) < 30.0


def test_ideal_gear_rigid_shafts_loads_no_contact_engine_and_no_shaft(tmp_path):
    """Run the scene in a fresh process (the FMUs run inside it) and look at what got imported."""
    code = f"""
import sys, json
from drivetrain.run.runner import run_scene
from drivetrain.scene.load import load_scene
scene = load_scene({str(EXAMPLE)!r}, overrides={SHORT!r} + ["effects.mesh_contact=ideal",
                    "effects.shaft_flexibility=rigid"])
res = run_scene(scene, out_dir=None, progress=False, fmu_dir={str(tmp_path / 'fmus')!r})
mods = [m for m in sys.modules if m.startswith("gearcontact_fmu")]
print(json.dumps({{"mods": mods, "models": [c.model for c in res.spec.components]}}))
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    info = json.loads(p.stdout.strip().splitlines()[-1])
    assert "FlexibleShaft" not in info["models"]
    loaded = set(info["mods"])
    for heavy in ("gearcontact_fmu.contact.kernels", "gearcontact_fmu.contact.engine",
                  "gearcontact_fmu.contact_map", "gearcontact_fmu.mesh_models.pcm", "gearcontact_fmu.geometry"):
        assert heavy not in loaded, f"{heavy} was imported for an ideal gear"


def test_switched_off_effects_reach_the_gear_as_flags():
    """friction / contact damping off: flags to the mesh model (never evaluated, same contact map)."""
    from gearcontact_fmu.contact_map import MapGrid, cache_key

    on = assemble(load_scene(EXAMPLE, overrides=SHORT))
    off = assemble(load_scene(EXAMPLE, overrides=SHORT + ["effects.friction=false",
                                                           "effects.contact_damping=false"]))
    g_on = next(c for c in on.components if c.model == "GearContact").parameters
    g_off = next(c for c in off.components if c.model == "GearContact").parameters
    assert g_on["friction"] is True and g_on["contact_damping"] is True
    assert g_off["friction"] is False and g_off["contact_damping"] is False
    # the PCM constants are untouched, so both scenes share one contact map
    for k in ("mu", "c_compression", "c_expansion"):
        assert g_on.get(k) == g_off.get(k)


def test_mesh_units_reach_the_contact_model(tmp_path):
    """gear.mesh_units was accepted and ignored (the FMU read every file in mm). The same pinion saved in
    m and in mm gives the same contact torques when each is read in its own unit, and the scene's unit
    reaches the GearContact FMU as a parameter."""
    from gearcontact_fmu import geometry
    from gearcontact_fmu.mesh_models.base import N_OUT, OUT_TAU_PINION
    from gearcontact_fmu.mesh_models.pcm import make_pcm_model
    from gearcontact_fmu.meshes import save_mesh
    from gearcontact_fmu.params import BevelGearParams, MeshResolution

    P, res = BevelGearParams(), MeshResolution(profile=0.3e-3, face=3e-3)
    pinion = geometry.build_gear_mesh(P, "pinion", resolution=res)
    save_mesh(pinion, tmp_path / "p_mm.obj", units="mm")
    save_mesh(pinion, tmp_path / "p_m.obj", units="m")
    torques = []
    for f, u in (("p_mm.obj", "mm"), ("p_m.obj", "m")):
        m = make_pcm_model(P, None, res, "mesh", {"pinion": str(tmp_path / f)}, mesh_units=u)
        if not torques:     # a loaded drive flank: 20 µrad beyond the contact onset at this angle
            from gearcontact_fmu.mesh_models.pcm import build_pcm_pair, contact_onset

            s0 = contact_onset(build_pcm_pair(P, None, res, "mesh", str(tmp_path / f), None, u), 0.3, +1) + 2e-5
        out = np.zeros(N_OUT)
        m.eval(m.data, 0.3, (0.3 - s0) / 4.0, 0.0, 0.0, out)
        torques.append(out[OUT_TAU_PINION])
    assert torques[0] != 0.0
    assert torques[1] == pytest.approx(torques[0], rel=1e-6)
    with pytest.raises(Exception, match="(?i)unit|size|scale|mm"):   # the m file read in mm is refused
        make_pcm_model(P, None, res, "mesh", {"pinion": str(tmp_path / "p_m.obj")}, mesh_units="mm")

    scene = load_scene(EXAMPLE, ["gear.health=mesh", f"gear.pinion_mesh={tmp_path / 'p_m.obj'}",
                                 "gear.mesh_units=m", "effects.mesh_contact=pcm"])
    gear = [c for c in assemble(scene, check=False).components if c.model == "GearContact"][0]
    assert gear.parameters["mesh_units"] == "m"


def test_map_grid_and_integrator_reach_the_gear():
    """numerics.map_points_per_pitch / map_approach_points reach the GearContact parameters and the map
    that is built from them (nodes per pitch x teeth along the angle, nodes along the approach);
    numerics.mesh_integrator reaches the stage's scheme; a grid outside 2..4096 is refused by name."""
    from drivetrain.models.stability import contact_inputs
    from gearcontact_fmu.contact_map import get_map
    from gearcontact_fmu.params import MapGrid

    scene = load_scene(EXAMPLE, SHORT + ["numerics.profile_element_mm=0.3", "numerics.face_element_mm=3",
                                         "numerics.map_points_per_pitch=12", "numerics.map_approach_points=16",
                                         "numerics.mesh_integrator=rk4"])
    gear = next(c for c in assemble(scene, check=False).components if c.model == "GearContact")
    assert (gear.parameters["map_points_per_pitch"], gear.parameters["map_approach_points"]) == (12, 16)
    assert gear.parameters["scheme"] == "rk4"
    inp = contact_inputs(gear)
    assert inp["grid"] == MapGrid(points_per_pitch=12, s_points=16)
    cmap = get_map(inp["gear"], inp["pcm"], inp["resolution"], inp["health"], grid=inp["grid"])
    assert cmap.theta.shape == (12 * inp["gear"].z_pinion,) and cmap.a.shape == (16,)
    with pytest.raises(ValueError, match="points_per_pitch"):
        MapGrid(points_per_pitch=1)
