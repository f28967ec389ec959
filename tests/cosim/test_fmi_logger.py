"""The master's FMI logger (drivetrain.cosim.slaves._LoggerRoutes).

fmpy's C logger proxy keeps one Python callback in a global of its library. A run that installed its
own callback and then freed it left every later FMU of the process calling freed memory when it logged:
a segmentation fault in the next FMU error (found as an order-dependent crash of the test suite). Each
case runs in a subprocess, so a crash is a failed test, not a lost test run."""
import subprocess
import sys
import textwrap

import pytest

pytest.importorskip("fmpy")


@pytest.fixture(scope="module")
def shaft_fmu(pythonfmu_fmus):
    return pythonfmu_fmus["FlexibleShaft"]


_PRELUDE = """
import gc, os, sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.fmi1 import FMICallException
from drivetrain.models import fmishell
from drivetrain.cosim.slaves import FmiCallbacks

PATH = sys.argv[1]
MD = read_model_description(PATH)
DIR = extract(PATH)
VR = {v.name: v.valueReference for v in MD.modelVariables}
H = 1.0 / 12000.0

def failing_instance(name, callbacks):
    fmu = FMU2Slave(guid=MD.guid, unzipDirectory=DIR, modelIdentifier=MD.coSimulation.modelIdentifier,
                    instanceName=name)
    fmu.instantiate(loggingOn=True, callbacks=callbacks)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    fmu.doStep(0.0, H)
    return fmu

def fail(fmu):
    fmu.setReal([VR[fmishell.port_inputs("FlexibleShaft")[0]]], [float("nan")])
    try:
        fmu.doStep(H, H)
    except FMICallException:
        return
    raise SystemExit("a NaN input was accepted")
"""


def _run(shaft_fmu, body):
    script = _PRELUDE + textwrap.dedent(body) + "\nsys.stdout.flush()\nos._exit(0)\n"
    return subprocess.run([sys.executable, "-c", script, str(shaft_fmu)], capture_output=True, text=True,
                          timeout=300)


def test_a_freed_run_logger_leaves_later_fmus_logging_safely(shaft_fmu):
    proc = _run(shaft_fmu, """
        run_callbacks = FmiCallbacks()          # a run's logger, then the run ends and frees it
        del run_callbacks
        gc.collect()
        fmu = failing_instance("later", None)   # an FMU on fmpy's default callbacks
        fail(fmu)                               # logs an error through the C proxy
        print("survived")
    """)
    assert proc.returncode == 0, f"rc {proc.returncode}\n{proc.stdout}\n{proc.stderr[-2000:]}"
    assert "survived" in proc.stdout
    # the message of the FMU that is no run's reaches the console as fmpy prints it
    assert "[ERROR]" in proc.stdout and "nan" in proc.stdout.lower()


def test_two_live_runs_keep_their_own_logs(shaft_fmu):
    """Instances of the same name in two runs that are alive at once: each run sees only its own."""
    proc = _run(shaft_fmu, """
        first, second = FmiCallbacks(), FmiCallbacks()
        a = failing_instance("shaft", first.struct)
        b = failing_instance("shaft", second.struct)
        fail(b)
        lines_first = list(first.logs["shaft"].lines) if "shaft" in first.logs else []
        lines_second = list(second.logs["shaft"].lines)
        print("FIRST", len([x for x in lines_first if "non-finite input" in x]))
        print("SECOND", len([x for x in lines_second if "non-finite input" in x]))
    """)
    assert proc.returncode == 0, f"rc {proc.returncode}\n{proc.stdout}\n{proc.stderr[-2000:]}"
    assert "FIRST 0" in proc.stdout
    second = [ln for ln in proc.stdout.splitlines() if ln.startswith("SECOND")]
    assert second and int(second[0].split()[1]) >= 1, proc.stdout


def test_a_run_after_fmpy_installed_its_own_logger_still_gets_its_log(shaft_fmu):
    """fmpy.instantiate_fmu/simulate_fmu(logger=f) point fmpy's proxy at f: a run made after that must
    still see its FMUs' messages (the master points the proxy back at its own callback)."""
    proc = _run(shaft_fmu, """
        from fmpy import instantiate_fmu
        seen = []
        earlier_run = FmiCallbacks()                    # the master's callback is installed first ...
        other = instantiate_fmu(DIR, MD, fmi_type="CoSimulation", logger=lambda *a: seen.append(a))
        run = FmiCallbacks()                            # ... fmpy's then, and a new run begins
        fmu = failing_instance("shaft", run.struct)
        fail(fmu)
        lines = list(run.logs["shaft"].lines) if "shaft" in run.logs else []
        print("OURS", len([x for x in lines if "non-finite input" in x]))
    """)
    assert proc.returncode == 0, f"rc {proc.returncode}\n{proc.stdout}\n{proc.stderr[-2000:]}"
    ours = [ln for ln in proc.stdout.splitlines() if ln.startswith("OURS")]
    assert ours and int(ours[0].split()[1]) >= 1, proc.stdout
