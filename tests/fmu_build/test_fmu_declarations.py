"""What the modelDescription of every FMU declares, in both builds, as the FMI 2.0 standard
and the FMI Reference FMUs (modelica/Reference-FMUs) have it: outputs computed in initialization mode are
``initial="calculated"`` without a start value and listed in ``<ModelStructure><InitialUnknowns>`` with the
knowns they are computed from; counts are Integer, switches Boolean; a ``min``/``max`` where the code refuses
values; ``<TypeDefinitions>`` with the physical quantities that the Real variables refer to; the native
GearContact's parameters fixed by its build are constants no host can set. Each FMU also passes
``fmpy validate`` (fmpy.validation.validate_fmu)."""
import math
import shutil
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import pytest

fmpy = pytest.importorskip("fmpy")
from fmpy.fmi1 import FMICallException  # noqa: E402
from _fmi_instances import KEEP, get_values, open_instance  # noqa: E402

MODELS = ("GearContact", "FlexibleShaft", "UpperTransmission", "MotorLoad")
H = 1.0 / 12000.0
_KEEP = KEEP


@pytest.fixture(scope="module")
def fmus(fmus_both_builds):
    """{(build, model): path} for build "pythonfmu" and, with a C toolchain, "native" (tests/conftest.py)."""
    return fmus_both_builds


def _root(path):
    with zipfile.ZipFile(path) as z:
        return ET.fromstring(z.read("modelDescription.xml"))


def _each(fmus):
    return [(key, path, _root(path)) for key, path in sorted(fmus.items())]


def test_every_fmu_validates(fmus):
    from fmpy.validation import validate_fmu

    assert len(fmus) in (4, 8)
    for key, path in fmus.items():
        assert validate_fmu(str(path)) == [], key


def test_outputs_are_calculated_and_initial_unknowns_name_their_knowns(fmus):
    """FMI 2.0 section 2.2.7/2.2.8: an output the FMU computes at initialization has initial "calculated" (no
    start), and InitialUnknowns lists exactly those outputs, in index order, each with dependencies on
    knowns only (inputs and parameters)."""
    for key, _, root in _each(fmus):
        svs = list(root.find("ModelVariables"))
        outputs = [i + 1 for i, sv in enumerate(svs) if sv.get("causality") == "output"]
        for i in outputs:
            sv = svs[i - 1]
            assert sv.get("initial") == "calculated" and sv[0].get("start") is None, (key, sv.get("name"))
        iu = root.find("ModelStructure").find("InitialUnknowns")
        assert iu is not None, key
        listed = [int(u.get("index")) for u in iu]
        assert listed == outputs, key
        knowns = {i + 1 for i, sv in enumerate(svs) if sv.get("causality") in ("input", "parameter")}
        inputs = {i + 1 for i, sv in enumerate(svs) if sv.get("causality") == "input"}
        deps = {svs[int(u.get("index")) - 1].get("name"): {int(d) for d in u.get("dependencies").split()}
                for u in iu}
        assert all(d <= knowns for d in deps.values()), key
        # the torques follow the flange inputs (a spring-side port's start torque); the inertia-side angles
        # and speeds of the drivetrain components are their start state, from the parameters alone
        assert inputs and any(d & inputs for d in deps.values()), key
        if "flange_b_tau" in deps or "drive_tau" in deps:
            assert deps.get("flange_b_tau", deps.get("drive_tau")) & inputs, key
        if key[1] != "GearContact":
            from drivetrain.models.fmishell import PORTS
            from drivetrain.system import INERTIA

            for port, kind in PORTS[key[1]].items():
                if kind == INERTIA:
                    assert deps[f"{port}_phi"] and not deps[f"{port}_phi"] & inputs, (key, port)
        else:
            assert deps["energy_supplied"] == set() and deps["flange_a_tau"] >= inputs
            assert deps["n_substeps"] == set() and deps["pinion_w"] >= inputs
        if key[1] in ("FlexibleShaft", "MotorLoad"):      # exactly the inputs that move it (a spring-side port)
            name = {i + 1: sv.get("name") for i, sv in enumerate(svs)}
            port = "flange_b" if key[1] == "FlexibleShaft" else "drive"
            assert {name[i] for i in deps[f"{port}_tau"] & inputs} == {f"{port}_phi", f"{port}_w"}, key


