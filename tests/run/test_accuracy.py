"""The accuracy-cost study's metrics and choices (drivetrain.run.accuracy), against closed-form signals, and
``--tolerance`` end to end on a short scene."""
from __future__ import annotations

import math

import numpy as np
import pytest

from drivetrain.run import accuracy as A
from drivetrain.campaigns import accuracy_study as S
from drivetrain.run import cost as runcost
from drivetrain.run.assemble import assemble
from drivetrain.scene.load import load_scene
from drivetrain.rig.signals import characteristic_frequencies

from _shared import EXAMPLE, accuracy_results
FS, SETTLE, RPM = 3000.0, 0.5, 1500.0


def _signal(scale=1.0, sideband=0.0, offset=0.0, seconds=4.5):
    """Mean + GMF line + a lower sideband at f_GMF - f_MSH, on both torque channels."""
    cf = characteristic_frequencies(RPM)
    t = np.arange(int(seconds * FS)) / FS
    x = 15.0 + offset + scale * (0.2 * np.sin(2 * np.pi * cf["f_GMF"] * t)
                                 + (0.02 + sideband) * np.sin(2 * np.pi * (cf["f_GMF"] - cf["f_MSH"]) * t))
    return {"time": t, "drive_shaft_torque": x / 8.0, "propeller_shaft_torque": x}


def test_identical_runs_have_no_error():
    e = A.compare(_signal(), _signal(), FS, SETTLE, RPM)["worst"]
    assert e["mean_err_pct"] == 0.0 and e["std_err_pct"] == 0.0 and e["gmf_dB"] == 0.0
    assert e["sideband_dB"] == 0.0 and e["spectral_distance_pct"] == 0.0


def test_errors_match_closed_form_values():
    """A fluctuation 10 % larger: std +10 %, GMF and sideband +0.83 dB (20 log10 1.1), mean unchanged;
    a mean 0.15 N·m higher: 1 % on 15 N·m. The sideband doubled: +6.02 dB."""
    e = A.compare(_signal(), _signal(scale=1.1), FS, SETTLE, RPM)["worst"]
    assert e["std_err_pct"] == pytest.approx(10.0, rel=1e-3)
    assert e["gmf_dB"] == pytest.approx(20 * math.log10(1.1), abs=1e-3)
    assert e["sideband_dB"] == pytest.approx(20 * math.log10(1.1), abs=1e-3)
    assert e["mean_err_pct"] < 1e-4         # (a sine over a non-integer number of periods)
    e = A.compare(_signal(), _signal(offset=0.15), FS, SETTLE, RPM)["worst"]
    assert e["mean_err_pct"] == pytest.approx(1.0, rel=1e-6) and e["std_err_pct"] < 1e-9
    e = A.compare(_signal(), _signal(sideband=0.02), FS, SETTLE, RPM)["worst"]
    assert e["sideband_dB"] == pytest.approx(20 * math.log10(2.0), abs=0.01)
    assert abs(e["gmf_dB"]) < 0.01


def test_an_unresolved_reference_sideband_constrains_nothing():
    """A sideband of the reference at the numerical floor (a healthy gear) is no yardstick."""
    ref, run = _signal(sideband=-0.02), _signal(sideband=-0.02 + 1e-9)
    assert A.compare(ref, run, FS, SETTLE, RPM)["worst"]["sideband_dB"] is None


def test_within_pairs_percent_and_decibel():
    assert A.within({"mean_err_pct": 0.9, "std_err_pct": 0.5, "gmf_dB": -0.9, "sideband_dB": None}, 1.0)
    assert not A.within({"mean_err_pct": 0.9, "std_err_pct": 1.5, "gmf_dB": 0.1}, 1.0)
    assert not A.within({"mean_err_pct": 0.1, "gmf_dB": 1.2}, 1.0)
    assert not A.within({"mean_err_pct": float("nan")}, 5.0)


def test_pareto_front():
    pts = [(1.0, 5.0, "a"), (2.0, 1.0, "b"), (2.5, 3.0, "c"), (4.0, 0.5, "d"), (0.5, 9.0, "e")]
    assert S.pareto_front(pts) == {"a", "b", "d", "e"}


def test_choose_picks_the_cheapest_setting_within_the_tolerance():
    healthy = load_scene(EXAMPLE)
    severe = load_scene(EXAMPLE, ["gear.health=severe", "operating_point.drive_speed_rpm=300"])
    R = accuracy_results()
    assert A.closest_scene(healthy, R) == "healthy_1500rpm" and A.closest_scene(severe, R) == "severe_250rpm"
    assert A.choose(healthy, 1.0, R).setting == "default"
    assert A.choose(healthy, 5.0, R).setting == "fast"
    assert A.choose(severe, 1.0, R).setting == "reference"       # nothing cheaper is within 1 %
    assert A.choose(severe, 5.0, R).setting == "default"
    # a realism effect changes the physics: never picked, however cheap
    assert "tooth_compliance" not in A.choose(healthy, 50.0, R).candidates


def test_every_setting_and_scene_of_the_study_is_a_valid_scene(contact_maps_read_once):
    """Every (scene, setting) of the study assembles and its predicted cost is affordable (the ~180 assemblies
    read the few contact maps they share once each: _shared.contact_map_read_once)."""
    runs, refused = S.study_scenes()
    assert len(runs) + len(refused) == len(A.STUDY_SCENES) * len(A.SETTINGS)
    # only the fidelities without tooth geometry are refused, and only for faulty gears
    assert {st for _, st in refused} <= {"analytic", "ideal"}
    assert all(not sc.startswith("healthy") for sc, _ in refused)
    assert all(runcost.refusal(runcost.predict(assemble(s), s.time.duration_s)) is None
               for s in runs if "__pcm" not in s.name)


