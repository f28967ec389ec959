"""Another bevel pair from its gear data ([gear.pair], issue 42): the rig's pair written out runs bit for bit as
the scene without it; the new pairs of scenarios/other_gearboxes reach the gear FMU, the drivetrain's steady
state follows their ratio, and their mesh line sits at z1·f1 (the pinion's speed measured from its encoder)."""
from __future__ import annotations

import numpy as np
import pytest

from drivetrain.models.eigen import gear_block
from drivetrain.rig.signals import spectrum_lowpass_Hz
from drivetrain.run.assemble import assemble
from drivetrain.run.runner import run_scene
from drivetrain.scene.load import load_scene

from _shared import EXAMPLE, ROOT

OTHER = ROOT / "scenarios" / "other_gearboxes"
RIG_WRITTEN = ["gear.pair.z_pinion=15", "gear.pair.z_wheel=60", "gear.pair.module_mm=3.0",
               "gear.pair.face_width_mm=25.0", "gear.pair.pressure_angle_deg=20.0", "gear.pair.shaft_angle_deg=90.0",
               "gear.pair.x_pinion=0.43", "gear.pair.addendum_coefficient=1.0", "gear.pair.dedendum_coefficient=1.25",
               "gear.pair.backlash_mm=0.075", "gear.pair.tip_radius_mm=0.2", "gear.pair.E_GPa=206.0",
               "gear.pair.nu=0.3", "gear.pair.layer_depth_mm=0.5"]
QUICK = ["time.duration_s=0.05", "time.settle_s=0.01", "outputs.plots=false", "outputs.aalto_csv=false"]


@pytest.mark.parametrize("fidelity", ["table", "analytic"])
def test_the_rig_pair_written_out_is_bit_identical(fidelity):
    base = load_scene(EXAMPLE, QUICK + [f"effects.mesh_contact={fidelity}"])
    written = load_scene(EXAMPLE, QUICK + [f"effects.mesh_contact={fidelity}"] + RIG_WRITTEN)
    assert written.gear.pair.is_rig
    assert assemble(written).components == assemble(base).components
    a = run_scene(base, None, backend="inprocess", progress=False, log=lambda m: None)
    b = run_scene(written, None, backend="inprocess", progress=False, log=lambda m: None)
    assert a.signals.keys() == b.signals.keys() and len(a.time) > 100
    for name in a.signals:
        assert np.array_equal(np.asarray(a.signals[name]), np.asarray(b.signals[name])), name


@pytest.mark.parametrize("name, z1, z2", [("pair_20_40_m4", 20, 40), ("miter_25_25", 25, 25)])
def test_a_new_pair_reaches_the_gear_and_the_drivetrain(name, z1, z2):
    scene = load_scene(OTHER / f"{name}.toml", ["time.duration_s=0.3"])
    spec = assemble(scene)
    gear = spec.components_of("GearContact")[0].parameters
    assert (gear["z_pinion"], gear["z_wheel"]) == (z1, z2)
    ss = spec.metadata["steady_state"]
    # an ideal lower pair at constant speed: speeds and torques in the ratio z2/z1 (no mesh loss in the balance)
    assert ss["w_prop"] == pytest.approx(ss["w_middle"] * z1 / z2, rel=1e-12)
    assert ss["T_msh"] == pytest.approx(ss["T_psh"] * z1 / z2, rel=1e-12)
    cf = spec.metadata["characteristic"]
    assert cf["f_GMF"] == pytest.approx(z1 * cf["f_MSH"]) and cf["f_PSH"] == pytest.approx(cf["f_MSH"] * z1 / z2)
    # the wheel starts where the pinion's angle over the ratio puts it (within the mesh's static deflection)
    assert gear["wheel_phi_start"] == pytest.approx(gear["pinion_phi_start"] * z1 / z2, abs=0.02)
    # drivetrain eigen: the mesh spring acts on theta_p - (z2/z1) theta_w
    blk = gear_block("gear", gear)
    assert blk.K[0, 1] / blk.K[0, 0] == pytest.approx(-z2 / z1, rel=1e-12)


