"""Any bevel pair from its gear data (issue 42): the rig's pair bit-identical, the placement and the exact
geometry at any shaft angle, and the library checks of the other pairs (gearcontact_fmu.pair_check.OTHER_PAIRS)
against independent oracles: the contact ratio against ISO 10300's virtual spur gears, the loaded mesh
stiffness against ISO 6336's c_gamma, the static transmission error against the analytic model.

The figures are the table "Other pairs" of docs/GEAR-CONTACT.md (``python -m pytest -s -m slow
tests/gear_contact/test_other_pairs.py`` prints them)."""
from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

from gearcontact_fmu import geometry as G
from gearcontact_fmu.pair_check import OTHER_PAIRS, iso10300_contact_ratio, other_pair, pair_problems
from gearcontact_fmu.params import BevelGearParams, MeshResolution

RIG = BevelGearParams()
#: sha256 of the rig's pitch cone, cone distance, derived tooth geometry, default meshes, placement, closure and
#: analytic-model data, computed by :func:`_rig_fingerprint` on 8d99096 (before any pair but the rig's existed)
RIG_FINGERPRINT = "989b7eb75806be78d101f91c071dad3e88151f8396d001b54c5acd6a524f3c0f"
#: a pair at an obtuse shaft angle (passes pair_check), for the placement and conjugacy checks
OBTUSE = BevelGearParams(z_pinion=30, z_wheel=40, face_width=20e-3, x_pinion=0.1, shaft_angle=math.radians(120.0))
#: the ends of the shaft-angle range (both pass pair_check)
ACUTE = BevelGearParams(z_pinion=20, z_wheel=40, face_width=20e-3, x_pinion=0.3, shaft_angle=math.radians(30.0))
FLAT = BevelGearParams(z_pinion=20, z_wheel=20, face_width=5e-3, x_pinion=0.0, shaft_angle=math.radians(150.0))
PAIRS = {"rig": RIG, **{n: other_pair(n) for n in OTHER_PAIRS}}
EXTRA = {"obtuse": OBTUSE, "acute30": ACUTE, "flat150": FLAT}


def _rig_fingerprint() -> str:
    from gearcontact_fmu.mesh_models.analytic import iso6336_stiffness, make_analytic_data

    P = BevelGearParams()
    h = hashlib.sha256()

    def add(a):
        h.update(np.ascontiguousarray(np.asarray(a, dtype=float)).tobytes())

    add([P.delta_pinion, P.delta_wheel, P.outer_cone_distance])
    for role in G.ROLES:
        g = G.gear_geometry(P, role)
        add([g.delta, g.delta_b, g.delta_a, g.delta_f, g.Re, g.omega0, g.psi_t, g.az_land, g.L_inv, g.s_pitch_param])
        m = G.build_gear_mesh(P, role, MeshResolution())
        add(m.vertices)
        add(m.face_points)
        add(m.face_normals)
    add(G.pinion_R0(P))
    add(G.wheel_R0(P))
    add(G.pinion_axis(P))
    add(G.wheel_axis(P))
    add(G.closure(np.linspace(0, 0.4, 7), +1, P))
    add(G.closure(np.linspace(0, 0.4, 7), -1, P))
    add(make_analytic_data(P)[0])
    add([iso6336_stiffness(P)["c_gamma"]])
    return h.hexdigest()


def test_rig_pair_is_bit_identical():
    """The rig's pair after the generalisation to any shaft angle: its pitch cone is still atan2(z1, z2), its
    cone distance, tooth geometry, meshes, poses, closure and analytic data hash as before."""
    assert RIG.delta_pinion == math.atan2(15, 60) == 0.24497866312686414
    assert RIG.outer_cone_distance == 0.09276987657639736
    assert np.array_equal(G.wheel_axis(RIG), [1.0, 0.0, 0.0])
    assert _rig_fingerprint() == RIG_FINGERPRINT


