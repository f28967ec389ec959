"""`drivetrain export-ssp`: the scene's system as an SSP 1.0 archive (drivetrain.interop.ssp).

Structure against the assembled system (every connection, every parameter value and FMU byte for
byte), refusals, and - marked ``hosts``, skipped when libcosimpy is not installed - the archive run in
libcosim against our master (mean and RMS torques within 1e-4 over 0.5 s). libcosim loads the Python
FMUs into its own process, so it runs in a subprocess: a crash there is a failed test, not a lost run.
"""
import json
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest
from _hosts import ANOTHER_CHAIN, ANOTHER_MACHINE, assert_matches, master_torques, run_host, schedule, torque_refs

from drivetrain.errors import ConfigurationError
from drivetrain.run.runner import assemble_scene
from drivetrain.scene.load import load_scene
from drivetrain.interop.ssp import PARAMETER_SET, SSD_NAME, export_ssp, system_connections

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"
NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
      "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
      "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
      "oms": "https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd"}
SHORT = ["time.duration_s=0.5", "time.settle_s=0", "outputs.plots=false"]


@pytest.fixture(scope="module")
def exported(tmp_path_factory, fmu_dir):
    scene = load_scene(EXAMPLE, SHORT)
    path = export_ssp(scene, tmp_path_factory.mktemp("ssp") / "example.ssp", fmu_dir=fmu_dir)
    return scene, assemble_scene(scene), path


def _value(el):
    (v,) = list(el)
    kind, text = v.tag.split("}")[1], v.get("value")
    return {"Real": float, "Integer": int, "Boolean": lambda s: s == "true", "String": str}[kind](text)


def test_the_archive_holds_the_assembled_system(exported, fmu_dir):
    scene, spec, path = exported
    with zipfile.ZipFile(path) as z:
        names = set(z.namelist())
        ssd = ET.fromstring(z.read(SSD_NAME))
        assert ssd.get("version") == "1.0"
        exp = ssd.find("ssd:DefaultExperiment", NS)
        assert float(exp.get("startTime")) == 0.0 and float(exp.get("stopTime")) == scene.time.duration_s
        step = ssd.find(".//oms:FixedStepMaster", NS)
        assert float(step.get("stepSize")) == spec.comm_step
        comps = {c.get("name"): c for c in ssd.findall("ssd:System/ssd:Elements/ssd:Component", NS)}
        assert set(comps) == {c.name for c in spec.components}
        kinds = {}
        for c in spec.components:
            el = comps[c.name]
            # the FMU, byte for byte the one our master runs
            src = el.get("source")
            assert src == f"resources/{c.model}.fmu" and z.read(src) == (Path(fmu_dir) / f"{c.model}.fmu").read_bytes()
            for conn in el.findall("ssd:Connectors/ssd:Connector", NS):
                kinds[(c.name, conn.get("name"))] = conn.get("kind")
            # every assembled parameter and constant input, with the exact value
            (binding,) = el.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS)
            ssv = ET.fromstring(z.read(binding.get("source")))
            assert ssv.get("name") == PARAMETER_SET
            got = {p.get("name"): _value(p) for p in ssv.findall("ssv:Parameters/ssv:Parameter", NS)}
            want = {**c.parameters, **c.inputs}
            assert set(got) == set(want), c.name
            for k, v in want.items():
                assert got[k] == (bool(v) if isinstance(got[k], bool) else v), (c.name, k)
        links = {(l.get("startElement"), l.get("startConnector"), l.get("endElement"), l.get("endConnector"))
                 for l in ssd.findall("ssd:System/ssd:Connections/ssd:Connection", NS)}
        # three variables per flange connection (phi and w to the spring side, tau back), outputs to inputs
        assert links == set(system_connections(spec)) and len(links) == 3 * len(spec.connections)
        for a, va, b, vb in links:
            assert kinds[(a, va)] == "output" and kinds[(b, vb)] == "input"
        assert len(kinds) == 2 * len(links)          # connectors only for connected variables
        assert {f"resources/{c.name}.ssv" for c in spec.components} <= names


def _units(el):
    """name -> {base unit: exponent, factor, offset} of an ssd:Units / ssv:Units element."""
    out = {}
    for u in el.findall("ssc:Unit", NS):
        b = u.find("ssc:BaseUnit", NS)
        out[u.get("name")] = ({k: int(b.get(k, 0)) for k in ("kg", "m", "s", "A", "K", "mol", "cd", "rad")}
                              | {"factor": float(b.get("factor", 1)), "offset": float(b.get("offset", 0))})
    return out


