"""The C stepping loop (drivetrain.cosim.stepper) against the master's Python loop (BEVEL_PY_STEPPER=1):
bit-identical signals with the pythonfmu and the native FMUs, the same failure (error and partial result),
warnings that keep the run going, and the fallback."""
import ctypes
import functools
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fmpy")

import drivetrain.cosim.master as master  # noqa: E402
from drivetrain.cosim import CosimError, simulate  # noqa: E402
from drivetrain.cosim import stepper as stepper_mod  # noqa: E402
from drivetrain.cosim.slaves import FmiSlave  # noqa: E402
from drivetrain.system import ComponentSpec, Connection, SystemSpec  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"
H12 = 1.0 / 12000.0

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not installed")


@pytest.fixture
def spy(monkeypatch):
    """Counts the C chunk calls (to check which loop ran)."""
    calls = []
    orig = stepper_mod.Stepper.run

    def run(self, k, k_end):
        calls.append((k, k_end))
        return orig(self, k, k_end)

    monkeypatch.setattr(master.Stepper, "run", run)
    return calls


def both(monkeypatch, spy, fn):
    """fn() with the Python loop, then with the C loop (which must have run)."""
    monkeypatch.setenv("BEVEL_PY_STEPPER", "1")
    a = fn()
    assert not spy
    monkeypatch.delenv("BEVEL_PY_STEPPER")
    b = fn()
    assert spy
    return a, b


def assert_raw_identical(a, b):
    assert a.keys() == b.keys() and len(a["time"]) > 1
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def toy_spec(fail_at_s=-1.0, fail_mode=1):
    return SystemSpec(
        components=[ComponentSpec("motor", "MTInertia", {"J": 0.01, "d": 0.002, "tau_src": 1.0}),
                    ComponentSpec("shaft", "MTSpring", {"k": 300.0, "c": 0.05}),
                    ComponentSpec("load", "MTInertia", {"J": 0.02, "d": 0.01, "fail_at_s": fail_at_s,
                                                        "fail_mode": fail_mode})],
        connections=[Connection("shaft.flange_a", "motor.flange"), Connection("shaft.flange_b", "load.flange")],
        comm_step=H12)


@pytest.fixture(scope="module")
def example():
    from drivetrain.run.runner import assemble_scene
    from drivetrain.scene.load import load_scene

    scene = load_scene(EXAMPLE, ["time.duration_s=0.4", "time.settle_s=0.1"])
    return scene, assemble_scene(scene)


def test_example_pythonfmu_bit_identical(example, fmu_dir, monkeypatch, spy):
    """The default fmi backend (pythonfmu FMUs: the GIL is taken inside the C loop's calls), > 1 chunk."""
    _, spec = example
    a, b = both(monkeypatch, spy, lambda: simulate(spec, 0.4, 3000.0, fmu_dir=fmu_dir, keep_raw=True))
    assert len(spy) >= 2
    assert_raw_identical(a.raw, b.raw)


def test_example_native_bit_identical(example, native_cache_dir, fmu_dir, monkeypatch, spy):
    from drivetrain.fmu_build.native_line import native_fmus

    scene, spec = example
    paths, note = native_fmus(spec, native_cache_dir)
    assert note is None, note
    a, b = both(monkeypatch, spy, lambda: simulate(spec, 0.4, 3000.0, fmu_dir=fmu_dir,
                                                   fmu_paths=paths, keep_raw=True))
    assert_raw_identical(a.raw, b.raw)


