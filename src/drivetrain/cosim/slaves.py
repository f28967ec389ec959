"""Slave adapters: the same four calls (set inputs, do step, get outputs, read) for both backends.

``FmiSlave``: an FMU through ``fmpy.fmi2.FMU2Slave`` with raw, batched ctypes calls and its log captured.
``InprocSlave``: the same pythonfmu ``Fmi2Slave`` class, imported from the FMU's resources
(``load_slave_class``), called directly in Python: the same results without the FMI layer.
"""
from __future__ import annotations

import collections
import ctypes
import functools
import importlib
import os
import sys
import traceback
from pathlib import Path

import numpy as np

from drivetrain.fmu_build.fmus import FMUInfo, extracted_dir
from drivetrain.cosim.plan import settable
from drivetrain.errors import FMI_STATUS, ConfigurationError, CosimError
from drivetrain.system import ComponentSpec


class _Log:
    """Per-instance log buffer, filled by the FMI logger callback or the in-process log queue."""

    def __init__(self, maxlen: int = 500):
        self.lines: collections.deque[str] = collections.deque(maxlen=maxlen)
        self.n_warnings = 0

    def add(self, status: int, category: str, message: str) -> None:
        st = FMI_STATUS[status] if 0 <= status < len(FMI_STATUS) else str(status)
        if status >= 1:
            self.n_warnings += 1
        self.lines.append(f"[{st}] {category + ': ' if category else ''}{message}")


class _LoggerRoutes:
    """The one FMI logger of this process: fmpy's C proxy in front of one Python callback, kept forever.

    FMUs log printf-style (a format and variadic arguments) that ctypes cannot receive, so fmpy puts a
    C function in front (``fmpy.logging.addLoggerProxy``). That proxy keeps the Python callback in **one
    global** of the library: each call re-points it, and a callback object that is later freed leaves
    every FMU of the process (ours, fmpy's default ones, a user's) calling freed memory at its next log
    message, which is a segmentation fault. So the proxy is set up once, with a callback that lives as
    long as the process, and each ``FmiCallbacks`` struct carries that proxy with its own key in
    ``componentEnvironment``, which FMUs pass back with every message. Messages under a key that is
    gone, or from FMUs on fmpy's default callbacks, are printed as fmpy prints them.

    Others re-point the global too: ``fmpy.simulate_fmu(..., logger=f)`` installs a callback of its own
    and frees it when it returns. So every new run points it back at this one (:meth:`get`).
    """

    _instance: "_LoggerRoutes | None" = None

    def __init__(self):
        import itertools
        import weakref

        from fmpy.fmi2 import fmi2CallbackLoggerTYPE

        self._routes: weakref.WeakValueDictionary[int, FmiCallbacks] = weakref.WeakValueDictionary()
        self._keys = itertools.count(1)
        self._callback = fmi2CallbackLoggerTYPE(self._dispatch)
        self.proxy = None

    @classmethod
    def get(cls) -> "_LoggerRoutes":
        """The process's routes, with fmpy's proxy pointed (again) at their callback."""
        if cls._instance is None:
            cls._instance = cls()
        cls._instance._install()
        return cls._instance

    def _install(self) -> None:
        """Point the library's global at this callback; ``proxy`` is then the C function in front of it."""
        from fmpy.fmi2 import fmi2CallbackFunctions
        from fmpy.logging import addLoggerProxy

        cb = fmi2CallbackFunctions()
        cb.logger = self._callback
        addLoggerProxy(ctypes.byref(cb))       # the global -> self._callback; cb.logger -> the C proxy
        self._proxied = cb                     # (keeps the struct the proxy function was read from)
        self.proxy = cb.logger

    def register(self, callbacks: "FmiCallbacks") -> int:
        key = next(self._keys)
        self._routes[key] = callbacks
        return key

    def _dispatch(self, env, instance, status, category, message):
        target = self._routes.get(env or 0)
        if target is None:
            from fmpy.fmi2 import printLogMessage

            printLogMessage(env, instance, status, category, message or b"")
            return
        target.log_message(instance, status, category, message)


