"""What every FMU carries for a user who meets it alone (issue 30): an example input at the example
operating point, ``documentation/index.html`` generated from the final modelDescription, a reference plot and
the runtime requirements as ranges. Used by both builders (``drivetrain.fmu_build.build`` for the pythonfmu FMUs,
``drivetrain.fmu_build.native_gear.compile_and_pack`` for the native ones), so the two builds ship the same.

- :func:`example_input`: the inputs of the FMU's DefaultExperiment at the example operating point (drive motor
  :data:`EXAMPLE_SPEED_RPM`, load motor :data:`EXAMPLE_LOAD_NM`, RIG.md's grid), from rest: speeds and torques
  ramp in over :data:`RAMP_S` and are held; each angle is its speed's integral. The torques and speeds are the
  rig's steady state (``drivetrain.rig.steady_state`` with the line models' default parameters); the gear's
  flange angles lead/lag by its port-spring twists at its own declared ``k_a``/``k_b`` and the mesh's static
  deflection, so the gear carries the load torque. Written as ``documentation/example_input.csv`` (the columns
  ``fmpy simulate --input-file`` reads: ``time`` then the inputs).
- :func:`documentation_html`: the variable table (name, causality, type, unit, description, start) read from
  the modelDescription the FMU ships (so it follows every declaration), the ports and their sign conventions
  (docs/ARCHITECTURE.md), the fmpy example and the reference plot.
- :func:`requirements_text`: ``resources/requirements.txt``: the runtime packages with the ranges the project
  declares (pyproject.toml), not this machine's versions.
- Reference plots: ``reference_plots/<Model>.png`` (pythonfmu) and ``<Model>-native.png``, committed, made by
  ``examples/fmu_reference_plots.py`` from a run of each FMU's DefaultExperiment with its example input.
"""
from __future__ import annotations

import dataclasses
import html
import io
import re
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np

from drivetrain.rig.data import PAPER_MAX_LOAD_NM

#: the example operating point of the FMUs' standalone experiments (RIG.md grid: 500 rpm, 11 % load)
EXAMPLE_SPEED_RPM = 500.0
EXAMPLE_LOAD_NM = PAPER_MAX_LOAD_NM
#: the speeds and torques of the example input ramp in from rest over this time, then stay
RAMP_S = 0.25
#: rows of the example input during the ramp (the angles are quadratic there; fmpy interpolates linearly)
RAMP_ROWS = 251
EXAMPLE_CSV = "documentation/example_input.csv"
REFERENCE_PNG = "documentation/reference.png"
PLOT_DIR = Path(__file__).resolve().parent / "reference_plots"
#: what each reference plot shows (the example's main outputs)
PLOT_VARIABLES = {
    "GearContact": ("flange_a_tau", "flange_b_tau", "pinion_w", "wheel_w"),
    "FlexibleShaft": ("flange_b_tau", "torque_sensor", "flange_a_w", "hub_b_w"),
    "UpperTransmission": ("flange_a_w", "flange_b_w", "loss_torque", "torque_sensor"),
    "MotorLoad": ("motor_w", "load_w", "drive_tau", "motor_torque"),
}


# ------------------------------------------------------------------------------------------------
# the modelDescription as plain data
# ------------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class Variable:
    name: str
    causality: str
    variability: str
    type: str
    unit: str
    start: str
    description: str


@dataclasses.dataclass(frozen=True)
class Description:
    model: str
    text: str
    native: bool
    start_time: float
    stop_time: float
    step_size: float
    variables: tuple

    def starts(self) -> dict:
        """name -> start value (Real as float, Integer as int) of every variable that declares one."""
        out = {}
        for v in self.variables:
            if v.start == "":
                continue
            out[v.name] = (float(v.start) if v.type == "Real" else int(v.start) if v.type == "Integer"
                           else v.start == "true" if v.type == "Boolean" else v.start)
        return out

    def names(self, causality: str) -> list[str]:
        return [v.name for v in self.variables if v.causality == causality]


