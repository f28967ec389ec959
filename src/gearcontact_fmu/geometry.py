"""Straight bevel pair with spherical-involute flanks: exact surfaces, placement, derived data, meshes.

Tooth form (tapered depth)
--------------------------
All cones (pitch, tip, root, base) meet at the common apex, so every tooth surface is a cone over a
curve on the unit sphere: ``point(rho, s) = rho * u(s)``, ``rho`` in ``[R_e - b, R_e]``, and the exact
unit normal ``n(s)`` does not depend on ``rho``. One flank of a tooth, in the *gear frame* (axis +z,
teeth at +z, the tooth centred on azimuth 0), consists of (from the root cone up):

1. a radial piece (constant azimuth) from the root cone to the base cone, only where the root cone
   lies inside the base cone (the pinion); it continues the involute tangentially (the involute
   starts on the base cone with a radial tangent);
2. the spherical involute: with the base cone angle ``delta_b`` (``sin delta_b = sin delta cos
   alpha``), tangency generator ``g(phi) = (sin delta_b cos phi, sin delta_b sin phi, cos delta_b)``,
   base-circle tangent ``t(phi) = (-sin phi, cos phi, 0)`` and ``psi = phi sin delta_b``, the point is
   ``Q(phi) = cos psi g(phi) - sin psi t(phi)`` (rotated about z to place the flank). The surface normal
   lies in the generating plane span(g, t) (that plane is the plane of action; dQ/dphi is normal to
   it): ``n = -(sin psi g + cos psi t)`` is the unit outward normal of the flank on the tooth's
   negative-azimuth side (checked numerically in tests: |Q| = 1, n.Q = 0, n.dQ/dphi = 0). The arc
   length on the unit sphere from the base cone is ``cos(delta_b) (1 - cos psi) / sin(delta_b)``,
   which is used as the profile parameter (closed-form inverse);
3. the tip rounding: a small circle on the unit sphere of angular radius ``kappa = r_tip / R_e``
   tangent to the involute and to the tip circle (so its physical radius scales with rho and is
   ``tip_radius`` at the outer end); exact normal ``(cos kappa u - c) / sin kappa``;
4. half of the top land (tip cone, normal along +polar direction). The top land cannot touch the
   partner at fixed axes, so meshes leave it out by default (``build_gear_mesh(top_land=False)``);
   each tooth is then two strips (drive and coast side, each root -> rounding end).

The other flank is the mirror image ``y -> -y``. Tooth thickness at the outer pitch circle
``s = m (pi/2 + 2 x tan alpha) - j/2`` (``j`` = circumferential backlash, split equally over both
gears); addendum ``h_a = m (h_a* + x)``, dedendum ``h_f = m (h_f* - x)`` at the outer end; tip and
root cone angles ``delta +- atan(h / R_e)``. Pinion ``x = x_pinion``, wheel ``x = -x_pinion``.

The profile parameter ``s`` of a flank (:func:`flank_point_normal`) is the arc length on the unit
sphere [rad] measured from the root cone (pieces 1-3), continuing over the half top land up to the
tooth centre line; a physical length at cone distance rho is ``rho * s``.

Placement (docs/ARCHITECTURE.md)
--------------------------------
World: common apex at the origin, both axes in the world XY plane, the shaft angle S between the cone
axes from the apex towards the teeth (+a1 and -a2, see below): pinion axis ``a1 = +Y``, wheel axis
``a2 = (sin S, -cos S, 0)`` (``+X`` at the rig's S = 90 deg, for which
the exact arrays are kept: bit-identical results). Pose of a gear at
angle theta: ``R = R0 @ Rz(theta)`` (body -> world), translation zero. The body +z axis is the
gear's positive rotation axis (``R0 @ e_z = a``). With these senses the kinematic meshing is
``theta_wheel = theta_pinion * z1/z2`` (both positive in operation).

NOTE (necessary deviation from "local +z points towards the teeth" for the wheel): two bevel gears
whose body +z both point from the apex towards their teeth mesh with *opposite* signs when both
rotate positively about body +z (the pitch-point velocities ``a1 x P`` and ``a2 x P`` are
antiparallel for any placement). To keep ``R = R0 Rz(theta)``, the world axes and the positive
kinematics, the **wheel's teeth lie on the body -z side**: the pinion teeth are at world +Y, the
wheel teeth towards ``-a2 = (-sin S, cos S, 0)`` (world -X at 90 deg), and the pitch cones touch along
``P = (-sin d1, cos d1, 0)``, d1 from ``a1`` and d2 = S - d1 from ``-a2``. The pitch-point velocities are
``w1 a1 x P = w1 sin(d1) e_Z`` and ``w2 a2 x P = w2 sin(d2) e_Z``: equal for ``w2 = w1 z1/z2`` at any S.
The wheel body frame is its gear frame turned by 180 deg about x (``F = diag(1, -1, -1)``).

Pinion ``R0`` maps body (x, y, z) to world (-X, +Z, +Y); wheel ``R0`` maps body (x, y, z) to world
((cos S, sin S, 0), +Z, a2), i.e. (+Y, +Z, +X) at 90 deg. At theta = 0 the pitch line is at body azimuth 0
of both gears (wheel body: ``(sin d2, 0, -cos d2)``).

Tooth numbering: tooth k enters the mesh k pitches later: pinion tooth k is centred at body azimuth
``-2 pi k / z1`` (tooth 0 centred on the pitch line at theta = 0); wheel tooth k is centred at body
azimuth ``pi/z2 - 2 pi k / z2``, so at theta = 0 the wheel's tooth space between teeth 1 and 0 is
centred on the pitch line (with the backlash split equally: s = theta_p - (z2/z1) theta_w = 0 is the
backlash-centred position, exactly, by mirror symmetry about the plane of the axes).

Flanks: **drive (+1)** = the flank loaded when the pinion drives in its positive sense. Pinion: the
tooth face on the +azimuth side (body frame, leading face). Wheel: the tooth face on the -azimuth
side of its body frame (trailing face), which is the +azimuth side of its gear frame. Coast = -1.
The drive flanks close at ``s = +s_b/2``, the coast flanks at ``s = -s_b/2`` (:func:`backlash_angle`).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from .meshes import (
    FLANK_COAST,
    FLANK_DRIVE,
    FLANK_OTHER,
    KIND_FLANK,
    KIND_ROOT_RADIAL,
    KIND_TIP_ROUND,
    KIND_TOP_LAND,
    KIND_VOID_FLOOR,
    KIND_VOID_WALL,
    SurfaceMesh,
)
from .params import SHAFT_ANGLE_90, BevelGearParams, MeshResolution, backlash_angle  # noqa: F401  (declared with the gear)

__all__ = [
    "GearGeometry", "gear_geometry", "flank_point_normal", "pinion_axis", "wheel_axis", "pinion_R0",
    "wheel_R0", "rot_z", "pose", "pinion_pose", "wheel_pose", "backlash_angle", "backlash_angle_exact",
    "build_gear_mesh", "build_pair", "BevelPair", "tooth_axis_body", "tooth_azimuth", "contact_ratio",
    "contact_ratio_tredgold", "unloaded_transmission_error", "closure", "summary", "analytic_area",
    "ROLES",
]

ROLES = ("pinion", "wheel")
_F_WHEEL = np.diag([1.0, -1.0, -1.0])       # wheel: gear frame <-> body frame (rotation by pi about x)
_MIN_ROUND_SEGMENTS = 6                     # the tip rounding gets at least this many elements


# ----------------------------------------------------------------------------- placement

def rot_z(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pinion_axis(params: BevelGearParams | None = None) -> np.ndarray:
    """World direction of the pinion's positive rotation axis (= R0 e_z): +Y."""
    return np.array([0.0, 1.0, 0.0])


