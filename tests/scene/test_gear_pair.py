"""[gear.pair]: the lower bevel pair from its gear data in a scene (issue 42). Its keys are checked like every
scene key (all problems at once), absent keys are the rig's pair exactly, an impossible pair is refused through
gearcontact_fmu.pair_check before any work, and the faults' tooth numbers are the pair's."""
from __future__ import annotations

import math

import pytest

from drivetrain.errors import ScenarioError
from drivetrain.scene import load as scene_load
from drivetrain.scene.load import load_scene, resolve, with_overrides
from drivetrain.scene.schema import PAIR_SCHEMA, RIG_PAIR
from gearcontact_fmu.params import BevelGearParams, PCMParams

from _shared import EXAMPLE, ROOT

#: the rig's pair as its drawings give it (RIG.md), written out by hand: the oracle of the defaults
RIG_WRITTEN = {"z_pinion": 15, "z_wheel": 60, "module_mm": 3.0, "face_width_mm": 25.0, "pressure_angle_deg": 20.0,
               "shaft_angle_deg": 90.0, "x_pinion": 0.43, "addendum_coefficient": 1.0, "dedendum_coefficient": 1.25,
               "backlash_mm": 0.075, "tip_radius_mm": 0.2, "E_GPa": 206.0, "nu": 0.3, "layer_depth_mm": 0.5}


def test_absent_keys_are_the_rig_pair_exactly():
    assert set(PAIR_SCHEMA) == set(RIG_WRITTEN)
    assert RIG_PAIR.as_dict() == RIG_WRITTEN
    assert RIG_PAIR.params() == BevelGearParams() and RIG_PAIR.pcm() == PCMParams() and RIG_PAIR.is_rig
    s = resolve({"gear": {"pair": dict(RIG_WRITTEN)}})
    assert s.gear.pair.params() == BevelGearParams() and s.gear.pair.is_rig
    assert resolve({}).gear.pair == RIG_PAIR
    # the rig's pair is not written out: the rig's scenes, their summaries and fingerprints stay as they were
    assert "pair" not in s.to_dict()["gear"]


def test_a_pair_in_SI_and_back():
    s = resolve({"gear": {"pair": {"z_pinion": 20, "z_wheel": 40, "module_mm": "4 mm", "face_width_mm": 22,
                                   "pressure_angle_deg": 25.0, "E_GPa": 210, "layer_depth_mm": "400 um"}}})
    p, pcm = s.gear.pair.params(), s.gear.pair.pcm()
    assert (p.z_pinion, p.z_wheel, p.ratio) == (20, 40, 2.0)
    assert p.module == 4e-3 and p.face_width == 22e-3 and p.pressure_angle == math.radians(25.0)
    assert p.x_pinion == BevelGearParams().x_pinion            # absent: the rig's
    assert pcm.E == 210e9 and pcm.layer_depth == pytest.approx(0.4e-3, rel=1e-15) and pcm.mu == PCMParams().mu
    d = s.to_dict()
    assert d["gear"]["pair"]["z_wheel"] == 40 and d["gear"]["pair"]["module_mm"] == 4.0
    again = resolve(d)
    assert again.gear.pair == s.gear.pair and again.to_dict() == d
    import tomllib

    assert tomllib.loads(s.to_toml()) == d


def test_bad_keys_are_refused_together():
    with pytest.raises(ScenarioError) as e:
        resolve({"gear": {"pair": {"zz": 20, "module": 3, "z_wheel": 2.5, "nu": float("nan"),
                                   "face_width_mm": -1.0, "pressure_angle_deg": "20 deg", "backlash_mm": True}},
                 "time": {"duration_s": -1}})
    text = str(e.value)
    for key in ("gear.pair.zz", "gear.pair.module ", "the key is 'module_mm'", "gear.pair.z_wheel",
                "gear.pair.nu", "gear.pair.face_width_mm", "gear.pair.pressure_angle_deg", "gear.pair.backlash_mm",
                "time.duration_s"):
        assert key in text, key
    assert len(e.value.problems) == 8
    with pytest.raises(ScenarioError, match="a table"):
        resolve({"gear": {"pair": 3}})
    with pytest.raises(ScenarioError, match="Poisson's ratio < 0.5"):
        resolve({"gear": {"pair": {"nu": 0.5}}})


def test_an_impossible_pair_is_refused_by_the_pair_check(monkeypatch):
    """The scene asks gearcontact_fmu.pair_check.pair_problems and refuses with each of its reasons."""
    seen = []

    def fake(params):
        seen.append(params)
        return ["face width 40 mm over a third of the cone distance (29.8 mm)"] if params.face_width > 0.03 else []

    monkeypatch.setattr(scene_load, "pair_problems", fake)
    with pytest.raises(ScenarioError) as e:
        resolve({"gear": {"pair": {"z_pinion": 20, "z_wheel": 40, "module_mm": 4.0, "face_width_mm": 40.0}}})
    assert "gear.pair" in str(e.value) and "a third of the cone distance (29.8 mm)" in str(e.value)
    assert seen[-1].z_pinion == 20 and seen[-1].face_width == 0.04
    resolve({"gear": {"pair": {"z_pinion": 20, "z_wheel": 40, "module_mm": 4.0, "face_width_mm": 22.0}}})


