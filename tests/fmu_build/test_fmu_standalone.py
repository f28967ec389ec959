"""Each FMU alone, as a new user meets it: its DefaultExperiment with the example input it ships
(``documentation/example_input.csv``), run by ``fmpy.simulate_fmu`` exactly as its documentation says, gives a
non-trivial, plausible result, judged against oracles that do not use the FMU's code: the rig's steady state
(``rig.data.steady_state``: the torque balance at 500 rpm, 1.31 N·m), the gear ratio, a shaft's torque =
twist / series compliance, a speed-controlled motor at its setpoint. Both builds (pythonfmu and native). Also:
what the FMU ships (documentation/index.html with the variable table of its own modelDescription, the reference
plot, requirement ranges) and GearContact's announcement of its first build in the log.
"""
import io
import zipfile
from xml.etree import ElementTree as ET

import numpy as np
import pytest

from drivetrain.fmu_build.fmu_docs import EXAMPLE_CSV, RAMP_S, operating_point
from drivetrain.fmu_build.fmus import ensure_fmus

MODELS = ("GearContact", "FlexibleShaft", "UpperTransmission", "MotorLoad")
BUILDS = ("pythonfmu", "native")


@pytest.fixture
def fmu(request, fmus_both_builds):
    model, build = request.param
    if (build, model) not in fmus_both_builds:
        pytest.skip("no C toolchain for the native builds")
    return fmus_both_builds[(build, model)]


def _starts(path) -> dict:
    import fmpy

    md = fmpy.read_model_description(str(path))
    return {v.name: v.start for v in md.modelVariables}


def _run(path):
    """The documented example (documentation/index.html): the shipped input, the DefaultExperiment."""
    import fmpy

    with zipfile.ZipFile(path) as z:
        inp = np.genfromtxt(io.BytesIO(z.read(EXAMPLE_CSV)), delimiter=",", names=True)
    res = fmpy.simulate_fmu(str(path), input=inp)
    md = fmpy.read_model_description(str(path))
    assert res["time"][-1] == pytest.approx(float(md.defaultExperiment.stopTime))
    return inp, res


def _steady(res, frac=0.4):
    """The last ``frac`` of the run (the example's ramp ends at RAMP_S)."""
    tail = res[res["time"] >= res["time"][-1] * (1 - frac)]
    assert tail["time"][0] > 2 * RAMP_S
    return tail


CASES = [(m, b) for m in MODELS for b in BUILDS]


@pytest.mark.parametrize("fmu", CASES, ids=[f"{m}-{b}" for m, b in CASES], indirect=True)
def test_the_default_experiment_with_the_shipped_input_is_plausible(fmu):
    ss = operating_point()
    starts = _starts(fmu)
    inp, res = _run(fmu)
    tail = _steady(res)
    mean = {n: float(np.mean(tail[n])) for n in tail.dtype.names}
    model = fmu.stem
    if model == "GearContact":
        ratio = float(starts["z_wheel"]) / float(starts["z_pinion"])
        # the gear carries the load: the rig's steady torques (an ideal gear's balance), the ratio between them
        assert mean["flange_a_tau"] == pytest.approx(-ss.T_msh, rel=0.02)
        assert mean["flange_b_tau"] == pytest.approx(ss.T_psh, rel=0.02)
        assert mean["flange_b_tau"] / mean["flange_a_tau"] == pytest.approx(-ratio, rel=0.01)
        assert mean["pinion_w"] == pytest.approx(ss.w_middle, rel=1e-3)
        assert mean["wheel_w"] == pytest.approx(ss.w_middle / ratio, rel=1e-3)
        assert mean["n_contact"] > 0
    elif model == "FlexibleShaft":
        # a torque T at flange_a against the body at flange_b: every section carries T, twisted T * compliance
        compliance = sum(1.0 / float(starts[k]) for k in ("k_t", "k_c", "k_shaft"))
        twist = tail["flange_a_phi"] - np.interp(tail["time"], inp["time"], inp["flange_b_phi"])
        assert mean["flange_b_tau"] == pytest.approx(ss.T_dsh, rel=1e-3)
        assert mean["torque_sensor"] == pytest.approx(ss.T_dsh, rel=1e-3)
        assert float(np.mean(twist)) == pytest.approx(ss.T_dsh * compliance, rel=0.01)
        assert mean["flange_a_w"] == pytest.approx(ss.w_drive, rel=1e-3)
    elif model == "UpperTransmission":
        # driven by torques alone, it runs up to where its loss balances them: the rig's 500 rpm
        last = res[-1]
        assert last["flange_a_w"] == pytest.approx(ss.w_drive, rel=2e-3)
        assert last["flange_b_w"] == pytest.approx(last["flange_a_w"] / float(starts["ratio"]), rel=1e-9)
        assert mean["loss_torque"] == pytest.approx(ss.T_dsh - ss.T_msh / float(starts["ratio"]), rel=0.01)
    else:
        # the drive motor reaches its speed setpoint; the load side runs at the propeller speed, the load motor
        # at its setting
        assert mean["motor_w"] == pytest.approx(ss.w_drive, rel=1e-3)
        assert res[-1]["load_w"] == pytest.approx(ss.w_prop, rel=0.01)
        assert mean["load_motor_torque"] == pytest.approx(1.31, rel=1e-9)
    for n in res.dtype.names[1:]:
        assert np.all(np.isfinite(res[n])), n


