"""GearContact: FMI 2.0 co-simulation FMU of the lower bevel gear stage (pythonfmu slave).

A thin shell over :mod:`gearcontact_fmu.stage`: the mesh model (fidelity pcm/table/analytic/ideal) is
built once in ``exit_initialization_mode`` from the parameters (``gearcontact_fmu.fmu_parameters.build_stage``,
the translation the native build shares), then every ``do_step`` advances the stage over the
communication step. Both flanges are spring side (ARCHITECTURE.md): inputs
``flange_*_phi`` [rad], ``flange_*_w`` [rad/s], outputs ``flange_*_tau`` [N.m]. See docs/FMU.md.

Errors (non-finite input, penetration beyond u_max, any exception) never propagate into the host:
``do_step`` logs the cause with status error and returns False, which pythonfmu 0.7.0 maps to
fmi2Discard; the instance then refuses further steps. (A raised exception would become fmi2Fatal.)

pythonfmu 0.7.0's export library corrupts the heap at process exit (double release of its interpreter
state; glibc then aborts the host after its work is done): ``fmu_runtime.guard`` fixes the
reference count on instantiation.

Package import: the installed ``gearcontact_fmu`` when importable, else the copy bundled in
``resources/_bundled`` (``BEVEL_FMU_USE_BUNDLED=1`` forces the bundled copy).
"""
import importlib.util
import os
import sys
from pathlib import Path
from typing import Any, NamedTuple

_HERE = Path(__file__).resolve().parent
_BUNDLED = _HERE / "_bundled"
_FORCE_BUNDLED = os.environ.get("BEVEL_FMU_USE_BUNDLED", "").strip() not in ("", "0")
if _BUNDLED.is_dir() and (_FORCE_BUNDLED or importlib.util.find_spec("gearcontact_fmu") is None):
    sys.path.insert(0, str(_BUNDLED))

from fmu_runtime import check_runtime  # noqa: E402

check_runtime("GearContact", _HERE)        # a missing package named where the host shows it
import gearcontact_fmu  # noqa: E402
from gearcontact_fmu.mesh_model import (OUT_CONTACT_AREA, OUT_DISSIPATED_POWER, OUT_ELASTIC_ENERGY,  # noqa: E402
                                      OUT_MAX_PENETRATION, OUT_N_CONTACT, OUT_NORMAL_FORCE,
                                      OUT_PEAK_PRESSURE, OUT_TAU_PINION, OUT_TAU_WHEEL)
from pythonfmu import Boolean, DefaultExperiment, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real, String  # noqa: E402
from pythonfmu.enums import Fmi2Status  # noqa: E402

from fmu_runtime.guard import enter_error_state, fmi_text, guard_value_references, restore_shell_state, shell_state  # noqa: E402,E501
from gearcontact_fmu.params import DEFAULT_COMM_STEP_S, MAP_GRID_RANGE, POSITIVE  # noqa: E402

PACKAGE_ORIGIN = str(Path(gearcontact_fmu.__file__).resolve().parent)
#: values of the ``initial_state`` parameter (the first is the default)
INITIAL_STATES = ("inputs", "parameters")


class From(NamedTuple):
    """A default taken from the library's parameter dataclasses (``_default_sources``)."""
    source: str
    attribute: str


class Counter(NamedTuple):
    """An output read from the stage when the host asks (no cost per step): ``GearStage.<prop>``."""
    prop: str


class Var(NamedTuple):
    """One FMU variable, declared once: the slave registers it, drivetrain.fmu_build.build and .native_gear read its unit
    and description from here."""
    name: str
    type: str            # Real | Integer | Boolean | String
    causality: str       # PARAMETER (fixed) | INPUT | OUTPUT
    unit: str            # Real only ("1": dimensionless)
    default: Any         # a literal, From(...) or Counter(...)
    description: str
    bounds: tuple = (None, None)   # (min, max): the values the code refuses outside of (modelDescription min/max)


PARAMETER, INPUT, OUTPUT = "parameter", "input", "output"
#: the largest fmi2Integer: a counter saturates there (2**31 - 1 sub-steps: ~6 h at 1e-5 s)
INT_MAX = 2 ** 31 - 1

