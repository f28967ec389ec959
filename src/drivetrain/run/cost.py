"""What a run will cost, said before it starts; a run predicted far beyond its simulated time is refused.

A scene can ask for far more work than its author meant: ``numerics.max_substep_s = 1e-9`` asks for
83 000 gear-stage sub-steps per communication step, online PCM (``effects.mesh_contact = "pcm"``) costs
about 2 ms per sub-step at the default mesh, and a long duration multiplies both. A run is therefore
predicted from its counts before anything is built or stepped:

    loop_s = steps * STEP_S[backend] + sub-steps * SUBSTEP_S[mesh model]      (+ contact, when measured)

* ``steps``: communication steps of the master (duration / the assembled system's comm_step). Each pays
  the per-step cost of the co-simulation loop: the FMI calls, the line components, the coupling
  correction, recording.
* ``sub-steps``: gear-stage sub-steps (steps x ceil(comm_step / max_substep), max_substep the gear
  component's). Each pays the mesh model (the gear component's fidelity): table and analytic interpolate
  (about 1 us), pcm searches and integrates the triangle meshes.

The counts are read from the assembled :class:`~drivetrain.system.SystemSpec`, which fixes them, not from
the scene it came from; only the duration (which no SystemSpec holds) is passed.
* ``contact``: when :func:`drivetrain.models.stability.check_contact_cost` has timed the pair on this machine
  (mesh files, element sizes finer than the default), its measured map build and online loop replace
  the default pcm figure.

The constants were measured on the reference 2-core machine (``drivetrain run`` summaries,
``loop_time_s``; benchmarks/bench_cosim.py): the default 20 s scene is predicted at about 2.7x its
simulated time. They are rounded up, not tuned: a prediction is good to a factor of about two, which is
what a refusal needs.

The rule (:func:`refusal`): a run predicted to take more than ``REFUSE_FACTOR`` times its simulated time
*and* more than ``REFUSE_FLOOR_S`` is refused before it starts, with the prediction, its parts and the way
out; ``--force`` (``run_scene(force=True)``) runs it anyway. The floor keeps short expensive runs (a
0.05 s online-PCM run, ~20 s) free of ceremony. Pure: no I/O, no printing.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from drivetrain.scene.load import default_of
from drivetrain.system import SystemSpec
from gearcontact_fmu.mesh_models import DEFAULT_FIDELITY
from gearcontact_fmu.params import GEAR_MODEL, substeps

#: wall seconds per communication step of the master (loop overhead without the mesh model; native: the
#: whole step, measured 25-35 us on 2 cores; its gear sub-steps cost less than SUBSTEP_S says: an upper bound)
STEP_S = {"fmi": 2.0e-4, "inprocess": 1.2e-4, "native": 4.0e-5}
#: wall seconds per gear-stage sub-step, by mesh model (pcm: default mesh, including its refinements)
SUBSTEP_S = {"pcm": 2.0e-3, "table": 1.5e-6, "analytic": 1.5e-6, "ideal": 0.0}
#: refuse a run predicted to take more than this many times its simulated time ...
REFUSE_FACTOR = 10.0
#: ... and more than this [s]
REFUSE_FLOOR_S = 600.0


@dataclass(frozen=True)
class RunCost:
    """The predicted wall time of a run's loop [s] and where it comes from."""

    duration_s: float
    steps: float
    substeps: float
    mesh_contact: str                             # the gear's fidelity ("none" without a gear stage)
    parts: dict = field(default_factory=dict)     # {what: seconds}
    max_substep_s: float | None = None            # the gear stage's largest sub-step (None: no gear)

    @property
    def total_s(self) -> float:
        return float(sum(self.parts.values()))

    @property
    def factor(self) -> float:
        """Predicted wall time per simulated second."""
        return self.total_s / self.duration_s if self.duration_s > 0 else float("inf")


def _gear_max_substep_s(comp) -> float:
    """The gear stage's largest sub-step: its parameter, else the FMU's default (a custom system)."""
    if "max_substep" in comp.parameters:
        return float(comp.parameters["max_substep"])
    from gearcontact_fmu.stage import StageParams      # (the stage loads the numba kernels: only here)

    return float(StageParams().max_substep)


def predict(spec: SystemSpec, duration_s: float, backend: str = "fmi", contact_reports=()) -> RunCost:
    """The predicted cost of running the assembled system ``spec`` for ``duration_s`` on ``backend``;
    ``contact_reports``: what :func:`drivetrain.models.stability.check_contact_cost` measured for its gear
    (replaces the default pcm figure)."""
    H = float(spec.comm_step)
    steps = duration_s / H
    gears = spec.components_of(GEAR_MODEL)
    # a gear without a fidelity runs the FMU's default, mesh_models.DEFAULT_FIDELITY: priced as that
    subs = [(str(c.parameters.get("fidelity", DEFAULT_FIDELITY)), _gear_max_substep_s(c)) for c in gears]
    n_subs = [(model, steps * substeps(H, sub)) for model, sub in subs]
    n_sub = float(sum(n for _, n in n_subs))
    model = ", ".join(dict.fromkeys(m for m, _ in subs)) or "none"
    parts = {"co-simulation loop": steps * STEP_S.get(backend, STEP_S["fmi"])}
    measured = [r for r in contact_reports or () if r.get("estimate_s")]
    if measured:
        parts["gear-stage sub-steps"] = n_sub * SUBSTEP_S["table"]
        parts["contact model (measured on this machine)"] = float(sum(r["estimate_s"] for r in measured))
    else:
        parts["gear-stage sub-steps"] = sum(n * SUBSTEP_S.get(m, SUBSTEP_S["pcm"]) for m, n in n_subs)
    return RunCost(duration_s, steps, n_sub, model, parts, min((s for _, s in subs), default=None))


def refusal(cost: RunCost) -> str | None:
    """The refusal message for a run predicted beyond the limits (None when it may run)."""
    if cost.total_s <= max(REFUSE_FACTOR * cost.duration_s, REFUSE_FLOOR_S):
        return None
    from gearcontact_fmu.cost import hours     # (cost imports the mesh geometry: only when refusing)

    parts = ", ".join(f"{k} {hours(v)}" for k, v in cost.parts.items() if v >= 1)
    ways = []
    if cost.mesh_contact == "pcm":
        ways.append("effects.mesh_contact = \"table\" (the same PCM contact, precomputed)")
    default_substep_s = default_of("numerics.max_substep_s")     # the scene's key: what the user can change
    if cost.max_substep_s is not None and cost.max_substep_s < default_substep_s:
        ways.append(f"a larger numerics.max_substep_s (now {cost.max_substep_s:.3g} s; "
                    f"default {default_substep_s:g} s)")
    ways.append(f"a shorter time.duration_s (now {cost.duration_s:g} s)")
    return (f"this run is predicted to take about {hours(cost.total_s)} ({cost.factor:.0f}x its "
            f"{cost.duration_s:g} s of simulated time; limit {REFUSE_FACTOR:g}x): {cost.steps:.3g} steps and "
            f"{cost.substeps:.3g} gear-stage sub-steps ({cost.mesh_contact}): {parts}. To run it anyway, pass "
            f"--force (run_scene(force=True)); to make it cheaper: {'; or '.join(ways)}")


__all__ = ["RunCost", "predict", "refusal", "STEP_S", "SUBSTEP_S", "REFUSE_FACTOR", "REFUSE_FLOOR_S"]
