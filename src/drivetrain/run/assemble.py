"""The assembler: a resolved Scene -> the SystemSpec the master runs (docs/DRIVETRAIN.md).

Only what the scene needs is instantiated:

| effects | FMUs |
|---|---|
| shaft_flexibility = "flexible" | motors (MotorLoad), drive_shaft (FlexibleShaft, ``shaft_elements``), upper (UpperTransmission), gear (GearContact) |
| shaft_flexibility = "rigid" | motors, upper, gear: no shaft FMU |
| mesh_contact = "ideal" | gear with fidelity "ideal": a rigid ratio, no contact engine |

The parameters come from :func:`drivetrain.rig.data.partition` (the lumped public model, the calibrated
coupling stiffness and losses); every cut is checked by :func:`drivetrain.models.stability.check_cuts` before the
spec is returned (an unstable cut is refused with the numbers). The initial state is the steady state
at the initial speed and load (every spring pre-twisted, the gear's port springs and mesh included;
the PI integrator pre-loaded; the mesh at the static deflection of its own model), so a constant-speed
scene starts at its operating point (first 50 ms within 0.1 % of the steady torques on the example scene).

``metadata``: ``sensors`` (rig sensor -> "component.variable"), ``characteristic`` (frequencies from
the final drive speed), ``fidelity`` (component -> fidelity), ``partition`` (bodies and cuts),
``cuts`` (the stability report of every cut), ``steady_state``, ``calibration``, ``mesh_start`` (how the
mesh's start deflection was found: :func:`start_mesh_model`).
"""
from __future__ import annotations

import copy
import dataclasses
import functools
import json
import math

import numpy as np

from drivetrain.rig import background
from drivetrain.rig import data as rig

from drivetrain.models import stability
from drivetrain.models.components import COMPONENTS, make_component
from drivetrain.models.parameters import params_from
from drivetrain.models.shaft import FlexibleShaft, FlexibleShaftParams
from drivetrain.rig.signals import characteristic_frequencies
from drivetrain.errors import NativeBuildError, ScenarioError, StartStateError
from drivetrain.system import ComponentSpec, Connection, SystemSpec
from gearcontact_fmu.fmu_variables import gear_pair, parameter_values
from gearcontact_fmu.manufacturing_specs import draw_errors, errors_of
from gearcontact_fmu.mesh_models import DEFAULT_FIDELITY
from gearcontact_fmu.params import GEAR_MODEL, BevelGearParams

#: Sensor variables per configuration (docs/DRIVETRAIN.md, "Sensors").
SENSORS_COMMON = {
    "propeller_shaft_torque": "gear.flange_b_tau_mean",
    "enc1": "motors.motor_phi",
    "enc2": "upper.flange_a_phi",
    "enc3": "upper.flange_b_phi",
    "enc4": "gear.pinion_phi",
    "enc5": "gear.wheel_phi",
}


def sensor_map(shafts: str) -> dict:
    m = {"drive_shaft_torque": "drive_shaft.torque_sensor" if shafts == "flexible" else "upper.torque_sensor"}
    m.update(SENSORS_COMMON)
    return m


def manufacturing_errors(scene, gear: BevelGearParams | None = None):
    """The scene's drawn manufacturing errors (manufacturing_specs.ManufacturingErrors), or None when
    ``effects.manufacturing_errors`` is off. Deterministic in ``manufacturing.seed``."""
    if not scene.effects.manufacturing_errors:
        return None
    m = scene.manufacturing
    return draw_errors(gear or scene.gear.pair.params(), grade=m.grade, seed=m.seed, single_pitch_um=m.single_pitch_um,
                       runout_um=m.runout_um, members=tuple(m.members),
                       runout_grade=m.runout_grade, profile=bool(m.profile_errors), profile_um=m.profile_um)


# ---- the scene's gear pair ([gear.pair]) as GearContact parameters -------------------------------------------
#: the GearContact parameters the pair sets: BevelGearParams' fields and the elastic layer's (same names)
PAIR_LAYER_FIELDS = ("E", "nu", "layer_depth")


