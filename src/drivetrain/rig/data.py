"""The rig's parameters: the public 22-inertia lumped model, its lumping and partition into FMUs, the
calibrated losses and coupling stiffness, and the steady state (the cut checks: ``drivetrain.models.stability``).

Sources: ``data/testbench_lumped_parameters.csv`` (Manngard et al. 2022, public model of the same
bench; another machine's table in its layout: a scene's ``[drivetrain] parameters``, :func:`partition`'s ``model``), ``data/calibration.json`` (written by ``drivetrain calibrate``; losses fitted to
``data/measured_mean_torques.csv``, elastomer stiffness fitted to the measured 24 Hz mode).
Why the partition is what it is: docs/DRIVETRAIN.md.

Conventions. Public node i (1..22) has inertia J_i and ground damping c_ext_i; element i joins nodes i
and i+1 with stiffness k_i and damping c_i, ratio r_i = speed(i+1)/speed(i); a geared element's
stiffness acts in the frame of node i+1 (this reproduces the published 27.9/39.6/68.2 Hz). Nodes
1-12 turn with the drive shaft (frame ratio R = 1), 13-17 with the middle shaft (R = 1/3), 18-22 with
the propeller shaft (R = 1/12). Lumping works on the model referred to the drive shaft (J R^2,
k R^2); component parameters are given back in each component's own frame.
"""
from __future__ import annotations

import csv
import functools
import json
import math
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np

from drivetrain.errors import ConfigurationError
from drivetrain.rig.lumped_table import read_lumped_table
from gearcontact_fmu.params import GEAR_MODEL, BevelGearParams

DATA = Path(__file__).resolve().parents[1] / "data"
PUBLIC_CSV = DATA / "testbench_lumped_parameters.csv"
MEASURED_CSV = DATA / "measured_mean_torques.csv"
CALIBRATION_JSON = DATA / "calibration.json"

def rpm_to_rad_s(speed_rpm):
    """A speed in rpm as an angular velocity in rad/s: ``speed_rpm * pi / 30`` (a float or an array,
    elementwise). The one conversion of the package; :data:`RAD_S_PER_RPM` is its factor."""
    return speed_rpm * math.pi / 30.0


#: rad/s per rpm: ``rpm_to_rad_s(1.0)`` (= 2 pi / 60 to the last bit); the motors and the line kernel multiply by it
RAD_S_PER_RPM = rpm_to_rad_s(1.0)

G_STEEL = 79.3e9          # Pa
RHO_STEEL = 7850.0        # kg/m^3
TINY_J = 1e-5             # kg m^2: hub inertias below this are condensed into their neighbours
Z_PINION = BevelGearParams.z_pinion     # the lower bevel pair's tooth counts (declared in gearcontact_fmu.params)
Z_WHEEL = BevelGearParams.z_wheel
UPPER_RATIO = 3.0
LOWER_RATIO = Z_WHEEL / Z_PINION        # 4
PG_RATIO = 8.0
ELASTOMER_ELEMENTS = (3, 4, 5, 6, 7)      # the elastomer coupling elements (k ~ 90 N m/rad)
THIN_SHAFTS = {11: "drive shaft", 14: "middle shaft", 16: "pinion shaft", 21: "propeller shaft"}
GEAR_ELEMENT_UPPER = 12
GEAR_ELEMENT_LOWER = 17

#: Fallback calibration (used only if data/calibration.json is missing): see calibrate.py.
#: the rig's instruments: name -> (unit, description); the torque transducers among them
RIG_SENSORS: dict[str, tuple[str, str]] = {
    "drive_shaft_torque": ("N.m", "drive-shaft torque transducer (before the upper gearbox), 'Torq1'"),
    "propeller_shaft_torque": ("N.m", "propeller-shaft torque transducer (after the lower gearbox), 'Torq2'"),
    "enc1": ("rad", "encoder 1, drive shaft (motor end): shaft angle"),
    "enc2": ("rad", "encoder 2, drive shaft (gearbox end): shaft angle"),
    "enc3": ("rad", "encoder 3, middle shaft (upper end): shaft angle"),
    "enc4": ("rad", "encoder 4, middle shaft (pinion end): shaft angle"),
    "enc5": ("rad", "encoder 5, propeller shaft: shaft angle"),
}
TORQUE_SENSORS = ("drive_shaft_torque", "propeller_shaft_torque")

#: The paper's operating points (the measured table's grid, MEASURED_CSV): drive speeds [rpm] ...
PAPER_SPEEDS_RPM = (250.0, 500.0, 750.0, 1000.0, 1250.0, 1500.0)
#: ... and load-motor torque settings [N·m], lightest first
PAPER_LOADS_NM = (0.12, 0.71, 1.31)
PAPER_MAX_SPEED_RPM = PAPER_SPEEDS_RPM[-1]      #: 1500 rpm
PAPER_MAX_LOAD_NM = PAPER_LOADS_NM[-1]          #: 1.31 N·m


