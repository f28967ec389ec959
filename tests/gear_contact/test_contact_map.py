"""The fixed-axis contact map ("table"): interpolation error against the online engine, disk cache."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gearcontact_fmu.contact_map import MapGrid, get_map
from gearcontact_fmu.mesh_models.table import make_table_data, table_eval
from gearcontact_fmu.mesh_models.base import N_OUT, OUT_TAU_PINION, OUT_TAU_WHEEL, OUT_STATUS
from gearcontact_fmu.mesh_models.pcm import build_pcm_pair
from gearcontact_fmu.params import BevelGearParams, MeshResolution, PCMParams

GEAR = BevelGearParams()
PCM = PCMParams()
RES = MeshResolution(profile=0.1e-3, face=2e-3)
GRID = MapGrid(points_per_pitch=24, s_points=24, max_torque=120.0)


# maps tabulated in one thread; the seed-map test keeps the threads (a build as a user's runs it)
pytestmark = pytest.mark.usefixtures("maps_tabulated_in_this_process")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    import os

    d = tmp_path_factory.mktemp("cache")
    old = os.environ.get("BEVEL_CACHE_DIR")
    os.environ["BEVEL_CACHE_DIR"] = str(d)
    yield d
    if old is None:
        os.environ.pop("BEVEL_CACHE_DIR")
    else:
        os.environ["BEVEL_CACHE_DIR"] = old


@pytest.fixture(scope="module")
def pair():
    return build_pcm_pair(GEAR, PCM, RES)


@pytest.fixture(scope="module")
def cmap(cache):
    return get_map(GEAR, PCM, RES, grid=GRID)


def test_interpolation_error_against_online(pair, cmap):
    """Report the table's error at random off-grid states under load (no damping/friction)."""
    rng = np.random.default_rng(1)
    data_el = pair.data_with(friction=False, damping=False)
    tdata = make_table_data(cmap, friction=False, damping=False)
    s_on = cmap.info["onset_drive"]
    span = cmap.info["span"]
    out_o = np.zeros(N_OUT)
    out_t = np.zeros(N_OUT)
    err, ref = [], []
    for _ in range(300):
        th = rng.uniform(0, 2 * math.pi)
        s = s_on + rng.uniform(0.05, 0.7) * span
        thw = (th - s) * GEAR.z_pinion / GEAR.z_wheel
        from gearcontact_fmu.contact import engine

        engine.fixed_axis_eval(data_el, th, thw, 0.0, 0.0, out_o)
        table_eval(tdata, th, thw, 0.0, 0.0, out_t)
        err.append(out_t[OUT_TAU_PINION] - out_o[OUT_TAU_PINION])
        ref.append(out_o[OUT_TAU_PINION])
    err = np.array(err)
    ref = np.array(ref)
    rms_rel = np.sqrt(np.mean(err**2)) / np.sqrt(np.mean(ref**2))
    max_rel = np.max(np.abs(err)) / np.max(np.abs(ref))
    print(f"\n table vs online: RMS error {100 * rms_rel:.2f} %, max error {100 * max_rel:.2f} % of max torque "
          f"({cmap.info['n_theta']} x {cmap.info['n_s']} grid)")
    assert rms_rel < 0.03
    assert max_rel < 0.10


def test_table_torque_ratio_and_backlash(cmap):
    out = np.zeros(N_OUT)
    tdata = make_table_data(cmap, friction=False, damping=False)
    # inside the backlash: no torque
    table_eval(tdata, 0.1, 0.1 * GEAR.z_pinion / GEAR.z_wheel, 0.0, 0.0, out)
    assert out[OUT_TAU_PINION] == 0.0 and out[OUT_TAU_WHEEL] == 0.0
    s = cmap.info["onset_drive"] + 0.3 * cmap.info["span"]
    table_eval(tdata, 0.1, (0.1 - s) * GEAR.z_pinion / GEAR.z_wheel, 0.0, 0.0, out)
    assert out[OUT_TAU_PINION] < 0 < out[OUT_TAU_WHEEL]
    assert out[OUT_TAU_WHEEL] == pytest.approx(-out[OUT_TAU_PINION] * GEAR.z_wheel / GEAR.z_pinion, rel=0.02)
    # NaN input: error status, no exception
    table_eval(tdata, float("nan"), 0.0, 0.0, 0.0, out)
    assert out[OUT_STATUS] != 0


