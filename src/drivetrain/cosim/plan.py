"""The exchange plan: a SystemSpec checked against the FMUs' model descriptions, before anything runs.

``check_system(spec, infos, record)`` checks every connection (a spring-side port feeds an inertia-side
port: phi, w one way, tau back, identical expected units), parameters (exist, settable, right type),
inputs (fed at most once; constants and time profiles), recorded variables; all problems are raised
together as ``ConfigurationError`` naming the ports. It returns the plan the loop runs on: value
references, the output->input gather index, external inputs, the energy ports.
``check_comm_step`` checks that the communication step divides the output period.
"""
from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from drivetrain.fmu_build.fmus import ENERGY_VARS, PORT_UNITS, PORT_VARS, FMUInfo
from drivetrain.errors import ConfigurationError
from drivetrain.system import steps_per_output
from drivetrain.system import INERTIA, SPRING, ComponentSpec, SystemSpec
from gearcontact_fmu.params import flange_variables


def split_ref(ref: str) -> tuple[str, str]:
    comp, _, rest = ref.partition(".")
    return comp, rest


def _type_ok(vtype: str, value) -> str | None:
    """None if value fits the FMI type, else what was expected."""
    if vtype == "Real":
        return None if isinstance(value, (int, float)) and not isinstance(value, bool) else "a real number"
    if vtype in ("Integer", "Enumeration"):
        return None if isinstance(value, (int, np.integer)) and not isinstance(value, bool) else "an integer"
    if vtype == "Boolean":
        return None if isinstance(value, (bool, np.bool_)) else "a boolean"
    if vtype == "String":
        return None if isinstance(value, (str, os.PathLike)) else "a string"
    return f"a supported type (not {vtype})"


def same_as_start(v, value) -> bool:
    """The value equals the variable's declared start (a constant's value: a host does not set it)."""
    if v.start is None:
        return False
    try:
        if v.type == "Real":
            return float(value) == float(v.start)
        if v.type in ("Integer", "Enumeration"):
            return int(value) == int(v.start)
        if v.type == "Boolean":
            return bool(value) == (str(v.start).strip().lower() in ("true", "1"))
        return os.fspath(value) == str(v.start)
    except (TypeError, ValueError):
        return False


def settable(values: dict, variables: dict) -> dict:
    """The values a host sets: all but the FMU's constants (checked equal to their start, :func:`same_as_start`,
    by check_system)."""
    return {n: v for n, v in values.items() if n not in variables or not variables[n].constant}


def is_profile(value) -> bool:
    """A time profile: rows [t, value], as a list of pairs, an (n, 2) numpy array, or an object that becomes one
    when read (``__array__`` and ``shape``: rig.background.GeneratedProfile)."""
    if isinstance(value, np.ndarray) or hasattr(value, "__array__"):     # an array, or one generated when read
        shape = getattr(value, "shape", ())
        return len(shape) == 2 and shape[0] > 0 and shape[1] == 2
    return (isinstance(value, (list, tuple)) and len(value) > 0
            and all(isinstance(p, (list, tuple)) and len(p) == 2 for p in value))


@dataclass
class ExchangePlan:
    comps: list[ComponentSpec]
    infos: list[FMUInfo]
    in_names: list[list[str]]          # per component: Real inputs set every step (connected or profiles)
    out_names: list[list[str]]         # per component: Real variables read every step
    gather: np.ndarray                 # u = y[gather]
    ext: list[tuple[int, Any]]         # (y index of the external slot, profile)
    y_names: list[str]                 # "comp.var" for every y entry (ext slots: "comp.var" of the input)
    u_names: list[str]
    energy: list[dict[str, int]]       # per component: energy var -> vr
    warnings: list[str]
    conn_index: list[tuple[int, int, int, int, int]]  # per connection: (ci_spring, ci_inertia, y_tau, y_phi, y_w)
    ext_work: list = dataclasses.field(default_factory=list)  # (ci, "comp.port", tau const | None, y_tau | None, y_phi)