@dataclass(frozen=True)
class DriveLoad:
    """The drive's speed controller and the load motor as the rig runs them: the defaults of the scene's
    ``[drivetrain]`` keys and of MotorLoad's parameters (declared here once)."""

    drive_Kp: float = 0.1                  #: N m s/rad, proportional gain of the PI speed controller
    drive_Ti_s: float = 0.4                #: s, its integral time (a ~2 Hz speed loop; assumed, not identified)
    drive_Ni: float = 0.9                  #: anti-windup gain (LimPID back-calculation)
    drive_torque_limit_Nm: float = 10.0    #: the drive motor's torque limit
    load_law: str = "torque"               #: the load motor's law: one of LOAD_LAWS
    load_w_reg_rad_s: float = 0.05         #: torque law: propeller-shaft speed below which the setting is regularised
    load_gear_ratio: float = PG_RATIO      #: the planetary between the load motor and the propeller shaft
    load_motor_J_kgm2: float = 0.0         #: the load motor's rotor inertia (referred through load_gear_ratio^2)


#: the load motor's laws, in the order of MotorLoad's ``load_mode`` (0 torque setting, 1 viscous)
LOAD_LAWS = ("torque", "viscous")
RIG_DRIVE_LOAD = DriveLoad()

FALLBACK_CALIBRATION = {
    "coupling_scale": 0.70,
    "upper": {"c_v": 1.5e-3, "T_c": 0.34, "w_c": 16.9, "a": 0.058},
    "planetary": {"c_v": 0.107, "T_c": 2.85, "w_c": 2.12, "a": 0.028},
}


# ------------------------------------------------------------------------------------------------
# Public model
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class PublicModel:
    J: np.ndarray          # [22] kg m^2, own frames
    c_ext: np.ndarray      # [22]
    k: np.ndarray          # [21] N m/rad (frame of node i+1)
    c: np.ndarray          # [21]
    ratio: np.ndarray      # [21] speed(i+1)/speed(i)

    @property
    def R(self) -> np.ndarray:
        """Speed ratio of each node relative to the drive shaft."""
        R = np.ones(len(self.J))
        for i, r in enumerate(self.ratio):
            R[i + 1] = R[i] * r
        return R


def load_public(path: str | Path | None = None) -> PublicModel:
    """The lumped model of a table in the layout of ``data/testbench_lumped_parameters.csv`` (``path``; default:
    that shipped table, the rig's), read checked (:func:`drivetrain.rig.lumped_table.read_lumped_table`:
    FileFormatError naming the file, the row and what was wrong)."""
    t = read_lumped_table(path or PUBLIC_CSV)
    return PublicModel(t["J"], t["c_ext"], t["k"], t["c"], t["ratio"])


# ---- another machine's table: the places the partition maps onto the four FMUs ------------------------

#: the rig's layout, which the partition maps onto the FMUs by place: nodes, and the geared elements
RIG_LAYOUT_NODES = 22


def tooth_ratio(ratio: float) -> Fraction:
    """A table's speed ratio as the ratio of whole numbers it is written for: the nearest fraction with a
    denominator up to 1000 when within 1e-9 of it (``0.3333333333`` -> 1/3), else the number itself.
    The components' frames use it (the rig's 3 and 12 exactly)."""
    frac = Fraction(float(ratio)).limit_denominator(1000)
    return frac if abs(float(frac) - ratio) <= 1e-9 * abs(ratio) else Fraction(float(ratio))


def layout_problems(model: PublicModel, lower_ratio: float | None = None) -> list[str]:
    """Why ``model`` cannot be partitioned into the drivetrain FMUs ([] if it can). A table of 22 nodes is in the
    rig's layout (docs/DRIVETRAIN.md): element 12 the upper gearbox (any ratio), element 17 the bevel mesh (the
    pair's z1/z2), every other element ratio 1, the rig's places; any other chain has its places found from its
    ratios (:func:`chain_places`)."""
    n = len(model.J)
    if n != RIG_LAYOUT_NODES:                # another chain: its places from its ratios (chain_places)
        return [f"{p} (a table of {n} nodes: docs/DRIVETRAIN.md, 'Another machine'; `drivetrain eigen --parameters "
                "FILE` reports the modes of any chain)" for p in chain_places(model, lower_ratio)[1]]
    out = []
    want = Z_PINION / Z_WHEEL if lower_ratio is None else 1.0 / lower_ratio
    r17 = float(model.ratio[GEAR_ELEMENT_LOWER - 1])
    if abs(r17 - want) > 1e-9 * want:
        out.append(f"element {GEAR_ELEMENT_LOWER} (the bevel mesh) has ratio_next = {r17:.10g}; the gear pair's "
                   f"z1/z2 = {want:.10g}")
    odd = [i + 1 for i, r in enumerate(model.ratio) if i + 1 not in (GEAR_ELEMENT_UPPER, GEAR_ELEMENT_LOWER)
           and r != 1.0]
    if odd:
        out.append(f"element(s) {', '.join(map(str, odd))} have ratio_next != 1; in the rig's layout only elements "
                   f"{GEAR_ELEMENT_UPPER} (upper gearbox) and {GEAR_ELEMENT_LOWER} (bevel mesh) are geared")
    return out


