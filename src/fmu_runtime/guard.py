"""Work-around for an exit-time double release in the pythonfmu 0.7.0 export library (linux64).

The export library keeps its interpreter state in a namespace-scope ``std::shared_ptr<PyState>
pyState`` and releases it twice when the process exits (or the library is unloaded): first the C++
static destructor of ``pyState`` drops the last reference and frees the state, then the library
destructor ``finalizePythonInterpreter`` assigns ``pyState = nullptr`` to the already destroyed
object and releases the stale control block again (valgrind: "invalid read of size 4 in
finalizePythonInterpreter, 8 bytes inside a block of size 128 free'd ... by __run_exit_handlers").
The write into freed heap memory makes glibc abort later at exit ("corrupted double-linked list",
typically in libgfortran's exit handler), after the host has finished its work. Measured with the
GearContact FMU: about half of the fresh ``fmpy simulate`` processes abort at exit.

The guard adds one reference to that control block, so that the static destructor only decrements
and the library destructor performs the one and only release (the state is then freed exactly once).
It touches nothing but the reference count, and only in the export library it recognises by its
SHA-256 (the linux64 binary of pythonfmu 0.7.0; every FMU built with it carries a byte-identical copy
named ``binaries/linux64/<modelIdentifier>.so``). Any other binary, platform or failure: no-op.

Call :func:`pin_export_library_state` from a slave's ``__init__``; it acts only when the export library
instantiated the slave (the ``logger`` keyword is present), not in pythonfmu's builder or the master's
in-process backend. ``BEVEL_FMU_NO_EXIT_GUARD=1`` disables it.
"""
from __future__ import annotations

import ctypes
import hashlib
import math
import os
import sys
from pathlib import Path
from typing import Any

# pythonfmu 0.7.0, resources/binaries/linux64/libpythonfmu-export.so
KNOWN_EXPORT_LIBS = {
    "4be156a552c16f30eb4395805c59855d8d4086056d0f165442565f6c5fbac0c9": {
        "pyState": 0x45C60,          # st_value of (anonymous namespace)::pyState (.bss, LOAD vaddr = offset)
    },
}
_USE_COUNT_OFFSET = 8                # _Sp_counted_base: vptr, int _M_use_count, int _M_weak_count

_GUARDED: dict[str, bool] = {}

#: the file name of pythonfmu's export library inside an FMU whose binary is the FMI wrapper
#: (drivetrain.fmu_build.fmi_wrapper: ``binaries/linux64/<modelIdentifier>.so`` is then the wrapper, which loads this)
EXPORT_LIBRARY = "{}.pythonfmu-export.so"
#: the hidden String variable through which the wrapper puts the slave into its error state when it refused
#: a call itself (registered last, only in an instance the export library made: its value reference is the
#: number of declared variables; not in modelDescription.xml)
FAIL_CHANNEL = "_fmi_wrapper_failed"


def _mapping_base(path: Path) -> int | None:
    real = os.path.realpath(path)
    with open("/proc/self/maps") as f:
        for line in f:
            parts = line.split(maxsplit=5)
            if len(parts) == 6 and parts[5].strip() == real and int(parts[2], 16) == 0:
                return int(parts[0].split("-")[0], 16)
    return None


def pin_export_library_state(slave_kwargs: dict, model_identifier: str) -> bool:
    """Add the missing reference for the export library that instantiated this slave (once per
    library file and process). Returns True when the guard is in place for that library."""
    if "logger" not in slave_kwargs or not sys.platform.startswith("linux"):
        return False
    if os.environ.get("BEVEL_FMU_NO_EXIT_GUARD", "").strip() not in ("", "0"):
        return False
    lib_dir = Path(str(slave_kwargs.get("resources", ""))).parent / "binaries" / "linux64"
    lib_path = lib_dir / EXPORT_LIBRARY.format(model_identifier)       # behind the FMI wrapper
    if not lib_path.is_file():
        lib_path = lib_dir / f"{model_identifier}.so"                   # an FMU built without the wrapper
    key = os.path.realpath(lib_path)
    if key in _GUARDED:
        return _GUARDED[key]
    _GUARDED[key] = False
    try:
        layout = KNOWN_EXPORT_LIBS.get(hashlib.sha256(Path(key).read_bytes()).hexdigest())
        base = _mapping_base(Path(key)) if layout else None
        if base is None:
            return False
        ctrl = ctypes.c_uint64.from_address(base + layout["pyState"] + 8).value
        if ctrl == 0:
            return False
        use = ctypes.c_int32.from_address(ctrl + _USE_COUNT_OFFSET)
        if use.value < 1:
            return False
        use.value += 1
    except Exception:  # noqa: BLE001 - the guard must never break the FMU itself
        return False
    _GUARDED[key] = True
    return True