def pair_parameters(scene) -> dict:
    """The GearContact parameters of the scene's ``[gear.pair]`` that differ from the FMU's declared defaults
    (the rig's pair: none, so its assembled system is as it was)."""
    pair = scene.gear.pair
    values = {f.name: getattr(pair.params(), f.name) for f in dataclasses.fields(BevelGearParams)}
    values.update({k: getattr(pair.pcm(), k) for k in PAIR_LAYER_FIELDS})
    declared = parameter_values()
    return {k: v for k, v in values.items() if v != declared[k]}


def _gear_parameters(scene, part: rig.Partition, max_substep: float) -> dict:
    eff = scene.effects
    pcm = scene.gear.pair.pcm()
    p = dict(part.params["gear"])
    p.update(pair_parameters(scene))
    p.update(fidelity=eff.mesh_contact, health=scene.gear.health, max_substep=float(max_substep),
             profile_element_size=scene.numerics.profile_element_mm * 1e-3,
             face_element_size=scene.numerics.face_element_mm * 1e-3,
             map_points_per_pitch=int(scene.numerics.map_points_per_pitch),
             map_approach_points=int(scene.numerics.map_approach_points),
             scheme=scene.numerics.mesh_integrator,
             energy_correction=bool(scene.numerics.energy_correction))
    if scene.gear.faults:
        p["faults"] = json.dumps([dict(f) for f in scene.gear.faults])
    if eff.tooth_compliance and eff.mesh_contact == "table":      # the analytic pair has it already
        p["tooth_compliance"] = float(scene.tooth_compliance.factor)
    errors = manufacturing_errors(scene, gear_pair(p))
    if errors is not None:
        p["manufacturing_errors"] = json.dumps(errors.to_dict())
    if scene.gear.pinion_mesh is not None:
        p["pinion_mesh_file"] = str(scene.gear.pinion_mesh)
    if scene.gear.wheel_mesh is not None:
        p["wheel_mesh_file"] = str(scene.gear.wheel_mesh)
    if scene.gear.pinion_mesh is not None or scene.gear.wheel_mesh is not None:
        p["mesh_units"] = scene.gear.mesh_units
    # effects switched off are not evaluated (the flags reach the mesh model; the contact map is the
    # same, so no new map is built for a scene without friction or damping)
    p["friction"] = bool(eff.friction)
    p["contact_damping"] = bool(eff.contact_damping)
    p.setdefault("c_compression", pcm.c_compression)
    return p


def initial_mesh_deflection(T_msh: float, fidelity: str, gear: BevelGearParams | None = None) -> float:
    """Pinion-referred mesh coordinate s = theta_p - (z2/z1) theta_w of the loaded flank at the steady
    middle-shaft torque (drive flank backlash/2 + T/K_mean; a reversed load, T < 0, loads the coast
    flank: -backlash/2 + T/K_mean); 0 for the ideal gear. The analytic estimate: it brackets the search for
    the mesh model's own static deflection (:func:`start_mesh_model`) and is the start when there is no
    model to search (``metadata["mesh_start"]``); ``gear``: the pair (default the rig's)."""
    if fidelity == "ideal":
        return 0.0
    try:
        from gearcontact_fmu.mesh_models.analytic import mesh_stiffness
        from gearcontact_fmu.params import backlash_angle

        g = gear or BevelGearParams()
        half = 0.5 * float(backlash_angle(g))
        return (half if T_msh >= 0.0 else -half) + T_msh / float(mesh_stiffness(g)["K_mean"])
    except Exception:  # pragma: no cover - the gear package decides; a start-up transient only
        return 0.0


#: ``metadata["mesh_start"]`` when the mesh starts at the analytic guess because the table map is not cached
#: yet (drivetrain.run.runner recomputes the start once its contact checks have passed: :func:`start_with_map`)
MESH_START_GUESS = "guess: contact map not cached"


MESH_START_PCM_GUESS = "guess: no shipped contact map of this pcm geometry"


def gearbox_name(scene) -> str:
    """Which gearbox a scene runs, in the words of its keys: the nominal one, or the manufacturing draw."""
    if not scene.effects.manufacturing_errors:
        return "the nominal gearbox (effects.manufacturing_errors = false)"
    return f"the gearbox of manufacturing.seed = {scene.manufacturing.seed}"


