"""The master's stepping loop in C: one ctypes call per chunk of steps (``stepper.c``).

For the ``fmi`` backend the per-step work of :meth:`Master.run` (gather the inputs, per FMU
fmi2SetReal / fmi2DoStep / fmi2GetReal on the preallocated buffers, record ``y``) is a few raw FMI
calls; in Python they cost ~11 us a step. ``stepper.c`` does the same calls with the same values in
the same order (``t = (double)kk * H`` as Python's ``kk * H``), so the results are bit-identical.

The C source is compiled on first use with the C compiler (``$CC`` or gcc) into the cache
(``$BEVEL_CACHE_DIR`` or ~/.cache/bevel-drivetrain, ``stepper/stepper_<hash>.so``, the hash of the
source and the compiler call), atomically and once across processes. No compiler, a failed build or
load, or ``BEVEL_PY_STEPPER=1``: :func:`load_stepper` returns None and the master keeps its Python
loop (identical results, slower).
"""
from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np

_log = logging.getLogger(__name__)
SOURCE = Path(__file__).with_name("stepper.c")
CALLS = ("fmi2SetReal", "fmi2DoStep", "fmi2GetReal")    # the ``call`` index the C loop reports
_LOADED: dict[str, object] = {}                          # library path -> the C function (or None)


class _Fmu(ctypes.Structure):
    _fields_ = [("c", ctypes.c_void_p), ("set_real", ctypes.c_void_p), ("do_step", ctypes.c_void_p),
                ("get_real", ctypes.c_void_p), ("vr_in", ctypes.c_void_p), ("n_in", ctypes.c_size_t),
                ("u", ctypes.c_void_p), ("vr_out", ctypes.c_void_p), ("n_out", ctypes.c_size_t),
                ("y", ctypes.c_void_p)]


def compile_command(src: Path, out: Path, cc: str = "gcc") -> list[str]:
    """The compiler call (the flags of the native FMUs, drivetrain.fmu_build.native_gear.compile_command)."""
    return [cc, "-O2", "-fPIC", "-shared", "-std=c99", "-ffp-contract=off", "-fvisibility=hidden",
            str(src), "-o", str(out)]


def library_path() -> Path | None:
    """The compiled stepper in the cache, built now if missing; None if it cannot be built."""
    from gearcontact_fmu.locks import cache_dir, file_lock

    cc = shutil.which(os.environ.get("CC", "gcc"))
    if cc is None:
        return None
    src = SOURCE.read_bytes()
    key = hashlib.sha256(src + "\0".join(compile_command(Path("SRC"), Path("OUT"), cc)).encode()).hexdigest()[:16]
    d = cache_dir() / "stepper"
    d.mkdir(parents=True, exist_ok=True)
    out = d / f"stepper_{key}.so"
    if out.exists():
        return out
    with file_lock(d / "stepper.lock"):
        if out.exists():
            return out
        tmp = d / f".stepper_{key}.{os.getpid()}.so"
        try:
            proc = subprocess.run(compile_command(SOURCE, tmp, cc), capture_output=True, text=True, timeout=120)
            if proc.returncode != 0 or not tmp.exists():
                _log.debug("stepper build failed (%s): %s", proc.returncode, proc.stderr[-2000:])
                return None
            os.replace(tmp, out)
        finally:
            tmp.unlink(missing_ok=True)
    return out


def load_stepper():
    """The C chunk function, or None (BEVEL_PY_STEPPER=1, no compiler, build or load failure)."""
    if os.environ.get("BEVEL_PY_STEPPER", "") not in ("", "0"):
        return None
    try:
        path = library_path()
    except (OSError, subprocess.SubprocessError) as exc:
        _log.debug("stepper unavailable: %s", exc)
        return None
    if path is None:
        return None
    key = str(path)
    if key not in _LOADED:
        try:
            fn = ctypes.CDLL(key).stepper_run_chunk
            vp, i64 = ctypes.c_void_p, ctypes.c_int64
            fn.argtypes = [i64, i64, ctypes.c_double, vp, i64, vp, vp, vp, i64, vp, i64, vp, vp, i64, vp]
            fn.restype = ctypes.c_int
        except (OSError, AttributeError) as exc:
            _log.debug("stepper load failed: %s", exc)
            fn = None
        _LOADED[key] = fn
    return _LOADED[key]


class Stepper:
    """The C loop bound to one run's FMUs and buffers (every array kept alive here)."""

    def __init__(self, fn, slaves, H: float, y: np.ndarray, u: np.ndarray, gather: np.ndarray,
                 ext_idx: np.ndarray, ext_table: np.ndarray | None, rec: np.ndarray, ny: int):
        for a in (y, u, rec) + (() if ext_table is None else (ext_table,)):
            if a.dtype != np.float64 or not a.flags.c_contiguous:
                raise ValueError("stepper buffers must be C-contiguous float64 arrays")
        self._fn = fn
        self._fmus = (_Fmu * max(len(slaves), 1))(*[_Fmu(*s.raw_calls) for s in slaves])
        self._gather = np.ascontiguousarray(gather, dtype=np.intp)
        self._ext_idx = np.ascontiguousarray(ext_idx, dtype=np.intp)
        self._keep = (y, u, rec, ext_table)
        self._out = (ctypes.c_int64 * 4)()
        n_ext = 0 if ext_table is None else int(self._ext_idx.size)
        self._args = (float(H), ctypes.addressof(self._fmus), len(slaves), y.ctypes.data, u.ctypes.data,
                      self._gather.ctypes.data, int(self._gather.size), self._ext_idx.ctypes.data, n_ext,
                      None if ext_table is None else ext_table.ctypes.data, rec.ctypes.data, int(ny),
                      ctypes.addressof(self._out))

    def run(self, k: int, k_end: int) -> tuple[int, int, int, int] | None:
        """Steps k .. k_end-1; None when all are done, else (step, FMU index, call, status) of the
        first non-zero status (that step's calls before it done, the rest not)."""
        if self._fn(k, k_end, *self._args) == 0:
            return None
        o = self._out
        return int(o[0]), int(o[1]), int(o[2]), int(o[3])
