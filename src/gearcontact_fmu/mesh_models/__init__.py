"""Mesh models of every fidelity behind one interface: ``BUILDERS`` maps a fidelity name to its builder.

The interface (``MeshModel``, the ``OUT_*`` layout, the vocabularies) lives in ``base`` (which imports
nothing of the package); one module of this folder per method builds it: ``pcm`` (online polygonal contact), ``table`` (the
precomputed contact map of ``gearcontact_fmu.contact_map``), ``analytic`` (ISO 6336 reference pair) and
``ideal`` (the rigid mesh). ``make_mesh_model(fidelity, ...)`` is the one entry point (the shape of
scipy.integrate's ``solve_ivp`` method table: an interface module, one file per method, a table mapping
names to implementations). The builders are named, not imported: a scene loads only the contact engine its
fidelity needs (an ideal or analytic gear never imports the PCM kernels).

The default fidelity, :data:`DEFAULT_FIDELITY` = ``"analytic"``, is the fidelity of a gear that names none:
the GearContact FMU's ``fidelity`` parameter starts at it (its modelDescription's start value,
``gearcontact_fmu.fmu_variables``), and every reader of a gear's parameters that falls back when the
fidelity is missing reads it here (``drivetrain.models.eigen``, ``drivetrain.run.assemble``,
``drivetrain.models.stability``). It is the FMU's long-standing default, kept so that no modelDescription
and no result changes; the cheapest compliant model, it needs neither a contact map nor the contact engine.
Not defaults in this sense: a scene's ``effects.mesh_contact`` (a scene key with its own default, which the
assembler always writes into the gear's parameters) and the native GearContact's ``table`` (the only
fidelity that FMU implements, ``drivetrain.fmu_build.native_gear``).
"""
from __future__ import annotations

import importlib
import math

from gearcontact_fmu.mesh_models.base import FIDELITIES, MeshModel, supports
from gearcontact_fmu.params import BevelGearParams, MeshResolution, PCMParams

BUILDERS = {
    "pcm": "gearcontact_fmu.mesh_models.pcm:make_pcm_model",             # online polygonal contact
    "table": "gearcontact_fmu.mesh_models.table:make_table_model",       # precomputed fixed-axis contact map
    "analytic": "gearcontact_fmu.mesh_models.analytic:make_analytic_model",  # ISO 6336 reference pair, healthy only
    "ideal": "gearcontact_fmu.mesh_models.ideal:make_ideal_model",       # rigid mesh, kind "rigid"
}
"""fidelity name -> "module:builder"; builder(gear_params, pcm_params, resolution, health=, mesh_files=, **kw)
-> MeshModel. Named, not imported: a scene loads only the contact engine its fidelity needs (an ideal
or analytic gear never imports the PCM kernels)."""
assert tuple(BUILDERS) == FIDELITIES

DEFAULT_FIDELITY = "analytic"
"""The fidelity of a gear whose parameters name none (the GearContact FMU's declared default; see the
module docstring)."""
assert DEFAULT_FIDELITY in BUILDERS


def builder(fidelity: str):
    """The builder function of ``fidelity`` (imports its module)."""
    module, func = BUILDERS[fidelity].split(":")
    return getattr(importlib.import_module(module), func)


def make_mesh_model(fidelity: str, gear_params=None, pcm_params=None, resolution=None,
                    health: str = "healthy", mesh_files=None, **kw) -> MeshModel:
    """Build the mesh model of one fidelity.

    - ``"pcm"``: online polygonal contact, ``gearcontact_fmu.mesh_models.pcm.make_pcm_model``
    - ``"table"``: precomputed contact map, ``gearcontact_fmu.mesh_models.table.make_table_model``
    - ``"analytic"``: ISO 6336 reference pair, ``gearcontact_fmu.mesh_models.analytic.make_analytic_model``
      (``health`` and ``mesh_files`` do not apply: it only models the healthy pair)
    - ``"ideal"``: rigid mesh, exact ratio, no backlash (``kind == "rigid"``),
      ``gearcontact_fmu.mesh_models.ideal.make_ideal_model``

    ``mesh_files``: dict with optional ``"pinion"``/``"wheel"`` paths (empty = generated).
    ``manufacturing_errors``: pitch errors and runout (``manufacturing_specs.ManufacturingErrors``, its dict
    or JSON) applied to the built model as a transmission-error offset (``manufacturing.with_errors``).
    Extra keywords go to the builder (e.g. ``damping_ratio``, ``J_pinion`` for "analytic")."""
    fidelity = str(fidelity).strip().lower()
    if fidelity not in BUILDERS:
        raise ValueError(f"unknown fidelity {fidelity!r}; expected one of {FIDELITIES}")
    errors = kw.pop("manufacturing_errors", None)
    compliance = float(kw.pop("tooth_compliance", 1.0))
    if not (math.isfinite(compliance) and compliance >= 1.0):
        raise ValueError(f"tooth compliance factor must be >= 1 (1 = none), not {compliance!r}")
    if compliance != 1.0:
        if not supports(fidelity, "tooth_compliance"):
            raise ValueError(f"tooth compliance is carried by the table fidelity (a series compliance on its map's "
                             f"approach axis) and already part of the analytic ISO 6336 pair; not by {fidelity!r}")
        if fidelity == "table":
            kw["tooth_compliance"] = compliance
    from gearcontact_fmu.elastic_layer import pair_pcm     # (it reads this folder's analytic module)

    gear_params = gear_params or BevelGearParams()
    model = builder(fidelity)(gear_params, pair_pcm(gear_params, pcm_params), resolution or MeshResolution(),
                              health=health, mesh_files=mesh_files, **kw)
    if errors:
        from gearcontact_fmu.manufacturing import with_errors

        model = with_errors(model, errors, gear_params)
    return model