def start_mesh_model(gear: dict, build_map: bool = False):
    """(the mesh model whose static deflection the gear starts at, how the start was found): the model the
    GearContact FMU builds from these parameters (``fmu_parameters.build_mesh_model``'s translation over
    the FMU's declared defaults, ``gearcontact_fmu.fmu_variables.parameter_values``). A table map is taken from the cache or the shipped maps only, unless
    ``build_map`` (the cost checks come after the assembly; past them the runner recomputes the start with
    ``build_map``: :func:`start_with_map`). ``pcm`` starts at its shipped table map, the same contact law tabulated
    (building the online pair costs seconds, its first evaluation a compile; only a shipped map, so the
    start does not depend on what a cache holds). (None, reason) for the ideal gear (no mesh
    coordinate) and when there is no map to use."""
    fidelity = str(gear.get("fidelity", DEFAULT_FIDELITY)).strip().lower()
    if fidelity == "ideal":
        return None, "rigid"
    from gearcontact_fmu.fmu_parameters import stage_arguments
    from gearcontact_fmu.fmu_variables import parameter_values
    from gearcontact_fmu.stage import stage_mesh_model

    args, kw = stage_arguments(parameter_values({**gear, "fidelity": "table" if fidelity == "pcm" else fidelity}))
    if fidelity in ("table", "pcm"):
        kw["build"] = "shipped" if fidelity == "pcm" else bool(build_map)
    try:
        return stage_mesh_model(*args, **kw), f"balanced on the {'table' if fidelity == 'pcm' else fidelity} model"
    except LookupError:
        return None, MESH_START_PCM_GUESS if fidelity == "pcm" else MESH_START_GUESS


def start_wheel_angle(gear: dict, ss, theta_p: float, errors, build_map: bool = False) -> tuple[float, str]:
    """(the wheel's start angle, how it was found: ``metadata["mesh_start"]``): the mesh at the static
    deflection of its own model (:func:`start_mesh_model`), where it puts the port spring's steady torque
    on the pinion at ``theta_p`` (errors and friction at the start speeds included); the analytic guess
    :func:`initial_mesh_deflection` brackets the search, and is the start when there is no model to search
    or no load (every position inside the backlash balances: the drive flank's onset, as always)."""
    fidelity = str(gear.get("fidelity", DEFAULT_FIDELITY)).strip().lower()
    pair = gear_pair(gear)
    s0 = initial_mesh_deflection(ss.T_msh, fidelity, pair)
    model, how = start_mesh_model(gear, build_map)
    if ss.T_msh == 0.0:
        model, how = None, "unloaded: at the drive flank's onset"
    if model is not None:
        from gearcontact_fmu.mesh_statics import StartStateError as NoPosition
        from gearcontact_fmu.mesh_statics import balanced_wheel_angle

        k_a = float(gear["k_a"])
        tau_port = k_a * (-ss.T_msh / k_a)             # the port spring's torque on the pinion, as twisted
        try:
            return balanced_wheel_angle(model, pair.ratio, theta_p, tau_port, ss.w_middle, ss.w_prop,
                                        s_guess=s0), how
        except NoPosition as exc:
            raise StartStateError(str(exc)) from exc
    theta_w = (theta_p - s0) / pair.ratio
    if errors is not None:
        # the errors offset the mesh coordinate by Delta(theta_p, theta_w): start where the offset mesh sits at s0
        from gearcontact_fmu.manufacturing import mesh_offset

        theta_w += mesh_offset(errors, theta_p, theta_w, pair) / pair.ratio
    return theta_w, how


#: Internal sub-step of the linear components [s] (implicit midpoint: A-stable; 1e-5 s resolves their
#: in-band modes, < 1.5 kHz, to better than 0.1 % in frequency). ``numerics.max_substep_s`` of the scene
#: is the gear stage's sub-step (the stiff mesh needs it); the components use the smaller of this and H.
COMPONENT_SUBSTEP = 1e-5


