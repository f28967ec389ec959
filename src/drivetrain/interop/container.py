"""A scene's system as one FMU: an FMU container built with FMU Manipulation Toolbox.

What: ``export_container(scene, path)`` writes one co-simulation FMU (FMI 2.0) that embeds the four FMUs
of the assembled system (instances motors, drive_shaft, upper, gear, as in our master and the SSP
archive), their internal connections (``ssp.system_connections``: phi and w of the inertia side to the
spring side, tau back), every assembled parameter and constant input as the embedded FMUs' start
values (``ssp.bound_values``, typed as each FMU declares it) and the container's internal step = the
scene's communication step. The container exposes outputs only: the rig's sensors (``sensor_map``,
under the sensor names, e.g. ``drive_shaft_torque``) and any ``outputs`` asked for. Any FMI 2.0 host
runs it as a single FMU (``fmpy.simulate_fmu(path, step_size=H, output_interval=H)``).

Why this shape: the container's runtime (FMU Manipulation Toolbox 2.0, ``container.so``) steps its FMUs
in parallel mode (Jacobi: every FMU gets the others' outputs of the previous step), the schedule our
master uses and the energy correction of the spring-side ports assumes (docs/FMU.md). It initializes
the FMUs one after the other in the order they are declared, each with the link values of those before
it; our system is all loops (phi and w one way, tau back), which it cuts before the first FMU of a loop,
whose linked inputs then stay 0. A spring-side port (MotorLoad ``drive``, FlexibleShaft ``flange_b``)
computes its torque at the start time from its angle and speed inputs at initialization: started before
its inertia side it began at -449 N.m instead of 1.9 (a 16x spike of the drive-shaft torque). So the
FMUs are declared with every spring side after its inertia sides (``initialization_order``).

The toolbox splits a start value at spaces (one token per array element), so a String value is written
without spaces: time profiles ('t0:v0;t1:v1') and JSON values (compact separators) are rewritten, any
other String with a space is refused. The toolbox is an optional dependency (``pip install
fmu-manipulation-toolbox``); it is imported when a container is built.
"""
from __future__ import annotations

import json
import logging
import shutil
import tempfile
from pathlib import Path

from drivetrain.run.assemble import sensor_map
from drivetrain.models.parameters import parse_profile
from drivetrain.errors import ConfigurationError
from drivetrain.cosim.plan import settable
from drivetrain.interop.ssp import bound_values, system_connections, system_fmus, value_text
from drivetrain.system import SystemSpec


def _spaceless(name: str, text: str) -> str:
    """A String start value without spaces, with the same meaning to the FMU; ValueError when none."""
    if not any(ch.isspace() for ch in text):
        return text
    try:
        return json.dumps(json.loads(text), separators=(",", ":"))
    except ValueError:
        pass
    try:
        if parse_profile(text) is not None:
            return "".join(text.split())
    except ValueError:
        pass
    raise ValueError(f"{name} = {text!r}: the container splits start values at spaces "
                     "(FMU Manipulation Toolbox), and this string has no form without them")


def initialization_order(spec: SystemSpec) -> list[str]:
    """The instances, each after the inertia sides its spring-side ports connect to (a topological order
    of the flange connections; the spec's order among the rest). The container initializes its FMUs in
    the order they are declared, each with the values of the FMUs initialized before it (a loop of
    links is cut before the first one), so every spring-side port then starts from the angle and speed
    of the body it connects to, as in our master."""
    after: dict[str, set[str]] = {c.name: set() for c in spec.components}
    for conn in spec.connections:
        s_comp, i_comp = conn.spring.split(".", 1)[0], conn.inertia.split(".", 1)[0]
        if s_comp != i_comp:
            after[s_comp].add(i_comp)
    order: list[str] = []
    while len(order) < len(after):
        ready = [n for n in after if n not in order and after[n] <= set(order)]
        if not ready:                                # a loop of spring sides: the spec's order
            ready = [n for n in after if n not in order]
        order.append(ready[0])
    return order


