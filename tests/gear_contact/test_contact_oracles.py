"""Closed-form oracles of the PCM contact engine: plane/plane, sphere/plane, cylinder/plane, swap of
base and target, energy of a loading-unloading cycle, damping and friction laws."""
from __future__ import annotations

import numpy as np
import pytest

from gearcontact_fmu.contact import primitives as P
from gearcontact_fmu.contact.engine import PCMBody, evaluate_pair
from gearcontact_fmu.params import PCMParams

PCM = PCMParams(u_max=2e-4)
C = PCM.stiffness
I3 = np.eye(3)
Z3 = np.zeros(3)


def at(z=0.0, x=0.0, y=0.0):
    return (I3, np.array([x, y, z], float))


# ---------------------------------------------------------------------------------------------
# 1. plane on plane
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def plates():
    base = PCMBody(*P.plate(16, 12, 0.010, 0.008, up=True))       # 10 x 8 mm, normal +z
    target = PCMBody(*P.plate(3, 5, 0.020, 0.030, up=False))      # larger, normal -z
    return base, target


@pytest.mark.parametrize("u", [1e-7, 1e-6, 5e-6, 3e-5, 1.5e-4])
def test_plane_on_plane(plates, u):
    base, target = plates
    r = evaluate_pair(base, target, at(), at(-u), pcm=PCM, friction=False, damping=False)
    A = 0.010 * 0.008
    F = C * A * u
    assert r.n_contact == base.n_faces
    assert abs(r.force_target[2] / F - 1.0) < 1e-9
    assert abs(r.force_base[2] / -F - 1.0) < 1e-9
    assert np.allclose(r.force_target[:2], 0.0, atol=1e-12 * F)
    assert abs(r.contact_area / A - 1.0) < 1e-12
    assert abs(r.elastic_energy / (0.5 * C * A * u * u) - 1.0) < 1e-9
    assert abs(r.max_penetration / u - 1.0) < 1e-9
    assert abs(r.peak_pressure / (C * u) - 1.0) < 1e-9
    assert abs(r.normal_force / F - 1.0) < 1e-9


def test_plane_apart_and_back_facing(plates):
    base, target = plates
    r = evaluate_pair(base, target, at(), at(+1e-6), pcm=PCM)      # gap: no contact
    assert r.n_contact == 0 and np.all(r.force_target == 0.0)
    # same-facing target (normal +z) below the base surface: not a contact
    same = PCMBody(*P.plate(3, 5, 0.020, 0.030, up=True))
    r = evaluate_pair(base, same, at(), at(-1e-5), pcm=PCM)
    assert r.n_contact == 0


# ---------------------------------------------------------------------------------------------
# 2. sphere on plane, cylinder on plane (converged + convergence)
# ---------------------------------------------------------------------------------------------
R_S = 0.01


def sphere_force(n, u, exact=True, R=R_S):
    a = np.sqrt(2 * R * u)
    V, F, fp, fn = P.sphere_cap(R, 1.4 * a, n, centre=(0, 0, R))
    sph = PCMBody(V, F, fp, fn) if exact else PCMBody(V, F)
    plane = PCMBody(*P.plate(2, 2, 0.05, 0.05, up=True))
    r = evaluate_pair(sph, plane, at(-u), at(), pcm=PCM, friction=False, damping=False)
    return -r.force_target[2], r


def cylinder_force(n, u, exact=True, R=R_S, L=0.004):
    a = np.sqrt(2 * R * u)
    V, F, fp, fn = P.cylinder_patch(R, 1.4 * a, L, n, 4, centre=(0, 0, R))
    cyl = PCMBody(V, F, fp, fn) if exact else PCMBody(V, F)
    plane = PCMBody(*P.plate(2, 2, 0.05, 0.05, up=True))
    r = evaluate_pair(cyl, plane, at(-u), at(), pcm=PCM, friction=False, damping=False)
    return -r.force_target[2], r