def check_system(spec: SystemSpec, infos: dict[str, FMUInfo], record: Sequence[str] = ()) -> ExchangePlan:
    """Validate the spec against the model descriptions; raise ConfigurationError listing every problem."""
    problems: list[str] = []
    _check_components(spec, infos, problems)
    if problems:
        raise ConfigurationError(problems)
    var = {c.name: infos[c.model].variables for c in spec.components}
    for c in spec.components:
        _check_parameters(c, var[c.name], problems)
        _check_inputs(c, var[c.name], problems)
    fed: dict[str, str] = {}           # input "comp.var" -> the output "comp.var" that feeds it
    conn_vars = [ports for ports in (_check_connection(conn, spec, var, fed, problems)
                                     for conn in spec.connections) if ports is not None]
    _check_inputs_fed_once(spec, fed, problems)
    _check_record(record, spec, var, problems)
    if problems:
        raise ConfigurationError(problems)
    return _layout(spec, infos, var, fed, conn_vars, record, _unconnected_flanges(spec, var, fed))


def _check_components(spec: SystemSpec, infos: dict[str, FMUInfo], problems: list[str]) -> None:
    """Unique names, an FMU for every model."""
    names = [c.name for c in spec.components]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        problems.append(f"component names are not unique: {', '.join(dup)}")
    for c in spec.components:
        if c.model not in infos:
            problems.append(f"component {c.name!r}: no FMU for model {c.model!r}")


def _check_parameters(c: ComponentSpec, var: dict, problems: list[str]) -> None:
    """Each parameter exists, is settable and has the FMI type's kind of value."""
    for pname, value in c.parameters.items():
        v = var.get(pname)
        if v is None:
            problems.append(f"{c.name}.{pname}: no such variable in {c.model} (parameters: "
                            + ", ".join(n for n, x in var.items() if x.causality == "parameter") + ")")
            continue
        if v.constant:
            if not same_as_start(v, value):
                problems.append(f"{c.name}.{pname} = {value!r}: {c.model} was built with {pname} = {v.start} "
                                "(a constant of this FMU, e.g. a native GearContact's contact-map parameter: "
                                "rebuild it with the new value)")
            continue
        if v.causality != "parameter":
            problems.append(f"{c.name}.{pname}: not a settable parameter (causality {v.causality}, "
                            f"variability {v.variability})")
            continue
        exp = _type_ok(v.type, value)
        if exp:
            problems.append(f"{c.name}.{pname} = {value!r}: expected {exp} (FMI type {v.type})")


def _check_inputs(c: ComponentSpec, var: dict, problems: list[str]) -> None:
    """Each constant or time-profile input is an input of the model, of the right type (a profile: Real,
    times strictly increasing)."""
    for iname, value in c.inputs.items():
        v = var.get(iname)
        if v is None or v.causality != "input":
            problems.append(f"{c.name}.{iname}: not an input of {c.model}")
            continue
        if is_profile(value):
            if v.type != "Real":
                problems.append(f"{c.name}.{iname}: a time profile needs a Real input (is {v.type})")
            else:
                ts = np.asarray(value, dtype=float)[:, 0]
                if np.any(np.diff(ts) <= 0) or not np.all(np.isfinite(np.asarray(value, dtype=float))):
                    problems.append(f"{c.name}.{iname}: profile times must increase strictly and its values be finite")
        else:
            exp = _type_ok(v.type, value)
            if exp:
                problems.append(f"{c.name}.{iname} = {value!r}: expected {exp} (FMI type {v.type})")


