"""Energy-conserving correction of the torque a spring-side port hands to a co-simulation master.

What
----
A spring-side port (the gear stage's flanges, the MotorLoad drive flange, the FlexibleShaft's
flange_b) takes the neighbour's flange angle and speed (phi_k, w_k) at the start of step k, moves the
flange along phi_k + w_k t inside the step, and returns a torque that the neighbour holds over the
*next* step. The work the port accounts for itself over step k is W_k = H tau_mean,k w_k; the work the
neighbour receives is tau_held,k (phi_k+1 - phi_k). Their difference is the coupling error of the cut:
first order in H, it is what the master's energy audit sees as a residual (0.5-2 % at H = 1/3000 s on
the stress campaign, docs/STABILITY.md).

How (nearly energy-preserving coupling, after Sadjina et al., 2017)
-----------------------------------------------------------------
One call later the port knows phi_k+1, so it measures the step's mismatch
m_k = tau_held,k (phi_k+1 - phi_k) - W_k + (jump of the port-spring energy between the extrapolated and
the actual flange angle) and keeps the cumulative E = sum m: exactly the port's share of the master's
energy residual (tested). It adds a correction c to the torque it returns so that the work of c returns
E over the time constant TIME_CONSTANT_S:

    c_k+1 = -g (E_k + c_k d) d / (d^2 + eps^2),   d = w H,   g = H / TIME_CONSTANT_S

where c_k d is the expected work of the correction still in flight (the output of the previous call is
held during the current step and measured only on the next call). The division is regularised by eps
(1e-5 rad) so a port at rest gets no correction, and |c| is capped at CAP_REL of the port torque (the
correction is a small perturbation by design; what a cap holds back stays in E and is returned later).

Why a time constant and not a one-step (deadbeat) return, g = 1: measured on the example drivetrain, the
deadbeat correction turns into a sustained oscillation of the coupling torques (0.05 N·m at
H = 1/3000 s, 0.66 N·m at 1/1500 s where the uncorrected run is steady) and g = 0.3 still at 1/1400 s.
The correction is an integral feedback of the impulse error of the held torque; returning E over 10 ms
keeps its bandwidth below the cut modes (hundreds of Hz), and at the predicted stability limits of the
cuts (eigen.cosim_radius just below 1) the corrected runs are as steady as the uncorrected ones.

Trade-offs
----------
- It assumes a Jacobi master with a fixed step (ours, libcosim's and most fixed-step hosts): the
  output of call k is what the neighbour holds during step k+1. Under another schedule the measured E is
  still the true mismatch but the in-flight estimate is off by one step (then switch it off: the
  ``energy_correction`` parameter of each FMU, scene key ``numerics.energy_correction``).
- It does not change the port's internal state or its step-mean outputs, only the coupling torque.
- The linear cut analysis (drivetrain stability checks) does not model it; measured at the predicted
  limits and on the stress campaign, it does not shrink the stable region (docs/STABILITY.md §4).
- A fast ramp through a coarse step builds up E faster than the capped correction returns it; E is
  then returned after the ramp (the residual of such a run is the part still pending at its end).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

#: time constant of the correction [s]: the mismatch is returned at a rate of H / TIME_CONSTANT_S per step
TIME_CONSTANT_S = 0.01
#: regularisation of the division by the expected displacement [rad]
EPS_RAD = 1e-5
#: largest correction relative to the larger of |tau_mean| and CAP_FLOOR_NM
CAP_REL = 0.1
#: torque floor of the cap [N m]: a port near zero torque may still return a small correction
CAP_FLOOR_NM = 0.05


# the correction state of one port: a row of a float64 array (several ports: one row each)
CS_K = 0              # port-spring stiffness [N m/rad]
CS_ENABLED = 1        # 1.0: correct; 0.0: only measure the mismatch
CS_STARTED = 2        # 1.0 after the first call (the first call has no step before it to measure)
CS_MISMATCH = 3       # cumulative measured work mismatch E [J]
CS_HELD_BEFORE = 4    # output held during the step measured next
CS_HELD_LAST = 5      # output of the last call
CS_C_LAST = 6         # correction in the last output
CS_PHI = 7            # flange angle input of the last call
CS_PHI_END = 8        # extrapolated flange angle at the end of the last step
CS_X = 9              # the port spring's inner angle at the end of the last step
CS_WORK = 10          # work the port accounted over the last step
N_CS = 11


@njit(cache=True)
def correct_port(cs, q, H, phi_q, w_q, tm_q, base_q, x_q):
    """One port's call per step (row ``q`` of the state ``cs``), after the port's step with the flange
    inputs ``phi_q``, ``w_q`` over ``H``: ``tm_q`` the step mean the port accounted its work with,
    ``base_q`` its uncorrected output, ``x_q`` the port spring's inner angle at the step end. Returns the
    output to hand to the master.

    The mismatch of the step before, measured now: the work the neighbour received,
    tau_held (phi - phi_prev), minus the work the port accounted, H tau_mean w, plus the jump of the
    port-spring energy between the extrapolated flange angle the step ended with and the actual one this
    step starts from (the port's stored energy is reported at the extrapolated angle). Called from Python
    (EnergyCorrection.apply) and from the drivetrain's line kernel: one implementation."""
    g = H / TIME_CONSTANT_S if H < TIME_CONSTANT_S else 1.0
    eps2 = EPS_RAD * EPS_RAD
    if cs[q, CS_STARTED] != 0.0:
        dphi = phi_q - cs[q, CS_PHI]
        a = cs[q, CS_X] - phi_q
        b = cs[q, CS_X] - cs[q, CS_PHI_END]
        jump = 0.5 * cs[q, CS_K] * (a * a - b * b)
        cs[q, CS_MISMATCH] += cs[q, CS_HELD_BEFORE] * dphi - cs[q, CS_WORK] + jump
    c = 0.0
    if cs[q, CS_ENABLED] != 0.0:
        d = w_q * H
        c = -g * (cs[q, CS_MISMATCH] + cs[q, CS_C_LAST] * d) * d / (d * d + eps2)
        cap = CAP_REL * max(abs(tm_q), CAP_FLOOR_NM)
        if c > cap:
            c = cap
        elif c < -cap:
            c = -cap
        if not math.isfinite(c):
            c = 0.0
    o = base_q + c
    cs[q, CS_HELD_BEFORE] = cs[q, CS_HELD_LAST]
    cs[q, CS_HELD_LAST] = o
    cs[q, CS_C_LAST] = c
    cs[q, CS_PHI] = phi_q
    cs[q, CS_PHI_END] = phi_q + w_q * H
    cs[q, CS_X] = x_q
    cs[q, CS_WORK] = H * tm_q * w_q
    cs[q, CS_STARTED] = 1.0
    return o


def correction_state(k_ports, enabled: bool, tau_initial=None) -> np.ndarray:
    """A fresh state array for ports with port-spring stiffnesses ``k_ports``; ``tau_initial``: the
    torques the ports return before the first step (held over step 0)."""
    cs = np.zeros((len(k_ports), N_CS))
    cs[:, CS_K] = [float(v) for v in k_ports]
    cs[:, CS_ENABLED] = 1.0 if enabled else 0.0
    if tau_initial is not None:
        cs[:, CS_HELD_LAST] = [float(v) for v in tau_initial]
    return cs


class EnergyCorrection:
    """The correction state of spring-side ports with port-spring stiffnesses ``k_ports``: one row per
    port of the array ``cs`` (CS_* columns), advanced by :func:`correct_port`. ``mismatch_J``: the
    measured cumulative work mismatch per port (tracked also when the correction is disabled: the cut's
    share of the energy residual)."""

    __slots__ = ("n", "enabled", "cs")

    def __init__(self, k_ports, enabled: bool = True):
        self.n = len(k_ports)
        self.enabled = bool(enabled)
        self.cs = correction_state(k_ports, self.enabled)

    def reset(self, tau_initial) -> None:
        """Start over; ``tau_initial``: the torques the ports return before the first step (held over
        step 0)."""
        self.cs[...] = correction_state(self.cs[:, CS_K], self.enabled, tau_initial)

    @property
    def mismatch_J(self) -> list[float]:
        return self.cs[:, CS_MISMATCH].tolist()

    def get_state(self) -> dict:
        """A copy of the correction state (for FMU state get/set)."""
        return {"cs": self.cs.copy()}

    def set_state(self, state: dict) -> None:
        self.cs[...] = state["cs"]

    def apply(self, phi, w, H: float, tau_mean, tau_base, x_end) -> list[float]:
        """One call per step, after the port's step with the flange inputs ``phi``, ``w`` (sequences,
        one per port) over ``H``: ``tau_mean`` the step means the port accounted its work with,
        ``tau_base`` the uncorrected outputs, ``x_end`` the port springs' inner angles at the step end.
        Returns the outputs to hand to the master (:func:`correct_port` per port)."""
        cs = self.cs
        H = float(H)
        return [correct_port(cs, q, H, float(phi[q]), float(w[q]), float(tau_mean[q]), float(tau_base[q]),
                             float(x_end[q])) for q in range(self.n)]
