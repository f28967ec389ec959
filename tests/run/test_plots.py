"""The run's plots read right: spectra not clipped, the amplitude convention on the axis, the
operating point, health and effects in the titles, a shaft-order panel, a difference plot of `check` only
where both runs have samples, waveforms drawn as a min/max envelope that keeps every peak.

Each test inspects the matplotlib Figure a plot function saves (``Figure.savefig`` is watched), so it
reads what the PNG shows: line data, limits, labels, titles."""
from pathlib import Path

import numpy as np
import pytest

from drivetrain.campaigns import baseline as B
from drivetrain.rig.signals import AMPLITUDE_CONVENTION, amplitude_spectrum, characteristic_frequencies
from drivetrain.run import outputs as O
from drivetrain.scene.load import load_scene

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"
CF = characteristic_frequencies(1500.0)          # f_PSH 2.08, f_MSH 8.33, f_DSH 25, f_GMF 125 Hz


@pytest.fixture
def saved(monkeypatch):
    """The Figures written by the code under test, in order."""
    from matplotlib.figure import Figure

    figs = []
    orig = Figure.savefig

    def savefig(self, *args, **kwargs):
        figs.append(self)
        return orig(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    return figs


def _spectrum(tiny=1e-15):
    """A line at f_GMF of 1 mN·m and one at f_PSH of 1 µN·m over a numerical floor of ``tiny`` N·m, the bins
    from 600 to 610 Hz exactly zero."""
    f = np.arange(0.0, 750.0, 0.05)
    A = np.full(len(f), tiny)
    A[np.argmin(np.abs(f - CF["f_GMF"]))] = 1e-3
    A[np.argmin(np.abs(f - CF["f_PSH"]))] = 1e-6
    A[(f >= 600.0) & (f < 610.0)] = 0.0
    return f, A


def test_spectra_are_drawn_as_computed_not_clipped_at_a_floor(saved, tmp_path):
    f, A = _spectrum()
    O.plot_spectra(tmp_path / "s.png", {"propeller_shaft_torque": (f, A)}, CF)
    ax = saved[-1].axes[0]
    y = np.asarray(ax.get_lines()[0].get_ydata(), dtype=float)
    assert np.nanmin(y) == pytest.approx(1e-15)                 # the floor is the data's, not 1e-12
    assert not np.any(y == 1e-12)
    assert np.isnan(y).any() and not np.any(y == 0)             # zero bins left out (a log axis has no 0)
    lo, hi = ax.get_ylim()
    assert lo < 1e-15 < 1e-3 < hi                               # the limits follow the data's range


def test_spectrum_axis_says_the_amplitude_convention_the_spectrum_computes(saved, tmp_path):
    fs, n = 3000.0, 6000
    t = np.arange(n) / fs
    x = 0.7 * np.sin(2 * np.pi * 125.0 * t) + 0.01 * np.sin(2 * np.pi * 250.0 * t)
    f, A = amplitude_spectrum(x, fs)
    w = np.hanning(n + 1)[:-1]
    assert np.allclose(A[1:], 2 * np.abs(np.fft.rfft(x * w))[1:] / w.sum())      # 2|X|/Σw, Hann
    assert A[np.argmin(np.abs(f - 125.0))] == pytest.approx(0.7, rel=1e-9)       # a sine reads its peak amplitude
    O.plot_spectra(tmp_path / "s.png", {"drive_shaft_torque": (f, A)}, CF)
    label = saved[-1].axes[0].get_ylabel().replace("\n", " ")
    assert AMPLITUDE_CONVENTION in label and "N·m" in label
    assert "single-sided peak amplitude" in label and "2|X|/Σw" in label and "Hann" in label


def test_spectra_have_a_panel_for_the_shaft_orders(saved, tmp_path):
    O.plot_spectra(tmp_path / "s.png", {"propeller_shaft_torque": _spectrum()}, CF)
    low = [ax for ax in saved[-1].axes if ax.get_xlim()[1] < 100.0]
    assert low, [ax.get_xlim() for ax in saved[-1].axes]
    ax = low[0]
    lo, hi = ax.get_xlim()
    assert lo < CF["f_PSH"] and hi > 3 * CF["f_DSH"]
    marked = {round(float(ln.get_xdata()[0]), 6) for ln in ax.get_lines()[1:]}
    for key in ("f_PSH", "f_MSH", "f_DSH"):
        assert round(CF[key], 6) in marked and round(2 * CF[key], 6) in marked, key
    y = np.asarray(ax.get_lines()[0].get_ydata(), dtype=float)
    x = np.asarray(ax.get_lines()[0].get_xdata(), dtype=float)
    assert np.nanmax(y[np.abs(x - CF["f_PSH"]) < 0.06]) == pytest.approx(1e-6)     # the f_PSH line is on it


def test_run_plots_carry_operating_point_health_and_effects(saved, tmp_path, fmu_dir):
    from drivetrain.run.runner import run_scene

    scene = load_scene(EXAMPLE, ["time.duration_s=0.3", "time.settle_s=0.1", "effects.mesh_contact=analytic",
                                 "effects.shaft_flexibility=rigid", "effects.friction=false",
                                 "operating_point.load_torque_Nm=0.71", "outputs.aalto_csv=false"])
    run_scene(scene, tmp_path / "out", backend="inprocess", progress=False, fmu_dir=fmu_dir, plots=True)
    titles = [fig.get_suptitle() for fig in saved]
    assert len(titles) == 2 and "torque waveforms" in titles[0] and "spectra" in titles[1]
    for title in titles:
        assert "1500 rpm" in title and "0.71 N·m" in title and "healthy" in title, title
        assert "mesh_contact=analytic" in title and "shaft_flexibility=rigid" in title, title
        assert "contact_damping" in title and "friction" not in title, title     # switches on by name, off left out


def test_run_title_names_the_faults():
    scene = load_scene(EXAMPLE, ['gear.health="severe"', "operating_point.drive_speed_rpm=500"])
    title = O.run_title(scene, "amplitude spectra", failed_at_s=0.25)
    assert "500 rpm" in title and "1.31 N·m" in title and "FAILED at t = 0.25 s" in title
    assert "severe: missing_tooth pinion tooth 0" in title


def _entry(t, x, settle_s=0.1):
    return B.Entry(name="c", scene={}, summary={}, metrics={}, time=np.asarray(t), signals={"T": np.asarray(x)},
                   units={"T": "N·m"}, spectra={}, decimation=1, sample_rate_Hz=1000.0, settle_s=settle_s)


def test_check_difference_plot_stays_within_the_common_time(saved, tmp_path):
    tb = np.arange(0, 1001) / 1000.0                  # baseline: 1 s
    tc = tb[:501]                                     # this run: ended at 0.5 s
    base, cur = _entry(tb, np.sin(tb)), _entry(tc, np.sin(tc) + 0.01)
    B.plot_against_baseline(tmp_path / "c.png", cur, base, ["T"])
    diff_ax = saved[-1].axes[1]
    x = np.asarray(diff_ax.get_lines()[0].get_xdata(), dtype=float)
    y = np.asarray(diff_ax.get_lines()[0].get_ydata(), dtype=float)
    assert x.max() <= 0.5 + 1e-12 and x.min() >= 0.0
    assert np.allclose(y, 0.01)                       # no held last value past this run's end
    notes = " ".join(t.get_text() for t in diff_ax.texts)
    assert "time bases differ" in notes and "0–0.5 s" in notes, notes


def test_check_difference_plot_on_one_time_base_has_no_note(saved, tmp_path):
    tb = np.arange(0, 501) / 1000.0
    B.plot_against_baseline(tmp_path / "c.png", _entry(tb, np.cos(tb) * 2), _entry(tb, np.cos(tb)), ["T"])
    diff_ax = saved[-1].axes[1]
    assert np.allclose(diff_ax.get_lines()[0].get_ydata(), np.cos(tb))
    assert not diff_ax.texts
    t, d, note = B.difference_on_overlap(tb + 2.0, tb, tb, tb)      # no common time: nothing drawn, said so
    assert len(t) == 0 and "no common time" in note


def test_waveforms_are_an_envelope_that_keeps_a_single_sample_peak(saved, tmp_path):
    n = 200_000
    t = np.arange(n) / 3000.0
    x = 15.0 + 0.01 * np.sin(2 * np.pi * 125.0 * t)
    x[123_457] = 16.5                                 # one sample
    x[77_777] = 13.9
    O.plot_torques(tmp_path / "t.png", t, {"propeller_shaft_torque": x}, 2.0, CF)
    line = saved[-1].axes[0].get_lines()[0]
    y = np.asarray(line.get_ydata())
    assert len(y) < 3000                              # <= 2 points per pixel column (13 in at 110 dpi: 1430 columns)
    assert len(y) <= 2 * O.pixel_columns(saved[-1].axes[0]) + 2
    assert y.max() == 16.5 and y.min() == 13.9
    assert np.all(np.diff(line.get_xdata()) >= 0)


def test_envelope_holds_every_column_extreme():
    rng = np.random.default_rng(3)
    x = np.arange(10_007.0)
    y = rng.normal(size=x.size)
    y[[5, 600, 10_006]] = np.nan
    xe, ye = O.envelope(x, y, 100)
    k = -(-x.size // 100)
    for start in range(0, x.size, k):
        block = y[start:start + k]
        inside = (xe >= start) & (xe < start + k)
        assert np.nanmax(ye[inside]) == np.nanmax(block) and np.nanmin(ye[inside]) == np.nanmin(block)
    assert np.all(np.diff(xe) > 0)
    xs, ys = O.envelope(x[:50], y[:50], 100)          # short traces as they are
    assert np.array_equal(xs, x[:50])
