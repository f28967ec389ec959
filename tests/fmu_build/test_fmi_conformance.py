"""FMI 2.0 conformance of every FMU in both builds: every misuse that FMI calls an error returns
fmi2Error with a logged reason, the state machine is the Reference FMUs' one, and no call sequence crashes the
host. The pythonfmu FMUs (GearContact, FlexibleShaft, UpperTransmission, MotorLoad) are the FMI wrapper in front
of pythonfmu's export library (drivetrain.fmu_build.fmi_wrapper); the native builds are compiled C
(drivetrain.fmu_build.native_line / native_gear).

The cases of one FMU run in a subprocess, each on a fresh instance, printing one JSON line per finished case. A
crash ends the subprocess: the case it was in fails with the exit code, and the cases after it run in a new
subprocess (a crash fails its own case, never pytest). The FMU Compliance Checker (fmuCheck, Modelon) is not on
PyPI and not installed here: `fmpy validate` stands for it (the modelDescription checks), and the call checks
are these cases.
"""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from _fmi_instances import case_records

fmpy = pytest.importorskip("fmpy")

MODELS = ("GearContact", "FlexibleShaft", "UpperTransmission", "MotorLoad")
BUILDS = ("pythonfmu", "native")
OK, DISCARD, ERROR = 0, 2, 3

