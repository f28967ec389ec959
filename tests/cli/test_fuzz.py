"""Fuzz pass: randomly mutated scenes, grids, mesh files and FMI call sequences, seeded, each judged by
the same rules as the hostile batteries: an exit code below 128 (a clear refusal or a result), no traceback,
nothing written outside the output directory, no success claimed for what did not finish.

The default suite draws a few hundred cases (about a minute); ``-m slow`` draws ten times as many, and the
FMI sequences there include GearContact. A failing case prints its seed and mutation: rerun it with
``FUZZ_SEED=<seed> pytest tests/cli/test_fuzz.py -k <family>``.
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import os
import random
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

from drivetrain.cli import main

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"
SEED = int(os.environ.get("FUZZ_SEED", "2026"))

#: values a hostile scene or FMU call puts anywhere
#: (the long fuzz found with these: a subnormal step crashed the output-rate check with OverflowError, a NUL in
#: a mesh path crashed the path check with ValueError; both fixed)
HOSTILE = [math.nan, math.inf, -math.inf, -1, 0, 1e308, -1e308, 2 ** 63, 2 ** 31 - 1, 1e-320, "", "nan", "../../x",
           "/etc/passwd", "%n%s%x", "a" * 5000, "\u202e\u0000", True, [], [1, "a"], {}, {"a": {"b": [1]}}, [[[]]]]


def _cli(argv) -> tuple[int, str]:
    """Run the command line in this process: (exit code, everything it printed). An exception escaping
    ``main`` (a traceback for the user) fails the calling test with the case that raised it."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        try:
            rc = main(argv)
        except SystemExit as exc:             # argparse's refusal
            rc = exc.code if isinstance(exc.code, int) else 2
    return int(rc or 0), buf.getvalue()


def _toml(value) -> str:
    """A TOML literal for a hostile value (NaN and infinities in TOML's spelling)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return "{" + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + "}"


def _dump(doc: dict) -> str:
    lines = []
    for section, table in doc.items():
        if isinstance(table, dict):
            lines.append(f"[{section}]")
            lines += [f"{json.dumps(k)} = {_toml(v)}" for k, v in table.items()]
        else:
            lines.insert(0, f"{json.dumps(section)} = {_toml(table)}")
    return "\n".join(lines) + "\n"


def _mutated_scene(rng: random.Random, base: dict, schema_keys: list[str]) -> tuple[str, str]:
    """(TOML text, what was done): a value replaced, a section dropped, an unknown key, or broken text."""
    doc = json.loads(json.dumps(base))
    what = rng.choice(["value", "value", "value", "drop", "unknown", "text"])
    if what == "value":
        for _ in range(rng.randint(1, 3)):
            key = rng.choice(schema_keys)
            sec, name = key.split(".", 1)
            v = rng.choice(HOSTILE)
            doc.setdefault(sec, {})[name] = v
            what += f" {key}={v!r:.40}"
    elif what == "drop" and doc:
        sec = rng.choice(list(doc))
        doc.pop(sec)
        what += f" [{sec}]"
    elif what == "unknown":
        sec = rng.choice(list(doc) + ["nosuch"])
        doc.setdefault(sec, {})[rng.choice(["bogus", "duration", "seed_", "ÄÖ"])] = rng.choice(HOSTILE)
        what += f" in [{sec}]"
    text = _dump(doc)
    if what == "text":
        cut = rng.randrange(len(text))
        text = text[:cut] + rng.choice(["", "\x00\xff", "[[", "= =", "\n[scenario]\n", '"""']) + text[cut:]
        what += f" at {cut}"
    return text, what


def _scene_keys() -> list[str]:
    from drivetrain.scene.load import all_keys

    return sorted(all_keys())


def _n(default: int, request) -> int:
    return default * 10 if request.node.get_closest_marker("slow") else default


def _judge(rc: int, text: str, case: str) -> None:
    assert rc < 128, f"{case}: exit code {rc}\n{text[-1500:]}"
    assert "Traceback" not in text, f"{case}: a traceback\n{text[-3000:]}"


def _scene_fuzz(tmp_path, n: int) -> None:
    rng = random.Random(SEED)
    base = tomllib.loads(EXAMPLE.read_text())
    keys = _scene_keys()
    for i in range(n):
        text, what = _mutated_scene(rng, base, keys)
        f = tmp_path / f"scene{i}.toml"
        f.write_text(text, encoding="utf-8", errors="surrogateescape")
        rc, out = _cli(["eigen", str(f)])
        _judge(rc, out, f"seed {SEED}, scene {i}: {what}")


