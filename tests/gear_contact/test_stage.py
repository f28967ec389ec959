"""Gear stage: modal and static oracles, energy audit, rigid closed form, errors, co-simulation."""
import math

import numpy as np
import pytest

from gearcontact_fmu.mesh_models.analytic import iso6336_stiffness, single_pair_phase
from gearcontact_fmu.mesh_models.base import OUT_N_CONTACT, OUT_TAU_PINION, OUT_TAU_WHEEL
from gearcontact_fmu.params import BevelGearParams, PCMParams
from gearcontact_fmu.stage import GearStage, StageError, StageParams, make_stage

R = 4.0


def _K_single(gear):
    """Pinion-referred single-pair mesh stiffness from ISO 6336 (c' b r_b^2), r_b = r_m1 cos(alpha)."""
    c1 = iso6336_stiffness(gear)["c_prime"]            # N/(mm um)
    Re = gear.module * gear.z_pinion / 2 / math.sin(gear.delta_pinion)
    r_b = (Re - gear.face_width / 2) * math.sin(gear.delta_pinion) * math.cos(gear.pressure_angle)
    return c1 * gear.face_width * 1e3 * 1e6 * r_b ** 2


def test_mesh_eigenfrequency_matches_two_inertia_formula():
    gear = BevelGearParams(backlash=0.0)
    sp = StageParams(d_a=0.0, d_b=0.0, scheme="rk4", max_substep=2e-7)
    K = _K_single(gear)
    T = 3.0                                       # preload keeps the mesh in drive contact
    th_w = R * T / sp.k_b
    th_p = R * th_w + T / K
    phi_a = th_p + T / sp.k_a
    st = make_stage("analytic", gear, PCMParams(), stage_params=sp, damping_ratio=0.0,
                    mesh_phase=single_pair_phase(gear, th_p))
    # closed-form 2-DOF eigenproblem (flanges held): [[k_a + K, -R K], [-R K, k_b + R^2 K]] x = w^2 J x
    Kmat = np.array([[sp.k_a + K, -R * K], [-R * K, sp.k_b + R * R * K]])
    Jp, Jw = sp.J_pinion, sp.J_wheel
    a, b, c = Jp * Jw, -(Kmat[0, 0] * Jw + Kmat[1, 1] * Jp), np.linalg.det(Kmat)
    w2 = (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)
    f_exact = math.sqrt(w2) / (2 * math.pi)
    f_two_inertia = math.sqrt(K * (1 / Jp + R * R / Jw)) / (2 * math.pi)
    # excite the mesh mode only: its mode shape
    shape = np.array([Kmat[0, 1], w2 * Jp - Kmat[0, 0]])
    shape /= shape[0]
    amp = 2e-7
    st.initialize(0.0, phi_a, 0.0, 0.0, 0.0, theta_pinion=th_p + amp, theta_wheel=th_w + amp * shape[1],
                  omega_pinion=0.0, omega_wheel=0.0)
    assert st.out[OUT_N_CONTACT] == 1
    H = 2e-6
    n = 600
    s = np.empty(n)
    for i in range(n):
        st.step(i * H, H, phi_a, 0.0, 0.0, 0.0)
        s[i] = st.theta_pinion - R * st.theta_wheel - T / K
    t = H * (np.arange(n) + 1)
    zc = [t[i] - s[i] * H / (s[i + 1] - s[i]) for i in range(n - 1) if s[i] < 0 <= s[i + 1]]
    f_sim = (len(zc) - 1) / (zc[-1] - zc[0])
    assert f_sim == pytest.approx(f_exact, rel=2e-3)
    assert f_sim == pytest.approx(f_two_inertia, rel=1e-2)
    assert 8e3 < f_sim < 35e3                      # the mesh mode band of the notes


