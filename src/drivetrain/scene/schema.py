"""Scene files: schema, loading, validation, ``--set`` overrides and the resolved ``Scene``.

A scene is a TOML file (documented key by key in ``docs/SCENARIOS.md``). Loading is all-or-nothing:
every problem (unknown key, wrong type or unit, impossible value, inconsistent combination, missing
mesh file) is collected and raised as one :class:`ScenarioError` that names the key, the value and
what was expected, before anything runs.

A *grid* file is a scene with an extra ``[sweep]`` table whose ``axes`` list values for some keys;
it expands to the Cartesian product of those values (see :func:`load_scenes`).

Numbers may be written plainly (in the unit of the key's suffix) or as a string with a unit,
``duration_s = "500 ms"``, ``drive_speed_rpm = "25 Hz"``; a unit of the wrong kind is refused.
"""
from __future__ import annotations

import copy
import dataclasses
import difflib
import itertools
import json
import math
import re
import string
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from drivetrain.errors import MISSING as _MISSING
from drivetrain.errors import ScenarioError
from drivetrain.rig.instruments import Instruments
from drivetrain.system import steps_per_output
from drivetrain.rig.data import RIG_SENSORS, TORQUE_SENSORS, UPPER_RATIO, Z_PINION, Z_WHEEL  # noqa: F401  (re-exported)
from gearcontact_fmu.fault_specs import (FAULT_KINDS, draw_faults, draw_rule_problems, fault_spec_problems,
                                         normalised_spec)
from gearcontact_fmu.manufacturing_specs import DEFAULT_GRADE as MANUFACTURING_GRADE
from gearcontact_fmu.manufacturing_specs import DEFAULT_RUNOUT_GRADE as MANUFACTURING_RUNOUT_GRADE
from gearcontact_fmu.manufacturing_specs import GRADES
from gearcontact_fmu.mesh_model import FIDELITIES, HEALTH_STATES, SCHEMES
from gearcontact_fmu.params import DEFAULT_COMM_STEP_S, TOOTH_COMPLIANCE_FACTOR, MapGrid, MeshResolution

# --------------------------------------------------------------------------------------------------
# Fixed vocabularies
# --------------------------------------------------------------------------------------------------

SHAFT_MODELS = ("flexible", "rigid")
MESH_UNITS = ("mm", "m")
ANTI_ALIAS = ("fir", "butter")
SAMPLE_DTYPES = ("float64", "float32")

#: The rig's sensors: name -> (unit, meaning). The assembler maps each to a "component.variable".


#: a scene name names a directory and files: no path separators, no ".", "..", hidden or option-like names
NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+\-]{0,199}")
NAME_RULE = ("1-200 letters, digits and _ . + -, starting with a letter, digit or _ "
             "(it names the output directory and files)")
#: format spec allowed in a grid name template field (width and precision at most 2 digits)
_SPEC_RE = re.compile(r"[<>^=]?[+\- ]?#?0?\d{0,2}[,_]?(\.\d{1,2})?[bdeEfFgGnosxX%]?")
_VAR_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*\.[A-Za-z_][A-Za-z0-9_.\[\]]*$")

# --------------------------------------------------------------------------------------------------
# Units accepted in "<number> <unit>" strings: unit -> (dimension, factor to the key's base unit)
# --------------------------------------------------------------------------------------------------

