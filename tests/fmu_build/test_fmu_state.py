"""FMI semantics of the four FMUs that other hosts rely on: GearContact's initial-state
parameters (a host that passes nothing during initialization), NaN outputs and the ``error`` output
after a failure, and FMU state get/set (a rolled-back step repeats bit for bit).

Every case drives the built FMUs through fmpy's FMU2Slave in a subprocess (a pythonfmu FMU that
reports an error in a process that already freed other pythonfmu instances can crash it: see
tests/fmu_build/test_gearcontact_fmu.py)."""
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

fmpy = pytest.importorskip("fmpy")

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"

# the host side, shared by every case: load, instantiate, set by name, step with inputs by name
_HOST = """
import json, math, sys
import fmpy
from fmpy.fmi2 import FMU2Slave

_KEEP = []

def open_fmu(path, name):
    md = fmpy.read_model_description(path)
    vars_ = {v.name: v for v in md.modelVariables}
    f = FMU2Slave(guid=md.guid, unzipDirectory=fmpy.extract(path), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=name)
    f.instantiate(loggingOn=bool(int(__import__("os").environ.get("FMU_LOG", "0"))))
    _KEEP.append(f)
    return f, vars_

def set_values(f, vars_, values):
    for n, v in values.items():
        var = vars_[n]
        if var.type == "Real":
            f.setReal([var.valueReference], [float(v)])
        elif var.type in ("Integer", "Enumeration"):
            f.setInteger([var.valueReference], [int(v)])
        elif var.type == "Boolean":
            f.setBoolean([var.valueReference], [bool(v)])
        else:
            f.setString([var.valueReference], [str(v)])

def reals(f, vars_, names):
    return f.getReal([vars_[n].valueReference for n in names])

def real_outputs(vars_):
    return [n for n, v in vars_.items() if v.causality == "output" and v.type == "Real"]
"""


