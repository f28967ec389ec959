"""A Python-free GearContact FMU for the ``table`` fidelity: the contact map as a binary resource and the
stage compiled from C (``gearcontact_fmu/native/gearcontact_native.c``), docs/FMU.md "A Python-free
GearContact".

``build_native_gear(parameters, out)`` takes the GearContact parameters (the dict ``drivetrain.run.assemble``
produces for component "gear", or any subset; the rest take the FMU's declared defaults) and

1. builds the contact map exactly as the pythonfmu slave does (``gearcontact_fmu.fmu_parameters``, the
   translation of the FMU's parameters the slave builds its stage with: the same cache, fault parsing and
   manufacturing errors), with friction, contact damping and tooth compliance in their neutral state (the
   C model applies those at initialization: they stay settable);
2. writes the map (and the manufacturing-error offset, if any) to ``resources/contact_map.bin``;
3. writes ``gearcontact_build.h``: value references (the same as the pythonfmu FMU's), start values,
   the parameters fixed by the build, and the model constants (from the Python modules);
4. writes ``modelDescription.xml`` (the variables, units and descriptions);
5. compiles ``binaries/linux64/GearContact.so`` with gcc (no Python) and zips the FMU with its
   ``sources/`` so other platforms can compile it.

What the FMU declares (model information, variables in value-reference order, units, descriptions, bounds,
initial dependencies) is read from the library, ``gearcontact_fmu.fmu_variables.declaration()`` (plain data,
a ``fmu_runtime.declaration.FmuDeclaration``): the pythonfmu slave reads the same; no slave is loaded here.

Parameters the map depends on (geometry, PCM constants, resolution, health, faults, mesh files, map
grid, manufacturing errors, u_max) are fixed by the build: the FMU declares them as constants (causality
"local", variability "constant", the built value as start: FMI 2.0 section 2.2.7) and refuses any
fmi2Set of them with fmi2Error and a message.
"""
from __future__ import annotations

import hashlib
import math
import os
import platform
import shutil
import struct
import subprocess
import tempfile
import uuid
import zipfile
from pathlib import Path
from typing import Callable
from xml.etree import ElementTree as ET

import numpy as np

import gearcontact_fmu
from fmu_runtime.declaration import FmuDeclaration
from gearcontact_fmu import fmu_variables
from gearcontact_fmu.params import GEAR_MODEL
from drivetrain.fmu_build.fmi_headers import COMMON_HEADERS, SHELL_HEADER, copy_fmi_headers, fmi_header_dir
from drivetrain.errors import NativeBuildError

NATIVE_DIR = Path(gearcontact_fmu.__file__).resolve().parent / "native"
C_SOURCE = "gearcontact_native.c"
#: the coupling correction, shared with the native line FMUs (drivetrain.fmu_build.native_line): in
#: gearcontact_fmu/native, shipped in each FMU's sources/ (the FMI shell and headers: :func:`shared_sources`)
SHARED_HEADERS = ("coupling_correction.h",)
BUILD_HEADER = "gearcontact_build.h"
VAR_HEADER = "gearcontact_var.h"          #: GcVar (package data, shipped in sources/)
VALUES_SOURCE = "gearcontact_values.c"     #: generated per build: GC_GUID and GC_VARS
MAP_RESOURCE = "contact_map.bin"

#: parameters the C model reads at initialization: settable as in the pythonfmu GearContact
RUNTIME_PARAMETERS = frozenset({
    "J_pinion", "J_wheel", "k_a", "d_a", "k_b", "d_b", "max_substep", "scheme", "output_torque",
    "energy_correction", "friction", "contact_damping", "tooth_compliance", "c_compression", "c_expansion",
    "initial_state", "pinion_phi_start", "pinion_w_start", "wheel_phi_start", "wheel_w_start", "twist_a_start",
    "twist_b_start"})
#: accepted and not used, as by the pythonfmu GearContact at fidelity table (analytic mesh only)
IGNORED_PARAMETERS = frozenset({"mesh_damping_ratio", "mesh_phase"})
#: neutral values of the runtime parameters that act on the map's data, used when the map is built
NEUTRAL = {"friction": True, "contact_damping": True, "tooth_compliance": 1.0}

