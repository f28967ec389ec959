"""Mesh models of every fidelity behind one interface (see docs/ARCHITECTURE.md).

``mesh_eval(data, theta_pinion, theta_wheel, omega_pinion, omega_wheel, out)`` is a numba function;
``out`` has ``N_OUT`` entries laid out as the ``OUT_*`` indices below.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from numba import njit

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

FIDELITIES = ("pcm", "table", "analytic", "ideal")

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


@njit(cache=True)
def ideal_eval(data, theta_pinion, theta_wheel, omega_pinion, omega_wheel, out):
    """Placeholder kernel of the ideal mesh: the rigid constraint has no constitutive law, the stage
    computes the constraint torque itself. Fills zeros (status ok)."""
    for i in range(out.shape[0]):
        out[i] = 0.0


def make_ideal_model(gear_params=None, **kw) -> MeshModel:
    from gearcontact_fmu.params import BevelGearParams

    gear = gear_params or BevelGearParams()
    return MeshModel(eval=ideal_eval, data=(np.zeros(1),), fidelity="ideal", kind="rigid",
                     info={"ratio": gear.z_wheel / gear.z_pinion})


def _lazy(module: str, func: str):
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name == module:
            raise NotImplementedError(
                f"fidelity needs {module}.{func}(...), but module {module} is not available") from exc
        raise
    try:
        return getattr(mod, func)
    except AttributeError:
        raise NotImplementedError(f"{module} does not provide {func}(...) yet") from None


def make_mesh_model(fidelity: str, gear_params=None, pcm_params=None, resolution=None,
                    health: str = "healthy", mesh_files=None, **kw) -> MeshModel:
    """Build the mesh model of one fidelity.

    - ``"pcm"``: online polygonal contact, ``gearcontact_fmu.gearpair.make_pcm_model``
    - ``"table"``: precomputed contact map, ``gearcontact_fmu.contact_map.make_table_model``
    - ``"analytic"``: ISO 6336 reference pair, ``gearcontact_fmu.analytic.make_analytic_model``
      (``health`` and ``mesh_files`` do not apply: it only models the healthy pair)
    - ``"ideal"``: rigid mesh, exact ratio, no backlash (``kind == "rigid"``)

    ``mesh_files``: dict with optional ``"pinion"``/``"wheel"`` paths (empty = generated).
    Extra keywords go to the builder (e.g. ``damping_ratio``, ``J_pinion`` for "analytic")."""
    from gearcontact_fmu.params import BevelGearParams, MeshResolution, PCMParams

    fidelity = str(fidelity).strip().lower()
    if fidelity not in FIDELITIES:
        raise ValueError(f"unknown fidelity {fidelity!r}; expected one of {FIDELITIES}")
    gear_params = gear_params or BevelGearParams()
    pcm_params = pcm_params or PCMParams()
    resolution = resolution or MeshResolution()
    if fidelity == "ideal":
        return make_ideal_model(gear_params)
    if fidelity == "analytic":
        if health not in ("healthy", "", None) or mesh_files:
            raise ValueError("the analytic mesh models the healthy pair only (health='healthy', "
                             "no mesh files); use fidelity 'pcm' or 'table' for faults")
        from gearcontact_fmu.analytic import make_analytic_model

        return make_analytic_model(gear_params, pcm_params, **kw)
    if fidelity == "pcm":
        make = _lazy("gearcontact_fmu.gearpair", "make_pcm_model")
    else:
        make = _lazy("gearcontact_fmu.contact_map", "make_table_model")
    return make(gear_params, pcm_params, resolution, health=health, mesh_files=mesh_files, **kw)
