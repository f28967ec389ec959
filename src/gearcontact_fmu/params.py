"""Parameters of the lower bevel pair and of the polygonal contact method (SI units).

Defaults follow ``RIG.md``. Values the paper does not give are project choices and are marked
"default (project choice)"; they stay parameters.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import functools
import math
from dataclasses import dataclass

#: the model name of the gear FMU (GearContact.fmu, its slave class, the native build's model)
GEAR_MODEL = "GearContact"

# The rotational flange connector of every FMU of the project (after Modelica.Mechanics.Rotational's
# flanges): a port <name> is the three Real variables <name>_phi [rad], <name>_w [rad/s], <name>_tau [N.m].
# On the spring side a port reads phi and w (inputs) and writes tau (output: the torque applied to the
# connected body); on the inertia side the reverse. A connection joins a spring-side and an inertia-side port.
FLANGE_QUANTITIES = ("phi", "w", "tau")
FLANGE_UNITS = {"phi": "rad", "w": "rad/s", "tau": "N.m"}
SPRING, INERTIA = "spring", "inertia"
_FLANGE_INPUTS = {SPRING: ("phi", "w"), INERTIA: ("tau",)}


def flange_variables(name: str, side: str) -> tuple[tuple[str, str, str], ...]:
    """The flange ``name`` on ``side`` (:data:`SPRING` or :data:`INERTIA`): ((variable, unit, causality), ...)
    in the order phi, w, tau; causality "input" or "output"."""
    inputs = _FLANGE_INPUTS[side]
    return tuple((f"{name}_{q}", FLANGE_UNITS[q], "input" if q in inputs else "output") for q in FLANGE_QUANTITIES)
#: the default communication step of a co-simulation [s] (scene key numerics.comm_step_s, the FMUs'
#: DefaultExperiment step size): 4 steps per output sample at the rig's ~3 kHz
DEFAULT_COMM_STEP_S = 1.0 / 12000.0
#: most internal sub-steps one communication step may take (a step that needs more is refused with a
#: message instead of blocking the host: 1e6 sub-steps are seconds of work; H = 1000 s blocked for 27 s)
MAX_SUBSTEPS_PER_STEP = 1_000_000


#: result codes of the sub-stepping kernels (gear stage and drivetrain line models), one numbering for both
CODE_OK = 0
CODE_MESH_STATUS = 1          # the mesh model reported an error state (penetration beyond u_max)
CODE_NONFINITE_STATE = 2
CODE_NONFINITE_INPUT = 3


def substeps(H: float, max_substep: float) -> int:
    """Internal sub-steps of one communication step H: ceil(H / max_substep), at least 1."""
    return max(1, int(math.ceil(H / max_substep - 1e-9)))


@functools.lru_cache(maxsize=64)
def _substeps_cached(H: float, max_substep: float) -> int:
    return substeps(H, max_substep)


def checked_substeps(H: float, t: float, max_substep: float) -> tuple[int, str | None]:
    """Sub-steps of a communication step and why it is refused (None if it is not): called at every
    step by the stage and the line models, so the count is cached per (H, max_substep)."""
    n = _substeps_cached(H, max_substep)
    if n <= MAX_SUBSTEPS_PER_STEP:
        return n, None
    return n, (f"communication step {H:.6g} s at t = {t:.9g} s needs {n} sub-steps of max_substep = "
               f"{max_substep:.3g} s (at most {MAX_SUBSTEPS_PER_STEP}); take smaller communication steps")


#: the shaft angle of the rig's pair [rad] (math.radians(90.0) == pi/2 exactly): the angle at which the
#: placement and the pitch cones keep their original expressions (bit-identical results for the rig)
SHAFT_ANGLE_90 = math.radians(90.0)


@dataclass(frozen=True)
class BevelGearParams:
    """Straight bevel pair, spherical-involute flanks, common apex, all cones through the apex.

    Any straight bevel pair: the numbers of teeth, the outer transverse module, the face width, the pressure
    angle, the shaft angle S (the angle between the two axes; pitch cones ``delta_1 + delta_2 = S``), the
    profile shift of the pinion (the wheel gets ``-x``: x1 + x2 = 0, no change of the working pressure
    angle), the addendum and dedendum factors, the backlash and the tip rounding. Whether a pair can be
    made (undercut, a pointed tip, interference, face width, contact ratio, the ranges) is
    :func:`gearcontact_fmu.pair_check.pair_problems`; this dataclass only holds the data."""

    z_pinion: int = 15
    z_wheel: int = 60
    module: float = 3.0e-3                 # outer transverse module [m]
    pressure_angle: float = math.radians(20.0)
    shaft_angle: float = SHAFT_ANGLE_90     # angle between the axes [rad]
    face_width: float = 25.0e-3            # default (project choice), <= cone distance / 3
    x_pinion: float = 0.43                 # profile shift of the pinion; wheel gets -x (default, project choice)
    addendum_coefficient: float = 1.0      # h_a* (outer end)
    dedendum_coefficient: float = 1.25     # h_f* (outer end)
    backlash: float = 0.075e-3             # circumferential backlash at the outer pitch circle [m] (default)
    tip_radius: float = 0.2e-3             # tip edge rounding radius at the outer end [m] (default)

    @property
    def ratio(self) -> float:
        return self.z_wheel / self.z_pinion

    @property
    def delta_pinion(self) -> float:
        """Pitch cone angle of the pinion [rad]: ``tan delta_1 = sin S / (z2/z1 + cos S)`` (S the shaft angle),
        as ``atan2(z1 sin S, z2 + z1 cos S)``. At a shaft angle of exactly 90 deg it is ``atan2(z1, z2)``, the
        expression of the rig's pair since the start, kept so that its pitch cones stay bit-identical
        (cos(pi/2) = 6e-17, not 0)."""
        if self.shaft_angle == SHAFT_ANGLE_90:
            return math.atan2(self.z_pinion, self.z_wheel)
        S = self.shaft_angle
        return math.atan2(self.z_pinion * math.sin(S), self.z_wheel + self.z_pinion * math.cos(S))

    @property
    def delta_wheel(self) -> float:
        return self.shaft_angle - self.delta_pinion

    @property
    def outer_cone_distance(self) -> float:
        """Outer cone distance R_e = m z1 / (2 sin delta_1) [m]."""
        return self.module * self.z_pinion / (2.0 * math.sin(self.delta_pinion))


def backlash_angle(params: BevelGearParams | None = None) -> float:
    """Angular backlash s_b [rad at the pinion]: ``j / r_e1 = 2 j / (m z1)``.

    The free play of the exact geometry equals this to sampling accuracy (~1e-9..1e-7 relative, see
    :func:`gearcontact_fmu.geometry.backlash_angle_exact`, tested); drive flanks close at s = +s_b/2, coast
    at -s_b/2. Declared with the gear (not in geometry) so that a light model (ideal, analytic) does not
    load the flank geometry for it."""
    p = params or BevelGearParams()
    return 2.0 * p.backlash / (p.module * p.z_pinion)


@dataclass(frozen=True)
class PCMParams:
    """Polygonal contact (elastic layer) parameters, paper values for the lower gear mesh."""

    E: float = 206e9                 # Young's modulus [Pa]
    nu: float = 0.3                  # Poisson's ratio
    layer_depth: float = 0.5e-3      # elastic layer depth b of each body [m]
    c_compression: float = 4e10      # damping while compressing [N·s/m³] (4e4 MN·s/m³)
    c_expansion: float = 3e9         # damping while expanding [N·s/m³] (3e3 MN·s/m³)
    transformation_depth: float = 5e-6   # damping ramps in over this penetration [m]
    mu: float = 0.002                # friction coefficient (lubricated)
    v_friction: float = 1e-3         # friction regularisation velocity [m/s]
    u_max: float = 1e-3              # maximum penetration [m]; beyond it is an error state

    @property
    def K(self) -> float:
        """Elastic modulus of a laterally constrained layer, K = (1-nu) E / ((1+nu)(1-2 nu)) [Pa]."""
        return (1.0 - self.nu) * self.E / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))

    @property
    def layer_stiffness(self) -> float:
        """Pressure per penetration of one layer, K/b [N/m³]."""
        return self.K / self.layer_depth

    @property
    def stiffness(self) -> float:
        """Pressure per penetration of the two layers in series, c1 c2/(c1+c2) [N/m³]."""
        c = self.layer_stiffness
        return c * c / (c + c)


@dataclass(frozen=True)
class MeshResolution:
    """Element size of the tooth surface meshes, set separately along the profile and the face width.

    Sizes are measured at the mean cone distance (the teeth scale with the cone distance). The
    defaults are the converged resolution of the mesh-convergence study (tests/gear_contact/test_pcm_pair.py):
    halving the profile size from 0.05 mm changes the mesh stiffness by 0.2 %; the flanks are
    straight along the face width, so 0.5-2 mm along it changes it by < 0.1 %."""

    profile: float = 0.05e-3
    face: float = 2.0e-3


#: tooth bending and foundation compliance in series with the PCM layers, as the total approach per unit
#: of layer approach (docs/GEAR-CONTACT.md, "Tooth compliance"): the loaded mesh of the default map is
#: 4.22 / 4.47 / 4.64 / 4.84x ISO 6336's c_gamma (with its low-load factor) at the paper's pinion torques
#: 0.86 / 1.3 / 2.4 / 3.71 N·m; 4.5 (about their geometric middle) puts all within 7 %
TOOTH_COMPLIANCE_FACTOR = 4.5



#: the contact-map grid's node counts the builder accepts (MapGrid; the FMU declares them as min/max)
MAP_GRID_RANGE = (2, 4096)
#: the smallest positive double: the inclusive FMI ``min`` that says "> 0" exactly (FMI 2.0 has no exclusive
#: bounds; no double lies between 0 and this one). Declared by every FMU parameter the code refuses unless > 0
POSITIVE = math.ulp(0.0)

@dataclass(frozen=True)
class MapGrid:
    """Grid of the fixed-axis contact map (fidelity "table"; gearcontact_fmu.contact_map)."""

    points_per_pitch: int = 48          # pinion-angle nodes per pinion pitch (full revolution stored)
    s_points: int = 48                  # nodes per flank along the approach beyond the contact onset
    max_torque: float = 200.0           # pinion torque [N·m] the approach range must cover
    reference_speed: float = 100.0      # pinion speed [rad/s] at which friction is tabulated
    omega_regularisation: float = 1.0   # pinion speed [rad/s] below which friction is ramped out
    max_approach: float = 0.5e-3        # onset search range along the line of action [m]: a pinion that
    #                                     runs ahead through a missing-tooth window meets the next tooth
    #                                     early, at its tip (~0.1 mm further on at 1500 rpm)

    def __post_init__(self):
        for name in ("points_per_pitch", "s_points"):
            v = getattr(self, name)
            lo, hi = MAP_GRID_RANGE
            if isinstance(v, bool) or int(v) != v or not lo <= v <= hi:
                raise ValueError(f"contact-map grid: {name} must be an integer in {lo}..{hi}, got {v!r}")


def params_hash(*objs) -> str:
    """Stable short hash of dataclasses / plain values, for disk caches."""

    def enc(o):
        if dataclasses.is_dataclass(o):
            return {"__type__": type(o).__name__, **{f.name: enc(getattr(o, f.name)) for f in dataclasses.fields(o)}}
        if isinstance(o, float):
            return repr(o)
        if isinstance(o, (list, tuple)):
            return [enc(v) for v in o]
        if isinstance(o, dict):
            return {str(k): enc(v) for k, v in sorted(o.items())}
        return o

    payload = json.dumps([enc(o) for o in objs], sort_keys=True, default=str).encode()
    return hashlib.sha256(payload).hexdigest()[:16]


def file_sha256(path) -> str:
    """SHA-256 (hex) of a file's content, read in 1 MiB chunks (mesh files, FMUs: cache and resume keys)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