class FmiCallbacks:
    """One fmi2CallbackFunctions struct for all instances of a run; routes log messages by instance name."""

    def __init__(self):
        from fmpy import calloc, free
        from fmpy.fmi2 import (
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2StepFinishedTYPE,
        )

        routes = _LoggerRoutes.get()
        self.logs: dict[str, _Log] = {}
        self._cb = fmi2CallbackFunctions()
        self._cb.logger = routes.proxy
        self._cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self._cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self._cb.stepFinished = fmi2StepFinishedTYPE()
        self._cb.componentEnvironment = routes.register(self)

    def log_message(self, instance, status, category, message):
        name = instance.decode("utf-8", "replace") if instance else "?"
        log = self.logs.setdefault(name, _Log())
        log.add(int(status), category.decode("utf-8", "replace") if category else "",
                message.decode("utf-8", "replace") if message else "")

    @property
    def struct(self):
        return self._cb


class Slave:
    """Common interface: ``set_fn() -> status``, ``step_fn(t, H, 1) -> status``, ``get_fn() -> status``."""

    name: str
    model: str
    log: _Log
    initialized: bool = False
    stepping: bool = False          # past exitInitializationMode (FMI's step mode: terminate is allowed)
    fatal: bool = False

    def set_parameters(self, params: dict) -> None: ...
    def set_values(self, names: list[str], values: list) -> None: ...
    def get_reals(self, names: list[str]) -> list[float]: ...
    def get_integers(self, names: list[str]) -> list[int]: ...
    def get_booleans(self, names: list[str]) -> list[bool]: ...

    def get_values(self, names: list[str]) -> list[float]:
        """The values of numeric variables of any type (Real, Integer, Boolean: a counter, a switch) as floats,
        one get call per type, in the order of ``names``."""
        by_type: dict[str, list[int]] = {}
        for i, n in enumerate(names):
            by_type.setdefault(self.info.variables[n].type, []).append(i)
        out = [0.0] * len(names)
        for typ, idx in by_type.items():
            got = self._get_typed(typ, [names[i] for i in idx])
            for i, v in zip(idx, got):
                out[i] = float(v)
        return out

    def _get_typed(self, typ: str, names: list[str]) -> list:
        if typ == "Real":
            return self.get_reals(names)
        if typ in ("Integer", "Enumeration"):
            return self.get_integers(names)
        if typ == "Boolean":
            return self.get_booleans(names)
        raise ConfigurationError(f"{self.name}: {', '.join(names)}: {typ} variables are not numbers")

    def setup(self, stop_time: float) -> None: ...
    def enter_init(self) -> None: ...
    def exit_init(self) -> None: ...
    def teardown(self) -> None: ...