@pytest.mark.parametrize("shaft_deg", [30.0, 70.0, 89.0, 90.0, 120.0, 150.0])
def test_pitch_cones_at_any_shaft_angle(shaft_deg):
    """tan(delta_1) = sin S / (z2/z1 + cos S), delta_1 + delta_2 = S, and the cone distance is the same from
    either gear: m z1 / (2 sin delta_1) = m z2 / (2 sin delta_2) (the pitch circles of the outer end)."""
    S = math.radians(shaft_deg)
    p = BevelGearParams(z_pinion=18, z_wheel=31, shaft_angle=S)
    d1, d2 = p.delta_pinion, p.delta_wheel
    assert math.tan(d1) == pytest.approx(math.sin(S) / (31 / 18 + math.cos(S)), rel=1e-13)
    assert d1 + d2 == pytest.approx(S, rel=1e-15)
    assert p.outer_cone_distance == pytest.approx(p.module * 31 / (2 * math.sin(d2)), rel=1e-13)


@pytest.mark.parametrize("name", ["rig", "20x40_m4", "20x30_s70_m3", "obtuse", "acute30", "flat150"])
def test_placement_at_any_shaft_angle(name):
    """Both axes in the world XY plane at the shaft angle (between the pinion's teeth side +a1 and the wheel's
    -a2); the pitch line (body polar delta, azimuth 0 of both
    gears) is one world line; the pitch-point velocities are equal at omega_w = omega_p z1/z2, both positive."""
    P = EXTRA[name] if name in EXTRA else PAIRS[name]
    R0p, R0w = G.pinion_R0(P), G.wheel_R0(P)
    for R in (R0p, R0w):
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-15) and np.linalg.det(R) == pytest.approx(1.0)
    a1, a2 = G.pinion_axis(P), G.wheel_axis(P)
    assert np.allclose(R0w[:, 2], a2) and abs(a2[2]) == 0.0
    # the shaft angle is between the cone axes from the apex towards the teeth: +a1 (pinion), -a2 (wheel)
    assert math.acos(np.clip(a1 @ -a2, -1, 1)) == pytest.approx(P.shaft_angle, rel=1e-14)
    d1, d2 = P.delta_pinion, P.delta_wheel
    Pp = R0p @ np.array([math.sin(d1), 0.0, math.cos(d1)])
    Pw = R0w @ np.array([math.sin(d2), 0.0, -math.cos(d2)])
    assert np.allclose(Pp, Pw, atol=1e-15)
    assert math.acos(Pp @ a1) == pytest.approx(d1, rel=1e-12) and math.acos(-Pw @ a2) == pytest.approx(d2, rel=1e-12)
    ww = P.z_pinion / P.z_wheel
    assert np.allclose(np.cross(a1, Pp), np.cross(ww * a2, Pw), atol=1e-15)


@pytest.mark.parametrize("name", ["20x40_m4", "miter25_m3", "20x30_s70_m3", "obtuse", "acute30", "flat150"])
def test_exact_geometry_is_conjugate_at_any_shaft_angle(name):
    """The exact flanks placed at the shaft angle are conjugate (unloaded TE below 1 nm) and close at the
    backlash split equally (drive at +s_b/2, coast at -s_b/2): what a wrong axis, pose or cone would break."""
    P = EXTRA[name] if name in EXTRA else PAIRS[name]
    assert pair_problems(P) == []
    r = G.unloaded_transmission_error(P, n_theta=60)
    rc = G.unloaded_transmission_error(P, n_theta=30, flank=-1)
    sb = G.backlash_angle(P)
    assert r["te_pp"] < 1e-9 and rc["te_pp"] < 1e-9
    assert r["s_mean"] == pytest.approx(sb / 2, rel=1e-5)
    assert rc["s_mean"] == pytest.approx(-sb / 2, rel=1e-5)


#: the contact-ratio rule, the rig's since tests/gear_contact/test_geometry.py::test_contact_ratio (fixed
#: before the other pairs were computed): the exact geometry within 0.02 of the virtual spur gears' contact
#: ratio with the same active tip (the start of the tip rounding), and below the sharp-tip figure (the
#: rounding shortens the active profile). The rig has 1.4943 vs 1.4940 (2e-4) and 1.5499
CONTACT_RATIO_ABS_TOL = 0.02


