"""Component physics (drivetrain.models.components): shaft twist, PI controller, planetary, energy balance."""
import math

import numpy as np
import pytest

from drivetrain.errors import ComponentError
from drivetrain.models import components as C
from drivetrain.models import motors, parameters
from drivetrain.models.components import make_component
from drivetrain.models.line import loss_torque
from drivetrain.models.motors import MotorLoad, MotorLoadParams
from drivetrain.models.shaft import FlexibleShaft, FlexibleShaftParams
from drivetrain.models.transmission import UpperTransmission, UpperTransmissionParams
from _line_energy import step_energy_residual

H = 1.0 / 12000.0
G, RHO = 79.3e9, 7850.0


def shaft_geometry(d=0.015, L=0.3):
    Ip = math.pi * d ** 4 / 32.0
    return Ip, G * Ip / L, RHO * Ip * L


@pytest.mark.parametrize("n,mass", [(1, 0), (4, 0), (16, 1)])
def test_shaft_static_twist(n, mass):
    """A torque T at flange_a with flange_b held: the twist across the shaft is T L / (G I_p)."""
    d, L, T = 0.015, 0.3, 2.0
    Ip, k, J = shaft_geometry(d, L)
    p = FlexibleShaftParams(J_a=1e-4, k_t=0.0, d_t=0.0, J_b=1e-4, k_c=0.0, d_c=0.0, k_shaft=k, d_shaft=0.05,
                            J_shaft=J, n_elements=n, mass_model=mass, max_substep=1e-5)
    fs = FlexibleShaft(p)
    for i in range(6000):
        fs.set_inputs(T, 0.0, 0.0)
        fs.step(i * H, H)
    out = fs.outputs()
    twist = out["flange_a_phi"] - 0.0
    assert twist == pytest.approx(T * L / (G * Ip), rel=1e-6)
    assert out["flange_b_tau"] == pytest.approx(T, rel=1e-6)        # the shaft passes the torque on
    assert out["shaft_torque"] == pytest.approx(T, rel=1e-6)
    assert fs.compliance_to_port() == pytest.approx(L / (G * Ip), rel=1e-12)


def test_shaft_transducer_torque_and_twist_with_couplings():
    fs = make_component("FlexibleShaft", {"n_elements": 4})
    p = fs.p
    T = 1.5
    for i in range(8000):
        fs.set_inputs(T, 0.0, 0.0)
        fs.step(i * H, H)
    out = fs.outputs()
    assert out["torque_sensor"] == pytest.approx(T, rel=1e-6)
    expect = T * (1 / p.k_t + 1 / p.k_c + 1 / p.k_shaft)
    assert out["flange_a_phi"] == pytest.approx(expect, rel=1e-6)


def test_shaft_element_count_changes_only_high_modes():
    """The line clamped at flange_b: its in-band mode (hubs on the thin shaft, ~490 Hz) hardly moves
    with the element count; the next one (transducer between the hubs) is above the 1.5 kHz band."""
    from drivetrain.models.eigen import component_block
    from scipy.linalg import eigh

    freqs = []
    for n in (1, 4, 16):
        b = component_block("s", "FlexibleShaft", {"n_elements": n}, operating=False)
        K = b.K.copy()
        pb = b.port("flange_b")
        K[pb.node, pb.node] += pb.k
        w2 = eigh(K, b.M, eigvals_only=True)
        freqs.append(np.sqrt(w2) / (2 * np.pi))
    f1 = [f[0] for f in freqs]
    assert 300.0 < f1[0] < 1500.0
    assert abs(f1[2] / f1[0] - 1) < 0.005
    assert min(f[1] for f in freqs) > 1500.0


def _motor_only(**kw):
    """MotorLoad with the drive flange free (no port spring): motor + C1 + flywheel."""
    p = dict(k_c2=0.0, d_c2=0.0, c_motor=0.0, max_substep=1e-5)
    p.update(kw)
    return MotorLoad(parameters.params_from(MotorLoadParams, p))