def test_the_archive_carries_units_and_unit_definitions(exported, fmu_dir):
    """Our own reader: every Real connector and parameter value has its FMU's unit, each file defines the units
    it uses as the FMUs define them (SI base units), and fmpy's schemas (SSP 1.0) accept every file."""
    import fmpy
    from fmpy.ssp.ssd import read_ssd, read_ssv

    scene, spec, path = exported
    fmus = {c.model: fmpy.read_model_description(str(Path(fmu_dir) / f"{c.model}.fmu")) for c in spec.components}
    declared = {m: {v.name: v for v in md.modelVariables} for m, md in fmus.items()}
    defined = {}
    for md in fmus.values():
        for u in md.unitDefinitions:
            b = u.baseUnit
            defined[u.name] = ({k: getattr(b, k) for k in ("kg", "m", "s", "A", "K", "mol", "cd", "rad")}
                               | {"factor": b.factor, "offset": b.offset})
    read_ssd(str(path), validate=True)
    with zipfile.ZipFile(path) as z:
        ssd = ET.fromstring(z.read(SSD_NAME))
        ssd_units = _units(ssd.find("ssd:Units", NS))
        n_real = 0
        for el in ssd.findall("ssd:System/ssd:Elements/ssd:Component", NS):
            model = Path(el.get("source")).stem
            for conn in el.findall("ssd:Connectors/ssd:Connector", NS):
                real = conn.find("ssc:Real", NS)
                assert real is not None and real.get("unit") == declared[model][conn.get("name")].unit
                assert ssd_units[real.get("unit")] == defined[real.get("unit")]
                n_real += 1
        assert n_real == 6 * len(spec.connections) and {"rad", "rad/s", "N.m"} <= set(ssd_units)
        for c in spec.components:
            read_ssv(str(path), resource=f"resources/{c.name}.ssv", validate=True)
            ssv = ET.fromstring(z.read(f"resources/{c.name}.ssv"))
            units = _units(ssv.find("ssv:Units", NS))
            for p in ssv.findall("ssv:Parameters/ssv:Parameter", NS):
                var = declared[c.model][p.get("name")]
                (v,) = list(p)
                if var.type == "Real":
                    assert v.get("unit") == var.unit and units[var.unit] == defined[var.unit], (c.name, var.name)
                    assert float(v.get("value")) == float({**c.parameters, **c.inputs}[var.name])
                else:
                    assert v.get("unit") is None
    # the parameters a reader needs units for most: the gear's port springs and start state, the motor's speed
    gear = ET.fromstring(zipfile.ZipFile(path).read("resources/gear.ssv"))
    got = {p.get("name"): list(p)[0].get("unit") for p in gear.findall("ssv:Parameters/ssv:Parameter", NS)}
    assert got["k_a"] == "N.m/rad" and got["pinion_w_start"] == "rad/s" and got["twist_a_start"] == "rad"


def test_ssp_1_0_has_no_standard_step_size(exported):
    """The step size stays in the FixedStepMaster annotation: SSP 1.0's DefaultExperiment takes startTime and
    stopTime only (fmpy's copy of the schema refuses a stepSize there)."""
    from fmpy.ssp.ssd import validate_tree

    _, spec, path = exported
    ssd = ET.fromstring(zipfile.ZipFile(path).read(SSD_NAME))
    exp = ssd.find("ssd:DefaultExperiment", NS)
    exp.set("stepSize", repr(spec.comm_step))
    from lxml import etree

    with pytest.raises(Exception, match="stepSize"):
        validate_tree(etree.fromstring(ET.tostring(ssd)), "SystemStructureDescription.xsd")


