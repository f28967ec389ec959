"""Shared pieces of the ``hosts`` tests: our system run by another FMI tool, compared with our master.

A host loads the pythonfmu FMUs into its own process, so it runs in a subprocess (a crash there is a
failed test, not a lost test session). The host script prints one line ``RESULT <json>``; a host that
is installed but whose library does not load prints ``UNAVAILABLE <reason>`` and the test skips with
that reason. Signals are compared as our master records them: one sample every ``every`` steps, the
first after ``every`` steps (our record's sample 0 is the initial value and is left out).
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivetrain.run.assemble import sensor_map
from drivetrain.run.outputs import read_hdf5
from drivetrain.run.runner import run_scene

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"
SHORT = ["time.duration_s=0.5", "time.settle_s=0", "outputs.plots=false"]
TORQUES = ("drive_shaft_torque", "propeller_shaft_torque")
#: the example scene on another machine (issue 42): its lumped table and a drive tuned for it
ANOTHER_MACHINE = [f'drivetrain.parameters="{ROOT / "scenarios" / "other_gearboxes" / "heavy_propeller_machine.csv"}"',
                   "drivetrain.drive_Kp=0.2"]
#: ... and on a chain of its own (not the rig's layout: 9 nodes, rigid shafts, 3 FMUs)
ANOTHER_CHAIN = [f'drivetrain.parameters="{ROOT / "scenarios" / "other_gearboxes" / "thruster_machine.csv"}"',
                 'effects.shaft_flexibility="rigid"', "drivetrain.drive_Kp=0.5", "drivetrain.drive_Ti_s=0.3",
                 "drivetrain.drive_torque_limit_Nm=30"]


def torque_refs(scene) -> dict[str, list[str]]:
    """The two torque transducers as [instance, variable] of the assembled system."""
    sensors = sensor_map(scene.effects.shaft_flexibility)
    return {k: sensors[k].split(".", 1) for k in TORQUES}


def schedule(scene, spec) -> tuple[float, int, int]:
    """(communication step H, steps over the scene's duration, steps per recorded sample)."""
    H = spec.comm_step
    return H, round(scene.time.duration_s / H), round(1.0 / scene.time.sample_rate_Hz / H)


def master_torques(scene, out_dir, fmu_dir, backend: str = "fmi") -> dict[str, np.ndarray]:
    """Our master's torque transducers over the scene, without the initial sample."""
    res = run_scene(scene, out_dir, backend, progress=False, fmu_dir=fmu_dir)
    signals = read_hdf5(res.files["signals"])["signals"]
    return {k: np.asarray(signals[k])[1:] for k in TORQUES}


def run_host(script: str, *args, timeout: float = 600, tmpdir=None) -> dict:
    """Run a host script in a subprocess; its ``RESULT`` json (skips when it reports ``UNAVAILABLE``).
    ``tmpdir``: the subprocess's TMPDIR (Ecos extracts archives there and leaves them)."""
    env = None if tmpdir is None else {**os.environ, "TMPDIR": str(tmpdir)}
    r = subprocess.run([sys.executable, "-c", script, *map(str, args)], capture_output=True, text=True,
                       timeout=timeout, env=env)
    lines = r.stdout.splitlines()
    unavailable = [line[12:] for line in lines if line.startswith("UNAVAILABLE ")]
    if unavailable:
        pytest.skip(unavailable[0])
    assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-3000:])
    return json.loads(next(line for line in lines if line.startswith("RESULT "))[7:])


def relative_differences(theirs: dict, ours: dict) -> dict[str, tuple[float, float]]:
    """Per signal: (relative difference of the means, of the RMS values), theirs against ours."""
    out = {}
    for k, b in ours.items():
        a = np.asarray(theirs[k], dtype=float)
        b = np.asarray(b, dtype=float)
        assert len(a) == len(b), (k, len(a), len(b))
        out[k] = (abs(a.mean() / b.mean() - 1), abs(np.sqrt(np.mean(a * a) / np.mean(b * b)) - 1))
    return out


def assert_matches(theirs: dict, ours: dict, rel: float = 1e-4) -> dict[str, tuple[float, float]]:
    """Mean and RMS of every signal of ``ours`` within ``rel`` in ``theirs``; returns the differences."""
    diffs = relative_differences(theirs, ours)
    for k, (dm, dr) in diffs.items():
        assert dm <= rel and dr <= rel, f"{k}: mean differs by {dm:.2e}, RMS by {dr:.2e} (relative; allowed {rel:g})"
    return diffs
