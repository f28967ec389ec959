"""operating_point.load_series_csv: a measured time/torque CSV as the load input (drivetrain.scene.series)."""
from pathlib import Path

import numpy as np
import pytest

from drivetrain.scene.load import ScenarioError, load_scene, resolve

ROOT = Path(__file__).resolve().parents[2]
VALIDATION = ROOT / "scenarios" / "validation"
RECORDS = ROOT / "src" / "drivetrain" / "data" / "rig_records"
KEY = "operating_point.load_series_csv"


def _scene(tmp_path, text, **op):
    (tmp_path / "load.csv").write_text(text)
    return resolve({"operating_point": {"load_series_csv": "load.csv", **op}}, base_dir=tmp_path)


def _refused(tmp_path, text, **extra):
    with pytest.raises(ScenarioError) as ei:
        _scene(tmp_path, text, **extra)
    return ei.value


def test_a_series_is_the_load_input_interpolated_and_converted(tmp_path):
    s = _scene(tmp_path, "# a comment\ntime [ms],torque [kN·m]\n0,0.001\n500,0.001\n600,0.002\n")
    op = s.operating_point
    assert op.load_profile_Nm == ((0.0, 1.0), (0.5, 1.0), (0.6, 2.0))
    assert op.load_at(0.55) == pytest.approx(1.5)          # linear between points
    assert op.load_at(3.0) == pytest.approx(2.0)           # held after the last
    assert op.load_series_csv == (tmp_path / "load.csv").resolve()


def test_the_path_is_relative_to_the_scene_file_and_the_resolved_scene_names_the_file(tmp_path):
    sub = tmp_path / "scenes"
    sub.mkdir()
    (sub / "duty.csv").write_text("time_s,load_torque_Nm\n0,0.12\n1,1.31\n")
    (sub / "s.toml").write_text('[operating_point]\nload_series_csv = "duty.csv"\n')
    s = load_scene(sub / "s.toml")
    d = s.to_dict()["operating_point"]
    assert d["load_series_csv"] == str((sub / "duty.csv").resolve()) and "load_profile_Nm" not in d
    again = resolve(s.to_dict(), base_dir=tmp_path)       # the file's absolute path round-trips
    assert again.operating_point.load_profile_Nm == ((0.0, 0.12), (1.0, 1.31))


@pytest.mark.parametrize("text, expected", [
    ("time_s,load_torque_Nm\n0,1\n1,nan\n", "non-finite"),
    ("time_s,load_torque_Nm\n0,1\ninf,2\n", "non-finite"),
    ("time_s,load_torque_Nm\n0,1\n1,2\n0.5,3\n", "does not increase"),
    ("time_s,load_torque_Nm\n0,1\n1,2\n1,3\n", "does not increase"),
    ("time_s,load_torque_Nm\n0.2,1\n1,2\n", "starts at 0.2 s"),
    ("time,torque\n0,1\n1,2\n", "no unit"),
    ("0,1\n1,2\n", "no unit"),                                  # no header at all: the first row is not one
    ("time_s,load_torque_furlong\n0,1\n1,2\n", "unknown unit"),
    ("time_s,load_torque_N\n0,1\n1,2\n", "a force unit"),       # a force is not a torque
    ("time_Nm,load_torque_Nm\n0,1\n1,2\n", "a torque unit"),
    ("time_s,load_torque_Nm\n0,1\n", "at least 2"),
    ("time_s,load_torque_Nm\n", "at least 2"),
    ("", "empty"),
    ("time_s,load_torque_Nm\n0,1,5\n1,2,5\n", "3 columns"),
    ("time_s,load_torque_Nm\n0,one\n1,2\n", "not a number"),
])
def test_a_bad_series_is_a_scene_problem_naming_the_file(tmp_path, text, expected):
    e = _refused(tmp_path, text)
    assert any(k == KEY and expected in exp and "load.csv" in exp for k, _, exp in e.problems), str(e)


def test_a_missing_file_is_named_and_collected_with_the_scenes_other_problems(tmp_path):
    with pytest.raises(ScenarioError) as ei:
        resolve({"operating_point": {"load_series_csv": "nowhere.csv"}, "time": {"duration_s": -1.0}},
                base_dir=tmp_path)
    keys = [k for k, _, _ in ei.value.problems]
    assert KEY in keys and "time.duration_s" in keys
    assert "nowhere.csv: no such file" in str(ei.value)


def test_a_series_and_an_inline_profile_together_are_refused(tmp_path):
    e = _refused(tmp_path, "time_s,load_torque_Nm\n0,1\n1,2\n", load_profile_Nm=[[0.0, 1.0], [1.0, 2.0]])
    assert any(k == KEY and "not both" in exp for k, _, exp in e.problems)


@pytest.mark.parametrize("scene, motor_csv, retimed", [
    ("rig_impulse_2004rpm.toml", "excitation_2004rpm_impulse_motor.csv", False),
    ("rig_sine_2004rpm.toml", "excitation_2004rpm_sin_motor.csv", True)])
def test_the_shipped_2004rpm_scenes_replay_the_records_setpoint_at_the_load_motor(scene, motor_csv, retimed):
    """Oracle: the record's own motor file, read here with numpy: its column 3 is referred to the propeller
    shaft (x8); the scene's load input is at the load motor, every logged value in its order. The impulse runs
    on the log's own time column; the multi-sine's log is retimed onto the rig's clock (rig.clock,
    tests/rig/test_clock.py): its times differ from the column's, run forward, and span the log's rows at
    about 1 kHz."""
    s = load_scene(VALIDATION / scene)
    raw = np.loadtxt(RECORDS / motor_csv, delimiter=",")
    prof = np.asarray(s.operating_point.load_profile_Nm)
    assert len(prof) == len(raw)
    assert np.allclose(prof[:, 1], raw[:, 3] / 8.0, rtol=1e-8)
    on_log_clock = np.allclose(prof[:, 0], raw[:, 0] - raw[0, 0], atol=1e-8)
    assert on_log_clock is not retimed
    assert np.all(np.diff(prof[:, 0]) > 0) and prof[-1, 0] == pytest.approx(len(raw) / 1000.0, rel=0.01)
    assert s.operating_point.final_speed_rpm == 2004.0
    assert 0.1 < prof[:, 1].min() and prof[:, 1].max() < 2.6       # the load motor's 0.119 ... 2.5 N·m, not x8
