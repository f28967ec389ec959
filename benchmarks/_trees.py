"""Run the same measurement in this tree and in another git revision, side by side (benchmarks only).

``worktree(rev)``: a temporary detached git worktree of ``rev``, removed afterwards.
``run_in_tree(tree, code, args)``: run ``code`` in a fresh Python process that imports the packages of
``tree/src``; the code prints one line ``RESULT <json>``, returned as a dict.
"""
from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@contextlib.contextmanager
def worktree(rev: str):
    with tempfile.TemporaryDirectory(prefix="bench_tree_") as tmp:
        wt = Path(tmp) / "tree"
        subprocess.run(["git", "worktree", "add", "-q", "--detach", str(wt), rev], cwd=ROOT, check=True)
        try:
            yield wt
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(wt)], cwd=ROOT, check=False)


def run_in_tree(tree: Path, code: str, args: list[str]) -> dict:
    env = dict(os.environ, PYTHONPATH=str(Path(tree) / "src"))
    proc = subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True, text=True, cwd=tree)
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    raise SystemExit(f"the run in {tree} failed (rc {proc.returncode}):\n{proc.stderr[-3000:]}")
