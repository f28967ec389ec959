"""A scene's system as an SSP 1.0 archive, so that another FMI tool rebuilds the system our master runs.

What: ``export_ssp(scene, path)`` writes one ``.ssp`` (a zip) holding

* ``SystemStructure.ssd``: one component per FMU of the assembled system (instance names as in our
  master: motors, drive_shaft, upper, gear), a connector for every connected variable with the type and
  unit its FMU declares, the connections of each flange (inertia side phi, w -> spring side; spring side
  tau -> inertia side), the unit definitions (``ssd:Units``: SI base-unit exponents and factor, as the FMUs
  define them), the default experiment (0 .. the scene's duration) and the communication step
  (OpenModelica's FixedStepMaster annotation: SSP 1.0 has no standard element for a step size, its
  DefaultExperiment takes startTime and stopTime only; libcosim and Ecos take the step from the caller:
  pass the same one);
* ``resources/<Model>.fmu``: the FMUs, as built from this checkout;
* ``resources/<instance>.ssv``: the assembled, calibrated parameter values of each instance and its
  constant inputs (speed reference, load torque), each Real with the unit its FMU declares and the
  file's own ``ssv:Units``, one parameter set per component, all with the same set name.

Why this shape: it is the subset of SSP 1.0 that OMSimulator, libcosim and Ecos read (docs/FMU.md):
version 1.0, component-to-component connections only, connectors only for connected or bound
variables, parameters in per-component .ssv files. Variable types and units come from each FMU's own
model description, so a parameter is written as the type the FMU declares. fmpy's own SSP runner
(``fmpy.ssp.simulation.simulate_ssp``) reads the structure only: :data:`FMPY_RUNNER_IGNORES`.

Time profiles (a speed ramp, a load step): our master feeds them as inputs, SSP 1.0 has no signal
table every host reads. MotorLoad carries them itself (``speed_profile``, ``load_profile``:
fmu_variables.INPUT_PROFILES), so they are written as those parameters; a profile on an input without such a
parameter is refused. The drive speed reference then moves linearly inside a step instead of being held
from the step start (the load setting is read at the step start either way): a lag of half a step
on a ramp. The master's own bookkeeping (energy audit, output sampling, rig instruments) is not part of
the system: another host gives the FMUs' outputs as they are.
"""
from __future__ import annotations

import math
import zipfile
from pathlib import Path
from xml.sax.saxutils import quoteattr

from drivetrain.fmu_build.fmus import ensure_fmus, fmu_dir_or_default, load_fmu_info
from drivetrain.cosim.plan import is_profile, settable
from drivetrain.errors import ConfigurationError
from drivetrain.models.fmu_variables import INPUT_PROFILES
from drivetrain.run.runner import assemble_scene
from drivetrain.system import INERTIA, SPRING, SystemSpec
from gearcontact_fmu.params import flange_variables

SSD_NAME = "SystemStructure.ssd"
PARAMETER_SET = "parameters"
_NS = ('xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription" '
       'xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" '
       'xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" '
       'xmlns:oms="https://raw.githubusercontent.com/OpenModelica/OMSimulator/master/schema/oms.xsd"')
_SSV_TYPE = {"Real": "Real", "Integer": "Integer", "Enumeration": "Integer", "Boolean": "Boolean",
             "String": "String"}
_BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
#: what fmpy's SSP runner (fmpy.ssp.simulation.simulate_ssp, read in fmpy 0.3.32) does not read of the archive;
#: docs/FMU.md says the same and tests/interop/test_ssp_export.py checks both against fmpy's behaviour
FMPY_RUNNER_IGNORES = (
    "the parameter bindings (the .ssv files): it parses them, but applies only the parameter_set "
    "argument of simulate_ssp (names 'instance.variable'), and sets no String there (it raises "
    "'Unsupported type: String')",
    "the DefaultExperiment: without stop_time it runs 1 s, without step_size at stop_time / 100",
    "the communication step (the FixedStepMaster annotation)",
    "the units (connectors and parameter values are taken as they are)",
    "a Boolean value's text: it sets a Boolean to value != 0.0, so 'false' becomes true",
    "the values of connected variables during initialization: every connector starts at 0",
)


