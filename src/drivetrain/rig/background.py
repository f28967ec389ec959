"""The rig's measured background: what a healthy run needs besides the gears to look like the rig.

A healthy run of the model is quieter than the rig: against a measured 2 s record of the rig at 500 rpm /
1.31 N·m (drivetrain.rig.record) its propeller-shaft torque std is 2.9x low, its shaft-order lines 26-31 dB
low, its broadband floor 22 dB low, and two humps near 27 and 58 Hz are missing. The effects below supply
what the record shows, each switchable per scene and off by default (off, a run is bit-identical to one
without this module); their constants are the scene section ``[background]`` (:class:`Background`), every
default identified from the record by campaigns.record_fit (``drivetrain calibrate --record``; the evidence
and the procedure: docs/DRIVETRAIN.md, "The measured background"):

* ``effects.drive_control = "record"``: the drive's PI speed controller as the rig runs it. The drive's own
  torque and speed signals give Kp 1.41 N·m·s/rad and Ti 0.065 s (a ~23 Hz speed loop), 14x the assumed
  gain: the rig's drive holds its speed to 0.009 rad/s std.
* ``effects.couplings = "record"``: coupling stiffness and damping and the propeller shaft's stiffness as the
  record shows them (modes on its humps at 27.8 and 58.4 Hz; damping from its broadband).
* ``effects.load_torque_noise``: broadband torque noise of the load motor, which is torque-controlled (no
  speed loop to oppose it) and acts through the 1:8 planetary on the propeller mass; white, one-sided
  density ``load_noise_Nm_rtHz`` (propeller-shaft frame) to ``noise_band_Hz``. With the drive held stiffly,
  a noise at the drive cannot make the record's spectra: its own torque signal would show it 10-1000x
  larger than it does; one at the load gives both transducers' spectra within a factor 2-3.
* ``effects.drive_torque_noise``: the drive's broadband torque noise on the motor rotor (MotorLoad's
  ``motor_torque_disturbance`` input), at the floor of its own torque signal: small, for completeness.
* ``effects.shaft_orders``: periodic torque on the propeller mass at 1x and 2x the middle and drive
  shafts' speeds (runout, bow and misalignment between the stiffly held drive and the free propeller mass:
  below the first mode their effect on both transducers is that of a torque on the one body free to follow)
  and at the planetary's mesh frequency (84 x the propeller shaft's speed: the record's largest line, at
  84.0 f_PSH, with 1 + 84/12 = 8 the planetary's ratio). In phase with the propeller shaft's nominal angle
  (the integral of the speed reference); phases drawn from ``seed``; amplitudes as a power of the speed
  (one exponent per line, ``order_*_exponent``; ``orders_speed_exponent`` for the planetary's mesh), the record's
  at 500 rpm. Each line has its own mechanism (runout and bow at 1x, misalignment at 2x, of a shaft of its own),
  so each has its own law: the exponents 0.608 (f_MSH), 1.388 (2 f_MSH), 1.936 (f_DSH) and 1.670 (2 f_DSH) are a
  calibration on the 500 rpm record and the 2004 rpm impulse record (campaigns.excitation_fit); the 2004 rpm
  multi-sine record judges them (docs/VALIDATION.md, check 12). Between 0 (a torque ripple of constant size) and 2
  (a kinematic error moving the propeller mass), which issue 28 had assumed for all and which put the lines 6-18
  dB over the rig's at 2004 rpm. The planetary's mesh has no second speed: it keeps the lines' common exponent
  1.400 (least squares in log over the four).

Torques on the propeller mass reach the model as the load motor's setting (MotorLoad's ``load_torque``
input, their 1/8 share), torques on the rotor as ``motor_torque_disturbance``: both are input profiles
the master feeds every communication step, so every backend and host that feeds inputs runs them. The
transducers' measured noise is ``[instruments]`` (effects.sensors = "rig"). Pure: numbers in, arrays out.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np

from drivetrain.rig.data import rpm_to_rad_s
from drivetrain.rig.record import RECORD_SPEED_RPM as REFERENCE_SPEED_RPM

#: the periodic lines of ``effects.shaft_orders``: key -> (what turns, lines per its revolution): the middle
#: and drive shafts' 1x and 2x, and the 1:8 planetary's mesh (``planetary_ring_teeth`` lines per propeller
#: revolution); :func:`propeller_order` turns each into lines per propeller revolution
ORDERS = {"order_msh_1x_Nm": ("middle", 1), "order_msh_2x_Nm": ("middle", 2), "order_dsh_1x_Nm": ("drive", 1),
          "order_dsh_2x_Nm": ("drive", 2), "planetary_mesh_Nm": ("planetary", None)}

#: the lines with a speed law of their own: [background] amplitude key -> its exponent's key
EXPONENT_KEYS = {k: k.replace("_Nm", "_exponent") for k in ORDERS if k.startswith("order_")}


@dataclass(frozen=True)
class Background:
    """Constants of the background effects (scene section ``[background]``), identified from the measured
    record by campaigns.record_fit.identify (docs/DRIVETRAIN.md, "The measured background"). Torques on
    the propeller mass are in the propeller-shaft frame (the load motor's share is 1/8 of them)."""

    seed: int = 0
    load_noise_Nm_rtHz: float = 0.02266
    drive_noise_Nm_rtHz: float = 0.0006895
    noise_band_Hz: float = 300.0
    order_msh_1x_Nm: float = 0.06153
    order_msh_2x_Nm: float = 0.05542
    order_dsh_1x_Nm: float = 0.02973
    order_dsh_2x_Nm: float = 0.01836
    planetary_mesh_Nm: float = 0.319
    planetary_ring_teeth: int = 84
    orders_speed_exponent: float = 1.400
    order_msh_1x_exponent: float = 0.6081
    order_msh_2x_exponent: float = 1.388
    order_dsh_1x_exponent: float = 1.936
    order_dsh_2x_exponent: float = 1.670
    drive_Kp: float = 1.411
    drive_Ti_s: float = 0.06506
    coupling_stiffness_scale: float = 1.049
    coupling_damping_scale: float = 1.114
    propeller_stiffness_scale: float = 0.4814
    propeller_damping_scale: float = 1.0


def _rng(seed: int, stream: str, run: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), zlib.crc32(stream.encode()), zlib.crc32(run.encode())])


