"""User text in an FMU's log message never crashes the host, and a bad value reference is named.

FMI 2.0's fmi2CallbackLogger takes the message as a printf-style format. A ``%n`` or ``%s`` in a mesh
path or a profile string used to reach fmpy's formatting logger as it was: the host process died with a
segmentation fault (rc 139). Each case runs in a subprocess, so a crash fails the test instead of
killing the test run."""
from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest


HOSTILE = "%n%s%n%s%x%%"

SCRIPT = textwrap.dedent("""
    import sys
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    path, name, value = sys.argv[1:4]
    md = read_model_description(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    f = FMU2Slave(guid=md.guid, unzipDirectory=extract(path), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="hostile")
    f.instantiate(loggingOn=True)
    f.setupExperiment(startTime=0.0)
    for assignment in sys.argv[4:]:
        k, v = assignment.split("=", 1)
        f.setString([vr[k]], [v])
    f.setString([vr[name]], [value])
    f.enterInitializationMode()
    try:
        f.exitInitializationMode()
    except Exception as exc:
        print("refused:", exc)
    print("host alive")
""")


@pytest.fixture(scope="module", autouse=True)
def _fmus_built(pythonfmu_fmus):
    """The session's FMUs built in ``fmu_dir`` (tests/conftest.py) before a test runs them."""


@pytest.mark.parametrize("model, name, value, extra", [
    ("GearContact", "pinion_mesh_file", f"/nonexistent/{HOSTILE}.obj", ["fidelity=table", "health=mesh"]),
    ("MotorLoad", "speed_profile", f"0:0; {HOSTILE}", []),
])
def test_percent_sequences_in_user_text_do_not_crash_the_host(fmu_dir, model, name, value, extra):
    r = subprocess.run([sys.executable, "-c", SCRIPT, str(fmu_dir / f"{model}.fmu"), name, value, *extra],
                       capture_output=True, text=True, timeout=300)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-2000:]
    assert "host alive" in out
    assert HOSTILE in out          # the logged message carries the text as given, not formatted


VR_SCRIPT = textwrap.dedent("""
    import sys
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    path = sys.argv[1]
    md = read_model_description(path)
    f = FMU2Slave(guid=md.guid, unzipDirectory=extract(path), modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName="vr")
    f.instantiate(loggingOn=True)
    f.setupExperiment(startTime=0.0)
    f.enterInitializationMode()
    f.exitInitializationMode()
    for call in (lambda: f.getReal([987654]), lambda: f.doStep(0.0, 1e-4)):
        try:
            call()
            print("accepted")
        except Exception as exc:
            print("refused:", exc)
""")


@pytest.mark.parametrize("model", ["GearContact", "MotorLoad"])
def test_an_unknown_value_reference_is_named_and_stops_the_instance(fmu_dir, model):
    """pythonfmu answered fmi2Fatal with only "PyObject_CallMethod" in its log and then accepted the next
    doStep as if nothing had happened."""
    r = subprocess.run([sys.executable, "-c", VR_SCRIPT, str(fmu_dir / f"{model}.fmu")],
                       capture_output=True, text=True, timeout=300)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-2000:]
    assert "accepted" not in out                       # neither the bad read nor the next step
    assert "987654 (no such variable)" in out


def test_a_percent_in_the_temporary_directory_does_not_crash_the_master(fmu_dir, tmp_path):
    """pythonfmu 0.7.0 crashes fmi2Instantiate (segmentation fault) when the FMU's resource path holds a
    '%'; the master extracts FMUs only into directories without one."""
    tmp = tmp_path / "t%n%s"
    tmp.mkdir()
    code = textwrap.dedent(f"""
        from drivetrain.fmu_build.fmus import extracted_dir
        from drivetrain.system import ComponentSpec, SystemSpec
        from drivetrain.cosim import simulate
        d = extracted_dir({str(fmu_dir / "MotorLoad.fmu")!r})
        assert "%" not in str(d), d
        spec = SystemSpec([ComponentSpec("motors", "MotorLoad", {{"w0": 10.0}})], [], 1e-4)
        res = simulate(spec, 0.01, 1000.0, ["motors.motor_w"], fmu_paths={{"MotorLoad": {str(fmu_dir / "MotorLoad.fmu")!r}}},
                       progress=False)
        print("host alive", res.status)
    """)
    env = {**__import__("os").environ, "TMPDIR": str(tmp)}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, (r.stdout + r.stderr)[-2000:]
    assert "host alive ok" in r.stdout