@dataclass(frozen=True)
class Places:
    """Where the components sit in a lumped table (public node and element numbers): the drive motor, the drive
    flywheel, the upper gearbox's body (its first node), the upper gearbox's geared element (0: none, ratio 1),
    the bevel mesh's element, the pinion, the wheel, the load."""

    motor: int
    flywheel: int
    upper: int
    upper_gear: int
    mesh: int
    pinion: int
    wheel: int
    load: int


#: the rig's places (its 22-node layout: docs/DRIVETRAIN.md, section 1)
RIG_PLACES = Places(motor=1, flywheel=5, upper=GEAR_ELEMENT_UPPER, upper_gear=GEAR_ELEMENT_UPPER,
                    mesh=GEAR_ELEMENT_LOWER, pinion=GEAR_ELEMENT_LOWER, wheel=GEAR_ELEMENT_LOWER + 1, load=22)


def chain_places(model: PublicModel, lower_ratio: float | None = None) -> tuple[Places | None, list[str]]:
    """The places of a table outside the rig's layout (any chain; docs/DRIVETRAIN.md, "Another machine"), found
    from its ratios: the bevel mesh is the last geared element (its ratio the pair's z1/z2), an upper gearbox the
    geared element before it (if any; its two nodes are one rigid body), the motor node 1, the load the last node,
    the wheel the node after the mesh, the pinion the node before it, the flywheel the heaviest node between the
    motor and the upper body (without an upper gearbox: the node before the pinion). (places, []) or (None, the
    problems)."""
    n = len(model.J)
    want = Z_PINION / Z_WHEEL if lower_ratio is None else 1.0 / lower_ratio
    geared = [i + 1 for i, r in enumerate(model.ratio) if r != 1.0]
    if not geared or abs(float(model.ratio[geared[-1] - 1]) - want) > 1e-9 * want:
        had = (f"element {geared[-1]} has ratio_next = {float(model.ratio[geared[-1] - 1]):.10g}" if geared
               else "no element has ratio_next != 1")
        return None, [f"the bevel mesh is the last geared element, its ratio_next the gear pair's z1/z2 = {want:.10g}; "
                      f"{had}"]
    if len(geared) > 2:
        return None, [f"elements {', '.join(map(str, geared))} are geared: at most two (an upper gearbox and the "
                      "bevel mesh, the last)"]
    mesh = geared[-1]
    ug = geared[0] if len(geared) == 2 else 0
    upper = ug if ug else mesh - 1
    last_upper = ug + 1 if ug else upper
    problems = []
    if upper < 3:
        problems.append(f"node {upper} would be the upper gearbox's body: a run needs the motor (node 1) and at least "
                        "one flywheel node before it")
    if last_upper >= mesh:
        problems.append(f"the upper gearbox (element {ug}) joins the bevel mesh's input node {mesh}: a run needs a "
                        "shaft (an element) between them")
    if n < mesh + 2:
        problems.append(f"the wheel (node {mesh + 1}) is the last node: a run needs a load node after it")
    if problems:
        return None, problems
    flywheel = 2 + int(np.argmax(model.J[1:upper - 1]))
    return Places(1, flywheel, upper, ug, mesh, mesh, mesh + 1, n), []


def public_matrices(model: PublicModel | None = None, referred: bool = True):
    """(M, K, C) of the unlumped public model referred to the drive shaft (the independent oracle)."""
    m = model or load_public()
    R = m.R
    n = len(m.J)
    M = np.diag(m.J * R ** 2)
    K = np.zeros((n, n))
    C = np.diag(m.c_ext * R ** 2)
    for i in range(n - 1):
        s = R[i + 1] ** 2
        for A, v in ((K, m.k[i] * s), (C, m.c[i] * s)):
            A[i, i] += v
            A[i + 1, i + 1] += v
            A[i, i + 1] -= v
            A[i + 1, i] -= v
    return M, K, C


def load_calibration(path: str | Path | None = None) -> dict:
    """The calibration: ``path``, else $DRIVETRAIN_CALIBRATION, else the shipped data/calibration.json
    (else the built-in fallback)."""
    import os

    env = os.environ.get("DRIVETRAIN_CALIBRATION", "").strip()
    p = Path(path) if path else (Path(env) if env else CALIBRATION_JSON)
    if (path or env) and not p.is_file():
        raise FileNotFoundError(f"calibration file not found: {p}")
    if p.is_file():
        with open(p) as fh:
            cal = json.load(fh)
    else:
        cal = json.loads(json.dumps(FALLBACK_CALIBRATION))
    for key in ("upper", "planetary"):
        if key not in cal:
            raise ValueError(f"calibration {p}: missing section {key!r}")
        for q in ("c_v", "T_c", "w_c", "a"):
            if q not in cal[key]:
                raise ValueError(f"calibration {p}: missing {key}.{q}")
    cal.setdefault("coupling_scale", FALLBACK_CALIBRATION["coupling_scale"])
    return cal


