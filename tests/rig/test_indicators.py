"""Condition indicators (drivetrain.rig.indicators) against closed-form signals: each metric's value on a
signal whose value follows from its definition by hand (sums of sines, an impulse, Gaussian moments)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from drivetrain.rig import indicators as ci

N, Z = 1024, 15
PHI = 2 * math.pi * np.arange(N) / N


def test_tsa_keeps_the_locked_part_and_averages_the_rest_out():
    """A tone locked to the shaft (order Z) plus an unlocked one (7.3 Hz) on a shaft at 2.78 Hz with a 1 %
    speed wobble, sampled at 3000 Hz: the TSA over 60 revolutions is the locked tone within 2 % of its
    amplitude (the unlocked one falls as 1/revolutions; the interpolation error is (pi Z / samples per rev)^2)."""
    fs, f_shaft, revs = 3000.0, 2.78, 60
    t = np.arange(int(fs * revs / f_shaft) + 10) / fs
    angle = 2 * math.pi * f_shaft * t + 0.01 * np.sin(2 * math.pi * 0.7 * t)
    x = np.sin(Z * angle) + 0.5 * np.sin(2 * math.pi * 7.3 * t)
    avg = ci.tsa(x, angle + 0.2, N)                  # an encoder whose zero is 0.2 rad off the tone's
    assert len(avg) == N
    assert np.max(np.abs(avg - np.sin(Z * (PHI - 0.2)))) < 0.02


def test_tsa_refuses_a_shaft_that_does_not_turn():
    with pytest.raises(ValueError, match="increase"):
        ci.tsa(np.zeros(10), np.zeros(10), 64)
    with pytest.raises(ValueError, match="whole revolution"):
        ci.tsa(np.zeros(10), np.linspace(0, 1, 10), 64)


def test_a_pure_mesh_tone():
    """x = A sin(Z phi): kurtosis 3/2, crest factor sqrt 2, FM0 = 2A / A = 2, no sidebands (SLF = SER = 0),
    no difference signal (ER = 0)."""
    m = ci.indicators([2.0 * np.sin(Z * PHI)], Z)
    assert m["kurtosis"] == pytest.approx(1.5, rel=1e-9)
    assert m["CF"] == pytest.approx(math.sqrt(2), rel=1e-9)
    assert m["FM0"] == pytest.approx(2.0, rel=1e-9)
    assert m["SLF"] == pytest.approx(0.0, abs=1e-12) and m["SER"] == pytest.approx(0.0, abs=1e-12)
    assert m["ER"] == pytest.approx(0.0, abs=1e-9)


def test_sidebands():
    """A mesh tone A with sidebands a_i at Z +- i: SER = sum(a_i + a_-i) / A, SLF = (a_1 + a_-1) / RMS with
    RMS^2 = (A^2 + sum a^2) / 2; the difference signal holds the sidebands beyond the first."""
    A, side = 1.0, {1: 0.2, -1: 0.1, 2: 0.05, -3: 0.03, 7: 0.5}          # 7: beyond SER's six
    x = A * np.sin(Z * PHI) + sum(a * np.sin((Z + i) * PHI + 0.3 * i) for i, a in side.items())
    m = ci.indicators([x], Z)
    assert m["SER"] == pytest.approx((0.2 + 0.1 + 0.05 + 0.03) / A, rel=1e-9)
    rms = math.sqrt((A ** 2 + sum(a * a for a in side.values())) / 2)
    assert m["SLF"] == pytest.approx(0.3 / rms, rel=1e-9)
    d = ci.split(x, Z)["difference"]
    assert np.std(d) == pytest.approx(math.sqrt((0.05 ** 2 + 0.03 ** 2 + 0.5 ** 2) / 2), rel=1e-9)


def test_one_impulse_per_revolution_on_a_mesh_tone():
    """x = A sin(Z phi) + h at one sample per revolution (a tooth's knock): kurtosis, FM4 and SER from the
    sums by hand. Sums over a revolution: sum sin = 0, sum sin^2 = N/2, sum sin^4 = 3N/8, sin(0) = 0; the
    impulse puts 2h/N (cosine phase) on every order, so A(Z) = sqrt(A^2 + (2h/N)^2) and each sideband 2h/N."""
    A, h = 1.0, 40.0
    x = A * np.sin(Z * PHI)
    x[0] += h
    m = ci.indicators([x], Z)
    c = h / N                                                          # the mean
    s2 = A * A * N / 2 + h * h - N * c * c
    # sum (A s_k - c)^4 over k != 0, plus (h - c)^4: A^4 3N/8 + 6 A^2 c^2 N/2 + N c^4 (odd powers of s sum to 0)
    s4 = A ** 4 * 3 * N / 8 + 6 * A * A * c * c * N / 2 + (N - 1) * c ** 4 + (h - c) ** 4
    assert m["kurtosis"] == pytest.approx(N * s4 / s2 ** 2, rel=1e-3)
    assert m["SER"] == pytest.approx(12 * (2 * h / N) / math.hypot(A, 2 * h / N), rel=1e-9)
    # the difference signal: the impulse less its mean and its share on the removed orders (1, 2, k Z, k Z +- 1)
    removed = {0, 1, 2} | {o + s for o in ci.mesh_orders(N, Z) for s in (-1, 0, 1)}
    k = np.arange(N)
    d = np.where(k == 0, h, 0.0) - h / N - sum(2 * h / N * np.cos(2 * math.pi * o * k / N) for o in removed if o)
    assert m["FM4"] == pytest.approx(N * np.sum(d ** 4) / np.sum(d ** 2) ** 2, rel=1e-6)
    assert m["FM4"] > 100                                              # the knock stands out once the mesh is removed


def test_gaussian_moments():
    """White Gaussian noise as the TSA: kurtosis 3, FM4 3, M6A 15, M8A 105 (the Gaussian's normalised moments),
    within their sampling scatter at 2^16 points; NA4 of stationary records 3."""
    rng = np.random.default_rng(5)
    n = 2 ** 16
    x = rng.standard_normal(n)
    m = ci.indicators([x], Z)
    assert m["kurtosis"] == pytest.approx(3.0, abs=0.1)
    assert m["FM4"] == pytest.approx(3.0, abs=0.1)
    assert m["M6A"] == pytest.approx(15.0, rel=0.08)
    assert m["M8A"] == pytest.approx(105.0, rel=0.2)
    recs = [rng.standard_normal(n) for _ in range(4)]
    assert ci.indicators(recs, Z)["NA4"] == pytest.approx(3.0, abs=0.1)


def test_na4_follows_a_change_against_the_run():
    """NA4's denominator is the run's mean variance: a last record with a doubled residual reads 16/((1+1+1+4)/4)^2
    times its own kurtosis (the trend the metric was made for); FM4 of the same record does not move."""
    rng = np.random.default_rng(1)
    n = 2 ** 14
    recs = [rng.standard_normal(n) for _ in range(3)] + [2 * rng.standard_normal(n)]
    r = ci.split(recs[-1], Z)["residual"]
    own = np.mean((r - r.mean()) ** 4) / np.var(r) ** 2
    var = np.mean([np.var(ci.split(x, Z)["residual"]) for x in recs])
    assert ci.indicators(recs, Z)["NA4"] == pytest.approx(np.mean((r - r.mean()) ** 4) / var ** 2, rel=1e-9)
    assert ci.indicators(recs, Z)["NA4"] > 2.5 * own


def test_nb4_of_an_amplitude_modulated_mesh():
    """A mesh tone modulated once per revolution, A (1 + mu cos phi) sin(Z phi): its band's envelope is
    A (1 + mu cos phi), whose kurtosis is a cosine's, 3/2."""
    x = (1 + 0.4 * np.cos(PHI)) * np.sin(Z * PHI)
    assert ci.indicators([x], Z)["NB4"] == pytest.approx(1.5, rel=1e-6)


def test_energy_ratio():
    """ER = RMS(difference) / RMS(regular): a mesh tone 1 with a non-mesh order 40 of 0.3 reads 0.3."""
    x = np.sin(Z * PHI) + 0.3 * np.sin(40 * PHI)
    assert ci.indicators([x], Z)["ER"] == pytest.approx(0.3, rel=1e-9)


def test_features_of_runs(tmp_path):
    """`drivetrain features` on a sweep of a healthy and a severe (missing pinion tooth) run at 1500 rpm with the
    rig's sensors: one row per run with the labels and every indicator of both shafts and transducers, finite;
    the missing tooth's knock raises the pinion TSA's FM4 and the sideband energy ratio of the propeller-shaft
    torque over the healthy gear's."""
    import subprocess
    import sys

    import pyarrow.parquet as pq

    from drivetrain.campaigns.features import LINES, SHAFTS, TORQUES

    out = tmp_path / "sweep"
    grid = tmp_path / "grid.toml"
    grid.write_text("""
[scenario]
name = "feat"
[operating_point]
drive_speed_rpm = 1500.0
load_torque_Nm = 1.31
[time]
duration_s = 1.0
settle_s = 0.4
[outputs]
plots = false
aalto_csv = false
[effects]
sensors = "rig"
[sweep.axes]
"gear.health" = ["healthy", "severe"]
""")
    # 0.6 s analysed (15 pinion revolutions; it was 1.5 s): severe/healthy FM4 2.68 and SER 28 (2.69 and 22 at
    # 1.5 s), so the factor 2 below still separates them; a severe run equal to the healthy one fails both
    p = subprocess.run([sys.executable, "-m", "drivetrain", "sweep", str(grid), "--out", str(out), "--workers", "1",
                        "--backend", "inprocess"], capture_output=True, text=True, timeout=1200)
    assert p.returncode == 0, p.stderr[-2000:]
    p = subprocess.run([sys.executable, "-m", "drivetrain", "features", str(out)], capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    rows = pq.read_table(out / "features.parquet").to_pylist()
    assert len(rows) == 2
    by = {r["gear.health"]: r for r in rows}
    for r in rows:
        for sig in TORQUES:
            for shaft in SHAFTS:
                for m in ci.METRICS:
                    assert math.isfinite(r[f"{m}_{shaft}.{sig}"]), (m, shaft, sig)
            for ln in LINES:
                assert r[f"amp_{ln}.{sig}"] >= 0
    h, s = by["healthy"], by["severe"]
    assert s["FM4_pinion.propeller_shaft_torque"] > 2 * h["FM4_pinion.propeller_shaft_torque"]
    assert s["SER_pinion.propeller_shaft_torque"] > 2 * h["SER_pinion.propeller_shaft_torque"]


def test_features_refuse_a_directory_without_runs(tmp_path):
    import subprocess
    import sys

    p = subprocess.run([sys.executable, "-m", "drivetrain", "features", str(tmp_path)], capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 2 and "manifest" in p.stderr and "Traceback" not in p.stderr


def test_auc_of_a_known_shift():
    """Two normal populations a shift d apart: AUC = Phi(d / sqrt 2) (the probability that X_f - X_h > 0, with
    X_f - X_h ~ N(d, 2)); paired with correlated noise the fraction that rose is Phi(d / (sigma_pair))."""
    from scipy.stats import norm

    rng = np.random.default_rng(3)
    h = rng.standard_normal(4000)
    f = rng.standard_normal(4000) + 1.0
    assert ci.auc(h, f) == pytest.approx(norm.cdf(1.0 / math.sqrt(2)), abs=0.01)
    assert ci.auc(f, h) == pytest.approx(1 - norm.cdf(1.0 / math.sqrt(2)), abs=0.01)
    assert ci.separability(ci.auc(f, h)) == pytest.approx(norm.cdf(1.0 / math.sqrt(2)), abs=0.01)
    # paired: the gearbox's own level (sd 3) cancels; the change has sd 0.5 about 0.3
    level = 3 * rng.standard_normal(4000)
    hp = level + 0.5 * rng.standard_normal(4000) / math.sqrt(2)
    fp = level + 0.3 + 0.5 * rng.standard_normal(4000) / math.sqrt(2)
    assert ci.paired_auc(hp, fp) == pytest.approx(norm.cdf(0.3 / 0.5), abs=0.015)
    assert ci.auc(hp, fp) < 0.56                                       # unpaired, the level hides it
    assert ci.auc([1.0, 2.0], [3.0, 4.0]) == 1.0 and ci.paired_auc([1.0, 2.0], [1.0, 3.0]) == 0.75


def test_signal_to_background_ratio():
    """f = h + s sample by sample: SBR = 10 log10(var-free energy of s / var h); a pair whose faulty run equals
    its twin reads -inf; pairs are found by their noise_name and one healthy member."""
    rng = np.random.default_rng(2)
    h = 5.0 + rng.standard_normal(10000)
    s = 0.1 * np.sin(np.arange(10000) / 7.0)
    assert ci.signal_to_background_dB(h + s, h) == pytest.approx(10 * math.log10(np.mean(s ** 2) / np.var(h)), rel=1e-12)
    assert ci.signal_to_background_dB(h, h) == float("-inf")
    t = np.arange(10000) / 1000.0
    runs = [{"name": "a_draw000", "labels": {"scenario.noise_name": "a_draw000", "gear.health": "faults",
                                             "time.settle_s": 1.0}, "time": t, "signals": {"x": h + s}},
            {"name": "a_draw000_healthy", "labels": {"scenario.noise_name": "a_draw000", "gear.health": "healthy",
                                                     "time.settle_s": 1.0}, "time": t, "signals": {"x": h}},
            {"name": "lonely", "labels": {"gear.health": "faults"}, "time": t, "signals": {"x": h}}]
    out = ci.paired_sbr(runs, ("x",))
    keep = t >= 1.0
    assert list(out) == ["a_draw000"]
    assert out["a_draw000"]["x"] == pytest.approx(10 * math.log10(np.mean(s[keep] ** 2) / np.var(h[keep])), rel=1e-12)


def test_detectability_table_on_known_rows():
    """The AUC table and verdicts on synthetic feature rows of 20 gearboxes (a gearbox level, spread 3, and a
    measurement noise, sd 0.5, shared by a faulty run and its same-noise healthy twin, another for the
    baseline): an indicator that rises by 3 with the fault is detectable against the baseline (paired 1.0)
    but not in a population; one that rises by 0.01 moves the same way in every gearbox with the noise shared
    (own effect 1.0) yet is not detectable against a baseline measured with other noise; one that does not
    move reads 0.5; the verdict follows the stated rule."""
    from drivetrain.campaigns import detectability as D

    fam = D.Family("void", "pinion", "default")
    study = D.Study([fam], (1500.0,), (1.31,), 20)
    rng = np.random.default_rng(0)
    rows = []
    for gb in range(20):
        level = 3 * rng.standard_normal()
        shared, other = 0.5 * rng.standard_normal(), 0.5 * rng.standard_normal()
        for f in (D.BASELINE, None, fam):
            name = D.case_names(f, 1500.0, 1.31, gb)[0]
            noise = other if f == D.BASELINE else shared
            faulty = f not in (None, D.BASELINE)
            rows.append({"run": name, "FM4_pinion.propeller_shaft_torque": level + noise + (3.0 if faulty else 0.0),
                         "NA4_pinion.propeller_shaft_torque": level + noise + (0.01 if faulty else 0.0),
                         "RMS_pinion.propeller_shaft_torque": level + noise})
    table = D.auc_table(rows, study)
    by = {r["indicator"]: r for r in table}
    fm4, na4, rms = (by[f"{m}_pinion.propeller_shaft_torque"] for m in ("FM4", "NA4", "RMS"))
    assert fm4["paired_auc"] == 1.0 and fm4["unpaired_auc"] < 0.85
    assert na4["same_noise_auc"] == 1.0 and 0.2 < na4["paired_auc"] < 0.8
    assert rms["same_noise_auc"] == 0.5
    (v,) = D.verdicts(table)
    assert v["detectable"] and not v["population"] and v["best_paired"] == "FM4_pinion.propeller_shaft_torque"
    assert v["same_noise"] == 1.0
    text = D.report_markdown([v], study, {"command": "x", "n_runs": 60, "workers": 1, "wall_time_s": 1.0}, None, "t.csv")
    assert "detectable against its own gearbox only" in text and "1 of 1" in text


def test_chance_levels_by_their_laws():
    """Paired: the binomial law of coin flips (one indicator over 20 gearboxes: 15 of 20 one way has
    2 P(B >= 15) = 0.041 <= 5 %, 14 of 20 has 0.115); unpaired: the Mann-Whitney null, normal about 1/2 with
    variance (n1 + n2 + 1) / (12 n1 n2): one indicator, 20 and 20 runs, 1/2 + 1.96 sqrt(41 / 4800)."""
    from scipy.stats import norm

    assert ci.chance_separability(20, 1) == 0.75
    assert ci.chance_separability(20, 1000) > ci.chance_separability(20, 10) >= 0.75
    assert ci.chance_unpaired(20, 20, 1) == pytest.approx(0.5 + norm.isf(0.025) * math.sqrt(41 / 4800), rel=1e-12)
    assert ci.chance_unpaired(20, 20, 60) > ci.chance_unpaired(20, 20, 1)


def test_what_moved_between_two_studies(tmp_path):
    """Two studies' verdicts, cell by cell: a cell detectable only in the other counts as lost here, the median
    change of the best separability is their difference; the AUC table survives its CSV."""
    from drivetrain.campaigns import detectability as D

    def v(fam, speed, paired, unpaired):
        return {"family": fam, "speed_rpm": speed, "load_Nm": 1.31, "paired": paired, "unpaired": unpaired,
                "detectable": paired >= 0.9, "population": unpaired >= 0.9}

    here = [v("void_pinion_default", 500.0, 0.7, 0.6), v("void_pinion_default", 1500.0, 1.0, 0.95)]
    there = [v("void_pinion_default", 500.0, 1.0, 0.9), v("void_pinion_default", 1500.0, 1.0, 0.95),
             v("pit_wheel_small", 500.0, 0.5, 0.5)]
    lines = D.what_moved(here, there, "the background off")
    assert "over the 2 cells" in lines[0] and "detectable (paired) in both 1, lost here 1, gained here 0" in lines[0]
    assert "median -0.15" in lines[0]
    assert lines[-1].startswith("| void_pinion_default | 2 | 1 | 2 | 1 | 2 |")
    table = [{"family": "f", "kind": "void", "member": "pinion", "size": "default", "speed_rpm": 500.0,
              "load_Nm": 1.31, "indicator": "FM4_pinion.propeller_shaft_torque", "n": 20, "paired_auc": 0.85,
              "unpaired_auc": 0.4}]
    assert D.read_table_csv(D.write_table_csv(table, tmp_path / "t.csv")) == table


@pytest.mark.slow
def test_detectability_command_on_a_small_grid(tmp_path):
    """The study through the sweep machinery on a small grid (the pinion void, 1500 rpm, 1.31 N·m, 3 gearboxes,
    2.5 s runs, native): the report, its table and figure are written, every cell has its 3 gearboxes."""
    import subprocess
    import sys

    report = tmp_path / "docs" / "DETECTABILITY.md"
    p = subprocess.run([sys.executable, "-m", "drivetrain", "detectability", "--kinds", "void", "--members", "pinion",
                        "--sizes", "default", "--speeds", "1500", "--loads", "1.31", "--gearboxes", "3",
                        "--duration", "2.5", "--settle", "0.5", "--backend", "native", "--workers", "2",
                        "--out", str(tmp_path / "out"), "--report", str(report), "--quiet"],
                       capture_output=True, text=True, timeout=3000)
    assert p.returncode == 0, p.stderr[-3000:]
    text = report.read_text()
    assert "| void_pinion_default | 1500 rpm | 1.31 N·m |" in text
    assert (report.parent / "detectability_auc.csv").exists() and (report.parent / "figures" / "detectability.png").exists()
    import csv as _csv

    rows = list(_csv.DictReader(open(report.parent / "detectability_auc.csv")))
    assert rows and all(r["n"] == "3" for r in rows)
