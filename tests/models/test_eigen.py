"""Natural frequencies (drivetrain.models.eigen): the public model as an independent oracle, the calibrated
24 Hz, and a simulated ring-down of the assembled components against the eigenvalue."""
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import eigh

from drivetrain.models import eigen

from drivetrain.rig import data as rig
from drivetrain.run.assemble import assemble
from drivetrain.scene.load import default_scene

ROOT = Path(__file__).resolve().parents[2]


def test_unlumped_public_model_reproduces_published_frequencies():
    M, K, _ = rig.public_matrices()
    w2 = eigh(K, M, eigvals_only=True)
    f = np.sqrt(np.abs(w2)) / (2 * np.pi)
    assert f[0] < 1e-3                                          # rigid-body mode
    np.testing.assert_allclose(f[1:4], [27.9, 39.6, 68.2], atol=0.06)
    np.testing.assert_allclose(f[4:7], [300.0, 572.0, 938.0], rtol=0.005)


def test_lowest_mode_is_24_Hz():
    spec = assemble(default_scene())
    f = eigen.natural_frequencies(spec)
    assert f[0] == pytest.approx(24.0, rel=0.05)
    assert f[0] == pytest.approx(24.0, abs=0.05)                # calibrated, not just within 5 %
    # the in-band modes of the flexible default: couplings, gearbox/load, middle shaft, drive shaft
    assert 30 < f[1] < 40 and 60 < f[2] < 80 and 250 < f[3] < 400 and 450 < f[4] < 700
    with pytest.raises(TypeError, match="assemble"):
        eigen.natural_frequencies(default_scene())                                   # a Scene is assembled first


def test_referred_and_local_frames_agree():
    """K, M referred to the drive shaft (J R^2, k R^2) give the same frequencies as the local frames."""
    spec = assemble(default_scene(effects__mesh_contact="analytic"))
    ls = eigen.assemble_linear(spec, operating=False)
    assert not np.any(np.isnan(ls.R))
    T = np.diag(1.0 / ls.R)                 # theta_local = theta_ref / R
    Mr, Kr = T @ ls.M @ T, T @ ls.K @ T
    f_ref = np.sqrt(np.abs(eigh(Kr, Mr, eigvals_only=True))) / (2 * np.pi)
    f_loc = np.sqrt(np.abs(eigh(ls.K, ls.M, eigvals_only=True))) / (2 * np.pi)
    np.testing.assert_allclose(f_ref, f_loc, rtol=1e-7, atol=1e-3)
    r = {lbl: R for lbl, R in zip(ls.labels, ls.R)}
    assert r["upper.n0"] == pytest.approx(1.0)
    assert r["gear.pinion"] == pytest.approx(1 / 3) and r["gear.wheel"] == pytest.approx(1 / 12)
    assert r["motors.load"] == pytest.approx(1 / 12)


def test_gear_rigid_vs_mesh_changes_low_modes_little():
    spec = assemble(default_scene())
    f_mesh = eigen.natural_frequencies(spec, gear="analytic")
    f_rig = eigen.natural_frequencies(spec, gear="rigid")
    np.testing.assert_allclose(f_mesh[:5], f_rig[:5], rtol=0.01)