def read_description(xml: bytes) -> Description:
    """The model description's name, text, DefaultExperiment and variables (declared types resolved for the unit)."""
    root = ET.fromstring(xml)
    types = {}
    for t in root.findall("TypeDefinitions/SimpleType"):
        child = next(iter(t), None)
        types[t.get("name")] = child.get("unit", "") if child is not None else ""
    variables = []
    for sv in root.findall("ModelVariables/ScalarVariable"):
        child = next(iter(sv))
        unit = child.get("unit") or types.get(child.get("declaredType") or "", "")
        variables.append(Variable(sv.get("name"), sv.get("causality", "local"), sv.get("variability", "continuous"),
                                  child.tag, unit, child.get("start", ""), sv.get("description", "")))
    de = root.find("DefaultExperiment")
    get = (lambda k, d: float(de.get(k, d))) if de is not None else (lambda k, d: float(d))
    return Description(root.get("modelName"), root.get("description", ""),
                       root.get("generationTool", "").startswith("bevel-drivetrain"),
                       get("startTime", 0.0), get("stopTime", 1.0), get("stepSize", 0.0), tuple(variables))


# ------------------------------------------------------------------------------------------------
# the example input
# ------------------------------------------------------------------------------------------------

def operating_point():
    """The rig's steady state at the example point (``rig.steady_state``) with the line models' defaults."""
    from drivetrain.rig import data as rig

    return rig.steady_state(EXAMPLE_SPEED_RPM, EXAMPLE_LOAD_NM, rig.default_parameters("UpperTransmission"),
                            rig.default_parameters("MotorLoad"))


def mesh_offset(starts: dict, T_msh: float) -> float:
    """Pinion-referred mesh coordinate of the loaded drive flank at the middle-shaft torque ``T_msh``
    (half the backlash plus T / K_mean of the gear the FMU declares: the analytic mesh's stiffness)."""
    from gearcontact_fmu.mesh_models.analytic import mesh_stiffness
    from gearcontact_fmu.params import BevelGearParams, backlash_angle

    fields = {f.name for f in dataclasses.fields(BevelGearParams)}
    g = BevelGearParams(**{k: v for k, v in starts.items() if k in fields})
    return 0.5 * float(backlash_angle(g)) + T_msh / float(mesh_stiffness(g)["K_mean"])


def _ramp(t: np.ndarray):
    """(r, dr/dt, integral of r) of the ramp 0 -> 1 over RAMP_S."""
    r = np.minimum(t / RAMP_S, 1.0)
    dr = np.where(t < RAMP_S, 1.0 / RAMP_S, 0.0)
    ir = np.where(t < RAMP_S, t * t / (2 * RAMP_S), t - RAMP_S / 2)
    return r, dr, ir


def example_signals(desc: Description, t: np.ndarray) -> dict:
    """Every input of the FMU at the times ``t`` (module docstring); KeyError for a model without an example."""
    ss = operating_point()
    r, dr, ir = _ramp(t)
    starts = desc.starts()

    def turning(w, offset=0.0):            # angle and speed of a body ramped to speed w, offset ramped in
        return w * ir + offset * r, w * r + offset * dr

    model = desc.model
    if model == "GearContact":
        ratio = starts["z_wheel"] / starts["z_pinion"]
        # pinion at the kinematic angle; flange_a ahead of it by the port twist (the stage resists the drive),
        # the wheel behind the pinion by the mesh deflection, flange_b behind the wheel (the wheel drives it)
        a_phi, a_w = turning(ss.w_middle, ss.T_msh / starts["k_a"])
        b_phi, b_w = turning(ss.w_middle / ratio, -mesh_offset(starts, ss.T_msh) / ratio - ss.T_psh / starts["k_b"])
        return {"flange_a_phi": a_phi, "flange_a_w": a_w, "flange_b_phi": b_phi, "flange_b_w": b_w}
    if model == "FlexibleShaft":
        b_phi, b_w = turning(ss.w_drive)
        return {"flange_a_tau": ss.T_dsh * r, "flange_b_phi": b_phi, "flange_b_w": b_w}
    if model == "UpperTransmission":
        return {"flange_a_tau": ss.T_dsh * r, "flange_b_tau": -ss.T_msh * r}
    if model == "MotorLoad":
        d_phi, d_w = turning(ss.w_drive, -ss.T_dsh * (1.0 / starts["k_c1"] + 1.0 / starts["k_c2"]))
        return {"drive_phi": d_phi, "drive_w": d_w, "load_tau": ss.T_psh * r, "speed_ref_rpm": EXAMPLE_SPEED_RPM * r,
                "load_torque": EXAMPLE_LOAD_NM * r, "motor_torque_disturbance": 0.0 * r}
    raise KeyError(model)


