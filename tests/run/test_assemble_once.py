"""`run_scene` assembles a scene once: a table gear whose contact map was not cached at assembly starts at the
analytic guess there, and past the cost checks only its start is recomputed on the assembled system
(drivetrain.run.assemble.start_with_map). The oracle is the assembly with the map at hand from the start
(``assemble(scene, build_map=True)``, what a cached map gives): the recomputed spec must equal it parameter for
parameter, bit for bit."""
from pathlib import Path

import numpy as np

from drivetrain.run import assemble as asm

ROOT = Path(__file__).resolve().parents[2]


def _scene(*overrides):
    from drivetrain.scene.load import load_scene

    return load_scene(ROOT / "scenarios" / "example.toml", ["time.duration_s=0.01", *overrides])


def _not_cached(monkeypatch):
    real = asm.start_mesh_model

    def not_cached_yet(gear, build_map=False):
        return real(gear, build_map) if build_map else (None, asm.MESH_START_GUESS)

    monkeypatch.setattr(asm, "start_mesh_model", not_cached_yet)


def _same(a, b, where=""):
    """Equal bit for bit (floats by their bytes, NaN included), in the same key order."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), where
        for k in a:
            _same(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, (list, tuple)):
        assert type(a) is type(b) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, (float, np.floating)):
        assert np.asarray(a, dtype=float).tobytes() == np.asarray(b, dtype=float).tobytes(), f"{where}: {a!r} != {b!r}"
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


def _assert_same_spec(got, want):
    assert [c.name for c in got.components] == [c.name for c in want.components]
    for c, w in zip(got.components, want.components):
        assert c.model == w.model
        _same(c.parameters, w.parameters, f"{c.name}.parameters")
        _same(c.inputs, w.inputs, f"{c.name}.inputs")
    assert got.connections == want.connections
    assert got.comm_step == want.comm_step
    _same(got.metadata, want.metadata, "metadata")


def test_the_start_recomputed_with_the_map_equals_the_assembly_with_a_cached_map(monkeypatch):
    for overrides in ((), ('gear.health="mild"',), ("effects.manufacturing_errors=true", "manufacturing.seed=3"),
                      ('effects.shaft_flexibility="rigid"',)):
        scene = _scene(*overrides)
        want = asm.assemble(scene, build_map=True)              # the map at hand: as a cached map starts
        assert want.metadata["mesh_start"] == "balanced on the table model"
        with monkeypatch.context() as m:
            _not_cached(m)
            guess = asm.assemble(scene)
        assert guess.metadata["mesh_start"] == asm.MESH_START_GUESS
        before = repr(guess)
        got = asm.start_with_map(scene, guess)
        assert repr(guess) == before                           # the caller's spec is not changed
        _assert_same_spec(got, want)
        # the start moved (the guess is not the balance), so the comparison can fail
        assert guess.components[0].parameters["phi0_load"] != got.components[0].parameters["phi0_load"]


def test_a_cached_map_spec_is_returned_as_is():
    scene = _scene()
    spec = asm.assemble(scene, build_map=True)
    assert asm.start_with_map(scene, spec) is spec


def test_prepare_run_assembles_once_whatever_the_cache_held(monkeypatch, tmp_path):
    from drivetrain.run import runner

    real = asm.assemble
    calls = []

    def counted(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(asm, "assemble", counted)
    scene = _scene()
    want = real(scene, build_map=True)
    _not_cached(monkeypatch)
    plan = runner.prepare_run(scene, None, "inprocess", None, fmu_dir=tmp_path, force=False, log=lambda m: None)
    assert len(calls) == 1
    _assert_same_spec(plan.spec, want)


def test_a_sweep_assembles_each_scene_once_whatever_the_cache_held(monkeypatch, tmp_path):
    from drivetrain.campaigns import sweep as S

    real = asm.assemble
    calls, handed = [], []

    def counted(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    def record(scenes, specs, out, **kwargs):
        handed.extend(specs)
        return [], []

    scene = _scene()
    want = real(scene, build_map=True)
    monkeypatch.setattr(asm, "assemble", counted)
    _not_cached(monkeypatch)
    monkeypatch.setattr(S, "_prepare_fmus", lambda *a, **k: None)
    monkeypatch.setattr(S, "_cases", record)
    S.run_sweep([scene], tmp_path / "out", progress=False)
    assert len(calls) == 1
    _assert_same_spec(handed[0], want)