def test_counts_are_integer_and_switches_boolean(fmus):
    for key, _, root in _each(fmus):
        v = {sv.get("name"): sv for sv in root.find("ModelVariables")}
        if key[1] != "UpperTransmission":           # (no spring-side port: nothing to correct)
            assert v["energy_correction"][0].tag == "Boolean", key
        if key[1] == "GearContact":
            for n in ("n_substeps", "n_refinements", "n_separations"):
                assert v[n][0].tag == "Integer" and v[n].get("variability") == "discrete", (key, n)
            assert v["friction"][0].tag == v["contact_damping"][0].tag == "Boolean"
        # no other count declared Real with unit "1" (n_contact is the contact-map's interpolated count of
        # contact elements at fidelity table: a fractional number, Real by right)
        reals = [n for n, sv in v.items() if n.startswith("n_") and sv[0].tag == "Real"]
        assert reals in ([], ["n_contact"]), (key, reals)


def test_bounds_are_the_ones_the_code_checks(fmus):
    from drivetrain.models.parameters import POSITIVE
    from gearcontact_fmu.params import MAP_GRID_RANGE

    assert POSITIVE > 0.0 and math.nextafter(0.0, 1.0) == POSITIVE          # min = POSITIVE means "> 0"
    expect = {
        "GearContact": {"J_pinion": (POSITIVE, None), "J_wheel": (POSITIVE, None), "max_substep": (POSITIVE, None),
                        "tooth_compliance": (1.0, None), "map_points_per_pitch": MAP_GRID_RANGE,
                        "map_approach_points": MAP_GRID_RANGE},
        "FlexibleShaft": {"max_substep": (POSITIVE, None), "J_a": (POSITIVE, None), "k_shaft": (POSITIVE, None),
                          "n_elements": (1, 1000), "mass_model": (0, 1)},
        "UpperTransmission": {"max_substep": (POSITIVE, None)},
        "MotorLoad": {"max_substep": (POSITIVE, None), "J_motor": (POSITIVE, None), "k_c1": (POSITIVE, None),
                      "ratio_pg": (POSITIVE, None), "load_mode": (0, 1)},
    }
    for key, _, root in _each(fmus):
        v = {sv.get("name"): sv for sv in root.find("ModelVariables")}
        for name, (lo, hi) in expect[key[1]].items():
            el = v[name][0]
            got = tuple(None if el.get(k) is None else float(el.get(k)) for k in ("min", "max"))
            assert got == (lo, hi), (key, name, got)


def test_type_definitions_carry_the_quantities(fmus):
    from drivetrain.fmu_build.build import QUANTITIES

    for key, _, root in _each(fmus):
        types = {st.get("name"): st[0] for st in root.find("TypeDefinitions")}
        for name, unit in (("Torque", "N.m"), ("Angle", "rad"), ("AngularVelocity", "rad/s"), ("Energy", "J")):
            assert (types[name].get("quantity"), types[name].get("unit")) == (name, unit), (key, name)
        for sv in root.find("ModelVariables"):
            el = sv[0]
            if el.tag == "Real" and el.get("unit") in QUANTITIES:
                t = el.get("declaredType")
                assert t == QUANTITIES[el.get("unit")] and types[t].get("unit") == el.get("unit"), (key, sv.get("name"))
        v = {sv.get("name"): sv[0] for sv in root.find("ModelVariables")}
        assert v["energy_stored"].get("declaredType") == "Energy"


