"""Scene files: validation, ``--set`` overrides, loading -> the resolved ``Scene``.

Loading is all-or-nothing: every problem (unknown key, wrong type or unit, impossible value, inconsistent
combination, missing mesh file) is collected and raised as one :class:`ScenarioError` that names the key,
the value and what was expected, before anything runs. The keys are declared in
:mod:`drivetrain.scene.schema` (re-exported here), grids expanded by :mod:`drivetrain.scene.grid`.
"""
from __future__ import annotations

import copy
import difflib
import math
import re
import sys
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from drivetrain.errors import MISSING as _MISSING
from drivetrain.errors import ScenarioError
from drivetrain.scene.grid import (GRID_SECTION, apply_grid_overrides, expand, override_value, refuse_swept_overrides,
                                   split_grid)
from drivetrain.scene.schema import (BASE_UNIT, CHECK_SECTIONS, NAME_RE, NAME_RULE, SCHEMA, SECTION_CLASSES,  # noqa: F401
                                     UNITS, VAR_RE, Key, Scene, all_keys, default_of, dump_toml, schema_markdown)
from drivetrain.scene.schema import PAIR_SCHEMA, RIG_PAIR, GearPair
from drivetrain.scene.schema import (FIDELITIES, HEALTH_STATES, SHAFT_MODELS,  # noqa: F401  (re-exported)
                                     EffectsSpec, GearSpec, NumericsSpec, OperatingPoint, OutputSpec, ScenarioInfo,
                                     TimeSpec)
from drivetrain.system import steps_per_output
from gearcontact_fmu.fault_specs import health_problems, normalised_spec
from gearcontact_fmu.mesh_models.base import fidelities_with, supports
from gearcontact_fmu.pair_check import pair_problems

# --------------------------------------------------------------------------------------------------
# Value checking
# --------------------------------------------------------------------------------------------------