def value_text(vtype: str, value) -> str:
    if vtype == "Real":
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"not a finite number: {value!r}")
        return repr(v)
    if vtype in ("Integer", "Enumeration"):
        return str(int(value))
    if vtype == "Boolean":
        return "true" if bool(value) else "false"
    return str(value)


def system_connections(spec: SystemSpec) -> list[tuple[str, str, str, str]]:
    """Every variable connection (from instance, from variable, to instance, to variable) of the flanges."""
    out = []
    for c in spec.connections:
        s_comp, s_port = c.spring.split(".", 1)
        i_comp, i_port = c.inertia.split(".", 1)
        for (s_var, _, s_causality), (i_var, _, _) in zip(flange_variables(s_port, SPRING),
                                                           flange_variables(i_port, INERTIA)):
            out.append((i_comp, i_var, s_comp, s_var) if s_causality == "input" else (s_comp, s_var, i_comp, i_var))
    return out


def profile_text(points) -> str:
    """A time profile [[t, v], ...] as the FMU's profile parameter text 't0:v0; t1:v1; ...'."""
    return "; ".join(f"{float(t)!r}:{float(v)!r}" for t, v in points)


def bound_values(component) -> dict:
    """The values an instance's parameter set binds: its parameters and constant inputs, and each time
    profile on an input as the parameter that carries it (fmu_variables.INPUT_PROFILES)."""
    out = dict(component.parameters)
    carriers = INPUT_PROFILES.get(component.model, {})
    for name, value in component.inputs.items():
        if is_profile(value) and name in carriers:
            out[carriers[name]] = profile_text(value)
        else:
            out[name] = value
    return out


def system_problems(spec: SystemSpec, descriptions: dict) -> list[str]:
    problems = []
    for c in spec.components:
        md = descriptions[c.model]
        for name, value in bound_values(c).items():
            if is_profile(value):
                problems.append(f"{c.name}.{name} is a time profile and {c.model} has no parameter that carries "
                                "it: SSP 1.0 has no input signal every host reads")
            elif name not in md:
                problems.append(f"{c.name}.{name}: not a variable of {c.model}.fmu")
    for a, va, b, vb in system_connections(spec):
        for inst, var in ((a, va), (b, vb)):
            model = next((c.model for c in spec.components if c.name == inst), None)
            if model is None or var not in descriptions[model]:
                problems.append(f"connection {a}.{va} -> {b}.{vb}: {inst}.{var} does not exist")
    return problems


def fmu_unit_definitions(fmu_path: Path) -> dict:
    """unit name -> {base unit: exponent, "factor": f, "offset": o} from an FMU's UnitDefinitions."""
    out = {}
    for u in load_fmu_info(fmu_path).description.unitDefinitions:
        b = u.baseUnit
        out[u.name] = ({k: int(getattr(b, k)) for k in _BASE_UNITS} | {"factor": float(b.factor), "offset": float(b.offset)}
                       if b is not None else {"factor": 1.0, "offset": 0.0})
    return out


def units_xml(prefix: str, names, definitions: dict, indent: str) -> str:
    """``<{prefix}:Units>`` with the ssc:Unit of every unit in ``names`` (SI base-unit exponents, factor, offset:
    only those that differ from the defaults). Empty when ``names`` is."""
    rows = []
    for name in sorted(set(names)):
        d = definitions.get(name)
        if d is None:
            raise ConfigurationError([f"unit {name!r}: no FMU of the system defines it"])
        attrs = " ".join(f'{k}="{v}"' for k, v in d.items() if k in _BASE_UNITS and v)
        attrs += "".join(f' {k}="{d[k]!r}"' for k, default in (("factor", 1.0), ("offset", 0.0)) if d[k] != default)
        rows.append(f'{indent}  <ssc:Unit name={quoteattr(name)}><ssc:BaseUnit {attrs.strip()}/></ssc:Unit>'
                    .replace("<ssc:BaseUnit />", "<ssc:BaseUnit/>"))
    if not rows:
        return ""
    return f"{indent}<{prefix}:Units>\n" + "\n".join(rows) + f"\n{indent}</{prefix}:Units>\n"


