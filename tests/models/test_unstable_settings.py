"""Deliberately unstable settings: refused before running where the instability can be predicted
(a communication step beyond a cut's limit; a u_max the static load alone would exceed), with a message
naming the setting and the numbers, and nothing written."""
from __future__ import annotations

from pathlib import Path

import pytest

from drivetrain.models import stability
from drivetrain.cli import main
from drivetrain.cosim import ConfigurationError
from drivetrain.run.runner import assemble_scene, run_scene
from drivetrain.scene.load import load_scene

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"


def test_comm_step_beyond_the_cut_limit_is_refused_by_the_cli(tmp_path, capsys, fmu_dir):
    out = tmp_path / "out"
    rc = main(["run", str(EXAMPLE), "--set", "time.sample_rate_Hz=1000.0", "--set", "numerics.comm_step_s=1e-3",
               "--set", "time.duration_s=0.5", "--out", str(out), "--quiet", "--fmu-dir", str(fmu_dir)])
    err = capsys.readouterr().err
    assert rc == 2
    assert "unstable" in err and "spectral radius" in err
    assert not out.exists()


def test_u_max_below_the_static_penetration_is_refused_before_any_step(tmp_path, fmu_dir):
    scene = load_scene(EXAMPLE, ["time.duration_s=0.1"])
    spec = assemble_scene(scene)
    gear = next(c for c in spec.components if c.model == "GearContact")
    gear.parameters["u_max"] = 1e-7          # the static penetration at 1.31 N·m is ~0.37 µm
    with pytest.raises(ConfigurationError) as ei:
        run_scene(scene, tmp_path / "out", spec=spec, progress=False, fmu_dir=fmu_dir)
    msg = str(ei.value)
    assert "u_max = 1e-07 m" in msg and "static penetration" in msg and "N·m" in msg
    assert not (tmp_path / "out").exists()


def test_static_contact_is_reported_with_the_default_u_max():
    from drivetrain.rig import data as rig

    spec = assemble_scene(load_scene(EXAMPLE, ["time.duration_s=0.1"]))
    (rep,) = stability.check_contact_range(spec)
    assert rep["component"] == "gear" and rep["u_max_m"] == pytest.approx(1e-3)
    # the loaded pair at ~3.8 N·m pinion torque: a fraction of a micrometre, far below u_max
    assert 1e-8 < rep["static_penetration_m"] < 2e-6