@pytest.mark.parametrize("fmu", CASES, ids=[f"{m}-{b}" for m, b in CASES], indirect=True)
def test_the_fmu_documents_itself_from_its_model_description(fmu):
    with zipfile.ZipFile(fmu) as z:
        names = set(z.namelist())
        page = z.read("documentation/index.html").decode()
        md = ET.fromstring(z.read("modelDescription.xml"))
        req = z.read("resources/requirements.txt").decode() if "resources/requirements.txt" in names else None
    de = md.find("DefaultExperiment")
    assert float(de.get("stopTime")) > 2 * RAMP_S and float(de.get("stepSize")) > 0
    for sv in md.findall("ModelVariables/ScalarVariable"):          # the table follows the declarations
        child = next(iter(sv))
        cells = [sv.get("name"), sv.get("causality"), child.tag]
        assert "<tr><td>" + "</td><td>".join(cells[:2]) in page, sv.get("name")
        assert f"<td>{child.tag}</td>" in page
    assert "spring side" in page or "inertia side" in page
    assert "fmpy.simulate_fmu" in page and EXAMPLE_CSV in page
    assert "documentation/reference.png" in names and 'src="reference.png"' in page
    assert EXAMPLE_CSV in names
    with zipfile.ZipFile(fmu) as z:                    # FMI 2.0's entry point: the same page
        assert z.read("documentation/_main.html").decode() == page
    if fmu.parent.name.startswith("native"):
        assert req is None
    else:                                              # ranges the project declares, not this machine's versions
        lines = [ln for ln in req.splitlines() if ln and not ln.startswith("#")]
        assert "pythonfmu==0.7.0" in lines and "numpy>=1.24" in lines
        assert all(("==" not in ln) or ln.startswith("pythonfmu") for ln in lines), lines


def _first_build_log(path, env=None) -> list[str]:
    """(seconds since the start, message) of every message a fresh process's fmpy run of ``path`` logs."""
    import subprocess
    import sys

    code = ("import fmpy, sys, time\nlog = []\nt0 = time.perf_counter()\n"
            "fmpy.simulate_fmu(sys.argv[1], stop_time=0.001, debug_logging=True,\n"
            "                  logger=lambda c, i, s, cat, m: log.append(f'{time.perf_counter() - t0:.3f} {m.decode()}'))\n"
            "print('\\n'.join(log))\n")
    r = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 0, r.stderr
    return [(float(ln.split(" ", 1)[0]), ln.split(" ", 1)[1]) for ln in r.stdout.splitlines() if ln.strip()]


def _announcement(log):
    first = next(i for i, (_, m) in enumerate(log) if "first stage of this process" in m)
    built = next(i for i, (_, m) in enumerate(log) if m.startswith("GearContact: fidelity"))
    assert first < built
    return log[first], log[built]


def test_gearcontact_announces_its_first_build_before_it_starts(fmu_dir):
    """A fresh process: the message about loading or compiling the kernels reaches the host's logger before
    exitInitializationMode (where the first stage is built and numba compiles) returns its own message."""
    path = ensure_fmus(["GearContact"], fmu_dir)["GearContact"]
    (_, text), _ = _announcement(_first_build_log(path))
    assert "numba" in text and "exitInitializationMode" in text


@pytest.mark.slow
def test_gearcontact_announces_a_compile_without_a_numba_cache(fmu_dir, tmp_path):
    """No numba cache (NUMBA_CACHE_DIR empty): the announcement says it compiles, seconds before the build ends
    (measured: at 0.9 s, the build's own message at 14 s)."""
    import os

    path = ensure_fmus(["GearContact"], fmu_dir)["GearContact"]
    (t_said, text), (t_built, _) = _announcement(_first_build_log(path, {**os.environ,
                                                                           "NUMBA_CACHE_DIR": str(tmp_path)}))
    assert "no cache" in text and "compiles them" in text
    assert t_built - t_said > 2.0