@pytest.mark.parametrize("u", [2e-6, 2e-5])
def test_sphere_on_plane_converged(u):
    ref = np.pi * R_S * C * u * u
    F, r = sphere_force(60, u)
    assert r.n_contact > 500
    assert abs(F / ref - 1.0) < 0.02
    # facets only (no exact face data) converge too
    F0, _ = sphere_force(60, u, exact=False)
    assert abs(F0 / ref - 1.0) < 0.02


@pytest.mark.parametrize("u", [2e-6, 2e-5])
def test_cylinder_on_plane_converged(u):
    L = 0.004
    ref = 4.0 / 3.0 * C * L * np.sqrt(2 * R_S) * u ** 1.5
    F, r = cylinder_force(60, u, L=L)
    assert abs(F / ref - 1.0) < 0.02
    F0, _ = cylinder_force(60, u, exact=False, L=L)
    assert abs(F0 / ref - 1.0) < 0.02


def test_convergence_with_refinement():
    """Facet meshes (no exact data): the error falls with refinement, ~h^2."""
    u = 1e-5
    ref_s = np.pi * R_S * C * u * u
    ref_c = 4.0 / 3.0 * C * 0.004 * np.sqrt(2 * R_S) * u ** 1.5
    es = [abs(sphere_force(n, u, exact=False)[0] / ref_s - 1) for n in (10, 20, 40, 80)]
    ec = [abs(cylinder_force(n, u, exact=False)[0] / ref_c - 1) for n in (10, 20, 40, 80)]
    print("sphere rel. errors n=10,20,40,80:", es)
    print("cylinder rel. errors n=10,20,40,80:", ec)
    assert es[-1] < 0.005 and ec[-1] < 0.005
    assert es[-1] < es[0] / 8 and ec[-1] < ec[0] / 8
    assert all(b < a for a, b in zip(es, es[1:]))
    assert all(b < a for a, b in zip(ec, ec[1:]))


@pytest.mark.slow
def test_convergence_exact_fine():
    for u in (1e-6, 1e-5, 5e-5):
        ref_s = np.pi * R_S * C * u * u
        ref_c = 4.0 / 3.0 * C * 0.004 * np.sqrt(2 * R_S) * u ** 1.5
        for n in (40, 80, 160):
            es = sphere_force(n, u)[0] / ref_s - 1
            ec = cylinder_force(n, u)[0] / ref_c - 1
            print(f"u={u:g} n={n}: sphere {es:+.2e} cylinder {ec:+.2e}")
            assert abs(es) < 0.01 and abs(ec) < 0.01


# ---------------------------------------------------------------------------------------------
# 4. swapping base and target
# ---------------------------------------------------------------------------------------------
def test_swap_sphere_plane():
    u = 1e-5
    a = np.sqrt(2 * R_S * u)
    V, F, fp, fn = P.sphere_cap(R_S, 1.4 * a, 60, centre=(0, 0, R_S))
    sph = PCMBody(V, F, fp, fn)
    coarse_plane = PCMBody(*P.plate(2, 2, 0.05, 0.05, up=True))
    fine_plane = PCMBody(*P.plate(60, 60, 2.8 * a, 2.8 * a, up=True))
    r1 = evaluate_pair(sph, coarse_plane, at(-u), at(), pcm=PCM, friction=False, damping=False)
    r2 = evaluate_pair(fine_plane, sph, at(), at(-u), pcm=PCM, friction=False, damping=False)
    # force on the plane from both evaluations
    f1 = r1.force_target
    f2 = r2.force_base
    assert abs(f2[2] / f1[2] - 1.0) < 0.02
    assert abs(r2.contact_area / r1.contact_area - 1.0) < 0.05