def _check_connection(conn, spec: SystemSpec, var: dict, fed: dict[str, str],
                      problems: list[str]) -> tuple[str, str, str, str] | None:
    """One connection: both components in the system, a spring-side port joined to an inertia-side port
    (causality, Real, units), inputs fed once (entered into ``fed``). Its (spring comp, port, inertia
    comp, port), or None when it has a problem."""
    sc, sp = split_ref(conn.spring)
    ic, ip = split_ref(conn.inertia)
    label = f"connection spring={conn.spring} <-> inertia={conn.inertia}"
    comps = {c.name: c for c in spec.components}
    missing = [(ref, comp) for ref, comp in ((conn.spring, sc), (conn.inertia, ic)) if comp not in comps]
    for ref, comp in missing:
        problems.append(f"{label}: component {comp!r} of {ref} is not in the system "
                        f"(components: {', '.join(c.name for c in spec.components)})")
    if missing:
        return None
    n0 = len(problems)
    _check_port(label, SPRING, sc, sp, ("phi", "w"), conn.inertia, comps[sc].model, var[sc], problems)
    _check_port(label, INERTIA, ic, ip, ("tau",), conn.spring, comps[ic].model, var[ic], problems)
    if len(problems) > n0:
        return None
    for q in PORT_VARS:
        us = var[sc][f"{sp}_{q}"].unit
        ui = var[ic][f"{ip}_{q}"].unit
        exp = PORT_UNITS[q]
        if us != ui or us != exp:
            problems.append(f"{label}: unit mismatch: {conn.spring}_{q} [{us or 'no unit'}] vs "
                            f"{conn.inertia}_{q} [{ui or 'no unit'}], expected {exp} on both")
    for (s_var, _, s_causality), (i_var, _, _) in zip(flange_variables(f"{sc}.{sp}", SPRING),
                                                       flange_variables(f"{ic}.{ip}", INERTIA)):
        tgt, src = (s_var, i_var) if s_causality == "input" else (i_var, s_var)
        if tgt in fed:
            problems.append(f"{label}: input {tgt} is already fed by {fed[tgt]}")
        fed[tgt] = src
    return None if len(problems) > n0 else (sc, sp, ic, ip)


def _check_port(label: str, side: str, comp: str, port: str, want_in: tuple[str, ...], other: str, model: str,
                var: dict, problems: list[str]) -> None:
    """A flange of the model, with the causalities of its side (``want_in`` inputs, the rest outputs),
    every variable Real."""
    for q in PORT_VARS:
        vn = f"{port}_{q}"
        v = var.get(vn)
        if v is None:
            problems.append(f"{label}: {comp}.{port} is not a flange of {model} (no variable {vn})")
            continue
        need = "input" if q in want_in else "output"
        if v.causality != need:
            problems.append(
                f"{label}: wrong causality: {comp}.{port} is not a {side}-side port "
                f"({vn} is {v.causality}, a {side}-side port needs {vn} as {need}); "
                f"it cannot be joined to {other}")
        if v.type != "Real":
            problems.append(f"{label}: {comp}.{vn} is {v.type}, expected Real")


def _check_inputs_fed_once(spec: SystemSpec, fed: dict[str, str], problems: list[str]) -> None:
    """No input both given as a component input and fed by a connection."""
    for c in spec.components:
        for iname in c.inputs:
            ref = f"{c.name}.{iname}"
            if ref in fed:
                problems.append(f"{ref}: given as a component input and also fed by connection from {fed[ref]}")


def _check_record(record: Sequence[str], spec: SystemSpec, var: dict, problems: list[str]) -> None:
    """Every recorded name is a Real variable of a component of the system."""
    comps = {c.name: c for c in spec.components}
    for ref in record:
        comp, vn = split_ref(ref)
        if comp not in comps:
            problems.append(f"recorded variable {ref}: no component {comp!r} in the system "
                            f"(components: {', '.join(c.name for c in spec.components)})")
        elif vn not in var[comp]:
            problems.append(f"recorded variable {ref}: {comps[comp].model} has no variable {vn!r}")
        elif var[comp][vn].type != "Real":
            problems.append(f"recorded variable {ref}: is {var[comp][vn].type}; only Real variables are recorded")


def _unconnected_flanges(spec: SystemSpec, var: dict, fed: dict[str, str]) -> list[str]:
    """Warnings for flanges joined to nothing (allowed: a free end / a clamped spring; reported)."""
    warnings = []
    for c in spec.components:
        vs = var[c.name]
        ports = {n[:-4] for n in vs if n.endswith("_tau") and f"{n[:-4]}_phi" in vs and f"{n[:-4]}_w" in vs}
        for p in sorted(ports):
            if not any(f"{c.name}.{p}_{q}" in fed or f"{c.name}.{p}_{q}" in fed.values() for q in PORT_VARS):
                warnings.append(f"flange {c.name}.{p} is not connected")
    return warnings


