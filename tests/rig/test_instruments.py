"""The rig's instruments against their own definitions measured back: the encoder's count step and
error, the transducer's -3 dB bandwidth and its noise floor from a long constant signal; seeds; and a
run with rig sensors whose ideal twin stays bit-identical."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal as sig

from drivetrain.rig.instruments import RIG_SAMPLE_RATE_HZ, Instruments, encoder, measure, torque_transducer

FS = RIG_SAMPLE_RATE_HZ


def test_encoder_counts_quadrature_edges():
    lines = 500
    q = 2 * math.pi / (4 * lines)
    theta = np.linspace(0.0, 3.0, 200_001)
    y = encoder(theta, lines)
    err = y - theta
    assert np.all(err <= 1e-12) and np.all(err > -q - 1e-12)           # the last count, never ahead
    steps = np.diff(np.unique(np.round(y / q)))
    assert np.all(steps == 1)                                            # every count once, one q apart
    assert len(np.unique(y)) == math.floor(3.0 / q) + 1
    assert err.std() == pytest.approx(q / math.sqrt(12), rel=0.02)       # uniform quantisation error
    with pytest.raises(ValueError, match="encoder_lines"):
        encoder(theta, 0)


@pytest.mark.parametrize("bw", [200.0, 1000.0])
def test_transducer_bandwidth_is_minus_3_dB(bw):
    t = np.arange(int(4 * FS)) / FS
    rng = np.random.default_rng(0)
    for f, gain in ((bw, 1 / math.sqrt(2)), (bw / 10, 1.0)):
        x = np.sin(2 * math.pi * f * t)
        y = torque_transducer(x, FS, bw, 0.0, rng)
        a = np.sqrt(2) * y[len(t) // 2:].std()                            # after the start-up
        assert a == pytest.approx(gain, rel=0.01 if f == bw else 0.002)
    # started in its steady state: a constant passes unchanged from the first sample
    assert np.allclose(torque_transducer(np.full(100, 15.0), FS, bw, 0.0, rng), 15.0, rtol=1e-9)


def test_noise_floor_measured_back_from_a_long_constant():
    sigma = 0.01
    n = int(60 * FS)
    y = torque_transducer(np.full(n, 15.0), FS, 1000.0, sigma, np.random.default_rng(1))
    assert y.mean() == pytest.approx(15.0, abs=5 * sigma / math.sqrt(n))
    assert y.std() == pytest.approx(sigma, rel=0.01)
    f, p = sig.welch(y - 15.0, fs=FS, nperseg=4096)                       # one-sided density, flat
    assert np.median(p) == pytest.approx(sigma ** 2 / (FS / 2), rel=0.05)


def test_seeded_channels_and_untouched_others():
    x = {"drive_shaft_torque": np.full(1000, 1.9), "propeller_shaft_torque": np.full(1000, 15.0),
         "enc1": np.linspace(0, 10, 1000), "gear.tau_a": np.linspace(0, 1, 1000)}
    a, b = measure(x, FS, Instruments(seed=2)), measure(x, FS, Instruments(seed=2))
    c = measure(x, FS, Instruments(seed=3))
    for k in x:
        assert np.array_equal(a[k], b[k])
    assert not np.array_equal(a["drive_shaft_torque"], c["drive_shaft_torque"])
    assert a["gear.tau_a"] is x["gear.tau_a"]                            # not an instrument: untouched
    # a channel's noise does not depend on which other channels are recorded
    only = measure({"propeller_shaft_torque": x["propeller_shaft_torque"]}, FS, Instruments(seed=2))
    assert np.array_equal(only["propeller_shaft_torque"], a["propeller_shaft_torque"])


def test_a_run_with_rig_sensors(tmp_path, fmu_dir):
    """Rig sensors change the readings (noise, counts) and are recorded; the ideal run of the same scene
    is bit-identical to a run that never heard of them."""
    from _shared import EXAMPLE, SHORT

    from drivetrain.run.runner import run_scene
    from drivetrain.scene.load import load_scene

    runs = {}
    for s in ("ideal", "rig"):
        scene = load_scene(EXAMPLE, overrides=SHORT + ["effects.mesh_contact=analytic", f"effects.sensors={s}"])
        runs[s] = run_scene(scene, out_dir=None, progress=False, backend="inprocess", fmu_dir=fmu_dir)
    base = run_scene(load_scene(EXAMPLE, overrides=SHORT + ["effects.mesh_contact=analytic"]), out_dir=None,
                     progress=False, backend="inprocess", fmu_dir=fmu_dir)
    for k, v in base.signals.items():
        assert np.array_equal(v, runs["ideal"].signals[k])
    rig, ideal = runs["rig"], runs["ideal"]
    q = 2 * math.pi / (4 * Instruments().encoder_lines)
    assert np.allclose(rig.signals["enc5"] / q, np.round(rig.signals["enc5"] / q), atol=1e-6)
    filtered = torque_transducer(ideal.signals["propeller_shaft_torque"], ideal.summary["sample_rate_Hz"],
                                 Instruments().torque_bandwidth_Hz, 0.0, None)
    d = rig.signals["propeller_shaft_torque"] - filtered                 # the noise alone
    assert d.std() == pytest.approx(Instruments().propeller_torque_noise_Nm, rel=0.25)
    assert rig.summary["instruments"]["seed"] == 0 and ideal.summary["instruments"] is None
    assert any("3012" in w for w in rig.summary["warnings"])