FIXED_NOTE = (" [fixed by this native build: the contact map was computed with it; declared a constant, "
              "setting it is refused]")
IGNORED_NOTE = " [not used at fidelity table]"


def _check(decl: FmuDeclaration, parameters: dict) -> list[str]:
    problems = []
    known = {v.name: v for v in decl.variables}
    for name in parameters:
        if name not in known:
            problems.append(f"parameter {name!r}: not a {GEAR_MODEL} parameter")
        elif known[name].causality != "parameter":
            problems.append(f"parameter {name!r}: is an {known[name].causality}, not a parameter")
    fid = str(parameters.get("fidelity", known["fidelity"].start)).strip().lower()
    if fid != "table":
        problems.append(f"fidelity = {fid!r}: the native GearContact implements fidelity 'table' only")
    mode = str(parameters.get("mode", known["mode"].start)).strip().lower()
    if mode != "stage":
        problems.append(f"mode = {mode!r}: the native GearContact implements mode 'stage' only")
    return problems


def _table_arrays(parameters: dict) -> dict:
    """The map and offset arrays of the table model the slave builds from these parameters (the declared
    defaults for the others, gearcontact_fmu.fmu_variables.parameter_values;
    gearcontact_fmu.fmu_parameters.build_mesh_model, the slave's own translation)."""
    from gearcontact_fmu.fmu_parameters import build_mesh_model

    values = fmu_variables.parameter_values()
    try:
        model = build_mesh_model({**values, **parameters, **NEUTRAL})
    except Exception as exc:  # noqa: BLE001 - every builder error becomes a refusal with its message
        raise NativeBuildError([f"the contact map cannot be built: {type(exc).__name__}: {exc}"]) from None
    from gearcontact_fmu.manufacturing import split_offset

    data, te = split_offset(model)             # manufacturing.with_errors' layout, named there
    values, a, onset, dtheta, ratio, _cc, _ce, _umax, _fric, w_reg, n_rev = data
    return {"values": np.ascontiguousarray(values, dtype="<f8"), "a": np.ascontiguousarray(a, dtype="<f8"),
            "onset": np.ascontiguousarray(onset, dtype="<f8"), "dtheta": float(dtheta), "ratio": float(ratio),
            "w_reg": float(w_reg), "n_rev": int(n_rev), "te": te, "info": dict(model.info)}


def write_map_resource(arrays: dict, path: Path) -> None:
    """The binary map read by the C model (little-endian int64 and IEEE 754 doubles): magic, header
    (n_theta, n_a, n_ch, n_rev, has_offset, z_pinion, z_wheel of the offset, n_rows), dtheta, ratio, w_reg,
    the approach nodes, the onsets, for every angle the index of its row among the distinct rows, the
    distinct rows of the values (gearcontact_fmu.contact_map.distinct_rows: a faulty map is one healthy pitch
    tiled with a few rows of its own), optionally the offset (parameters, pinion, wheel), end mark."""
    from gearcontact_fmu.contact_map import distinct_rows

    values, te = arrays["values"], arrays["te"]
    n_theta, sides, n_a, n_ch = values.shape
    assert sides == 2 and arrays["onset"].shape == (n_theta, 2)
    rows, index = distinct_rows(values)
    pin = whl = None
    if te is not None:
        p, pin, whl = (np.ascontiguousarray(x, dtype="<f8") for x in te)
    with open(path, "wb") as f:
        f.write(b"GCNMAP3\0")
        f.write(struct.pack("<8q", n_theta, n_a, n_ch, arrays["n_rev"], int(te is not None),
                            0 if te is None else len(pin), 0 if te is None else len(whl), len(rows)))
        f.write(struct.pack("<3d", arrays["dtheta"], arrays["ratio"], arrays["w_reg"]))
        f.write(arrays["a"].tobytes())
        f.write(arrays["onset"].tobytes())
        f.write(np.ascontiguousarray(index, dtype="<i8").tobytes())
        f.write(np.ascontiguousarray(rows, dtype="<f8").tobytes())
        if te is not None:
            f.write(p.tobytes())
            f.write(pin.tobytes())
            f.write(whl.tobytes())
        f.write(b"GCNEND\0\0")


