"""Manufacturing errors of the bevel pair: tooth position (pitch) errors, runout and the teeth's profile
form deviation, carried by every compliant mesh fidelity as a transmission-error offset of the mesh coordinate.

What: each tooth of pinion and wheel sits a little off its nominal angular position (single pitch
deviations f_p accumulate to a tooth position error), and each gear runs a little eccentric on its
shaft (radial runout F_r = 2 e). Both delay or advance the flank in contact along the line of action.
Measured gears show them as shaft-order content: a peak at the rotation frequency of each gear and
sidebands of the mesh frequency at its orders, which the paper's healthy spectra show and a perfect
model does not have.

How: a mesh model evaluates its torques at the mesh coordinate s = theta_p - r theta_w (r = z2/z1).
The errors shift it, s' = s + Delta(theta_p, theta_w), with Delta in pinion-referred radians (a
length along the line of action divided by the pinion's mean base radius r_bp; the wheel's errors,
divided by its own base radius and referred through r, come out over r_bp as well):

* runout: Delta = (kappa_p e_p / r_bp) sin(theta_p + phi_p) - (kappa_w e_w / r_bp) sin(theta_w + phi_w):
  the gear's centre, displaced by e in its body frame, moves the flank along the contact normal by
  d . n. On a straight bevel the normal has cos(alpha) along the tangent and sin(alpha) normal to the
  pitch cone, whose in-plane part is sin(alpha) cos(delta); so the once-per-revolution transmission
  error has the amplitude kappa e, kappa = sqrt(cos^2 alpha + sin^2 alpha cos^2 delta) (0.997 for the
  pinion, 0.943 for the wheel), and a phase offset that a drawn phase absorbs. Checked against the
  online PCM with an eccentric mesh (tests/gear_contact/test_manufacturing.py: within 2 %);
* pitch: the position error of the tooth pair in mesh, e_n = P_p[k] - P_w[j] (over r_bp), where pair n
  (pinion tooth n mod z1, wheel tooth n mod z2 when both angles start together) is engaged over
  epsilon_alpha pitches centred at theta_p = n + CENTRE pitches (contact_map finds tooth n in blocks n-1, n),
  entering and leaving with C1 ramps of RAMP pitches. In the double-contact zone the pair that leads
  carries the load, as the online PCM shows when one tooth is advanced by more than the load
  deflection (5 um at 20 N·m: that tooth carries 90-100 % of its error over its whole engagement):
  the larger error on the drive flank, the smaller on the coast flank, blended C1 with the engagement
  weights. Within 10 % of the PCM with a displaced tooth (tests/gear_contact/test_manufacturing.py); what it
  leaves out is the load sharing between two pairs whose errors differ by less than the deflection;
* profile: every tooth of a gear has the same profile form deviation, so the pair's transmission error
  gets a term periodic with the mesh (once per pitch), its fundamental
  Delta = (A_p sin(2 pi u + phi_p) + A_w sin(2 pi u + phi_w)) / r_bp, u = theta_p / pitch the engagement
  coordinate in pitches, A half the gear's peak-to-peak deviation along the line of action; summed
  once in :func:`offset_data` to one amplitude and phase (A sin(2 pi u + phi)). What it leaves out: the
  higher harmonics of the profile form and their load dependence (the deflection that spreads a pair's
  load over the double-contact zone).

The offset is applied by evaluating the wrapped model at the wheel angle theta_w - Delta / r. Its
torques are then the gradient of the shifted potential (chain rule: tau_p = tau_p0 - tau_w0 dDelta/dtheta_p / r,
tau_w = tau_w0 (1 - dDelta/dtheta_w / r)), so the excitation does the work it should and the stage's
energy audit still closes. Works for pcm, table and analytic (the rigid ideal mesh has no coordinate
to shift and refuses them).

Magnitudes come from an accuracy grade with the ISO 1328-1:1995 / ISO 1328-2:1997 formulas (the step
between grades is sqrt(2)): single pitch tolerance f_pt = (0.3 (m + 0.4 sqrt(d)) + 4) sqrt(2)^(Q-5) um,
total cumulative pitch F_p = (0.3 m + 1.25 sqrt(d) + 7) sqrt(2)^(Q-5) um and radial runout
F_r = 0.8 F_p, profile form f_falpha = (2.5 sqrt(m) + 0.17 sqrt(d) + 0.5) sqrt(2)^(Q-5) um (ISO
1328-1:1995, clause 6; its peak-to-peak along the line of action) (m in mm, d the pitch diameter in mm), or
from explicit values. Draws, seeded: single pitch
deviations normal with sigma = f_pt / 2 (95 % within the tolerance) clipped to +-f_pt, summed to tooth
positions that close the circle; eccentricity e = F_r / 2 at a uniform phase; with profile errors, the
amplitude f_falpha / 2 at a uniform phase in the mesh cycle (drawn after the others).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from gearcontact_fmu import geometry
from gearcontact_fmu.mesh_models.analytic import _smoothstep, virtual_spur_gears
from gearcontact_fmu.manufacturing_specs import ManufacturingErrors, errors_of
from gearcontact_fmu.mesh_models.base import OUT_TAU_PINION, OUT_TAU_WHEEL, MeshModel
from gearcontact_fmu.params import BevelGearParams

# layout of the parameter array of the offset kernel
P_PITCH_P, P_RATIO, P_ECC_P, P_PHASE_P, P_ECC_W, P_PHASE_W, P_EPS, P_RAMP, P_PROF_A, P_PROF_PHASE, N_P = range(11)

#: where pair n's engagement is centred [pitches from theta_p = n pitches] and the length of the C1
#: ramps at its ends [pitches]: measured on the online PCM with one advanced tooth at 20 N·m (entry at
#: 4.16, exit at 5.72 pitches for tooth 5, each within ~0.05 pitch; tests/gear_contact/test_manufacturing.py)
CENTRE = -0.06
RAMP = 0.05


def runout_factor(gear: BevelGearParams, member: str) -> float:
    """kappa: the part of an eccentricity that moves the flank along the contact normal (module docstring)."""
    a = gear.pressure_angle
    d = gear.delta_pinion if member == "pinion" else gear.delta_wheel
    return math.sqrt(math.cos(a) ** 2 + (math.sin(a) * math.cos(d)) ** 2)


def offset_data(errors: ManufacturingErrors, gear: BevelGearParams | None = None) -> tuple:
    """Parameter tuple of :func:`te_offset`: (p, pinion errors [rad of s], wheel errors [rad of s])."""
    gear = gear or BevelGearParams()
    errors.check(gear)
    rb = geometry.mean_base_radius(gear)
    p = np.zeros(N_P)
    p[P_PITCH_P] = 2.0 * math.pi / gear.z_pinion
    p[P_RATIO] = gear.z_wheel / gear.z_pinion
    p[P_ECC_P] = errors.pinion_eccentricity_um * 1e-6 * runout_factor(gear, "pinion") / rb
    p[P_PHASE_P] = errors.pinion_phase_rad
    p[P_ECC_W] = errors.wheel_eccentricity_um * 1e-6 * runout_factor(gear, "wheel") / rb
    p[P_PHASE_W] = errors.wheel_phase_rad
    p[P_EPS] = virtual_spur_gears(gear)["eps_alpha"]
    p[P_RAMP] = RAMP
    # the profile terms of both gears at the mesh frequency, summed to one sine (complex amplitudes)
    c = (0.5 * errors.pinion_profile_um * complex(math.cos(errors.pinion_profile_phase_rad),
                                                  math.sin(errors.pinion_profile_phase_rad))
         + 0.5 * errors.wheel_profile_um * complex(math.cos(errors.wheel_profile_phase_rad),
                                                   math.sin(errors.wheel_profile_phase_rad)))
    p[P_PROF_A] = abs(c) * 1e-6 / rb
    p[P_PROF_PHASE] = math.atan2(c.imag, c.real) if p[P_PROF_A] != 0.0 else 0.0
    pin = np.array(errors.pinion_position_um or [0.0] * gear.z_pinion, dtype=np.float64) * 1e-6 / rb
    whl = np.array(errors.wheel_position_um or [0.0] * gear.z_wheel, dtype=np.float64) * 1e-6 / rb
    return (p, pin, whl)


@njit(cache=True)
def te_offset(te, theta_pinion, theta_wheel):
    """Offset Delta of the mesh coordinate [rad] and its partial derivatives by the two angles."""
    p, pin, whl = te
    d = p[P_ECC_P] * math.sin(theta_pinion + p[P_PHASE_P]) - p[P_ECC_W] * math.sin(theta_wheel + p[P_PHASE_W])
    dp = p[P_ECC_P] * math.cos(theta_pinion + p[P_PHASE_P])
    dw = -p[P_ECC_W] * math.cos(theta_wheel + p[P_PHASE_W])
    u = theta_pinion / p[P_PITCH_P]                      # engagement coordinate [pitches]
    v = theta_wheel * p[P_RATIO] / p[P_PITCH_P]          # the same, from the wheel (u - v = s / pitch)
    shift = math.floor(v - u + 0.5)                      # wheel tooth offset (0 unless s is a pitch off)
    half, ramp = 0.5 * p[P_EPS], p[P_RAMP]
    s = theta_pinion - p[P_RATIO] * theta_wheel
    zp, zw = pin.shape[0], whl.shape[0]
    # the engaged pairs (at most two while epsilon_alpha + ramp < 2): weight, its u-derivative, error
    # (scalars, not arrays: this runs 4 times per sub-step)
    w0 = dw0 = e0 = w1 = dw1 = e1 = w2 = dw2 = e2 = 0.0
    m = 0
    n0 = math.floor(u)
    for n in range(n0 - 1, n0 + 3):
        c = n + CENTRE
        a, da = _smoothstep((u - (c - half)) / ramp + 0.5)      # pair n engages ...
        b, db = _smoothstep((u - (c + half)) / ramp + 0.5)      # ... and leaves
        w = a - b
        if w <= 0.0 or m == 3:
            continue
        e = pin[n % zp] - whl[(n + shift) % zw]
        if m == 0:
            w0, dw0, e0 = w, (da - db) / ramp, e
        elif m == 1:
            w1, dw1, e1 = w, (da - db) / ramp, e
        else:
            w2, dw2, e2 = w, (da - db) / ramp, e
        m += 1
    a_prof = p[P_PROF_A]
    prof = dprof = 0.0
    if a_prof != 0.0:                                    # the profile form: once per pitch
        x = 2.0 * math.pi * u + p[P_PROF_PHASE]
        prof = a_prof * math.sin(x)
        dprof = a_prof * math.cos(x) * 2.0 * math.pi / p[P_PITCH_P]
    if m == 1:
        d += e0
    elif m == 2:
        # states {only a, only b, both}; with both engaged the leading pair carries: on the drive flank
        # the more advanced one (max), on the coast flank the less advanced one (min). Which flank: the
        # one on this side of the offset mesh's backlash centre, halfway between the drive flank's offset
        # and the coast flank's (each flank's onset moves by its own offset). Not s = 0: a gearbox whose
        # errors close the backlash past its nominal centre kept contact at s < 0 only on the coast rule,
        # and its mesh torque jumped at s = 0 (seed 42 at 11.9 N m: from 0 to 32.5 N m on the pinion)
        den = w0 + w1 - w0 * w1
        mid = d + prof + (w0 * w1 * 0.5 * (e0 + e1) + w0 * (1.0 - w1) * e0 + w1 * (1.0 - w0) * e1) / den
        drive = s + mid >= 0.0
        lead = max(e0, e1) if drive else min(e0, e1)
        num = w0 * w1 * lead + w0 * (1.0 - w1) * e0 + w1 * (1.0 - w0) * e1
        dnum = (dw0 * w1 + w0 * dw1) * lead + (dw0 * (1.0 - w1) - w0 * dw1) * e0 \
            + (dw1 * (1.0 - w0) - w1 * dw0) * e1
        dden = dw0 + dw1 - dw0 * w1 - w0 * dw1
        d += num / den
        dp += (dnum * den - num * dden) / (den * den) / p[P_PITCH_P]
    elif m == 3:                                         # a contact ratio near 2: the weighted mean
        sw = w0 + w1 + w2
        swe = w0 * e0 + w1 * e1 + w2 * e2
        dsw = dw0 + dw1 + dw2
        dswe = dw0 * e0 + dw1 * e1 + dw2 * e2
        d += swe / sw
        dp += (dswe * sw - swe * dsw) / (sw * sw) / p[P_PITCH_P]
    if a_prof != 0.0:
        d += prof
        dp += dprof
    return d, dp, dw


def mesh_offset(errors, theta_pinion: float, theta_wheel: float, gear: BevelGearParams | None = None) -> float:
    """Delta [rad of s] of ``errors`` (any form errors_of takes) at one pair of angles; 0 without errors."""
    errors = errors_of(errors)
    if errors is None:
        return 0.0
    return float(te_offset(offset_data(errors, gear), float(theta_pinion), float(theta_wheel))[0])


_WRAPPERS: dict = {}


def _wrapped(inner_eval):
    """The eval of ``inner_eval`` at the offset mesh coordinate (one compiled wrapper per inner kernel)."""
    f = _WRAPPERS.get(inner_eval)
    if f is None:
        @njit
        def f(data, theta_pinion, theta_wheel, omega_pinion, omega_wheel, out):
            inner, te = data
            r = te[0][P_RATIO]
            d, dp, dw = te_offset(te, theta_pinion, theta_wheel)
            inner_eval(inner, theta_pinion, theta_wheel - d / r, omega_pinion,
                       omega_wheel - (dp * omega_pinion + dw * omega_wheel) / r, out)
            tp = out[OUT_TAU_PINION]
            tw = out[OUT_TAU_WHEEL]
            out[OUT_TAU_PINION] = tp - tw * dp / r
            out[OUT_TAU_WHEEL] = tw * (1.0 - dw / r)

        _WRAPPERS[inner_eval] = f
    return f


def split_offset(model: MeshModel) -> tuple[tuple, tuple | None]:
    """(the data of the mesh model inside, the offset data or None): the layout :func:`with_errors` gives a
    model's data, ``(inner data, offset data)``, read here so that no caller guesses it from a length."""
    if OFFSET_INFO in model.info:
        return model.data
    return model.data, None


#: the key of MeshModel.info that marks a model wrapped by with_errors (its value: the errors' dict)
OFFSET_INFO = "manufacturing_errors"


def with_errors(model: MeshModel, errors, gear: BevelGearParams | None = None) -> MeshModel:
    """``model`` with the manufacturing errors applied: ``errors`` a ManufacturingErrors, its dict or JSON
    (:func:`manufacturing_specs.errors_of`); unchanged if None or empty."""
    errors = errors_of(errors)
    if errors is None:
        return model
    if model.kind == "rigid":
        raise ValueError("the ideal (rigid) mesh cannot carry manufacturing errors: it has no mesh "
                         "coordinate to offset; use fidelity pcm, table or analytic")
    te = offset_data(errors, gear)
    info = {**model.info, OFFSET_INFO: errors.to_dict()}
    return MeshModel(eval=_wrapped(model.eval), data=(model.data, te), fidelity=model.fidelity, kind=model.kind,
                     info=info)