def test_swap_two_spheres():
    """Two curved bodies: R1 = 10 mm, R2 = 25 mm, F = pi R_eff c u^2."""
    u = 1e-5
    R1, R2 = 0.010, 0.025
    Re = R1 * R2 / (R1 + R2)
    a = np.sqrt(2 * Re * u)
    s1 = PCMBody(*P.sphere_cap(R1, 1.4 * a, 60, centre=(0, 0, R1)))
    s2 = PCMBody(*P.sphere_cap(R2, 1.4 * a, 60, centre=(0, 0, -R2), lower=False))
    ref = np.pi * Re * C * u * u
    r12 = evaluate_pair(s1, s2, at(-u), at(), pcm=PCM, friction=False, damping=False)
    r21 = evaluate_pair(s2, s1, at(), at(-u), pcm=PCM, friction=False, damping=False)
    F12 = r12.force_target[2]          # on s2 (base s1): downwards
    F21 = r21.force_base[2]            # on s2 (base s2)
    print("two spheres: F12/ref", -F12 / ref, "F21/ref", -F21 / ref)
    assert abs(F21 / F12 - 1.0) < 0.02
    assert abs(-F12 / ref - 1.0) < 0.02


# ---------------------------------------------------------------------------------------------
# 5. energy: loading-unloading cycle without damping and friction
# ---------------------------------------------------------------------------------------------
def _work(base, target, path, target_moves=True):
    """Work done BY the contact on the moving body along the path (trapezoid rule)."""
    F = []
    E = []
    for p in path:
        if target_moves:
            r = evaluate_pair(base, target, at(), at(*p), pcm=PCM, friction=False, damping=False)
            F.append(r.force_target.copy())
        else:
            r = evaluate_pair(base, target, at(*p), at(), pcm=PCM, friction=False, damping=False)
            F.append(r.force_base.copy())
        E.append(r.elastic_energy)
    F = np.array(F)
    X = np.array([[p[1], p[2] if len(p) > 2 else 0.0, p[0]] for p in path])  # (x, y, z)
    dX = np.diff(X, axis=0)
    W = np.sum(0.5 * (F[1:] + F[:-1]) * dX)
    return W, np.array(E)


def test_energy_cycle_sphere_plane():
    """Plane base (fine), faceted sphere target: press in vertically, then release along an
    oblique path with lateral motion; the work returned equals the work taken, and the elastic
    energy equals the integral of F du."""
    u_max = 2e-5
    R = R_S
    a = np.sqrt(2 * R * u_max)
    V, F, fp, fn = P.sphere_cap(R, 1.6 * a, 48, centre=(0, 0, R))
    sph = PCMBody(V, F)            # facets: u continuous along any path
    plane = PCMBody(*P.plate(70, 70, 4.0 * a, 4.0 * a, up=True))
    n = 400
    z_in = np.linspace(1e-6, -u_max, n)                 # (z, x): load straight down
    load = [(z, 0.0) for z in z_in]
    s = np.linspace(0.0, 1.0, n)
    unload = [(-u_max + (u_max + 1e-6) * si, 0.3 * a * np.sin(np.pi * si / 2)) for si in s]
    W_load, E_load = _work(plane, sph, load)            # negative: contact resists
    W_unload, _ = _work(plane, sph, unload)
    W_in = -W_load
    W_out = W_unload
    print("W_in", W_in, "W_out", W_out, "rel", (W_in - W_out) / W_in, "E_peak", E_load[-1])
    assert W_in > 0
    assert abs(W_in - W_out) < 0.005 * W_in
    # elastic energy = integral of F du along the vertical loading
    assert abs(E_load[-1] / W_in - 1.0) < 0.005
    assert E_load[0] == 0.0


def test_energy_sphere_base():
    """Sphere base on a plane target: the energy integral matches up to O(u/R)."""
    u_max = 1e-5
    R = R_S
    a = np.sqrt(2 * R * u_max)
    V, F, fp, fn = P.sphere_cap(R, 1.4 * a, 48, centre=(0, 0, R))
    sph = PCMBody(V, F, fp, fn)
    plane = PCMBody(*P.plate(2, 2, 0.05, 0.05, up=True))
    z = np.linspace(1e-6, -u_max, 300)
    W, E = _work(sph, plane, [(zi, 0.0) for zi in z], target_moves=False)
    print("sphere base: E/W_in", E[-1] / -W)
    assert abs(E[-1] / -W - 1.0) < 0.005