def _check_start_finite(scene, ss, angles: dict) -> None:
    """The steady start state at the scene's initial operating point must be finite numbers: a drive speed so
    large that the start state overflows (w0 = inf, the loss torques, the twists) is a scene error naming the
    operating point's keys, before any component is built."""
    values = {**{f"{k} [{'rad/s' if k.startswith('w') else 'N m'}]": v for k, v in dataclasses.asdict(ss).items()},
              **{f"{k} [rad]": v for k, v in angles.items()}}
    bad = [f"{k} = {v:g}" for k, v in values.items() if not math.isfinite(v)]
    if not bad:
        return
    op = scene.operating_point
    if not math.isfinite(ss.w_drive):           # the speed overflows: the speed's key
        key, value, what = (("operating_point.speed_profile_rpm", op.speed_profile_rpm, "speed") if op.speed_profile_rpm
                            else ("operating_point.drive_speed_rpm", op.drive_speed_rpm, "speed"))
    else:                                       # a finite speed: the load's torques (or both together) overflow
        key, value, what = (("operating_point.load_profile_Nm", op.load_profile_Nm, "load") if op.load_profile_Nm
                            else ("operating_point.load_torque_Nm", op.load_torque_Nm, "load"))
    raise ScenarioError([(key, value, f"a {what} whose steady start state is finite (with this one it overflows: "
                          + ", ".join(bad[:4]) + ")")], source=scene.name)


