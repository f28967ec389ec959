"""A sweep killed with SIGKILL (the whole process group) after some runs finished, then resumed:
manifest complete, no run lost or duplicated, signals bit-identical to an uninterrupted sweep."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from drivetrain.run.outputs import read_hdf5
from drivetrain.campaigns.sweep import JOURNAL, read_runs

ROOT = Path(__file__).resolve().parents[2]

GRID = """
[scenario]
name = "kill"
[operating_point]
drive_speed_rpm = 1000.0
[time]
duration_s = 0.3
settle_s = 0.1
[outputs]
plots = false
[effects]
mesh_contact = "analytic"
shaft_flexibility = "rigid"
[sweep]
name = "{base}_{operating_point.load_torque_Nm:g}Nm"
[sweep.axes]
"operating_point.load_torque_Nm" = [0.12, 0.4, 0.71, 1.0, 1.31, 1.6]
"""


def _sweep(grid, out, fmu_dir, *extra, **popen):
    return [sys.executable, "-m", "drivetrain.cli", "sweep", str(grid), "--out", str(out), "--workers", "1",
            "--fmu-dir", str(fmu_dir), "--quiet", *extra]


def _runs(out):
    """The records a reader finds: manifest.json updated by the append-only journal."""
    try:
        return read_runs(out)
    except OSError:
        return []


def _journal(out):
    return (out / JOURNAL).read_bytes()


class _InThisProcess:
    """An executor that runs each case in this process when it is submitted."""

    def submit(self, fn, case):
        import concurrent.futures as cf

        fut = cf.Future()
        fut.set_result(fn(case))
        return fut


@pytest.fixture(scope="module")
def full_sweep(tmp_path_factory, fmu_dir):
    """The grid run uninterrupted, in this process (the reference of the killed sweep, whose runs are in
    worker processes, and the sweep the dataset test truncates): (grid file, FMU directory, sweep directory)."""
    from drivetrain.scene.load import load_scenes
    from drivetrain.campaigns.sweep import run_sweep

    d = tmp_path_factory.mktemp("sweep_resume")
    grid = d / "kill.toml"
    grid.write_text(GRID)
    full = d / "full"
    man = run_sweep(load_scenes(grid), full, executor=_InThisProcess(), fmu_dir=fmu_dir, progress=False)
    assert man["complete"] and [r["status"] for r in man["runs"]] == ["ok"] * 6, man["runs"]
    return grid, fmu_dir, full


def test_a_killed_sweep_resumes_without_loss_or_duplicates(tmp_path, full_sweep):
    grid, fmu_dir, full = full_sweep
    killed = tmp_path / "killed"

    p = subprocess.Popen(_sweep(grid, killed, fmu_dir), cwd=ROOT, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL, start_new_session=True)
    t0 = time.time()
    while len(_runs(killed)) < 2 and time.time() - t0 < 600 and p.poll() is None:
        time.sleep(0.05)
    os.killpg(p.pid, signal.SIGKILL)
    p.wait()
    done_before = [r["name"] for r in _runs(killed)]
    assert 2 <= len(done_before) < 6, done_before          # killed in the middle
    m = json.loads((killed / "manifest.json").read_text())
    assert m["complete"] is False
    # the journal holds one whole line per finished run, each with its finished files
    lines = [json.loads(ln) for ln in _journal(killed).splitlines()]
    assert [x["name"] for x in lines] == done_before and all(x["status"] == "ok" for x in lines)
    assert all((killed / x["name"] / "summary.json").is_file() for x in lines)

    r = subprocess.run(_sweep(grid, killed, fmu_dir, "--resume"), cwd=ROOT, capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    m = json.loads((killed / "manifest.json").read_text())
    names = [x["name"] for x in m["runs"]]
    assert m["complete"] is True and len(names) == 6 and len(set(names)) == 6
    assert {x["name"] for x in m["runs"] if x.get("skipped")} >= set(done_before)   # not run twice
    # the resume says what it reused, and the wall time counts the preparation
    reused = sum(bool(x.get("skipped")) for x in m["runs"])
    assert m["reused_runs"] == reused                       # (the log says it too, unless --quiet)
    assert 0.0 <= m["preparation_s"] <= m["wall_time_s"]
    assert f"{reused} reused" in r.stdout and f"preparation {m['preparation_s']:.1f} s" in r.stdout
    for x in m["runs"]:
        a = read_hdf5(full / x["name"] / "signals.h5")["signals"]
        b = read_hdf5(killed / x["name"] / "signals.h5")["signals"]
        assert a.keys() == b.keys()
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=f"{x['name']} {k}")


def test_read_runs_skips_a_torn_line_and_prefers_the_journal(tmp_path):
    (tmp_path / "manifest.json").write_text(json.dumps({"runs": [{"name": "a", "status": "failed"},
                                                                 {"name": "b", "status": "ok"}]}))
    (tmp_path / JOURNAL).write_bytes(b'{"name":"a","status":"ok"}\n{"name":"c","status":"ok"}\n{"name":"d","sta')
    runs = read_runs(tmp_path)
    assert [(r["name"], r["status"]) for r in runs] == [("a", "ok"), ("b", "ok"), ("c", "ok")]
    with pytest.raises(OSError):
        read_runs(tmp_path / "nothing")


def test_a_dataset_of_a_killed_sweep_has_its_journaled_runs(tmp_path, full_sweep):
    """The dataset export reads the journal: a run that finished after the last manifest write is in it
    (a copy of the uninterrupted sweep, its manifest cut back to the first run)."""
    import shutil

    from drivetrain.campaigns.dataset import collect

    out = tmp_path / "sweep"
    shutil.copytree(full_sweep[2], out)
    m = json.loads((out / "manifest.json").read_text())
    names = [x["name"] for x in m["runs"]]
    assert len(names) == 6 and m["complete"] is True
    m["runs"] = m["runs"][:1]                         # as if killed before the manifest caught up
    m["complete"] = False
    (out / "manifest.json").write_text(json.dumps(m))
    assert sorted(x["name"] for x in collect(out)) == sorted(names)


def test_the_fingerprint_covers_version_sources_and_given_fmus(tmp_path, monkeypatch):
    """--resume reuses a run only if it would compute the same: a swapped-in FMU file (same path, other
    content) or another project version is another computation."""
    import drivetrain.campaigns.sweep as S
    from drivetrain.scene.load import load_scene

    scene = load_scene(ROOT / "scenarios" / "example.toml")
    fmu = tmp_path / "GearContact.fmu"
    fmu.write_bytes(b"one")
    a = S.fingerprint(scene, {"GearContact": fmu})
    assert S.fingerprint(scene, {"GearContact": fmu}) == a
    fmu.write_bytes(b"two!")
    assert S.fingerprint(scene, {"GearContact": fmu}) != a
    b = S.fingerprint(scene)
    monkeypatch.setattr(S, "__version__", "0.0.0-other")
    assert S.fingerprint(scene) != b


def test_a_sweep_prepares_each_contact_map_once():
    """Gearboxes (manufacturing seeds) and operating points share a contact map: the gear parameters that can
    shape a disk cache are the same for them, and differ for another fault; a run's state never counts."""
    from drivetrain.campaigns.sweep import _cache_shaping
    from drivetrain.run.runner import assemble_scene
    from drivetrain.scene.load import load_scene

    def gear(*overrides):
        scene = load_scene(ROOT / "scenarios" / "example.toml", ["effects.manufacturing_errors=true", *overrides])
        return _cache_shaping(assemble_scene(scene).components_of("GearContact")[0].parameters)

    base = gear()
    assert gear("manufacturing.seed=7", "operating_point.drive_speed_rpm=500") == base
    assert gear("gear.health=mild") != base
    assert not any(k.endswith("_start") or k == "manufacturing_errors" for k in base)