def _layout(spec: SystemSpec, infos: dict[str, FMUInfo], var: dict, fed: dict[str, str], conn_vars: list,
            record: Sequence[str], warnings: list[str]) -> ExchangePlan:
    """The layout of the exchange buffers of a checked system."""
    in_names = [[] for _ in spec.components]
    out_names = [[] for _ in spec.components]
    idx = {c.name: i for i, c in enumerate(spec.components)}

    def want_out(ref):
        comp, vn = split_ref(ref)
        lst = out_names[idx[comp]]
        if vn not in lst:
            lst.append(vn)

    for sc, sp, ic, ip in conn_vars:
        want_out(f"{sc}.{sp}_tau")
        want_out(f"{ic}.{ip}_phi")
        want_out(f"{ic}.{ip}_w")
    for ref in record:
        want_out(ref)
    # torques applied from outside (constant or profile inputs) on unconnected inertia-side flanges:
    # their work enters the energy audit as external work
    ext_torques = []
    for c in spec.components:
        for iname, value in c.inputs.items():
            port = iname[:-4] if iname.endswith("_tau") else None
            v_phi = var[c.name].get(f"{port}_phi") if port else None
            if v_phi is not None and v_phi.causality == "output" and v_phi.type == "Real":
                want_out(f"{c.name}.{port}_phi")
                ext_torques.append((c.name, port, iname, value))
    for tgt in fed:
        comp, vn = split_ref(tgt)
        in_names[idx[comp]].append(vn)
    profiles = []
    for c in spec.components:
        for iname, value in c.inputs.items():
            if is_profile(value):
                in_names[idx[c.name]].append(iname)
                profiles.append((f"{c.name}.{iname}", value))

    y_names = [f"{c.name}.{n}" for c, outs in zip(spec.components, out_names) for n in outs]
    ypos = {n: i for i, n in enumerate(y_names)}
    ext = []
    for ref, prof in profiles:
        ypos[f"ext:{ref}"] = len(y_names)
        ext.append((len(y_names), prof))
        y_names.append(f"ext:{ref}")
    u_names = [f"{c.name}.{n}" for c, ins in zip(spec.components, in_names) for n in ins]
    gather = np.array([ypos[fed[u]] if u in fed else ypos[f"ext:{u}"] for u in u_names], dtype=np.intp)

    energy = []
    for c in spec.components:
        energy.append({e: var[c.name][e].vr for e in ENERGY_VARS if e in var[c.name]})
    conn_index = [(idx[sc], idx[ic], ypos[f"{sc}.{sp}_tau"], ypos[f"{ic}.{ip}_phi"], ypos[f"{ic}.{ip}_w"])
                  for sc, sp, ic, ip in conn_vars]
    ext_work = []
    for cname, port, iname, value in ext_torques:
        if is_profile(value):
            ext_work.append((idx[cname], f"{cname}.{port}", None, ypos[f"ext:{cname}.{iname}"],
                             ypos[f"{cname}.{port}_phi"]))
        else:
            ext_work.append((idx[cname], f"{cname}.{port}", float(value), None, ypos[f"{cname}.{port}_phi"]))
    return ExchangePlan(list(spec.components), [infos[c.model] for c in spec.components], in_names, out_names,
                        gather, ext, y_names, u_names, energy, warnings, conn_index, ext_work)


def check_comm_step(comm_step: float, output_rate_Hz: float) -> int:
    """Steps per output sample; ConfigurationError unless H divides the output period."""
    if not (comm_step > 0 and math.isfinite(comm_step)):
        raise ConfigurationError(f"communication step H = {comm_step!r} s: expected a positive finite step")
    n, expected = steps_per_output(comm_step, output_rate_Hz)
    if expected:
        raise ConfigurationError(f"communication step H = {comm_step:.10g} s does not divide the output period: "
                                 f"expected {expected}")
    return n