def container_outputs(scene, outputs: dict | None = None) -> dict[str, tuple[str, str]]:
    """Container output name -> (instance, variable): the rig's sensors, then ``outputs``
    (name -> "instance.variable")."""
    chosen = {**sensor_map(scene.effects.shaft_flexibility), **(outputs or {})}
    return {name: tuple(ref.split(".", 1)) for name, ref in chosen.items()}


def export_container(scene, path: str | Path, fmu_dir: str | Path | None = None, spec: SystemSpec | None = None,
                     outputs: dict | None = None, build: bool = True, log=None, native: bool = False) -> Path:
    """Write the scene's assembled system as one FMU container at ``path`` (module docstring). The
    embedded FMUs come from ``fmu_dir`` (built when missing or stale); ``outputs`` adds container
    outputs (name -> "instance.variable") to the sensors. Raises ConfigurationError naming every problem
    (a time profile no parameter carries, a variable an FMU does not have, a start value the container
    cannot hold, the toolbox not installed); nothing is written then. ``native``: the compiled FMUs
    (ssp.system_fmus): a container without Python in it."""
    path = Path(path)
    if path.suffix != ".fmu":
        raise ConfigurationError([f"{path}: an FMU container's name ends in .fmu"])
    if not path.stem.isidentifier():
        raise ConfigurationError([f"{path}: the name (without .fmu) is the container's model identifier and "
                                  "must be a C identifier"])
    try:
        from fmu_manipulation_toolbox.assembly import AssemblyNode
    except ImportError as exc:
        raise ConfigurationError([f"FMU Manipulation Toolbox is not installed ({exc}): "
                                  "pip install fmu-manipulation-toolbox"]) from None
    spec, fmus, descriptions, problems = system_fmus(scene, fmu_dir, spec, build, log, native)
    instances = {c.name: c.model for c in spec.components}
    exposed = container_outputs(scene, outputs)
    for name, (inst, var) in exposed.items():
        if inst not in instances or var not in descriptions[instances[inst]]:
            problems.append(f"output {name}: {inst}.{var} does not exist")
    starts = []
    for c in spec.components:
        for name, value in settable(bound_values(c), descriptions[c.model]).items():
            if name not in descriptions[c.model]:
                continue                                   # named by system_problems
            vtype = descriptions[c.model][name].type
            try:
                text = value_text(vtype, value)
                if vtype == "String":
                    text = _spaceless(f"{c.name}.{name}", text)
            except (TypeError, ValueError) as exc:
                problems.append(f"{c.name}.{name}: {exc}")
                continue
            starts.append((c.name, name, text))
    if problems:
        raise ConfigurationError(problems)

    node = AssemblyNode(path.name, step_size=spec.comm_step, auto_link=False, auto_input=False,
                        auto_output=False)
    for name in initialization_order(spec):
        node.add_fmu(f"{name}.fmu", instances[name] + ".fmu")
    for a, va, b, vb in system_connections(spec):
        node.add_link(f"{a}.fmu", va, f"{b}.fmu", vb)
    for inst, name, text in starts:
        node.add_start_value(f"{inst}.fmu", name, text)
    for name, (inst, var) in exposed.items():
        node.add_output(f"{inst}.fmu", var, name)

    path.parent.mkdir(parents=True, exist_ok=True)
    toolbox_log = logging.getLogger("fmu_manipulation_toolbox")
    level = toolbox_log.level
    toolbox_log.setLevel(logging.CRITICAL)   # it warns of every unconnected output and errs on the constant inputs
    try:
        with tempfile.TemporaryDirectory(prefix="container_", dir=path.parent) as work:
            work = Path(work)
            for m, p in fmus.items():
                shutil.copyfile(p, work / f"{m}.fmu")
            try:
                node.make_fmu(work)
            except Exception as exc:        # the toolbox's own errors (FMUContainerError, AssemblyError)
                raise ConfigurationError([f"FMU Manipulation Toolbox refused the container: {exc}"]) from exc
            built = work / path.name
            if not built.is_file():
                raise ConfigurationError([f"FMU Manipulation Toolbox wrote no {path.name}"])
            shutil.move(str(built), str(path))
    finally:
        toolbox_log.setLevel(level)
    return path