# ------------------------------------------------------------------------------------------------
# Lumping on the referred chain
# ------------------------------------------------------------------------------------------------

@dataclass
class _Node:
    J: float
    c_ext: float
    members: dict            # public node id -> fraction of its inertia held here


@dataclass
class _Elem:
    k: float
    c: float
    members: list            # public element ids in series


def series(k1: float, c1: float, k2: float, c2: float) -> tuple[float, float]:
    """Two Kelvin-Voigt elements in series as one: k = k1 k2/(k1+k2); c from the low-frequency
    compliance, c = k^2 (c1/k1^2 + c2/k2^2). An infinite stiffness is rigid."""
    if math.isinf(k1):
        return k2, c2
    if math.isinf(k2):
        return k1, c1
    k = k1 * k2 / (k1 + k2)
    return k, k * k * (c1 / k1 ** 2 + c2 / k2 ** 2)


class RefChain:
    """The public chain referred to the drive shaft, reduced by merging (rigid elements) and
    condensing (static condensation of a small interior inertia: springs in series, the inertia
    split to the neighbours in proportion to the adjacent stiffnesses, as the row sums of the Guyan
    mass matrix)."""

    def __init__(self, model: PublicModel, scale: dict | None = None, rigid=()):
        R = model.R
        self.R = R
        self.nodes = [_Node(float(model.J[i] * R[i] ** 2), float(model.c_ext[i] * R[i] ** 2), {i + 1: 1.0})
                      for i in range(len(model.J))]
        self.elems = []
        for i in range(len(model.k)):
            s = R[i + 1] ** 2 * (scale or {}).get(i + 1, 1.0)
            k = math.inf if (i + 1) in rigid else float(model.k[i] * s)
            self.elems.append(_Elem(k, float(model.c[i] * R[i + 1] ** 2), [i + 1]))

    def idx(self, public_node: int) -> int:
        for i, nd in enumerate(self.nodes):
            if nd.members.get(public_node, 0.0) > 0.5:
                return i
        raise KeyError(f"public node {public_node} is not the main member of any node")

    def eidx(self, public_elem: int) -> int:
        for i, el in enumerate(self.elems):
            if public_elem in el.members:
                return i
        raise KeyError(public_elem)

    def merge(self, a: int, b: int) -> None:
        """Merge the nodes holding public nodes a and b (adjacent; the element between becomes rigid)."""
        i, j = sorted((self.idx(a), self.idx(b)))
        if j != i + 1:
            raise ValueError(f"nodes {a} and {b} are not adjacent")
        self._merge_at(i)

    def _merge_at(self, i: int) -> None:
        n0, n1 = self.nodes[i], self.nodes[i + 1]
        mem = dict(n0.members)
        for kk, v in n1.members.items():
            mem[kk] = mem.get(kk, 0.0) + v
        self.nodes[i] = _Node(n0.J + n1.J, n0.c_ext + n1.c_ext, mem)
        del self.nodes[i + 1]
        del self.elems[i]

    def condense(self, public_node: int) -> None:
        i = self.idx(public_node)
        if i == 0 or i == len(self.nodes) - 1:
            raise ValueError(f"public node {public_node} is at an end of the chain")
        el, er = self.elems[i - 1], self.elems[i]
        nd = self.nodes[i]
        if math.isinf(el.k) or math.isinf(er.k):
            self._merge_at(i - 1 if math.isinf(el.k) else i)
            return
        fl = el.k / (el.k + er.k)
        k, c = series(el.k, el.c, er.k, er.c)
        for tgt, f in ((self.nodes[i - 1], fl), (self.nodes[i + 1], 1.0 - fl)):
            tgt.J += f * nd.J
            tgt.c_ext += f * nd.c_ext
            for kk, v in nd.members.items():
                tgt.members[kk] = tgt.members.get(kk, 0.0) + f * v
        self.elems[i - 1] = _Elem(k, c, el.members + er.members)
        del self.elems[i]
        del self.nodes[i]

    def merge_rigid(self) -> None:
        """Merge across every rigid (infinite) element."""
        i = 0
        while i < len(self.elems):
            if math.isinf(self.elems[i].k):
                self._merge_at(i)
            else:
                i += 1

    def node(self, public_node: int) -> _Node:
        return self.nodes[self.idx(public_node)]

    def elem_between(self, a: int, b: int) -> _Elem:
        i, j = sorted((self.idx(a), self.idx(b)))
        if j != i + 1:
            raise ValueError(f"nodes {a} and {b} are not adjacent after lumping")
        return self.elems[i]


