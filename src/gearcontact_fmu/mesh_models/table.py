"""The precomputed contact map as a mesh model ("table" fidelity): the interpolating kernel and its data.

``table_eval`` interpolates a :class:`gearcontact_fmu.contact_map.ContactMap` at run time: periodic
linear in the pinion angle (over one revolution, or the tooth-pairing period when the wheel's teeth
differ), the contact onset of each flank linear in theta, the elastic torques and diagnostics bilinear in
(theta, approach beyond the onset), zero in the backlash, linear extrapolation beyond the grid (a
penetration beyond u_max there sets the error status). Contact damping is the tabulated torsional
coefficient times c_compression or c_expansion (whether the flank in contact closes or opens); friction
the torques tabulated at the reference speed, scaled by the regularised sign of the pinion speed.
``make_table_data`` turns a map into the kernel's data (with the optional series tooth compliance),
``make_table_model`` gets the map of a configuration (cache, seed or build: ``contact_map.get_map``) and
returns the MeshModel. How a map is built and cached is ``gearcontact_fmu.contact_map``'s concern.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from gearcontact_fmu.contact_map import (CH_AREA, CH_DAMP, CH_EEL, CH_FN, CH_FRIC_P, CH_FRIC_W, CH_N, CH_PEAK,
                                         CH_PEN, CH_TAU_P, CH_TAU_W, SEED_DIR, ContactMap, get_map, map_file_name)
from gearcontact_fmu.mesh_models.base import (OUT_CONTACT_AREA, OUT_DISSIPATED_POWER, OUT_ELASTIC_ENERGY,
                                        OUT_MAX_PENETRATION, OUT_N_CONTACT, OUT_NORMAL_FORCE, OUT_PEAK_PRESSURE,
                                        OUT_STATUS, OUT_TAU_PINION, OUT_TAU_WHEEL, MeshModel, read_only)
from gearcontact_fmu.mesh_models.pcm import fault_kwargs_of
from gearcontact_fmu.elastic_layer import pair_pcm
from gearcontact_fmu.params import BevelGearParams, MapGrid, MeshResolution, PCMParams


def make_table_data(cmap: ContactMap, friction: bool = True, damping: bool = True, compliance: float = 1.0) -> tuple:
    """Kernel data of a map. ``compliance`` > 1 puts a series compliance (compliance - 1) times the layers'
    own behind them: the approach axis stretches by that factor at every angle and load (the contact
    pattern at a load is the layers', the deflection grows), the elastic energy with it, and the contact
    damping, which acts on the layers' rate, is referred through it (divided by the factor)."""
    z1, z2 = cmap.gear.z_pinion, cmap.gear.z_wheel
    n_rev = cmap.values.shape[0] // (cmap.grid.points_per_pitch * z1)
    if not (math.isfinite(compliance) and compliance >= 1.0):
        raise ValueError(f"tooth compliance factor must be >= 1 (1 = none), not {compliance!r}")
    values, a = cmap.values, cmap.a
    if compliance != 1.0:
        values = values.copy()
        values[..., CH_EEL] *= compliance
        values[..., CH_DAMP] /= compliance
        a = a * compliance
    return (read_only(values), read_only(a), read_only(cmap.onset),
            float(cmap.theta[1] - cmap.theta[0]), float(z2) / float(z1),
            float(cmap.pcm.c_compression if damping else 0.0), float(cmap.pcm.c_expansion if damping else 0.0),
            float(cmap.pcm.u_max), 1.0 if friction else 0.0, float(cmap.grid.omega_regularisation), n_rev)


def make_table_model(gear_params=None, pcm_params=None, resolution=None, health="healthy",
                     mesh_files=None, mesh_units="mm", friction=True, damping=True, grid=None, faults=(),
                     tooth_compliance: float = 1.0, build: bool = True, **kw):
    """MeshModel of the precomputed contact map (fidelity "table"); ``tooth_compliance``: the series
    factor of :func:`make_table_data` (1 = the layers alone, the paper's model). ``build=False``: only a
    cached or shipped map, ``build="shipped"``: only a shipped one (LookupError when there is none)."""
    fault_kwargs = fault_kwargs_of(health, faults)
    if build == "shipped" and not (SEED_DIR / map_file_name(
            gear_params or BevelGearParams(), pair_pcm(gear_params, pcm_params), resolution or MeshResolution(), health,
            {k: v for k, v in (mesh_files or {}).items() if v}, grid or MapGrid(), mesh_units, fault_kwargs)).exists():
        raise LookupError("no contact map of this configuration is shipped")
    cmap = get_map(gear_params, pcm_params, resolution, health, mesh_files, grid, mesh_units,
                   fault_kwargs=fault_kwargs, build=bool(build))
    if cmap is None:
        raise LookupError("the contact map of this configuration is not cached (build=False)")
    return MeshModel(eval=table_eval, data=make_table_data(cmap, friction, damping, float(tooth_compliance)),
                     fidelity="table", kind="mesh", info={**cmap.info, "tooth_compliance": float(tooth_compliance)})



@njit(cache=True)
def _locate(s_nodes, s):
    """Index j and weight w with s = (1-w) s[j] + w s[j+1]; w may leave [0, 1] outside the grid."""
    n = s_nodes.shape[0]
    if s <= s_nodes[0]:
        j = 0
    elif s >= s_nodes[n - 1]:
        j = n - 2
    else:
        lo = 0
        hi = n - 1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if s_nodes[mid] <= s:
                lo = mid
            else:
                hi = mid
        j = lo
    w = (s - s_nodes[j]) / (s_nodes[j + 1] - s_nodes[j])
    return j, w


@njit(cache=True, inline="always")          # inlined: not one compilation per channel constant
def _bilinear(values, i0, i1, side, j, w, b, ch):
    """Value of channel ch between pinion-angle rows i0, i1 (weight b) and approach nodes j, j+1 (w)."""
    v0 = values[i0, side, j, ch] + w * (values[i0, side, j + 1, ch] - values[i0, side, j, ch])
    v1 = values[i1, side, j, ch] + w * (values[i1, side, j + 1, ch] - values[i1, side, j, ch])
    return v0 + b * (v1 - v0)


@njit(cache=True)
def table_eval(data, theta_pinion, theta_wheel, omega_pinion, omega_wheel, out):
    values, a_nodes, onset, dtheta, ratio, c_comp, c_exp, u_max, fric_on, w_reg, n_rev = data
    for k in range(out.shape[0]):
        out[k] = 0.0
    if not (math.isfinite(theta_pinion) and math.isfinite(theta_wheel)
            and math.isfinite(omega_pinion) and math.isfinite(omega_wheel)):
        out[OUT_STATUS] = 2.0
        return
    n_theta = values.shape[0]
    s = theta_pinion - ratio * theta_wheel
    sdot = omega_pinion - ratio * omega_wheel
    # periodic linear interpolation in theta, of the onsets and of the values. Over one pinion
    # revolution the row is the pinion angle; over the tooth-pairing period (n_rev revolutions) it is
    # the pinion angle unwrapped along the wheel's, ratio * theta_wheel (mod the period) + s
    two_pi = 2.0 * math.pi
    if n_rev == 1:
        th = theta_pinion - two_pi * math.floor(theta_pinion / two_pi)
    else:
        period = two_pi * n_rev
        th = ratio * theta_wheel
        th = th - period * math.floor(th / period) + s
        th = th - period * math.floor(th / period)
    x = th / dtheta
    i0 = int(math.floor(x))
    b = x - i0
    i0 = i0 % n_theta
    i1 = (i0 + 1) % n_theta
    on_d = onset[i0, 0] + b * (onset[i1, 0] - onset[i0, 0])
    on_c = onset[i0, 1] + b * (onset[i1, 1] - onset[i0, 1])
    if s >= 0.5 * (on_d + on_c):
        side = 0
        a = s - on_d
    else:
        side = 1
        a = on_c - s
    if a <= a_nodes[0]:
        return                                   # free flight in the backlash
    j, w = _locate(a_nodes, a)
    inside = w <= 1.0
    out[OUT_TAU_PINION] = _bilinear(values, i0, i1, side, j, w, b, CH_TAU_P)
    out[OUT_TAU_WHEEL] = _bilinear(values, i0, i1, side, j, w, b, CH_TAU_W)
    # positive-definite channels cannot go below zero through extrapolation
    out[OUT_N_CONTACT] = max(_bilinear(values, i0, i1, side, j, w, b, CH_N), 0.0)
    out[OUT_CONTACT_AREA] = max(_bilinear(values, i0, i1, side, j, w, b, CH_AREA), 0.0)
    out[OUT_PEAK_PRESSURE] = max(_bilinear(values, i0, i1, side, j, w, b, CH_PEAK), 0.0)
    out[OUT_MAX_PENETRATION] = max(_bilinear(values, i0, i1, side, j, w, b, CH_PEN), 0.0)
    out[OUT_NORMAL_FORCE] = max(_bilinear(values, i0, i1, side, j, w, b, CH_FN), 0.0)
    out[OUT_ELASTIC_ENERGY] = max(_bilinear(values, i0, i1, side, j, w, b, CH_EEL), 0.0)
    damp = max(_bilinear(values, i0, i1, side, j, w, b, CH_DAMP), 0.0)
    if out[OUT_TAU_PINION] == 0.0 and out[OUT_TAU_WHEEL] == 0.0:
        return
    # keep the elastic torques from changing sign through interpolation/extrapolation
    if side == 0:
        out[OUT_TAU_PINION] = min(out[OUT_TAU_PINION], 0.0)
        out[OUT_TAU_WHEEL] = max(out[OUT_TAU_WHEEL], 0.0)
    else:
        out[OUT_TAU_PINION] = max(out[OUT_TAU_PINION], 0.0)
        out[OUT_TAU_WHEEL] = min(out[OUT_TAU_WHEEL], 0.0)
    if not inside and out[OUT_MAX_PENETRATION] > u_max:
        out[OUT_STATUS] = 1.0                    # beyond the tabulated range and beyond u_max
    # contact damping: compressing when the flank in contact closes
    closing = sdot > 0.0 if side == 0 else sdot < 0.0
    d = c_comp if closing else c_exp
    tau_d = -d * damp * sdot
    # expansion damping cannot pull the flanks together (element forces are >= 0)
    if side == 0:
        tau_d = min(tau_d, -out[OUT_TAU_PINION])
    else:
        tau_d = max(tau_d, -out[OUT_TAU_PINION])
    tau_fp = 0.0
    tau_fw = 0.0
    if fric_on > 0.0:
        scale = min(max(omega_pinion / w_reg, -1.0), 1.0)
        tau_fp = scale * _bilinear(values, i0, i1, side, j, w, b, CH_FRIC_P)
        tau_fw = scale * _bilinear(values, i0, i1, side, j, w, b, CH_FRIC_W)
    out[OUT_TAU_PINION] += tau_d + tau_fp
    out[OUT_TAU_WHEEL] += -ratio * tau_d + tau_fw
    p = -tau_d * sdot - (tau_fp * omega_pinion + tau_fw * omega_wheel)
    out[OUT_DISSIPATED_POWER] = max(p, 0.0)