def wheel_axis(params: BevelGearParams | None = None) -> np.ndarray:
    """World direction of the wheel's positive rotation axis (= R0 e_z): ``(sin S, -cos S, 0)``, +X at the
    rig's shaft angle S = 90 deg (exactly, see :func:`wheel_R0`)."""
    return wheel_R0(params)[:, 2].copy()


def mean_base_radius(gear: BevelGearParams) -> float:
    """Mean base radius of the pinion (virtual-spur sense, at the mean cone distance): the length that
    turns the pinion-referred mesh coordinate s into a distance along the line of action."""
    rm = (gear.outer_cone_distance - 0.5 * gear.face_width) * math.sin(gear.delta_pinion)
    return rm * math.cos(gear.pressure_angle)


def pinion_R0(params: BevelGearParams | None = None) -> np.ndarray:
    """Body -> world rotation of the pinion at theta = 0: body (x, y, z) -> world (-X, +Z, +Y)."""
    return np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])


def wheel_R0(params: BevelGearParams | None = None) -> np.ndarray:
    """Body -> world rotation of the wheel at theta = 0: body (x, y, z) -> world ((cos S, sin S, 0), +Z,
    (sin S, -cos S, 0)) for the shaft angle S; at exactly 90 deg (the default) the exact matrix of body
    (x, y, z) -> world (+Y, +Z, +X), not one with cos(pi/2) = 6e-17 in it."""
    S = (params or BevelGearParams()).shaft_angle
    if S == SHAFT_ANGLE_90:
        return np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    c, s = math.cos(S), math.sin(S)
    return np.array([[c, 0.0, s], [s, 0.0, -c], [0.0, 1.0, 0.0]])


def pose(R0: np.ndarray, theta: float) -> np.ndarray:
    """Body -> world rotation at angle theta: ``R0 @ Rz(theta)``."""
    return R0 @ rot_z(theta)


def pinion_pose(theta: float, params: BevelGearParams | None = None) -> np.ndarray:
    return pose(pinion_R0(params), theta)


def wheel_pose(theta: float, params: BevelGearParams | None = None) -> np.ndarray:
    return pose(wheel_R0(params), theta)


def tooth_axis_body(role: str) -> np.ndarray:
    """Unit vector in the body frame from the apex towards the teeth: +z pinion, -z wheel."""
    _check_role(role)
    return np.array([0.0, 0.0, 1.0]) if role == "pinion" else np.array([0.0, 0.0, -1.0])


def _check_role(role):
    if role not in ROLES:
        raise ValueError(f"role must be 'pinion' or 'wheel', not {role!r}")


# ----------------------------------------------------------------------------- gear geometry

def _inv_s(phi, sdb):
    """Azimuth of the spherical involute point relative to its generator start: phi - atan(tan psi / sin db)."""
    psi = phi * sdb
    return phi - np.arctan2(np.sin(psi), np.cos(psi) * sdb)


def _sph(polar, az):
    sp = np.sin(polar)
    return np.stack([sp * np.cos(az), sp * np.sin(az), np.cos(polar) * np.ones_like(az)], axis=-1)


@dataclass(frozen=True)
class GearGeometry:
    """Derived geometry of one gear (angles in rad, lengths in m). Build with :func:`gear_geometry`."""

    role: str
    z: int
    module: float
    alpha: float
    x: float
    delta: float            # pitch cone angle
    delta_b: float          # base cone angle
    delta_a: float          # tip (face) cone angle
    delta_f: float          # root cone angle
    Re: float               # outer cone distance
    b: float                # face width
    s_pitch: float          # tooth thickness at the outer pitch circle (incl. backlash share) [m]
    beta_p: float           # half tooth angle (azimuth) at the pitch cone
    omega0: float           # azimuth where the (negative-side) involute leaves the base cone
    kappa: float            # angular radius of the tip rounding
    psi_t: float            # involute roll angle psi at the rounding tangency
    c_round: tuple          # rounding circle centre (unit vector, gear frame, negative side)
    w1: tuple               # rounding: unit direction from c to the flank tangent point
    w2p: tuple              # rounding: unit direction perpendicular to w1 towards the tip tangent point
    chi_tot: float          # rounding sweep angle
    az_land: float          # azimuth of the rounding/top-land tangent point (negative side, < 0)
    L_radial: float         # arc lengths on the unit sphere of the flank pieces
    L_inv: float
    s_inv0: float           # involute arc length (from base cone) at the involute start
    L_round: float
    L_land_half: float
    s_pitch_param: float    # profile parameter of the pitch cone on the flank

    @property
    def Ri(self) -> float:
        return self.Re - self.b

    @property
    def Rm(self) -> float:
        return self.Re - 0.5 * self.b

    @property
    def L_flank(self) -> float:
        """Profile parameter at the end of the tip rounding (start of the top land)."""
        return self.L_radial + self.L_inv + self.L_round

    @property
    def L_half(self) -> float:
        return self.L_flank + self.L_land_half

    @property
    def pitch_angle(self) -> float:
        return 2.0 * math.pi / self.z

    @property
    def addendum(self) -> float:
        return self.Re * math.tan(self.delta_a - self.delta)

    @property
    def dedendum(self) -> float:
        return self.Re * math.tan(self.delta - self.delta_f)

    @property
    def body_from_gear(self) -> np.ndarray:
        return np.eye(3) if self.role == "pinion" else _F_WHEEL

    @property
    def virtual_teeth(self) -> float:
        return self.z / math.cos(self.delta)

    @property
    def top_land_outer(self) -> float:
        """Width of the top land (between the roundings) at the outer end [m]."""
        return 2.0 * self.L_land_half * self.Re

    # --- per-flank profile (gear frame, tooth 0, negative-azimuth side = coast)
    def profile_minus(self, s):
        """Point u (unit sphere), outward normal n and piece kind of the negative-side flank at s."""
        s = np.asarray(s, dtype=float)
        u = np.empty(s.shape + (3,))
        n = np.empty(s.shape + (3,))
        kind = np.empty(s.shape, dtype=np.int8)
        sdb, cdb = math.sin(self.delta_b), math.cos(self.delta_b)
        s1 = self.L_radial
        s2 = s1 + self.L_inv
        s3 = s2 + self.L_round
        m_r = s < s1
        m_i = (s >= s1) & (s <= s2) if self.L_round > 0 else (s >= s1) & (s <= s3)
        m_t = (s > s2) & (s <= s3) if self.L_round > 0 else np.zeros_like(m_r)
        m_l = s > s3
        if np.any(m_r):
            pol = self.delta_f + s[m_r]
            az = np.full_like(pol, self.omega0)
            u[m_r] = _sph(pol, az)
            n[m_r] = np.array([math.sin(self.omega0), -math.cos(self.omega0), 0.0])
            kind[m_r] = KIND_ROOT_RADIAL
        if np.any(m_i):
            si = self.s_inv0 + (s[m_i] - s1)
            cpsi = np.clip(1.0 - si * sdb / cdb, -1.0, 1.0)
            psi = np.arccos(cpsi)
            spsi = np.sin(psi)
            phi = psi / sdb + self.omega0
            cph, sph = np.cos(phi), np.sin(phi)
            g = np.stack([sdb * cph, sdb * sph, np.full_like(phi, cdb)], axis=-1)
            t = np.stack([-sph, cph, np.zeros_like(phi)], axis=-1)
            u[m_i] = cpsi[:, None] * g - spsi[:, None] * t
            n[m_i] = -(spsi[:, None] * g + cpsi[:, None] * t)
            kind[m_i] = KIND_FLANK
        if np.any(m_t):
            chi = (s[m_t] - s2) / math.sin(self.kappa)
            c = np.array(self.c_round)
            w = np.cos(chi)[:, None] * np.array(self.w1) + np.sin(chi)[:, None] * np.array(self.w2p)
            ck, sk = math.cos(self.kappa), math.sin(self.kappa)
            uu = ck * c + sk * w
            u[m_t] = uu
            n[m_t] = (ck * uu - c) / sk
            kind[m_t] = KIND_TIP_ROUND
        if np.any(m_l):
            az = self.az_land + (np.minimum(s[m_l], self.L_half) - s3) / math.sin(self.delta_a)
            pol = np.full_like(az, self.delta_a)
            u[m_l] = _sph(pol, az)
            ca = math.cos(self.delta_a)
            n[m_l] = np.stack([ca * np.cos(az), ca * np.sin(az), np.full_like(az, -math.sin(self.delta_a))], axis=-1)
            kind[m_l] = KIND_TOP_LAND
        return u, n, kind

    def azimuth_minus(self, polar):
        """Azimuth of the negative-side flank (tooth 0, gear frame) at a polar angle in [delta_f, delta_a].

        Exact inverse of the profile (radial piece, involute, rounding); NaN outside."""
        p = np.asarray(polar, dtype=float)
        out = np.full(p.shape, np.nan)
        sdb, cdb = math.sin(self.delta_b), math.cos(self.delta_b)
        cpsi_t = math.cos(self.psi_t)
        pol_t = math.acos(cpsi_t * cdb)                 # polar angle at the rounding tangency
        m_r = (p >= self.delta_f - 1e-15) & (p < self.delta_b)
        out[m_r] = self.omega0
        m_i = (p >= max(self.delta_b, self.delta_f - 1e-15)) & (p <= pol_t)
        if np.any(m_i):
            psi = np.arccos(np.clip(np.cos(p[m_i]) / cdb, -1.0, 1.0))
            out[m_i] = self.omega0 + _inv_s(psi / sdb, sdb)
        m_t = (p > pol_t) & (p <= self.delta_a + 1e-15)
        if np.any(m_t):
            if self.kappa > 0:
                c = np.array(self.c_round)
                cxy = math.hypot(c[0], c[1])
                a_c = math.atan2(c[1], c[0])
                pp = np.minimum(p[m_t], self.delta_a)
                arg = (math.cos(self.kappa) - np.cos(pp) * c[2]) / (np.sin(pp) * cxy)
                out[m_t] = a_c - np.arccos(np.clip(arg, -1.0, 1.0))
            else:
                out[m_t] = self.az_land
        return out


