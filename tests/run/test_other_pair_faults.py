"""Every fault family on either gear of the other pairs (issue 42): each family of
``gearcontact_fmu.fault_specs.FAULT_KINDS`` at its default size, on the pinion and on the wheel of the 20/40 pair
of module 4 mm and of the 25/25 miter pair (their scenes in scenarios/other_gearboxes), runs (its own contact
map, built incrementally on the pair's healthy one) and sits where the load runs: the share of its footprint
inside the loaded contact region (found on the PCM pair's own teeth) and the largest relative drop of the mesh
torque between the healthy and the fault's contact maps (``fault_contact``) are both positive. The figures are docs/GEAR-CONTACT.md's table
"Every fault family on the other pairs" (``python -m pytest -s -m slow tests/run/test_other_pair_faults.py``)."""
from __future__ import annotations

import math

import pytest

from drivetrain.run.runner import run_scene
from drivetrain.scene.load import load_scene
from gearcontact_fmu.fault_specs import FAULT_KINDS, MEMBERS

from _shared import ROOT

OTHER = ROOT / "scenarios" / "other_gearboxes"
SCENES = {"20x40_m4": "pair_20_40_m4.toml", "miter25_m3": "miter_25_25.toml"}
SHORT = ["time.duration_s=0.2", "time.settle_s=0.05", "outputs.plots=false", "outputs.aalto_csv=false"]


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(FAULT_KINDS))
@pytest.mark.parametrize("member", MEMBERS)
@pytest.mark.parametrize("pair", list(SCENES))
def test_every_fault_family_on_either_gear_of_a_new_pair(pair, member, kind):
    tooth = 3
    scene = load_scene(OTHER / SCENES[pair], [*SHORT, "gear.health=faults",
                                              f'gear.faults=[{{kind="{kind}", member="{member}", tooth={tooth}}}]'])
    result = run_scene(scene, progress=False)
    s = result.summary
    assert result.status == "ok", s.get("failure")
    (label,) = s["fault_contact"]
    share, drop = label["contact_share"], label["mesh_torque_drop"]
    print(f"\n {pair} {member} {kind}: contact share {share:.3f}, mesh torque drop {drop:.3f}, "
          f"energy residual {s.get('energy_residual'):.1e}, wall {s['wall_time_s']:.1f} s")
    assert share is not None and share > 0.0
    assert drop is not None and drop > 0.0
    assert math.isfinite(s["energy_residual"]) and abs(s["energy_residual"]) < 1e-3
