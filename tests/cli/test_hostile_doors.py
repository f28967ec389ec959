"""The third hostile battery: the doors built since the second one. Every file the project reads
is refused with its name, the field and what was wrong, never a traceback; nothing is labelled better than
it is. Each case here failed on 812c552 (a traceback, or exit 0 with a result that claimed too much)."""
from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from _cosim_test_fmus import build_test_fmus
from drivetrain.cli import main
from drivetrain.scene.load import load_scene
from _cosim_test_fmus import toy_spec
from _shared import EXAMPLE

ROOT = Path(__file__).resolve().parents[2]


def cli(argv) -> tuple[int, str]:
    """(exit code, all it printed); an exception escaping main fails the test (a traceback for the user)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        try:
            rc = main([str(a) for a in argv])
        except SystemExit as exc:
            rc = exc.code if isinstance(exc.code, int) else 2
    return int(rc or 0), buf.getvalue()


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """Two 0.2 s runs of the toy system: a healthy one and its faulty twin (one noise record)."""
    from drivetrain.campaigns.sweep import run_sweep

    fmus = build_test_fmus(tmp_path_factory.mktemp("mtfmus_h3"))
    out = tmp_path_factory.mktemp("h3") / "sw"
    scenes = [load_scene(EXAMPLE, ["time.duration_s=0.2", f"scenario.name=toy{i}", "outputs.plots=false",
                                   f"gear.health={h}", f"operating_point.load_torque_Nm={v}",
                                   "scenario.noise_name=pair0"])
              for i, (h, v) in enumerate((("healthy", 0.12), ("severe", 1.31)))]
    run_sweep(scenes, out, workers=1, specs={s.name: toy_spec() for s in scenes}, fmu_paths=fmus, progress=False)
    return out


@pytest.fixture
def copy(sweep, tmp_path):
    d = tmp_path / "sw"
    shutil.copytree(sweep, d)
    return d


def _rewrite(sig: Path, fn) -> None:
    """Rewrite every array of a signals file through ``fn(name, array)``."""
    with h5py.File(sig, "a") as f:
        for key in ["time", *[f"signals/{k}" for k in f["signals"]]]:
            x = fn(key, f[key][()])
            attrs = dict(f[key].attrs)
            del f[key]
            f[key] = x
            f[key].attrs.update(attrs)


def _refused(d: Path, *words: str) -> None:
    for argv in (["dataset", d, "--out", d / "x.parquet"], ["features", d]):
        rc, text = cli(argv)
        assert rc == 2 and "Traceback" not in text, (argv[0], rc, text[-2000:])
        for w in words:
            assert w in text, (argv[0], w, text)


def test_a_channel_shorter_than_time(copy):
    _rewrite(copy / "toy0" / "signals.h5", lambda k, x: x[:10] if k.endswith("drive_shaft_torque") else x)
    _refused(copy, "toy0/signals.h5", "drive_shaft_torque", "10 samples")


def test_a_paired_healthy_twin_of_another_length(copy):
    _rewrite(copy / "toy0" / "signals.h5", lambda k, x: x[:500])      # the healthy twin, consistent in itself
    _refused(copy, "toy1", "healthy twin toy0", "500")


def test_a_stored_summary_that_is_not_json(copy):
    with h5py.File(copy / "toy0" / "signals.h5", "a") as f:
        f.attrs["summary_json"] = "{not json"
    _refused(copy, "toy0/signals.h5", "summary_json", "not JSON")


def test_a_manifest_whose_runs_is_a_number(copy):
    m = json.loads((copy / "manifest.json").read_text())
    m["runs"] = 5
    (copy / "manifest.json").write_text(json.dumps(m))
    (copy / "manifest.jsonl").unlink()
    _refused(copy, "manifest.json", "'runs'", "expected a list")


def test_a_manifest_record_of_the_wrong_shape(copy):
    m = json.loads((copy / "manifest.json").read_text())
    m["runs"][1] = {"name": ["toy1"]}
    (copy / "manifest.json").write_text(json.dumps(m))
    (copy / "manifest.jsonl").unlink()
    _refused(copy, "manifest.json", "runs[1]", "'name'")


def test_non_finite_samples_are_exported_as_failed_with_their_count(copy, tmp_path):
    import pandas as pd
    import pyarrow.parquet as pq

    def nan83(key, x):
        if key.endswith("propeller_shaft_torque"):
            x = x.copy()
            x[: int(0.83 * x.size)] = np.nan
        return x
    _rewrite(copy / "toy1" / "signals.h5", nan83)
    rc, text = cli(["dataset", copy, "--out", tmp_path / "d.parquet"])
    assert rc == 0 and "toy1" in text and "not finite" in text and "82.9 %" in text
    df = pd.read_parquet(tmp_path / "d.parquet")
    row = df[df["run"] == "toy1"].iloc[0]
    assert row["status"] == "failed" and row["nonfinite_samples"] == int(0.83 * 601)
    assert set(df[df["run"] == "toy0"]["status"]) == {"ok"}
    left = json.loads(pq.read_schema(tmp_path / "d.parquet").metadata[b"drivetrain.left_out"])
    assert "not finite" in left["toy1"]


@pytest.mark.parametrize("fmt", ["parquet", "hdf5", "aalto"])
def test_a_run_listed_ok_without_signals_is_named_as_left_out(copy, tmp_path, fmt):
    (copy / "toy0" / "signals.h5").unlink()
    out = tmp_path / f"d.{fmt}"
    rc, text = cli(["dataset", copy, "--format", fmt, "--out", out])
    assert rc == 0 and "toy0" in text and "left out" in text and "signals.h5 is missing" in text
    if fmt == "parquet":
        import pyarrow.parquet as pq
        left = json.loads(pq.read_schema(out).metadata[b"drivetrain.left_out"])
    elif fmt == "hdf5":
        with h5py.File(out) as f:
            left = json.loads(f.attrs["left_out"])
    else:
        left = json.loads((out / "left_out.json").read_text())
    assert "signals.h5 is missing" in left["toy0"]


# ------------------------------------------------------------------------------------------------
# draw grids: every value a rule can draw is checked when the grid is loaded (item 3)
# ------------------------------------------------------------------------------------------------
GRID = '[scenario]\nname = "g"\n[sweep.draw]\nn = 1\nseed = {seed}\n'


@pytest.mark.parametrize("body, words", [
    ('[[sweep.draw.faults]]\nkind = ["pit", "meteor"]\n', ["'meteor'", "before any draw"]),
    ('[[sweep.draw.faults]]\nkind = [["pit", "void"]]\n', ["kind", "no list or table inside"]),
    ('[[sweep.draw.faults]]\nkind = "pit"\nradius_mm = {uniform = [0.5, inf]}\n', ["radius_mm", "finite"]),
    ('[[sweep.draw.faults]]\nkind = "pit"\nradius_mm = [1.0, -3.0]\n', ["radius_mm", "-3.0", "> 0"]),
    ('[[sweep.draw.faults]]\nkind = "pit"\ndepth_mm = 1e400\n', ["depth_mm", "finite"]),
    ('[[sweep.draw.faults]]\nkind = "pit"\ntooth = [0, 99]\n', ["tooth", "99"]),
    ('[sweep.draw.background]\nload_noise_Nm_rtHz = [0.01, -5]\n', ["load_noise_Nm_rtHz", "-5"]),
])
def test_a_draw_grid_is_refused_at_load_whatever_the_seed(tmp_path, body, words):
    """Seed 1 draws "pit" from ["pit", "meteor"] (812c552 accepted it then); each case is refused at every seed,
    naming the key and the value, before any draw."""
    for seed in (1, 11):
        g = tmp_path / f"g{seed}.toml"
        g.write_text(GRID.format(seed=seed) + body)
        rc, text = cli(["sweep", g, "--out", tmp_path / f"o{seed}", "--quiet"])
        assert rc == 2 and "Traceback" not in text, text[-2000:]
        for w in words:
            assert w in text, (w, text)
        assert not (tmp_path / f"o{seed}" / "manifest.json").exists()


# ------------------------------------------------------------------------------------------------
# counts and numbers below their minimum (item 2)
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("argv, flag", [
    (["stress", "--n-random", "-5"], "--n-random"),
    (["stress", "--n-random", "0"], "--n-random"),
    (["stress", "--halving-subset", "-1"], "--halving-subset"),
    (["stress", "--seed", "-3"], "--seed"),
    (["stress", "--duration-random", "nan"], "--duration-random"),
    (["stress", "--duration-pcm", "-0.1"], "--duration-pcm"),
    (["validate", "--duration", "inf"], "--duration"),
    (["validate", "--settle", "-1"], "--settle"),
    (["detectability", "--speeds", "nan"], "--speeds"),
    (["frontier", "--ladder", "0"], "--ladder"),
])
def test_counts_and_numbers_below_their_minimum_are_refused(tmp_path, argv, flag):
    rc, text = cli([*argv, "--out", tmp_path / "o"])
    assert rc == 2 and flag in text and "Traceback" not in text, text
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("override, key", [("operating_point.drive_speed_rpm=1.7e308", "drive_speed_rpm"),
                                           ("operating_point.load_torque_Nm=1.7e308", "load_torque_Nm"),
                                           ("operating_point.speed_profile_rpm=[[0, 1.7e308]]", "speed_profile_rpm")])
def test_a_start_state_that_overflows_is_a_scene_error(tmp_path, override, key):
    """812c552: ValueError: parameters that are not finite numbers: phi0 = -inf, w0 = inf, tau0 = inf."""
    for argv in (["eigen", EXAMPLE, "--set", override],
                 ["run", EXAMPLE, "--set", override, "--out", tmp_path / "o", "--quiet"]):
        rc, text = cli(argv)
        assert rc == 2 and "Traceback" not in text and "invalid scene" in text, text[-2000:]
        assert f"operating_point.{key}" in text and "overflows" in text
    assert not (tmp_path / "o" / "signals.h5").exists()


# ------------------------------------------------------------------------------------------------
# an FMU swapped in with --fmu: checked before use, in both builds (item 1)
# ------------------------------------------------------------------------------------------------
def _swap(src: Path, dst: Path, md_fn=None, extra=()) -> Path:
    import zipfile

    with zipfile.ZipFile(src) as z, zipfile.ZipFile(dst, "w") as o:
        for n in z.namelist():
            data = z.read(n)
            if n == "modelDescription.xml" and md_fn is not None:
                data = md_fn(data.decode()).encode()
            o.writestr(n, data, compress_type=zipfile.ZIP_DEFLATED)
        for n, data in extra:
            o.writestr(n, data)
    return dst


def _no_guid(md: str) -> str:
    import re
    return md.replace(re.search(r'guid="([^"]+)"', md).group(1), "{00000000-1111-2222-3333-444444444444}")


def _drop_output(md: str) -> str:
    import re
    return md.replace(re.search(r'<ScalarVariable[^>]*name="flange_a_tau".*?</ScalarVariable>', md, re.S).group(0), "")


_BOMB = ('<?xml version="1.0"?>\n<!DOCTYPE lolz [<!ENTITY lol "lol"><!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;">'
         '<!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">]>\n')
SWAPS = {
    "not a zip": (None, "not a zip archive"),
    "wrong guid": (dict(md_fn=_no_guid), "not the one its binary was built with"),
    "lacks a variable": (dict(md_fn=_drop_output), "ModelStructure"),
    "entity bomb": (dict(md_fn=lambda md: _BOMB + md.split("?>", 1)[1].replace('description="', 'description="&lol3;', 1)),
                    "DTD"),
    "entry outside": (dict(extra=[("../../evil.txt", "x")]), "outside the FMU's folder"),
    "absolute entry": (dict(extra=[("/tmp/evil_h3.txt", "x")]), "outside the FMU's folder"),
    "FMI 1.0": (dict(md_fn=lambda md: md.replace('fmiVersion="2.0"', 'fmiVersion="1.0"')), "FMI 2.0"),
}


@pytest.mark.parametrize("build", ["pythonfmu", "native"])
@pytest.mark.parametrize("case", list(SWAPS))
def test_a_swapped_fmu_is_refused_before_use(fmus_both_builds, fmu_dir, tmp_path, build, case):
    """812c552: a traceback for each, and summary.json "running" for good."""
    good = fmus_both_builds.get((build, "GearContact"))
    if good is None:
        pytest.skip("no C toolchain: no native build")
    kw, words = SWAPS[case]
    bad = tmp_path / "swap" / "GearContact.fmu"
    bad.parent.mkdir()
    if kw is None:
        bad.write_bytes(b"not a zip " * 50)
    else:
        _swap(good, bad, **kw)
    out = tmp_path / "run"
    rc, text = cli(["run", EXAMPLE, "--set", "time.duration_s=0.01", "--fmu", f"GearContact={bad}",
                    "--fmu-dir", fmu_dir, "--out", out, "--quiet"])
    assert rc == 2 and "Traceback" not in text and words in text and str(bad) in text, text[-2000:]
    assert not (out / "summary.json").exists()            # refused before the folder says "running"
    assert not (tmp_path / "evil.txt").exists() and not Path("/tmp/evil_h3.txt").exists()


def test_an_fmu_of_another_model_is_refused(fmus_both_builds, fmu_dir, tmp_path):
    other = fmus_both_builds[("pythonfmu", "MotorLoad")]
    rc, text = cli(["run", EXAMPLE, "--set", "time.duration_s=0.01", "--fmu", f"GearContact={other}",
                    "--fmu-dir", fmu_dir, "--out", tmp_path / "o", "--quiet"])
    assert rc == 2 and "Traceback" not in text and "given for model 'GearContact'" in text, text[-2000:]


def test_the_variables_a_system_needs_of_a_given_fmu(tmp_path):
    from drivetrain.errors import ConfigurationError
    from drivetrain.run.runner import check_given_fmus
    from drivetrain.system import ComponentSpec, SystemSpec

    fmus = build_test_fmus(tmp_path / "f")
    spec = SystemSpec([ComponentSpec("s", "MTSpring", {"nosuch_parameter": 1.0}, {})], [], 1e-3, {})
    with pytest.raises(ConfigurationError, match="lacks variables the system needs of s: nosuch_parameter"):
        check_given_fmus(spec, {"MTSpring": fmus["MTSpring"]})


def test_a_run_that_fails_for_any_reason_is_marked_failed(tmp_path, monkeypatch):
    """A run that raises after it started (here: the loader of an FMU) leaves summary.json "failed" with the
    cause, never "running"."""
    from drivetrain.run import runner

    fmus = build_test_fmus(tmp_path / "f")
    scene = load_scene(EXAMPLE, ["time.duration_s=0.05", "outputs.plots=false"])

    def boom(*a, **k):
        raise RuntimeError("the loader tripped")
    monkeypatch.setattr(runner, "simulate_plan", boom)
    with pytest.raises(RuntimeError):
        runner.run_scene(scene, tmp_path / "o", spec=toy_spec(), fmu_paths=fmus, progress=False)
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["status"] == "failed" and "the loader tripped" in s["failure"]["cause"]


# ------------------------------------------------------------------------------------------------
# every FMU returns fmi2Error from a call whose work failed (item 2), in both builds
# ------------------------------------------------------------------------------------------------
#: (build, model, String parameters set before initialization, text of the failure the log reports)
INIT_FAILURES = [
    ("pythonfmu", "GearContact", {"fidelity": "pcm", "health": "mesh", "pinion_mesh_file": "/dev/zero"},
     "mesh files must be .obj or .stl"),
    ("pythonfmu", "GearContact", {"initial_state": "sideways"}, "initial_state = 'sideways'"),
    ("pythonfmu", "MotorLoad", {"node_w_start": "1, 2"}, "initialization failed"),
    ("pythonfmu", "FlexibleShaft", {"node_phi_start": "x"}, "initialization failed"),
    ("pythonfmu", "UpperTransmission", {"node_w_start": "1, 2, 3, 4, 5"}, "initialization failed"),
    ("native", "MotorLoad", {"node_w_start": "1, 2"}, "initialization failed"),
    ("native", "FlexibleShaft", {"node_phi_start": "x"}, "initialization failed"),
    ("native", "UpperTransmission", {"node_w_start": "1, 2, 3, 4, 5"}, "initialization failed"),
]


_INIT_SCRIPT = r"""
import json, sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from drivetrain.cosim.slaves import FmiCallbacks
for case, path, strings in json.loads(sys.argv[1]):
    print(json.dumps({"start": case}), flush=True)
    md = read_model_description(path)
    V = {v.name: v for v in md.modelVariables}
    cb = FmiCallbacks()
    f = FMU2Slave(guid=md.guid, unzipDirectory=extract(path), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=case)
    f.instantiate(callbacks=cb.struct)
    f.setupExperiment(startTime=0.0)
    f.setString([V[k].valueReference for k in strings], list(strings.values()))
    out = []
    for call in (f.enterInitializationMode, f.exitInitializationMode, lambda: f.doStep(0.0, 1e-4)):
        try:
            call(); out.append(0)
        except Exception as exc:
            out.append(getattr(exc, "status", -1))
    log = list(cb.logs[case].lines) if case in cb.logs else []
    print(json.dumps({"case": case, "statuses": out, "log": log}), flush=True)