_UNITS: dict[str, tuple[str, float]] = {
    # time, base s
    "s": ("time", 1.0), "ms": ("time", 1e-3), "us": ("time", 1e-6), "µs": ("time", 1e-6),
    "min": ("time", 60.0), "h": ("time", 3600.0),
    # rotational speed, base rpm
    "rpm": ("speed", 1.0), "1/min": ("speed", 1.0), "rad/s": ("speed", 60.0 / (2.0 * math.pi)),
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
_BASE_UNIT = {"time": "s", "speed": "rpm", "torque": "N·m", "frequency": "Hz", "length": "mm"}


# --------------------------------------------------------------------------------------------------
# Schema
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Key:
    """One scene key."""

    type: str                       # float | int | bool | str | enum | path | profile | str_list | var_list
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
SENSOR_MODELS = ("ideal", "rig")

SCHEMA: dict[str, dict[str, Key]] = {
    "scenario": {
        "name": Key("str", None, doc="scene name (used for output files and manifests)",
                    default_doc="the file name without .toml"),
        "description": Key("str", "", doc="free text"),
    },
    "operating_point": {
        "drive_speed_rpm": _f(1500.0, "rpm", "speed", "drive-motor speed reference (drive shaft)", minimum=0.0),
        "load_torque_Nm": _f(1.31, "N·m", "torque",
                             "load-motor torque setting, before the 1:8 planetary (paper: 0.12, 0.71, 1.31); "
                             "negative = a reversal: the load motor drives the propeller shaft and the coast "
                             "flanks carry the load"),
        "speed_profile_rpm": Key("profile", None, "rpm", doc=(
            "piecewise-linear speed reference, [[time_s, rpm], ...], times strictly increasing from 0; "
            "held constant after the last point; overrides drive_speed_rpm"), minimum=0.0),
        "load_profile_Nm": Key("profile", None, "N·m", doc=(
            "piecewise-linear load torque, [[time_s, N·m], ...] like speed_profile_rpm; overrides "
            "load_torque_Nm (a step: two points 1 ms apart); values may be negative (a load reversal)")),
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
        "friction": Key("bool", True, doc="tooth friction in the mesh (pcm/table)"),
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
            "tooth position (pitch) errors and runout of pinion and wheel, drawn from [manufacturing] "
            "(pcm, table, analytic; the paper's simulation had none)")),
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
    },
}

GRID_SECTION = "sweep"
GRID_KEYS = {"axes", "name", "draw"}
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


@dataclass(frozen=True)
class OperatingPoint:
    drive_speed_rpm: float
    load_torque_Nm: float
    speed_profile_rpm: tuple[tuple[float, float], ...] | None
    load_profile_Nm: tuple[tuple[float, float], ...] | None

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

    def steps_per_output(self, sample_rate_Hz: float) -> int:
        return int(round(1.0 / (sample_rate_Hz * self.comm_step_s)))


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
    tooth_compliance: ToothComplianceSpec
    manufacturing: ManufacturingSpec
    source: Path | None = None           # the file it came from (None if built in code)
    overrides: tuple[str, ...] = ()      # the --set strings applied
    # drivetrain.scene.expect.ExpectSpec of [expect]/[check] (None: absent); not part of what is simulated
    expect: Any = dataclasses.field(default=None, compare=False, repr=False)

    @property
    def name(self) -> str:
        return self.scenario.name

    def to_dict(self) -> dict:
        """The resolved scene as plain TOML/JSON-able data (same layout as the file)."""
        out: dict[str, dict] = {}
        for section in SCHEMA:
            obj = getattr(self, section)
            d = {}
            for f in dataclasses.fields(obj):
                v = getattr(obj, f.name)
                if v is None:
                    continue
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

    def with_overrides(self, overrides: list[str]) -> "Scene":
        """Re-validate this scene with ``--set`` style overrides applied."""
        raw = self.to_dict()
        if self.expect is not None:
            raw.update(self.expect.raw())
        apply_overrides(raw, overrides)
        base = self.source.parent if self.source else Path.cwd()
        return resolve(raw, base_dir=base, source=self.source, overrides=tuple(self.overrides) + tuple(overrides))


