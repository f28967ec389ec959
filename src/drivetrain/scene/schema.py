"""Scene files: the schema (every key's type, unit, default and meaning, declared once) and the resolved
``Scene``.

A scene is a TOML file (documented key by key in ``docs/SCENARIOS.md``, generated from :data:`SCHEMA` by
:func:`schema_markdown`). Validation and loading are in :mod:`drivetrain.scene.load`, grid expansion in
:mod:`drivetrain.scene.grid`.

Numbers may be written plainly (in the unit of the key's suffix) or as a string with a unit,
``duration_s = "500 ms"``, ``drive_speed_rpm = "25 Hz"``; :data:`UNITS` lists the units accepted and a
unit of the wrong kind is refused.
"""
from __future__ import annotations

import dataclasses
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivetrain.errors import MISSING as _MISSING
from drivetrain.rig.data import PAPER_LOADS_NM, PAPER_MAX_LOAD_NM, PAPER_MAX_SPEED_RPM, RAD_S_PER_RPM, RIG_SENSORS
from drivetrain.rig.data import LOAD_LAWS, RIG_DRIVE_LOAD as _DL
from drivetrain.rig.background import Background
from drivetrain.rig.instruments import Instruments
from gearcontact_fmu.fault_specs import FAULT_KINDS
from gearcontact_fmu.manufacturing_specs import DEFAULT_GRADE as MANUFACTURING_GRADE
from gearcontact_fmu.manufacturing_specs import DEFAULT_RUNOUT_GRADE as MANUFACTURING_RUNOUT_GRADE
from gearcontact_fmu.manufacturing_specs import GRADES
from gearcontact_fmu.mesh_models.base import FIDELITIES, HEALTH_STATES, SCHEMES, fidelities_with
from gearcontact_fmu.params import DEFAULT_COMM_STEP_S, TOOTH_COMPLIANCE_FACTOR, MapGrid, MeshResolution
from gearcontact_fmu.params import BevelGearParams, PCMParams

# --------------------------------------------------------------------------------------------------
# Fixed vocabularies
# --------------------------------------------------------------------------------------------------

SHAFT_MODELS = ("flexible", "rigid")
MESH_UNITS = ("mm", "m")
ANTI_ALIAS = ("fir", "butter")
SAMPLE_DTYPES = ("float64", "float32")

#: a scene name names a directory and files: no path separators, no ".", "..", hidden or option-like names
NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+\-]{0,199}")
NAME_RULE = ("1-200 letters, digits and _ . + -, starting with a letter, digit or _ "
             "(it names the output directory and files)")
#: an extra output variable: "component.variable"
VAR_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*\.[A-Za-z_][A-Za-z0-9_.\[\]]*$")

# --------------------------------------------------------------------------------------------------
# Units accepted in "<number> <unit>" strings: unit -> (dimension, factor to the key's base unit)
# --------------------------------------------------------------------------------------------------

UNITS: dict[str, tuple[str, float]] = {
    # time, base s
    "s": ("time", 1.0), "ms": ("time", 1e-3), "us": ("time", 1e-6), "µs": ("time", 1e-6),
    "min": ("time", 60.0), "h": ("time", 3600.0),
    # rotational speed, base rpm
    "rpm": ("speed", 1.0), "1/min": ("speed", 1.0), "rad/s": ("speed", 1.0 / RAD_S_PER_RPM),
    "rps": ("speed", 60.0), "rev/s": ("speed", 60.0),
    # torque, base N·m
    "N·m": ("torque", 1.0), "Nm": ("torque", 1.0), "N.m": ("torque", 1.0), "N*m": ("torque", 1.0),
    "mN·m": ("torque", 1e-3), "mNm": ("torque", 1e-3), "kN·m": ("torque", 1e3), "kNm": ("torque", 1e3),
    # frequency, base Hz
    "Hz": ("frequency", 1.0), "kHz": ("frequency", 1e3), "1/s": ("frequency", 1.0),
    # length, base mm
    "mm": ("length", 1.0), "m": ("length", 1e3), "um": ("length", 1e-3), "µm": ("length", 1e-3),
    "cm": ("length", 10.0),
    # force (only to recognise and refuse it in a torque key)
    "N": ("force", 1.0), "kN": ("force", 1e3),
    # angle (recognised, refused where a speed is expected)
    "rad": ("angle", 1.0), "deg": ("angle", 1.0),
}
BASE_UNIT = {"time": "s", "speed": "rpm", "torque": "N·m", "frequency": "Hz", "length": "mm"}


# --------------------------------------------------------------------------------------------------
# Schema
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Key:
    """One scene key."""

    type: str                       # float | int | bool | str | enum | path | profile | series | str_list | var_list
    default: Any = _MISSING         # _MISSING = required; None = optional (absent)
    unit: str = ""                  # unit of the value ("" = dimensionless / not a quantity)
    dimension: str = ""             # dimension accepted in "<number> <unit>" strings
    allowed: tuple = ()             # enum values, or allowed list items
    minimum: float | None = None
    maximum: float | None = None
    min_exclusive: bool = False
    doc: str = ""
    default_doc: str = ""           # how the default is shown in the docs, if not the plain value


def _f(default, unit, dimension, doc, minimum=None, min_exclusive=False, maximum=None, default_doc=""):
    return Key("float", default, unit, dimension, (), minimum, maximum, min_exclusive, doc, default_doc)


_RES = MeshResolution()       # the converged contact-mesh resolution of the gear library is the scene default
_GRID = MapGrid()             # the contact-map grid, likewise
_INST = Instruments()         # the instrument constants are declared in drivetrain.rig.instruments
_BG = Background()            # the background constants, in drivetrain.rig.background
SENSOR_MODELS = ("ideal", "rig")

