"""`run_scene`, the result files, `drivetrain run` and sweeps."""
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from _cosim_test_fmus import toy_spec
from drivetrain.cli import main
from drivetrain.run.outputs import AALTO_COLUMNS, read_hdf5
from drivetrain.run.runner import SUMMARY_KEYS, run_scene
from drivetrain.scene.expect import RUN_SUMMARY_TREE, summary_mismatch
from drivetrain.scene.load import load_scene, load_scenes

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"
HAVE_ASSEMBLER = importlib.util.find_spec("drivetrain.run.assemble") is not None


def test_run_scene_writes_everything(tmp_path, mt_fmus):
    scene = load_scene(EXAMPLE, ["time.duration_s=0.6", "outputs.variables=[\"load.flange_w\"]"])
    res = run_scene(scene, tmp_path / "out", spec=toy_spec(), fmu_paths=mt_fmus, progress=False)
    out = tmp_path / "out"
    for f in ("signals.h5", "summary.json", "torques.png", "spectra.png", "sensors.csv"):
        assert (out / f).is_file() and (out / f).stat().st_size > 1000, f
    s = json.loads((out / "summary.json").read_text())
    assert summary_mismatch(s) == []            # exactly the declared keys (scene.expect.SUMMARY_TREE)
    assert s["sim_time_s"] == pytest.approx(0.6)
    assert s["real_time_factor"] > 0 and s["wall_time_s"] > 0
    assert (s["f_DSH"], s["f_MSH"], s["f_PSH"], s["f_GMF"]) == pytest.approx((25.0, 25 / 3, 25 / 12, 125.0))
    assert set(s["torque"]) == {"drive_shaft_torque", "propeller_shaft_torque"}
    assert s["torque"]["drive_shaft_torque"]["mean"] > 0 and s["torque"]["drive_shaft_torque"]["rms"] > 0
    assert 0 <= s["energy_residual"] < 1e-3 and s["energy"]["complete"]
    assert [f["name"] for f in s["fmus"]] == ["motor", "shaft", "load"]
    assert any("enc2" in w for w in s["warnings"])            # not provided by the toy system
    h = read_hdf5(out / "signals.h5")
    assert h["attrs"]["format"] == "drivetrain-run/1"
    assert h["scene"]["scene"] == scene.to_dict()            # the full resolved scene
    assert h["scene"]["overrides"] == list(scene.overrides)
    assert h["units"]["drive_shaft_torque"] == "N.m" and h["units"]["enc1"] == "rad"
    assert h["units"]["load.flange_w"] == "rad/s"
    assert h["meta"]["enc1"]["source"] == "motor.flange_phi"
    assert len(h["time"]) == 1801 and h["time"][1] == pytest.approx(1 / 3000.0)
    for name, x in h["signals"].items():
        assert np.all(np.isfinite(x)) and len(x) == len(h["time"]), name
    np.testing.assert_allclose(h["signals"]["drive_shaft_torque"], res.signals["drive_shaft_torque"])
    header = (out / "sensors.csv").read_text().splitlines()[0]
    assert header.split(",") == list(AALTO_COLUMNS)


def test_an_assembled_run_writes_exactly_the_declared_summary(tmp_path, fmu_dir):
    """The example scene as assembled (every FMU, the stability block, the contact checks, natural
    frequencies), 0.05 s in process: summary.json holds exactly the keys scene.expect declares, the
    summary in memory those of the run (files and write time come with the writing)."""
    scene = load_scene(EXAMPLE, ["time.duration_s=0.05", "outputs.plots=false"])
    res = run_scene(scene, tmp_path / "out", backend="inprocess", progress=False, fmu_dir=fmu_dir,
                    log=lambda m: None)
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary_mismatch(s) == []
    assert tuple(s) == SUMMARY_KEYS and s["stability"]["gear"] == "gear" and s["natural_frequencies_Hz"]
    unwritten = {k: v for k, v in res.summary.items() if k not in ("files", "write_time_s")}
    assert summary_mismatch(unwritten, RUN_SUMMARY_TREE) == []