def _line_amplitude(t, x, f):
    """Amplitude of the line at f [Hz] (Hann window, coherent gain corrected), by a DFT at exactly f."""
    w = np.hanning(len(x))
    return 2.0 * abs(np.sum(w * (x - x.mean()) * np.exp(-2j * np.pi * f * t))) / w.sum()


@pytest.mark.parametrize("name, z1", [("pair_20_40_m4", 20), ("miter_25_25", 25)])
def test_the_mesh_line_of_a_new_pair_sits_at_z1_f1(name, z1):
    """Kinematics: the drive- and propeller-shaft torques carry the mesh line at z1 times the pinion's speed f1,
    measured from the pinion's encoder (enc4), not the rig's 15 f1; the strongest line of the propeller torque
    between 40 Hz and 1 kHz is a harmonic of it."""
    scene = load_scene(OTHER / f"{name}.toml", ["time.duration_s=0.5", "time.settle_s=0.1", "outputs.plots=false"])
    res = run_scene(scene, None, backend="inprocess", progress=False, log=lambda m: None)
    t = np.asarray(res.time)
    m = t >= 0.1
    f1 = np.polyfit(t[m], np.asarray(res.signals["enc4"])[m], 1)[0] / (2 * np.pi)
    assert f1 == pytest.approx(1500.0 / 60.0 / 3.0, rel=0.01)          # the upper 1:3 at 1500 rpm
    f_mesh = z1 * f1
    for sensor in ("drive_shaft_torque", "propeller_shaft_torque"):
        x = np.asarray(res.signals[sensor])[m]
        tm = t[m]
        at_mesh = _line_amplitude(tm, x, f_mesh)
        band = np.linspace(40.0, 1000.0, 2000)
        floor = np.median([_line_amplitude(tm, x, f) for f in band])
        assert at_mesh > 10.0 * floor, (sensor, at_mesh, floor)
        assert at_mesh > 10.0 * _line_amplitude(tm, x, 15 * f1), sensor     # not the rig's 15 teeth
        # the local peak around z1 f1 is at z1 f1 (within a quarter of the 1/T resolution)
        near = np.linspace(f_mesh - 2.0 / (tm[-1] - tm[0]), f_mesh + 2.0 / (tm[-1] - tm[0]), 81)
        peak = near[np.argmax([_line_amplitude(tm, x, f) for f in near])]
        assert abs(peak - f_mesh) < 0.25 / (tm[-1] - tm[0]), (sensor, peak, f_mesh)
    # what the run reports reads the pair's frequencies: the summary's spectra and RunResult.spectrum
    spec_attrs = res.spectrum("propeller_shaft_torque").attrs
    assert spec_attrs["characteristic_frequencies"]["z1"] == z1
    assert spec_attrs["lowpass_Hz"] == pytest.approx(spectrum_lowpass_Hz(z1 * 1500.0 / 60.0 / 3.0))
    x = np.asarray(res.signals["propeller_shaft_torque"])[m]
    strongest = band[np.argmax([_line_amplitude(t[m], x, f) for f in band])]
    k = strongest / f_mesh
    assert abs(k - round(k)) < 0.03 and round(k) >= 1, (strongest, f_mesh)