# ---- [gear.pair]: the lower bevel pair from its gear data (issue 42) ------------------------------------
#: each [gear.pair] key: (the library object it sets: "gear" BevelGearParams | "pcm" PCMParams, its field, the
#: scene unit). The defaults are the library's (the rig's pair), converted to the scene unit, never copied.
PAIR_FIELDS: dict[str, tuple[str, str, str]] = {
    "z_pinion": ("gear", "z_pinion", ""), "z_wheel": ("gear", "z_wheel", ""),
    "module_mm": ("gear", "module", "mm"), "face_width_mm": ("gear", "face_width", "mm"),
    "pressure_angle_deg": ("gear", "pressure_angle", "deg"), "shaft_angle_deg": ("gear", "shaft_angle", "deg"),
    "x_pinion": ("gear", "x_pinion", ""), "addendum_coefficient": ("gear", "addendum_coefficient", ""),
    "dedendum_coefficient": ("gear", "dedendum_coefficient", ""), "backlash_mm": ("gear", "backlash", "mm"),
    "tip_radius_mm": ("gear", "tip_radius", "mm"),
    "E_GPa": ("pcm", "E", "GPa"), "nu": ("pcm", "nu", ""), "layer_depth_mm": ("pcm", "layer_depth", "mm"),
}
#: scene unit -> (to SI, from SI); the rig's values go there and back exactly (tests/scene/test_gear_pair.py)
PAIR_UNITS = {"": (lambda v: v, lambda v: v), "mm": (lambda v: v / 1e3, lambda v: v * 1e3),
              "deg": (math.radians, math.degrees), "GPa": (lambda v: v * 1e9, lambda v: v / 1e9)}
_PAIR_DEFAULTS = {"gear": BevelGearParams(), "pcm": PCMParams()}


def _pair_default(key: str):
    target, field, unit = PAIR_FIELDS[key]
    return PAIR_UNITS[unit][1](getattr(_PAIR_DEFAULTS[target], field))


#: the [gear.pair] keys: domain checks only; whether the pair can be made is gearcontact_fmu.pair_check's
PAIR_SCHEMA: dict[str, Key] = {
    "z_pinion": Key("int", _pair_default("z_pinion"), minimum=1, maximum=1000, doc="teeth of the pinion (driving, on the middle shaft)"),
    "z_wheel": Key("int", _pair_default("z_wheel"), minimum=1, maximum=1000, doc="teeth of the wheel (on the propeller shaft)"),
    "module_mm": _f(_pair_default("module_mm"), "mm", "length", "outer transverse module", minimum=0.0,
                    min_exclusive=True),
    "face_width_mm": _f(_pair_default("face_width_mm"), "mm", "length", "face width (at most a third of the outer "
                        "cone distance)", minimum=0.0, min_exclusive=True),
    "pressure_angle_deg": _f(_pair_default("pressure_angle_deg"), "deg", "", "pressure angle", minimum=0.0,
                             min_exclusive=True, maximum=45.0),
    "shaft_angle_deg": _f(_pair_default("shaft_angle_deg"), "deg", "", "angle between the shafts", minimum=0.0,
                          min_exclusive=True, maximum=180.0),
    "x_pinion": _f(_pair_default("x_pinion"), "", "", "profile shift coefficient of the pinion; the wheel gets -x_pinion"),
    "addendum_coefficient": _f(_pair_default("addendum_coefficient"), "", "", "addendum / module at the outer end",
                               minimum=0.0),
    "dedendum_coefficient": _f(_pair_default("dedendum_coefficient"), "", "", "dedendum / module at the outer end",
                               minimum=0.0),
    "backlash_mm": _f(_pair_default("backlash_mm"), "mm", "length",
                      "circumferential backlash on the outer pitch circle", minimum=0.0),
    "tip_radius_mm": _f(_pair_default("tip_radius_mm"), "mm", "length", "rounding radius of the tip edge at the "
                        "outer end", minimum=0.0),
    "E_GPa": _f(_pair_default("E_GPa"), "GPa", "", "Young's modulus of the elastic layer (polygonal contact)",
                minimum=0.0, min_exclusive=True),
    "nu": _f(_pair_default("nu"), "", "", "Poisson's ratio of the elastic layer; < 0.5", minimum=0.0),
    "layer_depth_mm": _f(_pair_default("layer_depth_mm"), "mm", "length", "depth of the elastic layer of each body; "
                         "absent: the rig's carried to the pair's flank curvature, "
                         "b_rig sqrt(rho / rho_rig) (gearcontact_fmu.elastic_layer)", minimum=0.0, min_exclusive=True),
}
assert set(PAIR_SCHEMA) == set(PAIR_FIELDS)


@dataclass(frozen=True)
class GearPair:
    """``[gear.pair]`` as the scene gives it, in the keys' units (:data:`PAIR_SCHEMA`; absent keys at the rig's
    values): :meth:`params` and :meth:`pcm` are the library's objects of it (SI)."""

    values: tuple            # ((key, value), ...) in PAIR_SCHEMA's order

    @classmethod
    def of(cls, given: dict | None = None) -> "GearPair":
        """The pair of the keys ``given``; an absent key at the rig's value, but ``layer_depth_mm``, which an
        absent key takes from the pair (``gearcontact_fmu.elastic_layer.layer_depth``: the rig's layer carried to
        the pair's flank curvature; the rig's own 0.5 mm for the rig's pair)."""
        given = given or {}
        pair = cls(tuple((k, given[k] if k in given else spec.default) for k, spec in PAIR_SCHEMA.items()))
        if "layer_depth_mm" in given or not any(PAIR_FIELDS[k][0] == "gear" for k in given):
            return pair
        from gearcontact_fmu.elastic_layer import layer_depth      # (numba's import: only for another pair)

        depth = PAIR_UNITS[PAIR_FIELDS["layer_depth_mm"][2]][1](layer_depth(pair.params()))
        return cls(tuple((k, depth if k == "layer_depth_mm" else v) for k, v in pair.values))

    def as_dict(self) -> dict:
        return dict(self.values)

    def _objects(self) -> dict:
        kw: dict = {"gear": {}, "pcm": {}}
        for key, value in self.values:
            target, field, unit = PAIR_FIELDS[key]
            kw[target][field] = PAIR_UNITS[unit][0](value)
        return kw

    def params(self) -> BevelGearParams:
        """The pair as ``gearcontact_fmu.params.BevelGearParams`` (SI)."""
        return dataclasses.replace(_PAIR_DEFAULTS["gear"], **self._objects()["gear"])

    def pcm(self) -> PCMParams:
        """The elastic layer as ``gearcontact_fmu.params.PCMParams`` (its other fields at their defaults)."""
        return dataclasses.replace(_PAIR_DEFAULTS["pcm"], **self._objects()["pcm"])

    @property
    def is_rig(self) -> bool:
        """The rig's pair and layer (every key at its default)."""
        return self.params() == _PAIR_DEFAULTS["gear"] and self.pcm() == _PAIR_DEFAULTS["pcm"]


