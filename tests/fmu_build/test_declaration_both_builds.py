"""One declaration per FMU, read by both builds: the pythonfmu slaves and the native builders take what an FMU
declares (model information, variables, units, bounds, initial dependencies) from the library
(``gearcontact_fmu.fmu_variables.declaration``, ``drivetrain.models.fmu_variables.declaration``), neither from
the other; and the modelDescription.xml both builds write from it is the one they wrote before the native
builders stopped probing the pythonfmu slaves (main at 301d087).

The stored SHA-256 are of that XML with its GUID set aside (the GUID is not part of the declaration: the
native gear's hashes its contact map, a native line's the builder's own source files, pythonfmu's is new per
build). The native XML is written by the builders' own functions (no contact map, no compiler: cheap); they
were checked to give the built FMUs' XML byte for byte. An intended change of a declaration changes a hash:
``python tests/fmu_build/test_declaration_both_builds.py`` prints the current ones.
"""
import hashlib
import json
import re
import tempfile
from pathlib import Path


ROOT = Path(__file__).resolve().parents[2]
PLACEHOLDER_GUID = "{00000000-0000-0000-0000-000000000000}"
_COARSE = {"fidelity": "table", "profile_element_size": 0.5e-3, "face_element_size": 5e-3,
           "map_points_per_pitch": 2, "map_approach_points": 6}
#: native GearContact builds: the defaults, a fault, a pair other than the rig's, manufacturing errors
GEARS = {
    "empty": {},
    "fault_severe": {**_COARSE, "health": "severe"},
    "pair_20_40": {**_COARSE, "z_pinion": 20, "z_wheel": 40, "module": 4e-3, "face_width": 22e-3},
    "mfg_errors_mild": {**_COARSE, "health": "mild", "manufacturing_errors": json.dumps(
        {"pinion_eccentricity_um": 8.0, "pinion_phase_rad": 0.5, "wheel_eccentricity_um": 12.0,
         "wheel_profile_um": 3.0})},
}
LINES = ("FlexibleShaft", "UpperTransmission", "MotorLoad")
#: SHA-256 of modelDescription.xml as main at 301d087 wrote it (GUID: PLACEHOLDER_GUID)
NATIVE_SHA256 = {
    "GearContact-empty": "c9c5578baa5e154af167532a7389c3140ecf2b2bb8b356e34e0eb198bef8d641",
    "GearContact-fault_severe": "32f6efc3bcbaba08a7626392bef611e26a806b2ec43e59ec6d62536ac8669abb",
    "GearContact-pair_20_40": "8b8248cd9703a105c52eecd70851ea04a9c475c2c5eb5124669b3a8eba3ca6f9",
    "GearContact-mfg_errors_mild": "3e179fa4392200597458572826dbe2956cf9a913e57f78e26137718960904c17",
    "FlexibleShaft": "ef3293c8921767393961dbe17b5117878405c5ff6d7afaf02d6ec9e30e0a1a22",
    "UpperTransmission": "b83c978f52e4c172ef1a9d822509759f99a28e23d3afbce75a4fe998a2708f93",
    "MotorLoad": "50055cb27f7f50d4d1a76b39881ede2194741fd9529e362206afabd223d7a07c",
}
#: the same for the pythonfmu FMUs (guid and generationDateAndTime emptied: pythonfmu writes new ones per build)
PYTHONFMU_SHA256 = {
    "GearContact": "797e5db97c022e54689a9faa69d0ced9b009ff36ac5436f1452f20c2e8b9a469",
    "FlexibleShaft": "c0a66a6a4ad3e2c7da2e9f09b2119fd4827993e013d1ccef87bb2b08160de0ae",
    "UpperTransmission": "c853da97c9a4c2c2c4e4e732569b07c844f2e5309f8e626e52cec2b2c6702e8b",
    "MotorLoad": "26f00562548f1705e67ae6f946bab9e12ce53f6b7301e327d1666a1d34dc8810",
}
_HOW = "an intended change? the current hashes: python tests/fmu_build/test_declaration_both_builds.py"


def native_xml(name: str) -> bytes:
    """The native modelDescription.xml of ``name`` (GearContact-<set> or a line model), GUID set aside."""
    from drivetrain.fmu_build import native_gear, native_line
    from drivetrain.models.fmu_variables import declaration as line_declaration
    from gearcontact_fmu.fmu_variables import declaration as gear_declaration

    if name.startswith("GearContact-"):
        decl = gear_declaration()
        params = {"fidelity": "table", **GEARS[name.removeprefix("GearContact-")]}   # as build_native_gear
        return native_gear.model_description(decl, native_gear._variables(decl, params), PLACEHOLDER_GUID)
    decl = line_declaration(name)
    return native_line.model_description(decl, native_line.variables(decl), PLACEHOLDER_GUID)