@pytest.mark.parametrize("fidelity", ["analytic", "table"])
def test_manufacturing_errors_and_faults_are_drawn_on_a_new_pair(fidelity):
    """The errors are drawn per tooth of the pair's gears (20 and 40), with their pitch diameters m z (ISO 1328's
    tolerances depend on them), and the wheel starts on the errors' offset mesh (table: a grid no cache holds,
    so the start is the analytic guess offset by the errors, which once read the rig's teeth)."""
    scene = load_scene(OTHER / "pair_20_40_m4.toml", ["effects.manufacturing_errors=true",
                                                      f"effects.mesh_contact={fidelity}",
                                                      "numerics.map_points_per_pitch=17"])
    spec = assemble(scene)
    errors = spec.metadata["manufacturing_errors"]
    assert (len(errors["pinion_position_um"]), len(errors["wheel_position_um"])) == (20, 40)
    assert errors["source"]["pinion"]["pitch_diameter_mm"] == pytest.approx(4.0 * 20)
    assert errors["source"]["wheel"]["pitch_diameter_mm"] == pytest.approx(4.0 * 40)
    if fidelity == "table":
        assert spec.metadata["mesh_start"].startswith("guess")
    faulty = load_scene(OTHER / "pair_20_40_m4.toml", [
        "gear.health=faults",
        'gear.faults=[{kind="missing_tooth", member="pinion", tooth=17}, {kind="pit", member="wheel", tooth=33}]'])
    gear = assemble(faulty).components_of("GearContact")[0].parameters
    import json

    assert [f["tooth"] for f in json.loads(gear["faults"])] == [17, 33]   # teeth the rig's 15-tooth pinion lacks


def test_the_accuracy_choice_reads_the_study_of_the_scenes_own_pair():
    """The accuracy-cost errors are measured per pair: the rig's scenes choose from the rig's studied scenes, the
    20/40 pair's from its own (pair20x40_healthy_1500rpm), and a pair the study never ran is refused, saying so."""
    from drivetrain.run import accuracy

    results = accuracy.load_results()           # the shipped study
    rig = accuracy.choose(load_scene(EXAMPLE), 5.0, results)
    assert rig.setting and "pair" not in results["scenes"][rig.studied_scene]
    own = accuracy.choose(load_scene(OTHER / "pair_20_40_m4.toml"), 5.0, results)
    assert own.studied_scene == "pair20x40_healthy_1500rpm"
    assert results["scenes"][own.studied_scene]["pair"]["module_mm"] == 4.0
    with pytest.raises(ValueError, match="ran no scene of this"):
        accuracy.choose(load_scene(OTHER / "miter_25_25.toml"), 5.0, results)


def test_each_pair_has_its_own_contact_map_and_the_rig_keeps_its_shipped_one():
    """The map cache is keyed by the whole pair and layer: two pairs never share a map; the rig's scene still
    names the shipped seed map (the same file name as before [gear.pair] existed)."""
    from gearcontact_fmu.contact_map import map_file_name, seed_configurations, seed_path
    from gearcontact_fmu.params import MapGrid, MeshResolution

    def name(scene):
        return map_file_name(scene.gear.pair.params(), scene.gear.pair.pcm(), MeshResolution(), "healthy", {},
                             MapGrid(), "mm", None)

    rig = name(load_scene(EXAMPLE))
    assert rig == seed_path(seed_configurations()[0]).name and seed_path(seed_configurations()[0]).is_file()
    assert name(load_scene(EXAMPLE, RIG_WRITTEN)) == rig
    others = {name(load_scene(OTHER / f)) for f in ("pair_20_40_m4.toml", "miter_25_25.toml")}
    others |= {name(load_scene(EXAMPLE, ["gear.pair.E_GPa=210"])), name(load_scene(EXAMPLE, ["gear.pair.backlash_mm=0.1"]))}
    assert len(others) == 4 and rig not in others


@pytest.mark.parametrize("scene, name", [("pair_20_40_m4.toml", "20x40_m4"), ("miter_25_25.toml", "miter25_m3")])
def test_the_checked_pairs_are_the_scenes_pairs(scene, name):
    """docs/GEAR-CONTACT.md's checks of the other pairs (gearcontact_fmu.pair_check.OTHER_PAIRS) are of the
    scenes' own pairs, every gear datum equal."""
    from gearcontact_fmu.pair_check import other_pair

    assert load_scene(OTHER / scene).gear.pair.params() == other_pair(name)
