"""Check 12 of `drivetrain validate`: the rig's 2004 rpm excitation records (an impulse and a multi-sine on the load
motor, drivetrain/data/rig_records) against their scenes (scenarios/validation/rig_{impulse,sine}_2004rpm.toml),
run for every gearbox (manufacturing, background and instrument seeds 0..N-1 alike) with the one parameter set
every other check runs with.

Each figure is computed alike for the record and for a run (drivetrain.rig.excitation). The criteria (issue 41),
stated before the runs, each on the **median over the gearboxes**:

* impulse: ring frequency within 10 %, damping ratio within a factor 1.5, first overshoot within 25 %, speed
  dip within a factor 1.5, propeller- and drive-shaft torque std within a factor 2, the shaft-order lines
  (f_MSH, 2 f_MSH, f_DSH, 2 f_DSH on the propeller shaft) within 6 dB;
* multi-sine: torque std within a factor 2 on both shafts, the shaft-order lines within 6 dB, and the load
  response |H| at the 32 Hz load line (on the first mode's flank) within 6 dB; |H| at 129 and 256 Hz are
  shown, not judged.

The fraction of gearboxes within each criterion is shown beside it.

The impulse record's shaft-order lines are a **calibration**: each line's speed law ([background]
order_*_exponent) is fitted to its 500 rpm level and the impulse record's (campaigns.excitation_fit), so there they
show only that the fit holds through the simulation. The multi-sine's lines, not used by the fit, are the
**validation** of those laws; every other figure is a validation too (:data:`CALIBRATED`, the report's "role").
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from drivetrain.rig import excitation as ex
from drivetrain.rig import record as rec

SCENE_DIR = Path(__file__).resolve().parents[3] / "scenarios" / "validation"
RECORDS = ("impulse_2004rpm", "sine_2004rpm")
N_GEARBOXES = 8
_DB6 = ("dB", 6.0)
#: figure -> (how it is compared, the tolerance): "rel" |ours/measured - 1| <= tol; "factor" max(r, 1/r) <= tol;
#: "dB" |20 log10(ours/measured)| <= tol
CRITERIA = {
    "impulse_2004rpm": {"ring_Hz": ("rel", 0.10), "zeta": ("factor", 1.5), "overshoot": ("rel", 0.25),
                        "speed_dip_rad_s": ("factor", 1.5), "std_psh_Nm": ("factor", 2.0),
                        "std_dsh_Nm": ("factor", 2.0), "f_MSH": _DB6, "2f_MSH": _DB6, "f_DSH": _DB6, "2f_DSH": _DB6},
    "sine_2004rpm": {"std_psh_Nm": ("factor", 2.0), "std_dsh_Nm": ("factor", 2.0), "f_MSH": _DB6, "2f_MSH": _DB6,
                     "f_DSH": _DB6, "2f_DSH": _DB6, "H_32.1Hz": _DB6},
}
SHOWN = {"sine_2004rpm": ("H_129Hz", "H_256Hz", "Hband_32.1Hz", "psh_32Hz_Nm", "psh_64Hz_Nm", "psh_96Hz_Nm",
                          *(f"{k}_w" for k in ex.SINE_WINDOWED_LINES))}
#: the figures the parameters were fitted to (campaigns.excitation_fit): a calibration, not a validation
CALIBRATED = {"impulse_2004rpm": ("f_MSH", "2f_MSH", "f_DSH", "2f_DSH")}


def role(record: str, fig: str) -> str:
    """"calibration" for a figure the parameters were fitted to, else "validation"."""
    return "calibration" if fig in CALIBRATED.get(record, ()) else "validation"


def case_name(record: str, gearbox: int) -> str:
    return f"excitation_{record}_gearbox{gearbox}"


def scene_path(record: str) -> Path:
    return SCENE_DIR / rec.EXCITATION_SCENES[record][0]


def scenes(common: list, gearboxes: int = N_GEARBOXES) -> list:
    """Each excitation scene for each gearbox; of ``common`` only what is not the scene's own (its duration,
    settling and sample rate are the record's)."""
    from drivetrain.scene.load import load_scene

    keep = [c for c in common if not c.startswith(("time.", "numerics.comm_step_s"))]
    out = []
    for record in RECORDS:
        for gb in range(gearboxes):
            extra = [f"manufacturing.seed={gb}", f"background.seed={gb}", f"instruments.seed={gb}"]
            out.append(load_scene(scene_path(record), overrides=[*keep, *extra,
                                                                 f'scenario.name="{case_name(record, gb)}"']))
    return out