class FmiSlave(Slave):
    def __init__(self, comp: ComponentSpec, info: FMUInfo, callbacks: FmiCallbacks):
        from fmpy.fmi2 import FMU2Slave

        self.name, self.model, self.info = comp.name, comp.model, info
        self.log = callbacks.logs.setdefault(comp.name, _Log())
        unzip = extracted_dir(info.path)
        self.fmu = FMU2Slave(guid=info.guid, unzipDirectory=unzip, modelIdentifier=info.model_identifier,
                             instanceName=comp.name)
        self.instantiated = False
        self._callbacks = callbacks
        self.fmu.instantiate(visible=False, callbacks=callbacks.struct, loggingOn=True)
        self.instantiated = True
        self.c = self.fmu.component
        f = self.fmu._functions
        self._sr, self._ds, self._gr = f["fmi2SetReal"], f["fmi2DoStep"], f["fmi2GetReal"]

    def _call(self, what: str, fn, *args, t: float = 0.0):
        try:
            return fn(*args)
        except Exception as exc:   # fmpy raises FMICallException for status > warning
            status = getattr(exc, "status", 3)
            if status >= 4:
                self.fatal = True
            raise CosimError(self.name, self.model, what, status, t, list(self.log.lines)) from None

    def setup(self, stop_time):
        self._call("fmi2SetupExperiment", self.fmu.setupExperiment, None, 0.0, stop_time)

    def set_parameters(self, params):
        by_type: dict[str, tuple[list, list]] = {}
        for n, v in settable(params, self.info.variables).items():
            vi = self.info.variables[n]
            by_type.setdefault(vi.type, ([], []))
            by_type[vi.type][0].append(vi.vr)
            by_type[vi.type][1].append(v)
        for typ, (vrs, vals) in by_type.items():
            if typ == "Real":
                self._call("fmi2SetReal", self.fmu.setReal, vrs, [float(v) for v in vals])
            elif typ in ("Integer", "Enumeration"):
                self._call("fmi2SetInteger", self.fmu.setInteger, vrs, [int(v) for v in vals])
            elif typ == "Boolean":
                self._call("fmi2SetBoolean", self.fmu.setBoolean, vrs, [bool(v) for v in vals])
            elif typ == "String":
                self._call("fmi2SetString", self.fmu.setString, vrs, [os.fspath(v) for v in vals])

    set_values = lambda self, names, values: self.set_parameters(dict(zip(names, values)))  # noqa: E731

    def get_reals(self, names):
        return self._call("fmi2GetReal", self.fmu.getReal, [self.info.variables[n].vr for n in names])

    def get_integers(self, names):
        return self._call("fmi2GetInteger", self.fmu.getInteger, [self.info.variables[n].vr for n in names])

    def get_booleans(self, names):
        return self._call("fmi2GetBoolean", self.fmu.getBoolean, [self.info.variables[n].vr for n in names])

    def enter_init(self):
        self._call("fmi2EnterInitializationMode", self.fmu.enterInitializationMode)
        self.initialized = True

    def exit_init(self):
        self._call("fmi2ExitInitializationMode", self.fmu.exitInitializationMode)
        self.stepping = True

    def bind(self, in_names, out_names, u: np.ndarray, u_off: int, y: np.ndarray, y_off: int):
        """Raw per-step calls on preallocated buffers (no allocation, no Python-level conversion)."""
        dp = ctypes.POINTER(ctypes.c_double)
        n_in, n_out = len(in_names), len(out_names)
        self._vin = (ctypes.c_uint * max(n_in, 1))(*[self.info.variables[n].vr for n in in_names])
        self._vout = (ctypes.c_uint * max(n_out, 1))(*[self.info.variables[n].vr for n in out_names])
        uptr = ctypes.cast(u.ctypes.data + 8 * u_off, dp)
        yptr = ctypes.cast(y.ctypes.data + 8 * y_off, dp)
        # private function objects for the same entry points: get/set without argtypes (every argument is
        # a ready ctypes object: no per-call conversion), doStep with its argument types (two doubles)
        addr = lambda f: ctypes.cast(f, ctypes.c_void_p).value  # noqa: E731
        raw = ctypes.CFUNCTYPE(ctypes.c_int)
        sr, gr = raw(addr(self._sr)), raw(addr(self._gr))
        ds = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_double, ctypes.c_double,
                              ctypes.c_int)(addr(self._ds))
        c = ctypes.c_void_p(self.c)
        self.set_fn = functools.partial(sr, c, self._vin, ctypes.c_size_t(n_in), uptr) if n_in else None
        self.step_fn = functools.partial(ds, c)
        self.get_fn = functools.partial(gr, c, self._vout, ctypes.c_size_t(n_out), yptr) if n_out else None
        # the same calls for the C stepping loop (drivetrain.cosim.stepper): addresses and counts
        self.raw_calls = (self.c, addr(self._sr), addr(self._ds), addr(self._gr), ctypes.addressof(self._vin),
                          n_in, u.ctypes.data + 8 * u_off, ctypes.addressof(self._vout), n_out,
                          y.ctypes.data + 8 * y_off)

    def teardown(self):
        errors = []
        if self.instantiated:
            # fmi2Terminate only from step mode (the FMI 2.0 state machine: refused in initialization mode)
            if self.stepping and not self.fatal:
                try:
                    self.fmu.terminate()
                except Exception as exc:
                    errors.append(f"terminate: {exc}")
            if self.fatal:
                # pythonfmu 0.7.0: freeing an instance after a fatal error (a Python exception inside the
                # FMU, cf. PythonFMU issues #68/#71 on exception and GIL handling) corrupts the interpreter
                # and crashes the process at a later garbage collection (measured again after the logger
                # fix: 1 of 2 runs of tests/cosim/test_master.py then test_ssp_export.py). The broken instance
                # is never called again; it is kept alive and not freed.
                _LEAKED.append(self.fmu)
                self.instantiated = False
                errors.append("instance not freed after a fatal error (pythonfmu would crash the process)")
                return errors
            try:
                # fmi2FreeInstance only: fmpy's freeInstance() also dlclose()s the shared library, and a
                # pythonfmu library unloaded while Python objects it created are still alive crashes the
                # process at the next garbage collection. Libraries stay loaded for the process.
                self.fmu.fmi2FreeInstance(self.c)
            except Exception as exc:
                errors.append(f"freeInstance: {exc}")
            self.instantiated = False
        return errors