def vr_enum(rows: list[dict]) -> list[str]:
    """The VR_<name> value references of a generated build header."""
    return ["enum {", *(f"    VR_{r['name']} = {r['vr']}," for r in rows), "};"]


def start_literals(r: dict) -> tuple[str, str, str]:
    """A variable's start as the C literals of its table row: (real, integer, string)."""
    s = r["start"]
    real = c_double(s) if r["type"] == "Real" else "0.0"
    integer = str(int(bool(s)) if r["type"] == "Boolean" else int(s)) if r["type"] in ("Integer", "Boolean") else "0"
    string = c_string(s) if r["type"] == "String" else '""'
    return real, integer, string


def coupling_defines() -> list[str]:
    """The constants of coupling_correction.h (from gearcontact_fmu.coupling), for a generated build header."""
    from gearcontact_fmu import coupling

    return [f"#define CC_TIME_CONSTANT_S {c_double(coupling.TIME_CONSTANT_S)}",
            f"#define CC_EPS_RAD {c_double(coupling.EPS_RAD)}",
            f"#define CC_CAP_REL {c_double(coupling.CAP_REL)}",
            f"#define CC_CAP_FLOOR_NM {c_double(coupling.CAP_FLOOR_NM)}"]


def c_string(text: str) -> str:
    out = []
    for b in str(text).encode("utf-8"):
        ch = chr(b)
        if ch in '\\"?':
            out.append("\\" + ch)
        elif 0x20 <= b < 0x7F:
            out.append(ch)
        else:
            out.append(f"\\{b:03o}")
    return '"' + "".join(out) + '"'


def c_double(x: float) -> str:
    x = float(x)
    if not math.isfinite(x):
        raise NativeBuildError([f"non-finite value {x!r} cannot be a start value"])
    return f"{x.hex()} /* {x!r} */"


def is_running_state(name: str) -> bool:
    """A parameter that says where a run starts (angles, speeds, twists, how to start), not what the gear is."""
    return name.endswith("_start") or name == "initial_state"


def _variables(decl: FmuDeclaration, parameters: dict) -> list[dict]:
    """Every declared variable with its value reference, type, causality, start (this build's value of a
    parameter it fixes) and role."""
    rows = []
    counters = set(fmu_variables.COUNTERS)
    nan_on_failure = set(fmu_variables.NAN_ON_FAILURE)
    for v in decl.variables:
        if v.name in counters:
            start = 0.0
        elif is_running_state(v.name):
            # at rest, wherever the FMU is built: a scene's running state goes into the host's parameter
            # values (the SSP's, our master's), never into the FMU's defaults (issue 30)
            start = v.start
        else:
            start = parameters.get(v.name, v.start)
        role = "runtime"
        if v.causality == "parameter":
            role = ("runtime" if v.name in RUNTIME_PARAMETERS else
                    "ignored" if v.name in IGNORED_PARAMETERS else "fixed")
        rows.append({"vr": v.vr, "name": v.name, "type": v.type, "causality": v.causality, "start": start,
                     "role": role, "counter": v.name in counters, "nan_on_failure": v.name in nan_on_failure})
    return rows


