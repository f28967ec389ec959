"""The detectability frontier (drivetrain.campaigns.frontier) and the two-sided change score
(rig.indicators.change_auc): the bisection against a known threshold, and a small study run end to end and
resumed. Oracles: a synthetic monotone verdict with a known threshold; synthetic indicators whose change has a
gearbox-dependent sign (the case the paired rise scores at chance)."""
from __future__ import annotations

import numpy as np
import pytest

from drivetrain.campaigns import frontier as F
from drivetrain.rig import indicators as ci


@pytest.mark.parametrize("n", [1, 2, 5, 6, 9])
@pytest.mark.parametrize("threshold", range(-1, 10))
def test_bisection_finds_a_known_threshold(n, threshold):
    """Detectable from ladder index ``threshold`` on (>= n: never; < 0: always): the frontier is that index
    (or beyond), found in at most 2 + ceil(log2(n - 1)) sizes."""
    truth = lambda i: i >= threshold  # noqa: E731
    v: dict[int, bool] = {}
    while (i := F.next_index(v, n)) is not None:
        assert i not in v
        v[i] = truth(i)
    want = F.BEYOND if threshold >= n else max(threshold, 0)
    assert F.frontier_index(v, n) == want
    assert len(v) <= (1 if n == 1 else 2 + int(np.ceil(np.log2(n - 1))))
    assert F.monotone(v)


def test_a_non_monotone_cell_is_flagged():
    assert not F.monotone({0: False, 2: True, 3: False, 4: True})
    assert F.monotone({0: False, 4: True, 2: False, 3: True})


def test_the_change_score_sees_a_change_of_either_sign():
    """A line that moves +-10 dB depending on the gearbox (a fault sideband adding to an error sideband with a
    gearbox-dependent phase) scores at chance in the paired rise and near 1 in the change score; no change
    scores near 0.5 in both."""
    rng = np.random.default_rng(1)
    n = 20
    b = rng.normal(0.0, 1.0, n)
    h = b + rng.normal(0.0, 1.0, n)
    sign = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    f = h + 10.0 * sign
    assert ci.paired_auc(b, f) == pytest.approx(0.5, abs=0.1)
    assert ci.change_auc(b, h, f) >= 0.95
    assert abs(ci.change_auc(b, h, h + rng.normal(0.0, 1.0, n)) - 0.5) < 0.3
    need = ci.chance_change(n, 60)
    assert 0.7 < need < 0.9 and ci.chance_change(n, 60 * 36) > need      # family-wise is stricter


def test_the_change_score_decides_the_verdict():
    """detectability.verdicts: the two-sided rule is the verdict; a table without change_auc keeps its
    paired rule and says so."""
    from drivetrain.campaigns.detectability import verdicts

    base = {"family": "pit_pinion_default", "speed_rpm": 500.0, "load_Nm": 1.31, "n": 20,
            "same_noise_auc": 0.5, "unpaired_auc": 0.6}
    rows = [{**base, "indicator": "a.x", "change_auc": 0.97, "paired_auc": 0.5},
            {**base, "indicator": "b.x", "change_auc": 0.6, "paired_auc": 0.55}]
    (v,) = verdicts(rows)
    assert v["detectable"] and not v["rose"] and v["best_change"] == "a.x" and v["rule"] == "two-sided change"
    old = [{k: x for k, x in r.items() if k != "change_auc"} for r in rows]
    (w,) = verdicts(old)
    assert w["rule"].startswith("paired") and w["detectable"] == w["rose"]


@pytest.mark.slow
def test_a_small_frontier_runs_end_to_end_and_resumes(tmp_path, fmu_dir):
    """One kind, one member, one operating point, 3 gearboxes, short runs, a ladder of 2: the rounds end,
    the report is written, and a second invocation reuses every run."""
    study = F.FrontierStudy(("pit",), ("pinion",), (1500.0,), (1.31,), 3, 1.2, 0.2, (0.5, 2.0))
    a = F.run_frontier(study, tmp_path, workers=2, fmu_dir=fmu_dir, progress=False)
    assert len(a["cells"]) == 1 and 1 <= len(a["rounds"]) <= 2
    assert a["runs"] == 3 * (2 + len(a["cells"][0]["sizes_run"]))
    b = F.run_frontier(study, tmp_path, workers=2, fmu_dir=fmu_dir, progress=False)
    assert b["cells"] == a["cells"]
    assert all(r["reused"] == r["runs"] for r in b["rounds"])
    md = F.report_markdown(a, study, {"command": "x", "workers": 2, "wall_time_s": 1.0, "core_hours": 0.0})
    assert "| pit | pinion | 1500 rpm | 1.31 N·m |" in md


def test_what_moved_reads_the_earlier_paired_table(tmp_path):
    """The comparison against an earlier paired study: a family the paired rise saw and the frontier does not see
    at x1 is "lost", the other way "gained"; operating points the earlier study did not run are left out."""
    csv = tmp_path / "auc.csv"
    csv.write_text("family,kind,member,size,speed_rpm,load_Nm,indicator,n,paired_auc,same_noise_auc,unpaired_auc\n"
                   "void_pinion_default,void,pinion,default,1500.0,1.31,a,20,0.95,0.5,0.5\n"
                   "void_pinion_default,void,pinion,default,1500.0,1.31,b,20,0.60,0.5,0.5\n"
                   "pit_pinion_default,pit,pinion,default,1500.0,1.31,a,20,0.70,0.5,0.5\n"
                   "pit_pinion_small,pit,pinion,small,1500.0,1.31,a,20,0.99,0.5,0.5\n")
    cell = dict(member="pinion", speed_rpm=1500.0, load_Nm=1.31, at_or_below_smallest=False, monotone=True)
    result = {"cells": [
        {**cell, "kind": "void", "frontier_factor": None, "beyond": True, "scores": {"2": 0.7}},
        {**cell, "kind": "pit", "frontier_factor": 0.5, "beyond": False, "scores": {"0.25": 0.6, "0.5": 0.92, "1": 0.97}},
        {**cell, "kind": "crack", "load_Nm": 11.9, "frontier_factor": 1.0, "beyond": False, "scores": {}},
    ]}
    md = F.compare_markdown(result, csv)
    assert "1 cells gained, 1 lost, 0 the same" in md
    assert "| void | pinion | 1500 rpm | 1.31 N·m | 0.95 (yes) | – (no) | not detectable up to severe | lost |" in md
    assert "| pit | pinion | 1500 rpm | 1.31 N·m | 0.70 (no) | 0.97 (yes) |" in md and "| gained |" in md
    assert "crack" not in md
