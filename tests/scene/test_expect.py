"""Scenes as regression tests: [expect] parsing and evaluation, `drivetrain check` / `baseline`, the
pytest plugin. Runs are tiny (0.3 s, analytic mesh, rigid shafts, in-process backend) in a private FMU
directory."""
import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest

from drivetrain.scene import expect as X
from drivetrain.cli import main
from drivetrain.scene.load import ScenarioError, load_scene, load_scenes, with_overrides

ROOT = Path(__file__).resolve().parents[2]

TINY = """\
[scenario]
name = "{name}"
[operating_point]
drive_speed_rpm = 1500.0
load_torque_Nm = {load}
[time]
duration_s = 0.3
settle_s = 0.1
[outputs]
sensors = ["drive_shaft_torque", "propeller_shaft_torque"]
plots = false
[effects]
mesh_contact = "analytic"
shaft_flexibility = "rigid"
"""


def tiny(tmp_path, expect: str = "", name: str = "tiny", load: float = 1.31, extra: str = "") -> Path:
    p = tmp_path / f"{name}.toml"
    p.write_text(TINY.format(name=name, load=load) + extra + ("\n[expect]\n" + textwrap.dedent(expect) if expect else ""))
    return p


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory, fmu_dir):
    """One tiny run (scene, CaseRun) reused by the evaluation tests."""
    from drivetrain.campaigns.check import run_case

    d = tmp_path_factory.mktemp("tinyrun")
    scene = load_scene(tiny(d))
    run = run_case(scene, None, fmu_dir=fmu_dir, backend="inprocess")
    assert run.summary is not None and run.summary["status"] == "ok", run.error
    return scene, run


def _cli(args, fmu_dir, out):
    return main([*args, "--fmu-dir", str(fmu_dir), "--backend", "inprocess", "--quiet",
                 *(["--out", str(out)] if args[0] == "check" else [])])


# --------------------------------------------------------------------------------------------------
# Parsing and validation
# --------------------------------------------------------------------------------------------------


def test_the_expect_syntax_of_every_kind_is_accepted(tmp_path):
    scene = load_scene(tiny(tmp_path, """\
        "torque.propeller_shaft_torque.mean" = { value = 15.03, rel = 0.01 }
        "energy_residual" = { max = 1e-3 }
        "status" = "ok"
        "stability.rattle.separated" = false
        "stability.max_penetration_rel_umax" = { min = 0.0, max = 1.0 }
        "spectrum_peaks.propeller_shaft_torque.sidebands.0.lower_dB_re_GMF" = { max = 0.0 }
        "signal.propeller_shaft_torque[0.2:0.3].p2p" = { value = 0.1, abs = 0.1 }
        "spectrum.propeller_shaft_torque@f_GMF-f_MSH.dB_re_GMF" = { max = 10.0 }
        "spectrum.drive_shaft_torque[0.1:]@2*f_GMF+3*f_MSH.dB" = { max = 100.0 }
        "torque.drive_shaft_torque.mean" = { measured = "T_DSH_Nm", rel = 0.05 }
        """, extra="[check]\nslow = true\nbaseline_rel = 0.01\n"))
    items = {e.key: e for e in scene.expect.items}
    assert len(items) == 10
    e = items["torque.propeller_shaft_torque.mean"]
    assert (e.kind, e.path, e.value, e.rel, e.tolerance()) == ("summary", ("torque", "propeller_shaft_torque", "mean"),
                                                               15.03, 0.01, pytest.approx(0.1503))
    assert items["spectrum_peaks.propeller_shaft_torque.sidebands.0.lower_dB_re_GMF"].path[3] == 0
    e = items["signal.propeller_shaft_torque[0.2:0.3].p2p"]
    assert (e.kind, e.channel, e.stat, e.window) == ("signal", "propeller_shaft_torque", "p2p", (0.2, 0.3))
    e = items["spectrum.drive_shaft_torque[0.1:]@2*f_GMF+3*f_MSH.dB"]
    assert (e.channel, e.freq, e.level, e.window) == ("drive_shaft_torque", "2*f_GMF+3*f_MSH", "dB", (0.1, None))
    assert items["torque.drive_shaft_torque.mean"].value == 1.85          # the rig at 1500 rpm, 1.31 N·m
    assert scene.expect.options.slow is True and scene.expect.options.baseline_rel == 0.01
    assert X.is_slow(scene)
    assert X.frequency_value("f_GMF-2*f_MSH", {"f_GMF": 125.0, "f_MSH": 25 / 3}) == pytest.approx(125 - 50 / 3)
    # --set keeps the expectations; what depends on the scene is then left to the check (no refusal)
    s2 = with_overrides(scene, ["time.duration_s=0.15", "operating_point.load_torque_Nm=0.5"])
    items2 = {e.key: e for e in s2.expect.items}
    assert len(items2) == 10 and np.isnan(items2["torque.drive_shaft_torque.mean"].value)
    assert load_scene(tiny(tmp_path, '"status" = "ok"'), ["time.duration_s=0.2"]).expect.items[0].value == "ok"


