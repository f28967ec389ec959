"""The Python-free FlexibleShaft, UpperTransmission and MotorLoad (drivetrain.fmu_build.native_line): model description,
no libpython, agreement with the pythonfmu FMUs (bit for bit), errors, FMU state rollback, the system swap.

The native FMUs of the example are built once per session (native_fmus into conftest's native_cache_dir,
shared with test_stepper); the pythonfmu ones once per module through drivetrain.cosim.ensure_fmus."""
import math
import shutil
import subprocess
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy.fmi1 import FMICallException  # noqa: E402
from _fmi_instances import KEEP, open_instance  # noqa: E402
from _fmi_instances import set_values as _set  # noqa: E402

from drivetrain.models import fmishell  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"
MODELS = ("FlexibleShaft", "UpperTransmission", "MotorLoad")
H = 1.0 / 12000.0
N_STEPS = 400
_KEEP = KEEP           # pythonfmu instances stay loaded until exit (docs/FMU.md)
_EXTRACTED = {}


@pytest.fixture(scope="module")
def native_example(native_cache_dir):
    """The four native FMUs of the example scene (native_fmus: build_native_line for the three line models,
    build_native_gear for the gear's map), from the session's cache of native builds."""
    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed")
    from drivetrain.fmu_build.native_line import native_fmus
    from drivetrain.run.runner import assemble_scene
    from drivetrain.scene.load import load_scene

    paths, note = native_fmus(assemble_scene(load_scene(EXAMPLE)), native_cache_dir)
    assert note is None and set(paths) == {*MODELS, "GearContact"}, (paths, note)
    return paths


@pytest.fixture(scope="module")
def native(native_example):
    return {m: native_example[m] for m in MODELS}


@pytest.fixture(scope="module")
def pyfmu_dir(fmu_dir, pythonfmu_fmus):
    """The session's FMU directory, its four pythonfmu FMUs built (tests/conftest.py)."""
    return fmu_dir


@pytest.fixture(scope="module")
def pyfmu(pyfmu_dir):
    return {m: pyfmu_dir / f"{m}.fmu" for m in MODELS}


def _extract_once(path):
    """One extraction per FMU and process (pythonfmu imports the slave module by name)."""
    key = str(path)
    if key not in _EXTRACTED:
        _EXTRACTED[key] = fmpy.extract(str(path))
    return _EXTRACTED[key]


def _open(path, params=None, name="x"):
    """An instance (log lines in ``s.log_lines()``) and its variables by name; parameters set before
    initialization."""
    return open_instance(path, params, name, _extract_once(path))


def _inputs(model, t, disturbance=False):
    """Every input of the model at t (fmishell.port_inputs order): ramps and sines, a few hundred steps.
    MotorLoad's motor_torque_disturbance is 0 unless ``disturbance`` (then a sine around an offset)."""
    s1, s2 = math.sin(2 * math.pi * 70.0 * t), math.sin(2 * math.pi * 23.0 * t + 0.4)
    if model == "FlexibleShaft":
        w = 100.0 + 400.0 * t + 5.0 * s1
        phi = 100.0 * t + 200.0 * t * t - 5.0 / (2 * math.pi * 70.0) * (math.cos(2 * math.pi * 70.0 * t) - 1.0)
        return [2.0 + 30.0 * t + 1.5 * s2, phi, w]
    if model == "UpperTransmission":
        return [3.0 + 40.0 * t + 2.0 * s1, -(6.0 + 90.0 * t + 3.0 * s2)]
    w = 20.0 + 1500.0 * t + 3.0 * s2
    phi = 20.0 * t + 750.0 * t * t
    d = 0.15 + 0.25 * math.sin(2 * math.pi * 310.0 * t + 0.2) if disturbance else 0.0
    return [phi, w, -(1.0 + 20.0 * t + 0.5 * s1), 200.0 + 3.0e4 * t + 50.0 * s2, 0.5 + 10.0 * t + 0.3 * s1, d]


def _outputs(vr):
    return [n for n, v in vr.items() if v.causality == "output" and v.type == "Real"]