def gear_geometry(params: BevelGearParams | None, role: str, delta_b: float | None = None) -> GearGeometry:
    """Derived geometry of the pinion or the wheel. ``delta_b`` overrides the base cone (tests only)."""
    _check_role(role)
    p = params or BevelGearParams()
    return _gear_geometry(p, role, delta_b)


@lru_cache(maxsize=64)
def _gear_geometry(p: BevelGearParams, role: str, delta_b_override) -> GearGeometry:
    m, a = p.module, p.pressure_angle
    if role == "pinion":
        z, delta, x = p.z_pinion, p.delta_pinion, p.x_pinion
    else:
        z, delta, x = p.z_wheel, p.delta_wheel, -p.x_pinion
    Re, b = p.outer_cone_distance, p.face_width
    if not (0 < b < Re):
        raise ValueError("face width must be in (0, outer cone distance)")
    ha = m * (p.addendum_coefficient + x)
    hf = m * (p.dedendum_coefficient - x)
    delta_a = delta + math.atan(ha / Re)
    delta_f = delta - math.atan(hf / Re)
    delta_b = math.asin(math.sin(delta) * math.cos(a)) if delta_b_override is None else float(delta_b_override)
    sdb, cdb = math.sin(delta_b), math.cos(delta_b)
    s_pitch = m * (math.pi / 2 + 2 * x * math.tan(a)) - 0.5 * p.backlash
    beta_p = s_pitch / (m * z)
    psi_p = math.acos(math.cos(delta) / cdb)
    omega0 = -beta_p - float(_inv_s(psi_p / sdb, sdb))
    kappa = p.tip_radius / Re

    def inv_point_normal(psi):
        phi = psi / sdb + omega0
        g = np.array([sdb * math.cos(phi), sdb * math.sin(phi), cdb])
        t = np.array([-math.sin(phi), math.cos(phi), 0.0])
        return math.cos(psi) * g - math.sin(psi) * t, -(math.sin(psi) * g + math.cos(psi) * t)

    if kappa > 0:
        arg = math.cos(delta_a - kappa) / cdb
        if arg > 1.0:
            raise ValueError(f"{role}: tip rounding does not fit above the base cone")
        psi_t = kappa + math.acos(arg)
        Qt, nt = inv_point_normal(psi_t)
        c = math.cos(kappa) * Qt - math.sin(kappa) * nt
        a_c = math.atan2(c[1], c[0])
        T = _sph(np.array(delta_a), np.array(a_c))
        w1 = (Qt - math.cos(kappa) * c) / math.sin(kappa)
        w2 = (T - math.cos(kappa) * c) / math.sin(kappa)
        w2p = w2 - np.dot(w2, w1) * w1
        w2p /= np.linalg.norm(w2p)
        chi_tot = math.atan2(float(np.dot(w2, w2p)), float(np.dot(w2, w1)))
        az_land = a_c
        L_round = math.sin(kappa) * chi_tot
    else:
        psi_t = math.acos(math.cos(delta_a) / cdb)
        Qt, _ = inv_point_normal(psi_t)
        c = np.zeros(3)
        w1 = w2p = np.zeros(3)
        chi_tot = 0.0
        az_land = math.atan2(Qt[1], Qt[0])
        L_round = 0.0
    if az_land >= 0.0:
        raise ValueError(f"{role}: pointed tooth (the flanks meet below the tip cone incl. rounding)")
    if delta_f < delta_b:
        L_radial, s_inv0 = delta_b - delta_f, 0.0
    else:
        L_radial = 0.0
        s_inv0 = cdb * (1.0 - math.cos(delta_f) / cdb) / sdb
    s_inv_t = cdb * (1.0 - math.cos(psi_t)) / sdb
    L_inv = s_inv_t - s_inv0
    if L_inv <= 0:
        raise ValueError(f"{role}: no involute between root and tip")
    s_inv_p = cdb * (1.0 - math.cos(psi_p)) / sdb
    return GearGeometry(
        role=role, z=z, module=m, alpha=a, x=x, delta=delta, delta_b=delta_b, delta_a=delta_a,
        delta_f=delta_f, Re=Re, b=b, s_pitch=s_pitch, beta_p=beta_p, omega0=omega0, kappa=kappa,
        psi_t=psi_t, c_round=tuple(c), w1=tuple(w1), w2p=tuple(w2p), chi_tot=chi_tot, az_land=az_land,
        L_radial=L_radial, L_inv=L_inv, s_inv0=s_inv0, L_round=L_round,
        L_land_half=-az_land * math.sin(delta_a), s_pitch_param=L_radial + s_inv_p - s_inv0)