def write_header(rows: list[dict], path: Path) -> None:
    """gearcontact_build.h: the VR_* names, the constants and the declarations of GC_VARS and GC_GUID (defined
    per build in gearcontact_values.c, :func:`write_values`). The same for every build of one code: the
    compiled gearcontact_native.c is kept and linked with each build's values (:func:`_code_object`)."""
    from gearcontact_fmu import manufacturing, stage
    from gearcontact_fmu.params import MAX_SUBSTEPS_PER_STEP

    sp = stage.StageParams()
    assert [r["vr"] for r in rows] == list(range(len(rows))), "value references must be 0..n-1"
    lines = ["/* generated by drivetrain.fmu_build.native_gear: do not edit (the code of the native GearContact) */",
             "#ifndef GEARCONTACT_BUILD_H", "#define GEARCONTACT_BUILD_H", "",
             f"#define GC_N_VARS {len(rows)}",
             f"#define GC_MAX_SUBSTEPS_PER_STEP {int(MAX_SUBSTEPS_PER_STEP)}",
             f"#define GC_GAMMA {c_double(stage.GAMMA)}",
             f"#define GC_FD_ANGLE {c_double(sp.fd_angle)}",
             f"#define GC_FD_SPEED {c_double(sp.fd_speed)}",
             *coupling_defines(),
             f"#define GC_MFG_CENTRE {c_double(manufacturing.CENTRE)}", "", *vr_enum(rows), "",
             "/* with FMI2_FUNCTION_PREFIX (several source FMUs in one binary, fmi2Functions.h), the build's two",
             "   global tables are named apart like the fmi2 functions */",
             "#if defined(FMI2_FUNCTION_PREFIX)",
             "#define GC_PASTE_(a, b) a##b",
             "#define GC_PASTE(a, b) GC_PASTE_(a, b)",
             "#define GC_GUID GC_PASTE(FMI2_FUNCTION_PREFIX, GC_GUID)",
             "#define GC_VARS GC_PASTE(FMI2_FUNCTION_PREFIX, GC_VARS)",
             "#endif", "",
             "/* this build's GUID and variable table (gearcontact_values.c) */",
             "extern const char GC_GUID[];",
             "extern const GcVar GC_VARS[GC_N_VARS];", "", "#endif", ""]
    path.write_text("\n".join(lines))


def write_values(rows: list[dict], guid: str, path: Path) -> None:
    """gearcontact_values.c: this build's GUID and the GC_VARS table (by value reference: start values, the
    parameters fixed by the build)."""
    lines = ["/* generated by drivetrain.fmu_build.native_gear: do not edit (one build of the native GearContact) */",
             f'#include "{VAR_HEADER}"', f'#include "{BUILD_HEADER}"', "",
             f"const char GC_GUID[] = {c_string(guid)};", "",
             "const GcVar GC_VARS[GC_N_VARS] = {",
             "    /* name, type, is_input, is_parameter, is_counter, nan_on_failure, fixed_by_build, real, int, "
             "string start */"]
    for r in rows:
        real, integer, string = start_literals(r)
        lines.append(f"    {{{c_string(r['name'])}, \"{r['type']}\", {int(r['causality'] == 'input')}, "
                     f"{int(r['causality'] == 'parameter')}, {int(r['counter'])}, {int(r['nan_on_failure'])}, "
                     f"{int(r['role'] == 'fixed')}, "
                     f"{real}, {integer}, {string}}},")
    lines += ["};", ""]
    path.write_text("\n".join(lines))


def xml_start(r: dict) -> str:
    s = r["start"]
    if r["type"] == "Real":
        return repr(float(s))
    if r["type"] == "Boolean":
        return "true" if s else "false"
    if r["type"] == "Integer":
        return str(int(s))
    return str(s)