def _body_J(nd: _Node, model: PublicModel, p: Places):
    """Inertia of a body per frame (local values, not referred): (J_drive, J_middle, J_prop)."""
    out = [0.0, 0.0, 0.0]
    up = p.upper_gear or p.mesh            # without an upper gearbox the drive frame reaches the mesh
    for pid, f in nd.members.items():      # the frame by place: drive up to the upper gear, middle up to the mesh
        fr = 0 if pid <= up else (1 if pid <= p.mesh else 2)
        out[fr] += f * model.J[pid - 1]
    return out


# ------------------------------------------------------------------------------------------------
# Partition
# ------------------------------------------------------------------------------------------------

@dataclass
class Partition:
    """Physical parameters of each component (in the components' own frames), the cuts, and a
    description of which public nodes/elements each body holds (for docs and checks)."""

    shafts: str
    n_elements: int
    params: dict                      # component instance -> {parameter: value}
    models: dict                      # component instance -> model name
    connections: list                 # (spring "comp.port", inertia "comp.port")
    cuts: list                        # dicts: spring, inertia, elements (public ids), k, c (flange frame)
    bodies: dict                      # body name -> {"members": {node: fraction}, "J_ref": ...}
    calibration: dict = field(default_factory=dict)


def partition(shafts: str = "flexible", n_elements: int = 4, calibration: dict | None = None,
              coupling_scale: float | None = None, losses: bool = True,
              model: PublicModel | None = None, lower_ratio: float | None = None) -> Partition:
    """Lump the public model and split it into the components (docs/DRIVETRAIN.md, "Partition").

    shafts "flexible": FlexibleShaft ``drive_shaft`` between ``motors`` and ``upper`` (transducer,
    drive shaft in ``n_elements`` elements); "rigid": the thin shafts (public elements 11, 14, 16, 21)
    rigid, no shaft FMU, the drive line from the C2 coupling to the upper gearbox one rigid body in
    ``upper``. In both: the elastomer couplings C1 (inside ``motors``) and C2 (port spring of
    ``motors.drive``) stay compliant; the gear stage's port springs are the remaining compliance
    between the upper gearbox and the pinion (k_a) and between the wheel and the load (k_b).

    ``model``: the lumped table (default the rig's). A table of 22 nodes is in the rig's layout (its places and
    lumping); any other chain is lumped onto the places its ratios give (:func:`chain_places`, rigid shafts only,
    its stiffnesses as written); a table that cannot be mapped is a ConfigurationError naming why.
    ``lower_ratio``: the pair's z_wheel / z_pinion its bevel element must have (default the rig's)."""
    if shafts not in ("flexible", "rigid"):
        raise ValueError(f"shafts must be 'flexible' or 'rigid', got {shafts!r}")
    n_elements = int(n_elements)
    if n_elements < 1:
        raise ValueError("n_elements must be >= 1")
    m = model or load_public()
    problems = layout_problems(m, lower_ratio)
    rig_layout = len(m.J) == RIG_LAYOUT_NODES
    if not problems and not rig_layout and shafts != "rigid":
        problems = [f"a table of {len(m.J)} nodes runs with rigid shafts (effects.shaft_flexibility = \"rigid\"): the "
                    "drive shaft's FMU maps the rig's transducer hubs and thin shaft, which only its 22-node layout places"]
    if problems:
        raise ConfigurationError([f"lumped parameter table: {p}" for p in problems])
    cal = calibration if calibration is not None else load_calibration()
    # the coupling factor is the rig's (its elastomer elements 3-7); another chain's stiffnesses are taken as written
    s = float(cal["coupling_scale"] if coupling_scale is None else coupling_scale) if rig_layout else 1.0
    params: dict = {}
    cuts: list = []
    bodies: dict = {}
    if rig_layout:
        places = RIG_PLACES
        ch = _lumped_chain(m, shafts, s)
        C2, J_in_extra, J_sensor = _drive_line(ch, m, shafts, n_elements, params, cuts, bodies)
    else:
        places = chain_places(m, lower_ratio)[0]
        ch = _chain_lumped(m, places)
        C2, J_in_extra, J_sensor = ch.elem_between(places.flywheel, places.upper), 0.0, 0.0
        cuts.append(dict(spring="motors.drive", inertia="upper.flange_a", elements=C2.members, k=C2.k, c=C2.c))
    _upper_gear_motors(ch, m, cal, losses, C2, J_in_extra, J_sensor, params, cuts, bodies, places)
    models = {"motors": "MotorLoad", "upper": "UpperTransmission", "gear": GEAR_MODEL}
    if shafts == "flexible":
        models = {"motors": "MotorLoad", "drive_shaft": "FlexibleShaft", "upper": "UpperTransmission",
                  "gear": GEAR_MODEL}
    connections = [(cu["spring"], cu["inertia"]) for cu in cuts]
    params = {name: {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in pv.items()}
              for name, pv in params.items()}
    for cu in cuts:
        cu["k"], cu["c"] = float(cu["k"]), float(cu["c"])
    return Partition(shafts, n_elements, params, models, connections, cuts,
                     {k: {int(a): float(b) for a, b in v.items()} for k, v in bodies.items()},
                     {"coupling_scale": s, **{k: v for k, v in cal.items() if k != "coupling_scale"}})