def test_set_reaches_the_pair_table():
    s = load_scene(EXAMPLE, ["gear.pair.z_pinion=20", "gear.pair.z_wheel=40", 'gear.pair.module_mm="4 mm"'])
    assert (s.gear.pair.params().z_pinion, s.gear.pair.params().module) == (20, 4e-3)
    s2 = with_overrides(s, ["gear.pair.x_pinion=0.1"])
    assert s2.gear.pair.params().x_pinion == 0.1 and s2.gear.pair.params().z_wheel == 40
    with pytest.raises(ScenarioError, match="gear.pair.z_pinion"):
        load_scene(EXAMPLE, ["gear.pair.z_pinion=0"])
    with pytest.raises(ScenarioError, match="section.key"):
        load_scene(EXAMPLE, ["gear.other.z_pinion=20"])


def test_faults_sit_on_the_pairs_teeth():
    fault = {"kind": "missing_tooth", "member": "pinion", "tooth": 17}
    with pytest.raises(ScenarioError, match="gear.faults"):            # the rig's pinion has 15 teeth
        resolve({"gear": {"health": "faults", "faults": [fault]}})
    s = resolve({"gear": {"health": "faults", "faults": [fault], "pair": {"z_pinion": 20, "z_wheel": 40,
                                                                          "module_mm": 4.0}}})
    assert s.gear.faults[0]["tooth"] == 17
    with pytest.raises(ScenarioError, match="gear.faults"):
        resolve({"gear": {"health": "faults", "faults": [{"kind": "missing_tooth", "member": "wheel", "tooth": 45}],
                          "pair": {"z_pinion": 20, "z_wheel": 40, "module_mm": 4.0}}})


def test_a_grid_draws_faults_on_the_pairs_teeth(tmp_path):
    f = tmp_path / "g.toml"
    f.write_text('[gear.pair]\nz_pinion = 31\nz_wheel = 62\nmodule_mm = 2.0\nface_width_mm = 20.0\n[time]\nduration_s = 1.0\n'
                 '[sweep.draw]\nn = 40\nseed = 3\n'
                 '[[sweep.draw.faults]]\nkind = "missing_tooth"\nmember = "pinion"\ntooth = "any"\n')
    scenes = scene_load.load_scenes(f)
    teeth = {s.gear.faults[0]["tooth"] for s in scenes}
    assert max(teeth) >= 15 and max(teeth) < 31          # drawn over the pair's 31 teeth, not the rig's 15


def test_docs_list_every_pair_key():
    doc = (ROOT / "docs" / "SCENARIOS.md").read_text()
    assert "### [gear.pair]" in doc
    for key in PAIR_SCHEMA:
        assert f"| `{key}` |" in doc, key


def test_a_grid_sweeps_pair_keys(tmp_path):
    f = tmp_path / "g.toml"
    f.write_text('[gear.pair]\nmodule_mm = 4.0\n[time]\nduration_s = 1.0\n'
                 '[sweep]\nname = "{base}_z{gear.pair.z_pinion}"\n'
                 '[sweep.axes]\n"gear.pair.z_pinion" = [20, 25]\n"gear.pair.z_wheel" = [40]\n')
    scenes = scene_load.load_scenes(f)
    assert [(s.name, s.gear.pair.params().z_pinion, s.gear.pair.params().module) for s in scenes] == [
        ("g_z20", 20, 4e-3), ("g_z25", 25, 4e-3)]
    with pytest.raises(ScenarioError, match="sweep.axes.gear.pair.zz"):
        f.write_text('[sweep.axes]\n"gear.pair.zz" = [20]\n')
        scene_load.load_scenes(f)


def test_the_readmes_own_gearbox_scenes_load_with_their_pair_and_table():
    """README "Your own gearbox": the scene and its dataset grid carry the 20/40 pair and the thruster table; a
    pair the table's bevel element contradicts is refused before any work."""
    d = ROOT / "scenarios" / "other_gearboxes"
    sc = load_scene(d / "own_gearbox.toml")
    p = sc.gear.pair.params()
    assert (p.z_pinion, p.z_wheel, p.module) == (20, 40, 4e-3)
    assert str(sc.drivetrain.parameters).endswith("own_gearbox.csv")
    cases = scene_load.load_scenes(d / "own_gearbox_dataset.toml")
    assert len(cases) == 8 and all(c.gear.faults and c.gear.pair.params().z_wheel == 40 for c in cases)
    assert {c.gear.faults[0]["member"] for c in cases} <= {"pinion", "wheel"}
    with pytest.raises(ScenarioError, match="drivetrain.parameters"):
        load_scene(d / "own_gearbox.toml", ["gear.pair.z_wheel=60", "gear.pair.z_pinion=15",
                                             "gear.pair.module_mm=3.0", "gear.pair.face_width_mm=20.0"])
