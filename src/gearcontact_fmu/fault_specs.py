"""The vocabulary of generated faults: kinds, their keys and defaults, and the checks of a specification.

Light on purpose (no geometry, no numba): the scene schema and the GearContact FMU check fault lists
with it before any mesh is built; :mod:`gearcontact_fmu.faults` builds the meshes.
"""
from __future__ import annotations

import math

from gearcontact_fmu.mesh_models.base import HEALTH_STATES

DEFAULT_WIDTH = 1.0e-3      # [m] flank-fracture void width along the profile (the paper's mild fault)
DEFAULT_DEPTH = 0.3e-3      # [m] its depth along the flank normal
DEFAULT_POSITION = 0.0      # [m] its centre from the pitch cone towards the tip

FLANKS = {"drive": +1, "coast": -1}
"""Physical flanks: drive = the flank loaded when the pinion drives the wheel (on either gear)."""
MEMBERS = ("pinion", "wheel")

FAULT_KINDS = {
    "void": {"width_mm": DEFAULT_WIDTH * 1e3, "depth_mm": DEFAULT_DEPTH * 1e3, "position_mm": DEFAULT_POSITION * 1e3},
    "missing_tooth": {},
    "pit": {"radius_mm": 1.5, "depth_mm": 0.25, "face_position": 0.5, "position_mm": 0.0},
    "spall": {"length_mm": 2.0, "width_mm": 4.0, "depth_mm": 0.1, "face_position": 0.5, "position_mm": 0.0},
    "chipped_tip": {"height_mm": 0.5, "length_mm": 0.0, "face_position": 0.5},
    "crack": {"length_mm": 5.0, "face_position": 0.5},
    "wear": {"depth_um": 20.0, "profile": "uniform"},
}
"""Fault families of ``health = "faults"``: kind -> its size keys with defaults (scene units, mm). Every
specification also has ``member`` (pinion | wheel, default pinion), ``tooth`` (default 0) and ``flank``
(drive | coast, default drive; a missing tooth has no flank). ``void``: the flank-fracture void of
:func:`gearcontact_fmu.faults.mild_flank_fracture` (width along the profile, depth along the normal, position of its centre
from the pitch cone towards the tip, all at the mean cone distance), across the full face width.
``missing_tooth``: every surface of the tooth removed. ``pit``: a spherical cap of base radius
radius_mm and depth depth_mm pressed into the flank, its centre position_mm from the pitch cone towards
the tip and at face_position of the face width (0 = toe/inner end, 1 = heel/outer end). ``spall``: a
flat-bottomed patch length_mm along the profile by width_mm along the face, depth_mm deep. ``chipped_tip``:
the tip corner of the flank cut at 45°, height_mm along the profile, over length_mm of the face (0 = the
whole face). ``crack``: a tooth-root crack grown through, the flank missing over length_mm of the face
at face_position. ``wear``: depth_um removed over the whole flank, profile "uniform" or "sliding" (growing with
the distance from the pitch cone). Lengths along the profile are at the mean cone distance (the teeth
taper)."""
SPEC_KEYS = ("kind", "member", "tooth", "flank")


def loaded_flank(torque: float) -> str:
    """The physical flank that carries a torque through the pair: "drive" when the pinion drives (a pinion
    torque > 0, a braking load motor: load > 0, the two have one sign), "coast" when the load drives."""
    return "coast" if torque < 0.0 else "drive"
WEAR_PROFILES = ("uniform", "sliding")


class FaultGeometryError(ValueError):
    """A fault specification that is well formed but does not fit its tooth (a void that leaves the
    flank, a pit deeper than the tooth, ...), found when the mesh is built; the message names the fault."""


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
        elif key == "profile":
            if value not in WEAR_PROFILES:
                problems.append((key, value, f"one of {WEAR_PROFILES}"))
        elif isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            problems.append((key, value, "a finite number" + ("" if key == "face_position" else
                                                              " [µm]" if key.endswith("_um") else " [mm]")))
        elif key == "face_position" and not 0.0 <= value <= 1.0:
            problems.append((key, value, "a fraction of the face width, 0 (toe) .. 1 (heel)"))
        elif key not in ("position_mm", "face_position") and not (value > 0 or (kind, key) == ("chipped_tip", "length_mm")
                                                                 and value == 0):
            problems.append((key, value, "a size > 0" + (" µm" if key.endswith("_um") else " mm")))
    return problems


