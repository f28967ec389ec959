"""Fuzz pass for the newer doors: mutated manifests, summaries, signals files, draw grids, FMU
archives and rig records, seeded, judged as tests/cli/test_fuzz.py judges scenes and meshes: a result, or a refusal
that names the file, never another exception (a traceback for the user).

The default suite draws about two hundred cases (well under a minute on top of one 0.2 s toy sweep); ``-m slow``
ten times as many. A failing case prints its seed and mutation: rerun it with
``FUZZ_SEED=<seed> pytest tests/cli/test_fuzz_doors.py -k <family>``.
"""
from __future__ import annotations

import json
import random
import shutil
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest

from _cosim_test_fmus import build_test_fmus
from drivetrain.errors import ConfigurationError, DatasetError, FileFormatError, Refused
from test_fuzz import HOSTILE, SEED, _cli, _judge, _mutate_bytes, _n, _toml
from _cosim_test_fmus import toy_spec
from _shared import EXAMPLE

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    from drivetrain.campaigns.sweep import run_sweep
    from drivetrain.scene.load import load_scene

    fmus = build_test_fmus(tmp_path_factory.mktemp("fz_fmus"))
    out = tmp_path_factory.mktemp("fz") / "sw"
    scenes = [load_scene(EXAMPLE, ["time.duration_s=0.2", f"scenario.name=toy{i}", "outputs.plots=false",
                                   f"gear.health={h}", "scenario.noise_name=pair0"])
              for i, h in enumerate(("healthy", "severe"))]
    run_sweep(scenes, out, workers=1, specs={s.name: toy_spec() for s in scenes}, fmu_paths=fmus, progress=False)
    return out, fmus


def _mutate_json(rng: random.Random, doc):
    """A JSON document with one value somewhere replaced by a hostile one (or a key dropped)."""
    doc = json.loads(json.dumps(doc))
    node, path = doc, []
    for _ in range(rng.randint(1, 4)):
        if isinstance(node, dict) and node:
            k = rng.choice(sorted(node))
        elif isinstance(node, list) and node:
            k = rng.randrange(len(node))
        else:
            break
        path.append(k)
        if rng.random() < 0.4 or not isinstance(node[k], (dict, list)):
            break
        node = node[k]
    if not path:
        return rng.choice(HOSTILE), "whole document"
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    if isinstance(parent, dict) and rng.random() < 0.2:
        parent.pop(path[-1])
        return doc, f"dropped {path}"
    v = rng.choice(HOSTILE)
    parent[path[-1]] = v
    return doc, f"{path} = {v!r:.40}"


def _dump_json(rng, doc) -> bytes:
    try:
        return json.dumps(doc).encode()
    except (ValueError, TypeError):
        return json.dumps(doc, default=str).encode()


def _export_judged(d: Path, case: str) -> None:
    """The readers of a sweep directory: records, then every run read and checked (dataset.collect, without
    the indicators' cost being the point), then the command line's features."""
    from drivetrain.campaigns.dataset import load_run, run_records

    try:
        for rec in run_records(d):
            load_run(d, rec)
    except (FileFormatError, DatasetError, OSError) as exc:
        assert str(exc).strip(), f"{case}: an empty message"
    except Exception as exc:
        raise AssertionError(f"{case}: {type(exc).__name__}: {exc}") from exc


# ------------------------------------------------------------------------------------------------
def _manifest_fuzz(sweep, tmp_path, n):
    src, _ = sweep
    rng = random.Random(SEED + 10)
    doc = json.loads((src / "manifest.json").read_text())
    for i in range(n):
        d = tmp_path / f"m{i}"
        shutil.copytree(src, d)
        (d / "manifest.jsonl").unlink()
        if rng.random() < 0.7:
            mutated, what = _mutate_json(rng, doc)
            (d / "manifest.json").write_bytes(_dump_json(rng, mutated))
        else:
            data, what = _mutate_bytes(rng, (src / "manifest.json").read_bytes())
            (d / "manifest.json").write_bytes(data)
        _export_judged(d, f"seed {SEED}, manifest {i}: {what}")
        if i % 10 == 0:                       # the command line too, now and then (the indicators cost)
            rc, out = _cli(["features", str(d)])
            _judge(rc, out, f"seed {SEED}, manifest {i} (features): {what}")
        shutil.rmtree(d)


