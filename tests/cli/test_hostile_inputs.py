"""Bad input to the command line gets a message naming the problem and an exit code, never a traceback.
Cheap cases only: nothing here runs a simulation."""
from __future__ import annotations

from pathlib import Path

import pytest

from drivetrain.cli import main
from drivetrain.rig.data import MEASURED_CSV as MEASURED

ROOT = Path(__file__).resolve().parents[2]


def _rc(argv, capsys):
    try:
        rc = main(argv)
    except SystemExit as exc:          # argparse refuses with exit code 2
        rc = exc.code
    out = capsys.readouterr()
    return rc, out.out + out.err


def test_a_binary_file_as_scene(tmp_path, capsys):
    f = tmp_path / "scene.toml"
    f.write_bytes(bytes(range(256)) * 4)
    rc, text = _rc(["run", str(f), "--out", str(tmp_path / "o")], capsys)
    assert rc not in (0, None) and "UTF-8" in text and "Traceback" not in text


@pytest.mark.parametrize("value", ["-1", "0", "two"])
def test_workers_must_be_a_positive_count(tmp_path, capsys, value):
    rc, text = _rc(["sweep", str(ROOT / "scenarios" / "example.toml"), "--workers", value,
                    "--out", str(tmp_path / "o")], capsys)
    assert rc == 2 and "--workers" in text and ">= 1" in text
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("row, why", [("500,0.71", "has 2 fields"), (None, "is not a number")])
def test_calibrate_names_the_bad_row(tmp_path, capsys, row, why):
    lines = MEASURED.read_text().splitlines()
    data = [i for i, ln in enumerate(lines) if ln and not ln.startswith("#")]
    if row is None:                   # a non-numeric value in the first data row
        fields = lines[data[1]].split(",")
        fields[0] = "abc"
        lines[data[1]] = ",".join(fields)
    else:
        lines.append(row)
    bad = tmp_path / "m.csv"
    bad.write_text("\n".join(lines) + "\n")
    rc, text = _rc(["calibrate", str(bad), "--out", str(tmp_path / "c.json")], capsys)
    assert rc == 2 and why in text and "Traceback" not in text


def test_a_costly_scene_is_refused_before_it_runs_unless_forced(tmp_path, capsys):
    """max_substep_s = 1e-9 asks for 2e10 gear-stage sub-steps (hours): refused at once, naming the
    prediction, the key to change and --force; nothing is written."""
    out = tmp_path / "run"
    rc, text = _rc(["run", str(ROOT / "scenarios" / "example.toml"), "--set", "numerics.max_substep_s=1e-9",
                    "--out", str(out), "--quiet"], capsys)
    assert rc == 2 and "Traceback" not in text
    assert "predicted to take about" in text and "numerics.max_substep_s" in text and "--force" in text
    assert not out.exists()


def test_runcost_predicts_the_default_scene_cheap_and_online_pcm_costly():
    """The default 20 s scene runs in a few times its simulated time; 20 s of online PCM takes hours
    (measured here: 0.05 s in 19.5 s of loop) and is refused; 0.05 s of it is below the floor."""
    from drivetrain.run import cost as runcost
    from drivetrain.run.assemble import assemble
    from drivetrain.scene.load import load_scene

    def predict(scene, **kw):            # the counts are those of the assembled system
        return runcost.predict(assemble(scene), scene.time.duration_s, **kw)

    example = ROOT / "scenarios" / "example.toml"
    default = load_scene(example)
    c = predict(default)
    assert 1.0 < c.factor < runcost.REFUSE_FACTOR and runcost.refusal(c) is None
    pcm = load_scene(example, ["effects.mesh_contact=pcm"])
    c = predict(pcm)
    assert 3600 < c.total_s < 6 * 3600
    assert 'effects.mesh_contact = "table"' in runcost.refusal(c)
    short = load_scene(example, ["effects.mesh_contact=pcm", "time.duration_s=0.05"])
    assert runcost.refusal(predict(short)) is None
    # a measured contact model (mesh files, finer elements) replaces the default pcm figure
    c = predict(pcm, contact_reports=[{"estimate_s": 7200.0}])
    assert c.parts["contact model (measured on this machine)"] == 7200.0 and c.total_s < 7200.0 + 100
    # the sub-step advice names the scene's key, with the gear's sub-step
    fine = load_scene(example, ["numerics.max_substep_s=1e-9"])
    c = predict(fine)
    assert c.max_substep_s == 1e-9 and "numerics.max_substep_s (now 1e-09 s" in runcost.refusal(c)


