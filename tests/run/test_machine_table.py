"""Another machine's drivetrain from its lumped table (issue 42, item 2), run: the rig stays the default and a scene
that names the rig's own table runs bit for bit as one that names none; a modified table changes the run where
physics says it must (the load body's response to a load step scales as 1 / its inertia, the mean torques do
not move), and the [drivetrain] drive and load keys reach the drive motor."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from drivetrain.rig import data as rig
from drivetrain.run.assemble import assemble
from drivetrain.run.runner import run_scene
from drivetrain.scene.load import load_scene, scene_from_dict

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"
HEAVY = ROOT / "scenarios" / "other_gearboxes" / "heavy_propeller_machine.csv"
QUIET = dict(backend="inprocess", progress=False, log=lambda m: None)


def test_naming_the_rigs_own_table_runs_bit_identical(tmp_path):
    """The example scene (table gear, flexible shafts) for 30 ms, once as shipped and once naming the rig's table
    (a copy of it elsewhere, so that nothing can recognise the path): every signal equal, bit for bit."""
    copy = tmp_path / "my_rig.csv"
    copy.write_text(rig.PUBLIC_CSV.read_text())
    sets = ["time.duration_s=0.03", "time.settle_s=0.01", "outputs.plots=false", "outputs.aalto_csv=false"]
    a = run_scene(load_scene(EXAMPLE, sets), None, **QUIET)
    b = run_scene(load_scene(EXAMPLE, sets + [f'drivetrain.parameters="{copy}"']), None, **QUIET)
    assert b.scene.drivetrain.parameters == copy and a.scene.drivetrain.parameters is None
    assert a.status == b.status == "ok"
    assert np.array_equal(a.time, b.time) and sorted(a.signals) == sorted(b.signals) and len(a.signals) >= 7
    for name in a.signals:
        assert np.array_equal(a.signals[name], b.signals[name]), name
    assert [c.parameters for c in a.spec.components] == [c.parameters for c in b.spec.components]


def _step_run(table, rigid=True):
    """A load step (1.0 -> 1.5 N m at 10 ms) with a rigid mesh and rigid shafts, the load body's speed sampled at
    every communication step."""
    raw = {"operating_point": {"drive_speed_rpm": 1000.0, "load_profile_Nm": [[0.0, 1.0], [0.01, 1.0],
                                                                                [0.0101, 1.5]]},
           "time": {"duration_s": 0.02, "settle_s": 0.005, "sample_rate_Hz": 12000.0},
           "numerics": {"comm_step_s": 1.0 / 12000.0},
           "effects": {"mesh_contact": "ideal", "shaft_flexibility": "rigid" if rigid else "flexible"},
           "outputs": {"plots": False, "variables": ["motors.load_w"]}}
    if table is not None:
        raw["drivetrain"] = {"parameters": str(table)}
    return run_scene(scene_from_dict(raw), None, **QUIET)


def test_a_heavier_propeller_answers_a_load_step_as_its_inertia_says():
    """The heavy machine's propeller mass is 3 x the rig's (node 22). Before the step both run at the same steady
    state (the mean torques do not depend on inertia); just after it, before the propeller shaft's spring has
    answered (a quarter period of its local mode is ~1.5 ms), the load body decelerates at the step's torque over
    its inertia: the two runs' speed drops stand as the inverse ratio of the load bodies' inertias (from the
    partition), within 5 %."""
    rig_run, heavy_run = _step_run(None), _step_run(HEAVY)
    J = [r.spec.components[0].parameters["J_load"] for r in (rig_run, heavy_run)]
    assert J[1] / J[0] == pytest.approx((0.1485 + (J[0] - 0.0495)) / J[0], rel=1e-6)     # node 22 x 3
    t = rig_run.time
    before = (t > 0.005) & (t < 0.0095)
    for name in ("propeller_shaft_torque", "drive_shaft_torque"):
        assert np.mean(heavy_run.signals[name][before]) == pytest.approx(np.mean(rig_run.signals[name][before]),
                                                                         rel=1e-3), name
    i0 = int(np.searchsorted(t, 0.0101))
    i1 = int(np.searchsorted(t, 0.0101 + 0.0004))
    drops = [r.signals["motors.load_w"][i1] - r.signals["motors.load_w"][i0] for r in (rig_run, heavy_run)]
    assert drops[0] < 0 and drops[1] < 0
    assert drops[1] / drops[0] == pytest.approx(J[0] / J[1], rel=0.05)
    assert not np.array_equal(rig_run.signals["propeller_shaft_torque"], heavy_run.signals["propeller_shaft_torque"])


def test_the_drive_and_load_keys_reach_the_drive_motor():
    """[drivetrain] drive and load keys become MotorLoad's parameters (the rig's when absent); the viscous load
    law starts at its operating point (the steady state holds the setting at the initial speed)."""
    base = assemble(scene_from_dict({}), check=False).components[0].parameters
    assert (base["Kp"], base["Ti"], base["Ni"], base["tau_max"], base["load_mode"], base["ratio_pg"]) == \
        (0.1, 0.4, 0.9, 10.0, 0, 8.0)
    keys = {"drive_Kp": 0.25, "drive_Ti_s": 0.3, "drive_Ni": 0.5, "drive_torque_limit_Nm": 20.0,
            "load_law": "viscous", "load_gear_ratio": 6.0, "load_motor_J_kgm2": 1e-4, "load_w_reg_rad_s": 0.1}
    spec = assemble(scene_from_dict({"drivetrain": keys}), check=False)
    p = spec.components[0].parameters
    assert (p["Kp"], p["Ti"], p["Ni"], p["tau_max"], p["load_mode"], p["ratio_pg"], p["J_load_motor"],
            p["load_w_reg"]) == (0.25, 0.3, 0.5, 20.0, 1, 6.0, 1e-4, 0.1)
    ss = spec.metadata["steady_state"]
    assert ss["T_load_prop"] == pytest.approx(6.0 * 1.31, rel=1e-12)           # viscous: the setting at w0
    # the record's controller still wins with effects.drive_control = "record"
    rec = assemble(scene_from_dict({"drivetrain": keys, "effects": {"drive_control": "record"}}), check=False)
    bg = scene_from_dict({}).background
    assert rec.components[0].parameters["Kp"] == bg.drive_Kp and rec.components[0].parameters["Ti"] == bg.drive_Ti_s


def test_a_scene_refuses_a_table_it_cannot_run(tmp_path):
    """A two-mass chain has no bevel mesh, so no places for the FMUs: the scene is refused at loading, naming the
    key, the file and why (and `drivetrain eigen --parameters` is named for its modes)."""
    from drivetrain.errors import ScenarioError

    two = ROOT / "scenarios" / "other_gearboxes" / "two_mass_machine.csv"
    with pytest.raises(ScenarioError) as ei:
        scene_from_dict({"drivetrain": {"parameters": str(two)}})
    text = str(ei.value)
    assert "drivetrain.parameters" in text and "a table of 2 nodes" in text and "drivetrain eigen" in text
    assert "the bevel mesh is the last geared element" in text
    bad = tmp_path / "bad.csv"
    bad.write_text(rig.PUBLIC_CSV.read_text().replace("22,0.0495", "22,-0.0495"))
    with pytest.raises(ScenarioError) as ei:
        scene_from_dict({"drivetrain": {"parameters": "bad.csv"}}, base_dir=tmp_path)
    assert str(bad) in str(ei.value) and "(node 22): J_kgm2 = '-0.0495'" in str(ei.value)


def test_an_upper_gearbox_of_another_ratio_moves_the_mesh_frequency(tmp_path):
    """Element 12 at 1/2: at 1000 rpm the middle shaft turns at 1000/60/2 Hz and the mesh at z1 times that,
    125 Hz (the rig: 83.3 Hz), in the summary and in the run's spectra; the load body turns at 1/8 of the drive."""
    table = tmp_path / "half.csv"
    table.write_text(rig.PUBLIC_CSV.read_text().replace("12,0.000325,0.0031,43300,1.84,0.3333333333",
                                                        "12,0.000325,0.0031,43300,1.84,0.5"))
    raw = {"drivetrain": {"parameters": str(table)}, "operating_point": {"drive_speed_rpm": 1000.0},
           "time": {"duration_s": 0.05, "settle_s": 0.01},
           "effects": {"mesh_contact": "ideal", "shaft_flexibility": "rigid"}, "outputs": {"plots": False,
                                                                                           "variables": ["motors.load_w"]}}
    res = run_scene(scene_from_dict(raw), tmp_path / "run", **QUIET)
    assert res.status == "ok"
    assert res.summary["f_GMF"] == pytest.approx(15 * 1000 / 60 / 2, rel=1e-12)
    from drivetrain.campaigns.loaders import spectrum          # the stored run, read back

    assert spectrum(tmp_path / "run", "propeller_shaft_torque").attrs["characteristic_frequencies"]["f_GMF"] == \
        pytest.approx(125.0, rel=1e-12)
    assert res.summary["f_MSH"] == pytest.approx(1000 / 60 / 2, rel=1e-12)
    assert res.spectrum("propeller_shaft_torque").attrs["characteristic_frequencies"]["f_GMF"] == \
        pytest.approx(125.0, rel=1e-12)
    w_load = np.mean(res.signals["motors.load_w"][res.time > 0.01])
    assert w_load == pytest.approx(rig.rpm_to_rad_s(1000.0) / 2 / 4, rel=1e-4)


