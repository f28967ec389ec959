"""The GearContact FMU: build, validate, simulate with fmpy, error handling, bundled packages."""
import math
import os
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest

fmpy = pytest.importorskip("fmpy")

ROOT = Path(__file__).resolve().parents[2]
INPUT_CSV = ROOT / "examples" / "gearcontact_input.csv"


@pytest.fixture(scope="session")
def fmu(pythonfmu_fmus):
    """The session's GearContact FMU (tests/conftest.py)."""
    return pythonfmu_fmus["GearContact"]


def _md(fmu):
    with zipfile.ZipFile(fmu) as z:
        return ET.fromstring(z.read("modelDescription.xml")), z.namelist()


def test_validate_and_model_description(fmu):
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(fmu)) == []
    root, names = _md(fmu)
    assert root.find("CoSimulation").get("needsExecutionTool") == "true"      # a CPython with its packages
    svs = {sv.get("name"): sv for sv in root.find("ModelVariables")}
    # self-describing: every variable says what it is (options listed), every Real has a unit ("1" if none)
    assert [n for n, sv in svs.items() if not sv.get("description")] == []
    assert [n for n, sv in svs.items() if sv.find("Real") is not None and not sv.find("Real").get("unit")] == []
    assert "pcm" in svs["fidelity"].get("description") and "ideal" in svs["fidelity"].get("description")
    for name, unit in (("flange_a_phi", "rad"), ("flange_b_w", "rad/s"), ("flange_a_tau", "N.m"),
                       ("energy_stored", "J"), ("contact_area", "m2"), ("peak_pressure", "Pa"),
                       ("J_pinion", "kg.m2"), ("normal_force", "N"), ("max_penetration", "m")):
        assert svs[name].find("Real").get("unit") == unit, name
    for name in ("flange_a_phi", "flange_a_w", "flange_b_phi", "flange_b_w"):
        assert svs[name].get("causality") == "input"
    for name in ("flange_a_tau", "flange_b_tau", "n_contact", "pinion_w", "energy_dissipated"):
        assert svs[name].get("causality") == "output" and svs[name].get("initial") == "calculated"
    assert svs["z_pinion"].get("variability") == "fixed"
    units = {u.get("name") for u in root.find("UnitDefinitions")}
    assert {"rad", "rad/s", "N.m", "J", "W", "m", "m2", "Pa", "N", "kg.m2"} <= units
    # outputs depend on the state only (no algebraic loop through the stage)
    outs = root.find("ModelStructure").find("Outputs")
    assert all(u.get("dependencies") == "" for u in outs)
    # packages bundled as sources only
    assert "resources/_bundled/gearcontact_fmu/stage.py" in names
    assert "resources/_bundled/drivetrain/models/components.py" in names
    # what runs inside an FMU only (drivetrain.fmu_build.bundle: derived from the imports); the host's side stays out
    assert not any(n.startswith(("resources/_bundled/drivetrain/cosim/", "resources/_bundled/drivetrain/cli.py",
                                 "resources/_bundled/drivetrain/campaigns/")) for n in names)
    assert not any("__pycache__" in n or n.endswith((".pyc", ".nbi", ".nbc")) for n in names)


_KEEP = []   # instances whose libraries must stay loaded until the process exits


def _simulate(fmu, logger=None, debug_logging=False, **kw):
    """fmpy.simulate_fmu on an instance we own: fmpy frees (dlclose) an instance it created itself,
    and unloading a pythonfmu 0.7.0 export library while the interpreter keeps objects it made
    corrupts the process later (seen as a crash in a later test). The master keeps libraries loaded
    for the same reason (drivetrain/cosim/master.py)."""
    md = fmpy.read_model_description(str(fmu))
    inst = fmpy.instantiate_fmu(fmpy.extract(str(fmu)), md, fmi_type="CoSimulation", logger=logger,
                                debug_logging=debug_logging)
    _KEEP.append(inst)
    return fmpy.simulate_fmu(str(fmu), fmu_instance=inst, model_description=md, **kw)


def test_simulate_steady_mesh_torque(fmu):
    """examples/gearcontact_input.csv ramps flange_a to 0.01 rad (flange_b held): the steady mesh torque
    is the series-chain closed form T = (phi_a - s_b/2) / (1/k_a + 1/K + r^2/k_b)."""
    from gearcontact_fmu.mesh_models.analytic import iso6336_stiffness, single_pair_phase
    from gearcontact_fmu.params import BevelGearParams

    g = BevelGearParams()
    k_a, k_b, r, phi_a = 1140.0, 12200.0, 4.0, 0.01
    Re = g.module * g.z_pinion / 2 / math.sin(g.delta_pinion)
    r_b = (Re - g.face_width / 2) * math.sin(g.delta_pinion) * math.cos(g.pressure_angle)
    K = iso6336_stiffness(g)["c_prime"] * 25e6 * r_b ** 2          # single-pair zone
    s_b = g.backlash / (g.module * g.z_pinion / 2)
    T = (phi_a - s_b / 2) / (1 / k_a + 1 / K + r * r / k_b)
    theta_p = phi_a - T / k_a
    inp = np.genfromtxt(INPUT_CSV, delimiter=",", names=True)
    res = _simulate(fmu, stop_time=0.3, output_interval=1e-4, input=inp,
                            start_values={"fidelity": "analytic", "mesh_phase": single_pair_phase(g, theta_p)},
                            output=["flange_a_tau", "flange_b_tau", "mesh_torque_pinion", "mesh_torque_wheel",
                                    "n_contact", "pinion_w", "energy_stored"])
    end = res[-1]
    assert end["n_contact"] == 1.0
    assert -end["mesh_torque_pinion"] == pytest.approx(T, rel=1e-4)
    assert end["mesh_torque_wheel"] == pytest.approx(r * T, rel=1e-4)
    assert end["flange_a_tau"] == pytest.approx(-T, rel=1e-4)
    assert end["flange_b_tau"] == pytest.approx(r * T, rel=1e-4)
    assert abs(end["pinion_w"]) < 1e-6
    stored = 0.5 * T ** 2 / k_a + 0.5 * (r * T) ** 2 / k_b + 0.5 * T ** 2 / K
    assert end["energy_stored"] == pytest.approx(stored, rel=1e-4)