def health_problems(health, specs, z_pinion: int, z_wheel: int, health_key: str = "health",
                    faults_name: str = "fault specification") -> list[tuple[str, object, str]]:
    """Problems of a health state and its fault list, all of them, as (key, value, expectation) triples with
    keys ``health``, ``faults`` and ``faults[i].<key>``: a known state; a list of well-formed specifications
    (:func:`fault_spec_problems`); ``"faults"`` with at least one, the other states with none. The one
    check of the scene (``gear.health``, ``[[gear.faults]]``) and of the GearContact FMU's parameters;
    ``health_key`` and ``faults_name`` name them in the messages as the caller's user knows them.
    ``health`` None: not known (refused elsewhere), the list alone is checked. The value of a problem of
    a missing list is None."""
    problems = []
    if health is not None and health not in HEALTH_STATES:
        problems.append(("health", health, "one of " + ", ".join(repr(h) for h in HEALTH_STATES)))
    if not isinstance(specs, (list, tuple)):
        return problems + [("faults", specs, f"a list of {faults_name}s")]
    for i, spec in enumerate(specs):
        problems += [(f"faults[{i}]" + (f".{k}" if k else ""), v, e)
                     for k, v, e in fault_spec_problems(spec, z_pinion, z_wheel)]
    if health == "faults" and not specs:
        problems.append(("faults", None, f'at least one {faults_name} when {health_key} = "faults"'))
    elif specs and health is not None and health != "faults":
        problems.append(("faults", f"{len(specs)} fault(s)",
                         f'no {faults_name} unless {health_key} = "faults" (health is {health!r})'))
    return problems


#: the paper's fault states as the fault specifications of the same geometry (gearcontact_fmu.faults.apply_health:
#: mild = the flank-fracture void on pinion tooth 0 at the void's defaults, severe = pinion tooth 0 missing),
#: so that their runs carry the labels a drawn fault carries
PRESET_FAULTS = {"mild": ({"kind": "void", "member": "pinion", "tooth": 0},),
                 "severe": ({"kind": "missing_tooth", "member": "pinion", "tooth": 0},)}


def health_faults(health: str, specs=()) -> list[dict]:
    """The normalised fault specifications of a health state: the listed ones for ``faults``, the presets'
    for ``mild`` and ``severe``, none for ``healthy`` (and ``mesh``: a user's geometry has no specification)."""
    if health == "faults":
        return [normalised_spec(s) for s in specs or ()]
    return [normalised_spec(s) for s in PRESET_FAULTS.get(health, ())]


def normalised_spec(spec: dict) -> dict:
    """A specification with every default filled in (what a run records as its label)."""
    kind = spec["kind"]
    out = {"kind": kind, "member": spec.get("member", "pinion"), "tooth": int(spec.get("tooth", 0))}
    if kind != "missing_tooth":
        out["flank"] = spec.get("flank", "drive")
    out.update({k: spec.get(k, v) if isinstance(v, str) else float(spec.get(k, v)) for k, v in FAULT_KINDS[kind].items()})
    return out


def draw_value(rule, rng):
    """One value of a draw rule with the numpy Generator ``rng``: ``{uniform = [a, b]}`` a number uniformly in
    [a, b], a list one of its items uniformly, anything else itself (the grammar of ``[sweep.draw]``)."""
    if isinstance(rule, dict):
        lo, hi = rule["uniform"]
        return float(rng.uniform(lo, hi))
    if isinstance(rule, list):
        return rule[int(rng.integers(len(rule)))]
    return rule


def rule_problem(rule) -> str | None:
    """What is wrong with a draw rule's grammar (:func:`draw_value`), or None: ``{uniform = [a, b]}`` with finite
    numbers a <= b; a non-empty list of plain values (no list or table inside: a nested list is no rule)."""
    if isinstance(rule, dict):
        u = rule.get("uniform")
        if (set(rule) != {"uniform"} or not isinstance(u, list) or len(u) != 2
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in u)
                or not u[0] <= u[1]):
            return "{uniform = [a, b]} with finite numbers a <= b"
    elif isinstance(rule, list):
        if not rule:
            return "a non-empty list to choose from"
        if any(isinstance(x, (list, dict)) for x in rule):
            return "a list of plain values to choose from (no list or table inside)"
    return None


