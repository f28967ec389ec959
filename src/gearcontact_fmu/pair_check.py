"""Can this straight bevel pair be made? Every reason it cannot, found before any work.

:func:`pair_problems` returns the problems of a :class:`~gearcontact_fmu.params.BevelGearParams` as
sentences, each naming the figure, its value and its limit; :func:`check_pair` raises :class:`PairError`
with all of them. The pure library does not import the drivetrain package, so :class:`PairError` is the
library's own refusal (a ``ValueError`` with ``problems``, the shape of ``drivetrain.errors.Refused``): a
caller in the drivetrain (the scene loader) turns its ``problems`` into its own error.

The checks, in the order they are reported:

1. the data: whole numbers of teeth >= 1; module, face width, addendum and dedendum factors > 0; pressure
   angle in [10 deg, 35 deg]; backlash and tip rounding >= 0; a tip clearance ``h_f* - h_a* > 0`` (with
   x1 + x2 = 0 each tip runs ``(h_f* - h_a*) m`` above the partner's root); finite profile shift;
2. the shaft angle in [30 deg, 150 deg] (issue 42);
3. both pitch cones below 90 deg: above is an internal bevel gear, at 90 deg a crown gear, whose virtual
   spur gear (the basis of every check below and of ISO 10300 / 6336's reference) is a rack or worse;

and, when these hold, on the virtual spur gears of the back cone (Tredgold; ISO 10300, ISO 23509), at the
outer end: ``z_v = z / cos(delta)``, ``r_v = m z_v / 2``, ``r_vb = r_v cos(alpha)``, ``r_va = r_v + m (h_a* + x)``
(pinion ``x``, wheel ``-x``; the tapered teeth scale with the cone distance, so every ratio below holds at
any section):

4. **undercut**: the generating rack (ISO 53 profile A: dedendum ``h_fP* = h_f*``, root radius
   ``rho_fP* = 0.38``) cuts the involute up to its straight flank's end, ``h_FfP* = h_fP* - rho_fP* (1 - sin
   alpha)`` (1.000 m for the default 1.25 / 20 deg) below the reference line; no undercut when
   ``x >= x_min = h_FfP* - z_v sin^2(alpha) / 2`` (DIN 3960 / ISO 21771; z_min = 17 at x = 0);
5. **pointed tip**: the normal tooth thickness at the outer tip circle,
   ``s_a = 2 r_va (s / (2 r_v) + inv(alpha) - inv(alpha_a))``, ``cos(alpha_a) = r_vb / r_va``, with the tooth
   thickness at the pitch circle ``s = m (pi/2 + 2 x tan(alpha)) - j/2`` (j the backlash, half on each gear,
   as in the geometry), must be at least :data:`MIN_TIP_THICKNESS_MODULES` ``= 0.2`` modules: the common
   design rule of thumb for the top land (about 0.2 m for through-hardened gears, 0.4 m for case-hardened
   ones, whose hardened tip would be brittle through). Below it the tip chips off in service, and the tip
   rounding of the geometry (``tip_radius``, 0.2 mm = 0.067 m on the rig) has little top land left; the
   rig's pinion has 0.42 m;
6. **interference**: the partner's tip must meet this gear's flank on its involute: along the line of
   action of the virtual pair (centre distance ``a_v = r_v1 + r_v2``, x1 + x2 = 0), the partner's tip circle
   cuts it at ``T1A = a_v sin(alpha) - sqrt(r_va2^2 - r_vb2^2)`` from this gear's tangent point T1, and the
   generated involute starts at ``T1F = max(0, r_v1 sin(alpha) - m (h_FfP* - x1) / sin(alpha))`` (the form
   circle of the rack-cut gear, ISO 21771's d_Ff; 0, the base circle, for an undercut gear, which item 4
   reports). Interference when ``T1A < T1F``, in radii ``r_A = sqrt(r_vb^2 + T1A^2) < r_Ff`` (a negative T1A:
   the partner's tip reaches below the base circle);
7. **face width** at most a third of the outer cone distance (the usual bevel-gear limit; issue 42);
8. **transverse contact ratio** at least 1: ISO 10300's virtual-spur-gear formula
   ``eps_va = (sqrt(r_va1^2 - r_vb1^2) + sqrt(r_va2^2 - r_vb2^2) - a_v sin(alpha)) / (pi m cos(alpha))``,
   evaluated with the active tip circles (the tip circle less what the tip rounding takes off: the contact
   ends where the rounding starts): :func:`iso10300_contact_ratio`;

and last, 9. the exact tooth (``geometry.gear_geometry``) must build: a tip rounding that does not fit
above the base cone, or flanks meeting below the tip cone, are reported with the geometry's own words.

The other pairs of issue 42's checks (their scenes in scenarios/other_gearboxes/) are :data:`OTHER_PAIRS`.
"""
from __future__ import annotations

