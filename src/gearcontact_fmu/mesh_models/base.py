"""The mesh-model interface and the pair's vocabularies (see docs/ARCHITECTURE.md, "Mesh model interface").

Every fidelity (``mesh_models.BUILDERS``) returns a :class:`MeshModel`: a numba function
``mesh_eval(data, theta_pinion, theta_wheel, omega_pinion, omega_wheel, out)`` and its parameter tuple.
``out`` has ``N_OUT`` entries laid out as the ``OUT_*`` indices below. This module imports nothing of the
package, so every fidelity module, the stage and the FMU shell can depend on it without a cycle.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

OUT_TAU_PINION = 0
OUT_TAU_WHEEL = 1
OUT_N_CONTACT = 2
OUT_CONTACT_AREA = 3
OUT_PEAK_PRESSURE = 4
OUT_MAX_PENETRATION = 5
OUT_NORMAL_FORCE = 6
OUT_ELASTIC_ENERGY = 7
OUT_DISSIPATED_POWER = 8
OUT_STATUS = 9
N_OUT = 10

OUT_NAMES = (
    "tau_pinion", "tau_wheel", "n_contact", "contact_area", "peak_pressure",
    "max_penetration", "normal_force", "elastic_energy", "dissipated_power", "status",
)
OUT_UNITS = ("N.m", "N.m", "1", "m2", "Pa", "m", "N", "J", "W", "1")

STATUS_OK = 0
STATUS_PENETRATION_EXCEEDED = 1

#: sub-step integrators of the gear stage (auto: rk4 where it is stable, ros2 for stiff contact; stage.py)
SCHEMES = ("auto", "ros2", "rk4")
FIDELITIES = ("pcm", "table", "analytic", "ideal")
"""Mesh-contact fidelities, finest first (``mesh_models.BUILDERS`` maps each to its builder)."""
PAPER_HEALTH = ("healthy", "mild", "severe")
"""The paper's three health states, the ones the rig measured (validation, accuracy study, stress)."""
GENERATED_HEALTH = PAPER_HEALTH + ("faults",)
"""Health states generated from the healthy geometry (``faults.apply_health``; ``"faults"``: a list of
fault specifications on either gear, ``faults.FAULT_KINDS``)."""
HEALTH_STATES = GENERATED_HEALTH + ("mesh",)
"""Every health state a scene or the GearContact FMU accepts (``"mesh"``: user mesh files)."""
FIDELITY_SUPPORTS = {
    "pcm": frozenset({"teeth", "friction", "manufacturing_errors"}),
    "table": frozenset({"teeth", "friction", "tooth_compliance", "manufacturing_errors"}),
    "analytic": frozenset({"friction", "tooth_compliance", "manufacturing_errors"}),
    "ideal": frozenset(),
}
"""What each fidelity models beyond the healthy pair's mesh force, declared once (the scene's checks and
``mesh_models`` read it): ``teeth``, tooth geometry, so
every health state (faults, user meshes), the others the healthy pair only; ``friction``, tooth friction
(pcm/table from the PCM, analytic from ``mu``); ``tooth_compliance``, the series tooth compliance (table
applies it to its map; the analytic ISO 6336 pair has it already); ``manufacturing_errors``, a mesh
coordinate for the errors to offset (the rigid ideal mesh has none)."""


def supports(fidelity: str, feature: str) -> bool:
    """Does ``fidelity`` model ``feature`` (a key of :data:`FIDELITY_SUPPORTS`' sets)?"""
    return feature in FIDELITY_SUPPORTS[fidelity]


def fidelities_with(feature: str) -> tuple[str, ...]:
    """The fidelities that model ``feature``, finest first."""
    return tuple(f for f in FIDELITIES if supports(f, feature))


@dataclass
class MeshModel:
    """A mesh model of one fidelity: ``eval(data, theta_p, theta_w, omega_p, omega_w, out)`` (numba)
    with its parameter tuple ``data``.

    ``kind`` is ``"mesh"`` for a compliant mesh (the stage integrates pinion and wheel separately) or
    ``"rigid"`` for the ideal mesh (exact ratio, no compliance or backlash: the stage treats pinion and
    wheel as one rigid body and never calls ``eval``)."""

    eval: Callable
    data: tuple
    fidelity: str
    kind: str = "mesh"
    info: dict = field(default_factory=dict)

    def evaluate(self, theta_pinion, theta_wheel, omega_pinion=0.0, omega_wheel=0.0, out=None):
        """Convenience call from Python; returns the ``out`` array."""
        if out is None:
            out = np.zeros(N_OUT)
        self.eval(self.data, float(theta_pinion), float(theta_wheel), float(omega_pinion),
                  float(omega_wheel), out)
        return out


def eval_signature(mesh_eval, data_type):
    """The numba signature of a mesh kernel ``mesh_eval`` (``f(data, theta_pinion, theta_wheel, omega_pinion,
    omega_wheel, out)``) for its data of numba type ``data_type``, compiled for it: the type of a first-class
    function argument (``numba.types.FunctionType(...)``) through which a kernel calls a mesh model without
    compiling it into its own code."""
    from numba import types

    args = (data_type, types.float64, types.float64, types.float64, types.float64, types.float64[::1])
    mesh_eval.compile(args)
    ret = mesh_eval.overloads[args].signature.return_type
    return ret(*args)


def read_only(arr) -> np.ndarray:
    """A read-only contiguous view of ``arr`` (the array itself stays writable): what a kernel's array arguments
    are made, so that they have one numba type. numba compiles a kernel, and everything it calls, once per
    argument type, and a writable and a read-only array are two; the maps that
    :func:`~gearcontact_fmu.contact_map.load_map` shares are read-only."""
    view = np.ascontiguousarray(arr).view()
    view.flags.writeable = False
    return view