def test_force_runs_a_refused_scene_and_says_so(monkeypatch):
    """With the limit lowered so that a 0.02 s run is 'too costly': refused without force, run with it,
    and the summary carries the forced prediction as a warning."""
    from drivetrain.run import cost as runcost
    from drivetrain.errors import ConfigurationError
    from drivetrain.run.runner import run_scene
    from drivetrain.scene.load import load_scene

    monkeypatch.setattr(runcost, "REFUSE_FACTOR", 1e-6)
    monkeypatch.setattr(runcost, "REFUSE_FLOOR_S", 0.0)
    scene = load_scene(ROOT / "scenarios" / "example.toml",
                       ["time.duration_s=0.02", "time.settle_s=0.005", "effects.mesh_contact=ideal",
                        "outputs.plots=false"])
    with pytest.raises(ConfigurationError, match="predicted to take"):
        run_scene(scene, None, backend="inprocess", progress=False)
    res = run_scene(scene, None, backend="inprocess", progress=False, force=True, log=lambda m: None)
    assert res.summary["status"] == "ok"
    assert any(w.startswith("forced: this run is predicted") for w in res.summary["warnings"])


def test_a_sweep_refuses_every_costly_case_before_any_run(tmp_path, capsys):
    grid = tmp_path / "grid.toml"
    grid.write_text((ROOT / "scenarios" / "example.toml").read_text() + """
[sweep]
name = "c_{numerics.max_substep_s:g}"
[sweep.axes]
"numerics.max_substep_s" = [1e-9, 2e-9, 5e-6]
""")
    out = tmp_path / "sweep"
    rc, text = _rc(["sweep", str(grid), "--out", str(out), "--quiet", "--workers", "1"], capsys)
    assert rc == 2 and "Traceback" not in text
    assert text.count("predicted to take about") == 2, text
    assert not (out / "manifest.json").exists()