#: the rig's pair (every [gear.pair] key at its default)
RIG_PAIR = GearPair.of()


def pair_keys(gear: BevelGearParams) -> dict:
    """The ``[gear.pair]`` keys (scene units) of a ``BevelGearParams``: those of its gear data that differ from the
    rig's (the elastic layer left to the pair's default), so that ``GearPair.of(pair_keys(g)).params() == g``."""
    out = {}
    for key, (target, field, unit) in PAIR_FIELDS.items():
        if target == "gear" and getattr(gear, field) != getattr(_PAIR_DEFAULTS["gear"], field):
            out[key] = PAIR_UNITS[unit][1](getattr(gear, field))
    return out


SCHEMA: dict[str, dict[str, Key]] = {
    "scenario": {
        "name": Key("str", None, doc="scene name (used for output files and manifests)",
                    default_doc="the file name without .toml"),
        "description": Key("str", "", doc="free text"),
        "noise_name": Key("str", None, doc=(
            "the name the run's noise records (instruments, background) are drawn with; two runs with one "
            "noise_name are measured with the same noise: a paired healthy run ([sweep.draw] paired_healthy)"),
            default_doc="the scene's name"),
        "growth_stage": Key("int", None, minimum=0, doc=(
            "the stage of a fault's life this run shows ([sweep.growth]; 0 = the first, or the healthy gearbox "
            "before the fault): a label, nothing is simulated differently")),
        "remaining_life": _f(None, "", "", (
            "the fraction of the gearbox's life left at this stage ([sweep.growth]; 1 = new, towards 0 = failure): "
            "a label for prognostics"), minimum=0.0, maximum=1.0),
    },
    "operating_point": {
        "drive_speed_rpm": _f(PAPER_MAX_SPEED_RPM, "rpm", "speed", "drive-motor speed reference (drive shaft)",
                              minimum=0.0),
        "load_torque_Nm": _f(PAPER_MAX_LOAD_NM, "N·m", "torque",
                             "load-motor torque setting, before the 1:8 planetary "
                             f"(paper: {', '.join(f'{x:g}' for x in PAPER_LOADS_NM)}); "
                             "negative = a reversal: the load motor drives the propeller shaft and the coast "
                             "flanks carry the load"),
        "speed_profile_rpm": Key("profile", None, "rpm", doc=(
            "piecewise-linear speed reference, [[time_s, rpm], ...], times strictly increasing from 0; "
            "held constant after the last point; overrides drive_speed_rpm"), minimum=0.0),
        "load_profile_Nm": Key("profile", None, "N·m", doc=(
            "piecewise-linear load torque, [[time_s, N·m], ...] like speed_profile_rpm; overrides "
            "load_torque_Nm (a step: two points 1 ms apart); values may be negative (a load reversal)")),
        "load_series_csv": Key("series", None, "N·m", "torque", doc=(
            "a measured load-motor torque series as the load input: a CSV file (path relative to the scene "
            "file) with a header naming time and torque with their units (e.g. `time_s,load_torque_Nm`) and one "
            "row per point, time from 0 strictly increasing; interpolated linearly, held after the last point; "
            "overrides load_torque_Nm, excludes load_profile_Nm (docs/SCENARIOS.md, 'Measured load series')")),
    },
    "gear": {
        "health": Key("enum", "healthy", allowed=HEALTH_STATES, doc=(
            "healthy; mild = tooth-flank-fracture void on one pinion tooth; severe = one pinion tooth "
            "missing; faults = the faults listed in [[gear.faults]], on either gear; mesh = user surface "
            "mesh(es) from pinion_mesh / wheel_mesh")),
        "faults": Key("faults", (), doc=(
            "with health = \"faults\": an array of tables [[gear.faults]], each with kind ("
            + " | ".join(FAULT_KINDS) + "), member (pinion | wheel, default pinion), tooth (0..z-1, "
            "default 0), flank (drive | coast, default drive) and the sizes of its kind [mm]: "
            + "; ".join(f"{k}: " + (", ".join(f"{n} (default {v if isinstance(v, str) else format(v, 'g')})"
                                              for n, v in sz.items()) or "none")
                        for k, sz in FAULT_KINDS.items()))),
        "pinion_mesh": Key("path", None, doc="OBJ/STL of the pinion (health = \"mesh\"); relative to the scene file"),
        "wheel_mesh": Key("path", None, doc="OBJ/STL of the wheel (health = \"mesh\"; optional, healthy wheel if absent)"),
        "mesh_units": Key("enum", "mm", allowed=MESH_UNITS, doc="length unit of the mesh files"),
        "pair": Key("pair", RIG_PAIR, doc=(
            "the lower bevel pair from its gear data: the table [gear.pair] (its keys below); absent keys take "
            "the rig's values; a pair that cannot be made is refused before any work"),
            default_doc=f"the rig's {RIG_PAIR.params().z_pinion}/{RIG_PAIR.params().z_wheel} pair"),
    },
    "time": {
        "duration_s": _f(20.0, "s", "time", "simulated time", minimum=0.0, min_exclusive=True),
        "settle_s": _f(None, "s", "time", "initial transient excluded from statistics and spectra; < duration_s",
                       minimum=0.0, default_doc="min(2 s, 20 % of duration_s)"),
        "sample_rate_Hz": _f(3000.0, "Hz", "frequency",
                             "output sample rate (the rig: 3012 Hz); comm_step_s must divide its period",
                             minimum=0.0, min_exclusive=True),
    },
    "outputs": {
        "sensors": Key("str_list", list(RIG_SENSORS), allowed=tuple(RIG_SENSORS),
                       doc="rig sensors to write (torques in N·m, encoder angles in rad)"),
        "variables": Key("var_list", [], doc="extra FMU variables to write, each \"component.variable\""),
        "plots": Key("bool", True, doc="write PNG plots (torque waveforms, spectra)"),
        "aalto_csv": Key("bool", False, doc=(
            "also write sensors.csv in the Aalto Gear Fault Dataset layout: time, enc1..enc5, Torq1, Torq2")),
        "dtype": Key("enum", "float64", allowed=SAMPLE_DTYPES, doc="sample type of the HDF5 signals"),
    },
    "numerics": {
        "comm_step_s": _f(DEFAULT_COMM_STEP_S, "s", "time",
                          "communication step H of the master; must divide 1/sample_rate_Hz",
                          minimum=0.0, min_exclusive=True, default_doc="1/12000 (8.333e-05)"),
        "max_substep_s": _f(5.0e-6, "s", "time",
                            "largest internal sub-step of the gear stage; <= comm_step_s (5 µs: the same "
                            "torques as 1 µs to 0.1 %, see docs/pcm_vs_table.md)",
                            minimum=0.0, min_exclusive=True),
        "profile_element_mm": _f(_RES.profile * 1e3, "mm", "length",
                                 "contact-mesh element size along the tooth profile (default: the converged "
                                 "resolution of gearcontact_fmu.params.MeshResolution)",
                                 minimum=0.0, min_exclusive=True),
        "face_element_mm": _f(_RES.face * 1e3, "mm", "length",
                              "contact-mesh element size along the face width (default: MeshResolution)",
                              minimum=0.0, min_exclusive=True),
        "map_points_per_pitch": Key("int", _GRID.points_per_pitch, minimum=4, maximum=4096, doc=(
            "table: contact-map nodes along the pinion angle per pinion pitch (bilinear between them)")),
        "map_approach_points": Key("int", _GRID.s_points, minimum=4, maximum=4096, doc=(
            "table: contact-map nodes per flank along the approach beyond the contact onset")),
        "mesh_integrator": Key("enum", "auto", allowed=SCHEMES, doc=(
            "sub-step integrator of the gear stage: auto (rk4 where it is stable at max_substep_s, else "
            "ros2), ros2 (linearly implicit Rosenbrock, 2nd order), rk4 (explicit; stiff contact needs small "
            "sub-steps)")),
        "energy_correction": Key("bool", True, doc=(
            "energy-conserving correction of the torques the spring-side ports hand over (gear stage, "
            "drive motor, drive shaft; gearcontact_fmu.coupling): removes the first-order energy error "
            "of the co-simulation cuts (docs/STABILITY.md)")),
        "anti_alias": Key("enum", "fir", allowed=ANTI_ALIAS, doc=(
            "anti-alias filter before decimating to sample_rate_Hz: linear-phase Kaiser FIR or "
            "zero-phase Butterworth (sosfiltfilt)")),
        "max_contact_hours": _f(4.0, "h", "time", (
            "refuse, before it starts, a run whose contact model (map build and online PCM) is estimated "
            "to take longer: mesh files or element sizes finer than the default are timed on this machine "
            "first, and the refusal says how far to coarsen"), minimum=0.0, min_exclusive=True),
        "tolerance_pct": _f(None, "%", "", (
            "run with the cheapest setting whose measured error for the closest studied scene is within "
            "this: mean torques and fluctuation within T %, GMF and sidebands within T dB (docs/ACCURACY-COST.md; "
            "the choice and why go to the summary as accuracy_choice); `drivetrain run --tolerance 1%`"),
            minimum=0.0, min_exclusive=True, default_doc="none: the scene's own settings"),
    },
    "effects": {
        "mesh_contact": Key("enum", "table", allowed=FIDELITIES, doc=(
            "lower-gear mesh model: pcm (online polygonal contact), table (precomputed contact map), "
            "analytic (ISO 6336 stiffness), ideal (rigid kinematic ratio, no contact FMU)")),
        "shaft_flexibility": Key("enum", "flexible", allowed=SHAFT_MODELS,
                                 doc="flexible shafts (FlexibleShaft FMUs) or rigid (no shaft FMU)"),
        "shaft_elements": Key("int", 4, minimum=1, maximum=64,
                              doc="torsional elements per long shaft (flexible only)"),
        "friction": Key("bool", True, doc=f"tooth friction in the mesh ({'/'.join(fidelities_with('friction'))})"),
        "contact_damping": Key("bool", True, doc="contact damping in the mesh"),
        "losses": Key("bool", True, doc="viscous losses of the gearboxes and bearings"),
        "sensors": Key("enum", "ideal", allowed=SENSOR_MODELS, doc=(
            "ideal: the sensor signals as simulated; rig: as the rig's instruments report them (encoder "
            "quantisation, transducer bandwidth and noise, from [instruments], seeded)")),
        "tooth_compliance": Key("bool", False, doc=(
            "tooth bending and foundation compliance in series with the PCM layers, so that the loaded mesh "
            "stiffness is ISO 6336's ([tooth_compliance]; table; the analytic pair has it already; the "
            "paper's simulation had none)")),
        "manufacturing_errors": Key("bool", False, doc=(
            "tooth position (pitch) errors and runout of pinion and wheel, and with "
            "manufacturing.profile_errors their profile form deviation, drawn from [manufacturing] "
            "(pcm, table, analytic; the paper's simulation had none)")),
        "drive_torque_noise": Key("bool", False, doc=(
            "the drive's broadband torque noise on the drive motor's rotor ([background]; docs/DRIVETRAIN.md, "
            "\"The measured background\")")),
        "load_torque_noise": Key("bool", False, doc=(
            "the load motor's broadband torque noise on the propeller mass, through the 1:8 planetary "
            "([background]; identified from the rig's measured record)")),
        "shaft_orders": Key("bool", False, doc=(
            "periodic torque on the propeller mass at 1x and 2x the middle and drive shafts' speeds (runout, "
            "bow and misalignment against the stiffly held drive) and at the planetary's mesh frequency "
            "([background])")),
        "drive_control": Key("enum", "assumed", allowed=("assumed", "record"), doc=(
            "the drive's PI speed controller: assumed ([drivetrain] drive_Kp, drive_Ti_s: the rig's ~2 Hz speed loop) or record "
            "(identified from the drive's own torque and speed signals in the measured record: [background] "
            "drive_Kp, drive_Ti_s)")),
        "couplings": Key("enum", "fitted", allowed=("fitted", "record"), doc=(
            "stiffness and damping of the elastomer couplings and the propeller shaft: fitted (the coupling "
            "factor fitted to the paper's 24 Hz, public damping) or record (identified from the rig's measured "
            "record: [background] coupling_* and propeller_* scales)")),
    },
    "background": {
        "seed": Key("int", _BG.seed, minimum=0, doc=(
            "seed of the background: the noise records (with the run's name) and the periodic lines' phases")),
        "load_noise_Nm_rtHz": _f(_BG.load_noise_Nm_rtHz, "N·m/√Hz", "", (
            "one-sided amplitude spectral density of the load motor's torque noise on the propeller mass "
            "(propeller-shaft frame; effects.load_torque_noise)"), minimum=0.0),
        "drive_noise_Nm_rtHz": _f(_BG.drive_noise_Nm_rtHz, "N·m/√Hz", "", (
            "one-sided amplitude spectral density of the drive's torque noise on the motor rotor "
            "(effects.drive_torque_noise)"), minimum=0.0),
        "noise_band_Hz": _f(_BG.noise_band_Hz, "Hz", "frequency", (
            "upper edge of both torque noises (4th-order Butterworth)"), minimum=0.0, min_exclusive=True),
        "order_msh_1x_Nm": _f(_BG.order_msh_1x_Nm, "N·m", "torque", (
            "periodic torque on the propeller mass at the middle shaft's speed (effects.shaft_orders)"),
            minimum=0.0),
        "order_msh_2x_Nm": _f(_BG.order_msh_2x_Nm, "N·m", "torque", "... at twice the middle shaft's speed",
                              minimum=0.0),
        "order_dsh_1x_Nm": _f(_BG.order_dsh_1x_Nm, "N·m", "torque", "... at the drive shaft's speed", minimum=0.0),
        "order_dsh_2x_Nm": _f(_BG.order_dsh_2x_Nm, "N·m", "torque", "... at twice the drive shaft's speed",
                              minimum=0.0),
        "planetary_mesh_Nm": _f(_BG.planetary_mesh_Nm, "N·m", "torque", (
            "periodic torque on the propeller mass at the planetary's mesh frequency (effects.shaft_orders)"),
            minimum=0.0),
        "planetary_ring_teeth": Key("int", _BG.planetary_ring_teeth, minimum=1, maximum=1000, doc=(
            "teeth of the planetary's ring gear: its mesh frequency is this times the propeller shaft's speed "
            "(84: the record's line at 84.0 f_PSH; 1 + 84/12 = 8, the planetary's ratio)")),
        "orders_speed_exponent": _f(_BG.orders_speed_exponent, "", "", (
            "the planetary mesh line's amplitude (and every line without an exponent of its own) scales as (speed / 500 rpm)^this: 2 for kinematic errors (runout, "
            "misalignment, a mesh's transmission error between two bodies: the torque that makes a body follow a "
            "displacement grows as its frequency squared), 0 for constant torques; default identified over the "
            "rig's 500 and 2004 rpm records (drivetrain calibrate --record; campaigns.excitation_fit)"), minimum=0.0),
        # each shaft-order line's own speed law (order_<shaft>_<k>x_exponent)
        **{f"order_{sh}_{k}x_exponent": _f(getattr(_BG, f"order_{sh}_{k}x_exponent"), "", "", (
            f"the {shaft}'s {k}x line's amplitude scales as (speed / 500 rpm)^this (its own speed law; default a "
            "calibration on the rig's 500 rpm record and its 2004 rpm impulse record, drivetrain calibrate --record)"),
            minimum=0.0)
           for sh, shaft in (("msh", "middle shaft"), ("dsh", "drive shaft")) for k in (1, 2)},
        "drive_Kp": _f(_BG.drive_Kp, "N·m·s/rad", "", (
            "proportional gain of the drive's speed controller (effects.drive_control = record)"), minimum=0.0,
            min_exclusive=True),
        "drive_Ti_s": _f(_BG.drive_Ti_s, "s", "time", (
            "integral time of the drive's speed controller (effects.drive_control = record)"), minimum=0.0,
            min_exclusive=True),
        "coupling_stiffness_scale": _f(_BG.coupling_stiffness_scale, "", "", (
            "factor on the public model's elastomer coupling stiffness (effects.couplings = record)"),
            minimum=0.0, min_exclusive=True),
        "coupling_damping_scale": _f(_BG.coupling_damping_scale, "", "", (
            "factor on the public model's coupling damping (effects.couplings = record)"), minimum=0.0),
        "propeller_stiffness_scale": _f(_BG.propeller_stiffness_scale, "", "", (
            "factor on the stiffness between the wheel and the propeller mass (propeller shaft and its "
            "transducer; effects.couplings = record)"), minimum=0.0, min_exclusive=True),
        "propeller_damping_scale": _f(_BG.propeller_damping_scale, "", "", (
            "factor on the damping between the wheel and the propeller mass (effects.couplings = record)"),
            minimum=0.0),
    },
    "instruments": {
        "seed": Key("int", _INST.seed, minimum=0, doc="seed of the measurement noise (recorded in the summary)"),
        "encoder_lines": Key("int", _INST.encoder_lines, minimum=1, doc=(
            "lines per revolution of the incremental encoders (read in quadrature: 4 counts per line); "
            "assumed, not from a data sheet")),
        "torque_bandwidth_Hz": _f(_INST.torque_bandwidth_Hz, "Hz", "frequency", (
            "-3 dB bandwidth of the torque transducers (2nd-order Butterworth, causal); assumed"),
            minimum=0.0, min_exclusive=True),
        "drive_torque_noise_Nm": _f(_INST.drive_torque_noise_Nm, "N·m", "torque",
                                    "RMS white noise of the drive-shaft torque transducer; assumed", minimum=0.0),
        "propeller_torque_noise_Nm": _f(_INST.propeller_torque_noise_Nm, "N·m", "torque",
                                        "RMS white noise of the propeller-shaft torque transducer; assumed",
                                        minimum=0.0),
    },
    "tooth_compliance": {
        "factor": _f(TOOTH_COMPLIANCE_FACTOR, "", "", (
            "total mesh approach per unit of PCM layer approach (1 = the layers alone); the default makes the "
            "loaded mesh stiffness ISO 6336's c_gamma within 7 % at the paper's loads"), minimum=1.0),
    },
    "manufacturing": {
        "grade": Key("int", MANUFACTURING_GRADE, minimum=min(GRADES), maximum=max(GRADES), doc=(
            "ISO 1328 accuracy grade of the teeth: sets the single pitch tolerance f_pt of each gear (lower = "
            "finer; 6 = ground industrial gear)")),
        "runout_grade": Key("int", MANUFACTURING_RUNOUT_GRADE, minimum=min(GRADES), maximum=max(GRADES), doc=(
            "ISO 1328 grade of the radial runout F_r of each gear as mounted (its own runout plus its seat "
            "on the shaft; coarser than the teeth)")),
        "seed": Key("int", 0, minimum=0, doc=(
            "seed of the draw (one seed, one set of errors; recorded in the summary); the pair is numbered from "
            "its most loaded pinion tooth, so a fault on tooth 0 sits where a flank fracture starts")),
        "single_pitch_um": _f(None, "um", "length", "single pitch tolerance f_pt of both gears, instead of the grade's",
                              minimum=0.0, default_doc="from grade"),
        "runout_um": _f(None, "um", "length", "radial runout F_r (= 2 x eccentricity) of both gears, instead of the "
                        "runout grade's", minimum=0.0, default_doc="from runout_grade"),
        "members": Key("str_list", ["pinion", "wheel"], allowed=("pinion", "wheel"),
                       doc="the gears that have errors"),
        "profile_errors": Key("bool", False, doc=(
            "the teeth's profile form deviation f_falpha of `grade` as a mesh-periodic transmission error "
            "(ISO 1328); the paper's simulation had none")),
        "profile_um": _f(None, "um", "length", "peak-to-peak profile form deviation of both gears along the "
                         "line of action, instead of the grade's f_falpha", minimum=0.0, default_doc="from grade"),
    },
    # ---- the drivetrain around the pair: its lumped model and its drive and load (issue 42) ----------
    "drivetrain": {
        "parameters": Key("table", None, doc=(
            "the machine's lumped torsional model: a CSV table in the layout of testbench_lumped_parameters.csv "
            "(path relative to the scene file; docs/DRIVETRAIN.md, 'Another machine'): inertias, stiffnesses, "
            "dampings and ratios, read checked; a 22-node table in the rig's layout maps onto the four FMUs as the "
            "rig's, any other chain by the places its ratios give (the bevel mesh, an upper gearbox; rigid shafts)"),
            default_doc="the rig's table (drivetrain/data/testbench_lumped_parameters.csv)"),
        "coupling_scale": _f(None, "", "", (
            "factor on the stiffness of the elastomer couplings (the table's elements 3-7) instead of the "
            "calibration's (fitted to the rig's 24 Hz mode); 1 = the table's stiffnesses as written "
            "(effects.couplings = fitted; a table in the rig's layout only)"), minimum=0.0, min_exclusive=True,
            default_doc="the calibration's (0.70 shipped)"),
        "drive_Kp": _f(_DL.drive_Kp, "N·m·s/rad", "", (
            "proportional gain of the drive motor's PI speed controller (effects.drive_control = assumed)"),
            minimum=0.0, min_exclusive=True),
        "drive_Ti_s": _f(_DL.drive_Ti_s, "s", "time", "integral time of the PI speed controller "
                         "(effects.drive_control = assumed)", minimum=0.0, min_exclusive=True),
        "drive_Ni": _f(_DL.drive_Ni, "", "", "anti-windup gain of the PI speed controller (LimPID back-calculation)",
                       minimum=0.0, min_exclusive=True),
        "drive_torque_limit_Nm": _f(_DL.drive_torque_limit_Nm, "N·m", "torque", "the drive motor's torque limit",
                                    minimum=0.0, min_exclusive=True),
        "load_law": Key("enum", _DL.load_law, allowed=LOAD_LAWS, doc=(
            "the load motor's law: torque (the rig: the setting as a torque, regularised below load_w_reg_rad_s "
            "so that it brakes but never drives) or viscous (the paper: a torque proportional to the propeller "
            "shaft's speed, equal to the setting at the initial speed)")),
        "load_w_reg_rad_s": _f(_DL.load_w_reg_rad_s, "rad/s", "", (
            "torque law: the propeller-shaft speed below which the load torque is regularised (tanh)"),
            minimum=0.0, min_exclusive=True),
        "load_gear_ratio": _f(_DL.load_gear_ratio, "", "", (
            "the gear between the load motor and the propeller shaft (the rig's 1:8 planetary): load-motor speed / "
            "propeller-shaft speed; operating_point.load_torque_Nm is the load motor's torque before it"),
            minimum=0.0, min_exclusive=True),
        "load_motor_J_kgm2": _f(_DL.load_motor_J_kgm2, "kg·m²", "", (
            "the load motor's rotor inertia, added to the propeller-side body through load_gear_ratio²"), minimum=0.0),
    },
}

