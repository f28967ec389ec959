"""The numerical core of the drivetrain components (no FMI): :class:`LineModel` and its numba kernel.

FlexibleShaft (models.shaft), UpperTransmission (models.transmission) and MotorLoad (models.motors) are
all instances of one numerical core, :class:`LineModel`: a torsional chain of nodes (inertias)
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

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from drivetrain.errors import ComponentError
from drivetrain.models.parameters import parse_node_values
from drivetrain.system import INERTIA, SPRING
from gearcontact_fmu.coupling import EnergyCorrection, correct_port
from gearcontact_fmu.params import CODE_NONFINITE_INPUT, CODE_NONFINITE_STATE, CODE_OK, checked_substeps, substeps

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
        step start and end, linear in between), Td (motor torque disturbance, constant over the step: an
        external torque on the motor node added after the PI controller and its limit, outside the
        anti-windup; counted in the motor's work and its step-mean torque).
    st: th[n], om[n], pi_x, alpha[n] (acceleration of the last sub-step), cumulative dissipated and
        supplied energy.
    out (reset here): acc[N_ACC] (step means of motor and source torque, step dissipated and supplied
        energy), tau_mean[P] (step mean of the spring-port torques), work_out[P] (work out through each
        port over the step), el_mean[n] (step mean of the element torques), tau_out[P] (spring-port
        torque output: the mean or the end value).
    wk: work space of at least 7 n + 2 L + 2 floats.
    cs: the energy-correction state of the spring-side ports, one row each in port order
        (gearcontact_fmu.coupling.correct_port corrects tau_out of each after the step).

    Long kernel: one sub-step loop (assemble, solve with the PI motor, energy and port bookkeeping,
    update) that shares the packed layout's offsets; split into njit helpers (one per phase, bit-identical)
    it ran 1.5-2.5x slower (UpperTransmission, 34 sub-steps: 1.8 -> 4.8 us per call; inline="always"
    did not recover it), and the per-step cost of the line FMUs is what this kernel is packed for."""
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
    Td = fp[o_m + 6]
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
    if not (np.isfinite(wref0) and np.isfinite(wref1) and np.isfinite(Td)):
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
            rhs[m_node] += Td
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
            supp += (Tm + Td) * wm[m_node]
            out[o_acc + A_MOTOR] += h * (Tm + Td)
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
    i = np.int64(0)      # typed, not the literal 0: numba would compile correct_port for Literal[int](0) on its way
    for q in range(npt):  # to int64 (a kernel compiles once per argument type: test_kernel_specialisations)
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
    ``J, Mo, k, c, cext, p_*, l_*, m_par, m_dist, th, om, pi_x, alpha, energy, acc, tau_mean, work_out, el_mean,
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
        self.fp = np.zeros(5 * n + 5 * P + 3 * L + 7)
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
        self.m_dist = fp[o + 6:o + 7]      # the motor torque disturbance (set_motor_disturbance)
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

    def set_motor_disturbance(self, value: float) -> None:
        """The torque [N.m] added to the drive motor's controlled torque on its node from the next step on
        (after the PI controller and its torque limit; held over the step; 0 = none)."""
        self.m_dist[0] = value

    @property
    def motor_disturbance(self) -> float:
        return float(self.m_dist[0])

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
                                 f"{wref0!r}..{wref1!r}, law levels {self.l_Tc.tolist()}"
                                 + (f", motor disturbance {float(self.m_dist[0])!r}" if self.motor_node >= 0 else ""))
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
        """Mean drive-motor torque over the last step (the PI torque plus the disturbance)."""
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
# what the three components share
# ------------------------------------------------------------------------------------------------

#: the most shaft elements a line model builds (a host's 2**31 - 1 would hang the build)
MAX_ELEMENTS = 1000


def check_parameters(p) -> None:
    """Refuse, before anything is built, parameter values no model can use: numbers that are not finite
    (NaN fails every comparison, so a NaN stiffness would silently read as "no spring")."""
    import dataclasses

    bad = [f"{f.name} = {getattr(p, f.name)!r}" for f in dataclasses.fields(p)
           if isinstance(getattr(p, f.name), float) and not math.isfinite(getattr(p, f.name))]
    if bad:
        raise ValueError(f"parameters that are not finite numbers: {', '.join(bad)}")


class LineComponent:
    """What the three components share: a LineModel ``line``, outputs by FMU variable name."""

    line: LineModel

    def step_outputs(self) -> dict:
        """The outputs every step changes, by FMU variable name (Python floats; the FMU shell publishes them
        after every step, the others, fmishell.LAZY_OUTPUTS, when read)."""
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
        out = self.step_outputs()
        if energy:
            out.update(self.lazy_outputs())
        return out

