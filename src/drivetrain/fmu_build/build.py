"""Build every FMU of the project (``drivetrain build-fmus [--out DIR] [--only NAME ...]``).

For each slave script (``gearcontact_fmu/slaves/GearContact.py``, and the drivetrain component slaves
rendered from ``fmu_runtime.slave_template`` into a temporary directory, one per model):

1. pythonfmu ``FmuBuilder.build_FMU(script, dest, project_files=[_bundled])``
   where ``_bundled`` holds copies of the packages ``gearcontact_fmu``, ``drivetrain`` and ``fmu_runtime`` (Python
   sources and package data only: no ``__pycache__``, no numba caches). They land in
   ``resources/_bundled/``; the slave script imports the installed packages when importable and falls
   back to the bundled copy (``BEVEL_FMU_USE_BUNDLED=1`` forces it).
2. Post-process ``modelDescription.xml``:
   - ``description=`` on every variable from the slave class attribute ``variable_descriptions``;
   - ``unit=`` on every Real variable whose unit is known, from the slave class attribute ``units``
     (name -> unit) or else from the naming table :data:`NAME_UNITS` (suffixes ``_phi``, ``_w``,
     ``_tau``, ``energy_*`` ...), and the matching ``<UnitDefinitions>`` with SI base-unit exponents;
   - ``<ModelStructure><Outputs>``: ``dependencies`` of every output. By default ``""`` (outputs are
     functions of the FMU state at the communication point only: they are updated in ``do_step``, so
     setting an input never changes an output before the next step). A slave whose outputs do react
     to inputs immediately declares them in a class attribute ``output_dependencies``
     (output name -> list of input names, or ``"inputs"`` for all inputs); those are written as
     ``dependencies="<indices>"`` with ``dependenciesKind`` ``dependent``;
   - ``needsExecutionTool="true"``: the FMU runs only in a host process that can load a CPython
     with the packages of ``resources/requirements.txt`` (the execution tool; generationTool names
     pythonfmu). The native GearContact (``drivetrain.fmu_build.native_gear``) says "false";
   - ``canGetAndSetFMUstate="true"`` where the slave class says ``can_get_and_set_fmu_state = True``
     (it then implements ``_get_fmu_state``/``_set_fmu_state``; pythonfmu keeps the snapshot object).
3. Add what the FMU ships for a user (``drivetrain.fmu_build.fmu_docs``, from the final modelDescription):
   ``documentation/index.html``, the example input, the reference plot, ``resources/requirements.txt``.

4. The FMI wrapper (``drivetrain.fmu_build.fmi_wrapper``): a small C binary compiled from the final
   modelDescription.xml becomes ``binaries/linux64/<id>.so`` and loads pythonfmu's export library, renamed
   next to it; it refuses with fmi2Error what FMI calls an error and never lets a host reach a released slave.
   Without a C compiler the FMU keeps the bare export library, with a warning.

Slave module names must be unique across FMUs (pythonfmu issue #228); build_all checks it.
Built FMUs are outputs, not sources (``fmus/*.fmu`` is git-ignored).
"""
from __future__ import annotations

import importlib.util
import re
import shutil
import sys
import tempfile
import warnings
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from drivetrain.rig.data import RAD_S_PER_RPM


SRC_ROOT = Path(__file__).resolve().parents[2]          # src/
PACKAGES = ("gearcontact_fmu", "drivetrain", "fmu_runtime")
#: hand-written slave scripts (the GearContact shell); the drivetrain component slaves are rendered
#: from fmu_runtime.slave_template, one per model of drivetrain.models.fmu_variables.DESCRIPTIONS
SLAVE_DIRS = (SRC_ROOT / "gearcontact_fmu" / "slaves",)
_IGNORE = shutil.ignore_patterns("__pycache__", "*.pyc", "*.pyo", "*.nbi", "*.nbc", "*.egg-info", ".*",
                                 "seed_maps")    # contact maps shipped for the user's cache, not for the FMU