def fmi_text(text: str) -> str:
    """A log message as FMI 2.0 hands it to the host: ``fmi2CallbackLogger`` takes the message as a
    printf-style format, so every ``%`` of user text (a path, a name, a value) is doubled; a ``%n`` or
    ``%s`` left as it is makes a formatting host read arguments that do not exist (measured: fmpy's
    process died with a segmentation fault on a mesh path containing ``%n``)."""
    return str(text).replace("%", "%%")


def enter_error_state(slave, msg: str, log: bool = True) -> None:
    """The one way an instance fails: later steps are refused (``slave._failed``), its ``error`` output
    says why, the outputs named in ``slave.NAN_ON_FAILURE`` become NaN (a host that goes on passes NaN,
    not a stale, finite value), and the message is logged with status error (``log``; the FMI wrapper
    logs the calls it refuses itself)."""
    import math

    from pythonfmu.enums import Fmi2Status

    slave._failed = msg
    slave.error = msg
    for name in getattr(slave, "NAN_ON_FAILURE", ()):
        setattr(slave, name, math.nan)
    if log:
        slave.log(fmi_text(msg), Fmi2Status.error)


#: the shell's own attributes an FMU state holds (besides the variables and the model)
SHELL_STATE = ("_failed", "error", "_fmi_phase", "_fmi_t_next")


def shell_state(slave) -> dict:
    """The shell part of fmi2GetFMUstate (the error state and where the next step must start)."""
    return {n: getattr(slave, n) for n in SHELL_STATE if hasattr(slave, n)}


def restore_shell_state(slave, state: dict) -> None:
    for n, v in state.items():
        setattr(slave, n, v)


_ACCESSORS = {"get_real": "Real", "set_real": "Real", "get_integer": "Integer", "set_integer": "Integer",
              "get_boolean": "Boolean", "set_boolean": "Boolean", "get_string": "String", "set_string": "String"}


def _register_fail_channel(slave) -> None:
    """The hidden String variable :data:`FAIL_CHANNEL` (see there): setting a message enters the error state
    without a second log line; "" does nothing (an FMU state restores the error state itself)."""
    import weakref

    from pythonfmu.enums import Fmi2Causality, Fmi2Variability
    from pythonfmu.variables import String

    ref = weakref.ref(slave)

    def setter(msg):
        s = ref()
        if msg and s is not None and getattr(s, "_failed", None) is None:
            enter_error_state(s, str(msg), log=False)

    slave.register_variable(String(FAIL_CHANNEL, causality=Fmi2Causality.parameter,
                                   variability=Fmi2Variability.tunable, getter=lambda: "", setter=setter))


