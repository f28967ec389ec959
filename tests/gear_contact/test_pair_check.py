"""Which bevel pairs can be made (gearcontact_fmu.pair_check): one refusal per kind of impossible data, each
with its own message naming the figure, its value and its limit; the rig and the other pairs of issue 42 pass.

Oracles: the classic limits (z_min = 2 / sin^2(alpha) = 17 teeth for an unshifted spur gear, a rack's straight
flank of 1.0 m for ISO 53 profile A), and the exact spherical-involute tooth (geometry) for the tip thickness
of the virtual spur gear (Tredgold)."""
from __future__ import annotations

import dataclasses
import math

import pytest

from gearcontact_fmu import geometry as G
from gearcontact_fmu.pair_check import (OTHER_PAIRS, PairError, check_pair, iso10300_contact_ratio, other_pair,
                                        pair_problems, virtual_spur_pair)
from gearcontact_fmu.params import BevelGearParams

RIG = BevelGearParams()
R = math.radians

#: one case per kind of impossible gear data: (the data, the start of every problem it must give, words the
#: message must carry: the figure's value and its limit)
BAD = {
    "undercut": (dict(z_pinion=10, z_wheel=10, face_width=6e-3, x_pinion=0.0),
                 "undercut:", ["x = +0.000", "x_min", "+0.173", "z_v = z/cos(delta) = 14.14"]),
    "pointed tip": (dict(x_pinion=0.8), "pointed tip:", ["s_a = 0.4667 mm", "0.2 m = 0.6 mm"]),
    "interference": (dict(dedendum_coefficient=1.1), "interference:",
                     ["the wheel's tip meets the pinion's flank", "form circle r_Ff = 22.2 mm", "at radius 22 mm"]),
    "face width": (dict(face_width=35e-3), "face width:", ["35 mm", "R_e = 92.77 mm", "at most 30.92 mm"]),
    "contact ratio": (dict(z_pinion=25, z_wheel=25, face_width=16e-3, x_pinion=0.0, addendum_coefficient=0.5),
                      "contact ratio:", ["eps_va = 0.8381", "below 1"]),
    "shaft angle high": (dict(z_pinion=25, z_wheel=25, face_width=16e-3, x_pinion=0.0, shaft_angle=R(160.0)),
                         "shaft angle:", ["160 deg", "30..150 deg"]),
    "shaft angle low": (dict(z_pinion=25, z_wheel=25, face_width=5e-3, x_pinion=0.0, shaft_angle=R(20.0)),
                        "shaft angle:", ["20 deg", "30..150 deg"]),
    "internal gear": (dict(z_pinion=20, z_wheel=60, shaft_angle=R(120.0), face_width=10e-3, x_pinion=0.0),
                      "pitch cone:", ["100.9 deg", "below 90 deg", "internal bevel gear"]),
    "teeth not whole": (dict(z_pinion=15.5), "teeth:", ["z_pinion = 15.5", "whole number"]),
    "teeth zero": (dict(z_wheel=0), "teeth:", ["z_wheel = 0", "at least 1"]),
    "teeth bool": (dict(z_wheel=True), "teeth:", ["z_wheel = True", "whole number"]),
    "module": (dict(module=-3e-3), "data:", ["module = -0.003", "> 0"]),
    "not finite": (dict(backlash=float("nan")), "data:", ["backlash = nan", "finite"]),
    "pressure angle": (dict(pressure_angle=R(45.0)), "pressure angle:", ["45 deg", "10..35 deg"]),
    "tip clearance": (dict(dedendum_coefficient=1.0), "tip clearance:", ["h_f* = 1", "h_a* = 1"]),
    "tooth form": (dict(tip_radius=1.5e-3), "tooth form:", ["pinion", "pointed tooth"]),
}


@pytest.mark.parametrize("kind", list(BAD))
def test_each_kind_of_impossible_data_is_refused_with_its_own_message(kind):
    data, prefix, words = BAD[kind]
    problems = pair_problems(BevelGearParams(**data))
    print(f"\n {kind}: {problems}")
    assert problems and all(p.startswith(prefix) for p in problems), problems
    for w in words:
        assert any(w in p for p in problems), (w, problems)
    # no other kind answers this case (each message is its own)
    others = {b[1] for k, b in BAD.items() if b[1] != prefix}
    assert not any(p.startswith(o) for p in problems for o in others)
    with pytest.raises(PairError) as exc:
        check_pair(BevelGearParams(**data))
    assert exc.value.problems == problems and isinstance(exc.value, ValueError)
    assert all(p in str(exc.value) for p in problems)