def _drive(s, vr, model, n, t0=0.0, init=True, init_params=None, disturbance=False):
    """Initialize (inputs at t0; ``init_params`` set in initialization mode), then n steps; rows of every
    Real output (the initial values first when init). ``disturbance``: see _inputs."""
    names = fmishell.port_inputs(model)
    vin = [vr[k].valueReference for k in names]
    vout = [vr[k].valueReference for k in _outputs(vr)]
    rows = []
    if init:
        s.setupExperiment(startTime=t0)
        s.enterInitializationMode()
        if init_params:
            _set(s, vr, init_params)
        s.setReal(vin, _inputs(model, t0, disturbance))
        rows.append(s.getReal(vout))
        s.exitInitializationMode()
        rows.append(s.getReal(vout))
    for k in range(n):
        t = t0 + k * H
        s.setReal(vin, _inputs(model, t, disturbance))
        s.doStep(t, H)
        rows.append(s.getReal(vout))
    return np.array(rows)


def _rel(a, b):
    """Largest difference of each column relative to the column's largest magnitude."""
    scale = np.maximum(np.max(np.abs(b), axis=0), 1e-300)
    return np.max(np.abs(a - b), axis=0) / scale


def _md(path):
    with zipfile.ZipFile(path) as z:
        return ET.fromstring(z.read("modelDescription.xml")), z.namelist()


# ---- the model description ---------------------------------------------------------------------------------

@pytest.mark.parametrize("model", MODELS)
def test_validates_and_declares_like_the_pythonfmu(native, pyfmu, model):
    from fmpy.validation import validate_fmu

    path = native[model]
    assert validate_fmu(str(path)) == []
    root, names = _md(path)
    cs = root.find("CoSimulation")
    assert cs.get("needsExecutionTool") == "false"
    assert cs.get("canGetAndSetFMUstate") == "true" and cs.get("canSerializeFMUstate") == "true"
    assert {"sources/line_native.c", "sources/coupling_correction.h", "sources/line_build.h",
            "sources/fmi2Functions.h", f"binaries/linux64/{model}.so"} <= set(names)
    assert not any(n.endswith(".py") for n in names)
    proot, _ = _md(pyfmu[model])

    def sig(r):
        out = {}
        for sv in r.find("ModelVariables"):
            t = sv[0]
            start = t.get("start")
            if t.tag in ("Real", "Integer") and start is not None:
                start = float(start)
            out[sv.get("name")] = (sv.get("valueReference"), sv.get("causality"), sv.get("variability"),
                                   sv.get("initial"), t.tag, t.get("unit"), start, sv.get("description"))
        return out

    a, b = sig(root), sig(proot)
    assert a == b
    assert "error" in a and "energy_stored" in a and "energy_supplied" in a
    assert ("loss_torque" if model == "UpperTransmission" else "coupling_energy_error") in a


def test_binary_has_no_libpython(native, tmp_path):
    if shutil.which("ldd") is None:
        pytest.skip("ldd not available")
    for model, path in native.items():
        with zipfile.ZipFile(path) as z:
            z.extract(f"binaries/linux64/{model}.so", tmp_path)
        out = subprocess.run(["ldd", str(tmp_path / f"binaries/linux64/{model}.so")], capture_output=True,
                             text=True, check=True).stdout
        assert "libc.so" in out and "python" not in out.lower(), out
        libs = {ln.split()[0] for ln in out.splitlines() if ln.strip()}
        assert {x.split(".so")[0] for x in libs} <= {"linux-vdso", "libm", "libc", "/lib64/ld-linux-x86-64"}, libs


# ---- agreement with the pythonfmu FMUs ---------------------------------------------------------------------