_LEAKED: list = []     # instances deliberately not freed (see FmiSlave.teardown)
_SLAVE_CLASS_CACHE: dict[str, type] = {}


def load_slave_class(info: FMUInfo) -> type:
    """The pythonfmu Fmi2Slave subclass inside an FMU (imported from its extracted resources)."""
    key = str(info.path)
    cls = _SLAVE_CLASS_CACHE.get(key)
    if cls is not None:
        return cls
    importlib.import_module("pythonfmu")      # the installed one, before the FMU's resources join sys.path

    res = Path(extracted_dir(info.path)) / "resources"
    modname = (res / "slavemodule.txt").read_text().strip()
    if str(res) not in sys.path:
        # appended, not prepended: pythonfmu's builder copies a partial pythonfmu package (no export
        # binaries) into every FMU's resources; ahead on sys.path it shadowed the installed one, and a
        # later FmuBuilder in the same process wrote FMUs without binaries
        sys.path.append(str(res))
    mod = sys.modules.get(modname)
    if mod is None:
        mod = importlib.import_module(modname)
    cls = getattr(mod, info.model_identifier, None)
    if cls is None:
        from pythonfmu import Fmi2Slave

        cands = [v for v in vars(mod).values() if isinstance(v, type) and issubclass(v, Fmi2Slave)
                 and v is not Fmi2Slave and v.__module__ == mod.__name__]
        if len(cands) != 1:
            raise ConfigurationError(f"{info.path.name}: cannot find the slave class in module {modname}")
        cls = cands[0]
    _SLAVE_CLASS_CACHE[key] = cls
    return cls