_SECTION_CLASSES = {
    "scenario": ScenarioInfo, "operating_point": OperatingPoint, "gear": GearSpec, "time": TimeSpec,
    "outputs": OutputSpec, "numerics": NumericsSpec, "effects": EffectsSpec, "instruments": Instruments,
    "tooth_compliance": ToothComplianceSpec, "manufacturing": ManufacturingSpec,
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
# Value checking
# --------------------------------------------------------------------------------------------------


def _parse_quantity(key: str, spec: Key, value: str, problems) -> float | None:
    """'500 ms' -> 0.5 for a key in s. Returns None (and records a problem) when refused."""
    m = re.fullmatch(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([^\s\d].*?)?\s*", value)
    expected = f"a number in {spec.unit}" + (
        f" (or a string \"<number> <unit>\" with a {spec.dimension} unit)" if spec.dimension else "")
    if not m:
        problems.append((key, value, expected))
        return None
    number = float(m.group(1))
    unit = (m.group(2) or "").strip()
    if not unit:
        return number
    if unit not in _UNITS:
        problems.append((key, value, f"{expected}; unknown unit {unit!r}"))
        return None
    dim, factor = _UNITS[unit]
    if spec.dimension == "speed" and unit == "Hz":      # a rotation frequency: revolutions per second
        dim, factor = "speed", 60.0
    if dim != spec.dimension:
        problems.append((key, value, f"a {spec.dimension} in {spec.unit} (got a {dim} unit {unit!r}; "
                                     f"e.g. {_BASE_UNIT.get(spec.dimension, spec.unit)})"))
        return None
    # to the key's own unit (a key in um takes "0.01 mm" as 10)
    key_factor = _UNITS[spec.unit][1] if spec.unit in _UNITS and _UNITS[spec.unit][0] == dim else 1.0
    return number * factor / key_factor


def _check_range(key: str, spec: Key, value: float, problems, what: str = "") -> bool:
    ok = math.isfinite(value)
    if ok and spec.minimum is not None:
        ok = value > spec.minimum if spec.min_exclusive else value >= spec.minimum
    if ok and spec.maximum is not None:
        ok = value <= spec.maximum
    if not ok:
        rng = []
        if spec.minimum is not None:
            rng.append(f"{'>' if spec.min_exclusive else '>='} {spec.minimum:g}")
        if spec.maximum is not None:
            rng.append(f"<= {spec.maximum:g}")
        u = f" {spec.unit}" if spec.unit else ""
        problems.append((key, value, f"{what}a finite {spec.type} {' and '.join(rng)}{u}".strip()))
    return ok


def _check_value(key: str, spec: Key, value: Any, base_dir: Path, problems) -> Any:
    t = spec.type
    if t == "float":
        if isinstance(value, bool):
            problems.append((key, value, f"a number in {spec.unit or '1'} (not a boolean)"))
            return None
        if isinstance(value, str) and spec.dimension:
            value = _parse_quantity(key, spec, value, problems)
            if value is None:
                return None
        if not isinstance(value, (int, float)):
            problems.append((key, value, f"a number in {spec.unit}" if spec.unit else "a number"))
            return None
        value = float(value)
        return value if _check_range(key, spec, value, problems) else None
    if t == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            problems.append((key, value, "an integer" + (f" >= {spec.minimum:g}" if spec.minimum is not None else "")))
            return None
        return value if _check_range(key, spec, float(value), problems, "") else None
    if t == "bool":
        if not isinstance(value, bool):
            problems.append((key, value, "true or false"))
            return None
        return value
    if t == "str":
        if not isinstance(value, str):
            problems.append((key, value, "a string"))
            return None
        return value
    if t == "enum":
        if not isinstance(value, str) or value not in spec.allowed:
            problems.append((key, value, "one of " + ", ".join(repr(a) for a in spec.allowed)))
            return None
        return value
    if t == "path":
        if not isinstance(value, str) or not value:
            problems.append((key, value, "a file path (string)"))
            return None
        p = Path(value).expanduser()
        if not p.is_absolute():
            p = (base_dir / p).resolve()
        if p.suffix.lower() not in (".obj", ".stl"):
            problems.append((key, value, "an .obj or .stl mesh file"))
            return None
        if not p.is_file():
            problems.append((key, value, f"an existing mesh file (not found: {p})"))
            return None
        return p
    if t == "faults":
        if not isinstance(value, list):
            problems.append((key, value, "an array of tables [[gear.faults]]"))
            return None
        bad = len(problems)
        for i, spec in enumerate(value):
            for k, v, e in fault_spec_problems(spec, Z_PINION, Z_WHEEL):
                problems.append((f"{key}[{i}]" + (f".{k}" if k else ""), v, e))
        return tuple(normalised_spec(f) for f in value) if len(problems) == bad else None
    if t == "profile":
        exp = (f"a list of [time_s, {spec.unit}] pairs with times >= 0 strictly increasing and "
               + (f"values >= {spec.minimum:g} {spec.unit}" if spec.minimum is not None else "finite values"))
        if not isinstance(value, list) or not value:
            problems.append((key, value, exp))
            return None
        pts = []
        for p in value:
            if (not isinstance(p, list) or len(p) != 2
                    or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in p)
                    or not all(math.isfinite(x) for x in p)):
                problems.append((key, value, exp))
                return None
            pts.append((float(p[0]), float(p[1])))
        ts = [p[0] for p in pts]
        if ts[0] < 0 or any(b <= a for a, b in zip(ts, ts[1:])) or any(
                spec.minimum is not None and p[1] < spec.minimum for p in pts):
            problems.append((key, value, exp))
            return None
        return tuple(pts)
    if t == "str_list":
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            problems.append((key, value, "a list of strings from " + ", ".join(spec.allowed)))
            return None
        bad = [v for v in value if v not in spec.allowed]
        if bad:
            problems.append((key, value, f"names from {', '.join(spec.allowed)} (unknown: {', '.join(bad)})"))
            return None
        if len(set(value)) != len(value):
            problems.append((key, value, "a list without duplicates"))
            return None
        return tuple(value)
    if t == "var_list":
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            problems.append((key, value, 'a list of "component.variable" strings'))
            return None
        bad = [v for v in value if not _VAR_RE.match(v)]
        if bad:
            problems.append((key, value, f'"component.variable" strings (malformed: {", ".join(bad)})'))
            return None
        if len(set(value)) != len(value):
            problems.append((key, value, "a list without duplicates"))
            return None
        return tuple(value)
    raise AssertionError(t)  # pragma: no cover


def _suggest(name: str, candidates) -> str:
    close = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.5)
    return f"; did you mean {close[0]!r}?" if close else ""