#: every variable of the FMU, in value-reference order
VARIABLES = (
    Var("fidelity", "String", PARAMETER, "", "analytic",
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
    Var("flange_a_phi", "Real", INPUT, "rad", 0.0,
        "angle of the body connected to flange_a (middle shaft, pinion side)"),
    Var("flange_a_w", "Real", INPUT, "rad/s", 0.0, "speed of the body connected to flange_a"),
    Var("flange_b_phi", "Real", INPUT, "rad", 0.0,
        "angle of the body connected to flange_b (propeller shaft, wheel side)"),
    Var("flange_b_w", "Real", INPUT, "rad/s", 0.0, "speed of the body connected to flange_b"),
    Var("flange_a_tau", "Real", OUTPUT, "N.m", 0.0, "torque applied to the body at flange_a (see output_torque)"),
    Var("flange_b_tau", "Real", OUTPUT, "N.m", 0.0, "torque applied to the body at flange_b (see output_torque)"),
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


def _default_sources() -> dict:
    """The objects ``From`` defaults refer to: the library's defaults, declared there once."""
    from gearcontact_fmu.params import BevelGearParams, MapGrid, MeshResolution, PCMParams
    from gearcontact_fmu.stage import StageParams

    return {"gear": BevelGearParams(), "pcm": PCMParams(), "resolution": MeshResolution(), "stage": StageParams(),
            "grid": MapGrid()}


def parameter_values(given=None) -> dict:
    """Every parameter's value as an instance holds it before anything is set: ``given`` (name -> value)
    where it names a parameter, else the declared default (what ``fmu_parameters.build_mesh_model``
    takes, e.g. for the assembler's start state, drivetrain.run.assemble)."""
    given = given or {}
    sources = _default_sources()
    return {v.name: given[v.name] if v.name in given else
            (getattr(sources[v.default.source], v.default.attribute) if isinstance(v.default, From) else v.default)
            for v in VARIABLES if v.causality == PARAMETER}


_TYPES = {"Real": Real, "Integer": Integer, "Boolean": Boolean, "String": String}
_FIRST_BUILD = [True]       # the first stage build in this process loads or compiles the numba kernels


def _kernels_cached() -> bool:
    """Whether numba's on-disk cache holds the stage's kernels (its index for ``stage._rhs``); without it the
    first build in a process compiles them."""
    try:
        from gearcontact_fmu import stage

        return os.path.exists(stage._rhs._cache._cache_file._index_path)
    except Exception:  # noqa: BLE001 - numba internals: when unsure, say it may compile
        return False


def _announce_first_build(slave) -> None:
    """Log, before the first stage build of the process starts (at fmi2EnterInitializationMode; the build is in
    fmi2ExitInitializationMode), that it loads or compiles the numba kernels (without a cache: tens of seconds in
    which the host sees nothing else; issue 30)."""
    if not _FIRST_BUILD[0]:
        return
    _FIRST_BUILD[0] = False
    if _kernels_cached():
        text = ("GearContact: the first stage of this process is built at exitInitializationMode: it loads the "
                "numba kernels from numba's cache and compiles the stage's integrator (about a second)")
    else:
        text = ("GearContact: the first stage of this process is built at exitInitializationMode and numba has no "
                "cache of its kernels: it compiles them (up to tens of seconds, once: numba caches them for later "
                "processes)")
    slave.log(fmi_text(text), Fmi2Status.ok)


class GearContact(Fmi2Slave):
    description = ("Lower bevel gear stage (15/60, m 3 mm) of the azimuth-thruster rig: pinion and wheel "
                   "inertias, port spring-dampers and the mesh (pcm/table/analytic/ideal), sub-stepped.")
    author = "bevel-drivetrain"
    version = gearcontact_fmu.__version__
    # the shipped example input (documentation/example_input.csv: the rig's 500 rpm point ramped in over 0.25 s)
    # settles well inside it; no tolerance: the stage integrates with fixed sub-steps
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=DEFAULT_COMM_STEP_S)
    can_get_and_set_fmu_state = True   # read by drivetrain.fmu_build.build (canGetAndSetFMUstate)

    # read by drivetrain.fmu_build.build and .native_gear (modelDescription units and descriptions)
    units = {v.name: v.unit for v in VARIABLES if v.unit}
    variable_descriptions = {v.name: v.description for v in VARIABLES}
    bounds = {v.name: v.bounds for v in VARIABLES if v.bounds != (None, None)}          # (min/max)
    # InitialUnknowns: at exit of initialization every output follows the flange inputs (initial_state
    # inputs) and the parameters, but these: 0 whatever they are (no source inside; the sums and counts
    # since t = 0, the smallest sub-step before the first step, the pending coupling work)
    initial_dependencies = {n: [] for n in ("energy_supplied", "energy_dissipated", "n_substeps", "n_refinements",
                                            "n_separations", "separated_time", "min_substep",
                                            "coupling_energy_error")}

    INPUTS = tuple(v.name for v in VARIABLES if v.causality == INPUT)
    # the outputs published after every step
    OUTPUTS = tuple(v.name for v in VARIABLES if v.causality == OUTPUT and v.type == "Real"
                    and not isinstance(v.default, Counter))
    # after a failure: NaN (the state outputs keep the last completed step, see ``error``)
    NAN_ON_FAILURE = tuple(n for n in OUTPUTS if n not in ("pinion_phi", "pinion_w", "wheel_phi", "wheel_w"))
    # stability counters of the stage and the pending coupling mismatch, cumulative since t = 0: read from
    # the stage when the host asks; after a failed do_step they include the failing sub-step
    STABILITY = {v.name: v.default.prop for v in VARIABLES if isinstance(v.default, Counter)}

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        from fmu_runtime.guard import pin_export_library_state

        # pythonfmu 0.7.0 releases its interpreter state twice at process exit: see fmu_runtime.guard
        pin_export_library_state(kwargs, type(self).__name__)
        sources = _default_sources()
        for v in VARIABLES:
            kind = _TYPES[v.type]
            if isinstance(v.default, Counter):
                count = v.type == "Integer"
                extra = {"variability": Fmi2Variability.discrete} if count else {}
                self.register_variable(kind(v.name, causality=Fmi2Causality.output, initial=Fmi2Initial.exact,
                                            getter=(lambda prop=v.default.prop, c=count: self._counter(prop, c)),
                                            **extra))
                continue
            d = v.default
            setattr(self, v.name, getattr(sources[d.source], d.attribute) if isinstance(d, From) else d)
            if v.causality == PARAMETER:
                var = kind(v.name, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed)
                if v.type == "Integer":
                    # an Integer set outside its declared range is refused when set (fmu_runtime.guard)
                    var.min, var.max = v.bounds
                self.register_variable(var)
            elif v.causality == INPUT:
                self.register_variable(kind(v.name, causality=Fmi2Causality.input))
            else:
                extra = {"variability": Fmi2Variability.discrete} if v.type == "String" else {}
                self.register_variable(kind(v.name, causality=Fmi2Causality.output, initial=Fmi2Initial.exact,
                                            **extra))
        self._stage = None
        self._failed = None          # message once the instance is in the error state
        guard_value_references(self, "GearContact", exported="logger" in kwargs)
        self._t0 = 0.0

    # ---- FMI callbacks --------------------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self._t0 = float(start_time)

    def enter_initialization_mode(self):
        # pythonfmu hands the queued messages to the host when a call returns: announced here, the message
        # reaches the log before exitInitializationMode starts the first build
        _announce_first_build(self)

    def exit_initialization_mode(self):
        try:
            self._build()
            self._initialize_stage()
            self._publish()
            self.log(fmi_text(f"GearContact: fidelity {self.fidelity}, mode {self.mode}, scheme "
                              f"{self._stage.scheme}, package {PACKAGE_ORIGIN}"), Fmi2Status.ok)
        except Exception as exc:  # noqa: BLE001 - an exception here would be fmi2Fatal
            self._fail(f"initialization failed: {type(exc).__name__}: {exc}")

    def do_step(self, current_time, step_size):
        if self._failed is not None:
            self.log(fmi_text(f"GearContact is in the error state: {self._failed}"), Fmi2Status.error)
            return False
        try:
            self._stage.step(current_time, step_size, self.flange_a_phi, self.flange_a_w,
                             self.flange_b_phi, self.flange_b_w)
        except Exception as exc:  # noqa: BLE001 - StageError and anything unexpected
            name = "" if type(exc).__name__ == "StageError" else f"{type(exc).__name__}: "
            self._fail(f"do_step at t = {current_time:.9g} s failed: {name}{exc}")
            return False
        self._publish()
        return True

    def _get_fmu_state(self):
        """fmi2GetFMUstate: inputs, outputs, ``error`` and the stage (GearStage.get_state); the
        parameters are fixed after initialization and not part of it."""
        return {"values": {n: getattr(self, n) for n in self.INPUTS + self.OUTPUTS},
                "stage": None if self._stage is None else self._stage.get_state(), "shell": shell_state(self)}

    def _set_fmu_state(self, state):
        """fmi2SetFMUstate: restore a snapshot of this instance; the steps after it repeat bit for bit."""
        for n, v in state["values"].items():
            setattr(self, n, v)
        if state["stage"] is not None:
            self._stage.set_state(state["stage"])
        restore_shell_state(self, state["shell"])

    # ---- helpers ----------------------------------------------------------------------------------
    def _initialize_stage(self):
        """Start the stage (``initial_state``). "inputs": each body at its flange input plus the port
        twist, at the flange speed. "parameters": the bodies at ``pinion_*_start``/``wheel_*_start``,
        the flanges assumed at body - twist with the body speeds (for the outputs at the start time);
        the inputs a host sets before the first doStep are used from then on."""
        how = str(self.initial_state).strip()
        if how not in INITIAL_STATES:
            raise ValueError(f"initial_state = {how!r}: expected one of {' | '.join(INITIAL_STATES)}")
        ta, tb = float(self.twist_a_start), float(self.twist_b_start)
        if how == "inputs":
            a_phi, a_w, b_phi, b_w = self.flange_a_phi, self.flange_a_w, self.flange_b_phi, self.flange_b_w
            self._stage.initialize(self._t0, a_phi, a_w, b_phi, b_w, theta_pinion=a_phi + ta,
                                   theta_wheel=b_phi + tb)
            return
        p_phi, p_w = float(self.pinion_phi_start), float(self.pinion_w_start)
        w_phi, w_w = float(self.wheel_phi_start), float(self.wheel_w_start)
        self._stage.initialize(self._t0, p_phi - ta, p_w, w_phi - tb, w_w, theta_pinion=p_phi,
                               theta_wheel=w_phi, omega_pinion=p_w, omega_wheel=w_w)

    def _counter(self, prop, count=False):
        """A stability counter from the stage; ``count``: an Integer output (saturating at INT_MAX; -1 when
        it cannot be read, the Integer's NaN)."""
        st = self._stage
        if st is None:
            return 0 if count else 0.0
        try:
            v = getattr(st, prop)
            return min(int(v), INT_MAX) if count else float(v)
        except Exception:  # noqa: BLE001 - a getter must never raise into the host
            return -1 if count else float("nan")

    def _fail(self, msg):
        """Enter the error state (fmu_runtime.guard.enter_error_state; NAN_ON_FAILURE become NaN)."""
        enter_error_state(self, msg)

    def _build(self):
        """Build the stage from the parameters (gearcontact_fmu.fmu_parameters.build_stage: the native
        builder, drivetrain.fmu_build.native_gear, takes its contact map from the same translation)."""
        from gearcontact_fmu.fmu_parameters import build_stage

        self._stage = build_stage(self._parameter_values())

    def _parameter_values(self) -> dict:
        """Every parameter's current value, by name."""
        return {v.name: getattr(self, v.name) for v in VARIABLES if v.causality == PARAMETER}

    def _publish(self):
        st = self._stage
        out = st.out.tolist()        # Python floats, one conversion for all (every step: keep it lean)
        self.flange_a_tau = st.tau_a
        self.flange_b_tau = st.tau_b
        self.flange_a_tau_mean = st.tau_a_mean
        self.flange_b_tau_mean = st.tau_b_mean
        self.n_contact = out[OUT_N_CONTACT]
        self.contact_area = out[OUT_CONTACT_AREA]
        self.peak_pressure = out[OUT_PEAK_PRESSURE]
        self.max_penetration = out[OUT_MAX_PENETRATION]
        self.normal_force = out[OUT_NORMAL_FORCE]
        self.elastic_energy = out[OUT_ELASTIC_ENERGY]
        self.mesh_torque_pinion = out[OUT_TAU_PINION]
        self.mesh_torque_wheel = out[OUT_TAU_WHEEL]
        self.mesh_dissipated_power = out[OUT_DISSIPATED_POWER]
        self.pinion_phi = st.theta_pinion
        self.pinion_w = st.omega_pinion
        self.wheel_phi = st.theta_wheel
        self.wheel_w = st.omega_wheel
        self.energy_stored = st.energy_stored
        self.energy_dissipated = st.energy_dissipated
        self.energy_supplied = st.energy_supplied
