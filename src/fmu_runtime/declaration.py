"""What an FMU of this project declares, as plain data (nothing of pythonfmu): its model information and
its variables in value-reference order.

Each FMU's declaration lives in its library, once: the GearContact's in ``gearcontact_fmu.fmu_variables``
(:func:`gearcontact_fmu.fmu_variables.declaration`), the drivetrain components' in
``drivetrain.models.fmu_variables`` (:func:`drivetrain.models.fmu_variables.declaration`). Both builds read
it there: the pythonfmu slaves (``gearcontact_fmu/slaves/GearContact.py``, the scripts rendered from
:mod:`fmu_runtime.slave_template`) register their variables and take their class attributes from it, and
the native builders (``drivetrain.fmu_build.native_gear`` and ``.native_line``) write their tables and
modelDescription.xml from it without a slave.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, NamedTuple


class Experiment(NamedTuple):
    """The modelDescription's DefaultExperiment (no tolerance: the models integrate with fixed sub-steps)."""
    start_time: float
    stop_time: float
    step_size: float


class Variable(NamedTuple):
    """One variable of an FMU as a slave registers it: its value reference (its position), name, type
    (Real | Integer | Boolean | String), causality (parameter | input | output), the value an instance holds
    before anything is set, variability (None: the FMI default) and, for an Integer parameter, its bounds."""
    vr: int
    name: str
    type: str
    causality: str
    start: Any
    variability: str | None = None
    min: int | None = None
    max: int | None = None


@dataclass(frozen=True)
class FmuDeclaration:
    """An FMU's model information and variables (module docstring). ``initial_dependencies``: output ->
    the knowns it is computed from in initialization mode, or a callable that finds them (the drivetrain
    components run their initialization, ``drivetrain.models.fmu_variables.initial_dependencies``), or None
    (every output depends on every input and parameter)."""
    model: str
    description: str
    author: str
    version: str
    default_experiment: Experiment
    variables: tuple[Variable, ...]
    units: Mapping[str, str] = field(default_factory=dict)
    variable_descriptions: Mapping[str, str] = field(default_factory=dict)
    bounds: Mapping[str, tuple] = field(default_factory=dict)
    initial_dependencies: Mapping[str, list] | Callable[[], Mapping[str, list]] | None = None

    def __post_init__(self):
        if [v.vr for v in self.variables] != list(range(len(self.variables))):
            raise ValueError(f"{self.model}: the value references must be 0..n-1 in order")

    def initial_dependency_map(self) -> Mapping[str, list] | None:
        """``initial_dependencies``, found when it is a callable."""
        deps = self.initial_dependencies
        return deps() if callable(deps) else deps
