"""Lumping and partition of the public model (drivetrain.rig.data), and the stability check of every cut."""
import dataclasses
import math

import numpy as np
import pytest

from drivetrain.rig import data as rig

from drivetrain.models import stability
from drivetrain.run.assemble import assemble
from drivetrain.scene.load import default_scene

H12 = 1.0 / 12000.0


def test_public_model_and_data_are_packaged():
    m = rig.load_public()
    assert len(m.J) == 22 and len(m.k) == 21
    assert m.R[11] == 1.0 and m.R[12] == pytest.approx(1 / 3) and m.R[-1] == pytest.approx(1 / 12)
    assert rig.MEASURED_CSV.is_file() and rig.CALIBRATION_JSON.is_file()


@pytest.mark.parametrize("shafts,n", [("flexible", 1), ("flexible", 4), ("flexible", 16), ("rigid", 4)])
def test_total_inertia_is_conserved_and_no_tiny_bodies(shafts, n):
    """Lumping moves inertia, it never loses any: the drive-referred total equals the public model's.
    Every body left (outside the discretised shaft) is >= 1e-5 kg m^2."""
    m = rig.load_public()
    total = float(np.sum(m.J * m.R ** 2))
    part = rig.partition(shafts, n)
    P = part.params
    s = P["motors"]["J_motor"] + P["motors"]["J_flywheel"] + P["motors"]["J_load"] / 144.0
    s += P["upper"]["J_in"] + P["upper"]["J_out"] / 9.0
    s += P["gear"]["J_pinion"] / 9.0 + P["gear"]["J_wheel"] / 144.0
    bodies = [P["motors"]["J_motor"], P["motors"]["J_flywheel"], P["motors"]["J_load"], P["upper"]["J_in"],
              P["gear"]["J_pinion"], P["gear"]["J_wheel"]]          # own frames
    if shafts == "flexible":
        d = P["drive_shaft"]
        s += d["J_a"] + d["J_b"] + d["J_shaft"] - d["J_shaft"] / (2 * n)   # the end half is in J_in
        bodies += [d["J_a"], d["J_b"]]
    assert s == pytest.approx(total, rel=1e-12)
    assert min(bodies) >= rig.TINY_J


def test_couplings_stay_compliant_in_both_partitions():
    for shafts in ("flexible", "rigid"):
        P = rig.partition(shafts, 4).params["motors"]
        s = rig.load_calibration()["coupling_scale"]
        assert P["k_c1"] == pytest.approx(1 / (1 / 190000 + 1 / 6950 + 2 / (90 * s)), rel=1e-9)
        assert P["k_c2"] == pytest.approx(s / (2 / 90 + 1 / 90.39), rel=1e-9)
        assert P["k_c1"] < 100 and P["k_c2"] < 100


@pytest.mark.parametrize("shafts,n,fid", [("flexible", 1, "table"), ("flexible", 4, "table"),
                                          ("flexible", 64, "ideal"), ("rigid", 4, "table"),
                                          ("rigid", 4, "ideal")])
def test_every_cut_is_stable_at_the_default_step(shafts, n, fid):
    sc = default_scene(effects__shaft_flexibility=shafts, effects__shaft_elements=n, effects__mesh_contact=fid)
    spec = assemble(sc)                     # raises if any cut is unstable
    assert spec.comm_step == pytest.approx(H12)
    cuts = spec.metadata["cuts"]
    assert len(cuts) == (4 if shafts == "flexible" else 3)
    assert all(c["stable"] and c["radius"] < 1.0 for c in cuts)
    assert spec.metadata["cosim_spectral_radius"] < 1.0
    names = {c["spring"] for c in cuts}
    assert {"motors.drive", "gear.flange_a", "gear.flange_b"} <= names


def test_partition_models_and_causality():
    spec = assemble(default_scene())
    assert [c.model for c in spec.components] == ["MotorLoad", "FlexibleShaft", "UpperTransmission", "GearContact"]
    conns = {(c.spring, c.inertia) for c in spec.connections}
    assert conns == {("motors.drive", "drive_shaft.flange_a"), ("drive_shaft.flange_b", "upper.flange_a"),
                     ("gear.flange_a", "upper.flange_b"), ("gear.flange_b", "motors.load")}
    rigid = assemble(default_scene(effects__shaft_flexibility="rigid", effects__mesh_contact="ideal"))
    assert [c.model for c in rigid.components] == ["MotorLoad", "UpperTransmission", "GearContact"]
    gear = rigid.components[-1].parameters
    assert gear["fidelity"] == "ideal"          # no contact engine: the rigid ratio