def test_fmpy_runner_reads_what_the_docs_say(exported):
    """fmpy's own SSP runner (fmpy.ssp.simulation.simulate_ssp) against drivetrain.interop.ssp.FMPY_RUNNER_IGNORES
    and docs/FMU.md: it ignores the parameter files (an idle system: all gear torques 0, where our master's gear
    carries the load from the first step), runs 1 s at 10 ms without stop time and step, refuses a String in
    its own parameter_set and sets a Boolean 'false' to true. The docs say each of these."""
    from types import SimpleNamespace

    from fmpy.ssp.simulation import set_value, simulate_ssp
    from fmpy.ssp.ssd import ParameterSet, find_components, read_ssd

    from drivetrain.interop.ssp import FMPY_RUNNER_IGNORES

    scene, spec, path = exported
    gear = next(c for c in spec.components if c.model == "GearContact")
    assert abs(gear.parameters["twist_b_start"] * gear.parameters["k_b"]) > 10.0       # what the archive holds
    res = simulate_ssp(str(path), stop_time=20 * spec.comm_step, step_size=spec.comm_step)
    for name in ("gear.flange_a_tau", "gear.flange_b_tau", "motors.load_w", "drive_shaft.flange_b_tau"):
        assert np.all(res[name] == 0.0), name                                   # idle: no parameter applied
    res = simulate_ssp(str(path))
    assert res["time"][-1] == pytest.approx(0.99) and res["time"][1] == pytest.approx(0.01)   # not 0 .. 0.5 s
    params = []                      # the archive's own values, named as simulate_ssp's parameter_set wants them
    for c in find_components(read_ssd(str(path)).system):
        for b in c.parameterBindings:
            for values in b.parameterValues:
                for p in values.parameters:
                    p.name = f"{c.name}.{p.name}"
                    params.append(p)
    assert len(params) == sum(len(c.parameters) + len(c.inputs) for c in spec.components)
    with pytest.raises(Exception, match="Unsupported type: String"):
        simulate_ssp(str(path), stop_time=spec.comm_step, step_size=spec.comm_step,
                     parameter_set=ParameterSet(parameters=params))
    got = []
    fake = SimpleNamespace(variables={"b": SimpleNamespace(type="Boolean", valueReference=0)},
                           fmu=SimpleNamespace(setBoolean=lambda vr, values: got.extend(values)))
    set_value(fake, "b", "false")
    assert got == [True]
    docs = " ".join((ROOT / "docs" / "FMU.md").read_text().split())
    for claim in FMPY_RUNNER_IGNORES:
        assert " ".join(claim.split()) in docs, claim
    assert "fmpy, OMSimulator, libcosim and Ecos read alike" not in docs


def test_time_profiles_go_to_the_parameters_that_carry_them(tmp_path, fmu_dir):
    ramp = load_scene(EXAMPLE, SHORT + ["operating_point.speed_profile_rpm=[[0.0, 0.0], [0.2, 1500.0]]",
                                        "operating_point.load_profile_Nm=[[0.0, 0.5], [0.3, 1.31]]"])
    with zipfile.ZipFile(export_ssp(ramp, tmp_path / "ramp.ssp", fmu_dir=fmu_dir)) as z:
        ssv = ET.fromstring(z.read("resources/motors.ssv"))
    got = {p.get("name"): _value(p) for p in ssv.findall("ssv:Parameters/ssv:Parameter", NS)}
    assert "speed_ref_rpm" not in got and "load_torque" not in got
    from drivetrain.models.parameters import parse_profile

    for name, want in (("speed_profile", [[0.0, 0.0], [0.2, 1500.0]]), ("load_profile", [[0.0, 0.5], [0.3, 1.31]])):
        t, v = parse_profile(got[name])                  # read back as the FMU reads it
        assert t.tolist() == [p[0] for p in want] and v.tolist() == [p[1] for p in want]


def test_what_ssp_cannot_say_is_refused_and_nothing_is_written(tmp_path, fmu_dir):
    scene = load_scene(EXAMPLE, SHORT)
    spec = assemble_scene(scene)
    gear = next(c for c in spec.components if c.model == "GearContact")
    gear.inputs["flange_a_phi"] = [[0.0, 0.0], [1.0, 1.0]]        # a profile no parameter carries
    with pytest.raises(ConfigurationError, match="gear.flange_a_phi is a time profile"):
        export_ssp(scene, tmp_path / "x.ssp", fmu_dir=fmu_dir, spec=spec)
    with pytest.raises(ConfigurationError, match=r"ends in \.ssp"):
        export_ssp(scene, tmp_path / "system.zip", fmu_dir=fmu_dir)
    assert list(tmp_path.iterdir()) == []