CASES = {
    "FlexibleShaft": {
        "defaults": {},
        "consistent_rigid_coupling_end": {"mass_model": 1, "k_c": 0.0, "n_elements": 6, "output_torque": "end",
                                          "energy_correction": False, "tau0": 1.5, "w0": 100.0, "phi0": 0.2},
        "no_transducer": {"k_t": -1.0, "n_elements": 1, "max_substep": 3e-6, "d_shaft": 0.02},
        "node_start": {"k_c": 0.0, "n_elements": 3, "tau0": 0.7,
                       "node_phi_start": "0.01, -0.02,0.03 , 1e-3", "node_w_start": "1, 2, -3.5, 0"},
    },
    "UpperTransmission": {
        "defaults": {},
        "sensor_and_ratio": {"J_sensor": 2e-3, "ratio": 2.5, "loss_wc": 0.0, "loss_a": 0.05, "w0": 5.0,
                             "phi0": 1.0, "max_substep": 3e-6},
        "node_start": {"node_phi_start": " 0.25 ", "node_w_start": "-7.5"},
    },
    "MotorLoad": {
        "defaults": {},
        "viscous_profiles_limit_end": {"load_mode": 1, "speed_profile": "0:0; 0.01:1500, 0.02 : 1200",
                                       "load_profile": "0:1; 0.02:3", "tau_max": 2.0, "output_torque": "end",
                                       "energy_correction": False, "J_load_motor": 1e-4, "w0": 10.0, "tau0": 0.3,
                                       "load_w_nom": 50.0},
        "torque_load_limit": {"tau_max": 0.4, "Kp": 0.5, "pg_wc": 0.0, "load_w_reg": 0.0, "w0_load": 3.0},
        "node_start": {"w0": 10.0, "tau0": 0.3, "node_phi_start": "0.1, 0.05, -0.2", "node_w_start": "11, 9.5, 0.8"},
    },
}
#: outputs numpy computes in the Python (agreement to rounding, see below)
ROUNDING = ("energy_stored", "loss_torque")
PARAMS = [(m, c) for m in MODELS for c in CASES[m]]


@pytest.mark.parametrize("model, case", PARAMS, ids=[f"{m}-{c}" for m, c in PARAMS])
def test_matches_the_pythonfmu_bit_for_bit(native, pyfmu, model, case):
    """Driven by the same inputs (and, for one instance, the parameters set in initialization mode, where the
    pythonfmu FMU builds again), every Real output at every step is the pythonfmu FMU's, bit for bit: the
    kernel and the bookkeeping run the same operations in the same order (and gcc and numba's LLVM do not
    contract to FMA). Two outputs are computed by numpy in the Python, by libm here, and agree to rounding
    (<= 1e-12 relative): energy_stored (numpy's dot, BLAS: its summation order may differ; measured:
    identical) and UpperTransmission's loss_torque (np.tanh, numpy's own SIMD tanh, against libm's tanh the
    kernel uses in both; measured: <= 2.0e-16)."""
    params = CASES[model][case]
    a = _drive(*_open(native[model], params), model, N_STEPS)
    b = _drive(*_open(pyfmu[model], params), model, N_STEPS)
    s, vr = _open(native[model])
    c = _drive(s, vr, model, N_STEPS, init_params=params)           # the parameters set in initialization mode
    names = _outputs(vr)
    _assert_bit_for_bit(a, b, names)
    assert np.array_equal(a[1:], c[1:])
    if case == "torque_load_limit" or case == "viscous_profiles_limit_end":
        tm = b[2:, names.index("motor_torque")]
        assert np.max(np.abs(tm)) == pytest.approx(params["tau_max"]), "the torque limit was hit"


def _assert_bit_for_bit(a, b, names):
    """The native FMU's outputs ``a`` are the pythonfmu FMU's ``b``: finite, bit for bit but for the ROUNDING
    outputs, those within 1e-12 relative."""
    assert np.all(np.isfinite(a)) and np.all(np.isfinite(b))
    rel = dict(zip(names, _rel(a, b)))
    assert max(rel.values()) <= 1e-12, rel
    exact = [i for i, n in enumerate(names) if n not in ROUNDING]
    assert np.array_equal(a[:, exact], b[:, exact]), {n: v for n, v in rel.items() if v}


