"""Mesh models of every fidelity behind one interface (see docs/ARCHITECTURE.md).

``mesh_eval(data, theta_pinion, theta_wheel, omega_pinion, omega_wheel, out)`` is a numba function;
``out`` has ``N_OUT`` entries laid out as the ``OUT_*`` indices below.
"""
from __future__ import annotations

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