def test_cli_export_ssp(tmp_path, fmu_dir, capsys):
    """`python -m drivetrain export-ssp` in a fresh process; its two refusals through the same entry point
    (drivetrain.cli.main) in this process (exit status 2, the reason on stderr, no traceback)."""
    from drivetrain.cli import main

    out = tmp_path / "sys.ssp"
    r = subprocess.run([sys.executable, "-m", "drivetrain", "export-ssp", str(EXAMPLE), "--set", "time.duration_s=0.5",
                        "--out", str(out), "--fmu-dir", str(fmu_dir)], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert out.is_file() and "wrote" in r.stdout
    capsys.readouterr()
    rc = main(["export-ssp", str(EXAMPLE), "--out", str(tmp_path / "r.zip"), "--fmu-dir", str(fmu_dir)])
    err = capsys.readouterr().err
    assert rc == 2 and "ends in .ssp" in err and "Traceback" not in err
    blocked = tmp_path / "a_file"
    blocked.write_text("")
    rc = main(["export-ssp", str(EXAMPLE), "--out", str(blocked / "sys.ssp"), "--fmu-dir", str(fmu_dir)])
    err = capsys.readouterr().err
    assert rc == 2 and "cannot write" in err and "Traceback" not in err
    assert not (tmp_path / "r.zip").exists() and not (blocked / "sys.ssp").exists()


_LIBCOSIM = textwrap.dedent("""
    import json, sys
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    log_output_level(CosimLogLevel.WARNING)
    ssp, H, n, every, refs = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), json.loads(sys.argv[5])
    ex = CosimExecution.from_ssp_file(ssp, step_size=round(H * 1e9))     # libcosim steps in integer ns
    obs = CosimObserver.create_last_value()
    ex.add_observer(obs)
    idx = {s.name.decode(): s.index for s in ex.slave_infos()}
    vr = {}
    for key, (inst, var) in refs.items():
        vr[key] = (idx[inst], next(v.reference for v in ex.slave_variables(idx[inst]) if v.name.decode() == var))
    out = {k: [] for k in refs}
    for i in range(n):
        assert ex.step(), f"libcosim step {i} failed"
        if (i + 1) % every == 0:
            for k, (s, r) in vr.items():
                out[k].append(obs.last_real_values(s, [r])[0])
    print("RESULT " + json.dumps(out))
""")


@pytest.mark.hosts
@pytest.mark.parametrize("overrides", [[], ["operating_point.speed_profile_rpm=[[0.0, 0.0], [0.3, 1500.0]]"],
                                       ANOTHER_MACHINE, ANOTHER_CHAIN],
                         ids=["steady", "startup_ramp", "another_machine", "another_chain"])
def test_the_ssp_runs_in_libcosim_as_in_our_master(overrides, fmu_dir, tmp_path):
    pytest.importorskip("libcosimpy")
    scene = load_scene(EXAMPLE, SHORT + overrides)
    spec = assemble_scene(scene)
    path = export_ssp(scene, tmp_path / "system.ssp", fmu_dir=fmu_dir, spec=spec)
    ours = master_torques(scene, tmp_path / "ours", fmu_dir)
    H, n, every = schedule(scene, spec)
    theirs = run_host(_LIBCOSIM, path, repr(H), n, every, json.dumps(torque_refs(scene)))
    assert all(len(v) == n // every for v in theirs.values())
    assert_matches(theirs, ours)


@pytest.mark.hosts
def test_the_native_ssp_runs_in_libcosim_as_in_our_master(fmu_dir, tmp_path):
    """export-ssp --native: the archive of compiled FMUs (no Python in the host) in libcosim, against our
    master on the same native FMUs (backend native)."""
    pytest.importorskip("libcosimpy")
    import shutil
    import zipfile

    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed")
    scene = load_scene(EXAMPLE, SHORT)
    spec = assemble_scene(scene)
    path = export_ssp(scene, tmp_path / "system.ssp", fmu_dir=fmu_dir, spec=spec, native=True)
    with zipfile.ZipFile(path) as z:
        for name in (n for n in z.namelist() if n.endswith(".fmu")):
            with zipfile.ZipFile(z.open(name)) as f:
                assert 'needsExecutionTool="false"' in f.read("modelDescription.xml").decode(), name
    ours = master_torques(scene, tmp_path / "ours", fmu_dir, backend="native")
    H, n, every = schedule(scene, spec)
    theirs = run_host(_LIBCOSIM, path, repr(H), n, every, json.dumps(torque_refs(scene)))
    assert all(len(v) == n // every for v in theirs.values())
    assert_matches(theirs, ours)