def test_a_huge_communication_step_is_refused_not_computed():
    """One step of 1000 s blocked an FMU for 27 s; now it is refused at once with the reason."""
    import time

    from drivetrain.errors import ComponentError
    from drivetrain.models.components import make_component
    from gearcontact_fmu.stage import StageError, make_stage

    t0 = time.perf_counter()
    with pytest.raises(ComponentError, match="sub-steps"):
        make_component("UpperTransmission", {"w0": 10.0}).step(0.0, 1000.0)
    st = make_stage("analytic")
    st.initialize(0.0, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(StageError, match="sub-steps"):
        st.step(0.0, 1000.0, 0.0, 0.0, 0.0, 0.0)
    assert time.perf_counter() - t0 < 5.0


# ---- every scene key with values of the wrong kind: refused naming the key, or (where the value is a
# legitimate setting) accepted as given. Fast: validation only, nothing runs.
_BAD_VALUES = {
    "float": ["-1", "nan", "inf", '"fast"', "[1.0, 2.0]", "true", '"3 parsecs"', "0"],
    "int": ["-1", "1.5", '"x"', "0", "100000000"],
    "enum": ['"nonsense"', "1", '"../x"'],
    "bool": ['"yes"', "2", '"true"'],
    "str": ["1", '"a/b"', '".."', '"x\\u0000y"'],
    "str_list": ['"enc1"', '["nope"]', "[1]"],
    "var_list": ['["no_dot"]', '["gear.%n"]', '"x"'],
    "profile": ["[[0.0]]", "[[1.0, 0.0], [0.0, 1.0]]", '"x"', '[[0.0, "a"]]'],
    "path": ['"/nonexistent/x.obj"', "1", '"%n%s.obj"'],
    "table": ['"/nonexistent/x.csv"', "1", '"%n%s.csv"', '"."'],
}
# legitimate settings among them: free text, a drive held at standstill, a reversed or zero load, no
# settling time
_LEGITIMATE = {("scenario.description", '"a/b"'), ("scenario.description", '".."'),
               # a noise record's name is only hashed, never a path or a file name
               ("scenario.noise_name", '"a/b"'), ("scenario.noise_name", '".."'), ("scenario.noise_name", '"x\\u0000y"'),
               ("scenario.description", '"x\\u0000y"'), ("operating_point.drive_speed_rpm", "0"),
               ("operating_point.load_torque_Nm", "-1"), ("operating_point.load_torque_Nm", "0"),
               ("time.settle_s", "0"),
               # a growth label: any stage, a gearbox at the end of its life
               ("scenario.growth_stage", "0"), ("scenario.growth_stage", "100000000"), ("scenario.remaining_life", "0"),
               # no manufacturing errors of one kind, the finest grade, any seed, no measurement noise
               ("manufacturing.grade", "0"), ("manufacturing.runout_grade", "0"), ("manufacturing.seed", "0"), ("manufacturing.seed", "100000000"),
               ("manufacturing.single_pitch_um", "0"), ("manufacturing.runout_um", "0"), ("manufacturing.profile_um", "0"),
               ("instruments.seed", "0"), ("instruments.seed", "100000000"), ("instruments.encoder_lines", "100000000"),
               ("instruments.drive_torque_noise_Nm", "0"), ("instruments.propeller_torque_noise_Nm", "0"),
               # the measured background: any seed, no noise, no line, constant lines, undamped couplings
               ("background.seed", "0"), ("background.seed", "100000000"), ("background.load_noise_Nm_rtHz", "0"),
               ("background.drive_noise_Nm_rtHz", "0"), ("background.order_msh_1x_Nm", "0"),
               ("background.order_msh_2x_Nm", "0"), ("background.order_dsh_1x_Nm", "0"),
               ("background.order_dsh_2x_Nm", "0"), ("background.planetary_mesh_Nm", "0"),
               ("background.orders_speed_exponent", "0"), ("background.order_msh_1x_exponent", "0"),
               ("background.order_msh_2x_exponent", "0"), ("background.order_dsh_1x_exponent", "0"),
               ("background.order_dsh_2x_exponent", "0"), ("background.coupling_damping_scale", "0"),
               ("background.propeller_damping_scale", "0"),
               # a load motor without rotor inertia (the rig's default)
               ("drivetrain.load_motor_J_kgm2", "0")}


def _scene_key_cases():
    from drivetrain.scene.load import SCHEMA

    for sec, keys in SCHEMA.items():
        if sec in ("expect", "check"):
            continue
        for k, spec in keys.items():
            for v in _BAD_VALUES.get(spec.type, []):
                yield pytest.param(f"{sec}.{k}", v, id=f"{sec}.{k}={v}")


@pytest.mark.parametrize("key, value", list(_scene_key_cases()))
def test_scene_key_with_a_hostile_value(tmp_path, monkeypatch, key, value):
    from drivetrain.scene.load import ScenarioError, load_scene

    monkeypatch.chdir(tmp_path)
    example = ROOT / "scenarios" / "example.toml"
    if (key, value) in _LEGITIMATE:
        sc = load_scene(example, [f"{key}={value}"])
        sec, k = key.split(".")
        got = getattr(getattr(sc, sec), k)
        assert str(got) == value.strip('"').replace("\\u0000", "\x00") or float(got) == float(value)
    else:
        with pytest.raises(ScenarioError) as e:
            load_scene(example, [f"{key}={value}"])
        assert key in str(e.value)
    assert list(tmp_path.iterdir()) == []             # nothing written anywhere


@pytest.mark.parametrize("key, value", [("scenario.name", '".."'), ("operating_point.drive_speed_rpm", "nan"),
                                        ("gear.pinion_mesh", '"%n%s.obj"'), ("time.sample_rate_Hz", "0.001")])
def test_cli_refuses_before_writing(tmp_path, capsys, key, value):
    rc, text = _rc(["run", str(ROOT / "scenarios" / "example.toml"), "--set", f"{key}={value}",
                    "--out", str(tmp_path / "out")], capsys)
    assert rc == 2 and key in text and "Traceback" not in text
    assert not (tmp_path / "out").exists() and list(tmp_path.iterdir()) == []


_BAD_MESHES = {
    "garbage.stl": lambda: bytes((i * 97 + 13) % 256 for i in range(3000)),
    "face_index_out_of_range.obj": lambda: b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
    "half_truncated.obj": lambda: b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2\n",
    "truncated.stl": lambda: b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\n",
    "empty.obj": lambda: b"",
    "nan.obj": lambda: b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
}


@pytest.mark.parametrize("name", sorted(_BAD_MESHES))
def test_a_bad_mesh_file_is_an_error_naming_it(tmp_path, capsys, name):
    """Every unreadable or broken mesh file ends in a message naming the file and exit 2, wherever it is first
    read (the contact-cost check reads it before any step), never a traceback (fuzz pass: 18 of 23 mesh
    cases were tracebacks: IndexError, ValueError, a missing charset_normalizer)."""
    f = tmp_path / name
    f.write_bytes(_BAD_MESHES[name]())
    rc, text = _rc(["run", str(ROOT / "scenarios" / "example.toml"), "--set", "gear.health=mesh", "--set",
                    f'gear.pinion_mesh="{f}"', "--set", "time.duration_s=0.2", "--out", str(tmp_path / "o")], capsys)
    assert rc == 2 and "Traceback" not in text and name in text, text[-2000:]


def _bad_outs(tmp_path):
    f = tmp_path / "a_file"
    f.write_text("x")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere" / "gone")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    return {"existing file": f, "/dev/null": Path("/dev/null"), "dangling symlink": tmp_path / "dangling",
            "read-only": ro / "sub", "300 characters": tmp_path / ("n" * 300)}


