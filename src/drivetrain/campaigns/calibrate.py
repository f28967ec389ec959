"""Calibration of the loss parameters (mean torques) and of the elastomer coupling stiffness (24 Hz).

Losses. The measured table (``measured_mean_torques.csv``: load setting, drive-shaft and
propeller-shaft transducer torques and speeds at 18 operating points) is matched by the steady-state
torque balance of the model with an ideal lower gear (:func:`drivetrain.rig.data.steady_state`):

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

import json
from pathlib import Path

import numpy as np

from drivetrain.rig import data as rig
from drivetrain.run.assemble import assemble
from drivetrain.models.eigen import natural_frequencies
from drivetrain.rig.data import read_measured  # noqa: F401  (re-exported)
from drivetrain.scene.load import default_scene

LAW_KEYS = ("c_v", "T_c", "w_c", "a")
TARGET_LOWEST_HZ = 24.0


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


def regenerate_shipped(path: str | Path | None = None) -> dict:
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
