"""Python-free FMUs of the three linear drivetrain models (FlexibleShaft, UpperTransmission, MotorLoad) and the
native FMUs of a whole scene (docs/FMU.md, "Python-free drivetrain FMUs").

``build_native_line(model, out)`` writes one FMU: the C port of the model (``fmu_build/native/line_native.c``
with the coupling correction and the FMI shell it shares with the native GearContact,
``gearcontact_fmu/native/coupling_correction.h`` and ``fmu_runtime/native/fmi2_shell.h``), compiled with gcc,
with ``sources/`` so that other platforms can compile it. Nothing is retyped here: the variables (names, value references, types,
causality, start values), units and descriptions are read from the pythonfmu slave of the model (the one
``drivetrain.fmu_build.build`` builds), the port names from the component, the constants from the Python modules.

Unlike the native GearContact (its contact map is computed from the scene's gear, so it is built per
contact map), these FMUs do not depend on the scene: every parameter stays settable. One build serves every
scene; :func:`native_fmus` keeps them in a cache directory (default :func:`default_native_dir`) under a name that holds
a hash of what the FMU is made of (the C sources, the generated variable table, the compiler call), so a
second run finds them and a changed source builds anew. The GearContact there is keyed by the same kind of
hash plus the parameters that shape its contact map (:func:`build_fixed`) and the contact-map code; the
others are set per run, so the operating points of one gear share one build. A process computes each
fingerprint once (``_FINGERPRINTS``: by inputs and by the size and time of every file hashed, so an edited
source is hashed anew), however many runs ask for it.

``build_native_fmus(spec, out_dir)``: the four native FMUs of a scene's system into a directory (the CLI's
``drivetrain build-native SCENE --out DIR``); the gear must be of fidelity ``table``.
"""
from __future__ import annotations

import concurrent.futures
import functools
import hashlib
import json
import os
import shutil
import tempfile
import time
import uuid
from pathlib import Path
from typing import Callable

import gearcontact_fmu
from gearcontact_fmu.mesh_models import DEFAULT_FIDELITY
from gearcontact_fmu.params import GEAR_MODEL
from drivetrain.errors import NativeBuildError
from drivetrain.fmu_build.native_gear import (c_double, c_string, compile_and_pack, copy_shared_sources,
                                              coupling_defines, start_literals, vr_enum)
from drivetrain.fmu_build.native_gear import compile_command as native_compile_command
from drivetrain.fmu_build.native_gear import native_model_description

MODELS = ("FlexibleShaft", "UpperTransmission", "MotorLoad")
#: the model selector of line_native.c (LN_MODEL)
MODEL_CODES = {"FlexibleShaft": 1, "UpperTransmission": 2, "MotorLoad": 3}
NATIVE_DIR = Path(__file__).resolve().parent / "native"
C_SOURCE = "line_native.c"
BUILD_HEADER = "line_build.h"


def default_native_dir() -> Path:
    """The default cache of native FMUs (drivetrain run --native): ``native/`` in the default FMU
    directory (:func:`drivetrain.fmu_build.fmus.default_fmu_dir`), never the current folder."""
    from drivetrain.fmu_build.fmus import default_fmu_dir

    return default_fmu_dir() / "native"


def _probe_slave(model: str):
    """An instance of the pythonfmu slave of ``model`` (rendered from fmu_runtime.slave_template as
    drivetrain.fmu_build.build does): its variables, start values, units and descriptions."""
    from drivetrain.fmu_build.build import slave_class
    from fmu_runtime.slave_template import render

    if model not in MODEL_CODES:
        raise NativeBuildError([f"model {model!r}: no native line FMU (one of {', '.join(MODELS)})"])
    with tempfile.TemporaryDirectory(prefix="native_line_") as tmp:
        script = Path(tmp) / f"{model}.py"
        script.write_text(render(model))
        cls = slave_class(script)
    return cls(instance_name="native-build", resources=tempfile.gettempdir())