@pytest.mark.parametrize("name", list(PAIRS))
def test_contact_ratio_against_iso10300(name):
    P = PAIRS[name]
    exact = G.contact_ratio(P)
    exact_coast = G.contact_ratio(P, flank=-1)
    iso_active = iso10300_contact_ratio(P)
    iso_sharp = iso10300_contact_ratio(P, active_tip=False)
    print(f"\n {name}: contact ratio exact {exact:.4f} (coast {exact_coast:.4f}); ISO 10300 virtual spur gears "
          f"{iso_active:.4f} (active tips), {iso_sharp:.4f} (tip circles); exact - ISO = {exact - iso_active:+.4f}")
    assert exact == pytest.approx(exact_coast, abs=1e-6)
    assert abs(exact - iso_active) < CONTACT_RATIO_ABS_TOL
    assert exact < iso_sharp
    assert exact > 1.0


# --------------------------------------------------------------------------------------------------------------
# the loaded mesh: the table model (the contact map of the PCM pair, with the tooth compliance) against ISO 6336
# and the analytic model. Each pair's healthy map is built once (a few seconds with compiled kernels) and cached.

#: the pinion torques of the paper's grid on the rig [N m]; a new pair is loaded at the same line loads
#: (tangential force at the virtual pinion's mean pitch radius per mm of face width), 1.8 .. 7.6 N/mm
PAPER_TORQUES_NM = (0.86, 1.3, 2.4, 3.71)
#: ISO 6336's reference line load [N/mm]: its low-load factor is 1 there, the analytic model is its c_gamma
ISO_LINE_LOAD = 100.0
#: the stiffness rule of tests/gear_contact/test_tooth_compliance.py (the rig): within 10 % of c_gamma with its
#: low-load factor at each of the paper's loads
STIFFNESS_REL_TOL = 0.10
#: the layer of each other pair is the rig's carried to its flank curvature (gearcontact_fmu.elastic_layer).
#: With the rig's 0.5 mm kept for every pair, 20x40_m4 (1.11 / 1.10 / 1.22 / 1.23) and miter25_m3 (1.03 / 1.07 /
#: 1.11 / 1.10) failed this rule (docs/GEAR-CONTACT.md, "Other pairs"): the rule stayed, the layer law came after


def _line_load_N_per_mm(gear, torque_Nm):
    from gearcontact_fmu.mesh_models.analytic import virtual_spur_gears

    return abs(torque_Nm) / virtual_spur_gears(gear)["r_m1"] / (gear.face_width * 1e3)


def _torque_at(gear, line_load):
    from gearcontact_fmu.mesh_models.analytic import virtual_spur_gears

    return line_load * virtual_spur_gears(gear)["r_m1"] * gear.face_width * 1e3


@pytest.fixture(scope="module")
def table_models():
    """{pair: table model with the default tooth compliance} (built on first use, from the map cache)."""
    return {}


def _table(table_models, name):
    import time

    from gearcontact_fmu.mesh_models import make_mesh_model
    from gearcontact_fmu.params import TOOTH_COMPLIANCE_FACTOR

    if name not in table_models:
        t0 = time.perf_counter()
        table_models[name] = make_mesh_model("table", PAIRS[name], tooth_compliance=TOOTH_COMPLIANCE_FACTOR)
        info = table_models[name].info
        print(f"\n {name}: table model in {time.perf_counter() - t0:.1f} s "
              f"({'cached map' if info.get('from_cache') else 'map built'})")
    return table_models[name]


def test_the_layer_of_a_pair_is_the_rigs_carried_by_its_flank_curvature():
    """The rig's pair (any backlash) keeps PCMParams() itself; a pair scaled by k has every radius k times the
    rig's, so its layer is sqrt(k) times as deep (b / sqrt(rho) fixed); a given layer is kept; a scene without a
    layer key gets the pair's, one with the key its own."""
    from drivetrain.scene.schema import GearPair
    from gearcontact_fmu.elastic_layer import layer_depth, pair_pcm, pitch_curvature_radius
    from gearcontact_fmu.params import PCMParams

    assert pair_pcm(RIG) is not None and pair_pcm(RIG) == PCMParams() and pair_pcm() == PCMParams()
    assert layer_depth(BevelGearParams(backlash=0.2e-3, tip_radius=0.1e-3, x_pinion=0.3)) == 0.5e-3
    for k in (0.5, 4 / 3, 2.0):
        P = BevelGearParams(module=RIG.module * k, face_width=RIG.face_width * k)
        assert pitch_curvature_radius(P) == pytest.approx(k * pitch_curvature_radius(RIG), rel=1e-12)
        assert layer_depth(P) == pytest.approx(0.5e-3 * math.sqrt(k), rel=1e-12)
    given = PCMParams(layer_depth=0.3e-3)
    assert pair_pcm(PAIRS["20x40_m4"], given) is given
    assert GearPair.of().pcm() == PCMParams()
    scene_pair = GearPair.of({"z_pinion": 20, "z_wheel": 40, "module_mm": 4.0, "x_pinion": 0.35})
    assert scene_pair.pcm().layer_depth == layer_depth(scene_pair.params()) > 0.6e-3
    assert GearPair.of({"z_pinion": 20, "layer_depth_mm": 0.4}).pcm().layer_depth == pytest.approx(0.4e-3)


