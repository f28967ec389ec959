"""The energy-conserving coupling correction (gearcontact_fmu.coupling; docs/STABILITY.md §4).

Oracles, none of them the correction's own output: the master's energy audit (its own bookkeeping of the
work through every connection from the recorded held torques and inertia-side angles, and of every FMU's
energy counters), and the same scene at an 8 times smaller communication step (the converged coupling).
The scene is a stress-campaign failure: the drive held at standstill against a reversed load, the gear
rattling in the backlash, at H = 1/6000 s."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivetrain.cosim import simulate
from drivetrain.fmu_build.fmus import load_fmu_info
from drivetrain.run.runner import assemble_scene
from drivetrain.scene.load import load_scene

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "standstill_reversed_load.toml"
SPRING_SIDE = {"motors": "MotorLoad", "drive_shaft": "FlexibleShaft", "gear": "GearContact"}
RECORD = ["drive_shaft.torque_sensor", "gear.flange_b_tau_mean"]


def _run(fmu_dir, correction: bool, divide: int = 1):
    scene = load_scene(SCENE, [f"numerics.energy_correction={str(correction).lower()}",
                               f"numerics.comm_step_s={scene_step() / divide!r}"])
    spec = assemble_scene(scene)
    final = [f"{c}.coupling_energy_error" for c in SPRING_SIDE]
    res = simulate(spec, scene.time.duration_s, scene.time.sample_rate_Hz, RECORD, fmu_dir=fmu_dir,
                   progress=False, final=final)
    return res


def scene_step() -> float:
    return load_scene(SCENE).numerics.comm_step_s


@pytest.fixture(scope="module")
def off(fmu_dir):
    return _run(fmu_dir, False)


@pytest.fixture(scope="module")
def on(fmu_dir):
    return _run(fmu_dir, True)


def test_the_ports_measure_what_the_audit_finds(off):
    """Uncorrected, the work mismatch each FMU measures at its spring-side ports is its residual in the
    master's audit (the inertia sides close exactly): the correction acts on the quantity the audit sees."""
    per = off.energy["per_fmu"]
    assert off.energy["relative_residual"] > 0.01          # the failure this scene records
    for comp in SPRING_SIDE:
        measured = off.final[f"{comp}.coupling_energy_error"]
        audit = -per[comp]["residual_J"]
        assert measured == pytest.approx(audit, rel=0.02, abs=2e-6), comp
    assert abs(per["motors"]["residual_J"]) > 1e-3        # the motor cut carries it, not only the gear


def test_the_correction_closes_the_energy_balance(off, on):
    assert on.status == "ok"
    assert on.energy["relative_residual"] < 2e-3, on.energy["relative_residual"]
    assert on.energy["relative_residual"] < off.energy["relative_residual"] / 20
    for comp in SPRING_SIDE:      # what is still pending at the end (the correction's lag) is small
        pending = abs(on.final[f"{comp}.coupling_energy_error"])
        assert pending < abs(off.final[f"{comp}.coupling_energy_error"]) / 10 + 1e-6, comp


def test_the_correction_moves_towards_the_converged_coupling(fmu_dir, off, on):
    """The torque fluctuation (RMS after settling) with the correction at H is closer to the run at H/8
    than the uncorrected run at H: the balance is not bought with a wrong answer."""
    ref = _run(fmu_dir, False, divide=8)
    settle = load_scene(SCENE).time.settle_s

    def rms(res, name):
        x = res.signals[name][res.time >= settle]
        return float(np.sqrt(np.mean(x * x)))

    for name in RECORD:
        r = rms(ref, name)
        err_on = abs(rms(on, name) - r) / r
        err_off = abs(rms(off, name) - r) / r
        assert err_on < 0.01, (name, err_on, err_off)
        assert err_on < err_off, (name, err_on, err_off)


def test_every_spring_side_fmu_declares_the_switch_and_the_mismatch(fmu_dir, off):
    for comp, model in SPRING_SIDE.items():
        info = load_fmu_info(Path(fmu_dir) / f"{model}.fmu")
        assert info.variables["energy_correction"].causality == "parameter", model
        v = info.variables["coupling_energy_error"]
        assert v.causality == "output" and v.unit == "J", model