def _speed_step(ref_rpm, tau_max, Ni=0.9, T=4.0):
    m = _motor_only(tau_max=tau_max, Ni=Ni)
    Ts, ws = [], []
    for i in range(int(T / H)):
        m.set_inputs(0.0, 0.0, 0.0, speed_ref_rpm=ref_rpm, load_torque=0.0)
        m.step(i * H, H)
        o = m.outputs()
        Ts.append(o["motor_torque"])
        ws.append(o["motor_w"])
    return np.array(Ts), np.array(ws), m


def test_pi_reaches_reference_and_respects_torque_limit():
    ref = 600.0
    T, w, m = _speed_step(ref, tau_max=1.0)
    assert np.max(np.abs(T)) <= 1.0 + 1e-9                            # the torque limit holds
    assert np.mean(T[: int(0.1 / H)]) == pytest.approx(1.0, rel=1e-6)  # saturated at the start
    assert w[-1] == pytest.approx(ref * motors.RPM, rel=1e-4)               # reaches the reference


def test_anti_windup_limits_overshoot():
    """After a long saturation the back-calculation anti-windup (Ni = 0.9, as Modelica LimPID) keeps
    the overshoot below that of the unsaturated linear loop; without it (Ni huge) it winds up."""
    ref = 500.0
    _, w_lin, _ = _speed_step(10.0, tau_max=10.0)          # small step: the linear PI response
    lin = w_lin.max() / (10.0 * motors.RPM) - 1.0
    _, w_aw, _ = _speed_step(ref, tau_max=0.5)
    _, w_no, _ = _speed_step(ref, tau_max=0.5, Ni=1e9)
    aw = w_aw.max() / (ref * motors.RPM) - 1.0
    no = w_no.max() / (ref * motors.RPM) - 1.0
    assert aw <= lin + 1e-3
    assert no > 3.0 * lin


def test_speed_profile_parameter_ramps():
    m = _motor_only(speed_profile="0:0; 1:600", Kp=0.2, Ti=0.05, tau_max=5.0)
    for i in range(int(1.5 / H)):
        m.set_inputs(0.0, 0.0, 0.0, load_torque=0.0)
        m.step(i * H, H)
        if abs(i * H - 0.5) < H / 2:
            assert m.outputs()["motor_w"] == pytest.approx(300 * motors.RPM, rel=0.05)
    assert m.outputs()["motor_w"] == pytest.approx(600 * motors.RPM, rel=1e-3)


def test_planetary_ratio_and_energy():
    """Load side driven by a constant torque at the propeller flange: steady speed where the torque
    equals 8 T_set + the planetary loss; load motor at 8x the propeller speed; power balance."""
    T_set, tau_in = 1.0, 12.0
    m = make_component("MotorLoad", {"max_substep": 1e-5, "k_c2": 0.0, "d_c2": 0.0})
    p = m.p
    e0 = m.line.energy.copy()
    for i in range(int(6.0 / H)):
        m.set_inputs(0.0, 0.0, tau_in, speed_ref_rpm=0.0, load_torque=T_set)
        m.step(i * H, H)
    o = m.outputs()
    w = o["load_w"]
    pg = loss_torque(w, p.ratio_pg * T_set, p.pg_c, p.pg_Tc, p.pg_wc, p.pg_a)
    assert tau_in == pytest.approx(p.ratio_pg * T_set * math.tanh(w / p.load_w_reg) + pg, rel=1e-6)
    assert o["load_motor_w"] == pytest.approx(p.ratio_pg * w, rel=1e-12)
    assert o["load_motor_torque"] == pytest.approx(T_set, rel=1e-6)
    # over one more step at steady state: work in = load motor work + planetary dissipation
    E_diss0, E_sup0 = m.line.energy_dissipated, m.line.energy_supplied
    m.step(6.0, H)
    d_diss = m.line.energy_dissipated - E_diss0
    d_sup = m.line.energy_supplied - E_sup0
    assert -d_sup == pytest.approx(T_set * p.ratio_pg * w * H, rel=1e-6)   # the load motor absorbs
    assert d_diss == pytest.approx(pg * w * H, rel=1e-5)
    assert e0[0] == 0.0