#: a pair similar to the rig (every length 4/3 of the rig's: module 4 mm)
SIMILAR = BevelGearParams(module=RIG.module * 4 / 3, face_width=RIG.face_width * 4 / 3, backlash=RIG.backlash * 4 / 3,
                          tip_radius=RIG.tip_radius * 4 / 3)


@pytest.mark.slow
def test_the_layer_law_keeps_a_similar_pairs_stiffness():
    """The closed form of the layer's line contact (gearcontact_fmu.elastic_layer): at a fixed line load the
    approach goes as (b / sqrt(rho))^(2/3), so the secant stiffness per face width of the pair similar to the rig
    with the rig's 0.5 mm layer is (sqrt(4/3))^(2/3) = 1.10x that with its carried layer (within 2 %), and with
    its carried layer it is the rig's (within 6 %: the map's grid and the meshes' elements are not scaled).
    Rules set after a first measurement (1.094-1.103; 0.950-1.013), stated here."""
    from gearcontact_fmu.mesh_models import make_mesh_model
    from gearcontact_fmu.mesh_statics import static_mesh_stiffness
    from gearcontact_fmu.params import PCMParams, TOOTH_COMPLIANCE_FACTOR

    assert pair_problems(SIMILAR) == []
    models = {label: make_mesh_model("table", P, pcm, tooth_compliance=TOOTH_COMPLIANCE_FACTOR)
              for label, P, pcm in (("rig", RIG, None), ("carried", SIMILAR, None), ("fixed", SIMILAR, PCMParams()))}
    expected = (math.sqrt(4 / 3)) ** (2 / 3)
    for T_rig in PAPER_TORQUES_NM:
        w = _line_load_N_per_mm(RIG, T_rig)
        k = {label: static_mesh_stiffness(m, SIMILAR if label != "rig" else RIG,
                                          _torque_at(SIMILAR if label != "rig" else RIG, w))["mean"]
             for label, m in models.items()}
        print(f"\n {w:.1f} N/mm: rig {k['rig']:.3f}, similar pair with the carried layer {k['carried']:.3f}, with "
              f"the rig's {k['fixed']:.3f} N/(mm um); fixed / carried {k['fixed'] / k['carried']:.4f} "
              f"(closed form {expected:.4f})")
        assert k["fixed"] / k["carried"] == pytest.approx(expected, rel=0.02)
        assert k["carried"] / k["rig"] == pytest.approx(1.0, abs=0.06)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(PAIRS))
def test_loaded_mesh_stiffness_against_iso6336(table_models, name):
    """The loaded mesh stiffness of the table model (layers and tooth compliance; mean over a pitch) within 10 %
    of ISO 6336's c_gamma of the virtual spur gears (method B, with its low-load factor) at the line loads of the
    paper's torques on the rig: the rig's check (test_tooth_compliance) for every pair."""
    from gearcontact_fmu.mesh_models.analytic import iso6336_low_load_factor, iso6336_stiffness
    from gearcontact_fmu.mesh_statics import static_mesh_stiffness

    P = PAIRS[name]
    model = _table(table_models, name)
    c_gamma = iso6336_stiffness(P)["c_gamma"]
    ratios = []
    for T_rig in PAPER_TORQUES_NM:
        T = _torque_at(P, _line_load_N_per_mm(RIG, T_rig))
        k = static_mesh_stiffness(model, P, T)
        ratios.append(k["mean"] / (c_gamma * iso6336_low_load_factor(P, T)))
        assert k["double_single"] > 1.2            # the single/double alternation shows
    print(f"\n {name}: c_gamma {c_gamma:.2f} N/(mm um); k / (c_gamma LLF) at "
          f"{', '.join(f'{_line_load_N_per_mm(RIG, T):.1f}' for T in PAPER_TORQUES_NM)} N/mm: "
          f"{' '.join(f'{r:.3f}' for r in ratios)}")
    assert all(abs(r - 1.0) <= STIFFNESS_REL_TOL for r in ratios), ratios