def assemble(scene, calibration: dict | str | None = None, check: bool = True,
             component_substep: float | None = None, build_map: bool = False) -> SystemSpec:
    """Build the SystemSpec for a resolved Scene.

    ``calibration``: a calibration dict or a JSON file written by ``drivetrain calibrate`` (default:
    $DRIVETRAIN_CALIBRATION, else the shipped ``drivetrain/data/calibration.json``). ``check``: refuse
    unstable cuts (before any step) with :class:`drivetrain.errors.ConfigurationError`.
    ``component_substep``: internal sub-step of MotorLoad, FlexibleShaft and UpperTransmission
    (default min(COMPONENT_SUBSTEP, H); the gear stage uses ``numerics.max_substep_s``). ``build_map``: build
    a table gear's contact map when it is not cached, to start the mesh at its deflection (the runner, after
    its cost checks); otherwise such a gear starts at the analytic guess (``metadata["mesh_start"]``)."""
    eff = scene.effects
    num = scene.numerics
    op = scene.operating_point
    cal = calibration if isinstance(calibration, dict) else rig.load_calibration(calibration)
    if eff.couplings == "record":
        cal = dict(cal, coupling_scale=float(scene.background.coupling_stiffness_scale))
    elif scene.drivetrain.coupling_scale is not None:
        cal = dict(cal, coupling_scale=float(scene.drivetrain.coupling_scale))
    model = machine_model(scene)      # a named table's bevel element is the scene's pair (the rig's own: the rig's)
    part = rig.partition(eff.shaft_flexibility, eff.shaft_elements, cal, losses=eff.losses, model=model,
                         lower_ratio=None if model is None else scene.gear.pair.params().ratio)
    if eff.couplings == "record":
        record_couplings(part, scene.background)
    H = float(num.comm_step_s)
    sub = float(num.max_substep_s)
    csub = float(component_substep) if component_substep else min(COMPONENT_SUBSTEP, H)

    # ---- steady state at the initial operating point -------------------------------------------
    n0 = float(op.speed_at(0.0))
    T0 = float(op.load_at(0.0))
    up = dict(part.params["upper"])
    mo = dict(part.params["motors"])
    mo.update(drive_load_parameters(scene))
    if eff.drive_control == "record":
        mo.update(Kp=float(scene.background.drive_Kp), Ti=float(scene.background.drive_Ti_s))
    pair = scene.gear.pair.params()
    w_p0 = rig.rpm_to_rad_s(n0) / up["ratio"] / pair.ratio      # the viscous law equals the setting here
    ss = rig.steady_state(n0, T0, up, mo, load_mode=mo["load_mode"], load_w_nom=w_p0 if w_p0 > 0 else 1.0,
                          lower_ratio=pair.ratio)
    w = ss.w_drive
    th_motor = 0.0
    th_fw = th_motor - ss.T_dsh / mo["k_c1"]
    th_next = th_fw - ss.T_dsh / mo["k_c2"]          # hub A of the drive shaft, or the upper gearbox
    _check_start_finite(scene, ss, {"drive-shaft hub angle": th_next})
    comps = []
    if eff.shaft_flexibility == "flexible":
        ds = dict(part.params["drive_shaft"])
        ds.update(n_elements=int(eff.shaft_elements), max_substep=csub, phi0=th_next, w0=w, tau0=ss.T_dsh,
                  energy_correction=bool(num.energy_correction))
        fs = FlexibleShaft(params_from(FlexibleShaftParams, ds))
        th_ut = th_next - ss.T_dsh * fs.compliance_to_port()
        comps.append(("drive_shaft", "FlexibleShaft", ds))
    else:
        th_ut = th_next
    up.update(max_substep=csub, phi0=th_ut, w0=w)
    phi_a = th_ut / up["ratio"]
    gear = _gear_parameters(scene, part, sub)
    # the stage's port springs carry the steady through torques from the start: the pinion lags the
    # body at flange_a by T_msh / k_a (the stage resists the drive), the wheel leads the propeller
    # body by T_psh / k_b; the mesh sits at its own static deflection between them (start_wheel_angle)
    twist_a, twist_b = -ss.T_msh / float(gear["k_a"]), ss.T_psh / float(gear["k_b"])
    theta_p = phi_a + twist_a
    # the gear's manufacturing errors, read once from its parameter (the JSON the FMU receives)
    errors = errors_of(gear.get("manufacturing_errors"))
    theta_w, mesh_start = _start_wheel(scene, gear, ss, theta_p, errors, build_map)
    phi_b = theta_w - twist_b
    gear.update(twist_a_start=twist_a, twist_b_start=twist_b)
    mo.update(max_substep=csub, energy_correction=bool(num.energy_correction), phi0_motor=th_motor, w0=w,
              tau0=ss.T_dsh, phi0_load=phi_b, w0_load=ss.w_prop,
              load_w_nom=ss.w_prop if ss.w_prop > 0 else 1.0)

    inputs = {}
    inputs["speed_ref_rpm"] = ([list(p) for p in op.speed_profile_rpm] if op.speed_profile_rpm
                               else float(op.drive_speed_rpm))
    inputs["load_torque"] = ([list(p) for p in op.load_profile_Nm] if op.load_profile_Nm
                             else float(op.load_torque_Nm))
    inputs.update(background_inputs(scene, H, float(mo.get("ratio_pg", rig.PG_RATIO))))
    components = [ComponentSpec("motors", "MotorLoad", mo, inputs)]
    for name, model, params in comps:
        components.append(ComponentSpec(name, model, params))
    components.append(ComponentSpec("upper", "UpperTransmission", up))
    components.append(ComponentSpec("gear", GEAR_MODEL, gear))
    connections = [Connection(s, i) for s, i in part.connections]
    gear.update(gear_start_state(components, connections, "gear"))

    meta = {
        "sensors": sensor_map(eff.shaft_flexibility),
        "characteristic": characteristic_frequencies(op.final_speed_rpm, pair.z_pinion, pair.z_wheel,
                                                     upper_ratio=up["ratio"]),
        "fidelity": {"gear": eff.mesh_contact},
        "partition": {"shafts": part.shafts, "n_elements": part.n_elements if part.shafts == "flexible" else 0,
                      "bodies": part.bodies,
                      "cuts": [{k: v for k, v in c.items()} for c in part.cuts]},
        "steady_state": dataclasses.asdict(ss),
        "manufacturing_errors": errors.to_dict() if errors is not None else None,
        "calibration": part.calibration,
        "fmus": [c.model for c in components],
        "mesh_start": mesh_start,
        "substeps": {"gear": sub, "components": csub},
        "warnings": [],
    }
    spec = SystemSpec(components, connections, H, meta)
    if check:
        _check_cuts(spec)
    return spec


# ---- the machine: its lumped table and its drive and load settings ([drivetrain], issue 42) ----------------

def machine_model(scene) -> rig.PublicModel | None:
    """The lumped model the scene names (``drivetrain.parameters``, read checked), None: the rig's. The coupling
    factor (``drivetrain.coupling_scale``) scales the rig layout's elastomer couplings: refused for another chain."""
    path = scene.drivetrain.parameters
    model = None if path is None else rig.load_public(path)
    if model is not None and len(model.J) != rig.RIG_LAYOUT_NODES and scene.drivetrain.coupling_scale is not None:
        raise ScenarioError([("drivetrain.coupling_scale", scene.drivetrain.coupling_scale, (
            f"no coupling factor with a table of {len(model.J)} nodes (it scales the rig layout's elastomer couplings, "
            "elements 3-7; another chain's stiffnesses are taken as written)"))], source=scene.name)
    return model