def _random_drive(comp, rng, t, Hs):
    m = comp.model
    if m == "FlexibleShaft":
        comp.set_inputs(rng.normal(2, 1), 0.3 * math.sin(40 * t) + 150 * t, 150 + 10 * rng.normal())
    elif m == "UpperTransmission":
        comp.set_inputs(rng.normal(2, 1), rng.normal(-5, 1))
    else:
        comp.set_inputs(0.2 * math.sin(30 * t) + 150 * t, 150 + 5 * rng.normal(), rng.normal(10, 2),
                        speed_ref_rpm=1400.0, load_torque=1.0)


@pytest.mark.parametrize("model", ["FlexibleShaft", "UpperTransmission", "MotorLoad"])
def test_energy_balance_every_step(model):
    """supplied = delta stored + dissipated + work out through the ports, every step (round-off)."""
    comp = make_component(model, {"w0": 150.0, "max_substep": 2e-5} if model != "MotorLoad"
                          else {"w0": 150.0, "w0_load": 12.5, "max_substep": 2e-5})
    rng = np.random.default_rng(1)
    t = 0.0
    worst = 0.0
    _random_drive(comp, rng, t, H)
    for k in range(400):
        _random_drive(comp, rng, t, H)
        res, scale = step_energy_residual(comp, t, H)
        t += H
        worst = max(worst, abs(res) / scale)
    assert worst < 1e-9


def test_upper_transmission_ratio_and_steady_loss():
    p = parameters.params_from(UpperTransmissionParams, {"max_substep": 1e-5, "w0": 100.0})
    ut = UpperTransmission(p)
    T_out = 3.0            # middle-shaft torque the gear takes (on the UT output: -3 N m)
    for i in range(int(2.0 / H)):
        w = ut.line.om[0]
        T_loss = loss_torque(100.0, T_out / p.ratio, p.loss_c, p.loss_Tc, p.loss_wc, p.loss_a)
        ut.set_inputs(T_out / p.ratio + float(T_loss), -T_out)
        ut.step(i * H, H)
    o = ut.outputs()
    assert o["flange_a_w"] == pytest.approx(100.0, rel=1e-6)
    assert o["flange_b_w"] == pytest.approx(100.0 / 3.0, rel=1e-6)
    assert o["flange_b_phi"] == pytest.approx(o["flange_a_phi"] / 3.0, rel=1e-12)


def test_nan_input_is_an_error_not_a_crash():
    for model in ("FlexibleShaft", "UpperTransmission", "MotorLoad"):
        comp = make_component(model, {"max_substep": 1e-5})
        comp.line.p_u0[0] = float("nan")
        with pytest.raises(ComponentError, match="non-finite input"):
            comp.line.step(0.0, H)


def test_invalid_parameters_refused():
    with pytest.raises(ValueError):
        make_component("FlexibleShaft", {"n_elements": 0})
    with pytest.raises(ValueError):
        make_component("MotorLoad", {"load_mode": 3})
    with pytest.raises(ValueError, match="unknown parameters"):
        make_component("UpperTransmission", {"J_inn": 1.0})


def test_loss_law_is_dissipative_and_odd():
    w = np.linspace(-200, 200, 401)
    T = loss_torque(w, 1.3, 1e-3, 0.3, 16.0, 0.06)
    assert np.all(T * w >= 0)
    assert np.allclose(T, -loss_torque(-w, 1.3, 1e-3, 0.3, 16.0, 0.06))


def test_set_inputs_takes_the_fmu_inputs_in_order():
    """The FMU shell hands a component its inputs positionally, in ``fmishell.port_inputs`` order: each
    component's ``set_inputs`` must name them in that order (a swapped pair would pass a torque as an
    angle)."""
    import inspect

    from drivetrain.models import fmishell
    from drivetrain.models.components import COMPONENTS

    for model, (cls, _) in COMPONENTS.items():
        names = list(inspect.signature(cls.set_inputs).parameters)[1:]
        assert names == fmishell.port_inputs(model), model


def test_every_parameter_is_declared_once_with_unit_and_description():
    """A component's parameter field carries its unit and description (the FMU's modelDescription reads
    them from there); a Real parameter has a unit, an Integer or String one none."""
    import dataclasses

    from drivetrain.models import fmishell

    for model, (_, pcls) in C.COMPONENTS.items():
        defaults = pcls()
        for f in dataclasses.fields(pcls):
            assert parameters.parameter_description(f), f"{model}.{f.name}: no description"
            value = getattr(defaults, f.name)
            unit = parameters.parameter_unit(f)
            if isinstance(value, float):
                assert unit, f"{model}.{f.name}: a Real parameter without a unit"
            else:
                assert unit is None, f"{model}.{f.name}: {type(value).__name__} parameter with unit {unit}"
            assert fmishell.variable_descriptions(model)[f.name] == parameters.parameter_description(f)


