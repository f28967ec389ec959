"""Expectations of a scene: the ``[expect]`` and ``[check]`` sections, and their evaluation.

A scene may say what its result must be (docs/SCENARIOS.md, "Expectations")::

    [expect]
    "torque.propeller_shaft_torque.mean" = { value = 15.03, rel = 0.01 }
    "energy_residual" = { max = 1e-3 }
    "status" = "ok"
    "signal.propeller_shaft_torque[2.5:4.0].mean" = { value = 5.23, rel = 0.02 }
    "spectrum.propeller_shaft_torque@f_GMF-f_MSH.dB_re_GMF" = { min = -10.0 }
    "torque.drive_shaft_torque.mean" = { measured = "T_DSH_Nm", rel = 0.05 }

Three kinds of key:

- a dotted path into ``summary.json`` (``torque.<sensor>.<stat>``, ``stability.rattle.n_separations``,
  ``spectrum_peaks.<sensor>.sidebands.0.lower_dB_re_GMF``; list items by index);
- ``signal.<channel>[t0:t1].<stat>``: a statistic of an output channel (a sensor of ``outputs.sensors`` or
  a ``component.variable`` of ``outputs.variables``) over a time window in s (default ``[settle_s:end]``;
  either bound may be left out); stat = ``mean``, ``rms``, ``std``, ``p2p`` (peak to peak), ``min``, ``max``;
- ``spectrum.<channel>[t0:t1]@<frequency>[.<level>]``: the spectral amplitude of a channel at a
  characteristic frequency (the run's Hann-window amplitude spectrum after a low-pass at 5 × f_GMF, as
  the summary's ``spectrum_peaks``: the largest amplitude within ±2 bins). ``<frequency>`` is a sum of
  terms ``[k*]f_DSH|f_MSH|f_PSH|f_GMF`` or numbers in Hz: ``f_GMF``, ``2*f_GMF``, ``f_GMF-f_MSH``,
  ``f_GMF+2*f_MSH``, ``37.5``. Level: ``amplitude`` (default, in the channel's unit), ``dB`` (re 1 unit),
  ``dB_re_GMF`` (relative to the amplitude at f_GMF).

Each value is a tolerance spec: ``{ value = x, rel = r }`` and/or ``abs = a`` (holds if
``|actual - x| <= max(a, r·|x|)``), a range ``{ min = a }``, ``{ max = b }``, ``{ min = a, max = b }``
(inclusive), or for strings and booleans the plain value (``"status" = "ok"``, ``"stability.rattle.separated"
= true``). ``measured = "<column>"`` instead of ``value`` takes the value from the rig's measured mean-torque
table (``drivetrain/data/measured_mean_torques.csv``) at the scene's operating point (load setting and
final drive speed within 1 %), so one line in a grid file gives every case its own measured value.

``[check]`` says how a scene is checked: ``slow`` (mark its pytest item slow; default: the duration
rule :func:`is_slow`), ``baseline`` (the baseline file; default ``<scene>.baseline.h5`` beside the
scene), ``baseline_rel``, ``baseline_signal_rel``, ``baseline_dB`` (tolerances against the baseline),
``baseline_signals`` (the channels stored in the baseline).

Validation (:func:`parse_checks`, called by :func:`drivetrain.scene.load.resolve`) appends every problem
to the scene's problem list: unknown metric paths (with the closest known key), channels the scene does
not write, malformed frequencies or windows, bad tolerance specs. Evaluation (:func:`evaluate`) needs
only a run's summary, its output time and signals.
"""
from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drivetrain.rig.data import RIG_SENSORS, TORQUE_SENSORS, read_measured
from drivetrain.rig.signals import SPECTRUM_LINE_BINS, amplitude_near, amplitude_spectrum, spectrum_lowpass_Hz
from drivetrain.scene.schema import RIG_PAIR, SCHEMA

#: Statistics of ``signal.<channel>.<stat>``.
SIGNAL_STATS = ("mean", "rms", "std", "p2p", "min", "max")
#: Levels of ``spectrum.<channel>@<f>.<level>``.
SPECTRUM_LEVELS = ("amplitude", "dB", "dB_re_GMF")
#: Named characteristic frequencies usable in frequency expressions.
FREQ_NAMES = ("f_DSH", "f_MSH", "f_PSH", "f_GMF")
#: Keys of a tolerance spec.
SPEC_KEYS = ("value", "measured", "rel", "abs", "min", "max")
#: A scene is slow (pytest marker) when it simulates longer than this (``[check] slow`` overrides) ...
SLOW_DURATION_S = 5.0
#: ... or uses online PCM contact for longer than this.
SLOW_DURATION_PCM_S = 0.1
#: Bins either side of a frequency searched for its amplitude (as the summary's spectrum_peaks).
SPECTRUM_BINS = SPECTRUM_LINE_BINS

# --------------------------------------------------------------------------------------------------
# The layout of summary.json, declared once: drivetrain.run.runner builds the summary in this order and
# takes its top-level keys from here; the tests check a real run's summary.json against it key for key
# (summary_mismatch). Leaves: "num", "int", "str", "bool" (None allowed where it does not apply), "any"
# (a whole subtree is accepted: energy audit, failure record, ...). "<torque>" = a torque sensor of the
# scene, "<channel>" = any output channel of the scene, "<i>" = a list index.
# --------------------------------------------------------------------------------------------------