def test_the_native_gears_build_parameters_are_constants(fmus):
    """FMI 2.0 section 2.2.7: a value a host cannot change is causality local, variability constant."""
    if ("native", "GearContact") not in fmus:
        pytest.skip("gcc not installed")
    from drivetrain.fmu_build.native_gear import IGNORED_PARAMETERS, RUNTIME_PARAMETERS

    v = {sv.get("name"): sv for sv in _root(fmus[("native", "GearContact")]).find("ModelVariables")}
    py = {sv.get("name"): sv for sv in _root(fmus[("pythonfmu", "GearContact")]).find("ModelVariables")}
    params = [n for n, sv in py.items() if sv.get("causality") == "parameter"]
    fixed = [n for n in params if n not in RUNTIME_PARAMETERS | IGNORED_PARAMETERS]
    assert len(fixed) >= 25
    for n in fixed:
        assert (v[n].get("causality"), v[n].get("variability")) == ("local", "constant"), n
        assert v[n][0].get("start") is not None, n
    for n in RUNTIME_PARAMETERS:
        assert (v[n].get("causality"), v[n].get("variability")) == ("parameter", "fixed"), n
    s, vr = open_instance(fmus[("native", "GearContact")], None, "const")
    with pytest.raises(FMICallException):            # even the built value: a constant is not set
        s.setReal([vr["module"].valueReference], [float(vr["module"].start)])
    assert "a constant of this build" in s.log_lines()


def _steps(path, params, n):
    s, vr = open_instance(path, params, "steps")
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    names = ("n_substeps", "n_refinements", "n_separations", "energy_correction")
    first = get_values(s, vr, names)
    for k in range(n):
        s.doStep(k * H, H)
    return first, get_values(s, vr, names)


def test_the_counters_count_in_both_builds(fmus):
    """n_substeps = steps x ceil(H / max_substep), read with fmi2GetInteger; energy_correction with
    fmi2GetBoolean."""
    builds = [b for b in ("pythonfmu", "native") if (b, "GearContact") in fmus]
    for build in builds:
        params = {"fidelity": "analytic"} if build == "pythonfmu" else {}
        first, last = _steps(fmus[(build, "GearContact")], params, 12)
        assert first[:3] == [0.0, 0.0, 0.0] and first[3] == 1.0, build
        assert last[0] == 12 * math.ceil(H / 1e-5) and last[1] >= 0 and last[2] >= 0, (build, last)


#: tolerances of the t = 0 balance, fixed before the fix was measured: the pinion's mesh torque is the root of
#: a search on the model the FMU steps (to rounding); the wheel's differs from ratio x pinion by the mesh
#: friction of the step-end state (a bevel mesh loses well under 0.1 % of the power at these loads)
PINION_BALANCE_REL = 1e-9
WHEEL_RATIO_REL = 1e-3


def gear_slave_at_t0(spec):
    """The GearContact slave as the master starts it from an assembled system, after
    exit_initialization_mode (its t = 0 outputs)."""
    import tempfile

    from drivetrain.fmu_build.build import slave_class

    root = Path(__file__).resolve().parents[2]
    g = spec.components_of("GearContact")[0]
    cls = slave_class(root / "src" / "gearcontact_fmu" / "slaves" / "GearContact.py")
    s = cls(instance_name="t0", resources=tempfile.gettempdir())
    for k, x in g.parameters.items():
        setattr(s, k, x)
    s.enter_initialization_mode()
    s.exit_initialization_mode()
    return s


def _gear_at_t0(overrides):
    """:func:`gear_slave_at_t0` on the example scene with these overrides, and the assembled steady state."""
    from drivetrain.run.runner import assemble_scene
    from drivetrain.scene.load import load_scene

    root = Path(__file__).resolve().parents[2]
    spec = assemble_scene(load_scene(root / "scenarios" / "example.toml", ["time.duration_s=0.01", *overrides]))
    return gear_slave_at_t0(spec), spec.metadata["steady_state"]


def test_the_gear_starts_in_balance_on_the_example_scene():
    """The t = 0 outputs of the gear as the master starts it: the mesh torque on the pinion balances the port
    spring (steady start), and the wheel's is ratio times the pinion's (the mesh balance, less its friction;
    independent oracle: 15.03 N.m steady on the propeller shaft, docs/DRIVETRAIN.md). Before the mesh started
    at its own static deflection: -5.63 / 22.5 N.m."""
    s, _ = _gear_at_t0([])
    assert s.mesh_torque_wheel == pytest.approx(-4.0 * s.mesh_torque_pinion, rel=WHEEL_RATIO_REL)   # the mesh balance
    assert s.mesh_torque_pinion == pytest.approx(s.flange_a_tau, rel=PINION_BALANCE_REL)           # the pinion's
    assert s.mesh_torque_wheel == pytest.approx(15.03, rel=0.01)