def test_fuzz_manifests(sweep, tmp_path, request):
    _manifest_fuzz(sweep, tmp_path, _n(40, request))


@pytest.mark.slow
def test_fuzz_manifests_long(sweep, tmp_path, request):
    _manifest_fuzz(sweep, tmp_path, 400)


# ------------------------------------------------------------------------------------------------
def _mutate_signals(rng: random.Random, sig: Path) -> str:
    """One hostile change to a signals file: its stored summary or scene (JSON), a channel's length, shape or
    type, time itself, a group removed."""
    what = rng.choice(["summary", "summary", "scene", "short", "2d", "text", "nan", "time", "drop", "bytes"])
    with h5py.File(sig, "a") as f:
        chans = list(f["signals"])
        c = f"signals/{rng.choice(chans)}"
        if what in ("summary", "scene"):
            key = f"{what}_json"
            doc = json.loads(f.attrs[key])
            if rng.random() < 0.6:
                mutated, how = _mutate_json(rng, doc)
                f.attrs[key] = _dump_json(rng, mutated).decode("utf-8", "replace")
            else:
                data, how = _mutate_bytes(rng, f.attrs[key].encode())
                f.attrs[key] = data.decode("latin-1")
            return f"{what}: {how}"
        if what == "short":
            x = f[c][()]
            del f[c]
            f[c] = x[: rng.randrange(len(x))]
        elif what == "2d":
            x = f[c][()]
            del f[c]
            f[c] = np.stack([x, x])
        elif what == "text":
            del f[c]
            f[c] = np.array(["a"] * 10, dtype="S1")
        elif what == "nan":
            x = f[c][()]
            x[rng.randrange(len(x)):] = rng.choice([np.nan, np.inf])
            f[c][...] = x
        elif what == "time":
            t = f["time"][()]
            del f["time"]
            f["time"] = rng.choice([t[::-1], t[:3], np.full_like(t, np.nan), t.reshape(1, -1)])
        elif what == "drop":
            del f[rng.choice(["time", "signals"])]
    if what == "bytes":
        data, how = _mutate_bytes(rng, sig.read_bytes())
        sig.write_bytes(data)
        return f"bytes: {how}"
    return f"{what} {c}"


def _signals_fuzz(sweep, tmp_path, n):
    src, _ = sweep
    rng = random.Random(SEED + 11)
    for i in range(n):
        d = tmp_path / f"s{i}"
        shutil.copytree(src, d)
        what = _mutate_signals(rng, d / rng.choice(["toy0", "toy1"]) / "signals.h5")
        _export_judged(d, f"seed {SEED}, signals {i}: {what}")
        if i % 10 == 0:
            rc, out = _cli(["dataset", str(d), "--out", str(d / "x.parquet")])
            _judge(rc, out, f"seed {SEED}, signals {i} (dataset): {what}")
        shutil.rmtree(d)


def test_fuzz_signals_and_summaries(sweep, tmp_path, request):
    """Mutated signals.h5 files (their arrays and the summary and scene they keep): read and checked, or
    refused naming the file."""
    _signals_fuzz(sweep, tmp_path, _n(50, request))


@pytest.mark.slow
def test_fuzz_signals_and_summaries_long(sweep, tmp_path, request):
    _signals_fuzz(sweep, tmp_path, 500)


# ------------------------------------------------------------------------------------------------
DRAW_PARTS = [
    '[[sweep.draw.faults]]\nkind = {v}\n',
    '[[sweep.draw.faults]]\nkind = ["pit", {v}]\n',
    '[[sweep.draw.faults]]\nkind = "pit"\nradius_mm = {{ uniform = [{v}, {v}] }}\n',
    '[[sweep.draw.faults]]\nkind = ["spall", "pit"]\nwidth_mm = [{v}, 1.0]\nmember = [{v}]\n',
    '[[sweep.draw.faults]]\nkind = "void"\ntooth = [{v}, "any"]\nflank = {v}\n',
    '[sweep.draw.background]\nload_noise_Nm_rtHz = [{v}]\n',
    '[sweep.draw.background]\n"{k}" = {{ uniform = [0.0, {v}] }}\n',
]


