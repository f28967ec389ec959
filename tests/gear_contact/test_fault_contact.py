"""Labels that say how much contact a fault gets (gearcontact_fmu.fault_contact): fault<i>.contact_share and
fault<i>.mesh_torque_drop, in a run's summary and a dataset, and random draws on the flank that carries the
load. Oracles: the transverse contact ratio of ISO 10300's virtual spur gear (how long a tooth is in
contact), the end of the involute (where the path of contact ends on the driving pinion), the online PCM
engine (the map-read drop at one angle), and the flank the torque loads."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gearcontact_fmu import geometry
from gearcontact_fmu.mesh_models.analytic import virtual_spur_gears
from gearcontact_fmu.fault_contact import contact_points, contact_share, loaded_regions, mesh_torque_drop
from gearcontact_fmu.fault_specs import draw_faults, loaded_flank
from gearcontact_fmu.params import BevelGearParams, MeshResolution, PCMParams

ROOT = Path(__file__).resolve().parents[2]
G = BevelGearParams()
#: the example scene's pinion torque (T_MSH at 1500 rpm, 1.31 N.m at the load motor)
T_EXAMPLE = 3.7566
PITCH = 2 * math.pi / G.z_pinion


@pytest.fixture(scope="module")
def regions():
    return loaded_regions(G, PCMParams(), MeshResolution(), T_EXAMPLE)


@pytest.fixture(scope="module")
def points():
    return contact_points(G, PCMParams(), MeshResolution(), T_EXAMPLE, n_angles=64)


def test_a_tooth_is_in_contact_for_the_contact_ratio(points):
    """ISO 10300's virtual spur gear gives the transverse contact ratio epsilon_alpha: tooth 0 of either gear
    carries load over epsilon_alpha pinion pitches (at this light load within 0.1 pitch)."""
    eps = virtual_spur_gears(G)["eps_alpha"]
    step = (1.3 + 1.2) * PITCH / 63
    for member in ("pinion", "wheel"):
        th = np.unique(points[member][:, 2])
        span = (th.max() - th.min() + step) / PITCH
        assert span == pytest.approx(eps, abs=0.1), (member, span, eps)


def test_the_path_of_contact_ends_at_the_driving_pinions_tip(regions):
    """A driving pinion's contact runs from its root side to its tip: the region ends at the end of its
    involute (the tip rounding starts) within one profile element, on every face row."""
    g = geometry.gear_geometry(G, "pinion")
    end = g.L_radial + g.L_inv
    elem = MeshResolution().profile / g.Rm
    r = regions["pinion"]
    assert np.all(np.isfinite(r.s_hi)) and np.all(np.abs(r.s_hi - end) < 1.5 * elem), (r.s_hi, end)
    assert np.all(r.s_lo > g.L_radial)                 # it starts on the involute, above the base cone


@pytest.mark.parametrize("spec,lo,hi", [
    ({"kind": "pit", "flank": "coast"}, 0.0, 0.0),          # the load never runs there
    ({"kind": "void"}, 1.0, 1.0),                           # the paper's void sits on the pitch cone
    ({"kind": "pit", "position_mm": 2.0}, 1.0, 1.0),
    ({"kind": "pit", "position_mm": -2.0}, 0.1, 0.3),       # mostly below the start of active profile
    ({"kind": "missing_tooth"}, 0.7, 0.9),                  # the active part of its loaded flank
    ({"kind": "pit", "member": "wheel", "tooth": 7}, 0.9, 1.0),
])
def test_contact_share_by_where_the_fault_sits(spec, lo, hi, regions):
    assert lo <= contact_share(spec, regions, G) <= hi


def test_a_coast_load_puts_the_region_on_the_coast_flank():
    assert loaded_flank(-2.0) == "coast" and loaded_flank(2.0) == "drive"
    r = loaded_regions(G, PCMParams(), MeshResolution(), -T_EXAMPLE)
    assert r["pinion"].flank == "coast"
    assert contact_share({"kind": "pit", "flank": "coast"}, r, G) > 0.5
    assert contact_share({"kind": "pit", "flank": "drive"}, r, G) == 0.0


@pytest.fixture(scope="module")
def maps():
    from gearcontact_fmu.contact_map import get_map

    healthy = get_map(G, health="healthy")
    pit = get_map(G, health="faults", fault_kwargs={"faults": [{"kind": "pit"}]})
    coast = get_map(G, health="faults", fault_kwargs={"faults": [{"kind": "pit", "flank": "coast"}]})
    missing = get_map(G, health="severe")
    return healthy, pit, coast, missing


def test_mesh_torque_drop_by_fault(maps):
    healthy, pit, coast, missing = maps
    assert mesh_torque_drop(healthy, missing, T_EXAMPLE) == pytest.approx(1.0)   # single contact, no tooth
    assert 0.02 < mesh_torque_drop(healthy, pit, T_EXAMPLE) < 0.9
    assert mesh_torque_drop(healthy, coast, T_EXAMPLE) < 0.01                     # remeshing only


def test_the_map_read_drop_agrees_with_the_online_pcm(maps):
    """At the angle of the pit's largest drop, the online PCM (healthy and faulty pair, the healthy static
    deflection) gives the same drop within 0.05 (absolute): the map's reading is the engine's."""
    from gearcontact_fmu.fault_contact import row_drops
    from gearcontact_fmu.mesh_models.pcm import build_pcm_pair, contact_onset, static_deflection

    healthy, pit, _, _ = maps
    theta, drops = row_drops(healthy, pit, T_EXAMPLE)
    th = float(theta[int(np.nanargmax(drops))])
    assert mesh_torque_drop(healthy, pit, T_EXAMPLE) == np.nanmax(drops)
    hp = build_pcm_pair(G, friction=False, damping=False)
    fp = build_pcm_pair(G, friction=False, damping=False, health="faults", fault_kwargs={"faults": [{"kind": "pit"}]})
    s = static_deflection(hp, th, T_EXAMPLE, s_onset=contact_onset(hp, th, +1))
    online = 1.0 + fp.mesh_torque(th, s) / T_EXAMPLE          # tau_faulty is negative on a driving pinion
    assert online == pytest.approx(np.nanmax(drops), abs=0.05), (online, np.nanmax(drops), th)


def test_random_draws_put_the_fault_on_the_loaded_flank():
    rng = np.random.default_rng(0)
    tpl = [{"kind": ["pit", "spall", "missing_tooth"], "member": ["pinion", "wheel"], "tooth": "any"}]
    drawn = [draw_faults(tpl, rng, 15, 60, flank="coast")[0] for _ in range(40)]
    assert {f.get("flank") for f in drawn if f["kind"] != "missing_tooth"} == {"coast"}
    assert all("flank" not in f for f in drawn if f["kind"] == "missing_tooth")
    asked = [draw_faults([{**tpl[0], "flank": ["drive", "coast"]}], rng, 15, 60, flank="drive")[0] for _ in range(60)]
    assert {f["flank"] for f in asked if f["kind"] != "missing_tooth"} == {"drive", "coast"}   # the grid asks


def test_a_grid_draws_on_the_flank_its_load_loads(tmp_path):
    from drivetrain.scene.load import load_scenes

    grid = tmp_path / "g.toml"
    grid.write_text('[scenario]\nname = "g"\n[gear]\nhealth = "faults"\n[time]\nduration_s = 0.1\n'
                    '[sweep.axes]\n"operating_point.load_torque_Nm" = [1.31, -1.31]\n'
                    '[sweep.draw]\nn = 6\nseed = 1\n[[sweep.draw.faults]]\nkind = ["pit", "wear"]\ntooth = "any"\n')
    scenes = load_scenes(grid)
    for sc in scenes:
        want = "coast" if sc.operating_point.load_torque_Nm < 0 else "drive"
        assert [f["flank"] for f in sc.gear.faults] == [want], sc.name


def test_a_run_summary_and_the_dataset_labels_carry_the_contact(fmu_dir):
    from drivetrain.campaigns.dataset import run_labels
    from drivetrain.run.runner import run_scene
    from drivetrain.scene.expect import RUN_SUMMARY_TREE, summary_mismatch
    from drivetrain.scene.load import load_scene

    scene = load_scene(ROOT / "scenarios" / "example.toml", [
        "time.duration_s=0.01", "outputs.plots=false", 'gear.health="faults"',
        'gear.faults=[{kind="pit", member="pinion", tooth=2}, {kind="pit", flank="coast", tooth=9}]'])
    res = run_scene(scene, None, backend="inprocess", progress=False, fmu_dir=fmu_dir)
    fc = res.summary["fault_contact"]
    assert [f["loaded_flank"] for f in fc] == ["drive", "drive"]
    assert fc[0]["contact_share"] > 0.5 and fc[1]["contact_share"] == 0.0
    assert 0.0 < fc[0]["mesh_torque_drop"] < 1.0
    assert not summary_mismatch(res.summary, RUN_SUMMARY_TREE)
    labels = run_labels(scene.name, {"status": "ok"}, scene.to_dict(), res.summary)
    assert labels["fault0.contact_share"] == fc[0]["contact_share"]
    assert labels["fault1.contact_share"] == 0.0
    assert labels["fault0.mesh_torque_drop"] == fc[0]["mesh_torque_drop"]
    healthy = run_labels("h", {"status": "ok"}, {"gear": {"health": "healthy"}}, {"fault_contact": []})
    assert not any(k.startswith("fault0") for k in healthy)


@pytest.mark.slow
def test_the_shipped_random_dataset_puts_under_5_percent_of_its_faults_out_of_contact():
    """scenarios/datasets/random_faults.toml, all 1,000 drawn faults at their runs' loads (measured when the
    flank draw changed: 0 of 1,000 with a share of 0; before, with flank = ["drive", "coast"], 417 sat on the
    coast flank)."""
    from drivetrain.run.runner import assemble_scene
    from drivetrain.scene.load import load_scenes
    from gearcontact_fmu.fault_specs import health_faults

    regions, torques, zero = {}, {}, 0
    scenes = load_scenes(ROOT / "scenarios" / "datasets" / "random_faults.toml")
    for sc in scenes:
        key = (sc.operating_point.drive_speed_rpm, sc.operating_point.load_torque_Nm)
        if key not in torques:
            torques[key] = assemble_scene(sc).metadata["steady_state"]["T_msh"]
            regions[key] = loaded_regions(G, PCMParams(), MeshResolution(), torques[key])
        zero += contact_share(health_faults(sc.gear.health, sc.gear.faults)[0], regions[key], G) == 0.0
    assert zero < 0.05 * len(scenes), zero
