"""`drivetrain validate`: its judges on synthetic runs whose lines are known (each can fail), and the
command itself on short runs (slow)."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivetrain.campaigns import validation as V
from drivetrain.run.outputs import write_hdf5

FS = 3000.0
F = {"f_DSH": 25.0, "f_MSH": 25.0 / 3, "f_PSH": 25.0 / 12, "f_GMF": 125.0}


def _run(tmp: Path, name: str, signals: dict, **summary) -> dict:
    t = np.arange(len(next(iter(signals.values())))) / FS
    d = tmp / name
    write_hdf5(d / "signals.h5", t, signals, {k: {"unit": "N.m"} for k in signals}, {})
    s = {"settle_s": 1.0, "sample_rate_Hz": FS, **F, **summary}
    (d / "summary.json").write_text(json.dumps(s))
    return {"name": name, "status": "ok", "signals": str(d / "signals.h5"), "summary": str(d / "summary.json")}


def _sine(f, a, n, phase=0.3):
    return a * np.sin(2 * math.pi * f * np.arange(n) / FS + phase)


def test_shaft_peak_judge(tmp_path):
    """Lines at f_PSH and f_DSH 1e-3 N·m over a 1e-5 N·m noise floor pass; a run without them has nothing
    there above that floor (absent); a run with them in both states fails the "absent when off" half."""
    n = int(9 * FS)
    rng = np.random.default_rng(0)
    noise = lambda: 1e-5 * rng.standard_normal(n)  # noqa: E731
    lines = {"propeller_shaft_torque": 15 + _sine(F["f_PSH"], 1e-3, n) + noise(),
             "drive_shaft_torque": 1.9 + _sine(F["f_DSH"], 1e-3, n) + noise()}
    quiet = lambda: 1e-8 * rng.standard_normal(n)  # noqa: E731   (a simulation without errors or noise)
    flat = {"propeller_shaft_torque": 15 + quiet(), "drive_shaft_torque": 1.9 + quiet()}
    on, off = V.case_name("healthy", 1500.0, 1.31), V.case_name("healthy", 1500.0, 1.31, realistic=False)
    good = V.Runs({"runs": [_run(tmp_path / "a", on, lines), _run(tmp_path / "a", off, flat)]})
    r = V.check_shaft_peaks(good)
    assert r.status == "pass", r.figure
    bad = V.Runs({"runs": [_run(tmp_path / "b", on, lines), _run(tmp_path / "b", off, lines)]})
    assert V.check_shaft_peaks(bad).status == "fail"
    assert V.check_shaft_peaks(V.Runs({"runs": []})).status == "fail"      # missing runs never pass


def test_mild_judge(tmp_path):
    """Sidebands 4x healthy's (+12 dB) at equal peak-to-peak pass; twice the peak-to-peak fails; equal
    sidebands fail."""
    n = int(9 * FS)
    gmf = _sine(F["f_GMF"], 0.1, n)
    sb = lambda a: _sine(F["f_GMF"] - F["f_MSH"], a, n) + _sine(F["f_GMF"] + F["f_MSH"], a, n)  # noqa: E731
    h, m = V.case_name("healthy", 1500.0, 1.31), V.case_name("mild", 1500.0, 1.31)

    def judge(mild_signal, sub):
        runs = V.Runs({"runs": [_run(tmp_path / sub, h, {"propeller_shaft_torque": 15 + gmf + sb(0.002)}),
                                _run(tmp_path / sub, m, {"propeller_shaft_torque": mild_signal})]})
        return V.check_mild(runs)

    assert judge(15 + gmf + sb(0.008), "a").status == "pass"
    assert judge(15 + 2.2 * gmf + sb(0.008), "b").status == "fail"        # visible in the time domain
    assert judge(15 + gmf + sb(0.002), "c").status == "fail"              # no sideband rise


def test_order_judge(tmp_path):
    """Check 6 on 54 synthetic cells: healthy < mild < severe in the sum of the first sideband pair passes,
    also where the mild fault raises only one sideband of the two; one cell where the mild fault leaves
    both as they were fails it (17 of 18); missing runs fail."""
    n = int(6 * FS)
    gmf = _sine(F["f_GMF"], 0.1, n)

    def sig(lower, upper):
        return 15 + gmf + _sine(F["f_GMF"] - F["f_MSH"], lower, n) + _sine(F["f_GMF"] + F["f_MSH"], upper, n)

    def runs(sub, flat_cell=None):
        out = []
        for speed in V.SPEEDS_RPM:
            for load in V.LOADS_NM:
                flat = (speed, load) == flat_cell
                for h, (lo, up) in zip(V.HEALTHS, ((0.002, 0.003), (0.002 if flat else 0.0027, 0.003),
                                                   (0.02, 0.02))):
                    out.append(_run(tmp_path / sub, V.case_name(h, speed, load),
                                    {"propeller_shaft_torque": sig(lo, up)}))
        return V.Runs({"runs": out})

    r = V.check_order(runs("a"))
    assert r.status == "pass" and "18 of 18" in r.figure, (r.figure, r.details)
    r = V.check_order(runs("b", flat_cell=(250.0, 0.12)))
    assert r.status == "fail" and "17 of 18" in r.figure and r.details[0].startswith("250 rpm 0.12")
    assert V.check_order(V.Runs({"runs": []})).status == "fail"


def test_stiffness_check_is_static_and_passes():
    """Check 8 needs no run: the table model with the default compliance against ISO 6336 at the pinion
    torques of the measured table (1500 rpm); check 9 without its runs fails rather than reports."""
    r = V.check_stiffness(V.Runs({"runs": []}))
    assert r.status == "pass" and len(r.details) == 3
    assert V.check_peaks_compliance(V.Runs({"runs": []})).status == "fail"


@pytest.mark.slow
def test_validate_command_on_short_runs(tmp_path):
    """The whole command at 4 s per run (74 runs, in-process): the checks that do not need 20 s pass, the
    report is written with every check and the figure."""
    report = tmp_path / "docs" / "VALIDATION.md"
    p = subprocess.run([sys.executable, "-m", "drivetrain", "validate", "--duration", "4", "--settle", "1",
                        "--backend", "inprocess", "--out", str(tmp_path / "out"), "--report", str(report), "--quiet"],
                       capture_output=True, text=True, timeout=3000)
    print(p.stdout[-3000:], p.stderr[-3000:])
    text = report.read_text()
    for k in range(1, 12):
        assert f"| {k} |" in text
    status = {int(line.split()[0]): line.split()[1] for line in p.stdout.splitlines() if line[:2].strip().isdigit()}
    for k in (1, 3, 7, 8, 10):
        assert status[k] == "pass", p.stdout
    assert status[2] == "calibration", p.stdout
    assert (report.parent / "figures" / "validation_spectra.png").exists()


def test_record_judge(tmp_path):
    """Check 11 judged on the record itself as every gearbox's run: every figure within 0.5 dB (the record
    against itself; the run's 1.84 s window starts after its settling second) and pass; the same signals
    scaled by 2 (+6 dB) fail on std; missing runs fail."""
    from drivetrain.campaigns import record_check as RC
    from drivetrain.rig import record as rec

    r = rec.load_record()
    global FS
    fs_saved, FS = FS, r.fs
    try:
        cut = int(round(rec.SKIP_S * r.fs))
        pad = int(round(1.0 * r.fs))                      # the settling second the judge leaves out

        def sig(scale):
            return {k: np.concatenate([np.full(pad, r.channels[k][cut]), scale * r.channels[k][cut:]])
                    for k in rec.TORQUES}

        def runs(sub, scale):
            names = [RC.case_name(s) for s in range(RC.N_GEARBOXES)] + [RC.case_name(None)]
            return V.Runs({"runs": [_run(tmp_path / sub, n, sig(scale), sample_rate_Hz=r.fs) for n in names]})

        good = V.check_record(runs("a", 1.0))
        assert good.status == "pass", good.figure
        c = RC.compare(runs("a", 1.0))
        assert all(abs(v["dB"]) < 0.5 for rows in c["table"].values() for v in rows.values()), c
        bad = V.check_record(runs("b", 2.0))
        assert bad.status == "fail" and "std" in bad.figure
        assert V.check_record(V.Runs({"runs": []})).status == "fail"
    finally:
        FS = fs_saved