def variables(slave) -> list[dict]:
    """Every variable of the slave: value reference, name, type, causality, variability, start."""
    rows = []
    for vr, v in sorted(slave.vars.items()):
        rows.append({"vr": vr, "name": v.name, "type": type(v).__name__, "causality": v.causality.name,
                     "variability": getattr(v.variability, "name", None) if v.variability is not None else None,
                     "start": getattr(slave, v.name), "min": getattr(v, "min", None), "max": getattr(v, "max", None)})
    assert [r["vr"] for r in rows] == list(range(len(rows))), "value references must be 0..n-1"
    return rows


def _port_names(model: str) -> list[str]:
    """The line model's ports in the kernel's order (the component builds them)."""
    from drivetrain.models.components import make_component

    return [p.name for p in make_component(model).line.ports]


def write_header(model: str, rows: list[dict], guid: str, path: Path) -> None:
    """line_build.h: the model selector, the LN_VARS table (by value reference), the VR_* names, the constants."""
    from drivetrain.models.motors import RPM
    from gearcontact_fmu.params import CODE_NONFINITE_INPUT, CODE_NONFINITE_STATE, MAX_SUBSTEPS_PER_STEP

    ports = _port_names(model)
    lines = [f"/* generated by drivetrain.fmu_build.native_line: do not edit (the native {model}) */",
             "#ifndef LINE_BUILD_H", "#define LINE_BUILD_H", "",
             f"#define LN_MODEL {MODEL_CODES[model]}",
             f"#define LN_MODEL_NAME {c_string(model)}",
             f"#define LN_GUID {c_string(guid)}",
             f"#define LN_N_VARS {len(rows)}",
             f"#define LN_MAX_SUBSTEPS_PER_STEP {int(MAX_SUBSTEPS_PER_STEP)}",
             f"#define LN_CODE_NONFINITE_INPUT {int(CODE_NONFINITE_INPUT)}",
             f"#define LN_CODE_NONFINITE_STATE {int(CODE_NONFINITE_STATE)}",
             *coupling_defines(),
             f"#define LN_RPM {c_double(RPM)}",
             f"#define LN_PORT_NAMES {{{', '.join(c_string(p) for p in ports)}}}", "", *vr_enum(rows)]
    lines += ["", "static const LnVar LN_VARS[LN_N_VARS] = {",
              "    /* name, type, is_input, is_parameter, is_output, real, int, string start, int min, int max */"]
    for r in rows:
        real, integer, string = start_literals(r)
        lo = "INT_MIN" if r.get("min") is None else str(int(r["min"]))
        hi = "INT_MAX" if r.get("max") is None else str(int(r["max"]))
        lines.append(f"    {{{c_string(r['name'])}, \"{r['type']}\", {int(r['causality'] == 'input')}, "
                     f"{int(r['causality'] == 'parameter')}, {int(r['causality'] == 'output')}, "
                     f"{real}, {integer}, {string}, {lo}, {hi}}},")
    lines += ["};", "", "#endif", ""]
    path.write_text("\n".join(lines))


def model_description(model: str, slave, rows: list[dict], guid: str) -> bytes:
    """modelDescription.xml: the slave's variables (names, value references, types, causality, variability,
    initial, start), units and descriptions. Real starts as pythonfmu writes them (f"{x:.16g}"), so the two
    FMUs declare the same; the value the instance starts from is the exact default in both (the C table
    holds it to the bit)."""
    return native_model_description(model, slave, rows, guid, c_source=C_SOURCE, note=" Native build: compiled C "
                                    "(no Python).", tool="bevel-drivetrain fmu_build.native_line",
                                    descriptions=dict(type(slave).variable_descriptions),
                                    real_start=lambda x: format(x, ".16g"))


def compile_command(src_dir: Path, out: Path, cc: str = "gcc") -> list[str]:
    """The compiler call of every native FMU (native_gear.compile_command) for line_native.c."""
    return native_compile_command(src_dir, out, cc, C_SOURCE)