def pythonfmu_xml(fmu: Path) -> bytes:
    import zipfile

    with zipfile.ZipFile(fmu) as z:
        xml = z.read("modelDescription.xml")
    xml = re.sub(rb' guid="[^"]*"', b' guid=""', xml, count=1)
    return re.sub(rb' generationDateAndTime="[^"]*"', b' generationDateAndTime=""', xml, count=1)


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def test_the_native_model_descriptions_are_todays():
    got = {name: _sha(native_xml(name)) for name in NATIVE_SHA256}
    changed = sorted(n for n in got if got[n] != NATIVE_SHA256[n])
    assert not changed, f"native modelDescription.xml changed: {changed} ({_HOW})"
    # the placeholder stands where the GUID goes, and the parameters reach the XML (the sets differ)
    assert PLACEHOLDER_GUID.encode() in native_xml("FlexibleShaft")
    assert len(set(got.values())) == len(got)


def test_the_pythonfmu_model_descriptions_are_todays(pythonfmu_fmus):
    got = {m: _sha(pythonfmu_xml(pythonfmu_fmus[m])) for m in PYTHONFMU_SHA256}
    changed = sorted(m for m in got if got[m] != PYTHONFMU_SHA256[m])
    assert not changed, f"pythonfmu modelDescription.xml changed: {changed} ({_HOW})"


def _slaves() -> dict:
    """{model: a pythonfmu slave instance} of the four FMUs (the scripts the build loads)."""
    from drivetrain.fmu_build.build import slave_class
    from fmu_runtime.slave_template import render

    out = {}
    cls = slave_class(ROOT / "src" / "gearcontact_fmu" / "slaves" / "GearContact.py")
    out["GearContact"] = cls(instance_name="declaration", resources=tempfile.gettempdir())
    with tempfile.TemporaryDirectory() as tmp:
        for model in LINES:
            script = Path(tmp) / f"{model}.py"
            script.write_text(render(model))
            out[model] = slave_class(script)(instance_name="declaration", resources=tempfile.gettempdir())
    return out


def test_the_slaves_register_what_the_library_declares():
    """Each pythonfmu slave's variables (value reference, name, type, causality, variability, start, Integer
    bounds) and class attributes are its declaration's: one place, which the native build reads too."""
    from drivetrain.fmu_build.build import declared_initial_dependencies
    from drivetrain.models.fmu_variables import declaration as line_declaration
    from gearcontact_fmu.fmu_variables import COUNTERS
    from gearcontact_fmu.fmu_variables import declaration as gear_declaration

    for model, slave in _slaves().items():
        decl = gear_declaration() if model == "GearContact" else line_declaration(model)
        registered = []
        for vr, v in sorted(slave.vars.items()):
            # a counter is read from the stage (no attribute): it starts at 0 before the first step
            start = 0 if v.name in COUNTERS and model == "GearContact" else getattr(slave, v.name)
            registered.append((vr, v.name, type(v).__name__, v.causality.name,
                               None if v.variability is None else v.variability.name, start,
                               getattr(v, "min", None), getattr(v, "max", None)))
        declared = [(v.vr, v.name, v.type, v.causality, v.variability, v.start, v.min, v.max)
                    for v in decl.variables]
        assert registered == declared, model
        assert all(type(a[5]) is type(b[5]) or a[1] in COUNTERS for a, b in zip(registered, declared)), model
        cls = type(slave)
        de = cls.default_experiment
        assert (cls.description, cls.author, cls.version) == (decl.description, decl.author, decl.version), model
        assert (de.start_time, de.stop_time, de.step_size, de.tolerance) == (*decl.default_experiment, None), model
        assert (dict(cls.units), dict(cls.variable_descriptions), dict(cls.bounds)) == (
            dict(decl.units), dict(decl.variable_descriptions), dict(decl.bounds)), model
        assert declared_initial_dependencies(cls) == decl.initial_dependency_map(), model


if __name__ == "__main__":
    print("NATIVE_SHA256 =", json.dumps({n: _sha(native_xml(n)) for n in NATIVE_SHA256}, indent=4))
    print("pythonfmu: build them (drivetrain build-fmus --out DIR) and hash pythonfmu_xml(DIR / '<Model>.fmu')")
