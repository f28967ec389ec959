"""Calibration of the loss parameters (mean torques) and of the elastomer coupling stiffness (24 Hz).

Losses. The measured table (``measured_mean_torques.csv``: load setting, drive-shaft and
propeller-shaft transducer torques and speeds at 18 operating points) is matched by the steady-state
torque balance of the model with an ideal lower gear (:func:`drivetrain.rig.steady_state`):

    T_PSH = 8 T_set + T_pg(w_PSH, 8 T_set)
    T_DSH = T_PSH / 12 + T_ut(w_DSH, T_PSH / 12)

with the loss law T(w, T_trans) = c_v w + (T_c + a |T_trans|) tanh(w / w_c) for the planetary
(propeller frame) and the upper gearbox (drive frame; it stands for all losses between the two
transducers: both bevel boxes and their bearings). Eight parameters, fitted by least squares on the
relative errors of both torques at every point (scipy ``least_squares``). At constant speed the
inertias and springs carry no torque of their own, so this balance is what a long simulation averages
to (checked by a time-domain test).

Coupling stiffness. The lowest torsional mode of the assembled default drivetrain (flexible shafts)
is brought to the measured 24 Hz by one factor on the five elastomer coupling elements
(:func:`fit_coupling_scale`).
"""
from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

from drivetrain import rig

LAW_KEYS = ("c_v", "T_c", "w_c", "a")
TARGET_LOWEST_HZ = 24.0