def _fit_damped_sine(t, y, f0):
    """Least-squares fit y = c + A exp(-s t) cos(2 pi f t + p); returns (f, zeta, fit residual rms / A)."""
    from scipy.optimize import curve_fit

    y = np.asarray(y, dtype=float)
    c0 = float(np.mean(y[-len(y) // 4:]))
    A0 = float(np.max(np.abs(y - c0)))

    def model(tt, c, A, s, f, p):
        return c + A * np.exp(-s * tt) * np.cos(2 * np.pi * f * tt + p)

    best = None
    for p0 in (0.0, np.pi / 2, np.pi, -np.pi / 2):
        try:
            popt, _ = curve_fit(model, t, y, p0=[c0, A0, 1.0, f0, p0], maxfev=20000)
        except RuntimeError:
            continue
        r = float(np.sqrt(np.mean((model(t, *popt) - y) ** 2)))
        if best is None or r < best[1]:
            best = (popt, r)
    popt, r = best
    c, A, s, f, p = popt
    wd = 2 * np.pi * abs(f)
    zeta = s / np.sqrt(s * s + wd * wd)
    return abs(f), float(zeta), r / abs(A)


def _start_from_vector(spec, labels, x, v):
    """Set the spec's start parameters so that every node starts at x (angles) and v (speeds) over ``labels``
    ("component.node", drivetrain.models.eigen): node_phi_start / node_w_start of the line models, and the gear's
    initial_state "parameters" (the ideal gear's one body "pinion+wheel" in the pinion frame, the wheel at
    pinion / ratio) with the port twists from the bodies' angles on both sides (as
    drivetrain.run.assemble.gear_start_state: the connected component built from its parameters, read back)."""
    from drivetrain.models.components import COMPONENTS, make_component
    from gearcontact_fmu.params import BevelGearParams

    idx = {lbl: i for i, lbl in enumerate(labels)}
    by_name = {c.name: c for c in spec.components}
    for c in spec.components:
        if c.model not in COMPONENTS:
            continue
        nodes = make_component(c.model, c.parameters).line.node_names
        c.parameters["node_phi_start"] = ", ".join(repr(float(x[idx[f"{c.name}.{n}"]])) for n in nodes)
        c.parameters["node_w_start"] = ", ".join(repr(float(v[idx[f"{c.name}.{n}"]])) for n in nodes)
    for g in spec.components:
        if g.model != "GearContact":
            continue
        p = g.parameters
        if f"{g.name}.pinion+wheel" in idx:
            ratio = float(p.get("z_wheel", BevelGearParams.z_wheel)) / float(p.get("z_pinion", BevelGearParams.z_pinion))
            j = idx[f"{g.name}.pinion+wheel"]
            start = {"pinion": (x[j], v[j]), "wheel": (x[j] / ratio, v[j] / ratio)}
        else:
            start = {b: (x[idx[f"{g.name}.{b}"]], v[idx[f"{g.name}.{b}"]]) for b in ("pinion", "wheel")}
        p["initial_state"] = "parameters"
        for body, flange in (("pinion", "flange_a"), ("wheel", "flange_b")):
            conn = next(cn for cn in spec.connections if cn.spring == f"{g.name}.{flange}")
            comp, port = conn.inertia.split(".", 1)
            out = make_component(by_name[comp].model, by_name[comp].parameters).outputs(energy=False)
            p[f"{body}_phi_start"], p[f"{body}_w_start"] = float(start[body][0]), float(start[body][1])
            p[f"twist_{flange[-1]}_start"] = float(start[body][0]) - float(out[f"{port}_phi"])


@pytest.mark.parametrize("shafts", ["flexible", "rigid"])
def test_ringdown_matches_eigenfrequency(shafts, fmu_dir):
    """Mesh excitation off (ideal gear), losses and controller off, the assembled components run through
    the master (in-process backend) at H = 1/12000 s from the real part of the first complex mode (the
    node start parameters node_phi_start / node_w_start and the gear's start parameters): the fitted
    ring-down frequency agrees with the eigenvalue within 3 % (in practice < 1.5 %)."""
    from drivetrain.cosim import simulate

    sc = default_scene(effects__shaft_flexibility=shafts, effects__mesh_contact="ideal", effects__losses=False,
                       operating_point__drive_speed_rpm=0.0, operating_point__load_torque_Nm=0.0)
    spec = assemble(sc)
    f_un = eigen.natural_frequencies(spec)[0]
    lam, psi, ls = eigen.damped_modes(spec)
    f_d = lam[0].imag / (2 * math.pi)
    zeta = -lam[0].real / abs(lam[0])
    spec.components[[c.name for c in spec.components].index("motors")].parameters.update(Kp=1e-12, Ti=1e12)
    n = ls.M.shape[0]
    z0 = np.real(psi[:, 0])
    z0 = 0.01 * z0 / np.max(np.abs(z0[:n]))
    _start_from_vector(spec, ls.labels, z0[:n], z0[n:])
    sensor = spec.metadata["sensors"]["drive_shaft_torque"]
    names = [sensor, "motors.flywheel_w"]
    res = simulate(spec, 0.25, round(1.0 / spec.comm_step), names, backend="inprocess", fmu_dir=fmu_dir,
                   keep_raw=True, progress=False)
    t = res.raw["time"]
    for name in names:
        f_fit, z_fit, res_rel = _fit_damped_sine(t, res.raw[name], f_d)
        assert res_rel < 0.02, name
        assert f_fit == pytest.approx(f_d, rel=0.03), name
        assert f_fit == pytest.approx(f_un, rel=0.03), name
        assert z_fit == pytest.approx(zeta, rel=0.15), name


def test_eigen_command_prints_modes_and_cuts(capsys):
    from drivetrain.cli import main

    rc = main(["eigen", str(ROOT / "scenarios" / "example.toml")])
    text = capsys.readouterr().out
    assert rc == 0
    assert "natural frequencies of example" in text
    assert "24.0" in text
    assert "whole co-simulated system" in text and "stable" in text


def test_eigen_command_refuses_a_bad_scene(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[effects]\nshaft_flexibility = 'bendy'\n")
    from drivetrain.cli import main

    assert main(["eigen", str(bad)]) == 2
