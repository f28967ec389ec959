"""Analytic (ISO 6336) reference mesh: stiffness, contact ratio, mesh cycle, backlash, torques, energy."""
import math

import numpy as np
import pytest

from gearcontact_fmu.mesh_models import analytic as an
from gearcontact_fmu.mesh_models import make_mesh_model
from gearcontact_fmu.mesh_models.base import (N_OUT, OUT_DISSIPATED_POWER, OUT_ELASTIC_ENERGY, OUT_MAX_PENETRATION,
                                        OUT_N_CONTACT, OUT_NORMAL_FORCE, OUT_STATUS, OUT_TAU_PINION,
                                        OUT_TAU_WHEEL)
from gearcontact_fmu.params import BevelGearParams, PCMParams

GEAR = BevelGearParams()


def _independent_iso(z1, z2, x1, x2, h_fp=1.25, alpha_deg=20.0):
    """ISO 6336-1 (2006) method B, written out from the standard."""
    q = (0.04723 + 0.15551 / z1 + 0.25791 / z2 - 0.00635 * x1 - 0.11654 * x1 / z1 - 0.00193 * x2
         - 0.24188 * x2 / z2 + 0.00529 * x1 ** 2 + 0.00182 * x2 ** 2)
    c_b = (1 + 0.5 * (1.2 - h_fp)) * (1 - 0.02 * (20.0 - alpha_deg))
    return (1.0 / q) * 0.8 * 1.0 * c_b


def _independent_geometry():
    """Virtual spur gears at the mean cone distance, from the RIG data (m = 3 mm, 15/60, b = 25 mm)."""
    m, z1, z2, b, x1 = 3.0, 15, 60, 25.0, 0.43          # mm
    a = math.radians(20.0)
    d1 = math.atan(z1 / z2)
    d2 = math.pi / 2 - d1
    Re = m * z1 / 2 / math.sin(d1)
    mm = m * (Re - b / 2) / Re
    zv1, zv2 = z1 / math.cos(d1), z2 / math.cos(d2)
    r1, r2 = mm * zv1 / 2, mm * zv2 / 2
    ra1, ra2 = r1 + (1 + x1) * mm, r2 + (1 - x1) * mm
    rb1, rb2 = r1 * math.cos(a), r2 * math.cos(a)
    eps = (math.sqrt(ra1 ** 2 - rb1 ** 2) + math.sqrt(ra2 ** 2 - rb2 ** 2) - (r1 + r2) * math.sin(a)) / (
        math.pi * mm * math.cos(a))
    r_b = (Re - b / 2) * math.sin(d1) * math.cos(a) * 1e-3      # m, real pinion mean base radius
    return dict(zv1=zv1, zv2=zv2, eps=eps, r_b=r_b, x1=x1)


def test_iso6336_stiffness_matches_independent_formula():
    g = _independent_geometry()
    c1 = _independent_iso(g["zv1"], g["zv2"], g["x1"], -g["x1"])
    iso = an.iso6336_stiffness(GEAR)
    assert iso["c_prime"] == pytest.approx(c1, rel=1e-10)
    assert iso["c_gamma"] == pytest.approx(c1 * (0.75 * g["eps"] + 0.25), rel=1e-10)
    # the engineering notes quote c' ~ 14 and c_gamma ~ 20 N/(mm um) for this pair
    assert 13.0 < iso["c_prime"] < 15.0
    assert 18.5 < iso["c_gamma"] < 21.5
    st = an.mesh_stiffness(GEAR)
    assert st["k_single"] == pytest.approx(c1 * 25.0 * 1e6, rel=1e-10)       # N/(mm um) * mm -> N/m
    assert st["K_single"] == pytest.approx(c1 * 25e6 * g["r_b"] ** 2, rel=1e-10)


def test_contact_ratio_of_virtual_spur_gears():
    g = _independent_geometry()
    v = an.virtual_spur_gears(GEAR)
    assert v["eps_alpha"] == pytest.approx(g["eps"], rel=1e-12)
    assert 1.5 < v["eps_alpha"] < 1.64            # RIG.md: about 1.5-1.64 depending on addenda
    assert v["z_v1"] == pytest.approx(15.46, abs=0.01) and v["z_v2"] == pytest.approx(247.4, abs=0.1)
    assert v["r_b"] == pytest.approx(g["r_b"], rel=1e-12)


