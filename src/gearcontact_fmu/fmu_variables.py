"""The GearContact FMU's declaration, once: its variables (name, type, causality, unit, default, description,
bounds) and its model information (description, author, version, default experiment, initial dependencies).

Both builds read it here: the pythonfmu slave (``slaves/GearContact.py``) registers the variables and takes its
class attributes from it, the native builder (``drivetrain.fmu_build.native_gear``) writes its variable table
and modelDescription.xml from :func:`declaration` (a ``fmu_runtime.declaration.FmuDeclaration``) without a
slave. The defaults are the library's own: literals, or attributes of its parameter dataclasses (``From``:
``BevelGearParams``, ``PCMParams``, ``MeshResolution``, ``MapGrid``, ``StageParams``); the ``fidelity``
parameter starts at the library's default fidelity (``mesh_models.DEFAULT_FIDELITY``). Declared here in the
library, not in the slave script, so that a host reads the FMU's defaults (:func:`parameter_values`, e.g.
``drivetrain.run.assemble`` for the start state, ``drivetrain.run.runner`` for the fault labels) without
importing the slave (which imports pythonfmu and edits ``sys.path``). Plain data: nothing of pythonfmu.
"""
from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

from fmu_runtime.declaration import Experiment, FmuDeclaration, Variable
from gearcontact_fmu import __version__
from gearcontact_fmu.mesh_models import DEFAULT_FIDELITY
from gearcontact_fmu.params import (DEFAULT_COMM_STEP_S, GEAR_MODEL, MAP_GRID_RANGE, POSITIVE, SPRING,
                                    BevelGearParams, MapGrid, MeshResolution, PCMParams, flange_variables)
from gearcontact_fmu.stage import StageParams

#: values of the ``initial_state`` parameter (the first is the default)
INITIAL_STATES = ("inputs", "parameters")


class From(NamedTuple):
    """A default taken from the library's parameter dataclasses (:func:`default_sources`)."""
    source: str
    attribute: str


class Counter(NamedTuple):
    """An output read from the stage when the host asks (no cost per step): ``GearStage.<prop>``."""
    prop: str


class Var(NamedTuple):
    """One FMU variable, declared once: the slave registers it, drivetrain.fmu_build.build and .native_gear read its unit
    and description from here (:func:`declaration`)."""
    name: str
    type: str            # Real | Integer | Boolean | String
    causality: str       # PARAMETER (fixed) | INPUT | OUTPUT
    unit: str            # Real only ("1": dimensionless)
    default: Any         # a literal, From(...) or Counter(...)
    description: str
    bounds: tuple = (None, None)   # (min, max): the values the code refuses outside of (modelDescription min/max)


PARAMETER, INPUT, OUTPUT = "parameter", "input", "output"
#: the GearContact FMU's flanges flange_a (pinion) and flange_b (wheel), both spring side: name -> (causality, unit)
_GEAR_FLANGES = {v: (c, u) for p in ("flange_a", "flange_b") for v, u, c in flange_variables(p, SPRING)}
#: the largest fmi2Integer: a counter saturates there (2**31 - 1 sub-steps: ~6 h at 1e-5 s)
INT_MAX = 2 ** 31 - 1