def _static_te(model, gear, thetas, torque):
    """Static transmission error [m] along the line of action at the mean base radius, from the backlash-closed
    position, where ``model`` carries ``torque`` on the drive flank (mesh_statics.balanced_wheel_angle)."""
    from gearcontact_fmu.mesh_statics import balanced_wheel_angle

    r = gear.z_wheel / gear.z_pinion
    s = np.array([t - r * balanced_wheel_angle(model, r, t, -torque) for t in thetas])
    return (s - G.backlash_angle(gear) / 2) * G.mean_base_radius(gear)


#: the STE rule: the same period (one mesh pitch: the largest Fourier component over two pitches is the second)
#: in the table model, the analytic model and the PCM pair's own teeth (over two pitches different teeth carry,
#: equal within 2 % of the peak-to-peak); the same order of magnitude as the analytic model: mean and
#: peak-to-peak within a factor 1.5 at ISO's line load of 100 N/mm, within a factor 3 at the paper's heaviest
#: (the analytic model leaves out ISO's low-load factor: there the table is ~2.5x softer, the rig 2.57x)
STE_FACTOR_ISO_LOAD, STE_FACTOR_PAPER_LOAD = 1.5, 3.0


@pytest.mark.slow
@pytest.mark.parametrize("name", list(PAIRS))
def test_static_transmission_error_against_the_analytic_model(table_models, name):
    from gearcontact_fmu.mesh_models import make_mesh_model
    from gearcontact_fmu.mesh_models.pcm import build_pcm_pair, static_transmission_error

    P = PAIRS[name]
    table = _table(table_models, name)
    analytic = make_mesh_model("analytic", P)
    pitch = 2 * math.pi / P.z_pinion
    n = 24
    th = 0.013 + np.arange(2 * n) * pitch / n
    rows = []
    for w, factor in ((ISO_LINE_LOAD, STE_FACTOR_ISO_LOAD),
                      (_line_load_N_per_mm(RIG, PAPER_TORQUES_NM[-1]), STE_FACTOR_PAPER_LOAD)):
        T = _torque_at(P, w)
        te_t, te_a = _static_te(table, P, th, T), _static_te(analytic, P, th, T)
        for te in (te_t, te_a):
            assert int(np.argmax(np.abs(np.fft.rfft(te - te.mean())))) == 2       # one mesh pitch
        r_mean, r_pp = te_t.mean() / te_a.mean(), np.ptp(te_t) / np.ptp(te_a)
        rows.append(f"{w:.1f} N/mm: table {te_t.mean() * 1e6:.3f} / {np.ptp(te_t) * 1e6:.3f} um, analytic "
                    f"{te_a.mean() * 1e6:.3f} / {np.ptp(te_a) * 1e6:.3f} um (mean / p-p), ratios {r_mean:.2f} / {r_pp:.2f}")
        assert 1 / factor <= r_mean <= factor and 1 / factor <= r_pp <= factor, rows[-1]
    # the PCM pair's own teeth (not the map's tiled pitch): teeth -2..3 of the pinion, -3..3 of the wheel
    pair = build_pcm_pair(P, pinion_teeth=[k % P.z_pinion for k in range(-2, 4)],
                          wheel_teeth=[k % P.z_wheel for k in range(-3, 4)])
    te_p = static_transmission_error(pair, th, _torque_at(P, ISO_LINE_LOAD))["te"]
    assert int(np.argmax(np.abs(np.fft.rfft(te_p - te_p.mean())))) == 2
    assert np.max(np.abs(te_p[n:] - te_p[:n])) < 0.02 * np.ptp(te_p)
    print(f"\n {name}: STE " + "; ".join(rows) + f"; PCM pair's teeth: pitch-to-pitch "
          f"{np.max(np.abs(te_p[n:] - te_p[:n])) / np.ptp(te_p):.1e} of p-p")