"""


@pytest.fixture(scope="module")
def init_failures(fmus_both_builds):
    """Every INIT_FAILURES case in one fresh process (one interpreter and fmpy start-up for the eight, each case
    on its own freshly extracted and instantiated FMU, as a co-simulation loads several FMUs in one process):
    {case id: its statuses and log}, and the process's exit code and stderr for a case that never finished."""
    import subprocess
    import sys

    cases = [[_init_id(b, m, s), str(fmus_both_builds[(b, m)]), s] for b, m, s, _ in INIT_FAILURES
             if fmus_both_builds.get((b, m)) is not None]
    r = subprocess.run([sys.executable, "-c", _INIT_SCRIPT, json.dumps(cases)], capture_output=True, text=True,
                       timeout=300)
    done = {}
    for ln in r.stdout.splitlines():
        rec = json.loads(ln) if ln.startswith("{") else {}
        if "case" in rec:
            done[rec["case"]] = rec
    return done, f"subprocess rc {r.returncode}\n{r.stderr[-2000:]}"


def _init_id(build, model, strings) -> str:
    """A case's id: its build, model and the first string parameter it sets."""
    return f"{build}-{model}-{next(iter(strings))}"


@pytest.mark.parametrize("build, model, strings, text", INIT_FAILURES,
                         ids=[_init_id(b, m, s) for b, m, s, _ in INIT_FAILURES])
