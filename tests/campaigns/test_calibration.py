"""Loss calibration (drivetrain.campaigns.calibrate): the healthy mean torques at the 18 measured operating points,
recovery of known parameters from a synthetic table, the calibrate command, and a time-domain check
that the simulated means equal the steady-state balance used for the fit."""
import csv
import json
import math

import numpy as np
import pytest

from drivetrain.campaigns import calibrate as CAL
from drivetrain.rig import data as rig
from drivetrain.run.assemble import assemble
from drivetrain.scene.load import default_scene



def _measured():
    return CAL.read_measured()


def test_healthy_mean_torques_within_5_percent_at_all_18_points():
    """The assembled default system (its actual parameters), steady state at each measured operating
    point (the measured drive speed and load setting): both transducer torques within 5 %."""
    d = _measured()
    assert len(d["T_load_Nm"]) == 18
    worst = 0.0
    for TL, TD, TP, n in zip(d["T_load_Nm"], d["T_DSH_Nm"], d["T_PSH_Nm"], d["n_DSH_rpm"]):
        spec = assemble(default_scene(operating_point__drive_speed_rpm=float(n),
                                      operating_point__load_torque_Nm=float(TL)), check=False)
        ss = spec.metadata["steady_state"]
        for model, meas in ((ss["T_dsh"], TD), (ss["T_psh"], TP)):
            err = abs(model / meas - 1.0)
            worst = max(worst, err)
            assert err < 0.05, (TL, n, model, meas)
    assert worst < 0.035          # the shipped fit: max 3.0 %


def test_shipped_calibration_is_the_fit_of_the_shipped_table():
    res = CAL.calibrate()
    cal = rig.load_calibration()
    for key in ("upper", "planetary"):
        for q in CAL.LAW_KEYS:
            assert res[key][q] == pytest.approx(cal[key][q], rel=2e-3, abs=1e-7), (key, q)
    assert res["errors"]["max_abs_DSH"] < 0.05 and res["errors"]["max_abs_PSH"] < 0.05


def test_calibrate_recovers_known_parameters(tmp_path):
    true_up = {"c_v": 2.0e-3, "T_c": 0.25, "w_c": 12.0, "a": 0.04}
    true_pg = {"c_v": 0.08, "T_c": 2.2, "w_c": 3.0, "a": 0.05}
    loads = [0.12, 0.71, 1.31]
    speeds = [250.5, 500.99, 751.49, 1001.98, 1252.48, 1502.98]
    TL = np.repeat(loads, len(speeds))
    nD = np.tile(speeds, len(loads))
    TD, TP = CAL.predict(TL, nD, true_up, true_pg)
    p = tmp_path / "synthetic.csv"
    with open(p, "w", newline="") as fh:
        fh.write("# synthetic table\n")
        w = csv.writer(fh)
        w.writerow(["T_load_Nm", "T_DSH_Nm", "T_PSH_Nm", "n_DSH_rpm", "n_PSH_rpm"])
        for row in zip(TL, TD, TP, nD, nD / 12):
            w.writerow([f"{v:.12g}" for v in row])
    res = CAL.calibrate(p)
    assert res["errors"]["max_abs_DSH"] < 1e-6 and res["errors"]["max_abs_PSH"] < 1e-6
    for key, true in (("upper", true_up), ("planetary", true_pg)):
        for q in CAL.LAW_KEYS:
            assert res[key][q] == pytest.approx(true[q], rel=0.02), (key, q)


def test_calibrate_command_writes_a_file_the_assembler_takes(tmp_path, capsys):
    out = tmp_path / "cal.json"
    from drivetrain.cli import main

    assert main(["calibrate", str(rig.MEASURED_CSV), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "max |error|" in text and "wrote" in text
    cal = json.loads(out.read_text())
    assert set(cal) >= {"coupling_scale", "upper", "planetary"}
    spec = assemble(default_scene(), calibration=str(out), check=False)
    assert spec.components[2].parameters["loss_Tc"] == pytest.approx(cal["upper"]["T_c"])
    assert main(["calibrate", str(tmp_path / "missing.csv"), "--out", str(out)]) == 2


def _time_domain_means(fmu_dir, speed, load, duration=1.0, settle=0.6):
    """Mean sensor torques after ``settle`` of a plain run through the master (in-process backend), every
    communication step (the internal-rate records), and the assembler's steady state."""
    from drivetrain.cosim import simulate

    sc = default_scene(effects__mesh_contact="ideal", operating_point__drive_speed_rpm=speed,
                       operating_point__load_torque_Nm=load)
    spec = assemble(sc)
    sens = spec.metadata["sensors"]
    names = [sens["drive_shaft_torque"], sens["propeller_shaft_torque"]]
    res = simulate(spec, duration, round(1.0 / spec.comm_step), names, backend="inprocess", fmu_dir=fmu_dir,
                   keep_raw=True, progress=False)
    t, r = res.raw["time"], res.raw
    m = t >= settle
    ss = spec.metadata["steady_state"]
    return (float(np.mean(r[sens["drive_shaft_torque"]][m])), float(np.mean(r[sens["propeller_shaft_torque"]][m])),
            ss["T_dsh"], ss["T_psh"])


def test_time_domain_mean_equals_steady_state(fmu_dir):
    td, tp, sd, sp = _time_domain_means(fmu_dir, 1500.0, 1.31)
    assert td == pytest.approx(sd, rel=2e-3)
    assert tp == pytest.approx(sp, rel=2e-3)


@pytest.mark.slow
def test_time_domain_means_at_all_18_points_within_5_percent(fmu_dir):
    d = _measured()
    for TL, TD, TP, n in zip(d["T_load_Nm"], d["T_DSH_Nm"], d["T_PSH_Nm"], d["n_DSH_rpm"]):
        td, tp, _, _ = _time_domain_means(fmu_dir, float(n), float(TL), duration=2.0, settle=1.0)
        assert abs(td / TD - 1) < 0.05 and abs(tp / TP - 1) < 0.05, (TL, n, td, TD, tp, TP)


def test_coupling_scale_puts_the_lowest_mode_at_24_Hz():
    cal = rig.load_calibration()
    assert 0.5 < cal["coupling_scale"] < 0.9
    assert CAL.lowest_mode(cal["coupling_scale"]) == pytest.approx(24.0, abs=0.01)
    assert CAL.lowest_mode(1.0) == pytest.approx(28.4, abs=0.3)     # the public stiffness: ~28 Hz
