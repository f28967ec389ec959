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

The variables (names, types, units, defaults, descriptions, bounds) and the model information (description,
author, version, default experiment, initial dependencies) are declared in the library,
``gearcontact_fmu.fmu_variables``, where a host reads the defaults and the native build the whole declaration
without importing this script.

Package import: the installed ``gearcontact_fmu`` when importable, else the copy bundled in
``resources/_bundled`` (``BEVEL_FMU_USE_BUNDLED=1`` forces the bundled copy).
"""
import importlib.util
import os
import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent
_BUNDLED = _HERE / "_bundled"
_FORCE_BUNDLED = os.environ.get("BEVEL_FMU_USE_BUNDLED", "").strip() not in ("", "0")
if _BUNDLED.is_dir() and (_FORCE_BUNDLED or importlib.util.find_spec("gearcontact_fmu") is None):
    sys.path.insert(0, str(_BUNDLED))

from fmu_runtime import check_runtime  # noqa: E402

check_runtime("GearContact", _HERE)        # a missing package named where the host shows it
import gearcontact_fmu  # noqa: E402
from gearcontact_fmu.mesh_models.base import (OUT_CONTACT_AREA, OUT_DISSIPATED_POWER, OUT_ELASTIC_ENERGY,  # noqa: E402
                                      OUT_MAX_PENETRATION, OUT_N_CONTACT, OUT_NORMAL_FORCE,
                                      OUT_PEAK_PRESSURE, OUT_TAU_PINION, OUT_TAU_WHEEL)
from pythonfmu import Boolean, DefaultExperiment, Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Integer, Real, String  # noqa: E402
from pythonfmu.enums import Fmi2Status  # noqa: E402

from fmu_runtime.guard import enter_error_state, fmi_text, guard_value_references, restore_shell_state, shell_state  # noqa: E402,E501
from gearcontact_fmu import fmu_variables as declared  # noqa: E402
from gearcontact_fmu.fmu_variables import INITIAL_STATES, INPUT, INT_MAX, OUTPUT, PARAMETER, VARIABLES  # noqa: E402

PACKAGE_ORIGIN = str(Path(gearcontact_fmu.__file__).resolve().parent)

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
    # the model information, declared in the library (gearcontact_fmu.fmu_variables: the native build reads it
    # there too); read by drivetrain.fmu_build.build (modelDescription units, descriptions, bounds, InitialUnknowns)
    description = declared.DESCRIPTION
    author = declared.AUTHOR
    version = declared.VERSION
    default_experiment = DefaultExperiment(**declared.DEFAULT_EXPERIMENT._asdict())
    can_get_and_set_fmu_state = True   # read by drivetrain.fmu_build.build (canGetAndSetFMUstate)
    units = declared.UNITS
    variable_descriptions = declared.VARIABLE_DESCRIPTIONS
    bounds = declared.BOUNDS
    initial_dependencies = declared.INITIAL_DEPENDENCIES

    INPUTS = tuple(v.name for v in VARIABLES if v.causality == INPUT)
    OUTPUTS = declared.OUTPUTS                  # published after every step
    NAN_ON_FAILURE = declared.NAN_ON_FAILURE    # after a failure: NaN (fmu_runtime.guard.enter_error_state)
    STABILITY = declared.COUNTERS               # read from the stage when the host asks

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        from fmu_runtime.guard import pin_export_library_state

        # pythonfmu 0.7.0 releases its interpreter state twice at process exit: see fmu_runtime.guard
        pin_export_library_state(kwargs, type(self).__name__)
        for v in declared.declared_variables():
            kind = _TYPES[v.type]
            extra = {} if v.variability is None else {"variability": Fmi2Variability[v.variability]}
            if v.causality == OUTPUT:
                extra["initial"] = Fmi2Initial.exact
            prop = self.STABILITY.get(v.name)
            if prop is not None:
                count = v.type == "Integer"
                self.register_variable(kind(v.name, causality=Fmi2Causality.output,
                                            getter=(lambda prop=prop, c=count: self._counter(prop, c)), **extra))
                continue
            setattr(self, v.name, v.start)
            var = kind(v.name, causality=Fmi2Causality[v.causality], **extra)
            if v.causality == PARAMETER and v.type == "Integer":
                # an Integer set outside its declared range is refused when set (fmu_runtime.guard)
                var.min, var.max = v.min, v.max
            self.register_variable(var)
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