def _run(body: str, timeout=240):
    code = _HOST + textwrap.dedent(body)
    env = dict(os.environ)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, env=env)
    assert p.returncode == 0, (p.returncode, p.stdout[-3000:], p.stderr[-3000:])
    return json.loads(p.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def fmus(pythonfmu_fmus):
    """The four FMUs of the session (tests/conftest.py)."""
    return {m: str(p) for m, p in pythonfmu_fmus.items()}


@pytest.fixture(scope="module")
def assembled():
    """The example scene's assembled parameters; the gear analytic (no contact map: fast)."""
    from drivetrain.run.runner import assemble_scene
    from drivetrain.scene.load import load_scene

    spec = assemble_scene(load_scene(EXAMPLE))
    params = {c.name: dict(c.parameters) for c in spec.components}
    params["gear"]["fidelity"] = "analytic"
    return params


def test_model_descriptions_declare_state_and_error(fmus):
    for model, path in fmus.items():
        md = fmpy.read_model_description(path)
        assert md.coSimulation.canGetAndSetFMUstate, model
        err = next(v for v in md.modelVariables if v.name == "error")
        assert (err.type, err.causality, err.variability) == ("String", "output", "discrete"), model
        assert fmpy.validation.validate_fmu(path) == [], model


def test_gear_starts_right_when_the_host_passes_nothing(fmus, assembled):
    """A host that sets no input during initialization (as an FMU container does): with the assembled
    initial-state parameters the gear starts exactly as in a host that passes the neighbours' values;
    without them (``initial_state = "inputs"``) it starts at rest against spinning neighbours."""
    gear = assembled["gear"]
    assert gear["initial_state"] == "parameters" and gear["pinion_w_start"] > 50.0
    assert gear["twist_a_start"] < 0.0 < gear["twist_b_start"]      # the port springs carry the load
    flange = {"flange_a_phi": gear["pinion_phi_start"] - gear["twist_a_start"], "flange_a_w": gear["pinion_w_start"],
              "flange_b_phi": gear["wheel_phi_start"] - gear["twist_b_start"], "flange_b_w": gear["wheel_w_start"]}
    out = _run(f"""
        gear, flange = json.loads({json.dumps(gear)!r}), json.loads({json.dumps(flange)!r})
        H = 1.0 / 12000.0
        def run(params, at_init):
            f, v = open_fmu({fmus["GearContact"]!r}, "gear")
            set_values(f, v, params)
            f.setupExperiment(startTime=0.0)
            f.enterInitializationMode()
            set_values(f, v, at_init)
            f.exitInitializationMode()
            rows = [reals(f, v, ["flange_a_tau", "flange_b_tau"])]
            t = 0.0
            for k in range(40):           # the neighbours at their start speeds
                set_values(f, v, {{"flange_a_phi": flange["flange_a_phi"] + flange["flange_a_w"] * t,
                                  "flange_a_w": flange["flange_a_w"],
                                  "flange_b_phi": flange["flange_b_phi"] + flange["flange_b_w"] * t,
                                  "flange_b_w": flange["flange_b_w"]}})
                f.doStep(t, H)
                t += H
                rows.append(reals(f, v, ["flange_a_tau", "flange_b_tau"]))
            return rows
        by_inputs = run(dict(gear, initial_state="inputs"), flange)
        by_parameters = run(gear, {{}})
        nothing = run(dict(gear, initial_state="inputs"), {{}})
        print(json.dumps([by_inputs, by_parameters, nothing]))
    """)
    by_inputs, by_parameters, nothing = out
    assert by_parameters == by_inputs                    # bit for bit, the outputs at t0 included
    peak = max(abs(r[1]) for r in by_inputs)
    assert by_inputs[0][1] == pytest.approx(gear["k_b"] * gear["twist_b_start"])   # the loaded port at t0
    assert peak <= 1.1 * abs(by_inputs[0][1])            # ... and no start-up transient of the stage
    assert max(abs(r[1]) for r in nothing) > 5 * peak    # the start-up spike the parameters prevent


ROLLBACK_MODELS = ("GearContact", "MotorLoad", "FlexibleShaft", "UpperTransmission")


@pytest.fixture(scope="module")
def rollbacks(fmus, assembled):
    """The rollback case of every model, one subprocess for the four (no instance fails or is freed: the
    crash the subprocesses guard against needs both): {model: {"same", "moved", "n"}}."""
    names = {"GearContact": "gear", "MotorLoad": "motors", "FlexibleShaft": "drive_shaft",
             "UpperTransmission": "upper"}
    cases = {}
    for model in ROLLBACK_MODELS:
        params = {k: v for k, v in assembled[names[model]].items() if not isinstance(v, list)}
        # flange angle and speed at t = 0 per spring-side port (the gear's as assembled: its mesh must not
        # be forced beyond u_max)
        base = {"flange_a": (params.get("pinion_phi_start", 0.0), params.get("pinion_w_start", 50.0)),
                "flange_b": (params.get("wheel_phi_start", 0.0), params.get("wheel_w_start", 50.0))}
        cases[model] = {"path": fmus[model], "params": params, "base": base}
    return _run(f"""
        def rollback(path, params, base):
            f, v = open_fmu(path, "x")
            set_values(f, v, params)
            inputs = [n for n, var in v.items() if var.causality == "input" and var.type == "Real"]
            outs = real_outputs(v)
            f.setupExperiment(startTime=0.0)
            f.enterInitializationMode()
            f.exitInitializationMode()
            H = 1.0 / 12000.0
            def step(k):
                # smooth, distinct inputs per step (angles grow with their speeds, torques oscillate)
                vals = {{}}
                for i, n in enumerate(inputs):
                    phi0, w0 = base.get(n.rsplit("_", 1)[0], (0.0, 50.0))
                    if n.endswith("_phi"):
                        vals[n] = phi0 + w0 * k * H + 1e-5 * math.sin(0.3 * k + i)
                    elif n.endswith("_w"):
                        vals[n] = w0 * (1.0 + 0.01 * math.cos(0.3 * k + i))
                    elif n.endswith("_tau"):
                        vals[n] = -1.0 + 0.5 * math.sin(0.2 * k + i)
                set_values(f, v, vals)
                f.doStep(k * H, H)
                return reals(f, v, outs)
            for k in range(30):
                step(k)
            s = f.getFMUstate()
            first = [step(k) for k in range(30, 60)]
            f.setFMUstate(s)
            again = [step(k) for k in range(30, 60)]
            f.setFMUstate(s)                      # the snapshot stays usable
            third = [step(k) for k in range(30, 35)]
            f.freeFMUstate(s)
            return {{"same": first == again and first[:5] == third, "moved": first[0] != first[-1], "n": len(outs)}}
        cases = json.loads({json.dumps(cases)!r})
        print(json.dumps({{m: rollback(c["path"], c["params"], {{k: tuple(x) for k, x in c["base"].items()}})
                          for m, c in cases.items()}}))
    """)


@pytest.mark.parametrize("model", ROLLBACK_MODELS)
def test_rollback_repeats_bit_for_bit(rollbacks, model):
    """fmi2GetFMUstate after 30 steps, 30 more steps, fmi2SetFMUstate, the same 30 steps again: every
    Real output identical. A state that missed anything that changes (the PI integrator, the energy
    correction, the sub-step counters, ...) would differ."""
    out = rollbacks[model]
    assert out["moved"] and out["n"] >= 5
    assert out["same"], model


@pytest.mark.parametrize("model", ["GearContact", "UpperTransmission"])
def test_after_a_failure_outputs_are_nan_and_error_says_why(fmus, assembled, model):
    name = "gear" if model == "GearContact" else "upper"
    params = {k: v for k, v in assembled[name].items() if not isinstance(v, list)}
    out = _run(f"""
        f, v = open_fmu({fmus[model]!r}, "x")
        set_values(f, v, json.loads({json.dumps(params)!r}))
        f.setupExperiment(startTime=0.0)
        f.enterInitializationMode(); f.exitInitializationMode()
        H = 1.0 / 12000.0
        f.doStep(0.0, H)
        err0 = f.getString([v["error"].valueReference])[0].decode()
        first_input = next(n for n, var in v.items() if var.causality == "input" and var.type == "Real")
        set_values(f, v, {{first_input: float("nan")}})
        try:
            f.doStep(H, H)
            status = 0
        except fmpy.fmi1.FMICallException as e:
            status = e.status
        outs = real_outputs(v)
        vals = dict(zip(outs, reals(f, v, outs)))
        err = f.getString([v["error"].valueReference])[0].decode()
        count = f.getInteger([v["n_substeps"].valueReference])[0] if "n_substeps" in v else None
        print(json.dumps({{"status": status, "err0": err0, "err": err, "n_substeps": count,
                          "nan": sorted(n for n, x in vals.items() if math.isnan(x)),
                          "finite": sorted(n for n, x in vals.items() if not math.isnan(x))}}))
    """)
    assert out["status"] >= 2 and out["err0"] == ""
    assert "non-finite input" in out["err"] and "t = " in out["err"]
    assert "flange_a_tau" in out["nan"] or "flange_b_phi" in out["nan"]
    if model == "GearContact":
        assert {"flange_a_tau", "flange_b_tau", "flange_a_tau_mean", "energy_stored"} <= set(out["nan"])
        # the bodies at the last completed step and the stability counters stay readable
        assert {"pinion_phi", "pinion_w", "peak_penetration"} <= set(out["finite"])
        assert out["n_substeps"] > 0              # an Integer counter (fmi2GetInteger)
    else:
        assert out["finite"] == []


def test_a_missing_package_is_named_at_the_default_log_level(fmus):
    """A host whose Python lacks numba: pythonfmu 0.7.0 only says "Failed to instantiate model" and
    forwards no log message without debug logging; the FMU names the package and what to install on
    the host's stderr."""
    code = _HOST + textwrap.dedent(f"""
        sys.modules["numba"] = None          # as if numba were not installed
        md = fmpy.read_model_description({fmus["MotorLoad"]!r})
        f = FMU2Slave(guid=md.guid, unzipDirectory=fmpy.extract({fmus["MotorLoad"]!r}),
                      modelIdentifier="MotorLoad", instanceName="m")
        try:
            f.instantiate(loggingOn=False)
            print("INSTANTIATED")
        except Exception as e:
            print("FAILED", e)
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "FAILED" in p.stdout and "INSTANTIATED" not in p.stdout, p.stdout
    assert "MotorLoad FMU" in p.stderr and "'numba'" in p.stderr and "requirements.txt" in p.stderr, p.stderr