#: every variable of the FMU, in value-reference order
VARIABLES = (
    Var("fidelity", "String", PARAMETER, "", DEFAULT_FIDELITY,
        "mesh model: pcm (online polygonal contact) | table (precomputed contact map) | analytic (ISO "
        "6336 reference) | ideal (rigid, exact ratio, no backlash)"),
    Var("mode", "String", PARAMETER, "", From("stage", "mode"),
        "stage (owns pinion and wheel inertias, sub-steps the mesh) | bare (raw contact torques)"),
    Var("health", "String", PARAMETER, "", "healthy",
        "healthy | mild (flank-fracture void) | severe (missing tooth) | faults (the faults list) | mesh "
        "(the mesh files); all but healthy: pcm/table only"),
    Var("faults", "String", PARAMETER, "", "[]",
        "health faults: JSON list of fault specifications (kind, member, tooth, flank, sizes)"),
    Var("manufacturing_errors", "String", PARAMETER, "", "",
        "pitch errors and runout as JSON (ManufacturingErrors.to_dict()); empty = none"),
    Var("pinion_mesh_file", "String", PARAMETER, "", "", "OBJ/STL surface mesh of the pinion; empty = generated"),
    Var("wheel_mesh_file", "String", PARAMETER, "", "", "OBJ/STL surface mesh of the wheel; empty = generated"),
    Var("mesh_units", "String", PARAMETER, "", "mm", "length unit of the mesh files: mm | m | cm | um | in"),
    Var("scheme", "String", PARAMETER, "", From("stage", "scheme"), "sub-step integrator: auto | ros2 | rk4"),
    Var("output_torque", "String", PARAMETER, "", From("stage", "output_torque"),
        "what flange_*_tau carries: predicted | mean | end"),
    Var("initial_state", "String", PARAMETER, "", INITIAL_STATES[0],
        "where the pinion and wheel start: inputs (the flange inputs at exit of initialization plus "
        "twist_*_start) | parameters (pinion_*_start, wheel_*_start; for a host that passes no values "
        "during initialization)"),
    Var("z_pinion", "Integer", PARAMETER, "", From("gear", "z_pinion"), "pinion teeth"),
    Var("z_wheel", "Integer", PARAMETER, "", From("gear", "z_wheel"), "wheel teeth"),
    Var("map_points_per_pitch", "Integer", PARAMETER, "", From("grid", "points_per_pitch"),
        "table: contact-map nodes along the pinion angle per pinion pitch", MAP_GRID_RANGE),
    Var("map_approach_points", "Integer", PARAMETER, "", From("grid", "s_points"),
        "table: contact-map nodes per flank along the approach beyond the contact onset", MAP_GRID_RANGE),
    Var("friction", "Boolean", PARAMETER, "", True, "tooth friction in the mesh (false: not evaluated)"),
    Var("contact_damping", "Boolean", PARAMETER, "", True, "contact damping in the mesh (false: not evaluated)"),
    Var("energy_correction", "Boolean", PARAMETER, "", From("stage", "energy_correction"),
        "energy-conserving correction of flange_*_tau (returns the measured work mismatch of each cut "
        "over 10 ms)"),
    Var("E", "Real", PARAMETER, "Pa", From("pcm", "E"), "Young's modulus of the elastic layer"),
    Var("nu", "Real", PARAMETER, "1", From("pcm", "nu"), "Poisson's ratio of the elastic layer"),
    Var("layer_depth", "Real", PARAMETER, "m", From("pcm", "layer_depth"), "elastic layer depth of each body"),
    Var("c_compression", "Real", PARAMETER, "N.s/m3", From("pcm", "c_compression"),
        "PCM damping while compressing (pressure per penetration velocity)"),
    Var("c_expansion", "Real", PARAMETER, "N.s/m3", From("pcm", "c_expansion"), "PCM damping while expanding"),
    Var("transformation_depth", "Real", PARAMETER, "m", From("pcm", "transformation_depth"),
        "penetration over which the damping ramps in"),
    Var("mu", "Real", PARAMETER, "1", From("pcm", "mu"), "friction coefficient"),
    Var("v_friction", "Real", PARAMETER, "m/s", From("pcm", "v_friction"), "regularisation velocity of friction"),
    Var("u_max", "Real", PARAMETER, "m", From("pcm", "u_max"),
        "largest admissible penetration (beyond it the step fails)"),
    Var("profile_element_size", "Real", PARAMETER, "m", From("resolution", "profile"),
        "PCM surface-mesh element size along the tooth profile"),
    Var("face_element_size", "Real", PARAMETER, "m", From("resolution", "face"),
        "PCM surface-mesh element size along the face width"),
    Var("J_pinion", "Real", PARAMETER, "kg.m2", From("stage", "J_pinion"), "pinion-side inertia of the stage",
        (POSITIVE, None)),
    Var("J_wheel", "Real", PARAMETER, "kg.m2", From("stage", "J_wheel"), "wheel-side inertia of the stage",
        (POSITIVE, None)),
    Var("k_a", "Real", PARAMETER, "N.m/rad", From("stage", "k_a"), "stiffness of the flange_a - pinion port spring"),
    Var("d_a", "Real", PARAMETER, "N.m.s/rad", From("stage", "d_a"), "damping of the flange_a - pinion port"),
    Var("k_b", "Real", PARAMETER, "N.m/rad", From("stage", "k_b"), "stiffness of the flange_b - wheel port spring"),
    Var("d_b", "Real", PARAMETER, "N.m.s/rad", From("stage", "d_b"), "damping of the flange_b - wheel port"),
    Var("max_substep", "Real", PARAMETER, "s", From("stage", "max_substep"),
        "largest internal sub-step; sub-steps per communication step = ceil(H / max_substep)", (POSITIVE, None)),
    Var("module", "Real", PARAMETER, "m", From("gear", "module"), "outer transverse module"),
    Var("pressure_angle", "Real", PARAMETER, "rad", From("gear", "pressure_angle"), "pressure angle"),
    Var("shaft_angle", "Real", PARAMETER, "rad", From("gear", "shaft_angle"), "shaft angle"),
    Var("face_width", "Real", PARAMETER, "m", From("gear", "face_width"), "face width"),
    Var("x_pinion", "Real", PARAMETER, "1", From("gear", "x_pinion"), "pinion profile shift coefficient"),
    Var("addendum_coefficient", "Real", PARAMETER, "1", From("gear", "addendum_coefficient"), "addendum / module"),
    Var("dedendum_coefficient", "Real", PARAMETER, "1", From("gear", "dedendum_coefficient"), "dedendum / module"),
    Var("backlash", "Real", PARAMETER, "m", From("gear", "backlash"),
        "circumferential backlash on the outer pitch circle"),
    Var("tip_radius", "Real", PARAMETER, "m", From("gear", "tip_radius"), "tip rounding radius"),
    Var("tooth_compliance", "Real", PARAMETER, "1", 1.0,
        "total mesh approach per PCM layer approach (table only; 1 = the layers alone)", (1.0, None)),
    Var("mesh_damping_ratio", "Real", PARAMETER, "1", 0.05, "analytic mesh: damping ratio of the mesh mode"),
    Var("mesh_phase", "Real", PARAMETER, "rad", 0.0,
        "analytic mesh: pinion angle at which a drive flank passes the pitch point"),
    Var("pinion_phi_start", "Real", PARAMETER, "rad", 0.0,
        "initial_state parameters: pinion angle at the start time"),
    Var("pinion_w_start", "Real", PARAMETER, "rad/s", 0.0,
        "initial_state parameters: pinion speed at the start time"),
    Var("wheel_phi_start", "Real", PARAMETER, "rad", 0.0, "initial_state parameters: wheel angle at the start time"),
    Var("wheel_w_start", "Real", PARAMETER, "rad/s", 0.0, "initial_state parameters: wheel speed at the start time"),
    Var("twist_a_start", "Real", PARAMETER, "rad", 0.0,
        "twist of the flange_a port spring at the start time (pinion angle - flange_a angle)"),
    Var("twist_b_start", "Real", PARAMETER, "rad", 0.0,
        "twist of the flange_b port spring at the start time (wheel angle - flange_b angle)"),
    Var("flange_a_phi", "Real", *_GEAR_FLANGES["flange_a_phi"], 0.0,
        "angle of the body connected to flange_a (middle shaft, pinion side)"),
    Var("flange_a_w", "Real", *_GEAR_FLANGES["flange_a_w"], 0.0, "speed of the body connected to flange_a"),
    Var("flange_b_phi", "Real", *_GEAR_FLANGES["flange_b_phi"], 0.0,
        "angle of the body connected to flange_b (propeller shaft, wheel side)"),
    Var("flange_b_w", "Real", *_GEAR_FLANGES["flange_b_w"], 0.0, "speed of the body connected to flange_b"),
    Var("flange_a_tau", "Real", *_GEAR_FLANGES["flange_a_tau"], 0.0,
        "torque applied to the body at flange_a (see output_torque)"),
    Var("flange_b_tau", "Real", *_GEAR_FLANGES["flange_b_tau"], 0.0,
        "torque applied to the body at flange_b (see output_torque)"),
    Var("flange_a_tau_mean", "Real", OUTPUT, "N.m", 0.0, "exact mean over the last step of the torque at flange_a"),
    Var("flange_b_tau_mean", "Real", OUTPUT, "N.m", 0.0, "exact mean over the last step of the torque at flange_b"),
    Var("n_contact", "Real", OUTPUT, "1", 0.0, "pairs in contact (analytic), contact elements (pcm/table)"),
    Var("contact_area", "Real", OUTPUT, "m2", 0.0, "contact area"),
    Var("peak_pressure", "Real", OUTPUT, "Pa", 0.0, "peak contact pressure"),
    Var("max_penetration", "Real", OUTPUT, "m", 0.0, "largest penetration"),
    Var("normal_force", "Real", OUTPUT, "N", 0.0, "total normal force"),
    Var("elastic_energy", "Real", OUTPUT, "J", 0.0, "energy in the mesh compliance"),
    Var("mesh_torque_pinion", "Real", OUTPUT, "N.m", 0.0, "mesh torque on the pinion at the step end"),
    Var("mesh_torque_wheel", "Real", OUTPUT, "N.m", 0.0, "mesh torque on the wheel at the step end"),
    Var("mesh_dissipated_power", "Real", OUTPUT, "W", 0.0, "mesh damping and friction power"),
    Var("pinion_phi", "Real", OUTPUT, "rad", 0.0, "pinion angle"),
    Var("pinion_w", "Real", OUTPUT, "rad/s", 0.0, "pinion speed"),
    Var("wheel_phi", "Real", OUTPUT, "rad", 0.0, "wheel angle"),
    Var("wheel_w", "Real", OUTPUT, "rad/s", 0.0, "wheel speed"),
    Var("energy_stored", "Real", OUTPUT, "J", 0.0, "kinetic, port-spring and mesh elastic energy"),
    Var("energy_dissipated", "Real", OUTPUT, "J", 0.0,
        "energy dissipated since t = 0 (port dampers, mesh damping and friction)"),
    Var("energy_supplied", "Real", OUTPUT, "J", 0.0, "always 0 (no sources inside)"),
    Var("error", "String", OUTPUT, "", "",
        "empty while the instance works; after a failure, why it failed (then the torque, mesh and energy"
        " outputs are NaN; pinion/wheel keep the last completed step, the counters include the failing "
        "sub-step)"),
    Var("peak_penetration", "Real", OUTPUT, "m", Counter("peak_penetration"),
        "stability counter: largest element penetration since t = 0"),
    Var("min_substep", "Real", OUTPUT, "s", Counter("min_substep"),
        "stability counter: smallest accepted sub-step since t = 0"),
    Var("n_substeps", "Integer", OUTPUT, "", Counter("n_substeps_total"),
        "stability counter: accepted sub-steps since t = 0"),
    Var("n_refinements", "Integer", OUTPUT, "", Counter("n_refinements"),
        "stability counter: sub-step halvings since t = 0"),
    Var("separated_time", "Real", OUTPUT, "s", Counter("separated_time"),
        "stability counter: time out of contact since t = 0"),
    Var("n_separations", "Integer", OUTPUT, "", Counter("n_separations"),
        "stability counter: contact-loss events since t = 0"),
    Var("coupling_energy_error", "Real", OUTPUT, "J", Counter("coupling_energy_error"),
        "work mismatch of the two flange cuts since t = 0 not yet corrected"),
)


