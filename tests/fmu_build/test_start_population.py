"""Every gearbox starts: the mesh's static-deflection start over a population of manufacturing draws.

The gear starts at the static deflection of its own mesh model (drivetrain.run.assemble.start_wheel_angle,
gearcontact_fmu.mesh_statics.balanced_wheel_angle). A drawn gearbox whose runout closes the backlash at the
start angle already carries more than the load at the backlash centre; the search used to bracket from
there towards the loaded flank only and never found a sign change: seeds 3, 10, 15 and 24 of 0-29 could
not start at the example's 1.31 N.m (one gearbox in eight). Pass rule, fixed before the population was run:
every draw assembles, its gear's t = 0 mesh torque on the pinion equals the port spring's steady torque
(the rig's steady-state torque balance, the independent oracle) within 1e-9 relative, and a run of four
mesh periods ends ``ok`` with the contact penetration below u_max. 0 failures allowed.

Default suite: the four seeds that failed (both backends where a C compiler exists) and a sample of the
population; ``-m slow``: seeds 0-199 x loads {0.12, 1.31, 11.9} N.m x {250, 1500} rpm through a sweep.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from test_fmu_declarations import gear_slave_at_t0

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"

#: the seeds of 0-29 that had no start at 1.31 N.m (main at 812c552)
FAILED_BEFORE = (3, 10, 15, 24)
#: load-motor torques [N m]: the paper's lightest, the example's, the load motor's nominal
LOADS_NM = (0.12, 1.31, 11.9)
SPEEDS_RPM = (250.0, 1500.0)
MESH_PERIODS = 4
PINION_BALANCE_REL = 1e-9


def _scene(seed: int, load_Nm: float = 1.31, speed_rpm: float = 1500.0, *extra: str):
    from drivetrain.rig import data as rig
    from drivetrain.scene.load import load_scene

    f_gmf = speed_rpm / 60.0 / rig.UPPER_RATIO * rig.Z_PINION
    return load_scene(EXAMPLE, [
        "effects.manufacturing_errors=true", "effects.tooth_compliance=true", f"manufacturing.seed={seed}",
        f"operating_point.load_torque_Nm={load_Nm!r}", f"operating_point.drive_speed_rpm={speed_rpm!r}",
        f"time.duration_s={MESH_PERIODS / f_gmf!r}", "outputs.plots=false", "outputs.aalto_csv=false",
        f"scenario.name=start_s{seed:03d}_T{str(load_Nm).replace('.', 'p')}_n{int(speed_rpm)}", *extra])


def _assert_balanced(scene):
    from drivetrain.run.assemble import assemble

    spec = assemble(scene, build_map=True)
    assert spec.metadata["mesh_start"] == "balanced on the table model", spec.metadata["mesh_start"]
    s = gear_slave_at_t0(spec)
    T_msh = spec.metadata["steady_state"]["T_msh"]
    assert s.mesh_torque_pinion == pytest.approx(-T_msh, rel=PINION_BALANCE_REL), scene.name
    return spec


def _assert_ran(summary, name):
    assert summary["status"] == "ok", (name, summary.get("failure"))
    assert summary["stability"]["max_penetration_rel_umax"] < 1.0, name
    for sensor, v in summary["torque"].items():
        assert math.isfinite(v["mean"]) and math.isfinite(v["rms"]), (name, sensor)


# ---- the search itself ------------------------------------------------------------------------------------


class _Closed:
    """A mesh model whose drive flank is already in contact at the backlash centre (the errors of a drawn
    gearbox close the backlash at this angle): tau_pinion = -k (s - s_on) for s > s_on, +k (s_off - s) on
    the coast flank for s < s_off. Closed form: the static deflection under a load T is s = s_on + T / k."""

    def __init__(self, k=3.0e5, s_on=-2.0e-3, s_off=-6.0e-3):
        from gearcontact_fmu.mesh_models.base import N_OUT

        self.k, self.s_on, self.s_off, self.n_out = k, s_on, s_off, N_OUT
        self.data = ()

    def eval(self, data, tp, tw, wp, ww, out):
        from gearcontact_fmu.mesh_models.base import OUT_TAU_PINION

        s = tp - 4.0 * tw
        out[:] = 0.0
        out[OUT_TAU_PINION] = (-self.k * (s - self.s_on) if s > self.s_on
                               else self.k * (self.s_off - s) if s < self.s_off else 0.0)


@pytest.mark.parametrize("load", [3.75662, 600.0, 0.01])
def test_the_start_search_backs_off_when_the_errors_close_the_backlash(load):
    """Closed-form oracle: with the drive flank already loaded at s = 0 (600 N m at s = 0 here), the
    search finds s = s_on + T / k, on either side of the backlash centre."""
    from gearcontact_fmu.mesh_statics import balanced_wheel_angle

    m = _Closed()
    tp = 0.3
    tw = balanced_wheel_angle(m, 4.0, tp, -load, s_guess=1.7e-3)
    assert tp - 4.0 * tw == pytest.approx(m.s_on + load / m.k, rel=1e-9, abs=1e-15)


def test_the_start_search_says_why_when_no_position_carries_the_load():
    from gearcontact_fmu.mesh_statics import StartStateError, balanced_wheel_angle

    class Nothing(_Closed):
        def eval(self, data, tp, tw, wp, ww, out):
            out[:] = 0.0

    with pytest.raises(StartStateError, match="carries no 2 N m on the drive flank"):
        balanced_wheel_angle(Nothing(), 4.0, 0.0, -2.0)

    class NotFinite(_Closed):
        def eval(self, data, tp, tw, wp, ww, out):
            out[:] = np.nan

    with pytest.raises(StartStateError, match="not finite"):
        balanced_wheel_angle(NotFinite(), 4.0, 0.0, -2.0)


# ---- the drivetrain: the four gearboxes that could not start, a sample, the population --------------------


@pytest.mark.parametrize("seed", FAILED_BEFORE)
def test_the_gearboxes_that_could_not_start_start_in_balance_and_run(seed, fmu_dir):
    from drivetrain.run.runner import run_scene

    scene = _scene(seed)
    _assert_balanced(scene)
    res = run_scene(scene, None, backend="fmi", progress=False, fmu_dir=fmu_dir)
    _assert_ran(res.summary, scene.name)


def test_a_gearbox_that_could_not_start_runs_on_the_native_backend(fmu_dir):
    from drivetrain.fmu_build.native_line import toolchain_problems
    from drivetrain.run.runner import run_scene

    if toolchain_problems():
        pytest.skip(f"no C toolchain: {toolchain_problems()}")
    scene = _scene(FAILED_BEFORE[0])
    res = run_scene(scene, None, backend="native", progress=False, fmu_dir=fmu_dir)
    _assert_ran(res.summary, scene.name)


#: the default suite's sample of the population: seeds spread over 0-199 (fixed before looking)
SAMPLE_SEEDS = (0, 37, 81, 124, 199)


@pytest.mark.parametrize("seed", SAMPLE_SEEDS)
def test_a_sample_of_the_population_starts_in_balance_at_every_load_and_speed(seed):
    for load in LOADS_NM:
        for speed in SPEEDS_RPM:
            _assert_balanced(_scene(seed, load, speed))


def test_a_sweep_names_a_gearbox_without_start_state_and_goes_on(monkeypatch, tmp_path):
    """A start state that is truly infeasible (forced here) is one failed case of the sweep, named with its
    gearbox in the manifest and the log; the other cases are handed to the workers."""
    from drivetrain.campaigns import sweep as S
    from drivetrain.errors import StartStateError
    from drivetrain.run import assemble as asm

    real = asm.start_wheel_angle

    def no_start_for_seed_7(gear, ss, theta_p, errors, build_map=False):
        if errors is not None and errors.source.get("seed") == 7:
            raise StartStateError("the mesh model carries no 3.76 N m on the drive flank within s = 1e+15 rad")
        return real(gear, ss, theta_p, errors, build_map)

    handed = []

    def record(scenes, specs, out, **kwargs):
        handed.extend(s.name for s in scenes)
        return [], []

    monkeypatch.setattr(asm, "start_wheel_angle", no_start_for_seed_7)
    monkeypatch.setattr(S, "_cases", record)
    scenes = [_scene(6), _scene(7), _scene(8)]
    manifest = S.run_sweep(scenes, tmp_path / "out", progress=False)
    assert handed == [scenes[0].name, scenes[2].name]
    (failed,) = [r for r in manifest["runs"] if r["status"] == "failed"]
    assert failed["name"] == scenes[1].name
    assert failed["failure_cause"] == "no start state"
    assert "manufacturing.seed = 7" in failed["error"] and "carries no 3.76 N m" in failed["error"]
    assert [r["name"] for r in S.read_runs(tmp_path / "out")] == [scenes[1].name]


def test_run_refuses_a_gearbox_without_start_state_with_a_message_not_a_traceback(monkeypatch, tmp_path, capsys):
    from drivetrain import cli
    from drivetrain.errors import StartStateError
    from drivetrain.run import assemble as asm

    def none(*args, **kwargs):
        raise StartStateError("the mesh model carries no 3.76 N m on the drive flank within s = 1e+15 rad")

    monkeypatch.setattr(asm, "start_wheel_angle", none)
    rc = cli.main(["run", str(EXAMPLE), "--set", "effects.manufacturing_errors=true", "--set", "manufacturing.seed=3",
                   "--set", "time.duration_s=0.01", "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert rc != 0
    assert "Traceback" not in err
    assert "no start state" in err and "manufacturing.seed = 3" in err and "1500 rpm" in err, err


@pytest.mark.slow
def test_every_gearbox_of_the_population_starts_and_runs(fmu_dir, tmp_path):
    """Seeds 0-199 x three loads x two speeds (1,200 gearbox/operating-point pairs): each assembles in
    balance and runs four mesh periods through a sweep (local processes), 0 failures."""
    from drivetrain.campaigns.sweep import run_sweep

    scenes = [_scene(seed, load, speed) for seed in range(200) for load in LOADS_NM for speed in SPEEDS_RPM]
    for sc in scenes:
        _assert_balanced(sc)
    manifest = run_sweep(scenes, tmp_path / "pop", fmu_dir=fmu_dir, plots=False, progress=False)
    bad = [(r["name"], r.get("error")) for r in manifest["runs"] if r["status"] != "ok"]
    assert not bad, bad
    for r in manifest["runs"]:
        assert r["stability"]["max_penetration_rel_umax"] < 1.0, r["name"]


@pytest.mark.slow
@pytest.mark.parametrize("seed", FAILED_BEFORE)
def test_the_gearboxes_that_could_not_start_run_native_at_every_load_and_speed(seed, fmu_dir):
    from drivetrain.fmu_build.native_line import toolchain_problems
    from drivetrain.run.runner import run_scene

    if toolchain_problems():
        pytest.skip(f"no C toolchain: {toolchain_problems()}")
    for load in LOADS_NM:
        for speed in SPEEDS_RPM:
            scene = _scene(seed, load, speed)
            res = run_scene(scene, None, backend="native", progress=False, fmu_dir=fmu_dir)
            _assert_ran(res.summary, scene.name)