def test_the_shipped_results_choose_different_settings():
    """The study's results ship with the package: --tolerance needs no re-run, and different scenes and
    tolerances get different settings."""
    R = A.load_results()
    picks = {(sc, T): A.choose(load_scene(EXAMPLE, over), T, R).setting
             for sc, over in (("healthy", []), ("severe", ["gear.health=severe", "operating_point.drive_speed_rpm=250"]))
             for T in (1.0, 5.0, 20.0)}
    assert len(set(picks.values())) >= 2, picks


SHORT = ["time.duration_s=1.5", "time.settle_s=0.5", "outputs.plots=false"]


def test_run_with_a_tolerance_records_its_choice(tmp_path):
    """drivetrain run --tolerance: the chosen setting is applied, and recorded with why (a 0.1 s run: the
    choice and the step it sets do not depend on the length)."""
    import json

    from drivetrain.cli import main

    T = 5.0
    tiny = ["time.duration_s=0.1", "time.settle_s=0.05", "outputs.plots=false"]
    assert main(["run", str(EXAMPLE), "--tolerance", f"{T:g}%", "--out", str(tmp_path / "tol"), "--quiet",
                 "--backend", "inprocess", *sum((["--set", o] for o in tiny), [])]) == 0
    summ = json.loads((tmp_path / "tol" / "summary.json").read_text())
    choice = summ["accuracy_choice"]
    expected = A.choose(load_scene(EXAMPLE), T)
    assert choice["tolerance_pct"] == T and choice["setting"] == expected.setting and choice["why"]
    assert choice["studied_scene"] == "healthy_1500rpm"
    applied = load_scene(EXAMPLE, [*tiny, *choice["overrides"]])
    assert summ["comm_step_s"] == applied.numerics.comm_step_s


@pytest.mark.slow
def test_the_chosen_setting_meets_the_tolerance_against_the_reference():
    """On a short scene, the setting chosen for 5 % agrees with the reference settings' run within 5 % on
    mean torques and fluctuation and 5 dB at f_GMF (slow: the reference's converged-mesh contact map is
    built once, ~1-2 min on a cold cache)."""
    from drivetrain.run.runner import run_scene

    T = 5.0
    choice = A.choose(load_scene(EXAMPLE), T)
    chosen = load_scene(EXAMPLE, [*SHORT, *choice.overrides])
    ref = load_scene(EXAMPLE, [*SHORT, *A.SETTINGS[A.REFERENCE].overrides])
    a = run_scene(chosen, None, backend="inprocess", progress=False, log=lambda m: None)
    b = run_scene(ref, None, backend="inprocess", progress=False, log=lambda m: None)
    e = A.compare({"time": b.time, **b.signals}, {"time": a.time, **a.signals}, 3000.0, 0.5, 1500.0)["worst"]
    assert A.within(e, T), e


def test_the_report_and_plots_render(tmp_path):
    R = accuracy_results()
    R["meta"] = {"command": "drivetrain accuracy-cost", "wall_time_s": 60.0, "workers": 2}
    R["scenes"]["healthy_1500rpm"]["rows"]["mesh_0.5mm"] = {"status": "not applicable", "reason": "x"}
    figs = S.plot_pareto(R, tmp_path)
    assert set(figs) == {"healthy_1500rpm", "severe_250rpm"} and all((tmp_path / f).is_file() for f in figs.values())
    md = S.report_markdown(R, {k: f"figures/{v}" for k, v in figs.items()})
    assert "## healthy_1500rpm" in md and "| fast | 0.9 |" in md and "not applicable: x" in md
    assert "Within 5 % / 5 dB: cheapest `fast`" in md and "(realism)" in md


def test_a_study_of_one_scene_keeps_the_other_scenes_rows():
    """drivetrain accuracy-cost --scenes NAME rewrites the results file with NAME's rows and every other scene's
    earlier rows as they were (named with the command that measured them), in STUDY_SCENES' order; a scene the
    new study ran replaces its earlier rows."""
    from drivetrain.campaigns.accuracy_study import keep_earlier, report_markdown

    earlier = {"meta": {"command": "drivetrain accuracy-cost --workers 2"},
               "scenes": {"healthy_250rpm": {"what": "a", "rows": {}},
                          "pair20x40_healthy_1500rpm": {"what": "old", "rows": {}},
                          "not_a_studied_scene": {"what": "x", "rows": {}}}}
    new = {"meta": {"command": "drivetrain accuracy-cost --scenes pair20x40_healthy_1500rpm"},
           "scenes": {"pair20x40_healthy_1500rpm": {"what": "new", "rows": {}}}}
    out = keep_earlier(new, earlier)
    assert list(out["scenes"]) == ["healthy_250rpm", "pair20x40_healthy_1500rpm"]
    assert out["scenes"]["pair20x40_healthy_1500rpm"]["what"] == "new"
    assert out["meta"]["kept_from_earlier"] == {"healthy_250rpm": "drivetrain accuracy-cost --workers 2"}
    assert "kept as they were: healthy_250rpm (`drivetrain accuracy-cost --workers 2`)" in report_markdown(out, {})
