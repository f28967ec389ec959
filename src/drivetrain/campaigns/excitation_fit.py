"""Identification from the rig's 2004 rpm excitation records (``drivetrain calibrate --record``, after the 500 rpm
background of campaigns.record_fit): what the impulse and the multi-sine on the load motor say of the first
mode, the drive's speed control and the shaft-order lines, each value with its source and a physical range.

1. **First mode** (identified): the impulse record's noise-driven ring after the pulse (rig.excitation.noise_mode:
   frequency and damping ratio); the multi-sine's response |H| at its load lines (32, 129, 256 Hz), beside the
   linearised model's (campaigns.record_fit.response at 2004 rpm): the 32 Hz line sits on the mode's flank.
2. **Speed control** (identified): around the pulse, the drive motor's torque (motor clock, put on the sensor
   clock by the pulse's peak in the propeller torque) against the drive-side encoder speed, both averaged over
   one middle-shaft revolution: a PI, dT = -Kp (dw + (1/Ti) int dw), by linear least squares.
3. **Shaft-order lines** (identified from the impulse record only: the calibration record; the multi-sine's lines
   judge the law, check 12): each line's amplitude in the impulse record's propeller-shaft torque over the model's
   |H| from a torque on the propeller mass at its frequency at 2004 rpm is its source torque at 2004 rpm; with the
   500 rpm sources ([background] order_*) each line's own speed law A(n) = A_500 (n / 500 rpm)^p_line (two
   speeds: exactly determined, a calibration; written as [background] order_*_exponent). Each line has its own
   mechanism (runout and bow of the middle and drive shafts at 1x, misalignment at 2x), so one exponent for
   all need not hold; the common exponent (least squares in log over the four) is shown beside them and kept
   for the planetary's mesh, which has no second speed. ``judge``: the multi-sine record's lines beside the
   linear model's prediction from the calibrated law (the simulated judgement is check 12's). ``order_law_reverse``:
   the other way round (calibrated on the multi-sine, judged on the impulse record), shown, never written.

Every value is finite or the identification refuses (ExcitationFitError naming the value): a record that
gives no pulse, no mode or no line cannot write NaN into a scene. Pure: records in, numbers out.
"""
from __future__ import annotations

import math

import numpy as np

from drivetrain.campaigns import record_fit
from drivetrain.rig import excitation as ex
from drivetrain.rig import record as rec
from drivetrain.rig.background import ORDERS, Background

SPEED_RPM = 2004.0
#: the records it reads (drivetrain.rig.record.RECORDS)
RECORD_NAMES = ("impulse_2004rpm", "sine_2004rpm")
#: the order lines' names in rig.excitation and their [background] keys
LINE_KEYS = {"f_MSH": "order_msh_1x_Nm", "2f_MSH": "order_msh_2x_Nm", "f_DSH": "order_dsh_1x_Nm",
             "2f_DSH": "order_dsh_2x_Nm"}
#: the PI fit's window around the pulse [s before its start, s after its end]
CONTROL_WINDOW_S = (0.3, 0.5)
#: physical ranges of the identified values (what a value outside would mean is wrong)
RANGES = {
    "first_mode_Hz": (20.0, 40.0, "the public lumped model puts it at 28.4 Hz (testbench_lumped_parameters.csv); "
                                   "the paper measured 24 Hz"),
    "first_mode_zeta": (0.01, 0.3, "elastomer couplings: relative damping psi 0.1-1.5, zeta = psi / (4 pi)"),
    "drive_Kp": (0.05, 20.0, "N·m·s/rad: a speed loop of 1-100 Hz on the drive side's 8e-4..1e-2 kg·m²"),
    "drive_Ti_s": (0.002, 2.0, "s"),
    "order_exponent": (0.0, 2.5, "per line: 0 a torque ripple of constant size, 2 a kinematic error moving the "
                                 "propeller mass; a little over 2 where the error itself grows with speed (bow)"),
    "orders_speed_exponent": (0.0, 2.0, "0: a torque ripple of constant size (motor cogging, current ripple); "
                                        "2: a kinematic error (runout) moving the propeller mass"),
}


class ExcitationFitError(ValueError):
    """The identification cannot give a finite value within reach: names the value and the record."""


def _finite(name: str, value: float, where: str) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ExcitationFitError(f"{where}: {name} came out non-finite ({v}); nothing written")
    return v