import math
import numbers

from gearcontact_fmu.params import BevelGearParams

__all__ = ["PairError", "pair_problems", "check_pair", "virtual_spur_pair", "iso10300_contact_ratio",
           "OTHER_PAIRS", "other_pair", "SHAFT_ANGLE_RANGE_DEG", "PRESSURE_ANGLE_RANGE_DEG",
           "MIN_TIP_THICKNESS_MODULES", "MAX_FACE_WIDTH_CONE_FRACTION", "RACK_ROOT_RADIUS_FACTOR"]

#: the shaft angles a pair may have [deg] (issue 42: any angle from 30 to 150 deg)
SHAFT_ANGLE_RANGE_DEG = (30.0, 150.0)
#: the pressure angles a pair may have [deg]: the standard straight-bevel range (14.5 .. 25 deg) with margin
PRESSURE_ANGLE_RANGE_DEG = (10.0, 35.0)
#: least normal tooth thickness at the outer tip circle, in modules (module docstring, item 5)
MIN_TIP_THICKNESS_MODULES = 0.2
#: largest face width as a fraction of the outer cone distance
MAX_FACE_WIDTH_CONE_FRACTION = 1.0 / 3.0
#: root radius of the generating rack in modules (ISO 53 profile A): where its straight flank ends
RACK_ROOT_RADIUS_FACTOR = 0.38
#: least transverse contact ratio (ISO 10300 virtual spur gears, active tips)
MIN_CONTACT_RATIO = 1.0


#: The other pairs of issue 42's checks, as BevelGearParams keywords (SI units, angles in rad), one table for
#: the library's checks (tests/gear_contact/test_pair_check.py, docs/GEAR-CONTACT.md "Other pairs") and the
#: scenes of scenarios/other_gearboxes/. Profile shift after Gleason's straight-bevel rule, the rule the rig's
#: x = 0.43 follows (wheel addendum (0.54 + 0.46 z_v1/z_v2) m, so x = 0.46 (1 - z_v1/z_v2): 0.431 for 15/60):
#: 0.35 for 20/40, 0 for the miter pair, 0.21 for 20/30 at 70 deg. Face widths about 0.28-0.30 of the outer
#: cone distance (<= 1/3, and <= 10 modules). Backlash and tip rounding: the rig's on a 3 mm module
#: (0.075 mm, 0.2 mm), about 4/3 of them on the 4 mm module.
OTHER_PAIRS = {
    # issue 42, item 3: a 20/40 pair of module 4 mm, 20 deg, at 90 deg (R_e = 89.44 mm, b = 0.28 R_e)
    "20x40_m4": dict(z_pinion=20, z_wheel=40, module=4.0e-3, pressure_angle=math.radians(20.0),
                     shaft_angle=math.radians(90.0), face_width=25.0e-3, x_pinion=0.35,
                     addendum_coefficient=1.0, dedendum_coefficient=1.25, backlash=0.1e-3, tip_radius=0.25e-3),
    # a 25/25 miter pair at 90 deg (R_e = 53.03 mm, b = 0.30 R_e): equal gears need no shift
    "miter25_m3": dict(z_pinion=25, z_wheel=25, module=3.0e-3, pressure_angle=math.radians(20.0),
                       shaft_angle=math.radians(90.0), face_width=16.0e-3, x_pinion=0.0,
                       addendum_coefficient=1.0, dedendum_coefficient=1.25, backlash=0.075e-3, tip_radius=0.2e-3),
    # a 20/30 pair at a shaft angle of 70 deg (delta_1 = 27.03 deg, R_e = 66.02 mm, b = 0.30 R_e)
    "20x30_s70_m3": dict(z_pinion=20, z_wheel=30, module=3.0e-3, pressure_angle=math.radians(20.0),
                         shaft_angle=math.radians(70.0), face_width=20.0e-3, x_pinion=0.21,
                         addendum_coefficient=1.0, dedendum_coefficient=1.25, backlash=0.075e-3,
                         tip_radius=0.2e-3),
}