def _on(path: str, *values) -> tuple:
    return ((path, values or (True,)),)


_LOAD, _DRIVE, _ORDERS = (_on("effects.load_torque_noise"), _on("effects.drive_torque_noise"),
                          _on("effects.shaft_orders"))
#: When a setting acts: a section or "section.key" -> its alternatives (any), each a tuple of conditions
#: (all) ("section.key", the values that switch it on). A setting not listed always acts; a dataset leaves
#: the label of one that does not act empty (drivetrain.campaigns.dataset), not its unused value.
ACTS_WHEN: dict[str, tuple] = {
    "manufacturing": (_on("effects.manufacturing_errors"),),
    "manufacturing.profile_um": (_on("effects.manufacturing_errors") + _on("manufacturing.profile_errors"),),
    "instruments": (_on("effects.sensors", "rig"),),
    "tooth_compliance": (_on("effects.tooth_compliance"),),
    "background.seed": (_LOAD, _DRIVE, _ORDERS),
    "background.noise_band_Hz": (_LOAD, _DRIVE),
    "background.load_noise_Nm_rtHz": (_LOAD,),
    "background.drive_noise_Nm_rtHz": (_DRIVE,),
    **{f"background.{k}": (_ORDERS,) for k in ("order_msh_1x_Nm", "order_msh_2x_Nm", "order_dsh_1x_Nm",
                                               "order_dsh_2x_Nm", "planetary_mesh_Nm", "planetary_ring_teeth",
                                               "orders_speed_exponent", "order_msh_1x_exponent",
                                               "order_msh_2x_exponent", "order_dsh_1x_exponent",
                                               "order_dsh_2x_exponent")},
    **{f"background.{k}": (_on("effects.drive_control", "record"),) for k in ("drive_Kp", "drive_Ti_s")},
    **{f"drivetrain.{k}": (_on("effects.drive_control", "assumed"),) for k in ("drive_Kp", "drive_Ti_s")},
    "drivetrain.load_w_reg_rad_s": (_on("drivetrain.load_law", "torque"),),
    "drivetrain.coupling_scale": (_on("effects.couplings", "fitted"),),
    **{f"background.{k}": (_on("effects.couplings", "record"),)
       for k in ("coupling_stiffness_scale", "coupling_damping_scale", "propeller_stiffness_scale",
                 "propeller_damping_scale")},
}