#: the summary's type of a scene key's value (the scene's [effects] are copied into the summary as resolved)
_SUMMARY_TYPE = {"bool": "bool", "int": "int", "float": "num", "enum": "str", "str": "str"}
_STATS_TREE = {"mean": "num", "rms": "num", "std": "num", "min": "num", "max": "num", "unit": "str"}
_RATTLE3 = {"separated_time_s": "num", "separated_fraction": "num", "n_separations": "int"}
#: what :func:`drivetrain.run.runner.run_scene` computes (RunResult.summary)
RUN_SUMMARY_TREE: dict = {
    "name": "str", "status": "str", "failure": "any", "description": "str", "source": "str",
    "overrides": "any", "backend": "str", "wall_time_s": "num", "sim_time_s": "num",
    "requested_sim_time_s": "num", "real_time_factor": "num", "real_time_factor_wall": "num",
    "loop_time_s": "num", "loop_cpu_time_s": "num",
    "time_breakdown_s": {"startup": "num", "assemble_and_check": "num", "native_build": "num", "fmu_setup": "num",
                         "loop": "num", "postprocess": "num", "write": "num", "plots": "num"},
    "us_per_step": "num", "us_per_step_steady": "num", "n_steps": "int", "comm_step_s": "num",
    "sample_rate_Hz": "num", "settle_s": "num", "n_fmus": "int",
    "operating_point": {"drive_speed_rpm": "num", "load_torque_Nm": "num", "profiles": "bool"},
    "health": "str",
    "fault_contact": {"<i>": {"loaded_flank": "str", "contact_share": "num", "mesh_torque_drop": "num"}},
    "effects": {key: _SUMMARY_TYPE[spec.type] for key, spec in SCHEMA["effects"].items()},
    "manufacturing_errors": "any", "instruments": "any",
    "torque": {"<torque>": _STATS_TREE},
    "channels": {"<channel>": _STATS_TREE},
    "f_DSH": "num", "f_MSH": "num", "f_PSH": "num", "f_GMF": "num",
    "characteristic_frequencies": {
        "f_DSH": "num", "f_MSH": "num", "f_PSH": "num", "f_GMF": "num", "harmonics": {"<i>": "num"},
        "sidebands": {"<i>": {"k": "int", "lower": "num", "upper": "num"}}, "z1": "int", "z2": "int",
        "upper_ratio": "num", "drive_speed_rpm": "num"},
    "spectrum_peaks": {"<torque>": {
        "bin_Hz": "num",
        "GMF_harmonics": {"<i>": {"k": "int", "f_Hz": "num", "amplitude": "num"}},
        "sidebands": {"<i>": {"k": "int", "lower_Hz": "num", "upper_Hz": "num", "lower_amplitude": "num",
                              "upper_amplitude": "num", "lower_dB_re_GMF": "num", "upper_dB_re_GMF": "num"}}}},
    "energy_residual": "num",
    "energy": "any",
    "natural_frequencies_Hz": {"<i>": "num"},
    "stability": {
        "gear": "str", "time_s": "num", "max_penetration_m": "num", "u_max_m": "num",
        "max_penetration_rel_umax": "num", "min_substep_s": "num", "max_substep_s": "num", "n_substeps": "int",
        "n_refinements": "int", "energy_residual": "num", "coupling_energy_pending_J": "any",
        "rattle": {"window_s": {"<i>": "num"}, "separated": "bool", **_RATTLE3, "whole_run": dict(_RATTLE3)},
        "static_contact": "any", "contact_cost": "any"},
    "fmus": "any", "nonfinite_channels": "any", "nonfinite_samples": "any", "warnings": "any", "accuracy_choice": "any",
    "drivetrain_version": "str",
}
#: what :func:`drivetrain.run.runner.write_run` adds when it writes the files
WRITE_SUMMARY_TREE: dict = {"files": "any", "write_time_s": "num"}
#: summary.json as written
SUMMARY_TREE: dict = {**RUN_SUMMARY_TREE, **WRITE_SUMMARY_TREE}
#: the placeholders of a tree: a key the scene names (a torque sensor, an output channel)
_NAMED = ("<torque>", "<channel>")


def summary_mismatch(summary: Any, tree: Any = None, where: str = "") -> list[str]:
    """Where ``summary`` (a summary.json's content, or a part of it at ``where``) differs in its keys from
    the declared ``tree`` (default :data:`SUMMARY_TREE`): keys missing, keys not declared, a subtree where a
    leaf is declared or the reverse. None fits anything (an entry that does not apply); "any" takes any
    subtree. Empty when they agree."""
    tree = SUMMARY_TREE if tree is None else tree
    at = where or "summary.json"
    if tree == "any" or summary is None:
        return []
    if not isinstance(tree, dict):
        return [f"{at}: a {type(summary).__name__} where a {tree} is declared"] \
            if isinstance(summary, (dict, list)) else []
    if isinstance(summary, list) and "<i>" in tree:
        return [p for i, x in enumerate(summary) for p in summary_mismatch(x, tree["<i>"], f"{where}.{i}".lstrip("."))]
    if not isinstance(summary, dict) or "<i>" in tree:
        return [f"{at}: a {type(summary).__name__} where {'a list' if '<i>' in tree else 'a table'} is declared"]
    named = next((tree[k] for k in _NAMED if k in tree), None)
    problems = [f"{at}: no {k!r}" for k in tree if k not in summary and k not in _NAMED]
    for k, x in summary.items():
        sub = tree.get(k, named)
        if sub is None:
            problems.append(f"{at}: {k!r} is not declared")
        else:
            problems += summary_mismatch(x, sub, f"{where}.{k}".lstrip("."))
    return problems