def test_a_thruster_of_its_own_runs_at_its_torque_balance():
    """The shipped 9-node thruster table (not the rig's layout: places from its ratios, rigid shafts, 3 FMUs), 0.3 s at
    1200 rpm and 2 N m: the settled mean torques are the torque balance through its gears and losses
    (rig.data.steady_state with the assembled parameters: T_PSH = 8 T + planetary loss, T_DSH = T_PSH / 4 / 2 +
    upper loss) within 0.5 %, the mesh at z1 x 1200/60/2 = 150 Hz; every cut stable."""
    scene = load_scene(ROOT / "scenarios" / "other_gearboxes" / "thruster_machine.toml",
                       ["time.duration_s=0.3", "time.settle_s=0.1", "outputs.plots=false"])
    res = run_scene(scene, None, **QUIET)
    assert res.status == "ok" and [c.model for c in res.spec.components] == ["MotorLoad", "UpperTransmission",
                                                                              "GearContact"]
    ss = res.spec.metadata["steady_state"]
    assert res.summary["torque"]["propeller_shaft_torque"]["mean"] == pytest.approx(ss["T_psh"], rel=0.005)
    assert res.summary["torque"]["drive_shaft_torque"]["mean"] == pytest.approx(ss["T_dsh"], rel=0.005)
    assert ss["T_psh"] > 8 * 2.0 and ss["T_dsh"] > ss["T_psh"] / 8       # the losses, on top of the ideal ratios
    assert res.summary["f_GMF"] == pytest.approx(150.0, rel=1e-12)
    assert res.spec.metadata["cosim_spectral_radius"] <= 1.0