@pytest.mark.parametrize("case", ["existing file", "/dev/null", "dangling symlink", "read-only", "300 characters"])
def test_a_bad_out_is_refused_before_the_simulation(tmp_path, capsys, case):
    """`drivetrain run --out` that cannot take the results is refused at once with its reason (the fuzz pass found it
    only after the whole simulation, as a traceback)."""
    import os
    import time

    out = _bad_outs(tmp_path)[case]
    if case == "read-only" and os.geteuid() == 0:
        pytest.skip("root writes into a read-only directory")
    t0 = time.perf_counter()
    rc, text = _rc(["run", str(ROOT / "scenarios" / "example.toml"), "--out", str(out), "--no-plots"], capsys)
    assert rc == 2 and "output directory" in text and "Traceback" not in text, text[-1500:]
    assert time.perf_counter() - t0 < 20                    # before the 20 s run, not after it


def test_a_deeply_nested_toml_is_a_scene_error(tmp_path, capsys):
    """5000 nested arrays in a scene file or an override: a message, exit 2, no RecursionError traceback."""
    f = tmp_path / "deep.toml"
    f.write_text("[operating_point]\ndrive_speed_rpm = " + "[" * 5000 + "]" * 5000 + "\n")
    rc, text = _rc(["run", str(f), "--out", str(tmp_path / "o")], capsys)
    assert rc == 2 and "nested less deeply" in text and "Traceback" not in text, text[-800:]
    rc, text = _rc(["run", str(ROOT / "scenarios" / "example.toml"), "--set",
                    "time.duration_s=" + "[" * 5000 + "]" * 5000, "--out", str(tmp_path / "o")], capsys)
    assert rc == 2 and "nested less deeply" in text and "Traceback" not in text, text[-800:]


