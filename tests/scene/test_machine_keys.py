"""The scene's [drivetrain] keys (issue 42, item 2): the machine's lumped table and its drive and load settings.
Their defaults are the rig's, declared once (rig.data.DriveLoad) and the same as MotorLoad's parameter defaults;
a scene naming a table round-trips; when a setting acts (a dataset's null labels)."""
import dataclasses
from pathlib import Path

import pytest

from drivetrain.models.motors import MotorLoadParams
from drivetrain.rig.data import LOAD_LAWS, RIG_DRIVE_LOAD
from drivetrain.scene.load import SCHEMA, ScenarioError, load_scene, resolve, scene_from_dict
from drivetrain.scene.schema import setting_acts

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ROOT / "scenarios" / "other_gearboxes" / "heavy_propeller_machine.toml"
#: scene key -> MotorLoad parameter
TO_MOTORLOAD = {"drive_Kp": "Kp", "drive_Ti_s": "Ti", "drive_Ni": "Ni", "drive_torque_limit_Nm": "tau_max",
                "load_w_reg_rad_s": "load_w_reg", "load_gear_ratio": "ratio_pg", "load_motor_J_kgm2": "J_load_motor"}


def test_the_defaults_are_the_rigs_and_motorloads():
    fmu = {f.name: f.default for f in dataclasses.fields(MotorLoadParams)}
    for key, param in TO_MOTORLOAD.items():
        assert SCHEMA["drivetrain"][key].default == getattr(RIG_DRIVE_LOAD, key) == fmu[param], key
    assert LOAD_LAWS.index(SCHEMA["drivetrain"]["load_law"].default) == fmu["load_mode"] == 0
    d = scene_from_dict({}).drivetrain
    assert d.parameters is None and d.coupling_scale is None and d.drive_Kp == 0.1 and d.load_law == "torque"


def test_a_scene_naming_a_table_round_trips_and_takes_overrides():
    s = load_scene(HEAVY)
    assert s.drivetrain.parameters == HEAVY.with_name("heavy_propeller_machine.csv")
    assert s.drivetrain.drive_Kp == 0.2 and s.drivetrain.drive_torque_limit_Nm == 12.0
    again = resolve(s.to_dict(), base_dir=HEAVY.parent)
    assert again.to_dict() == s.to_dict()
    s2 = load_scene(HEAVY, ["drivetrain.drive_Kp=0.3", 'drivetrain.load_law="viscous"'])
    assert s2.drivetrain.drive_Kp == 0.3 and s2.drivetrain.load_law == "viscous"


def test_bad_drive_and_load_keys_are_refused_together():
    with pytest.raises(ScenarioError) as ei:
        scene_from_dict({"drivetrain": {"drive_Kp": 0, "load_law": "quadratic", "load_gear_ratio": -8,
                                        "coupling_scale": float("nan"), "parameters": 3, "drive_Kp_s": 1}})
    text = str(ei.value)
    for key in ("drivetrain.drive_Kp", "drivetrain.load_law", "drivetrain.load_gear_ratio", "drivetrain.coupling_scale",
                "drivetrain.parameters", "drivetrain.drive_Kp_s"):
        assert key in text, key
    assert "'torque', 'viscous'" in text and "a CSV file path" in text


def test_when_the_drive_keys_act():
    on = scene_from_dict({}).to_dict()
    rec = scene_from_dict({"effects": {"drive_control": "record"}}).to_dict()
    assert setting_acts("drivetrain", "drive_Kp", on) and not setting_acts("drivetrain", "drive_Kp", rec)
    assert setting_acts("drivetrain", "drive_torque_limit_Nm", rec)             # the limit acts either way
    visc = scene_from_dict({"drivetrain": {"load_law": "viscous"}}).to_dict()
    assert setting_acts("drivetrain", "load_w_reg_rad_s", on) and not setting_acts("drivetrain", "load_w_reg_rad_s", visc)