def guard_value_references(slave, model: str, exported: bool = False) -> None:
    """Check every value reference a host passes to ``fmi2Get*``/``fmi2Set*`` before pythonfmu looks it
    up. An unknown reference (or one of another type) is logged with the references and what exists, the
    instance enters its error state (``slave._failed``: every later ``doStep`` is refused) and the call
    fails. Without this, pythonfmu answered fmi2Fatal with only "PyObject_CallMethod" in the log and
    then accepted the next doStep as if nothing had happened.
    ``exported``: the export library made this instance (its ``logger`` keyword): the hidden
    :data:`FAIL_CHANNEL` of the FMI wrapper is registered (last: its value reference is the number of declared
    variables)."""
    import weakref

    if exported:
        _register_fail_channel(slave)

    # the wrappers live on the instance: they hold it weakly and call the class's function, so that the
    # instance is not kept alive by a reference cycle (freed by the garbage collector at some later time,
    # possibly after pythonfmu's export library has released the interpreter state)
    ref = weakref.ref(slave)
    # what a host may still set once initialization is over: inputs and tunable parameters (FMI 2.0)
    settable_in_step = frozenset(vr for vr, v in slave.vars.items()
                                 if getattr(v.causality, "name", "") == "input"
                                 or getattr(v.variability, "name", "") == "tunable")
    slave._fmi_phase = "instantiated"
    # Integer variables with declared bounds (attributes min, max: drivetrain.models.fmishell.init_slave, GearContact)
    bounded = {vr: (getattr(v, "min", None), getattr(v, "max", None)) for vr, v in slave.vars.items()
               if getattr(v, "min", None) is not None or getattr(v, "max", None) is not None}

    def fail(msg):
        enter_error_state(ref(), msg)
        raise ValueError(msg)

    for name, vtype in _ACCESSORS.items():
        original = getattr(type(slave), name)
        # the variables are all registered by now (the guard is installed at the end of __init__)
        valid = frozenset(vr for vr, v in slave.vars.items() if type(v).__name__ == vtype)
        call = f"fmi2{name.split('_')[0].capitalize()}{vtype}"

        def checked(vrs, *args, _original=original, _call=call, _vtype=vtype, _valid=valid,
                    _setter=name.startswith("set")):
            slave = ref()
            if not _valid.issuperset(vrs):          # one set operation per call: no cost per variable
                bad = [vr for vr in vrs if vr not in _valid]
                detail = ", ".join(f"{vr} ({type(slave.vars[vr]).__name__} {slave.vars[vr].name})"
                                   if vr in slave.vars else f"{vr} (no such variable)" for vr in bad)
                fail(f"{model}: {_call} with value references that are not {_vtype} variables of this FMU: "
                     f"{detail}; the instance is now in its error state")
            if _setter and _vtype == "Integer" and bounded:
                for vr, x in zip(vrs, args[0]):
                    lo, hi = bounded.get(vr, (None, None))
                    if (lo is not None and x < lo) or (hi is not None and x > hi):
                        fail(f"{model}: {_call} of {slave.vars[vr].name} = {x}: outside its declared range "
                             f"[{lo}, {hi}]; the instance is now in its error state")
            if _setter and slave._fmi_phase in _AFTER_INIT and not settable_in_step.issuperset(vrs):
                names = ", ".join(slave.vars[vr].name for vr in vrs if vr not in settable_in_step)
                fail(f"{model}: {_call} of {names} after initialization: fixed parameters can only be set "
                     f"before fmi2ExitInitializationMode (FMI 2.0; the value would not take effect); the "
                     f"instance is now in its error state")
            return _original(slave, vrs, *args)

        setattr(slave, name, checked)
    _install_fast_real_access(slave, ref, settable_in_step)
    _install_state_machine(slave, ref, model)


#: phases after initialization: only inputs and tunable parameters may be set
_AFTER_INIT = frozenset(("step", "terminated"))


def _install_state_machine(slave, ref, model: str) -> None:
    """The FMI 2.0 co-simulation states around the slave's own callbacks: ``fmi2DoStep`` only between
    fmi2ExitInitializationMode and fmi2Terminate, and only at the communication point where the previous
    step ended (a jump would be integrated as if time were continuous).
    Anything else is logged naming the call and what was expected, and the instance enters its error
    state (every later step refused), as for any other error. fmi2SetFMUstate restores the point where
    the next step must start (``SHELL_STATE``): a rollback is a jump back through the FMU state only."""
    from pythonfmu.enums import Fmi2Status

    cls = type(slave)
    slave._fmi_t_next = None
    # Initialization mode: a slave class with ``refresh_initialization_outputs`` brings its outputs up to
    # date with parameters set after fmi2EnterInitializationMode before any fmi2GetReal (FMI 2.0 allows
    # setting them there; Ecos does, then passes the outputs it reads to the connected inputs). The
    # refreshing getter is installed for initialization mode only: no cost per step.
    refresh = getattr(cls, "refresh_initialization_outputs", None)
    step_get_real = slave.get_real

    def init_get_real(vrs):
        s = ref()
        if s._fmi_phase == "initialization":
            refresh(s)
        return step_get_real(vrs)

    def setup_experiment(start_time, stop_time=None, tolerance=None):
        # a start time that is not finite or a stop time before it: the error state (the call itself cannot
        # answer fmi2Error: an exception here is fmi2Fatal in pythonfmu's export library), every step refused
        s = ref()
        msg = None
        if not math.isfinite(start_time):
            msg = (f"{model}: fmi2SetupExperiment with start time {start_time!r}: the start time must be a finite "
                   "time; the instance is now in its error state")
        elif stop_time is not None and not stop_time >= start_time:
            msg = (f"{model}: fmi2SetupExperiment with stop time {stop_time!r} s before the start time "
                   f"{start_time!r} s; the instance is now in its error state")
        if msg is not None:
            if s._failed is None:
                enter_error_state(s, msg)
            return None
        return cls.setup_experiment(s, start_time, stop_time, tolerance)

    def enter_initialization_mode():
        s = ref()
        s._fmi_phase = "initialization"
        s._fmi_t_next = None
        result = cls.enter_initialization_mode(s)
        if refresh is not None:
            s.get_real = init_get_real
        return result

    def exit_initialization_mode():
        s = ref()
        s._fmi_phase = "step"
        s.get_real = step_get_real
        return cls.exit_initialization_mode(s)

    def terminate():
        s = ref()
        s._fmi_phase = "terminated"
        return cls.terminate(s)

    def do_step(current_time, step_size):
        s = ref()
        t_next = s._fmi_t_next
        finite = math.isfinite(current_time)
        if s._fmi_phase != "step" or not finite or (
                t_next is not None and s._failed is None
                and abs(current_time - t_next) > 1e-3 * step_size + 1e-12 * abs(t_next)):
            if not finite:
                why = "(the communication point must be a finite time)"
            elif s._fmi_phase == "terminated":
                why = "after fmi2Terminate"
            elif s._fmi_phase != "step":
                why = "before fmi2ExitInitializationMode"
            else:
                why = (f"but the previous step ended at t = {t_next:.12g} s (communication points must follow "
                       f"each other; to go back, restore an FMU state)")
            msg = f"{model}: fmi2DoStep at t = {current_time:.12g} s {why}; the instance is now in its error state"
            if s._failed is None:
                enter_error_state(s, msg)
            else:
                s.log(fmi_text(msg), Fmi2Status.error)
            return False
        ok = cls.do_step(s, current_time, step_size)
        if ok:
            s._fmi_t_next = current_time + step_size
        return ok

    slave.setup_experiment = setup_experiment
    slave.enter_initialization_mode = enter_initialization_mode
    slave.exit_initialization_mode = exit_initialization_mode
    slave.terminate = terminate
    slave.do_step = do_step