def _unit_hint(section: str, key: str) -> str:
    """For a key that looks like a known key with another unit suffix, say so."""
    stem = key.rsplit("_", 1)[0] if "_" in key else key
    for k, spec in SCHEMA.get(section, {}).items():
        if spec.unit and k.rsplit("_", 1)[0] == stem and k != key:
            return f"; wrong unit: the key is {k!r} (unit {spec.unit})"
    return ""


def resolve(raw: dict, base_dir: Path | str = ".", source: Path | str | None = None,
            overrides: tuple[str, ...] = ()) -> Scene:
    """Validate raw scene data (as parsed from TOML) and return the resolved :class:`Scene`."""
    base_dir = Path(base_dir)
    src = str(source) if source else None
    problems: list[tuple[str, Any, str]] = []
    if not isinstance(raw, dict):
        raise ScenarioError([("(scene)", raw, "a table of sections")], src)
    values: dict[str, dict[str, Any]] = {}
    for section, content in raw.items():
        if section in CHECK_SECTIONS:
            continue
        if section not in SCHEMA:
            known = (*SCHEMA, *CHECK_SECTIONS)
            problems.append((section, content if not isinstance(content, dict) else "{...}",
                             "a known section: " + ", ".join(known) + _suggest(section, known)))
            continue
        if not isinstance(content, dict):
            problems.append((section, content, f"a table [{section}]"))
            continue
        for key, value in content.items():
            full = f"{section}.{key}"
            if key not in SCHEMA[section]:
                hint = _unit_hint(section, key) or _suggest(key, SCHEMA[section])
                problems.append((full, value, f"a known key of [{section}]: "
                                 + ", ".join(SCHEMA[section]) + hint))
                continue
            checked = _check_value(full, SCHEMA[section][key], value, base_dir, problems)
            if checked is not None:
                values.setdefault(section, {})[key] = checked
            else:
                values.setdefault(section, {})[key] = _MISSING  # marks "given but bad"

    # defaults and required keys
    for section, keys in SCHEMA.items():
        sv = values.setdefault(section, {})
        for key, spec in keys.items():
            if key not in sv:
                if spec.default is _MISSING:
                    problems.append((f"{section}.{key}", _MISSING, f"a value ({spec.doc})"))
                else:
                    sv[key] = copy.deepcopy(spec.default)
                    if isinstance(sv[key], list):
                        sv[key] = tuple(sv[key])

    def ok(section, *keys):
        return all(values[section].get(k) is not _MISSING for k in keys)

    # ---- cross-key checks --------------------------------------------------------------------
    if values["scenario"].get("name") is None:
        values["scenario"]["name"] = Path(source).stem if source else "scene"
    name = values["scenario"]["name"]
    if name is not _MISSING and not NAME_RE.fullmatch(str(name)):
        problems.append(("scenario.name", name, NAME_RULE))

    tm = values["time"]
    if ok("time", "duration_s", "settle_s"):
        if tm["settle_s"] is None:
            tm["settle_s"] = min(2.0, 0.2 * tm["duration_s"])
        elif tm["settle_s"] >= tm["duration_s"]:
            problems.append(("time.settle_s", tm["settle_s"],
                             f"a settling time shorter than time.duration_s = {tm['duration_s']:g} s"))

    if ok("time", "duration_s", "sample_rate_Hz") and tm["duration_s"] * tm["sample_rate_Hz"] < 16.0 * (1 - 1e-9):
        # the run is a whole number of output samples: a longer period would stretch it silently
        problems.append(("time.sample_rate_Hz", tm["sample_rate_Hz"],
                         f"at least 16 output samples in time.duration_s = {tm['duration_s']:g} s, i.e. "
                         f">= {16.0 / tm['duration_s']:.6g} Hz (the run is a whole number of sample periods)"))
    nm = values["numerics"]
    if ok("numerics", "comm_step_s") and ok("time", "sample_rate_Hz"):
        _, expected = steps_per_output(nm["comm_step_s"], tm["sample_rate_Hz"])
        if expected:
            problems.append(("numerics.comm_step_s", nm["comm_step_s"], expected))
    if ok("numerics", "comm_step_s", "max_substep_s") and nm["max_substep_s"] > nm["comm_step_s"] * (1 + 1e-12):
        problems.append(("numerics.max_substep_s", nm["max_substep_s"],
                         f"a sub-step <= numerics.comm_step_s = {nm['comm_step_s']:.6g} s"))

    gr = values["gear"]
    eff = values["effects"]
    if ok("gear", "health", "faults"):
        if gr["health"] == "faults" and not gr["faults"]:
            problems.append(("gear.faults", _MISSING, 'at least one [[gear.faults]] table when gear.health = "faults"'))
        elif gr["faults"] and gr["health"] != "faults":
            problems.append(("gear.faults", f"{len(gr['faults'])} fault(s)",
                             f'no [[gear.faults]] unless gear.health = "faults" (health is {gr["health"]!r})'))
    if ok("gear", "health", "pinion_mesh", "wheel_mesh"):
        if gr["health"] == "mesh":
            if gr["pinion_mesh"] is None and gr["wheel_mesh"] is None:
                problems.append(("gear.pinion_mesh", _MISSING,
                                 'a mesh file (gear.pinion_mesh and/or gear.wheel_mesh) when gear.health = "mesh"'))
        else:
            for k in ("pinion_mesh", "wheel_mesh"):
                if gr[k] is not None:
                    problems.append((f"gear.{k}", str(gr[k]),
                                     f'no mesh file unless gear.health = "mesh" (health is {gr["health"]!r})'))
        if ok("effects", "mesh_contact"):
            if eff["mesh_contact"] == "ideal" and gr["health"] != "healthy":
                problems.append(("effects.mesh_contact", "ideal",
                                 f"a fidelity with tooth geometry (pcm or table) for gear.health = "
                                 f"{gr['health']!r}; the ideal gear has no teeth"))
            if eff["mesh_contact"] == "analytic" and gr["health"] != "healthy":
                problems.append(("effects.mesh_contact", "analytic",
                                 f"pcm or table for gear.health = {gr['health']!r} (the analytic ISO 6336 pair "
                                 "models the healthy gear only: it has no fault and cannot read a mesh)"))

    if ok("effects", "mesh_contact", "tooth_compliance") and eff["tooth_compliance"] \
            and eff["mesh_contact"] in ("pcm", "ideal"):
        problems.append(("effects.tooth_compliance", True,
                         f"false with effects.mesh_contact = \"{eff['mesh_contact']}\" (the series compliance is "
                         "applied to the contact map: use table; the analytic ISO 6336 pair has it already)"))
    if ok("effects", "mesh_contact", "manufacturing_errors") and eff["manufacturing_errors"] \
            and eff["mesh_contact"] == "ideal":
        problems.append(("effects.manufacturing_errors", True,
                         "false with effects.mesh_contact = \"ideal\" (a rigid mesh has no mesh coordinate for the "
                         "errors to offset; use pcm, table or analytic)"))

    op = values["operating_point"]
    for pk in ("speed_profile_rpm", "load_profile_Nm"):
        prof = op.get(pk)
        if prof not in (None, _MISSING) and prof[0][0] != 0.0:
            problems.append((f"operating_point.{pk}", [list(p) for p in prof], "a profile starting at time 0"))

    expect = None
    if any(s in raw for s in CHECK_SECTIONS):
        from drivetrain.scene.expect import parse_checks

        expect = parse_checks(raw.get("expect"), raw.get("check"), values, base_dir, problems,
                              strict=not overrides)

    if problems:
        raise ScenarioError(problems, src)

    sections = {}
    for section, cls in _SECTION_CLASSES.items():
        sections[section] = cls(**values[section])
    return Scene(**sections, source=Path(source).resolve() if source else None, overrides=tuple(overrides),
                 expect=expect)