# --------------------------------------------------------------------------------------------------
# Parsed expectations
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Expectation:
    """One ``[expect]`` entry, validated."""

    key: str                                  # as written in the scene
    kind: str                                 # "summary" | "signal" | "spectrum"
    path: tuple = ()                          # summary path (str keys, int indices)
    channel: str | None = None                # signal / spectrum channel
    stat: str | None = None                   # signal statistic
    freq: str | None = None                   # spectrum frequency expression
    level: str = "amplitude"                  # spectrum level
    window: tuple | None = None               # (t0 | None, t1 | None) [s]
    value: Any = None                         # expected value (number, str, bool)
    rel: float | None = None
    abs: float | None = None
    min: float | None = None
    max: float | None = None
    ref: str | None = None                    # where the value came from (measured table)

    @property
    def numeric(self) -> bool:
        return not isinstance(self.value, (str, bool))

    def tolerance(self) -> float | None:
        """The allowed |actual - value| (None for ranges and exact values)."""
        if self.value is None or not self.numeric:
            return None
        return max(self.abs or 0.0, (self.rel or 0.0) * abs(self.value))

    def expected_text(self) -> str:
        if self.value is not None and not self.numeric:
            return _fmt(self.value)
        if self.value is not None and math.isnan(self.value):
            return "a measured value (none at this operating point)"
        if self.value is not None:
            return _fmt(self.value) + (f" ({self.ref})" if self.ref else "")
        if self.min is not None and self.max is not None:
            return f"in [{_fmt(self.min)}, {_fmt(self.max)}]"
        if self.min is not None:
            return f">= {_fmt(self.min)}"
        return f"<= {_fmt(self.max)}"

    def tolerance_text(self) -> str:
        if self.value is None:
            return "range"
        if not self.numeric:
            return "exact"
        parts = []
        if self.rel is not None:
            parts.append(f"rel {_fmt(self.rel)}")
        if self.abs is not None:
            parts.append(f"abs {_fmt(self.abs)}")
        return f"±{_fmt(self.tolerance())} (" + ", ".join(parts) + ")"

    def check(self, actual) -> bool:
        if isinstance(self.value, bool):
            return isinstance(actual, (bool, np.bool_)) and bool(actual) == self.value
        if self.value is not None and not self.numeric:
            return isinstance(actual, str) and actual == self.value
        if not _is_number(actual) or not math.isfinite(float(actual)):
            return False
        a = float(actual)
        if self.value is not None:
            return abs(a - self.value) <= self.tolerance() * (1 + 1e-12) + 1e-300
        return (self.min is None or a >= self.min) and (self.max is None or a <= self.max)

    def to_raw(self) -> Any:
        d = {k: getattr(self, k) for k in ("rel", "abs", "min", "max") if getattr(self, k) is not None}
        if self.value is not None:
            if not self.numeric and not d:
                return self.value
            d = {"value": self.value, **d}
        return d


@dataclass(frozen=True)
class CheckOptions:
    """The ``[check]`` section."""

    slow: bool | None = None                  # None: the duration rule (is_slow)
    baseline: Path | None = None              # the baseline file (None: beside the scene)
    baseline_rel: float = 1e-3                # summary metrics vs the baseline (relative, with a scale floor)
    baseline_signal_rel: float = 0.01         # RMS difference of a signal / RMS of the baseline signal
    baseline_dB: float = 1.0                  # spectral levels at the characteristic frequencies
    baseline_signals: tuple[str, ...] | None = None   # channels stored (None: torques + variables)


@dataclass(frozen=True)
class ExpectSpec:
    """The parsed ``[expect]`` and ``[check]`` sections of a scene (empty if absent)."""

    items: tuple[Expectation, ...] = ()
    options: CheckOptions = field(default_factory=CheckOptions)
    raw_expect: dict | None = None            # the sections as written (re-validated by load.with_overrides)
    raw_check: dict | None = None

    def __bool__(self) -> bool:
        return bool(self.items)

    def raw(self) -> dict:
        out = {}
        if self.raw_expect is not None:
            out["expect"] = dict(self.raw_expect)
        if self.raw_check is not None:
            out["check"] = dict(self.raw_check)
        return out


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, str):
        return repr(v)
    return str(v)


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


# --------------------------------------------------------------------------------------------------
# Frequencies and windows
# --------------------------------------------------------------------------------------------------

_TERM_RE = re.compile(r"\s*([+-])?\s*(?:(\d+(?:\.\d*)?(?:[eE][-+]?\d+)?|\.\d+)\s*(\*)?\s*)?(f_[A-Za-z]+)?\s*(Hz)?\s*")


def parse_frequency(expr: str) -> list[tuple[float, str | None]]:
    """'f_GMF-2*f_MSH' -> [(1, 'f_GMF'), (-2, 'f_MSH')]; numbers are Hz (name None). ValueError if malformed."""
    if not isinstance(expr, str) or not expr.strip():
        raise ValueError("an empty frequency")
    terms, pos, first = [], 0, True
    s = expr.strip()
    while pos < len(s):
        m = _TERM_RE.match(s, pos)
        if not m or m.end() == pos:
            raise ValueError(f"cannot read {s[pos:]!r}")
        sign, num, star, name, hz = m.groups()
        if not first and not sign:
            raise ValueError(f"expected + or - before {s[m.start():].strip()!r}")
        if name is None and num is None:
            raise ValueError(f"a term without a number or a name at {s[pos:]!r}")
        if name is not None and name not in FREQ_NAMES:
            raise ValueError(f"unknown frequency {name!r} (known: {', '.join(FREQ_NAMES)})")
        if name is not None and num is not None and not star:
            raise ValueError(f"write a factor as k*{name}")
        if name is None and star:
            raise ValueError(f"a factor without a frequency name at {s[pos:]!r}")
        if name is not None and hz:
            raise ValueError(f"'Hz' after {name}")
        k = float(num) if num is not None else 1.0
        terms.append((-k if sign == "-" else k, name))
        pos, first = m.end(), False
    return terms