@pytest.mark.parametrize("case", ["defaults", "torque_load_limit", "viscous_profiles_limit_end"])
def test_motor_torque_disturbance_matches_the_pythonfmu_bit_for_bit(native, pyfmu, case):
    """MotorLoad driven with a nonzero motor_torque_disturbance (a sine around an offset, also while the PI's
    torque limit is hit): the native FMU's outputs are the pythonfmu FMU's bit for bit (energy_stored to
    rounding, as above), and the disturbance does move them (against the same run without it)."""
    model = "MotorLoad"
    params = CASES[model][case]
    a = _drive(*_open(native[model], params), model, N_STEPS, disturbance=True)
    b = _drive(*_open(pyfmu[model], params), model, N_STEPS, disturbance=True)
    z = _drive(*_open(native[model], params), model, N_STEPS)
    s, vr = _open(native[model])
    names = _outputs(vr)
    _assert_bit_for_bit(a, b, names)
    for n in ("motor_w", "motor_torque", "energy_supplied"):
        assert not np.array_equal(a[2:, names.index(n)], z[2:, names.index(n)]), n
    if case != "defaults":
        # the limit bounds the PI's share only: the total exceeds tau_max by up to the disturbance
        tm = a[2:, names.index("motor_torque")]
        assert np.max(np.abs(tm)) > params["tau_max"] + 0.05


@pytest.mark.parametrize("model, name", [("FlexibleShaft", "J_a"), ("UpperTransmission", "loss_c"),
                                         ("MotorLoad", "k_c2")])
def test_the_comparison_sees_a_wrong_parameter(native, pyfmu, model, name):
    """The comparison has teeth: one parameter off by 1e-9 relative in one FMU breaks it."""
    from drivetrain.models.components import COMPONENTS

    default = getattr(COMPONENTS[model][1](), name)
    a = _drive(*_open(native[model]), model, N_STEPS)
    b = _drive(*_open(pyfmu[model], {name: default * (1 + 1e-9)}), model, N_STEPS)
    assert max(_rel(a, b)) > 1e-11


# ---- errors ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("model", MODELS)
def test_nan_input_is_an_error_status_nan_outputs_and_an_error_text(native, pyfmu, model):
    errors = []
    name = fmishell.port_inputs(model)[-1]
    for path in (pyfmu[model], native[model]):
        s, vr = _open(path)
        _drive(s, vr, model, 10)
        s.setReal([vr[name].valueReference], [float("nan")])
        with pytest.raises(FMICallException) as exc:
            s.doStep(10 * H, H)
        assert exc.value.status == 2                               # fmi2Discard
        errors.append(s.getString([vr["error"].valueReference])[0].decode())
        out = s.getReal([vr[n].valueReference for n in _outputs(vr)])
        assert all(math.isnan(v) for v in out)
        with pytest.raises(FMICallException):
            s.doStep(11 * H, H)
    assert errors[0] == errors[1]
    assert errors[1] == (f"{model}: do_step at t = 0.000833333333 s failed: non-finite input at t = "
                         f"0.000833333333 s: {{'{name}': nan}}")
    assert f"{model} is in the error state: {errors[1]}" in s.log_lines()


BAD = [("FlexibleShaft", {"J_a": 0.0}, "J_a must be > 0"),
       ("FlexibleShaft", {"output_torque": "predicted"},
        "output_torque must be one of ('mean', 'end'), got 'predicted'"),
       ("FlexibleShaft", {"d_t": -1.0}, "c must be finite and >= 0, got [-1.0, "),
       ("UpperTransmission", {"ratio": -3.0}, "ratio must be > 0 and J_in, J_out >= 0"),
       ("MotorLoad", {"speed_profile": "0:0; 1:abc"}, "could not convert string to float: 'abc'"),
       ("MotorLoad", {"load_profile": "0:1; 0:2"}, "profile '0:1; 0:2': expected 't0:v0; t1:v1; ...' with "
                                                    "increasing times"),
       ("MotorLoad", {"Ti": 0.0}, "motor: Kp, Ti, Ni must be > 0 and tau_max >= 0"),
       ("MotorLoad", {"node_phi_start": "1, 2"}, "node_phi_start: got 2 values, expected 3 comma-separated values, "
                                                 "one per node (motor, flywheel, load)"),
       ("MotorLoad", {"node_w_start": "1, x, 3"}, "node_w_start: value 2 of 3 ('x') is not a finite number; expected "
                                                  "3 comma-separated values, one per node (motor, flywheel, load)"),
       ("FlexibleShaft", {"node_w_start": "0, 0, nan, 0, 0, 0"},
        "node_w_start: value 3 of 6 ('nan') is not a finite number; expected 6 comma-separated values, one per node "
        "(hub_a, hub_b, shaft_0, shaft_1, shaft_2, shaft_3)"),
       ("FlexibleShaft", {"k_c": 0.0, "n_elements": 2, "node_phi_start": "1,2,3,4"},
        "node_phi_start: got 4 values, expected 3 comma-separated values, one per node (hub_a, hub_b, shaft_1)"),
       ("UpperTransmission", {"node_phi_start": "1,"}, "node_phi_start: got 2 values, expected 1 comma-separated "
                                                       "values, one per node (n0)")]


