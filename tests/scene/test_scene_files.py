"""Scene files: validation, overrides, grid expansion, shipped scenes (drivetrain.scene.load)."""
import itertools
from pathlib import Path

import pytest

from drivetrain.scene.load import (SCHEMA, ScenarioError, all_keys, load_scene, load_scenes, parse_override, resolve,
                                 scene_from_dict)

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "scenarios"


def refused(raw, base_dir=".", **kw):
    with pytest.raises(ScenarioError) as ei:
        resolve(raw, base_dir=base_dir, **kw)
    return ei.value


def assert_problem(err, key, value_text, expected_text):
    """One of the problems names the key, shows the value and says what was expected."""
    for k, v, exp in err.problems:
        if k == key and expected_text in exp:
            assert value_text.lower() in str(err).lower(), str(err)
            assert key in str(err)
            return
    raise AssertionError(f"no problem for {key!r} expecting {expected_text!r} in:\n{err}")


# ------------------------------------------------------------------------------------------------ malformed


def test_unknown_key_and_section():
    e = refused({"time": {"duration_s": 1.0, "durration_s": 2.0}, "timing": {"x": 1}})
    assert_problem(e, "time.durration_s", "2.0", "a known key of [time]")
    assert "did you mean 'duration_s'" in str(e)
    assert_problem(e, "timing", "{...}", "a known section")


def test_wrong_unit():
    # a key with another unit suffix
    e = refused({"operating_point": {"drive_speed_Hz": 25.0}})
    assert_problem(e, "operating_point.drive_speed_Hz", "25.0", "wrong unit: the key is 'drive_speed_rpm'")
    # a quantity string of the wrong kind
    e = refused({"operating_point": {"load_torque_Nm": "3 N"}})
    assert_problem(e, "operating_point.load_torque_Nm", "'3 N'", "a torque in N·m")
    e = refused({"time": {"duration_s": "3 rpm"}})
    assert_problem(e, "time.duration_s", "'3 rpm'", "a time in s")
    e = refused({"time": {"duration_s": "3 parsecs"}})
    assert_problem(e, "time.duration_s", "'3 parsecs'", "unknown unit")


def test_quantity_strings_are_converted():
    s = scene_from_dict({"time": {"duration_s": "500 ms", "sample_rate_Hz": "3.012 kHz"},
                         "operating_point": {"drive_speed_rpm": "25 Hz", "load_torque_Nm": "710 mN·m"},
                         "numerics": {"comm_step_s": 1.0 / 12048.0}})
    assert s.time.duration_s == pytest.approx(0.5)
    assert s.time.sample_rate_Hz == pytest.approx(3012.0)
    assert s.operating_point.drive_speed_rpm == pytest.approx(1500.0)
    assert s.operating_point.load_torque_Nm == pytest.approx(0.71)


def test_wrong_types():
    e = refused({"time": {"duration_s": "long"}, "effects": {"shaft_elements": 2.5, "friction": 1},
                 "outputs": {"sensors": "enc1"}, "scenario": {"name": 7}})
    assert_problem(e, "time.duration_s", "'long'", "a number in s")
    assert_problem(e, "effects.shaft_elements", "2.5", "an integer")
    assert_problem(e, "effects.friction", "1", "true or false")
    assert_problem(e, "outputs.sensors", "'enc1'", "a list of strings")
    assert_problem(e, "scenario.name", "7", "a string")
    e = refused({"time": {"duration_s": True}})
    assert_problem(e, "time.duration_s", "true", "not a boolean")


@pytest.mark.parametrize("section,key,value,expected", [
    ("time", "duration_s", -1.0, "> 0 s"),
    ("time", "duration_s", 0.0, "> 0 s"),
    ("time", "sample_rate_Hz", -3000.0, "> 0 Hz"),
    ("operating_point", "drive_speed_rpm", -0.5, ">= 0 rpm"),
    ("operating_point", "drive_speed_rpm", float("nan"), "finite"),
    ("effects", "shaft_elements", 0, ">= 1"),
    ("numerics", "max_substep_s", -1e-6, "> 0 s"),
])
def test_impossible_values(section, key, value, expected):
    e = refused({section: {key: value}})
    assert_problem(e, f"{section}.{key}", str(value)[:3], expected)