def test_stiff_cut_is_refused_with_the_numbers():
    spec = assemble(default_scene(effects__mesh_contact="ideal"))
    for c in spec.components:
        if c.name == "gear":
            c.parameters["k_a"] = 5e6
    with pytest.raises(stability.UnstableCutError) as ei:
        stability.check_cuts(spec)
    msg = str(ei.value)
    assert "gear.flange_a -> upper.flange_b" in msg
    assert "omega_if*H" in msg and "spectral radius" in msg and "UNSTABLE" in msg


def test_assembler_refuses_a_too_large_step():
    from drivetrain.cosim import ConfigurationError

    sc = default_scene(effects__shaft_flexibility="rigid", time__sample_rate_Hz=1000.0,
                       numerics__comm_step_s=1e-3)
    with pytest.raises(ConfigurationError, match="unstable|spectral radius"):
        assemble(sc)


def test_two_body_limits_match_the_notes():
    """Equal inertias, zeta = 0.05, step-mean torque: the limit is omega H ~ 0.2 (notes: a plain cut
    needs omega H / 4 < zeta); a heavy inertia side is stable far beyond."""
    J = 1e-4
    H = 1e-4

    def radius(wH, ratio, zeta=0.05):
        Jb = ratio * J
        w = wH / H
        k = w * w / (1 / J + 1 / Jb)
        d = 2 * zeta * math.sqrt(k / (1 / J + 1 / Jb))
        return stability.two_body_radius(J, Jb, k, d, H, "mean")

    assert radius(0.15, 1.0) < 1.0
    assert radius(0.3, 1.0) > 1.0
    assert radius(3.0, 300.0) < 1.0


def test_whole_system_check_predicts_divergence(fmu_dir):
    """The one-step map of the linearised co-simulation says 1/3000 s is stable and 1/2000 s is not
    for the rigid-shaft system; running it through the master (in-process backend) confirms both: a
    diverging run either fails (CosimError, the completed part in ``partial``) or its step-to-step change
    grows. The master starts the assembled system at its steady state (round-off alone needs > 0.3 s to
    show the divergence), so the upper gearbox starts 1 mrad off it (node_phi_start): the transient
    decays when stable and grows when not."""
    from drivetrain.cosim import CosimError, simulate

    for inv, stable in ((3000, True), (2000, False)):
        sc = default_scene(effects__shaft_flexibility="rigid", effects__mesh_contact="ideal",
                           time__sample_rate_Hz=float(inv), numerics__comm_step_s=1.0 / inv)
        spec = assemble(sc, check=False)
        _, rho = stability.check_cuts(spec, raise_on_unstable=False)
        assert (rho < 1.0) == stable
        upper = next(c for c in spec.components if c.name == "upper")
        upper.parameters["node_phi_start"] = repr(float(upper.parameters.get("phi0", 0.0)) + 1e-3)
        try:
            res = simulate(spec, 0.3, float(inv), ["gear.flange_a_tau"], backend="inprocess",
                           fmu_dir=fmu_dir, keep_raw=True, progress=False)
            dy = np.abs(np.diff(res.raw["gear.flange_a_tau"]))
            grew = dy[len(dy) // 2:].max() > 10 * dy[: len(dy) // 2].max()
        except CosimError as exc:
            grew = True
            assert exc.partial is None or exc.partial.status == "failed"
        assert grew == (not stable)


def test_steady_state_balance():
    part = rig.partition("flexible", 4)
    ss = rig.steady_state(1500.0, 1.31, part.params["upper"], part.params["motors"])
    assert ss.w_prop == pytest.approx(ss.w_drive / 12)
    assert ss.T_msh == pytest.approx(ss.T_psh / 4)
    assert ss.T_psh > 8 * 1.31 and ss.T_dsh > ss.T_psh / 12
    # power: drive-shaft power = propeller-shaft power + the upper gearbox loss power
    up = part.params["upper"]
    loss = rig.loss(ss.w_drive, ss.T_msh / 3, {"c_v": up["loss_c"], "T_c": up["loss_Tc"], "w_c": up["loss_wc"],
                                               "a": up["loss_a"]})
    assert ss.T_dsh * ss.w_drive == pytest.approx(ss.T_psh * ss.w_prop + loss * ss.w_drive)