def test_static_torque_reaches_equilibrium_deflection():
    gear = BevelGearParams()
    sp = StageParams()
    K = _K_single(gear)
    s_b = gear.backlash / (gear.module * gear.z_pinion / 2)
    phi_a = 0.01
    T = (phi_a - s_b / 2) / (1 / sp.k_a + 1 / K + R * R / sp.k_b)       # series chain, closed form
    th_p = phi_a - T / sp.k_a
    st = make_stage("analytic", gear, stage_params=sp, mesh_phase=single_pair_phase(gear, th_p))
    st.initialize(0.0, 0.0, 0.0, 0.0, 0.0)
    H = 1e-4
    for i in range(4000):
        t = i * H
        ramp = min(t / 0.02, 1.0)
        st.step(t, H, phi_a * ramp, phi_a / 0.02 if t < 0.02 else 0.0, 0.0, 0.0)
    assert st.out[OUT_N_CONTACT] == 1
    T_mesh = -st.out[OUT_TAU_PINION]
    assert T_mesh == pytest.approx(T, rel=1e-4)
    d_s = st.theta_pinion - R * st.theta_wheel - s_b / 2
    assert d_s == pytest.approx(T / K, rel=1e-4)
    assert st.out[OUT_TAU_WHEEL] == pytest.approx(R * T, rel=1e-4)
    assert st.tau_a == pytest.approx(-T, rel=1e-4)          # pulls flange_a back
    assert st.tau_b == pytest.approx(R * T, rel=1e-4)       # drives flange_b forward
    assert abs(st.omega_pinion) < 1e-6 and abs(st.omega_wheel) < 1e-6


def _drive(case, n, H):
    """Flange inputs: 500 rpm on flange_a, 1/4 on flange_b, with load and oscillation (impacts)."""
    w_a = 52.36
    t = H * np.arange(n)
    amp, om = (1.5e-3, 2 * np.pi * 180.0) if case == "rattle" else (4e-4, 2 * np.pi * 90.0)
    lag = 0.002 if case == "rattle" else 0.008
    phi_a = lag + w_a * t + amp * np.sin(om * t)
    w = w_a + amp * om * np.cos(om * t)
    return t, phi_a, w, w_a / R * t, np.full(n, w_a / R)


def _audit(st, H, n, case, theta_pinion=None):
    """Per-step energy residual and flow; the pinion starts touching the drive flank (or at theta_pinion)."""
    t, pa, wa, pb, wb = _drive(case, n, H)
    s_b2 = 0.5 * 0.075e-3 / 0.0225
    st.initialize(0.0, pa[0], wa[0], pb[0], wb[0], theta_pinion=s_b2 if theta_pinion is None else theta_pinion,
                  theta_wheel=0.0)
    res = np.empty(n)
    flow = np.empty(n)
    for i in range(n):
        e0 = st.stored_energy_at_inputs(pa[i], wa[i], pb[i], wb[i])
        d0 = st.energy_dissipated_quadrature
        st.step(t[i], H, pa[i], wa[i], pb[i], wb[i])
        work = -H * (st.tau_a_mean * wa[i] + st.tau_b_mean * wb[i])
        res[i] = st.energy_stored - e0 + st.energy_dissipated_quadrature - d0 - work
        flow[i] = abs(work) + abs(st.energy_dissipated_quadrature - d0)
    return res, flow


@pytest.mark.parametrize("fidelity,mode,case,scheme,tol,order", [
    ("analytic", "stage", "loaded", "ros2", 2e-4, 2),
    ("analytic", "stage", "loaded", "rk4", 1e-6, 2),
    ("ideal", "stage", "loaded", "ros2", 2e-4, 2),
    ("analytic", "bare", "rattle", "ros2", 1e-4, 2),
    # impacts with friction: kinks at every contact closing/opening, resolved down to h/64
    ("analytic", "stage", "rattle", "ros2", 1e-3, 0),
    ("analytic", "stage", "rattle", "rk4", 1e-4, 0)])
