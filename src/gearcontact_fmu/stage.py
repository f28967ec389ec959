"""Gear stage dynamics: pinion and wheel inertias, a port spring-damper on each flange, and the mesh
model in between, advanced over one communication step by a numba sub-stepping integrator.

Modes
-----
``"stage"`` (default): the stage owns the pinion inertia J_p and the wheel inertia J_w and a
spring-damper (k_a, d_a) between flange_a and the pinion and (k_b, d_b) between flange_b and the wheel.
Inputs per communication step [t_n, t_n + H]: the flange angles and speeds at t_n. Inside the step the
flange angles are extrapolated linearly, phi(t) = phi_n + w_n (t - t_n), w(t) = w_n (this raises the
co-simulation stability limit of the port cut, see docs/FMU.md). Outputs: the torque the stage applies
to the external body on each flange, tau_a = k_a (theta_p - phi_a) + d_a (omega_p - w_a) (it pulls the
external body towards the pinion) and tau_b likewise with the wheel, in three forms:
- ``tau_*_mean``: the exact mean over the step, (1/H) int tau dt. The work the stage exchanges through a
  flange over the step is exactly -H tau_mean w_n: the energy audit closes with it.
- the step-end value;
- the prediction of the mean over the *next* step, tau_end + H/2 k (omega_int - w_ext).
``output_torque`` selects which one ``tau_a``/``tau_b`` (the coupling torques) carry. A Jacobi master
applies them over the next step, so the mean of the last step is a full step late: measured, it is the
least stable coupling; the prediction (default) is the most stable (docs/FMU.md has the limits).
``energy_correction`` (default on) adds to the coupling torques a small correction that returns the
work mismatch of each cut measured one step later (gearcontact_fmu.coupling); the step means and the
state are not touched, ``correction.mismatch_J`` holds what is still pending.
With fidelity "ideal" (MeshModel.kind == "rigid") pinion and wheel form one rigid body
J_p + J_w/r^2 (pinion-referred, r = z2/z1); the mesh torques reported are the constraint torques.

``"bare"``: no inertias and no port springs. The inputs are the pinion (flange_a) and wheel (flange_b)
angles and speeds themselves, the outputs the mesh torques on pinion and wheel, averaged over the step
along the extrapolated inputs. The host owns the inertias and must take steps small enough for the
mesh mode (8-35 kHz): a zero-order-hold cut through the mesh is stable only for
omega H / 4 < zeta < 1 / (omega H), i.e. H of about 1 us.

Integrators (sub-step h = H / ceil(H / max_substep))
----------------------------------------------------
``"ros2"``: the 2-stage linearly implicit Rosenbrock method of Verwer et al. (1999),
gamma = 1 + 1/sqrt(2), L-stable, second order for any Jacobian approximation (a W-method). The
Jacobian's mesh part comes from forward differences of the mesh torques with respect to the wheel
angle and speed (the mesh coordinate s and its rate); the spring parts are analytic. Cost: 4 mesh
evaluations per sub-step. Stable for the over-damped PCM contact at any sub-step.
``"rk4"``: classic explicit Runge-Kutta, 4 evaluations per sub-step; stable only for
omega_mesh h < 2.8 and, with the paper's contact damping, h below about 0.1 us.
``"auto"`` (default): rk4 where it is stable (ideal mesh; analytic mesh with |lambda| h < 2.5), else ros2.
A contact closing or opening inside a sub-step halves it, down to h/64.
Measured trade-off: docs/FMU.md.

The energy audit integrates the port and mesh dissipation with the same scheme as the state:
energy_stored = kinetic + port springs + mesh elastic energy, energy_dissipated (cumulative) = port
dampers + mesh damping/friction; over a step, -H (tau_a_mean w_a + tau_b_mean w_b) = delta stored + delta
dissipated to integrator accuracy.

Stability counters (cumulative since ``initialize``, accumulated inside the kernel at no extra mesh
evaluation, they never change the state): the largest element penetration at any evaluated sub-step
point (``peak_penetration``), the smallest accepted sub-step (``min_substep``), accepted sub-steps and
halvings (``n_substeps_total``, ``n_refinements``), the time out of contact (``separated_time``, the
trapezoidal rule on the contact state at the sub-step ends) and the contact-loss events
(``n_separations``); ``counters()`` returns them all. Out of contact means the mesh torque and normal
force are exactly zero (inside the backlash). The ideal mesh never separates (its counters stay 0).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
from numba import njit, types

from gearcontact_fmu.coupling import EnergyCorrection
from gearcontact_fmu.mesh_models import DEFAULT_FIDELITY, make_mesh_model
from gearcontact_fmu.mesh_models.base import (
    N_OUT,
    OUT_DISSIPATED_POWER,
    OUT_ELASTIC_ENERGY,
    OUT_MAX_PENETRATION,
    OUT_NORMAL_FORCE,
    OUT_STATUS,
    OUT_TAU_PINION,
    OUT_TAU_WHEEL,
    SCHEMES,
    MeshModel,
    eval_signature,
)
from gearcontact_fmu.params import (CODE_MESH_STATUS, CODE_NONFINITE_INPUT, CODE_NONFINITE_STATE, CODE_OK,
                                    BevelGearParams, checked_substeps, substeps)


class StageError(RuntimeError):
    """The stage cannot continue: a mesh error state, a non-finite state or input."""


MODES = ("stage", "bare")

# kernel modes
_M_STAGE = 0
_M_RIGID = 1
_M_BARE = 2
_S_ROS2 = 0
_S_RK4 = 1
# return codes

# par layout
_PJP, _PJW, _PKA, _PDA, _PKB, _PDB, _PR, _PHTH, _PHW = range(9)
N_PAR = 9
# state layout: theta_p, theta_w, omega_p, omega_w, int tau_a dt, int tau_b dt, dissipated energy
N_X = 7
# res layout
# mean torques over the step, stored energy at the end, failure time and detail, torques at the step
# end, torques predicted as the mean over the next step (first-order Taylor at the end)
_RTA, _RTB, _RES, _RTF, _RDET, _RTAE, _RTBE, _RTAP, _RTBP = range(9)
# stability counters, cumulative over the steps (the kernel never resets them; GearStage.initialize
# does): smallest accepted sub-step, sub-step halvings (event refinements), accepted sub-steps, time
# out of contact, contact-loss events, largest element penetration, contact state at the last point
# evaluated (1 in contact, 0 not, -1 unknown). The rigid (ideal) mesh has no contact to lose: its
# separation counters and penetration stay 0.
_RDTMIN, _RNREF, _RNSUB, _RTSEP, _RNSEP, _RPEN, _RINC = range(9, 16)
N_RES = 16
OUTPUT_TORQUES = ("predicted", "mean", "end")

GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


@dataclass
class StageParams:
    """Parameters of the gear stage (SI). Inertia and port defaults: the public lumped model
    (testbench_lumped_parameters.csv): J_p node 17, J_w node 18, k_a/d_a element 14, k_b/d_b element
    16; the drivetrain assembler may override them."""

    J_pinion: float = 2.69e-4      # kg m^2
    J_wheel: float = 1.8e-4        # kg m^2
    k_a: float = 1140.0            # N m/rad, flange_a -> pinion
    d_a: float = 0.05              # N m s/rad
    k_b: float = 12200.0           # N m/rad, flange_b -> wheel
    d_b: float = 0.52              # N m s/rad
    max_substep: float = 1e-5      # s
    scheme: str = "auto"           # "auto" | "ros2" | "rk4" (auto: see GearStage.scheme)
    mode: str = "stage"
    output_torque: str = "predicted"   # flange torque output: "predicted" | "mean" | "end"
    energy_correction: bool = True     # energy-conserving correction of the flange torques (coupling.py)
    fd_angle: float = 1e-7         # rad, finite-difference step of the mesh Jacobian (wheel angle x z2/z1)
    fd_speed: float = 1e-4         # rad/s


# --------------------------------------------------------------------------------------------
# numba kernel
# --------------------------------------------------------------------------------------------

@njit(cache=True)
def _rhs(f, data, mode, par, u, t, y, dy, out):
    """dy/dt of the augmented state at time t (relative to the step start); fills the mesh ``out``."""
    phi_a = u[0] + u[1] * t
    phi_b = u[2] + u[3] * t
    ka = par[_PKA]
    da = par[_PDA]
    kb = par[_PKB]
    db = par[_PDB]
    if mode == _M_STAGE:
        f(data, y[0], y[1], y[2], y[3], out)
        ta = -ka * (y[0] - phi_a) - da * (y[2] - u[1])
        tb = -kb * (y[1] - phi_b) - db * (y[3] - u[3])
        dy[0] = y[2]
        dy[1] = y[3]
        dy[2] = (ta + out[OUT_TAU_PINION]) / par[_PJP]
        dy[3] = (tb + out[OUT_TAU_WHEEL]) / par[_PJW]
        dy[4] = -ta
        dy[5] = -tb
        dy[6] = (da * (y[2] - u[1]) ** 2 + db * (y[3] - u[3]) ** 2 + out[OUT_DISSIPATED_POWER])
    else:  # rigid
        r = par[_PR]
        for i in range(out.shape[0]):
            out[i] = 0.0
        ta = -ka * (y[0] - phi_a) - da * (y[2] - u[1])
        tb = -kb * (y[0] / r - phi_b) - db * (y[2] / r - u[3])
        jeq = par[_PJP] + par[_PJW] / (r * r)
        acc = (ta + tb / r) / jeq
        dy[0] = y[2]
        dy[1] = y[2] / r
        dy[2] = acc
        dy[3] = acc / r
        dy[4] = -ta
        dy[5] = -tb
        dy[6] = da * (y[2] - u[1]) ** 2 + db * (y[2] / r - u[3]) ** 2
        out[OUT_TAU_PINION] = par[_PJP] * acc - ta
        out[OUT_TAU_WHEEL] = par[_PJW] * acc / r - tb


@njit(cache=True)
def _stored(mode, par, u, t, y, out):
    phi_a = u[0] + u[1] * t
    phi_b = u[2] + u[3] * t
    if mode == _M_BARE:
        return out[OUT_ELASTIC_ENERGY]
    if mode == _M_RIGID:
        r = par[_PR]
        jeq = par[_PJP] + par[_PJW] / (r * r)
        return (0.5 * jeq * y[2] ** 2 + 0.5 * par[_PKA] * (y[0] - phi_a) ** 2
                + 0.5 * par[_PKB] * (y[0] / r - phi_b) ** 2)
    return (0.5 * par[_PJP] * y[2] ** 2 + 0.5 * par[_PJW] * y[3] ** 2
            + 0.5 * par[_PKA] * (y[0] - phi_a) ** 2 + 0.5 * par[_PKB] * (y[1] - phi_b) ** 2
            + out[OUT_ELASTIC_ENERGY])


@njit(cache=True)
def _jacobian(f, data, mode, par, u, t, y, out0, outp, J, ft):
    """Jacobian of the augmented rhs (7x7, quadrature columns zero) and its time derivative.
    ``out0`` holds the mesh outputs at y."""
    n = y.shape[0]
    for i in range(n):
        ft[i] = 0.0
        for j in range(n):
            J[i, j] = 0.0
    ka = par[_PKA]
    da = par[_PDA]
    kb = par[_PKB]
    db = par[_PDB]
    r = par[_PR]
    jp = par[_PJP]
    jw = par[_PJW]
    if mode == _M_STAGE:
        # mesh derivatives w.r.t. the wheel angle and speed (forward differences); the pinion columns
        # follow from s = theta_p - r theta_w (the explicit phase dependence is neglected: W-method)
        # perturb towards the flank the mesh coordinate is closer to (deeper into contact), so that a
        # state just touching still sees the contact stiffness
        sgn = -1.0 if y[0] - r * y[1] >= 0.0 else 1.0
        hth = sgn * par[_PHTH] / r
        hw = sgn * par[_PHW] / r
        f(data, y[0], y[1] + hth, y[2], y[3], outp)
        dtp_dthw = (outp[OUT_TAU_PINION] - out0[OUT_TAU_PINION]) / hth
        dtw_dthw = (outp[OUT_TAU_WHEEL] - out0[OUT_TAU_WHEEL]) / hth
        dp_dthw = (outp[OUT_DISSIPATED_POWER] - out0[OUT_DISSIPATED_POWER]) / hth
        f(data, y[0], y[1], y[2], y[3] + hw, outp)
        dtp_dww = (outp[OUT_TAU_PINION] - out0[OUT_TAU_PINION]) / hw
        dtw_dww = (outp[OUT_TAU_WHEEL] - out0[OUT_TAU_WHEEL]) / hw
        dp_dww = (outp[OUT_DISSIPATED_POWER] - out0[OUT_DISSIPATED_POWER]) / hw
        J[0, 2] = 1.0
        J[1, 3] = 1.0
        J[2, 0] = (-ka - dtp_dthw / r) / jp
        J[2, 1] = dtp_dthw / jp
        J[2, 2] = (-da - dtp_dww / r) / jp
        J[2, 3] = dtp_dww / jp
        J[3, 0] = (-dtw_dthw / r) / jw
        J[3, 1] = (-kb + dtw_dthw) / jw
        J[3, 2] = (-dtw_dww / r) / jw
        J[3, 3] = (-db + dtw_dww) / jw
        J[4, 0] = ka
        J[4, 2] = da
        J[5, 1] = kb
        J[5, 3] = db
        J[6, 0] = -dp_dthw / r
        J[6, 1] = dp_dthw
        J[6, 2] = 2.0 * da * (y[2] - u[1]) - dp_dww / r
        J[6, 3] = 2.0 * db * (y[3] - u[3]) + dp_dww
        ft[2] = ka * u[1] / jp
        ft[3] = kb * u[3] / jw
        ft[4] = -ka * u[1]
        ft[5] = -kb * u[3]
    else:  # rigid
        jeq = jp + jw / (r * r)
        a_th = (-ka - kb / (r * r)) / jeq
        a_w = (-da - db / (r * r)) / jeq
        J[0, 2] = 1.0
        J[1, 2] = 1.0 / r
        J[2, 0] = a_th
        J[2, 2] = a_w
        J[3, 0] = a_th / r
        J[3, 2] = a_w / r
        J[4, 0] = ka
        J[4, 2] = da
        J[5, 0] = kb / r
        J[5, 2] = db / r
        J[6, 2] = 2.0 * da * (y[2] - u[1]) + 2.0 * db * (y[2] / r - u[3]) / r
        ft[2] = (ka * u[1] + kb * u[3] / r) / jeq
        ft[3] = ft[2] / r
        ft[4] = -ka * u[1]
        ft[5] = -kb * u[3]


@njit(cache=True)
def _lu_factor(A, piv):
    n = A.shape[0]
    for k in range(n):
        p = k
        amax = abs(A[k, k])
        for i in range(k + 1, n):
            if abs(A[i, k]) > amax:
                amax = abs(A[i, k])
                p = i
        piv[k] = p
        if p != k:
            for j in range(n):
                tmp = A[k, j]
                A[k, j] = A[p, j]
                A[p, j] = tmp
        akk = A[k, k]
        if akk == 0.0:
            continue
        for i in range(k + 1, n):
            A[i, k] /= akk
            lik = A[i, k]
            if lik != 0.0:
                for j in range(k + 1, n):
                    A[i, j] -= lik * A[k, j]


@njit(cache=True)
def _lu_solve(A, piv, b):
    n = A.shape[0]
    for k in range(n):
        p = piv[k]
        if p != k:
            tmp = b[k]
            b[k] = b[p]
            b[p] = tmp
    for i in range(n):
        s = b[i]
        for j in range(i):
            s -= A[i, j] * b[j]
        b[i] = s
    for i in range(n - 1, -1, -1):
        s = b[i]
        for j in range(i + 1, n):
            s -= A[i, j] * b[j]
        b[i] = s / A[i, i]


@njit(cache=True)
def _in_contact(out):
    return out[OUT_TAU_PINION] != 0.0 or out[OUT_NORMAL_FORCE] != 0.0


#: bare mode always tracks; a typed True, not the literal, so that _tally and _tally_start compile once for both modes
_TRACK = np.bool_(True)


@njit(cache=True)
def _tally_start(res, c, pen, track):
    """Stability counters at the start of a step (state c, penetration pen): a contact lost between
    the last point of the previous step and this one (bare mode: new inputs) counts as an event."""
    if track:
        if res[_RINC] == 1.0 and not c:
            res[_RNSEP] += 1.0
        if pen > res[_RPEN]:
            res[_RPEN] = pen
        res[_RINC] = 1.0 if c else 0.0


@njit(cache=True)
def _tally(res, dt, c0, c1, pen, track):
    """Stability counters of one accepted sub-step of length dt from contact state c0 to c1 with the
    penetration pen at its end; time out of contact by the trapezoidal rule on the two end states."""
    if dt < res[_RDTMIN]:
        res[_RDTMIN] = dt
    res[_RNSUB] += 1.0
    if track:
        if pen > res[_RPEN]:
            res[_RPEN] = pen
        sep = 0.0
        if not c0:
            sep += 0.5
        if not c1:
            sep += 0.5
        res[_RTSEP] += sep * dt
        if c0 and not c1:
            res[_RNSEP] += 1.0
        res[_RINC] = 1.0 if c1 else 0.0


@njit(cache=True)
def _finite(y):
    for i in range(y.shape[0]):
        if not np.isfinite(y[i]):
            return False
    return True


@njit(cache=True)
def _advance_bare(f, data, u, H, n_sub, x, out, res):
    """_advance_py in bare mode (no inertias): the driven motion u, Simpson quadrature of the mesh torques
    and the dissipation per sub-step; the torques at the step end and predicted over the next step."""
    h = H / n_sub
    outp = np.empty(out.shape[0])
    t = 0.0
    f(data, u[0], u[2], u[1], u[3], out)
    _tally_start(res, _in_contact(out), out[OUT_MAX_PENETRATION], _TRACK)
    for i in range(n_sub):
        if out[OUT_STATUS] != 0.0:
            res[_RTF] = t
            res[_RDET] = out[OUT_MAX_PENETRATION]
            return CODE_MESH_STATUS
        ta0 = out[OUT_TAU_PINION]
        tb0 = out[OUT_TAU_WHEEL]
        p0 = out[OUT_DISSIPATED_POWER]
        c0 = _in_contact(out)
        tm = t + 0.5 * h
        f(data, u[0] + u[1] * tm, u[2] + u[3] * tm, u[1], u[3], out)
        ta1 = out[OUT_TAU_PINION]
        tb1 = out[OUT_TAU_WHEEL]
        p1 = out[OUT_DISSIPATED_POWER]
        pen1 = out[OUT_MAX_PENETRATION]
        if pen1 > res[_RPEN]:
            res[_RPEN] = pen1
        t = (i + 1) * h
        f(data, u[0] + u[1] * t, u[2] + u[3] * t, u[1], u[3], out)
        _tally(res, h, c0, _in_contact(out), out[OUT_MAX_PENETRATION], _TRACK)
        x[4] += h / 6.0 * (ta0 + 4.0 * ta1 + out[OUT_TAU_PINION])
        x[5] += h / 6.0 * (tb0 + 4.0 * tb1 + out[OUT_TAU_WHEEL])
        x[6] += h / 6.0 * (p0 + 4.0 * p1 + out[OUT_DISSIPATED_POWER])
        if not (_finite(out) and _finite(x)):
            res[_RTF] = t
            return CODE_NONFINITE_STATE
    x[0] = u[0] + u[1] * H
    x[1] = u[2] + u[3] * H
    x[2] = u[1]
    x[3] = u[3]
    if out[OUT_STATUS] != 0.0:
        res[_RTF] = H
        res[_RDET] = out[OUT_MAX_PENETRATION]
        return CODE_MESH_STATUS
    res[_RTA] = x[4] / H
    res[_RTB] = x[5] / H
    res[_RES] = out[OUT_ELASTIC_ENERGY]
    res[_RTAE] = out[OUT_TAU_PINION]
    res[_RTBE] = out[OUT_TAU_WHEEL]
    # predicted mean over the next step: the torques at its midpoint along the extrapolation
    tm = 1.5 * H
    f(data, u[0] + u[1] * tm, u[2] + u[3] * tm, u[1], u[3], outp)
    res[_RTAP] = outp[OUT_TAU_PINION]
    res[_RTBP] = outp[OUT_TAU_WHEEL]
    return CODE_OK


@njit(cache=True)
def _end_of_step(mode, par, u, H, y, out, res):
    """After the last sub-step of an integrating mode: the mean torques, the stored energy, the torques
    at the step end and the prediction of their mean over the next step, into res."""
    res[_RTA] = y[4] / H
    res[_RTB] = y[5] / H
    res[_RES] = _stored(mode, par, u, H, y, out)
    # torques at the step end, and the prediction of their mean over the next step: the spring part
    # extrapolated with the relative speed at the end (the damper's acceleration term is left out: it
    # carries the unresolved mesh-mode and impact accelerations and adds nothing to stability)
    wa = u[1]
    wb = u[3]
    if mode == _M_RIGID:
        th_w = y[0] / par[_PR]
        w_w = y[2] / par[_PR]
    else:
        th_w = y[1]
        w_w = y[3]
    ta = par[_PKA] * (y[0] - u[0] - wa * H) + par[_PDA] * (y[2] - wa)
    tb = par[_PKB] * (th_w - u[2] - wb * H) + par[_PDB] * (w_w - wb)
    ta_dot = par[_PKA] * (y[2] - wa)
    tb_dot = par[_PKB] * (w_w - wb)
    res[_RTAE] = ta
    res[_RTBE] = tb
    res[_RTAP] = ta + 0.5 * H * ta_dot
    res[_RTBP] = tb + 0.5 * H * tb_dot


def _advance_py(f, data, mode, scheme, x, par, u, H, n_sub, out, res):
    """Advance the stage over one communication step [0, H] (time relative to the step start).

    x: augmented state (updated in place; x[4], x[5] are reset: per-step torque integrals).
    u: inputs (phi_a, w_a, phi_b, w_b) at the step start. out: mesh outputs at the step end.
    res: tau_a_mean, tau_b_mean, energy_stored at the step end, failure time, failure detail; the
    stability counters (_RDTMIN.._RINC) are accumulated, never reset here.
    Returns a CODE_* value."""
    res[_RTF] = 0.0
    res[_RDET] = 0.0
    if not _finite(u):
        return CODE_NONFINITE_INPUT
    n = N_X
    h = H / n_sub
    x[4] = 0.0
    x[5] = 0.0
    if mode == _M_BARE:
        return _advance_bare(f, data, u, H, n_sub, x, out, res)

    outp = np.empty(out.shape[0])
    y = x
    f0 = np.empty(n)
    fn = np.empty(n)
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    k4 = np.empty(n)
    yn = np.empty(n)
    ytmp = np.empty(n)
    outn = np.empty(out.shape[0])
    J = np.empty((n, n))
    W = np.empty((n, n))
    ft = np.empty(n)
    piv = np.empty(n, dtype=np.int64)
    h_min = h / 64.0
    t = 0.0
    dt = h
    _rhs(f, data, mode, par, u, t, y, f0, out)
    track = mode != _M_RIGID
    _tally_start(res, _in_contact(out), out[OUT_MAX_PENETRATION], track)
    have_jac = False
    while True:
        if out[OUT_STATUS] != 0.0:
            res[_RTF] = t
            res[_RDET] = out[OUT_MAX_PENETRATION]
            return CODE_MESH_STATUS
        if not (_finite(y) and _finite(f0)):
            res[_RTF] = t
            return CODE_NONFINITE_STATE
        if t >= H * (1.0 - 1e-12):
            break
        if dt > H - t:
            dt = H - t
        c0 = _in_contact(out)
        if scheme == _S_ROS2:
            if not have_jac:
                _jacobian(f, data, mode, par, u, t, y, out, outp, J, ft)
                have_jac = True
            gh = GAMMA * dt
            for a in range(n):
                for b in range(n):
                    W[a, b] = -gh * J[a, b]
                W[a, a] += 1.0
            _lu_factor(W, piv)
            for a in range(n):
                k1[a] = f0[a] + gh * ft[a]
            _lu_solve(W, piv, k1)
            for a in range(n):
                ytmp[a] = y[a] + dt * k1[a]
            _rhs(f, data, mode, par, u, t + dt, ytmp, k2, outp)
            changed = _in_contact(outp) != c0
            for a in range(n):
                k2[a] = k2[a] - 2.0 * k1[a] - gh * ft[a]
            _lu_solve(W, piv, k2)
            for a in range(n):
                yn[a] = y[a] + dt * (1.5 * k1[a] + 0.5 * k2[a])
        else:
            for a in range(n):
                ytmp[a] = y[a] + 0.5 * dt * f0[a]
            _rhs(f, data, mode, par, u, t + 0.5 * dt, ytmp, k2, outp)
            changed = _in_contact(outp) != c0
            for a in range(n):
                ytmp[a] = y[a] + 0.5 * dt * k2[a]
            _rhs(f, data, mode, par, u, t + 0.5 * dt, ytmp, k3, outp)
            changed = changed or _in_contact(outp) != c0
            for a in range(n):
                ytmp[a] = y[a] + dt * k3[a]
            _rhs(f, data, mode, par, u, t + dt, ytmp, k4, outp)
            changed = changed or _in_contact(outp) != c0
            for a in range(n):
                yn[a] = y[a] + dt / 6.0 * (f0[a] + 2.0 * k2[a] + 2.0 * k3[a] + k4[a])
        _rhs(f, data, mode, par, u, t + dt, yn, fn, outn)
        # a contact closing or opening inside the sub-step (at a stage or at the end): the Jacobian of
        # the start state does not describe it; retry with halved steps down to h/64 (event refinement)
        c1 = _in_contact(outn)
        if (changed or c1 != c0) and dt > h_min:
            dt *= 0.5
            res[_RNREF] += 1.0
            continue
        _tally(res, dt, c0, c1, outn[OUT_MAX_PENETRATION], track)
        t += dt
        for a in range(n):
            y[a] = yn[a]
            f0[a] = fn[a]
        for a in range(out.shape[0]):
            out[a] = outn[a]
        have_jac = False
        if dt < h:
            dt = min(2.0 * dt, h)
    _end_of_step(mode, par, u, H, y, out, res)
    return CODE_OK


# --------------------------------------------------------------------------------------------
# kernel binding: the integrator is compiled (and cached on disk) once per data-tuple type with the
# mesh function as a first-class function argument; a tiny uncached wrapper binds the concrete
# mesh function so that a Python call costs ~0.3 us instead of ~18 us of function unboxing.
# --------------------------------------------------------------------------------------------

_KERNELS: dict = {}
_RUNNERS: dict = {}


def _get_runner(mesh_eval, data):
    data_type = nb.typeof(data)
    key = (mesh_eval, data_type)
    run = _RUNNERS.get(key)
    if run is not None:
        return run
    fsig = eval_signature(mesh_eval, data_type)
    kern = _KERNELS.get(fsig)
    if kern is None:
        arr = types.float64[::1]
        sig = types.int64(types.FunctionType(fsig), data_type, types.int64, types.int64, arr, arr, arr,
                          types.float64, types.int64, arr, arr)
        kern = njit(sig, cache=True)(_advance_py)
        _KERNELS[fsig] = kern

    f = mesh_eval

    @njit
    def run(data, mode, scheme, x, par, u, H, n_sub, out, res):
        return kern(f, data, mode, scheme, x, par, u, H, n_sub, out, res)

    _RUNNERS[key] = run
    return run


# --------------------------------------------------------------------------------------------
# Python API
# --------------------------------------------------------------------------------------------

class GearStage:
    """The gear stage around one mesh model. ``ratio`` = z2/z1.

    >>> st = GearStage(model, ratio=4.0)
    >>> st.initialize(0.0, phi_a, w_a, phi_b, w_b)
    >>> st.step(t, H, phi_a, w_a, phi_b, w_b)   # -> (tau_a, tau_b) coupling torques
    """

    def __init__(self, model: MeshModel, ratio: float, params: StageParams | None = None):
        self.model = model
        self.params = params = params or StageParams()
        if params.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {params.mode!r}")
        if params.scheme not in SCHEMES:
            raise ValueError(f"scheme must be one of {SCHEMES}, got {params.scheme!r}")
        if not params.max_substep > 0.0:
            raise ValueError("max_substep must be > 0")
        self.rigid = model.kind == "rigid"
        if params.mode == "bare":
            if self.rigid:
                raise ValueError("bare mode needs a compliant mesh; the ideal mesh has no torque law "
                                 "(use mode 'stage' with fidelity 'ideal')")
            self._mode = _M_BARE
        else:
            for name in ("J_pinion", "J_wheel"):
                if not getattr(params, name) > 0.0:
                    raise ValueError(f"{name} must be > 0 in stage mode")
            self._mode = _M_RIGID if self.rigid else _M_STAGE
        self.ratio = float(ratio)
        self.scheme = self._choose_scheme(params.scheme, model)
        self._scheme = _S_ROS2 if self.scheme == "ros2" else _S_RK4
        if params.output_torque not in OUTPUT_TORQUES:
            raise ValueError(f"output_torque must be one of {OUTPUT_TORQUES}, got {params.output_torque!r}")
        self._output = params.output_torque
        self._par = np.array([params.J_pinion, params.J_wheel, params.k_a, params.d_a, params.k_b,
                              params.d_b, self.ratio, params.fd_angle, params.fd_speed], dtype=np.float64)
        self._run = _get_runner(model.eval, model.data)
        self.x = np.zeros(N_X)
        self.u = np.zeros(4)
        self.out = np.zeros(N_OUT)
        self._u_scratch = np.zeros(4)
        self._out_scratch = np.zeros(N_OUT)
        self._res = np.zeros(N_RES)
        self.t = 0.0
        self.tau_a = 0.0
        self.tau_b = 0.0
        self.tau_a_mean = 0.0
        self.tau_b_mean = 0.0
        self.energy_stored = 0.0
        self.energy_supplied = 0.0
        self._e_diss_balance = 0.0
        self.n_sub_last = 0
        # the bare mode's outputs are mesh torques on host-owned bodies, not spring-side ports
        self.correction = EnergyCorrection((params.k_a, params.k_b),
                                           bool(params.energy_correction) and self._mode != _M_BARE)
        self.reset_counters()

    def _choose_scheme(self, scheme: str, model: MeshModel) -> str:
        """"auto": rk4 where it is stable at max_substep (ideal mesh; analytic mesh whose mesh-mode
        eigenvalue satisfies |lambda| h < 2.5), ros2 otherwise (pcm/table: over-damped stiff contact)."""
        if scheme != "auto":
            return scheme
        if self.rigid:
            return "rk4"
        info = model.info
        if model.fidelity == "analytic" and self._mode == _M_STAGE:
            p, r = self.params, self.ratio
            inv_j = 1.0 / p.J_pinion + r * r / p.J_wheel
            w = math.sqrt(info["K_double"] * inv_j)
            zeta = info["c_mesh"] * info["r_b"] ** 2 * inv_j / (2.0 * w)
            lam = w * (zeta + math.sqrt(zeta * zeta - 1.0)) if zeta >= 1.0 else w
            if lam * p.max_substep < 2.5:
                return "rk4"
        if self._mode == _M_BARE:
            return "rk4"        # bare mode has no ODE: the scheme is unused (Simpson quadrature)
        return "ros2"

    # ---- state access ---------------------------------------------------------------------
    @property
    def theta_pinion(self) -> float:
        return float(self.x[0])

    @property
    def theta_wheel(self) -> float:
        return float(self.x[1])

    @property
    def omega_pinion(self) -> float:
        return float(self.x[2])

    @property
    def omega_wheel(self) -> float:
        return float(self.x[3])

    @property
    def energy_dissipated(self) -> float:
        """Energy the sub-stepping actually removed, cumulative [J]: per communication step the work in
        through the flanges minus the change of stored energy (stage and rigid modes). It contains the
        port dampers, mesh damping and friction, and the numerical dissipation of the sub-steps, so the
        FMU's balance closes by construction and the master's audit measures the coupling.

        In an over-damped impact the linearly implicit sub-step removes the approach speed within a
        fraction of a sub-step; a quadrature of the dissipated power at the stage points then counts
        far more than was ever stored (measured: 140 J against 5.3 J of port work on the missing-tooth
        scene). That quadrature stays available as :attr:`energy_dissipated_quadrature`; its agreement
        with this balance is the integrator-accuracy check (tests/gear_contact/test_stage.py)."""
        if self._mode == _M_BARE:
            return float(self.x[6])
        return float(self._e_diss_balance)

    @property
    def energy_dissipated_quadrature(self) -> float:
        """Quadrature of the port-damper and mesh dissipated power over the sub-steps, cumulative [J]."""
        return float(self.x[6])

    # ---- stability counters (cumulative since initialize; kept by the kernel in self._res) ----------
    def reset_counters(self) -> None:
        """Restart the stability counters; the largest penetration starts from the current outputs."""
        res = self._res
        res[_RDTMIN] = math.inf
        res[_RNREF] = 0.0
        res[_RNSUB] = 0.0
        res[_RTSEP] = 0.0
        res[_RNSEP] = 0.0
        pen = 0.0 if self._mode == _M_RIGID else float(self.out[OUT_MAX_PENETRATION])
        res[_RPEN] = pen if math.isfinite(pen) else 0.0
        res[_RINC] = -1.0

    @property
    def peak_penetration(self) -> float:
        """Largest element penetration over every evaluated sub-step point [m] (0 for the ideal mesh).
        After a mesh error it includes the penetration that exceeded u_max."""
        return float(self._res[_RPEN])

    @property
    def coupling_energy_error(self) -> float:
        """Work mismatch of the two flange cuts still uncorrected [J] (gearcontact_fmu.coupling)."""
        return float(sum(self.correction.mismatch_J))

    @property
    def min_substep(self) -> float:
        """Smallest accepted sub-step [s]; 0.0 before the first step."""
        v = float(self._res[_RDTMIN])
        return v if math.isfinite(v) else 0.0

    @property
    def n_substeps_total(self) -> int:
        """Accepted sub-steps."""
        return int(self._res[_RNSUB])

    @property
    def n_refinements(self) -> int:
        """Sub-step halvings: sub-steps rejected because a contact closed or opened inside them."""
        return int(self._res[_RNREF])

    @property
    def separated_time(self) -> float:
        """Time the mesh spent out of contact (teeth separated, inside the backlash) [s]; 0 for the
        ideal mesh."""
        return float(self._res[_RTSEP])

    @property
    def n_separations(self) -> int:
        """Contact-loss events (in contact at one sub-step point, out of contact at the next)."""
        return int(self._res[_RNSEP])

    def counters(self) -> dict:
        """The stability counters as a dict (see the properties)."""
        return {"peak_penetration": self.peak_penetration, "min_substep": self.min_substep,
                "n_substeps": self.n_substeps_total, "n_refinements": self.n_refinements,
                "separated_time": self.separated_time, "n_separations": self.n_separations}

    def n_substeps(self, H: float) -> int:
        return substeps(H, self.params.max_substep)

    #: what changes as the stage steps (the rest is fixed when it is built; the mesh models keep no state
    #: that changes a result)
    _STATE_ARRAYS = ("x", "u", "out", "_res")
    _STATE_SCALARS = ("t", "tau_a", "tau_b", "tau_a_mean", "tau_b_mean", "energy_stored", "energy_supplied",
                      "_e_diss_balance", "n_sub_last")

    def get_state(self) -> dict:
        """A snapshot of everything a step changes (copies): ``set_state`` of it and the same steps
        repeat bit for bit (FMI fmi2GetFMUstate / fmi2SetFMUstate)."""
        state = {n: getattr(self, n).copy() for n in self._STATE_ARRAYS}
        state.update({n: getattr(self, n) for n in self._STATE_SCALARS})
        state["correction"] = self.correction.get_state()
        return state

    def set_state(self, state: dict) -> None:
        """Restore a snapshot of :meth:`get_state` (in place: the arrays keep their identity)."""
        for n in self._STATE_ARRAYS:
            getattr(self, n)[:] = state[n]
        for n in self._STATE_SCALARS:
            setattr(self, n, state[n])
        self.correction.set_state(state["correction"])

    def initialize(self, t0: float, phi_a: float, w_a: float, phi_b: float, w_b: float,
                   theta_pinion: float | None = None, theta_wheel: float | None = None,
                   omega_pinion: float | None = None, omega_wheel: float | None = None) -> None:
        """Set the internal state. Defaults: pinion at flange_a, wheel at flange_b (stage, mesh), the
        rigid body at flange_a (ideal); speeds likewise. Bare mode takes the inputs as the state."""
        u = np.array([phi_a, w_a, phi_b, w_b], dtype=np.float64)
        if not np.all(np.isfinite(u)):
            raise StageError(f"non-finite input at t = {t0:.9g} s: phi_a, w_a, phi_b, w_b = {u.tolist()}")
        r = self.ratio
        tp = phi_a if theta_pinion is None else theta_pinion
        wp = w_a if omega_pinion is None else omega_pinion
        if self._mode == _M_RIGID:
            tw, ww = tp / r, wp / r
        elif self._mode == _M_BARE:
            tp, wp, tw, ww = phi_a, w_a, phi_b, w_b
        else:
            tw = phi_b if theta_wheel is None else theta_wheel
            ww = w_b if omega_wheel is None else omega_wheel
        self.x[:] = (tp, tw, wp, ww, 0.0, 0.0, 0.0)
        self._e_diss_balance = 0.0
        self.u[:] = u
        self.t = float(t0)
        # outputs at t0: instantaneous values
        self._instantaneous()
        self.correction.reset((self.tau_a, self.tau_b))
        self.reset_counters()

    def _instantaneous(self):
        p = self._par
        x, u = self.x, self.u
        if self._mode == _M_BARE:
            self.model.eval(self.model.data, x[0], x[1], x[2], x[3], self.out)
            self.tau_a = float(self.out[OUT_TAU_PINION])
            self.tau_b = float(self.out[OUT_TAU_WHEEL])
            self.tau_a_mean, self.tau_b_mean = self.tau_a, self.tau_b
            self.energy_stored = float(self.out[OUT_ELASTIC_ENERGY])
            return
        if self._mode == _M_RIGID:
            self.out[:] = 0.0
            tw, ww = x[0] / self.ratio, x[2] / self.ratio
        else:
            self.model.eval(self.model.data, x[0], x[1], x[2], x[3], self.out)
            tw, ww = x[1], x[3]
        self.tau_a = float(p[_PKA] * (x[0] - u[0]) + p[_PDA] * (x[2] - u[1]))
        self.tau_b = float(p[_PKB] * (tw - u[2]) + p[_PDB] * (ww - u[3]))
        self.tau_a_mean, self.tau_b_mean = self.tau_a, self.tau_b
        ke = 0.5 * p[_PJP] * x[2] ** 2 + 0.5 * p[_PJW] * ww ** 2
        self.energy_stored = float(ke + 0.5 * p[_PKA] * (x[0] - u[0]) ** 2
                                   + 0.5 * p[_PKB] * (tw - u[2]) ** 2 + self.out[OUT_ELASTIC_ENERGY])

    def stored_energy_at_inputs(self, phi_a: float, w_a: float, phi_b: float, w_b: float) -> float:
        """Stored energy of the current internal state with the given flange angles (the energy at
        the start of a step, after the master set new inputs)."""
        u = self._u_scratch                  # called every step (energy balance): no allocation
        u[0], u[1], u[2], u[3] = phi_a, w_a, phi_b, w_b
        out = self._out_scratch
        x = self.x
        if self._mode == _M_BARE:
            self.model.eval(self.model.data, phi_a, phi_b, w_a, w_b, out)
            return float(out[OUT_ELASTIC_ENERGY])
        if self._mode == _M_STAGE:
            self.model.eval(self.model.data, x[0], x[1], x[2], x[3], out)
        return float(_stored(self._mode, self._par, u, 0.0, x, out))

    def _stored_at_step_start(self, phi_a: float, phi_b: float) -> float:
        """``stored_energy_at_inputs`` without evaluating the mesh again: ``self.out`` holds the mesh
        at the current state (evaluated by ``initialize`` and at the end of every step), so only the
        kinetic and port-spring terms are new. The same arithmetic as ``_stored`` at t = 0, in the same
        order (bit-identical); it saves two numba dispatches per step."""
        x, par = self.x, self._par
        da = x[0] - phi_a
        if self._mode == _M_RIGID:
            r = par[_PR]
            jeq = par[_PJP] + par[_PJW] / (r * r)
            db = x[0] / r - phi_b
            return float(0.5 * jeq * (x[2] * x[2]) + 0.5 * par[_PKA] * (da * da) + 0.5 * par[_PKB] * (db * db))
        db = x[1] - phi_b
        return float(0.5 * par[_PJP] * (x[2] * x[2]) + 0.5 * par[_PJW] * (x[3] * x[3])
                     + 0.5 * par[_PKA] * (da * da) + 0.5 * par[_PKB] * (db * db) + self.out[OUT_ELASTIC_ENERGY])

    def step(self, t: float, H: float, phi_a: float, w_a: float, phi_b: float, w_b: float):
        """Advance from t to t + H with the flange inputs at t. Returns the output torques
        (tau_a, tau_b) as selected by ``output_torque``; the step means are in tau_a_mean, tau_b_mean."""
        if not H > 0.0:
            raise StageError(f"communication step must be > 0, got {H!r} at t = {t:.9g} s")
        u = self.u
        u[0] = phi_a
        u[1] = w_a
        u[2] = phi_b
        u[3] = w_b
        n_sub, problem = checked_substeps(H, t, self.params.max_substep)
        if problem:
            raise StageError(problem)
        balance = self._mode != _M_BARE
        if balance:
            e0 = self._stored_at_step_start(phi_a, phi_b)
        code = self._run(self.model.data, self._mode, self._scheme, self.x, self._par, u, float(H), n_sub,
                         self.out, self._res)
        if code != CODE_OK:
            tf = t + self._res[_RTF]
            if code == CODE_NONFINITE_INPUT:
                raise StageError(f"non-finite input at t = {t:.9g} s: phi_a, w_a, phi_b, w_b = "
                                 f"{[phi_a, w_a, phi_b, w_b]}")
            if code == CODE_MESH_STATUS:
                raise StageError(f"mesh error state (status {int(self.out[OUT_STATUS])}: penetration "
                                 f"{self._res[_RDET]:.6g} m beyond u_max) at t = {tf:.9g} s")
            raise StageError(f"non-finite stage state at t = {tf:.9g} s (state {self.x[:4].tolist()}); "
                             f"reduce max_substep or check the parameters")
        self.t = t + H
        self.n_sub_last = n_sub
        res = self._res
        self.tau_a_mean = float(res[_RTA])
        self.tau_b_mean = float(res[_RTB])
        if self._output == "predicted":
            self.tau_a, self.tau_b = float(res[_RTAP]), float(res[_RTBP])
        elif self._output == "end":
            self.tau_a, self.tau_b = float(res[_RTAE]), float(res[_RTBE])
        else:
            self.tau_a, self.tau_b = self.tau_a_mean, self.tau_b_mean
        if balance:
            x = self.x
            self.tau_a, self.tau_b = self.correction.apply(
                (phi_a, phi_b), (w_a, w_b), H, (self.tau_a_mean, self.tau_b_mean), (self.tau_a, self.tau_b),
                (x[0], x[0] / self.ratio if self._mode == _M_RIGID else x[1]))
        self.energy_stored = float(res[_RES])
        if balance:
            # work in through the flanges (linearly extrapolated flange angles: constant speeds)
            w_in = -H * (w_a * self.tau_a_mean + w_b * self.tau_b_mean)
            self._e_diss_balance += w_in - (self.energy_stored - e0)
        return self.tau_a, self.tau_b


def make_stage(fidelity: str = DEFAULT_FIDELITY, gear_params=None, pcm_params=None, resolution=None,
               health: str = "healthy", mesh_files=None, stage_params: StageParams | None = None,
               **kw) -> GearStage:
    """Build the mesh model of ``fidelity`` (mesh_models.make_mesh_model) and a GearStage around it.
    The stage inertias are passed to the mesh builder (the analytic model uses them for its damping
    ratio)."""
    gear_params = gear_params or BevelGearParams()
    sp = stage_params or StageParams()
    model = stage_mesh_model(fidelity, gear_params, pcm_params, resolution, health, mesh_files, sp, **kw)
    return GearStage(model, gear_params.z_wheel / gear_params.z_pinion, sp)


def stage_mesh_model(fidelity: str = DEFAULT_FIDELITY, gear_params=None, pcm_params=None, resolution=None,
                     health: str = "healthy", mesh_files=None, stage_params: StageParams | None = None,
                     **kw) -> MeshModel:
    """The mesh model :func:`make_stage` puts in its stage (nothing of the stage's kernels compiled: what
    drivetrain.fmu_build.native_gear needs)."""
    sp = stage_params or StageParams()
    kw.setdefault("J_pinion", sp.J_pinion)
    kw.setdefault("J_wheel", sp.J_wheel)
    return make_mesh_model(fidelity, gear_params or BevelGearParams(), pcm_params, resolution, health=health,
                           mesh_files=mesh_files, **kw)