def example_input(desc: Description) -> np.ndarray:
    """The example input as the structured array ``fmpy.simulate_fmu(input=...)`` takes: ``time`` and every
    input of the FMU, over its DefaultExperiment."""
    t = np.unique(np.concatenate([np.linspace(desc.start_time, desc.start_time + RAMP_S, RAMP_ROWS),
                                  [max(desc.stop_time, desc.start_time + RAMP_S)]]))
    signals = example_signals(desc, t - desc.start_time)
    inputs = desc.names("input")
    missing = sorted(set(inputs) ^ set(signals))
    if missing:
        raise ValueError(f"{desc.model}: the example input and the FMU's inputs differ in {missing}")
    arr = np.zeros(len(t), dtype=[("time", float)] + [(n, float) for n in inputs])
    arr["time"] = t
    for n in inputs:
        arr[n] = signals[n]
    return arr


def csv_text(arr: np.ndarray) -> str:
    buf = io.StringIO()
    buf.write(",".join(arr.dtype.names) + "\n")
    for row in arr:
        buf.write(",".join(repr(float(x)) for x in row) + "\n")
    return buf.getvalue()


# ------------------------------------------------------------------------------------------------
# requirements and documentation
# ------------------------------------------------------------------------------------------------

def declared_requirements() -> dict:
    """name -> requirement string as the project declares it (pyproject.toml, else the installed metadata)."""
    reqs = []
    pyproject = Path(__file__).resolve().parents[3] / "pyproject.toml"
    if pyproject.is_file():
        import tomllib

        reqs = tomllib.loads(pyproject.read_text())["project"]["dependencies"]
    else:                                                     # pragma: no cover - an installed wheel
        from importlib.metadata import PackageNotFoundError, requires

        try:
            reqs = requires("bevel-drivetrain") or []
        except PackageNotFoundError:
            reqs = []
    out = {}
    for req in reqs:
        m = re.match(r"\s*([A-Za-z0-9_.\-]+)", req)
        if m:
            out[m.group(1).lower()] = req.strip()
    return out


def requirements_text() -> str:
    """``resources/requirements.txt`` of a pythonfmu FMU: the packages its code imports in the host's Python,
    with the project's declared ranges (pythonfmu exactly 0.7.0: the FMU's binary is its export library)."""
    from fmu_runtime import RUNTIME_PACKAGES

    declared = declared_requirements()
    lines = ["# Python packages this FMU imports in the host's Python process (a CPython with the",
             "# pythonfmu export runtime). Ranges as the project declares them (pyproject.toml).",
             "# Install them with: python -m pip install -r requirements.txt"]
    lines += [declared.get(pkg.lower(), pkg) for pkg in RUNTIME_PACKAGES]
    return "\n".join(lines) + "\n"


def port_kinds(desc: Description) -> dict:
    """flange -> "spring" | "inertia" from the causality of its _tau variable."""
    kinds = {}
    for v in desc.variables:
        if v.name.endswith("_tau") and v.causality in ("input", "output"):
            kinds[v.name[:-4]] = "spring" if v.causality == "output" else "inertia"
    return kinds


_PORT_TEXT = {
    "spring": ("spring side: inputs <code>{p}_phi</code>, <code>{p}_w</code> (angle and speed of the body connected "
               "to the flange), output <code>{p}_tau</code> = the torque this FMU applies to that body"),
    "inertia": ("inertia side: input <code>{p}_tau</code> (the torque the connected neighbour applies to the FMU's "
                "body at the flange), outputs <code>{p}_phi</code>, <code>{p}_w</code> (that body's angle and speed)"),
}