def test_bad_expectations_refused_together_with_the_key_named(tmp_path):
    p = tiny(tmp_path, """\
        "torque.propeller_shaft_torq.mean" = { value = 15.03, rel = 0.01 }
        "energy_residul" = { max = 1e-3 }
        "torque.drive_shaft_torque.mean" = { value = 1.9 }
        "torque.drive_shaft_torque.rms" = { value = 1.9, tol = 0.1 }
        "torque.drive_shaft_torque.std" = { min = 2.0, max = 1.0 }
        "torque.drive_shaft_torque.min" = { value = 1.9, rel = -0.1 }
        "torque.drive_shaft_torque.max" = 2.0
        "status" = { value = "ok", rel = 0.1 }
        "signal.enc9.mean" = { max = 1.0 }
        "signal.propeller_shaft_torque.median" = { max = 1.0 }
        "signal.propeller_shaft_torque[0.2:0.9].mean" = { max = 1.0 }
        "spectrum.propeller_shaft_torque@f_GFM" = { max = 1.0 }
        "spectrum.propeller_shaft_torque@100*f_GMF" = { max = 1.0 }
        "stability" = { max = 1.0 }
        "torque.propeller_shaft_torque.mean" = { measured = "T_XSH_Nm", rel = 0.05 }
        """, extra="[check]\nslo = true\n")
    with pytest.raises(ScenarioError) as ei:
        load_scene(p)
    keys = [k for k, _, _ in ei.value.problems]
    msg = str(ei.value)
    assert len(keys) == 16, msg
    assert "check.slo" in keys and "did you mean 'slow'" in msg
    for k in ("torque.propeller_shaft_torq.mean", "energy_residul", "torque.drive_shaft_torque.mean",
              "torque.drive_shaft_torque.rms", "torque.drive_shaft_torque.std", "torque.drive_shaft_torque.min",
              "torque.drive_shaft_torque.max", "status", "signal.enc9.mean", "signal.propeller_shaft_torque.median",
              "signal.propeller_shaft_torque[0.2:0.9].mean", "spectrum.propeller_shaft_torque@f_GFM",
              "spectrum.propeller_shaft_torque@100*f_GMF", "stability", "torque.propeller_shaft_torque.mean"):
        assert f'expect."{k}"' in keys, k
    assert "did you mean 'propeller_shaft_torque'" in msg and "did you mean 'energy_residual'" in msg
    assert "a tolerance with the value" in msg and "unknown: tol" in msg and "min <= max" in msg
    assert "Nyquist" in msg and "unknown frequency 'f_GFM'" in msg and "time.duration_s = 0.3 s" in msg
    # a grid's per-case tables must match a case
    g = tmp_path / "g.toml"
    g.write_text(TINY.format(name="g", load=1.31) + '[sweep.axes]\n"operating_point.load_torque_Nm" = [0.71, 1.31]\n'
                 '[sweep.expect."g_*_typo"]\n"status" = "ok"\n')
    with pytest.raises(ScenarioError, match="matches at least one case"):
        load_scenes(g)