def default_sources() -> dict:
    """The objects ``From`` defaults refer to: the library's defaults, declared there once."""
    return {"gear": BevelGearParams(), "pcm": PCMParams(), "resolution": MeshResolution(), "stage": StageParams(),
            "grid": MapGrid()}


def gear_pair(parameters) -> BevelGearParams:
    """The pair a GearContact's parameter values name (name -> value; the declared default, the rig's, where
    they name none): what a host reads of the pair (its ratio, its ISO stiffness) without building the FMU."""
    return BevelGearParams(**{f.name: parameters[f.name] for f in dataclasses.fields(BevelGearParams)
                              if f.name in parameters})


def declared_default(var: Var, sources: dict | None = None):
    """The value ``var`` (not a ``Counter``) starts at: its literal, or the library attribute ``From`` names
    (``sources``: :func:`default_sources`, made once by a caller that asks for many)."""
    d = var.default
    if isinstance(d, From):
        return getattr((sources or default_sources())[d.source], d.attribute)
    return d


def parameter_values(given=None) -> dict:
    """Every parameter's value as an instance holds it before anything is set: ``given`` (name -> value)
    where it names a parameter, else the declared default (what ``fmu_parameters.build_mesh_model``
    takes, e.g. for the assembler's start state, drivetrain.run.assemble)."""
    given = given or {}
    sources = default_sources()
    return {v.name: given[v.name] if v.name in given else declared_default(v, sources)
            for v in VARIABLES if v.causality == PARAMETER}