def native_model_description(decl: FmuDeclaration, rows: list[dict], guid: str, *, c_source: str, note: str,
                             tool: str, descriptions: dict, real_start=repr) -> bytes:
    """modelDescription.xml of a native FMU: the declared variables (``rows``: the same names, types and value
    references as the pythonfmu FMU's), model information, units, bounds and initial dependencies of ``decl``
    and ``descriptions`` (drivetrain.fmu_build.build's post-processing, one place for both builds), the C
    source, ``note`` after the declared description, ``real_start`` formatting the Real start values."""
    from drivetrain.fmu_build.build import edit_model_description

    model = decl.model
    de = decl.default_experiment
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": model, "guid": guid, "description": decl.description + note,
        "author": decl.author, "version": str(decl.version), "generationTool": tool,
        "variableNamingConvention": "flat", "numberOfEventIndicators": "0"})
    cs = ET.SubElement(root, "CoSimulation", {
        "modelIdentifier": model, "needsExecutionTool": "false", "canHandleVariableCommunicationStepSize": "true",
        "canInterpolateInputs": "false", "canBeInstantiatedOnlyOncePerProcess": "false",
        "canNotUseMemoryManagementFunctions": "true", "canGetAndSetFMUstate": "true",
        "canSerializeFMUstate": "true", "providesDirectionalDerivative": "false"})
    files = ET.SubElement(cs, "SourceFiles")
    ET.SubElement(files, "File", name=c_source)
    cats = ET.SubElement(root, "LogCategories")
    ET.SubElement(cats, "Category", name="logStatusError", description="errors: the cause of a refused call or step")
    ET.SubElement(cats, "Category", name="logAll", description="information (with debug logging on)")
    ET.SubElement(root, "DefaultExperiment", startTime=repr(float(de.start_time)), stopTime=repr(float(de.stop_time)),
                  stepSize=repr(float(de.step_size)))
    mv = ET.SubElement(root, "ModelVariables")
    for r in rows:
        attrs = {"name": r["name"], "valueReference": str(r["vr"]), "causality": r["causality"]}
        if r.get("role") == "fixed":
            # baked into this build (the contact map depends on it): a constant no host can set, FMI 2.0
            # section 2.2.7 (causality "local" with variability "constant", initial "exact": "the value of the
            # variable never changes"; fmi2SetXXX is not allowed on it, table of section 2.2.7 / 4.2.4)
            attrs.update(causality="local", variability="constant")
        elif r["causality"] == "parameter":
            attrs["variability"] = "fixed"
        elif r["type"] != "Real":
            attrs["variability"] = "discrete"
        if r["causality"] == "output":
            attrs["initial"] = "exact"
        sv = ET.SubElement(mv, "ScalarVariable", attrs)
        start = real_start(float(r["start"])) if r["type"] == "Real" else xml_start(r)
        bounds = {k: str(int(r[k])) for k in ("min", "max") if r["type"] == "Integer" and r.get(k) is not None}
        ET.SubElement(sv, r["type"], start=start, **bounds)
    ms = ET.SubElement(root, "ModelStructure")
    outs = ET.SubElement(ms, "Outputs")
    for i, r in enumerate(rows):
        if r["causality"] == "output":
            ET.SubElement(outs, "Unknown", index=str(i + 1))
    return edit_model_description(ET.tostring(root, encoding="UTF-8", xml_declaration=True), decl.units, {},
                                  descriptions, decl.bounds, decl.initial_dependency_map())


def model_description(decl: FmuDeclaration, rows: list[dict], guid: str) -> bytes:
    """modelDescription.xml of the native GearContact (the fixed and ignored parameters say so)."""
    notes = {"fixed": FIXED_NOTE, "ignored": IGNORED_NOTE}
    descriptions = {r["name"]: decl.variable_descriptions.get(r["name"], "") + notes.get(r["role"], "")
                    for r in rows}
    return native_model_description(decl, rows, guid, c_source=C_SOURCE,
                                    tool="bevel-drivetrain fmu_build.native_gear",
                                    note=" Native build: fidelity table, mode stage, compiled C (no Python).",
                                    descriptions=descriptions)