def frequency_value(expr: str, freqs: dict) -> float:
    """The value [Hz] of a frequency expression, with ``freqs`` = {f_DSH: ..., f_MSH: ..., ...}."""
    return float(sum(k * (freqs[name] if name else 1.0) for k, name in parse_frequency(expr)))


_WINDOW_RE = re.compile(r"^(.*)\[\s*([^\[\]:]*)\s*:\s*([^\[\]:]*)\s*\]$")


def _split_window(text: str):
    """'propeller_shaft_torque[2.5:4]' -> ('propeller_shaft_torque', (2.5, 4.0)); no window -> (text, None)."""
    m = _WINDOW_RE.match(text)
    if not m:
        return text, None
    name, a, b = m.group(1), m.group(2).strip(), m.group(3).strip()
    try:
        t0 = float(a) if a else None
        t1 = float(b) if b else None
    except ValueError:
        raise ValueError(f"a time window [t0:t1] in s (got [{a}:{b}])") from None
    return name, (t0, t1)


def window_mask(time: np.ndarray, window, settle_s: float) -> np.ndarray:
    t0 = settle_s if window is None or window[0] is None else window[0]
    t1 = None if window is None else window[1]
    m = time >= t0 - 1e-12
    if t1 is not None:
        m &= time <= t1 + 1e-12
    return m


def is_slow(scene) -> bool:
    """The pytest ``slow`` marker of a scene: ``[check] slow`` if given, else the duration rule
    (simulated time > 5 s, or > 0.1 s with online PCM contact)."""
    opt = scene.expect.options if getattr(scene, "expect", None) is not None else CheckOptions()
    if opt.slow is not None:
        return opt.slow
    limit = SLOW_DURATION_PCM_S if scene.effects.mesh_contact == "pcm" else SLOW_DURATION_S
    return scene.time.duration_s > limit


# --------------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------------


def _known_children(node, torque: tuple, channels: tuple) -> list[str]:
    out = []
    for k in node:
        if k == "<torque>":
            out += list(torque)
        elif k == "<channel>":
            out += list(channels)
        elif k == "<i>":
            out.append("0")
        else:
            out.append(k)
    return out


def _summary_leaf(path: list[str], torque: tuple, channels: tuple):
    """(leaf type, parsed path) or raise ValueError(message) for an unknown path."""
    node: Any = SUMMARY_TREE
    parsed: list = []
    for i, part in enumerate(path):
        if node == "any":
            parsed.append(int(part) if part.isdigit() else part)
            continue
        if not isinstance(node, dict):
            raise ValueError(f"{'.'.join(path[:i])} is a {node}, it has no key {part!r}")
        if part in node:
            node = node[part]
            parsed.append(part)
        elif "<torque>" in node and part in torque:
            node = node["<torque>"]
            parsed.append(part)
        elif "<channel>" in node and part in channels:
            node = node["<channel>"]
            parsed.append(part)
        elif "<i>" in node and part.isdigit():
            node = node["<i>"]
            parsed.append(int(part))
        else:
            known = _known_children(node, torque, channels)
            where = ".".join(path[:i]) or "summary.json"
            if "<torque>" in node:
                what = "a torque sensor"
            elif "<channel>" in node:
                what = "a rig sensor or a variable of outputs.variables"
            elif "<i>" in node:
                what = "a list index"
            else:
                what = "a known key"
            close = difflib.get_close_matches(part, known, n=1, cutoff=0.5)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"a known metric path: {where} has no {part!r} ({what}: "
                             f"{', '.join(known[:12])}{', ...' if len(known) > 12 else ''}){hint}")
    if isinstance(node, dict):
        raise ValueError(f"a path to a single value: {'.'.join(path)} is a table (keys: "
                         f"{', '.join(_known_children(node, torque, channels)[:12])})")
    return node, tuple(parsed)