# ------------------------------------------------------------------------------------------------
# the model information and what follows from the variables (read by the slave and the native build)
# ------------------------------------------------------------------------------------------------
DESCRIPTION = ("Lower bevel gear stage (15/60, m 3 mm) of the azimuth-thruster rig: pinion and wheel "
               "inertias, port spring-dampers and the mesh (pcm/table/analytic/ideal), sub-stepped.")
AUTHOR = "bevel-drivetrain"
VERSION = __version__
#: the shipped example input (documentation/example_input.csv: the rig's 500 rpm point ramped in over 0.25 s)
#: settles well inside it; no tolerance: the stage integrates with fixed sub-steps
DEFAULT_EXPERIMENT = Experiment(start_time=0.0, stop_time=1.0, step_size=DEFAULT_COMM_STEP_S)

#: the modelDescription's units, descriptions and bounds (min/max), by variable name
UNITS = {v.name: v.unit for v in VARIABLES if v.unit}
VARIABLE_DESCRIPTIONS = {v.name: v.description for v in VARIABLES}
BOUNDS = {v.name: v.bounds for v in VARIABLES if v.bounds != (None, None)}
#: InitialUnknowns: at exit of initialization every output follows the flange inputs (initial_state inputs) and
#: the parameters, but these: 0 whatever they are (no source inside; the sums and counts since t = 0, the
#: smallest sub-step before the first step, the pending coupling work)
INITIAL_DEPENDENCIES = {n: [] for n in ("energy_supplied", "energy_dissipated", "n_substeps", "n_refinements",
                                        "n_separations", "separated_time", "min_substep", "coupling_energy_error")}