def record_figures(records: dict) -> dict:
    """The excitation figures (rig.excitation) of the two records."""
    out = {}
    for name, fn in (("impulse_2004rpm", ex.impulse_figures), ("sine_2004rpm", ex.sine_figures)):
        r = records[name]
        out[name] = fn(r.t, r.channels["propeller_shaft_torque"], r.channels["drive_shaft_torque"],
                       r.channels["enc1_w"], r.fs, *rec.load_setpoint(r))
    return out


def controller(r: rec.Record, figures: dict) -> dict:
    """Kp, Ti of the drive's PI from the impulse record (module docstring, step 2)."""
    pulse = ex.setpoint_pulse(r.t_motor, r.motor["load_motor_torque_set"])
    times = figures["times"]
    offset = times["peak_s"] - pulse["peak_s"]          # sensor clock minus motor clock at the pulse
    fm = figures["f_MSH_Hz"]
    t0, t1 = times["start_s"] - CONTROL_WINDOW_S[0], times["end_s"] + CONTROL_WINDOW_S[1]
    tm = r.t_motor + offset
    Tm = ex.revolution_mean(r.motor["drive_motor_torque"], r.fs_motor, fm)
    w = ex.revolution_mean(r.channels["enc1_w"], r.fs, fm)
    sel = (r.t >= t0) & (r.t <= t1)
    t = r.t[sel]
    before = (r.t >= t0) & (r.t < times["start_s"])
    dw = w[sel] - np.mean(w[before])
    dT = np.interp(t, tm, Tm) - np.mean(np.interp(r.t[before], tm, Tm))
    iw = np.concatenate([[0.0], np.cumsum(0.5 * (dw[1:] + dw[:-1]) * np.diff(t))])
    A = -np.column_stack([dw, iw])
    (kp, ki), *_ = np.linalg.lstsq(A, dT, rcond=None)
    resid = A @ np.array([kp, ki]) - dT
    where = f"{r.name}: the speed controller"
    return {"drive_Kp": _finite("Kp", kp, where), "drive_Ti_s": _finite("Ti", kp / ki if ki else float("nan"), where),
            "residual_rms_Nm": float(np.sqrt(np.mean(resid ** 2))), "torque_rise_Nm": float(np.ptp(dT)),
            "clock_offset_s": float(offset)}


def order_law(line_levels: dict, bg: Background, speed_rpm: float = SPEED_RPM, judge: dict | None = None) -> dict:
    """The shaft-order sources at ``speed_rpm`` from ``line_levels`` (the calibration record's lines) and the speed
    laws over 500 rpm and it (module docstring, step 3); ``judge``: another record's lines, set beside the
    calibrated laws' linear prediction (``judge_dB``: prediction over measured)."""
    from drivetrain.rig.data import LOWER_RATIO, UPPER_RATIO
    from drivetrain.rig.background import propeller_order

    f_psh = speed_rpm / 60.0 / (UPPER_RATIO * LOWER_RATIO)
    keys = list(LINE_KEYS.values())
    freqs = np.array([propeller_order(k, bg, UPPER_RATIO, LOWER_RATIO) * f_psh for k in keys])
    h = record_fit.response(bg, freqs, "load", speed_rpm, 1.309)["propeller_shaft_torque"]
    ratio = speed_rpm / record_fit.rec.RECORD_SPEED_RPM
    rows = {}
    for (line, key), f, hk in zip(LINE_KEYS.items(), freqs, h):
        src = line_levels[line] / hk
        a500 = float(getattr(bg, key))
        rows[key] = {"line": line, "f_Hz": float(f), "measured_Nm": line_levels[line], "H": float(hk),
                     "source_Nm": float(src), "source_500rpm_Nm": a500,
                     "own_exponent": float(math.log(src / a500) / math.log(ratio))}
        if judge is not None:
            rows[key]["judge_measured_Nm"] = float(judge[line])
            rows[key]["judge_dB"] = float(20 * math.log10(src * hk / judge[line]))
    lr = np.array([math.log(r["source_Nm"] / r["source_500rpm_Nm"]) for r in rows.values()])
    p = float(np.mean(lr) / math.log(ratio))
    for r in rows.values():
        r["common_law_dB"] = float(20 * (p * math.log10(ratio) - math.log10(r["source_Nm"] / r["source_500rpm_Nm"])))
    return {"exponent": _finite("the orders' speed exponent", p, "the 2004 rpm records"), "lines": rows}


def _value(v, unit, source, key=None, note=""):
    lo, hi, why = RANGES.get(key, (None, None, ""))
    out = {"value": float(v), "unit": unit, "source": source, "note": note}
    if lo is not None:
        out.update(range=[lo, hi], range_why=why, within=bool(lo <= v <= hi))
    return out


