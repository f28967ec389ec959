"""MotorLoad's ``motor_torque_disturbance`` input: a torque added to the drive motor's controlled torque on its
rotor after the PI controller and its torque limit (models.line.line_step's Td slot).

Oracles independent of the kernel: the speed loop's steady state (the integrator takes over -d, the total motor
torque stays what the bearing loss needs), the first sub-step's acceleration d / J_motor from a steady state, the
momentum balance of the free drive side, the limit bounding the PI's share only, the energy balance every step
under a sinusoidal disturbance (the disturbance's work over a step is exactly d times the motor node's angle
change: the midpoint rule advances the angle by h times the midpoint speed the work is counted with), and the
error on a non-finite value. Native = Python: tests/fmu_build/test_native_line.py."""
import math
import re

import numpy as np
import pytest

from drivetrain.errors import ComponentError
from drivetrain.models import motors
from drivetrain.models.components import make_component
from drivetrain.models.line import LineModel, Port
from drivetrain.system import INERTIA
from _line_energy import step_energy_residual

H = 1.0 / 12000.0


def _free_drive(**kw):
    """MotorLoad with the drive flange free (no port spring C2): motor + C1 + flywheel; the load side apart."""
    p = {"k_c2": 0.0, "d_c2": 0.0, "max_substep": 1e-5}
    p.update(kw)
    return make_component("MotorLoad", p)


def test_default_is_zero_and_set_inputs_stores_it():
    m = _free_drive()
    assert m.motor_torque_disturbance == 0.0 and m.line.motor_disturbance == 0.0
    m.set_inputs(0.0, 0.0, 0.0, motor_torque_disturbance=0.25)
    assert m.motor_torque_disturbance == 0.25
    m.set_inputs(0.0, 0.0, 0.0)                      # None: kept
    assert m.motor_torque_disturbance == 0.25
    m.step(0.0, H)
    assert m.line.motor_disturbance == 0.25          # handed to the line for the step


def test_steady_state_the_integrator_takes_over_minus_d():
    """At a steady speed with a bearing loss c_motor and the drive side free, the motor torque is c_motor w.
    A constant disturbance d does not change that total (the speed loop compensates it): once the
    integrator settled, the PI's share Kp (e + x) is c_motor w - d and the speed is back at the reference."""
    w_ref = 100.0
    d = 0.3
    m = _free_drive(c_motor=2e-3, w0=w_ref, tau0=0.0)
    p = m.p
    ref_rpm = w_ref / motors.RPM
    for i in range(int(4.0 / H)):
        m.set_inputs(0.0, 0.0, 0.0, speed_ref_rpm=ref_rpm, load_torque=0.0, motor_torque_disturbance=d)
        m.step(i * H, H)
    o = m.outputs()
    w = o["motor_w"]
    assert w == pytest.approx(w_ref, rel=1e-6)
    assert o["motor_torque"] == pytest.approx(p.c_motor * w, abs=1e-5 * d)            # total unchanged
    pi_share = p.Kp * ((w_ref - w) + float(m.line.pi_x[0]))
    assert pi_share == pytest.approx(p.c_motor * w - d, abs=1e-5 * d)                  # the PI's share drops by d
    # the integrator started at the undisturbed steady state (c_motor w0 / Kp): it moved by -d / Kp
    assert float(m.line.pi_x[0]) - p.c_motor * w_ref / p.Kp == pytest.approx(-d / p.Kp, rel=1e-4)


def test_first_substep_acceleration_is_d_over_J_motor():
    """From a steady state (speed at the reference, no loss, C1 untwisted, the integrator at 0) one sub-step
    of h = 1 us: the disturbance accelerates the motor rotor alone by about d / J_motor (C1 has not twisted
    yet; the PI's proportional reaction Kp (w_mid - w_ref) and C1's damper take ~1e-4 of it). Exactly: the
    midpoint speeds w + delta of motor (0) and flywheel (1) solve
        (2 J0 / h + Kp + c + k h / 2) delta0 - (c + k h / 2) delta1 = d
        (2 J1 / h + c + k h / 2) delta1 - (c + k h / 2) delta0 = 0
    and the end accelerations are 2 delta / h."""
    d = 0.4
    m = _free_drive(c_motor=0.0, w0=50.0, tau0=0.0)
    p = m.p
    h = 1e-6
    m.set_inputs(0.0, 0.0, 0.0, speed_ref_rpm=50.0 / motors.RPM, load_torque=0.0, motor_torque_disturbance=d)
    assert float(m.line.pi_x[0]) == 0.0
    w0 = m.line.om.copy()
    m.step(0.0, h)
    assert m.line.n_sub_last == 1
    acc = (m.line.om - w0) / h
    g = p.d_c1 + 0.5 * p.k_c1 * h
    A = np.array([[2 * p.J_motor / h + p.Kp + g, -g], [-g, 2 * p.J_flywheel / h + g]])
    delta = np.linalg.solve(A, [d, 0.0])
    assert acc[0] == pytest.approx(2 * delta[0] / h, rel=1e-9)
    assert acc[1] == pytest.approx(2 * delta[1] / h, rel=1e-4)     # a 4e-9 rad/s change of 50 rad/s: round-off
    assert acc[0] == pytest.approx(d / p.J_motor, rel=2e-4)
    assert abs(acc[1]) < 1e-3 * acc[0]
    assert acc[2] == 0.0                              # the load side is apart