SCRIPT = textwrap.dedent(r'''
    import json, math, sys, warnings
    warnings.simplefilter("ignore")
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    from drivetrain.cosim.slaves import FmiCallbacks

    path, build, cases = sys.argv[1], sys.argv[2], sys.argv[3].split(",")
    md = read_model_description(path)
    DIR = extract(path)
    V = {v.name: v for v in md.modelVariables}
    H = 1.0 / 12000.0
    INPUT = next(v for v in md.modelVariables if v.causality == "input" and v.type == "Real")
    OUTPUTS = [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
    OUTPUT = next(v for v in md.modelVariables if v.causality == "output" and v.type == "Real")
    PARAM = next(v for v in md.modelVariables
                 if v.causality == "parameter" and v.type == "Real" and v.variability == "fixed")
    # the cheap gear: the analytic mesh needs no contact kernels (the native gear's fidelity is fixed by its build)
    START = {"fidelity": "analytic"} if md.modelName == "GearContact" and build == "pythonfmu" else {}
    CB = FmiCallbacks()

    def status(fn):
        try:
            fn()
            return 0
        except Exception as e:                      # fmpy raises for a status above fmi2Warning
            return int(getattr(e, "status", -1))

    def new(name, guid=None):
        f = FMU2Slave(guid=guid or md.guid, unzipDirectory=DIR, modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName=name)
        f.instantiate(loggingOn=True, callbacks=CB.struct)
        for k, v in START.items():
            f.setString([V[k].valueReference], [v])
        return f

    def ready(name, stepped=True):
        f = new(name)
        f.setupExperiment(startTime=0.0)
        f.enterInitializationMode()
        f.exitInitializationMode()
        if stepped:
            f.doStep(0.0, H)
        return f

    def free(f):
        f.fmi2FreeInstance(f.component)

    def c_unknown_vr_get(f):
        return [status(lambda: f.getReal([987654])), status(lambda: f.doStep(H, H))]

    def c_unknown_vr_set(f):
        return [status(lambda: f.setReal([987654], [1.0])), status(lambda: f.doStep(H, H))]

    def c_mistyped_vr(f):
        return [status(lambda: f.setInteger([INPUT.valueReference], [1])),
                status(lambda: f.getBoolean([INPUT.valueReference]))]

    def c_calls_go_on_after_refusals(f):
        # the pythonfmu FMUs crashed here before the FMI wrapper: getReal(bad), setReal(bad), a valid setReal
        return [status(lambda: f.getReal([987654])), status(lambda: f.setReal([987654], [1.0])),
                status(lambda: f.setReal([INPUT.valueReference], [1.0])), status(lambda: f.getReal(OUTPUTS)),
                status(lambda: f.getString([V["error"].valueReference])), status(lambda: f.reset()),
                status(lambda: f.setupExperiment(startTime=0.0)), status(lambda: f.enterInitializationMode()),
                status(lambda: f.exitInitializationMode()), status(lambda: f.doStep(0.0, H))]

    def c_set_an_output(f):
        return [status(lambda: f.setReal([OUTPUT.valueReference], [1.0]))]

    def c_fixed_parameter_after_init(f):
        return [status(lambda: f.setReal([PARAM.valueReference], [1.0])), status(lambda: f.doStep(H, H))]

    def c_nan_parameter(f):
        return [status(lambda: f.setReal([PARAM.valueReference], [math.nan]))]

    def c_nan_start_time(f):
        return [status(lambda: f.setupExperiment(startTime=math.nan))]

    def c_stop_before_start(f):
        return [status(lambda: f.setupExperiment(startTime=1.0, stopTime=0.5))]

    def c_setup_after_init(f):
        return [status(lambda: f.setupExperiment(startTime=0.0))]

    def c_get_before_init(f):
        return [status(lambda: f.getReal(OUTPUTS))]

    def c_enter_twice(f):
        return [status(lambda: f.setupExperiment(startTime=0.0)), status(lambda: f.enterInitializationMode()),
                status(lambda: f.enterInitializationMode()), status(lambda: f.exitInitializationMode()),
                status(lambda: f.doStep(0.0, H))]

    def c_exit_without_enter(f):
        return [status(lambda: f.exitInitializationMode())]

    def c_terminate_before_init(f):
        return [status(lambda: f.terminate())]

    def c_terminate_twice(f):
        return [status(lambda: f.terminate()), status(lambda: f.terminate())]

    def c_step_before_init(f):
        return [status(lambda: f.doStep(0.0, H))]

    def c_step_after_terminate(f):
        return [status(lambda: f.terminate()), status(lambda: f.doStep(H, H))]

    def c_set_after_terminate(f):
        return [status(lambda: f.terminate()), status(lambda: f.setReal([INPUT.valueReference], [1.0]))]

    def c_zero_step(f):
        return [status(lambda: f.doStep(H, 0.0))]

    def c_negative_step(f):
        return [status(lambda: f.doStep(H, -H)), status(lambda: f.doStep(H, H))]

    def c_nan_step(f):
        return [status(lambda: f.doStep(H, math.nan))]

    def c_nan_time(f):
        return [status(lambda: f.doStep(math.nan, H))]

    def c_time_jump(f):
        return [status(lambda: f.doStep(5.0, H))]

    def c_rollback_then_serialize(f):
        # the pythonfmu FMUs crashed at exit after this, before the FMI wrapper; serialization is declared by each build
        out = []
        s = f.getFMUstate()
        out.append(status(lambda: f.doStep(H, H)))
        out.append(status(lambda: f.setFMUstate(s)))
        out.append(status(lambda: f.doStep(H, H)))
        out.append(status(lambda: f.serializeFMUstate(s)))
        f.freeFMUstate(s)
        return out

    def c_normal_run(f):
        out = [status(lambda: f.doStep(k * H, H)) for k in range(1, 4)]
        return out + [status(lambda: f.getReal(OUTPUTS)), status(lambda: f.terminate())]

    CASES = {   # name: (instance: "new" | "ready", the case)
        "unknown_vr_get": ("ready", c_unknown_vr_get), "unknown_vr_set": ("ready", c_unknown_vr_set),
        "mistyped_vr": ("ready", c_mistyped_vr), "calls_go_on_after_refusals": ("ready", c_calls_go_on_after_refusals),
        "set_an_output": ("ready", c_set_an_output), "fixed_parameter_after_init": ("ready", c_fixed_parameter_after_init),
        "nan_parameter": ("new", c_nan_parameter), "nan_start_time": ("new", c_nan_start_time),
        "stop_before_start": ("new", c_stop_before_start), "setup_after_init": ("ready", c_setup_after_init),
        "get_before_init": ("new", c_get_before_init), "enter_twice": ("new", c_enter_twice),
        "exit_without_enter": ("new", c_exit_without_enter), "terminate_before_init": ("new", c_terminate_before_init),
        "terminate_twice": ("ready", c_terminate_twice), "step_before_init": ("new", c_step_before_init),
        "step_after_terminate": ("ready", c_step_after_terminate), "set_after_terminate": ("ready", c_set_after_terminate),
        "zero_step": ("ready", c_zero_step), "negative_step": ("ready", c_negative_step), "nan_step": ("ready", c_nan_step),
        "nan_time": ("ready", c_nan_time), "time_jump": ("ready", c_time_jump),
        "rollback_then_serialize": ("ready", c_rollback_then_serialize), "normal_run": ("ready", c_normal_run),
    }
    for name in cases:
        print(json.dumps({"start": name}), flush=True)
        if name == "wrong_guid_and_double_free":
            try:
                new(name + "_guid", guid="{00000000-0000-0000-0000-000000000000}")
                out = ["accepted"]
            except Exception:
                out = ["refused"]
            f = new(name)
            free(f)
            free(f)                 # a host's error: one instance freed twice
            g = ready(name + "_after")
            out.append(status(lambda: g.doStep(H, H)))
            free(g)
            log = list(CB.logs[name + "_guid"].lines) if name + "_guid" in CB.logs else []
        else:
            kind, fn = CASES[name]
            f = new(name) if kind == "new" else ready(name)
            out = fn(f)
            free(f)
            log = list(CB.logs[name].lines) if name in CB.logs else []
        print(json.dumps({"case": name, "statuses": out, "log": log}), flush=True)
    print(json.dumps({"done": True}), flush=True)
''')