@pytest.mark.parametrize("mode,status", [(1, "discard"), (2, "fatal")])
def test_failure_mid_run_same_error_and_partial(mt_fmus, monkeypatch, spy, mode, status):
    def run():
        with pytest.raises(CosimError) as ei:
            simulate(toy_spec(0.4 + H12 / 3, mode), 0.6, 3000.0, ["load.flange_w"], fmu_paths=mt_fmus,
                     keep_raw=True, final=["load.energy_dissipated"])
        return ei.value

    a, b = both(monkeypatch, spy, run)
    for e in (a, b):
        assert e.component == "load" and e.function == "fmi2DoStep" and status in str(e)
    assert (a.component, a.model, a.function, a.status, a.time) == (b.component, b.model, b.function, b.status,
                                                                    b.time)
    assert str(a) == str(b)
    pa, pb = a.partial, b.partial
    assert pa.n_steps == pb.n_steps == int(round((0.4 + H12) / H12)) and pb.status == "failed"
    assert_raw_identical(pa.raw, pb.raw)
    assert np.array_equal(pa.signals["load.flange_w"], pb.signals["load.flange_w"])
    assert pa.final == pb.final
    assert {k: v for k, v in pa.failure.items()} == {k: v for k, v in pb.failure.items()}


@pytest.mark.parametrize("call", ["set", "step", "get"])
def test_warning_status_continues(mt_fmus, monkeypatch, spy, call):
    """The shaft's SetReal / DoStep / GetReal returns fmi2Warning at one step: the run goes on and the rest
    of that step (the shaft's later calls, the load's) is done, giving the run without the warning."""
    rec = ["load.flange_w", "shaft.flange_a_tau"]
    ref = simulate(toy_spec(), 0.5, 3000.0, rec, fmu_paths=mt_fmus, keep_raw=True)
    spy.clear()
    k_warn = 4100            # in the second chunk
    orig_bind = FmiSlave.bind
    keep = []
    hits = []

    def warn(r):
        hits.append(r)
        return 1

    def bind(self, *args):
        orig_bind(self, *args)
        if self.name != "shaft":
            return
        st = {"n": 0}
        addr = lambda f: ctypes.cast(f, ctypes.c_void_p).value  # noqa: E731
        raw = list(self.raw_calls)
        if call == "step":
            real = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                                    ctypes.c_int)(addr(self._ds))

            @ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int)
            def wrapped(c, t, h, flag):
                r = real(c, t, h, flag)
                return warn(r) if (r == 0 and t == k_warn * H12) else r

            self.step_fn = functools.partial(wrapped, ctypes.c_void_p(self.c))
            raw[2] = addr(wrapped)
        else:
            idx, fn = (1, self._sr) if call == "set" else (3, self._gr)
            proto = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t,
                                     ctypes.c_void_p)
            real = proto(addr(fn))

            @proto
            def wrapped(c, vr, n, v):
                st["n"] += 1
                r = real(c, vr, n, v)
                return warn(r) if (r == 0 and st["n"] == k_warn + 1) else r

            part = self.set_fn if call == "set" else self.get_fn
            new = functools.partial(ctypes.CFUNCTYPE(ctypes.c_int)(addr(wrapped)), *part.args)
            if call == "set":
                self.set_fn = new
            else:
                self.get_fn = new
            raw[idx] = addr(wrapped)
        self.raw_calls = tuple(raw)
        keep.append(wrapped)

    monkeypatch.setattr(FmiSlave, "bind", bind)
    a, b = both(monkeypatch, spy, lambda: simulate(toy_spec(), 0.5, 3000.0, rec, fmu_paths=mt_fmus, keep_raw=True))
    assert a.status == b.status == "ok"
    assert_raw_identical(ref.raw, a.raw)
    assert_raw_identical(ref.raw, b.raw)
    assert len(hits) == 2          # one warning in each run
    assert spy == [(0, 4096), (4096, 6000), (k_warn + 1, 6000)]     # the C loop stopped there and resumed


def test_fallback_without_compiler(mt_fmus, monkeypatch, spy):
    monkeypatch.setenv("CC", "no-such-compiler-cc")
    assert stepper_mod.load_stepper() is None
    r = simulate(toy_spec(), 0.05, 3000.0, ["load.flange_w"], fmu_paths=mt_fmus)
    assert r.status == "ok" and not spy