# SI base-unit exponents (kg, m, s, A, K, mol, cd, rad) of the units used in the project
UNIT_DEFS: dict[str, dict[str, int]] = {
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
    "rad/s2": {"rad": 1, "s": -2},
    "rpm": {"rad": 1, "s": -1},                 # factor 2 pi / 60
    "s": {"s": 1},
    "Hz": {"s": -1},
    "m": {"m": 1},
    "mm": {"m": 1},                             # factor 1e-3
    "m2": {"m": 2},
    "m/s": {"m": 1, "s": -1},
    "kg": {"kg": 1},
    "kg.m2": {"kg": 1, "m": 2},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "N/m": {"kg": 1, "s": -2},
    "N.s/m": {"kg": 1, "s": -1},
    "N/m3": {"kg": 1, "m": -2, "s": -2},
    "N.s/m3": {"kg": 1, "m": -2, "s": -1},
    "Pa": {"kg": 1, "m": -1, "s": -2},
    "J": {"kg": 1, "m": 2, "s": -2},
    "W": {"kg": 1, "m": 2, "s": -3},
    "A": {"A": 1},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "1": {},                                    # dimensionless
}
UNIT_FACTORS = {"rpm": RAD_S_PER_RPM, "mm": 1e-3}

# naming table: applied when the slave does not name the variable in its ``units`` attribute
NAME_UNITS: tuple[tuple[str, str], ...] = (
    (r"(^|_)phi$", "rad"), (r"(^|_)w$", "rad/s"), (r"(^|_)tau(_mean)?$", "N.m"),
    (r"^energy_", "J"), (r"_power$", "W"), (r"(^|_)torque(_|$)", "N.m"), (r"^J(_|$)", "kg.m2"),
    (r"_rpm$", "rpm"), (r"_mm$", "mm"), (r"_s$", "s"), (r"_Hz$", "Hz"),
)


#: the physical quantity of a unit: the modelDescription's <TypeDefinitions> declare one SimpleType per entry
#: used (name = quantity, as the FMI Reference FMUs and Modelica.Units.SI name them) and every Real of that
#: unit refers to it with declaredType. Units without an entry (counts "1", option values) keep the unit only.
QUANTITIES: dict[str, str] = {
    "N.m": "Torque", "rad": "Angle", "rad/s": "AngularVelocity", "rad/s2": "AngularAcceleration",
    "rpm": "AngularVelocity_rpm", "J": "Energy", "W": "Power", "s": "Time", "Hz": "Frequency", "m": "Length",
    "mm": "Length_mm", "m2": "Area", "m/s": "Velocity", "kg": "Mass", "kg.m2": "MomentOfInertia", "N": "Force",
    "N.m/rad": "RotationalSpringConstant", "N.m.s/rad": "RotationalDampingConstant", "N/m": "TranslationalSpringConstant",
    "N.s/m": "TranslationalDampingConstant", "Pa": "Pressure", "N.s/m3": "PressureDampingCoefficient",
    "N/m3": "PressureStiffness", "A": "Current", "V": "Voltage",
}


def unit_for(name: str, overrides: dict | None = None) -> str | None:
    """Unit of a variable: the slave's ``units`` entry, else the naming table, else None.
    Dimensionless variables have the unit "1"; an empty entry means none."""
    if overrides and name in overrides:
        u = overrides[name]
        return u or None
    for pattern, unit in NAME_UNITS:
        if re.search(pattern, name):
            return unit
    return None


def find_slave_scripts(render_dir: str | Path | None = None) -> list[Path]:
    """Every slave script: the hand-written ones in SLAVE_DIRS and, when ``render_dir`` is given, the
    drivetrain component slaves rendered there from ``fmu_runtime.slave_template``."""
    from drivetrain.models.fmu_variables import DESCRIPTIONS
    from fmu_runtime.slave_template import render

    scripts = []
    for d in SLAVE_DIRS:
        if d.is_dir():
            scripts += sorted(p for p in d.glob("*.py") if not p.name.startswith("_"))
    if render_dir is not None:
        render_dir = Path(render_dir)
        render_dir.mkdir(parents=True, exist_ok=True)
        for model in DESCRIPTIONS:
            path = render_dir / f"{model}.py"
            path.write_text(render(model))
            scripts.append(path)
    names = [p.stem for p in scripts]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ValueError(f"slave module names must be unique across FMUs (pythonfmu #228): {sorted(dup)}")
    return scripts


