"""The rig's instruments as models: what a run's ideal sensor signals look like once measured.

``effects.sensors = "rig"`` passes every recorded rig sensor through its instrument, after the
co-simulation and before statistics, spectra and files (so everything a user reads is "measured"):

* **incremental encoders** (enc1..enc5): a disc of ``encoder_lines`` lines read in quadrature counts
  4 edges per line; the angle latched at each sample is the last count, floor(theta / q) q with
  q = 2 pi / (4 lines): a staircase with error in (-q, 0], uniform, RMS q / sqrt(12);
* **strain-gauge torque transducers** (drive_shaft_torque, propeller_shaft_torque): the transducer and
  its amplifier as a causal 2nd-order Butterworth low-pass of ``torque_bandwidth_Hz`` (-3 dB there,
  the phase lag a real measurement has), then white measurement noise of RMS ``*_torque_noise_Nm``
  (the broadband floor of the measured spectra; one-sided density sigma^2 / (fs / 2)).

Everything is drawn from ``instruments.seed`` (numpy's PCG64): one seed, one noise record; each
channel of each run draws from its own stream (the seed, the channel name and the run's name), so
adding a channel does not change the others and the cases of a grid are not measured with one record. The sample clock is the run's ``time.sample_rate_Hz``; the rig's is 3012 Hz
(with 1/12048 s steps), and a run with rig sensors at another rate is told so.

The instrument constants are not from a data sheet (RIG.md does not give them): the defaults are
typical of such rigs (5000-line encoders, 1 kHz strain-gauge transducers, noise of a few mN·m: 5 mN·m on
the propeller shaft is 0.025 % of a 20 N·m transducer's range) and are
scene keys, so a user with the real data sheet sets them. ``"ideal"`` leaves every signal untouched:
bit-identical to a run without the switch. Pure: arrays in, arrays out.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np

#: the rig's data acquisition samples every sensor synchronously at this rate [Hz] (RIG.md)
RIG_SAMPLE_RATE_HZ = 3012.0
ENCODERS = ("enc1", "enc2", "enc3", "enc4", "enc5")
TORQUES = {"drive_shaft_torque": "drive", "propeller_shaft_torque": "propeller"}


@dataclass(frozen=True)
class Instruments:
    """Constants of the rig's instruments (scene section ``[instruments]``)."""

    seed: int = 0
    encoder_lines: int = 5000
    torque_bandwidth_Hz: float = 1000.0
    drive_torque_noise_Nm: float = 0.002
    propeller_torque_noise_Nm: float = 0.005


def encoder(theta: np.ndarray, lines: int) -> np.ndarray:
    """Angle [rad] an incremental encoder of ``lines`` lines (quadrature, 4 counts per line) reports."""
    if not (int(lines) == lines and lines >= 1):
        raise ValueError(f"encoder_lines must be a whole number >= 1, not {lines!r}")
    q = 2.0 * math.pi / (4 * int(lines))
    return np.floor(np.asarray(theta, dtype=float) / q) * q


def torque_transducer(x: np.ndarray, fs: float, bandwidth_Hz: float, noise_Nm: float,
                      rng: np.random.Generator) -> np.ndarray:
    """A torque signal [N·m] sampled at ``fs`` as the transducer reports it: causal 2nd-order Butterworth
    low-pass at ``bandwidth_Hz`` (started in its steady state at the first sample), plus white noise of
    RMS ``noise_Nm``. A bandwidth at or above the Nyquist frequency is no filter."""
    x = np.asarray(x, dtype=float)
    if not (bandwidth_Hz > 0 and noise_Nm >= 0):
        raise ValueError("torque_bandwidth_Hz must be > 0 and the torque noise >= 0")
    y = x.copy()
    if len(x) and bandwidth_Hz < 0.5 * fs:
        from scipy import signal as _sig

        sos = _sig.butter(2, bandwidth_Hz, fs=fs, output="sos")
        zi = _sig.sosfilt_zi(sos) * x[0]
        y, _ = _sig.sosfilt(sos, x, zi=zi)
    if noise_Nm > 0:
        y = y + rng.normal(0.0, noise_Nm, len(x))
    return y


def _rng(seed: int, channel: str, stream: str) -> np.random.Generator:
    return np.random.default_rng([int(seed), zlib.crc32(channel.encode()), zlib.crc32(stream.encode())])


def measure(signals: dict, fs: float, inst: Instruments, stream: str = "") -> dict:
    """The rig's readings of ``signals`` (name -> samples at ``fs``): encoders and torque transducers
    replaced, other channels (extra FMU variables) untouched. ``stream`` (the run's name) separates the
    noise of the cases of a grid that share one seed. Returns a new dict."""
    out = dict(signals)
    for name, x in signals.items():
        if name in ENCODERS:
            out[name] = encoder(x, inst.encoder_lines)
        elif name in TORQUES:
            noise = getattr(inst, f"{TORQUES[name]}_torque_noise_Nm")
            out[name] = torque_transducer(x, fs, inst.torque_bandwidth_Hz, noise, _rng(inst.seed, name, stream))
    return out