def compile_and_pack(tmp: Path, model: str, sources, cc: str, out: Path, log, about_html: str,
                     prebuilt: dict | None = None) -> None:
    """The last steps of every native build, in the FMU's directory tree ``tmp`` (sources/ and
    modelDescription.xml written): compile binaries/linux64/<model>.so from ``sources`` (a file name or
    several; ``prebuilt``: {source: its object file}, linked instead of compiled), write
    documentation/index.html (``about_html``, then how to compile the sources elsewhere) and zip the tree to
    ``out`` (written to a part file first, then renamed: never half an FMU). The documentation, example input
    and reference plot: drivetrain.fmu_build.fmu_docs, from the modelDescription written."""
    sources = (sources,) if isinstance(sources, str) else tuple(sources)
    prebuilt = prebuilt or {}
    src = tmp / "sources"
    inputs = [prebuilt.get(name, src / name) for name in sources]
    cmd = compile_command(src, tmp / "binaries" / "linux64" / f"{model}.so", cc, inputs=inputs)
    if log:
        log(" ".join(map(str, cmd)))
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise NativeBuildError([f"compiling the native {model} failed ({' '.join(map(str, cmd))}):\n{proc.stderr}"])
    from drivetrain.fmu_build.fmu_docs import fmu_extras

    host = (f"{about_html}</p><p>The sources (<code>sources/</code>) compile on other platforms with "
            f"<code>cc -O3 -fPIC -shared -std=c99 -ffp-contract=off -I. {' '.join(sources)} -o {model}.so -lm</code>.")
    for name, data in fmu_extras((tmp / "modelDescription.xml").read_bytes(), host).items():
        (tmp / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp / name).write_bytes(data)
    out.parent.mkdir(parents=True, exist_ok=True)
    part = out.with_name(out.name + f".{os.getpid()}.part")
    with zipfile.ZipFile(part, "w", zipfile.ZIP_DEFLATED) as z:
        for f in sorted(tmp.rglob("*")):
            if f.is_file():
                z.write(f, f.relative_to(tmp).as_posix())
    os.replace(part, out)


#: the compiler flags of every native FMU (``-shared`` added when linking)
COMPILE_FLAGS = ("-O3", "-fPIC", "-std=c99", "-ffp-contract=off", "-fvisibility=hidden")


def _code_object(src: Path, cc: str, log) -> Path:
    """gearcontact_native.c compiled once per code, kept in the cache: its source, every header it includes
    (the generated code header is the same for every build), the compiler and its flags name the object;
    each build links it with its own gearcontact_values.c (a table: milliseconds), instead of compiling the
    whole stage again (2.5 s a gear, measured; a dataset builds one gear per fault and gearbox)."""
    from gearcontact_fmu.locks import cache_dir, file_lock

    h = hashlib.sha256()
    for name in (C_SOURCE, VAR_HEADER, BUILD_HEADER, *(p.name for p in shared_sources())):
        h.update(name.encode() + b"\0" + (src / name).read_bytes())
    version = subprocess.run([cc, "--version"], capture_output=True, text=True).stdout
    h.update(f"{cc}\0{version}\0{' '.join(COMPILE_FLAGS)}".encode())
    obj = cache_dir() / "native" / f"gearcontact-{h.hexdigest()[:24]}.o"
    if obj.is_file():
        return obj
    with file_lock(obj.with_suffix(".lock")):
        if not obj.is_file():
            tmp = obj.with_name(f"{obj.stem}.{os.getpid()}.tmp.o")
            cmd = [cc, *COMPILE_FLAGS, f"-I{src}", "-c", str(src / C_SOURCE), "-o", str(tmp)]
            if log:
                log(" ".join(cmd))
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                tmp.unlink(missing_ok=True)
                raise NativeBuildError([f"compiling the native GearContact failed ({' '.join(cmd)}):\n{proc.stderr}"])
            os.replace(tmp, obj)
    return obj


def shared_sources() -> list[Path]:
    """The C headers every native FMU compiles besides its model (shipped in its sources/): the coupling
    correction (gearcontact_fmu/native), the FMI shell, the state machine's rules and the FMI 2.0 headers
    (fmu_runtime/native, drivetrain.fmu_build.fmi_headers)."""
    runtime = fmi_header_dir()
    return [*(NATIVE_DIR / name for name in SHARED_HEADERS), runtime / SHELL_HEADER,
            *(runtime / name for name in COMMON_HEADERS)]


def copy_shared_sources(src: Path) -> None:
    """Into a native FMU's sources/: :func:`shared_sources`."""
    for name in SHARED_HEADERS:
        shutil.copy2(NATIVE_DIR / name, src / name)
    shutil.copy2(fmi_header_dir() / SHELL_HEADER, src / SHELL_HEADER)
    copy_fmi_headers(src)


