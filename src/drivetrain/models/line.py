"""Pure models of the drivetrain components (no FMI): FlexibleShaft, UpperTransmission, MotorLoad.

All three are instances of one numerical core, :class:`LineModel`: a torsional chain of nodes (inertias)
joined by spring-dampers, with flange *ports* on some nodes, speed-dependent losses, sources (a PI
speed-controlled motor, a load torque) and one numba kernel, :func:`line_step`, that advances it over a
communication step H with ``n_sub = ceil(H / max_substep)`` sub-steps.

Integrator: the implicit midpoint rule (for the linear part identical to the trapezoidal rule),
A-stable for any sub-step, second order, and with an *exact* discrete energy balance: over every
sub-step, the kinetic energy change equals ``h * omega_mid . F_mid`` and the spring energy change
``k * defl_mid * d(defl)``, so ``supplied = delta stored + dissipated + work out through the ports``
holds to round-off (the energy audit of the master relies on it). Each sub-step solves one symmetric,
strictly diagonally dominant tridiagonal system (Thomas algorithm, O(N)). The nonlinear losses are
linearised at the start of the sub-step (the torque actually applied is what enters the balance).

Ports (docs/ARCHITECTURE.md): a port sits on node j with a ratio r (flange angle = r * theta_j).
- inertia side: input tau (torque on the flange from the neighbour, held over the step), outputs
  phi = r theta_j, w = r omega_j at the step end;
- spring side: the component owns a port spring (k_p, c_p) between r theta_j and the flange; inputs
  phi_n, w_n at the step start, extrapolated inside the step as phi(t) = phi_n + w_n (t - t_n) (this
  raises the stability limit of the cut, docs/DRIVETRAIN.md); output tau = torque applied to the
  neighbour, k_p (r theta_j - phi) + c_p (r omega_j - w), as ``output_torque`` says: 0 "mean" (the
  mean over the step just taken; default), 1 "end" (at the step end). (A "predicted" output, the end
  value plus H/2 times its rate, as the gear stage offers, is not offered here: the rate of a port on a
  light node is dominated by the sub-step dynamics of that node and fed a Nyquist oscillation back
  into the cut in a test; the step mean filters it.)

Loss law (one form for the upper gearbox and the planetary, fitted by ``drivetrain.campaigns.calibrate``):

    T_loss(omega, T_trans) = c_v omega + (T_c + a |T_trans|) tanh(omega / omega_c)

a speed-dependent viscous loss (equivalent coefficient c_v + (T_c + a|T|) tanh(omega/omega_c)/omega,
finite at standstill) plus a part proportional to the transmitted torque (gear efficiency).
It always opposes the motion (dissipative).
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, fields

import numpy as np
from numba import njit

from drivetrain.rig import data as rig
from drivetrain.errors import ComponentError  # noqa: F401  (re-exported)
from drivetrain.system import INERTIA, SPRING
from gearcontact_fmu.coupling import EnergyCorrection, correct_port
from gearcontact_fmu.params import CODE_NONFINITE_INPUT, CODE_NONFINITE_STATE, CODE_OK, checked_substeps, substeps

RPM = 2.0 * math.pi / 60.0

#: the kernel's code of each port kind (drivetrain.system.INERTIA / SPRING: the one vocabulary)
PORT_CODES = {INERTIA: 0, SPRING: 1}
OUTPUT_TORQUES = ("mean", "end")


# accumulator layout (per step, reset by the kernel)
A_DISS = 0          # dissipated energy [J]
A_SUPP = 1          # supplied energy [J] (motor work + work of source laws)
A_MOTOR = 2         # int motor torque dt
A_SRC = 3           # int source-law torque dt (load motor, on its node, as applied: resisting > 0)
N_ACC = 4


# ------------------------------------------------------------------------------------------------
# numba kernel
# ------------------------------------------------------------------------------------------------

@njit(cache=True)
def _finite(x):
    for i in range(x.shape[0]):
        if not np.isfinite(x[i]):
            return False
    return True


@njit(cache=True)
def _thomas(a, b, rhs, x, cp, dp):
    """Solve the symmetric tridiagonal system (diag a, off-diagonal b) a x = rhs."""
    n = a.shape[0]
    if n == 1:
        x[0] = rhs[0] / a[0]
        return
    cp[0] = b[0] / a[0]
    dp[0] = rhs[0] / a[0]
    for i in range(1, n):
        den = a[i] - b[i - 1] * cp[i - 1]
        if i < n - 1:
            cp[i] = b[i] / den
        dp[i] = (rhs[i] - b[i - 1] * dp[i - 1]) / den
    x[n - 1] = dp[n - 1]
    for i in range(n - 2, -1, -1):
        x[i] = dp[i] - cp[i] * x[i + 1]


@njit(cache=True)
def line_step(H, n_sub, fp, ip, st, out, wk, cs):
    """Advance a LineModel over [0, H] (time relative to the step start). Arguments are packed into
    few arrays (a numba call unboxes every array argument: ~0.3 us each), laid out by LineModel:

    ip (int64): n, P, L, motor node (-1: none), output mode (0 mean, 1 end), p_node[P], p_kind[P]
        (0 inertia, 1 spring), l_node[L],
        l_src[L] (1: the law is the work of a source, counted as negative supplied energy).
    fp (float64): Md[n], Mo[n] (off-diagonal mass, last unused), k[n], c[n] (element i joins node i and
        i+1, last unused), cext[n], p_ratio[P], p_k[P], p_c[P], p_u0[P] (tau | phi_n), p_u1[P] (- | w_n),
        l_cv[L], l_Tc[L], l_wc[L], m_par[4] (Kp, Ti, Ni, tau_max), wref0, wref1 (speed reference at the
        step start and end, linear in between).
    st: th[n], om[n], pi_x, alpha[n] (acceleration of the last sub-step), cumulative dissipated and
        supplied energy.
    out (reset here): acc[N_ACC] (step means of motor and source torque, step dissipated and supplied
        energy), tau_mean[P] (step mean of the spring-port torques), work_out[P] (work out through each
        port over the step), el_mean[n] (step mean of the element torques), tau_out[P] (spring-port
        torque output: the mean or the end value).
    wk: work space of at least 7 n + 2 L + 2 floats.
    cs: the energy-correction state of the spring-side ports, one row each in port order
        (gearcontact_fmu.coupling.correct_port corrects tau_out of each after the step)."""
    n = ip[0]
    npt = ip[1]
    nl = ip[2]
    m_node = ip[3]
    out_mode = ip[4]
    o_pn = 5
    o_pk = o_pn + npt
    o_ln = o_pk + npt
    o_ls = o_ln + nl
    o_Md = 0
    o_Mo = n
    o_k = 2 * n
    o_c = 3 * n
    o_ce = 4 * n
    o_pr = 5 * n
    o_pkk = o_pr + npt
    o_pc = o_pkk + npt
    o_u0 = o_pc + npt
    o_u1 = o_u0 + npt
    o_cv = o_u1 + npt
    o_Tc = o_cv + nl
    o_wc = o_Tc + nl
    o_m = o_wc + nl
    wref0 = fp[o_m + 4]
    wref1 = fp[o_m + 5]
    Kp = fp[o_m]
    Ti = fp[o_m + 1]
    Ni = fp[o_m + 2]
    Tmax = fp[o_m + 3]
    s_th = 0
    s_om = n
    s_pi = 2 * n
    s_al = 2 * n + 1
    s_e = 3 * n + 1
    o_acc = 0
    o_ti = N_ACC
    o_wo = o_ti + npt
    o_el = o_wo + npt
    o_to = o_el + n
    for i in range(o_to + npt):
        out[i] = 0.0
    for q in range(npt):
        if not (np.isfinite(fp[o_u0 + q]) and np.isfinite(fp[o_u1 + q])):
            return CODE_NONFINITE_INPUT
    if not (np.isfinite(wref0) and np.isfinite(wref1)):
        return CODE_NONFINITE_INPUT
    for q in range(nl):
        if not (np.isfinite(fp[o_Tc + q]) and np.isfinite(fp[o_cv + q])):
            return CODE_NONFINITE_INPUT
    h = H / n_sub
    a = wk[0:n]
    b = wk[n:2 * n]
    rhs = wk[2 * n:3 * n]
    wm = wk[3 * n:4 * n]
    cp = wk[4 * n:5 * n]
    dp = wk[5 * n:6 * n]
    lT0 = wk[6 * n:6 * n + nl]
    lS = wk[6 * n + nl:6 * n + 2 * nl]
    for sub in range(n_sub):
        tm = (sub + 0.5) * h
        # ---- assemble (2M/h + h/2 K + C) w_mid = 2M/h w0 - K th0 + f -----------------------------
        for i in range(n):
            a[i] = 2.0 * fp[o_Md + i] / h + fp[o_ce + i]
            rhs[i] = 2.0 * fp[o_Md + i] * st[s_om + i] / h
        for i in range(n - 1):
            ki = fp[o_k + i]
            ci = fp[o_c + i]
            mo = fp[o_Mo + i]
            b[i] = 2.0 * mo / h - 0.5 * h * ki - ci
            a[i] += 0.5 * h * ki + ci
            a[i + 1] += 0.5 * h * ki + ci
            rhs[i] += 2.0 * mo * st[s_om + i + 1] / h
            rhs[i + 1] += 2.0 * mo * st[s_om + i] / h
            f = ki * (st[s_th + i] - st[s_th + i + 1])
            rhs[i] -= f
            rhs[i + 1] += f
        for q in range(npt):
            j = ip[o_pn + q]
            r = fp[o_pr + q]
            if ip[o_pk + q] == 0:
                rhs[j] += r * fp[o_u0 + q]
            else:
                pk = fp[o_pkk + q]
                pc = fp[o_pc + q]
                phim = fp[o_u0 + q] + fp[o_u1 + q] * tm
                a[j] += r * r * (0.5 * h * pk + pc)
                rhs[j] += -r * pk * (r * st[s_th + j] - phim) + r * pc * fp[o_u1 + q]
        for q in range(nl):
            j = ip[o_ln + q]
            w0 = st[s_om + j]
            wc = fp[o_wc + q]
            tq = math.tanh(w0 / wc)
            lT0[q] = fp[o_cv + q] * w0 + fp[o_Tc + q] * tq
            lS[q] = fp[o_cv + q] + fp[o_Tc + q] * (1.0 - tq * tq) / wc
            a[j] += lS[q]
            rhs[j] -= lT0[q] - lS[q] * w0
        Tm = 0.0
        wr = wref0 + (wref1 - wref0) * (tm / H)
        if m_node >= 0:
            a[m_node] += Kp
            rhs[m_node] += Kp * (wr + st[s_pi])
        _thomas(a, b, rhs, wm, cp, dp)
        if m_node >= 0:
            j = m_node
            Tun = Kp * (wr - wm[j] + st[s_pi])
            Tm = Tun
            if Tun > Tmax or Tun < -Tmax:
                Tm = Tmax if Tun > 0.0 else -Tmax
                a[j] -= Kp
                rhs[j] += -Kp * (wr + st[s_pi]) + Tm
                _thomas(a, b, rhs, wm, cp, dp)
                Tun = Kp * (wr - wm[j] + st[s_pi])
            # LimPID integrator with back-calculation anti-windup
            st[s_pi] += h * ((wr - wm[j]) + (Tm - Tun) / (Kp * Ni)) / Ti
        # ---- energy and port bookkeeping (midpoint values) ------------------------------------------
        diss = 0.0
        supp = 0.0
        for i in range(n):
            diss += fp[o_ce + i] * wm[i] * wm[i]
        for i in range(n - 1):
            dw = wm[i] - wm[i + 1]
            ci = fp[o_c + i]
            diss += ci * dw * dw
            thm = (st[s_th + i] - st[s_th + i + 1]) + 0.5 * h * dw
            out[o_el + i] += h * (fp[o_k + i] * thm + ci * dw)
        for q in range(npt):
            j = ip[o_pn + q]
            r = fp[o_pr + q]
            if ip[o_pk + q] == 0:
                out[o_wo + q] -= h * r * fp[o_u0 + q] * wm[j]
            else:
                w = fp[o_u1 + q]
                phim = fp[o_u0 + q] + w * tm
                rel = r * wm[j] - w
                pc = fp[o_pc + q]
                te = fp[o_pkk + q] * (r * (st[s_th + j] + 0.5 * h * wm[j]) - phim) + pc * rel
                diss += pc * rel * rel
                out[o_ti + q] += h * te
                out[o_wo + q] += h * te * w
        for q in range(nl):
            j = ip[o_ln + q]
            Tu = lT0[q] + lS[q] * (wm[j] - st[s_om + j])
            if ip[o_ls + q] != 0:
                supp -= Tu * wm[j]
                out[o_acc + A_SRC] += h * Tu
            else:
                diss += Tu * wm[j]
        if m_node >= 0:
            supp += Tm * wm[m_node]
            out[o_acc + A_MOTOR] += h * Tm
        out[o_acc + A_DISS] += h * diss
        out[o_acc + A_SUPP] += h * supp
        # ---- update ------------------------------------------------------------------------------
        ok = True
        for i in range(n):
            w0 = st[s_om + i]
            w1 = 2.0 * wm[i] - w0
            st[s_al + i] = (w1 - w0) / h
            st[s_th + i] += h * wm[i]
            st[s_om + i] = w1
            if not (np.isfinite(w1) and np.isfinite(st[s_th + i])):
                ok = False
        if not ok:
            return CODE_NONFINITE_STATE
    # ---- step means, outputs, cumulative energies -----------------------------------------------------
    for i in range(N_ACC):
        if i == A_MOTOR or i == A_SRC:
            out[o_acc + i] /= H
    st[s_e] += out[o_acc + A_DISS]
    st[s_e + 1] += out[o_acc + A_SUPP]
    for i in range(n):
        out[o_el + i] /= H
    for q in range(npt):
        out[o_ti + q] /= H
        if ip[o_pk + q] == 1:
            if out_mode == 1:
                j = ip[o_pn + q]
                r = fp[o_pr + q]
                w = fp[o_u1 + q]
                out[o_to + q] = (fp[o_pkk + q] * (r * st[s_th + j] - fp[o_u0 + q] - w * H)
                                 + fp[o_pc + q] * (r * st[s_om + j] - w))
            else:
                out[o_to + q] = out[o_ti + q]
    # ---- energy-conserving correction of the spring-side outputs (gearcontact_fmu.coupling) -----------
    i = 0
    for q in range(npt):
        if ip[o_pk + q] == 1:
            out[o_to + q] = correct_port(cs, i, H, fp[o_u0 + q], fp[o_u1 + q], out[o_ti + q], out[o_to + q],
                                         fp[o_pr + q] * st[s_th + ip[o_pn + q]])
            i += 1
    return CODE_OK


# ------------------------------------------------------------------------------------------------
# LineModel: the Python side of the kernel
# ------------------------------------------------------------------------------------------------

@dataclass
class Port:
    name: str
    node: int
    kind: str                 # drivetrain.system.INERTIA | SPRING
    ratio: float = 1.0        # flange angle = ratio * node angle
    k: float = 0.0            # port spring (spring side)
    c: float = 0.0


@dataclass
class Law:
    """Loss law T = c_v w + (T_c + a |T_trans|) tanh(w / w_c) on a node (``source`` = it is the
    work of a source, e.g. the load motor, not a dissipation)."""
    name: str
    node: int
    c_v: float = 0.0
    T_c: float = 0.0
    w_c: float = 1.0
    a: float = 0.0
    source: bool = False


class LineModel:
    """A torsional chain with ports, laws and an optional PI-controlled motor (see module doc).

    The parameters and the state live in a few packed arrays (the kernel's layout); the attributes
    ``J, Mo, k, c, cext, p_*, l_*, m_par, th, om, pi_x, alpha, energy, acc, tau_mean, work_out, el_mean,
    tau_out`` are
    views into them, so writing e.g. ``model.l_Tc[0] = 2.0`` changes what the next step uses."""

    def __init__(self, J, k, c, cext=None, ports=(), laws=(), motor_node=-1, motor_par=(1.0, 1.0, 0.9, 1e9),
                 max_substep=1e-5, output_torque="mean", Mo=None, node_names=None, energy_correction=True):
        J = np.asarray(J, dtype=np.float64)
        n = J.shape[0]
        self.n = n
        if not (np.all(J > 0) and np.all(np.isfinite(J))):
            raise ValueError(f"node inertias must be finite and > 0, got {J.tolist()}")
        kk = np.zeros(n)
        cc = np.zeros(n)
        mo = np.zeros(n)
        kk[: n - 1] = np.asarray(k, dtype=float)[: n - 1] if n > 1 else []
        cc[: n - 1] = np.asarray(c, dtype=float)[: n - 1] if n > 1 else []
        if Mo is not None and n > 1:
            mo[: n - 1] = np.asarray(Mo, dtype=float)[: n - 1]
        ce = np.zeros(n) if cext is None else np.asarray(cext, dtype=np.float64)
        for nm, arr in (("k", kk), ("c", cc), ("cext", ce)):
            if not (np.all(arr >= 0) and np.all(np.isfinite(arr))):
                raise ValueError(f"{nm} must be finite and >= 0, got {arr.tolist()}")
        if not max_substep > 0:
            raise ValueError(f"max_substep must be > 0, got {max_substep!r}")
        if isinstance(output_torque, (int, np.integer)):
            if not 0 <= int(output_torque) < len(OUTPUT_TORQUES):
                raise ValueError(f"output_torque must be 0 (mean) or 1 (end), got {output_torque}")
            output_torque = OUTPUT_TORQUES[int(output_torque)]
        if output_torque not in OUTPUT_TORQUES:
            raise ValueError(f"output_torque must be one of {OUTPUT_TORQUES}, got {output_torque!r}")
        self.output_torque = output_torque
        self.max_substep = float(max_substep)
        self.node_names = list(node_names) if node_names else [f"n{i}" for i in range(n)]
        self.ports = list(ports)
        self.port_index = {p.name: i for i, p in enumerate(self.ports)}
        self.laws = list(laws)
        self.law_index = {lw.name: i for i, lw in enumerate(self.laws)}
        for lw in self.laws:
            if not lw.w_c > 0:
                raise ValueError(f"law {lw.name}: w_c must be > 0")
        P, L = len(self.ports), len(self.laws)
        self.motor_node = int(motor_node)
        m_par = np.array(motor_par, dtype=np.float64)
        if self.motor_node >= 0 and not (m_par[0] > 0 and m_par[1] > 0 and m_par[2] > 0 and m_par[3] >= 0):
            raise ValueError("motor: Kp, Ti, Ni must be > 0 and tau_max >= 0")
        # packed arrays
        self.ip = np.zeros(5 + 2 * P + 2 * L, dtype=np.int64)
        self.ip[:5] = (n, P, L, self.motor_node, OUTPUT_TORQUES.index(output_torque))
        self.ip[5:5 + P] = [p.node for p in self.ports]
        self.ip[5 + P:5 + 2 * P] = [PORT_CODES[p.kind] for p in self.ports]
        self.ip[5 + 2 * P:5 + 2 * P + L] = [lw.node for lw in self.laws]
        self.ip[5 + 2 * P + L:] = [1 if lw.source else 0 for lw in self.laws]
        self.fp = np.zeros(5 * n + 5 * P + 3 * L + 6)
        fp = self.fp
        self.J, self.Mo, self.k, self.c, self.cext = (fp[0:n], fp[n:2 * n], fp[2 * n:3 * n], fp[3 * n:4 * n],
                                                      fp[4 * n:5 * n])
        o = 5 * n
        self.p_ratio, self.p_k, self.p_c, self.p_u0, self.p_u1 = (fp[o + i * P:o + (i + 1) * P] for i in range(5))
        o += 5 * P
        self.l_cv, self.l_Tc, self.l_wc = (fp[o + i * L:o + (i + 1) * L] for i in range(3))
        o += 3 * L
        self.m_par = fp[o:o + 4]
        self.wref = fp[o + 4:o + 6]
        self.J[:] = J
        self.Mo[:] = mo
        self.k[:] = kk
        self.c[:] = cc
        self.cext[:] = ce
        self.p_ratio[:] = [p.ratio for p in self.ports]
        self.p_k[:] = [p.k for p in self.ports]
        self.p_c[:] = [p.c for p in self.ports]
        self.l_cv[:] = [lw.c_v for lw in self.laws]
        self.l_Tc[:] = [lw.T_c for lw in self.laws]
        self.l_wc[:] = [lw.w_c for lw in self.laws]
        self.m_par[:] = m_par
        self.p_node = self.ip[5:5 + P]
        self.p_kind = self.ip[5 + P:5 + 2 * P]
        self.st = np.zeros(3 * n + 3)
        self.th, self.om, self.pi_x, self.alpha, self.energy = (
            self.st[0:n], self.st[n:2 * n], self.st[2 * n:2 * n + 1], self.st[2 * n + 1:3 * n + 1],
            self.st[3 * n + 1:3 * n + 3])
        self.out = np.zeros(N_ACC + 3 * P + n)
        self.acc = self.out[:N_ACC]
        self.tau_mean = self.out[N_ACC:N_ACC + P]
        self.work_out = self.out[N_ACC + P:N_ACC + 2 * P]
        self.el_mean = self.out[N_ACC + 2 * P:N_ACC + 2 * P + n]
        self.tau_out = self.out[N_ACC + 2 * P + n:]      # spring-port outputs as selected
        self.wk = np.zeros(7 * n + 2 * L + 2)
        self.last_H = 0.0
        self.n_sub_last = 0
        self.spring_ports = [q for q, p in enumerate(self.ports) if p.kind == SPRING]
        self.correction = EnergyCorrection([self.p_k[q] for q in self.spring_ports], bool(energy_correction))

    # ---- state ------------------------------------------------------------------------------------
    def set_state(self, th, om, pi_x=0.0):
        self.th[:] = th
        self.om[:] = om
        self.pi_x[0] = pi_x
        self.alpha[:] = 0.0
        self.energy[:] = 0.0

    def set_input(self, port: str, u0: float, u1: float = 0.0):
        q = self.port_index[port]
        self.p_u0[q] = u0
        self.p_u1[q] = u1

    def n_substeps(self, H):
        return substeps(H, self.max_substep)

    def step(self, t, H, wref0=0.0, wref1=None):
        """Advance from t to t + H (inputs already set with set_input). Raises ComponentError."""
        if not (H > 0 and math.isfinite(H)):
            raise ComponentError(f"communication step must be > 0, got {H!r} at t = {t:.9g} s")
        if wref1 is None:
            wref1 = wref0
        n_sub, problem = checked_substeps(H, t, self.max_substep)
        if problem:
            raise ComponentError(problem)
        self.wref[0] = wref0
        self.wref[1] = wref1
        code = line_step(float(H), n_sub, self.fp, self.ip, self.st, self.out, self.wk, self.correction.cs)
        if code == CODE_NONFINITE_INPUT:
            vals = {p.name: (float(self.p_u0[i]), float(self.p_u1[i])) for i, p in enumerate(self.ports)}
            raise ComponentError(f"non-finite input at t = {t:.9g} s: ports {vals}, speed reference "
                                 f"{wref0!r}..{wref1!r}, law levels {self.l_Tc.tolist()}")
        if code == CODE_NONFINITE_STATE:
            raise ComponentError(f"non-finite state at t = {t:.9g} s; check the parameters")
        self.last_H = H
        self.n_sub_last = n_sub
        return code

    def start_ports(self) -> None:
        """Before the first step (inputs set): the spring-port outputs are the port springs against the
        current inputs; they seed the coupling correction (the torque held over step 0)."""
        for q in self.spring_ports:
            name = self.ports[q].name
            self.tau_out[q] = self.tau_mean[q] = self.spring_torque(name, self.p_u0[q], self.p_u1[q])
        self.correction.reset([self.tau_out[q] for q in self.spring_ports])

    @property
    def coupling_energy_error(self) -> float:
        """Cumulative work mismatch at the spring-side ports [J] (the cuts' share of the energy
        residual still uncorrected; gearcontact_fmu.coupling)."""
        return float(sum(self.correction.mismatch_J))

    @property
    def energy_dissipated(self) -> float:
        return float(self.energy[0])

    @property
    def energy_supplied(self) -> float:
        return float(self.energy[1])

    @property
    def motor_torque(self) -> float:
        """Mean drive-motor torque over the last step."""
        return float(self.acc[A_MOTOR])

    @property
    def source_torque(self) -> float:
        """Mean torque of the source laws over the last step (as applied, resisting > 0)."""
        return float(self.acc[A_SRC])

    # ---- outputs ----------------------------------------------------------------------------------
    def flange(self, port: str):
        """(phi, w) of an inertia-side port."""
        p = self.ports[self.port_index[port]]
        return p.ratio * float(self.th[p.node]), p.ratio * float(self.om[p.node])

    def spring_torque(self, port: str, phi: float, w: float) -> float:
        """Instantaneous port-spring torque for given flange values (initial outputs)."""
        p = self.ports[self.port_index[port]]
        return p.k * (p.ratio * float(self.th[p.node]) - phi) + p.c * (p.ratio * float(self.om[p.node]) - w)

    def stored_energy(self, port_phi: dict | None = None) -> float:
        """Kinetic + element springs + port springs (port springs against the flange angle at the step
        end, or against ``port_phi[name]`` if given)."""
        om, th = self.om, self.th
        e = 0.5 * float(np.dot(self.J, om * om))
        if self.n > 1:
            e += float(np.dot(self.Mo[: self.n - 1], om[:-1] * om[1:]))
            d = th[:-1] - th[1:]
            e += 0.5 * float(np.dot(self.k[: self.n - 1], d * d))
        for q, p in enumerate(self.ports):
            if p.kind != SPRING:
                continue
            if port_phi is not None and p.name in port_phi:
                phi = port_phi[p.name]
            else:
                phi = self.p_u0[q] + self.p_u1[q] * self.last_H
            dd = p.ratio * th[p.node] - phi
            e += 0.5 * p.k * dd * dd
        return e

    # ---- linear description (eigen, cut checks) -------------------------------------------------
    def linear_matrices(self):
        """(M, K, C) of the chain alone (ports, laws and controller not included)."""
        n = self.n
        M = np.diag(self.J.copy())
        K = np.zeros((n, n))
        C = np.diag(self.cext.copy())
        for i in range(n - 1):
            M[i, i + 1] = M[i + 1, i] = self.Mo[i]
            for A, v in ((K, self.k[i]), (C, self.c[i])):
                A[i, i] += v
                A[i + 1, i + 1] += v
                A[i, i + 1] -= v
                A[i + 1, i] -= v
        return M, K, C


def warmup() -> None:
    """Load (or compile) the kernel with a throw-away model (numba's first dispatch costs 0.1-1 s;
    call this to take it out of a timed section)."""
    m = LineModel([1.0, 1.0], [1.0], [0.1], None, [Port("a", 0, INERTIA), Port("b", 1, SPRING, 1.0, 1.0, 0.1)],
                  [Law("l", 0, 0.1, 0.1, 1.0)], motor_node=0)
    m.step(0.0, 1e-3)


def loss_torque(w, T_trans, c_v, T_c, w_c, a):
    """The loss law (numpy-vectorised): c_v w + (T_c + a |T_trans|) tanh(w / w_c)."""
    w = np.asarray(w, dtype=float)
    return c_v * w + (T_c + a * np.abs(T_trans)) * np.tanh(w / w_c)


def loss_slope(w, T_trans, c_v, T_c, w_c, a):
    """d T_loss / d w (small-signal viscous coefficient at speed w)."""
    t = np.tanh(np.asarray(w, dtype=float) / w_c)
    return c_v + (T_c + a * np.abs(T_trans)) * (1.0 - t * t) / w_c


# ------------------------------------------------------------------------------------------------
# Parameter sets (field names = FMU variable names; defaults = the rig, see drivetrain.rig.data)
# ------------------------------------------------------------------------------------------------

def _rig_default(model: str, name: str):
    return rig.default_parameters(model)[name]


# Each FMU parameter is declared once, as a field of its component's parameter dataclass: name, type,
# default, unit and description (the field's metadata). The FMU shell registers its parameters from these
# fields and drivetrain.cosim.build writes their units and descriptions into the modelDescription.

def _d(model: str, name: str, unit: str | None, description: str):
    """A parameter whose default is the rig's (drivetrain.rig.data, read when an instance is made)."""
    return field(default_factory=lambda: _rig_default(model, name),
                 metadata={"unit": unit, "description": description})


def _v(default, unit: str | None, description: str):
    """A parameter with a fixed default."""
    return field(default=default, metadata={"unit": unit, "description": description})


def parameter_unit(f) -> str | None:
    """The unit a parameter field declares (None: dimensionless count, option or text)."""
    return f.metadata.get("unit")


def parameter_description(f) -> str:
    return f.metadata.get("description", "")


# parameters every line model has, declared once
def _max_substep():
    return _v(1e-5, "s", "largest internal sub-step; sub-steps per communication step = ceil(H / max_substep)")


def _output_torque():
    return _v("mean", None, "what the spring-side flange torque carries: mean (over the step) | end (value at "
                            "the step end)")


def _energy_correction():
    return _v(1, None, "1: energy-conserving correction of the spring-side flange torque (returns the measured "
                       "work mismatch of the cut over 10 ms); 0: off")


def _node_start(state: str, unit: str):
    """node_phi_start / node_w_start: a start value per node of the component's chain (one place)."""
    return _v("", None, f"start {state} [{unit}] of every node of the chain as comma-separated numbers in the "
                        "node order (LineModel.node_names, docs/FMU.md); empty = the start from the other start "
                        "parameters")


def parse_node_values(text: str, name: str, node_names) -> np.ndarray | None:
    """A node start parameter (``node_phi_start``, ``node_w_start``): comma-separated numbers, one per node
    in the order ``node_names`` -> array, or None for an empty text. ValueError naming the parameter, the
    count expected and the nodes for a wrong count, a non-number or a non-finite value (the native FMUs
    give the same message, drivetrain/native/line_native.c)."""
    text = (text or "").strip()
    if not text:
        return None
    names = list(node_names)
    want = (f"expected {len(names)} comma-separated values, one per node ({', '.join(names)})")
    parts = [x.strip() for x in text.split(",")]
    if len(parts) != len(names):
        raise ValueError(f"{name}: got {len(parts)} values, {want}")
    out = np.empty(len(parts))
    for i, part in enumerate(parts):
        try:
            v = float(part)
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise ValueError(f"{name}: value {i + 1} of {len(names)} ('{part}') is not a finite number; {want}")
        out[i] = v
    return out


@dataclass
class FlexibleShaftParams:
    """The drive-shaft line from the elastomer coupling C2 to the upper gearbox (docs/DRIVETRAIN.md):

    flange_a (inertia side) -> hub A (J_a) -> transducer spring (k_t, d_t) -> hub B (J_b) -> stiff
    coupling (k_c, d_c; k_c <= 0: rigid) -> thin shaft (k_shaft, d_shaft, J_shaft, n_elements equal
    elements) -> flange_b (spring side: the last shaft element is the port spring).

    The distributed shaft inertia is lumped per element (mass_model 0: J_e/2 at each end) or consistent
    (1: J_e/6 [[2,1],[1,2]]; the port element stays lumped); the half element at the flange_b end
    belongs to the body across the port (the assembler adds J_shaft/(2 n) to the upper gearbox)."""

    J_a: float = _d("FlexibleShaft", "J_a", "kg.m2", "inertia of transducer hub A (flange_a side)")
    k_t: float = _d("FlexibleShaft", "k_t", "N.m/rad", "torsional stiffness of the transducer section")
    d_t: float = _d("FlexibleShaft", "d_t", "N.m.s/rad", "damping of the transducer section")
    J_b: float = _d("FlexibleShaft", "J_b", "kg.m2", "inertia of transducer hub B")
    k_c: float = _d("FlexibleShaft", "k_c", "N.m/rad",
                    "stiffness of the stiff coupling between hub B and the thin shaft (<= 0: rigid)")
    d_c: float = _d("FlexibleShaft", "d_c", "N.m.s/rad", "damping of the stiff coupling")
    k_shaft: float = _d("FlexibleShaft", "k_shaft", "N.m/rad", "torsional stiffness of the whole thin shaft")
    d_shaft: float = _d("FlexibleShaft", "d_shaft", "N.m.s/rad", "damping of the whole thin shaft")
    J_shaft: float = _d("FlexibleShaft", "J_shaft", "kg.m2",
                        "inertia of the whole thin shaft (distributed over its elements)")
    n_elements: int = _v(4, None, "number of equal shaft elements")
    mass_model: int = _v(0, None, "element inertia: 0 = lumped (J_e/2 at each end), 1 = consistent "
                                  "(J_e/6 [[2,1],[1,2]])")
    max_substep: float = _max_substep()
    output_torque: str = _output_torque()
    energy_correction: int = _energy_correction()
    phi0: float = _v(0.0, "rad", "initial angle of the line (all nodes, before twist)")
    w0: float = _v(0.0, "rad/s", "initial speed of the line")
    tau0: float = _v(0.0, "N.m", "initial torque through the line (sets the initial twist of every spring)")
    node_phi_start: str = _node_start("angle", "rad")
    node_w_start: str = _node_start("speed", "rad/s")


@dataclass
class UpperTransmissionParams:
    """The 3:1 upper bevel gearbox as one rigid geared body: input inertia J_in (drive frame, the
    drive-line parts lumped into it), output inertia J_out (middle-shaft frame), ratio; the loss law
    on the input shaft with T_trans = |flange_b_tau| / ratio (drive-referred output torque). Both
    flanges inertia side. ``J_sensor``: inertia of the body upstream of the drive-shaft transducer
    section (rigid shafts: the transducer sits inside this body; its torque is tau_a - J_sensor alpha)."""

    J_in: float = _d("UpperTransmission", "J_in", "kg.m2",
                     "inertia on the input (drive) shaft, the drive-line parts lumped into it")
    J_out: float = _d("UpperTransmission", "J_out", "kg.m2", "inertia on the output (middle) shaft")
    ratio: float = _v(3.0, "1", "transmission ratio input speed / output speed (3 for the rig's upper gearbox)")
    loss_c: float = _d("UpperTransmission", "loss_c", "N.m.s/rad", "loss law: viscous coefficient on the input shaft")
    loss_Tc: float = _d("UpperTransmission", "loss_Tc", "N.m", "loss law: Coulomb torque level")
    loss_wc: float = _d("UpperTransmission", "loss_wc", "rad/s",
                        "loss law: speed below which the Coulomb torque is regularised")
    loss_a: float = _d("UpperTransmission", "loss_a", "1", "loss law: load-dependent share of the transmitted torque")
    J_sensor: float = _v(0.0, "kg.m2", "inertia upstream of the drive-shaft transducer section (rigid shafts: the "
                                       "transducer sits inside this body); 0 = none")
    max_substep: float = _max_substep()
    phi0: float = _v(0.0, "rad", "initial angle of the input shaft")
    w0: float = _v(0.0, "rad/s", "initial speed of the input shaft")
    node_phi_start: str = _node_start("angle", "rad")
    node_w_start: str = _node_start("speed", "rad/s")


@dataclass
class MotorLoadParams:
    """Drive motor (PI speed control, torque limit, LimPID back-calculation anti-windup) with the
    elastomer coupling C1 and the drive flywheel, and the load side (flywheel/propeller mass, the
    1:8 planetary with its loss, the load motor).

    drive: motor (J_motor, bearing c_motor) -C1 (k_c1, d_c1)- flywheel (J_flywheel) -C2 (k_c2, d_c2,
    the port spring of flange ``drive``, spring side).
    load: one body in the propeller-shaft frame, J_load + ratio_pg^2 J_load_motor, flange ``load``
    (inertia side); planetary loss law (pg_*) with T_trans = ratio_pg |load_torque|; the load motor:
    load_mode 0 "torque" (the rig: a torque setting, ratio_pg * load_torque at the propeller shaft,
    regularised below load_w_reg so that it brakes but never drives), 1 "viscous" (the paper: a
    viscous torque equal to the setting at load_w_nom)."""

    J_motor: float = _d("MotorLoad", "J_motor", "kg.m2", "drive motor rotor inertia")
    c_motor: float = _d("MotorLoad", "c_motor", "N.m.s/rad", "drive motor bearing viscous loss")
    k_c1: float = _d("MotorLoad", "k_c1", "N.m/rad", "stiffness of elastomer coupling C1 (motor - drive flywheel)")
    d_c1: float = _d("MotorLoad", "d_c1", "N.m.s/rad", "damping of coupling C1")
    J_flywheel: float = _d("MotorLoad", "J_flywheel", "kg.m2", "drive flywheel inertia")
    k_c2: float = _d("MotorLoad", "k_c2", "N.m/rad",
                     "stiffness of elastomer coupling C2 (drive flywheel - flange drive; the port spring)")
    d_c2: float = _d("MotorLoad", "d_c2", "N.m.s/rad", "damping of coupling C2")
    Kp: float = _v(0.1, "N.m.s/rad", "speed controller proportional gain")
    Ti: float = _v(0.4, "s", "speed controller integral time")
    Ni: float = _v(0.9, "1", "anti-windup gain of the controller (LimPID back-calculation)")
    tau_max: float = _v(10.0, "N.m", "drive motor torque limit")
    J_load: float = _d("MotorLoad", "J_load", "kg.m2",
                       "propeller-shaft side inertia (flywheel / propeller mass), propeller-shaft frame")
    J_load_motor: float = _v(0.0, "kg.m2", "load motor rotor inertia (referred through ratio_pg^2)")
    ratio_pg: float = _v(8.0, "1", "planetary gearbox ratio load motor speed / propeller-shaft speed (8 on the rig)")
    pg_c: float = _d("MotorLoad", "pg_c", "N.m.s/rad", "planetary loss law: viscous coefficient")
    pg_Tc: float = _d("MotorLoad", "pg_Tc", "N.m", "planetary loss law: Coulomb torque level")
    pg_wc: float = _d("MotorLoad", "pg_wc", "rad/s", "planetary loss law: regularisation speed")
    pg_a: float = _d("MotorLoad", "pg_a", "1", "planetary loss law: load-dependent share")
    load_mode: int = _v(0, None, "load motor law: 0 = torque setting (the rig; regularised below load_w_reg so "
                                 "that it brakes but never drives), 1 = viscous torque equal to the setting at "
                                 "load_w_nom (the paper)")
    load_w_reg: float = _v(0.05, "rad/s", "load_mode 0: speed below which the load torque is regularised")
    load_w_nom: float = _v(1.0, "rad/s", "load_mode 1: speed at which the viscous load equals the setting")
    speed_profile: str = _v("", None, "drive speed reference over time as 't0:v0; t1:v1; ...' [s:rpm], linear "
                                      "between points; empty = the speed_ref_rpm input")
    load_profile: str = _v("", None, "load torque setting over time as 't0:v0; t1:v1; ...' [s:N.m]; empty = the "
                                     "load_torque input")
    max_substep: float = _max_substep()
    output_torque: str = _output_torque()
    energy_correction: int = _energy_correction()
    phi0_motor: float = _v(0.0, "rad", "initial angle of the drive motor")
    w0: float = _v(0.0, "rad/s", "initial speed of the drive side")
    tau0: float = _v(0.0, "N.m", "initial torque through the drive couplings (sets their initial twist)")
    phi0_load: float = _v(0.0, "rad", "initial angle of the load body")
    w0_load: float = _v(0.0, "rad/s", "initial speed of the load body")
    node_phi_start: str = _node_start("angle", "rad")
    node_w_start: str = _node_start("speed", "rad/s")


def params_from(cls, values: dict | None = None, **kw):
    """A parameter dataclass from a dict of FMU variable values (unknown names refused)."""
    names = {f.name for f in fields(cls)}
    vals = dict(values or {})
    vals.update(kw)
    bad = sorted(set(vals) - names)
    if bad:
        raise ValueError(f"{cls.__name__}: unknown parameters {bad} (known: {sorted(names)})")
    return cls(**vals)


def parse_profile(text: str):
    """'t0:v0; t1:v1; ...' -> (times, values) arrays, or None for an empty string."""
    text = (text or "").strip()
    if not text:
        return None
    ts, vs = [], []
    for part in text.replace(",", ";").split(";"):
        part = part.strip()
        if not part:
            continue
        t, _, v = part.partition(":")
        ts.append(float(t))
        vs.append(float(v))
    ts, vs = np.array(ts), np.array(vs)
    if len(ts) == 0 or np.any(np.diff(ts) <= 0) or not (np.all(np.isfinite(ts)) and np.all(np.isfinite(vs))):
        raise ValueError(f"profile {text!r}: expected 't0:v0; t1:v1; ...' with increasing times")
    return ts, vs


def profile_string(profile) -> str:
    """[[t, v], ...] -> 't:v; ...' (for the profile parameters)."""
    return "; ".join(f"{float(t)!r}:{float(v)!r}" for t, v in profile)


# ------------------------------------------------------------------------------------------------
# The three components
# ------------------------------------------------------------------------------------------------

class _LineComponent:
    """What the three components share: a LineModel ``line``, outputs by FMU variable name."""

    STEP_OUTPUTS: tuple = ()       #: the outputs every step changes, in the order of step_outputs()
    line: LineModel

    def step_outputs(self) -> tuple:
        raise NotImplementedError

    def _parse_node_start(self) -> None:
        """The node start parameters (node_phi_start, node_w_start) checked and parsed once, at the build."""
        names = self.line.node_names
        self.node_phi_start = parse_node_values(self.p.node_phi_start, "node_phi_start", names)
        self.node_w_start = parse_node_values(self.p.node_w_start, "node_w_start", names)

    def _node_start(self, th, om):
        """(th, om) with the node start parameters in place of the given start, where set."""
        th = th if self.node_phi_start is None else self.node_phi_start.copy()
        om = om if self.node_w_start is None else self.node_w_start.copy()
        return th, om

    def lazy_outputs(self) -> dict:
        """The outputs the FMU shell computes only when a host reads them (fmishell.LAZY_OUTPUTS)."""
        return {"coupling_energy_error": self.line.coupling_energy_error, "energy_stored": self.line.stored_energy()}

    def outputs(self, energy: bool = True) -> dict:
        """Output values by FMU variable name. ``energy=False``: the lazy outputs (``energy_stored``,
        ``coupling_energy_error``, ``loss_torque``) are left out (the FMU shell computes them when a host
        reads them, drivetrain.models.fmishell)."""
        out = dict(zip(self.STEP_OUTPUTS, self.step_outputs()))
        if energy:
            out.update(self.lazy_outputs())
        return out


class FlexibleShaft(_LineComponent):
    """Drive-shaft line (see FlexibleShaftParams). Ports ``flange_a`` (inertia), ``flange_b`` (spring)."""

    model = "FlexibleShaft"
    PORTS = {"flange_a": INERTIA, "flange_b": SPRING}       #: port name -> kind (the FMU's flanges)

    def __init__(self, p: FlexibleShaftParams):
        self.p = p
        n = int(p.n_elements)
        if n < 1:
            raise ValueError(f"n_elements must be >= 1, got {n}")
        for nm in ("J_a", "J_b", "k_shaft"):
            if not getattr(p, nm) > 0:
                raise ValueError(f"{nm} must be > 0")
        ke = n * p.k_shaft
        ce = n * p.d_shaft
        Je = p.J_shaft / n
        J = [p.J_a]
        k, c = [], []
        names = ["hub_a"]
        if p.k_t > 0:
            J.append(p.J_b)
            k.append(p.k_t)
            c.append(p.d_t)
            names.append("hub_b")
        else:
            J[-1] += p.J_b
        self.i_hub_b = len(J) - 1
        # shaft nodes S0..S_{n-1}; S0 at hub B through the stiff coupling (or merged into hub B)
        shaft_nodes = []
        if p.k_c > 0:
            J.append(0.0)
            k.append(p.k_c)
            c.append(p.d_c)
            names.append("shaft_0")
        shaft_nodes.append(len(J) - 1)
        for i in range(1, n):
            J.append(0.0)
            k.append(ke)
            c.append(ce)
            names.append(f"shaft_{i}")
            shaft_nodes.append(len(J) - 1)
        J = np.array(J, dtype=float)
        Mo = np.zeros(max(len(J) - 1, 1))
        # element masses: elements 0..n-2 are internal (between shaft nodes), element n-1 is the port
        for e in range(n):
            i0 = shaft_nodes[e]
            if e < n - 1:
                i1 = shaft_nodes[e + 1]
                if int(p.mass_model) == 1:
                    J[i0] += Je / 3.0
                    J[i1] += Je / 3.0
                    Mo[i0] += Je / 6.0     # i1 = i0 + 1
                else:
                    J[i0] += Je / 2.0
                    J[i1] += Je / 2.0
            else:
                J[i0] += Je / 2.0          # the other half belongs to the body across flange_b
        self.shaft_nodes = shaft_nodes
        self.port_k = ke
        self.port_c = ce
        kind = self.PORTS
        ports = [Port("flange_a", 0, kind["flange_a"]), Port("flange_b", len(J) - 1, kind["flange_b"], 1.0, ke, ce)]
        self.line = LineModel(J, k, c, None, ports, (), max_substep=p.max_substep,
                              output_torque=p.output_torque, Mo=Mo, node_names=names,
                              energy_correction=bool(p.energy_correction))
        self.sensor_element = 0 if p.k_t > 0 else -1
        self._parse_node_start()
        self.initialize()

    def compliance_to_port(self) -> float:
        """Static twist per unit through-torque from hub A to the flange_b flange."""
        kk = [kv for kv in self.line.k[: self.line.n - 1]] + [self.port_k]
        return float(sum(1.0 / kv for kv in kk))

    def initialize(self):
        p = self.p
        th = np.empty(self.line.n)
        th[0] = p.phi0
        for i in range(1, self.line.n):
            th[i] = th[i - 1] - p.tau0 / self.line.k[i - 1]
        self.line.set_state(*self._node_start(th, np.full(self.line.n, p.w0)))
        self.torque_sensor = float(p.tau0) if self.sensor_element >= 0 else float(p.tau0)
        self.shaft_torque = float(p.tau0)

    def set_inputs(self, flange_a_tau, flange_b_phi, flange_b_w):
        self.line.set_input("flange_a", flange_a_tau)
        self.line.set_input("flange_b", flange_b_phi, flange_b_w)

    def step(self, t, H):
        self.line.step(t, H)
        em = self.line.el_mean
        self.torque_sensor = float(em[self.sensor_element]) if self.sensor_element >= 0 else float(
            self.line.tau_mean[1])
        self.shaft_torque = float(self.line.tau_mean[1])

    #: the outputs every step changes, in the order of step_outputs
    STEP_OUTPUTS = ("flange_a_phi", "flange_a_w", "flange_b_tau", "flange_b_tau_mean", "torque_sensor",
                    "shaft_torque", "hub_b_phi", "hub_b_w", "energy_dissipated", "energy_supplied")

    def step_outputs(self) -> tuple:
        """The values of STEP_OUTPUTS (Python floats), read by the FMU shell after every step."""
        ln = self.line
        phi, w = ln.flange("flange_a")
        return (phi, w, float(ln.tau_out[1]), float(ln.tau_mean[1]), self.torque_sensor, self.shaft_torque,
                float(ln.th[self.i_hub_b]), float(ln.om[self.i_hub_b]), ln.energy_dissipated, ln.energy_supplied)



class UpperTransmission(_LineComponent):
    """Rigid 3:1 body with two inertia-side flanges and the calibrated loss (UpperTransmissionParams)."""

    model = "UpperTransmission"
    PORTS = {"flange_a": INERTIA, "flange_b": INERTIA}     #: port name -> kind (the FMU's flanges)

    def __init__(self, p: UpperTransmissionParams):
        self.p = p
        if not (p.ratio > 0 and p.J_in >= 0 and p.J_out >= 0):
            raise ValueError("ratio must be > 0 and J_in, J_out >= 0")
        Jtot = p.J_in + p.J_out / p.ratio ** 2
        if not Jtot > 0:
            raise ValueError("J_in + J_out / ratio^2 must be > 0")
        self.J = Jtot
        kind = self.PORTS
        ports = [Port("flange_a", 0, kind["flange_a"], 1.0), Port("flange_b", 0, kind["flange_b"], 1.0 / p.ratio)]
        laws = [Law("loss", 0, p.loss_c, p.loss_Tc, p.loss_wc if p.loss_wc > 0 else 1.0, p.loss_a)]
        self.line = LineModel([Jtot], [], [], None, ports, laws, max_substep=p.max_substep)
        self._parse_node_start()
        self.initialize()

    def initialize(self):
        self.line.set_state(*self._node_start([self.p.phi0], [self.p.w0]))
        self.torque_sensor = 0.0
        self._loss_at = None           # (w, loss level) at the end of the last step: loss_torque when read
        self._tau_a = 0.0

    def set_inputs(self, flange_a_tau, flange_b_tau):
        self._tau_a = float(flange_a_tau)
        self.line.set_input("flange_a", flange_a_tau)
        self.line.set_input("flange_b", flange_b_tau)
        p = self.p
        # loss level: T_c + a |T_trans|, T_trans = drive-referred output torque
        self.line.l_Tc[0] = p.loss_Tc + p.loss_a * abs(float(flange_b_tau)) / p.ratio

    def step(self, t, H):
        w0 = float(self.line.om[0])
        self.line.step(t, H)
        alpha = (float(self.line.om[0]) - w0) / H
        self.torque_sensor = self._tau_a - self.p.J_sensor * alpha
        # mean loss torque from the dissipated energy is not separable; report the law at the end speed
        # (evaluated when read: the master does not read it every step)
        self._loss_at = (self.line.om[0], self.line.l_Tc[0], self.line.l_wc[0])

    @property
    def loss_torque(self) -> float:
        if self._loss_at is None:
            return 0.0
        w, T_c, w_c = self._loss_at
        return float(loss_torque(w, 0.0, self.p.loss_c, T_c, w_c, 0.0))

    #: the outputs every step changes, in the order of step_outputs
    STEP_OUTPUTS = ("flange_a_phi", "flange_a_w", "flange_b_phi", "flange_b_w", "torque_sensor",
                    "energy_dissipated", "energy_supplied")

    def step_outputs(self) -> tuple:
        """The values of STEP_OUTPUTS (Python floats), read by the FMU shell after every step."""
        ln = self.line
        pa, wa = ln.flange("flange_a")
        pb, wb = ln.flange("flange_b")
        return pa, wa, pb, wb, self.torque_sensor, ln.energy_dissipated, ln.energy_supplied

    def lazy_outputs(self) -> dict:
        return {"loss_torque": self.loss_torque, "energy_stored": self.line.stored_energy()}


class MotorLoad(_LineComponent):
    """Drive motor + C1 + flywheel (flange ``drive``, spring side: C2) and the load side (flange
    ``load``, inertia side) with the planetary and the load motor (MotorLoadParams)."""

    model = "MotorLoad"
    PORTS = {"drive": SPRING, "load": INERTIA}              #: port name -> kind (the FMU's flanges)

    def __init__(self, p: MotorLoadParams):
        self.p = p
        for nm in ("J_motor", "J_flywheel", "J_load", "ratio_pg", "k_c1"):
            if not getattr(p, nm) > 0:
                raise ValueError(f"{nm} must be > 0")
        if int(p.load_mode) not in (0, 1):
            raise ValueError(f"load_mode must be 0 (torque) or 1 (viscous), got {p.load_mode}")
        self.J_L = p.J_load + p.ratio_pg ** 2 * p.J_load_motor
        J = [p.J_motor, p.J_flywheel, self.J_L]
        k = [p.k_c1, 0.0]
        c = [p.d_c1, 0.0]
        cext = [p.c_motor, 0.0, 0.0]
        kind = self.PORTS
        ports = [Port("drive", 1, kind["drive"], 1.0, p.k_c2, p.d_c2), Port("load", 2, kind["load"], 1.0)]
        laws = [Law("planetary", 2, p.pg_c, p.pg_Tc, p.pg_wc if p.pg_wc > 0 else 1.0, p.pg_a),
                Law("load_motor", 2, 0.0, 0.0, p.load_w_reg if p.load_w_reg > 0 else 1e-3, 0.0, source=True)]
        self.line = LineModel(J, k, c, cext, ports, laws, motor_node=0,
                              motor_par=(p.Kp, p.Ti, p.Ni, p.tau_max), max_substep=p.max_substep,
                              output_torque=p.output_torque, node_names=["motor", "flywheel", "load"],
                              energy_correction=bool(p.energy_correction))
        self.speed_profile = parse_profile(p.speed_profile)
        self.load_profile = parse_profile(p.load_profile)
        self.speed_ref_rpm = p.w0 / RPM
        self.load_torque = 0.0
        self._parse_node_start()
        self.initialize()

    # steady state of the drive side for a through torque tau0 at speed w0
    def initialize(self, load_torque: float | None = None):
        p = self.p
        if load_torque is not None:
            self.load_torque = float(load_torque)
        th = np.array([p.phi0_motor, p.phi0_motor - p.tau0 / p.k_c1, p.phi0_load])
        om = np.array([p.w0, p.w0, p.w0_load])
        # the PI integrator holds the motor torque of the parameters' start (tau0 at w0), node start or not
        Tm = p.tau0 + p.c_motor * p.w0
        self.line.set_state(*self._node_start(th, om), Tm / p.Kp)
        self.motor_torque = Tm
        self.load_motor_torque = self.load_torque
        self._set_load_level(self.load_torque)

    def speed_ref_at(self, t: float) -> float:
        """Speed reference [rad/s] at time t (profile parameter if set, else the input)."""
        if self.speed_profile is not None:
            return float(np.interp(t, *self.speed_profile)) * RPM
        return self.speed_ref_rpm * RPM

    def load_at(self, t: float) -> float:
        if self.load_profile is not None:
            return float(np.interp(t, *self.load_profile))
        return self.load_torque

    def _set_load_level(self, T_set: float):
        p = self.p
        T_prop = p.ratio_pg * T_set
        ln = self.line
        ln.l_Tc[0] = p.pg_Tc + p.pg_a * abs(T_prop)
        if int(p.load_mode) == 0:
            ln.l_cv[1] = 0.0
            ln.l_Tc[1] = T_prop
        else:
            ln.l_cv[1] = T_prop / p.load_w_nom if p.load_w_nom > 0 else 0.0
            ln.l_Tc[1] = 0.0

    def set_inputs(self, drive_phi, drive_w, load_tau, speed_ref_rpm=None, load_torque=None):
        self.line.set_input("drive", drive_phi, drive_w)
        self.line.set_input("load", load_tau)
        if speed_ref_rpm is not None:
            self.speed_ref_rpm = float(speed_ref_rpm)
        if load_torque is not None:
            self.load_torque = float(load_torque)

    def step(self, t, H):
        T_set = self.load_at(t)
        if not math.isfinite(T_set):
            raise ComponentError(f"non-finite load torque {T_set!r} at t = {t:.9g} s")
        self._set_load_level(T_set)
        self.line.step(t, H, self.speed_ref_at(t), self.speed_ref_at(t + H))
        self.motor_torque = self.line.motor_torque
        self.load_motor_torque = self.line.source_torque / self.p.ratio_pg

    #: the outputs every step changes, in the order of step_outputs
    STEP_OUTPUTS = ("load_phi", "load_w", "drive_tau", "drive_tau_mean", "motor_phi", "motor_w", "flywheel_phi",
                    "flywheel_w", "motor_torque", "load_motor_torque", "load_motor_w", "coupling_torque",
                    "energy_dissipated", "energy_supplied")

    def step_outputs(self) -> tuple:
        """The values of STEP_OUTPUTS (Python floats), read by the FMU shell after every step."""
        ln = self.line
        pl, wl = ln.flange("load")
        th, om = ln.th, ln.om
        return (pl, wl, float(ln.tau_out[0]), float(ln.tau_mean[0]), float(th[0]), float(om[0]), float(th[1]),
                float(om[1]), self.motor_torque, self.load_motor_torque, self.p.ratio_pg * wl,
                float(ln.el_mean[0]), ln.energy_dissipated, ln.energy_supplied)



COMPONENTS = {"FlexibleShaft": (FlexibleShaft, FlexibleShaftParams),
              "UpperTransmission": (UpperTransmission, UpperTransmissionParams),
              "MotorLoad": (MotorLoad, MotorLoadParams)}


def get_state(comp) -> dict:
    """A snapshot of a component (and its LineModel) for FMI fmi2GetFMUstate: every array copied,
    every other attribute deep-copied. :func:`set_state` writes the arrays back in place, so views
    into them (the LineModel's ``th``, ``om``, ... are views of its state vector) keep working."""
    state = {}
    for name, value in vars(comp).items():
        if isinstance(value, LineModel):
            state[name] = get_state(value)
        elif isinstance(value, np.ndarray):
            state[name] = value.copy()
        else:
            state[name] = copy.deepcopy(value)
    return state


def set_state(comp, state: dict) -> None:
    """Restore a :func:`get_state` snapshot into the same component (the same steps then repeat bit for
    bit; the snapshot stays usable for another restore)."""
    for name, value in state.items():
        current = getattr(comp, name)
        if isinstance(current, LineModel):
            set_state(current, value)
        elif isinstance(current, np.ndarray):
            current[...] = value
        else:
            setattr(comp, name, copy.deepcopy(value))


def make_component(model: str, parameters: dict | None = None):
    """Build a component from FMU-style parameter values (name -> value)."""
    cls, pcls = COMPONENTS[model]
    return cls(params_from(pcls, parameters))