def test_damping_dissipates(cmap):
    out = np.zeros(N_OUT)
    tdata = make_table_data(cmap, friction=False, damping=True)
    s = cmap.info["onset_drive"] + 0.3 * cmap.info["span"]
    th = 0.05
    thw = (th - s) * GEAR.z_pinion / GEAR.z_wheel
    table_eval(make_table_data(cmap, friction=False, damping=False), th, thw, 0.0, 0.0, out)
    tau0 = out[OUT_TAU_PINION]
    table_eval(tdata, th, thw, 1e-3, 0.0, out)  # closing: more resisting torque
    assert out[OUT_TAU_PINION] < tau0
    assert out[8] > 0


def test_cache_hit_and_key(cache, cmap):
    again = get_map(GEAR, PCM, RES, grid=GRID)
    assert again.info["from_cache"] is True
    np.testing.assert_array_equal(again.values, cmap.values)
    files = list(cache.glob("contactmap-*.npz"))
    assert len(files) == 1
    # another backlash is another key (not recomputed here: just the key)
    from gearcontact_fmu.contact_map import cache_key

    k1 = cache_key(GEAR, PCM, RES, "healthy", None, GRID)
    k2 = cache_key(BevelGearParams(backlash=0.1e-3), PCM, RES, "healthy", None, GRID)
    assert k1 != k2