def test_cross_key_rules():
    e = refused({"time": {"duration_s": 1.0, "settle_s": 1.5}})
    assert_problem(e, "time.settle_s", "1.5", "shorter than time.duration_s")
    e = refused({"numerics": {"comm_step_s": 1e-4, "max_substep_s": 1e-3}})
    assert_problem(e, "numerics.comm_step_s", "0.0001", "divides the output period")
    assert "8.333333333333333e-05" in str(e)                       # the suggestion
    e = refused({"time": {"sample_rate_Hz": 3012.0}})              # default H = 1/12000 does not divide 1/3012
    assert_problem(e, "numerics.comm_step_s", "8.33", "divides the output period")
    e = refused({"numerics": {"max_substep_s": 1e-3}})
    assert_problem(e, "numerics.max_substep_s", "0.001", "<= numerics.comm_step_s")
    e = refused({"gear": {"health": "severe"}, "effects": {"mesh_contact": "ideal"}})
    assert_problem(e, "effects.mesh_contact", "'ideal'", "tooth geometry")
    e = refused({"gear": {"health": "mild"}, "effects": {"mesh_contact": "analytic"}})   # the FMU would fail
    assert_problem(e, "effects.mesh_contact", "'analytic'", "models the healthy gear only")
    e = refused({"operating_point": {"speed_profile_rpm": [[0.0, 0.0], [1.0, 1500.0], [0.5, 10.0]]}})
    assert_problem(e, "operating_point.speed_profile_rpm", "[[0.0, 0.0]", "strictly increasing")
    e = refused({"operating_point": {"load_profile_Nm": [[1.0, 1.31], [2.0, 0.12]]}})
    assert_problem(e, "operating_point.load_profile_Nm", "[[1.0, 1.31]", "starting at time 0")


def test_negative_load_is_a_reversal_speeds_stay_non_negative():
    s = scene_from_dict({"operating_point": {"load_torque_Nm": -1.31}})
    assert s.operating_point.load_torque_Nm == -1.31
    s = scene_from_dict({"operating_point": {"load_profile_Nm": [[0.0, 1.31], [0.5, 1.31], [0.501, -2.62]]}})
    assert s.operating_point.load_at(1.0) == pytest.approx(-2.62)
    e = refused({"operating_point": {"speed_profile_rpm": [[0.0, 0.0], [1.0, -10.0]]}})
    assert_problem(e, "operating_point.speed_profile_rpm", "-10.0", "values >= 0 rpm")
    e = refused({"operating_point": {"load_profile_Nm": [[0.0, 1.0], [1.0, float("inf")]]}})
    assert_problem(e, "operating_point.load_profile_Nm", "[[0.0, 1.0]", "finite values")


def test_health_and_mesh_files(tmp_path):
    e = refused({"gear": {"health": "broken"}})
    assert_problem(e, "gear.health", "'broken'", "one of 'healthy', 'mild', 'severe', 'faults', 'mesh'")
    e = refused({"gear": {"health": "mesh", "pinion_mesh": "faults/nope.obj"}}, base_dir=tmp_path)
    assert_problem(e, "gear.pinion_mesh", "'faults/nope.obj'", "an existing mesh file")
    e = refused({"gear": {"health": "mesh"}})
    assert_problem(e, "gear.pinion_mesh", "(missing)", 'when gear.health = "mesh"')
    (tmp_path / "faults").mkdir()
    (tmp_path / "faults" / "p.obj").write_text("v 0 0 0\n")
    e = refused({"gear": {"health": "severe", "pinion_mesh": "faults/p.obj"}}, base_dir=tmp_path)
    assert_problem(e, "gear.pinion_mesh", "p.obj", 'unless gear.health = "mesh"')
    e = refused({"gear": {"health": "mesh", "pinion_mesh": "faults/p.txt"}}, base_dir=tmp_path)
    assert_problem(e, "gear.pinion_mesh", "p.txt", ".obj or .stl")
    # accepted: relative to the scene file's directory, stored absolute
    f = tmp_path / "scene.toml"
    f.write_text('[gear]\nhealth = "mesh"\npinion_mesh = "faults/p.obj"\n')
    s = load_scene(f)
    assert s.gear.pinion_mesh == (tmp_path / "faults" / "p.obj").resolve()