@pytest.mark.parametrize("model, params, text", BAD, ids=[f"{m}-{next(iter(p))}" for m, p, _ in BAD])
def test_a_bad_parameter_is_an_error_message_not_a_crash(native, pyfmu, model, params, text):
    """Set before initialization or in it: the same message as the pythonfmu FMU (initialization failed:
    ValueError: ...), NaN outputs, fmi2ExitInitializationMode and the first step refused."""
    errors = []
    for path in (pyfmu[model], native[model]):
        for when in ("before", "in"):
            s, vr = _open(path, params if when == "before" else None)
            s.setupExperiment(startTime=0.0)
            s.enterInitializationMode()
            if when == "in":
                _set(s, vr, params)
                s.getReal([vr[_outputs(vr)[0]].valueReference])           # refresh: rebuilt here
            with pytest.raises(FMICallException):                        # its work failed: fmi2Error (issue 45)
                s.exitInitializationMode()
            with pytest.raises(FMICallException):
                s.doStep(0.0, H)
            errors.append(s.getString([vr["error"].valueReference])[0].decode())
            assert math.isnan(s.getReal([vr[_outputs(vr)[0]].valueReference])[0])
    assert len(set(errors)) == 1, errors
    assert errors[0].startswith(f"{model}: initialization failed: ValueError: ") and text in errors[0], errors


@pytest.mark.parametrize("model, name, value, bounds", [
    ("FlexibleShaft", "n_elements", 0, ("1", "1000")), ("FlexibleShaft", "n_elements", 1001, ("1", "1000")),
    ("MotorLoad", "load_mode", 2, ("0", "1")), ("MotorLoad", "load_mode", -1, ("0", "1")),
    ("FlexibleShaft", "mass_model", 2, ("0", "1"))])
def test_an_integer_outside_its_declared_range_is_refused_when_set(native, pyfmu, model, name, value, bounds):
    """n_elements declares 1..1000, load_mode and mass_model 0..1 (the range the component
    checks; mass_model 2 was taken as lumped without a word):
    both builds refuse a value outside at fmi2SetInteger, not at initialization (a value of 2^31 - 1 used
    to hang the host building its chain)."""
    for path in (pyfmu[model], native[model]):
        s, vr = _open(path)
        assert (vr[name].min, vr[name].max) == bounds
        with pytest.raises(FMICallException):
            s.setInteger([vr[name].valueReference], [value])


def test_parameters_set_in_initialization_mode_reach_the_outputs_read_there(native, pyfmu):
    """Outputs read in initialization mode follow the parameters set there (the model is built again)."""
    for path in (native["FlexibleShaft"], pyfmu["FlexibleShaft"]):
        s, vr = _open(path)
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        get = lambda n: s.getReal([vr[n].valueReference])[0]  # noqa: E731
        assert get("flange_a_w") == 0.0
        _set(s, vr, {"w0": 12.5, "tau0": 2.0})
        assert get("flange_a_w") == 12.5 and get("torque_sensor") == 2.0