def _lumped_chain(m: PublicModel, shafts: str, coupling_scale: float) -> RefChain:
    """The public model lumped for the partition: the elastomer couplings scaled, the rigid elements
    merged, the small hubs condensed (which ones: by the shafts' model)."""
    rigid = set(THIN_SHAFTS) if shafts == "rigid" else set()
    rigid |= {GEAR_ELEMENT_UPPER}                 # upper mesh: rigid transmission (local mode ~3 kHz)
    rigid |= {15, 16, 18} if shafts == "flexible" else {8, 9, 10, 18}
    ch = RefChain(m, {e: coupling_scale for e in ELASTOMER_ELEMENTS}, rigid)
    # --- drive motor side: condense the small hubs 2, 3, 4 (C1) and 6, 7 (C2) -------------------
    for pid in (2, 3, 4, 6, 7):
        ch.condense(pid)
    # --- drive line ---------------------------------------------------------------------------------
    ch.condense(9)                                 # transducer element 9 with its couplings 8
    # rigid: shafts 11, 14, 16, 21 are rigid, merged across; flexible: the drive shaft (element 11,
    # distributed inertia = public node 11) is discretised inside FlexibleShaft, node 11 stays as its start
    ch.merge_rigid()
    # upper gearbox body: 12+13 (+ condensed 14 in the flexible case)
    if shafts == "flexible":
        ch.condense(14)
    # --- middle shaft / pinion ----------------------------------------------------------------
    if shafts == "rigid":
        # 14+15 sit between the couplings 13 and 15 (local mode ~3 kHz): condensed
        ch.condense(15)
    # --- propeller side -------------------------------------------------------------------------
    if shafts == "flexible":
        ch.condense(21)
    ch.condense(20)
    return ch


def _chain_lumped(m: PublicModel, p: Places) -> RefChain:
    """Another chain lumped onto its places (:func:`chain_places`): the upper gearbox rigid (its two nodes one
    body), every node between the motor and the upper body but the flywheel, between the upper body and the
    pinion, and between the wheel and the load condensed (springs in series, the inertia to the neighbours)."""
    ch = RefChain(m, None, {p.upper_gear} if p.upper_gear else set())
    ch.merge_rigid()
    last_upper = p.upper_gear + 1 if p.upper_gear else p.upper
    for pid in [*range(2, p.upper), *range(last_upper + 1, p.pinion), *range(p.wheel + 1, p.load)]:
        if pid != p.flywheel:
            ch.condense(pid)
    return ch


def _drive_line(ch: RefChain, m: PublicModel, shafts: str, n_elements: int, params: dict, cuts: list,
                bodies: dict):
    """The drive line from coupling C2 to the upper gearbox into ``params``, ``cuts``, ``bodies``:
    flexible, FlexibleShaft ``drive_shaft`` and its two cuts; rigid, the one cut of C2 into the rigid
    upper body. Returns (C2, the shaft inertia the upper body takes, the upper body's J_sensor)."""
    if shafts == "flexible":
        H8 = ch.node(8)
        C2 = ch.elem_between(5, 8)
        H10 = ch.node(10)
        T = ch.elem_between(8, 10)
        S0 = ch.node(11)
        Ec = ch.elem_between(10, 11)
        Es = ch.elem_between(11, 12)
        J_shaft = S0.J
        # shaft start node S0 is replaced by the discretised shaft: its inertia is the shaft's own
        params["drive_shaft"] = dict(
            J_a=H8.J, k_t=T.k, d_t=T.c, J_b=H10.J, k_c=Ec.k, d_c=Ec.c,
            k_shaft=Es.k, d_shaft=Es.c, J_shaft=J_shaft, n_elements=n_elements)
        cuts.append(dict(spring="motors.drive", inertia="drive_shaft.flange_a", elements=C2.members,
                         k=C2.k, c=C2.c))
        cuts.append(dict(spring="drive_shaft.flange_b", inertia="upper.flange_a",
                         elements=[11], k=Es.k * n_elements, c=Es.c * n_elements,
                         note=f"last of {n_elements} drive-shaft elements"))
        bodies.update(hub_a=H8.members, hub_b=H10.members, drive_shaft=S0.members)
        return C2, J_shaft / (2 * n_elements), 0.0
    C2 = ch.elem_between(5, 12)
    cuts.append(dict(spring="motors.drive", inertia="upper.flange_a", elements=C2.members, k=C2.k, c=C2.c))
    # the transducer (public element 9, between nodes 9 and 10) lies inside the rigid body: the
    # inertia upstream of its measuring section (nodes <= 8 and half of node 9, drive frame)
    UT = ch.node(12)
    J_sensor = sum(f * m.J[pid - 1] for pid, f in UT.members.items() if pid <= 8) + \
        0.5 * UT.members.get(9, 0.0) * m.J[8]
    return C2, 0.0, J_sensor