def ssv_text(component, variables: dict, definitions: dict) -> str:
    """The parameter set of one instance: its parameters and constant inputs but the FMU's constants
    (plan.settable), typed as its FMU declares (``variables``: name -> fmus.VarInfo), each Real with its FMU's
    unit (defined in the file's own ssv:Units, from ``definitions``)."""
    rows = []
    used = []
    for name, value in settable(bound_values(component), variables).items():
        vtype, unit = variables[name].type, variables[name].unit
        try:
            text = value_text(vtype, value)
        except (TypeError, ValueError) as exc:
            raise ConfigurationError([f"{component.name}.{name} = {value!r}: {exc}"]) from None
        unit_attr = ""
        if vtype == "Real" and unit:
            unit_attr = f" unit={quoteattr(unit)}"
            used.append(unit)
        rows.append(f'    <ssv:Parameter name={quoteattr(name)}>\n'
                    f'      <ssv:{_SSV_TYPE[vtype]} value={quoteattr(text)}{unit_attr}/>\n'
                    f'    </ssv:Parameter>')
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            '<ssv:ParameterSet xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" '
            'xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" '
            f'version="1.0" name="{PARAMETER_SET}">\n  <ssv:Parameters>\n' + "\n".join(rows)
            + "\n  </ssv:Parameters>\n" + units_xml("ssv", used, definitions, "  ") + "</ssv:ParameterSet>\n")


def ssd_text(spec: SystemSpec, name: str, stop_time_s: float, descriptions: dict, definitions: dict) -> str:
    """The system structure: components with their connectors (type and unit as the FMU declares them) and
    parameter bindings, connections, the fixed communication step, the unit definitions (from
    ``definitions``: unit -> base units, :func:`fmu_unit_definitions`) and the default experiment."""
    links = system_connections(spec)
    connected: dict[str, list[str]] = {c.name: [] for c in spec.components}
    for a, va, b, vb in links:
        connected[a].append(va)
        connected[b].append(vb)
    elements = []
    used = []
    for c in spec.components:
        md = descriptions[c.model]
        conns = []
        for var in sorted(connected[c.name]):
            vtype, causality = md[var].type, md[var].causality       # the kind the FMU itself declares
            unit = md[var].unit if vtype == "Real" else None
            if unit:
                used.append(unit)
            conns.append(f'          <ssd:Connector name={quoteattr(var)} kind="{causality}">'
                         f'<ssc:{_SSV_TYPE[vtype]}{f" unit={quoteattr(unit)}" if unit else ""}/></ssd:Connector>')
        elements.append(
            f'      <ssd:Component name={quoteattr(c.name)} type="application/x-fmu-sharedlibrary" '
            f'source="resources/{c.model}.fmu">\n        <ssd:Connectors>\n' + "\n".join(conns)
            + '\n        </ssd:Connectors>\n        <ssd:ParameterBindings>\n'
            f'          <ssd:ParameterBinding source="resources/{c.name}.ssv"/>\n'
            '        </ssd:ParameterBindings>\n      </ssd:Component>')
    links = [f'      <ssd:Connection startElement={quoteattr(a)} startConnector={quoteattr(va)} '
             f'endElement={quoteattr(b)} endConnector={quoteattr(vb)}/>' for a, va, b, vb in links]
    H = repr(float(spec.comm_step))
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            f'<ssd:SystemStructureDescription {_NS} version="1.0" name={quoteattr(name)}>\n'
            f'  <ssd:System name={quoteattr(name)}>\n    <ssd:Elements>\n' + "\n".join(elements)
            + '\n    </ssd:Elements>\n    <ssd:Connections>\n' + "\n".join(links)
            + '\n    </ssd:Connections>\n    <ssd:Annotations>\n'
            '      <ssc:Annotation type="org.openmodelica">\n        <oms:Annotations>\n'
            '          <oms:SimulationInformation>\n'
            f'            <oms:FixedStepMaster description="oms-ma" stepSize="{H}"/>\n'
            '          </oms:SimulationInformation>\n        </oms:Annotations>\n'
            '      </ssc:Annotation>\n    </ssd:Annotations>\n  </ssd:System>\n'
            + units_xml("ssd", used, definitions, "  ") +
            f'  <ssd:DefaultExperiment startTime="0.0" stopTime="{float(stop_time_s)!r}"/>\n'
            '</ssd:SystemStructureDescription>\n')