def test_fault_lists_are_checked_whole_and_normalised():
    e = refused({"gear": {"health": "faults", "faults": [
        {"kind": "dent", "member": "wheel"},
        {"kind": "void", "member": "wheel", "tooth": 60, "flank": "left", "depth_mm": -0.1, "colour": 3},
        {"kind": "missing_tooth", "member": "axle", "tooth": 2, "flank": "drive"},
        "void"]}})
    assert_problem(e, "gear.faults[0].kind", "'dent'", "one of ('void', 'missing_tooth', 'pit', 'spall', 'chipped_tip', 'crack', 'wear')")
    assert_problem(e, "gear.faults[1].tooth", "60", "tooth index 0..59 of the wheel")
    assert_problem(e, "gear.faults[1].flank", "'left'", "one of ('drive', 'coast')")
    assert_problem(e, "gear.faults[1].depth_mm", "-0.1", "a size > 0 mm")
    assert_problem(e, "gear.faults[1].colour", "3", "a key of a void fault")
    assert_problem(e, "gear.faults[2].member", "'axle'", "one of ('pinion', 'wheel')")
    assert_problem(e, "gear.faults[2].flank", "'drive'", "no flank for a missing tooth")
    assert_problem(e, "gear.faults[3]", "'void'", "a table of fault keys")
    e = refused({"gear": {"health": "faults", "faults": [{"kind": "pit", "face_position": 1.5, "radius_mm": 0}]}})
    assert_problem(e, "gear.faults[0].face_position", "1.5", "0 (toe) .. 1 (heel)")
    assert_problem(e, "gear.faults[0].radius_mm", "0", "a size > 0 mm")
    e = refused({"gear": {"health": "faults"}})
    assert_problem(e, "gear.faults", "(missing)", 'at least one [[gear.faults]]')
    e = refused({"gear": {"health": "mild", "faults": [{"kind": "missing_tooth"}]}})
    assert_problem(e, "gear.faults", "1 fault(s)", 'unless gear.health = "faults"')
    e = refused({"gear": {"health": "faults", "faults": [{"kind": "missing_tooth"}]},
                 "effects": {"mesh_contact": "analytic"}})
    assert_problem(e, "effects.mesh_contact", "'analytic'", "pcm or table")
    s = resolve({"gear": {"health": "faults", "faults": [{"kind": "void", "member": "wheel", "tooth": 38},
                                                         {"kind": "missing_tooth", "tooth": 7}]}})
    assert s.gear.faults == (
        {"kind": "void", "member": "wheel", "tooth": 38, "flank": "drive", "width_mm": 1.0, "depth_mm": 0.3,
         "position_mm": 0.0},
        {"kind": "missing_tooth", "member": "pinion", "tooth": 7})
    import tomllib

    assert tomllib.loads(s.to_toml()) == s.to_dict()
    assert resolve(s.to_dict()).gear.faults == s.gear.faults


