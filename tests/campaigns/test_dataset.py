"""`drivetrain dataset`: a sweep directory as one labelled file set; labels and signals read back equal
what the runs wrote."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from _cosim_test_fmus import toy_spec
from _shared import EXAMPLE
from drivetrain.cli import main
from drivetrain.run.outputs import read_hdf5
from drivetrain.scene.load import load_scene


@pytest.fixture(scope="module")
def sweep(tmp_path_factory, mt_fmus):
    from drivetrain.campaigns.sweep import run_sweep

    out = tmp_path_factory.mktemp("ds") / "sw"
    scenes = [load_scene(EXAMPLE, ["time.duration_s=0.2", f"scenario.name=toy{i}", "outputs.plots=false",
                                   f"gear.health={h}", f"operating_point.load_torque_Nm={v}"])
              for i, (h, v) in enumerate((("healthy", 0.12), ("severe", 1.31)))]
    run_sweep(scenes, out, workers=1, specs={s.name: toy_spec() for s in scenes}, fmu_paths=mt_fmus, progress=False)
    return out


def _written(sweep):
    runs = json.loads((sweep / "manifest.json").read_text())["runs"]
    return {r["name"]: read_hdf5(sweep / r["name"] / "signals.h5") for r in runs}


def test_parquet_round_trip(sweep, tmp_path, capsys):
    import pandas as pd

    assert main(["dataset", str(sweep), "--format", "parquet", "--out", str(tmp_path / "d.parquet")]) == 0
    df = pd.read_parquet(tmp_path / "d.parquet")                      # the one line of the docs
    import pyarrow.parquet as pq

    assert pq.ParquetFile(tmp_path / "d.parquet").num_row_groups == len(_written(sweep))   # written run by run
    for name, h in _written(sweep).items():
        part = df[df["run"] == name]
        np.testing.assert_array_equal(part["time_s"].to_numpy(), h["time"])
        for c, x in h["signals"].items():
            np.testing.assert_array_equal(part[c].to_numpy(), x)
        assert set(part["gear.health"]) == {h["scene"]["scene"]["gear"]["health"]}
        assert set(part["operating_point.load_torque_Nm"]) == {h["scene"]["scene"]["operating_point"]["load_torque_Nm"]}
        assert set(part["status"]) == {"ok"}
        # the condition indicators are per-run columns, those of `drivetrain features` (campaigns.features)
        from drivetrain.campaigns.features import run_features

        scene = h["scene"]["scene"]
        cols = run_features(h["time"], h["signals"], scene["time"]["settle_s"],
                            scene["operating_point"]["drive_speed_rpm"])
        assert cols and all(set(part[k]) == {v} or (np.isnan(v) and part[k].isna().all()) for k, v in cols.items())


def test_hdf5_round_trip(sweep, tmp_path):
    import h5py

    assert main(["dataset", str(sweep), "--format", "hdf5", "--out", str(tmp_path / "d.h5")]) == 0
    written = _written(sweep)
    with h5py.File(tmp_path / "d.h5") as f:
        names = json.loads(f.attrs["runs"])
        assert names == list(written)
        health = [v.decode() for v in f["labels/gear.health"][()]]
        load = f["labels/operating_point.load_torque_Nm"][()]
        for i, name in enumerate(names):
            h = written[name]
            assert health[i] == h["scene"]["scene"]["gear"]["health"]
            assert load[i] == h["scene"]["scene"]["operating_point"]["load_torque_Nm"]
            np.testing.assert_array_equal(f[f"runs/{name}/time"][()], h["time"])
            for c, x in h["signals"].items():
                np.testing.assert_array_equal(f[f"runs/{name}/{c}"][()], x)
                assert f[f"runs/{name}/{c}"].attrs["unit"] == h["units"][c]


def test_aalto_layout_and_labels(sweep, tmp_path):
    import pandas as pd

    assert main(["dataset", str(sweep), "--format", "aalto", "--out", str(tmp_path / "aalto")]) == 0
    labels = pd.read_csv(tmp_path / "aalto" / "labels.csv")
    assert list(labels["run"]) == ["toy0", "toy1"] and list(labels["gear.health"]) == ["healthy", "severe"]
    csv0 = pd.read_csv(tmp_path / "aalto" / "toy0.csv")
    assert list(csv0.columns[:2]) == ["time", "enc1"]


def test_not_a_sweep_directory(tmp_path, capsys):
    assert main(["dataset", str(tmp_path)]) == 2
    assert "manifest.json" in capsys.readouterr().err


def test_faults_become_label_columns():
    from drivetrain.campaigns.dataset import run_labels
    from drivetrain.scene.load import resolve

    scene = resolve({"gear": {"health": "faults", "faults": [{"kind": "pit", "member": "wheel", "tooth": 38},
                                                            {"kind": "missing_tooth", "tooth": 3}]}}).to_dict()
    lab = run_labels("r", {"status": "ok"}, scene, None)
    assert lab["gear.health"] == "faults"
    assert (lab["fault0.kind"], lab["fault0.member"], lab["fault0.tooth"], lab["fault0.radius_mm"]) == (
        "pit", "wheel", 38, 1.5)
    assert (lab["fault1.kind"], lab["fault1.member"], lab["fault1.tooth"]) == ("missing_tooth", "pinion", 3)


def test_labels_tell_the_truth(sweep, tmp_path):
    """The severe run is labelled with its fault like a drawn one (fault0.kind missing_tooth on pinion tooth 0);
    the healthy run has no fault; settings whose effect is off (manufacturing errors, rig instruments, the
    background) are null, the ones that act are not; the settled column marks the samples after settle_s and
    --settled-only keeps only those; every array in dataset.h5 has its unit."""
    import h5py
    import pandas as pd

    assert main(["dataset", str(sweep), "--format", "parquet", "--out", str(tmp_path / "d.parquet")]) == 0
    df = pd.read_parquet(tmp_path / "d.parquet")
    severe, healthy = df[df["run"] == "toy1"], df[df["run"] == "toy0"]
    assert set(severe["fault0.kind"]) == {"missing_tooth"} and set(severe["fault0.member"]) == {"pinion"}
    assert set(severe["fault0.tooth"]) == {0} and healthy["fault0.kind"].isna().all()
    for off in ("manufacturing.seed", "manufacturing.grade", "instruments.encoder_lines", "background.seed",
                "background.drive_Kp", "tooth_compliance.factor"):
        assert df[off].isna().all(), off
    assert df["operating_point.drive_speed_rpm"].notna().all() and df["effects.sensors"].notna().all()
    settle = df["time.settle_s"].iloc[0]
    assert settle > 0 and (df["settled"] == (df["time_s"] >= settle)).all() and (~df["settled"]).any()
    assert main(["dataset", str(sweep), "--out", str(tmp_path / "s.parquet"), "--settled-only"]) == 0
    s = pd.read_parquet(tmp_path / "s.parquet")
    assert s["settled"].all() and s["time_s"].min() >= settle and len(s) == int(df["settled"].sum())
    assert main(["dataset", str(sweep), "--format", "hdf5", "--out", str(tmp_path / "d.h5")]) == 0
    missing = []
    with h5py.File(tmp_path / "d.h5") as f:
        f.visititems(lambda name, obj: missing.append(name) if isinstance(obj, h5py.Dataset)
                     and "unit" not in obj.attrs else None)
        assert f["runs/toy0/time"].attrs["unit"] == "s"
        assert f["labels/operating_point.drive_speed_rpm"].attrs["unit"] == "rpm"
        assert f["labels/fault0.tooth"].attrs["unit"] == "1"
    assert not missing, missing


def test_acts_when_covers_every_background_constant():
    """With every background effect off no background label survives, with each on its own constants do."""
    from drivetrain.scene.load import resolve
    from drivetrain.scene.schema import SCHEMA, setting_acts

    off = resolve({}).to_dict()
    assert not any(setting_acts("background", k, off) for k in SCHEMA["background"])
    on = resolve({"effects": {"shaft_orders": True}}).to_dict()
    assert setting_acts("background", "order_msh_1x_Nm", on) and setting_acts("background", "seed", on)
    assert not setting_acts("background", "load_noise_Nm_rtHz", on)
    prof = resolve({"effects": {"manufacturing_errors": True}}).to_dict()
    assert setting_acts("manufacturing", "seed", prof) and not setting_acts("manufacturing", "profile_um", prof)


def test_the_paper_faults_are_their_fault_specifications():
    """mild and severe build the geometry of the specifications they are labelled with (the same mesh)."""
    from gearcontact_fmu.fault_specs import health_faults
    from gearcontact_fmu.faults import apply_faults, apply_health
    from gearcontact_fmu.geometry import build_gear_mesh
    from gearcontact_fmu.params import BevelGearParams, MeshResolution

    g = BevelGearParams()
    mesh = build_gear_mesh(g, "pinion", MeshResolution(profile=0.05e-3, face=1e-3))
    for health in ("mild", "severe"):
        a = apply_health(mesh, g, health, "pinion")
        b = apply_faults(mesh, g, health_faults(health), "pinion")
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.faces, b.faces)


@pytest.mark.parametrize("bad", ["../../escape", "/tmp/victim", "a/../../b", ".hidden"])
def test_a_hostile_run_name_reads_and_writes_nothing_outside(sweep, tmp_path, capsys, bad):
    """A manifest is data: a run name that is not a scene name (a path) is refused before any file is read
    or written for it, with exit 2 and a message naming it (fuzz pass: `dataset --format aalto` wrote
    escape.csv beside the sweep and victim.csv anywhere)."""
    import shutil

    d = tmp_path / "deep" / "sw"
    shutil.copytree(sweep, d)
    for f in (d / "manifest.json", d / "manifest.jsonl"):
        if f.is_file():
            f.write_text(f.read_text().replace('"toy1"', json.dumps(bad)))
    before = {p for p in tmp_path.rglob("*")}
    assert main(["dataset", str(d), "--format", "aalto", "--out", str(d / "out")]) == 2
    err = capsys.readouterr().err
    assert "not a valid run name" in err and bad[:20] in err
    assert {p for p in tmp_path.rglob("*")} == before            # nothing written anywhere


def test_a_dataset_out_that_cannot_take_it(sweep, tmp_path, capsys):
    """An existing directory as the parquet file, or a place that cannot be written: exit 2, the path named,
    no stray temporary file (fuzz pass: a traceback and taken.tmp)."""
    taken = tmp_path / "taken"
    taken.mkdir()
    assert main(["dataset", str(sweep), "--out", str(taken)]) == 2
    assert "a directory" in capsys.readouterr().err and list(taken.iterdir()) == []
    blocked = tmp_path / "a_file"
    blocked.write_text("x")
    assert main(["dataset", str(sweep), "--out", str(blocked / "d.parquet")]) == 2
    assert "cannot be written" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "taken"]


def test_the_export_holds_one_run_at_a_time(sweep, tmp_path, monkeypatch):
    """A dataset of thousands of runs is never held in memory: ``collect`` keeps labels only, and
    each writer reads a run's samples when it writes that run, once. Counted: every signals.h5 is read
    once for the labels and once more by the writer, and the collected runs hold no arrays."""
    from drivetrain.campaigns import dataset as D

    reads = []
    original = D.read_run
    monkeypatch.setattr(D, "read_run", lambda sig, rec: reads.append(sig) or original(sig, rec))
    runs = D.collect(sweep)
    assert runs and all(not any(isinstance(v, np.ndarray) for v in r.values()) for r in runs)
    assert all(set(r) == {"name", "labels", "units", "channels", "_source"} for r in runs)
    n_runs = len(runs)
    assert len(reads) == n_runs
    D.write_parquet(runs, tmp_path / "d.parquet")
    assert len(reads) == 2 * n_runs and sorted(reads[n_runs:]) == sorted(reads[:n_runs])


def test_a_growth_grid_runs_and_exports_with_its_stage_labels(tmp_path, fmu_dir):
    """The same on a real sweep (the drivetrain's own models, not toy specs): a pinion pit grows and becomes a
    spall in one gearbox; every stage is a run labelled with its stage, remaining life and the fault's sizes
    (fault0.*), the healthy stage with empty fault labels; the labels of effects that are off are empty; the
    settled column marks the samples after settle_s; units in the parquet schema. Coarse meshes and map so
    that the three contact maps cost seconds."""
    import pandas as pd
    import pyarrow.parquet as pq

    from drivetrain.campaigns.dataset import export
    from drivetrain.campaigns.sweep import run_sweep
    from drivetrain.scene.load import load_scenes

    grid = tmp_path / "growth.toml"
    grid.write_text("""
[scenario]
name = "life"
[operating_point]
drive_speed_rpm = 1000.0
load_torque_Nm = 1.31
[time]
duration_s = 0.3
settle_s = 0.1
[numerics]
profile_element_mm = 0.3
face_element_mm = 3.0
map_points_per_pitch = 8
map_approach_points = 8
[outputs]
plots = false
[sweep.growth]
healthy = true
fault = { kind = "pit", member = "pinion", tooth = 4, face_position = 0.5 }
stages = [{ radius_mm = 1.0, depth_mm = 0.1 }, { kind = "spall", length_mm = 3.0, width_mm = 4.0, depth_mm = 0.1 }]
life = [0.5, 0.9]
""")
    scenes = load_scenes(grid)
    man = run_sweep(scenes, tmp_path / "sw", workers=1, backend="inprocess", fmu_dir=fmu_dir, progress=False)
    assert [r["status"] for r in man["runs"]] == ["ok"] * 3, man["runs"]
    path = export(tmp_path / "sw", "parquet")
    df = pd.read_parquet(path)
    per_run = df.groupby("run").first()
    assert list(per_run["scenario.growth_stage"]) == [0, 1, 2]
    assert list(per_run["scenario.remaining_life"]) == pytest.approx([1.0, 0.5, 0.1])
    assert pd.isna(per_run["fault0.kind"].iloc[0]) and list(per_run["fault0.kind"].iloc[1:]) == ["pit", "spall"]
    assert per_run["fault0.radius_mm"].iloc[1] == 1.0 and pd.isna(per_run["fault0.radius_mm"].iloc[2])
    assert per_run["fault0.length_mm"].iloc[2] == 3.0 and set(per_run["fault0.tooth"].iloc[1:]) == {4}
    assert per_run["gear.health"].tolist() == ["healthy", "faults", "faults"]
    # effects that are off leave their settings empty (ideal sensors: no instrument noise labels)
    instrument_cols = [c for c in df.columns if c.startswith("instruments.")]
    assert instrument_cols and all(per_run[c].isna().all() for c in instrument_cols)
    first = df[df["run"] == per_run.index[0]]
    assert not first["settled"].iloc[0] and first["settled"].iloc[-1]
    assert (first.loc[first["settled"], "time_s"] >= 0.1 - 1e-12).all()
    units = json.loads(pq.read_schema(path).metadata[b"drivetrain.units"])
    assert units["time_s"] == "s" and units["fault0.radius_mm"] == "mm" and units["propeller_shaft_torque"] == "N.m"
    assert units["operating_point.load_torque_Nm"] == "N.m"          # one spelling per unit in a dataset