def test_momentum_of_the_free_drive_side_counts_the_disturbance():
    """Drive side free, no loss: the momentum change of motor + flywheel over a step is H times the step-mean
    motor torque (the ``motor_torque`` output: PI torque + disturbance), to round-off, for any disturbance."""
    m = _free_drive(c_motor=0.0, w0=30.0)
    p = m.p
    for k in range(200):
        t = k * H
        d = 0.5 * math.sin(2 * math.pi * 150.0 * t) + 0.1
        m.set_inputs(0.0, 0.0, 0.0, speed_ref_rpm=(30.0 + 2000.0 * t) / motors.RPM, load_torque=0.0,
                     motor_torque_disturbance=d)
        L0 = p.J_motor * m.line.om[0] + p.J_flywheel * m.line.om[1]
        m.step(t, H)
        L1 = p.J_motor * m.line.om[0] + p.J_flywheel * m.line.om[1]
        assert L1 - L0 == pytest.approx(H * m.outputs()["motor_torque"], rel=1e-9, abs=1e-15)


def test_the_torque_limit_bounds_the_pi_share_only():
    """Saturated (a large speed step, tau_max = 0.5): the mean motor torque is tau_max + d, to round-off (the
    disturbance is added after the limit and is no part of the anti-windup's unlimited torque)."""
    d = 0.2
    m = _free_drive(c_motor=0.0, tau_max=0.5)
    for i in range(50):
        m.set_inputs(0.0, 0.0, 0.0, speed_ref_rpm=3000.0, load_torque=0.0, motor_torque_disturbance=d)
        m.step(i * H, H)
        assert m.outputs()["motor_torque"] == pytest.approx(0.5 + d, rel=1e-12)


def test_energy_balance_with_a_sinusoidal_disturbance():
    """supplied = delta stored + dissipated + work out through the ports every step (round-off), the drive
    flange and the load flange driven, under a sinusoidal disturbance; the disturbance's work (d times the
    motor node's angle change per step) is a large part of the supplied energy, so the balance would fail by
    that much if the kernel did not count it."""
    m = make_component("MotorLoad", {"w0": 150.0, "w0_load": 12.5, "max_substep": 2e-5})
    ln = m.line
    rng = np.random.default_rng(3)
    t = 0.0
    worst = 0.0
    w_dist = 0.0
    w_supp = 0.0
    for _ in range(600):
        d = 0.8 * math.sin(2 * math.pi * 90.0 * t)
        m.set_inputs(0.2 * math.sin(30 * t) + 150 * t, 150 + 5 * rng.normal(), rng.normal(10, 2),
                     speed_ref_rpm=1400.0, load_torque=1.0, motor_torque_disturbance=d)
        s0, th0 = ln.energy_supplied, float(ln.th[0])
        res, scale = step_energy_residual(m, t, H)
        t += H
        worst = max(worst, abs(res) / scale)
        w_dist += abs(d * (float(ln.th[0]) - th0))
        w_supp += abs(ln.energy_supplied - s0)
    assert worst < 1e-9
    assert w_dist > 0.2 * w_supp, (w_dist, w_supp)


def test_supplied_energy_includes_the_disturbance_work_exactly():
    """One step of a saturated motor (the PI gives tau_max at every sub-step), the load side at rest and
    unloaded: the supplied energy is the motor's work (tau_max + d) times the motor node's angle change (the
    midpoint rule advances the angle by h times the midpoint speed the work is counted with), with and
    without a disturbance."""
    d = 0.3
    for dist in (0.0, d):
        m = _free_drive(c_motor=0.0, tau_max=0.5)
        m.set_inputs(0.0, 0.0, 0.0, speed_ref_rpm=3000.0, load_torque=0.0, motor_torque_disturbance=dist)
        th0 = float(m.line.th[0])
        m.step(0.0, H)
        dth = float(m.line.th[0]) - th0
        # no source law works on the load side (load_torque 0, load at rest): supplied = motor work
        assert m.line.energy_supplied == pytest.approx((0.5 + dist) * dth, rel=1e-12)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_disturbance_is_the_non_finite_input_error(bad):
    m = _free_drive()
    m.set_inputs(0.0, 0.0, 0.0, motor_torque_disturbance=bad)
    with pytest.raises(ComponentError, match=r"non-finite input at t = 0\.001 s: .*motor disturbance "
                                             + re.escape(repr(bad))):
        m.step(0.001, H)
    # the state is untouched (the kernel refuses before the first sub-step): a finite value steps on
    m.set_inputs(0.0, 0.0, 0.0, motor_torque_disturbance=0.0)
    m.step(0.001, H)


def test_line_without_motor_ignores_nothing_but_checks_the_slot():
    """LineModel.set_motor_disturbance writes the fp slot after wref; without a motor the kernel adds nothing
    (m_node < 0) but still refuses a non-finite value."""
    ln = LineModel([1.0, 2.0], [10.0], [0.1], None, [Port("a", 0, INERTIA)])
    assert ln.fp.shape[0] == 5 * 2 + 5 * 1 + 0 + 7
    ln.set_motor_disturbance(1.5)
    assert ln.fp[-1] == 1.5 and ln.m_dist[0] == 1.5
    ln.set_state([0.0, 0.0], [1.0, 1.0])
    ln.step(0.0, 1e-3)
    assert np.allclose(ln.om, [1.0, 1.0]) and ln.motor_torque == 0.0
    ln.set_motor_disturbance(float("nan"))
    with pytest.raises(ComponentError, match="non-finite input"):
        ln.step(0.0, 1e-3)