def _model(**kw):
    return an.make_analytic_model(GEAR, PCMParams(), **kw)


def test_single_double_zone_lengths_match_contact_ratio():
    m = _model(transition=0.0, damping_ratio=0.0)
    info = m.info
    sb2 = info["s_backlash"] / 2
    period = 2 * math.pi / GEAR.z_pinion
    n = 20000
    th = np.linspace(0.0, period, n, endpoint=False) + 0.3
    d_s = 1e-5
    ncont = np.empty(n)
    K = np.empty(n)
    for i, t in enumerate(th):
        out = m.evaluate(t, (t - sb2 - d_s) / 4.0)
        ncont[i] = out[OUT_N_CONTACT]
        K[i] = out[OUT_TAU_WHEEL] / 4.0 / d_s
    frac2 = np.mean(ncont == 2)
    assert frac2 == pytest.approx(info["eps_alpha"] - 1.0, abs=2.0 / n)
    assert np.mean(ncont == 1) == pytest.approx(2.0 - info["eps_alpha"], abs=2.0 / n)
    # torsional stiffness per zone, and the cycle mean equals the ISO mesh stiffness c_gamma b r_b^2
    assert np.allclose(K[ncont == 1], info["K_single"], rtol=1e-9)
    assert np.allclose(K[ncont == 2], info["K_double"], rtol=1e-9)
    assert np.mean(K) == pytest.approx(info["K_mean"], rel=1e-3)
    # the double zone is one contiguous interval per cycle
    edges = np.count_nonzero(np.diff(np.r_[ncont, ncont[0]]) != 0)
    assert edges == 2


def test_backlash_dead_zone_and_signs():
    m = _model(damping_ratio=0.0)
    s_b = GEAR.backlash / (GEAR.module * GEAR.z_pinion / 2)
    assert m.info["s_backlash"] == pytest.approx(s_b, rel=1e-12)
    tp = 0.01
    for s in np.linspace(-0.499 * s_b, 0.499 * s_b, 41):
        out = m.evaluate(tp, (tp - s) / 4.0, 1.0, 0.25)
        assert out[OUT_TAU_PINION] == 0.0 and out[OUT_TAU_WHEEL] == 0.0 and out[OUT_N_CONTACT] == 0
    drive = m.evaluate(tp, (tp - 0.5 * s_b - 2e-5) / 4.0)
    coast = m.evaluate(tp, (tp + 0.5 * s_b + 2e-5) / 4.0)
    assert drive[OUT_TAU_PINION] < 0.0 < drive[OUT_TAU_WHEEL]       # ARCHITECTURE.md: pinion driving
    assert coast[OUT_TAU_PINION] > 0.0 > coast[OUT_TAU_WHEEL]
    assert drive[OUT_MAX_PENETRATION] == pytest.approx(m.info["r_b"] * 2e-5, rel=1e-9)


def test_torque_ratio_and_normal_force():
    m = _model(damping_ratio=0.0)
    rb = m.info["r_b"]
    sb2 = m.info["s_backlash"] / 2
    for tp in np.linspace(0.0, 0.5, 37):
        out = m.evaluate(tp, (tp - sb2 - 3e-5) / 4.0)
        # exact away from the stiffness transitions; inside them the conservative term
        # -1/2 K' d_s^2 acts on the pinion only (a few 1e-4 of the torque at most)
        assert out[OUT_TAU_WHEEL] == pytest.approx(-4.0 * out[OUT_TAU_PINION], rel=2e-3)
        assert out[OUT_NORMAL_FORCE] == pytest.approx(out[OUT_TAU_WHEEL] / 4.0 / rb, rel=1e-12)