#: every case's statuses (fmi2OK 0, fmi2Discard 2, fmi2Error 3), the same in both builds, and text the log must hold
EXPECT = {
    "unknown_vr_get": ([ERROR, ERROR], "987654 (no such variable)"),
    "unknown_vr_set": ([ERROR, ERROR], "987654 (no such variable)"),
    "mistyped_vr": ([ERROR, ERROR], "are not Integer variables"),
    "calls_go_on_after_refusals": ([ERROR, ERROR, OK, OK, OK, OK, OK, OK, OK, OK], "987654 (no such variable)"),
    "set_an_output": ([ERROR], "an output cannot be set"),
    "fixed_parameter_after_init": ([ERROR, ERROR], "after initialization: fixed parameters"),
    "nan_parameter": ([ERROR], "parameters that are not finite numbers"),
    "nan_start_time": ([ERROR], "the start time must be a finite time"),
    "stop_before_start": ([ERROR], "stop time 0.5 s before the start time 1.0 s"),
    "setup_after_init": ([ERROR], "fmi2SetupExperiment in step mode: allowed only after fmi2Instantiate or fmi2Reset"),
    "get_before_init": ([ERROR], "fmi2GetReal in the instantiated state"),
    "enter_twice": ([OK, OK, ERROR, OK, OK], "fmi2EnterInitializationMode in initialization mode"),
    "exit_without_enter": ([ERROR], "fmi2ExitInitializationMode in the instantiated state"),
    "terminate_before_init": ([ERROR], "fmi2Terminate in the instantiated state"),
    "terminate_twice": ([OK, ERROR], "fmi2Terminate in the terminated state"),
    "step_before_init": ([ERROR], "before fmi2ExitInitializationMode"),
    "step_after_terminate": ([OK, ERROR], "after fmi2Terminate"),
    "set_after_terminate": ([OK, ERROR], "fmi2SetReal in the terminated state"),
    "zero_step": ([ERROR], "with step size 0.0 s"),
    "negative_step": ([ERROR, ERROR], "with step size -8.333333333333333e-05 s"),
    "nan_step": ([ERROR], "with step size nan s"),
    "nan_time": ([ERROR], "must be a finite time"),
    "time_jump": ([ERROR], "the previous step ended at t = 8.33333333333e-05 s"),
    "rollback_then_serialize": (None, None),            # serialization: per build (below)
    "normal_run": ([OK] * 5, None),
    "wrong_guid_and_double_free": (["refused", OK], "does not match"),
}
#: the native builds serialize FMU states (canSerializeFMUstate="true"); pythonfmu's cannot, and say so
SERIALIZE = {"native": ([OK, OK, OK, OK], None),
             "pythonfmu": ([OK, OK, OK, ERROR], "FMU states cannot be serialized")}