def _copy_packages(dest: Path) -> Path:
    """The packages into ``dest/_bundled``: their data files and the modules that run inside an FMU
    (:func:`drivetrain.fmu_build.bundle.fmu_modules`; the host-only modules stay out)."""
    from drivetrain.fmu_build.bundle import fmu_files

    bundled = dest / "_bundled"
    bundled.mkdir(parents=True)
    dirs = {pkg: SRC_ROOT / pkg for pkg in PACKAGES if (SRC_ROOT / pkg).is_dir()}
    fmu_side = {f.resolve() for f in fmu_files(dirs)}

    def host_only(path: Path) -> bool:
        """A module that never runs inside an FMU, or a folder of a host-only package (its nearest
        package's __init__ is host-only: e.g. fmu_build/native's C sources); package data stays."""
        if path.suffix == ".py":
            return path.resolve() not in fmu_side
        if not path.is_dir():
            return False
        pkg = path
        while not (pkg / "__init__.py").is_file() and pkg.parent != pkg:
            pkg = pkg.parent
        return (pkg / "__init__.py").resolve() not in fmu_side

    def ignore(folder, names):
        return set(_IGNORE(folder, names)) | {n for n in names if host_only(Path(folder) / n)}

    for pkg, src in dirs.items():
        shutil.copytree(src, bundled / pkg, ignore=ignore)
    return bundled


def slave_class(script: Path):
    """Import the slave script under a private module name and return its Fmi2Slave subclass."""
    from pythonfmu import Fmi2Slave

    spec = importlib.util.spec_from_file_location(f"_fmu_build_{script.stem}", script)
    mod = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(script.parent))
    try:
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(script.parent))
    classes = [v for v in vars(mod).values() if isinstance(v, type) and issubclass(v, Fmi2Slave)
               and v is not Fmi2Slave and v.__module__ == mod.__name__]
    if len(classes) != 1:
        raise ValueError(f"{script}: expected exactly one Fmi2Slave subclass, found {len(classes)}")
    return classes[0]




#: what a host needs to run a pythonfmu FMU (documentation/index.html, drivetrain.fmu_build.fmu_docs)
HOST_NOTE = ("This FMU is built with pythonfmu 0.7.0: its binary embeds the host's CPython and imports the model's "
             "Python packages there (they are bundled in <code>resources/_bundled</code>; their own dependencies are "
             "not). The host process must be able to load libpython and import the packages of "
             "<code>resources/requirements.txt</code>; a tool without a Python runtime cannot run it (the native "
             "builds can). The first instance in a process loads the numba kernels from numba's cache or, without "
             "one, compiles them (GearContact: up to tens of seconds; it says so in its log first). Log messages "
             "need logging on (debug logging in fmpy).")


def postprocess_model_description(fmu: Path, units: dict | None = None,
                                  output_dependencies: dict | None = None, variable_descriptions: dict | None = None,
                                  bounds: dict | None = None, initial_dependencies: dict | None = None) -> None:
    """Add units, UnitDefinitions and output dependencies in place, and what the FMU ships for a user
    (drivetrain.fmu_build.fmu_docs: resources/requirements.txt, documentation/index.html from the final
    modelDescription, the example input, the reference plot)."""
    from drivetrain.fmu_build.fmu_docs import fmu_extras

    fmu = Path(fmu)
    tmp = fmu.with_name(fmu.name + ".tmp")
    with zipfile.ZipFile(fmu) as zin:
        items = [(item, zin.read(item.filename)) for item in zin.infolist()]
    xml = next(data for item, data in items if item.filename == "modelDescription.xml")
    xml = edit_model_description(xml, units or {}, output_dependencies or {}, variable_descriptions or {},
                                 bounds, initial_dependencies)
    extras = fmu_extras(xml, HOST_NOTE)
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zout:
        for item, data in items:
            if item.filename == "modelDescription.xml":
                data = xml
            if item.filename in extras:
                continue
            zout.writestr(item, data)
        for name, data in extras.items():
            zout.writestr(name, data)
    tmp.replace(fmu)