def test_loading_unloading_cycle_returns_the_energy():
    """A closed path in (theta_p, theta_w): load at one phase, rotate the loaded pair through a
    single/double transition, unload, rotate back. Without damping and friction the work of the
    mesh torques around the loop is zero and the elastic energy equals the loading work."""
    m = _model(damping_ratio=0.0, mu=0.0)
    sb2 = m.info["s_backlash"] / 2
    r = 4.0
    # corners in (theta_p, s); the rotation crosses the transition at the end of the double zone
    v = an.virtual_spur_gears(GEAR)
    t_tr = (v["p_b"] * (v["eps_alpha"] - 1) - v["g_a"]) / v["r_b"]   # theta_p of a transition
    corners = [(t_tr - 0.01, sb2 - 1e-5), (t_tr - 0.01, sb2 + 6e-5), (t_tr + 0.01, sb2 + 6e-5),
               (t_tr + 0.01, sb2 - 1e-5), (t_tr - 0.01, sb2 - 1e-5)]
    out = np.zeros(N_OUT)
    work = 0.0          # work done BY the mesh torques on the gears
    load_work = 0.0
    elastic_loaded = None
    for k in range(4):
        (t0, s0), (t1, s1) = corners[k], corners[k + 1]
        n = 20000
        lam = np.linspace(0.0, 1.0, n + 1)
        tp = t0 + (t1 - t0) * lam
        s = s0 + (s1 - s0) * lam
        tw = (tp - s) / r
        P = np.empty(n + 1)
        for i in range(n + 1):
            m.eval(m.data, tp[i], tw[i], 0.0, 0.0, out)
            P[i] = out[OUT_TAU_PINION] * (tp[1] - tp[0]) + out[OUT_TAU_WHEEL] * (tw[1] - tw[0])
            if k == 0 and i == n:
                elastic_loaded = out[OUT_ELASTIC_ENERGY]
        seg = np.sum(0.5 * (P[1:] + P[:-1]))
        work += seg
        if k == 0:
            load_work = -seg
    assert elastic_loaded > 0.0
    assert load_work == pytest.approx(elastic_loaded, rel=1e-6)
    assert abs(work) < 1e-6 * elastic_loaded


def test_power_balance_with_damping_and_friction():
    """-(tau_p w_p + tau_w w_w) = dV/dt + P_diss along a trajectory, and P_diss >= 0."""
    m = _model(damping_ratio=0.1, mu=0.05)
    sb2 = m.info["s_backlash"] / 2
    out = np.zeros(N_OUT)
    wp = 50.0

    def state(t):
        # pinion at constant speed; wheel oscillates so the mesh loads and unloads
        tw = (wp * t - sb2 - 3e-5 * (1 + np.sin(2 * np.pi * 700 * t))) / 4.0
        dtw = (wp - 3e-5 * 2 * np.pi * 700 * np.cos(2 * np.pi * 700 * t)) / 4.0
        return wp * t, tw, wp, dtw

    dt = 1e-8
    for t in np.linspace(0.0, 3e-3, 301):
        tp, tw, w1, w2 = state(t)
        m.eval(m.data, tp, tw, w1, w2, out)
        p_in = -(out[OUT_TAU_PINION] * w1 + out[OUT_TAU_WHEEL] * w2)
        pd = out[OUT_DISSIPATED_POWER]
        assert pd >= -1e-12
        Vp = m.evaluate(*state(t + dt))[OUT_ELASTIC_ENERGY]
        Vm = m.evaluate(*state(t - dt))[OUT_ELASTIC_ENERGY]
        dV = (Vp - Vm) / (2 * dt)
        scale = abs(out[OUT_TAU_WHEEL] * w2)
        assert p_in == pytest.approx(dV + pd, abs=1e-5 * scale + 1e-9)


def test_status_beyond_u_max():
    m = _model(u_max=1e-6)
    sb2 = m.info["s_backlash"] / 2
    ok = m.evaluate(0.0, -(sb2 + 0.5e-6 / m.info["r_b"]) / 4.0)
    bad = m.evaluate(0.0, -(sb2 + 2e-6 / m.info["r_b"]) / 4.0)
    assert ok[OUT_STATUS] == 0 and bad[OUT_STATUS] == 1


def test_factory():
    m = make_mesh_model("analytic", GEAR, PCMParams(), None, J_pinion=1e-4)
    assert m.fidelity == "analytic" and m.kind == "mesh"
    ideal = make_mesh_model("ideal", GEAR)
    assert ideal.kind == "rigid"
    with pytest.raises(ValueError):
        make_mesh_model("analytic", GEAR, health="severe")
    with pytest.raises(ValueError):
        make_mesh_model("hertz", GEAR)