def toolchain_problems(cc: str | None = None) -> list[str]:
    """Why native FMUs cannot be compiled here (no C compiler, another platform); empty when they can."""
    return _check_toolchain(cc or os.environ.get("CC", "gcc"))


def _check_toolchain(cc: str) -> list[str]:
    import platform

    problems = []
    if shutil.which(cc) is None:
        problems.append(f"C compiler {cc!r} not found (set CC or install gcc)")
    if platform.system() != "Linux" or platform.machine() not in ("x86_64", "AMD64"):
        problems.append(f"the builder compiles binaries/linux64 only (this is {platform.system()} "
                        f"{platform.machine()}); compile the FMU's sources/ by hand (docs/FMU.md)")
    return problems


def _doc_sources() -> list[Path]:
    """What every native FMU ships beside its model (drivetrain.fmu_build.fmu_docs: documentation, example input,
    the committed reference plots): part of every fingerprint."""
    from drivetrain.fmu_build.fmu_docs import PLOT_DIR

    return [Path(__file__).with_name("fmu_docs.py"), *sorted(PLOT_DIR.glob("*.png"))]


def _line_sources() -> list[Path]:
    """The files a line FMU's fingerprint hashes: its C source, the shared and FMI headers, this module, the
    modelDescription writers (native_gear.native_model_description, build.edit_model_description) and the docs."""
    from drivetrain.fmu_build.native_gear import shared_sources

    return [NATIVE_DIR / C_SOURCE, *shared_sources(), Path(__file__),
            Path(__file__).with_name("native_gear.py"), Path(__file__).with_name("build.py"), *_doc_sources()]


def _fingerprint(model: str, rows: list[dict], cc: str) -> str:
    """The hash of what the FMU is made of: the C sources, the variable table, the ports, the compiler call."""
    h = hashlib.sha256()
    h.update(model.encode())
    h.update(repr([(r["vr"], r["name"], r["type"], r["causality"], r["start"]) for r in rows]).encode())
    h.update(repr(_port_names(model)).encode())
    for f in _line_sources():
        h.update(f.read_bytes())
    h.update(" ".join(compile_command(Path("src"), Path("out"), cc)).encode())
    return h.hexdigest()


#: The fingerprints computed in this process (native_fmus asks for all four on every run: a sweep or a test
#: session asks for the same ones many times). Keyed by everything a fingerprint is computed from that can
#: change while the process runs: the model or the gear's fixed parameters, the compiler, and the path, size
#: and modification time of every file it hashes (an edited source is another key, so it is hashed anew).
#: The variable table and the ports come from the modules loaded in the process, fixed for its life.
_FINGERPRINTS: dict[tuple, str] = {}


def _file_stamps(files) -> tuple:
    """(path, size, modification time in ns) of each file, in order."""
    stamps = []
    for f in files:
        st = os.stat(f)
        stamps.append((str(f), st.st_size, st.st_mtime_ns))
    return tuple(stamps)


def _memo(key: tuple, compute: Callable[[], str]) -> str:
    fp = _FINGERPRINTS.get(key)
    if fp is None:
        fp = _FINGERPRINTS[key] = compute()
    return fp


def _line_fingerprint_now(model: str, cc: str) -> str:
    """The fingerprint of the native ``model``, computed (probes the pythonfmu slave)."""
    return _fingerprint(model, variables(_probe_slave(model)), cc)


def line_fingerprint(model: str, cc: str | None = None) -> str:
    """The cache key of the native ``model`` (see the module docstring); computed once per process for the
    same model, compiler and source files (:data:`_FINGERPRINTS`)."""
    cc = cc or os.environ.get("CC", "gcc")
    return _memo(("line", model, cc, _file_stamps(_line_sources())), lambda: _line_fingerprint_now(model, cc))