def parse_key(key: str, *, variables=()) -> dict:
    """Parse a metric key into the fields of :class:`Expectation` (kind, path, channel, stat, freq,
    level, window) and its leaf type. ValueError(expected) when the key is not a known metric. Channels:
    the rig's sensors and the scene's ``outputs.variables``."""

    sensors = tuple(RIG_SENSORS)
    channels = sensors + tuple(v for v in variables if v not in sensors)
    torque = tuple(TORQUE_SENSORS)
    if not isinstance(key, str) or not key:
        raise ValueError("a metric key")
    if key.startswith("spectrum."):
        body = key[len("spectrum."):]
        if "@" not in body:
            raise ValueError("spectrum.<channel>[t0:t1]@<frequency>[.amplitude|.dB|.dB_re_GMF], e.g. "
                             "spectrum.propeller_shaft_torque@f_GMF-f_MSH")
        chan, _, fexpr = body.partition("@")
        level = "amplitude"
        for lv in SPECTRUM_LEVELS:
            if fexpr.endswith("." + lv):
                fexpr, level = fexpr[: -len(lv) - 1], lv
                break
        chan, window = _split_window(chan)
        if chan not in channels:
            raise ValueError(f"a channel: a rig sensor or a variable of outputs.variables: "
                             f"{', '.join(channels)} (got {chan!r})")
        try:
            parse_frequency(fexpr)
        except ValueError as exc:
            raise ValueError(f"a frequency like f_GMF, 2*f_GMF, f_GMF-f_MSH or 37.5 (Hz), then optionally "
                             f".amplitude, .dB or .dB_re_GMF ({exc})") from None
        return {"kind": "spectrum", "channel": chan, "freq": fexpr.strip(), "level": level, "window": window,
                "type": "num"}
    if key.startswith("signal."):
        body = key[len("signal."):]
        head, dot, stat = body.rpartition(".")
        if not dot or stat not in SIGNAL_STATS:
            raise ValueError(f"signal.<channel>[t0:t1].<stat> with stat one of {', '.join(SIGNAL_STATS)}")
        chan, window = _split_window(head)
        if chan not in channels:
            raise ValueError(f"a channel: a rig sensor or a variable of outputs.variables: "
                             f"{', '.join(channels)} (got {chan!r})")
        return {"kind": "signal", "channel": chan, "stat": stat, "window": window, "type": "num"}
    parts = key.split(".")
    if any(not p for p in parts):
        raise ValueError("a dotted path into summary.json, e.g. torque.propeller_shaft_torque.mean")
    leaf, path = _summary_leaf(parts, torque, channels)
    return {"kind": "summary", "path": path, "type": leaf}


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _measured_value(column: str, op: dict) -> tuple[float, str]:
    """The measured table's ``column`` at the operating point (constant load setting, final speed)."""

    data = read_measured()
    if column not in data:
        raise ValueError(f"a column of the measured table ({', '.join(k for k in data if k != 'T_load_Nm')})")
    if op.get("load_profile_Nm"):
        raise ValueError("a scene with a constant load (the measured table has no load profiles)")
    speed = op["speed_profile_rpm"][-1][1] if op.get("speed_profile_rpm") else op["drive_speed_rpm"]
    load = op["load_torque_Nm"]
    hit = [i for i in range(len(data["T_load_Nm"]))
           if abs(data["T_load_Nm"][i] - load) <= 1e-6 * max(1.0, abs(load))
           and abs(data["n_DSH_rpm"][i] - speed) <= 0.01 * max(speed, 1e-9)]
    if not hit:
        pts = sorted({(float(n), float(t)) for n, t in zip(data["n_DSH_rpm"], data["T_load_Nm"])})
        raise ValueError(f"an operating point of the measured table (this scene: {speed:g} rpm, {load:g} N·m; "
                         f"the table has {len(pts)} points, speeds "
                         f"{', '.join(f'{n:.0f}' for n in sorted({p[0] for p in pts}))} rpm within 1 %, loads "
                         f"{', '.join(f'{t:g}' for t in sorted({p[1] for p in pts}))} N·m)")
    i = hit[0]
    return float(data[column][i]), f"measured {column} at {data['n_DSH_rpm'][i]:g} rpm, {data['T_load_Nm'][i]:g} N·m"


def parse_spec(key: str, spec, leaf: str, problems: list, op: dict | None = None,
               strict: bool = True) -> dict | None:
    """The tolerance fields of one entry (value/rel/abs/min/max/ref) or None (problem recorded).
    ``op``: the operating point for ``measured``; a point the table does not have is a problem when
    ``strict``, else the expectation gets value NaN (it fails when checked, with the reason in ``ref``)."""
    name = f'expect."{key}"'
    if isinstance(spec, (str, bool)):
        spec = {"value": spec}
    if not isinstance(spec, dict):
        problems.append((name, spec, "a tolerance spec { value = x, rel = r } / { value = x, abs = a } or a "
                                     "range { min = a, max = b } (a plain value only for strings and booleans)"))
        return None
    bad = [k for k in spec if k not in SPEC_KEYS]
    if bad:
        close = difflib.get_close_matches(bad[0], SPEC_KEYS, n=1, cutoff=0.5)
        problems.append((name, spec, f"tolerance keys from {', '.join(SPEC_KEYS)} (unknown: {', '.join(bad)})"
                         + (f"; did you mean {close[0]!r}?" if close else "")))
        return None
    out: dict = {}
    n0 = len(problems)
    for k in ("rel", "abs", "min", "max"):
        if k in spec:
            v = spec[k]
            if not _number(v):
                problems.append((name, spec, f"{k} = a finite number (got {v!r})"))
            elif k in ("rel", "abs") and v < 0:
                problems.append((name, spec, f"{k} >= 0 (got {v!r})"))
            else:
                out[k] = float(v)
    if "value" in spec and "measured" in spec:
        problems.append((name, spec, "either value or measured, not both"))
    value = spec.get("value")
    if "measured" in spec:
        if not isinstance(spec["measured"], str):
            problems.append((name, spec, "measured = the name of a column of the measured table, e.g. \"T_PSH_Nm\""))
        elif op is not None:
            try:
                value, out["ref"] = _measured_value(spec["measured"], op)
            except ValueError as exc:
                if strict or str(exc).startswith("a column"):
                    problems.append((name, spec, f"measured = {spec['measured']!r}: {exc}"))
                else:
                    value, out["ref"] = float("nan"), f"no measured {spec['measured']}: expected {exc}"
            except Exception as exc:  # noqa: BLE001 - the table could not be read
                problems.append((name, spec, f"a readable measured table ({type(exc).__name__}: {exc})"))
        else:
            value = 0.0            # validated later with the operating point
    has_value = value is not None
    has_range = "min" in out or "max" in out or "min" in spec or "max" in spec
    has_tol = "rel" in spec or "abs" in spec
    if len(problems) > n0:
        return None
    if has_value and has_range:
        problems.append((name, spec, "either value (with rel/abs) or a range (min/max), not both"))
        return None
    if not has_value and not has_range:
        problems.append((name, spec, "value = x with rel/abs, or min and/or max"))
        return None
    if has_range and has_tol:
        problems.append((name, spec, "rel/abs only with value (a range has its own limits)"))
        return None
    if has_range:
        if leaf in ("str", "bool"):
            plain = '"..."' if leaf == "str" else "true or false"
            problems.append((name, spec, f"a {'string' if leaf == 'str' else 'boolean'}: \"{key}\" = "
                                         f"{plain} (no range)"))
            return None
        if "min" in out and "max" in out and out["min"] > out["max"]:
            problems.append((name, spec, f"min <= max (min {out['min']:g} > max {out['max']:g})"))
            return None
        return out
    if isinstance(value, (str, bool)):
        if has_tol:
            problems.append((name, spec, "rel/abs only for numbers"))
            return None
        if leaf == "num" or leaf == "int":
            problems.append((name, spec, f"a number with rel/abs or a range: {key} is numeric"))
            return None
        if leaf == "bool" and not isinstance(value, bool):
            problems.append((name, spec, f"true or false: {key} is a boolean"))
            return None
        if leaf == "str" and not isinstance(value, str):
            problems.append((name, spec, f"a string: {key} is a string"))
            return None
        out["value"] = value
        return out
    if not _number(value) and not (out.get("ref") and isinstance(value, float)):
        problems.append((name, spec, f"value = a finite number, string or boolean (got {value!r})"))
        return None
    if leaf in ("str", "bool"):
        problems.append((name, spec, f"a {'string' if leaf == 'str' else 'boolean'} value: {key} is not a number"))
        return None
    if not has_tol:
        problems.append((name, spec, "a tolerance with the value: rel = r (relative) and/or abs = a "
                                     f"(e.g. {{ value = {value!r}, rel = 0.01 }}), or a range min/max"))
        return None
    out["value"] = float(value)
    return out