def other_pair(name: str) -> BevelGearParams:
    """The BevelGearParams of one of :data:`OTHER_PAIRS`."""
    try:
        return BevelGearParams(**OTHER_PAIRS[name])
    except KeyError:
        raise KeyError(f"no other pair {name!r}; expected one of {sorted(OTHER_PAIRS)}") from None


class PairError(ValueError):
    """A bevel pair that cannot be made (found before any work). ``problems``: every reason, one sentence
    each (the figure, its value, its limit); the message lists them one per line."""

    def __init__(self, problems):
        if isinstance(problems, str):
            problems = [problems]
        self.problems = list(problems)
        super().__init__("bevel pair refused:\n" + "\n".join(f"  - {p}" for p in self.problems))


def _inv(a: float) -> float:
    return math.tan(a) - a


def virtual_spur_pair(params: BevelGearParams) -> dict:
    """The virtual spur gears of the back cone at the outer end (SI, radians), per gear ("pinion", "wheel":
    z_v, x, r_v, r_vb, r_va, r_va_active, s (pitch thickness incl. the backlash share), s_a (tip thickness),
    x_min (undercut limit), T_F (form circle along the line of action from T), r_Ff) and for the pair (a_v,
    the line-of-action lengths T1A, T2E of the partners' tips from each tangent point, h_FfP)."""
    p = params
    m, a = p.module, p.pressure_angle
    sa, ca = math.sin(a), math.cos(a)
    h_ffp = p.dedendum_coefficient - RACK_ROOT_RADIUS_FACTOR * (1.0 - sa)
    out = {"h_FfP": h_ffp}
    for role, z, delta, x in (("pinion", p.z_pinion, p.delta_pinion, p.x_pinion),
                              ("wheel", p.z_wheel, p.delta_wheel, -p.x_pinion)):
        zv = z / math.cos(delta)
        rv = 0.5 * m * zv
        rvb = rv * ca
        rva = rv + m * (p.addendum_coefficient + x)
        # active tip: the start of the tip rounding (its radius scales with the cone distance: tip_radius at
        # the outer end), on the virtual gear as for the geometry's Tredgold figure
        rva_act = rva - p.tip_radius * (1.0 - math.sin(math.acos(min(1.0, rvb / rva))))
        s = m * (0.5 * math.pi + 2.0 * x * math.tan(a)) - 0.5 * p.backlash
        alpha_a = math.acos(min(1.0, rvb / rva))
        s_a = 2.0 * rva * (s / (2.0 * rv) + _inv(a) - _inv(alpha_a))
        t_f = max(0.0, rv * sa - m * (h_ffp - x) / sa)
        out[role] = dict(z_v=zv, x=x, r_v=rv, r_vb=rvb, r_va=rva, r_va_active=rva_act, s=s, s_a=s_a,
                         x_min=h_ffp - 0.5 * zv * sa * sa, T_F=t_f, r_Ff=math.hypot(rvb, t_f))
    g1, g2 = out["pinion"], out["wheel"]
    a_v = g1["r_v"] + g2["r_v"]
    out["a_v"] = a_v
    out["T1A"] = a_v * sa - math.sqrt(g2["r_va"] ** 2 - g2["r_vb"] ** 2)   # wheel tip on the pinion's flank
    out["T2E"] = a_v * sa - math.sqrt(g1["r_va"] ** 2 - g1["r_vb"] ** 2)   # pinion tip on the wheel's flank
    return out