def test_all_problems_reported_together_from_file(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text('[time]\nduration_s = -2\n[gear]\nhealth = "rusty"\n[effects]\nfriction = "yes"\n')
    with pytest.raises(ScenarioError) as ei:
        load_scene(f)
    assert len(ei.value.problems) == 3
    assert str(f) in str(ei.value)
    f.write_text("[time\nduration_s = 1")
    with pytest.raises(ScenarioError, match="valid TOML"):
        load_scene(f)


# ------------------------------------------------------------------------------------------------ overrides


def test_set_overrides_are_typed():
    s = load_scene(SCENARIOS / "example.toml", [
        "time.duration_s=0.5", "effects.shaft_elements=6", "effects.friction=false", "gear.health=severe",
        'outputs.sensors=["drive_shaft_torque", "enc5"]', "operating_point.drive_speed_rpm=500",
        'scenario.description="a b c"'])
    assert s.time.duration_s == 0.5 and isinstance(s.time.duration_s, float)
    assert s.effects.shaft_elements == 6 and isinstance(s.effects.shaft_elements, int)
    assert s.effects.friction is False
    assert s.gear.health == "severe"
    assert s.outputs.sensors == ("drive_shaft_torque", "enc5")
    assert s.operating_point.drive_speed_rpm == 500.0 and isinstance(s.operating_point.drive_speed_rpm, float)
    assert s.scenario.description == "a b c"
    assert s.time.settle_s == pytest.approx(0.1)        # default: min(2 s, 20 % of duration)
    assert s.overrides[0] == "time.duration_s=0.5"
    assert load_scene(SCENARIOS / "example.toml", ["time.duration_s=500ms"]).time.duration_s == pytest.approx(0.5)
    assert parse_override("a.b = [1, 2]") == (["a", "b"], [1, 2])


def test_bad_overrides_refused():
    with pytest.raises(ScenarioError) as ei:
        load_scene(SCENARIOS / "example.toml", ["time.duration_s=-3"])
    assert_problem(ei.value, "time.duration_s", "-3", "> 0 s")
    with pytest.raises(ScenarioError, match="unknown: enc9"):
        load_scene(SCENARIOS / "example.toml", ['outputs.sensors=["enc9"]'])
    with pytest.raises(ScenarioError, match="section.key=value"):
        load_scene(SCENARIOS / "example.toml", ["duration"])
    with pytest.raises(ScenarioError, match="section.key"):
        load_scene(SCENARIOS / "example.toml", ["duration_s=3"])
    with pytest.raises(ScenarioError, match="a known key of \\[time\\]"):
        load_scene(SCENARIOS / "example.toml", ["time.duraton_s=3"])


# ------------------------------------------------------------------------------------------------ grids, shipped


def test_paper_grid_expands_to_54():
    scenes = load_scenes(SCENARIOS / "paper" / "paper.toml")
    assert len(scenes) == 54
    combos = {(s.operating_point.drive_speed_rpm, s.operating_point.load_torque_Nm, s.gear.health) for s in scenes}
    expected = set(itertools.product([250.0, 500.0, 750.0, 1000.0, 1250.0, 1500.0], [0.12, 0.71, 1.31],
                                     ["healthy", "mild", "severe"]))
    assert combos == expected
    assert len({s.name for s in scenes}) == 54
    for s in scenes:
        assert s.time.duration_s == 20.0 and s.time.sample_rate_Hz == 3000.0 and s.time.settle_s == 2.0
        assert s.effects.mesh_contact == "table"
        assert s.name == (f"paper_{s.gear.health}_{s.operating_point.drive_speed_rpm:g}rpm_"
                          f"{s.operating_point.load_torque_Nm:g}Nm")
    one = load_scene(SCENARIOS / "paper" / "paper.toml", case="paper_severe_1500rpm_1.31Nm")
    assert (one.gear.health, one.operating_point.drive_speed_rpm) == ("severe", 1500.0)
    with pytest.raises(ScenarioError, match="expands to 54"):
        load_scene(SCENARIOS / "paper" / "paper.toml")
    with pytest.raises(ScenarioError, match="sweep axis"):
        load_scenes(SCENARIOS / "paper" / "paper.toml", ["gear.health=healthy"])
    short = load_scenes(SCENARIOS / "paper" / "paper.toml", ["time.duration_s=1", "time.settle_s=0.5"])
    assert {s.time.duration_s for s in short} == {1.0}


def test_all_shipped_scenes_validate():
    files = sorted(SCENARIOS.rglob("*.toml"))
    assert len(files) >= 6
    names = set()
    for f in files:
        for s in load_scenes(f):
            assert s.name not in names
            names.add(s.name)
    hard = {s.name: s for f in (SCENARIOS / "hard").glob("*.toml") for s in load_scenes(f)}
    assert hard["hard_missing_tooth_1500rpm"].gear.health == "severe"
    assert hard["hard_low_load_rattle"].operating_point.load_torque_Nm == 0.12
    assert hard["hard_startup_ramp"].operating_point.speed_profile_rpm[0] == (0.0, 0.0)
    assert hard["hard_load_step"].operating_point.load_at(3.0) == pytest.approx(0.12)
    assert hard["hard_load_step"].operating_point.load_at(1.0) == pytest.approx(1.31)


def test_round_trip_and_docs_cover_every_key():
    s = load_scene(SCENARIOS / "example.toml")
    again = resolve(s.to_dict(), base_dir=SCENARIOS)
    assert again.to_dict() == s.to_dict()
    import tomllib

    assert tomllib.loads(s.to_toml()) == s.to_dict()
    doc = (ROOT / "docs" / "SCENARIOS.md").read_text()
    for section, keys in SCHEMA.items():
        assert f"[{section}]" in doc
        for key in keys:
            assert f"`{key}`" in doc, f"{section}.{key} undocumented"
    assert len(all_keys()) == sum(len(k) for k in SCHEMA.values())


@pytest.mark.parametrize("name", ["..", ".", ".hidden", "-rf", "a/b", "a\\b", "x" * 201, ""])
def test_scene_names_that_would_escape_or_hide_are_refused(name):
    with pytest.raises(ScenarioError) as e:
        resolve({"scenario": {"name": name}})
    assert "scenario.name" in str(e.value)


@pytest.mark.parametrize("template, why", [
    ("{gear.__class__.__init__.__globals__}", "scene keys"),       # attribute walking
    ("{base:>300000000}", "short format spec"),                    # a 300 MB name
    ("{gear.health!r}", "conversions"),
    ("{operating_point}", "scene keys"),
    ("..", "valid scene names"),
])
def test_grid_name_templates_evaluate_only_scene_keys(tmp_path, template, why):
    grid = tmp_path / "g.toml"
    grid.write_text(f'[sweep]\nname = "{template}"\n[sweep.axes]\n"gear.health" = ["healthy", "mild"]\n',
                    encoding="utf-8")
    with pytest.raises(ScenarioError) as e:
        load_scenes(grid)
    assert why in str(e.value)


def test_grid_name_template_with_format_specs(tmp_path):
    grid = tmp_path / "g.toml"
    grid.write_text('[sweep]\nname = "{base}_{gear.health}_{operating_point.drive_speed_rpm:g}rpm"\n'
                    '[sweep.axes]\n"operating_point.drive_speed_rpm" = [250.0, 1500.0]\n', encoding="utf-8")
    assert [s.scenario.name for s in load_scenes(grid)] == ["g_healthy_250rpm", "g_healthy_1500rpm"]


def test_a_sample_rate_that_would_stretch_the_run_is_refused():
    """sample_rate_Hz = 0.001 made a 1 s scene run for 1000 s (whole output samples) without a word."""
    with pytest.raises(ScenarioError) as e:
        resolve({"time": {"duration_s": 1.0, "sample_rate_Hz": 0.001}, "numerics": {"comm_step_s": 1.0}})
    assert "time.sample_rate_Hz" in str(e.value) and "16 output samples" in str(e.value)


def test_grid_follows_a_fault_through_its_life(tmp_path):
    """[sweep.growth]: per axes combination a healthy stage 0 and one case per stage, the same gearbox, each
    stage's keys added to the last (a change of kind keeps only the placement), stage and remaining life as
    scene keys; the shipped example expands; bad tables are reported together, never half-expanded."""
    text = """
[scenario]
name = "life"
[manufacturing]
seed = 3
[sweep.axes]
"operating_point.drive_speed_rpm" = [500.0, 1500.0]
[sweep.growth]
healthy = true
fault = { kind = "pit", member = "wheel", tooth = 38 }
stages = [{ radius_mm = 0.5, depth_mm = 0.05 }, { radius_mm = 1.0 }, { kind = "spall", length_mm = 3.0 }]
LIFE
"""
    f = tmp_path / "grid.toml"
    f.write_text(text.replace("LIFE", "life = [0.5, 0.7, 0.9]"))
    a = load_scenes(f)
    assert [s.name for s in a] == [f"life_{v}_stage{k:02d}" for v in ("500.0", "1500.0") for k in range(4)]
    assert [s.scenario.growth_stage for s in a[:4]] == [0, 1, 2, 3]
    assert [s.scenario.remaining_life for s in a[:4]] == pytest.approx([1.0, 0.5, 0.3, 0.1])
    assert a[0].gear.health == "healthy" and all(s.manufacturing.seed == 3 for s in a)
    pit1, pit2, spall = (s.gear.faults[0] for s in a[1:4])
    assert (pit1["radius_mm"], pit1["depth_mm"], pit2["radius_mm"], pit2["depth_mm"]) == (0.5, 0.05, 1.0, 0.05)
    assert spall["kind"] == "spall" and spall["length_mm"] == 3.0 and "radius_mm" not in spall
    assert (spall["member"], spall["tooth"]) == ("wheel", 38)
    f.write_text(text.replace("LIFE", ""))                           # life spread evenly: stage i of n at (i+1)/(n+1)
    assert [s.scenario.remaining_life for s in load_scenes(f)[1:4]] == pytest.approx([0.75, 0.5, 0.25])
    shipped = load_scenes(SCENARIOS / "datasets" / "pit_growth.toml")
    assert len(shipped) == 14 and shipped[-1].gear.faults[0]["kind"] == "spall"
    f.write_text(text.replace("LIFE", "life = [0.9, 0.7]\n[sweep.draw]\nn = 2\nseed = 1\n"
                              "[[sweep.draw.faults]]\nkind = \"pit\"").replace("radius_mm = 1.0", "radius_mm = -1.0"))
    with pytest.raises(ScenarioError) as ei:
        load_scenes(f)
    msg = str(ei.value)
    assert "sweep.growth.life" in msg and "either [sweep.draw] or [sweep.growth]" in msg, msg
    f.write_text(text.replace("LIFE", "").replace("radius_mm = 1.0", "radius_mm = -1.0"))
    with pytest.raises(ScenarioError) as ei:                        # a stage's fault is checked as a scene's
        load_scenes(f)
    assert "radius_mm" in str(ei.value)


def test_grid_draws_random_faults_reproducibly(tmp_path):
    """[sweep.draw]: n cases per axes combination, each with faults drawn from the templates with the
    seed; the draws are in the resolved scenes (the run's labels) and the same on every load."""
    from drivetrain.campaigns.sweep import labels

    text = """
[scenario]
name = "rand"
[effects]
mesh_contact = "table"
[sweep.axes]
"operating_point.drive_speed_rpm" = [500.0, 1500.0]
[sweep.draw]
n = 4
seed = SEED
[[sweep.draw.faults]]
kind = ["pit", "void", "missing_tooth"]
member = ["pinion", "wheel"]
tooth = "any"
radius_mm = { uniform = [0.5, 2.0] }
depth_mm = { uniform = [0.05, 0.2] }
face_position = { uniform = [0.2, 0.8] }
"""
    f = tmp_path / "grid.toml"
    f.write_text(text.replace("SEED", "7"))
    a, b = load_scenes(f), load_scenes(f)
    assert [s.name for s in a] == [f"rand_{v}_draw{d:03d}" for v in ("500.0", "1500.0") for d in range(4)]
    assert [s.gear.faults for s in a] == [s.gear.faults for s in b]
    assert all(s.gear.health == "faults" and len(s.gear.faults) == 1 for s in a)
    for s in a:
        flt = s.gear.faults[0]
        assert 0 <= flt["tooth"] < (60 if flt["member"] == "wheel" else 15)
        if flt["kind"] == "pit":
            assert 0.5 <= flt["radius_mm"] <= 2.0 and 0.2 <= flt["face_position"] <= 0.8
        if flt["kind"] == "void":
            assert "radius_mm" not in flt and flt["width_mm"] == 1.0
    assert len({repr(s.gear.faults) for s in a}) > 4                 # the draws differ
    assert labels(a[0].to_dict()) == {"health": "faults", "faults": [dict(a[0].gear.faults[0])]}
    f.write_text(text.replace("SEED", "8"))
    assert [s.gear.faults for s in load_scenes(f)] != [s.gear.faults for s in a]
    bad = text.replace("SEED", "-1").replace('tooth = "any"', 'tooth = "some"\nsize_mm = 3').replace(
        "[0.5, 2.0]", "[2.0, 0.5]")
    f.write_text(bad)
    with pytest.raises(ScenarioError) as ei:
        load_scenes(f)
    msg = str(ei.value)
    for part in ("sweep.draw.seed", "sweep.draw.faults[0].size_mm", "sweep.draw.faults[0].radius_mm"):
        assert part in msg, msg


def test_grid_draw_gives_each_case_its_own_gearbox(tmp_path):
    """[sweep.draw] gearboxes = true: the manufacturing seed is the case's number in the grid (a paired
    healthy twin shares its faulty case's); without it every case keeps the base scene's seed."""
    text = """
[scenario]
name = "fleet"
[manufacturing]
seed = 5
[sweep.axes]
"operating_point.drive_speed_rpm" = [500.0, 1500.0]
[sweep.draw]
n = 3
seed = 1
GEARBOXES
paired_healthy = true
[[sweep.draw.faults]]
kind = "pit"
"""
    f = tmp_path / "grid.toml"
    f.write_text(text.replace("GEARBOXES", "gearboxes = true"))
    scenes = load_scenes(f)
    assert [s.manufacturing.seed for s in scenes] == [0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5]
    assert [s.gear.health for s in scenes[:2]] == ["faults", "healthy"]
    f.write_text(text.replace("GEARBOXES", ""))
    assert {s.manufacturing.seed for s in load_scenes(f)} == {5}
    f.write_text(text.replace("GEARBOXES", 'gearboxes = "yes"'))
    with pytest.raises(ScenarioError, match="sweep.draw.gearboxes"):
        load_scenes(f)