def test_a_damaged_cache_file_is_named_and_rebuilt(cache):
    """A truncated cache file crashed without naming it; one with an altered array shape ran with exit
    code 0 and wrong torques. Now: load_map names the file and the problem, get_map moves the file
    aside and rebuilds the same map."""
    from gearcontact_fmu.contact_map import ContactMapFileError, cache_dir, cache_key, content_digest, load_map

    grid, res = MapGrid(points_per_pitch=2, s_points=8, max_torque=120.0), MeshResolution(profile=0.5e-3, face=5e-3)
    cmap = get_map(GEAR, PCM, res, grid=grid)                           # a coarse map: 0.25 s to rebuild
    path = cache_dir() / f"contactmap-{cache_key(GEAR, PCM, res, 'healthy', None, grid)}.npz"
    good = path.read_bytes()
    try:
        path.write_bytes(good[: len(good) // 2])                       # truncated
        with pytest.raises(ContactMapFileError, match=path.name):
            load_map(path, GEAR, PCM, grid)
        again = get_map(GEAR, PCM, res, grid=grid)
        assert "unreadable" in again.info["cache_problem"] and path.name in again.info["cache_problem"]
        np.testing.assert_array_equal(again.values, cmap.values)
        assert Path(str(path) + ".damaged").exists()

        def write(values, digest_of=None):
            arrays = {"theta": cmap.theta, "a": cmap.a, "onset": cmap.onset, "values": values}
            info = repr(cmap.info)
            digest = content_digest(digest_of or arrays, info)
            np.savez_compressed(path, **arrays, info=np.array(info), digest=np.array(digest))

        # same size, other shape, consistent digest: the layout check names it
        write(cmap.values.reshape(cmap.values.shape[0] * 2, 1, *cmap.values.shape[2:]))
        with pytest.raises(ContactMapFileError, match="values has shape"):
            load_map(path, GEAR, PCM, grid)
        again = get_map(GEAR, PCM, res, grid=grid)
        assert "values has shape" in again.info["cache_problem"]
        np.testing.assert_array_equal(again.values, cmap.values)

        # one finite value altered, the layout intact: only the content digest can tell
        altered = cmap.values.copy()
        altered[0, 0, 0, 0] += 1.0
        write(altered, digest_of={"theta": cmap.theta, "a": cmap.a, "onset": cmap.onset, "values": cmap.values})
        with pytest.raises(ContactMapFileError, match="does not match its digest"):
            load_map(path, GEAR, PCM, grid)
        again = get_map(GEAR, PCM, res, grid=grid)
        assert "digest" in again.info["cache_problem"]
        np.testing.assert_array_equal(again.values, cmap.values)

        # a file of an older writer (no digest) is rebuilt, not trusted
        np.savez_compressed(path, theta=cmap.theta, a=cmap.a, onset=cmap.onset, values=cmap.values,
                            info=np.array(repr(cmap.info)))
        with pytest.raises(ContactMapFileError, match="no content digest"):
            load_map(path, GEAR, PCM, grid)
    finally:
        path.write_bytes(good)


def test_a_map_file_holds_its_distinct_rows(cache, tmp_path):
    """A map is written as its distinct rows and each angle's index among them (a pitch tiled is one pitch
    on disk) and read back bit for bit; a file written whole (an older writer, a seed) still reads; an index
    that points outside the rows is named, not read."""
    from gearcontact_fmu.contact_map import (ContactMapFileError, content_digest, distinct_rows, load_map,
                                             save_map)

    grid, res = MapGrid(points_per_pitch=2, s_points=8, max_torque=120.0), MeshResolution(profile=0.5e-3, face=5e-3)
    cmap = get_map(GEAR, PCM, res, grid=grid)
    rows, index = distinct_rows(cmap.values)
    assert len(rows) == grid.points_per_pitch < len(cmap.values)     # healthy: one pitch, tiled
    np.testing.assert_array_equal(rows[index], cmap.values)
    path = tmp_path / "compact.npz"
    save_map(cmap, path)
    with np.load(path) as z:
        assert z["values"].shape[0] == len(rows) and z["value_rows"].shape == (len(cmap.values),)
    back = load_map(path, GEAR, PCM, grid)
    for name in ("theta", "a", "onset", "values"):
        np.testing.assert_array_equal(getattr(back, name), getattr(cmap, name))
    arrays = {"theta": cmap.theta, "a": cmap.a, "onset": cmap.onset, "values": cmap.values}
    info = repr(cmap.info)
    whole = tmp_path / "whole.npz"
    np.savez_compressed(whole, **arrays, info=np.array(info), digest=np.array(content_digest(arrays, info)))
    np.testing.assert_array_equal(load_map(whole, GEAR, PCM, grid).values, cmap.values)
    bad = tmp_path / "bad.npz"
    np.savez_compressed(bad, **{**arrays, "values": rows}, value_rows=index + len(rows), info=np.array(info),
                        digest=np.array(content_digest(arrays, info)))
    with pytest.raises(ContactMapFileError, match="value_rows"):
        load_map(bad, GEAR, PCM, grid)


def test_rows_tabulated_in_threads_are_the_rows_computed_one_chunk_after_another():
    """The map's rows are tabulated in threads, each chunk of rows with kernel data of its own, the meshes'
    trees shared: the result must be, bit for bit, the chunks computed one after another in one thread (no
    state shared between threads, none left from one chunk to the next), on a faulty pair with both flanks
    and a row subset."""
    from gearcontact_fmu import contact_map as cm

    grid, res = MapGrid(points_per_pitch=8, s_points=6, max_torque=120.0), MeshResolution(profile=0.5e-3, face=5e-3)
    pair = build_pcm_pair(GEAR, PCM, res, "faults", fault_kwargs={"faults": [{"kind": "pit", "member": "wheel",
                                                                              "tooth": 1}]})
    a, _ = cm._approach_grid(pair, grid)
    theta = np.linspace(0.0, 2 * math.pi / GEAR.z_pinion * 2, 25, endpoint=False)
    sides = np.ones((len(theta), 2), dtype=bool)
    sides[::3, 1] = False
    on_t, v_t = cm._tabulate(pair, theta, a, grid, workers=2, sides=sides)
    n_chunks = min(len(theta) - 1, max(4 * 2, (len(theta) - 1) // 6))      # the chunks _tabulate cuts
    chunks = [np.arange(1)] + np.array_split(np.arange(1, len(theta)), n_chunks)
    parts = [cm._tabulate_rows(pair, theta[idx], a, grid, sides[idx]) for idx in chunks]
    np.testing.assert_array_equal(on_t, np.concatenate([p[0] for p in parts]))
    np.testing.assert_array_equal(v_t, np.concatenate([p[1] for p in parts]))
    assert np.count_nonzero(v_t[::3, 1]) == 0 and np.count_nonzero(v_t[:, 0]) > 0


def test_missing_tooth_window_is_tabulated_as_early_engagement(cache):
    """In the no-contact window of a missing tooth the pinion runs ahead and the next tooth first
    touches at its tip, much further on than the nominal onset. The map must hold that onset and the
    response beyond it, matching the online engine there (a map that only covers the nominal range
    meets the next tooth by extrapolation: violent, unphysical impacts). The map here is coarser than the
    module's (0.2 mm mesh, 8 rows per pitch: the window row is a node row either way): a third of the build
    time for the same early onset (0.34 mm beyond the nominal one, measured with both)."""
    pitch = 2 * math.pi / GEAR.z_pinion
    res = MeshResolution(profile=0.2e-3, face=3e-3)
    grid = MapGrid(points_per_pitch=8, s_points=24, max_torque=120.0)
    cmap = get_map(GEAR, PCM, res, health="severe", grid=grid)
    pair = build_pcm_pair(GEAR, PCM, res, health="severe")
    i_win = int(round((2 * math.pi - 0.25 * pitch) / (cmap.theta[1] - cmap.theta[0])))
    th = float(cmap.theta[i_win])
    nominal = cmap.info["onset_drive"]
    assert cmap.onset[i_win, 0] > nominal + 0.2e-3        # > 3.7 µm further along the line of action
    data_el = pair.data_with(friction=False, damping=False)
    tdata = make_table_data(cmap, friction=False, damping=False)
    from gearcontact_fmu.contact import engine

    out_o = np.zeros(N_OUT)
    out_t = np.zeros(N_OUT)
    for frac in (0.2, 0.5):
        s = cmap.onset[i_win, 0] + frac * cmap.info["span"]
        thw = (th - s) * GEAR.z_pinion / GEAR.z_wheel
        engine.fixed_axis_eval(data_el, th, thw, 0.0, 0.0, out_o)
        table_eval(tdata, th, thw, 0.0, 0.0, out_t)
        assert out_o[OUT_TAU_PINION] < 0
        assert out_t[OUT_TAU_PINION] == pytest.approx(out_o[OUT_TAU_PINION], rel=0.02)   # theta on a node row
    # just before that onset: free flight in the table as in the engine
    s = cmap.onset[i_win, 0] - 1e-5
    thw = (th - s) * GEAR.z_pinion / GEAR.z_wheel
    table_eval(tdata, th, thw, 0.0, 0.0, out_t)
    engine.fixed_axis_eval(data_el, th, thw, 0.0, 0.0, out_o)
    assert out_t[OUT_TAU_PINION] == 0.0 and out_o[OUT_TAU_PINION] == 0.0


def _tiny_map_built_here(cache_dir: str) -> bool:
    import os

    os.environ["BEVEL_CACHE_DIR"] = cache_dir
    cm = get_map(GEAR, PCM, MeshResolution(profile=0.3e-3, face=3e-3),
                 grid=MapGrid(points_per_pitch=2, s_points=8, max_torque=120.0))
    return not cm.info["from_cache"]


def test_two_processes_build_one_map_once(tmp_path):
    """Two processes asking for the same new map both built it. Now the second waits for the
    first's build (a lock beside the cache file) and reads it."""
    import concurrent.futures as cf
    import multiprocessing as mp

    with cf.ProcessPoolExecutor(2, mp_context=mp.get_context("spawn")) as ex:
        built = list(ex.map(_tiny_map_built_here, [str(tmp_path)] * 2))
    assert sorted(built) == [False, True], built
    assert len(list(tmp_path.glob("contactmap-*.npz"))) == 1


@pytest.mark.parametrize("health, tooth, member", [("severe", 3, "pinion"), ("mild", 11, "pinion"),
                                                   ("faults", 21, "wheel")])
def test_map_computed_by_pitch_equals_every_row_computed(health, tooth, member):
    """The map computes one healthy pitch block, tiles it, and computes again the flank rows where a faulty
    tooth is in mesh. Oracle: every row tabulated by the engine. The fault sits on another tooth than
    the default, so a wrong engagement window would show. A wheel fault spans the tooth-pairing period
    (4 pinion revolutions), a pinion fault one revolution. Two rows per pitch (the least the grid takes): the
    blocks and the tiling are what is checked; the faulty rows (the blocks tooth - 1 and tooth: with local
    surgery the mild void differs only where the contact line crosses it) still differ from the healthy ones
    by more than 0.1 % of the largest torque."""
    from gearcontact_fmu import contact_map as cm

    res = MeshResolution(profile=0.3e-3, face=3e-3)
    # 3 approach nodes (was 10): a pitch shift of the wrong sign in the contact table fails 2 of these 3
    # tests, the tiled block taken one row late all 3
    grid = MapGrid(points_per_pitch=2, s_points=3, max_torque=120.0)
    kw = ({"tooth": tooth} if member == "pinion" else
          {"faults": [{"kind": "void", "member": "wheel", "tooth": tooth, "depth_mm": 0.3}]})
    pair = build_pcm_pair(GEAR, PCM, res, health=health, fault_kwargs=kw)
    fast = cm.compute_map(pair, grid)
    n_rev = 1 if member == "pinion" else GEAR.z_wheel // GEAR.z_pinion
    assert fast.info["pinion_revolutions"] == n_rev and len(fast.theta) == grid.points_per_pitch * 15 * n_rev
    # the rows recomputed are those where the faulty tooth is in mesh: blocks tooth - 1 and tooth, and a
    # neighbour where it meets its partner only deep in the approach range
    assert {tooth - 1, tooth} <= set(fast.info["fault_blocks"]) <= {tooth - 2, tooth - 1, tooth, tooth + 1}
    assert fast.info["built"] == "one pitch + fault rows" and fast.info["tiled_from_block"] is not None
    onset, vals = cm._tabulate(pair, fast.theta, fast.a, grid)
    scale = np.abs(vals).reshape(-1, vals.shape[-1]).max(axis=0)
    assert np.all(np.abs(fast.values - vals) <= 1e-6 * scale)
    np.testing.assert_allclose(fast.onset, onset, rtol=0, atol=1e-9)
    # the faulty blocks are really different from the tiled healthy ones (the check can fail)
    per = grid.points_per_pitch
    diff = max(np.abs(vals[b * per:(b + 1) * per, :, :, cm.CH_TAU_P] - vals[0:per, :, :, cm.CH_TAU_P]).max()
               for b in (tooth - 1, tooth))
    assert diff > 1e-3 * scale[cm.CH_TAU_P]


def test_healthy_map_computes_one_pitch():
    from gearcontact_fmu import contact_map as cm

    res = MeshResolution(profile=0.3e-3, face=3e-3)
    grid = MapGrid(points_per_pitch=2, s_points=3, max_torque=120.0)   # 3 nodes (was 10): the tiled block
    pair = build_pcm_pair(GEAR, PCM, res)                              # taken one row late fails it
    fast = cm.compute_map(pair, grid)
    assert fast.info["built"] == "one pitch" and fast.info["rows_computed"] == grid.points_per_pitch
    onset, vals = cm._tabulate(pair, fast.theta, fast.a, grid)
    scale = np.abs(vals).reshape(-1, vals.shape[-1]).max(axis=0)
    assert np.all(np.abs(fast.values - vals) <= 1e-6 * scale)
    np.testing.assert_allclose(fast.onset, onset, rtol=0, atol=1e-9)


def test_wheel_fault_map_follows_the_wheel_not_the_pinion(cache):
    """With a wheel fault the same pinion angle meets a faulty or a healthy wheel tooth depending on
    the revolution: the table must tell them apart (a map over one pinion revolution would fold the
    wheel fault onto every pinion revolution, the signature of a pinion fault)."""
    from gearcontact_fmu.mesh_models.table import make_table_model

    res = MeshResolution(profile=0.3e-3, face=3e-3)
    grid = MapGrid(points_per_pitch=4, s_points=10, max_torque=120.0)
    spec = {"kind": "missing_tooth", "member": "wheel", "tooth": 21}
    model = make_table_model(GEAR, PCM, res, health="faults", grid=grid, faults=[spec], friction=False,
                             damping=False)
    pitch = 2 * math.pi / GEAR.z_pinion
    r = GEAR.z_wheel / GEAR.z_pinion
    s = model.info["onset_drive"] + 0.5 * model.info["span"]
    out = np.zeros(N_OUT)
    torques = []
    for rev in range(4):                        # the same pinion angle in each of 4 pinion revolutions
        thp = 21 * pitch - 0.5 * pitch + 2 * math.pi * rev
        model.eval(model.data, thp, (thp - s) / r, 0.0, 0.0, out)
        torques.append(out[OUT_TAU_PINION])
    # wheel tooth 21 meets the pinion in the first revolution only: there one pair fewer carries at
    # the same deflection (72 vs 137 N·m measured)
    assert abs(torques[0]) < 0.9 * abs(torques[1])
    assert torques[1] == pytest.approx(torques[2], rel=1e-6) and torques[1] == pytest.approx(torques[3], rel=1e-6)


def test_sliding_pit_has_no_blind_spot():
    """A 1 mm wheel pit slid across one 2 mm face-row interval of the pinion in 0.5 mm steps (the
    sliding-pit study of benchmarks/sliding_pit.py, coarse profile): the peak torque deviation never
    drops to zero and varies smoothly (physics: the load along the face changes slowly). Without the
    pinion's extra face rows the same study shows zeros between rows (measured: 0.000 % at 11.5 and
    13.5 mm, 5 % at 11.25 mm; 11.5 mm is one of the positions here). With the rows, in 0.25 mm steps:
    1.59-1.71 %, neighbours within 1 % of the median; in 0.5 mm steps within 2 %."""
    import importlib.util

    root = Path(__file__).resolve().parents[2]
    spec = importlib.util.spec_from_file_location("sliding_pit", root / "benchmarks" / "sliding_pit.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    rows = mod.study("wheel", radius_mm=0.5, depth_mm=0.1, step_mm=0.5, lo_mm=11.0, hi_mm=13.0,
                     res=MeshResolution(profile=0.3e-3, face=2e-3))
    devs = np.array([d for _, d in rows])
    print("\n sliding pit, peak torque deviation [%]:", np.round(100 * devs, 3).tolist())
    assert [p for p, _ in rows] == pytest.approx([11.0, 11.5, 12.0, 12.5, 13.0])
    assert devs.min() > 0.5 * np.median(devs) and devs.min() > 1e-3
    assert np.max(np.abs(np.diff(devs))) < 0.2 * np.median(devs)


def test_a_wheel_mesh_file_alone_spans_the_pairing_period(tmp_path):
    """health = "mesh" with only a wheel mesh (it used to fail at start with "health must be one of
    ..."): the pinion is generated healthy, the map spans 4 pinion revolutions and, the file's teeth not
    being known copies of one tooth, every pitch block is computed."""
    from gearcontact_fmu import contact_map as cm
    from gearcontact_fmu import faults
    from gearcontact_fmu import geometry as G
    from gearcontact_fmu.meshes import save_mesh

    res = MeshResolution(profile=0.3e-3, face=3e-3)
    f = tmp_path / "wheel.obj"
    save_mesh(faults.missing_tooth(G.build_gear_mesh(GEAR, "wheel", res), 21), f)
    pair = build_pcm_pair(GEAR, PCM, res, health="mesh", wheel_mesh_file=str(f))
    # the smallest grid: what is checked is which blocks are computed, not the values
    m = cm.compute_map(pair, MapGrid(points_per_pitch=2, s_points=2, max_torque=120.0))
    assert m.info["pinion_revolutions"] == 4 and m.info["built"] == "every row"
    assert m.info["rows_computed"] == len(m.theta) and m.info["tiled_from_block"] is None


def test_seed_maps_are_what_a_build_gives(monkeypatch):
    """The maps shipped in gearcontact_fmu/data/seed_maps stand in for a build: each must carry the key
    the current code gives its configuration (else it is stale and silently unused) and hold what a
    fresh build computes (here, on this machine)."""
    from gearcontact_fmu import contact_map as cm

    monkeypatch.delenv("BEVEL_MAP_WORKERS", raising=False)       # the pool, as a user's build
    configs = cm.seed_configurations()
    expected = {cm.seed_path(c).name for c in configs}
    shipped = {p.name for p in cm.SEED_DIR.glob("contactmap-*.npz")}
    assert shipped == expected, (
        f"seed maps {sorted(shipped)} do not match the current cache keys {sorted(expected)} (the map code "
        "or a default changed): run python -c 'from gearcontact_fmu.contact_map import refresh_seed_maps; "
        "refresh_seed_maps()'")
    for config in configs:
        seed = cm.load_map(cm.seed_path(config), config["gear"], config["pcm"], config["grid"])
        fresh = get_map(config["gear"], config["pcm"], config["resolution"], config["health"],
                        grid=config["grid"], use_cache=False)
        # each output channel against its own scale: a build on another processor generation differs in the
        # last bits (numba vectorises the sums differently; measured up to 6e-9 of a channel's scale, on the
        # dissipated power at standstill whose scale is itself 8e-9 W, and <= 7e-12 elsewhere, on a znver4
        # against the machine that wrote the seed); 1e-8 is 1e4 x below any figure a run reports
        for name in ("theta", "a", "onset", "values"):
            a, b = getattr(seed, name), getattr(fresh, name)
            a, b = a.reshape(-1, a.shape[-1]) if name == "values" else a.reshape(-1, 1), \
                b.reshape(-1, b.shape[-1]) if name == "values" else b.reshape(-1, 1)
            scale = np.maximum(np.max(np.abs(b), axis=0), np.finfo(float).tiny)
            worst = np.max(np.abs(a - b), axis=0) / scale
            assert np.all(worst <= 1e-8), f"{name}: the seed map differs from a fresh build (relative {worst.max():.2e})"
        timing = {"build_seconds"}
        kept = {k: v for k, v in seed.info.items() if k not in timing}
        built = {k: v for k, v in fresh.info.items() if k in seed.info and k not in timing}
        assert kept.keys() == built.keys()
        for k, v in kept.items():      # computed figures (the span) to the same 1e-8, the rest exactly
            if isinstance(v, float):
                assert v == pytest.approx(built[k], rel=1e-8), k
            else:
                assert v == built[k], k


def test_a_cache_miss_of_a_seed_configuration_takes_the_shipped_map(tmp_path, monkeypatch):
    from gearcontact_fmu import contact_map as cm

    monkeypatch.setenv("BEVEL_CACHE_DIR", str(tmp_path))
    config = cm.seed_configurations()[0]
    got = get_map(config["gear"], config["pcm"], config["resolution"], config["health"], grid=config["grid"],
                  build=False)                          # only from the cache: None unless the seed came in
    assert got is not None and got.info["from_cache"]
    cached = tmp_path / cm.seed_path(config).name
    assert cached.read_bytes() == cm.seed_path(config).read_bytes()