def test_time_jumps_are_refused_with_the_gear_wording(native):
    s, vr = _open(native["UpperTransmission"])
    _drive(s, vr, "UpperTransmission", 3)
    with pytest.raises(FMICallException):
        s.doStep(5.0, H)
    text = s.log_lines()
    assert ("UpperTransmission: fmi2DoStep at t = 5 s but the previous step ended at t = 0.00025 s (communication "
            "points must follow each other; to go back, restore an FMU state); the instance is now in its error "
            "state") in text


@pytest.mark.parametrize("model", MODELS)
def test_fmu_state_rollback_is_bit_identical(native, model):
    s, vr = _open(native[model], CASES[model][list(CASES[model])[-1]])
    _drive(s, vr, model, 100)
    state = s.getFMUstate()
    blob = s.serializeFMUstate(state)
    first = _drive(s, vr, model, 60, t0=100 * H, init=False)
    s.setFMUstate(state)
    again = _drive(s, vr, model, 60, t0=100 * H, init=False)
    assert np.array_equal(first, again)
    s.setFMUstate(s.deSerializeFMUstate(blob))
    assert np.array_equal(first, _drive(s, vr, model, 60, t0=100 * H, init=False))
    s.freeFMUstate(state)


@pytest.mark.parametrize("model", MODELS)
def test_hostile_calls(native, model):
    """The hostile FMI calls of tests/fmu_build/test_fmu_hostile.py: the same outcomes and log texts as the pythonfmu
    FMUs."""
    import json
    import os
    import sys

    from test_fmu_hostile import EXPECT, NATIVE_EXPECT, PYTHONFMU_ONLY, SCRIPT, not_applicable

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(native[model])], capture_output=True, text=True,
                       timeout=300, env=env)
    done = {rec["case"]: rec for rec in map(json.loads, filter(None, r.stdout.splitlines())) if "case" in rec}
    assert set(done) == set(EXPECT), (r.returncode, r.stderr[-2000:])
    for case, (outcomes, text) in {**EXPECT, **NATIVE_EXPECT}.items():
        if case in PYTHONFMU_ONLY:
            continue
        rec = done[case]
        if rec["outcomes"] == ["n/a"]:
            assert not_applicable(model, case), (model, case)
            continue
        assert rec["outcomes"] == outcomes, (case, rec)
        assert text is None or any(text in line for line in rec["log"]), (case, rec["log"])
        if outcomes.count("refused") == 0:
            assert not any(line.startswith("[error]") for line in rec["log"]), (case, rec["log"])


@pytest.mark.parametrize("model", MODELS)
def test_a_wrong_guid_and_a_second_free_do_not_hurt_the_host(native, model):
    from test_fmu_hostile import check_lifecycle

    check_lifecycle(native[model])


# ---- building, caching, the command line -------------------------------------------------------------------

def test_native_fmus_are_cached_and_a_non_table_gear_keeps_its_pythonfmu(tmp_path):
    """drivetrain run --native's cache: the three line FMUs once, found again by their fingerprints; a scene
    whose gear is not fidelity table gets the three and a note (and build-native refuses it)."""
    from drivetrain.fmu_build.native_line import native_fmus
    from drivetrain.run.runner import assemble_scene
    from drivetrain.scene.load import load_scene

    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed")
    scene = assemble_scene(load_scene(EXAMPLE, ["time.duration_s=0.1", "effects.mesh_contact=analytic"]))
    paths, note = native_fmus(scene, tmp_path)
    assert set(paths) == set(MODELS)
    assert "fidelity 'analytic'" in note and "uses the pythonfmu GearContact" in note
    stamps = {m: p.stat().st_mtime_ns for m, p in paths.items()}
    again, _ = native_fmus(scene, tmp_path)
    assert again == paths and {m: p.stat().st_mtime_ns for m, p in again.items()} == stamps
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in paths.values())