def broadband_noise(n: int, fs: float, asd: float, band_Hz: float, rng: np.random.Generator) -> np.ndarray:
    """``n`` samples at ``fs`` of Gaussian noise with one-sided amplitude spectral density ``asd`` [unit/sqrt(Hz)]
    in its pass band, low-passed at ``band_Hz`` (causal 4th-order Butterworth; none at or above Nyquist)."""
    if not (asd >= 0 and band_Hz > 0 and fs > 0):
        raise ValueError("the noise density must be >= 0, noise_band_Hz and the sample rate > 0")
    x = rng.normal(0.0, asd * math.sqrt(0.5 * fs), n)
    if band_Hz < 0.5 * fs:
        from scipy import signal

        x = signal.sosfilt(signal.butter(4, band_Hz, fs=fs, output="sos"), x)
    return x


def speed_at(t: np.ndarray, speed_rpm) -> np.ndarray:
    """The speed reference [rpm] at times ``t``: a constant or a profile [[t_s, rpm], ...] (linear between
    points, held outside)."""
    t = np.asarray(t, dtype=float)
    if np.isscalar(speed_rpm) or np.ndim(speed_rpm) == 0:
        return np.full_like(t, float(speed_rpm))
    p = np.asarray(speed_rpm, dtype=float)
    return np.interp(t, p[:, 0], p[:, 1])


def drive_angle(t: np.ndarray, speed_rpm) -> np.ndarray:
    """The drive shaft's nominal angle [rad] at times ``t``: the integral of the speed reference
    (:func:`speed_at`; exact for a constant speed, trapezoidal along a profile)."""
    t = np.asarray(t, dtype=float)
    if np.isscalar(speed_rpm) or np.ndim(speed_rpm) == 0:
        return rpm_to_rad_s(float(speed_rpm)) * t
    w = rpm_to_rad_s(speed_at(t, speed_rpm))
    out = np.zeros_like(t)
    out[1:] = np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))
    return out


def line_exponent(key: str, bg: Background) -> float:
    """The speed exponent of the periodic line ``key``: its own (``<key stem>_exponent``) where it has one, else
    the common ``orders_speed_exponent`` (the planetary's mesh)."""
    own = EXPONENT_KEYS.get(key)
    return float(getattr(bg, own) if own else bg.orders_speed_exponent)


def propeller_order(key: str, bg: Background, upper_ratio: float, lower_ratio: float) -> float:
    """Lines per propeller revolution of the periodic line ``key`` of :data:`ORDERS`."""
    what, k = ORDERS[key]
    if what == "planetary":
        return float(bg.planetary_ring_teeth)
    return float(k) * (lower_ratio if what == "middle" else upper_ratio * lower_ratio)


