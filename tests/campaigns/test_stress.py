"""The stress campaign (drivetrain.campaigns.stress, `drivetrain stress`): the seeded scene distribution, the
judging of runs and halving pairs, the class table, and one tiny end-to-end campaign."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from drivetrain.campaigns import stress as S
from drivetrain.cli import main
from drivetrain.scene.load import FIDELITIES, SHAFT_MODELS

N = 200


@pytest.fixture(scope="module")
def draws():
    return S.random_draws(0, N)


def _values(p, key_const, key_prof):
    return [v for _, v in p[key_prof]] if p.get(key_prof) else [p[key_const]]


# ------------------------------------------------------------------------------------------ generator


def test_generator_is_deterministic_per_seed_and_index(draws):
    assert S.random_draws(0, N) == draws
    other = S.random_draws(1, N)
    assert sum(a != b for a, b in zip(draws, other)) > 0.9 * N
    # scene i depends only on (seed, i): a subset or a resumed campaign reproduces it
    assert S.draw_random(0, 137) == draws[137]
    assert S.random_draws(0, 10) == draws[:10]
    assert S.fault_mesh_params(0, 2) == S.fault_mesh_params(0, 2) != S.fault_mesh_params(1, 2)
    # restricting the fidelities leaves the other decisions as drawn
    fast = S.random_draws(0, 30, fidelities=["analytic", "ideal"])
    assert all(p["health"] == "healthy" and p["mesh_contact"] in ("analytic", "ideal") for p in fast)
    for a, b in zip(draws[:30], fast):
        for k in ("comm_step_s", "shaft_flexibility", "load_mode", "speed_mode", "unstable_probe"):
            assert a[k] == b[k], k


def test_distribution_covers_the_required_ranges(draws):
    speeds = [v for p in draws for v in _values(p, "drive_speed_rpm", "speed_profile_rpm")]
    loads = [v for p in draws for v in _values(p, "load_torque_Nm", "load_profile_Nm")]
    assert min(speeds) == 0.0 and 2700.0 < max(speeds) <= S.MAX_SPEED_RPM
    assert S.MAX_LOAD_NM == pytest.approx(2.62)
    assert max(loads) <= S.MAX_LOAD_NM and max(loads) > 2.3
    assert min(loads) < -2.0                                       # reversals
    assert 0.0 in loads and sum(0.0 < abs(v) < S.RATTLE_LOAD_NM for v in loads) >= 5   # rattle
    modes = {p["speed_mode"] for p in draws}
    assert modes == set(S.SPEED_MODES)
    assert sum(1 for p in draws if p.get("speed_profile_rpm") and p["speed_profile_rpm"][0][1] == 0.0) >= 20
    assert sum(1 for p in draws if p.get("speed_profile_rpm")) >= 60               # ramps
    assert {p["load_mode"] for p in draws} == set(S.LOAD_MODES)
    steps = [p for p in draws if p["load_mode"] == "step"]
    assert len(steps) >= 20
    for p in steps:                                                 # a step is two points 1 ms apart
        prof = p["load_profile_Nm"]
        assert any(abs((b[0] - a[0]) - 1e-3) < 1e-9 for a, b in zip(prof, prof[1:]))
    assert sum(1 for p in draws if p.get("load_profile_Nm") and min(_values(p, "load_torque_Nm", "load_profile_Nm")) < 0
               < max(_values(p, "load_torque_Nm", "load_profile_Nm"))) >= 10        # reversal steps
    assert {p["health"] for p in draws} == {"healthy", "mild", "severe", "mesh"}
    assert {p["fault_mesh"] for p in draws if p["health"] == "mesh"} == set(range(S.N_FAULT_MESHES))
    stable = [p for p in draws if not p["unstable_probe"]]
    Hs = sorted({p["comm_step_s"] for p in stable})
    assert Hs == pytest.approx(sorted(1.0 / (3000.0 * k) for k in (1, 2, 4, 8, 16)))
    assert max(Hs) == pytest.approx(1 / 3000) and min(Hs) == pytest.approx(1 / 48000)
    probes = [p for p in draws if p["unstable_probe"]]
    assert 1 <= len(probes) <= 0.1 * N                               # mostly steps the system accepts
    combos = {(p["mesh_contact"], p["shaft_flexibility"]) for p in draws}
    assert combos == {(f, s) for f in FIDELITIES for s in SHAFT_MODELS}
    for p in draws:
        if p["mesh_contact"] in ("ideal", "analytic"):
            assert p["health"] == "healthy"
        if p["mesh_contact"] == "pcm":
            assert p["duration_s"] == S.DEFAULT_DURATION_PCM_S        # online contact only on short scenes
    for flag in ("friction", "contact_damping", "losses"):
        assert {p[flag] for p in draws} == {True, False}
    assert {p["shaft_elements"] for p in draws} == set(S.SHAFT_ELEMENTS)


def test_every_generated_scene_validates(draws, tmp_path):
    # validation checks the mesh files exist; their content is checked in test_fault_meshes
    paths = {}
    for j in range(S.N_FAULT_MESHES):
        paths[j] = tmp_path / f"fault_{j}.obj"
        paths[j].write_text("v 0 0 0\n")
    cases = S.random_cases(draws, paths, halving_subset=10, base_dir=tmp_path)
    names = [c.name for c in cases]
    assert len(names) == len(set(names))
    base = {c.name: c for c in cases if c.set == "random"}
    halves = [c for c in cases if c.set == "halving"]
    assert len(base) == N and len(halves) == sum(1 for p in draws if p["index"] % 10 == 0 and not p["unstable_probe"])
    for c in cases:
        sc, p = c.scene, c.parameters
        assert sc.name == c.name
        assert sc.effects.mesh_contact == p["mesh_contact"] and sc.gear.health == p["health"]
        assert sc.numerics.comm_step_s == pytest.approx(p["comm_step_s"])
        assert sc.time.duration_s == p["duration_s"] and not sc.outputs.plots
        if p["health"] == "mesh":
            assert sc.gear.pinion_mesh == paths[p["fault_mesh"]].resolve()
    for h in halves:
        assert h.scene.numerics.comm_step_s == pytest.approx(0.5 * base[h.pair_of].scene.numerics.comm_step_s)
        assert h.scene.operating_point == base[h.pair_of].scene.operating_point
    reversals = [c.scene.operating_point for c in cases if "load_reversal" in c.classes]
    assert len(reversals) >= 20
    for op in reversals:                       # negative load torques pass the scene schema
        assert min([v for _, v in op.load_profile_Nm] if op.load_profile_Nm else [op.load_torque_Nm]) < 0


def test_classes(draws):
    cls = {c for p in draws for c in S.random_classes(p)}
    assert {"standstill", "speed_ramp", "load_step", "load_reversal", "rattle", "unstable_probe",
            "shafts_flexible", "shafts_rigid", "random_mesh_table", "random_healthy_ideal",
            "H_1/3000", "H_1/48000"} <= cls
    assert S.random_classes(next(p for p in draws if p["unstable_probe"])) == ["unstable_probe"]


def test_fault_meshes(tmp_path):
    from gearcontact_fmu import faults

    p = S.fault_mesh_params(0, 3)
    assert p["missing_tooth"] is not None and p["missing_tooth"] != p["void"]["tooth"]
    paths = S.write_fault_meshes(tmp_path, 0, [3])
    m = faults.user_mesh(paths[3])                        # a valid pinion mesh file in mm
    assert p["missing_tooth"] not in set(m.face_tooth.tolist())
    mtime = paths[3].stat().st_mtime_ns
    assert S.write_fault_meshes(tmp_path, 0, [3]) == paths and paths[3].stat().st_mtime_ns == mtime   # reused


def test_the_random_scenes_on_another_pair(draws, tmp_path):
    """--pair: the same draws (every parameter but the name), the scenes carry the pair's [gear.pair] keys, the
    fault meshes are the pair's pinion (20 teeth), the rig's draws unchanged; the paper grid or an unknown pair is
    refused before any work."""
    from drivetrain.scene.load import scene_from_dict
    from gearcontact_fmu import faults
    from gearcontact_fmu.pair_check import other_pair

    other = S.random_draws(0, 40, pair="20x40_m4")
    for p, q in zip(draws, other):
        assert q["name"] == f"rnd_20x40_m4_s0_{p['index']:04d}" and q["pair"] == "20x40_m4"
        assert {k: v for k, v in q.items() if k not in ("name", "pair")} == {k: v for k, v in p.items() if k != "name"}
    j = next(p["fault_mesh"] for p in other if p["fault_mesh"] is not None)
    paths = S.write_fault_meshes(tmp_path, 0, [j], pair="20x40_m4")
    assert paths[j].name.startswith("fault_20x40_m4_")
    teeth = set(faults.user_mesh(paths[j], other_pair("20x40_m4")).face_tooth.tolist())   # checked on the pair
    assert teeth <= set(range(20)) and len(teeth) >= 19
    mesh_paths = [paths.get(i, paths[j]) for i in range(S.N_FAULT_MESHES)]
    for q in other:
        sc = scene_from_dict(S.random_scene_dict(q, mesh_paths), base_dir=tmp_path)
        assert sc.gear.pair.params() == other_pair("20x40_m4")
    assert "pair" not in draws[0] and S.random_name(0, 3) == "rnd_s0_0003"
    with pytest.raises(ValueError, match="paper grid is the rig's"):
        S.build_cases(set_name="all", n_random=2, out_dir=tmp_path, pair="20x40_m4")
    with pytest.raises(ValueError, match="expected one of"):
        S.build_cases(set_name="random", n_random=2, out_dir=tmp_path, pair="nope")


def test_unstable_probe_is_refused_before_running(draws):
    p = next(p for p in draws if p["unstable_probe"])
    p = dict(p, health="healthy", mesh_contact="analytic", fault_mesh=None)
    cases = S.random_cases([p], None, halving_subset=0)
    S.assemble_cases(cases)
    assert cases[0].spec is None and cases[0].refused
    assert "spectral radius" in S.short_refusal(cases[0].refused)
    v = S.judge_run(None, refused=cases[0].refused)
    assert v["outcome"] == "refused"


# ------------------------------------------------------------------------------------------ judging


def _summary(**kw):
    s = {"status": "ok", "nonfinite_channels": [], "energy_residual": 1e-4, "sim_time_s": 1.0, "wall_time_s": 2.0,
         "torque": {"drive_shaft_torque": {"mean": 1.85, "rms": 1.9}, "propeller_shaft_torque": {"mean": 14.75, "rms": 15.0}},
         "stability": {"max_penetration_rel_umax": 0.02, "min_substep_s": 6e-8, "n_refinements": 12,
                       "rattle": {"separated_time_s": 0.0, "separated_fraction": 0.0, "n_separations": 0}}}
    s.update(kw)
    return s


def test_judge_run_classifies_synthetic_summaries():
    good = S.judge_run(_summary())
    assert good["outcome"] == "pass" and not good["reasons"] and not good["not_reported"]
    assert good["figures"]["max_penetration_rel_umax"] == 0.02 and good["figures"]["min_substep_s"] == 6e-8

    failed = S.judge_run(_summary(status="failed", energy_residual=None,
                                  failure={"time_s": 0.3125, "component": "gear", "cause": "penetration beyond u_max"}))
    assert failed["outcome"] == "fail"
    assert "penetration beyond u_max" in failed["reasons"][0] and "gear" in failed["reasons"][0]
    assert "0.3125" in failed["reasons"][0]

    nonfinite = S.judge_run(_summary(nonfinite_channels=["drive_shaft_torque"]))
    assert nonfinite["outcome"] == "fail" and "drive_shaft_torque" in nonfinite["reasons"][0]

    energy = S.judge_run(_summary(energy_residual=0.015))
    assert energy["outcome"] == "fail" and "energy residual 1.5 %" in energy["reasons"][0]
    assert S.judge_run(_summary(energy_residual=float("nan")))["outcome"] == "fail"

    deep = _summary()
    deep["stability"] = dict(deep["stability"], max_penetration_rel_umax=1.2)
    assert S.judge_run(deep)["outcome"] == "fail"
    deep["stability"]["max_penetration_rel_umax"] = 0.3
    v = S.judge_run(deep)
    assert v["outcome"] == "pass" and v["flags"] and "suspicious" in v["flags"][0]

    # summaries from before the status/stability blocks: not reported, not failed
    old = _summary()
    del old["status"], old["stability"]
    v = S.judge_run(old, {"status": "ok"})
    assert v["outcome"] == "pass" and {"status", "stability"} <= set(v["not_reported"])
    # ... and the stability block may come from the manifest record instead
    v = S.judge_run(old, {"status": "ok", "stability": _summary()["stability"]})
    assert "stability" not in v["not_reported"] and v["figures"]["n_refinements"] == 12
    assert S.judge_run(old, {"status": "ok"}, expected_duration_s=2.0)["outcome"] == "fail"   # stopped early

    # no summary at all
    assert S.judge_run(None, {"status": "failed", "error": "CosimError: boom"})["outcome"] == "fail"
    refusal = "ConfigurationError: system refused before any step:\n  - cut a.x -> b.y: spectral radius = 1.2 (UNSTABLE)"
    assert S.judge_run(None, {"status": "failed", "error": refusal})["outcome"] == "refused"


def test_judge_halving():
    a, b = _summary(), _summary()
    ok = S.judge_run(a)
    assert S.judge_halving(ok, ok, a, b)["outcome"] == "pass"
    c = _summary(torque={"drive_shaft_torque": {"mean": 1.85 * 1.003, "rms": 1.9 * 1.015},
                         "propeller_shaft_torque": {"mean": 14.75, "rms": 15.0}})
    v = S.judge_halving(ok, ok, c, b)
    assert v["outcome"] == "pass" and v["max_mean_dev"] == pytest.approx(0.003) and v["max_rms_dev"] == pytest.approx(0.015)
    outside = _summary(torque={"drive_shaft_torque": {"mean": 1.85 * 1.01, "rms": 1.9},
                               "propeller_shaft_torque": {"mean": 14.75, "rms": 15.0 * 1.03}})
    v = S.judge_halving(ok, ok, outside, b)
    assert v["outcome"] == "fail" and len(v["reasons"]) == 2
    assert "drive_shaft_torque: mean" in v["reasons"][0] and "propeller_shaft_torque: RMS" in v["reasons"][1]
    # a drivetrain at rest without load: exactly zero torques agree
    zero = _summary(torque={n: {"mean": 0.0, "rms": 0.0} for n in S.HALVING_SENSORS})
    assert S.judge_halving(ok, ok, zero, zero)["outcome"] == "pass"
    bad = S.judge_run(_summary(status="failed"))
    assert S.judge_halving(ok, bad, a, b)["outcome"] == "fail"


def test_held_standstill_is_compared_over_its_moving_part():
    """A draw that holds its drive at standstill under friction or losses: the held torque is indeterminate within
    the friction band (the creep speed decides it, and the creep follows the step), so a halving pair compares the
    part before the standstill when the whole runs differ beyond the limits; held from the start, it is then not
    comparable: never a pass, never a failure. A pair within the limits whole passes as every pair does."""
    stop = {"friction": True, "losses": False, "speed_mode": "ramp_to_stop",
            "speed_profile_rpm": [[0.0, 900.0], [0.2, 900.0], [0.729, 0.0]], "duration_s": 1.5}
    assert S.held_standstill_from_s(stop) == pytest.approx(0.729)
    assert S.held_standstill_from_s({**stop, "friction": False}) is None              # frictionless: determinate
    assert S.held_standstill_from_s({**stop, "speed_profile_rpm": [[0.0, 0.0], [0.5, 900.0]]}) is None
    assert S.held_standstill_from_s({"losses": True, "speed_mode": "hold_zero", "drive_speed_rpm": 0.0}) == 0.0

    ok = S.judge_run(_summary())
    whole_a = _summary(torque={"drive_shaft_torque": {"mean": 1.0, "rms": 1.0},
                               "propeller_shaft_torque": {"mean": 4.0, "rms": 4.0}})
    whole_b = _summary(torque={"drive_shaft_torque": {"mean": 1.05, "rms": 1.0},
                               "propeller_shaft_torque": {"mean": 4.0, "rms": 4.0}})
    assert S.judge_halving(ok, ok, whole_a, whole_b)["outcome"] == "fail"     # the whole run: 5 % apart
    same = {"drive_shaft_torque": {"mean": 1.0, "rms": 1.0}, "propeller_shaft_torque": {"mean": 4.0, "rms": 4.0}}
    held = {"window_s": [0.3, 0.729], "moving": (same, same),
            "held": ({"drive_shaft_torque": {"mean": 0.9}}, {"drive_shaft_torque": {"mean": 1.1}})}
    v = S.judge_halving(ok, ok, whole_a, whole_b, held)
    assert v["outcome"] == "pass" and v["window_s"] == [0.3, 0.729]
    assert v["held_means"]["drive_shaft_torque"] == [0.9, 1.1]
    off = {"drive_shaft_torque": {"mean": 1.02, "rms": 1.0}, "propeller_shaft_torque": {"mean": 4.0, "rms": 4.0}}
    v = S.judge_halving(ok, ok, whole_a, whole_b, {**held, "moving": (off, same)})
    assert v["outcome"] == "fail" and v["reasons"][0].startswith("over the moving part 0.3 <= t < 0.729 s")
    v = S.judge_halving(ok, ok, whole_a, whole_b, {**held, "window_s": [0.3, 0.3], "moving": None})
    assert v["outcome"] == "not_comparable" and "indeterminate within the friction band" in v["reasons"][0]
    assert "whole runs differ beyond the limits" in v["reasons"][0]
    md = S.report_markdown({"runs": [], "pairs": [{"base": "x", "half": "x_halfH", **v}], "table": []})
    assert "not comparable" in md and "`x` / `x_halfH` | not_comparable" in md
    # judged whole first, as every pair: whole runs within the limits pass, held from the start or not
    w = S.judge_halving(ok, ok, whole_a, whole_a, {**held, "window_s": [0.3, 0.3], "moving": None})
    assert w["outcome"] == "pass" and w["compared"] == "whole run" and w["max_mean_dev"] == 0.0
    assert w["held_means"]["drive_shaft_torque"] == [0.9, 1.1]
    md = S.report_markdown({"runs": [], "pairs": [{"base": "y", "half": "y_halfH", **w}], "table": []})
    assert "`y` / `y_halfH` | pass | whole run |" in md
    # ... and a pair beyond them whole is not excused by a moving part that is itself beyond them
    assert S.judge_halving(ok, ok, whole_a, whole_b, {**held, "moving": (off, same)})["compared"] == "moving part"


def test_class_table_and_report():
    runs = [
        {"name": "a", "classes": ["paper_healthy"], "outcome": "pass", "reasons": [], "flags": [], "not_reported": [],
         "figures": {"max_penetration_rel_umax": 0.01, "min_substep_s": 1e-7, "energy_residual": 1e-4}},
        {"name": "b", "classes": ["paper_healthy"], "outcome": "fail", "reasons": ["energy residual 2 % >= 1 %"],
         "flags": [], "not_reported": [], "figures": {"max_penetration_rel_umax": 0.05, "energy_residual": 0.02}},
        {"name": "c", "classes": ["unstable_probe"], "outcome": "refused", "reasons": ["predicted unstable"],
         "flags": [], "not_reported": [], "figures": {}, "parameters": {"comm_step_s": 1e-3}},
        {"name": "d", "classes": ["rattle"], "outcome": "pass", "reasons": [], "flags": [],
         "not_reported": ["stability"], "figures": {"energy_residual": 3e-3}},
    ]
    pairs = [{"base": "a", "half": "a_halfH", "outcome": "fail", "reasons": ["drive_shaft_torque: mean differs"],
              "max_mean_dev": 0.01, "max_rms_dev": 0.001}]
    rows = {r["class"]: r for r in S.class_table(runs, pairs)}
    assert (rows["paper_healthy"]["runs"], rows["paper_healthy"]["pass"], rows["paper_healthy"]["fail"]) == (2, 1, 1)
    assert rows["paper_healthy"]["max_penetration_rel_umax"] == 0.05 and rows["paper_healthy"]["min_substep_s"] == 1e-7
    assert rows["paper_healthy"]["max_energy_residual"] == 0.02 and rows["paper_healthy"]["max_halving_mean_dev"] == 0.01
    assert rows["unstable_probe"]["refused"] == 1 and rows["unstable_probe"]["fail"] == 0
    assert rows["rattle"]["max_penetration_rel_umax"] is None and rows["rattle"]["n_not_reported_stability"] == 1
    assert (rows["halving_pairs"]["runs"], rows["halving_pairs"]["fail"]) == (1, 1)
    assert (rows["all runs"]["runs"], rows["all runs"]["pass"], rows["all runs"]["fail"], rows["all runs"]["refused"]) == (4, 2, 1, 1)
    md = S.report_markdown({"command": "drivetrain stress --seed 3", "wall_time_s": 12.0, "runs_wall_time_s": 20.0,
                            "seed": 3, "runs": runs, "pairs": pairs, "table": S.class_table(runs, pairs)})
    assert "`drivetrain stress --seed 3`" in md and "| class | runs | pass | fail | refused |" in md
    assert "| paper_healthy | 2 | 1 | 1 | 0 | 0.05 |" in md
    assert "`b` (paper_healthy): energy residual 2 % >= 1 %" in md
    assert "halving pair `a` / `a_halfH`" in md and "n/r" in md


# ------------------------------------------------------------------------------------------ end to end


def test_drivetrain_stress_end_to_end(tmp_path, fmu_dir):
    """`drivetrain stress` on two short random scenes (fast fidelities, no paper scenes) and one halving
    pair, with a private FMU directory; then the report regenerated from the run directories."""
    out = tmp_path / "stress"
    rc = main(["stress", "--set-name", "random", "--n-random", "2", "--seed", "0", "--fidelities", "analytic,ideal",
               "--duration-random", "0.2", "--halving-subset", "2", "--out", str(out), "--workers", "2",
               "--fmu-dir", str(fmu_dir), "--quiet"])
    rec = json.loads((out / "stress.json").read_text())
    assert rc == (0 if rec["n_fail"] == 0 else 3)
    names = [r["name"] for r in rec["runs"]]
    # a pair outside the limits with both runs passing is refined (issue 45): rnd_s0_0000_H4 (and _H8) follow
    assert names[:3] == ["rnd_s0_0000", "rnd_s0_0000_halfH", "rnd_s0_0001"]
    assert all(n in ("rnd_s0_0000_H4", "rnd_s0_0000_H8") for n in names[3:]), names
    assert not any(n.startswith("paper_") for n in names)
    for r in rec["runs"]:
        assert r["outcome"] in ("pass", "fail", "refused")
        if r["outcome"] != "refused":
            assert (out / r["name"] / "summary.json").is_file()
            assert not any(x.startswith("did not complete") for x in r["reasons"]), r   # the machinery works
            assert math.isfinite(r["figures"]["energy_residual"])
    assert len(rec["pairs"]) == len(names) - 2 and rec["pairs"][0]["base"] == "rnd_s0_0000"
    outcomes = [p["outcome"] for p in rec["pairs"]]
    if "refined" in outcomes:                 # never a silent pass: the coarse step refused, a converged one named
        assert outcomes[-1] == "pass" and rec["pairs"][-1]["converged_step_s"] > 0
        assert all("step refused by the halving rule" in p["reasons"][0] for p in rec["pairs"] if p["outcome"] == "refined")
    md = (out / "stress.md").read_text()
    assert "| class | runs | pass | fail | refused |" in md and f"| all runs | {len(names)} |" in md
    assert "drivetrain stress --set-name random --n-random 2" in md
    assert (out / "manifest.json").is_file()
    # the report again from the run directories (nothing rerun)
    before = rec["table"]
    assert main(["stress", "--out", str(out), "--report-only", "--quiet"]) in (0, 3)
    assert json.loads((out / "stress.json").read_text())["table"] == before
