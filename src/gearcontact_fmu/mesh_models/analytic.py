"""Analytic reference mesh of the bevel pair ("analytic" fidelity).

The role of Simpack's Hertz-based Gear Pair element: a mesh stiffness after ISO 6336-1 (method B)
applied to the virtual spur gears of the bevel pair at the mean cone distance (Tredgold), a
single/double pair alternation over the mesh cycle from the transverse contact ratio of those virtual
gears, backlash, a viscous mesh damping and optional regularised Coulomb friction.

Geometry (all at the mean cone distance R_m = R_e - b/2, mean module m_m = m R_m/R_e):
  virtual spur gears  z_v = z / cos(delta), r_v = m_m z_v / 2, r_vb = r_v cos(alpha),
                      r_va = r_v + (h_a* + x) m_m (tooth proportions scale with the cone distance)
  contact ratio       eps = (sqrt(r_va1^2-r_vb1^2) + sqrt(r_va2^2-r_vb2^2) - (r_v1+r_v2) sin(alpha))
                            / (pi m_m cos(alpha))            (x1 + x2 = 0: no working-angle change)
  lever arm           r_b = r_m1 cos(alpha), r_m1 = R_m sin(delta_1) (mean base radius of the real
                      pinion; equal to r_vb1 cos(delta_1) because the virtual pinion turns by
                      theta cos(delta_1)). Line-of-action approach: delta = r_b (s -/+ s_b/2).

Stiffness (ISO 6336-1, per unit face width, N/(mm um)):
  q' = C1 + C2/z_v1 + C3/z_v2 + C4 x1 + C5 x1/z_v1 + C6 x2 + C7 x2/z_v2 + C8 x1^2 + C9 x2^2
  c'_th = 1/q',  c' = c'_th C_M C_R C_B cos(beta)   (C_M = 0.8, C_R = 1 solid blanks,
  C_B = [1 + 0.5 (1.2 - h_fP/m)] [1 - 0.02 (20 deg - alpha)])
  c_gamma = c' (0.75 eps + 0.25)
The ISO low-load factor ((F_t/b)/100 N/mm)^0.25 is not applied (it would make the mesh nonlinear).

Mesh cycle (period 2 pi / z1 in pinion angle, p_b = pi m_m cos(alpha) along the line of action):
single-pair stiffness k1 = c' b, double-pair stiffness k2 = 1.75 k1. With these the cycle mean is
exactly c_gamma b: (2-eps) k1 + (eps-1) k2 = (0.75 eps + 0.25) k1. The transitions are blended by a
C1 smoothstep over ``transition`` x p_b so that the mesh is conservative: the elastic potential is
V = 1/2 K(theta_p) delta_s^2 (K = k r_b^2, delta_s = s -/+ s_b/2) and the torques are its gradient,
tau_p = -K delta_s - 1/2 K'(theta_p) delta_s^2, tau_w = (z2/z1) K delta_s. The K' term (a few per mil
of the mesh torque, only inside the transition zones) is what makes the audit close: without it, a
stiffness jump under load would create or destroy 1/2 (k2-k1) delta^2 of energy per transition.

Phase: at theta_p = mesh_phase a drive flank of the pinion passes the pitch point. The drive contact
runs from the wheel tip (distance g_a before the pitch point) to the pinion tip (g_r after it); the
coast contact (wheel driving the pinion backwards in load, same rotation sense) runs from the pinion
tip to the wheel tip and passes the pitch point at theta_p = mesh_phase + (pi + 4 x1 tan(alpha))/z1
(the pinion's pitch tooth-thickness angle).

Damping: Kelvin-Voigt along the line of action, F = k delta + c_mesh d(delta)/dt, clamped to F >= 0
(no adhesion). c_mesh is a parameter; by default it is set from a damping ratio of the mesh mode,
c_mesh = 2 zeta sqrt(k_mean m_eq), m_eq = 1/(r_b^2 (1/J_p + (z2/z1)^2 / J_w)) with the stage inertias.

Friction (mu > 0): per pair in contact, F_f = mu F_i clip(v_s/v_f, -1, 1) against the sliding
velocity v_s = w1v rho1 - w2v rho2 of the virtual gears (w_v = w cos(delta), rho the flank radii of
curvature along the line of action), load shared 1/(1+w), w/(1+w) between the pairs.

Contact diagnostics: Hertz line contact per pair at the virtual-gear curvatures (half width
a = sqrt(4 q R / (pi E*)), peak pressure p0 = sqrt(q E* / (pi R)), q = F_i/b, 1/E* = 2 (1-nu^2)/E),
contact area = sum 2 a b; max_penetration = the line-of-action approach r_b |delta_s|; status 1 when
the approach exceeds u_max.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from gearcontact_fmu.mesh_models.base import (
    OUT_CONTACT_AREA,
    OUT_DISSIPATED_POWER,
    OUT_ELASTIC_ENERGY,
    OUT_MAX_PENETRATION,
    OUT_N_CONTACT,
    OUT_NORMAL_FORCE,
    OUT_PEAK_PRESSURE,
    OUT_STATUS,
    OUT_TAU_PINION,
    OUT_TAU_WHEEL,
    STATUS_OK,
    STATUS_PENETRATION_EXCEEDED,
    MeshModel,
    supports,
)
from gearcontact_fmu.params import BevelGearParams, PCMParams, backlash_angle

# ISO 6336-1:2006 method B, coefficients of q' (mm um / N)
ISO6336_C = (0.04723, 0.15551, 0.25791, -0.00635, -0.11654, -0.00193, -0.24188, 0.00529, 0.00182)
ISO6336_C_M = 0.8          # theoretical -> real stiffness correction
ISO6336_C_R = 1.0          # solid gear blanks
DOUBLE_PAIR_FACTOR = 1.75  # k2/k1 that makes the cycle mean equal c_gamma (see module docstring)

# layout of the parameter vector (data = (p,))
P_RATIO = 0          # z2/z1
P_SB = 1             # backlash in the mesh coordinate s [rad]
P_RB = 2             # lever arm r_b [m]
P_K1 = 3             # single-pair line-of-action stiffness [N/m]
P_K2 = 4             # double-pair stiffness [N/m]
P_PB = 5             # base pitch of the virtual gears [m]
P_LD = 6             # length of the double-pair zone per cycle, (eps-1) p_b [m]
P_GA = 7             # drive path: distance from its start (wheel tip) to the pitch point [m]
P_GR = 8             # drive path: pitch point to its end (pinion tip) [m]
P_PHASE = 9          # pinion angle where a drive flank is at the pitch point [rad]
P_COAST = 10         # + offset of the coast-flank pitch-point passage [rad]
P_DELTA = 11         # transition blend width [m]
P_C = 12             # mesh damping along the line of action [N s/m]
P_MU = 13            # friction coefficient
P_VF = 14            # friction regularisation velocity [m/s]
P_RHO1 = 15          # virtual pinion flank curvature radius at the pitch point [m]
P_RHO2 = 16          # virtual wheel flank curvature radius at the pitch point [m]
P_COS1 = 17          # cos(delta_1)
P_COS2 = 18          # cos(delta_2)
P_ESTAR = 19         # Hertz plane-strain modulus E* = E / (2 (1 - nu^2)) [Pa]
P_FACE = 20          # face width [m]
P_UMAX = 21          # maximum approach (error state beyond) [m]
N_P = 22


# --------------------------------------------------------------------------------------------
# geometry and ISO 6336 (plain Python, evaluated once)
# --------------------------------------------------------------------------------------------

def virtual_spur_gears(gear: BevelGearParams) -> dict:
    """Virtual spur gears of the bevel pair at the mean cone distance (SI units)."""
    alpha = gear.pressure_angle
    Re = gear.outer_cone_distance
    Rm = Re - 0.5 * gear.face_width
    m_m = gear.module * Rm / Re
    d1, d2 = gear.delta_pinion, gear.delta_wheel
    x1, x2 = gear.x_pinion, -gear.x_pinion
    zv1, zv2 = gear.z_pinion / math.cos(d1), gear.z_wheel / math.cos(d2)
    rv1, rv2 = 0.5 * m_m * zv1, 0.5 * m_m * zv2
    rvb1, rvb2 = rv1 * math.cos(alpha), rv2 * math.cos(alpha)
    rva1 = rv1 + (gear.addendum_coefficient + x1) * m_m
    rva2 = rv2 + (gear.addendum_coefficient + x2) * m_m
    p_b = math.pi * m_m * math.cos(alpha)
    g_r = math.sqrt(rva1 ** 2 - rvb1 ** 2) - rv1 * math.sin(alpha)   # recess: pitch point -> pinion tip
    g_a = math.sqrt(rva2 ** 2 - rvb2 ** 2) - rv2 * math.sin(alpha)   # approach: wheel tip -> pitch point
    eps = (g_a + g_r) / p_b
    rm1 = Rm * math.sin(d1)
    return dict(
        R_m=Rm, m_m=m_m, z_v1=zv1, z_v2=zv2, x1=x1, x2=x2, r_v1=rv1, r_v2=rv2, r_vb1=rvb1, r_vb2=rvb2,
        r_va1=rva1, r_va2=rva2, p_b=p_b, g_a=g_a, g_r=g_r, eps_alpha=eps, r_m1=rm1,
        r_b=rm1 * math.cos(alpha), rho1_pitch=rv1 * math.sin(alpha), rho2_pitch=rv2 * math.sin(alpha),
    )


def iso6336_low_load_factor(gear: BevelGearParams, pinion_torque_Nm: float) -> float:
    """ISO 6336-1 method B below a line load of 100 N/mm: c' and c_gamma scale with
    ((F_t K_A / b) / (100 N/mm))^0.25 (K_A = 1; F_t the tangential force at the virtual pinion's mean
    pitch radius). 1 at and above 100 N/mm."""
    v = virtual_spur_gears(gear)
    line_load = abs(pinion_torque_Nm) / v["r_m1"] / (gear.face_width * 1e3)       # N/mm
    return min(1.0, (line_load / 100.0) ** 0.25) if line_load > 0 else 0.0


def iso6336_stiffness(gear: BevelGearParams) -> dict:
    """Single-pair stiffness c' and mesh stiffness c_gamma per unit face width [N/(mm um)] after
    ISO 6336-1 method B, for the virtual spur gears of the pair."""
    v = virtual_spur_gears(gear)
    C1, C2, C3, C4, C5, C6, C7, C8, C9 = ISO6336_C
    z1, z2, x1, x2 = v["z_v1"], v["z_v2"], v["x1"], v["x2"]
    q = (C1 + C2 / z1 + C3 / z2 + C4 * x1 + C5 * x1 / z1 + C6 * x2 + C7 * x2 / z2
         + C8 * x1 ** 2 + C9 * x2 ** 2)
    c_th = 1.0 / q
    h_fp = gear.dedendum_coefficient
    C_B = (1.0 + 0.5 * (1.2 - h_fp)) * (1.0 - 0.02 * (20.0 - math.degrees(gear.pressure_angle)))
    c1 = c_th * ISO6336_C_M * ISO6336_C_R * C_B * 1.0   # cos(beta) = 1: straight teeth
    c_gamma = c1 * (0.75 * v["eps_alpha"] + 0.25)
    return dict(q_prime=q, c_th=c_th, C_M=ISO6336_C_M, C_R=ISO6336_C_R, C_B=C_B, c_prime=c1,
                c_gamma=c_gamma, eps_alpha=v["eps_alpha"], z_v1=z1, z_v2=z2)


def mesh_stiffness(gear: BevelGearParams) -> dict:
    """Line-of-action stiffnesses [N/m] and their pinion-referred torsional values [N m/rad]."""
    iso = iso6336_stiffness(gear)
    v = virtual_spur_gears(gear)
    b_mm = gear.face_width * 1e3
    k1 = iso["c_prime"] * b_mm * 1e6          # N/um -> N/m
    k2 = DOUBLE_PAIR_FACTOR * k1
    k_mean = iso["c_gamma"] * b_mm * 1e6
    rb2 = v["r_b"] ** 2
    return dict(k_single=k1, k_double=k2, k_mean=k_mean, K_single=k1 * rb2, K_double=k2 * rb2,
                K_mean=k_mean * rb2, r_b=v["r_b"])


def single_pair_phase(gear: BevelGearParams, theta_pinion: float) -> float:
    """``mesh_phase`` that puts the drive contact at pinion angle ``theta_pinion`` in the middle of a
    single-pair zone (constant stiffness K_single around it)."""
    v = virtual_spur_gears(gear)
    u_mid = 0.5 * ((v["eps_alpha"] - 1.0) * v["p_b"] + v["p_b"])
    return theta_pinion - (u_mid - v["g_a"]) / v["r_b"]


def make_analytic_data(gear: BevelGearParams | None = None, pcm: PCMParams | None = None, *,
                       damping_ratio: float = 0.05, c_mesh: float | None = None,
                       J_pinion: float = 2.69e-4, J_wheel: float = 1.8e-4,
                       mu: float = 0.0, v_friction: float | None = None,
                       mesh_phase: float = 0.0, transition: float = 0.05,
                       u_max: float | None = None) -> tuple:
    """Parameter tuple ``(p,)`` of :func:`analytic_eval`.

    ``pcm`` supplies E, nu (Hertz diagnostics), v_friction and u_max unless given explicitly."""
    gear = gear or BevelGearParams()
    pcm = pcm or PCMParams()
    v = virtual_spur_gears(gear)
    st = mesh_stiffness(gear)
    eps = v["eps_alpha"]
    if not 1.0 < eps < 2.0:
        raise ValueError(f"analytic mesh needs 1 < contact ratio < 2, got {eps:.3f}")
    ratio = gear.z_wheel / gear.z_pinion
    if c_mesh is None:
        m_eq = 1.0 / (v["r_b"] ** 2 * (1.0 / J_pinion + ratio ** 2 / J_wheel))
        c_mesh = 2.0 * damping_ratio * math.sqrt(st["k_mean"] * m_eq)
    L_d = (eps - 1.0) * v["p_b"]
    delta = transition * v["p_b"]
    if not 0.0 <= delta < min(L_d, v["p_b"] - L_d):
        raise ValueError("transition must be shorter than the single and double pair zones")
    p = np.zeros(N_P)
    p[P_RATIO] = ratio
    p[P_SB] = backlash_angle(gear)
    p[P_RB] = v["r_b"]
    p[P_K1] = st["k_single"]
    p[P_K2] = st["k_double"]
    p[P_PB] = v["p_b"]
    p[P_LD] = L_d
    p[P_GA] = v["g_a"]
    p[P_GR] = v["g_r"]
    p[P_PHASE] = mesh_phase
    p[P_COAST] = (math.pi + 4.0 * gear.x_pinion * math.tan(gear.pressure_angle)) / gear.z_pinion
    p[P_DELTA] = delta
    p[P_C] = c_mesh
    p[P_MU] = mu
    p[P_VF] = pcm.v_friction if v_friction is None else v_friction
    p[P_RHO1] = v["rho1_pitch"]
    p[P_RHO2] = v["rho2_pitch"]
    p[P_COS1] = math.cos(gear.delta_pinion)
    p[P_COS2] = math.cos(gear.delta_wheel)
    p[P_ESTAR] = pcm.E / (2.0 * (1.0 - pcm.nu ** 2))
    p[P_FACE] = gear.face_width
    p[P_UMAX] = pcm.u_max if u_max is None else u_max
    return (p,)


def make_analytic_model(gear_params: BevelGearParams | None = None, pcm_params: PCMParams | None = None,
                        resolution=None, health="healthy", mesh_files=None, **kw) -> MeshModel:
    """MeshModel of the analytic reference pair (fidelity "analytic"). It models the healthy pair only
    (``health`` other than healthy or ``mesh_files`` raise ValueError); ``resolution`` does not apply.
    Keywords: see :func:`make_analytic_data`; unknown keywords are ignored (the factory passes stage
    options)."""
    if not supports("analytic", "teeth") and (health not in ("healthy", "", None) or mesh_files):
        raise ValueError("the analytic mesh models the healthy pair only (health='healthy', "
                         "no mesh files); use fidelity 'pcm' or 'table' for faults")
    gear = gear_params or BevelGearParams()
    names = ("damping_ratio", "c_mesh", "J_pinion", "J_wheel", "mu", "v_friction", "mesh_phase",
             "transition", "u_max")
    opts = {k: kw[k] for k in names if k in kw}
    data = make_analytic_data(gear, pcm_params, **opts)
    v = virtual_spur_gears(gear)
    iso = iso6336_stiffness(gear)
    st = mesh_stiffness(gear)
    info = dict(c_prime=iso["c_prime"], c_gamma=iso["c_gamma"], eps_alpha=v["eps_alpha"], r_b=v["r_b"],
                z_v1=v["z_v1"], z_v2=v["z_v2"], K_single=st["K_single"], K_double=st["K_double"],
                K_mean=st["K_mean"], c_mesh=float(data[0][P_C]), s_backlash=float(data[0][P_SB]),
                mesh_period=2.0 * math.pi / gear.z_pinion)
    return MeshModel(eval=analytic_eval, data=data, fidelity="analytic", kind="mesh", info=info)


# --------------------------------------------------------------------------------------------
# numba kernel
# --------------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _smoothstep(x):
    """C1 step 0 -> 1 on [0, 1] and its derivative."""
    if x <= 0.0:
        return 0.0, 0.0
    if x >= 1.0:
        return 1.0, 0.0
    return x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x)


@njit(cache=True)
def _double_weight(u, p_b, L_d, delta):
    """Weight w in [0, 1] of the second pair at cycle position u (double zone [0, L_d) per cycle),
    blended over delta, and dw/du."""
    u = u - p_b * math.floor(u / p_b)
    w = 0.0
    dw = 0.0
    if delta <= 0.0:
        if u < L_d:
            w = 1.0
        return w, dw
    for m in range(-1, 2):
        a, da = _smoothstep((u - m * p_b) / delta + 0.5)
        b, db = _smoothstep((u - L_d - m * p_b) / delta + 0.5)
        w += a - b
        dw += (da - db) / delta
    return w, dw


@njit(cache=True)
def analytic_eval(data, theta_pinion, theta_wheel, omega_pinion, omega_wheel, out):
    p = data[0]
    for i in range(out.shape[0]):
        out[i] = 0.0
    r = p[P_RATIO]
    sb2 = 0.5 * p[P_SB]
    s = theta_pinion - r * theta_wheel
    if s > sb2:
        d_s = s - sb2
        flank = 1.0
        u = p[P_GA] + p[P_RB] * (theta_pinion - p[P_PHASE])
    elif s < -sb2:
        d_s = s + sb2
        flank = -1.0
        u = p[P_GR] + p[P_RB] * (theta_pinion - p[P_PHASE] - p[P_COAST])
    else:
        out[OUT_STATUS] = STATUS_OK
        return
    rb = p[P_RB]
    w, dw = _double_weight(u, p[P_PB], p[P_LD], p[P_DELTA])
    k = p[P_K1] + (p[P_K2] - p[P_K1]) * w
    K = k * rb * rb                         # N m / rad
    dK = (p[P_K2] - p[P_K1]) * dw * rb * rb * rb   # dK/dtheta_p
    sdot = omega_pinion - r * omega_wheel
    C = p[P_C] * rb * rb
    Q = K * d_s + C * sdot                  # generalised mesh force in s [N m]
    if flank * Q < 0.0:
        Q = 0.0
    tau_p = -Q - 0.5 * dK * d_s * d_s
    tau_w = r * Q
    V = 0.5 * K * d_s * d_s
    p_diss = (Q - K * d_s) * sdot
    F = abs(Q) / rb                         # normal force along the line of action [N]

    # pairs in contact: the newer tooth at cycle position u0, the older one at u0 + p_b (weight w)
    p_b = p[P_PB]
    u0 = u - p_b * math.floor(u / p_b)
    shares0 = 1.0 / (1.0 + w)
    shares1 = w / (1.0 + w)
    w1v = omega_pinion * p[P_COS1]
    w2v = omega_wheel * p[P_COS2]
    area = 0.0
    pmax = 0.0
    E = p[P_ESTAR]
    bface = p[P_FACE]
    for j in range(2):
        share = shares0 if j == 0 else shares1
        if share <= 0.0:
            continue
        uj = u0 + j * p_b
        # distance from the pitch point towards the pinion tip
        if flank > 0.0:
            g = uj - p[P_GA]
        else:
            g = p[P_GR] - uj
        rho1 = p[P_RHO1] + g
        rho2 = p[P_RHO2] - g
        Fi = F * share
        if rho1 > 0.0 and rho2 > 0.0 and Fi > 0.0:
            R = rho1 * rho2 / (rho1 + rho2)
            q = Fi / bface
            a = math.sqrt(4.0 * q * R / (math.pi * E))
            area += 2.0 * a * bface
            p0 = math.sqrt(q * E / (math.pi * R))
            if p0 > pmax:
                pmax = p0
        if p[P_MU] > 0.0 and Fi > 0.0:
            vs = w1v * rho1 - w2v * rho2
            x = vs / p[P_VF]
            if x > 1.0:
                x = 1.0
            elif x < -1.0:
                x = -1.0
            Ff = -p[P_MU] * Fi * x
            tau_p += Ff * rho1 * p[P_COS1]
            tau_w -= Ff * rho2 * p[P_COS2]
            p_diss -= Ff * vs
    approach = rb * abs(d_s)
    out[OUT_TAU_PINION] = tau_p
    out[OUT_TAU_WHEEL] = tau_w
    out[OUT_N_CONTACT] = 2.0 if w >= 0.5 else 1.0
    out[OUT_CONTACT_AREA] = area
    out[OUT_PEAK_PRESSURE] = pmax
    out[OUT_MAX_PENETRATION] = approach
    out[OUT_NORMAL_FORCE] = F
    out[OUT_ELASTIC_ENERGY] = V
    out[OUT_DISSIPATED_POWER] = p_diss
    out[OUT_STATUS] = STATUS_PENETRATION_EXCEEDED if approach > p[P_UMAX] else STATUS_OK