def _figures(record: str, t, psh, dsh, enc1_w, fs, r: rec.Record, setpoint=None) -> dict:
    fn = ex.impulse_figures if record.startswith("impulse") else ex.sine_figures
    return fn(t, psh, dsh, enc1_w, fs, *(setpoint or rec.load_setpoint(r)))


def measured_figures(records: dict | None = None, setpoints: dict | None = None) -> dict:
    """The records' own figures (``setpoints``: their rec.load_setpoint, where the caller has them)."""
    out = {}
    for name in RECORDS:
        r = (records or {}).get(name) or rec.load_record(name=name)
        out[name] = _figures(name, r.t, r.channels["propeller_shaft_torque"], r.channels["drive_shaft_torque"],
                             r.channels["enc1_w"], r.fs, r, (setpoints or {}).get(name))
    return out


def run_figures(signals: dict, record: str, r: rec.Record | None = None, setpoint=None) -> dict:
    """The figures of one run's signals (drivetrain.run.outputs.read_hdf5 layout; enc1 an angle); ``setpoint``:
    the record's rec.load_setpoint, when the caller has it (retiming the multi-sine's log takes about 0.3 s)."""
    r = r or rec.load_record(name=record)
    t = np.asarray(signals["time"], dtype=float)
    s = signals["signals"]
    fs = 1.0 / float(np.median(np.diff(t)))
    return _figures(record, t, s["propeller_shaft_torque"], s["drive_shaft_torque"], ex.speed_of(s["enc1"], fs), fs, r,
                    setpoint)


def within(kind: str, tol: float, ours: float, measured: float) -> tuple[bool, float]:
    """Whether ``ours`` is within the criterion, and the comparison's figure (relative error, factor or dB)."""
    if not (ours > 0 and measured > 0):
        return False, float("nan")
    q = ours / measured
    if kind == "rel":
        return abs(q - 1) <= tol, q - 1
    if kind == "factor":
        return max(q, 1 / q) <= tol, q
    db = 20 * math.log10(q)
    return abs(db) <= tol, db


def compare_figures(ours: list[dict], measured: dict) -> dict:
    """Per record and figure: measured, median and 10th/90th percentile of ours, the comparison, within."""
    table = {}
    for record in RECORDS:
        rows = {}
        figs = [o[record] for o in ours if record in o]
        for fig, (kind, tol) in list(CRITERIA[record].items()) + [(f, ("dB", float("inf"))) for f in SHOWN.get(record, ())]:
            vals = np.array([f[fig] for f in figs]) if figs else np.array([np.nan])
            med = float(np.median(vals))
            ok, q = within(kind, tol, med, measured[record][fig])
            rows[fig] = {"measured": measured[record][fig], "median": med, "p10": float(np.percentile(vals, 10)),
                         "p90": float(np.percentile(vals, 90)), "kind": kind, "tol": tol, "q": q, "within": ok,
                         "deciding": fig in CRITERIA[record], "role": role(record, fig),
                         "fraction_within": float(np.mean([within(kind, tol, v, measured[record][fig])[0] for v in vals]))}
        table[record] = rows
    return table


def compare(runs, gearboxes: int = N_GEARBOXES) -> dict:
    """The comparison of the runs of a validation directory (campaigns.validation.Runs) with the records;
    ``missing``: the runs that did not complete."""
    names = {record: [case_name(record, g) for g in range(gearboxes)] for record in RECORDS}
    missing = [n for ns in names.values() for n in ns if not runs.ok(n)]
    loaded = {record: rec.load_record(name=record) for record in RECORDS}
    setpoints = {record: rec.load_setpoint(r) for record, r in loaded.items()}
    ours = []
    for g in range(gearboxes):
        one = {}
        for record in RECORDS:
            n = case_name(record, g)
            if runs.ok(n):
                one[record] = run_figures(runs.signals(n), record, loaded[record], setpoints[record])
        ours.append(one)
    return {"table": compare_figures(ours, measured_figures(loaded, setpoints)), "missing": missing, "n": gearboxes}


def _fmt_q(kind: str, q: float) -> str:
    return {"rel": f"{100 * q:+.0f} %", "factor": f"x{q:.2f}", "dB": f"{q:+.1f} dB"}[kind]


def _fmt_tol(kind: str, tol: float) -> str:
    if not math.isfinite(tol):
        return "shown"
    return {"rel": f"±{100 * tol:.0f} %", "factor": f"x{tol:g}", "dB": f"±{tol:g} dB"}[kind]