CHECK_KEYS = {
    "slow": "true or false (default: simulated time > 5 s, or > 0.1 s with pcm contact)",
    "baseline": "a baseline file path (.h5), relative to the scene file",
    "baseline_rel": "a relative tolerance > 0 for summary metrics against the baseline",
    "baseline_signal_rel": "a tolerance > 0 for the RMS difference of a signal relative to its RMS",
    "baseline_dB": "a tolerance > 0 in dB for spectral levels against the baseline",
    "baseline_signals": "a list of channels the scene writes",
}


def parse_check_options(raw, base_dir: Path, channels: tuple, problems: list) -> CheckOptions:
    if raw is None:
        return CheckOptions()
    if not isinstance(raw, dict):
        problems.append(("check", raw, "a table [check]"))
        return CheckOptions()
    kw: dict = {}
    for k, v in raw.items():
        name = f"check.{k}"
        if k not in CHECK_KEYS:
            close = difflib.get_close_matches(k, list(CHECK_KEYS), n=1, cutoff=0.5)
            problems.append((name, v, "a known key of [check]: " + ", ".join(CHECK_KEYS)
                             + (f"; did you mean {close[0]!r}?" if close else "")))
        elif k == "slow":
            if not isinstance(v, bool):
                problems.append((name, v, CHECK_KEYS[k]))
            else:
                kw[k] = v
        elif k == "baseline":
            if not isinstance(v, str) or not v or "\x00" in v:
                problems.append((name, v, CHECK_KEYS[k]))
            else:
                p = Path(v).expanduser()
                kw[k] = p if p.is_absolute() else (base_dir / p).resolve()
        elif k == "baseline_signals":
            if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
                problems.append((name, v, CHECK_KEYS[k]))
            elif [x for x in v if x not in channels]:
                problems.append((name, v, f"channels the scene writes: {', '.join(channels)} "
                                          f"(unknown: {', '.join(x for x in v if x not in channels)})"))
            else:
                kw[k] = tuple(v)
        else:
            if not _number(v) or v <= 0:
                problems.append((name, v, CHECK_KEYS[k]))
            else:
                kw[k] = float(v)
    return CheckOptions(**kw)


