"""The rig's measured background: what a healthy run needs besides the gears to look like the rig.

A simulated healthy drivetrain is quieter than the rig: a measured 2 s record of the rig at 500 rpm /
1.31 N·m (``drivetrain/data/rig_records``, docs/VALIDATION.md "The measured record") has a propeller-shaft
torque std 2.9x ours, shaft-order lines 26-31 dB over ours, two humps near 27 and 58 Hz and a floor
22 dB over ours. Three effects supply it, each switchable per scene and off by default (off, a run is
bit-identical to one without this module); their parameters are the scene section ``[background]``:

* ``effects.drive_torque_noise``: broadband torque noise of the drive, a stationary Gaussian torque on
  the drive motor's rotor (the ``motor_torque_disturbance`` input of MotorLoad, added after the PI
  controller): current-loop and PWM noise of a servo drive. White with one-sided amplitude spectral
  density ``drive_noise_Nm_rtHz`` up to ``drive_noise_band_Hz`` (4th-order Butterworth roll-off).
  Why at the drive: the ratio of the two transducers' spectra in the humps (5.8 at 27 Hz, 16 at 58 Hz
  measured) is what the linearised drivetrain gives for a torque entering at the drive motor (6.6, 17),
  not for one at the mesh (8.5, 88) or the load motor (8.0, 20); the drive's own torque signal is
  coherent with the propeller-shaft torque in both humps (0.6, 0.8).
* ``effects.shaft_orders``: torque ripple at 1x and 2x the drive shaft's and the middle shaft's speed
  (coupling misalignment and shaft bow on the drive shaft, runout of the upper bevel pair on the middle
  shaft), on the same rotor input, in phase with the drive shaft's angle (the integral of the speed
  reference): ``order_*_Nm`` amplitudes, phases drawn from ``seed`` (one gearbox, one set of phases).
* ``effects.couplings = "record"``: the elastomer couplings' stiffness and damping and the propeller
  shaft's as identified from the record (``coupling_*_scale``, ``propeller_*_scale`` on the public
  lumped model) instead of the coupling factor fitted to the paper's 24 Hz (``"fitted"``).

The transducers' measured noise is not here: it is ``[instruments]`` (``effects.sensors = "rig"``), set
to the record's high-frequency floor in ``scenarios/validation/rig_record_500rpm.toml``.

Every default below is identified from the record by ``drivetrain calibrate --record`` (campaigns.record_fit;
the procedure in docs/VALIDATION.md): fitted, not tuned line by line. Pure: numbers in, arrays out.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np

#: the periodic lines of ``effects.shaft_orders``: key -> order of the propeller shaft (lines per propeller
#: revolution; the drive shaft turns 12 times, the middle shaft 4 times per propeller revolution);
#: ``planetary_mesh_Nm`` is at ``planetary_ring_teeth`` (the 1:8 planetary's mesh frequency)
ORDERS = {"order_msh_1x_Nm": 4, "order_msh_2x_Nm": 8, "order_dsh_1x_Nm": 12, "order_dsh_2x_Nm": 24,
          "planetary_mesh_Nm": None}


@dataclass(frozen=True)
class Background:
    """Constants of the background effects (scene section ``[background]``), identified from the measured
    record by campaigns.record_fit.identify (docs/DRIVETRAIN.md, "The measured background"). Torques on
    the propeller mass are in the propeller-shaft frame (the load motor's share is 1/8 of them)."""

    seed: int = 0
    load_noise_Nm_rtHz: float = 0.0131
    drive_noise_Nm_rtHz: float = 0.00069
    noise_band_Hz: float = 300.0
    order_msh_1x_Nm: float = 0.0615
    order_msh_2x_Nm: float = 0.0554
    order_dsh_1x_Nm: float = 0.0303
    order_dsh_2x_Nm: float = 0.0188
    planetary_mesh_Nm: float = 0.309
    planetary_ring_teeth: int = 84
    drive_Kp: float = 1.41
    drive_Ti_s: float = 0.065
    coupling_stiffness_scale: float = 0.887
    coupling_damping_scale: float = 1.93
    propeller_stiffness_scale: float = 0.581
    propeller_damping_scale: float = 1.0


def _rng(seed: int, stream: str, run: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), zlib.crc32(stream.encode()), zlib.crc32(run.encode())])


