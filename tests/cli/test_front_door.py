"""The front door: the Python API and the README's example of it, commands that write where
they are told (shipped files only with --update-shipped, FMU folders with FMUs only, nothing in the
current folder), and words that say what is printed (--tolerance against the scene's own setting,
eigen's overdamped modes)."""
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import drivetrain
from drivetrain.fmu_build import fmus as F

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
EXAMPLE = ROOT / "scenarios" / "example.toml"


def _env(tmp_path: Path) -> dict:
    return {**os.environ, "BEVEL_CACHE_DIR": str(tmp_path / "cache"),
            "PYTHONPATH": os.pathsep.join([str(Path(drivetrain.__file__).parents[1]), os.environ.get("PYTHONPATH", "")])}


def _tree(d: Path) -> set:
    return {p.relative_to(d).as_posix() for p in d.rglob("*")}


# ------------------------------------------------------------------------------------------------
# the Python API
# ------------------------------------------------------------------------------------------------
def test_import_is_cheap_and_exports_the_api():
    """``import drivetrain`` loads none of the library (the names load their modules when first used);
    the API's names are there and an unknown name is an AttributeError."""
    code = ("import sys, drivetrain\n"
            "heavy = [m for m in ('numpy', 'pandas', 'drivetrain.scene.load', 'drivetrain.run.runner') if m in sys.modules]\n"
            "assert not heavy, heavy\n"
            "from drivetrain import load_scene, run_scene, sweep, RunResult, SweepResult\n"
            "assert {'load_scene', 'run_scene', 'sweep'} <= set(dir(drivetrain))\n"
            "print(run_scene.__module__, sweep.__module__)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["drivetrain.run.runner", "drivetrain.campaigns.sweep_api"]
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        drivetrain.nothing  # noqa: B018


def test_fmus_are_kept_where_the_package_says_not_in_the_current_folder(tmp_path, monkeypatch):
    """The default FMU directory does not depend on the current folder: a source checkout's fmus/, and for
    an installed package fmus/ in the user-level cache (native FMUs beneath it)."""
    from drivetrain.fmu_build.native_line import default_native_dir

    monkeypatch.chdir(tmp_path)
    assert F.default_fmu_dir() == ROOT / "fmus" and tmp_path not in F.default_fmu_dir().parents
    monkeypatch.setenv("BEVEL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(drivetrain, "__file__", str(tmp_path / "site-packages" / "drivetrain" / "__init__.py"))
    assert F.source_checkout() is None
    assert F.default_fmu_dir() == tmp_path / "cache" / "fmus"
    assert default_native_dir() == tmp_path / "cache" / "fmus" / "native"
    assert F.fmu_dir_or_default("mine") == Path("mine")


def test_a_run_as_a_dataframe_carries_its_units():
    import numpy as np

    from drivetrain.run.runner import RunResult
    from drivetrain.scene.load import load_scene

    scene = load_scene(EXAMPLE, ["time.settle_s=0.5"])
    t = np.arange(4) * 0.25
    r = RunResult(scene=scene, summary={}, time=t, signals={"drive_shaft_torque": t * 2, "gear.n_contact": t},
                  units={"drive_shaft_torque": "N.m"}, sources={}, cosim=None, spec=None)
    df = r.to_dataframe()
    assert list(df.columns) == ["drive_shaft_torque", "gear.n_contact"] and df.index.name == "time_s"
    assert df.attrs["units"] == {"time_s": "s", "drive_shaft_torque": "N.m", "gear.n_contact": ""}
    assert list(r.to_dataframe(settled_only=True).index) == [0.5, 0.75]
    assert df["drive_shaft_torque"].iloc[-1] == 1.5


def _readme_api_code() -> str:
    section = README.read_text().split("## Python API (notebooks)", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert blocks, "README.md: no python block in the section 'Python API (notebooks)'"
    return "\n".join(blocks)


#: appended to the README's block when the test runs it: what the block computed, for the test to check
_README_CHECK = """
if __name__ == "__main__":
    import json, os
    json.dump({"index": df.index.name, "units": df.attrs["units"], "last_t": float(df.index[-1]),
               "n_columns": len(df.columns), "runs": sorted(data["run"].unique()),
               "data_units": data.attrs["units"], "f_GMF": sp.attrs["characteristic_frequencies"]["f_GMF"],
               "spectrum_columns": list(sp.columns)}, open(os.environ["README_CHECK"], "w"))
"""


def test_the_readme_python_example_runs_and_writes_nothing_in_the_current_folder(tmp_path):
    """The README's notebook example as a user runs it: saved as a .py file and run with python in a
    fresh process from a fresh folder holding only the scene, with 0.3 s runs. It completes (a sweep's workers
    import the file again: the block keeps its work under the __main__ guard), the run writes nothing there
    (no fmus/), the sweep only its out/ directory; the DataFrames carry their units."""
    import json

    code = _readme_api_code()
    assert "time.duration_s=2" in code and 'if __name__ == "__main__":' in code
    code = code.replace("time.duration_s=2", "time.duration_s=0.3")
    cwd = tmp_path / "notebook"
    (cwd / "scenarios").mkdir(parents=True)
    shutil.copy(EXAMPLE, cwd / "scenarios")
    (tmp_path / "example.py").write_text(code + _README_CHECK)
    before = _tree(cwd)
    check = tmp_path / "check.json"
    env = {**_env(tmp_path), "MPLBACKEND": "Agg", "README_CHECK": str(check)}
    env.pop("BEVEL_CACHE_DIR")              # the FMUs and maps where a user's come from (the checkout's fmus/)
    p = subprocess.run([sys.executable, str(tmp_path / "example.py")], cwd=cwd, env=env, capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    new = _tree(cwd) - before
    assert new and all(q.split("/")[0] == "out" for q in new), sorted(new)
    got = json.loads(check.read_text())
    assert got["index"] == "time_s" and got["units"]["time_s"] == "s"
    assert got["units"]["drive_shaft_torque"] == "N.m" and got["units"]["enc1"] == "rad"
    assert got["last_t"] == pytest.approx(0.3) and got["n_columns"] == 7
    assert got["runs"] == ["rpm1500", "rpm500"]
    assert got["data_units"]["propeller_shaft_torque"] == "N.m" and got["data_units"]["time_s"] == "s"
    assert got["f_GMF"] == pytest.approx(125.0) and got["spectrum_columns"] == ["frequency_Hz", "amplitude"]


def test_the_readme_fmpy_commands_write_their_results(tmp_path, fmus_both_builds):
    """The README's fmpy commands as a shell runs them: each writes its --output-file."""
    text = README.read_text()
    section = text.split("## Using the FMUs from fmpy", 1)[1].split("\n## ", 1)[0]
    cmd = re.search(r"(fmpy simulate fmus/GearContact\.fmu.*?--output-file \S+)", section, re.S).group(1)
    standalone = re.search(r"`(unzip -p fmus/MotorLoad\.fmu.*?)`", section, re.S).group(1)
    fmus = tmp_path / "fmus"
    fmus.mkdir()
    for m in ("GearContact", "MotorLoad"):
        shutil.copy(fmus_both_builds[("pythonfmu", m)], fmus / f"{m}.fmu")
    (tmp_path / "examples").mkdir()
    shutil.copy(ROOT / "examples" / "gearcontact_input.csv", tmp_path / "examples")
    bindir = Path(sys.executable).parent
    env = {**_env(tmp_path), "PATH": f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}"}
    for line in (cmd.replace("\\\n", " "), " ".join(standalone.split())):
        p = subprocess.run(line, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
        assert p.returncode == 0, (line, p.stderr[-2000:])
        out = tmp_path / line.split("--output-file", 1)[1].split()[0]
        rows = out.read_text().splitlines()
        assert len(rows) > 10 and rows[0].startswith('"time"'), (line, rows[:2])


# ------------------------------------------------------------------------------------------------
# commands write to their output directory; shipped files only with --update-shipped
# ------------------------------------------------------------------------------------------------
def test_build_fmus_out_holds_only_the_fmus(tmp_path, monkeypatch, capfd):
    """``build-fmus --out DIR``: DIR holds the FMUs and nothing else (the build lock and the sources stamp
    live in the user-level cache), the current folder stays empty, and a run sees the FMU as fresh."""
    from drivetrain.cli import main

    cwd = tmp_path / "cwd"
    cwd.mkdir()
    # in this process (the folder is the point, not a fresh interpreter: 1.4 s of start-up saved); the lock
    # written beside the FMUs instead of the cache fails it (1 of 1)
    monkeypatch.chdir(cwd)
    monkeypatch.setenv("BEVEL_CACHE_DIR", str(tmp_path / "cache"))
    assert main(["build-fmus", "--out", "mine", "--only", "FlexibleShaft"]) == 0, capfd.readouterr().err
    assert _tree(cwd) == {"mine", "mine/FlexibleShaft.fmu"}
    assert F.stale_models(["FlexibleShaft"], cwd / "mine") == []


def test_validate_writes_its_report_into_out(tmp_path, monkeypatch, capfd):
    """``validate`` (here judging existing, empty runs) writes its report and figures into --out, not
    docs/ of the current folder, and leaves the shipped docs/VALIDATION.md alone."""
    from drivetrain.cli import main

    cwd = tmp_path / "cwd"
    for d in ("grid", "repeat"):
        (cwd / "out" / d).mkdir(parents=True)
        (cwd / "out" / d / "manifest.json").write_text('{"runs": []}')
    shipped = (ROOT / "docs" / "VALIDATION.md").read_bytes()
    # in this process (the folder is the point, not a fresh interpreter); the report written to docs/ of the
    # current folder instead of --out fails it (1 of 1)
    monkeypatch.chdir(cwd)
    monkeypatch.setenv("BEVEL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    main(["validate", "--judge-only", "--out", "out", "--gearboxes", "1", "--duration", "1", "--quiet"])
    p = capfd.readouterr()
    assert "wrote out/VALIDATION.md" in p.out, p.out + p.err
    assert (cwd / "out" / "VALIDATION.md").is_file() and (cwd / "out" / "figures" / "validation_spectra.png").is_file()
    assert {x.split("/")[0] for x in _tree(cwd)} == {"out"}
    assert (ROOT / "docs" / "VALIDATION.md").read_bytes() == shipped


def test_update_shipped_needs_a_checkout(tmp_path, monkeypatch, capsys):
    from drivetrain.cli import main

    monkeypatch.setattr(F, "source_checkout", lambda: None)
    monkeypatch.chdir(tmp_path)
    assert main(["validate", "--update-shipped", "--judge-only", "--out", "out", "--quiet"]) == 2
    assert main(["accuracy-cost", "--update-shipped", "--evaluate-only", "--out", "out", "--quiet"]) == 2
    assert main(["detectability", "--update-shipped", "--out", "out", "--quiet"]) == 2
    assert "--update-shipped rewrites the shipped reports of a source checkout" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_accuracy_cost_writes_into_out_and_the_shipped_files_only_when_asked(tmp_path, monkeypatch):
    """``accuracy-cost`` (its study replaced by canned results) writes report, plots and results into --out;
    the shipped results (which run --tolerance reads) and docs/ACCURACY-COST.md change only with
    --update-shipped."""
    from _shared import accuracy_results as _results

    from drivetrain.campaigns import accuracy_study as S
    from drivetrain.cli import main
    from drivetrain.run import accuracy as A

    monkeypatch.setattr(S, "run_study", lambda out, *a, meta=None, **k: {**_results(), "meta": dict(meta or {})})
    shipped = tmp_path / "package" / "accuracy_cost.json"
    shipped.parent.mkdir()
    shipped.write_text("{}")
    monkeypatch.setattr(A, "RESULTS_FILE", shipped)
    checkout = tmp_path / "checkout"
    (checkout / "docs").mkdir(parents=True)
    monkeypatch.setattr(F, "source_checkout", lambda: checkout, raising=False)
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    assert main(["accuracy-cost", "--out", "out", "--quiet"]) == 0
    assert shipped.read_text() == "{}" and not any((checkout / "docs").iterdir())
    assert {"out/ACCURACY-COST.md", "out/accuracy_cost.json", "out/figures"} <= _tree(cwd)
    assert {x.split("/")[0] for x in _tree(cwd)} == {"out"}
    assert main(["accuracy-cost", "--out", "out2", "--quiet", "--update-shipped"]) == 0
    assert '"healthy_1500rpm"' in shipped.read_text()
    assert (checkout / "docs" / "ACCURACY-COST.md").is_file() and (checkout / "docs" / "figures").is_dir()


def test_detectability_writes_its_report_into_out(tmp_path, monkeypatch):
    """``detectability`` (its runs and features replaced by one canned AUC row) writes report, AUC table and
    figure into --out, not docs/ of the current folder; the shipped docs/DETECTABILITY.md stays."""
    import drivetrain.campaigns.features as FE
    import drivetrain.campaigns.sweep as SW
    from drivetrain.campaigns import detectability as D
    from drivetrain.cli import main

    monkeypatch.setattr(SW, "run_sweep", lambda *a, **k: {"runs": []})
    monkeypatch.setattr(FE, "features", lambda d: [])
    monkeypatch.setattr(D, "auc_table", lambda rows, study: [
        {"family": "void_pinion_default", "kind": "void", "member": "pinion", "size": "default", "speed_rpm": 1500.0,
         "load_Nm": 1.31, "indicator": "FM4_pinion.propeller_shaft_torque", "n": 2, "paired_auc": 0.85,
         "unpaired_auc": 0.4}])
    shipped = (ROOT / "docs" / "DETECTABILITY.md").read_bytes()
    monkeypatch.chdir(tmp_path)
    assert main(["detectability", "--kinds", "void", "--members", "pinion", "--sizes", "default", "--speeds", "1500",
                 "--loads", "1.31", "--gearboxes", "2", "--out", "out", "--quiet"]) == 0
    assert _tree(tmp_path) == {"out", "out/DETECTABILITY.md", "out/detectability_auc.csv", "out/figures",
                               "out/figures/detectability.png"}
    assert (ROOT / "docs" / "DETECTABILITY.md").read_bytes() == shipped


# ------------------------------------------------------------------------------------------------
# words that say what is printed
# ------------------------------------------------------------------------------------------------
def test_tolerance_compares_its_choice_with_the_scenes_own_setting():
    """With the shipped results, 1 % picks H = 1/24000 s for the example: 1.9x the cost of the scene's own
    (default) setting, said so, not only "0.38x the reference"; 5 % picks a cheaper one; a scene already at
    the chosen setting is 1x; a scene whose numerics were not studied is compared with the studied defaults."""
    from drivetrain.run import accuracy as A
    from drivetrain.scene.load import load_scene

    scene = load_scene(EXAMPLE)
    c = A.choose(scene, 1.0)
    rows = A.load_results()["scenes"][c.studied_scene]["rows"]
    ratio = c.loop_s_per_s / rows["default"]["loop_s_per_s"]
    assert f"{ratio:.2g}x the scene's own setting (default" in c.why and "it costs more" in c.why
    assert A.own_setting(scene) == "default"
    assert c.own_setting == "default" and c.own_loop_s_per_s == rows["default"]["loop_s_per_s"]
    assert c.cost_vs_own == pytest.approx(c.loop_s_per_s / rows["default"]["loop_s_per_s"]) and c.cost_vs_own > 1
    assert f"{c.cost_vs_own:.2g}x the scene's own setting (default" in c.why and "it costs more" in c.why
    assert c.to_dict()["cost_vs_own"] == c.cost_vs_own
    cheap = A.choose(scene, 5.0)
    assert cheap.cost_vs_own < 1 and "the scene's own setting (default" in cheap.why and "costs more" not in cheap.why
    same = load_scene(EXAMPLE, list(A.SETTINGS[c.setting].overrides))
    assert A.own_setting(same) == c.setting and A.choose(same, 1.0).cost_vs_own == pytest.approx(1.0)
    odd = load_scene(EXAMPLE, ["numerics.comm_step_s=4.761904761904762e-05"])
    assert A.own_setting(odd) is None
    assert "the studied defaults" in A.choose(odd, 1.0).why


def test_eigen_reports_overdamped_modes_as_such(capsys):
    """The example's modes 7, 9, 10 and 11 are overdamped (the state matrix has four pairs of real
    eigenvalues besides the rigid-body pair): each says so with its damping ratio (>= 1), never nan, and no
    damped eigenvalue serves two modes; the header says the frequencies are undamped and zeta is damped."""
    import numpy as np

    from drivetrain.cli import main
    from drivetrain.models.eigen import describe_modes, modes
    from drivetrain.run.assemble import assemble
    from drivetrain.scene.load import load_scene

    assert main(["eigen", str(EXAMPLE)]) == 0
    out = capsys.readouterr().out
    assert not re.search(r"\bnan\b", out) and out.count("(overdamped)") == 4
    assert "undamped natural frequency" in out and "damping ratio of the mode" in out
    assert "excluded), undamped" not in out
    spec = assemble(load_scene(EXAMPLE), check=False)
    rows = describe_modes(spec, 12)
    over = [r["mode"] for r in rows if r["overdamped"]]
    assert over == [7, 9, 10, 11]
    assert all(np.isfinite(r["zeta"]) for r in rows)
    assert all((r["zeta"] >= 1) == r["overdamped"] for r in rows)
    f, _, ls, fd, _ = modes(spec, controller=False, damped=True)
    assert len(fd) == len(rows) - len(over)               # one complex pair per oscillating mode


def test_the_accuracy_report_states_costs_against_the_scenes_defaults():
    """The study's report says what a tolerance's choice costs against the scene as it runs without one."""
    from _shared import accuracy_results as _results

    from drivetrain.campaigns import accuracy_study as S

    md = S.report_markdown({**_results(), "meta": {}}, {})
    assert "Within 5 % / 5 dB: cheapest `fast` (0.9 s/s, 0.45x the scene's defaults, 0.23x the reference)." in md
    assert "`--update-shipped` rewrites this page" in md


def test_build_native_without_out_writes_to_the_fmu_directory_not_the_current_folder(tmp_path, monkeypatch, capfd):
    """``build-native SCENE`` with no --out: the FMUs go to native/ of the FMU directory (a source checkout's
    fmus/, else the user-level cache), as ``run --native`` finds them; the current folder stays empty (it
    wrote ./fmus/native before)."""
    from drivetrain.cli import main

    cwd = tmp_path / "cwd"
    cwd.mkdir()
    # in this process (the folder is the point, not a fresh interpreter); ./fmus/native as the default again
    # fails it (1 of 1)
    monkeypatch.chdir(cwd)
    rc = main(["build-native", str(EXAMPLE)])
    cap = capfd.readouterr()
    assert rc == 0, cap.err
    assert _tree(cwd) == set()
    wrote = re.findall(r"wrote (\S+\.fmu)", cap.out + cap.err)
    assert len(wrote) == 4, cap.out + cap.err
    assert all(Path(w).parent.resolve() == (F.default_fmu_dir() / "native").resolve() for w in wrote), wrote