def system_fmus(scene, fmu_dir, spec: SystemSpec | None = None, build: bool = True, log=None,
                native: bool = False):
    """What an export of the scene's system starts from: the assembled spec (given or assembled here),
    its FMUs (built when missing or stale), each model's variables (name -> fmus.VarInfo) and
    every problem of binding the spec to them (:func:`system_problems`). ``native``: the compiled FMUs
    (drivetrain.fmu_build.native_line, kept in ``<fmu_dir>/native``) wherever there is one; a gear that is not
    fidelity table keeps its pythonfmu FMU (``log`` says so); no C compiler is a ConfigurationError."""
    if spec is None:
        spec = assemble_scene(scene)
    models = list(dict.fromkeys(c.model for c in spec.components))
    fmus = {}
    if native:
        from drivetrain.fmu_build.native_line import native_fmus, toolchain_problems

        missing = toolchain_problems()
        if missing:
            raise ConfigurationError([f"native FMUs: {m}" for m in missing])
        built, note = native_fmus(spec, fmu_dir_or_default(fmu_dir) / "native", log=log)
        if note and log:
            log(f"native FMUs: {note}")
        fmus = {m: p for m, p in built.items() if m in models}
    rest = [m for m in models if m not in fmus]
    if rest:
        fmus.update(ensure_fmus(rest, fmu_dir, build=build, log=log))
    descriptions = {m: load_fmu_info(fmus[m]).variables for m in dict.fromkeys(models)}
    return spec, fmus, descriptions, system_problems(spec, descriptions)


def export_ssp(scene, path: str | Path, fmu_dir: str | Path | None = None, spec: SystemSpec | None = None,
               build: bool = True, log=None, native: bool = False) -> Path:
    """Write the scene's assembled system as an SSP 1.0 archive at ``path`` (module docstring). The
    FMUs come from ``fmu_dir`` (built when missing or stale); ``native``: the compiled FMUs (a host then
    needs no Python, :func:`system_fmus`). Raises ConfigurationError naming every
    problem (a time profile, a parameter the FMU does not have); nothing is written then. The archive
    is written to a temporary name and renamed, so a failed export leaves no partial file."""
    path = Path(path)
    if path.suffix != ".ssp":
        raise ConfigurationError([f"{path}: an SSP archive's name ends in .ssp"])
    spec, fmus, descriptions, problems = system_fmus(scene, fmu_dir, spec, build, log, native)
    if problems:
        raise ConfigurationError(problems)
    definitions = {}
    for m, p in fmus.items():
        for unit, d in fmu_unit_definitions(p).items():
            if definitions.setdefault(unit, d) != d:
                raise ConfigurationError([f"unit {unit!r}: {m}.fmu defines it otherwise than another FMU of the system"])
    ssd = ssd_text(spec, scene.name, scene.time.duration_s, descriptions, definitions)
    ssvs = {c.name: ssv_text(c, descriptions[c.model], definitions) for c in spec.components}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    try:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as z:
            z.writestr(SSD_NAME, ssd)
            for name, text in ssvs.items():
                z.writestr(f"resources/{name}.ssv", text)
            for m, p in fmus.items():
                z.write(p, f"resources/{m}.fmu")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