def identify(directory=None, bg: Background | None = None) -> dict:
    """Every value the excitation records identify (``values``: name -> value, unit, source, physical range),
    the records' figures and the model's linear prediction beside them."""
    bg = bg or Background()
    records = {n: rec.load_record(directory, n) for n in RECORD_NAMES}
    figs = record_figures(records)
    imp, sin = figs["impulse_2004rpm"], figs["sine_2004rpm"]
    ctrl = controller(records["impulse_2004rpm"], imp)
    law = order_law({line: imp[line] for line in LINE_KEYS}, bg, judge={line: sin[line] for line in LINE_KEYS})
    reverse = order_law({line: sin[line] for line in LINE_KEYS}, bg, judge={line: imp[line] for line in LINE_KEYS})
    model_modes = record_fit.first_modes(bg, 4, SPEED_RPM, 1.309)
    sine_keys = [k for k in sin if k.startswith("H_")]
    f_lines = [float(k[2:-2]) for k in sine_keys]
    h_model = record_fit.response(bg, np.array(f_lines), "load", SPEED_RPM, 1.309)["propeller_shaft_torque"]
    where = "impulse_2004rpm"
    values = {
        "first_mode_Hz": _value(_finite("the ring frequency", imp["ring_Hz"], where), "Hz",
                                "identified: impulse record, noise-driven ring after the pulse", "first_mode_Hz",
                                note="a test of the couplings placed at 500 rpm, not written"),
        "first_mode_zeta": _value(_finite("the ring damping", imp["zeta"], where), "",
                                  "identified: impulse record, noise-driven ring after the pulse", "first_mode_zeta"),
        "drive_Kp": _value(ctrl["drive_Kp"], "N·m·s/rad", "identified: impulse record, drive torque vs encoder-1 "
                           "speed around the pulse", "drive_Kp", note="shown, not written: [background] keeps the 500 "
                           "rpm PI, whose integral gain this one repeats (drive_Ki)"),
        "drive_Ti_s": _value(ctrl["drive_Ti_s"], "s", "identified: as drive_Kp", "drive_Ti_s"),
        "drive_Ki": _value(ctrl["drive_Kp"] / ctrl["drive_Ti_s"], "N·m/rad", "identified: as drive_Kp",
                           note=f"500 rpm: {bg.drive_Kp / bg.drive_Ti_s:.3g} (the 100 ms ramps are followed by the "
                                "integral term; Kp is weakly determined by them)"),
        "orders_speed_exponent": _value(law["exponent"], "", "identified: order sources at 500 rpm ([background]) "
                                        "and 2004 rpm (impulse record), one exponent for the four lines",
                                        "orders_speed_exponent", note="written to [background]: the planetary "
                                        "mesh's law (no second speed of its own)"),
    }
    for key, row in law["lines"].items():
        values[f"{key}@2004rpm"] = _value(_finite(key, row["source_Nm"], "the impulse record"), "N·m",
                                          f"calibration: impulse record's {row['line']} line {row['measured_Nm']:.3g} "
                                          f"N·m over the model's |H| {row['H']:.3g}")
        values[key.replace("_Nm", "_exponent")] = _value(
            _finite(f"{key}'s exponent", row["own_exponent"], "the impulse record"), "",
            f"calibration: {row['line']} source at 500 rpm and 2004 rpm (impulse record)", "order_exponent",
            note=f"written to [background]; multi-sine (judge) linear prediction {row['judge_dB']:+.1f} dB over its "
                 f"{row['judge_measured_Nm']:.3g} N·m")
    return {"values": values, "figures": figs, "controller": ctrl, "order_law": law, "order_law_reverse": reverse,
            "model": {"modes_2004rpm": model_modes,
                      "sine_H": {k: {"measured": sin[k], "model": float(h)} for k, h in zip(sine_keys, h_model)}},
            "assumed": {"coupling_stiffness_scale": (bg.coupling_stiffness_scale, "identified at 500 rpm (hump 27.8 Hz)"),
                        "inertias and shaft stiffnesses": "public lumped model, testbench_lumped_parameters.csv",
                        "planetary_ring_teeth": (bg.planetary_ring_teeth, "assumed (the record's 84 f_PSH line)")}}


__all__ = ["RECORD_NAMES", "identify", "record_figures", "controller", "order_law", "ExcitationFitError", "RANGES", "LINE_KEYS"]
