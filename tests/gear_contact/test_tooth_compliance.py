"""Tooth compliance in series with the PCM layers (table fidelity): the series-spring law, ISO 6336 at
the paper's loads, the elastic energy as the work of the torque, and the scene and FMU plumbing."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from gearcontact_fmu.mesh_models.analytic import iso6336_low_load_factor, iso6336_stiffness
from gearcontact_fmu.mesh_models import make_mesh_model
from gearcontact_fmu.mesh_statics import static_mesh_stiffness
from gearcontact_fmu.mesh_models.base import N_OUT, OUT_ELASTIC_ENERGY, OUT_TAU_PINION
from gearcontact_fmu.params import TOOTH_COMPLIANCE_FACTOR, BevelGearParams

G = BevelGearParams()
R = G.z_wheel / G.z_pinion


@pytest.fixture(scope="module")
def models():
    return make_mesh_model("table", G), make_mesh_model("table", G, tooth_compliance=TOOTH_COMPLIANCE_FACTOR)


@pytest.mark.parametrize("torque", [1.0, 3.7, 20.0])
def test_series_spring_law(models, torque):
    """A series compliance (f - 1) times the layers' own: 1/k = 1/k_layers + (f - 1)/k_layers, so at the
    same load the mesh is f times softer at every angle (the single/double alternation kept)."""
    stiff, soft = models
    a, b = static_mesh_stiffness(stiff, G, torque, n=8), static_mesh_stiffness(soft, G, torque, n=8)
    assert b["k"] == pytest.approx(a["k"] / TOOTH_COMPLIANCE_FACTOR, rel=0.03)
    assert b["double_single"] == pytest.approx(a["double_single"], rel=0.05)


def test_iso6336_at_the_papers_loads(models):
    """With the default factor the loaded mesh stiffness is ISO 6336's c_gamma (method B with its low-load
    factor) within 10 % from the lightest to the heaviest pinion torque of the paper's grid."""
    _, soft = models
    c_gamma = iso6336_stiffness(G)["c_gamma"]
    for T in (0.86, 1.3, 2.4, 3.71):
        k = static_mesh_stiffness(soft, G, T)
        assert k["mean"] == pytest.approx(c_gamma * iso6336_low_load_factor(G, T), rel=0.10), T
        assert k["double_single"] > 1.2


def test_elastic_energy_is_the_work_of_the_torque(models):
    """The stored energy the model reports equals the integral of its torque over the mesh coordinate
    from the onset (what the stage's energy audit relies on), with the compliance as without."""
    out = np.zeros(N_OUT)
    for model in models:
        th = 0.37

        def tau(s):
            model.eval(model.data, th, (th - s) / R, 0.0, 0.0, out)
            return -out[OUT_TAU_PINION]

        s_load = 0.0
        while tau(s_load) < 5.0:
            s_load += 2e-6
        s0 = s_load
        while tau(s0) > 0.0:
            s0 -= 1e-7
        work, _ = quad(tau, s0, s_load, limit=400)
        model.eval(model.data, th, (th - s_load) / R, 0.0, 0.0, out)
        assert out[OUT_ELASTIC_ENERGY] == pytest.approx(work, rel=0.02)


def test_scene_and_fmu_plumbing():
    from _shared import EXAMPLE

    from drivetrain.run.assemble import assemble
    from drivetrain.errors import ScenarioError
    from drivetrain.scene.load import load_scene

    on = ["effects.tooth_compliance=true"]
    gear = [c for c in assemble(load_scene(EXAMPLE, overrides=on), check=False).components
            if c.model == "GearContact"][0]
    assert gear.parameters["tooth_compliance"] == TOOTH_COMPLIANCE_FACTOR
    gear = [c for c in assemble(load_scene(EXAMPLE, overrides=on + ["tooth_compliance.factor=2"]), check=False)
            .components if c.model == "GearContact"][0]
    assert gear.parameters["tooth_compliance"] == 2.0
    assert "tooth_compliance" not in [c for c in assemble(load_scene(EXAMPLE), check=False).components
                                      if c.model == "GearContact"][0].parameters
    for fid in ("pcm", "ideal"):
        with pytest.raises(ScenarioError, match="tooth_compliance"):
            load_scene(EXAMPLE, overrides=on + [f"effects.mesh_contact={fid}"])
    with pytest.raises(ValueError, match="table"):
        make_mesh_model("pcm", G, tooth_compliance=2.0)
    for bad in (0.0, 0.5, float("nan")):          # never silently the layers alone, in any fidelity
        for fid in ("table", "analytic"):
            with pytest.raises(ValueError, match=">= 1"):
                make_mesh_model(fid, G, tooth_compliance=bad)
    with pytest.raises(ScenarioError, match="factor"):
        load_scene(EXAMPLE, overrides=on + ["tooth_compliance.factor=0.5"])
