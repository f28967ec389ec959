"""The drivetrain FMUs serve another machine (issue 42, item 2): its inertias and stiffnesses are FMU parameters
(start values the rig's, from rig.data), set by the host at instantiation. A MotorLoad FMU run by
``fmpy.simulate_fmu`` with the load inertia of another machine's table decelerates as that inertia says
(independent oracle: a constant braking torque over an inertia), in both builds; and the exported SSP carries
the table's values."""
import zipfile
from xml.etree import ElementTree as ET

import pytest

from drivetrain.fmu_build.fmus import ensure_fmus
from drivetrain.rig import data as rig

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ROOT / "scenarios" / "other_gearboxes" / "heavy_propeller_machine.csv"
W0 = 10.0          # rad/s, the load body's start speed
T_SET = 1.0        # N m, the load motor's setting: ratio_pg * T_SET brakes the load body (tanh(W0 / w_reg) = 1)
STOP = 0.05


def _load_speed(fmu, J_load):
    import fmpy

    start = {"J_load": J_load, "pg_c": 0.0, "pg_Tc": 0.0, "pg_a": 0.0, "w0_load": W0, "load_torque": T_SET}
    res = fmpy.simulate_fmu(str(fmu), start_time=0.0, stop_time=STOP, output_interval=1e-3, step_size=1e-4,
                            start_values=start, output=["load_w"])
    return res["time"], res["load_w"]


def _builds(fmu_dir, tmp_path):
    out = {"pythonfmu": ensure_fmus(["MotorLoad"], fmu_dir)["MotorLoad"]}
    from drivetrain.fmu_build.native_line import build_native_line, toolchain_problems

    if not toolchain_problems():
        out["native"] = build_native_line("MotorLoad", tmp_path / "MotorLoad.fmu")
    return out


def test_motorload_fmu_takes_another_machines_load_inertia(fmu_dir, tmp_path):
    J_rig = rig.partition().params["motors"]["J_load"]
    J_heavy = rig.partition(model=rig.load_public(HEAVY)).params["motors"]["J_load"]
    assert J_heavy - J_rig == pytest.approx(2 * 0.0495, rel=1e-9)       # node 22: 0.0495 -> 0.1485 kg m^2
    ratio = rig.RIG_DRIVE_LOAD.load_gear_ratio
    for build, fmu in _builds(fmu_dir, tmp_path).items():
        for J in (J_rig, J_heavy):
            t, w = _load_speed(fmu, J)
            expected = W0 - ratio * T_SET * t / J         # a constant braking torque over the load body
            assert w[-1] == pytest.approx(expected[-1], rel=1e-9), (build, J)
            assert max(abs(w - expected)) < 1e-9 * W0, (build, J)
        # the start value of J_load is the rig's: a run that sets nothing brakes the rig's load body
        import fmpy

        md = fmpy.read_model_description(str(fmu))
        start = {v.name: v.start for v in md.modelVariables}
        assert float(start["J_load"]) == J_rig and float(start["Kp"]) == rig.RIG_DRIVE_LOAD.drive_Kp


def test_the_exported_ssp_carries_the_tables_values(fmu_dir, tmp_path):
    from drivetrain.interop.ssp import export_ssp
    from drivetrain.scene.load import load_scene

    scene = load_scene(ROOT / "scenarios" / "other_gearboxes" / "heavy_propeller_machine.toml",
                       ["time.duration_s=0.1", 'effects.mesh_contact="ideal"'])
    path = export_ssp(scene, tmp_path / "heavy.ssp", fmu_dir=fmu_dir)
    with zipfile.ZipFile(path) as z:
        root = ET.fromstring(z.read("resources/motors.ssv"))
    values = {e.get("name"): e[0].get("value") for e in root.iter() if e.tag.endswith("Parameter")}
    J_heavy = rig.partition(model=rig.load_public(HEAVY)).params["motors"]["J_load"]
    assert float(values["J_load"]) == pytest.approx(J_heavy, rel=1e-12)
    assert float(values["Kp"]) == 0.2 and float(values["tau_max"]) == 12.0     # the scene's [drivetrain] drive