def test_a_failed_initialization_returns_fmi2error(fmus_both_builds, init_failures, build, model, strings, text):
    """812c552: the GearContact FMU logged "initialization failed: ... mesh files must be .obj or .stl" for a
    /dev/zero mesh and fmi2ExitInitializationMode still returned fmi2OK. (The eight cases share one process:
    init_failures: GearContact's failed initialization only logged again, not failed, fails its 2 cases of the 8 and
    leaves the other 6 to their own outcome.)"""
    if fmus_both_builds.get((build, model)) is None:
        pytest.skip("no C toolchain: no native build")
    done, why = init_failures
    cid = _init_id(build, model, strings)
    assert cid in done, why
    got = done[cid]
    assert got["statuses"] == [0, 3, 3], got                  # enter ok, exit fmi2Error, doStep refused
    assert any(text in ln for ln in got["log"]), got["log"]
    assert any("fmi2ExitInitializationMode: the initialization failed" in ln for ln in got["log"]), got["log"]



# ------------------------------------------------------------------------------------------------
# an output folder in use is refused (item 4)
# ------------------------------------------------------------------------------------------------
@pytest.fixture
def held(tmp_path):
    """A folder whose lock another live process holds (drivetrain.run.lock.output_lock)."""
    import subprocess
    import sys
    import time

    out = tmp_path / "busy"
    flag = tmp_path / "holding"
    p = subprocess.Popen([sys.executable, "-c", (
        "import sys, time, pathlib\nfrom drivetrain.run.lock import output_lock\n"
        f"with output_lock({str(out)!r}):\n    pathlib.Path({str(flag)!r}).write_text('1')\n    time.sleep(120)\n")])
    t0 = time.time()
    while not flag.exists():
        assert time.time() - t0 < 60 and p.poll() is None
        time.sleep(0.05)
    yield out, p.pid
    p.kill()
    p.wait()


