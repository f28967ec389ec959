"""Identify the background effects' parameters from the rig's measured record (``drivetrain calibrate --record``).

The procedure (docs/DRIVETRAIN.md, "The measured background"), in this order, each step on what the
steps before it fixed; H below is the linearised drivetrain at the record's operating point
(models.eigen: every component's mass, stiffness and damping, the PI controller, the small-signal losses,
the ISO 6336 mean mesh stiffness), from a torque on the drive motor's rotor to a transducer's torque:

1. **Transducer floors** (measured, no model): the torque PSDs between 300 and 1000 Hz, where the
   drivetrain's response has fallen by > 40 dB, are flat; their median is each transducer's white noise.
2. **The drive's speed controller** (2 numbers): from the drive's own signals (1 kHz), the transfer from
   its speed to its torque where the two are coherent (>= 0.5, 1.5-6.5 Hz) is the controller's reaction
   to speed errors; a PI C = Kp (1 + 1 / (j w Ti)) is fitted to its magnitude (log least squares).
3. **The two modes** (2 numbers): the coupling stiffness scale puts the first torsional mode on the
   propeller-shaft torque's hump near 27 Hz, the propeller-shaft stiffness scale the third on the hump
   near 58 Hz (each hump's peak by parabolic interpolation; one-dimensional roots, repeated until both hold).
4. **Damping and broadband drive noise** (2 numbers): over 12-50 Hz (Welch, 1.5 Hz bins; bins within
   1 Hz of a periodic line left out) the propeller-shaft PSD is S0 |H|^2 + floor; for each coupling damping
   scale on a grid the best S0 is the geometric mean of (PSD - floor) / |H|^2, and the scale with the least
   log residual is taken. (The humps' own widths cannot give the damping: both peaks are as narrow as
   1.84 s resolve and sit within 0.1 Hz of periodic lines, 10 f_MSH and 7 f_DSH.)
5. **Periodic lines** (5 numbers): each line's amplitude in the propeller-shaft torque over |H| at its
   frequency: 1x and 2x of the drive and middle shafts, and the motor's electrical frequency (7 f_DSH).

Only the propeller-shaft torque and the drive's own signals are fitted. The drive-shaft torque (std,
humps, floor, lines), the encoders and the motor's speed follow and are the comparison's test.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from drivetrain.rig import record as rec
from drivetrain.rig.signals import amplitude_spectrum
from drivetrain.rig.background import ORDERS, Background, propeller_order

#: the band [Hz] of the damping and noise fit, and the half width around lines left out of it [Hz]
FIT_BAND_HZ = (10.0, 80.0)
LINE_GAP_HZ = 1.0
FLOOR_BAND_HZ = (300.0, 1000.0)
NPERSEG = 1024
#: the drive's signals: band and coherence of the controller fit, Welch segment
CONTROL_BAND_HZ = (1.5, 10.5)
CONTROL_MIN_COHERENCE = 0.4
CONTROL_NPERSEG = 512
#: the drive's torque signal's floor band [Hz] (above its speed loop, below its logger's rise)
DRIVE_FLOOR_HZ = (60.0, 150.0)
DAMPING_GRID = tuple(np.round(np.geomspace(0.05, 4.0, 25), 4))


#: where the identification starts: the public model's couplings and propeller shaft (every scale 1), not
#: the shipped defaults (so that it is the same however often it is rerun)
START = Background(coupling_stiffness_scale=1.0, coupling_damping_scale=1.0, propeller_stiffness_scale=1.0,
                   propeller_damping_scale=1.0)


def _scene(bg: Background, speed_rpm: float = rec.RECORD_SPEED_RPM, load_Nm: float = rec.RECORD_LOAD_NM):
    from drivetrain.scene.load import resolve

    sc = resolve({"scenario": {"name": "record_fit"},
                  "operating_point": {"drive_speed_rpm": speed_rpm, "load_torque_Nm": load_Nm},
                  "effects": {"mesh_contact": "table", "tooth_compliance": True, "couplings": "record",
                              "drive_control": "record"}})
    return dataclasses.replace(sc, background=bg)


def response(bg: Background, freqs: np.ndarray, at: str = "load", speed_rpm: float = rec.RECORD_SPEED_RPM,
             load_Nm: float = rec.RECORD_LOAD_NM) -> dict:
    """|H(f)| of the two transducers' torques [N·m per N·m] to a torque ``at`` the propeller mass
    (``"load"``) or the drive motor's rotor (``"drive"``), linearised at the record's operating point with
    the couplings and controller of ``bg`` (or at ``speed_rpm`` and ``load_Nm``)."""
    from drivetrain.models import eigen
    from drivetrain.run.assemble import assemble

    spec = assemble(_scene(bg, speed_rpm, load_Nm), check=False)
    ls = eigen.assemble_linear(spec, operating=True)
    M, K, C = ls.M, ls.K + ls.K_ground, ls.C + ls.C_ground
    lab = {name: i for i, name in enumerate(ls.labels)}
    motor, load, wheel = lab["motors.motor"], lab["motors.load"], lab["gear.wheel"]
    a, b = [i for i, name in enumerate(ls.labels) if name.startswith("drive_shaft.shaft_")][:2]
    u = np.zeros(len(M))
    u[{"drive": motor, "load": load}[at]] = 1.0
    hp, hd = [], []
    for f in np.asarray(freqs, dtype=float):
        w = 2.0 * math.pi * f
        x = np.linalg.solve(K + 1j * w * C - w * w * M, u)
        hp.append(abs(-(K[wheel, load] + 1j * w * C[wheel, load]) * (x[wheel] - x[load])))
        hd.append(abs(-(K[a, b] + 1j * w * C[a, b]) * (x[a] - x[b])))
    return {"propeller_shaft_torque": np.array(hp), "drive_shaft_torque": np.array(hd)}


def first_modes(bg: Background, n: int = 3, speed_rpm: float = rec.RECORD_SPEED_RPM,
                load_Nm: float = rec.RECORD_LOAD_NM) -> list[dict]:
    """Damped natural frequencies [Hz] and damping ratios of the linearised drivetrain with the couplings
    and controller of ``bg`` (losses included), above 5 Hz (the speed loop's own slow pole is not a mode)."""
    from drivetrain.models import eigen
    from drivetrain.run.assemble import assemble

    _, _, _, fd, zeta = eigen.modes(assemble(_scene(bg, speed_rpm, load_Nm), check=False), controller=True,
                                    damped=True)
    keep = fd > 5.0
    return [{"f_Hz": float(a), "zeta": float(z)} for a, z in list(zip(fd[keep], zeta[keep]))[:n]]


def hump_mode(f: np.ndarray, amp: np.ndarray, band: tuple[float, float]) -> dict:
    """A hump of a Hann amplitude spectrum read as one mode: the peak's frequency (parabolic interpolation
    of the log amplitude over three bins) and a damping ratio from the half-power width with the window's
    own (1.44 bins) removed in quadrature; at the resolution limit this is an upper bound."""
    sel = np.flatnonzero((f >= band[0]) & (f <= band[1]))
    i = int(sel[np.argmax(amp[sel])])
    df = float(f[1] - f[0])
    la, lb, lc = np.log(amp[i - 1:i + 2])
    fp = float(f[i] + 0.5 * (la - lc) / (la - 2 * lb + lc) * df)
    half = amp[i] / math.sqrt(2.0)
    j, k = i, i
    while amp[j - 1] > half:
        j -= 1
    while amp[k + 1] > half:
        k += 1
    lo = f[j - 1] + (half - amp[j - 1]) / (amp[j] - amp[j - 1]) * df
    hi = f[k] + (amp[k] - half) / (amp[k] - amp[k + 1]) * df
    width = float(hi - lo)
    zeta = math.sqrt(max(width ** 2 - (1.44 * df) ** 2, (0.25 * df) ** 2)) / (2.0 * fp)
    return {"f_Hz": fp, "zeta_bound": zeta, "half_power_width_Hz": width, "amplitude_Nm": float(amp[i])}


def record_humps(record: rec.Record | None = None) -> dict:
    """The record's humps (rig.record.HUMPS) in its propeller-shaft torque, each read as one mode (:func:`hump_mode`)."""
    r = record or rec.load_record()
    fa, amp = amplitude_spectrum(r.channels["propeller_shaft_torque"][int(round(rec.SKIP_S * r.fs)):], r.fs)
    return {name: hump_mode(fa, amp, band) for name, band in rec.HUMPS.items()}


def periodic_lines(speed_rpm: float, ring_teeth: int) -> dict:
    """The record's periodic lines [Hz]: ``named``, the lines of ``effects.shaft_orders`` by their
    [background] key; ``all``, the lines left out of the broadband fit (those, the mesh frequency and its
    second harmonic, the drive shaft's orders up to 12)."""
    from drivetrain.rig.data import LOWER_RATIO, UPPER_RATIO
    from drivetrain.rig.signals import characteristic_frequencies

    cf = characteristic_frequencies(speed_rpm, n_harmonics=2)
    bg = Background(planetary_ring_teeth=ring_teeth)
    named = {key: propeller_order(key, bg, UPPER_RATIO, LOWER_RATIO) * cf["f_PSH"] for key in ORDERS}
    others = [k * cf["f_DSH"] for k in range(1, 13)] + list(cf["harmonics"])
    return {"named": named, "all": sorted(set(list(named.values()) + others))}


def _lead(q, f):
    kp, ti, td = np.exp(q)
    s = 2j * np.pi * f
    return -kp * (1 + 1 / (s * ti)) * np.exp(s * td)


def controller(record: rec.Record) -> dict:
    """Kp [N·m·s/rad] and Ti [s] of the drive's PI speed controller from its own speed and torque: where
    the two are coherent the transfer torque / speed is the controller's reaction, -Kp (1 + 1/(j w Ti)),
    seen through the logged speed's lag (a delay t_d: the logged speed falls steeply above 10 Hz, a filter
    of the drive's); fitted in log magnitude and phase."""
    from scipy import optimize, signal

    c = int(round(0.2 * record.fs_motor))
    w = record.motor["drive_motor_w"][c:]
    T = record.motor["drive_motor_torque"][c:]
    w, T = w - w.mean(), T - T.mean()
    kw = dict(fs=record.fs_motor, nperseg=CONTROL_NPERSEG)
    f, pww = signal.welch(w, **kw)
    _, ptt = signal.welch(T, **kw)
    _, pwt = signal.csd(w, T, **kw)
    coh = np.abs(pwt) ** 2 / (pww * ptt)
    sel = (f >= CONTROL_BAND_HZ[0]) & (f <= CONTROL_BAND_HZ[1]) & (coh >= CONTROL_MIN_COHERENCE)
    h = pwt[sel] / pww[sel]

    def resid(q):
        m = _lead(q, f[sel])
        return np.concatenate([np.log(np.abs(m) / np.abs(h)), np.angle(m / h)])

    fit = optimize.least_squares(resid, np.log([1.0, 0.1, 0.02]))
    kp, ti, td = np.exp(fit.x)
    return {"drive_Kp": float(kp), "drive_Ti_s": float(ti), "logged_speed_delay_s": float(td),
            "bins_Hz": [float(x) for x in f[sel]], "magnitude": [float(x) for x in np.abs(h)],
            "phase_deg": [float(x) for x in np.degrees(np.angle(h))], "coherence": [float(x) for x in coh[sel]],
            "residual_rms": float(np.sqrt(np.mean(fit.fun ** 2))), "motor_speed_std": float(np.std(w)),
            "motor_torque_std": float(np.std(T))}


#: the hump each stiffness scale places, the band its mode is looked for in [Hz], the bracket of the scale
MODE_PLACEMENT = (("hump_27", (18.0, 42.0), "coupling_stiffness_scale", (0.5, 3.0)),
                  ("hump_58", (45.0, 110.0), "propeller_stiffness_scale", (0.2, 3.0)))


def mode_in(bg: Background, band: tuple[float, float]) -> dict:
    """The least damped mode of the linearised drivetrain in ``band`` [Hz] (a mode is followed by its band:
    the stiff speed loop adds a heavily damped mode of its own, 10-19 Hz, and the modes' order changes)."""
    modes = first_modes(bg, 8)
    inside = [m for m in modes if band[0] < m["f_Hz"] < band[1]]
    if not inside:                     # over-damped or moved out: the nearest one (keeps the root's sign)
        return min(modes, key=lambda m: abs(math.log(m["f_Hz"] / math.sqrt(band[0] * band[1]))))
    return min(inside, key=lambda m: m["zeta"])


def _place_modes(bg: Background, humps: dict) -> Background:
    from scipy import optimize

    for hump, band, key, (lo, hi) in MODE_PLACEMENT * 4:   # repeated: each stiffness moves the other mode
        def miss(log_s, key=key, band=band, target=humps[hump]["f_Hz"]):
            return mode_in(dataclasses.replace(bg, **{key: float(np.exp(log_s))}), band)["f_Hz"] - target
        bg = dataclasses.replace(bg, **{key: float(np.exp(optimize.brentq(miss, np.log(lo), np.log(hi),
                                                                          xtol=1e-4)))})
    return bg


def _fit_damping(bg: Background, f: np.ndarray, excess: np.ndarray) -> tuple[Background, dict]:
    """The coupling damping scale on DAMPING_GRID with the least log residual of S0 |H_load|^2 against
    ``excess`` (the PSD over the floor), S0 the geometric mean of excess / |H|^2 at each scale."""
    trials = []
    for scale in DAMPING_GRID:
        h = response(dataclasses.replace(bg, coupling_damping_scale=float(scale)), f)["propeller_shaft_torque"]
        logr = np.log(excess / h ** 2)
        trials.append((float(np.sqrt(np.mean((logr - logr.mean()) ** 2)) / math.log(10)), float(scale),
                       float(math.exp(logr.mean()))))
    rms, scale, s0 = min(trials)
    bg = dataclasses.replace(bg, coupling_damping_scale=scale, load_noise_Nm_rtHz=math.sqrt(s0))
    return bg, {"rms_log10": rms, "bins": int(len(f)), "band_Hz": list(FIT_BAND_HZ),
                "grid": [{"coupling_damping_scale": t[1], "rms_log10": t[0]} for t in trials]}


def identify(record: rec.Record | None = None, base: Background | None = None) -> dict:
    """The identified parameters (Background fields, the transducers' noise) and the figures of each step."""
    from scipy import signal

    r = record or rec.load_record()
    bg = base or START
    cut = int(round(rec.SKIP_S * r.fs))
    out: dict = {}
    psd = {}
    for name in rec.TORQUES:
        x = r.channels[name][cut:]
        f, psd[name] = signal.welch(x - x.mean(), fs=r.fs, nperseg=NPERSEG)
        band = (f >= FLOOR_BAND_HZ[0]) & (f <= FLOOR_BAND_HZ[1])
        out[f"{name}.floor_psd"] = float(np.median(psd[name][band]))
    out["instruments"] = {"drive_torque_noise_Nm": math.sqrt(out["drive_shaft_torque.floor_psd"] * r.fs / 2),
                          "propeller_torque_noise_Nm": math.sqrt(out["propeller_shaft_torque.floor_psd"] * r.fs / 2)}
    # the drive's torque noise: its own torque signal's floor above the speed loop (measured, not fitted)
    cm = int(round(0.2 * r.fs_motor))
    fm, ptm = signal.welch(r.motor["drive_motor_torque"][cm:] - r.motor["drive_motor_torque"][cm:].mean(),
                           fs=r.fs_motor, nperseg=CONTROL_NPERSEG)
    drive_floor = float(np.median(ptm[(fm >= DRIVE_FLOOR_HZ[0]) & (fm <= DRIVE_FLOOR_HZ[1])]))
    out["controller"] = controller(r)
    bg = dataclasses.replace(bg, drive_Kp=out["controller"]["drive_Kp"], drive_Ti_s=out["controller"]["drive_Ti_s"],
                             drive_noise_Nm_rtHz=math.sqrt(drive_floor))
    fa, amp = amplitude_spectrum(r.channels["propeller_shaft_torque"][cut:], r.fs)
    out["humps"] = record_humps(r)
    lines = periodic_lines(rec.RECORD_SPEED_RPM, bg.planetary_ring_teeth)
    sel = (f >= FIT_BAND_HZ[0]) & (f <= FIT_BAND_HZ[1])
    sel &= np.min(np.abs(f[:, None] - np.array(lines["all"])[None, :]), axis=1) > LINE_GAP_HZ
    ff = f[sel]
    excess = np.clip(psd["propeller_shaft_torque"][sel] - out["propeller_shaft_torque.floor_psd"], 1e-30, None)
    for _ in range(3):                 # the damping moves the modes a little: place, fit, place again
        bg = _place_modes(bg, out["humps"])
        bg, out["fit"] = _fit_damping(bg, ff, excess)
    bg = _place_modes(bg, out["humps"])
    named = lines["named"]
    h = response(bg, np.array(list(named.values())))["propeller_shaft_torque"]
    for (key, fl), hk in zip(named.items(), h):
        near = np.abs(fa - fl) <= rec.LINE_HALF_WIDTH_HZ
        bg = dataclasses.replace(bg, **{key: float(amp[near].max() / hk)})
    out["background"] = dataclasses.asdict(bg)
    out["modes"] = first_modes(bg, 4)
    return out


__all__ = ["identify", "response", "first_modes", "mode_in", "hump_mode", "record_humps", "controller",
           "periodic_lines"]