def setting_acts(section: str, key: str, scene: dict) -> bool:
    """Whether ``section.key`` acts in a resolved scene (its dict, ``Scene.to_dict()``): :data:`ACTS_WHEN`."""
    rule = ACTS_WHEN.get(f"{section}.{key}", ACTS_WHEN.get(section))
    if rule is None:
        return True

    def value(path):
        sec, k = path.split(".", 1)
        return (scene.get(sec) or {}).get(k)

    return any(all(value(p) in values for p, values in alternative) for alternative in rule)


#: Sections validated by drivetrain.scene.expect (expectations and how a scene is checked; docs/SCENARIOS.md).
CHECK_SECTIONS = ("expect", "check")


# --------------------------------------------------------------------------------------------------
# Resolved scene
# --------------------------------------------------------------------------------------------------


# The resolved sections: every value is filled in by the loader from SCHEMA, which declares each key's
# default once (the dataclasses have none; a section is never built with missing values).

@dataclass(frozen=True)
class ScenarioInfo:
    name: str
    description: str
    noise_name: str | None
    growth_stage: int | None
    remaining_life: float | None


@dataclass(frozen=True)
class OperatingPoint:
    drive_speed_rpm: float
    load_torque_Nm: float
    speed_profile_rpm: tuple[tuple[float, float], ...] | None
    load_profile_Nm: tuple[tuple[float, float], ...] | None
    load_series_csv: Path | None = None      # the file load_profile_Nm was read from (None: given inline)

    def speed_at(self, t: float) -> float:
        """Speed reference [rpm] at time t (profile if given)."""
        return _interp_profile(self.speed_profile_rpm, t, self.drive_speed_rpm)

    def load_at(self, t: float) -> float:
        return _interp_profile(self.load_profile_Nm, t, self.load_torque_Nm)

    @property
    def final_speed_rpm(self) -> float:
        return self.speed_profile_rpm[-1][1] if self.speed_profile_rpm else self.drive_speed_rpm


