"""Which code computed a report: the git commit of the checkout the package runs from.

Every generated report (``drivetrain validate``, ``detectability``, ``accuracy-cost``, ``stress``) and every
sweep's manifest names it, so a figure in docs/ can be traced to the code that made it and reproduced there.
A run is reused by ``--resume`` only while the model sources are unchanged (the sweep's fingerprint), so the
commit a report names is the code its runs were computed with, up to changes outside the sources.

Outside a git checkout (an installed wheel) the answer says so and gives the package version instead.
"""
from __future__ import annotations

import functools
import subprocess
from pathlib import Path

from drivetrain import __version__

#: the checkout that holds this package when it runs from source: <root>/src/drivetrain/campaigns/provenance.py
_ROOT = Path(__file__).resolve().parents[3]


@functools.lru_cache(maxsize=1)
def code_commit() -> str:
    """The commit (12 hex digits) of the checkout, with ``+modified`` when ``src/`` differs from it; or
    ``unknown (...)`` with the package version when the package does not run from a git checkout."""
    if not (_ROOT / "src" / "drivetrain" / "__init__.py").is_file() or not (_ROOT / ".git").exists():
        return f"unknown (version {__version__}, not run from a git checkout)"
    try:
        head = subprocess.run(["git", "-C", str(_ROOT), "rev-parse", "--short=12", "HEAD"], capture_output=True,
                              text=True, timeout=30)
        if head.returncode != 0:
            return f"unknown (version {__version__}: git rev-parse failed: {head.stderr.strip()[:200]})"
        changed = subprocess.run(["git", "-C", str(_ROOT), "status", "--porcelain", "--untracked-files=no", "--", "src"],
                                 capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError) as exc:
        return f"unknown (version {__version__}: {type(exc).__name__}: {exc})"
    return head.stdout.strip() + ("+modified" if changed.stdout.strip() else "")


def commit_line() -> str:
    """The report line that names the code."""
    return f"- code: commit {code_commit()}"


__all__ = ["code_commit", "commit_line"]
