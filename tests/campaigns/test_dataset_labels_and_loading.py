"""The ML user's front door: class labels, a gearbox-level split, units in df.attrs read back by
load_dataset, a windows iterator that reads run by run, the dataset card."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from _cosim_test_fmus import build_test_fmus
from drivetrain.campaigns import splits as S
from drivetrain.cli import main
from drivetrain.scene.load import load_scene
from _cosim_test_fmus import toy_spec
from _shared import EXAMPLE

#: four gearboxes (manufacturing seeds 3, 5, 8, 13), each healthy and with the paper's severe fault
SEEDS = (3, 5, 8, 13)


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    from drivetrain.campaigns.sweep import run_sweep

    fmus = build_test_fmus(tmp_path_factory.mktemp("mtfmus_ml"))
    out = tmp_path_factory.mktemp("ml") / "sw"
    scenes = [load_scene(EXAMPLE, ["time.duration_s=0.3", "time.settle_s=0.1", f"scenario.name=g{seed}_{h}",
                                   "outputs.plots=false", f"gear.health={h}", "effects.manufacturing_errors=true",
                                   f"manufacturing.seed={seed}"])
              for seed in SEEDS for h in ("healthy", "severe")]
    run_sweep(scenes, out, workers=1, specs={s.name: toy_spec() for s in scenes}, fmu_paths=fmus, progress=False)
    return out


# ------------------------------------------------------------------ the split, on its own


@pytest.mark.parametrize("seed", range(5))
def test_the_split_never_puts_one_gearbox_in_two_sets(seed):
    rng = np.random.default_rng(seed)
    # runs of 37 gearboxes, each at several operating points and with and without faults, in random order
    labels = [{"manufacturing.seed": int(b), "run": f"r{i}"} for i, b in enumerate(rng.integers(0, 37, 400))]
    cols = S.class_columns(labels, (0.6, 0.2, 0.2), seed=seed)
    where: dict = {}
    for lab, c in zip(labels, cols):
        where.setdefault(lab["manufacturing.seed"], set()).add(c["split"])
    assert all(len(v) == 1 for v in where.values())
    per = {s: sum(next(iter(v)) == s for v in where.values()) for s in S.SPLITS}
    n = len(where)
    assert sum(per.values()) == n
    assert all(abs(per[s] - f * n) < 1 for s, f in zip(S.SPLITS, (0.6, 0.2, 0.2)))
    # deterministic from the seed, whatever the order of the runs
    again = S.class_columns(labels[::-1], (0.6, 0.2, 0.2), seed=seed)[::-1]
    assert [c["split"] for c in again] == [c["split"] for c in cols]
    other = S.class_columns(labels, (0.6, 0.2, 0.2), seed=seed + 100)
    assert [c["split"] for c in other] != [c["split"] for c in cols]


def test_fractions_are_checked_and_labels_name_family_and_member():
    with pytest.raises(ValueError, match="adding up to 1"):
        S.check_fractions((0.5, 0.5, 0.5))
    assert S.class_label({"fault0.kind": "pit", "fault0.member": "wheel"}) == "pit/wheel"
    assert S.class_label({"fault0.kind": "pit", "fault0.member": "wheel", "fault1.kind": "void",
                          "fault1.member": "pinion"}) == "pit/wheel+void/pinion"
    assert S.class_label({"gear.health": "healthy"}) == "healthy"
    assert S.gearbox_of({"manufacturing.seed": None, "scenario.noise_name": "p7"}) == "pair:p7"


# ------------------------------------------------------------------ an exported dataset


def test_dataset_has_split_label_faulty_units_and_a_card(sweep, tmp_path):
    from drivetrain import load_dataset

    out = tmp_path / "d.parquet"
    assert main(["dataset", str(sweep), "--out", str(out), "--split", "0.5", "0.25", "0.25",
                 "--split-seed", "1"]) == 0
    df = load_dataset(out)
    per_run = df.groupby("run").first()
    assert set(per_run["label"]) == {"healthy", "missing_tooth/pinion"}   # severe: the paper's missing pinion tooth
    assert (per_run["faulty"] == (per_run["gear.health"] == "severe")).all()
    boxes = per_run.groupby("gearbox")["split"].nunique()
    assert len(boxes) == len(SEEDS) and (boxes == 1).all()                # a gearbox's runs in one set
    assert sorted(per_run.groupby("gearbox")["split"].first()) == ["test", "train", "train", "validation"]
    # units: in df.attrs, for every column, from load_dataset and from plain pandas
    import pandas as pd

    units = df.attrs["units"]
    assert set(units) == set(df.columns)
    assert units["propeller_shaft_torque"] == "N.m" and units["time_s"] == "s" and units["drive_shaft_torque"] == "N.m"
    assert units["operating_point.load_torque_Nm"] == "N.m" and units["label"] == ""
    assert pd.read_parquet(out).attrs["units"] == units
    # the card beside the data
    card = (tmp_path / "DATASET.md").read_text()
    for text in ("| missing_tooth/pinion | 4 |", "| healthy | 4 |", "commit", "`propeller_shaft_torque` | N.m |",
                 "`split`", "load_dataset(", "faulty runs carry contact", "manufacturing.seed 3, 5, 8, 13",
                 "propeller shaft ≈ 10.5 N·m", "Detectability"):
        assert text in card, text
    assert all(f"| `{c}` |" in card for c in df.columns)                 # every column with its unit and meaning


def test_units_round_trip_through_hdf5_and_features(sweep, tmp_path):
    import h5py

    from drivetrain import load_dataset

    assert main(["dataset", str(sweep), "--format", "hdf5", "--out", str(tmp_path / "d.h5")]) == 0
    df = load_dataset(tmp_path / "d.h5")
    with h5py.File(tmp_path / "d.h5") as f:
        run = json.loads(f.attrs["runs"])[0]
        for c in ("propeller_shaft_torque", "drive_shaft_torque"):
            assert df.attrs["units"][c] == f[f"runs/{run}/{c}"].attrs["unit"]
        assert df.attrs["units"]["operating_point.drive_speed_rpm"] == f["labels/operating_point.drive_speed_rpm"].attrs["unit"] == "rpm"
    assert main(["features", str(sweep), "--out", str(tmp_path / "f.parquet")]) == 0
    feats = load_dataset(tmp_path / "f.parquet")
    assert {"label", "faulty", "split", "gearbox"} <= set(feats.columns)
    u = feats.attrs["units"]
    assert set(u) == set(feats.columns)
    assert u["amp_f_GMF.propeller_shaft_torque"] == "N.m" and u["fault0.kind"] == ""
    assert u["operating_point.drive_speed_rpm"] == "rpm"
    # the same split as the dataset's, run for run (same seed, same gearboxes)
    d = load_dataset(tmp_path / "d.h5").groupby("run")["split"].first()
    assert all(d[r] == s for r, s in zip(feats["run"], feats["split"]))


def test_windows_read_run_by_run(sweep, tmp_path, monkeypatch):
    import pyarrow.parquet as pq

    from drivetrain import load_dataset, windows

    out = tmp_path / "d.parquet"
    assert main(["dataset", str(sweep), "--out", str(out)]) == 0
    df = load_dataset(out, settled_only=True)
    # memory-bounded: never the whole file, one row group (a run) per read
    monkeypatch.setattr(pq, "read_table", lambda *a, **k: pytest.fail("windows read the whole dataset"))
    sizes = []
    real = pq.ParquetFile.read_row_group

    def spy(self, i, *a, **k):
        t = real(self, i, *a, **k)
        sizes.append(set(t.column("run").to_pylist()))
        return t

    monkeypatch.setattr(pq.ParquetFile, "read_row_group", spy)
    got = list(windows(out, ["propeller_shaft_torque", "drive_shaft_torque"], length=64, hop=32))
    assert all(len(s) == 1 for s in sizes) and len(sizes) == len(got) == 2 * len(SEEDS)
    for w in got:
        x = df[df["run"] == w.run][["propeller_shaft_torque", "drive_shaft_torque"]].to_numpy(np.float32)
        n = (len(x) - 64) // 32 + 1
        assert w.x.shape == (n, 64, 2) and w.x.dtype == np.float32
        np.testing.assert_array_equal(w.x[1], x[32:96])                     # the second window, both channels
        assert w.faulty == (w.label != "healthy") and (w.y == int(w.faulty)).all()
    train = list(windows(out, ["drive_shaft_torque"], length=64, splits=("train",), channels_first=True))
    assert {w.split for w in train} == {"train"} and train[0].x.shape[1:] == (1, 64)


# ------------------------------------------------------------------ a spectrum in one call


def test_spectrum_reads_a_known_sine_at_its_amplitude():
    """Oracle: a sine of amplitude a at a bin frequency below the low-pass reads a there (the plots'
    convention, single-sided peak amplitude), and the characteristic frequencies ride along."""
    from drivetrain.run.runner import spectrum_frame

    fs, settle, dur = 3000.0, 0.5, 4.5
    t = np.arange(int(dur * fs)) / fs
    n_settled = int(np.sum(t >= settle))
    f0 = 120 * fs / n_settled                     # a bin of the settled part: 90 Hz
    x = 7.0 + 0.35 * np.sin(2 * np.pi * f0 * t) + 0.02 * np.sin(2 * np.pi * 3 * f0 * t)
    x[t < settle] += 50.0                         # a start-up transient the spectrum leaves out
    sp = spectrum_frame(t, x, settle, fs, 1500.0, "propeller_shaft_torque", "N.m")
    i = int(np.argmin(np.abs(sp["frequency_Hz"] - f0)))
    assert sp["amplitude"][i] == pytest.approx(0.35, rel=1e-3)
    j = int(np.argmin(np.abs(sp["frequency_Hz"] - 3 * f0)))
    assert sp["amplitude"][j] == pytest.approx(0.02, rel=2e-3)
    assert sp["amplitude"][0] < 1e-6                                       # the mean is removed
    cf = sp.attrs["characteristic_frequencies"]
    assert cf["f_GMF"] == pytest.approx(1500 / 60 / 3 * 15) and sp.attrs["units"]["amplitude"] == "N.m"
    assert sp.attrs["lowpass_Hz"] == pytest.approx(5 * cf["f_GMF"]) and "Hann" in sp.attrs["convention"]
    # far above the low-pass edge (5 x f_GMF = 625 Hz) a line is filtered out, as in the plots: 1200 Hz
    x2 = np.sin(2 * np.pi * (4800 * fs / n_settled) * t)
    sp2 = spectrum_frame(t, x2, settle, fs, 1500.0)
    assert sp2["amplitude"].max() < 1e-3


def test_spectrum_of_a_loaded_run_is_the_summary_s(sweep):
    """The spectrum from a run's directory and from the dataset equal the one its summary read its GMF line
    from (the spectrum the plots draw)."""
    from drivetrain import load_dataset, spectrum
    from drivetrain.rig.signals import amplitude_near

    name = "g3_severe"
    summary = json.loads((sweep / name / "summary.json").read_text())
    want = summary["spectrum_peaks"]["propeller_shaft_torque"]["GMF_harmonics"][0]["amplitude"]
    sp = spectrum(sweep / name, "propeller_shaft_torque")
    f_gmf = sp.attrs["characteristic_frequencies"]["f_GMF"]
    assert amplitude_near(sp["frequency_Hz"].to_numpy(), sp["amplitude"].to_numpy(), f_gmf) == pytest.approx(want, rel=1e-12)
    df = load_dataset(sweep / "dataset.parquet") if (sweep / "dataset.parquet").exists() else None
    if df is None:
        assert main(["dataset", str(sweep)]) == 0
        df = load_dataset(sweep / "dataset.parquet")
    sp2 = spectrum(df, "propeller_shaft_torque", run=name)
    np.testing.assert_allclose(sp2["amplitude"], sp["amplitude"], rtol=0, atol=1e-12)


# ------------------------------------------------------------------ the command line


def test_set_applies_to_a_grid_s_sweep_table():
    from drivetrain.errors import ScenarioError
    from drivetrain.scene.load import load_scenes

    root = Path(__file__).resolve().parents[2]
    grid = root / "scenarios" / "datasets" / "random_faults.toml"
    scenes = load_scenes(grid, ["sweep.draw.n=2", "time.duration_s=3"])
    assert len(scenes) == 8 and all(s.time.duration_s == 3 for s in scenes)      # 2 draws x 2 speeds x 2 loads
    assert len({s.name for s in scenes}) == 8
    one = load_scenes(grid, ["sweep.draw.n=1", "sweep.axes.operating_point.drive_speed_rpm=[1500.0]"])
    assert [s.operating_point.drive_speed_rpm for s in one] == [1500.0, 1500.0]
    other_seed = load_scenes(grid, ["sweep.draw.n=2", "sweep.draw.seed=7"])
    assert [s.gear.faults for s in other_seed] != [s.gear.faults for s in scenes]
    with pytest.raises(ScenarioError, match="not a grid"):
        load_scenes(root / "scenarios" / "example.toml", ["sweep.draw.n=2"])
    with pytest.raises(ScenarioError, match="sweep.draw.n"):                    # still checked as a grid
        load_scenes(grid, ["sweep.draw.n=0"])


def _subparsers():
    import argparse

    from drivetrain.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return parser, sub.choices


def test_every_option_has_help_and_help_is_plain_text():
    import argparse

    parser, commands = _subparsers()
    missing = [f"{name} {a.option_strings or a.dest}" for name, p in commands.items() for a in p._actions
               if not isinstance(a, argparse._HelpAction) and not (a.help or "").strip()]
    assert not missing, missing
    for text in [parser.format_help(), *(p.format_help() for p in commands.values())]:
        for markup in ("``", ":func:", ":mod:", ":data:", ":class:"):
            assert markup not in text, (markup, text[:200])


def test_loads_name_the_load_motor_and_the_propeller_shaft():
    from drivetrain.run.outputs import load_text, run_title
    from drivetrain.scene.load import load_scene

    assert load_text(1.31) == "load motor 1.31 N·m (propeller shaft ≈ 10.5 N·m)"        # the 1:8 planetary
    title = run_title(load_scene(EXAMPLE), "torque waveforms")
    assert "load motor 1.31 N·m (propeller shaft ≈ 10.5 N·m)" in title


def test_shipped_scenes_state_no_run_figures_in_their_comments():
    """Issue 43: expected values in scene comments come from the scene's [expect], or they go: no shipped scene
    quotes "measured with this model" figures (they went stale: 8.6e-7 stated, 1.7e-10 given)."""
    root = Path(__file__).resolve().parents[2] / "scenarios"
    stale = [f"{p.relative_to(root)}:{i + 1}" for p in root.rglob("*.toml")
             for i, line in enumerate(p.read_text().splitlines())
             if "#" in line and "measured with this model" in line.split("#", 1)[1].lower()]
    assert not stale, stale


def test_the_readme_dataset_block_runs_as_a_file(sweep, tmp_path):
    """The README's dataset block, saved as a .py file and run in a fresh process on an exported sweep."""
    import re
    import subprocess
    import sys

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    block = next(b for b in re.findall(r"```python\n(.*?)```", readme, re.S) if 'load_dataset("DIR/dataset.parquet")' in b)
    assert main(["dataset", str(sweep), "--out", str(tmp_path / "d" / "dataset.parquet")]) == 0
    assert main(["dataset", str(sweep), "--format", "hdf5", "--out", str(tmp_path / "d" / "dataset.h5")]) == 0
    (tmp_path / "block.py").write_text(block.replace("DIR", str(tmp_path / "d")))
    p = subprocess.run([sys.executable, str(tmp_path / "block.py")], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "missing_tooth/pinion" in p.stdout and "N.m" in p.stdout
    assert re.search(r"g\d+_(healthy|severe) (healthy|missing_tooth/pinion) \(1, 512, 1\) \[[01]\]", p.stdout), p.stdout