def parse_checks(raw_expect, raw_check, values: dict, base_dir: Path | str, problems: list,
                 strict: bool = True) -> ExpectSpec:
    """Validate the ``[expect]`` and ``[check]`` sections against the resolved sections ``values``
    (scenario.resolve's per-section dicts). Problems are appended as (key, value, expected).

    What depends on the rest of the scene (a window within time.duration_s, a frequency below Nyquist,
    an operating point of the measured table) is refused only when ``strict`` (the scene as written);
    with ``--set`` overrides it is left to the check, where it fails with the reason, so that an
    override never makes a scene unrunnable because of its expectations."""
    base_dir = Path(base_dir)
    outputs = values.get("outputs", {})

    variables = outputs.get("variables") if isinstance(outputs.get("variables"), (tuple, list)) else ()
    channels = tuple(RIG_SENSORS) + tuple(v for v in variables if v not in RIG_SENSORS)
    op = values.get("operating_point", {})
    profile = op.get("speed_profile_rpm")
    # the operating point as far as it is valid (a bad value is reported by its own section's check)
    profile_ok = not profile or (isinstance(profile, (list, tuple)) and all(
        isinstance(p, (list, tuple)) and len(p) == 2 and all(_number(x) for x in p) for p in profile))
    op_ok = profile_ok and all(_number(op.get(k)) for k in ("drive_speed_rpm", "load_torque_Nm"))
    tm = values.get("time", {})
    duration = tm.get("duration_s") if isinstance(tm.get("duration_s"), (int, float)) else None
    fs = tm.get("sample_rate_Hz") if isinstance(tm.get("sample_rate_Hz"), (int, float)) else None
    options = parse_check_options(raw_check, base_dir, channels, problems)
    items = []
    if raw_expect is not None and not isinstance(raw_expect, dict):
        problems.append(("expect", raw_expect, 'a table [expect] of "metric" = { value = x, rel = r } entries'))
        raw_expect = None
    for key, spec in (raw_expect or {}).items():
        name = f'expect."{key}"'
        try:
            parsed = parse_key(key, variables=variables)
        except ValueError as exc:
            problems.append((name, spec, str(exc)))
            continue
        leaf = parsed.pop("type")
        if leaf == "any":
            leaf = "num" if isinstance(spec, dict) and any(k in spec for k in ("rel", "abs", "min", "max")) else "str"
        win = parsed.get("window")
        if win is not None:
            t0, t1 = win
            beyond = strict and duration is not None and (
                (t1 is not None and t1 > duration + 1e-9) or (t0 is not None and t0 >= duration))
            if (t0 is not None and t0 < 0) or (t0 is not None and t1 is not None and t1 <= t0) or beyond:
                problems.append((name, spec, f"a time window [t0:t1] in s with 0 <= t0 < t1"
                                             f"{f' <= time.duration_s = {duration:g} s' if duration is not None else ''}"))
                continue
        if parsed["kind"] == "spectrum" and op_ok and fs and strict:
            from drivetrain.rig.signals import characteristic_frequencies

            speed = op["speed_profile_rpm"][-1][1] if op.get("speed_profile_rpm") else op["drive_speed_rpm"]
            pair = (values.get("gear") or {}).get("pair")
            pair = pair.params() if hasattr(pair, "params") else RIG_PAIR.params()     # [gear.pair]'s teeth
            f0 = frequency_value(parsed["freq"], characteristic_frequencies(speed, pair.z_pinion, pair.z_wheel))
            if not (0.0 < f0 < 0.5 * fs):
                problems.append((name, spec, f"a frequency between 0 and the Nyquist frequency {0.5 * fs:g} Hz "
                                             f"({parsed['freq']} = {f0:g} Hz at {speed:g} rpm)"))
                continue
        tol = parse_spec(key, spec, leaf, problems, op=op if op_ok else None, strict=strict)
        if tol is None:
            continue
        items.append(Expectation(key=key, **parsed, **tol))
    return ExpectSpec(items=tuple(items), options=options,
                      raw_expect=dict(raw_expect) if raw_expect is not None else None,
                      raw_check=dict(raw_check) if isinstance(raw_check, dict) else None)


def _grid_tables(grid_expect, problems: list) -> dict:
    if not isinstance(grid_expect, dict):
        problems.append(("sweep.expect", grid_expect, 'a table of [sweep.expect."<case name pattern>"] tables'))
        return {}
    good = {}
    for pat, tbl in grid_expect.items():
        if not isinstance(tbl, dict):
            problems.append((f'sweep.expect."{pat}"', tbl, 'a table of "metric" = { ... } entries for the cases '
                                                          "whose name matches the pattern (fnmatch: * ? [...])"))
        else:
            good[pat] = tbl
    return good


def case_expectations(grid_expect, case_name: str, problems: list) -> dict:
    """The ``[sweep.expect."<pattern>"]`` entries of a grid file that apply to one case (fnmatch on the
    case name; later tables override earlier ones for the same metric). Raw entries (validated by
    :func:`parse_checks` with the case's other sections)."""
    import fnmatch

    out: dict = {}
    for pat, tbl in _grid_tables(grid_expect, problems).items():
        if fnmatch.fnmatchcase(case_name, pat):
            out.update(tbl)
    return out


def unmatched_case_patterns(grid_expect, names) -> list:
    """Problems for ``[sweep.expect."<pattern>"]`` tables that match no case (a typo would check nothing)."""
    import fnmatch

    probs: list = []
    names = list(names)
    for pat, tbl in _grid_tables(grid_expect, []).items():
        if not any(fnmatch.fnmatchcase(n, pat) for n in names):
            probs.append((f'sweep.expect."{pat}"', "{...}", f"a case name pattern that matches at least one case "
                                                          f"(e.g. {names[0] if names else '?'!r})"))
    return probs


# --------------------------------------------------------------------------------------------------
# Evaluation
# --------------------------------------------------------------------------------------------------


@dataclass
class Outcome:
    """One checked quantity of one run."""

    scene: str                     # the scene (case) name
    key: str                       # metric key (as in [expect], or the baseline's name for it)
    source: str                    # "expect" | "baseline" | "run"
    ok: bool
    expected: str                  # expected value or range, as text
    actual: Any                    # the value found (None: missing)
    tolerance: str                 # tolerance, as text
    deviation: str = ""            # actual - expected (absolute and relative), as text
    note: str = ""
    channel: str | None = None     # the signal concerned (plots)

    @property
    def message(self) -> str:
        act = "missing" if self.actual is None else _fmt(self.actual)
        s = (f"{self.scene}: {self.key}: expected {self.expected}, actual {act}, tolerance {self.tolerance}"
             f"{f', deviation {self.deviation}' if self.deviation else ''}")
        return s + (f" ({self.note})" if self.note else "")


def summary_value(summary: dict, path: tuple):
    node: Any = summary
    for p in path:
        if isinstance(node, dict) and p in node:
            node = node[p]
        elif isinstance(node, list) and isinstance(p, int) and -len(node) <= p < len(node):
            node = node[p]
        else:
            return None
    return node


