"""Anti-alias decimation, spectra and characteristic frequencies (drivetrain.rig.signals)."""
import numpy as np
import pytest

from drivetrain.rig.signals import (amplitude_near, amplitude_spectrum, characteristic_frequencies, decimate,
                                decimation_factor, peak_frequency, to_db)


def _fit_amplitudes(t, y, freqs):
    """Least-squares amplitudes of sines at freqs (plus a constant) in y(t)."""
    cols = [np.ones_like(t)]
    for f in freqs:
        cols += [np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)]
    c, *_ = np.linalg.lstsq(np.column_stack(cols), y, rcond=None)
    return c[0], [float(np.hypot(c[1 + 2 * i], c[2 + 2 * i])) for i in range(len(freqs))]


@pytest.mark.parametrize("method", ["fir", "butter"])
@pytest.mark.parametrize("fs_out,steps", [(3000.0, 4), (3012.0, 4), (3000.0, 12)])
def test_decimation_keeps_band_and_rejects_alias(method, fs_out, steps):
    fs_in = fs_out * steps
    t = np.arange(0.0, 3.0, 1.0 / fs_in)
    # documented flat pass band: FIR to 0.7 x output Nyquist, Butterworth (filtfilt) to 0.5 x
    edge = 0.69 if method == "fir" else 0.5
    band = {125.0: 1.0, 437.3: 0.5, edge * fs_out / 2: 0.25}
    f_alias = fs_out - 400.0 + 0.37                 # above the output Nyquist: would fold to ~400 Hz
    x = 3.0 + sum(a * np.sin(2 * np.pi * f * t + 0.4 * i) for i, (f, a) in enumerate(band.items()))
    x = x + 0.8 * np.sin(2 * np.pi * f_alias * t)
    y = decimate(x, fs_in, fs_out, method=method)
    assert len(y) == (len(x) - 1) // steps + 1
    to = np.arange(len(y)) / fs_out
    core = slice(int(0.2 * fs_out), len(y) - int(0.2 * fs_out))      # away from the ends
    folded = fs_out - f_alias
    mean, amps = _fit_amplitudes(to[core], y[core], list(band) + [folded])
    assert mean == pytest.approx(3.0, rel=1e-4)
    for (f, a), got in zip(band.items(), amps):
        assert got == pytest.approx(a, rel=1e-3), f"in-band tone {f} Hz"
    assert 20 * np.log10(amps[-1] / 0.8) < -40.0, "alias not suppressed by 40 dB"
    # the same without filtering aliases fully: the test signal is meaningful
    _, amps_raw = _fit_amplitudes(to[core], x[::steps][core], [folded])
    assert amps_raw[0] == pytest.approx(0.8, rel=1e-2)


def test_decimation_zero_phase_and_time_alignment():
    fs_in, fs_out = 12000.0, 3000.0
    t = np.arange(0.0, 1.0, 1.0 / fs_in)
    x = np.sin(2 * np.pi * 50.0 * t)
    y = decimate(x, fs_in, fs_out)
    to = np.arange(len(y)) / fs_out
    core = slice(300, -300)
    assert np.max(np.abs(y[core] - np.sin(2 * np.pi * 50.0 * to[core]))) < 5e-4


def test_decimation_factor_must_be_integer():
    assert decimation_factor(12000.0, 3000.0) == 4
    with pytest.raises(ValueError, match="not an integer multiple"):
        decimation_factor(10000.0, 3000.0)


def test_characteristic_frequencies_from_gear_data():
    for n in (250.0, 500.0, 1500.0, 1502.98):
        cf = characteristic_frequencies(n)
        assert cf["f_DSH"] == pytest.approx(n / 60.0)
        assert cf["f_MSH"] == pytest.approx(cf["f_DSH"] / 3.0)
        assert cf["f_PSH"] == pytest.approx(cf["f_MSH"] * 15 / 60)
        assert cf["f_GMF"] == pytest.approx(15 * cf["f_MSH"])
        assert cf["f_GMF"] == pytest.approx(60 * cf["f_PSH"])
        assert cf["f_PSH"] == pytest.approx(cf["f_DSH"] / 12.0)        # propeller shaft: 1/12 of the drive
        assert cf["harmonics"][:3] == pytest.approx([cf["f_GMF"], 2 * cf["f_GMF"], 3 * cf["f_GMF"]])
        sb = cf["sidebands"][0]
        assert (sb["lower"], sb["upper"]) == pytest.approx((cf["f_GMF"] - cf["f_MSH"], cf["f_GMF"] + cf["f_MSH"]))
    cf = characteristic_frequencies(1500.0)
    assert (cf["f_DSH"], cf["f_MSH"], cf["f_PSH"], cf["f_GMF"]) == pytest.approx((25.0, 25 / 3, 25 / 12, 125.0))


def test_amplitude_spectrum_hann_reads_amplitude_on_bin():
    fs, n = 3000.0, 30000
    t = np.arange(n) / fs
    x = 2.0 + 0.7 * np.sin(2 * np.pi * 100.0 * t)          # 100 Hz is bin 1000
    f, A = amplitude_spectrum(x, fs)
    assert f[1] - f[0] == pytest.approx(fs / n)
    assert A[np.argmin(abs(f - 100.0))] == pytest.approx(0.7, rel=1e-9)
    assert A[0] < 1e-9                                       # mean removed


@pytest.mark.parametrize("rpm", [500.0, 1500.0])
def test_gmf_tone_lands_within_one_bin(rpm):
    cf = characteristic_frequencies(rpm)
    fs_in, fs_out = 12000.0, 3000.0
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 10.0, 1.0 / fs_in)
    x = (1.3 + 0.05 * np.sin(2 * np.pi * cf["f_GMF"] * t)
         + 0.02 * np.sin(2 * np.pi * cf["sidebands"][0]["upper"] * t)
         + 0.03 * np.sin(2 * np.pi * 4100.0 * t)            # mesh harmonic above Nyquist: must not alias
         + 0.005 * rng.standard_normal(len(t)))
    y = decimate(x, fs_in, fs_out)[int(fs_out):]             # settle excluded
    f, A = amplitude_spectrum(y, fs_out, lowpass_Hz=5 * cf["f_GMF"])
    df = f[1] - f[0]
    fpk = peak_frequency(f, A, 0.5 * cf["f_GMF"], 1.5 * cf["f_GMF"])
    assert abs(fpk - cf["f_GMF"]) <= df
    assert amplitude_near(f, A, cf["f_GMF"]) == pytest.approx(0.05, rel=0.2)    # Hann scalloping <= 1.4 dB
    assert to_db(amplitude_near(f, A, 4100.0 - 3000.0) / 0.03) < -40.0 or 5 * cf["f_GMF"] < 1100.0