# --------------------------------------------------------------------------------------------------
# Overrides
# --------------------------------------------------------------------------------------------------


def parse_override(text: str) -> tuple[list[str], Any]:
    """'time.duration_s=0.5' -> (['time', 'duration_s'], 0.5). The value is read as a TOML value
    (numbers, true/false, "strings", [lists]); anything that is not valid TOML is taken as a string."""
    if "=" not in text:
        raise ScenarioError([(text, _MISSING, "an override of the form section.key=value")])
    key, _, value = text.partition("=")
    key = key.strip()
    parts = key.split(".")
    if len(parts) != 2 or not all(parts):
        raise ScenarioError([(key, value, "a key of the form section.key (e.g. time.duration_s)")])
    value = value.strip()
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value
    return parts, parsed


def apply_overrides(raw: dict, overrides: list[str] | tuple[str, ...]) -> dict:
    """Apply ``--set`` strings to raw scene data in place (validation happens in :func:`resolve`)."""
    for text in overrides or ():
        (section, key), value = parse_override(text)
        tbl = raw.setdefault(section, {})
        if not isinstance(tbl, dict):
            raise ScenarioError([(section, tbl, f"a table [{section}]")])
        tbl[key] = value
    return raw


# --------------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------------


def read_toml(path: Path | str) -> dict:
    path = Path(path)
    if not path.is_file():
        raise ScenarioError([("(file)", str(path), "an existing scene file")])
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError([("(file)", str(path), f"valid TOML ({exc})")], str(path)) from None
    except UnicodeDecodeError as exc:
        raise ScenarioError([("(file)", str(path), f"a UTF-8 text file (TOML); byte {exc.start} is not UTF-8 "
                             "(a binary file?)")], str(path)) from None
    except OSError as exc:
        raise ScenarioError([("(file)", str(path), f"a readable file ({exc.strerror or exc})")], str(path)) from None