def iso10300_contact_ratio(params: BevelGearParams, active_tip: bool = True) -> float:
    """Transverse contact ratio of the virtual spur gears, ISO 10300-1 (method B):
    ``eps_va = (sqrt(d_va1^2 - d_vb1^2) / 2 + sqrt(d_va2^2 - d_vb2^2) / 2 - a_v sin(alpha)) / (pi m cos(alpha))``,
    at the outer end (the same at the mean cone distance: every length scales with it). ``active_tip``: the
    tip circles less what the tip rounding takes off (the contact ends where the rounding starts), else the
    tip circles themselves (the standard's figure for sharp tips)."""
    v = virtual_spur_pair(params)
    a = params.pressure_angle
    key = "r_va_active" if active_tip else "r_va"
    path = sum(math.sqrt(v[r][key] ** 2 - v[r]["r_vb"] ** 2) for r in ("pinion", "wheel"))
    return (path - v["a_v"] * math.sin(a)) / (math.pi * params.module * math.cos(a))


def _is_whole(v) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _within_deg(angle_rad: float, lo_deg: float, hi_deg: float) -> bool:
    """``lo_deg <= angle <= hi_deg``, the bounds inclusive to rounding (math.radians(30.0) is 29.999999999999996 deg)."""
    tol = 1e-12
    return math.radians(lo_deg) - tol <= angle_rad <= math.radians(hi_deg) + tol


def _data_problems(p: BevelGearParams) -> list[str]:
    out = []
    for name in ("z_pinion", "z_wheel"):
        v = getattr(p, name)
        if not _is_whole(v):
            out.append(f"teeth: {name} = {v!r} is not a whole number of teeth")
        elif v < 1:
            out.append(f"teeth: {name} = {v} must be at least 1")
    checks = (("module", "module [m]", lambda v: v > 0, "must be > 0"),
              ("face_width", "face width [m]", lambda v: v > 0, "must be > 0"),
              ("addendum_coefficient", "addendum factor h_a*", lambda v: v > 0, "must be > 0"),
              ("dedendum_coefficient", "dedendum factor h_f*", lambda v: v > 0, "must be > 0"),
              ("backlash", "backlash [m]", lambda v: v >= 0, "must be >= 0"),
              ("tip_radius", "tip rounding radius [m]", lambda v: v >= 0, "must be >= 0"),
              ("x_pinion", "profile shift x", lambda v: True, ""),
              ("pressure_angle", "pressure angle", lambda v: True, ""),
              ("shaft_angle", "shaft angle", lambda v: True, ""))
    for name, label, ok, limit in checks:
        v = getattr(p, name)
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
            out.append(f"data: {label} {name} = {v!r} is not a finite number")
        elif not ok(v):
            out.append(f"data: {label} {name} = {v!r} {limit}")
    if out:
        return out
    lo, hi = PRESSURE_ANGLE_RANGE_DEG
    if not _within_deg(p.pressure_angle, lo, hi):
        out.append(f"pressure angle: {math.degrees(p.pressure_angle):.4g} deg is outside {lo:g}..{hi:g} deg")
    if p.dedendum_coefficient <= p.addendum_coefficient:
        out.append(f"tip clearance: dedendum factor h_f* = {p.dedendum_coefficient:.4g} must exceed the addendum "
                   f"factor h_a* = {p.addendum_coefficient:.4g} (each tip runs (h_f* - h_a*) m = "
                   f"{(p.dedendum_coefficient - p.addendum_coefficient) * p.module * 1e3:.4g} mm above the partner's root)")
    lo, hi = SHAFT_ANGLE_RANGE_DEG
    S = math.degrees(p.shaft_angle)
    if not _within_deg(p.shaft_angle, lo, hi):
        out.append(f"shaft angle: {S:.4g} deg is outside {lo:g}..{hi:g} deg")
    return out