def _parse_quantity(key: str, spec: Key, value: str, problems) -> float | None:
    """'500 ms' -> 0.5 for a key in s. Returns None (and records a problem) when refused."""
    m = re.fullmatch(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([^\s\d].*?)?\s*", value)
    expected = f"a number in {spec.unit}" + (
        f" (or a string \"<number> <unit>\" with a {spec.dimension} unit)" if spec.dimension else "")
    if not m:
        problems.append((key, value, expected))
        return None
    number = float(m.group(1))
    unit = (m.group(2) or "").strip()
    if not unit:
        return number
    if unit not in UNITS:
        problems.append((key, value, f"{expected}; unknown unit {unit!r}"))
        return None
    dim, factor = UNITS[unit]
    if spec.dimension == "speed" and unit == "Hz":      # a rotation frequency: revolutions per second
        dim, factor = "speed", 60.0
    if dim != spec.dimension:
        problems.append((key, value, f"a {spec.dimension} in {spec.unit} (got a {dim} unit {unit!r}; "
                                     f"e.g. {BASE_UNIT.get(spec.dimension, spec.unit)})"))
        return None
    # to the key's own unit (a key in um takes "0.01 mm" as 10)
    key_factor = UNITS[spec.unit][1] if spec.unit in UNITS and UNITS[spec.unit][0] == dim else 1.0
    return number * factor / key_factor


def _check_range(key: str, spec: Key, value: float, problems, what: str = "") -> bool:
    ok = math.isfinite(value)
    if ok and spec.minimum is not None:
        ok = value > spec.minimum if spec.min_exclusive else value >= spec.minimum
    if ok and spec.maximum is not None:
        ok = value <= spec.maximum
    if not ok:
        rng = []
        if spec.minimum is not None:
            rng.append(f"{'>' if spec.min_exclusive else '>='} {spec.minimum:g}")
        if spec.maximum is not None:
            rng.append(f"<= {spec.maximum:g}")
        u = f" {spec.unit}" if spec.unit else ""
        problems.append((key, value, f"{what}a finite {spec.type} {' and '.join(rng)}{u}".strip()))
    return ok


def _check_value(key: str, spec: Key, value: Any, base_dir: Path, problems) -> Any:
    t = spec.type
    if t == "float":
        if isinstance(value, bool):
            problems.append((key, value, f"a number in {spec.unit or '1'} (not a boolean)"))
            return None
        if isinstance(value, str) and spec.dimension:
            value = _parse_quantity(key, spec, value, problems)
            if value is None:
                return None
        if not isinstance(value, (int, float)):
            problems.append((key, value, f"a number in {spec.unit}" if spec.unit else "a number"))
            return None
        value = float(value)
        return value if _check_range(key, spec, value, problems) else None
    if t == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            problems.append((key, value, "an integer" + (f" >= {spec.minimum:g}" if spec.minimum is not None else "")))
            return None
        return value if _check_range(key, spec, float(value), problems, "") else None
    if t == "bool":
        if not isinstance(value, bool):
            problems.append((key, value, "true or false"))
            return None
        return value
    if t == "str":
        if not isinstance(value, str):
            problems.append((key, value, "a string"))
            return None
        return value
    if t == "enum":
        if not isinstance(value, str) or value not in spec.allowed:
            problems.append((key, value, "one of " + ", ".join(repr(a) for a in spec.allowed)))
            return None
        return value
    if t == "path":
        p = _file_path(key, value, base_dir, problems, "a file path")
        if p is None:
            return None
        if p.suffix.lower() not in (".obj", ".stl"):
            problems.append((key, value, "an .obj or .stl mesh file"))
            return None
        if not p.is_file():
            problems.append((key, value, f"an existing mesh file (not found: {p})"))
            return None
        return p
    if t == "series":                   # a CSV file of time and the key's quantity, read now (scene.series)
        from drivetrain.scene.series import SeriesError, read_series

        p = _file_path(key, value, base_dir, problems, "a CSV file path")
        if p is None:
            return None
        try:
            ts, vs = read_series(p, spec.dimension, spec.dimension)
        except SeriesError as exc:
            problems += [(key, value, f"a time/{spec.dimension} series file; {p}: {pr}") for pr in exc.problems]
            return None
        return _Series(p, tuple(zip(ts.tolist(), vs.tolist())))
    if t == "table":                    # a lumped torsional model ([drivetrain] parameters), read and checked now
        return _check_table(key, value, base_dir, problems)
    if t == "pair":                     # [gear.pair]: its own keys (PAIR_SCHEMA); whether it can be made: _check_pair
        return _check_pair_table(key, value, base_dir, problems)
    if t == "faults":                   # each specification: checked with the health (_check_gear)
        if not isinstance(value, list):
            problems.append((key, value, "an array of tables [[gear.faults]]"))
            return None
        return tuple(value)
    if t == "profile":
        exp = (f"a list of [time_s, {spec.unit}] pairs with times >= 0 strictly increasing and "
               + (f"values >= {spec.minimum:g} {spec.unit}" if spec.minimum is not None else "finite values"))
        if not isinstance(value, list) or not value:
            problems.append((key, value, exp))
            return None
        pts = []
        for p in value:
            if (not isinstance(p, list) or len(p) != 2
                    or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in p)
                    or not all(math.isfinite(x) for x in p)):
                problems.append((key, value, exp))
                return None
            pts.append((float(p[0]), float(p[1])))
        ts = [p[0] for p in pts]
        if ts[0] < 0 or any(b <= a for a, b in zip(ts, ts[1:])) or any(
                spec.minimum is not None and p[1] < spec.minimum for p in pts):
            problems.append((key, value, exp))
            return None
        return tuple(pts)
    if t == "str_list":
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            problems.append((key, value, "a list of strings from " + ", ".join(spec.allowed)))
            return None
        bad = [v for v in value if v not in spec.allowed]
        if bad:
            problems.append((key, value, f"names from {', '.join(spec.allowed)} (unknown: {', '.join(bad)})"))
            return None
        if len(set(value)) != len(value):
            problems.append((key, value, "a list without duplicates"))
            return None
        return tuple(value)
    if t == "var_list":
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            problems.append((key, value, 'a list of "component.variable" strings'))
            return None
        bad = [v for v in value if not VAR_RE.match(v)]
        if bad:
            problems.append((key, value, f'"component.variable" strings (malformed: {", ".join(bad)})'))
            return None
        if len(set(value)) != len(value):
            problems.append((key, value, "a list without duplicates"))
            return None
        return tuple(value)
    raise AssertionError(t)  # pragma: no cover


