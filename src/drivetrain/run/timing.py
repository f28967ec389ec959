"""Where a command's wall time goes: when its process started, so that the start-up (the interpreter and
the imports, before any of our code runs) counts too.

:func:`process_start` is a ``time.perf_counter()`` reading of the moment the process started (Linux:
``/proc/self/stat`` against ``/proc/uptime``, 10 ms resolution); elsewhere the moment this module was
first imported (the interpreter's own start, some 20 ms, is then missed). The command line passes it to
:func:`drivetrain.run.runner.run_scene` (``started``), whose ``summary["time_breakdown_s"]`` then begins
with ``startup``; the other commands print their parts from it. Imports nothing heavy.
"""
from __future__ import annotations

import os
import time

_IMPORTED = time.perf_counter()


def process_age_s() -> float | None:
    """Seconds since this process started (from /proc), None where that cannot be read."""
    try:
        with open("/proc/self/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()     # after the command name: field 3 (state) on
        with open("/proc/uptime") as f:
            uptime_s = float(f.read().split()[0])
        start_ticks = int(fields[19])                        # field 22: starttime, clock ticks after boot
        return max(0.0, uptime_s - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return None


def process_start() -> float:
    """The ``time.perf_counter()`` reading of this process's start (see the module's text)."""
    now = time.perf_counter()
    age = process_age_s()
    return _IMPORTED if age is None else min(now - age, _IMPORTED)