def _upper_gear_motors(ch: RefChain, m: PublicModel, cal: dict, losses: bool, C2, J_in_extra: float,
                       J_sensor: float, params: dict, cuts: list, bodies: dict, p: Places = RIG_PLACES) -> None:
    """The upper gearbox, the gear stage and the motors (their parameters, the gear stage's two cuts,
    the bodies) into ``params``, ``cuts``, ``bodies``; the losses from the calibration (0 if not
    ``losses``); ``p``: where they sit in the table (the rig's places by default)."""
    M_ = ch.node(p.motor)
    FW = ch.node(p.flywheel)
    C1 = ch.elem_between(p.motor, p.flywheel)
    pin = ch.node(p.pinion)
    whl = ch.node(p.wheel)
    L = ch.node(p.load)
    UT = ch.node(p.upper)
    Ka = ch.elem_between(p.upper, p.pinion)
    Kb = ch.elem_between(p.wheel, p.load)
    J_ut = UT.J + J_in_extra
    Jd, Jm, _ = _body_J(UT, m, p)
    # J_in (drive frame) and J_out (middle frame) of the upper gearbox body
    # the frames of the middle and propeller shafts (the rig: 1/3 and 1/12, exactly: tooth_ratio)
    r_up = tooth_ratio(m.ratio[p.upper_gear - 1]) if p.upper_gear else Fraction(1)
    upper_ratio, R_m, R_p = float(1 / r_up), float(r_up), float(r_up * tooth_ratio(m.ratio[p.mesh - 1]))
    J_out = Jm
    J_in = J_ut - J_out * R_m ** 2
    up = cal["upper"]
    pg = cal["planetary"]
    lz = 1.0 if losses else 0.0
    params["upper"] = dict(J_in=J_in, J_out=J_out, ratio=upper_ratio,
                           loss_c=lz * up["c_v"], loss_Tc=lz * up["T_c"], loss_wc=up["w_c"],
                           loss_a=lz * up["a"], J_sensor=J_sensor)
    Rm2 = R_m ** 2
    Rp2 = R_p ** 2
    params["gear"] = dict(J_pinion=pin.J / Rm2, J_wheel=whl.J / Rp2, k_a=Ka.k / Rm2, d_a=Ka.c / Rm2,
                          k_b=Kb.k / Rp2, d_b=Kb.c / Rp2)
    params["motors"] = dict(J_motor=M_.J, c_motor=lz * M_.c_ext, k_c1=C1.k, d_c1=C1.c, J_flywheel=FW.J,
                            k_c2=C2.k, d_c2=C2.c, J_load=L.J / Rp2, ratio_pg=PG_RATIO,
                            pg_c=lz * pg["c_v"], pg_Tc=lz * pg["T_c"], pg_wc=pg["w_c"], pg_a=lz * pg["a"])
    cuts.append(dict(spring="gear.flange_a", inertia="upper.flange_b", elements=Ka.members,
                     k=Ka.k / Rm2, c=Ka.c / Rm2))
    cuts.append(dict(spring="gear.flange_b", inertia="motors.load", elements=Kb.members,
                     k=Kb.k / Rp2, c=Kb.c / Rp2))
    bodies.update(motor=M_.members, flywheel=FW.members, upper=UT.members, pinion=pin.members,
                  wheel=whl.members, load=L.members)


@functools.lru_cache(maxsize=4)
def _defaults_cached() -> dict:
    part = partition("flexible", 4)
    return {"FlexibleShaft": dict(part.params["drive_shaft"]),
            "UpperTransmission": dict(part.params["upper"]),
            "MotorLoad": dict(part.params["motors"]),
            GEAR_MODEL: dict(part.params["gear"])}


def default_parameters(model: str) -> dict:
    """Default physical parameters of a component model (flexible partition, 4 shaft elements)."""
    return dict(_defaults_cached()[model])


# ------------------------------------------------------------------------------------------------
# Steady state (constant speed): torques and angles
# ------------------------------------------------------------------------------------------------

def loss(w, T_trans, law: dict):
    return law["c_v"] * w + (law["T_c"] + law["a"] * abs(T_trans)) * math.tanh(w / law["w_c"])


@dataclass
class SteadyState:
    w_drive: float            # rad/s, drive shaft
    w_middle: float
    w_prop: float
    T_load_prop: float        # N m at the propeller shaft from the load motor (8 T_set)
    T_psh: float              # propeller-shaft torque (transducer, k_b)
    T_msh: float              # middle-shaft torque (k_a)
    T_dsh: float              # drive-shaft torque (transducer, C2 and the drive line)
    T_motor: float            # drive-motor torque