def test_a_second_run_into_a_folder_in_use_is_refused_naming_the_holder(held):
    out, pid = held
    rc, text = cli(["run", EXAMPLE, "--set", "time.duration_s=0.01", "--out", out, "--quiet"])
    assert rc == 2 and "Traceback" not in text and "in use by process" in text and str(pid) in text, text[-2000:]
    assert not (out / "summary.json").exists()


def test_a_second_sweep_into_a_folder_in_use_is_refused_naming_the_holder(held, tmp_path):
    out, pid = held
    from drivetrain.campaigns.sweep import run_sweep
    from drivetrain.errors import OutputLockedError

    fmus = build_test_fmus(tmp_path / "f")
    scenes = [load_scene(EXAMPLE, ["time.duration_s=0.05", "scenario.name=t0", "outputs.plots=false"])]
    with pytest.raises(OutputLockedError, match=f"in use by process {pid}"):
        run_sweep(scenes, out, workers=1, specs={"t0": toy_spec()}, fmu_paths=fmus, progress=False)
    assert not (out / "manifest.json").exists()


def test_a_stale_lock_is_taken_over(tmp_path):
    """A killed writer's lock (its flock gone with its process, its pid in the file) does not block the next."""
    from drivetrain.run.lock import LOCK_FILE, output_lock

    out = tmp_path / "o"
    out.mkdir()
    (out / LOCK_FILE).write_text(json.dumps({"pid": 2 ** 22 + 12345, "host": "elsewhere", "command": "killed"}))
    with output_lock(out, takeover=True):
        assert json.loads((out / LOCK_FILE).read_text())["pid"] != 2 ** 22 + 12345
    with output_lock(out):
        pass