def test_fuzz_scenes(tmp_path, request):
    """Mutated scenes through `drivetrain eigen` (load, validate, assemble, linearise: no simulation)."""
    _scene_fuzz(tmp_path, _n(150, request))


@pytest.mark.slow
def test_fuzz_scenes_long(tmp_path, request):
    _scene_fuzz(tmp_path, 1500)


GRID_PARTS = [
    '[sweep.axes]\n"operating_point.drive_speed_rpm" = {v}\n',
    '[sweep.axes]\n"{k}" = [1, 2]\n',
    '[sweep]\nname = {v}\n[sweep.axes]\n"operating_point.load_torque_Nm" = [0.1, 0.2]\n',
    '[sweep.draw]\nn = {v}\nseed = 1\n[[sweep.draw.faults]]\nkind = "pit"\n',
    '[sweep.draw]\nn = 2\nseed = {v}\n[[sweep.draw.faults]]\nkind = {v}\nradius_mm = {{ uniform = {v} }}\n',
    '[sweep.draw]\nn = 2\nseed = 1\ngearboxes = {v}\npaired_healthy = {v}\n[[sweep.draw.faults]]\nkind = "void"\n',
    '[sweep.growth]\nfault = {{ kind = "pit", tooth = {v} }}\nstages = [{{ radius_mm = {v} }}]\nlife = {v}\n',
    '[sweep.expect."{k}"]\n"torque.drive_shaft_torque.std" = {{ min = {v} }}\n[sweep.axes]\n"time.duration_s" = [1.0]\n',
]


def _grid_fuzz(tmp_path, n: int) -> None:
    from drivetrain.scene.load import ScenarioError, load_scenes

    rng = random.Random(SEED + 1)
    base = EXAMPLE.read_text()
    keys = _scene_keys()
    for i in range(n):
        part = rng.choice(GRID_PARTS).format(v=_toml(rng.choice(HOSTILE)), k=rng.choice(keys + ["x.y", "*", ""]))
        f = tmp_path / f"grid{i}.toml"
        f.write_text(base + "\n" + part)
        try:
            scenes = load_scenes(f)
        except ScenarioError as exc:
            assert str(exc).strip(), f"seed {SEED}, grid {i}: an empty message\n{part}"
            continue
        except Exception as exc:                   # anything else is a traceback for the user
            raise AssertionError(f"seed {SEED}, grid {i}: {type(exc).__name__}: {exc}\n{part}") from exc
        assert all(s.name for s in scenes)


def test_fuzz_grids(tmp_path, request):
    """Mutated [sweep] tables: a grid expands to scenes or is refused with a ScenarioError (the command line
    prints it), never another exception."""
    _grid_fuzz(tmp_path, _n(100, request))


@pytest.mark.slow
def test_fuzz_grids_long(tmp_path, request):
    _grid_fuzz(tmp_path, 1000)


@pytest.fixture(scope="module")
def small_meshes(tmp_path_factory):
    """A coarse pinion as OBJ and STL (files in mm)."""
    from gearcontact_fmu import geometry
    from gearcontact_fmu.meshes import save_mesh
    from gearcontact_fmu.params import BevelGearParams, MeshResolution

    d = tmp_path_factory.mktemp("fuzz_meshes")
    mesh = geometry.build_gear_mesh(BevelGearParams(), "pinion", MeshResolution(profile=1e-3, face=5e-3))
    paths = {}
    for ext in ("obj", "stl"):
        paths[ext] = d / f"pinion.{ext}"
        save_mesh(mesh, paths[ext])
    return paths


