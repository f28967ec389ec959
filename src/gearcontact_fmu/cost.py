"""What a contact model will cost, said before it runs: triangle counts, a timed probe, an estimate.

A mesh file or an element size can ask for far more triangles than a run can afford: a 1.5-million-
triangle wheel makes one PCM evaluation ~10 ms, and a 20 s online-PCM run needs ~16 million of them
(4 per sub-step, ros2). The estimate here lets a caller refuse such a run with its price and a way out,
instead of starting a job of many hours:

* :func:`predicted_triangles`: the triangle count of a generated mesh at an element size, from the
  exact flank area (no mesh is built: a too-fine size is refused before it fills the memory);
* :func:`probe`: the measured cost of the built pair on this machine: seconds per contact-map row
  (both flanks: the onset search and the approach grid, as :mod:`contact_map` computes it) and seconds
  per sub-step of the online engine along a trajectory at the run's speed and sub-step;
* :func:`estimate`: map build (rows still to compute, spread over the map workers) and loop time;
* :func:`advice`: the triangle count and element size that would fit a time budget, from the measured
  growth of the evaluation cost with the triangle count (exponent :data:`COST_EXPONENT`).

Measured growth (2-core machine, default pair 105 k + 399 k triangles, then 2x and 4x finer in both
directions): per evaluation 3.4 / 10.6 / 28 ms, per map row 0.32 / 0.85 / 3.7 s for 1x / 3.8x / 15x
the triangles: cost ~ triangles^0.8. Pure: no I/O beyond the meshes the caller names, no printing.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np

from gearcontact_fmu import geometry
from gearcontact_fmu.params import BevelGearParams, MeshResolution

#: mesh evaluations per sub-step of the gear stage's ros2 integrator (stage.py)
EVALS_PER_SUBSTEP = 4
#: cost of one contact evaluation ~ triangles ** COST_EXPONENT (measured, module docstring)
COST_EXPONENT = 0.8
#: peak memory of a built pair per triangle [bytes] (measured: 0.9 kB at 1 M triangles, rounded up)
BYTES_PER_TRIANGLE = 1000


@dataclass(frozen=True)
class CostEstimate:
    """The contact part of a run, before it starts [s]; ``triangles`` of pinion + wheel."""

    triangles: int
    build_s: float = 0.0          # meshes and contact structures of the pair
    map_build_s: float = 0.0      # rows still to compute (0 if the map is cached or not used)
    loop_s: float = 0.0           # online PCM evaluations of the run (0 for a table gear)
    row_s: float = 0.0            # measured: one map row
    substep_s: float = 0.0        # measured: one sub-step of the online engine

    @property
    def total_s(self) -> float:
        return self.build_s + self.map_build_s + self.loop_s

    @property
    def memory_bytes(self) -> int:
        return int(self.triangles * BYTES_PER_TRIANGLE)


def predicted_triangles(gear: BevelGearParams | None, resolution: MeshResolution) -> int:
    """Triangles of the generated pinion + wheel meshes at ``resolution``, without building them: a tooth
    is a structured strip of (profile segments) x (face rows) x 2 triangles, and each factor is counted on
    one tooth meshed coarsely in the other direction (two one-row builds per gear)."""
    gear = gear or BevelGearParams()
    n = 0
    for role in ("pinion", "wheel"):
        g = geometry.gear_geometry(gear, role)
        coarse_face = MeshResolution(resolution.profile, 10 * g.b)                  # one face row
        coarse_profile = MeshResolution(10 * g.b, resolution.face)                  # fewest profile segments
        segments = len(geometry.build_gear_mesh(gear, role, coarse_face, teeth=[0]).faces) // 2
        rows = len(geometry.build_gear_mesh(gear, role, coarse_profile, teeth=[0]).faces) // (
            len(geometry.build_gear_mesh(gear, role, MeshResolution(10 * g.b, 10 * g.b), teeth=[0]).faces))
        n += g.z * 2 * segments * rows
    return int(n)


def probe(pair, pinion_speed_rad_s: float, substep_s: float, n_substeps: int = 100, n_rows: int = 1,
          n_warm: int = 20) -> tuple:
    """(seconds per map row, seconds per online sub-step) of a built PCMGearPair, measured here.

    The sub-step probe follows the pair in mesh at ``pinion_speed_rad_s`` with sub-steps of
    ``substep_s`` and evaluates :data:`EVALS_PER_SUBSTEP` times per sub-step (the integrator's points
    lie within one sub-step of each other); ``n_warm`` sub-steps first compile and warm the contact
    search's caches (untimed: the first sub-steps along a trajectory cost 2-3x the steady ones).
    ``n_substeps = 0``: no sub-step probe (a table gear does not run online), 0 s per sub-step."""
    from gearcontact_fmu.contact import engine
    from gearcontact_fmu.contact_map import MapGrid, _approach_grid, _tabulate_rows
    from gearcontact_fmu.mesh_models.pcm import contact_onset
    from gearcontact_fmu.mesh_models.base import N_OUT

    z1, z2 = pair.gear.z_pinion, pair.gear.z_wheel
    out = np.zeros(N_OUT)
    th0 = 0.5 * 2 * math.pi / z1
    s = contact_onset(pair, th0, +1)
    s = (s if math.isfinite(s) else 0.0) + 1e-6          # lightly loaded: elements in contact
    dth = max(pinion_speed_rad_s, 1.0) * substep_s
    sub = 0.0
    if n_substeps > 0:
        t0 = 0.0
        for i in range(n_warm + n_substeps):
            if i == n_warm:
                t0 = time.perf_counter()
            th = th0 + i * dth
            for q in range(EVALS_PER_SUBSTEP):
                thw = (th - s - 1e-9 * q) * z1 / z2
                engine.fixed_axis_eval(pair.data, th, thw, pinion_speed_rad_s, pinion_speed_rad_s * z1 / z2, out)
        sub = (time.perf_counter() - t0) / n_substeps
    grid = MapGrid()
    a, _ = _approach_grid(pair, grid)
    t0 = time.perf_counter()
    _tabulate_rows(pair, th0 + np.arange(n_rows) * 0.01, a, grid)
    row = (time.perf_counter() - t0) / n_rows
    return row, sub


#: one contact-map row (both flanks) of the default pair [s] and that pair's triangles, measured on the
#: 2-core machine (issue 29): the progress bar's estimate before the first rows are timed
MAP_ROW_S = 0.045
MAP_ROW_TRIANGLES = 504_000


def map_row_seconds(triangles: int) -> float:
    """Estimated seconds per contact-map row (both flanks) of a pair of ``triangles``, by the growth law
    (the progress bar of a map build says it before the first rows are timed)."""
    return MAP_ROW_S * (max(triangles, 1) / MAP_ROW_TRIANGLES) ** COST_EXPONENT


def estimate(triangles: int, *, build_s: float = 0.0, row_s: float = 0.0, substep_s: float = 0.0,
             map_rows: int = 0, map_workers: int = 1, n_substeps: float = 0.0) -> CostEstimate:
    """Pair build, map build (``map_rows`` rows over ``map_workers`` processes) and loop (``n_substeps``)."""
    return CostEstimate(int(triangles), build_s, map_rows * row_s / max(1, map_workers), n_substeps * substep_s,
                        row_s, substep_s)


def scaled(cost: CostEstimate, triangles: int) -> CostEstimate:
    """The same run with ``triangles`` instead of ``cost.triangles``: the build grows in proportion, the
    evaluations by the measured growth law."""
    n = triangles / max(cost.triangles, 1)
    f = n ** COST_EXPONENT
    return CostEstimate(int(triangles), cost.build_s * n, cost.map_build_s * f, cost.loop_s * f, cost.row_s * f,
                        cost.substep_s * f)


def available_memory_bytes() -> int | None:
    """Physical memory not in use on this machine (None where the OS does not say)."""
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def fitting_triangles(cost: CostEstimate, budget_s: float) -> int:
    """Triangles (pinion + wheel) at which ``cost`` would take ``budget_s``."""
    if cost.total_s <= budget_s:
        return cost.triangles
    return int(cost.triangles * (budget_s / cost.total_s) ** (1.0 / COST_EXPONENT))


def hours(seconds: float) -> str:
    """A duration as people say it: 40 s, 12 min, 3.4 h."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"
