"""Saying so while numba compiles the contact kernels (a fresh install's, or a changed source's, first map build).

The kernels are compiled on their first call and cached on disk (``cache=True``: ``__pycache__`` beside the
sources, or ``$NUMBA_CACHE_DIR``); later processes load them in about a second. The first compile is long, and
silent unless someone says so: :func:`compiling` reports it through :mod:`gearcontact_fmu.progress` (the
command line shows a bar counting the seconds against :data:`COLD_COMPILE_S`) when :func:`kernels_cold` finds
no cached code for the kernel it is given (the contact engine's, ``engine.fixed_axis_eval``, which the first
map build compiles with everything it calls). The library never prints.
"""
from __future__ import annotations

import contextlib
import threading

from gearcontact_fmu import progress

#: seconds of a cold compile of the kernels (one core: numba compiles serially), measured with
#: benchmarks/bench_first_compile.py: 8 distinct-fault maps from an empty NUMBA_CACHE_DIR spent 56.7 and 53.2 CPU-seconds
#: more than from a warm one (two runs; 2026-11-28, after the kernels compiled once per argument type)
COLD_COMPILE_S = 60


def kernels_cold(kernel) -> bool:
    """True when numba has no usable cached code of ``kernel`` (a ``cache=True`` dispatcher): its first call
    compiles. False when it is cached, already compiled in this process, or when this cannot be told."""
    try:
        if kernel.signatures:
            return False
        return not kernel._cache._cache_file._load_index()
    except Exception:  # noqa: BLE001 - numba's cache internals moved: say nothing rather than fail
        return False


def notice_text(kernel) -> str:
    """What the bar (and a sweep's log) says while the kernels compile."""
    try:
        where = str(kernel._cache._cache_path)
    except Exception:  # noqa: BLE001
        where = "numba's cache"
    return (f"compiling the contact kernels (numba; once after an install or a change of the sources, cached in "
            f"{where}; about {COLD_COMPILE_S} s of one idle core)")


@contextlib.contextmanager
def compiling(kernel):
    """While the body runs, report the seconds of a cold compile of ``kernel`` against the estimate (a bar that
    counts up to :data:`COLD_COMPILE_S` and waits there); nothing when it is cached."""
    if not kernels_cold(kernel):
        yield
        return
    bar = progress.reporter(notice_text(kernel), COLD_COMPILE_S, unit=" s")
    done = threading.Event()

    def tick():
        shown = 0
        while not done.wait(1.0):
            if shown < COLD_COMPILE_S - 1:
                bar.update(1)
                shown += 1

    t = threading.Thread(target=tick, daemon=True)
    t.start()
    try:
        yield
    finally:
        done.set()
        t.join()
        bar.close()


__all__ = ["compiling", "kernels_cold", "notice_text", "COLD_COMPILE_S"]