def _draw_grid_fuzz(tmp_path, n):
    from drivetrain.scene.load import ScenarioError, load_scenes
    from drivetrain.scene.schema import SCHEMA

    rng = random.Random(SEED + 12)
    keys = list(SCHEMA["background"]) + ["nosuch"]
    for i in range(n):
        seed = rng.randrange(50)
        part = rng.choice(DRAW_PARTS).format(v=_toml(rng.choice(HOSTILE)), k=rng.choice(keys))
        text = f'[scenario]\nname = "g"\n[sweep.draw]\nn = 3\nseed = {seed}\n' + part
        f = tmp_path / f"g{i}.toml"
        f.write_text(text)
        try:
            scenes = load_scenes(f)
        except ScenarioError as exc:
            assert "sweep.draw" in str(exc) or "invalid scene" in str(exc), f"seed {SEED}, grid {i}: {exc}"
            continue
        except Exception as exc:
            raise AssertionError(f"seed {SEED}, grid {i}: {type(exc).__name__}: {exc}\n{text}") from exc
        # accepted: the same grid at every other seed is accepted too (every drawable value was checked)
        for other in (seed + 1, seed + 17):
            f.write_text(text.replace(f"seed = {seed}\n", f"seed = {other}\n"))
            try:
                load_scenes(f)
            except ScenarioError as exc:
                raise AssertionError(f"seed {SEED}, grid {i}: accepted at draw seed {seed}, refused at {other}: "
                                     f"{exc}\n{text}") from exc
        assert scenes


def test_fuzz_draw_grids(tmp_path, request):
    """Hostile draw rules: refused at load, or accepted at every draw seed (never by luck of the seed)."""
    _draw_grid_fuzz(tmp_path, _n(60, request))


@pytest.mark.slow
def test_fuzz_draw_grids_long(tmp_path, request):
    _draw_grid_fuzz(tmp_path, 600)


# ------------------------------------------------------------------------------------------------
def _mutate_fmu(rng: random.Random, src: Path, dst: Path) -> str:
    what = rng.choice(["bytes", "entry", "md_bytes", "md_attr", "md_attr", "drop"])
    if what == "bytes":
        data, how = _mutate_bytes(rng, src.read_bytes())
        dst.write_bytes(data)
        return f"bytes: {how}"
    with zipfile.ZipFile(src) as z, zipfile.ZipFile(dst, "w") as o:
        names = z.namelist()
        drop = rng.choice(names) if what == "drop" else None
        for nm in names:
            if nm == drop:
                continue
            data = z.read(nm)
            if nm == "modelDescription.xml" and what == "md_bytes":
                data, how = _mutate_bytes(rng, data)
            elif nm == "modelDescription.xml" and what == "md_attr":
                text = data.decode()
                attr = rng.choice(["fmiVersion", "guid", "modelName", "modelIdentifier", "valueReference",
                                   "causality", "index", "dependencies", "name"])
                v = str(rng.choice(HOSTILE)).replace('"', "&quot;").replace("<", "&lt;").replace("&", "&amp;")
                text = text.replace(f'{attr}="', f'{attr}="{v}', 1)
                data, how = text.encode(), f"{attr} prefixed with {v[:30]!r}"
            o.writestr(nm, data, compress_type=zipfile.ZIP_DEFLATED)
        if what == "entry":
            nm = rng.choice(["../x", "/abs/x", "a/../../x", "C:/x", "ok/\x00x", "resources/" + "a" * 300])
            o.writestr(nm, b"x")
            how = repr(nm)
        elif what == "drop":
            how = repr(drop)
    return f"{what}: {how}"