def _file_path(key: str, value: Any, base_dir: Path, problems, what: str) -> Path | None:
    """A file a scene key names: a non-empty string without NUL characters, ``~`` expanded, relative to the
    scene's folder; None (and the problem, ``what`` saying what was expected) otherwise."""
    if not isinstance(value, str) or not value or "\x00" in value:
        problems.append((key, value, f"{what} (a non-empty string without NUL characters)"))
        return None
    p = Path(value).expanduser()
    return p if p.is_absolute() else (base_dir / p).resolve()


def _check_table(key: str, value: Any, base_dir: Path, problems) -> Path | None:
    """A lumped parameter table (rig.lumped_table's layout): its path, read through the checked reader; every
    problem named with the file (whether it maps onto the FMUs with the scene's pair: :func:`_check_machine`)."""
    from drivetrain.errors import FileFormatError
    from drivetrain.rig.data import load_public

    p = _file_path(key, value, base_dir, problems, "a CSV file path")
    if p is None:
        return None
    try:
        load_public(p)
    except FileFormatError as exc:
        problems += [(key, value, f"a lumped parameter table; {pr if str(p) in pr else f'{p}: {pr}'}")
                     for pr in exc.problems]
        return None
    return p


def _check_machine(values: dict, problems) -> None:
    """A named lumped table maps onto the FMUs (rig.data.layout_problems) with the scene's pair: its bevel mesh
    element at the pair's z1/z2."""
    from drivetrain.rig.data import layout_problems, load_public

    table = values["drivetrain"].get("parameters")
    if table in (None, _MISSING) or not _ok(values, "gear", "pair"):
        return
    for why in layout_problems(load_public(table), values["gear"]["pair"].params().ratio):
        problems.append(("drivetrain.parameters", str(table), f"a lumped parameter table the run can map; {table}: {why}"))


def _check_pair_table(key: str, value: Any, base_dir: Path, problems) -> GearPair | None:
    """A ``[gear.pair]`` table: every key known and checked like any scene key; absent keys at the rig's values.
    None (and the problems recorded) when any is refused."""
    if not isinstance(value, dict):
        problems.append((key, value, "a table [gear.pair] of gear data (" + ", ".join(PAIR_SCHEMA) + ")"))
        return None
    given, n = {}, len(problems)
    for k, v in value.items():
        if k not in PAIR_SCHEMA:
            problems.append((f"{key}.{k}", v, "a known key of [gear.pair]: " + ", ".join(PAIR_SCHEMA)
                             + (_unit_hint_in(PAIR_SCHEMA, k) or _suggest(k, PAIR_SCHEMA))))
            continue
        given[k] = _check_value(f"{key}.{k}", PAIR_SCHEMA[k], v, base_dir, problems)
    return GearPair.of(given) if len(problems) == n else None


def _suggest(name: str, candidates) -> str:
    close = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.5)
    return f"; did you mean {close[0]!r}?" if close else ""


def _unit_hint(section: str, key: str) -> str:
    """For a key that looks like a known key with another unit suffix, say so."""
    return _unit_hint_in(SCHEMA.get(section, {}), key)


def _unit_hint_in(keys: dict, key: str) -> str:
    stem = key.rsplit("_", 1)[0] if "_" in key else key
    for k, spec in keys.items():
        if spec.unit and k.rsplit("_", 1)[0] == stem and k != key:
            return f"; wrong unit: the key is {k!r} (unit {spec.unit})"
    return ""


