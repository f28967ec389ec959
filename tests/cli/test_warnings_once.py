"""Each warning and each "wrote ..." once: the compiler fallback of ``run --native`` was said
while the run ran (the run's log) and again in the report after it (summary warnings); ``build-native``'s
"wrote PATH" came from the library's log and again from the command."""
import os
import re
import subprocess
import sys
from pathlib import Path

from drivetrain.cli import main

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "scenarios" / "example.toml"


def test_the_compiler_fallback_is_said_once(tmp_path, fmu_dir):
    """In a process of its own, as a user sees it (in pytest's process the library's logging is captured)."""
    env = {**os.environ, "CC": "no-such-cc",
           "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    r = subprocess.run([sys.executable, "-m", "drivetrain", "run", str(EXAMPLE), "--native", "--set",
                        "time.duration_s=0.02", "--no-plots", "--out", str(tmp_path / "o"), "--fmu-dir",
                        str(fmu_dir)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    said = r.stdout + r.stderr
    assert said.count("C compiler 'no-such-cc' not found") == 1, said
    assert "the run uses the pythonfmu FMUs" in said


def test_build_native_says_wrote_once_per_fmu(tmp_path, capsys):
    rc = main(["build-native", str(EXAMPLE), "--out", str(tmp_path)])
    cap = capsys.readouterr()
    assert rc == 0, cap.err[-2000:]
    said = cap.out + cap.err
    fmus = sorted(p.name for p in tmp_path.glob("*.fmu"))
    assert fmus == ["FlexibleShaft.fmu", "GearContact.fmu", "MotorLoad.fmu", "UpperTransmission.fmu"]
    for name in fmus:
        assert len(re.findall(rf"wrote \S*{name}", said)) == 1, said