def test_energy_balance_per_step(fidelity, mode, case, scheme, tol, order):
    """Per step: work in through the flanges = delta stored + delta dissipated, to integrator accuracy
    (the residual shrinks with the sub-step; for smooth cases at least as h^order)."""
    H = 1e-4
    n = 800
    errs = []
    for ms in (2e-5, 1e-5):
        kw = {"mu": 0.05 if case == "rattle" else 0.0, "damping_ratio": 0.1} if fidelity == "analytic" else {}
        st = make_stage(fidelity, stage_params=StageParams(mode=mode, max_substep=ms, scheme=scheme), **kw)
        res, flow = _audit(st, H, n, case)
        assert np.sum(np.abs(res)) <= tol * np.sum(flow)
        errs.append(np.sum(np.abs(res)))
        assert st.energy_supplied == 0.0
    assert errs[1] <= errs[0] * (2.0 ** -order if order else 1.0) * 1.25


@pytest.mark.parametrize("scheme,max_substep,tol", [("auto", 1e-5, 1e-6), ("ros2", 2.5e-6, 1e-3)])
def test_ideal_mode_equals_rigid_closed_form(scheme, max_substep, tol):
    sp = StageParams(scheme=scheme, max_substep=max_substep)
    st = make_stage("ideal", stage_params=sp)
    th0 = 0.01
    st.initialize(0.0, 0.0, 0.0, 0.0, 0.0, theta_pinion=th0, omega_pinion=0.0)
    J = sp.J_pinion + sp.J_wheel / R ** 2
    k = sp.k_a + sp.k_b / R ** 2
    c = sp.d_a + sp.d_b / R ** 2
    wn = math.sqrt(k / J)
    z = c / (2 * math.sqrt(k * J))
    wd = wn * math.sqrt(1 - z * z)
    H = 1e-4
    for i in range(200):
        st.step(i * H, H, 0.0, 0.0, 0.0, 0.0)
        t = (i + 1) * H
        exact = th0 * math.exp(-z * wn * t) * (math.cos(wd * t) + z * wn / wd * math.sin(wd * t))
        assert st.theta_pinion == pytest.approx(exact, abs=tol * th0)
        assert st.theta_wheel == pytest.approx(st.theta_pinion / R, rel=1e-9, abs=1e-15)
        # ideal mesh: the constraint torques transmit the exact ratio
        assert st.out[OUT_TAU_WHEEL] == pytest.approx(-R * st.out[OUT_TAU_PINION], rel=1e-9, abs=1e-12)