def machine_upper_ratio(scene) -> float:
    """The upper gearbox's ratio of the scene's machine (the rig's UPPER_RATIO unless its table says otherwise)."""
    model = machine_model(scene)
    return rig.UPPER_RATIO if model is None else float(1 / rig.tooth_ratio(model.ratio[rig.GEAR_ELEMENT_UPPER - 1]))


def drive_load_parameters(scene) -> dict:
    """MotorLoad's parameters of the scene's drive and load settings (``[drivetrain]``; the rig's by default)."""
    d = scene.drivetrain
    return dict(Kp=float(d.drive_Kp), Ti=float(d.drive_Ti_s), Ni=float(d.drive_Ni), tau_max=float(d.drive_torque_limit_Nm),
                load_mode=rig.LOAD_LAWS.index(d.load_law), load_w_reg=float(d.load_w_reg_rad_s),
                ratio_pg=float(d.load_gear_ratio), J_load_motor=float(d.load_motor_J_kgm2))


def _start_wheel(scene, gear: dict, ss, theta_p: float, errors, build_map: bool) -> tuple[float, str]:
    """:func:`start_wheel_angle` for ``scene``'s gear; a StartStateError names the scene and gearbox."""
    try:
        with np.errstate(all="ignore"):     # an overflow is the StartStateError's to name, not a printed warning
            return start_wheel_angle(gear, ss, theta_p, errors, build_map)
    except StartStateError as exc:          # no mesh position carries the start load: say which scene and gearbox
        n0, T0 = float(scene.operating_point.speed_at(0.0)), float(scene.operating_point.load_at(0.0))
        raise StartStateError(f"{scene.name}: {gearbox_name(scene)} at {n0:g} rpm and {T0:g} N m: "
                              f"{'; '.join(exc.problems)}") from exc


def _check_cuts(spec: SystemSpec) -> None:
    """Refuse unstable cuts (ConfigurationError with the reports); the reports into ``spec.metadata``. The
    whole linearised system is checked at its start and at every other speed of its drive speed profile
    (:func:`speeds_to_check`): its small-signal losses damp less the faster it runs, so a start at standstill
    says little of the top of a ramp."""
    from drivetrain.cosim import ConfigurationError
    from drivetrain.models import eigen

    try:
        reports, rho = stability.check_cuts(spec)
    except stability.UnstableCutError as exc:
        err = ConfigurationError(exc.problems)
        err.reports = exc.reports
        raise err from None
    at_speeds = {}
    for rpm in speeds_to_check(spec):
        r = eigen.cosim_radius(spec_at_speed(spec, rpm))
        at_speeds[f"{rpm:g}"] = r
        if r > 1.0 + 1e-9:
            err = ConfigurationError([
                f"the whole co-simulated system is unstable at H = {spec.comm_step:.6g} s at {rpm:g} rpm, a speed of "
                f"its drive speed profile (operating_point.speed_profile_rpm): spectral radius of the one-step map "
                f"{r:.6f} > 1 (at its start: {rho:.6f}); reduce the communication step"])
            err.reports = reports
            raise err
    spec.metadata["cuts"] = [r.as_dict() for r in reports]
    spec.metadata["cosim_spectral_radius"] = rho
    if at_speeds:
        spec.metadata["cosim_spectral_radius_at_rpm"] = at_speeds


def speeds_to_check(spec: SystemSpec) -> list[float]:
    """The drive speeds [rpm] of the MotorLoad's speed profile (``speed_ref_rpm`` given as points) other than its
    start: where the linearised co-simulation is checked besides the start. [] for a constant speed."""
    motors = [c for c in spec.components if c.model == "MotorLoad"]
    ref = motors[0].inputs.get("speed_ref_rpm") if motors else None
    if not isinstance(ref, (list, tuple)) or not ref:
        return []
    start = float(ref[0][1])
    return sorted({float(v) for _, v in ref if float(v) != start}, key=abs)