def _example_code(desc: Description) -> str:
    fmu = f"{desc.model}.fmu"
    return html.escape(
        f"import io, zipfile\nimport numpy as np, fmpy\n\nwith zipfile.ZipFile(\"{fmu}\") as z:\n"
        f"    inp = np.genfromtxt(io.BytesIO(z.read(\"{EXAMPLE_CSV}\")), delimiter=\",\", names=True)\n"
        f"res = fmpy.simulate_fmu(\"{fmu}\", input=inp)   # the DefaultExperiment: {desc.start_time:g} .. "
        f"{desc.stop_time:g} s, step {desc.step_size:.6g} s\n"
        f"print(res[\"time\"][-1], res[\"{PLOT_VARIABLES.get(desc.model, ('time',))[0]}\"][-1])\n\n"
        f"# or: unzip -p {fmu} {EXAMPLE_CSV} > example_input.csv\n"
        f"#     fmpy simulate {fmu} --input-file example_input.csv")


def documentation_html(desc: Description, plot: str | None, plot_note: str, host_note: str) -> str:
    """``documentation/index.html`` (module docstring)."""
    e = html.escape
    ports = "".join(f"<li><code>{e(p)}</code>: {_PORT_TEXT[k].format(p=e(p))}</li>" for p, k in port_kinds(desc).items())
    rows = []
    for v in desc.variables:
        rows.append("<tr>" + "".join(f"<td>{e(x)}</td>" for x in (v.name, v.causality, v.variability, v.type,
                                                                    v.unit, v.start, v.description)) + "</tr>")
    ss = operating_point()
    gear = ""
    if desc.model == "GearContact":
        gear = ("<p><code>flange_a</code> = middle-shaft side (pinion), <code>flange_b</code> = propeller-shaft side "
                "(wheel). Kinematic meshing is <code>theta_wheel = theta_pinion * z_pinion/z_wheel</code> (both "
                "positive in normal operation); under load (pinion driving) <code>mesh_torque_pinion &lt; 0 &lt; "
                "mesh_torque_wheel</code>, so <code>flange_a_tau &lt; 0</code> (the stage resists the middle shaft) "
                "and <code>flange_b_tau &gt; 0</code> (it drives the propeller shaft). The parameters are at rest "
                "by default (<code>initial_state = inputs</code>, no twist): a host sets a running state through "
                "them or passes the connected values during initialization.</p>")
    plot_html = (f"<p><img src=\"{e(Path(plot).name)}\" alt=\"reference result\" style=\"max-width:100%\"></p>"
                 if plot else "<p>(no reference plot in this build)</p>")
    return (
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{e(desc.model)}</title>"
        "<style>body{font-family:sans-serif;max-width:70em}td,th{border:1px solid #ccc;padding:2px 6px;"
        "font-size:90%}table{border-collapse:collapse}</style></head><body>"
        f"<h1>{e(desc.model)}{' (native build)' if desc.native else ''}</h1><p>{e(desc.text)}</p>"
        "<h2>Ports and sign conventions</h2><p>Every port is a flange with <code>_phi</code> [rad], <code>_w</code> "
        "[rad/s] and <code>_tau</code> [N.m]; angles, speeds and torques are positive in the shaft's positive sense "
        "(the rig turns positively in normal operation). A connection joins a spring-side flange to an "
        "inertia-side flange: phi to phi, w to w, tau back to tau, no sign flips.</p>"
        f"<ul>{ports}</ul>{gear}" + (f"<p>{SIGN_NOTES[desc.model]}</p>" if desc.model in SIGN_NOTES else "") +
        "<h2>Standalone example</h2><p>The DefaultExperiment "
        f"({desc.start_time:g} .. {desc.stop_time:g} s, communication step {desc.step_size:.6g} s) with "
        f"<code>{EXAMPLE_CSV}</code>: the rig's example operating point (drive motor {EXAMPLE_SPEED_RPM:g} rpm, "
        f"load motor {EXAMPLE_LOAD_NM:g} N.m; steady drive-shaft torque {ss.T_dsh:.3f} N.m, middle shaft "
        f"{ss.T_msh:.3f} N.m, propeller shaft {ss.T_psh:.3f} N.m), speeds and torques ramped in from rest over "
        f"{RAMP_S:g} s and then held, each angle the integral of its speed. fmpy runs the DefaultExperiment with "
        "the step doubled until it takes at most 1000 steps (the output interval is fmpy's communication step); "
        f"<code>--output-interval {desc.step_size:.10g}</code> (<code>output_interval=</code>) runs the declared "
        "step. With fmpy:</p>"
        f"<pre>{_example_code(desc)}</pre>"
        f"<h2>Reference result</h2>{plot_html}<p>{e(plot_note)}</p>"
        f"<h2>What a host needs</h2><p>{host_note}</p>"
        "<h2>Variables</h2><table><tr><th>name</th><th>causality</th><th>variability</th><th>type</th><th>unit</th>"
        "<th>start</th><th>description</th></tr>" + "".join(rows) + "</table></body></html>\n")