def _as_geom(gear, params=None) -> GearGeometry:
    if isinstance(gear, GearGeometry):
        return gear
    return gear_geometry(params, gear)


def tooth_azimuth(gear, k, params=None):
    """Azimuth of the centre of tooth k in the *gear* frame (body azimuth for the pinion, minus the
    body azimuth for the wheel)."""
    g = _as_geom(gear, params)
    k = np.asarray(k)
    if g.role == "pinion":
        return -2.0 * np.pi * k / g.z
    return (2.0 * k - 1.0) * np.pi / g.z


def _tooth_rotation(g: GearGeometry, k: int) -> np.ndarray:
    """gear frame tooth 0 -> body frame tooth k."""
    return g.body_from_gear @ rot_z(float(tooth_azimuth(g, k)))


_MIRROR = np.array([1.0, -1.0, 1.0])


def _side_of_flank(flank: int) -> int:
    """Gear-frame side (+1: +azimuth side of the tooth) of a physical flank (+1 drive, -1 coast)."""
    if flank not in (1, -1):
        raise ValueError("flank must be +1 (drive) or -1 (coast)")
    return flank      # drive = +azimuth side of the gear frame for both gears (see module docstring)


def flank_point_normal(gear, flank: int, profile_param, rho, tooth: int = 0, params=None):
    """Exact surface point and unit outward normal of a flank, body frame (vectorised, broadcast).

    gear: ``GearGeometry`` or ``"pinion"``/``"wheel"`` (with ``params``, default parameters);
    flank: +1 drive, -1 coast; profile_param: arc length on the unit sphere [rad] from the root cone
    (0 ... ``L_flank`` covers root, involute and tip rounding; up to ``L_half`` the half top land);
    rho: cone distance [m]. Returns ``(points (..., 3), normals (..., 3))``."""
    g = _as_geom(gear, params)
    side = _side_of_flank(flank)
    s, r = np.broadcast_arrays(np.asarray(profile_param, dtype=float), np.asarray(rho, dtype=float))
    u, n, _ = g.profile_minus(s)
    if side == 1:
        u = u * _MIRROR
        n = n * _MIRROR
    R = _tooth_rotation(g, tooth)
    u = u @ R.T
    n = n @ R.T
    return r[..., None] * u, n


# ----------------------------------------------------------------------------- tooth profile polyline

class _Piece:
    """A piece of the tooth profile curve on the unit sphere (gear frame, tooth 0)."""

    def __init__(self, length, fn, kind, flank, sfun):
        self.length, self.fn, self.kind, self.flank, self.sfun = length, fn, kind, flank, sfun

    def eval(self, t):
        return self.fn(np.asarray(t, dtype=float))


def _flank_piece(g: GearGeometry, side: int, s0: float, s1: float, kind: int) -> _Piece:
    """Part of a flank between profile parameters s0 -> s1 (may run downwards)."""
    flank = FLANK_OTHER if kind in (KIND_TIP_ROUND, KIND_TOP_LAND) else (FLANK_DRIVE if side == 1 else FLANK_COAST)

    def fn(t):
        u, n, _ = g.profile_minus(s0 + (s1 - s0) * t)
        if side == 1:
            u, n = u * _MIRROR, n * _MIRROR
        return u, n

    return _Piece(abs(s1 - s0), fn, kind, flank, lambda t: s0 + (s1 - s0) * t)


def _tangent(g, side, s):
    """Unit tangent of the flank curve towards increasing s (gear frame)."""
    u, n, _ = g.profile_minus(np.atleast_1d(np.asarray(s, dtype=float)))
    t = np.cross(u[0], n[0])    # negative side: u x n points to increasing s (up the flank)
    if side == 1:
        t = t * _MIRROR         # tangent vectors mirror like points
    return t / np.linalg.norm(t)


def _notch_pieces(g: GearGeometry, side: int, s_a: float, s_b: float, d: float, down: bool):
    """Void in a flank between s_a < s_b, depth d (angle on the unit sphere): wall, floor, wall.

    ``down``: the polyline runs towards decreasing s (true for the +side in our traversal)."""
    def base(s):
        u, n, _ = g.profile_minus(np.atleast_1d(s))
        if side == 1:
            u, n = u * _MIRROR, n * _MIRROR
        return u, n

    cd, sd = math.cos(d), math.sin(d)

    def wall(s_x, t_sign):
        u0, n0 = base(s_x)
        u0, n0 = u0[0], n0[0]
        tan = _tangent(g, side, s_x) * t_sign      # outward normal of the wall (into the void)

        def fn(t, into=True):
            tau = d * t
            return (np.cos(tau)[..., None] * u0 - np.sin(tau)[..., None] * n0,
                    np.broadcast_to(tan, np.shape(t) + (3,)).copy())
        return fn

    def floor_fn(s0, s1):
        def fn(t):
            u, n = base(s0 + (s1 - s0) * np.asarray(t))
            return cd * u - sd * n, sd * u + cd * n
        return fn

    # wall at s_b: void at s < s_b -> normal -tangent; wall at s_a: normal +tangent
    wb = wall(s_b, -1.0)
    wa = wall(s_a, +1.0)
    if down:
        pieces = [
            _Piece(d, lambda t: wb(np.asarray(t)), KIND_VOID_WALL, FLANK_OTHER, lambda t: np.full(np.shape(t), s_b)),
            _Piece(s_b - s_a, floor_fn(s_b, s_a), KIND_VOID_FLOOR, FLANK_OTHER, lambda t: s_b + (s_a - s_b) * np.asarray(t)),
            _Piece(d, lambda t: wa(1.0 - np.asarray(t)), KIND_VOID_WALL, FLANK_OTHER, lambda t: np.full(np.shape(t), s_a)),
        ]
    else:
        pieces = [
            _Piece(d, lambda t: wa(np.asarray(t)), KIND_VOID_WALL, FLANK_OTHER, lambda t: np.full(np.shape(t), s_a)),
            _Piece(s_b - s_a, floor_fn(s_a, s_b), KIND_VOID_FLOOR, FLANK_OTHER, lambda t: s_a + (s_b - s_a) * np.asarray(t)),
            _Piece(d, lambda t: wb(1.0 - np.asarray(t)), KIND_VOID_WALL, FLANK_OTHER, lambda t: np.full(np.shape(t), s_b)),
        ]
    return pieces


def _flank_breaks(g: GearGeometry):
    """(s0, s1, kind) of the flank pieces from the root to the tooth centre line."""
    out = []
    s = 0.0
    for L, kind in ((g.L_radial, KIND_ROOT_RADIAL), (g.L_inv, KIND_FLANK), (g.L_round, KIND_TIP_ROUND),
                    (g.L_land_half, KIND_TOP_LAND)):
        if L > 0:
            out.append((s, s + L, kind))
            s += L
    return out