def test_a_huge_grid_is_refused_at_once(tmp_path, capsys):
    """A grid of 10^6 cases is refused in well under a second, naming its size and the limit (fuzz pass: it
    neither started nor was refused within 90 s)."""
    import time

    f = tmp_path / "huge.toml"
    f.write_text('[sweep.axes]\n"operating_point.drive_speed_rpm" = [' + ", ".join(str(500.0 + i) for i in range(1000))
                 + ']\n"operating_point.load_torque_Nm" = [' + ", ".join(str(0.1 + i / 1000) for i in range(1000)) + "]\n")
    t0 = time.perf_counter()
    rc, text = _rc(["sweep", str(f), "--out", str(tmp_path / "o")], capsys)
    assert rc == 2 and "1000000 cases" in text and "at most 100000" in text, text[-800:]
    assert time.perf_counter() - t0 < 10 and not (tmp_path / "o").exists()


def test_a_corrupt_baseline_is_named(tmp_path):
    """A baseline file that is not HDF5 (or not ours) fails with its path in the message (fuzz pass: "bad
    superblock version number" alone)."""
    from drivetrain.campaigns.baseline import read_baseline

    bad = tmp_path / "example.baseline.h5"
    bad.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(200))
    with pytest.raises(ValueError, match="example.baseline.h5: not a readable baseline file"):
        read_baseline(bad)


@pytest.mark.parametrize("edit, why", [("zero", "a measured torque > 0"), ("negative_speed", "a drive speed > 0")])
def test_calibrate_refuses_rows_it_cannot_fit(tmp_path, capsys, edit, why):
    """All-zero torques (fuzz pass: a scipy message naming no row) and a negative speed (accepted, 187 % error)
    are refused naming the row."""
    lines = MEASURED.read_text().splitlines()
    hdr_i = next(i for i, ln in enumerate(lines) if ln and not ln.startswith("#"))
    hdr = lines[hdr_i].split(",")
    for i in range(hdr_i + 1, len(lines)):
        if not lines[i] or lines[i].startswith("#"):
            continue
        f = lines[i].split(",")
        if edit == "zero":
            for k in ("T_DSH_Nm", "T_PSH_Nm"):
                f[hdr.index(k)] = "0"
        elif i == hdr_i + 1:
            f[hdr.index("n_DSH_rpm")] = "-" + f[hdr.index("n_DSH_rpm")]
        lines[i] = ",".join(f)
    bad = tmp_path / "m.csv"
    bad.write_text("\n".join(lines) + "\n")
    rc, text = _rc(["calibrate", str(bad), "--out", str(tmp_path / "c.json")], capsys)
    assert rc == 2 and why in text and "data row 1" in text and "Traceback" not in text, text[-800:]
    assert not (tmp_path / "c.json").exists()


def test_a_file_size_limit_is_a_message_not_a_traceback(tmp_path):
    """`ulimit -f` (fuzz pass: a traceback from inside the FMU build or fmpy's unpacking): the command names the
    operation and the limit, exits 1, and the output directory does not say ok."""
    import resource
    import subprocess
    import sys

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (150_000, 150_000))

    r = subprocess.run([sys.executable, "-m", "drivetrain", "run", str(ROOT / "scenarios" / "example.toml"),
                        "--set", "time.duration_s=0.05", "--out", str(tmp_path / "o"), "--no-plots", "--quiet",
                        "--fmu-dir", str(tmp_path / "fmus")], capture_output=True, text=True, preexec_fn=limit,
                       timeout=300)
    assert r.returncode == 1, (r.returncode, r.stderr[-2000:])
    assert "Traceback" not in r.stderr and "File too large" in r.stderr and "ulimit -f" in r.stderr, r.stderr[-2000:]
    summary = tmp_path / "o" / "summary.json"
    assert not summary.exists() or '"ok"' not in summary.read_text()


def test_version(capsys):
    """`drivetrain --version` says the version, the Python and where the package is."""
    from drivetrain import __version__

    rc, text = _rc(["--version"], capsys)
    assert rc == 0 and f"drivetrain {__version__}" in text and "Python" in text