@dataclass(frozen=True)
class GearSpec:
    health: str
    faults: tuple                        # normalised fault specifications (dicts), health = "faults"
    pinion_mesh: Path | None             # absolute
    wheel_mesh: Path | None              # absolute
    mesh_units: str
    pair: GearPair = RIG_PAIR            # [gear.pair]: .params() BevelGearParams, .pcm() PCMParams


@dataclass(frozen=True)
class TimeSpec:
    duration_s: float
    settle_s: float
    sample_rate_Hz: float

    @property
    def output_period_s(self) -> float:
        return 1.0 / self.sample_rate_Hz


@dataclass(frozen=True)
class OutputSpec:
    sensors: tuple[str, ...]
    variables: tuple[str, ...]
    plots: bool
    aalto_csv: bool
    dtype: str


@dataclass(frozen=True)
class NumericsSpec:
    comm_step_s: float
    max_substep_s: float
    profile_element_mm: float
    face_element_mm: float
    map_points_per_pitch: int
    map_approach_points: int
    mesh_integrator: str
    energy_correction: bool
    anti_alias: str
    max_contact_hours: float
    tolerance_pct: float | None


@dataclass(frozen=True)
class EffectsSpec:
    mesh_contact: str
    shaft_flexibility: str
    shaft_elements: int
    friction: bool
    contact_damping: bool
    losses: bool
    sensors: str
    tooth_compliance: bool
    manufacturing_errors: bool
    drive_torque_noise: bool
    load_torque_noise: bool
    shaft_orders: bool
    drive_control: str
    couplings: str