def rule_values(rule) -> list:
    """The values that stand for all a (well-formed) rule can draw: a list's items, a uniform's two bounds
    (every check of a size is an interval), a fixed value itself."""
    if isinstance(rule, dict):
        return list(rule["uniform"])
    if isinstance(rule, list):
        return list(rule)
    return [rule]


def _draw_value(key, rule, rng, z):
    if key == "tooth" and rule == "any":
        return int(rng.integers(z))
    return draw_value(rule, rng)


def draw_rule_problems(template, z_pinion: int | None = None, z_wheel: int | None = None
                       ) -> list[tuple[str, object, str]]:
    """Problems of one random fault template. A key is a fixed value, a list (one of them, uniformly),
    ``{uniform = [a, b]}`` (a number uniformly in [a, b]) or, for ``tooth``, ``"any"`` (uniformly over the
    member's teeth). With the tooth counts, every value the template can draw is checked as a fault
    (:func:`fault_spec_problems`), before any draw: an unknown kind in a list is refused whatever the seed."""
    if not isinstance(template, dict):
        return [("", template, "a table of fault keys, each a value, a list to choose from or {uniform = [a, b]}")]
    known = set(SPEC_KEYS).union(*FAULT_KINDS.values())
    problems = []
    if "kind" not in template:
        problems.append(("kind", None, f"a kind or a list of kinds from {tuple(FAULT_KINDS)}"))
    for key, rule in template.items():
        if key not in known:
            problems.append((key, rule, f"a fault key: {tuple(sorted(known))}"))
        elif rule_problem(rule):
            problems.append((key, rule, rule_problem(rule)))
    if problems or z_pinion is None or z_wheel is None:
        return problems
    return _drawable_problems(template, z_pinion, z_wheel)


def _drawable_problems(template: dict, z_pinion: int, z_wheel: int) -> list[tuple[str, object, str]]:
    """The problems of every value a well-formed template can draw, each key's values in turn (the others at
    their first value), as :func:`draw_faults` would assemble them."""
    seen: dict = {}
    for kind in rule_values(template["kind"]):
        if not isinstance(kind, str) or kind not in FAULT_KINDS:
            seen[("kind", repr(kind))] = ("kind", kind, f"one of {tuple(FAULT_KINDS)} (every listed kind is checked "
                                          "before any draw)")
            continue
        for member in rule_values(template.get("member", "pinion")):
            base = {"kind": kind, "member": member}
            keys = [k for k in template if k not in ("kind", "member") and (k in SPEC_KEYS or k in FAULT_KINDS[kind])
                    and not (k == "flank" and kind == "missing_tooth")]
            first = {k: rule_values(template[k])[0] for k in keys}
            for key in keys or [None]:
                for value in rule_values(template[key]) if key else [None]:
                    spec = {**base, **first, **({key: value} if key else {})}
                    if spec.get("tooth") == "any":
                        spec["tooth"] = 0
                    for k, v, e in fault_spec_problems(spec, z_pinion, z_wheel):
                        seen.setdefault((k, repr(v)), (k, v, e))
    return list(seen.values())


def draw_faults(templates, rng, z_pinion: int, z_wheel: int, flank: str | None = None) -> list[dict]:
    """One fault per template, drawn with the numpy Generator ``rng`` (keys not of the drawn kind are
    left out, so one template can mix kinds). ``flank``: the flank of a fault whose template names none (the
    flank that carries the case's load: a fault where the load never runs has no physics behind its label);
    a template that names one (or a list) keeps it."""
    out = []
    for tpl in templates:
        kind = _draw_value("kind", tpl["kind"], rng, 0)
        member = _draw_value("member", tpl.get("member", "pinion"), rng, 0)
        z = z_wheel if member == "wheel" else z_pinion
        spec = {"kind": kind, "member": member}
        for key, rule in tpl.items():
            if key in ("kind", "member"):
                continue
            if key in SPEC_KEYS or key in FAULT_KINDS.get(kind, {}):
                if key == "flank" and kind == "missing_tooth":
                    continue
                spec[key] = _draw_value(key, rule, rng, z)
        if flank is not None and "flank" not in tpl and kind != "missing_tooth":
            spec["flank"] = flank
        out.append(spec)
    return out