def _default_accessor(fn) -> bool:
    """True for pythonfmu's own getter/setter lambda (``Fmi2Slave.register_variable``)."""
    return (getattr(fn, "__name__", None) == "<lambda>"
            and getattr(fn, "__qualname__", "").startswith("Fmi2Slave.register_variable."))


def _install_fast_real_access(slave, ref, settable_in_step: frozenset) -> None:
    """``get_real``/``set_real`` for the value-reference lists a host repeats every step (an FMI master
    passes the same references at every communication point): the first call with a list is checked
    and served by the guarded pythonfmu path above; it also prepares a plan for that list (attribute
    names for pythonfmu's default accessors, the getter itself for a custom one), used by every later
    call with the same references. Values, conversions (``float`` of each getter result) and errors
    are those of pythonfmu's path; the per-call type checks are done once per list."""
    import operator

    checked_get, checked_set = slave.get_real, slave.set_real
    get_plans: dict[tuple, Any] = {}
    set_plans: dict[tuple, Any] = {}

    def plan_get(key):
        s = ref()
        variables = [s.vars[vr] for vr in key]
        if all(v.getter is not None and _default_accessor(v.getter) and "." not in v.name
               for v in variables):
            names = [v.local_name for v in variables]
            if not names:
                return lambda s: []
            ag = operator.attrgetter(*names)
            if len(names) == 1:
                return lambda s: [float(ag(s))]
            return lambda s: list(map(float, ag(s)))
        getters = [v.getter for v in variables]
        return lambda s: [float(g()) for g in getters]

    def plan_set(key):
        s = ref()
        variables = [s.vars[vr] for vr in key]
        cls = type(s)
        if cls.__setattr__ is object.__setattr__ and all(
                v.setter is not None and _default_accessor(v.setter) and "." not in v.name
                and v.local_name in s.__dict__ and not hasattr(cls, v.local_name) for v in variables):
            names = tuple(v.local_name for v in variables)
            return lambda s, values: s.__dict__.update(zip(names, values))
        setters = [v.setter for v in variables]

        def run(s, values):
            for f, v in zip(setters, values):
                f(v)
        return run

    def get_real(vrs):
        key = tuple(vrs)
        plan = get_plans.get(key)
        if plan is None:
            result = checked_get(vrs)          # validates (and raises) exactly as before
            try:
                get_plans[key] = plan_get(key)
            except Exception:  # noqa: BLE001 - no plan: this list keeps the guarded path
                get_plans[key] = lambda s: checked_get(vrs)
            return result
        return plan(ref())

    def set_real(vrs, values):
        key = tuple(vrs)
        plan = set_plans.get(key)
        if plan is None:
            result = checked_set(vrs, values)
            try:
                plan = plan_set(key)
            except Exception:  # noqa: BLE001
                plan = lambda s, values: checked_set(vrs, values)  # noqa: E731
            if not settable_in_step.issuperset(key):
                # a list with fixed parameters: the phase is checked at every call (refused after init)
                fast = plan
                plan = lambda s, values: (checked_set(vrs, values) if s._fmi_phase in _AFTER_INIT  # noqa: E731
                                          else fast(s, values))
            set_plans[key] = plan
            return result
        return plan(ref(), values)

    slave.get_real = get_real
    slave.set_real = set_real