def order_ripple(t: np.ndarray, speed_rpm, bg: Background, upper_ratio: float, lower_ratio: float) -> np.ndarray:
    """Periodic torque [N·m] on the propeller mass at the orders of ``ORDERS``, in phase with the
    propeller shaft's nominal angle (the drive's angle over the two gear stages). Each amplitude is the
    record's at its speed (``REFERENCE_SPEED_RPM``) times (speed / that speed)^(its exponent, :func:`line_exponent`): a
    kinematic error between two bodies is a displacement, and the torque that makes a body follow it grows as
    the square of its frequency (exponent 2); a motor's torque ripple keeps its size (0); the rig's lines grow
    between, each by its own exponent (:func:`line_exponent`, module docstring). The phases are drawn from ``bg.seed``
    (one gearbox, one set of phases; not the run's name)."""
    theta = drive_angle(t, speed_rpm) / (upper_ratio * lower_ratio)
    ratio = speed_at(t, speed_rpm) / REFERENCE_SPEED_RPM
    phases = _rng(bg.seed, "shaft_orders", "").uniform(0.0, 2.0 * math.pi, len(ORDERS))
    out = np.zeros_like(theta)
    for key, ph in zip(ORDERS, phases):
        amp = float(getattr(bg, key))
        if amp:
            out += amp * ratio ** line_exponent(key, bg) * np.sin(
                propeller_order(key, bg, upper_ratio, lower_ratio) * theta + ph)
    return out


#: where the background's torques act: on the drive motor's rotor, or on the propeller mass
PLACES = ("drive", "load")


def acts_on(where: str, effects) -> bool:
    """Whether any switched-on background effect puts a torque ``where`` (:data:`PLACES`)."""
    if where == "drive":
        return bool(effects.drive_torque_noise)
    return bool(effects.load_torque_noise or effects.shaft_orders)


def disturbance(where: str, effects, n_steps: int, H: float, speed_rpm, bg: Background, run: str,
                upper_ratio: float, lower_ratio: float) -> np.ndarray:
    """The background's torque [N·m] at the communication points t_k = k H, k = 0..n_steps, acting ``where``:
    ``"drive"`` (on the drive motor's rotor) or ``"load"`` (on the propeller mass, propeller-shaft frame), of
    the switched-on effects only (zeros when none acts there). Each noise record is drawn from (``bg.seed``,
    its stream, the run's name): each run of a grid gets its own, a scene rerun the same."""
    if where not in PLACES:
        raise ValueError(f"a background torque acts on {' or '.join(PLACES)}, not {where!r}")
    fs = 1.0 / H
    out = np.zeros(n_steps + 1)
    if where == "drive":
        if effects.drive_torque_noise:
            out += broadband_noise(n_steps + 1, fs, bg.drive_noise_Nm_rtHz, bg.noise_band_Hz,
                                   _rng(bg.seed, "drive_torque_noise", run))
        return out
    if effects.load_torque_noise:
        out += broadband_noise(n_steps + 1, fs, bg.load_noise_Nm_rtHz, bg.noise_band_Hz,
                               _rng(bg.seed, "load_torque_noise", run))
    if effects.shaft_orders:
        out += order_ripple(np.arange(n_steps + 1) * H, speed_rpm, bg, upper_ratio, lower_ratio)
    return out


class GeneratedProfile:
    """An input profile computed when it is read: rows [t_k, value] at the communication points, as
    ``numpy.asarray`` (``__array__``), indexing and iteration see them. It keeps and pickles its recipe
    (a picklable callable returning the values), not its samples: a sweep of thousands of runs holds and
    ships recipes of a few numbers, not megabytes of noise per run."""

    def __init__(self, make, n_rows: int, H: float):
        self._make, self._n, self._H = make, int(n_rows), float(H)

    shape = property(lambda self: (self._n, 2))
    ndim = 2

    def __len__(self) -> int:
        return self._n

    def __array__(self, dtype=None, copy=None):
        rows = as_profile(self._H, np.asarray(self._make(), dtype=float))
        if rows.shape != (self._n, 2):
            raise ValueError(f"a generated profile gave {rows.shape[0]} rows, not {self._n}")
        return rows if dtype is None else rows.astype(dtype)

    def __getitem__(self, index):
        return np.asarray(self)[index]

    def __iter__(self):
        return iter(np.asarray(self))

    def __repr__(self) -> str:
        return f"GeneratedProfile({self._n} rows at H = {self._H:g} s)"


def as_profile(H: float, values: np.ndarray) -> np.ndarray:
    """An input profile (rows [t_s, value]) of values at the communication points k H."""
    return np.column_stack([np.arange(len(values)) * H, values])


__all__ = ["Background", "ORDERS", "REFERENCE_SPEED_RPM", "broadband_noise", "drive_angle", "speed_at",
           "propeller_order",
           "order_ripple", "PLACES", "acts_on", "disturbance", "as_profile", "GeneratedProfile"]
