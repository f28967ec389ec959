"""A run into an existing --out says what it is: "running" from its start (an earlier run's files cleared), an
interrupt (SIGINT, SIGTERM) ends it "interrupted" with what it computed, exit 130; only a finished run says
"ok". Each case is a subprocess (signals)."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from drivetrain.run.outputs import read_hdf5

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module", autouse=True)
def _fmus_built(pythonfmu_fmus):
    """The session's FMUs built in ``fmu_dir`` (tests/conftest.py) before a test runs them."""


def _start(out: Path, fmu_dir: Path, duration: float = 60.0, quiet: bool = True):
    return subprocess.Popen([sys.executable, "-m", "drivetrain", "run", str(ROOT / "scenarios" / "example.toml"),
                             "--set", f"time.duration_s={duration}", "--set", "effects.mesh_contact=\"ideal\"",
                             "--no-plots", "--backend", "inprocess", "--fmu-dir", str(fmu_dir), "--out", str(out),
                             *(["--quiet"] if quiet else [])], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _status(out: Path):
    try:
        return json.loads((out / "summary.json").read_text()).get("status")
    except (OSError, ValueError):
        return None


def _wait_stepping(p, out: Path, seconds: float) -> None:
    """Until the run has been stepping a while (its summary says running; the loop then takes seconds)."""
    t0 = time.time()
    while _status(out) != "running" and time.time() - t0 < 120 and p.poll() is None:
        time.sleep(0.05)
    time.sleep(seconds)


#: the co-simulation's progress bar on stderr with a step count above zero ("co-sim 60 s:   5%| ... | 36.3k/720k")
_STEPPED = re.compile(r"co-sim [^|]*\|[^|]*\|\s*(?!0/)[0-9][0-9.]*[kM]?/")


class _StderrReader:
    """The child's stderr read as it comes (a thread), so that a test can wait for what the run says."""

    def __init__(self, p):
        self._chunks: list[bytes] = []
        self._thread = threading.Thread(target=self._read, args=(p.stderr.fileno(),), daemon=True)
        self._thread.start()

    def _read(self, fd):
        while chunk := os.read(fd, 65536):
            self._chunks.append(chunk)

    @property
    def text(self) -> str:
        return b"".join(self._chunks).decode(errors="replace")

    def wait_for(self, pattern, p, timeout_s: float = 120.0) -> None:
        t0 = time.time()
        while not pattern.search(self.text) and time.time() - t0 < timeout_s and p.poll() is None:
            time.sleep(0.05)

    def rest(self) -> str:
        self._thread.join(timeout=120)
        return self.text


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupted_run_keeps_what_it_computed(tmp_path, fmu_dir, sig):
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text(json.dumps({"status": "ok"}))       # an earlier run's
    (out / "sensors.csv").write_text("time\n0\n")
    # the run's own progress bar says when it steps (it used to be given 10 s after its start: 10 s of a
    # 60 s run computed for nothing); then half a second more of steps before the signal. (The command's
    # SIGINT/SIGTERM handler left uninstalled, cli.py: both cases fail with the shorter wait.)
    p = _start(out, fmu_dir, quiet=False)
    err_reader = _StderrReader(p)
    err_reader.wait_for(_STEPPED, p)
    time.sleep(0.5)
    assert p.poll() is None, err_reader.rest()[-2000:]
    p.send_signal(sig)
    p.wait(timeout=120)
    err = err_reader.rest()
    assert p.returncode == 130, err[-2000:]
    assert "interrupted at t =" in err and "Traceback" not in err, err[-2000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and signal.Signals(sig).name in s["failure"]["cause"]
    t = read_hdf5(out / "signals.h5")["time"]
    assert 0 < t[-1] < 60.0
    csv = out / "sensors.csv"                     # the earlier run's is gone (this run may write its own)
    assert not csv.exists() or csv.read_text() != "time\n0\n"


def test_a_killed_rerun_never_says_ok(tmp_path, fmu_dir):
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text(json.dumps({"status": "ok"}))
    p = _start(out, fmu_dir)
    _wait_stepping(p, out, 1.0)
    os.kill(p.pid, signal.SIGKILL)
    p.communicate()
    assert _status(out) == "running"


def test_ctrl_c_during_a_sweep_stops_it_without_tracebacks(tmp_path, fmu_dir):
    """Ctrl-C reaches every process of the terminal: the sweep's workers end the runs they are stepping as
    "interrupted" (what they computed written), start no other, print no traceback; the sweep exits 130 at
    once, its manifest written; --resume then runs what is missing. Each worker used to print its
    KeyboardInterrupt traceback, and the parent waited for the queued runs."""
    grid = tmp_path / "grid.toml"
    grid.write_text((ROOT / "scenarios" / "example.toml").read_text() + """
[sweep.axes]
"operating_point.drive_speed_rpm" = [500.0, 750.0, 1000.0, 1250.0, 1500.0]
""")
    out = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "drivetrain", "sweep", str(grid), "--set", "time.duration_s=60",
           "--set", "effects.mesh_contact=\"ideal\"", "--no-plots", "--backend", "inprocess", "--fmu-dir", str(fmu_dir),
           "--out", str(out), "--workers", "2", "--quiet"]
    # a terminal's Ctrl-C: SIGINT to the whole process group (SIGINT at its default, as in a shell)
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    t0 = time.time()
    while time.time() - t0 < 180 and p.poll() is None and not any(
            _status(d) == "running" for d in out.glob("*/") if d.is_dir()):
        time.sleep(0.1)
    time.sleep(2.5)                                   # the runs are stepping (a run starts stepping within 1 s)
    assert p.poll() is None, p.communicate()
    os.killpg(p.pid, signal.SIGINT)
    t_sig = time.time()
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err[-2000:]
    assert time.time() - t_sig < 30, "the sweep waited for its queued runs"
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    statuses = {d.name: _status(d) for d in out.iterdir() if d.is_dir()}
    assert "interrupted" in statuses.values(), statuses
    assert len(statuses) < 5 and "ok" not in statuses.values(), statuses      # the rest never started
    assert json.loads((out / "manifest.json").read_text())["complete"] is False