#: per model: the signs of its port torques in normal operation (the rig driven by its motor) and what the
#: standalone example shows of them
SIGN_NOTES = {
    "FlexibleShaft": ("In normal operation <code>flange_a_tau &gt; 0</code> (the motor's coupling drives the shaft), "
                      "<code>flange_b_tau &gt; 0</code> (the shaft drives the upper gearbox) and the shaft is twisted "
                      "forward: <code>flange_a_phi - flange_b_phi = T (1/k_t + 1/k_c + 1/k_shaft)</code> in steady "
                      "operation, as in the example."),
    "UpperTransmission": ("In normal operation <code>flange_a_tau &gt; 0</code> (the drive shaft drives it), "
                          "<code>flange_b_tau &lt; 0</code> (the gear stage resists); <code>flange_b</code> turns at "
                          "<code>flange_a / ratio</code> in its own positive sense. Driven by torques alone (the "
                          "example) it runs up to the speed where its loss balances them."),
    "MotorLoad": ("In normal operation <code>drive_tau &gt; 0</code> (the motor drives the drive shaft) and "
                  "<code>load_tau &gt; 0</code> (the gear stage drives the propeller mass against the load motor). "
                  "In the example the drive shaft is prescribed at the setpoint speed, so it holds the motor there "
                  "and the PI controller's integral stays where the ramp left it: <code>drive_tau</code> is small "
                  "and may be negative."),
}


def reference_plot(model: str, native: bool) -> Path:
    """The committed reference plot of a model's build (it may not exist)."""
    return PLOT_DIR / f"{model}{'-native' if native else ''}.png"


PLOT_NOTE = ("The plot is committed with the sources (src/drivetrain/fmu_build/reference_plots, made by "
             "examples/fmu_reference_plots.py from a run of this FMU's DefaultExperiment with its example input, "
             "fmpy.simulate_fmu), not computed when the FMU is built: building costs nothing for it.")


def fmu_extras(xml: bytes, host_note: str) -> dict[str, bytes]:
    """The files an FMU ships beside its model (path in the FMU -> bytes): documentation/index.html (and the same
    page as documentation/_main.html, FMI 2.0's entry point), the example input, the reference plot and, for a
    pythonfmu FMU, resources/requirements.txt."""
    desc = read_description(xml)
    out = {}
    try:
        out[EXAMPLE_CSV] = csv_text(example_input(desc)).encode()
    except KeyError:
        pass
    plot = reference_plot(desc.model, desc.native)
    if plot.is_file():
        out[REFERENCE_PNG] = plot.read_bytes()
    page = documentation_html(desc, REFERENCE_PNG if plot.is_file() else None, PLOT_NOTE, host_note).encode()
    out["documentation/index.html"] = page
    out["documentation/_main.html"] = page           # FMI 2.0's name of the entry point (FMI 3.0: index.html)
    if not desc.native:
        out["resources/requirements.txt"] = requirements_text().encode()
    return out