def _mutate_bytes(rng: random.Random, data: bytes) -> tuple[bytes, str]:
    what = rng.choice(["truncate", "flip", "garbage", "splice", "numbers", "empty"])
    if what == "truncate":
        return data[:rng.randrange(len(data))], what
    if what == "flip":
        b = bytearray(data)
        for _ in range(rng.randint(1, 50)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        return bytes(b), what
    if what == "garbage":
        return bytes(rng.randrange(256) for _ in range(rng.randint(1, 4000))), what
    if what == "splice":
        i, j = sorted(rng.randrange(len(data)) for _ in range(2))
        return data[:i] + data[j:] + data[i:j], what
    if what == "numbers":
        text = data.decode("latin-1")
        for token in rng.sample(["nan", "inf", "-1", "999999999", "1e400", "0", "-0"], 3):
            pos = rng.randrange(len(text))
            text = text[:pos] + " " + token + " " + text[pos:]
        return text.encode("latin-1"), what
    return b"", what


def _mesh_fuzz(small_meshes, tmp_path, n: int) -> None:
    from gearcontact_fmu.mesh_check import load_gear_mesh
    from gearcontact_fmu.meshes import MeshError

    rng = random.Random(SEED + 2)
    originals = {ext: p.read_bytes() for ext, p in small_meshes.items()}
    for i in range(n):
        ext = rng.choice(sorted(originals))
        data, what = _mutate_bytes(rng, originals[ext])
        f = tmp_path / f"m{i}.{ext}"
        f.write_bytes(data)
        try:
            load_gear_mesh(f, None, "pinion")
        except MeshError as exc:
            assert str(f) in str(exc) or f.name in str(exc), f"seed {SEED}, mesh {i} ({what}): {exc} names no file"
        except Exception as exc:
            raise AssertionError(f"seed {SEED}, mesh {i} ({ext}, {what}): {type(exc).__name__}: {exc}") from exc


def test_fuzz_mesh_files(small_meshes, tmp_path, request):
    """Mutated OBJ and STL files: loaded, or refused with a MeshError naming the file (the command line
    prints it, exit 2), never another exception."""
    _mesh_fuzz(small_meshes, tmp_path, _n(60, request))


@pytest.mark.slow
def test_fuzz_mesh_files_long(small_meshes, tmp_path, request):
    _mesh_fuzz(small_meshes, tmp_path, 600)


FMI_SCRIPT = textwrap.dedent(r'''
    import json, math, random, sys, warnings
    warnings.simplefilter("ignore")
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    from drivetrain.cosim.slaves import FmiCallbacks

    path, seed, n, unknown_refs = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "1"
    go_on = sys.argv[5] == "1"          # call on after a refused call (else stop there, as after fmi2Fatal)
    md = read_model_description(path)
    DIR = extract(path)
    CB = FmiCallbacks()
    rng = random.Random(seed)
    V = md.modelVariables
    VALUES = [math.nan, math.inf, -math.inf, 0.0, -1.0, 1e300, 1e-300, 1.0 / 12000.0, 1.0, 5.0]
    STRINGS = ["", "%n%s%x", "nan", "../../x", "a" * 10000, "ideal", "mean"]

    def vr(vtype):
        # unknown_refs: also references that do not exist or are of another type (else of the call's own type)
        if unknown_refs and rng.random() < 0.3:
            return rng.choice([987654, 2 ** 32 - 1, rng.choice(V).valueReference])
        return rng.choice([v for v in V if v.type == vtype] or V).valueReference

    def call(f, name, *args):
        try:
            getattr(f, name)(*args)
            return "ok"
        except Exception:
            return "refused"

    OPS = {
        "setupExperiment": lambda f: call(f, "setupExperiment", None, rng.choice(VALUES), rng.choice([None, rng.choice(VALUES)])),
        "enter": lambda f: call(f, "enterInitializationMode"),
        "exit": lambda f: call(f, "exitInitializationMode"),
        "doStep": lambda f: call(f, "doStep", rng.choice(VALUES + [0.0, 0.0]), rng.choice(VALUES)),
        "setReal": lambda f: call(f, "setReal", [vr("Real")], [rng.choice(VALUES)]),
        "getReal": lambda f: call(f, "getReal", [vr("Real")]),
        "setInteger": lambda f: call(f, "setInteger", [vr("Integer")], [rng.choice([0, 1, -1, 2 ** 31 - 1, -2 ** 31])]),
        "getInteger": lambda f: call(f, "getInteger", [vr("Integer")]),
        "setString": lambda f: call(f, "setString", [vr("String")], [rng.choice(STRINGS)]),
        "getString": lambda f: call(f, "getString", [vr("String")]),
        "terminate": lambda f: call(f, "terminate"),
        "reset": lambda f: call(f, "reset"),
        # FMU states of the instance: taken, restored, serialized (freed at the end of the sequence)
        "getState": lambda f: get_state(f),
        "setState": lambda f: call(f, "setFMUstate", rng.choice(STATES)) if STATES else "n/a",
        "serialize": lambda f: call(f, "serializeFMUstate", rng.choice(STATES)) if STATES else "n/a",
    }
    STATES = []

    def get_state(f):
        try:
            STATES.append(f.getFMUstate())
            return "ok"
        except Exception:
            return "refused"
    NAMES = sorted(OPS)
    for k in range(n):
        f = FMU2Slave(guid=md.guid, unzipDirectory=DIR, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName=f"fuzz{k}")
        f.instantiate(loggingOn=False, callbacks=CB.struct)
        ops = ["setupExperiment", "enter", "exit"] + [rng.choice(NAMES) for _ in range(rng.randint(3, 12))]
        if rng.random() < 0.3:
            rng.shuffle(ops)
        print(json.dumps({"start": k, "ops": ops}), flush=True)     # the sequence a crash was in
        outcomes = []
        for op in ops:
            outcomes.append((op, OPS[op](f)))
            if outcomes[-1][1] == "refused" and not go_on:
                break
        if go_on or outcomes[-1][1] != "refused":
            for st in STATES:
                call(f, "freeFMUstate", st)
            f.fmi2FreeInstance(f.component)
        STATES.clear()
        print(json.dumps({"sequence": k, "ops": outcomes}), flush=True)
    print(json.dumps({"done": n}), flush=True)
''')


def _fmi_fuzz(fmu: Path, n: int, seed: int, unknown_refs: bool = True, go_on: bool = True) -> None:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    r = subprocess.run([sys.executable, "-c", FMI_SCRIPT, str(fmu), str(seed), str(n), str(int(unknown_refs)),
                        str(int(go_on))], capture_output=True, text=True, timeout=900, env=env)
    lines = [json.loads(ln) for ln in r.stdout.splitlines() if ln.startswith("{")]
    started = [ln for ln in lines if "start" in ln]
    where = f"in sequence {started[-1]['start']}: {started[-1]['ops']}" if started else "before any sequence"
    assert r.returncode == 0 and lines and lines[-1] == {"done": n}, (
        f"{fmu.name}, seed {seed}: the host died (rc {r.returncode}) {where}\n{r.stderr[-2000:]}")


@pytest.fixture(scope="module")
def line_fmus(fmu_dir, pythonfmu_fmus):
    """The session's FMU directory (tests/conftest.py), its FMUs built."""
    return fmu_dir


@pytest.mark.parametrize("model", ["FlexibleShaft", "MotorLoad"])
def test_fuzz_fmi_call_sequences_pythonfmu(line_fmus, model, request):
    """Random FMI call sequences (hostile values, calls out of order) on the pythonfmu FMUs: the host survives
    every one. Value references are of the call's type, and a sequence ends at its first refused call (as a
    host would after fmi2Fatal): the next test calls on.""" 
    _fmi_fuzz(line_fmus / f"{model}.fmu", _n(40, request), SEED + 3, unknown_refs=False, go_on=False)


def test_fuzz_fmi_unknown_references_pythonfmu(line_fmus):
    """Sequences that call on after a refusal, with unknown and mistyped value references: the pythonfmu FMUs
    crashed here until their FMI wrapper (pythonfmu answered fmi2Fatal and released the slave; the next call crashed);
    their FMI wrapper now refuses with fmi2Error and the host goes on (as with the native builds, below)."""
    _fmi_fuzz(line_fmus / "FlexibleShaft.fmu", 40, SEED + 3, unknown_refs=True, go_on=True)


@pytest.fixture(scope="module")
def native_line_fmus(fmus_both_builds):
    from drivetrain.fmu_build.native_line import toolchain_problems

    if toolchain_problems():
        pytest.skip("no C toolchain: " + "; ".join(toolchain_problems()))
    return {m: fmus_both_builds[("native", m)] for m in ("FlexibleShaft", "MotorLoad")}


@pytest.mark.parametrize("model", ["FlexibleShaft", "MotorLoad"])
def test_fuzz_fmi_call_sequences_native(native_line_fmus, model, request):
    """The same on the native builds."""
    _fmi_fuzz(native_line_fmus[model], _n(60, request), SEED + 4)


@pytest.mark.slow
def test_fuzz_fmi_call_sequences_gear(tmp_path):
    """GearContact, both builds, many sequences (its first initialization builds the contact kernels)."""
    from drivetrain.cosim import ensure_fmus
    from drivetrain.fmu_build.native_gear import build_native_gear
    from drivetrain.fmu_build.native_line import toolchain_problems

    ensure_fmus(["GearContact"], tmp_path)
    _fmi_fuzz(tmp_path / "GearContact.fmu", 200, SEED + 5)      # calls on after refusals (the FMI wrapper)
    if not toolchain_problems():
        _fmi_fuzz(build_native_gear({}, tmp_path / "native" / "GearContact.fmu"), 400, SEED + 6)