class InprocSlave(Slave):
    """The pythonfmu slave object stepped directly: setters, do_step, getters (no FMI layer)."""

    def __init__(self, comp: ComponentSpec, info: FMUInfo):
        self.name, self.model, self.info = comp.name, comp.model, info
        self.log = _Log()
        cls = load_slave_class(info)
        res = Path(extracted_dir(info.path)) / "resources"
        self.time = 0.0
        self.obj = self._guard("instantiate", lambda: cls(instance_name=comp.name, resources=str(res),
                                                         visible=False))
        self._vars = self.obj.vars   # vr -> ScalarVariable

    def _drain_log(self):
        q = getattr(self.obj, "log_queue", None) if hasattr(self, "obj") else None
        if q:
            for m in q:
                # the slaves double every "%" for the FMI logger's printf format (fmu_runtime.guard.fmi_text)
                self.log.add(int(getattr(m.status, "value", m.status)), m.category or "",
                             str(m.msg).replace("%%", "%"))
            q.clear()

    def _guard(self, what, fn, status_on_false: int | None = None, t: float = 0.0):
        try:
            r = fn()
        except Exception as exc:
            self._drain_log()
            self.log.add(4, "", f"Python exception in {what}: {exc!r}\n{traceback.format_exc(limit=5)}")
            self.fatal = True
            raise CosimError(self.name, self.model, what, 4, t, list(self.log.lines)) from None
        self._drain_log()
        if status_on_false is not None and r is False:
            raise CosimError(self.name, self.model, what, status_on_false, t, list(self.log.lines))
        return r

    def _vr(self, n):
        return self.info.variables[n].vr

    def setup(self, stop_time):
        self._guard("setup_experiment", lambda: self.obj.setup_experiment(0.0, stop_time, None))

    def set_parameters(self, params):
        def do():
            for n, v in params.items():
                vi = self.info.variables[n]
                if vi.type == "Real":
                    self.obj.set_real([vi.vr], [float(v)])
                elif vi.type in ("Integer", "Enumeration"):
                    self.obj.set_integer([vi.vr], [int(v)])
                elif vi.type == "Boolean":
                    self.obj.set_boolean([vi.vr], [bool(v)])
                else:
                    self.obj.set_string([vi.vr], [os.fspath(v)])
        self._guard("set parameters", do)

    set_values = lambda self, names, values: self.set_parameters(dict(zip(names, values)))  # noqa: E731

    def get_reals(self, names):
        return self._guard("get_real", lambda: self.obj.get_real([self._vr(n) for n in names]))

    def get_integers(self, names):
        return self._guard("get_integer", lambda: self.obj.get_integer([self._vr(n) for n in names]))

    def get_booleans(self, names):
        return self._guard("get_boolean", lambda: self.obj.get_boolean([self._vr(n) for n in names]))

    def enter_init(self):
        self._guard("enter_initialization_mode", self.obj.enter_initialization_mode)
        self.initialized = True

    def exit_init(self):
        self._guard("exit_initialization_mode", self.obj.exit_initialization_mode)
        if getattr(self.obj, "_failed", None):   # its work failed: fmi2Error, as the FMUs' binaries answer
            raise CosimError(self.name, self.model, "exit_initialization_mode", 3, 0.0, list(self.log.lines))

    def bind(self, in_names, out_names, u: np.ndarray, u_off: int, y: np.ndarray, y_off: int):
        setters = [self._vars[self._vr(n)].setter for n in in_names]
        getters = [self._vars[self._vr(n)].getter for n in out_names]
        n_in, n_out = len(in_names), len(out_names)
        u_view = u[u_off:u_off + n_in]
        y_view = y[y_off:y_off + n_out]
        obj = self.obj

        def set_fn():
            for s, v in zip(setters, u_view.tolist()):
                s(v)
            return 0

        def step_fn(t, h, _flag):
            try:
                ok = obj.do_step(t, h)
            except Exception as exc:
                self._drain_log()
                self.log.add(4, "", f"Python exception in do_step: {exc!r}\n{traceback.format_exc(limit=5)}")
                self.fatal = True
                return 4
            if obj.log_queue:
                self._drain_log()
            return 0 if ok else 2     # pythonfmu: do_step returning False -> fmi2Discard

        def get_fn():
            y_view[:] = [float(g()) for g in getters]
            return 0

        self.set_fn = set_fn if n_in else None
        self.step_fn = step_fn
        self.get_fn = get_fn if n_out else None

    def teardown(self):
        errors = []
        if hasattr(self, "obj") and self.initialized and not self.fatal:
            try:
                self.obj.terminate()
            except Exception as exc:
                errors.append(f"terminate: {exc}")
        return errors
