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
     pythonfmu). The native GearContact (``drivetrain.cosim.native_gear``) says "false";
   - ``canGetAndSetFMUstate="true"`` where the slave class says ``can_get_and_set_fmu_state = True``
     (it then implements ``_get_fmu_state``/``_set_fmu_state``; pythonfmu keeps the snapshot object).

3. The FMI wrapper (``drivetrain.cosim.fmi_wrapper``): a small C binary compiled from the final
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

from fmu_runtime import RUNTIME_PACKAGES

SRC_ROOT = Path(__file__).resolve().parents[2]          # src/
PACKAGES = ("gearcontact_fmu", "drivetrain", "fmu_runtime")
#: hand-written slave scripts (the GearContact shell); the drivetrain component slaves are rendered
#: from fmu_runtime.slave_template, one per model of drivetrain.models.fmishell.DESCRIPTIONS
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
UNIT_FACTORS = {"rpm": 2.0 * 3.141592653589793 / 60.0, "mm": 1e-3}

# naming table: applied when the slave does not name the variable in its ``units`` attribute
NAME_UNITS: tuple[tuple[str, str], ...] = (
    (r"(^|_)phi$", "rad"), (r"(^|_)w$", "rad/s"), (r"(^|_)tau(_mean)?$", "N.m"),
    (r"^energy_", "J"), (r"_power$", "W"), (r"(^|_)torque(_|$)", "N.m"), (r"^J(_|$)", "kg.m2"),
    (r"_rpm$", "rpm"), (r"_mm$", "mm"), (r"_s$", "s"), (r"_Hz$", "Hz"),
)


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
    from drivetrain.models.fmishell import DESCRIPTIONS
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
    (:func:`drivetrain.cosim.bundle.fmu_modules`; the host-only modules stay out)."""
    from drivetrain.cosim.bundle import fmu_files

    bundled = dest / "_bundled"
    bundled.mkdir(parents=True)
    dirs = {pkg: SRC_ROOT / pkg for pkg in PACKAGES if (SRC_ROOT / pkg).is_dir()}
    fmu_side = {f.resolve() for f in fmu_files(dirs)}

    def host_only(path: Path) -> bool:
        """A module that never runs inside an FMU, or a folder of a host-only package (its nearest
        package's __init__ is host-only: e.g. cosim/native's C sources); package data stays."""
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

    spec = importlib.util.spec_from_file_location(f"_fmubuild_{script.stem}", script)
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




def runtime_requirements() -> str:
    """``resources/requirements.txt`` of every FMU: the Python packages its code imports in the host
    process, pinned to the versions it was built and tested with."""
    from importlib.metadata import PackageNotFoundError, version

    lines = ["# Python packages this FMU imports in the host's Python process (a CPython with the",
             f"# pythonfmu export runtime, Python {sys.version_info.major}.{sys.version_info.minor} here).",
             "# Install them with: python -m pip install -r requirements.txt"]
    for pkg in RUNTIME_PACKAGES:
        try:
            lines.append(f"{pkg}=={version(pkg)}")
        except PackageNotFoundError:
            lines.append(pkg)
    return "\n".join(lines) + "\n"


def documentation_html(model: str, description: str, requirements: str) -> str:
    """``documentation/index.html``: what the FMU is and what a host needs to run it."""
    import html

    req = html.escape(requirements)
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(model)}</title></head><body>"
            f"<h1>{html.escape(model)}</h1><p>{html.escape(description or '')}</p>"
            "<h2>What a host needs</h2><p>This FMU is built with pythonfmu 0.7.0: its binary embeds the "
            "host's CPython and imports the model's Python packages there (they are bundled in "
            "<code>resources/_bundled</code>; their own dependencies are not). The host process must be "
            "able to load libpython and import the packages below (<code>resources/requirements.txt</code>); "
            "a tool without a Python runtime cannot run it. The first instantiation in a process compiles "
            "the numba kernels (seconds). Log messages need logging on (debug logging in fmpy).</p>"
            f"<pre>{req}</pre></body></html>\n")


def postprocess_model_description(fmu: Path, units: dict | None = None,
                                  output_dependencies: dict | None = None, model: str = "",
                                  description: str = "", variable_descriptions: dict | None = None) -> None:
    """Add units, UnitDefinitions and output dependencies in place, and the
    runtime requirements and documentation (resources/requirements.txt, documentation/index.html)."""
    fmu = Path(fmu)
    tmp = fmu.with_name(fmu.name + ".tmp")
    with zipfile.ZipFile(fmu) as zin, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = edit_model_description(data, units or {}, output_dependencies or {}, variable_descriptions or {})
            if item.filename in ("resources/requirements.txt", "documentation/index.html"):
                continue
            zout.writestr(item, data)
        req = runtime_requirements()
        zout.writestr("resources/requirements.txt", req)
        zout.writestr("documentation/index.html", documentation_html(model or fmu.stem, description, req))
    tmp.replace(fmu)


def edit_model_description(data: bytes, units: dict, output_dependencies: dict, descriptions: dict) -> bytes:
    """modelDescription.xml with the descriptions, units, UnitDefinitions and output dependencies of
    the module docstring (also used for the native GearContact, drivetrain.cosim.native_gear)."""
    root = ET.fromstring(data)
    svs = list(root.find("ModelVariables"))
    used = set()
    for sv in svs:
        text = descriptions.get(sv.get("name"))
        if text:
            sv.set("description", text)
        real = sv.find("Real")
        if real is None:
            continue
        u = unit_for(sv.get("name"), units)
        if u:
            if u not in UNIT_DEFS:
                raise ValueError(f"unit {u!r} of {sv.get('name')} is not in fmubuild.UNIT_DEFS")
            real.set("unit", u)
            used.add(u)
    for old in root.findall("UnitDefinitions"):
        root.remove(old)
    if used:
        ud = ET.Element("UnitDefinitions")
        for u in sorted(used):
            unit = ET.SubElement(ud, "Unit", name=u)
            attrs = {k: str(v) for k, v in UNIT_DEFS[u].items()}
            if u in UNIT_FACTORS:
                attrs["factor"] = repr(UNIT_FACTORS[u])
            ET.SubElement(unit, "BaseUnit", attrs)
        children = list(root)
        idx = next(i for i, c in enumerate(children)
                   if c.tag in ("TypeDefinitions", "LogCategories", "DefaultExperiment", "VendorAnnotations",
                                "ModelVariables"))
        root.insert(idx, ud)
    # output dependencies (indices are 1-based positions in ModelVariables)
    index = {sv.get("name"): i + 1 for i, sv in enumerate(svs)}
    inputs = [sv.get("name") for sv in svs if sv.get("causality") == "input"]
    ms = root.find("ModelStructure")
    outs = ms.find("Outputs") if ms is not None else None
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
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def build_fmu(script: Path, out_dir: Path) -> Path:
    """Build one FMU from a slave script (see the module docstring)."""
    from pythonfmu.builder import FmuBuilder

    script = Path(script).resolve()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cls = slave_class(script)
    with tempfile.TemporaryDirectory(prefix="fmubuild_") as tmp:
        bundled = _copy_packages(Path(tmp))
        fmu = FmuBuilder.build_FMU(script, dest=out_dir, project_files=[bundled], needsExecutionTool=True,
                                   canGetAndSetFMUstate=bool(getattr(cls, "can_get_and_set_fmu_state", False)))
    fmu = Path(fmu)
    postprocess_model_description(fmu, getattr(cls, "units", None), getattr(cls, "output_dependencies", None),
                                  model=cls.__name__, description=getattr(cls, "description", ""),
                                  variable_descriptions=getattr(cls, "variable_descriptions", None))
    # last, from the final modelDescription.xml: the FMI wrapper in front of pythonfmu's export library
    # (drivetrain.cosim.fmi_wrapper; without a C compiler the FMU keeps the bare library, and says so here)
    from drivetrain.cosim.fmi_wrapper import wrap_pythonfmu_binary

    why = wrap_pythonfmu_binary(fmu)
    if why:
        warnings.warn(f"{fmu.name}: built WITHOUT the FMI wrapper ({why}): pythonfmu's export library answers a "
                      "refused call with fmi2Fatal and a host that calls on crashes (docs/FMU.md)", stacklevel=2)
    return fmu


def build_all(out_dir: str | Path = "fmus", only=None) -> list[Path]:
    """Build every slave script into ``out_dir``; ``only``: model names (script stems) to build."""
    with tempfile.TemporaryDirectory(prefix="fmuslaves_") as tmp:
        scripts = find_slave_scripts(Path(tmp) / "slaves")
        if only:
            wanted = set(only)
            unknown = wanted - {s.stem for s in scripts}
            if unknown:
                raise ValueError(f"no slave script for {sorted(unknown)}; available: {[s.stem for s in scripts]}")
            scripts = [s for s in scripts if s.stem in wanted]
        return [build_fmu(s, Path(out_dir)) for s in scripts]