def test_non_finite_input_raises():
    st = make_stage("analytic")
    st.initialize(0.0, 0.0, 0.0, 0.0, 0.0)
    st.step(0.0, 1e-4, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(StageError, match=r"non-finite input at t = 0\.0001"):
        st.step(1e-4, 1e-4, float("nan"), 0.0, 0.0, 0.0)
    with pytest.raises(StageError, match="non-finite input"):
        st.step(2e-4, 1e-4, 0.0, float("inf"), 0.0, 0.0)


def test_penetration_beyond_u_max_raises():
    st = make_stage("analytic", pcm_params=PCMParams(u_max=1e-6))
    st.initialize(0.0, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(StageError, match=r"penetration .* beyond u_max\) at t = "):
        for i in range(3000):
            t = i * 1e-4
            st.step(t, 1e-4, 0.2 * t, 0.2, 0.0, 0.0)      # the load grows until the approach > 1 um


def test_bare_ideal_rejected_and_bad_params():
    from gearcontact_fmu.mesh_models import make_mesh_model

    with pytest.raises(ValueError):
        GearStage(make_mesh_model("ideal"), R, StageParams(mode="bare"))
    with pytest.raises(ValueError):
        GearStage(make_mesh_model("analytic"), R, StageParams(scheme="euler"))


# --- co-simulation ------------------------------------------------------------------------------

J_A, J_B, T_A, C_L = 2e-3, 2e-3, 2.0, 0.8


def _drive_torque(t):
    return T_A * min(t / 0.005, 1.0)


def _cosim(H, t_end):
    """Tiny Jacobi master: the stage (spring side on both flanges) between two external inertias,
    torques held over the step, inputs (phi, w) at the step start."""
    st = make_stage("analytic")
    pa = wa = pb = wb = 0.0
    st.initialize(0.0, pa, wa, pb, wb)
    ta, tb = st.tau_a, st.tau_b
    n = int(round(t_end / H))
    wB = np.empty(n)
    for i in range(n):
        t = i * H
        ta_n, tb_n = st.step(t, H, pa, wa, pb, wb)
        TA = _drive_torque(t) + ta
        TB = -C_L * wb + tb
        pa, wa = pa + H * wa + 0.5 * H * H * TA / J_A, wa + H * TA / J_A
        pb, wb = pb + H * wb + 0.5 * H * H * TB / J_B, wb + H * TB / J_B
        ta, tb = ta_n, tb_n
        wB[i] = wb
    return wB


def _monolithic(t_eval):
    from scipy.integrate import solve_ivp

    st = make_stage("analytic")
    sp, m = st.params, st.model
    out = np.zeros(10)

    def rhs(t, y):
        pa, wa, tp, wp, tw, ww, pb, wb = y
        m.eval(m.data, tp, tw, wp, ww, out)
        ta = sp.k_a * (tp - pa) + sp.d_a * (wp - wa)
        tb = sp.k_b * (tw - pb) + sp.d_b * (ww - wb)
        return [wa, (_drive_torque(t) + ta) / J_A, wp, (-ta + out[OUT_TAU_PINION]) / sp.J_pinion,
                ww, (-tb + out[OUT_TAU_WHEEL]) / sp.J_wheel, wb, (-C_L * wb + tb) / J_B]

    # max_step 1e-5 s: the tolerances decide the steps; with max_step 2e-6 s (4x the evaluations) the
    # reference moves by 2e-9 rad/s (measured), the coupling errors compared with it are ~1e-2 rad/s
    sol = solve_ivp(rhs, (0.0, t_eval[-1]), np.zeros(8), method="RK45", t_eval=t_eval, rtol=1e-9,
                    atol=1e-12, max_step=1e-5)
    assert sol.success
    return sol.y[7]


def test_cosim_jacobi_master_is_stable_and_matches_monolithic():
    H = 1e-4
    t_end = 0.08
    y_h = _cosim(H, t_end)
    y_h2 = _cosim(H / 2, t_end)[1::2]
    t = H * (np.arange(len(y_h)) + 1)
    ref = _monolithic(t)
    assert np.all(np.isfinite(y_h)) and np.max(np.abs(y_h)) < 20.0
    err = np.abs(y_h - ref)
    est = 2.0 * np.abs(y_h - y_h2)            # first-order coupling error: step halving estimate
    assert err[-1] <= 1.25 * est[-1]
    assert np.sqrt(np.mean(err ** 2)) <= 1.25 * np.sqrt(np.mean(est ** 2))
    assert err[-1] < 5e-3 * abs(ref[-1])


def test_reported_dissipation_is_the_step_balance():
    """energy_dissipated (what the FMU reports to the audit) is port work minus stored-energy change,
    cumulative, so it agrees with an independent bookkeeping of the same steps to round-off; and in a
    smooth case it agrees with the quadrature of the dissipated power to integrator accuracy."""
    from gearcontact_fmu.stage import make_stage

    H, n = 1e-4, 300
    st = make_stage("analytic")
    t, pa, wa, pb, wb = _drive("loaded", n, H)
    s_b2 = 0.5 * 0.075e-3 / 0.0225
    st.initialize(0.0, pa[0], wa[0], pb[0], wb[0], theta_pinion=s_b2, theta_wheel=0.0)
    total = 0.0
    for i in range(n):
        e0 = st.stored_energy_at_inputs(pa[i], wa[i], pb[i], wb[i])
        st.step(t[i], H, pa[i], wa[i], pb[i], wb[i])
        total += -H * (st.tau_a_mean * wa[i] + st.tau_b_mean * wb[i]) - (st.energy_stored - e0)
    assert st.energy_dissipated == pytest.approx(total, rel=1e-12, abs=1e-15)
    assert st.energy_dissipated > 0
    assert st.energy_dissipated == pytest.approx(st.energy_dissipated_quadrature, rel=1e-3)