def is_grid(path: Path | str) -> bool:
    return GRID_SECTION in read_toml(path)


def _split_grid(raw: dict, src: str):
    grid = raw.pop(GRID_SECTION, None)
    if grid is None:
        return None, None, None
    problems = []
    if not isinstance(grid, dict):
        raise ScenarioError([(GRID_SECTION, grid, "a table [sweep] with axes = {\"section.key\" = [values]}")], src)
    for k in grid:
        if k not in GRID_KEYS:
            problems.append((f"{GRID_SECTION}.{k}", grid[k], "a known key of [sweep]: axes, name, draw"))
    draw = grid.get("draw")
    if draw is not None:
        problems.extend(_draw_problems(draw))
    axes = grid.get("axes", {} if draw is not None else None)
    if not isinstance(axes, dict) or not (axes or draw is not None):
        problems.append((f"{GRID_SECTION}.axes", axes, 'a table {"section.key" = [value, ...]} with at least one axis'))
        axes = {}
    for k, vals in axes.items():
        parts = k.split(".")
        if len(parts) != 2 or parts[0] not in SCHEMA or parts[1] not in SCHEMA[parts[0]]:
            problems.append((f"{GRID_SECTION}.axes.{k}", vals, "a scene key of the form section.key"))
        elif not isinstance(vals, list) or not vals:
            problems.append((f"{GRID_SECTION}.axes.{k}", vals, "a non-empty list of values"))
    template = grid.get("name", None)
    if template is not None and not isinstance(template, str):
        problems.append((f"{GRID_SECTION}.name", template, "a name template string, e.g. \"run_{gear.health}\""))
    if problems:
        raise ScenarioError(problems, src)
    return axes, template, draw


DRAW_KEYS = {"n", "seed", "faults"}


def _draw_problems(draw) -> list:
    """Problems of ``[sweep.draw]``: ``n`` drawn cases per axes combination, ``seed``, and
    ``[[sweep.draw.faults]]`` templates (gearcontact_fmu.fault_specs.draw_rule_problems)."""
    key = f"{GRID_SECTION}.draw"
    if not isinstance(draw, dict):
        return [(key, draw, "a table [sweep.draw] with n, seed and [[sweep.draw.faults]]")]
    problems = [(f"{key}.{k}", v, "a key of [sweep.draw]: n, seed, faults") for k, v in draw.items()
                if k not in DRAW_KEYS]
    for k in ("n", "seed"):
        v = draw.get(k)
        if isinstance(v, bool) or not isinstance(v, int) or v < (1 if k == "n" else 0):
            problems.append((f"{key}.{k}", v, "an integer >= 1" if k == "n" else "an integer seed >= 0"))
    tpls = draw.get("faults")
    if not isinstance(tpls, list) or not tpls:
        problems.append((f"{key}.faults", tpls, "at least one [[sweep.draw.faults]] table"))
        return problems
    for i, tpl in enumerate(tpls):
        problems += [(f"{key}.faults[{i}]" + (f".{k}" if k else ""), v, e) for k, v, e in draw_rule_problems(tpl)]
    return problems