#: the stability counters of the stage and the pending coupling mismatch, cumulative since t = 0: output name ->
#: the ``GearStage`` property read when the host asks (after a failed step they include the failing sub-step)
COUNTERS = {v.name: v.default.prop for v in VARIABLES if isinstance(v.default, Counter)}
#: the outputs published after every step
OUTPUTS = tuple(v.name for v in VARIABLES if v.causality == OUTPUT and v.type == "Real"
                and not isinstance(v.default, Counter))
#: after a failure: NaN (the state outputs keep the last completed step, see ``error``)
NAN_ON_FAILURE = tuple(n for n in OUTPUTS if n not in ("pinion_phi", "pinion_w", "wheel_phi", "wheel_w"))


def declared_variables() -> tuple[Variable, ...]:
    """Every variable as the slave registers it (value reference = position in :data:`VARIABLES`): its start
    is the declared default (a counter's: 0 before the first step), an Integer parameter has its bounds, a
    parameter is fixed, a count or text output discrete."""
    sources = default_sources()
    rows = []
    for vr, v in enumerate(VARIABLES):
        counter = isinstance(v.default, Counter)
        start = (0 if v.type == "Integer" else 0.0) if counter else declared_default(v, sources)
        variability = ("fixed" if v.causality == PARAMETER else
                       "discrete" if v.causality == OUTPUT and (v.type == "String" or (counter and v.type == "Integer"))
                       else None)
        lo, hi = v.bounds if v.causality == PARAMETER and v.type == "Integer" else (None, None)
        rows.append(Variable(vr, v.name, v.type, v.causality, start, variability, lo, hi))
    return tuple(rows)


def declaration() -> FmuDeclaration:
    """The GearContact FMU's declaration (module docstring), as both builds read it."""
    return FmuDeclaration(model=GEAR_MODEL, description=DESCRIPTION, author=AUTHOR, version=VERSION,
                          default_experiment=DEFAULT_EXPERIMENT, variables=declared_variables(), units=UNITS,
                          variable_descriptions=VARIABLE_DESCRIPTIONS, bounds=BOUNDS,
                          initial_dependencies=INITIAL_DEPENDENCIES)