def resolve(raw: dict, base_dir: Path | str = ".", source: Path | str | None = None,
            overrides: tuple[str, ...] = ()) -> Scene:
    """Validate raw scene data (as parsed from TOML) and return the resolved :class:`Scene`.

    The steps: each given key checked against SCHEMA, defaults filled in, the cross-key checks, the
    ``[expect]``/``[check]`` sections; every problem of every step is collected and raised together."""
    base_dir = Path(base_dir)
    src = str(source) if source else None
    if not isinstance(raw, dict):
        raise ScenarioError([("(scene)", raw, "a table of sections")], src)
    problems: list[tuple[str, Any, str]] = []
    values = _checked_values(raw, base_dir, problems)
    _fill_defaults(values, problems)
    _check_name(values, source, problems)
    _check_time(values, problems)
    _check_pair(values, problems)
    _check_machine(values, problems)
    _check_gear(values, problems)
    _check_effects(values, problems)
    _check_profiles(values, problems)
    expect = None
    if any(s in raw for s in CHECK_SECTIONS):
        from drivetrain.scene.expect import parse_checks

        expect = parse_checks(raw.get("expect"), raw.get("check"), values, base_dir, problems,
                              strict=not overrides)
    if problems:
        raise ScenarioError(problems, src)
    sections = {section: cls(**values[section]) for section, cls in SECTION_CLASSES.items()}
    return Scene(**sections, source=Path(source).resolve() if source else None, overrides=tuple(overrides),
                 expect=expect)


def _checked_values(raw: dict, base_dir: Path, problems) -> dict[str, dict[str, Any]]:
    """The given keys, each checked against SCHEMA: section -> key -> value (``MISSING``: given but bad)."""
    values: dict[str, dict[str, Any]] = {}
    for section, content in raw.items():
        if section in CHECK_SECTIONS:
            continue
        if section not in SCHEMA:
            known = (*SCHEMA, *CHECK_SECTIONS)
            problems.append((section, content if not isinstance(content, dict) else "{...}",
                             "a known section: " + ", ".join(known) + _suggest(section, known)))
            continue
        if not isinstance(content, dict):
            problems.append((section, content, f"a table [{section}]"))
            continue
        for key, value in content.items():
            full = f"{section}.{key}"
            if key not in SCHEMA[section]:
                hint = _unit_hint(section, key) or _suggest(key, SCHEMA[section])
                problems.append((full, value, f"a known key of [{section}]: "
                                 + ", ".join(SCHEMA[section]) + hint))
                continue
            checked = _check_value(full, SCHEMA[section][key], value, base_dir, problems)
            if checked is not None:
                values.setdefault(section, {})[key] = checked
            else:
                values.setdefault(section, {})[key] = _MISSING  # marks "given but bad"
    return values


def _fill_defaults(values: dict, problems) -> None:
    """SCHEMA's default for every key not given; a required key not given is a problem."""
    for section, keys in SCHEMA.items():
        sv = values.setdefault(section, {})
        for key, spec in keys.items():
            if key not in sv:
                if spec.default is _MISSING:
                    problems.append((f"{section}.{key}", _MISSING, f"a value ({spec.doc})"))
                else:
                    sv[key] = copy.deepcopy(spec.default)
                    if isinstance(sv[key], list):
                        sv[key] = tuple(sv[key])


def _ok(values: dict, section: str, *keys) -> bool:
    """The keys were given well (or defaulted): a cross-key check can read them."""
    return all(values[section].get(k) is not _MISSING for k in keys)


def _check_name(values: dict, source, problems) -> None:
    """The scene name: given, or the file's stem ("scene" for a scene built in code)."""
    if values["scenario"].get("name") is None:
        values["scenario"]["name"] = Path(source).stem if source else "scene"
    name = values["scenario"]["name"]
    if name is not _MISSING and not NAME_RE.fullmatch(str(name)):
        problems.append(("scenario.name", name, NAME_RULE))


def _check_time(values: dict, problems) -> None:
    """Settling time (default: min(2 s, 20 % of the run)), output samples, and the steps: the
    communication step divides the output period (drivetrain.system.steps_per_output), the sub-step is
    at most the communication step."""
    tm = values["time"]
    if _ok(values, "time", "duration_s", "settle_s"):
        if tm["settle_s"] is None:
            tm["settle_s"] = min(2.0, 0.2 * tm["duration_s"])
        elif tm["settle_s"] >= tm["duration_s"]:
            problems.append(("time.settle_s", tm["settle_s"],
                             f"a settling time shorter than time.duration_s = {tm['duration_s']:g} s"))

    if _ok(values, "time", "duration_s", "sample_rate_Hz") and tm["duration_s"] * tm["sample_rate_Hz"] < 16.0 * (1 - 1e-9):
        # the run is a whole number of output samples: a longer period would stretch it silently
        problems.append(("time.sample_rate_Hz", tm["sample_rate_Hz"],
                         f"at least 16 output samples in time.duration_s = {tm['duration_s']:g} s, i.e. "
                         f">= {16.0 / tm['duration_s']:.6g} Hz (the run is a whole number of sample periods)"))
    nm = values["numerics"]
    if _ok(values, "numerics", "comm_step_s") and _ok(values, "time", "sample_rate_Hz"):
        _, expected = steps_per_output(nm["comm_step_s"], tm["sample_rate_Hz"])
        if expected:
            problems.append(("numerics.comm_step_s", nm["comm_step_s"], expected))
    if _ok(values, "numerics", "comm_step_s", "max_substep_s") and nm["max_substep_s"] > nm["comm_step_s"] * (1 + 1e-12):
        problems.append(("numerics.max_substep_s", nm["max_substep_s"],
                         f"a sub-step <= numerics.comm_step_s = {nm['comm_step_s']:.6g} s"))