def _tooth_pieces(g: GearGeometry, top_land: bool = False, notch=None):
    """Pieces of one tooth's profile: coast side root -> tip (-> land) -> drive side tip -> root.

    notch: None or (side, s_a, s_b, depth_angle) - a void in that flank's radial/involute part."""
    breaks = _flank_breaks(g)
    if not top_land:
        breaks = [b for b in breaks if b[2] != KIND_TOP_LAND]
    pieces = []
    # negative side (coast), upwards
    for s0, s1, kind in breaks:
        pieces.extend(_split_for_notch(g, -1, s0, s1, kind, notch, down=False))
    # positive side (drive), downwards
    if not top_land:
        pieces.append(None)            # marks a break in the polyline (two strips)
    for s0, s1, kind in reversed(breaks):
        pieces.extend(_split_for_notch(g, +1, s1, s0, kind, notch, down=True))
    return pieces


def _split_for_notch(g, side, s_from, s_to, kind, notch, down):
    if notch is None or notch[0] != side or kind not in (KIND_FLANK, KIND_ROOT_RADIAL):
        return [_flank_piece(g, side, s_from, s_to, kind)]
    _, s_a, s_b, d = notch
    lo, hi = min(s_from, s_to), max(s_from, s_to)
    out = []
    if down:
        # running from hi to lo
        if s_b <= lo or s_a >= hi:
            return [_flank_piece(g, side, s_from, s_to, kind)]
        if not (lo - 1e-15 <= s_a and s_b <= hi + 1e-15):
            raise ValueError("the void must lie within one piece of the flank (root part or involute)")
        if hi - s_b > 1e-15:
            out.append(_flank_piece(g, side, hi, s_b, kind))
        out.extend(_notch_pieces(g, side, s_a, s_b, d, down=True))
        if s_a - lo > 1e-15:
            out.append(_flank_piece(g, side, s_a, lo, kind))
    else:
        if s_b <= lo or s_a >= hi:
            return [_flank_piece(g, side, s_from, s_to, kind)]
        if not (lo - 1e-15 <= s_a and s_b <= hi + 1e-15):
            raise ValueError("the void must lie within one piece of the flank (root part or involute)")
        if s_a - lo > 1e-15:
            out.append(_flank_piece(g, side, lo, s_a, kind))
        out.extend(_notch_pieces(g, side, s_a, s_b, d, down=False))
        if hi - s_b > 1e-15:
            out.append(_flank_piece(g, side, s_b, hi, kind))
    return out


def graded_face_nodes(g: GearGeometry, face: float, bands) -> tuple:
    """Cone distances of the face rows: spacing ``face`` (the uniform rows), and within each band
    ``(rho_lo, rho_hi, fine)`` rows every ``fine`` (a local fault, or its partner's), the uniform rows
    kept where they do not fall inside a band."""
    nf = max(1, int(math.ceil(g.b / face - 1e-9)))
    rows = np.linspace(g.Ri, g.Re, nf + 1)
    for rho_lo, rho_hi, fine in bands:
        lo, hi = max(g.Ri, rho_lo), min(g.Re, rho_hi)
        if hi <= lo:
            continue
        n = max(1, int(math.ceil((hi - lo) / fine - 1e-9)))
        keep = rows[(rows < lo - 0.5 * fine) | (rows > hi + 0.5 * fine)]
        rows = np.unique(np.concatenate([keep, np.linspace(lo, hi, n + 1)]))
    return tuple(float(r) for r in rows)


def _banded_t(t, s0: float, s1: float, profile_bands):
    """The piece parameters ``t`` (uniform 0 .. 1 over profile parameters s0 -> s1) with the nodes inside each
    of ``profile_bands`` ``[(s_lo, s_hi, fine), ...]`` ([rad]) replaced by nodes at most ``fine`` apart from the
    band's ends (clipped to the piece); ``t`` itself where no band meets the piece."""
    for s_lo, s_hi, fine in profile_bands:
        a, b = max(min(s0, s1), s_lo), min(max(s0, s1), s_hi)
        if b - a <= 1e-15:
            continue
        ta, tb = sorted(((a - s0) / (s1 - s0), (b - s0) / (s1 - s0)))
        k = max(1, int(math.ceil((b - a) / fine - 1e-9)))
        keep = t[(t < ta - 1e-12) | (t > tb + 1e-12)]
        t = np.unique(np.concatenate([keep, np.linspace(ta, tb, k + 1)]))
    return t


def _strip_arrays(strip, rho, ds, profile_bands=()):
    """One structured strip of profile pieces (``strip``, run in order) by the face rows ``rho`` [m], the
    profile spacing at most ``ds`` [rad] (finer in ``profile_bands`` on the involute, :func:`_banded_t`):
    vertices, faces (order: segment, row, two triangles), exact face points and normals, kinds, flank
    codes and profile parameters."""
    rho = np.asarray(rho, dtype=float)
    nf = len(rho) - 1
    nodes_u = []
    seg_piece, seg_t0, seg_t1 = [], [], []
    for ip, pc in enumerate(strip):
        n = max(1, int(math.ceil(pc.length / ds - 1e-9)), getattr(pc, "min_segments", 1))
        if pc.kind == KIND_TIP_ROUND:
            n = max(n, _MIN_ROUND_SEGMENTS)
        t = np.linspace(0.0, 1.0, n + 1)
        if profile_bands and pc.kind == KIND_FLANK:
            t = _banded_t(t, float(pc.sfun(0.0)), float(pc.sfun(1.0)), profile_bands)
            n = t.size - 1
        u, _ = pc.eval(t)
        nodes_u.append(u if not nodes_u else u[1:])
        seg_piece += [ip] * n
        seg_t0.append(t[:-1])
        seg_t1.append(t[1:])
    U = np.concatenate(nodes_u, axis=0)
    seg_piece = np.array(seg_piece)
    seg_t0 = np.concatenate(seg_t0)
    seg_t1 = np.concatenate(seg_t1)
    N = U.shape[0]
    nseg = N - 1
    verts = (rho[None, :, None] * U[:, None, :]).reshape(-1, 3)
    i = np.arange(nseg)[:, None]
    j = np.arange(nf)[None, :]
    a = i * (nf + 1) + j
    b_ = (i + 1) * (nf + 1) + j
    tri1 = np.stack([a, b_, b_ + 1], axis=-1)
    tri2 = np.stack([a, b_ + 1, a + 1], axis=-1)
    faces = np.stack([tri1, tri2], axis=2).reshape(-1, 3)          # order: seg, rho, (tri1, tri2)
    # exact per-face data: weighted parameter of the centroid
    r0 = rho[:-1][None, :]
    r1 = rho[1:][None, :]
    t0 = seg_t0[:, None]
    t1 = seg_t1[:, None]
    tc1 = (r0 * t0 + (r0 + r1) * t1) / (2 * r0 + r1)
    tc2 = ((r0 + r1) * t0 + r1 * t1) / (r0 + 2 * r1)
    tc = np.stack([tc1, tc2], axis=2).reshape(nseg, -1)          # (nseg, 2 nf)
    fu = np.empty((nseg, 2 * nf, 3))
    fn_ = np.empty((nseg, 2 * nf, 3))
    fk = np.empty(nseg, dtype=np.int8)
    ff = np.empty(nseg, dtype=np.int8)
    fs = np.empty((nseg, 2 * nf))
    for ip, pc in enumerate(strip):
        msk = seg_piece == ip
        uu, nn = pc.eval(tc[msk])
        fu[msk], fn_[msk] = uu, nn
        fk[msk] = pc.kind
        ff[msk] = pc.flank
        fs[msk] = pc.sfun(tc[msk])
    fu = fu.reshape(-1, 3)
    fn_ = fn_.reshape(-1, 3)
    cent = verts[faces].mean(axis=1)
    rc = np.einsum("ij,ij->i", cent, fu)
    return (verts, faces, rc[:, None] * fu, fn_ / np.linalg.norm(fn_, axis=1)[:, None], np.repeat(fk, 2 * nf),
            np.repeat(ff, 2 * nf), fs.reshape(-1))