def signal_stat(x: np.ndarray, stat: str) -> float:
    x = np.asarray(x, dtype=float)
    if stat == "mean":
        return float(np.mean(x))
    if stat == "rms":
        return float(np.sqrt(np.mean(x * x)))
    if stat == "std":
        return float(np.std(x))
    if stat == "p2p":
        return float(np.max(x) - np.min(x))
    if stat == "min":
        return float(np.min(x))
    if stat == "max":
        return float(np.max(x))
    raise ValueError(stat)


def spectrum_levels(x: np.ndarray, fs: float, freqs: dict, exprs, bins: int = SPECTRUM_BINS) -> dict:
    """{expr: amplitude} at frequency expressions, from the Hann-window amplitude spectrum after the
    low-pass at 5 × f_GMF (drivetrain.rig.signals.amplitude_spectrum), largest within ±bins bins."""

    f, A = amplitude_spectrum(np.asarray(x, dtype=float), fs,
                              lowpass_Hz=spectrum_lowpass_Hz(freqs["f_GMF"]) if freqs.get("f_GMF", 0) > 0 else None)
    return {e: amplitude_near(f, A, frequency_value(e, freqs), bins=bins) for e in exprs}


def freqs_of(summary: dict) -> dict:
    return {k: float(summary[k]) for k in FREQ_NAMES if summary.get(k) is not None}


def metric_value(e: Expectation, summary: dict, time: np.ndarray | None, signals: dict | None):
    """The actual value of an expectation's metric in a run (None if the run does not have it), and a note."""
    if e.kind == "summary":
        return summary_value(summary, e.path), ""
    if time is None or signals is None or e.channel not in signals:
        return None, f"channel {e.channel!r} not in the run's signals"
    m = window_mask(np.asarray(time), e.window, float(summary.get("settle_s") or 0.0))
    x = np.asarray(signals[e.channel])[: len(m)][m[: len(signals[e.channel])]]
    if len(x) == 0:
        return None, "no samples in the window"
    if e.kind == "signal":
        return signal_stat(x, e.stat), ""
    fs = float(summary["sample_rate_Hz"])
    fr = freqs_of(summary)
    try:
        lv = spectrum_levels(x, fs, fr, [e.freq, "f_GMF"])
    except ValueError as exc:           # too short for the low-pass
        return None, f"no spectrum: {exc}"
    a = lv[e.freq]
    if e.level == "amplitude":
        return a, ""
    if e.level == "dB":
        return float(20.0 * math.log10(max(a, 1e-300))), ""
    g = lv["f_GMF"]
    return float(20.0 * math.log10(max(a, 1e-300) / max(g, 1e-300))), ""


def _deviation(e: Expectation, actual) -> str:
    if not _is_number(actual) or e.value is None or not e.numeric:
        if _is_number(actual) and e.value is None:
            a = float(actual)
            if e.min is not None and a < e.min:
                return f"{a - e.min:+.4g} below min"
            if e.max is not None and a > e.max:
                return f"{a - e.max:+.4g} above max"
        return ""
    if not math.isfinite(e.value):
        return ""
    d = float(actual) - e.value
    rel = f" ({100 * d / abs(e.value):+.3g} %)" if e.value != 0 else ""
    return f"{d:+.4g}{rel}"


def evaluate(spec: ExpectSpec | tuple, summary: dict, time: np.ndarray | None = None,
             signals: dict | None = None, scene_name: str | None = None) -> list[Outcome]:
    """Evaluate every expectation on a run. A run whose status is not "ok" fails an implicit
    ``status = "ok"`` check unless the scene's [expect] says something about ``status``."""
    items = spec.items if isinstance(spec, ExpectSpec) else tuple(spec)
    name = scene_name or summary.get("name", "?")
    out = []
    if not any(e.kind == "summary" and e.path == ("status",) for e in items):
        st = summary.get("status", "ok")
        if st != "ok":
            f = summary.get("failure") or {}
            out.append(Outcome(name, "status", "run", False, "'ok'", st, "exact",
                               note=f"failed at t = {f.get('time_s')} s in {f.get('component')}: {f.get('cause')}"))
    for e in items:
        try:
            actual, note = metric_value(e, summary, time, signals)
        except Exception as exc:  # noqa: BLE001 - a metric that cannot be computed fails, with the reason
            actual, note = None, f"{type(exc).__name__}: {exc}"
        if isinstance(actual, (np.floating, np.integer)):
            actual = actual.item()
        ok = actual is not None and e.check(actual)
        if e.value is not None and e.numeric and math.isnan(e.value):
            note = e.ref or note
        out.append(Outcome(name, e.key, "expect", ok, e.expected_text(), actual, e.tolerance_text(),
                           _deviation(e, actual), note, channel=_channel_of(e)))
    return out


def _channel_of(e: Expectation) -> str | None:
    if e.channel:
        return e.channel
    if e.kind == "summary" and len(e.path) >= 2 and e.path[0] in ("torque", "channels", "spectrum_peaks"):
        return str(e.path[1])
    return None


__all__ = ["Expectation", "ExpectSpec", "CheckOptions", "Outcome", "SUMMARY_TREE", "RUN_SUMMARY_TREE",
           "WRITE_SUMMARY_TREE", "summary_mismatch", "SIGNAL_STATS",
           "SPECTRUM_LEVELS", "FREQ_NAMES", "parse_checks", "parse_key", "parse_spec", "parse_frequency",
           "frequency_value", "evaluate", "metric_value", "summary_value", "signal_stat", "spectrum_levels",
           "window_mask", "is_slow", "freqs_of"]