def _check_gear(values: dict, problems) -> None:
    """Faults only with health "faults" (and then at least one), mesh files only with health "mesh" (and
    then at least one), and a fidelity that models the health state."""
    gr = values["gear"]
    eff = values["effects"]
    pair = (gr["pair"] if _ok(values, "gear", "pair") else RIG_PAIR).params()     # the teeth the faults sit on
    if _ok(values, "gear", "faults"):       # gearcontact_fmu.fault_specs: the check the FMU makes too
        found = [(f"gear.{k}", _MISSING if v is None else v, e) for k, v, e in health_problems(
            gr["health"] if _ok(values, "gear", "health") else None, list(gr["faults"]), pair.z_pinion, pair.z_wheel,
            health_key="gear.health", faults_name="[[gear.faults]] table")]
        problems += found
        gr["faults"] = _MISSING if found else tuple(normalised_spec(f) for f in gr["faults"])
    if not _ok(values, "gear", "health", "pinion_mesh", "wheel_mesh"):
        return
    if gr["health"] == "mesh":
        if gr["pinion_mesh"] is None and gr["wheel_mesh"] is None:
            problems.append(("gear.pinion_mesh", _MISSING,
                             'a mesh file (gear.pinion_mesh and/or gear.wheel_mesh) when gear.health = "mesh"'))
    else:
        for k in ("pinion_mesh", "wheel_mesh"):
            if gr[k] is not None:
                problems.append((f"gear.{k}", str(gr[k]),
                                 f'no mesh file unless gear.health = "mesh" (health is {gr["health"]!r})'))
    fid = eff["mesh_contact"]
    if _ok(values, "effects", "mesh_contact") and gr["health"] != "healthy" and not supports(fid, "teeth"):
        toothed = " or ".join(fidelities_with("teeth"))
        problems.append(("effects.mesh_contact", fid,
                         f"a fidelity with tooth geometry ({toothed}) for gear.health = {gr['health']!r}; the "
                         "ideal gear has no teeth" if fid == "ideal" else
                         f"{toothed} for gear.health = {gr['health']!r} (the analytic ISO 6336 pair models the "
                         "healthy gear only: it has no fault and cannot read a mesh)"))


def _check_pair(values: dict, problems) -> None:
    """[gear.pair]: a pair that can be made (gearcontact_fmu.pair_check.pair_problems: each refusal with the
    figure that failed and its limit), before any work; a layer with Poisson's ratio < 0.5."""
    if not _ok(values, "gear", "pair") or values["gear"]["pair"].is_rig:
        return
    pair = values["gear"]["pair"]
    given = pair.as_dict()
    if given["nu"] >= 0.5:
        problems.append(("gear.pair.nu", given["nu"], "a Poisson's ratio < 0.5 (0.5: an incompressible layer has "
                         "no finite stiffness)"))
        return
    for why in pair_problems(pair.params()):
        problems.append(("gear.pair", "{" + ", ".join(f"{k} = {v!r}" for k, v in given.items()) + "}",
                         f"a bevel pair that can be made: {why}"))