def test_step_outputs_and_lazy_outputs_cover_every_output_once():
    """The shell publishes the step outputs after every step and computes LAZY_OUTPUTS when read: together
    they are the FMU's outputs (but the flange torques a spring side returns are among the step's)."""
    from drivetrain.models import fmishell

    for model, (cls, pcls) in C.COMPONENTS.items():
        outputs = set(fmishell.port_outputs(model))
        comp = cls(pcls())
        step = comp.step_outputs()
        lazy = outputs - set(step)
        assert lazy <= set(fmishell.LAZY_OUTPUTS), f"{model}: {sorted(lazy)} published by nobody"
        assert set(step) <= outputs
        assert set(comp.outputs()) == outputs, model
        assert all(type(v) is float for v in step.values()), model


@pytest.mark.parametrize("model", ["FlexibleShaft", "UpperTransmission", "MotorLoad"])
def test_node_start_parameters(model):
    """node_phi_start / node_w_start: the start state asked, node by node (the other start parameters still
    set the rest: the PI integrator, the initial sensor torques); the default start written out as node
    values steps bit for bit like the default (empty) start."""
    base = {"w0": 150.0, "tau0": 0.4, "phi0": 0.3} if model != "MotorLoad" else {
        "w0": 150.0, "w0_load": 12.5, "tau0": 0.4, "phi0_motor": 0.3, "phi0_load": -0.1}
    if model == "UpperTransmission":
        del base["tau0"]
    ref = make_component(model, base)
    n = ref.line.n
    phi = np.linspace(0.5, -0.25, n)
    w = np.linspace(-3.0, 7.0, n)
    comp = make_component(model, {**base, "node_phi_start": ", ".join(map(repr, phi.tolist())),
                                  "node_w_start": ",".join(map(repr, w.tolist()))})
    assert comp.line.th.tolist() == phi.tolist() and comp.line.om.tolist() == w.tolist()
    assert comp.line.pi_x[0] == ref.line.pi_x[0]
    only_w = make_component(model, {**base, "node_w_start": ",".join(map(repr, w.tolist()))})
    assert only_w.line.th.tolist() == ref.line.th.tolist() and only_w.line.om.tolist() == w.tolist()
    # the default start, written out: the same steps bit for bit
    same = make_component(model, {**base, "node_phi_start": ", ".join(map(repr, ref.line.th.tolist())),
                                  "node_w_start": ", ".join(map(repr, ref.line.om.tolist()))})
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    for k in range(50):
        _random_drive(ref, rng_a, k * H, H)
        _random_drive(same, rng_b, k * H, H)
        ref.step(k * H, H)
        same.step(k * H, H)
    assert ref.outputs() == same.outputs()


def test_node_start_errors_name_the_parameter_the_count_and_the_nodes():
    with pytest.raises(ValueError, match=r"^node_phi_start: got 2 values, expected 3 comma-separated values, one "
                                         r"per node \(motor, flywheel, load\)$"):
        make_component("MotorLoad", {"node_phi_start": "1, 2"})
    with pytest.raises(ValueError, match=r"^node_w_start: value 1 of 1 \('fast'\) is not a finite number; expected 1 "
                                         r"comma-separated values, one per node \(n0\)$"):
        make_component("UpperTransmission", {"node_w_start": "fast"})
    for bad in ("inf, 0, 0, 0, 0, 0", "0, 0, 0, 0, 0, ", "0;0;0;0;0;0"):
        with pytest.raises(ValueError, match=r"node_phi_start: .*\(hub_a, hub_b, shaft_0, shaft_1, shaft_2, shaft_3\)"):
            make_component("FlexibleShaft", {"node_phi_start": bad})
    assert make_component("MotorLoad", {"node_phi_start": "  "}).node_phi_start is None     # blank = empty