def _number(value, kind: str) -> str:
    return str(int(value)) if kind == "Integer" else repr(float(value))


def edit_model_description(data: bytes, units: dict, output_dependencies: dict, descriptions: dict,
                           bounds: dict | None = None, initial_dependencies: dict | None = None) -> bytes:
    """modelDescription.xml with the descriptions, units, UnitDefinitions, TypeDefinitions, bounds, initial
    values and dependencies of the module docstring (also used for the native FMUs, drivetrain.fmu_build.native_gear
    and native_line): one place for both builds.

    - ``bounds``: name -> (min, max) (None: unbounded), written as ``min``/``max`` of the Real or Integer: the
      range the code refuses values outside of (one declaration, read by the code and written here);
    - every output is ``initial="calculated"`` without a start value (FMI 2.0, section 2.2.7: its value is
      computed by the FMU in initialization mode; the Reference FMUs declare their outputs so), and listed
      in ``<ModelStructure><InitialUnknowns>`` (section 2.2.8) with the knowns it is computed from:
      ``initial_dependencies`` (output -> names); by default
      every input and every parameter (the start state follows the flange inputs and the parameters);
    - Integer and Boolean outputs are ``variability="discrete"`` (they change at communication points only).
    """
    root = ET.fromstring(data)
    bounds = bounds or {}
    initial_dependencies = initial_dependencies or {}
    svs = list(root.find("ModelVariables"))
    used = set()
    for sv in svs:
        name = sv.get("name")
        text = descriptions.get(name)
        if text:
            sv.set("description", text)
        kind = sv[0].tag if len(sv) else ""
        value = sv[0] if len(sv) else None
        if name in bounds and kind in ("Real", "Integer"):
            for key, b in zip(("min", "max"), bounds[name]):
                if b is not None:
                    value.set(key, _number(b, kind))
        if sv.get("causality") == "output":
            sv.set("initial", "calculated")
            if value is not None and "start" in value.attrib:
                del value.attrib["start"]
            if kind in ("Integer", "Boolean", "String"):
                sv.set("variability", "discrete")
        if kind != "Real":
            continue
        u = unit_for(name, units)
        if u:
            if u not in UNIT_DEFS:
                raise ValueError(f"unit {u!r} of {name} is not in fmu_build.build.UNIT_DEFS")
            value.set("unit", u)
            used.add(u)
            if u in QUANTITIES:
                value.set("declaredType", QUANTITIES[u])
    for old in root.findall("UnitDefinitions") + root.findall("TypeDefinitions"):
        root.remove(old)
    if used:
        ud = ET.Element("UnitDefinitions")
        for u in sorted(used):
            unit = ET.SubElement(ud, "Unit", name=u)
            attrs = {k: str(v) for k, v in UNIT_DEFS[u].items()}
            if u in UNIT_FACTORS:
                attrs["factor"] = repr(UNIT_FACTORS[u])
            ET.SubElement(unit, "BaseUnit", attrs)
        td = ET.Element("TypeDefinitions")
        for u in sorted((u for u in used if u in QUANTITIES), key=lambda x: QUANTITIES[x]):
            st = ET.SubElement(td, "SimpleType", name=QUANTITIES[u])
            ET.SubElement(st, "Real", quantity=QUANTITIES[u].split("_")[0], unit=u)
        children = list(root)
        idx = next(i for i, c in enumerate(children)
                   if c.tag in ("LogCategories", "DefaultExperiment", "VendorAnnotations", "ModelVariables"))
        root.insert(idx, ud)
        if len(td):
            root.insert(idx + 1, td)
    # output dependencies (indices are 1-based positions in ModelVariables)
    index = {sv.get("name"): i + 1 for i, sv in enumerate(svs)}
    inputs = [sv.get("name") for sv in svs if sv.get("causality") == "input"]
    parameters = [sv.get("name") for sv in svs if sv.get("causality") == "parameter"]
    ms = root.find("ModelStructure")
    if ms is None:
        ms = ET.SubElement(root, "ModelStructure")
    outs = ms.find("Outputs")
    if outs is not None:
        for unk in outs.findall("Unknown"):
            name = svs[int(unk.get("index")) - 1].get("name")
            deps = output_dependencies.get(name, [])
            if deps == "inputs":
                deps = inputs
            unk.set("dependencies", " ".join(str(index[d]) for d in deps))
            if deps:
                unk.set("dependenciesKind", " ".join("dependent" for _ in deps))
            elif "dependenciesKind" in unk.attrib:
                del unk.attrib["dependenciesKind"]
    for old in ms.findall("InitialUnknowns"):
        ms.remove(old)
    calculated = [sv for sv in svs if sv.get("causality") == "output" and sv.get("initial") == "calculated"]
    if calculated:
        iu = ET.Element("InitialUnknowns")
        for sv in calculated:
            deps = initial_dependencies.get(sv.get("name"), inputs + parameters)
            idx = sorted(index[d] for d in dict.fromkeys(deps))
            # no dependenciesKind: "dependent" (not a linear factor), the default
            ET.SubElement(iu, "Unknown", {"index": str(index[sv.get("name")]), "dependencies": " ".join(map(str, idx))})
        pos = [i for i, c in enumerate(ms) if c.tag in ("Outputs", "Derivatives")]
        ms.insert(pos[-1] + 1 if pos else 0, iu)
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def declared_initial_dependencies(cls) -> dict | None:
    """A slave class's ``initial_dependencies``: a dict, or a class method that finds them (the drivetrain
    component slaves run their initialization, drivetrain.models.fmu_variables.initial_dependencies)."""
    deps = getattr(cls, "initial_dependencies", None)
    return deps() if callable(deps) else deps