def test_cli_refuses_malformed_scene_before_running(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[time]\nduration_s = -1\n[gear]\nhealth = "cracked"\n')
    out = tmp_path / "never"
    rc = main(["run", str(bad), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert "time.duration_s = -1" in err and "> 0 s" in err
    assert "gear.health = 'cracked'" in err and "'healthy'" in err
    assert not out.exists()
    rc = main(["run", str(EXAMPLE), "--set", "numerics.comm_step_s=1e-4", "--out", str(out)])
    assert rc == 2 and "divides the output period" in capsys.readouterr().err
    assert not out.exists()


def test_sweep_local_processes(tmp_path, mt_fmus):
    from drivetrain.campaigns.sweep import run_sweep

    scenes = [load_scene(EXAMPLE, ["time.duration_s=0.2", f"scenario.name=toy{i}", f"operating_point.load_torque_Nm={v}"])
              for i, v in enumerate((0.12, 1.31))]
    specs = {s.name: toy_spec() for s in scenes}
    man = run_sweep(scenes, tmp_path / "sw", workers=2, specs=specs, fmu_paths=mt_fmus, plots=False, progress=False)
    assert [r["status"] for r in man["runs"]] == ["ok", "ok"], man
    assert (tmp_path / "sw" / "manifest.csv").is_file() and (tmp_path / "sw" / "manifest.json").is_file()
    for r in man["runs"]:
        assert Path(r["signals"]).is_file()
        assert r["pid"] != os.getpid()
    # the same case in this process gives the same signals (deterministic, independent of the process)
    ref = run_scene(scenes[0], None, spec=toy_spec(), fmu_paths=mt_fmus, progress=False)
    h = read_hdf5(man["runs"][0]["signals"])
    np.testing.assert_array_equal(h["signals"]["drive_shaft_torque"], ref.signals["drive_shaft_torque"])


class _OneThenKill:
    """An executor that runs the first case in this process and then dies (as a killed sweep would)."""

    def __init__(self):
        self.n = 0

    def submit(self, fn, case):
        import concurrent.futures as cf

        fut = cf.Future()
        self.n += 1
        if self.n == 1:
            fut.set_result(fn(case))
        else:                        # dies a moment later, after the first run was recorded
            import threading

            threading.Timer(1.0, fut.set_exception, (KeyboardInterrupt(),)).start()
        return fut


class _InThisProcess:
    """An executor that runs each case in this process when it is submitted (the sweep's bookkeeping without
    a process pool; test_sweep_local_processes runs the pool)."""

    def submit(self, fn, case):
        import concurrent.futures as cf

        fut = cf.Future()
        try:
            fut.set_result(fn(case))
        except BaseException as exc:  # noqa: BLE001 - handed to the sweep as a worker's failure would be
            fut.set_exception(exc)
        return fut


def test_sweep_loses_no_work(tmp_path, mt_fmus):
    """The manifest was written only at the end (a kill left none), --skip-existing reused runs
    made with other settings and dropped their metrics, --only overwrote the whole sweep's manifest,
    plots were written for scenes that said outputs.plots = false. (The cases run in this process:
    what is checked is the sweep's bookkeeping, not its process pool.)"""
    from drivetrain.campaigns.sweep import run_sweep

    def scenes(load=1.31):
        return [load_scene(EXAMPLE, ["time.duration_s=0.2", f"scenario.name=toy{i}", "outputs.plots=false",
                                     f"operating_point.load_torque_Nm={v}"])
                for i, v in enumerate((0.12, load))]

    out = tmp_path / "sw"
    kw = dict(specs={f"toy{i}": toy_spec() for i in range(2)}, fmu_paths=mt_fmus, progress=False)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(scenes(), out, executor=_OneThenKill(), **kw)
    m = json.loads((out / "manifest.json").read_text())
    assert m["complete"] is False and [r["name"] for r in m["runs"]] == ["toy0"]      # kept what finished
    assert m["runs"][0]["torque_mean"]["drive_shaft_torque"] > 0

    here = _InThisProcess()
    man = run_sweep(scenes(), out, executor=here, skip_existing=True, **kw)
    assert man["complete"] and [r.get("skipped", False) for r in man["runs"]] == [True, False]
    assert man["runs"][0]["torque_mean"] == m["runs"][0]["torque_mean"]         # the reused run keeps its metrics
    assert not list(out.rglob("*.png"))                                         # outputs.plots = false holds

    man = run_sweep(scenes(load=0.71), out, executor=here, skip_existing=True, **kw)   # toy1 changed
    assert [r.get("skipped", False) for r in man["runs"]] == [True, False]
    assert "changed" in man["runs"][1]["rerun_reason"]

    man = run_sweep(scenes(load=0.71)[1:], out, executor=here, grid_names=["toy0", "toy1"], **kw)  # like --only toy1
    assert [r["name"] for r in man["runs"]] == ["toy0", "toy1"]


def test_sweep_refuses_an_unwritable_out_before_running(tmp_path, mt_fmus):
    from drivetrain.cosim import ConfigurationError
    from drivetrain.campaigns.sweep import run_sweep

    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    sc = [load_scene(EXAMPLE, ["time.duration_s=0.2", "scenario.name=toy0"])]
    with pytest.raises(ConfigurationError, match="not writable"):
        run_sweep(sc, blocker / "out", specs={"toy0": toy_spec()}, fmu_paths=mt_fmus, progress=False)


def _run_cli(args, tmp_path):
    """`drivetrain run ...` in a subprocess, FMUs built on demand into a private directory."""
    return subprocess.run([sys.executable, "-m", "drivetrain.cli", "run", *args, "--fmu-dir", str(tmp_path / "fmus"),
                           "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=3000)


def _check_example_output(out):
    for f in ("signals.h5", "summary.json", "torques.png", "spectra.png", "sensors.csv"):
        assert (out / f).is_file() and (out / f).stat().st_size > 1000, f
    s = json.loads((out / "summary.json").read_text())
    for k in SUMMARY_KEYS:
        assert k in s, k
    h = read_hdf5(out / "signals.h5")
    assert set(h["signals"]) >= {"drive_shaft_torque", "propeller_shaft_torque", "enc1", "enc5"}
    for name, x in h["signals"].items():
        assert np.all(np.isfinite(x)), name
        assert h["units"][name], name
    assert h["units"]["drive_shaft_torque"] == "N.m" and h["units"]["enc1"] == "rad"
    assert h["scene"]["scene"]["time"]["duration_s"] == 0.5
    assert s["sim_time_s"] == pytest.approx(0.5) and s["real_time_factor"] > 0
    assert (s["f_DSH"], s["f_MSH"], s["f_PSH"], s["f_GMF"]) == pytest.approx((25.0, 25 / 3, 25 / 12, 125.0))
    # physics sanity against the rig (1500 rpm, 1.31 N·m: 1.85 and 14.75 N·m measured)
    tq = s["torque"]
    assert tq["drive_shaft_torque"]["mean"] == pytest.approx(1.85, rel=0.15)
    assert tq["propeller_shaft_torque"]["mean"] == pytest.approx(14.75, rel=0.15)
    assert s["energy_residual"] < 0.01
    assert {f["name"] for f in s["fmus"]} >= {"motors", "gear"}
    return s


@pytest.mark.skipif(not HAVE_ASSEMBLER, reason="drivetrain.run.assemble not available yet")
def test_cli_run_example_fast_fidelity(tmp_path, capsys, fmu_dir):
    """The example through the command line (analytic mesh: no contact map to build), in this process
    (`drivetrain.cli.main`; the console entry point in a fresh process: the slow test below and
    tests/campaigns/test_sweep_resume.py)."""
    out = tmp_path / "tmp"
    rc = main(["run", str(EXAMPLE), "--set", "time.duration_s=0.5", "--set", "effects.mesh_contact=analytic",
               "--out", str(out), "--fmu-dir", str(fmu_dir), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    s = _check_example_output(out)
    assert [f["fidelity"] for f in s["fmus"] if f["name"] == "gear"] == ["analytic"]


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_ASSEMBLER, reason="drivetrain.run.assemble not available yet")
def test_cli_run_example_as_shipped(tmp_path):
    """Exactly `drivetrain run scenarios/example.toml --set time.duration_s=0.5 --out tmp` (table fidelity:
    the first run builds the contact map, which takes long; later runs use the disk cache)."""
    out = tmp_path / "tmp"
    r = _run_cli([str(EXAMPLE), "--set", "time.duration_s=0.5", "--out", str(out)], tmp_path)
    assert r.returncode == 0, r.stderr
    s = _check_example_output(out)
    assert [f["fidelity"] for f in s["fmus"] if f["name"] == "gear"] == ["table"]


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_ASSEMBLER, reason="drivetrain.run.assemble not available yet")
def test_hard_scenes_finite(tmp_path, fmu_dir):
    for f in sorted((ROOT / "scenarios" / "hard").glob("*.toml")):
        scene = load_scenes(f)[0]
        res = run_scene(scene, tmp_path / scene.name, progress=False, fmu_dir=fmu_dir)
        assert not res.summary["nonfinite_channels"], scene.name
        for name, st in res.summary["torque"].items():          # no divergence: bounded torques
            assert max(abs(st["min"]), abs(st["max"])) < 300.0, (scene.name, name, st)


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_ASSEMBLER, reason="drivetrain.run.assemble not available yet")
def test_paper_sweep_short_on_dask(tmp_path, fmu_dir):
    """All 54 paper scenes (shortened to 1 s) through a Dask LocalCluster executor."""
    from distributed import LocalCluster

    from drivetrain.campaigns.sweep import run_sweep

    scenes = load_scenes(ROOT / "scenarios" / "paper" / "paper.toml",
                         ["time.duration_s=1.0", "time.settle_s=0.5"])
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True) as cluster:
        man = run_sweep(scenes, tmp_path / "paper", address=cluster.scheduler_address, plots=False, progress=False,
                        fmu_dir=fmu_dir)
    assert [r["status"] for r in man["runs"]] == ["ok"] * 54


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_ASSEMBLER, reason="drivetrain.run.assemble not available yet")
def test_severe_scene_20s_step_halving_and_energy(tmp_path, fmu_dir):
    """The 20 s severe-fault scene at 1500 rpm, 1.31 N·m: halving H changes mean torques < 0.5 % and
    torque RMS < 2 %; the energy residual is < 1 % of the energy through the drivetrain."""
    f = ROOT / "scenarios" / "hard" / "missing_tooth_1500rpm.toml"
    a = run_scene(load_scene(f), tmp_path / "H", progress=False, fmu_dir=fmu_dir)
    b = run_scene(load_scene(f, [f"numerics.comm_step_s={1.0 / 24000.0!r}"]), tmp_path / "H2", progress=False,
                  fmu_dir=fmu_dir)
    for res in (a, b):
        assert not res.summary["nonfinite_channels"]
        assert res.summary["energy_residual"] < 0.01
    for name in ("drive_shaft_torque", "propeller_shaft_torque"):
        ta, tb = a.summary["torque"][name], b.summary["torque"][name]
        assert abs(ta["mean"] - tb["mean"]) < 0.005 * abs(tb["mean"]), name
        assert abs(ta["rms"] - tb["rms"]) < 0.02 * abs(tb["rms"]), name


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_ASSEMBLER, reason="drivetrain.run.assemble not available yet")
@pytest.mark.parametrize("rpm", [500.0, 1500.0])
def test_severe_fault_raises_first_sidebands(tmp_path, fmu_dir, rpm):
    """Spectra from the summary: f_GMF ± f_MSH rise by > 10 dB from healthy to severe at 1.31 N·m."""
    levels = {}
    for health in ("healthy", "severe"):
        scene = load_scene(EXAMPLE, [f"operating_point.drive_speed_rpm={rpm}", f"gear.health={health}",
                                     "time.duration_s=8", "time.settle_s=2", "outputs.plots=false"])
        s = run_scene(scene, None, progress=False, fmu_dir=fmu_dir).summary
        sb = s["spectrum_peaks"]["propeller_shaft_torque"]["sidebands"][0]
        levels[health] = (sb["lower_amplitude"], sb["upper_amplitude"])
        gmf = s["spectrum_peaks"]["propeller_shaft_torque"]["GMF_harmonics"][0]
        assert abs(gmf["f_Hz"] - 15 * rpm / 180.0) < 1e-9
    for i in range(2):
        assert 20 * np.log10(levels["severe"][i] / levels["healthy"][i]) > 10.0


def test_an_inprocess_run_leaves_pythonfmu_as_installed(tmp_path):
    """The in-process backend put each FMU's resources first on sys.path; pythonfmu copies a partial
    pythonfmu package (no export binaries) into them, so a fresh process that ran a scene in-process and
    then built an FMU got one without binaries. Runs in a fresh process (pytest has pythonfmu loaded)."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent(f"""
        import os, sys
        sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r})
        from pathlib import Path
        from drivetrain.run.runner import run_scene
        from drivetrain.scene.load import load_scene
        scene = load_scene({str(EXAMPLE)!r}, ["time.duration_s=0.02", "time.settle_s=0.005",
                                              "effects.mesh_contact=ideal", "outputs.plots=false"])
        run_scene(scene, None, backend="inprocess", progress=False, log=lambda m: None)
        import pythonfmu
        from _cosim_test_fmus import build_test_fmus
        paths = build_test_fmus(Path({str(tmp_path)!r}))
        import zipfile
        names = zipfile.ZipFile(paths["MTInertia"]).namelist()
        print("PYTHONFMU", pythonfmu.__file__)
        print("BINARIES", any(n.startswith("binaries/linux64/") for n in names))
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "BINARIES True" in p.stdout, p.stdout
    assert "site-packages" in p.stdout.split("PYTHONFMU", 1)[1].splitlines()[0]