def _tooth_template(g: GearGeometry, resolution: MeshResolution, top_land=False, notch=None, rho_nodes=None,
                    profile_bands=()):
    """Mesh of tooth 0 in the gear frame: vertices, faces and per-face data (strips of the polyline).
    ``rho_nodes``: the cone distances of the face rows (default uniform at ``resolution.face``);
    ``profile_bands``: finer profile nodes on the involute (:func:`_banded_t`)."""
    ds = resolution.profile / g.Rm
    if rho_nodes is None:
        nf = max(1, int(math.ceil(g.b / resolution.face - 1e-9)))
        rho = np.linspace(g.Ri, g.Re, nf + 1)
    else:
        rho = np.asarray(rho_nodes, dtype=float)
        nf = len(rho) - 1
    pieces = _tooth_pieces(g, top_land, notch)
    # split into strips at None markers
    strips, cur = [], []
    for pc in pieces:
        if pc is None:
            strips.append(cur)
            cur = []
        else:
            cur.append(pc)
    strips.append(cur)
    V, Fc, FP, FN, FK, FF, FS = [], [], [], [], [], [], []
    nv = 0
    for strip in strips:
        verts, faces, fp, fn_, fk, ff, fs = _strip_arrays(strip, rho, ds, profile_bands)
        V.append(verts)
        Fc.append(faces + nv)
        FP.append(fp)
        FN.append(fn_)
        FK.append(fk)
        FF.append(ff)
        FS.append(fs)
        nv += verts.shape[0]
    return (np.concatenate(V), np.concatenate(Fc), np.concatenate(FP), np.concatenate(FN),
            np.concatenate(FK), np.concatenate(FF), np.concatenate(FS))


def flank_profile_nodes(g: GearGeometry, profile: float, side: int, profile_bands=()) -> np.ndarray:
    """Profile parameters [rad] of the nodes of one side's flank strip (root part, involute, tip rounding;
    not the top land) as :func:`_tooth_template` places them at the element size ``profile`` [m] (and
    ``profile_bands``), ascending."""
    ds = profile / g.Rm
    out = []
    for s0, s1, kind in _flank_breaks(g):
        if kind == KIND_TOP_LAND:
            continue
        n = max(1, int(math.ceil(abs(s1 - s0) / ds - 1e-9)))
        if kind == KIND_TIP_ROUND:
            n = max(n, _MIN_ROUND_SEGMENTS)
        t = np.linspace(0.0, 1.0, n + 1)
        if profile_bands and kind == KIND_FLANK:
            t = _banded_t(t, s0, s1, profile_bands) if side == -1 else _banded_t(t, s1, s0, profile_bands)
        out.append(s0 + (s1 - s0) * t if side == -1 else s1 + (s0 - s1) * t)
    return np.unique(np.concatenate(out))


def flank_patch(params: BevelGearParams | None, role: str, side: int, s_lo: float, s_hi: float, rho_nodes,
                profile: float, tooth: int = 0, notch=None, nodes=None) -> SurfaceMesh:
    """A structured patch of one side's flank strip (root part, involute, tip rounding) of ``tooth``: the
    profile parameters ``s_lo`` .. ``s_hi`` [rad] by the face rows ``rho_nodes`` [m], element size at most
    ``profile`` [m] along the profile, run and wound as the tooth's own strip (body frame, exact face data).
    ``notch``: ``(side, s_a, s_b, depth_angle)``, a void inside the patch. ``nodes``: the profile parameters
    of the tooth's own nodes (:func:`flank_profile_nodes`): a piece gets at least as many elements as they
    put on it. Vertex ``i * len(rho_nodes) + j``
    is profile node i (in the strip's direction: towards the root on the +1 side) on row j. Used by
    :mod:`faults` for local surgery: the patch replaces the healthy elements of the same rectangle."""
    _check_role(role)
    params = params or BevelGearParams()
    g = gear_geometry(params, role)
    breaks = [b for b in _flank_breaks(g) if b[2] != KIND_TOP_LAND]
    pieces = []
    for s0, s1, kind in (breaks if side == -1 else reversed(breaks)):
        a, b = max(s0, s_lo), min(s1, s_hi)
        if b - a <= 1e-15:
            continue
        new = (_split_for_notch(g, -1, a, b, kind, notch, down=False) if side == -1 else
               _split_for_notch(g, 1, b, a, kind, notch, down=True))
        if nodes is not None:
            for pc in new:
                if pc.kind in (KIND_FLANK, KIND_ROOT_RADIAL, KIND_TIP_ROUND):
                    lo_, hi_ = sorted(float(x) for x in pc.sfun(np.array([0.0, 1.0])))
                    pc.min_segments = int(np.sum((nodes > lo_ + 1e-15) & (nodes <= hi_ + 1e-15)))
        pieces.extend(new)
    if not pieces:
        raise ValueError(f"no flank between profile parameters {s_lo:g} and {s_hi:g}")
    V, F, FP, FN, FK, FF, FS = _strip_arrays(pieces, rho_nodes, profile / g.Rm)
    R = _tooth_rotation(g, int(tooth) % g.z)
    return SurfaceMesh(vertices=V @ R.T, faces=F, face_points=FP @ R.T, face_normals=FN @ R.T,
                       face_tooth=np.full(F.shape[0], int(tooth) % g.z, dtype=np.int32), face_flank=FF,
                       face_kind=FK, face_profile=FS)


def _teeth_list(g: GearGeometry, teeth):
    if teeth is None:
        return list(range(g.z))
    out = []
    for k in teeth:
        k = int(k) % g.z
        if k not in out:
            out.append(k)
    return out