# ---------------------------------------------------------------------------------------------
# 6. damping and friction
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("u", [1e-6, 2.5e-6, 5e-6, 2e-5])
@pytest.mark.parametrize("v", [1e-3, -1e-3, -0.5, 0.2])
def test_damping_closed_form(plates, u, v):
    """Target moves along -z with speed v (v > 0: approaching)."""
    base, target = plates
    A = 0.010 * 0.008
    r = evaluate_pair(base, target, at(), at(-u), None, (np.array([0.0, 0.0, -v]), Z3),
                      pcm=PCM, friction=True, damping=True)
    ramp = min(u / PCM.transformation_depth, 1.0)
    d = PCM.c_compression if v > 0 else PCM.c_expansion
    F_el = C * A * u
    F = max(F_el + d * A * v * ramp, 0.0)
    assert abs(r.force_target[2] - F) <= 1e-9 * max(F, F_el)
    P_expected = (F - F_el) * v
    assert r.dissipated_power >= 0.0
    assert abs(r.dissipated_power - P_expected) <= 1e-9 * max(abs(P_expected), F_el * abs(v))
    # no tangential motion -> no friction
    assert np.allclose(r.force_target[:2], 0.0, atol=1e-12 * max(F_el, 1.0))
    # the base moving along +z instead gives the same (relative velocity only)
    r2 = evaluate_pair(base, target, at(), at(-u), (np.array([0.0, 0.0, v]), Z3), None,
                       pcm=PCM, friction=True, damping=True)
    assert abs(r2.force_target[2] - F) <= 1e-9 * max(F, F_el)


def test_damping_off(plates):
    base, target = plates
    r = evaluate_pair(base, target, at(), at(-1e-5), None, (np.array([0, 0, -1.0]), Z3),
                      pcm=PCM, friction=False, damping=False)
    assert abs(r.force_target[2] / (C * 0.010 * 0.008 * 1e-5) - 1) < 1e-9
    assert r.dissipated_power == 0.0


@pytest.mark.parametrize("vs", [0.2e-3, 0.5e-3, 3e-3, 1.0])
@pytest.mark.parametrize("direction", [(1.0, 0.0), (0.6, -0.8)])
def test_friction(plates, vs, direction):
    """Target slides over the base with speed vs: friction on it opposes the sliding with
    magnitude mu F_n clip(vs/v_f, 0, 1); the base gets the opposite."""
    base, target = plates
    u = 1e-5
    dvec = np.array([direction[0], direction[1], 0.0])
    r = evaluate_pair(base, target, at(), at(-u), None, (vs * dvec, Z3), pcm=PCM,
                      friction=True, damping=True)
    Fn = C * 0.010 * 0.008 * u
    ft = PCM.mu * Fn * min(vs / PCM.v_friction, 1.0)
    assert abs(r.force_target[2] / Fn - 1.0) < 1e-9
    assert np.allclose(r.force_target[:2], -ft * dvec[:2], rtol=1e-9, atol=1e-12 * Fn)
    assert np.allclose(r.force_base, -r.force_target, rtol=0, atol=1e-12 * Fn)
    assert abs(r.dissipated_power - ft * vs) <= 1e-9 * ft * vs
    # per-element friction opposes the sliding of the target
    assert np.all(r.F_t @ dvec < 0.0)
    # friction off
    r0 = evaluate_pair(base, target, at(), at(-u), None, (vs * dvec, Z3), pcm=PCM,
                       friction=False, damping=True)
    assert np.allclose(r0.force_target[:2], 0.0, atol=1e-12 * Fn)