# ------------------------------------------------------------------------------------------------
# a run with non-finite samples is failed, with the count, in the run and the manifest (item 2)
# ------------------------------------------------------------------------------------------------
def test_a_run_with_non_finite_samples_is_failed_with_its_count(tmp_path, monkeypatch):
    from drivetrain.campaigns.sweep import make_case, simulate
    from drivetrain.run import runner

    fmus = build_test_fmus(tmp_path / "f")
    scene = load_scene(EXAMPLE, ["time.duration_s=0.2", "outputs.plots=false", "scenario.name=nan83"])
    measured = runner.measured_channels

    def with_nan(plan, res):                 # 83 % of a torque channel NaN, as the battery found exported "ok"
        ch = measured(plan, res)
        x = np.array(ch.signals["propeller_shaft_torque"], dtype=float)
        x[: int(0.83 * x.size)] = np.nan
        ch.signals["propeller_shaft_torque"] = x
        return ch
    monkeypatch.setattr(runner, "measured_channels", with_nan)
    res = runner.run_scene(scene, tmp_path / "run", spec=toy_spec(), fmu_paths=fmus, progress=False)
    s = json.loads((tmp_path / "run" / "summary.json").read_text())
    n = int(0.83 * len(res.time))
    assert s["status"] == "failed" and s["nonfinite_samples"] == {"propeller_shaft_torque": n}
    assert "non-finite samples" in s["failure"]["cause"] and "82.9 %" in s["failure"]["cause"]
    rec = simulate(make_case(scene, tmp_path / "sw" / "nan83", spec=toy_spec(), fmu_paths=fmus))
    assert rec["status"] == "failed" and rec["nonfinite_samples"] == n and "non-finite" in rec["error"]