@dataclass(frozen=True)
class ToothComplianceSpec:
    factor: float


@dataclass(frozen=True)
class ManufacturingSpec:
    grade: int
    runout_grade: int
    seed: int
    single_pitch_um: float | None
    runout_um: float | None
    members: tuple[str, ...]
    profile_errors: bool
    profile_um: float | None


@dataclass(frozen=True)
class DrivetrainSpec:
    parameters: Path | None              # the lumped table (absolute), None: the rig's
    coupling_scale: float | None         # None: the calibration's
    drive_Kp: float
    drive_Ti_s: float
    drive_Ni: float
    drive_torque_limit_Nm: float
    load_law: str
    load_w_reg_rad_s: float
    load_gear_ratio: float
    load_motor_J_kgm2: float


@dataclass(frozen=True)
class Scene:
    """A validated, fully resolved scene (every default filled in, paths absolute)."""

    scenario: ScenarioInfo
    operating_point: OperatingPoint
    gear: GearSpec
    time: TimeSpec
    outputs: OutputSpec
    numerics: NumericsSpec
    effects: EffectsSpec
    instruments: Instruments
    background: Background
    tooth_compliance: ToothComplianceSpec
    manufacturing: ManufacturingSpec
    drivetrain: DrivetrainSpec
    source: Path | None = None           # the file it came from (None if built in code)
    overrides: tuple[str, ...] = ()      # the --set strings applied
    # drivetrain.scene.expect.ExpectSpec of [expect]/[check] (None: absent); not part of what is simulated
    expect: Any = dataclasses.field(default=None, compare=False, repr=False)

    @property
    def name(self) -> str:
        return self.scenario.name

    @property
    def noise_name(self) -> str:
        """The name the run's noise records are drawn with (``scenario.noise_name``, else the scene's name)."""
        return self.scenario.noise_name or self.scenario.name

    def to_dict(self) -> dict:
        """The resolved scene as plain TOML/JSON-able data (same layout as the file)."""
        out: dict[str, dict] = {}
        for section in SCHEMA:
            obj = getattr(self, section)
            d = {}
            for f in dataclasses.fields(obj):
                v = getattr(obj, f.name)
                if v is None or (section == "operating_point" and f.name == "load_profile_Nm"
                                 and obj.load_series_csv is not None):   # read from the file the scene names
                    continue
                if isinstance(v, GearPair):      # the rig's pair is not written: its scenes stay as they were
                    if v.is_rig:
                        continue
                    v = v.as_dict()
                if isinstance(v, Path):
                    v = str(v)
                elif isinstance(v, tuple):
                    v = [list(x) if isinstance(x, tuple) else x for x in v]
                d[f.name] = v
            out[section] = d
        return out

    def to_json(self) -> str:
        return json.dumps({"scene": self.to_dict(), "source": str(self.source) if self.source else None,
                           "overrides": list(self.overrides)}, indent=1)

    def to_toml(self) -> str:
        return dump_toml(self.to_dict())

    def replace(self, **sections) -> "Scene":
        """Copy with whole sections replaced, e.g. ``scene.replace(time=dataclasses.replace(scene.time, duration_s=1))``."""
        return dataclasses.replace(self, **sections)


