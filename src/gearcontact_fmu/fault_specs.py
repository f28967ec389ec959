"""The vocabulary of generated faults: kinds, their keys and defaults, and the checks of a specification.

Light on purpose (no geometry, no numba): the scene schema and the GearContact FMU check fault lists
with it before any mesh is built; :mod:`gearcontact_fmu.faults` builds the meshes.
"""
from __future__ import annotations

DEFAULT_WIDTH = 1.0e-3      # [m] flank-fracture void width along the profile (the paper's mild fault)
DEFAULT_DEPTH = 0.3e-3      # [m] its depth along the flank normal
DEFAULT_POSITION = 0.0      # [m] its centre from the pitch cone towards the tip

FLANKS = {"drive": +1, "coast": -1}
"""Physical flanks: drive = the flank loaded when the pinion drives the wheel (on either gear)."""
MEMBERS = ("pinion", "wheel")

FAULT_KINDS = {
    "void": {"width_mm": DEFAULT_WIDTH * 1e3, "depth_mm": DEFAULT_DEPTH * 1e3, "position_mm": DEFAULT_POSITION * 1e3},
    "missing_tooth": {},
}
"""Fault families of ``health = "faults"``: kind -> its size keys with defaults (scene units, mm). Every
specification also has ``member`` (pinion | wheel, default pinion), ``tooth`` (default 0) and ``flank``
(drive | coast, default drive; a missing tooth has no flank). ``void``: the flank-fracture void of
:func:`gearcontact_fmu.faults.mild_flank_fracture` (width along the profile, depth along the normal, position of its centre
from the pitch cone towards the tip, all at the mean cone distance), across the full face width.
``missing_tooth``: every surface of the tooth removed."""
SPEC_KEYS = ("kind", "member", "tooth", "flank")


def fault_spec_problems(spec, z_pinion: int, z_wheel: int) -> list[tuple[str, object, str]]:
    """Problems of one fault specification as (key, value, expectation) triples, all of them."""
    if not isinstance(spec, dict):
        return [("", spec, "a table of fault keys (kind, member, tooth, ...)")]
    problems = []
    kind = spec.get("kind")
    if kind not in FAULT_KINDS:
        problems.append(("kind", kind, f"one of {tuple(FAULT_KINDS)}"))
        return problems
    member = spec.get("member", "pinion")
    if member not in MEMBERS:
        problems.append(("member", member, f"one of {MEMBERS}"))
    z = z_wheel if member == "wheel" else z_pinion
    tooth = spec.get("tooth", 0)
    if isinstance(tooth, bool) or not isinstance(tooth, int) or not 0 <= tooth < z:
        problems.append(("tooth", tooth, f"an integer tooth index 0..{z - 1} of the {member}"))
    if "flank" in spec and (kind == "missing_tooth" or spec["flank"] not in FLANKS):
        problems.append(("flank", spec["flank"], "no flank for a missing tooth" if kind == "missing_tooth"
                         else f"one of {tuple(FLANKS)}"))
    sizes = FAULT_KINDS[kind]
    for key, value in spec.items():
        if key in SPEC_KEYS:
            continue
        if key not in sizes:
            problems.append((key, value, f"a key of a {kind} fault: {SPEC_KEYS + tuple(sizes)}"))
        elif isinstance(value, bool) or not isinstance(value, (int, float)) or not value == value:
            problems.append((key, value, "a number [mm]"))
        elif key != "position_mm" and not value > 0:
            problems.append((key, value, "a size > 0 mm"))
    return problems


def normalised_spec(spec: dict) -> dict:
    """A specification with every default filled in (what a run records as its label)."""
    kind = spec["kind"]
    out = {"kind": kind, "member": spec.get("member", "pinion"), "tooth": int(spec.get("tooth", 0))}
    if kind != "missing_tooth":
        out["flank"] = spec.get("flank", "drive")
    out.update({k: float(spec.get(k, v)) for k, v in FAULT_KINDS[kind].items()})
    return out
