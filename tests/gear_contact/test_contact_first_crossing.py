"""The first-crossing rule of the penetration line (root cause of the mild-fault failure, docs/STABILITY.md).

A base element penetrates the target only if its base point lies inside the target: the first target
surface its inward line crosses must be an exit. Before the rule, a line that left the base body,
entered the target and exited again counted the exit as a penetration (0.82 mm from the walls of the
mild fault's void, with +650 N·m of wrong-signed pinion torque in the contact map).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from gearcontact_fmu.contact import primitives as P
from gearcontact_fmu.contact.engine import PCMBody, evaluate_pair, fixed_axis_eval, make_fixed_axis_data
from gearcontact_fmu.mesh_models.base import N_OUT, OUT_MAX_PENETRATION, OUT_N_CONTACT, OUT_STATUS, OUT_TAU_PINION
from gearcontact_fmu.params import PCMParams

PCM = PCMParams(u_max=2e-3)
I3 = np.eye(3)
Z3 = np.zeros(3)


def closed_box(lo, hi, n=4):
    """A closed box surface (outward normals) from six plates."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    cx, cy, cz = (x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2
    sx, sy, sz = x1 - x0, y1 - y0, z1 - z0
    parts = []
    V, F = P.plate(n, n, sx, sy, z=z1, up=True, centre=(cx, cy))
    parts.append((V, F))
    V, F = P.plate(n, n, sx, sy, z=z0, up=False, centre=(cx, cy))
    parts.append((V, F))
    # side faces: plates in a local frame (x', y', normal z'), mapped by a rotation
    for normal, (a, b, c), (la, lb), off in (
            ((1, 0, 0), ((0, 1, 0), (0, 0, 1), (1, 0, 0)), (sy, sz), x1 - cx),
            ((-1, 0, 0), ((0, 0, 1), (0, 1, 0), (-1, 0, 0)), (sz, sy), cx - x0),
            ((0, 1, 0), ((0, 0, 1), (1, 0, 0), (0, 1, 0)), (sz, sx), y1 - cy),
            ((0, -1, 0), ((1, 0, 0), (0, 0, 1), (0, -1, 0)), (sx, sz), cy - y0)):
        V, F = P.plate(n, n, la, lb, z=off, up=True)
        R = np.array([a, b, c], dtype=float).T          # local x', y', z' -> world columns
        parts.append((V @ R.T + np.array([cx, cy, cz]), F))
    verts, faces, k = [], [], 0
    for V, F in parts:
        verts.append(V)
        faces.append(F + k)
        k += len(V)
    return np.vstack(verts), np.vstack(faces)


def _bodies(z_lo, z_hi):
    base = PCMBody(*P.plate(8, 8, 2e-3, 2e-3, z=0.0, up=True))      # base below z = 0, inward -z
    target = PCMBody(*closed_box((-0.5e-3, -0.5e-3, z_lo), (0.5e-3, 0.5e-3, z_hi)))
    return base, target


def test_closed_box_normals_point_out():
    V, F = closed_box((-1, -1, -1), (1, 1, 1))
    tri = V[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    c = tri.mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", n, c) > 0)


@pytest.mark.parametrize("path", ["exact", "fixed_axis"])
def test_line_through_a_detached_target_is_no_contact(path):
    """Target 0.5..0.8 mm below the base surface, not touching it: the line enters the box top at
    0.5 mm and leaves through its bottom at 0.8 mm. No base point is inside the target: no contact."""
    base, target = _bodies(-0.8e-3, -0.5e-3)
    if path == "exact":
        res = evaluate_pair(base, target, (I3, Z3), (I3, Z3), pcm=PCM, check_penetration=False)
        assert res.n_contact == 0 and res.max_penetration == 0.0
    else:
        data = make_fixed_axis_data(base, target, I3, I3, PCM)
        out = np.zeros(N_OUT)
        for _ in range(3):                       # first call builds the candidate cache, then reuses it
            fixed_axis_eval(data, 0.0, 0.0, 0.0, 0.0, out)
            assert out[OUT_N_CONTACT] == 0 and out[OUT_MAX_PENETRATION] == 0.0


@pytest.mark.parametrize("path", ["exact", "fixed_axis"])
def test_base_point_inside_the_target_still_penetrates(path):
    """Control: the box reaches 0.05 mm above the base surface, so the base points over its footprint
    are inside it (the entry at s = -0.05 mm lies behind them): penetration 0.8 mm to the box bottom."""
    base, target = _bodies(-0.8e-3, 0.05e-3)
    if path == "exact":
        res = evaluate_pair(base, target, (I3, Z3), (I3, Z3), pcm=PCM, check_penetration=False)
        n, umax = res.n_contact, res.max_penetration
    else:
        data = make_fixed_axis_data(base, target, I3, I3, PCM)
        out = np.zeros(N_OUT)
        fixed_axis_eval(data, 0.0, 0.0, 0.0, 0.0, out)
        fixed_axis_eval(data, 0.0, 0.0, 0.0, 0.0, out)
        n, umax = out[OUT_N_CONTACT], out[OUT_MAX_PENETRATION]
    assert n > 0
    assert umax == pytest.approx(0.8e-3, rel=1e-9)


@pytest.fixture(scope="module")
def mild_pair():
    from gearcontact_fmu.mesh_models.pcm import build_pcm_pair

    return build_pcm_pair(health="mild")


def test_void_passage_has_no_wrong_signed_torque(mild_pair):
    """The mild fault's void passes the mesh at pinion angles ~340-345 deg. On the drive side the
    elastic mesh torque on the pinion opposes the approach (<= 0) and the penetration stays elastic
    (micrometres) from the contact onset to the approach of 200 N·m; before the first-crossing rule
    the void walls gave u = 0.75-0.95 mm and up to +700 N·m there."""
    from gearcontact_fmu.mesh_models.pcm import contact_onset
    from gearcontact_fmu.geometry import mean_base_radius

    pair = mild_pair
    rb = mean_base_radius(pair.gear)
    out = np.zeros(N_OUT)
    for deg in np.arange(339.0, 346.01, 0.5):
        th = math.radians(deg)
        on = contact_onset(pair, th, +1, max_approach=0.5e-3)
        assert math.isfinite(on)
        assert abs(on - contact_onset(pair, math.radians(deg + 180.0), +1)) * rb < 2e-6
        for approach_m in (0.2e-6, 1e-6, 3e-6, 6e-6):
            pair.evaluate(th, pair.wheel_angle(th, on + approach_m / rb), 0.0, 0.0, out)
            assert out[OUT_STATUS] == 0
            assert out[OUT_TAU_PINION] <= 0.0, (deg, approach_m, out[OUT_TAU_PINION])
            assert out[OUT_MAX_PENETRATION] < 20e-6, (deg, approach_m, out[OUT_MAX_PENETRATION])