def spec_at_speed(spec: SystemSpec, rpm: float) -> SystemSpec:
    """``spec`` linearised at a steady drive speed ``rpm``: its components' start speeds (``w0`` of the drive
    side, ``w0_load`` of the load body, the propeller speed through the upper and the lower ratio) at that speed,
    everything else as it is. For the stability check only (the losses' small-signal damping is speed-dependent)."""
    upper = next(c for c in spec.components if c.model == "UpperTransmission").parameters
    motors = next(c for c in spec.components if c.model == "MotorLoad").parameters
    gear = next((c for c in spec.components if c.model == GEAR_MODEL), None)
    lower = gear_pair(gear.parameters).ratio if gear is not None else rig.LOWER_RATIO
    ss = rig.steady_state(rpm, 0.0, upper, motors, lower_ratio=lower)     # its speeds, as assemble's start
    comps = []
    for c in spec.components:
        p = dict(c.parameters)
        if "w0" in p:
            p["w0"] = ss.w_drive
        if "w0_load" in p:
            p["w0_load"] = ss.w_prop
        comps.append(dataclasses.replace(c, parameters=p))
    return SystemSpec(comps, list(spec.connections), spec.comm_step, spec.metadata)


def start_with_map(scene, spec: SystemSpec) -> SystemSpec:
    """``spec`` (assembled from ``scene`` by :func:`assemble`), or, when its table gear started at the analytic
    guess because the contact map was not cached at assembly (``metadata["mesh_start"] == MESH_START_GUESS``:
    the assembler builds no map, the cost refusal comes after it), a copy whose gear starts at its own static
    deflection with the map built (:func:`start_mesh_model`), as on every later run of the scene. Only the start
    is recomputed on the assembled spec: the wheel's start angle, the load body's start angle
    (``motors.phi0_load``), the gear's start state (:func:`gear_start_state`), ``metadata["mesh_start"]`` and the
    cut reports; every value equal, bit for bit, to ``assemble(scene, build_map=True)``'s. For the runner past
    its cost checks and a sweep past its preparation: one rule, whatever the cache held. ``spec`` is not changed."""
    if spec.metadata.get("mesh_start") != MESH_START_GUESS:
        return spec
    components = [dataclasses.replace(c, parameters=dict(c.parameters)) for c in spec.components]
    by_name = {c.name: c.parameters for c in components}
    gear, mo, up = by_name["gear"], by_name["motors"], by_name["upper"]
    twist_a, twist_b = gear["twist_a_start"], gear["twist_b_start"]
    theta_p = up["phi0"] / up["ratio"] + twist_a            # as assemble: phi_a + twist_a
    # the gear's parameters as start_wheel_angle saw them in assemble: before the start state was set
    start_keys = {"twist_a_start", "twist_b_start", "initial_state",
                  *(f"{body}_{q}_start" for body, _ in _GEAR_BODIES for q in ("phi", "w"))}
    ss = rig.SteadyState(**spec.metadata["steady_state"])
    theta_w, mesh_start = _start_wheel(scene, {k: v for k, v in gear.items() if k not in start_keys}, ss, theta_p,
                                       errors_of(gear.get("manufacturing_errors")), True)
    mo["phi0_load"] = theta_w - twist_b
    gear.update(gear_start_state(components, spec.connections, "gear"))
    meta = copy.deepcopy(spec.metadata)
    meta["mesh_start"] = mesh_start
    out = SystemSpec(components, list(spec.connections), spec.comm_step, meta)
    if "cuts" in meta:
        _check_cuts(out)
    return out


#: the gear stage's bodies and the flange whose connected body each one starts at
_GEAR_BODIES = (("pinion", "flange_a"), ("wheel", "flange_b"))