def _run(path, build: str, cases: list[str]) -> dict:
    """{case: record}; a crashed case gets {"crash": rc, "stderr": ...} and the cases after it run anew."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    done: dict = {}
    todo = list(cases)
    while todo:
        r = subprocess.run([sys.executable, "-c", SCRIPT, str(path), build, ",".join(todo)], capture_output=True,
                           text=True, timeout=600, env=env)
        got, started = case_records(r.stdout)
        done.update(got)
        if r.returncode == 0:
            for c in todo:
                done.setdefault(c, {"crash": "no result", "stderr": r.stderr[-2000:]})
            break
        crashed = started if started is not None and started not in done else todo[0]
        done[crashed] = {"crash": r.returncode, "stderr": r.stderr[-2000:]}
        if all(c in done for c in todo):          # the crash came at exit: every case blamed, the last one named
            done[todo[-1]] = {"crash": f"rc {r.returncode} at process exit", "stderr": r.stderr[-2000:]}
            break
        todo = [c for c in todo if c not in done]
    return done


@pytest.fixture(scope="module")
def fmus(fmus_both_builds):
    """{(build, model): path}: both builds of the four FMUs (the session's, tests/conftest.py)."""
    from drivetrain.fmu_build.native_line import toolchain_problems

    if toolchain_problems():
        pytest.skip("no C toolchain (the FMI wrapper and the native builds need one): " + "; ".join(toolchain_problems()))
    return fmus_both_builds


@pytest.fixture(scope="module")
def results(fmus):
    cache: dict = {}

    def of(build, model):
        if (build, model) not in cache:
            cache[(build, model)] = _run(fmus[(build, model)], build, list(EXPECT))
        return cache[(build, model)]
    return of


@pytest.mark.parametrize("case", list(EXPECT))
@pytest.mark.parametrize("build", BUILDS)
@pytest.mark.parametrize("model", MODELS)
def test_misuse_is_an_error_with_a_reason_and_no_crash(results, model, build, case):
    rec = results(build, model)[case]
    assert "crash" not in rec, f"{build} {model} {case}: the host died ({rec['crash']})\n{rec['stderr']}"
    statuses, text = SERIALIZE[build] if case == "rollback_then_serialize" else EXPECT[case]
    assert rec["statuses"] == statuses, f"{build} {model} {case}: {rec['statuses']}\nlog: {rec['log']}"
    if text is not None:
        assert any(text in line for line in rec["log"]), f"{build} {model} {case}: {text!r} not in log {rec['log']}"
    # every refusal is logged with status error
    if ERROR in statuses:
        assert any(line.startswith("[error]") for line in rec["log"]), rec["log"]


def test_negative_step_message_names_the_step_not_a_time_mismatch(results):
    """The negative step was reported as "the previous step ended at t = 8.33e-05 s" at t = 8.33e-05 s."""
    for build in BUILDS:
        rec = results(build, "FlexibleShaft")["negative_step"]
        assert not any("previous step ended" in line for line in rec["log"]), (build, rec["log"])


@pytest.mark.parametrize("build", BUILDS)
@pytest.mark.parametrize("model", MODELS)
def test_fmpy_validate_is_clean(fmus, model, build):
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(fmus[(build, model)])) == []


def test_pythonfmu_fmus_are_wrapped(fmus):
    """binaries/linux64/<id>.so is the FMI wrapper; pythonfmu's export library is next to it, renamed."""
    import zipfile

    from fmu_runtime.guard import EXPORT_LIBRARY

    for m in MODELS:
        with zipfile.ZipFile(fmus[("pythonfmu", m)]) as z:
            names = set(z.namelist())
            assert {f"binaries/linux64/{m}.so", f"binaries/linux64/{EXPORT_LIBRARY.format(m)}"} <= names
            assert z.getinfo(f"binaries/linux64/{m}.so").file_size < 100_000       # the wrapper, not pythonfmu's
            assert "_fmi_wrapper_failed" not in z.read("modelDescription.xml").decode()