def broadband_noise(n: int, fs: float, asd: float, band_Hz: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` samples at ``fs`` of Gaussian noise with one-sided amplitude spectral density ``asd`` [unit/sqrt(Hz)]
    in its pass band, low-passed at ``band_Hz`` (causal 4th-order Butterworth; none at or above Nyquist)."""
    if not (asd >= 0 and band_Hz > 0 and fs > 0):
        raise ValueError("drive_noise_Nm_rtHz must be >= 0, drive_noise_band_Hz and the sample rate > 0")
    x = rng.normal(0.0, asd * math.sqrt(0.5 * fs), n)
    if band_Hz < 0.5 * fs:
        from scipy import signal

        x = signal.sosfilt(signal.butter(4, band_Hz, fs=fs, output="sos"), x)
    return x


def drive_angle(t: np.ndarray, speed_rpm) -> np.ndarray:
    """The drive shaft's nominal angle [rad] at times ``t``: the integral of the speed reference, a
    constant [rpm] or a profile [[t_s, rpm], ...] (linear between points, held outside)."""
    t = np.asarray(t, dtype=float)
    if np.isscalar(speed_rpm) or np.ndim(speed_rpm) == 0:
        return float(speed_rpm) * math.pi / 30.0 * t
    p = np.asarray(speed_rpm, dtype=float)
    w = np.interp(t, p[:, 0], p[:, 1]) * math.pi / 30.0
    out = np.zeros_like(t)
    out[1:] = np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))
    return out


def order_ripple(t: np.ndarray, speed_rpm, bg: Background, upper_ratio: float, lower_ratio: float) -> np.ndarray:
    """Periodic torque [N·m] on the propeller mass at the orders of ``ORDERS``, in phase with the
    propeller shaft's nominal angle (the drive's angle over the two gear stages); the phases are drawn from
    ``bg.seed`` (one gearbox, one set of phases; not the run's name)."""
    theta = drive_angle(t, speed_rpm) / (upper_ratio * lower_ratio)
    phases = _rng(bg.seed, "shaft_orders", "").uniform(0.0, 2.0 * math.pi, len(ORDERS))
    out = np.zeros_like(theta)
    for (key, order), ph in zip(ORDERS.items(), phases):
        amp = float(getattr(bg, key))
        if amp:
            k = float(bg.planetary_ring_teeth if order is None else order)
            out += amp * np.sin(k * theta + ph)
    return out


def disturbances(scene_effects, n_steps: int, H: float, speed_rpm, bg: Background, run: str,
                 upper_ratio: float, lower_ratio: float) -> dict:
    """The background's torques at the communication points t_k = k H, k = 0..n_steps, by where they act:
    ``"drive"`` (on the drive motor's rotor [N·m]) and ``"load"`` (on the propeller mass, propeller-shaft
    frame [N·m]); only the switched-on effects, and only the places something acts on. Each noise record is
    drawn from (``bg.seed``, its stream, the run's name): each run of a grid gets its own, a scene rerun the
    same."""
    fs = 1.0 / H
    out = {}
    if scene_effects.drive_torque_noise:
        out["drive"] = broadband_noise(n_steps + 1, fs, bg.drive_noise_Nm_rtHz, bg.noise_band_Hz,
                                       _rng(bg.seed, "drive_torque_noise", run))
    load = np.zeros(n_steps + 1)
    if scene_effects.load_torque_noise:
        load += broadband_noise(n_steps + 1, fs, bg.load_noise_Nm_rtHz, bg.noise_band_Hz,
                                _rng(bg.seed, "load_torque_noise", run))
    if scene_effects.shaft_orders:
        load += order_ripple(np.arange(n_steps + 1) * H, speed_rpm, bg, upper_ratio, lower_ratio)
    if scene_effects.load_torque_noise or scene_effects.shaft_orders:
        out["load"] = load
    return out


def as_profile(H: float, values: np.ndarray) -> np.ndarray:
    """An input profile (rows [t_s, value]) of values at the communication points k H."""
    return np.column_stack([np.arange(len(values)) * H, values])


__all__ = ["Background", "ORDERS", "broadband_noise", "drive_angle", "order_ripple", "disturbances",
           "as_profile"]