# ------------------------------------------------------------------------------------------------
# the stress campaign: seeds, and a step that cannot meet the halving rule (item 5)
# ------------------------------------------------------------------------------------------------
def test_stress_takes_seeds():
    from drivetrain.cli import _seed_list

    assert _seed_list("0-9") == list(range(10)) and _seed_list("0,3,7") == [0, 3, 7] and _seed_list("4") == [4]
    for bad in ("-1", "9-0", "a", "1,,2"):
        rc, text = cli(["stress", "--seeds", bad, "--out", "/nonexistent/x"])
        assert rc == 2 and "--seeds" in text and "Traceback" not in text


def _pair(level, outcome, dev=0.0074):
    return {"base": f"b{level}", "half": f"h{level}", "root": "r", "level": level, "step_s": 1 / (3000 * 2 ** (level - 1)),
            "outcome": outcome, "reasons": [] if outcome == "pass" else ["propeller_shaft_torque: mean differs"],
            "deviation": {"propeller_shaft_torque": {"mean": dev}}}


def test_a_step_that_fails_the_halving_rule_is_refused_and_a_converged_one_named():
    """Random scene 30 of seed 7: the H/H/2 pair 0.74 % apart (limit 0.5 %); H/2 against H/4 within the limits. The
    coarse step is refused with its deviation, the converged step named; never a silent pass."""
    from drivetrain.campaigns.stress import resolve_halving

    pairs = [_pair(1, "fail"), _pair(2, "pass", 0.001)]
    resolve_halving(pairs)
    assert pairs[0]["outcome"] == "refined" and "step refused by the halving rule" in pairs[0]["reasons"][0]
    assert pairs[1]["outcome"] == "pass" and pairs[0]["converged_step_s"] == pairs[1]["step_s"] == 1 / 6000
    chain = [_pair(1, "fail"), _pair(2, "fail"), _pair(3, "fail")]        # no converged step: failures stay
    resolve_halving(chain)
    assert [p["outcome"] for p in chain] == ["fail"] * 3


@pytest.mark.slow
def test_a_stress_pair_beyond_the_halving_rule_is_refined_to_a_converged_step(tmp_path, fmu_dir):
    """Seed 7, scene 30: online PCM, rigid shafts, a load reversal, H = 1/3000 s; its halving pair was 0.74 %
    apart in the propeller-shaft mean (limit 0.5 %). Measured: H/2 against H/4 within the limits; about 5 min
    on 2 busy cores (3 runs of 0.1 s online PCM)."""
    out = tmp_path / "st"
    rc, text = cli(["stress", "--set-name", "random", "--seeds", "7", "--n-random", "31", "--only", "rnd_s7_0030",
                    "--out", out, "--workers", "1", "--fmu-dir", fmu_dir, "--quiet"])
    rec = json.loads((out / "stress.json").read_text())
    assert rc == 0 and rec["n_fail"] == 0, text
    first = next(p for p in rec["pairs"] if p["base"] == "rnd_s7_0030")
    assert first["outcome"] == "refined" and first["max_mean_dev"] > 0.005
    assert first["converged_step_s"] == pytest.approx(1 / 6000)
    assert "Steps refused by the halving rule" in (out / "stress.md").read_text()