def _fmu_fuzz(sweep, tmp_path, n):
    from drivetrain.fmu_build.fmu_check import fmu_archive_problems
    from drivetrain.fmu_build.fmus import load_fmu_info

    _, fmus = sweep
    rng = random.Random(SEED + 13)
    for i in range(n):
        model = rng.choice(sorted(fmus))
        dst = tmp_path / f"f{i}" / f"{model}.fmu"
        dst.parent.mkdir()
        what = _mutate_fmu(rng, fmus[model], dst)
        case = f"seed {SEED}, fmu {i} ({model}): {what}"
        try:
            problems = fmu_archive_problems(dst, model)
            assert all(str(dst) in p for p in problems), f"{case}: {problems} name no file"
            load_fmu_info(dst)
        except (ConfigurationError, Refused) as exc:
            assert str(dst) in str(exc) or dst.name in str(exc), f"{case}: {exc} names no file"
        except Exception as exc:
            raise AssertionError(f"{case}: {type(exc).__name__}: {exc}") from exc
        assert not (tmp_path / "x").exists() and not Path("/abs/x").exists()


def test_fuzz_fmu_archives(sweep, tmp_path, request):
    """Mutated FMU archives (bytes, entries, the model description): checked before use; refused naming the
    file, or usable."""
    _fmu_fuzz(sweep, tmp_path, _n(50, request))


@pytest.mark.slow
def test_fuzz_fmu_archives_long(sweep, tmp_path, request):
    _fmu_fuzz(sweep, tmp_path, 500)


# ------------------------------------------------------------------------------------------------
def _record_fuzz(tmp_path, n):
    from drivetrain.rig.record import RECORD_DIR     # the shipped record this family mutates

    src = RECORD_DIR
    rng = random.Random(SEED + 14)
    files = sorted(p.name for p in src.glob("*.csv"))
    for i in range(n):
        d = tmp_path / f"r{i}"
        shutil.copytree(src, d)
        name = rng.choice(files)
        data, what = _mutate_bytes(rng, (src / name).read_bytes()[:200_000])
        (d / name).write_bytes(data)
        rc, out = _cli(["calibrate", "--record", str(d), "--out", str(tmp_path / f"bg{i}.toml")])
        _judge(rc, out, f"seed {SEED}, record {i} ({name}, {what})")
        if rc == 0:
            text = (tmp_path / f"bg{i}.toml").read_text()
            assert "nan" not in text and "inf" not in text, f"seed {SEED}, record {i}: a non-finite parameter"
        shutil.rmtree(d)


@pytest.fixture
def baseline_fit_once(monkeypatch):
    """record_fit.identify of the 500 rpm record computed once per distinct record: a case that mutates an
    excitation file reads (and calibrate fits) the pristine baseline record first, 1.4 s each time, the same
    deterministic result; a case that mutates a baseline file gives other arrays, so identify runs on them. The
    key is the loaded arrays themselves (bytes of every channel), so no mutated input is ever answered from the
    cache."""
    import copy
    import hashlib

    from drivetrain.campaigns import record_fit

    real, seen = record_fit.identify, {}

    def identify(record=None, base=None):
        if record is None or base is not None:
            return real(record, base)
        h = hashlib.sha1(repr((record.name, record.fs, record.fs_motor)).encode())
        for group in (record.channels, record.motor):
            for k in sorted(group):
                h.update(k.encode())
                h.update(np.ascontiguousarray(group[k]).tobytes())
        for t in (record.t, record.t_motor):
            h.update(b"-" if t is None else np.ascontiguousarray(t).tobytes())
        key = h.hexdigest()
        if key not in seen:
            seen[key] = real(record, base)
        return copy.deepcopy(seen[key])

    monkeypatch.setattr(record_fit, "identify", identify)
    # with this fixture (11.7 -> 2.6 s): rig.record's "not a number" or "unreadable" refusal planted as a
    # RuntimeError fails test_fuzz_rig_records each time (1 of 1)


def test_fuzz_rig_records(tmp_path, request, contact_maps_read_once, baseline_fit_once):
    """Mutated rig records through `drivetrain calibrate --record`: a background without a non-finite value, or
    a refusal, never a traceback. (The rig pair's contact map, which no case mutates, is read once:
    _shared.contact_map_read_once; the pristine baseline record's fit too: baseline_fit_once.)"""
    _record_fuzz(tmp_path, _n(8, request))