def case_name(template: str, base: str, scene: "Scene", src: str = "") -> str:
    """The name of a grid case from the ``[sweep] name`` template: literal text and fields ``{base}`` or
    ``{section.key}`` (a scene key), each with an optional short format spec (``{operating_point.
    drive_speed_rpm:g}``, width and precision at most 2 digits). Nothing else is evaluated (no
    attribute or index walking, no conversions); characters other than letters, digits and ``_ . + -``
    become ``_``, and the result must be a valid scene name."""
    key = f"{GRID_SECTION}.name"

    def bad(why):
        return ScenarioError([(key, template, why)], src)

    out = []
    try:
        parts = list(string.Formatter().parse(template))
    except ValueError as exc:
        raise bad(f"a valid name template ({exc})") from None
    for literal, field, spec, conv in parts:
        out.append(literal)
        if field is None:
            continue
        if conv is not None:
            raise bad(f"fields without conversions (!{conv} in {{{field}}})")
        if not _SPEC_RE.fullmatch(spec or ""):
            raise bad(f"a short format spec such as :g or :.1f, not {spec!r} in {{{field}}}")
        if field == "base":
            value = base
        else:
            sec, _, k = field.partition(".")
            if sec not in SCHEMA or k not in SCHEMA[sec]:
                raise bad(f"fields {{base}} or {{section.key}} of scene keys, not {{{field}}}")
            value = getattr(getattr(scene, sec), k)
        try:
            out.append(format(value, spec or ""))
        except (TypeError, ValueError) as exc:
            raise bad(f"a format spec that suits {field} = {value!r} ({exc})") from None
    nm = re.sub(r"[^A-Za-z0-9_.+\-]", "_", "".join(out))
    if not NAME_RE.fullmatch(nm):
        raise bad(f"names that are valid scene names ({NAME_RULE}), not {nm[:80]!r}")
    return nm


def load_scenes(path: Path | str, overrides: list[str] | tuple[str, ...] = ()) -> list[Scene]:
    """Load a scene file (one scene) or a grid file (its expansion). ``overrides`` change the base scene;
    overriding a swept key is refused. All cases are validated before any is returned."""
    path = Path(path)
    src = str(path)
    raw = read_toml(path)
    grid_expect = raw[GRID_SECTION].pop("expect", None) if isinstance(raw.get(GRID_SECTION), dict) else None
    axes, template, draw = _split_grid(raw, src)
    overrides = tuple(overrides or ())
    apply_overrides(raw, overrides)
    if axes is None:
        return [resolve(raw, base_dir=path.parent, source=path, overrides=overrides)]
    for text in overrides:
        k = text.partition("=")[0].strip()
        if k in axes:
            raise ScenarioError([(k, text.partition("=")[2], f"a key that is not a sweep axis of {path.name} "
                                  f"(axes: {', '.join(axes)})")], src)
    scenes, problems, names = [], [], set()
    keys = list(axes)
    # random faults: n drawn cases per axes combination, one Generator for the whole grid (reproducible)
    rng = np.random.default_rng(draw["seed"]) if draw else None
    draws = range(draw["n"]) if draw else [None]
    for combo, d in itertools.product(itertools.product(*(axes[k] for k in keys)), draws):
        case = copy.deepcopy(raw)
        for k, v in zip(keys, combo):
            sec, key = k.split(".")
            case.setdefault(sec, {})[key] = v
        if d is not None:
            case.setdefault("gear", {}).update(
                health="faults", faults=draw_faults(draw["faults"], rng, Z_PINION, Z_WHEEL))
        case.setdefault("scenario", {}).pop("name", None)
        try:
            sc = resolve(case, base_dir=path.parent, source=path, overrides=overrides)
        except ScenarioError as exc:
            problems.extend(exc.problems)
            continue
        base_name = raw.get("scenario", {}).get("name", path.stem)
        nm = case_name(template or "_".join(["{base}"] + ["{" + k + "}" for k in keys]), base_name, sc, src)
        if d is not None:
            nm += f"_draw{d:03d}"
        if nm in names:
            raise ScenarioError([(f"{GRID_SECTION}.name", template, f"a template giving unique names ({nm!r} twice)")], src)
        names.add(nm)
        if grid_expect is not None:          # [sweep.expect."<case name pattern>"]: more checks per case
            from drivetrain.scene.expect import case_expectations

            extra = case_expectations(grid_expect, nm, problems)
            if extra:
                case["expect"] = {**(case.get("expect") or {}), **extra}
                try:
                    sc = resolve(case, base_dir=path.parent, source=path, overrides=overrides)
                except ScenarioError as exc:
                    problems.extend(exc.problems)
                    continue
        scenes.append(dataclasses.replace(sc, scenario=dataclasses.replace(sc.scenario, name=nm)))
    if grid_expect is not None:
        from drivetrain.scene.expect import unmatched_case_patterns

        problems.extend(unmatched_case_patterns(grid_expect, names))
    if problems:
        raise ScenarioError(list({(k, repr(v), e): (k, v, e) for k, v, e in problems}.values()), src)
    return scenes