@pytest.mark.parametrize("overrides", [
    ["effects.mesh_contact = \"analytic\""],
    ["operating_point.load_torque_Nm = 0.5", "operating_point.drive_speed_rpm = 600.0"],
    ["operating_point.load_torque_Nm = 2.5", "effects.friction = false"],
    ["effects.mesh_contact = \"analytic\"", "operating_point.load_torque_Nm = 2.5",
     "operating_point.drive_speed_rpm = 900.0"],
    ["effects.manufacturing_errors = true"],
], ids=["analytic", "table-light-slow", "table-heavy-no-friction", "analytic-heavy", "table-manufacturing-errors"])
def test_the_mesh_starts_at_its_own_static_deflection(overrides):
    """Oracle over operating points and fidelities: at t = 0 the mesh torque on the pinion equals the port
    spring's steady torque (-T_MSH of the assembler's steady state, the torque balance of the rig's
    steady-state model), the wheel's is ratio x pinion, and so the wheel's is the steady propeller-shaft
    torque T_PSH (within the mesh friction)."""
    s, ss = _gear_at_t0(overrides)
    assert s.flange_a_tau == pytest.approx(-ss["T_msh"], rel=1e-12)
    assert s.mesh_torque_pinion == pytest.approx(-ss["T_msh"], rel=PINION_BALANCE_REL)
    assert s.mesh_torque_wheel == pytest.approx(-4.0 * s.mesh_torque_pinion, rel=WHEEL_RATIO_REL)
    assert s.mesh_torque_wheel == pytest.approx(ss["T_psh"], rel=WHEEL_RATIO_REL)


def test_a_map_not_cached_at_assembly_is_balanced_on_after_the_cost_checks(monkeypatch, tmp_path):
    """The assembler builds no contact map (the cost refusal comes after it): a table gear whose map is not
    cached starts at the analytic guess there, and the runner recomputes the start with the map once its checks
    passed (run.assemble.start_with_map), so a first run starts like every later one."""
    from drivetrain.run import assemble as asm
    from drivetrain.run.runner import prepare_run
    from drivetrain.scene.load import load_scene

    real = asm.start_mesh_model
    calls = []

    def not_cached_yet(gear, build_map=False):
        calls.append(build_map)
        return real(gear, build_map) if build_map else (None, asm.MESH_START_GUESS)

    monkeypatch.setattr(asm, "start_mesh_model", not_cached_yet)
    scene = load_scene(Path(__file__).resolve().parents[2] / "scenarios" / "example.toml", ["time.duration_s=0.01"])
    assert asm.assemble(scene).metadata["mesh_start"] == asm.MESH_START_GUESS
    plan = prepare_run(scene, None, "inprocess", None, fmu_dir=tmp_path, force=False, log=lambda m: None)
    assert calls == [False, False, True]
    assert plan.spec.metadata["mesh_start"] == "balanced on the table model"


def test_a_sweep_starts_a_map_not_cached_at_assembly_balanced_too(monkeypatch, tmp_path):
    """The same rule in a sweep: it assembles every scene before preparing the maps, and then recomputes the
    start of the gears that started at the guess, so a sweep's runs start as `drivetrain run` starts them, whatever
    the cache held (the runs it hands to its workers are recorded here instead of run)."""
    from drivetrain.campaigns import sweep as S
    from drivetrain.run import assemble as asm
    from drivetrain.scene.load import load_scene

    real = asm.start_mesh_model
    cached = {"map": False}

    def cached_after_preparation(gear, build_map=False):
        return real(gear, build_map) if build_map or cached["map"] else (None, asm.MESH_START_GUESS)

    def prepared(*args, **kwargs):
        cached["map"] = True

    handed = []

    def record(scenes, specs, out, **kwargs):
        handed.extend(specs)
        return [], []

    monkeypatch.setattr(asm, "start_mesh_model", cached_after_preparation)
    monkeypatch.setattr(S, "_prepare_fmus", prepared)
    monkeypatch.setattr(S, "_cases", record)
    scene = load_scene(Path(__file__).resolve().parents[2] / "scenarios" / "example.toml", ["time.duration_s=0.01"])
    S.run_sweep([scene], tmp_path / "out", progress=False)
    assert [sp.metadata["mesh_start"] for sp in handed] == ["balanced on the table model"]