def pair_problems(params: BevelGearParams) -> list[str]:
    """Every reason the pair cannot be made, one sentence each (the figure, its value, its limit); [] when it
    can. The checks and their limits: the module docstring."""
    p = params
    out = _data_problems(p)
    if out:
        return out            # the derived figures need sound data
    for role, d in (("pinion", p.delta_pinion), ("wheel", p.delta_wheel)):
        if not 0.0 < d < 0.5 * math.pi:
            kind = "a crown gear" if d == 0.5 * math.pi else ("an internal bevel gear" if d > 0 else "no gear")
            out.append(f"pitch cone: the {role}'s pitch cone angle {math.degrees(d):.4g} deg must be below 90 deg "
                       f"({kind}: its virtual spur gear, the basis of the checks and of the ISO reference, "
                       f"is not defined; {p.z_pinion}/{p.z_wheel} teeth at a shaft angle of "
                       f"{math.degrees(p.shaft_angle):.4g} deg)")
    if out:
        return out
    m = p.module
    v = virtual_spur_pair(p)
    for role in ("pinion", "wheel"):
        g = v[role]
        if g["x"] < g["x_min"] - 1e-12:
            out.append(f"undercut: the {role}'s profile shift x = {g['x'] + 0.0:+.3f} is below the undercut limit "
                       f"x_min = h_FfP* - z_v sin^2(alpha)/2 = {g['x_min']:+.3f} of its virtual spur gear "
                       f"(z_v = z/cos(delta) = {g['z_v']:.4g}; rack of ISO 53 profile A, h_FfP* = {v['h_FfP']:.4g})")
    for role in ("pinion", "wheel"):
        g = v[role]
        lim = MIN_TIP_THICKNESS_MODULES * m
        if g["s_a"] < lim:
            out.append(f"pointed tip: the {role}'s tooth thickness at the outer tip circle s_a = "
                       f"{g['s_a'] * 1e3:.4g} mm ({g['s_a'] / m:.3g} m) is below {MIN_TIP_THICKNESS_MODULES:g} m = "
                       f"{lim * 1e3:.4g} mm (virtual spur gear z_v = {g['z_v']:.4g}, x = {g['x'] + 0.0:+.3f})")
    for role, partner, key in (("pinion", "wheel", "T1A"), ("wheel", "pinion", "T2E")):
        g = v[role]
        t = v[key]
        if t < g["T_F"] - 1e-12 * m:
            where = (f"at radius {math.hypot(g['r_vb'], t) * 1e3:.4g} mm" if t >= 0 else
                     f"below its base circle r_vb = {g['r_vb'] * 1e3:.4g} mm")
            out.append(f"interference: the {partner}'s tip meets the {role}'s flank {where}, below the start of its "
                       f"involute, the form circle r_Ff = {g['r_Ff'] * 1e3:.4g} mm (virtual spur gears; along the "
                       f"line of action the tip's path starts {t * 1e3:.4g} mm from the {role}'s tangent point, the "
                       f"involute {g['T_F'] * 1e3:.4g} mm from it)")
    Re = p.outer_cone_distance
    if p.face_width > MAX_FACE_WIDTH_CONE_FRACTION * Re * (1.0 + 1e-12):
        out.append(f"face width: {p.face_width * 1e3:.4g} mm is over a third of the outer cone distance "
                   f"R_e = {Re * 1e3:.4g} mm (at most {MAX_FACE_WIDTH_CONE_FRACTION * Re * 1e3:.4g} mm)")
    if all(v[r]["r_va_active"] > v[r]["r_vb"] for r in ("pinion", "wheel")):
        eps = iso10300_contact_ratio(p, active_tip=True)
        if eps < MIN_CONTACT_RATIO:
            out.append(f"contact ratio: the transverse contact ratio of the virtual spur gears (ISO 10300, active "
                       f"tips) eps_va = {eps:.4g} is below {MIN_CONTACT_RATIO:g}")
    else:
        out.append("contact ratio: a tip circle (less its rounding) lies inside the base circle of its virtual "
                   "spur gear: no involute contact (eps_va undefined, below 1)")
    if not out:
        from gearcontact_fmu.geometry import gear_geometry    # the exact tooth (only when the figures pass)

        for role in ("pinion", "wheel"):
            try:
                gear_geometry(p, role)
            except ValueError as exc:
                out.append(f"tooth form: the exact {role} tooth cannot be built: {exc}")
    return out


def check_pair(params: BevelGearParams) -> BevelGearParams:
    """``params`` when the pair can be made, else :class:`PairError` with every problem of :func:`pair_problems`."""
    problems = pair_problems(params)
    if problems:
        raise PairError(problems)
    return params