def steady_state(speed_rpm: float, load_Nm: float, upper: dict, motors: dict, load_mode: int = 0,
                 load_w_nom: float = 1.0, load_w_reg: float | None = None,
                 lower_ratio: float = LOWER_RATIO) -> SteadyState:
    """Torque balance at constant speed with an ideal lower gear (no mesh loss):

        T_PSH = 8 T_set + T_pg(w_PSH, 8 T_set)              (load side, propeller frame)
        T_MSH = T_PSH / lower_ratio                         (ideal lower gear; the rig: 4)
        T_DSH = T_MSH / 3 + T_ut(w_DSH, T_MSH / 3)         (upper gearbox, drive frame)
        T_motor = T_DSH + c_motor w_DSH

    ``upper``/``motors``: the parameter dicts of UpperTransmission and MotorLoad; ``lower_ratio``: the lower
    pair's z_wheel / z_pinion (the scene's [gear.pair]; default the rig's, LOWER_RATIO). At standstill the
    load setting is 0 (its regularisation below ``load_w_reg``), so a start from rest is at rest."""
    w = rpm_to_rad_s(speed_rpm)
    wm = w / upper.get("ratio", UPPER_RATIO)
    wp = wm / lower_ratio
    r8 = motors.get("ratio_pg", PG_RATIO)
    if int(load_mode) == 0:
        # the torque setting, regularised at standstill as in MotorLoad (tanh = 1 at any operating speed)
        wr = load_w_reg if load_w_reg is not None else motors.get("load_w_reg", RIG_DRIVE_LOAD.load_w_reg_rad_s)
        T_prop_load = r8 * load_Nm * math.tanh(wp / wr) if wr > 0 else r8 * load_Nm
    else:
        T_prop_load = r8 * load_Nm * wp / load_w_nom
    pg = {"c_v": motors["pg_c"], "T_c": motors["pg_Tc"], "w_c": motors["pg_wc"], "a": motors["pg_a"]}
    T_psh = T_prop_load + loss(wp, r8 * load_Nm, pg)
    T_msh = T_psh / lower_ratio
    ratio = upper.get("ratio", UPPER_RATIO)
    ut = {"c_v": upper["loss_c"], "T_c": upper["loss_Tc"], "w_c": upper["loss_wc"], "a": upper["loss_a"]}
    T_dsh = T_msh / ratio + loss(w, T_msh / ratio, ut)
    T_motor = T_dsh + motors.get("c_motor", 0.0) * w
    return SteadyState(w, wm, wp, T_prop_load, T_psh, T_msh, T_dsh, T_motor)


# ------------------------------------------------------------------------------------------------
# Measured mean torques (the calibration target)
# ------------------------------------------------------------------------------------------------

def read_measured(path: str | Path | None = None) -> dict:
    """The measured table as arrays: T_load, T_DSH, T_PSH, n_DSH (rpm), n_PSH (rpm)."""
    p = Path(path) if path else MEASURED_CSV
    try:
        with open(p, newline="", encoding="utf-8") as fh:
            rows = [r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{p}: not a readable CSV text file ({exc})") from None
    if not rows:
        raise ValueError(f"{p}: no data")
    hdr = [h.strip() for h in rows[0]]
    need = {"T_load_Nm", "T_DSH_Nm", "T_PSH_Nm", "n_DSH_rpm"}
    missing = need - set(hdr)
    if missing:
        raise ValueError(f"{p}: missing columns {sorted(missing)} (have {hdr})")
    col = {h: i for i, h in enumerate(hdr)}
    problems = []
    for n, r in enumerate(rows[1:], start=2):
        if len(r) != len(hdr):
            problems.append(f"data row {n - 1} has {len(r)} fields, the header {len(hdr)}: {','.join(r)}")
            continue
        for k in need:
            try:
                v = float(r[col[k]])
            except ValueError:
                problems.append(f"data row {n - 1}: {k} = {r[col[k]]!r} is not a number")
                continue
            if not math.isfinite(v):
                problems.append(f"data row {n - 1}: {k} = {r[col[k]]!r} is not a finite number")
            elif k == "n_DSH_rpm" and not v > 0:
                problems.append(f"data row {n - 1}: n_DSH_rpm = {v:g}: a drive speed > 0 rpm (the rig turns one way)")
            elif k in ("T_DSH_Nm", "T_PSH_Nm") and not v > 0:
                problems.append(f"data row {n - 1}: {k} = {v:g}: a measured torque > 0 N·m (the drive loads the "
                                "shafts; a zero or negative mean torque cannot be fitted)")
    if problems:
        raise ValueError(f"{p}: " + "; ".join(problems))
    data = {}
    for k in hdr:                 # every numeric column (the fit's were checked above; expectations read others)
        try:
            data[k] = np.array([float(r[col[k]]) for r in rows[1:]])
        except ValueError:
            pass
    if len(data["T_load_Nm"]) < 8:
        raise ValueError(f"{p}: at least 8 operating points are needed to fit 8 parameters")
    return data