def build_native_line(model: str, out: str | Path | None = None, *, cc: str | None = None,
                      log: Callable[[str], None] | None = None) -> Path:
    """Build the native FMU of ``model`` (FlexibleShaft | UpperTransmission | MotorLoad); returns its path.
    Refusals (another model, no compiler, a failed compile) raise NativeBuildError with every problem."""
    out = Path(out) if out is not None else default_native_dir() / f"{model}.fmu"
    if out.suffix != ".fmu":
        raise NativeBuildError([f"--out {out}: the FMU file name must end in .fmu"])
    cc = cc or os.environ.get("CC", "gcc")
    slave = _probe_slave(model)
    problems = _check_toolchain(cc)
    if problems:
        raise NativeBuildError(problems)
    rows = variables(slave)
    guid = "{" + str(uuid.UUID(_fingerprint(model, rows, cc)[:32])) + "}"
    with tempfile.TemporaryDirectory(prefix="native_line_") as tmp:
        tmp = Path(tmp)
        src = tmp / "sources"
        bind = tmp / "binaries" / "linux64"
        for d in (src, bind):
            d.mkdir(parents=True)
        shutil.copy2(NATIVE_DIR / C_SOURCE, src / C_SOURCE)
        copy_shared_sources(src)
        write_header(model, rows, guid, src / BUILD_HEADER)
        (tmp / "modelDescription.xml").write_bytes(model_description(model, slave, rows, guid))
        compile_and_pack(tmp, model, C_SOURCE, cc, out, log,
                         "Compiled C: no Python needed; every parameter settable before and in initialization mode.")
    return out          # the caller says what it wrote (build-native said "wrote" twice)


# ------------------------------------------------------------------------------------------------
# The native FMUs of a scene
# ------------------------------------------------------------------------------------------------

def _gear_sources() -> tuple[Path, list[Path], Path]:
    """The files a native GearContact's fingerprint hashes: (the gearcontact_fmu package directory, its
    Python and C sources in order, drivetrain/fmu_build/native_gear.py)."""
    pkg = Path(gearcontact_fmu.__file__).resolve().parent
    files = [f for f in sorted(pkg.rglob("*")) if f.suffix in (".py", ".c", ".h") and "__pycache__" not in f.parts]
    return pkg, files, Path(__file__).with_name("native_gear.py")


def _gear_fingerprint_now(text: str, pkg: Path, files: list[Path], builder: Path) -> str:
    """The fingerprint of a native GearContact, computed: ``text`` its parameters as JSON, then every source."""
    h = hashlib.sha256(text.encode())
    for f in files:
        h.update(f.relative_to(pkg).as_posix().encode())
        h.update(f.read_bytes())
    h.update(builder.read_bytes())
    h.update(builder.with_name("build.py").read_bytes())      # the modelDescription writer
    for f in _doc_sources():
        h.update(f.read_bytes())
    return h.hexdigest()


def _gear_fingerprint(parameters: dict) -> str:
    """The cache key of a native GearContact: its parameters, the C sources, the builder and the contact-map
    code (the map is computed at the build); computed once per process for the same parameters and source
    files (:data:`_FINGERPRINTS`)."""
    text = json.dumps(parameters, sort_keys=True, default=str)
    pkg, files, builder = _gear_sources()
    return _memo(("gear", text, _file_stamps([*files, builder, builder.with_name("build.py"), *_doc_sources()])),
                 lambda: _gear_fingerprint_now(text, pkg, files, builder))


def system_gear(spec) -> tuple[dict | None, str | None]:
    """(the GearContact parameters of the system ``spec``, None) if it has a gear of fidelity table;
    (None, why not) else."""
    gears = spec.components_of(GEAR_MODEL)
    if not gears:
        return None, "the system has no GearContact component"
    params = dict(gears[0].parameters)
    # a gear without a fidelity runs the FMU's default, mesh_models.DEFAULT_FIDELITY (not table: then its
    # pythonfmu FMU and a native build would run two models)
    fid = str(params.get("fidelity", DEFAULT_FIDELITY)).strip().lower()
    mode = str(params.get("mode", "stage")).strip().lower()
    if fid != "table" or mode != "stage":
        return None, (f"the scene's GearContact has fidelity {fid!r}, mode {mode!r}: the native GearContact "
                      f"implements fidelity 'table', mode 'stage' only")
    return params, None


