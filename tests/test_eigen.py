"""Natural frequencies (drivetrain.eigen): the public model as an independent oracle, the calibrated
24 Hz, and a simulated ring-down of the assembled components against the eigenvalue."""
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import eigh

from drivetrain import eigen, rig
from drivetrain.assemble import assemble
from drivetrain.scenario import default_scene

sys.path.insert(0, str(Path(__file__).parent))
ROOT = Path(__file__).resolve().parents[1]


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


@pytest.mark.parametrize("shafts", ["flexible", "rigid"])
def test_ringdown_matches_eigenfrequency(shafts):
    """Mesh excitation off (ideal gear), losses and controller off, the assembled components stepped
    by a Jacobi loop at H = 1/12000 s from the real part of the first complex mode: the fitted
    ring-down frequency agrees with the eigenvalue within 3 % (in practice < 1.5 %)."""
    from _drivetrain_loop import Loop, fit_damped_sine, set_state_from_vector

    sc = default_scene(effects__shaft_flexibility=shafts, effects__mesh_contact="ideal", effects__losses=False,
                       operating_point__drive_speed_rpm=0.0, operating_point__load_torque_Nm=0.0)
    spec = assemble(sc)
    f_un = eigen.natural_frequencies(spec)[0]
    lam, psi, ls = eigen.damped_modes(spec)
    f_d = lam[0].imag / (2 * math.pi)
    zeta = -lam[0].real / abs(lam[0])
    loop = Loop(spec, {"motors": {"Kp": 1e-12, "Ti": 1e12}})
    n = ls.M.shape[0]
    z0 = np.real(psi[:, 0])
    z0 = 0.01 * z0 / np.max(np.abs(z0[:n]))
    set_state_from_vector(loop, ls.labels, z0[:n], z0[n:])
    sensor = spec.metadata["sensors"]["drive_shaft_torque"]
    t, r = loop.run(0.25, [sensor, "motors.flywheel_w"])
    for name, y in r.items():
        f_fit, z_fit, res = fit_damped_sine(t, y, f_d)
        assert res < 0.02, name
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