def load_scene(path: Path | str, overrides: list[str] | tuple[str, ...] = (), case: str | None = None) -> Scene:
    """Load one scene. For a grid file, ``case`` selects one expanded scene by name."""
    scenes = load_scenes(path, overrides)
    if case is not None:
        for s in scenes:
            if s.name == case:
                return s
        raise ScenarioError([("case", case, "one of " + ", ".join(s.name for s in scenes))], str(path))
    if len(scenes) != 1:
        raise ScenarioError([("(file)", str(path), f"a single scene; this grid expands to {len(scenes)} "
                              "(choose one with --case NAME, or use `drivetrain sweep`)")], str(path))
    return scenes[0]


def scene_from_dict(raw: dict, base_dir: Path | str = ".", overrides=()) -> Scene:
    """Build a scene in code (tests, sweeps): ``raw`` has the file's layout; missing keys default."""
    raw = copy.deepcopy(raw)
    apply_overrides(raw, overrides)
    return resolve(raw, base_dir=base_dir, overrides=tuple(overrides))


def default_scene(**overrides_by_key) -> Scene:
    """The all-defaults scene; keyword overrides like ``time__duration_s=0.5``."""
    raw: dict = {}
    for k, v in overrides_by_key.items():
        sec, key = k.split("__", 1)
        raw.setdefault(sec, {})[key] = v
    return resolve(raw)


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
    """The key reference table of docs/SCENARIOS.md, generated from SCHEMA."""
    out = []
    for section, keys in SCHEMA.items():
        out.append(f"### [{section}]\n")
        out.append("| key | type | unit | default | allowed values | meaning |")
        out.append("|---|---|---|---|---|---|")
        for key, spec in keys.items():
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
            typ = {"faults": "array of tables", "str_list": "list of str", "var_list": "list of str", "profile": "list of [float, float]",
                   "path": "str (path)", "enum": "str"}.get(spec.type, spec.type)
            out.append(f"| `{key}` | {typ} | {spec.unit or '–'} | {dflt} | {allowed or '–'} | {spec.doc} |")
        out.append("")
    return "\n".join(out)


def all_keys() -> list[str]:
    return [f"{s}.{k}" for s, keys in SCHEMA.items() for k in keys]


def default_of(key: str) -> Any:
    """The default of a scene key "section.key", as SCHEMA declares it (None: optional, absent)."""
    section, name = key.split(".", 1)
    return SCHEMA[section][name].default


__all__ = [
    "Scene", "ScenarioInfo", "OperatingPoint", "GearSpec", "TimeSpec", "OutputSpec", "NumericsSpec",
    "EffectsSpec", "ScenarioError", "SCHEMA", "RIG_SENSORS", "TORQUE_SENSORS", "HEALTH_STATES", "FIDELITIES",
    "load_scene", "load_scenes", "resolve", "apply_overrides", "parse_override", "scene_from_dict",
    "default_scene", "schema_markdown", "dump_toml", "all_keys", "default_of", "is_grid", "Z_PINION", "Z_WHEEL", "UPPER_RATIO",
]