def test_summary_tree_covers_every_summary_value(tiny_run):
    """Every value of a real summary.json is a valid metric path (the schema follows run.py)."""
    scene, run = tiny_run

    def leaves(d, prefix=()):
        if isinstance(d, dict):
            for k, v in d.items():
                yield from leaves(v, prefix + (str(k),))
        elif isinstance(d, list):
            for i, v in enumerate(d):
                yield from leaves(v, prefix + (str(i),))
        else:
            yield prefix

    n = 0
    for path in leaves(run.summary):
        X.parse_key(".".join(path))
        n += 1
    assert n > 100
    # and the other way round: the declaration holds no key the summary lacks (written: + files, write time)
    assert X.summary_mismatch(run.summary, X.RUN_SUMMARY_TREE) == []


def test_summary_mismatch_names_what_differs():
    """The check of a summary against its declaration: missing and undeclared keys, at any depth; named
    keys (torque sensors, channels) and list items against their template; None and "any" fit anything."""
    tree = {"a": "num", "b": {"c": "int", "d": "any"}, "t": {"<torque>": {"mean": "num"}}, "l": {"<i>": "num"},
            "o": {"x": "num"}}
    ok = {"a": 1.0, "b": {"c": 2, "d": {"whatever": [1]}}, "t": {"drive_shaft_torque": {"mean": 1.0}},
          "l": [1.0, 2.0], "o": None}
    assert X.summary_mismatch(ok, tree) == []
    bad = {"a": {"x": 1}, "b": {"e": 1, "d": 0}, "t": {"drive_shaft_torque": {"rms": 1.0}}, "l": {"0": 1},
           "o": {"x": 1.0}, "z": 0}
    assert sorted(X.summary_mismatch(bad, tree)) == sorted([
        "a: a dict where a num is declared", "b: no 'c'", "b: 'e' is not declared",
        "t.drive_shaft_torque: no 'mean'", "t.drive_shaft_torque: 'rms' is not declared",
        "l: a dict where a list is declared", "summary.json: 'z' is not declared"])
    assert set(X.SUMMARY_TREE) == set(X.RUN_SUMMARY_TREE) | set(X.WRITE_SUMMARY_TREE)


# --------------------------------------------------------------------------------------------------
# Evaluation
# --------------------------------------------------------------------------------------------------


def test_evaluate_holds_and_off_by_5_percent_fails(tiny_run, tmp_path):
    from drivetrain.campaigns.check import check_run

    scene, run = tiny_run
    mean = run.summary["torque"]["propeller_shaft_torque"]["mean"]
    sig = run.signals["propeller_shaft_torque"][run.time >= 0.2]
    ok_scene = load_scene(tiny(tmp_path, f"""\
        "torque.propeller_shaft_torque.mean" = {{ value = {mean!r}, rel = 0.01 }}
        "signal.propeller_shaft_torque[0.2:].p2p" = {{ value = {float(np.ptp(sig))!r}, rel = 1e-9 }}
        "energy_residual" = {{ max = 1e-3 }}
        "status" = "ok"
        """))
    cc = check_run(run.__class__(ok_scene, run.summary, run.time, run.signals, run.units))
    assert cc.ok and cc.n_checks == 4, cc.report()
    off = 1.05 * mean
    bad_scene = load_scene(tiny(tmp_path, f'"torque.propeller_shaft_torque.mean" = {{ value = {off!r}, rel = 0.01 }}\n'))
    cc = check_run(run.__class__(bad_scene, run.summary, run.time, run.signals, run.units), plot_dir=tmp_path / "p")
    assert not cc.ok and len(cc.failures) == 1
    m = cc.failures[0].message
    assert "torque.propeller_shaft_torque.mean" in m
    assert f"expected {off:.6g}" in m and f"actual {mean:.6g}" in m and f"±{0.01 * off:.6g}" in m and "rel 0.01" in m
    assert re.search(r"-4\.76? %", m), m
    assert cc.plots and Path(cc.plots[0]).is_file()
    # a failed run fails the implicit status check (unless [expect] says something about status)
    failed = dict(run.summary, status="failed", failure={"time_s": 0.1, "component": "gear", "cause": "boom"})
    out = X.evaluate(ok_scene.expect, {k: v for k, v in failed.items()}, run.time, run.signals)
    assert [o.key for o in out if not o.ok] == ["status"]
    out = X.evaluate(X.parse_checks({}, None, {}, ".", []), failed)
    assert [o.key for o in out if not o.ok] == ["status"] and "boom" in out[0].message


