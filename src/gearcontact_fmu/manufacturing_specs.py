"""Vocabulary of manufacturing errors, light to import (no numba): the accuracy grades, the ISO 1328
tolerances, the drawn errors and the draw. The kernel that applies them is :mod:`gearcontact_fmu.manufacturing`.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from gearcontact_fmu.params import BevelGearParams

#: accuracy grades of ISO 1328 (0 best .. 12 coarsest)
GRADES = tuple(range(0, 13))
#: the default grade of the teeth (single pitch): a ground industrial gear (the rig's pair is a catalogue
#: gear). How it bears on the paper's mild-fault findings: docs/GEAR-CONTACT.md, 'Pitch errors and the mild fault'.
DEFAULT_GRADE = 6
#: the default grade of the radial runout as mounted: the gear's own runout plus its seat on the shaft
#: (bore fit, shaft and bearing runout), a grade coarser than the teeth. It puts the wheel's
#: eccentricity at 20 um, which makes the paper's clear peak at f_PSH in the propeller-shaft spectrum.
DEFAULT_RUNOUT_GRADE = 7


def iso1328_tolerances(grade: int, module_mm: float, pitch_diameter_mm: float) -> dict:
    """Single pitch f_pt, total cumulative pitch F_p, radial runout F_r and profile form f_falpha
    tolerances [um] of an accuracy grade (ISO 1328-1:1995 clause 6, ISO 1328-2:1997 Annex B; unrounded):
    f_falpha = (2.5 sqrt(m) + 0.17 sqrt(d) + 0.5) sqrt(2)^(Q-5) (ISO 1328-1:1995, the formula of the profile form tolerance)."""
    if int(grade) != grade or grade not in GRADES:
        raise ValueError(f"accuracy grade must be an integer in 0..12, not {grade!r}")
    q = math.sqrt(2.0) ** (grade - 5)
    m, d = float(module_mm), float(pitch_diameter_mm)
    f_pt = (0.3 * (m + 0.4 * math.sqrt(d)) + 4.0) * q
    F_p = (0.3 * m + 1.25 * math.sqrt(d) + 7.0) * q
    f_fa = (2.5 * math.sqrt(m) + 0.17 * math.sqrt(d) + 0.5) * q
    return {"f_pt_um": f_pt, "F_p_um": F_p, "F_r_um": 0.8 * F_p, "f_falpha_um": f_fa}


@dataclass(frozen=True)
class ManufacturingErrors:
    """Drawn (or given) errors of one pair: tooth position errors along the line of action [um] per
    tooth (positive = ahead in the direction of rotation), eccentricities [um] and their phases [rad]
    in each gear's body frame; the mesh-periodic profile form deviation of each gear (the same on every
    tooth): its peak-to-peak along the line of action [um] and its phase in the mesh cycle [rad].
    ``source``: how they were obtained (grade, tolerances, seed)."""

    pinion_position_um: tuple = ()
    wheel_position_um: tuple = ()
    pinion_eccentricity_um: float = 0.0
    pinion_phase_rad: float = 0.0
    wheel_eccentricity_um: float = 0.0
    wheel_phase_rad: float = 0.0
    pinion_profile_um: float = 0.0
    wheel_profile_um: float = 0.0
    pinion_profile_phase_rad: float = 0.0
    wheel_profile_phase_rad: float = 0.0
    source: dict = field(default_factory=dict, compare=False)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["pinion_position_um"] = list(self.pinion_position_um)
        d["wheel_position_um"] = list(self.wheel_position_um)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ManufacturingErrors":
        known = {f for f in cls.__dataclass_fields__}
        bad = sorted(set(d) - known)
        if bad:
            raise ValueError(f"unknown manufacturing-error keys {bad}; known: {sorted(known)}")
        kw = dict(d)
        for k, v in d.items():
            if k == "source":
                continue
            try:
                if k.endswith("_position_um"):
                    if not isinstance(v, (list, tuple)):
                        raise TypeError
                    kw[k] = tuple(float(x) for x in v)
                else:
                    kw[k] = float(v)
            except (TypeError, ValueError):
                want = "a list of numbers, one per tooth" if k.endswith("_position_um") else "a number"
                raise ValueError(f"manufacturing error {k} = {v!r}: expected {want}") from None
        e = cls(**kw)
        vals = list(e.pinion_position_um) + list(e.wheel_position_um) + [
            e.pinion_eccentricity_um, e.pinion_phase_rad, e.wheel_eccentricity_um, e.wheel_phase_rad,
            e.pinion_profile_um, e.wheel_profile_um, e.pinion_profile_phase_rad, e.wheel_profile_phase_rad]
        if not all(math.isfinite(v) for v in vals):
            raise ValueError("manufacturing errors must be finite numbers")
        return e

    def check(self, gear: BevelGearParams) -> None:
        for name, vals, z in (("pinion", self.pinion_position_um, gear.z_pinion),
                              ("wheel", self.wheel_position_um, gear.z_wheel)):
            if vals and len(vals) != z:
                raise ValueError(f"{name}_position_um needs one value per tooth ({z}), got {len(vals)}")


def draw_errors(gear: BevelGearParams | None = None, grade: int = DEFAULT_GRADE, seed: int = 0,
                single_pitch_um: float | None = None, runout_um: float | None = None,
                members: tuple = ("pinion", "wheel"), runout_grade: int = DEFAULT_RUNOUT_GRADE,
                profile: bool = False, profile_um: float | None = None) -> ManufacturingErrors:
    """Errors of both gears drawn with ``seed``: single pitch deviations from the tolerance f_pt of
    ``grade``, eccentricities from the radial runout F_r of ``runout_grade`` (or the explicit f_pt and
    F_r [um], the same for both gears); ``members`` limits them to one gear. Deterministic: one seed,
    one set of errors.

    ``profile``: each gear also gets the profile form deviation f_falpha of ``grade`` (or the explicit
    peak-to-peak ``profile_um``, the same for both gears) as a mesh-periodic transmission error at a
    uniform phase. Its phases are drawn after every other draw, so the pitch and runout errors of a seed
    are the same with and without it; without it nothing more is drawn.

    The pair is numbered from its most loaded pinion tooth. A pair carries load as far as it leads
    (e = P_pinion - P_wheel), so the most advanced pinion tooth carries the most, and a flank fracture
    starts where the load is highest: a fault on tooth 0 (the default of every fault) sits there. The
    numbering turns both gears together by the same number of teeth, eccentricities included, so it is
    the same pair of gears in the same assembly, started a few pitches later (tests/gear_contact/test_manufacturing.py)."""
    gear = gear or BevelGearParams()
    rng = np.random.default_rng(int(seed))
    out, source = {}, {"grade": int(grade), "runout_grade": int(runout_grade), "seed": int(seed)}
    drawn = {}
    for member, z in (("pinion", gear.z_pinion), ("wheel", gear.z_wheel)):
        d_mm = gear.module * z * 1e3
        tol = iso1328_tolerances(grade, gear.module * 1e3, d_mm)
        f_pt = tol["f_pt_um"] if single_pitch_um is None else float(single_pitch_um)
        F_r = iso1328_tolerances(runout_grade, gear.module * 1e3, d_mm)["F_r_um"] if runout_um is None \
            else float(runout_um)
        if not (f_pt >= 0 and F_r >= 0 and math.isfinite(f_pt) and math.isfinite(F_r)):
            raise ValueError("single pitch and runout tolerances must be finite and >= 0")
        # draw every member so that the wheel's errors do not depend on whether the pinion has any
        dev = np.clip(rng.normal(0.0, 0.5 * f_pt, z), -f_pt, f_pt)
        dev -= dev.mean()                                 # the deviations close the circle
        pos = np.cumsum(dev)
        pos -= pos.mean()
        drawn[member] = (z, pos, float(rng.uniform(0.0, 2.0 * math.pi)), F_r)
        source[member] = {"f_pt_um": f_pt, "F_r_um": F_r, "pitch_diameter_mm": d_mm}
        if profile:
            f_fa = tol["f_falpha_um"] if profile_um is None else float(profile_um)
            if not (f_fa >= 0 and math.isfinite(f_fa)):
                raise ValueError("the profile form tolerance must be finite and >= 0")
            source[member]["f_falpha_um"] = f_fa
    # the profile phases after every other draw (the pitch and runout errors of a seed stay as they were);
    # the same on every tooth, so the renumbering below leaves them as drawn
    prof = {member: (source[member]["f_falpha_um"], float(rng.uniform(0.0, 2.0 * math.pi)))
            for member in ("pinion", "wheel")} if profile else {}
    k = int(np.argmax(drawn["pinion"][1]))           # the most loaded pinion tooth becomes tooth 0
    for member, (z, pos, phase, F_r) in drawn.items():
        # tooth i is drawn tooth i + k; the body frame turns by k pitches with it (theta = theta_drawn - k p)
        pos, phase = np.roll(pos, -k), math.fmod(phase + 2.0 * math.pi * k / z, 2.0 * math.pi)
        on = member in members
        out[f"{member}_position_um"] = tuple(float(v) for v in pos) if on else ()
        out[f"{member}_eccentricity_um"] = 0.5 * F_r if on else 0.0
        out[f"{member}_phase_rad"] = phase if on else 0.0
        if member in prof:
            out[f"{member}_profile_um"] = prof[member][0] if on else 0.0
            out[f"{member}_profile_phase_rad"] = prof[member][1] if on else 0.0
    source["numbered_from_drawn_tooth"] = k
    return ManufacturingErrors(**out, source=source)


def errors_of(value) -> ManufacturingErrors | None:
    """A ManufacturingErrors from itself, its dict or its JSON text; None for None, "" or {}."""
    import json

    if value is None or isinstance(value, ManufacturingErrors):
        return value
    if isinstance(value, str):
        if not value.strip():
            return None
        try:
            value = json.loads(value)
        except ValueError as exc:
            raise ValueError(f"manufacturing errors are not JSON ({exc})") from None
    if not isinstance(value, dict):
        raise ValueError("manufacturing errors must be a JSON object (ManufacturingErrors.to_dict())")
    return ManufacturingErrors.from_dict(value) if value else None
