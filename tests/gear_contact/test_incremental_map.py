"""A faulty contact map built from the healthy one equals the map computed row by row.

Oracle: every row and flank of the faulty pair tabulated by the engine (``contact_map._tabulate``), on the
healthy map's approach nodes. The incremental build (``compute_map(pair, grid, healthy=...)``) takes the
healthy rows and recomputes only the flank rows where a faulty tooth touches its partner; a wrong contact
table (a missed row, a wrong pitch shift) shows as a difference here. Coarse meshes, three rows per pitch and
two approach nodes (just short of the onset, the deepest), tabulated in this process (``$BEVEL_MAP_WORKERS``
= 1: the pool is not what is tested): what is checked is which rows are recomputed and that the rest equal
the healthy ones, not the values' convergence. Every family on both members, and faults on several teeth of
both gears at once; the faults sit on teeth other than 0, so a window guessed from tooth 0 would show.
"""
from __future__ import annotations

import numpy as np
import pytest

from gearcontact_fmu import contact_map as cm
from gearcontact_fmu.fault_specs import FAULT_KINDS
from gearcontact_fmu.mesh_models.pcm import build_pcm_pair
from gearcontact_fmu.params import BevelGearParams, MapGrid, MeshResolution, PCMParams

GEAR, PCM = BevelGearParams(), PCMParams()
RES = MeshResolution(profile=0.3e-3, face=3e-3)
GRID = MapGrid(points_per_pitch=3, s_points=2, max_torque=120.0)
#: (A contact table read too shallow, 0.02 of the deepest node instead of TOUCH_MARGIN, fails 14 of these
#: 16 tests; a pitch shift of the wrong sign fails 14.) On this grid (was 4 rows per pitch, 6 nodes: 63 CPU-s,
#: now 22) the too-shallow read fails 13 of 16, the wrong-sign shift 13 (the same with 3 nodes); with 2 rows per
#: pitch the too-shallow read failed only 2 (the rows at 0 and 1/2 pitch miss the patches' edges), so 3 rows.
#: "exact to rounding": tiled healthy rows and recomputed faulty rows against every row computed. Healthy
#: teeth are rotated copies of one tooth, so the same row a pitch apart differs by rounding (measured at
#: most 1e-8 of a channel's scale, the damping probe, a difference quotient; 6e-9 on this grid); onsets to
#: the search's 1e-10 (0 on this grid)
REL_TOL = 1e-6
ONSET_TOL = 2e-10


# maps and oracles tabulated in one thread (the small maps gain little from the threads)
pytestmark = pytest.mark.usefixtures("maps_tabulated_in_this_process")


@pytest.fixture(scope="module")
def healthy():
    return cm.compute_map(build_pcm_pair(GEAR, PCM, RES), GRID)


def _compare(faults, healthy, built="healthy map + fault rows"):
    pair = build_pcm_pair(GEAR, PCM, RES, health="faults", fault_kwargs={"faults": faults})
    inc = cm.compute_map(pair, GRID, healthy=healthy)
    assert inc.info["built"] == built
    onset, vals = cm._tabulate(pair, inc.theta, inc.a, GRID)
    scale = np.abs(vals).reshape(-1, vals.shape[-1]).max(axis=0)
    worst = (np.abs(inc.values - vals) / np.where(scale > 0, scale, 1.0)).max()
    assert worst <= REL_TOL, f"{faults}: largest difference {worst:.2e} of the channel scale"
    np.testing.assert_allclose(inc.onset, onset, rtol=0, atol=ONSET_TOL)
    # the fault is really in the map (the check can fail): some rows differ from the healthy pitch tiled
    per = GRID.points_per_pitch
    far = inc.info["contact_table_block"]
    tiled = np.tile(vals[far * per:(far + 1) * per], (len(inc.theta) // per, 1, 1, 1))
    assert np.abs(vals[..., cm.CH_TAU_P] - tiled[..., cm.CH_TAU_P]).max() > 1e-4 * scale[cm.CH_TAU_P]
    return inc


@pytest.mark.parametrize("member", ["pinion", "wheel"])
@pytest.mark.parametrize("kind", sorted(FAULT_KINDS))
def test_incremental_map_equals_every_row(kind, member, healthy):
    tooth = 6 if member == "pinion" else 41
    spec = {"kind": kind, "member": member, "tooth": tooth}
    if kind == "wear":
        spec["depth_um"] = 60.0          # the default 20 µm wears less than the coarse mesh resolves here
    if kind == "chipped_tip" and member == "pinion":
        # the default 0.5 mm chip lies inside the pinion's top 0.3 mm elements here: with the tooth no longer
        # re-meshed as a whole (local surgery), this coarse pair does not feel it (the default mesh does)
        spec["height_mm"] = 1.5
    if kind in ("pit", "spall", "crack", "chipped_tip") and member == "wheel":
        # a wheel pit, spall or crack gives every pinion tooth extra face rows (a chipped tip extra profile
        # nodes): not the healthy pinion; its own
        # healthy pitch block is computed and tiled, then the fault rows
        assert not cm.incremental_from_healthy(GEAR, "faults", None, {"faults": [spec]})
        inc = _compare([spec], None, built="one pitch + fault rows")
    else:
        inc = _compare([spec], healthy)
    # only the rows where the faulty tooth meets its partner: a few pitches, once (a wheel tooth meets the
    # pinion once in the four revolutions of the map)
    assert 0 < inc.info["flank_rows_computed"] <= 2 * 4 * GRID.points_per_pitch


def test_faults_on_several_teeth_of_both_gears(healthy):
    faults = [{"kind": "void", "member": "pinion", "tooth": 3},
              {"kind": "pit", "member": "pinion", "tooth": 9, "flank": "coast"},
              {"kind": "missing_tooth", "member": "wheel", "tooth": 17},
              {"kind": "spall", "member": "wheel", "tooth": 50, "flank": "coast"}]
    # the wheel spall gives every pinion tooth face rows at its edges: the pair's own healthy pitch, tiled
    inc = _compare(faults, None, built="one pitch + fault rows")
    assert inc.info["pinion_revolutions"] == 4


def test_contact_table_shift_matches_a_direct_reading(healthy):
    """The teeth in contact a pitch block later are the same teeth shifted by one, on both gears: the rule
    the incremental build carries its contact table by (read directly here on two blocks)."""
    pair = build_pcm_pair(GEAR, PCM, RES)
    a_deep = cm.TOUCH_MARGIN * healthy.a[-1]
    per = GRID.points_per_pitch
    for i in range(per):
        for side, sign in ((cm.SIDE_DRIVE, 1.0), (cm.SIDE_COAST, -1.0)):
            on = healthy.onset[i, side] + sign * a_deep
            p0, w0 = cm._contact_teeth(pair, healthy.theta[i], on)
            for b in (1, 5):
                pb, wb = cm._contact_teeth(pair, healthy.theta[i] + b * 2 * np.pi / GEAR.z_pinion, on)
                assert p0 and w0
                assert pb == {(t + b) % GEAR.z_pinion for t in p0}
                assert wb == {(w + b) % GEAR.z_wheel for w in w0}