def compile_command(src_dir: Path, out: Path, cc: str = "gcc", source: str = C_SOURCE, inputs=None) -> list[str]:
    """The compiler call of every native FMU (the one documented for other platforms in docs/FMU.md): the
    ``source`` in ``src_dir``, or the given ``inputs`` (sources and object files)."""
    files = [str(f) for f in inputs] if inputs is not None else [str(src_dir / source)]
    return [cc, *COMPILE_FLAGS, "-shared", f"-I{src_dir}", *files, "-o", str(out), "-lm"]


def build_native_gear(parameters: dict | None = None, out: str | Path = "fmus/native/GearContact.fmu", *,
                      cc: str | None = None, log: Callable[[str], None] | None = None) -> Path:
    """Build the native GearContact FMU for these GearContact parameters; returns its path.
    Refusals (fidelity other than table, unknown parameters, a map that cannot be built, no compiler)
    raise NativeBuildError (a ConfigurationError) with every problem."""
    parameters = dict(parameters or {})
    # the only fidelity the native FMU implements (not the library default, mesh_models.DEFAULT_FIDELITY)
    parameters.setdefault("fidelity", "table")
    out = Path(out)
    if out.suffix != ".fmu":
        raise NativeBuildError([f"--out {out}: the FMU file name must end in .fmu"])
    cc = cc or os.environ.get("CC", "gcc")
    decl = fmu_variables.declaration()
    problems = _check(decl, parameters)
    if shutil.which(cc) is None:
        problems.append(f"C compiler {cc!r} not found (set CC or install gcc)")
    if platform.system() != "Linux" or platform.machine() not in ("x86_64", "AMD64"):
        problems.append(f"the builder compiles binaries/linux64 only (this is {platform.system()} "
                        f"{platform.machine()}); compile the FMU's sources/ by hand (docs/FMU.md)")
    if problems:
        raise NativeBuildError(problems)
    if log:
        log("contact map (from the cache or built) ...")
    arrays = _table_arrays(parameters)
    rows = _variables(decl, parameters)
    with tempfile.TemporaryDirectory(prefix="native_gear_") as tmp:
        tmp = Path(tmp)
        src = tmp / "sources"
        res = tmp / "resources"
        bind = tmp / "binaries" / "linux64"
        for d in (src, res, bind):
            d.mkdir(parents=True)
        write_map_resource(arrays, res / MAP_RESOURCE)
        h = hashlib.sha256((res / MAP_RESOURCE).read_bytes())
        h.update(repr([(r["name"], r["type"], r["start"], r["role"]) for r in rows]).encode())
        h.update((NATIVE_DIR / C_SOURCE).read_bytes())
        h.update((NATIVE_DIR / VAR_HEADER).read_bytes())
        for path in shared_sources():
            h.update(path.read_bytes())
        guid = "{" + str(uuid.UUID(h.hexdigest()[:32])) + "}"
        shutil.copy2(NATIVE_DIR / C_SOURCE, src / C_SOURCE)
        shutil.copy2(NATIVE_DIR / VAR_HEADER, src / VAR_HEADER)
        copy_shared_sources(src)
        write_header(rows, src / BUILD_HEADER)
        write_values(rows, guid, src / VALUES_SOURCE)
        (tmp / "modelDescription.xml").write_bytes(model_description(decl, rows, guid))
        compile_and_pack(tmp, GEAR_MODEL, (C_SOURCE, VALUES_SOURCE), cc, out, log,
                         "Lower bevel gear stage, fidelity table, mode stage, compiled C: no Python needed. The "
                         "contact map is <code>resources/contact_map.bin</code>.",
                         prebuilt={C_SOURCE: _code_object(src, cc, log)})
    if log:
        info = arrays["info"]
        # what went in; the writing of ``out`` is its caller's to say (build-native said "wrote" twice)
        log(f"{GEAR_MODEL}: contact map {arrays['values'].shape[0]} x {arrays['values'].shape[2]} nodes "
            f"({'from the cache' if info.get('from_cache') else 'built'}), "
            f"{'with' if arrays['te'] is not None else 'no'} manufacturing errors")
    return out
