"""An exclusive lock between processes on one machine (POSIX ``flock`` on a lock file): for the builds
that several processes may start at once (a contact map, an FMU) and that must happen once."""
from __future__ import annotations

import contextlib
from pathlib import Path


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