def _check_effects(values: dict, problems) -> None:
    """The effects the chosen fidelity can carry: tooth compliance, manufacturing errors."""
    eff = values["effects"]
    if _ok(values, "effects", "mesh_contact", "tooth_compliance") and eff["tooth_compliance"] \
            and not supports(eff["mesh_contact"], "tooth_compliance"):
        problems.append(("effects.tooth_compliance", True,
                         f"false with effects.mesh_contact = \"{eff['mesh_contact']}\" (the series compliance is "
                         "applied to the contact map: use table; the analytic ISO 6336 pair has it already)"))
    if _ok(values, "effects", "mesh_contact", "manufacturing_errors") and eff["manufacturing_errors"] \
            and not supports(eff["mesh_contact"], "manufacturing_errors"):
        problems.append(("effects.manufacturing_errors", True,
                         f"false with effects.mesh_contact = \"{eff['mesh_contact']}\" (a rigid mesh has no mesh "
                         f"coordinate for the errors to offset; use {', '.join(fidelities_with('manufacturing_errors')[:-1])} "
                         f"or {fidelities_with('manufacturing_errors')[-1]})"))


class _Series(tuple):
    """A series key's value while resolving: (the file, its (t, value) pairs)."""

    def __new__(cls, path: Path, points: tuple):
        return super().__new__(cls, (path, points))


def _check_profiles(values: dict, problems) -> None:
    """Speed and load profiles start at time 0; a load series file is the load profile (not both)."""
    op = values["operating_point"]
    series = op.get("load_series_csv")
    if isinstance(series, _Series):
        if op.get("load_profile_Nm") not in (None, _MISSING):
            problems.append(("operating_point.load_series_csv", str(series[0]),
                             "either load_series_csv or load_profile_Nm, not both"))
        op["load_series_csv"], op["load_profile_Nm"] = series
    elif series is _MISSING:
        op["load_series_csv"] = None
    for pk in ("speed_profile_rpm", "load_profile_Nm"):
        prof = op.get(pk)
        if prof not in (None, _MISSING) and prof[0][0] != 0.0:
            problems.append((f"operating_point.{pk}", [list(p) for p in prof], "a profile starting at time 0"))


# --------------------------------------------------------------------------------------------------
# Overrides
# --------------------------------------------------------------------------------------------------


def parse_override(text: str) -> tuple[list[str], Any]:
    """'time.duration_s=0.5' -> (['time', 'duration_s'], 0.5). The value is read as a TOML value
    (numbers, true/false, "strings", [lists]); anything that is not valid TOML is taken as a string."""
    if "=" not in text:
        raise ScenarioError([(text, _MISSING, "an override of the form section.key=value")])
    key, _, value = text.partition("=")
    key = key.strip()
    parts = key.split(".")
    if parts[0] == GRID_SECTION:
        raise ScenarioError([(key, value, "a scene key; a grid's [sweep] key (sweep.draw.n, sweep.axes.<section.key>, "
                              "...) changes a grid file (load_scenes, drivetrain sweep), not one scene")])
    if len(parts) == 3 and parts[:2] == ["gear", "pair"] and parts[2]:      # a key of the [gear.pair] table
        return parts, override_value(key, value)
    if len(parts) != 2 or not all(parts):
        raise ScenarioError([(key, value, "a key of the form section.key (e.g. time.duration_s; gear.pair.z_wheel)")])
    return parts, override_value(key, value)


def apply_overrides(raw: dict, overrides: list[str] | tuple[str, ...]) -> dict:
    """Apply ``--set`` strings to raw scene data in place (validation happens in :func:`resolve`)."""
    for text in overrides or ():
        (section, key, *sub), value = parse_override(text)
        tbl = raw.setdefault(section, {})
        if not isinstance(tbl, dict):
            raise ScenarioError([(section, tbl, f"a table [{section}]")])
        if sub:                             # gear.pair.<key>: into the [gear.pair] table
            tbl = tbl.setdefault(key, {})
            if not isinstance(tbl, dict):
                raise ScenarioError([(f"{section}.{key}", tbl, f"a table [{section}.{key}]")])
            key = sub[0]
        tbl[key] = value
    return raw


# --------------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------------