def build_fixed(parameters: dict) -> dict:
    """The GearContact parameters a native build fixes (what shapes the contact map): the cache key. The
    others stay settable in the FMU (a host, our master included, sets them per run), so one build serves
    every operating point of a gear."""
    from drivetrain.fmu_build.native_gear import IGNORED_PARAMETERS, RUNTIME_PARAMETERS

    return {k: v for k, v in parameters.items() if k not in RUNTIME_PARAMETERS and k not in IGNORED_PARAMETERS}


def build_native_fmus(spec, out_dir: str | Path, *, log: Callable[[str], None] | None = None) -> dict[str, Path]:
    """The four native FMUs of a system (a scene's SystemSpec) into ``out_dir`` (``<Model>.fmu``); the gear
    must be fidelity table (else NativeBuildError naming the problem)."""
    from drivetrain.fmu_build.native_gear import build_native_gear

    gear, why = system_gear(spec)
    if gear is None:
        raise NativeBuildError([why])
    out_dir = Path(out_dir)
    paths = {m: build_native_line(m, out_dir / f"{m}.fmu", log=log) for m in MODELS}
    paths[GEAR_MODEL] = build_native_gear(gear, out_dir / f"{GEAR_MODEL}.fmu", log=log)
    return paths


def native_fmus(spec, cache_dir: str | Path | None = None, *,
                log: Callable[[str], None] | None = None) -> tuple[dict[str, Path], str | None]:
    """The native FMUs for a run of the system ``spec`` (a scene's SystemSpec), built once and kept in
    ``cache_dir`` under names holding their fingerprints (``<Model>-<hash>.fmu``; the gear's includes the
    parameters that shape its contact map, :func:`build_fixed`). Returns ({model: path}, note): the note
    (None if all four are native) says why the gear is not (it is not fidelity table: the run keeps the
    pythonfmu GearContact). ``log``: one line when something was built."""
    from drivetrain.fmu_build.native_gear import build_native_gear

    cache_dir = Path(cache_dir) if cache_dir is not None else default_native_dir()
    cc = os.environ.get("CC", "gcc")
    builds = {}                    # model -> (path, build function or None when cached)
    for model in MODELS:
        path = cache_dir / f"{model}-{line_fingerprint(model, cc)[:16]}.fmu"
        builds[model] = (path, None if path.is_file() else functools.partial(build_native_line, model, path, cc=cc))
    gear, why = system_gear(spec)
    if gear is not None:
        fixed = build_fixed(gear)
        path = cache_dir / f"{GEAR_MODEL}-{_gear_fingerprint(fixed)[:16]}.fmu"
        builds[GEAR_MODEL] = (path, None if path.is_file() else
                                 functools.partial(build_native_gear, fixed, path))
    todo = {m: b for m, (_, b) in builds.items() if b is not None}
    if todo:
        from gearcontact_fmu.progress import reporter

        t0 = time.perf_counter()
        bar = reporter(f"native FMUs: building {', '.join(todo)}", len(todo), unit=" FMUs")   # after 2 s (CLI)
        # the compilers run side by side (each build writes its own file, atomically)
        with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, min(len(todo), os.cpu_count() or 1))) as ex:
            for future in concurrent.futures.as_completed([ex.submit(b) for b in todo.values()]):
                future.result()
                bar.update(1)
        bar.close()
        if log:
            log(f"native FMUs: built {', '.join(todo)} into {cache_dir} in {time.perf_counter() - t0:.1f} s "
                "(kept for later runs)")
    paths = {model: path for model, (path, _) in builds.items()}
    if gear is None:
        return paths, why + "; the run uses the pythonfmu GearContact"
    return paths, None