def test_fingerprints_are_computed_once_per_process_and_anew_for_an_edited_source(native_example, native_cache_dir,
                                                                                   tmp_path, monkeypatch):
    """native_fmus asks for the four fingerprints on every run (sweeps, tests): the process computes each once
    (the value a fresh computation gives), again for other inputs (compiler, the gear's fixed parameters) and
    when a file it hashes changes; an operating point of the same gear is the same gear key."""
    import os

    import drivetrain.fmu_build.native_line as NL
    from drivetrain.run.runner import assemble_scene
    from drivetrain.scene.load import load_scene

    monkeypatch.setattr(NL, "_FINGERPRINTS", {})
    computed = []
    line_now, gear_now = NL._line_fingerprint_now, NL._gear_fingerprint_now
    monkeypatch.setattr(NL, "_line_fingerprint_now", lambda m, cc: computed.append(m) or line_now(m, cc))
    monkeypatch.setattr(NL, "_gear_fingerprint_now", lambda *a: computed.append("GearContact") or gear_now(*a))
    cc = os.environ.get("CC", "gcc")

    paths, _ = NL.native_fmus(assemble_scene(load_scene(EXAMPLE)), native_cache_dir)
    assert paths == native_example and sorted(computed) == sorted([*MODELS, "GearContact"])
    for m in MODELS:
        assert paths[m].name == f"{m}-{line_now(m, cc)[:16]}.fmu"
    other_point = load_scene(EXAMPLE, ["operating_point.drive_speed_rpm=900", "operating_point.load_torque_Nm=0.8"])
    for scene in (load_scene(EXAMPLE), other_point):
        assert NL.native_fmus(assemble_scene(scene), native_cache_dir)[0] == paths
    assert len(computed) == 4                                   # nothing computed again
    fixed = NL.build_fixed(NL.system_gear(assemble_scene(load_scene(EXAMPLE)))[0])
    assert NL._gear_fingerprint({**fixed, "z_pinion": 16}) != NL._gear_fingerprint(fixed)
    assert NL.line_fingerprint("MotorLoad", "no-such-cc") != NL.line_fingerprint("MotorLoad", cc)
    assert computed[4:] == ["GearContact", "MotorLoad"]

    # the same sources elsewhere: computed again (other files), the same value; an edited source: another
    src = tmp_path / "native"
    src.mkdir()
    (src / NL.C_SOURCE).write_bytes((NL.NATIVE_DIR / NL.C_SOURCE).read_bytes())
    monkeypatch.setattr(NL, "NATIVE_DIR", src)
    before = NL.line_fingerprint("MotorLoad", cc)
    assert len(computed) == 7 and paths["MotorLoad"].name == f"MotorLoad-{before[:16]}.fmu"
    assert NL.line_fingerprint("MotorLoad", cc) == before and len(computed) == 7
    with open(src / NL.C_SOURCE, "a") as f:
        f.write("/* edited */\n")
    edited = NL.line_fingerprint("MotorLoad", cc)
    assert edited != before and NL.line_fingerprint("MotorLoad", cc) == edited and len(computed) == 8