def test_problems_are_collected_together():
    bad = BevelGearParams(face_width=35e-3, x_pinion=0.8, dedendum_coefficient=1.1)
    with pytest.raises(PairError) as exc:
        check_pair(bad)
    kinds = {p.split(":")[0] for p in exc.value.problems}
    assert {"pointed tip", "face width", "interference"} <= kinds, exc.value.problems
    assert str(exc.value).startswith("bevel pair refused:\n  - ")


@pytest.mark.parametrize("name", [None, *OTHER_PAIRS])
def test_the_rig_and_the_other_pairs_pass(name):
    params = RIG if name is None else other_pair(name)
    assert pair_problems(params) == []
    assert check_pair(params) is params


def test_other_pairs_table():
    """The table of issue 42's other pairs: 20/40 of module 4 mm at 90 deg; a miter pair; a pair at 70 deg."""
    p = other_pair("20x40_m4")
    assert (p.z_pinion, p.z_wheel, p.module, p.shaft_angle) == (20, 40, 4e-3, R(90.0))
    assert p.pressure_angle == R(20.0)
    m = other_pair("miter25_m3")
    assert m.z_pinion == m.z_wheel == 25 and m.x_pinion == 0.0 and m.delta_pinion == pytest.approx(math.pi / 4)
    s = other_pair("20x30_s70_m3")
    assert math.degrees(s.shaft_angle) == pytest.approx(70.0)
    for name in OTHER_PAIRS:
        q = other_pair(name)
        assert q.face_width <= q.outer_cone_distance / 3 and q.face_width <= 10 * q.module
    with pytest.raises(KeyError, match="expected one of"):
        other_pair("nope")


def test_undercut_limit_is_the_classic_one():
    """Unshifted, the undercut limit of ISO 53 profile A is z_v = 2 / sin^2(alpha) = 17.1 teeth (the rack's
    straight flank ends 1.25 - 0.38 (1 - sin 20 deg) = 1.000 m below its reference line)."""
    z_lim = 2.0 / math.sin(R(20.0)) ** 2
    for zv, undercut in ((z_lim * 0.97, True), (z_lim * 1.03, False)):
        # a miter pair: z_v = z / cos(45 deg); choose the face width to pass
        z = zv * math.cos(math.pi / 4)
        lo, hi = math.floor(z), math.ceil(z)
        z = lo if undercut else hi
        p = BevelGearParams(z_pinion=z, z_wheel=z, x_pinion=0.0, face_width=0.3 * 3e-3 * z / (2 * math.sin(math.pi / 4)))
        v = virtual_spur_pair(p)
        assert v["h_FfP"] == pytest.approx(1.0, abs=2e-4)
        assert (v["pinion"]["x_min"] > 0) == (v["pinion"]["z_v"] < z_lim)
        assert any(q.startswith("undercut") for q in pair_problems(p)) == (v["pinion"]["z_v"] < z_lim)


@pytest.mark.parametrize("name", [None, *OTHER_PAIRS])
def test_tip_thickness_of_the_virtual_gear_is_the_exact_tooths(name):
    """The pointed-tip figure (virtual spur gear, Tredgold) against the exact spherical-involute tooth: the
    arc thickness at the outer end of the tip cone (sharp tip: no rounding) agrees within 1 %."""
    params = RIG if name is None else other_pair(name)
    sharp = dataclasses.replace(params, tip_radius=0.0)
    v = virtual_spur_pair(params)
    for role in G.ROLES:
        g = G.gear_geometry(sharp, role)
        exact = 2.0 * (-g.az_land) * g.Re * math.sin(g.delta_a)
        assert v[role]["s_a"] == pytest.approx(exact, rel=0.01), role


def test_iso10300_contact_ratio_formula():
    """The formula by hand for the rig: outer end, z_v = 15.46 / 247.4, active tip circles; with sharp tips
    it is the plain ISO 10300 figure (1.550)."""
    m, a = 3e-3, R(20.0)
    tot = 0.0
    rv_sum = 0.0
    for z, d, x in ((15, RIG.delta_pinion, 0.43), (60, RIG.delta_wheel, -0.43)):
        rv = m * z / math.cos(d) / 2
        rb, ra = rv * math.cos(a), rv + m * (1 + x)
        tot += math.sqrt(ra * ra - rb * rb)
        rv_sum += rv
    eps = (tot - rv_sum * math.sin(a)) / (math.pi * m * math.cos(a))
    assert iso10300_contact_ratio(RIG, active_tip=False) == pytest.approx(eps, rel=1e-12)
    assert eps == pytest.approx(1.550, abs=1e-3)
    assert iso10300_contact_ratio(RIG) < eps