def test_function_prefix_links_several_source_fmus_into_one_binary(fmus, tmp_path):
    """FMI 2.0 section 2.1.1 / fmi2Functions.h: a source FMU compiled with FMI2_FUNCTION_PREFIX names its
    functions <prefix>fmi2...; the shipped headers (the Modelica Association's 2.0.5, not fmpy's copy, which
    ignores the prefix) let three of ours share one binary."""
    import ctypes
    import subprocess

    if ("native", "GearContact") not in fmus:
        pytest.skip("gcc not installed")
    objects = []
    for model in ("FlexibleShaft", "MotorLoad", "GearContact"):
        d = tmp_path / model
        with zipfile.ZipFile(fmus[("native", model)]) as z:
            z.extractall(d)
        sources = [f for f in (d / "sources").iterdir() if f.suffix == ".c"]
        with open(d / "sources" / "fmi2Functions.h") as f:
            assert "FMI2_ACTUAL_FUNCTION_PREFIX" in f.read()
        for src in sources:
            obj = tmp_path / f"{model}_{src.stem}.o"
            subprocess.run(["gcc", "-O0", "-fPIC", "-std=c99", f"-DFMI2_FUNCTION_PREFIX={model}_",
                            f"-I{d / 'sources'}", "-c", str(src), "-o", str(obj)], check=True)
            objects.append(str(obj))
    so = tmp_path / "three.so"
    subprocess.run(["gcc", "-shared", *objects, "-o", str(so), "-lm"], check=True)    # no duplicate symbols
    lib = ctypes.CDLL(str(so))
    for model in ("FlexibleShaft", "MotorLoad", "GearContact"):
        fn = getattr(lib, f"{model}_fmi2GetVersion")
        fn.restype = ctypes.c_char_p
        assert fn() == b"2.0"
        assert hasattr(lib, f"{model}_fmi2DoStep") and hasattr(lib, f"{model}_fmi2Instantiate")
    assert not hasattr(lib, "fmi2GetVersion")


def test_hosts_leave_the_constants_alone(tmp_path, fmu_dir):
    """The native gear's constants are neither in the SSP's parameter set nor set by our master (its check
    accepts the scene's value when it equals the built one and names the difference otherwise)."""
    if shutil.which("gcc") is None:
        pytest.skip("gcc not installed")
    from drivetrain.fmu_build.fmus import load_fmu_info
    from drivetrain.cosim.plan import _check_parameters
    from drivetrain.interop.ssp import export_ssp
    from drivetrain.run.runner import assemble_scene
    from drivetrain.scene.load import load_scene

    root = Path(__file__).resolve().parents[2]
    scene = load_scene(root / "scenarios" / "example.toml", ["time.duration_s=0.01"])
    spec = assemble_scene(scene)
    path = export_ssp(scene, tmp_path / "system.ssp", fmu_dir=fmu_dir, spec=spec, native=True)
    with zipfile.ZipFile(path) as z:
        ssv = z.read("resources/gear.ssv").decode()
        fmu = tmp_path / "GearContact.fmu"
        fmu.write_bytes(z.read("resources/GearContact.fmu"))
    assert 'name="J_pinion"' in ssv and 'name="health"' not in ssv and 'name="fidelity"' not in ssv
    gear = spec.components_of("GearContact")[0]
    variables = load_fmu_info(fmu).variables
    assert variables["health"].constant and gear.parameters["health"] == "healthy"
    problems = []
    _check_parameters(gear, variables, problems)
    assert problems == []
    gear.parameters["map_points_per_pitch"] = 64
    _check_parameters(gear, variables, problems)
    assert len(problems) == 1 and "was built with map_points_per_pitch = 48" in problems[0], problems