# --------------------------------------------------------------------------------------------------
# drivetrain check / baseline
# --------------------------------------------------------------------------------------------------


def test_cli_check_exit_codes_and_table(tmp_path, fmu_dir, capsys):
    good = tiny(tmp_path, """\
        "torque.propeller_shaft_torque.mean" = { value = 15.03, rel = 0.01 }
        "energy_residual" = { max = 1e-3 }
        """, name="good")
    assert _cli(["check", str(good)], fmu_dir, tmp_path / "out") == 0
    assert "good: ok: 2/2 checks hold" in capsys.readouterr().out
    bad = tiny(tmp_path, '"torque.propeller_shaft_torque.mean" = { value = 15.78, rel = 0.01 }\n', name="bad")
    assert _cli(["check", str(bad)], fmu_dir, tmp_path / "out") == 1
    out = capsys.readouterr().out
    row = [ln for ln in out.splitlines() if ln.startswith("FAIL")][0]
    assert "torque.propeller_shaft_torque.mean" in row and "15.78" in row and "15.02" in row and "rel 0.01" in row
    assert (tmp_path / "out" / "bad" / "check_bad.png").is_file()
    refused = tiny(tmp_path, '"torque.nothing.mean" = { max = 1.0 }\n', name="refused")
    assert _cli(["check", str(refused)], fmu_dir, tmp_path / "out") == 2
    assert 'expect."torque.nothing.mean"' in capsys.readouterr().err


def test_baseline_then_changed_parameter_moves(tmp_path, fmu_dir, capsys):
    from drivetrain.campaigns.baseline import read_baseline

    scene = tiny(tmp_path, name="base")                       # no [expect]: the baseline alone
    assert _cli(["baseline", str(scene)], fmu_dir, None) == 0
    bfile = tmp_path / "base.baseline.h5"
    assert bfile.is_file() and "base.baseline.h5" in capsys.readouterr().out
    b = read_baseline(bfile)
    e = b["cases"]["base"]
    assert e.metrics["torque.propeller_shaft_torque.mean"] == pytest.approx(15.03, rel=0.01)
    assert set(e.signals) == {"drive_shaft_torque", "propeller_shaft_torque"} and len(e.time) > 100
    assert "f_GMF" in e.spectra["propeller_shaft_torque"] and "f_GMF-f_MSH" in e.spectra["propeller_shaft_torque"]
    assert e.scene["scene"]["operating_point"]["load_torque_Nm"] == 1.31 and b["versions"]["numpy"]
    # unchanged: every metric, signal and spectral level holds
    rep = tmp_path / "rep.json"
    assert _cli(["check", str(scene), "--json", str(rep)], fmu_dir, tmp_path / "o1") == 0
    r = json.loads(rep.read_text())
    assert r["ok"] and sum(o["source"] == "baseline" for o in r["cases"][0]["outcomes"]) > 20
    capsys.readouterr()
    # a changed parameter: the load-motor torque 1.31 -> 1.25 N·m moves the mean torques
    assert _cli(["check", str(scene), "--set", "operating_point.load_torque_Nm=1.25"], fmu_dir, tmp_path / "o2") == 1
    out = capsys.readouterr().out
    moved = {ln.split()[2] for ln in out.splitlines() if ln.startswith("FAIL")}
    assert {"torque.propeller_shaft_torque.mean", "torque.drive_shaft_torque.mean",
            "signal.propeller_shaft_torque"} <= moved, out
    assert "operating_point.load_torque_Nm: 1.31 -> 1.25" in out
    assert (tmp_path / "o2" / "base" / "check_base.png").is_file()