def build_gear_mesh(params: BevelGearParams | None, role: str, resolution: MeshResolution | None = None,
                    teeth=None, *, top_land: bool = False, notch: dict | None = None,
                    rho_nodes: dict | None = None, face_bands=(), profile_bands=()) -> SurfaceMesh:
    """Surface mesh (body frame, m) of both flanks of the teeth incl. tip rounding (top land optional).

    Element size: ``resolution.profile`` along the profile and ``resolution.face`` along the face
    width, both at the mean cone distance (the profile spacing scales with rho, the face spacing is
    uniform in rho); the tip rounding gets at least 6 elements along the profile. ``teeth``: subset of tooth indices (mod z), default all. Each tooth is one
    structured strip (shared vertices, consistent winding, geometric normals outward). Exact face
    data: ``face_points`` on the analytic surface at the element centroid's profile parameter,
    ``face_normals`` the analytic outward normal. ``notch`` (used by :mod:`faults`):
    ``{tooth: (side, s_a, s_b, depth_angle)}``; ``rho_nodes`` (used by :mod:`faults`): ``{tooth: cone
    distances of its face rows}``; ``face_bands``: ``[(rho_lo, rho_hi, fine), ...]`` finer face rows for
    every tooth (see :func:`graded_face_nodes`; used where the partner gear has a local fault);
    ``profile_bands``: ``[(s_lo, s_hi, fine), ...]`` [rad] finer profile nodes on the involute of both flanks
    of every tooth (:func:`_banded_t`; used where the partner gear has a chipped tip)."""
    _check_role(role)
    params = params or BevelGearParams()
    resolution = resolution or MeshResolution()
    g = gear_geometry(params, role)
    ks = _teeth_list(g, teeth)
    notch = notch or {}
    cache = {}
    Vs, Fs, FPs, FNs, FKs, FFs, FSs, FTs = [], [], [], [], [], [], [], []
    nv = 0
    for k in ks:
        key = notch.get(k)
        if key not in cache:
            rows = graded_face_nodes(g, resolution.face, face_bands) if face_bands else None
            cache[key] = _tooth_template(g, resolution, top_land, key, rows, profile_bands)
        V, F, FP, FN, FK, FF, FS = cache[key]
        if rho_nodes and k in rho_nodes:     # a tooth with its own face rows (a local fault on it)
            V, F, FP, FN, FK, FF, FS = _tooth_template(g, resolution, top_land, key, rho_nodes[k], profile_bands)
        R = _tooth_rotation(g, k)
        Vs.append(V @ R.T)
        Fs.append(F + nv)
        FPs.append(FP @ R.T)
        FNs.append(FN @ R.T)
        FKs.append(FK)
        FFs.append(FF)
        FSs.append(FS)
        FTs.append(np.full(F.shape[0], k, dtype=np.int32))
        nv += V.shape[0]
    if not ks:
        raise ValueError("no teeth selected")
    return SurfaceMesh(
        vertices=np.ascontiguousarray(np.concatenate(Vs)), faces=np.ascontiguousarray(np.concatenate(Fs), dtype=np.int64),
        face_points=np.ascontiguousarray(np.concatenate(FPs)), face_normals=np.ascontiguousarray(np.concatenate(FNs)),
        face_tooth=np.concatenate(FTs), face_flank=np.concatenate(FFs), face_kind=np.concatenate(FKs),
        face_profile=np.concatenate(FSs),
        meta={"source": "analytic", "role": role, "profile": resolution.profile, "face": resolution.face,
              "top_land": top_land, "params": params, "face_bands": [tuple(b) for b in face_bands],
              **({"profile_bands": [tuple(b) for b in profile_bands]} if profile_bands else {})})


def analytic_area(params: BevelGearParams | None, role: str, top_land: bool = False, n_teeth: int | None = None) -> float:
    """Exact area of the meshed tooth surfaces: (Re^2 - Ri^2)/2 * (profile arc length) per tooth."""
    g = gear_geometry(params, role)
    L = 2.0 * (g.L_half if top_land else g.L_flank)
    return 0.5 * (g.Re ** 2 - g.Ri ** 2) * L * (g.z if n_teeth is None else n_teeth)


# ----------------------------------------------------------------------------- pair

@dataclass
class BevelPair:
    params: BevelGearParams
    resolution: MeshResolution
    pinion: SurfaceMesh
    wheel: SurfaceMesh
    pinion_R0: np.ndarray
    wheel_R0: np.ndarray
    pinion_axis: np.ndarray
    wheel_axis: np.ndarray
    pinion_geom: GearGeometry
    wheel_geom: GearGeometry
    backlash_angle: float
    info: dict = field(default_factory=dict)

    def poses(self, theta_pinion: float, theta_wheel: float):
        """Body -> world rotations (R_pinion, R_wheel)."""
        return pose(self.pinion_R0, theta_pinion), pose(self.wheel_R0, theta_wheel)

    def wheel_angle(self, theta_pinion: float, s: float = 0.0) -> float:
        """Wheel angle for a pinion angle and mesh coordinate s = theta_p - (z2/z1) theta_w."""
        return (theta_pinion - s) * self.params.z_pinion / self.params.z_wheel


def build_pair(params: BevelGearParams | None = None, resolution: MeshResolution | None = None,
               pinion_teeth=None, wheel_teeth=None, **kw) -> BevelPair:
    params = params or BevelGearParams()
    resolution = resolution or MeshResolution()
    t0 = time.perf_counter()
    pm = build_gear_mesh(params, "pinion", resolution, pinion_teeth, **kw)
    t1 = time.perf_counter()
    wm = build_gear_mesh(params, "wheel", resolution, wheel_teeth, **kw)
    t2 = time.perf_counter()
    return BevelPair(params, resolution, pm, wm, pinion_R0(params), wheel_R0(params), pinion_axis(params),
                     wheel_axis(params), gear_geometry(params, "pinion"), gear_geometry(params, "wheel"),
                     backlash_angle(params),
                     info={"pinion_triangles": pm.n_faces, "wheel_triangles": wm.n_faces,
                           "pinion_build_s": t1 - t0, "wheel_build_s": t2 - t1})


# ----------------------------------------------------------------------------- exact kinematics

#: The profile sampling rule of the exact kinematics (closure, backlash): a flank, root .. end of the tip
#: rounding (profile parameter 0 .. ``L_flank``), at this many evenly spaced points (:func:`_profile_samples`)
PROFILE_SAMPLES = 4000


def _profile_samples(g: GearGeometry, side: int, n: int = PROFILE_SAMPLES):
    """Dense unit-sphere points of one flank (root .. end of rounding), gear frame tooth 0: the profile
    sampling rule (:data:`PROFILE_SAMPLES` evenly spaced points, profile parameter 0 .. ``L_flank``)."""
    s = np.linspace(0.0, g.L_flank, n)
    u, _, _ = g.profile_minus(s)
    if side == 1:
        u = u * _MIRROR
    return u, s


def closure(thetas, flank: int = +1, params: BevelGearParams | None = None, pinion_geom=None, wheel_geom=None,
            pinion_teeth=None, n_profile: int = PROFILE_SAMPLES, return_per_tooth: bool = False):
    """Mesh coordinate s [rad] at which the flanks of the exact surfaces first touch, per pinion angle.

    For each pinion angle the wheel starts at the backlash-centred position (s = 0); the smallest wheel
    rotation that brings a wheel flank onto a pinion flank point is found exactly per point (rotation
    about the axis keeps the polar angle, and the wheel flank's azimuth at a polar angle is known in
    closed form), minimised over densely sampled pinion flank points (incl. tip roundings). Returns
    ``s_drive > 0`` (flank=+1) or ``s_coast < 0`` (flank=-1); with ``return_per_tooth`` an array
    (n_theta, n_teeth) of the closure of every selected pinion tooth (inf when it cannot touch)."""
    params = params or BevelGearParams()
    gp = pinion_geom or gear_geometry(params, "pinion")
    gw = wheel_geom or gear_geometry(params, "wheel")
    side = _side_of_flank(flank)
    ratio = gp.z / gw.z
    teeth = _teeth_list(gp, pinion_teeth)
    u0, _ = _profile_samples(gp, side, n_profile)
    # pinion points in body frame per tooth: (T, n, 3)
    Ub = np.stack([u0 @ _tooth_rotation(gp, k).T for k in teeth])
    R0p, R0w = pinion_R0(params), wheel_R0(params)
    thetas = np.atleast_1d(np.asarray(thetas, dtype=float))
    out = np.empty((thetas.size, len(teeth)))
    pitch_w = 2 * math.pi / gw.z
    for i, th in enumerate(thetas):
        thw = th * ratio
        # body pinion -> world -> wheel body -> wheel gear frame
        M = _F_WHEEL @ pose(R0w, thw).T @ pose(R0p, th)
        X = Ub @ M.T
        pol = np.arccos(np.clip(X[..., 2], -1.0, 1.0))
        az = np.arctan2(X[..., 1], X[..., 0])
        am = gw.azimuth_minus(pol)              # NaN outside the wheel's flank range
        tooth0 = float(tooth_azimuth(gw, 0))
        if side == 1:
            gap = np.mod(az - (tooth0 - am), pitch_w)
        else:
            gap = np.mod((tooth0 + am) - az, pitch_w)
        gap = np.where(np.isnan(gap), np.inf, gap)
        out[i] = gap.min(axis=1) / ratio * side
    if return_per_tooth:
        return out
    return _closure_min(out, side)