def build_fmu(script: Path, out_dir: Path) -> Path:
    """Build one FMU from a slave script (see the module docstring)."""
    from pythonfmu.builder import FmuBuilder

    script = Path(script).resolve()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cls = slave_class(script)
    with tempfile.TemporaryDirectory(prefix="fmu_build_") as tmp:
        bundled = _copy_packages(Path(tmp))
        fmu = FmuBuilder.build_FMU(script, dest=out_dir, project_files=[bundled], needsExecutionTool=True,
                                   canGetAndSetFMUstate=bool(getattr(cls, "can_get_and_set_fmu_state", False)))
    fmu = Path(fmu)
    postprocess_model_description(fmu, getattr(cls, "units", None), getattr(cls, "output_dependencies", None),
                                  variable_descriptions=getattr(cls, "variable_descriptions", None),
                                  bounds=getattr(cls, "bounds", None),
                                  initial_dependencies=declared_initial_dependencies(cls))
    # last, from the final modelDescription.xml: the FMI wrapper in front of pythonfmu's export library
    # (drivetrain.fmu_build.fmi_wrapper; without a C compiler the FMU keeps the bare library, and says so here)
    from drivetrain.fmu_build.fmi_wrapper import wrap_pythonfmu_binary

    why = wrap_pythonfmu_binary(fmu)
    if why:
        warnings.warn(f"{fmu.name}: built WITHOUT the FMI wrapper ({why}): pythonfmu's export library answers a "
                      "refused call with fmi2Fatal and a host that calls on crashes (docs/FMU.md)", stacklevel=2)
    return fmu


def build_all(out_dir: str | Path, only=None) -> list[Path]:
    """Build every slave script into ``out_dir`` (only the FMUs are written there); ``only``: model names
    (script stems) to build."""
    with tempfile.TemporaryDirectory(prefix="fmuslaves_") as tmp:
        scripts = find_slave_scripts(Path(tmp) / "slaves")
        if only:
            wanted = set(only)
            unknown = wanted - {s.stem for s in scripts}
            if unknown:
                raise ValueError(f"no slave script for {sorted(unknown)}; available: {[s.stem for s in scripts]}")
            scripts = [s for s in scripts if s.stem in wanted]
        return [build_fmu(s, Path(out_dir)) for s in scripts]
