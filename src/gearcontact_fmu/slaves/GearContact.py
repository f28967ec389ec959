"""GearContact: FMI 2.0 co-simulation FMU of the lower bevel gear stage (pythonfmu slave).

A thin shell over :mod:`gearcontact_fmu.stage`: the mesh model (fidelity pcm/table/analytic/ideal) is
built once in ``exit_initialization_mode`` from the parameters, then every ``do_step`` advances the
stage over the communication step. Both flanges are spring side (ARCHITECTURE.md): inputs
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
from gearcontact_fmu.params import DEFAULT_COMM_STEP_S  # noqa: E402

PACKAGE_ORIGIN = str(Path(gearcontact_fmu.__file__).resolve().parent)
#: values of the ``initial_state`` parameter (the first is the default)
INITIAL_STATES = ("inputs", "parameters")


class GearContact(Fmi2Slave):
    description = ("Lower bevel gear stage (15/60, m 3 mm) of the azimuth-thruster rig: pinion and wheel "
                   "inertias, port spring-dampers and the mesh (pcm/table/analytic/ideal), sub-stepped.")
    author = "bevel-drivetrain"
    version = gearcontact_fmu.__version__
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=DEFAULT_COMM_STEP_S)
    can_get_and_set_fmu_state = True   # read by drivetrain.fmubuild (canGetAndSetFMUstate)

    # units of the variables (read by drivetrain.fmubuild to post-process modelDescription.xml)
    units = {
        "flange_a_phi": "rad", "flange_a_w": "rad/s", "flange_b_phi": "rad", "flange_b_w": "rad/s",
        "flange_a_tau": "N.m", "flange_b_tau": "N.m", "flange_a_tau_mean": "N.m", "flange_b_tau_mean": "N.m",
        "n_contact": "1", "contact_area": "m2", "peak_pressure": "Pa", "max_penetration": "m",
        "normal_force": "N", "elastic_energy": "J", "mesh_torque_pinion": "N.m", "mesh_torque_wheel": "N.m",
        "mesh_dissipated_power": "W",
        "pinion_phi": "rad", "pinion_w": "rad/s", "wheel_phi": "rad", "wheel_w": "rad/s",
        "energy_stored": "J", "energy_dissipated": "J", "energy_supplied": "J", "coupling_energy_error": "J",
        "E": "Pa", "nu": "1", "layer_depth": "m", "c_compression": "N.s/m3", "c_expansion": "N.s/m3",
        "transformation_depth": "m", "mu": "1", "v_friction": "m/s", "u_max": "m",
        "profile_element_size": "m", "face_element_size": "m",
        "J_pinion": "kg.m2", "J_wheel": "kg.m2", "k_a": "N.m/rad", "d_a": "N.m.s/rad", "k_b": "N.m/rad",
        "d_b": "N.m.s/rad", "max_substep": "s",
        "module": "m", "pressure_angle": "rad", "shaft_angle": "rad", "face_width": "m", "x_pinion": "1",
        "addendum_coefficient": "1", "dedendum_coefficient": "1", "backlash": "m", "tip_radius": "m",
        "mesh_damping_ratio": "1", "mesh_phase": "rad", "tooth_compliance": "1",
        "map_points_per_pitch": "1", "map_approach_points": "1",
        "peak_penetration": "m", "min_substep": "s", "n_substeps": "1", "n_refinements": "1",
        "separated_time": "s", "n_separations": "1",
        "pinion_phi_start": "rad", "pinion_w_start": "rad/s", "wheel_phi_start": "rad", "wheel_w_start": "rad/s",
        "twist_a_start": "rad", "twist_b_start": "rad",
    }

    # what every variable means (read by drivetrain.fmubuild: modelDescription descriptions; docs/FMU.md)
    variable_descriptions = {
        "fidelity": "mesh model: pcm (online polygonal contact) | table (precomputed contact map) | analytic "
                    "(ISO 6336 reference) | ideal (rigid, exact ratio, no backlash)",
        "mode": "stage (owns pinion and wheel inertias, sub-steps the mesh) | bare (raw contact torques)",
        "health": "healthy | mild (flank-fracture void) | severe (missing tooth) | faults (the faults list) | mesh "
                  "(the mesh files); all but healthy: pcm/table only",
        "faults": "health faults: JSON list of fault specifications (kind, member, tooth, flank, sizes)",
        "manufacturing_errors": "pitch errors and runout as JSON (ManufacturingErrors.to_dict()); empty = none",
        "pinion_mesh_file": "OBJ/STL surface mesh of the pinion; empty = generated",
        "wheel_mesh_file": "OBJ/STL surface mesh of the wheel; empty = generated",
        "mesh_units": "length unit of the mesh files: mm | m | cm | um | in",
        "scheme": "sub-step integrator: auto | ros2 | rk4",
        "output_torque": "what flange_*_tau carries: predicted | mean | end",
        "initial_state": "where the pinion and wheel start: inputs (the flange inputs at exit of initialization "
                         "plus twist_*_start) | parameters (pinion_*_start, wheel_*_start; for a host that "
                         "passes no values during initialization)",
        "pinion_phi_start": "initial_state parameters: pinion angle at the start time",
        "pinion_w_start": "initial_state parameters: pinion speed at the start time",
        "wheel_phi_start": "initial_state parameters: wheel angle at the start time",
        "wheel_w_start": "initial_state parameters: wheel speed at the start time",
        "twist_a_start": "twist of the flange_a port spring at the start time (pinion angle - flange_a angle)",
        "twist_b_start": "twist of the flange_b port spring at the start time (wheel angle - flange_b angle)",
        "z_pinion": "pinion teeth", "z_wheel": "wheel teeth",
        "friction": "tooth friction in the mesh (false: not evaluated)",
        "contact_damping": "contact damping in the mesh (false: not evaluated)",
        "energy_correction": "energy-conserving correction of flange_*_tau (returns the measured work mismatch "
                             "of each cut over 10 ms)",
        "E": "Young's modulus of the elastic layer", "nu": "Poisson's ratio of the elastic layer",
        "layer_depth": "elastic layer depth of each body",
        "c_compression": "PCM damping while compressing (pressure per penetration velocity)",
        "c_expansion": "PCM damping while expanding",
        "transformation_depth": "penetration over which the damping ramps in",
        "mu": "friction coefficient", "v_friction": "regularisation velocity of friction",
        "u_max": "largest admissible penetration (beyond it the step fails)",
        "profile_element_size": "PCM surface-mesh element size along the tooth profile",
        "face_element_size": "PCM surface-mesh element size along the face width",
        "J_pinion": "pinion-side inertia of the stage", "J_wheel": "wheel-side inertia of the stage",
        "k_a": "stiffness of the flange_a - pinion port spring", "d_a": "damping of the flange_a - pinion port",
        "k_b": "stiffness of the flange_b - wheel port spring", "d_b": "damping of the flange_b - wheel port",
        "max_substep": "largest internal sub-step; sub-steps per communication step = ceil(H / max_substep)",
        "module": "outer transverse module", "pressure_angle": "pressure angle", "shaft_angle": "shaft angle",
        "face_width": "face width", "x_pinion": "pinion profile shift coefficient",
        "addendum_coefficient": "addendum / module", "dedendum_coefficient": "dedendum / module",
        "backlash": "circumferential backlash on the outer pitch circle", "tip_radius": "tip rounding radius",
        "tooth_compliance": "total mesh approach per PCM layer approach (table only; 1 = the layers alone)",
        "map_points_per_pitch": "table: contact-map nodes along the pinion angle per pinion pitch",
        "map_approach_points": "table: contact-map nodes per flank along the approach beyond the contact onset",
        "mesh_damping_ratio": "analytic mesh: damping ratio of the mesh mode",
        "mesh_phase": "analytic mesh: pinion angle at which a drive flank passes the pitch point",
        "flange_a_phi": "angle of the body connected to flange_a (middle shaft, pinion side)",
        "flange_a_w": "speed of the body connected to flange_a",
        "flange_b_phi": "angle of the body connected to flange_b (propeller shaft, wheel side)",
        "flange_b_w": "speed of the body connected to flange_b",
        "flange_a_tau": "torque applied to the body at flange_a (see output_torque)",
        "flange_b_tau": "torque applied to the body at flange_b (see output_torque)",
        "flange_a_tau_mean": "exact mean over the last step of the torque at flange_a",
        "flange_b_tau_mean": "exact mean over the last step of the torque at flange_b",
        "n_contact": "pairs in contact (analytic), contact elements (pcm/table)",
        "contact_area": "contact area", "peak_pressure": "peak contact pressure",
        "max_penetration": "largest penetration", "normal_force": "total normal force",
        "elastic_energy": "energy in the mesh compliance",
        "mesh_torque_pinion": "mesh torque on the pinion at the step end",
        "mesh_torque_wheel": "mesh torque on the wheel at the step end",
        "mesh_dissipated_power": "mesh damping and friction power",
        "pinion_phi": "pinion angle", "pinion_w": "pinion speed", "wheel_phi": "wheel angle", "wheel_w": "wheel speed",
        "energy_stored": "kinetic, port-spring and mesh elastic energy",
        "energy_dissipated": "energy dissipated since t = 0 (port dampers, mesh damping and friction)",
        "energy_supplied": "always 0 (no sources inside)",
        "peak_penetration": "stability counter: largest element penetration since t = 0",
        "min_substep": "stability counter: smallest accepted sub-step since t = 0",
        "n_substeps": "stability counter: accepted sub-steps since t = 0",
        "n_refinements": "stability counter: sub-step halvings since t = 0",
        "separated_time": "stability counter: time out of contact since t = 0",
        "n_separations": "stability counter: contact-loss events since t = 0",
        "coupling_energy_error": "work mismatch of the two flange cuts since t = 0 not yet corrected",
        "error": "empty while the instance works; after a failure, why it failed (then the torque, mesh and "
                 "energy outputs are NaN; pinion/wheel keep the last completed step, the counters include "
                 "the failing sub-step)",
    }

    INPUTS = ("flange_a_phi", "flange_a_w", "flange_b_phi", "flange_b_w")
    OUTPUTS = ("flange_a_tau", "flange_b_tau", "flange_a_tau_mean", "flange_b_tau_mean",
               "n_contact", "contact_area", "peak_pressure", "max_penetration", "normal_force",
               "elastic_energy", "mesh_torque_pinion", "mesh_torque_wheel", "mesh_dissipated_power",
               "pinion_phi", "pinion_w", "wheel_phi", "wheel_w",
               "energy_stored", "energy_dissipated", "energy_supplied")
    # after a failure: NaN (the state outputs keep the last completed step, see ``error``)
    NAN_ON_FAILURE = tuple(n for n in OUTPUTS if n not in ("pinion_phi", "pinion_w", "wheel_phi", "wheel_w"))
    # stability counters of the stage and the pending coupling mismatch, cumulative since t = 0: read from
    # the stage when the host asks (no cost per step); after a failed do_step they include the failing sub-step
    STABILITY = {"peak_penetration": "peak_penetration", "min_substep": "min_substep",
                 "n_substeps": "n_substeps_total", "n_refinements": "n_refinements",
                 "separated_time": "separated_time", "n_separations": "n_separations",
                 "coupling_energy_error": "coupling_energy_error"}

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        from fmu_runtime.guard import pin_export_library_state

        # pythonfmu 0.7.0 releases its interpreter state twice at process exit: see fmu_runtime.guard
        pin_export_library_state(kwargs, type(self).__name__)
        from gearcontact_fmu.params import BevelGearParams, MapGrid, MeshResolution, PCMParams
        from gearcontact_fmu.stage import StageParams

        g, p, r, s = BevelGearParams(), PCMParams(), MeshResolution(), StageParams()
        # structural choices (strings)
        self.fidelity = "analytic"
        self.mode = s.mode
        self.health = "healthy"
        self.faults = "[]"          # health "faults": JSON list of fault specifications (faults.FAULT_KINDS)
        self.manufacturing_errors = ""   # JSON of manufacturing_specs.ManufacturingErrors ("" = none)
        self.tooth_compliance = 1.0      # series factor of the table map's approach (1 = the PCM layers alone)
        grid = MapGrid()                 # the table's contact-map grid
        self.map_points_per_pitch, self.map_approach_points = grid.points_per_pitch, grid.s_points
        self.pinion_mesh_file = ""
        self.wheel_mesh_file = ""
        self.mesh_units = "mm"
        self.scheme = s.scheme
        self.output_torque = s.output_torque
        # the initial state of pinion and wheel (INITIAL_STATES; docs/FMU.md "Initialization")
        self.initial_state = INITIAL_STATES[0]
        self.pinion_phi_start = self.pinion_w_start = self.wheel_phi_start = self.wheel_w_start = 0.0
        self.twist_a_start = self.twist_b_start = 0.0
        # PCM constants (RIG.md)
        self.E, self.nu, self.layer_depth = p.E, p.nu, p.layer_depth
        self.c_compression, self.c_expansion = p.c_compression, p.c_expansion
        self.transformation_depth, self.mu, self.v_friction, self.u_max = (
            p.transformation_depth, p.mu, p.v_friction, p.u_max)
        # resolution
        self.profile_element_size, self.face_element_size = r.profile, r.face
        # stage
        self.J_pinion, self.J_wheel = s.J_pinion, s.J_wheel
        self.k_a, self.d_a, self.k_b, self.d_b = s.k_a, s.d_a, s.k_b, s.d_b
        self.max_substep = s.max_substep
        # gear
        self.z_pinion, self.z_wheel = g.z_pinion, g.z_wheel
        self.module, self.pressure_angle, self.shaft_angle = g.module, g.pressure_angle, g.shaft_angle
        self.face_width, self.x_pinion = g.face_width, g.x_pinion
        self.addendum_coefficient, self.dedendum_coefficient = g.addendum_coefficient, g.dedendum_coefficient
        self.backlash, self.tip_radius = g.backlash, g.tip_radius
        # effects: switched off, they are not evaluated at all (and the contact map is shared)
        self.friction = True
        self.contact_damping = True
        # coupling: energy-conserving correction of the flange torques (gearcontact_fmu.coupling)
        self.energy_correction = s.energy_correction
        # analytic mesh
        self.mesh_damping_ratio = 0.05
        self.mesh_phase = 0.0
        for name in self.INPUTS + self.OUTPUTS:
            setattr(self, name, 0.0)

        P, F = Fmi2Causality.parameter, Fmi2Variability.fixed
        for name in ("fidelity", "mode", "health", "faults", "manufacturing_errors", "pinion_mesh_file",
                     "wheel_mesh_file", "mesh_units", "scheme", "output_torque", "initial_state"):
            self.register_variable(String(name, causality=P, variability=F))
        for name in ("z_pinion", "z_wheel", "map_points_per_pitch", "map_approach_points"):
            self.register_variable(Integer(name, causality=P, variability=F))
        for name in ("friction", "contact_damping", "energy_correction"):
            self.register_variable(Boolean(name, causality=P, variability=F))
        for name in ("E", "nu", "layer_depth", "c_compression", "c_expansion", "transformation_depth", "mu",
                     "v_friction", "u_max", "profile_element_size", "face_element_size",
                     "J_pinion", "J_wheel", "k_a", "d_a", "k_b", "d_b", "max_substep",
                     "module", "pressure_angle", "shaft_angle", "face_width", "x_pinion",
                     "addendum_coefficient", "dedendum_coefficient", "backlash", "tip_radius", "tooth_compliance",
                     "mesh_damping_ratio", "mesh_phase", "pinion_phi_start", "pinion_w_start",
                     "wheel_phi_start", "wheel_w_start", "twist_a_start", "twist_b_start"):
            self.register_variable(Real(name, causality=P, variability=F))
        for name in self.INPUTS:
            self.register_variable(Real(name, causality=Fmi2Causality.input))
        for name in self.OUTPUTS:
            self.register_variable(Real(name, causality=Fmi2Causality.output, initial=Fmi2Initial.exact))
        self.error = ""
        self.register_variable(String("error", causality=Fmi2Causality.output,
                                      variability=Fmi2Variability.discrete, initial=Fmi2Initial.exact))
        for name, prop in self.STABILITY.items():
            self.register_variable(Real(name, causality=Fmi2Causality.output, initial=Fmi2Initial.exact,
                                        getter=(lambda prop=prop: self._counter(prop))))

        self._stage = None
        self._failed = None          # message once the instance is in the error state
        guard_value_references(self, "GearContact")
        self._t0 = 0.0

    # ---- FMI callbacks --------------------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        self._t0 = float(start_time)

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

    def _counter(self, prop):
        st = self._stage
        if st is None:
            return 0.0
        try:
            return float(getattr(st, prop))
        except Exception:  # noqa: BLE001 - a getter must never raise into the host
            return float("nan")

    def _fail(self, msg):
        """Enter the error state (fmu_runtime.guard.enter_error_state; NAN_ON_FAILURE become NaN)."""
        enter_error_state(self, msg)

    def _build(self):
        from gearcontact_fmu.params import BevelGearParams, MapGrid, MeshResolution, PCMParams
        from gearcontact_fmu.stage import StageParams, make_stage

        gear = BevelGearParams(
            z_pinion=int(self.z_pinion), z_wheel=int(self.z_wheel), module=self.module,
            pressure_angle=self.pressure_angle, shaft_angle=self.shaft_angle, face_width=self.face_width,
            x_pinion=self.x_pinion, addendum_coefficient=self.addendum_coefficient,
            dedendum_coefficient=self.dedendum_coefficient, backlash=self.backlash,
            tip_radius=self.tip_radius)
        pcm = PCMParams(E=self.E, nu=self.nu, layer_depth=self.layer_depth, c_compression=self.c_compression,
                        c_expansion=self.c_expansion, transformation_depth=self.transformation_depth,
                        mu=self.mu, v_friction=self.v_friction, u_max=self.u_max)
        res = MeshResolution(profile=self.profile_element_size, face=self.face_element_size)
        sp = StageParams(J_pinion=self.J_pinion, J_wheel=self.J_wheel, k_a=self.k_a, d_a=self.d_a,
                         k_b=self.k_b, d_b=self.d_b, max_substep=self.max_substep, scheme=self.scheme,
                         mode=self.mode, output_torque=self.output_torque,
                         energy_correction=bool(self.energy_correction))
        mesh_files = {k: v for k, v in (("pinion", self.pinion_mesh_file), ("wheel", self.wheel_mesh_file)) if v}
        kw = {}
        fidelity = self.fidelity.strip().lower()
        friction, damping = bool(self.friction), bool(self.contact_damping)
        if fidelity == "analytic":
            # the analytic reference takes its friction from mu (the PCM constant) as well
            kw = dict(damping_ratio=self.mesh_damping_ratio if damping else 0.0, mesh_phase=self.mesh_phase,
                      mu=self.mu if friction else 0.0)
        elif fidelity in ("pcm", "table"):
            kw = dict(friction=friction, damping=damping, mesh_units=str(self.mesh_units).strip(),
                      faults=self._fault_specs())
            if fidelity == "table":
                kw["grid"] = MapGrid(points_per_pitch=int(self.map_points_per_pitch),
                                     s_points=int(self.map_approach_points))
        if float(self.tooth_compliance) != 1.0:          # table only: pcm and ideal refuse it
            kw["tooth_compliance"] = float(self.tooth_compliance)
        if str(self.manufacturing_errors).strip():      # the ideal mesh refuses them (no mesh coordinate)
            kw["manufacturing_errors"] = str(self.manufacturing_errors)
        self._stage = make_stage(self.fidelity, gear, pcm, res, health=self.health,
                                 mesh_files=mesh_files or None, stage_params=sp, **kw)

    def _fault_specs(self) -> list:
        """The ``faults`` parameter (JSON), checked: every problem named at once."""
        import json

        from gearcontact_fmu.fault_specs import fault_spec_problems

        try:
            specs = json.loads(str(self.faults) or "[]")
        except ValueError as exc:
            raise ValueError(f"parameter faults is not JSON ({exc})") from None
        if not isinstance(specs, list):
            raise ValueError("parameter faults must be a JSON list of fault specifications")
        problems = [f"faults[{i}].{k} = {v!r}: expected {e}" for i, spec in enumerate(specs)
                    for k, v, e in fault_spec_problems(spec, int(self.z_pinion), int(self.z_wheel))]
        if problems:
            raise ValueError("; ".join(problems))
        if str(self.health).strip() == "faults" and not specs:
            raise ValueError('health = "faults" needs at least one fault in the faults parameter')
        return specs

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