def read_toml(path: Path | str) -> dict:
    path = Path(path)
    if not path.is_file():
        raise ScenarioError([("(file)", str(path), "an existing scene file")])
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError([("(file)", str(path), f"valid TOML ({exc})")], str(path)) from None
    except UnicodeDecodeError as exc:
        raise ScenarioError([("(file)", str(path), f"a UTF-8 text file (TOML); byte {exc.start} is not UTF-8 "
                             "(a binary file?)")], str(path)) from None
    except RecursionError:
        raise ScenarioError([("(file)", str(path), "TOML nested less deeply (arrays or tables nested thousands "
                             "of levels deep)")], str(path)) from None
    except OSError as exc:
        raise ScenarioError([("(file)", str(path), f"a readable file ({exc.strerror or exc})")], str(path)) from None


def is_grid(path: Path | str) -> bool:
    return GRID_SECTION in read_toml(path)


def load_scenes(path: Path | str, overrides: list[str] | tuple[str, ...] = ()) -> list[Scene]:
    """Load a scene file (one scene) or a grid file (its expansion, :mod:`drivetrain.scene.grid`).
    ``overrides`` change the base scene; overriding a swept key is refused. All cases are validated
    before any is returned."""
    path = Path(path)
    src = str(path)
    raw = read_toml(path)
    # "--set sweep.draw.n=2": a key of the grid's own [sweep] table, applied before the grid is read
    grid_sets = [o for o in overrides or () if o.partition("=")[0].strip().split(".")[0] == GRID_SECTION]
    apply_grid_overrides(raw, grid_sets, src)
    grid = split_grid(raw, src)
    overrides = tuple(o for o in overrides or () if o not in grid_sets)
    apply_overrides(raw, overrides)
    if grid is None:
        return [resolve(raw, base_dir=path.parent, source=path, overrides=overrides)]
    refuse_swept_overrides(grid, overrides, path)
    base_name = raw.get("scenario", {}).get("name", path.stem)
    return expand(raw, grid, lambda case: resolve(case, base_dir=path.parent, source=path, overrides=overrides),
                  base_name, src)


def load_scene(path: Path | str, overrides: list[str] | tuple[str, ...] = (), case: str | None = None) -> Scene:
    """Load one scene. For a grid file, ``case`` selects one expanded scene by name."""
    scenes = load_scenes(path, overrides)
    if case is not None:
        for s in scenes:
            if s.name == case:
                return s
        raise ScenarioError([("case", case, "one of " + ", ".join(s.name for s in scenes))], str(path))
    if len(scenes) != 1:
        raise ScenarioError([("(file)", str(path), f"a single scene; this grid expands to {len(scenes)} "
                              "(choose one with --case NAME, or use `drivetrain sweep`)")], str(path))
    return scenes[0]


def scene_from_dict(raw: dict, base_dir: Path | str = ".", overrides=()) -> Scene:
    """Build a scene in code (tests, sweeps): ``raw`` has the file's layout; missing keys default."""
    raw = copy.deepcopy(raw)
    apply_overrides(raw, overrides)
    return resolve(raw, base_dir=base_dir, overrides=tuple(overrides))


def default_scene(**overrides_by_key) -> Scene:
    """The all-defaults scene; keyword overrides like ``time__duration_s=0.5``."""
    raw: dict = {}
    for k, v in overrides_by_key.items():
        sec, key = k.split("__", 1)
        raw.setdefault(sec, {})[key] = v
    return resolve(raw)



def with_overrides(scene: Scene, overrides: list[str]) -> Scene:
    """Re-validate ``scene`` with ``--set`` style overrides applied."""
    raw = scene.to_dict()
    if scene.expect is not None:
        raw.update(scene.expect.raw())
    apply_overrides(raw, overrides)
    base = scene.source.parent if scene.source else Path.cwd()
    return resolve(raw, base_dir=base, source=scene.source, overrides=tuple(scene.overrides) + tuple(overrides))


__all__ = [
    "Scene", "ScenarioInfo", "OperatingPoint", "GearSpec", "TimeSpec", "OutputSpec", "NumericsSpec",
    "EffectsSpec", "ScenarioError", "SCHEMA", "HEALTH_STATES", "FIDELITIES", "SHAFT_MODELS",
    "load_scene", "load_scenes", "resolve", "apply_overrides", "parse_override", "scene_from_dict",
    "default_scene", "with_overrides", "schema_markdown", "dump_toml", "all_keys", "default_of", "is_grid",
]