def test_two_source_fmus_link_into_one_binary_and_both_run(fmus, tmp_path):
    """FMI2_FUNCTION_PREFIX is honoured by the shipped sources: a native gear and a native shaft, each compiled with
    its own prefix, link into one shared library (nothing unprefixed is exported); both FMUs are instantiated
    from it and step (the gear reads its map from its own resources). No -fvisibility=hidden: the standard headers
    leave FMI2_Export empty when a prefix is set (a prefixed build is meant for static linking), so a hidden
    default would export nothing."""
    import ctypes
    import pathlib
    import zipfile

    from fmpy import read_model_description

    from drivetrain.cosim.slaves import FmiCallbacks

    objs, units = [], {}
    for m, prefix in (("GearContact", "Gear_"), ("FlexibleShaft", "Shaft_")):
        root = tmp_path / m
        with zipfile.ZipFile(fmus[("native", m)]) as z:
            z.extractall(root)
        units[prefix] = (root, read_model_description(str(fmus[("native", m)])))
        for c in sorted((root / "sources").glob("*.c")):
            obj = tmp_path / f"{m}_{c.stem}.o"
            subprocess.run(["gcc", "-O2", "-fPIC", "-std=c99", "-ffp-contract=off",
                            f"-DFMI2_FUNCTION_PREFIX={prefix}", f"-I{root / 'sources'}", "-c", str(c), "-o", str(obj)],
                           check=True)
            objs.append(str(obj))
    lib = tmp_path / "both.so"
    subprocess.run(["gcc", "-shared", *objs, "-o", str(lib), "-lm"], check=True)
    exported = subprocess.run(["nm", "-D", "--defined-only", str(lib)], capture_output=True, text=True).stdout
    names = [ln.split()[-1] for ln in exported.splitlines() if ln.strip()]
    assert names and all(n.startswith(("Gear_", "Shaft_")) for n in names if "fmi2" in n or "GC_" in n), names
    assert not any(n.startswith("fmi2") for n in names)
    dll = ctypes.CDLL(str(lib))
    cb = FmiCallbacks()
    for prefix, (root, md) in units.items():
        fn = lambda name: getattr(dll, prefix + name)  # noqa: E731
        fn("fmi2Instantiate").restype = ctypes.c_void_p
        c = fn("fmi2Instantiate")(prefix.encode(), 1, md.guid.encode(), pathlib.Path(root, "resources").as_uri().encode(),
                                  ctypes.byref(cb.struct), 0, 0)
        assert c, prefix
        c = ctypes.c_void_p(c)
        fn("fmi2DoStep").argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int]
        fn("fmi2SetupExperiment").argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_double, ctypes.c_double,
                                              ctypes.c_int, ctypes.c_double]
        assert fn("fmi2SetupExperiment")(c, 0, 0.0, 0.0, 0, 0.0) == OK
        assert fn("fmi2EnterInitializationMode")(c) == OK and fn("fmi2ExitInitializationMode")(c) == OK
        assert [fn("fmi2DoStep")(c, k * 1e-4, 1e-4, 1) for k in range(3)] == [OK] * 3, prefix
        out = next(v.valueReference for v in md.modelVariables if v.causality == "output" and v.type == "Real")
        vr, val = (ctypes.c_uint * 1)(out), (ctypes.c_double * 1)()
        assert fn("fmi2GetReal")(c, vr, ctypes.c_size_t(1), val) == OK
        assert fn("fmi2Terminate")(c) == OK
        fn("fmi2FreeInstance")(c)


def test_without_a_compiler_the_fmu_keeps_pythonfmus_library_and_the_build_warns(tmp_path, monkeypatch):
    """No C compiler at build time: the FMU is built with pythonfmu's bare export library and a warning says so
    (docs/FMU.md, Build)."""
    import zipfile

    from drivetrain.fmu_build.build import build_all

    monkeypatch.setenv("CC", "no-such-cc-here")
    with pytest.warns(UserWarning, match="built WITHOUT the FMI wrapper.*no-such-cc-here"):
        (fmu,) = build_all(tmp_path, only=["MotorLoad"])
    assert fmu.name == "MotorLoad.fmu"                      # only the model asked for
    with zipfile.ZipFile(fmu) as z:
        assert "binaries/linux64/MotorLoad.so" in z.namelist()
        assert not any("pythonfmu-export" in n for n in z.namelist())