def verdict(c: dict) -> tuple[str, list[str]]:
    """The check's one-line figure and the deciding figures outside their criterion (none: pass)."""
    bad = [f"{rec_.split('_')[0]} {f}" + (" (calibration)" if v["role"] == "calibration" else "")
           for rec_, rows in c["table"].items() for f, v in rows.items() if v["deciding"] and not v["within"]]
    parts = []
    for record, rows in c["table"].items():
        for which in ("validation", "calibration"):
            figs = [f"{f} {_fmt_q(v['kind'], v['q'])}" for f, v in rows.items() if v["deciding"] and v["role"] == which]
            if figs:
                parts.append(f"{record.split('_')[0]} ({which}): " + ", ".join(figs))
    return "; ".join(parts) + (f"; outside: {', '.join(bad)}" if bad else ""), bad


def table_lines(c: dict) -> list[str]:
    lines = ["", "| record | figure | role | measured | ours: median [p10, p90] | ours / measured | criterion | "
                 "gearboxes within |", "|---|---|---|---|---|---|---|---|"]
    for record, rows in c["table"].items():
        for fig, v in rows.items():
            ok = ("within" if v["within"] else "**outside**") if v["deciding"] else ""
            lines.append(f"| {record} | {fig} | {v['role'] if v['deciding'] else 'shown'} | {v['measured']:.4g} | {v['median']:.4g} [{v['p10']:.3g}, {v['p90']:.3g}] "
                         f"| {_fmt_q(v['kind'], v['q'])} | {_fmt_tol(v['kind'], v['tol'])} {ok} "
                         f"| {100 * v['fraction_within']:.0f} % |")
    return lines


def plot(signal_of, path: Path, gearbox: int = 0) -> Path | None:
    """Per record: the propeller-shaft torque measured and simulated over time (the impulse around its pulse,
    aligned at the pulse's peak; the multi-sine over 0.5 s) and their amplitude spectra to 150 Hz.
    ``signal_of(record)``: the read signals of one run of it (None: not run)."""
    from drivetrain.rig.signals import amplitude_spectrum
    from drivetrain.run.outputs import _finish, _mpl

    plt = _mpl()
    fig, axes = plt.subplots(2, 2, figsize=(14, 8))
    for row, record in zip(axes, RECORDS):
        r = rec.load_record(name=record)
        meas = measured_figures({record: r})[record] if record.startswith("impulse") else None
        d = signal_of(record)
        curves = [("measured (2023 record)", "k", r.t, r.channels["propeller_shaft_torque"], r.fs, meas)]
        if d is not None:
            t = np.asarray(d["time"], dtype=float)
            fs = 1.0 / float(np.median(np.diff(t)))
            figs = run_figures(d, record, r) if record.startswith("impulse") else None
            curves.append((f"ours, gearbox {gearbox}", "tab:red", t, d["signals"]["propeller_shaft_torque"], fs, figs))
        for label, color, t, x, fs, figs in curves:
            keep = t >= t[0] + ex.SKIP_S
            if figs is not None:
                tt = t - figs["times"]["peak_s"]
                m = (tt >= -0.6) & (tt <= 1.0)
                row[0].plot(tt[m], x[m], color=color, lw=0.7, label=label)
            else:
                m = keep & (t >= 2.0) & (t <= 2.5)
                row[0].plot(t[m] - 2.0, x[m], color=color, lw=0.7, label=label)
            f, a = amplitude_spectrum(x[keep], fs)
            mm = (f > 0) & (f <= 150)
            row[1].semilogy(f[mm], a[mm], color=color, lw=0.7, label=label)
        row[0].set_title(f"{record}: propeller-shaft torque" + (" around the pulse (peak at 0)" if record.startswith(
            "impulse") else " (0.5 s, the clocks not aligned)"), fontsize=9)
        row[0].set_xlabel("time [s]")
        row[0].set_ylabel("torque [N·m]")
        row[1].set_title(f"{record}: amplitude spectrum (Hann, whole record after 0.2 s)", fontsize=9)
        row[1].set_xlabel("frequency [Hz]")
        row[0].legend(fontsize=8)
    return _finish(plt, fig, path, "2004 rpm: the rig's excitation records and ours")


__all__ = ["RECORDS", "CRITERIA", "CALIBRATED", "role", "N_GEARBOXES", "scenes", "case_name", "measured_figures", "run_figures",
           "compare_figures", "compare", "verdict", "table_lines", "plot", "within"]