def test_check_grid_through_the_sweep(tmp_path, fmu_dir, capsys):
    g = tmp_path / "grid.toml"
    g.write_text(TINY.format(name="grid", load=1.31) + textwrap.dedent("""\
        [sweep]
        name = "grid_{operating_point.load_torque_Nm:g}Nm"
        [sweep.axes]
        "operating_point.load_torque_Nm" = [0.71, 1.31]
        [sweep.expect."grid_1.31Nm"]
        "torque.propeller_shaft_torque.mean" = { value = 15.03, rel = 0.01 }
        [expect]
        "status" = "ok"
        "torque.drive_shaft_torque.mean" = { measured = "T_DSH_Nm", rel = 0.05 }
        """))
    scenes = load_scenes(g)
    assert [len(s.expect.items) for s in scenes] == [2, 3]
    assert _cli(["check", str(g), "--workers", "2", "--all"], fmu_dir, tmp_path / "out") == 0
    out = capsys.readouterr().out
    assert "grid_0.71Nm: ok: 2/2" in out and "grid_1.31Nm: ok: 3/3" in out, out
    assert (tmp_path / "out" / "manifest.json").is_file()      # the sweep ran the cases


# --------------------------------------------------------------------------------------------------
# pytest plugin
# --------------------------------------------------------------------------------------------------


def test_pytest_plugin_collects_scenes_and_writes_junit(tmp_path, fmu_dir):
    d = tmp_path / "scenes"
    d.mkdir()
    tiny(d, '"torque.propeller_shaft_torque.mean" = { value = 15.03, rel = 0.01 }\n', name="holds")
    tiny(d, '"torque.propeller_shaft_torque.mean" = { value = 15.78, rel = 0.01 }\n', name="moved")
    tiny(d, '"status" = "ok"\n', name="long", extra="[check]\nslow = true\n")
    tiny(d, name="nothing")                                   # no [expect], no baseline: not collected
    (d / "pyproject.toml").write_text("[tool.other]\nx = 1\n")
    report = tmp_path / "report.xml"
    r = subprocess.run([sys.executable, "-m", "pytest", str(d), "-m", "not slow", "-p", "no:cacheprovider",
                        "--rootdir", str(d), f"--junitxml={report}", "--drivetrain-fmu-dir", str(fmu_dir),
                        "--drivetrain-backend", "inprocess", "--drivetrain-out", str(tmp_path / "plots")],
                       cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "1 failed, 1 passed, 1 deselected" in r.stdout, r.stdout
    assert "expected 15.78, actual 15.02" in r.stdout
    cases = {tc.get("name"): tc for tc in ET.parse(report).getroot().iter("testcase")}
    assert set(cases) == {"holds", "moved"}
    assert cases["moved"].find("failure") is not None and cases["holds"].find("failure") is None
    props = {p.get("name"): p.get("value") for p in cases["moved"].iter("property")}
    assert props["failed_checks"] == "1" and "torque.propeller_shaft_torque.mean" in props["failed:torque.propeller_shaft_torque.mean"]
    assert (tmp_path / "plots" / "moved" / "check_moved.png").is_file()


def test_shipped_scenes_carry_expectations():
    """Every shipped scene has [expect] (validated here) and the long ones are marked slow; the
    default test run (testpaths = tests) does not collect them."""
    files = [ROOT / "scenarios" / "example.toml", *sorted((ROOT / "scenarios" / "hard").glob("*.toml")),
             ROOT / "scenarios" / "paper" / "paper.toml"]
    slow = {}
    for f in files:
        for s in load_scenes(f):
            keys = {e.key for e in s.expect.items}
            assert {"status", "energy_residual", "stability.max_penetration_rel_umax"} <= keys, s.name
            slow[s.name] = X.is_slow(s)
    assert len(slow) == 5 + 54 and not slow["hard_startup_ramp"] and slow["example"] and slow["paper_severe_1500rpm_1.31Nm"]
    import tomllib

    assert tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["testpaths"] == ["tests"]