def test_cli_refusals(tmp_path, capsys):
    from drivetrain.cli import main

    rc = main(["build-native", str(EXAMPLE), "--set", "effects.mesh_contact=analytic", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert rc == 2 and "implements fidelity 'table', mode 'stage' only" in err and "Traceback" not in err
    rc = main(["run", str(EXAMPLE), "--native", "--backend", "inprocess", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "runs compiled FMUs through FMI: not with --backend 'inprocess'" in err


# ---- the system --------------------------------------------------------------------------------------------

def test_example_system_with_all_four_native_fmus(native, native_example, pyfmu_dir):
    """0.5 s of the example scene through our master: all four FMUs native (the gear: build_native_gear of the
    parameters that shape its map, as backend native builds it; the master sets the others) against the
    pythonfmu FMUs; every recorded torque within 1e-9 relative (the native gear agrees to rounding; measured
    over 1 s: <= 2.3e-10), and with the three native line FMUs alone the very same run."""
    from drivetrain.cosim import simulate
    from drivetrain.run.runner import assemble_scene
    from drivetrain.scene.load import load_scene

    scene = load_scene(EXAMPLE, ["time.duration_s=0.5"])
    spec = assemble_scene(scene)
    paths = {**native, "GearContact": native_example["GearContact"]}
    rec = ["gear.flange_a_tau", "gear.flange_b_tau", "drive_shaft.flange_a_tau", "drive_shaft.flange_b_tau",
           "motors.drive_tau", "motors.load_tau", "upper.flange_a_tau", "upper.flange_b_tau",
           "motors.motor_torque", "drive_shaft.torque_sensor", "upper.torque_sensor", "motors.coupling_torque"]
    models = {c.name: c.model for c in spec.components}
    rec = [r for r in rec if r.split(".")[0] in models]
    assert len({models[r.split(".")[0]] for r in rec}) == 4, (rec, models)
    nat = simulate(spec, 0.5, 3000.0, rec, fmu_dir=pyfmu_dir, fmu_paths=paths, keep_raw=True)
    ref = simulate(spec, 0.5, 3000.0, rec, fmu_dir=pyfmu_dir, keep_raw=True)
    lines = simulate(spec, 0.5, 3000.0, rec, fmu_dir=pyfmu_dir, fmu_paths=native, keep_raw=True)
    used = {Path(f["path"]) for f in nat.fmus}
    assert set(paths.values()) <= used, used
    worst = {}
    for name in rec:
        a, b = nat.raw[name], ref.raw[name]
        assert len(a) == len(b) and len(a) > 1000
        worst[name] = float(np.max(np.abs(a - b)) / np.max(np.abs(b)))
        # the three native line FMUs with the pythonfmu gear: the pythonfmu system's run, bit for bit
        assert np.array_equal(lines.raw[name], b), name
    assert max(worst.values()) <= 1e-9, worst


def test_backend_native_builds_one_gear_per_map_and_runs_like_fmi(pyfmu_dir, tmp_path):
    """run_scene(backend="native") (drivetrain run --native, and every many-run command's --backend native):
    two operating points of one gear share one native GearContact (its cache key is what shapes the map, the
    start state is set per run), and the run gives the pythonfmu run's torques."""
    from drivetrain.run.runner import run_scene
    from drivetrain.scene.load import load_scene

    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed")
    over = ["time.duration_s=0.2", "time.settle_s=0.1"]
    a = load_scene(EXAMPLE, over)
    b = load_scene(EXAMPLE, over + ["operating_point.drive_speed_rpm=900", "operating_point.load_torque_Nm=0.8"])
    fmu_dir = tmp_path / "fmus"
    ra = run_scene(a, None, backend="native", progress=False, fmu_dir=fmu_dir, plots=False)
    rb = run_scene(b, None, backend="native", progress=False, fmu_dir=fmu_dir, plots=False)
    gears = sorted((fmu_dir / "native").glob("GearContact-*.fmu"))
    assert len(gears) == 1, gears
    assert ra.summary["backend"] == "native" and ra.summary["time_breakdown_s"]["native_build"] > 0
    assert rb.summary["time_breakdown_s"]["native_build"] < ra.summary["time_breakdown_s"]["native_build"]
    for scene, res in ((a, ra), (b, rb)):
        ref = run_scene(scene, None, backend="fmi", progress=False, fmu_dir=pyfmu_dir, plots=False)
        for name, st in ref.summary["torque"].items():
            for key in ("mean", "std", "max"):
                assert res.summary["torque"][name][key] == pytest.approx(st[key], rel=1e-9, abs=1e-12), (name, key)


def test_backend_native_without_a_compiler_runs_on_the_pythonfmu_fmus_and_says_so(pyfmu_dir, monkeypatch):
    from drivetrain.run.runner import run_scene
    from drivetrain.scene.load import load_scene

    monkeypatch.setenv("CC", "no-such-compiler-cc")
    scene = load_scene(EXAMPLE, ["time.duration_s=0.05", "time.settle_s=0.01"])
    res = run_scene(scene, None, backend="native", progress=False, fmu_dir=pyfmu_dir, plots=False)
    assert res.summary["backend"] == "fmi"
    assert any("'no-such-compiler-cc' not found" in w and "uses the pythonfmu FMUs" in w
               for w in res.summary["warnings"]), res.summary["warnings"]
