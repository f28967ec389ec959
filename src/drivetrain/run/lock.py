"""An output folder in use is refused (issue 45): a run or a sweep holds a lock on its ``--out`` folder while it
writes, and a second writer gets an :class:`~drivetrain.errors.OutputLockedError` naming the holder.

The lock is ``OUT/.drivetrain.lock``: a POSIX ``flock`` held for as long as the writer's process lives (the system
releases it when the process ends, however it ends), and in the file the holder's pid, host, command and start
time, for the message. A lock whose holder is gone (killed) is stale: the next writer takes it over (``--resume``
or a fresh run alike; the run's own files say what the killed one left). Where ``flock`` is not supported (some
network file systems), the file alone decides: a holder on this host whose process is alive keeps it; a holder on
another host is taken to be alive unless ``takeover`` (``--resume``) is asked.
"""
from __future__ import annotations

import contextlib
import datetime
import json
import os
import socket
import sys
from pathlib import Path

from drivetrain.errors import OutputLockedError

LOCK_FILE = ".drivetrain.lock"


def _holder(path: Path) -> dict:
    try:
        doc = json.loads(path.read_text() or "{}")
        return doc if isinstance(doc, dict) else {}
    except (OSError, ValueError):
        return {}


def _alive(pid) -> bool:
    try:
        os.kill(int(pid), 0)
    except (ProcessLookupError, ValueError, TypeError, OverflowError):
        return False
    except PermissionError:
        return True
    return True


def holder_text(h: dict) -> str:
    return (f"process {h.get('pid', '?')} on {h.get('host', '?')} ({str(h.get('command') or '?')[:160]}, since "
            f"{h.get('started', '?')})")


def _refuse(out: Path, h: dict) -> OutputLockedError:
    return OutputLockedError(f"output folder {out} is in use by {holder_text(h)}: wait for it to finish, stop it, "
                             f"or choose another --out (the lock: {out / LOCK_FILE})")


@contextlib.contextmanager
def output_lock(out_dir: Path | str, takeover: bool = False):
    """Hold the lock of ``out_dir`` (created) for the ``with`` block; refuse with OutputLockedError naming the
    holder when another live process holds it. Re-entrant within one process (a sweep's in-process runs)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / LOCK_FILE
    key = str(path.resolve())
    if key in _HELD:                     # this process holds it already (nested): nothing to do
        yield
        return
    me = {"pid": os.getpid(), "host": socket.gethostname(), "command": " ".join(sys.argv)[:500],
          "started": datetime.datetime.now().isoformat(timespec="seconds")}
    fh = open(path, "a+")
    try:
        locked = _flock(fh)
        if locked is False:              # held by a live process
            raise _refuse(out, _holder(path))
        if locked is None:               # no flock here: the file decides
            h = _holder(path)
            same_host = h.get("host") == me["host"]
            if h.get("pid") not in (None, me["pid"]) and ((same_host and _alive(h["pid"])) or
                                                          (not same_host and not takeover)):
                raise _refuse(out, h)
        fh.seek(0)
        fh.truncate()
        fh.write(json.dumps(me))
        fh.flush()
        _HELD.add(key)
        try:
            yield
        finally:
            _HELD.discard(key)
            with contextlib.suppress(OSError):
                fh.seek(0)
                fh.truncate()
    finally:
        fh.close()                       # closing releases the flock


_HELD: set[str] = set()


def _flock(fh) -> bool | None:
    """True: locked; False: another process holds it; None: flock not supported here."""
    try:
        import fcntl
    except ImportError:                  # pragma: no cover - not POSIX
        return None
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False
    except OSError:
        return None


__all__ = ["output_lock", "LOCK_FILE", "holder_text"]
