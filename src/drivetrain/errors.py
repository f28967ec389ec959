"""Every exception the drivetrain package raises, in one place, with one payload shape.

Errors found *before* any work (a scene, a system, a cut, a sweep directory) are refusals: they carry
``problems``, a list of everything wrong (collected, then raised together), and their message lists
them one per line. A scene's problems are structured as (key, value, expected) triples, so that a
caller can point at the key; every other refusal's problems are sentences.

Errors found *during* a run (an FMU failed) carry where and when: the component, the model, the FMI
function, the status, the time and the FMU's log; ``partial`` holds what was computed before it.

The pure library of the gear pair has its own (``gearcontact_fmu.meshes.MeshError``,
``gearcontact_fmu.stage.StageError``, ``gearcontact_fmu.contact_map.ContactMapFileError``): it never
imports this package.
"""
from __future__ import annotations

import json
from typing import Any, Sequence

FMI_STATUS = ("ok", "warning", "discard", "error", "fatal", "pending")
"""fmi2Status names by value."""


class Refused(ValueError):
    """Base of every refusal: ``problems`` (a list), ``headline`` (what was refused; None: the problems
    alone, one per line)."""

    headline: str | None = "refused"

    def __init__(self, problems: Sequence[Any] | str):
        if isinstance(problems, str):
            problems = [problems]
        self.problems = list(problems)
        super().__init__(self._message())

    def problem_lines(self) -> list[str]:
        return [str(p) for p in self.problems]

    def _message(self) -> str:
        if self.headline is None:
            return "\n".join(self.problem_lines())
        return f"{self.headline}:\n" + "\n".join(f"  - {p}" for p in self.problem_lines())


class ConfigurationError(Refused):
    """The system cannot be run as specified (found before any step). ``problems``: list of strings."""

    headline = "system refused before any step"


class NativeBuildError(ConfigurationError):
    """The native GearContact FMU cannot be built as asked (drivetrain.fmu_build.native_gear). ``problems``: list
    of strings."""

    headline = "native GearContact not built"


class StartStateError(ConfigurationError):
    """No start state for the gear of a scene: its mesh carries the start load at no position (raised
    while assembling, before any step). The message names the scene, the gearbox and the reason."""

    headline = "no start state"


class UnstableCutError(Refused):
    """A cut of the partition is unstable at the communication step (raised before any step).
    ``reports``: the CutReport of every cut."""

    headline = "unstable co-simulation cut(s)"

    def __init__(self, problems: list[str], reports: list | None = None):
        self.reports = reports or []
        super().__init__(problems)


class ContactRangeError(Refused):
    """A gear contact whose error bound the static load alone would pass (raised before any step)."""

    headline = None


class ContactCostError(Refused):
    """A gear contact whose estimated cost exceeds the scene's budget (raised before any step)."""

    headline = None


class MissingValue:
    """The marker of a scene key that is required but absent, or given with an unusable value."""

    def __repr__(self) -> str:
        return "(missing)"


MISSING = MissingValue()


def show_value(value: Any) -> str:
    """A value as a scene author wrote it (JSON-like), cut at 120 characters."""
    if value is MISSING:
        return "(missing)"
    s = json.dumps(value, default=str) if not isinstance(value, str) else repr(value)
    return s if len(s) <= 120 else s[:117] + "..."


class ScenarioError(Refused):
    """A scene is malformed. ``problems`` lists (key, value, expected) triples; ``source`` the file."""

    def __init__(self, problems: list[tuple[str, Any, str]], source: str | None = None):
        self.source = source
        super().__init__(problems)

    def problem_lines(self) -> list[str]:
        return [f"{key} = {show_value(value)}: expected {expected}" for key, value, expected in self.problems]

    def _message(self) -> str:
        n = len(self.problems)
        where = f"{self.source}: " if self.source else ""
        return "\n".join([f"{where}invalid scene ({n} problem{'s' if n != 1 else ''}):"]
                         + [f"  {line}" for line in self.problem_lines()])


class DatasetError(Refused):
    """The sweep directory cannot be exported (no manifest, no finished run, a run's file unreadable)."""

    headline = None


class FileFormatError(Refused):
    """A file the project reads back (a manifest, a summary, a signals file, an FMU archive, a record) is not
    what it should be: ``problems`` name the file, the field and what was wrong (drivetrain.run.files)."""

    headline = None


class OutputLockedError(Refused):
    """An output folder is in use by another run or sweep (drivetrain.run.lock): names the holder."""

    headline = None


class ComponentError(RuntimeError):
    """A drivetrain component cannot continue (non-finite input or state)."""


class CosimError(RuntimeError):
    """An FMU returned discard/error/fatal (or raised, in-process). Names the FMU, the time and its log."""

    def __init__(self, component: str, model: str, function: str, status: int, time_s: float, log: list[str]):
        self.component = component
        self.model = model
        self.function = function
        self.status = status
        self.time = time_s
        self.log = list(log)
        #: the CosimResult of the completed part of the run (Master.run), None if nothing was computed
        self.partial = None
        st = FMI_STATUS[status] if 0 <= status < len(FMI_STATUS) else str(status)
        tail = "\n".join("    " + line for line in self.log[-20:]) or "    (empty)"
        super().__init__(f"FMU '{component}' (model {model}) returned {st} from {function} at t = {time_s:.9g} s; "
                         f"its log:\n{tail}")


class RunInterrupted(CosimError):
    """The run was asked to stop (the command line's SIGINT or SIGTERM, drivetrain.cosim.master.request_stop)
    and ended at the next chunk of steps: ``partial`` holds what it computed (status "interrupted")."""

    def __init__(self, reason: str, time_s: float):
        super().__init__("(master)", "-", "the stepping loop", 0, time_s, [f"[interrupted] {reason}"])
        self.reason = reason

    def __str__(self) -> str:
        return f"interrupted at t = {self.time:.9g} s ({self.reason})"


class RunFailedError(CosimError):
    """An FMU failed during ``run_scene``. ``result``: the RunResult of the completed part (its summary
    has ``status = "failed"`` and the ``failure`` block; ``result.files`` lists what was written when an
    output directory was given); ``cause``: the master's CosimError."""

    def __init__(self, cause: CosimError, result):
        super().__init__(cause.component, cause.model, cause.function, cause.status, cause.time, cause.log)
        self.cause = cause
        self.result = result
        self.partial = cause.partial