def test_a_named_tables_bevel_element_is_the_scenes_pair(tmp_path):
    """With another pair ([gear.pair] 20/40), a named table's bevel element must be that pair's z1/z2 = 1/2: the rig's
    table (1/4 there) is refused naming both ratios; the same table at 1/2 runs its propeller side in the frame
    1/3 x 1/2 = 1/6 (the wheel's own inertia the table's node 18 body, whatever the frame)."""
    from drivetrain.errors import ScenarioError

    pair = ROOT / "scenarios" / "other_gearboxes" / "pair_20_40_m4.toml"
    rig_copy = tmp_path / "rig.csv"
    rig_copy.write_text(rig.PUBLIC_CSV.read_text())
    with pytest.raises(ScenarioError) as ei:
        load_scene(pair, [f'drivetrain.parameters="{rig_copy}"'])
    assert "element 17 (the bevel mesh) has ratio_next = 0.25; the gear pair's z1/z2 = 0.5" in str(ei.value)
    half = tmp_path / "half.csv"
    half.write_text(rig.PUBLIC_CSV.read_text().replace("17,0.000269,0.0031,44300,1.88,0.25",
                                                       "17,0.000269,0.0031,44300,1.88,0.5"))
    spec = assemble(load_scene(pair, [f'drivetrain.parameters="{half}"']), check=False)
    base = assemble(load_scene(pair), check=False)
    g, g0 = spec.components_of("GearContact")[0].parameters, base.components_of("GearContact")[0].parameters
    assert g["J_wheel"] == pytest.approx(g0["J_wheel"], rel=1e-9) and g["k_b"] == pytest.approx(g0["k_b"], rel=1e-9)
    assert spec.metadata["steady_state"]["w_prop"] == pytest.approx(rig.rpm_to_rad_s(1500.0) / 3 / 2, rel=1e-12)
