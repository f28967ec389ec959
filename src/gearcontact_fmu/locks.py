"""The disk cache of built things and an exclusive lock between processes on one machine (POSIX
``flock`` on a lock file): for the builds that several processes may start at once (a contact map, an
FMU, the master's C loop) and that must happen once. Light: imports nothing of the package."""
from __future__ import annotations

import contextlib
import os
from pathlib import Path


def cache_dir() -> Path:
    """The cache directory (``$BEVEL_CACHE_DIR`` or ``~/.cache/bevel-drivetrain``), created if missing."""
    d = Path(os.environ.get("BEVEL_CACHE_DIR", Path.home() / ".cache" / "bevel-drivetrain"))
    d.mkdir(parents=True, exist_ok=True)
    return d


@contextlib.contextmanager
def file_lock(path: Path | str):
    """Hold an exclusive lock on ``path`` (created if missing) for the ``with`` block."""
    import fcntl

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)