def test_an_interrupted_dask_sweep_cancels_instead_of_failing(tmp_path, full_sweep, monkeypatch):
    """An interrupted sweep on Dask (--scheduler ADDRESS or local): Dask's executor has no cancel_futures, so
    the shutdown that cancels the runs not started must be its own (wait=False), and the interrupt itself
    reaches the caller; it used to be replaced by a TypeError. The client (and a local cluster) is closed."""
    import drivetrain.campaigns.sweep as S
    from drivetrain.scene.load import load_scenes

    calls = []

    class DaskLike:                                   # distributed's ClientExecutor.shutdown(self, wait=True)
        def shutdown(self, wait=True):
            calls.append(("shutdown", wait))

    class Client:
        def close(self):
            calls.append(("close",))

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(S, "_executor", lambda workers, address: (DaskLike(), Client()))
    monkeypatch.setattr(S, "_run_cases", interrupted)
    grid, fmu_dir, _ = full_sweep
    with pytest.raises(KeyboardInterrupt):
        S.run_sweep(load_scenes(grid), tmp_path / "sw", address="local", fmu_dir=fmu_dir, progress=False)
    assert calls == [("shutdown", False), ("close",)]


def test_the_fingerprint_covers_the_machines_table(tmp_path):
    """A scene naming a lumped table ([drivetrain] parameters): an edited table (same path) is another computation."""
    import drivetrain.campaigns.sweep as S
    from drivetrain.rig.data import PUBLIC_CSV
    from drivetrain.scene.load import load_scene

    table = tmp_path / "machine.csv"
    table.write_text(PUBLIC_CSV.read_text())
    scene = load_scene(ROOT / "scenarios" / "example.toml", [f'drivetrain.parameters="{table}"'])
    a = S.fingerprint(scene)
    assert S.fingerprint(scene) == a != S.fingerprint(load_scene(ROOT / "scenarios" / "example.toml"))
    table.write_text(PUBLIC_CSV.read_text().replace("22,0.0495", "22,0.0496"))
    assert S.fingerprint(scene) != a