def _closure_min(per_tooth, side):
    return np.min(np.abs(per_tooth), axis=1) * side


def unloaded_transmission_error(params: BevelGearParams | None = None, n_theta: int = 240, flank: int = +1,
                                n_profile: int = PROFILE_SAMPLES, pinion_geom=None, wheel_geom=None):
    """Unloaded TE over one pinion pitch with the backlash taken up (exact geometry).

    Returns dict: theta [rad], s [rad] (closure), te [m] = (s - mean) * r_e1 (a length at the outer
    pitch circle, pinion-referred), te_pp [m], s_mean [rad]."""
    params = params or BevelGearParams()
    gp = pinion_geom or gear_geometry(params, "pinion")
    th = np.linspace(0.0, gp.pitch_angle, n_theta, endpoint=False)
    per = closure(th, flank, params, gp, wheel_geom, pinion_teeth=[-2, -1, 0, 1, 2], n_profile=n_profile,
                  return_per_tooth=True)
    s = _closure_min(per, flank)
    r1 = params.module * params.z_pinion / 2
    te = (s - s.mean()) * r1
    return {"theta": th, "s": s, "te": te, "te_pp": float(te.max() - te.min()), "s_mean": float(s.mean())}


@lru_cache(maxsize=16)
def backlash_angle_exact(params: BevelGearParams | None = None, n_profile: int = PROFILE_SAMPLES) -> float:
    """Free play of the exact geometry [rad at the pinion]: s_drive - s_coast at theta = 0."""
    params = params or BevelGearParams()
    sd = _closure_min(closure([0.0], +1, params, pinion_teeth=[-2, -1, 0, 1, 2], n_profile=n_profile,
                              return_per_tooth=True), +1)[0]
    sc = _closure_min(closure([0.0], -1, params, pinion_teeth=[-2, -1, 0, 1, 2], n_profile=n_profile,
                              return_per_tooth=True), -1)[0]
    return float(sd - sc)


def contact_ratio(params: BevelGearParams | None = None, flank: int = +1, tol: float = 1e-8,
                  n_profile: int = PROFILE_SAMPLES) -> float:
    """Transverse contact ratio from the exact geometry.

    The pinion angle range during which tooth 0 is one of the pairs in contact at the unloaded
    closure (its own closure within ``tol`` rad of the conjugate closure), divided by the pitch
    angle. Boundaries by bisection to 1e-10 rad."""
    params = params or BevelGearParams()
    gp = gear_geometry(params, "pinion")
    pitch = gp.pitch_angle
    s_conj = float(np.median(_closure_min(closure(np.linspace(0, pitch, 16, endpoint=False), flank, params,
                                                    pinion_teeth=[-2, -1, 0, 1, 2], n_profile=n_profile,
                                                    return_per_tooth=True), flank)))

    def in_contact(th):
        c = closure([th], flank, params, pinion_teeth=[0], n_profile=n_profile, return_per_tooth=True)[0, 0]
        return abs(c) <= abs(s_conj) + tol

    th = np.linspace(-1.5 * pitch, 1.5 * pitch, 241)
    c = closure(th, flank, params, pinion_teeth=[0], n_profile=n_profile, return_per_tooth=True)[:, 0]
    inside = np.abs(c) <= abs(s_conj) + tol
    idx = np.flatnonzero(inside)
    if idx.size == 0 or idx[0] == 0 or idx[-1] == th.size - 1:
        raise RuntimeError("contact interval of tooth 0 not bracketed")

    def bisect(a, b):      # a in contact, b not
        for _ in range(60):
            mid = 0.5 * (a + b)
            if in_contact(mid):
                a = mid
            else:
                b = mid
            if abs(b - a) < 1e-10:
                break
        return 0.5 * (a + b)

    lo = bisect(th[idx[0]], th[idx[0] - 1])
    hi = bisect(th[idx[-1]], th[idx[-1] + 1])
    return (hi - lo) / pitch


def contact_ratio_tredgold(params: BevelGearParams | None = None, rounding: bool = False) -> float:
    """Tredgold approximation: transverse contact ratio of the virtual spur gears at the outer end.

    ``rounding``: use the start of the tip rounding instead of the tip circle as the active tip."""
    params = params or BevelGearParams()
    a = params.pressure_angle
    tot = 0.0
    rv_sum = 0.0
    for role in ROLES:
        g = gear_geometry(params, role)
        rv = g.Re * math.tan(g.delta)
        rb = rv * math.cos(a)
        ra = rv + g.addendum
        if rounding and g.kappa > 0:
            ra -= params.tip_radius * (1.0 - math.sin(math.acos(rb / ra)))
        tot += math.sqrt(ra * ra - rb * rb)
        rv_sum += rv
    return (tot - rv_sum * math.sin(a)) / (math.pi * params.module * math.cos(a))


def summary(params: BevelGearParams | None = None, exact: bool = True) -> dict:
    """Derived quantities of the pair (angles in degrees, lengths in mm) for reports."""
    params = params or BevelGearParams()
    out = {"shaft_angle_deg": math.degrees(params.shaft_angle),
           "outer_cone_distance_mm": params.outer_cone_distance * 1e3,
           "face_width_mm": params.face_width * 1e3,
           "backlash_angle_rad": backlash_angle(params)}
    for role in ROLES:
        g = gear_geometry(params, role)
        out[role] = {
            "z": g.z, "x": g.x, "pitch_cone_deg": math.degrees(g.delta), "base_cone_deg": math.degrees(g.delta_b),
            "tip_cone_deg": math.degrees(g.delta_a), "root_cone_deg": math.degrees(g.delta_f),
            "addendum_mm": g.addendum * 1e3, "dedendum_mm": g.dedendum * 1e3,
            "virtual_teeth": g.virtual_teeth, "thickness_outer_pitch_mm": g.s_pitch * 1e3,
            "top_land_outer_mm": g.top_land_outer * 1e3,
        }
    out["contact_ratio_tredgold"] = contact_ratio_tredgold(params)
    if exact:
        out["contact_ratio_exact"] = contact_ratio(params)
        te = unloaded_transmission_error(params)
        out["unloaded_te_pp_m"] = te["te_pp"]
        out["backlash_angle_exact_rad"] = backlash_angle_exact(params)
    return out