#: section name -> the dataclass it resolves to
SECTION_CLASSES = {
    "scenario": ScenarioInfo, "operating_point": OperatingPoint, "gear": GearSpec, "time": TimeSpec,
    "outputs": OutputSpec, "numerics": NumericsSpec, "effects": EffectsSpec, "background": Background,
    "instruments": Instruments,
    "tooth_compliance": ToothComplianceSpec, "manufacturing": ManufacturingSpec,
    "drivetrain": DrivetrainSpec,
}


def _interp_profile(profile, t: float, default: float) -> float:
    if not profile:
        return default
    ts = [p[0] for p in profile]
    vs = [p[1] for p in profile]
    if t <= ts[0]:
        return vs[0]
    if t >= ts[-1]:
        return vs[-1]
    for i in range(1, len(ts)):
        if t <= ts[i]:
            a = (t - ts[i - 1]) / (ts[i] - ts[i - 1])
            return vs[i - 1] + a * (vs[i] - vs[i - 1])
    return vs[-1]  # pragma: no cover


# --------------------------------------------------------------------------------------------------
# TOML output and documentation
# --------------------------------------------------------------------------------------------------


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int,)):
        return str(v)
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    return json.dumps(str(v))


def dump_toml(data: dict) -> str:
    lines = []
    for section, content in data.items():
        lines.append(f"[{section}]")
        for k, v in content.items():
            lines.append(f"{k} = {_toml_value(v)}")
        lines.append("")
    return "\n".join(lines)


def schema_markdown() -> str:
    """The key reference table of docs/SCENARIOS.md, generated from SCHEMA (and [gear.pair]'s PAIR_SCHEMA)."""
    out = []
    tables = [(section, keys) for section, keys in SCHEMA.items()]
    tables.insert([s for s, _ in tables].index("gear") + 1, ("gear.pair", PAIR_SCHEMA))
    for section, keys in tables:
        out.append(f"### [{section}]\n")
        out.append("| key | type | unit | default | allowed values | meaning |")
        out.append("|---|---|---|---|---|---|")
        for key, spec in keys.items():
            out.append(_key_row(key, spec))
        out.append("")
    return "\n".join(out)


def _key_row(key: str, spec: Key) -> str:
    """One key's row of the key reference table."""
    if spec.default_doc:
        dflt = spec.default_doc
    elif spec.default is _MISSING:
        dflt = "required"
    elif spec.default is None:
        dflt = "(absent)"
    else:
        dflt = "`" + _toml_value(spec.default) + "`"
    if spec.allowed:
        allowed = ", ".join(f"`{a}`" for a in spec.allowed)
    else:
        rng = []
        if spec.minimum is not None:
            rng.append(f"{'>' if spec.min_exclusive else '>='} {spec.minimum:g}")
        if spec.maximum is not None:
            rng.append(f"<= {spec.maximum:g}")
        allowed = " and ".join(rng)
        if not allowed and spec.type in ("float", "profile"):
            allowed = "any finite value (negative allowed)"
    typ = {"table": "str (path to a CSV)", "faults": "array of tables", "pair": "table", "str_list": "list of str", "var_list": "list of str",
           "profile": "list of [float, float]", "path": "str (path)", "series": "str (path to a CSV)",
           "enum": "str"}.get(spec.type, spec.type)
    return f"| `{key}` | {typ} | {spec.unit or '–'} | {dflt} | {allowed or '–'} | {spec.doc} |"


def all_keys() -> list[str]:
    """Every scene key, "section.key"."""
    return [f"{s}.{k}" for s, keys in SCHEMA.items() for k in keys]


def default_of(key: str) -> Any:
    """The default of a scene key "section.key", as SCHEMA declares it (None: optional, absent)."""
    section, name = key.split(".", 1)
    return SCHEMA[section][name].default