def read_measured(path: str | Path | None = None) -> dict:
    """The measured table as arrays: T_load, T_DSH, T_PSH, n_DSH (rpm), n_PSH (rpm)."""
    p = Path(path) if path else rig.MEASURED_CSV
    try:
        with open(p, newline="", encoding="utf-8") as fh:
            rows = [r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{p}: not a readable CSV text file ({exc})") from None
    if not rows:
        raise ValueError(f"{p}: no data")
    hdr = [h.strip() for h in rows[0]]
    need = {"T_load_Nm", "T_DSH_Nm", "T_PSH_Nm", "n_DSH_rpm"}
    missing = need - set(hdr)
    if missing:
        raise ValueError(f"{p}: missing columns {sorted(missing)} (have {hdr})")
    col = {h: i for i, h in enumerate(hdr)}
    problems = []
    for n, r in enumerate(rows[1:], start=2):
        if len(r) != len(hdr):
            problems.append(f"data row {n - 1} has {len(r)} fields, the header {len(hdr)}: {','.join(r)}")
            continue
        for k in need:
            try:
                float(r[col[k]])
            except ValueError:
                problems.append(f"data row {n - 1}: {k} = {r[col[k]]!r} is not a number")
    if problems:
        raise ValueError(f"{p}: " + "; ".join(problems))
    data = {}
    for k in hdr:                 # every numeric column (the fit's were checked above; expectations read others)
        try:
            data[k] = np.array([float(r[col[k]]) for r in rows[1:]])
        except ValueError:
            pass
    if len(data["T_load_Nm"]) < 8:
        raise ValueError(f"{p}: at least 8 operating points are needed to fit 8 parameters")
    return data


def _laws_from_vector(x) -> tuple[dict, dict]:
    up = dict(zip(LAW_KEYS, map(float, x[:4])))
    pg = dict(zip(LAW_KEYS, map(float, x[4:])))
    return up, pg


def predict(T_load, n_dsh, upper: dict, planetary: dict) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state (T_DSH, T_PSH) of the model at the given load settings and drive speeds."""
    up = {"loss_c": upper["c_v"], "loss_Tc": upper["T_c"], "loss_wc": upper["w_c"], "loss_a": upper["a"],
          "ratio": rig.UPPER_RATIO}
    mo = {"pg_c": planetary["c_v"], "pg_Tc": planetary["T_c"], "pg_wc": planetary["w_c"], "pg_a": planetary["a"],
          "ratio_pg": rig.PG_RATIO}
    td, tp = [], []
    for T, n in zip(np.atleast_1d(T_load), np.atleast_1d(n_dsh)):
        ss = rig.steady_state(float(n), float(T), up, mo)
        td.append(ss.T_dsh)
        tp.append(ss.T_psh)
    return np.array(td), np.array(tp)


def calibrate(measured_csv: str | Path | None = None, x0: dict | None = None) -> dict:
    """Fit the loss parameters of the upper gearbox and the planetary to a measured mean-torque table.

    Returns {"upper": {c_v, T_c, w_c, a}, "planetary": {...}, "errors": {...}, "source": path}."""
    from scipy.optimize import least_squares

    d = read_measured(measured_csv)
    TL, TD, TP, nD = d["T_load_Nm"], d["T_DSH_Nm"], d["T_PSH_Nm"], d["n_DSH_rpm"]
    start = x0 or rig.FALLBACK_CALIBRATION
    x_init = np.array([start["upper"][k] for k in LAW_KEYS] + [start["planetary"][k] for k in LAW_KEYS])
    lo = np.array([0.0, 0.0, 0.05, 0.0] * 2)
    hi = np.array([1.0, 10.0, 500.0, 1.0, 10.0, 50.0, 100.0, 1.0])
    x_init = np.clip(x_init, lo + 1e-12, hi - 1e-12)

    def res(x):
        up, pg = _laws_from_vector(x)
        td, tp = predict(TL, nD, up, pg)
        return np.r_[(td - TD) / TD, (tp - TP) / TP]

    best = None
    for scale in (1.0, 0.5, 2.0):
        xi = np.clip(x_init * np.array([scale, scale, 1.0, scale] * 2), lo + 1e-12, hi - 1e-12)
        r = least_squares(res, xi, bounds=(lo, hi), x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12)
        if best is None or r.cost < best.cost:
            best = r
    up, pg = _laws_from_vector(best.x)
    td, tp = predict(TL, nD, up, pg)
    err_d = td / TD - 1.0
    err_p = tp / TP - 1.0
    points = [{"T_load_Nm": float(a), "n_DSH_rpm": float(b), "T_DSH_meas": float(c), "T_DSH_model": float(e),
               "err_DSH": float(f), "T_PSH_meas": float(g), "T_PSH_model": float(h), "err_PSH": float(i)}
              for a, b, c, e, f, g, h, i in zip(TL, nD, TD, td, err_d, TP, tp, err_p)]
    return {"upper": up, "planetary": pg,
            "errors": {"max_abs_DSH": float(np.max(np.abs(err_d))), "max_abs_PSH": float(np.max(np.abs(err_p))),
                       "rms": float(np.sqrt(np.mean(np.r_[err_d, err_p] ** 2))), "points": points},
            "source": str(measured_csv or rig.MEASURED_CSV)}


def lowest_mode(coupling_scale: float, calibration: dict | None = None) -> float:
    """Lowest torsional mode [Hz] of the default assembled drivetrain (flexible shafts, table gear)."""
    from drivetrain.assemble import assemble
    from drivetrain.eigen import natural_frequencies
    from drivetrain.scenario import default_scene

    cal = dict(calibration or rig.load_calibration())
    cal["coupling_scale"] = float(coupling_scale)
    spec = assemble(default_scene(), calibration=cal, check=False)
    return float(natural_frequencies(spec)[0])


def fit_coupling_scale(target_hz: float = TARGET_LOWEST_HZ, calibration: dict | None = None) -> float:
    """The factor on the elastomer coupling stiffness (public elements 3-7) that puts the lowest
    torsional mode of the default drivetrain at ``target_hz``."""
    from scipy.optimize import brentq

    return float(brentq(lambda s: lowest_mode(s, calibration) - target_hz, 0.2, 2.0, xtol=1e-8))


def write_calibration(path: str | Path, losses: dict, coupling_scale: float, extra: dict | None = None) -> Path:
    out = {"coupling_scale": float(coupling_scale), "upper": losses["upper"], "planetary": losses["planetary"],
           "law": "T = c_v*w + (T_c + a*|T_trans|)*tanh(w/w_c); upper: drive frame, T_trans = T_PSH/12; "
                  "planetary: propeller frame, T_trans = 8*T_set",
           "fit": {"max_abs_DSH": losses["errors"]["max_abs_DSH"], "max_abs_PSH": losses["errors"]["max_abs_PSH"],
                   "rms": losses["errors"]["rms"], "source": Path(losses["source"]).name}}
    out.update(extra or {})
    p = Path(path)
    p.write_text(json.dumps(out, indent=1) + "\n")
    return p


def run_calibrate_command(csv_path, out_path=None, file=None) -> int:
    """``drivetrain calibrate MEASURED.csv [--out FILE]``: refit the losses, print the fit at every
    operating point, write the calibration JSON (default ./calibration.json; use it with
    ``drivetrain.assemble.assemble(scene, calibration=FILE)`` or the environment variable
    DRIVETRAIN_CALIBRATION). The coupling-stiffness factor is kept from the current calibration."""
    file = file or sys.stdout
    try:
        res = calibrate(csv_path)
    except (OSError, ValueError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    cur = rig.load_calibration()
    print(f"loss law T = c_v w + (T_c + a |T_trans|) tanh(w / w_c), fitted to {csv_path}", file=file)
    for key, frame in (("upper", "drive frame, T_trans = T_PSH/12"), ("planetary", "propeller frame, T_trans = 8 T_set")):
        v = res[key]
        print(f"  {key:9s} ({frame}): c_v = {v['c_v']:.6g} N m s/rad, T_c = {v['T_c']:.6g} N m, "
              f"w_c = {v['w_c']:.6g} rad/s, a = {v['a']:.6g}", file=file)
    print(f"{'T_load':>7} {'n_DSH':>8} {'T_DSH meas':>10} {'model':>8} {'err %':>7} {'T_PSH meas':>10} "
          f"{'model':>8} {'err %':>7}", file=file)
    for pt in res["errors"]["points"]:
        print(f"{pt['T_load_Nm']:>7.2f} {pt['n_DSH_rpm']:>8.2f} {pt['T_DSH_meas']:>10.3f} {pt['T_DSH_model']:>8.3f} "
              f"{100 * pt['err_DSH']:>7.2f} {pt['T_PSH_meas']:>10.3f} {pt['T_PSH_model']:>8.3f} "
              f"{100 * pt['err_PSH']:>7.2f}", file=file)
    print(f"max |error|: drive shaft {100 * res['errors']['max_abs_DSH']:.2f} %, propeller shaft "
          f"{100 * res['errors']['max_abs_PSH']:.2f} %", file=file)
    out = Path(out_path) if out_path else Path("calibration.json")
    write_calibration(out, res, cur["coupling_scale"],
                      {k: v for k, v in cur.items() if k not in ("coupling_scale", "upper", "planetary", "law", "fit")})
    print(f"wrote {out} (coupling_scale {cur['coupling_scale']:.6g} kept)", file=file)
    return 0


def main_regenerate(path: str | Path | None = None) -> dict:
    """Regenerate the shipped data/calibration.json: losses from the shipped table, then the coupling
    factor for 24 Hz (the lowest mode hardly depends on the losses)."""
    res = calibrate()
    cal = {"coupling_scale": rig.FALLBACK_CALIBRATION["coupling_scale"], "upper": res["upper"],
           "planetary": res["planetary"]}
    s = fit_coupling_scale(TARGET_LOWEST_HZ, cal)
    f1 = lowest_mode(s, cal)
    f1_public = lowest_mode(1.0, cal)
    write_calibration(path or rig.CALIBRATION_JSON, res, s,
                      {"modal": {"target_lowest_Hz": TARGET_LOWEST_HZ, "lowest_Hz": f1,
                                 "lowest_Hz_unscaled": f1_public,
                                 "what": "factor on the stiffness of the elastomer coupling elements 3-7 of "
                                         "the public model"}})
    return {"coupling_scale": s, "lowest_Hz": f1, "lowest_Hz_unscaled": f1_public, **res}


if __name__ == "__main__":  # pragma: no cover
    r = main_regenerate()
    print(json.dumps({k: v for k, v in r.items() if k != "errors"}, indent=1))
    print("max errors", r["errors"]["max_abs_DSH"], r["errors"]["max_abs_PSH"])