def test_penetration_beyond_u_max_is_an_fmi_error(fmu):
    """do_step returns fmi2Discard with an fmi2Error log message. pythonfmu 0.7.0 then reports
    fmi2Terminated = true, so fmpy.simulate_fmu ends the run at the last successful time (it raises
    only for error/fatal); FMU2Slave.doStep raises (see the NaN test). Messages need debug logging
    (pythonfmu forwards no message otherwise)."""
    msgs = []

    def logger(component, instance, status, category, message):
        msgs.append((status, message.decode() if isinstance(message, bytes) else str(message)))

    inp = np.genfromtxt(INPUT_CSV, delimiter=",", names=True)
    res = _simulate(fmu, stop_time=0.3, output_interval=1e-4, input=inp, logger=logger,
                            debug_logging=True, start_values={"u_max": 2e-7},
                            output=["max_penetration"])
    assert res["time"][-1] < 0.1                             # stopped at the failure
    errors = [m for st, m in msgs if st == 3]                # fmi2Error
    assert any("beyond u_max" in m and "t = " in m for m in errors), msgs
    pen = res["max_penetration"]
    assert np.isnan(pen[-1])                                 # after the failure: NaN, not a stale value
    assert np.all(pen[:-1] <= 2e-7)                          # every accepted state is within u_max


def _run(code, env=None, timeout=180):
    e = dict(os.environ)
    e.update(env or {})
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True,
                          env=e, timeout=timeout)


def test_nan_input_is_an_fmi_error_and_the_host_survives(fmu):
    code = f"""
        import numpy as np, fmpy
        from fmpy.fmi2 import FMU2Slave
        path = {str(fmu)!r}
        md = fmpy.read_model_description(path)
        vr = {{v.name: v.valueReference for v in md.modelVariables}}
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=fmpy.extract(path), modelIdentifier="GearContact",
                        instanceName="gear")
        fmu.instantiate(loggingOn=True)           # fmpy's default logger prints the FMU's messages
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode(); fmu.exitInitializationMode()
        fmu.doStep(0.0, 1e-4)
        fmu.setReal([vr["flange_a_phi"]], [float("nan")])
        try:
            fmu.doStep(1e-4, 1e-4)
            print("NO-ERROR")
        except fmpy.fmi1.FMICallException as e:
            print("STATUS", e.status)
        try:                                      # stays in the error state
            fmu.setReal([vr["flange_a_phi"]], [0.0]); fmu.doStep(2e-4, 1e-4); print("NO-ERROR-2")
        except fmpy.fmi1.FMICallException as e:
            print("STATUS2", e.status)
        fmu.terminate(); fmu.freeInstance()
        print("SURVIVED")
    """
    p = _run(code)
    assert p.returncode == 0, p.stderr
    # the failing step is fmi2Discard; a step in the error state is a misuse: fmi2Error
    assert "STATUS 2" in p.stdout and "STATUS2 3" in p.stdout and "SURVIVED" in p.stdout, p.stdout
    # fmpy's default logger prints the FMU's error message
    assert "non-finite input at t = 0.0001" in p.stdout, p.stdout


def test_fmpy_cli_runs_and_exits_cleanly(fmu, tmp_path):
    """The docs/FMU.md command in fresh processes: results written and exit status 0 (pythonfmu 0.7.0
    alone aborts about half of such processes at exit; fmu_runtime.guard prevents it)."""
    out = tmp_path / "out.csv"
    cmd = [sys.executable, "-m", "fmpy", "simulate", str(fmu), "--input-file", str(INPUT_CSV),
           "--stop-time", "0.05", "--output-interval", "1e-4", "--output-variables", "flange_a_tau",
           "flange_b_tau", "--output-file", str(out)]
    for _ in range(3):
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
        assert p.returncode == 0, (p.returncode, p.stdout[-500:], p.stderr[-500:])
        rows = np.genfromtxt(out, delimiter=",", names=True)
        assert len(rows) == 501 and rows["flange_b_tau"][-1] > 0.0


def test_bundled_copy_works(fmu):
    code = f"""
        import fmpy
        msgs = []
        def logger(c, inst, status, cat, msg):
            msgs.append(msg.decode())
        res = fmpy.simulate_fmu({str(fmu)!r}, stop_time=0.02, output_interval=1e-4, debug_logging=True,
                                logger=logger, start_values={{"flange_a_w": 1.0}},
                                output=["pinion_w", "flange_a_tau"])
        print("ROWS", len(res))
        print("ORIGIN", [m for m in msgs if "package" in m])
    """
    p = _run(code, env={"BEVEL_FMU_USE_BUNDLED": "1"})
    assert p.returncode == 0, p.stderr
    assert "ROWS 201" in p.stdout
    assert "_bundled/gearcontact_fmu" in p.stdout, p.stdout