def gear_start_state(components: list[ComponentSpec], connections: list[Connection], gear: str) -> dict:
    """GearContact's initial-state parameters (``initial_state = "parameters"``): each of its bodies
    starts at the angle of the body its flange connects to plus the port twist (``twist_a_start``,
    ``twist_b_start`` of the gear's parameters), at that body's speed, as that component starts (built
    here from its own parameters and read back, so the values are the ones a master passes during
    initialization, bit for bit). The FMU then starts right in a host that passes nothing before the
    first step (docs/FMU.md, "Initialization"); with ``initial_state = "inputs"`` it starts the same."""
    by_name = {c.name: c for c in components}
    twists = {"a": float(by_name[gear].parameters.get("twist_a_start", 0.0)),
              "b": float(by_name[gear].parameters.get("twist_b_start", 0.0))}
    out = {"initial_state": "parameters"}
    for body, flange in _GEAR_BODIES:
        conn = next(c for c in connections if c.spring == f"{gear}.{flange}")
        comp_name, port = conn.inertia.split(".", 1)
        comp = by_name[comp_name]
        if comp.model not in COMPONENTS:          # another FMU: it passes its values during initialization
            return {}
        values = make_component(comp.model, comp.parameters).outputs(energy=False)
        out[f"{body}_phi_start"] = float(values[f"{port}_phi"]) + twists[flange[-1]]
        out[f"{body}_w_start"] = float(values[f"{port}_w"])
    return out


def record_couplings(part: rig.Partition, bg: background.Background) -> None:
    """``effects.couplings = "record"``: the coupling damping (C1 and C2) and the stiffness and damping
    between the wheel and the propeller mass (the gear's port spring k_b, d_b: propeller shaft and its
    transducer) scaled as identified from the measured record (the coupling stiffness scale enters the
    partition itself); the cuts' copies of the same springs follow."""
    mo, gear = part.params["motors"], part.params["gear"]
    mo["d_c1"] *= bg.coupling_damping_scale
    mo["d_c2"] *= bg.coupling_damping_scale
    gear["k_b"] *= bg.propeller_stiffness_scale
    gear["d_b"] *= bg.propeller_damping_scale
    for cu in part.cuts:
        if cu["spring"] == "motors.drive":
            cu["c"] = mo["d_c2"]
        elif cu["spring"] == "gear.flange_b":
            cu["k"], cu["c"] = gear["k_b"], gear["d_b"]


#: the MotorLoad input that carries the background's torque at each place (rig.background.PLACES)
BACKGROUND_INPUTS = {"drive": "motor_torque_disturbance", "load": "load_torque"}


def background_inputs(scene, H: float, ratio_pg: float) -> dict:
    """MotorLoad's inputs that carry the scene's background torques (drivetrain.rig.background), as profiles at
    every communication point of the run, generated when the master reads them: ``motor_torque_disturbance``
    (on the drive rotor) and ``load_torque`` (the load motor's setting plus its share, 1/ratio_pg, of the torques
    on the propeller mass; a load profile of the scene is kept under them). Empty when no background effect is on."""
    n_rows = int(round(scene.time.duration_s / H)) + 2
    return {name: background.GeneratedProfile(functools.partial(_background_values, scene, H, ratio_pg, where),
                                              n_rows, H)
            for where, name in BACKGROUND_INPUTS.items() if background.acts_on(where, scene.effects)}


def _background_values(scene, H: float, ratio_pg: float, where: str) -> np.ndarray:
    """The values of one background input of :func:`background_inputs` at the communication points."""
    op = scene.operating_point
    n_steps = int(round(scene.time.duration_s / H)) + 1
    speed = [list(p) for p in op.speed_profile_rpm] if op.speed_profile_rpm else float(op.drive_speed_rpm)
    torque = background.disturbance(where, scene.effects, n_steps, H, speed, scene.background, scene.noise_name,
                                    upper_ratio=machine_upper_ratio(scene), lower_ratio=scene.gear.pair.params().ratio)
    if where == "drive":
        return torque
    t = np.arange(n_steps + 1) * H
    setting = (np.interp(t, *np.asarray(op.load_profile_Nm, dtype=float).T) if op.load_profile_Nm
               else np.full(n_steps + 1, float(op.load_torque_Nm)))
    return setting + torque / ratio_pg


__all__ = ["assemble", "gear_start_state", "sensor_map", "SENSORS_COMMON", "record_couplings",
           "background_inputs"]


def gear_parameters(scene) -> dict:
    """The GearContact parameters of a scene (component "gear" as assembled): what ``drivetrain
    build-native-gear`` builds."""
    spec = assemble(scene)
    gears = spec.components_of(GEAR_MODEL)
    if not gears:
        raise NativeBuildError([f"scene {scene.name!r} has no GearContact component (effects.mesh_contact = "
                                f"'ideal' with rigid shafts assembles none)"])
    return dict(gears[0].parameters)
