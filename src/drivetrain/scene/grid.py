"""Grid files: a scene with a ``[sweep]`` table, expanded to one scene per case.

``axes`` list values for some keys; the grid is the Cartesian product of those values. ``[sweep.draw]``
adds ``n`` cases with randomly drawn faults and/or background parameters (``[sweep.draw.background]``:
domain randomisation of the measured background) per axes combination (one seeded generator for the
whole grid: reproducible). ``[sweep.growth]`` follows one fault through its life instead: per axes
combination one case per stage of its sizes (a pit growing, becoming a spall, a crack lengthening), the
same gearbox throughout, each labelled with ``scenario.growth_stage`` and ``scenario.remaining_life``. ``name`` is a template for the case names (:func:`case_name`), and
``[sweep.expect."<case name pattern>"]`` adds checks to the cases it matches. Each case is validated by
the ``resolve`` the loader passes in (:func:`drivetrain.scene.load.load_scenes`); every problem of every
case is reported together.
"""
from __future__ import annotations

import copy
import dataclasses
import itertools
import re
import string
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivetrain.errors import ScenarioError
from drivetrain.scene.schema import NAME_RE, NAME_RULE, PAIR_SCHEMA, SCHEMA, Scene, default_of
from gearcontact_fmu.fault_specs import (draw_faults, draw_rule_problems, draw_value, loaded_flank, rule_problem,
                                         rule_values)

GRID_SECTION = "sweep"
GRID_KEYS = {"axes", "name", "draw", "growth"}
GROWTH_KEYS = {"fault", "stages", "life", "healthy"}
DRAW_KEYS = {"n", "seed", "faults", "background", "paired_healthy", "gearboxes"}
#: the largest seed a ``seed = "any"`` rule of [sweep.draw.background] draws
MAX_DRAWN_SEED = 2 ** 31 - 1
#: the second word of the background draws' seed (numpy SeedSequence entropy [seed, this])
BACKGROUND_STREAM = 0x6267
#: format spec allowed in a grid name template field (width and precision at most 2 digits)
_SPEC_RE = re.compile(r"[<>^=]?[+\- ]?#?0?\d{0,2}[,_]?(\.\d{1,2})?[bdeEfFgGnosxX%]?")


@dataclass(frozen=True)
class Grid:
    """The ``[sweep]`` table of a grid file, checked: the swept keys ("section.key" -> values), the case
    name template, the ``[sweep.draw]`` table and the ``[sweep.expect]`` table (None: absent)."""

    axes: dict
    template: str | None
    draw: dict | None
    expect: dict | None
    growth: dict | None = None


def _pair_key(parts: list) -> bool:
    """``gear.pair.<key>`` split at its dots: a key of the [gear.pair] table."""
    return len(parts) == 3 and parts[:2] == ["gear", "pair"] and parts[2] in PAIR_SCHEMA


def pair_teeth(raw: dict) -> tuple[int, int]:
    """(z_pinion, z_wheel) of raw scene data's [gear.pair] (the rig's where it gives none, or none usable: the
    scene's own check refuses a bad one), for the faults a grid draws."""
    pair = (raw.get("gear") or {}).get("pair") if isinstance(raw.get("gear"), dict) else None
    pair = pair if isinstance(pair, dict) else {}
    return tuple(pair[k] if isinstance(pair.get(k), int) and not isinstance(pair.get(k), bool) and pair[k] >= 1
                 else PAIR_SCHEMA[k].default for k in ("z_pinion", "z_wheel"))


def split_grid(raw: dict, src: str) -> Grid | None:
    """Take the ``[sweep]`` table out of raw scene data and check it (None: not a grid file)."""
    grid = raw.pop(GRID_SECTION, None)
    if grid is None:
        return None
    problems = []
    if not isinstance(grid, dict):
        raise ScenarioError([(GRID_SECTION, grid, "a table [sweep] with axes = {\"section.key\" = [values]}")], src)
    expect = grid.pop("expect", None)
    for k in grid:
        if k not in GRID_KEYS:
            problems.append((f"{GRID_SECTION}.{k}", grid[k], "a known key of [sweep]: axes, name, draw, growth"))
    draw, growth = grid.get("draw"), grid.get("growth")
    if draw is not None:
        problems.extend(_draw_problems(draw, pair_teeth(raw)))
    if growth is not None:
        problems.extend(_growth_problems(growth))
        if draw is not None:
            problems.append((f"{GRID_SECTION}.growth", "[sweep.growth]", "either [sweep.draw] or [sweep.growth], "
                             "not both: a growth sequence follows one fault of one gearbox"))
    generated = draw is not None or growth is not None
    axes = grid.get("axes", {} if generated else None)
    if not isinstance(axes, dict) or not (axes or generated):
        problems.append((f"{GRID_SECTION}.axes", axes, 'a table {"section.key" = [value, ...]} with at least one axis'))
        axes = {}
    for k, vals in axes.items():
        parts = k.split(".")
        if not (_pair_key(parts) or (len(parts) == 2 and parts[0] in SCHEMA and parts[1] in SCHEMA[parts[0]])):
            problems.append((f"{GRID_SECTION}.axes.{k}", vals, "a scene key of the form section.key (or "
                             "gear.pair.<key>)"))
        elif not isinstance(vals, list) or not vals:
            problems.append((f"{GRID_SECTION}.axes.{k}", vals, "a non-empty list of values"))
    template = grid.get("name", None)
    if template is not None and not isinstance(template, str):
        problems.append((f"{GRID_SECTION}.name", template, "a name template string, e.g. \"run_{gear.health}\""))
    if problems:
        raise ScenarioError(problems, src)
    return Grid(axes, template, draw, expect, growth)


def _growth_problems(growth) -> list:
    """Problems of ``[sweep.growth]``: ``fault`` (a fault specification's fixed keys: kind, member, tooth, ...),
    ``stages`` (a list of tables, each the keys that change at that stage: sizes, or the kind), ``life``
    (optional: the fraction of the life used at each stage, increasing in [0, 1)) and ``healthy`` (optional:
    a stage 0 without the fault). The merged specifications are checked with the rest of each case."""
    key = f"{GRID_SECTION}.growth"
    if not isinstance(growth, dict):
        return [(key, growth, "a table [sweep.growth] with fault = {...} and stages = [{...}, ...]")]
    problems = [(f"{key}.{k}", v, "a key of [sweep.growth]: fault, stages, life, healthy")
                for k, v in growth.items() if k not in GROWTH_KEYS]
    if not isinstance(growth.get("fault"), dict) or "kind" not in growth.get("fault", {}):
        problems.append((f"{key}.fault", growth.get("fault"), "a fault table with its kind, e.g. "
                         "{kind = \"pit\", member = \"wheel\", tooth = 38}"))
    stages = growth.get("stages")
    if not isinstance(stages, list) or not stages or not all(isinstance(x, dict) for x in stages):
        problems.append((f"{key}.stages", stages, "a non-empty list of tables, each the fault's keys at that stage"))
        stages = []
    life = growth.get("life")
    if life is not None:
        ok = (isinstance(life, list) and len(life) == len(stages) and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and 0.0 <= x < 1.0 for x in life)
            and all(a < b for a, b in zip(life, life[1:])))
        if not ok:
            problems.append((f"{key}.life", life, f"one fraction of the life used per stage ({len(stages)}), "
                             "increasing, each in [0, 1)"))
    if not isinstance(growth.get("healthy", False), bool):
        problems.append((f"{key}.healthy", growth["healthy"], "true or false"))
    return problems


def growth_stages(growth: dict) -> list[tuple[int, float, dict | None]]:
    """The stages of a ``[sweep.growth]``: (stage number, remaining life, fault specification or None for the
    healthy stage 0). The remaining life is 1 - the life used: ``life`` if given, else the stages spread
    evenly over the life (stage i of n: (i + 1) / (n + 1) used); the healthy stage has all of it."""
    stages = growth["stages"]
    n = len(stages)
    life = growth.get("life") or [(i + 1) / (n + 1) for i in range(n)]
    out: list[tuple[int, float, dict | None]] = [(0, 1.0, None)] if growth.get("healthy") else []
    spec: dict = dict(growth["fault"])
    for i, stage in enumerate(stages):
        spec = {**spec, **stage}
        if "kind" in stage and stage["kind"] != growth["fault"]["kind"]:        # a pit becoming a spall: the
            spec = {k: spec[k] for k in ("member", "tooth", "flank") if k in spec} | dict(stage)   # new kind's sizes
        out.append((len(out), 1.0 - float(life[i]), dict(spec)))
    return out


def _draw_problems(draw, teeth: tuple[int, int]) -> list:
    """Problems of ``[sweep.draw]``: ``n`` drawn cases per axes combination, ``seed``, and
    ``[[sweep.draw.faults]]`` templates (gearcontact_fmu.fault_specs.draw_rule_problems) and/or a
    ``[sweep.draw.background]`` table (:func:`_background_rule_problems`)."""
    key = f"{GRID_SECTION}.draw"
    if not isinstance(draw, dict):
        return [(key, draw, "a table [sweep.draw] with n, seed and [[sweep.draw.faults]] or [sweep.draw.background]")]
    problems = [(f"{key}.{k}", v, "a key of [sweep.draw]: n, seed, faults, background, paired_healthy, gearboxes")
                for k, v in draw.items() if k not in DRAW_KEYS]
    if not isinstance(draw.get("gearboxes", False), bool):
        problems.append((f"{key}.gearboxes", draw["gearboxes"], "true (each drawn case its own gearbox) or false"))
    if not isinstance(draw.get("paired_healthy", False), bool):
        problems.append((f"{key}.paired_healthy", draw["paired_healthy"], "true or false"))
    elif draw.get("paired_healthy") and not draw.get("faults"):
        problems.append((f"{key}.paired_healthy", True, "[[sweep.draw.faults]] to pair healthy runs with"))
    for k in ("n", "seed"):
        v = draw.get(k)
        if isinstance(v, bool) or not isinstance(v, int) or v < (1 if k == "n" else 0):
            problems.append((f"{key}.{k}", v, "an integer >= 1" if k == "n" else "an integer seed >= 0"))
    if "background" in draw:
        problems += _background_rule_problems(draw["background"])
    tpls = draw.get("faults")
    if tpls is None and "background" in draw:
        return problems
    if not isinstance(tpls, list) or not tpls:
        problems.append((f"{key}.faults", tpls, "at least one [[sweep.draw.faults]] table (or a [sweep.draw.background])"))
        return problems
    for i, tpl in enumerate(tpls):
        problems += [(f"{key}.faults[{i}]" + (f".{k}" if k else ""), v, e)
                     for k, v, e in draw_rule_problems(tpl, *teeth)]
    return problems


def _background_rule_problems(table) -> list:
    """Problems of ``[sweep.draw.background]``: keys of [background], each a fixed value, a list (one of its
    items, uniformly), ``{uniform = [a, b]}`` or, for ``seed``, ``"any"`` (uniformly over 0..2^31-1); the
    drawn values are then checked as any scene value."""
    key = f"{GRID_SECTION}.draw.background"
    if not isinstance(table, dict) or not table:
        return [(key, table, 'a table of [background] keys, e.g. load_noise_Nm_rtHz = { uniform = [0.01, 0.04] }')]
    problems = []
    for k, rule in table.items():
        if k not in SCHEMA["background"]:
            problems.append((f"{key}.{k}", rule, f"a key of [background]: {', '.join(SCHEMA['background'])}"))
        elif rule_problem(rule):
            problems.append((f"{key}.{k}", rule, rule_problem(rule)))
        elif rule == "any" and k != "seed":
            problems.append((f"{key}.{k}", rule, '"any" only for seed; a value, a list or {uniform = [a, b]}'))
    return problems


def _check_background_values(raw: dict, table: dict, resolve_case: Callable[[dict], Scene], src: str) -> None:
    """Every value ``[sweep.draw.background]`` can draw (gearcontact_fmu.fault_specs.rule_values: a list's items,
    a uniform's bounds) checked as the scene key it sets, before any draw: a value is refused whatever the seed."""
    problems: dict = {}
    for k, rule in table.items():
        for value in ([0] if rule == "any" else rule_values(rule)):
            case = copy.deepcopy(raw)
            case.setdefault("background", {})[k] = value
            try:
                resolve_case(case)
            except ScenarioError as exc:
                for key, v, e in exc.problems:
                    if key == f"background.{k}":
                        problems.setdefault((k, repr(v)), (f"{GRID_SECTION}.draw.background.{k}", v,
                                                           f"{e} (every value the rule can draw is checked)"))
    if problems:
        raise ScenarioError(list(problems.values()), src)


def draw_background(table: dict, rng: np.random.Generator) -> dict:
    """The [background] values of one drawn case, in the table's order, with the numpy Generator ``rng``."""
    return {k: int(rng.integers(MAX_DRAWN_SEED + 1)) if rule == "any" else draw_value(rule, rng)
            for k, rule in table.items()}


def override_value(key: str, value: str):
    """A ``--set`` override's value read as a TOML value (numbers, true/false, "strings", [lists], {inline
    tables}); anything that is not valid TOML is taken as a string (scene keys and a grid's [sweep] keys alike)."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib

    value = value.strip()
    try:
        return tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        return value
    except RecursionError:
        raise ScenarioError([(key, value[:60] + "...", "a value nested less deeply")]) from None


def apply_grid_overrides(raw: dict, overrides: list[str], src: str) -> None:
    """``--set sweep.<key>=value`` changes of a grid file's ``[sweep]`` table, in place, before it is checked:
    ``sweep.draw.n=2``, ``sweep.draw.seed=7``, ``sweep.name="{base}_{operating_point.drive_speed_rpm:g}"``,
    ``sweep.axes.operating_point.drive_speed_rpm=[500.0]`` (after ``axes`` or ``expect`` the rest of the key is
    one name). The value is read as TOML. A file without ``[sweep]`` is refused: it is not a grid."""
    for text in overrides:
        key, _, value = text.partition("=")
        key = key.strip()
        if not _:
            raise ScenarioError([(text, None, "an override of the form sweep.key=value")], src)
        table = raw.get(GRID_SECTION)
        if not isinstance(table, dict):
            raise ScenarioError([(key, value, f"a key of a grid file; {src} has no [{GRID_SECTION}] table (not a grid)")],
                                src)
        parts = key.split(".")[1:]
        if not parts or not all(parts):
            raise ScenarioError([(key, value, "a key of [sweep], e.g. sweep.draw.n")], src)
        path: list[str] = []
        for i, part in enumerate(parts):
            path.append(part)
            if part in ("axes", "expect") and i + 1 < len(parts):
                path.append(".".join(parts[i + 1:]))
                break
        node = table
        for part in path[:-1]:
            nxt = node.setdefault(part, {})
            if not isinstance(nxt, dict):
                raise ScenarioError([(key, value, f"a key inside a table; {GRID_SECTION}.{part} is not a table")], src)
            node = nxt
        node[path[-1]] = override_value(key, value)


def refuse_swept_overrides(grid: Grid, overrides: tuple[str, ...], path) -> None:
    """Overriding a swept key would silently replace the axis: refused."""
    for text in overrides:
        k = text.partition("=")[0].strip()
        if k in grid.axes:
            raise ScenarioError([(k, text.partition("=")[2], f"a key that is not a sweep axis of {path.name} "
                                  f"(axes: {', '.join(grid.axes)})")], str(path))


def case_name(template: str, base: str, scene: "Scene", src: str = "") -> str:
    """The name of a grid case from the ``[sweep] name`` template: literal text and fields ``{base}`` or
    ``{section.key}`` (a scene key), each with an optional short format spec (``{operating_point.
    drive_speed_rpm:g}``, width and precision at most 2 digits). Nothing else is evaluated (no
    attribute or index walking, no conversions); characters other than letters, digits and ``_ . + -``
    become ``_``, and the result must be a valid scene name."""
    key = f"{GRID_SECTION}.name"

    def bad(why):
        return ScenarioError([(key, template, why)], src)

    out = []
    try:
        parts = list(string.Formatter().parse(template))
    except ValueError as exc:
        raise bad(f"a valid name template ({exc})") from None
    for literal, field, spec, conv in parts:
        out.append(literal)
        if field is None:
            continue
        if conv is not None:
            raise bad(f"fields without conversions (!{conv} in {{{field}}})")
        if not _SPEC_RE.fullmatch(spec or ""):
            raise bad(f"a short format spec such as :g or :.1f, not {spec!r} in {{{field}}}")
        if field == "base":
            value = base
        else:
            sec, _, k = field.partition(".")
            if _pair_key(field.split(".")):              # {gear.pair.z_wheel}
                value = scene.gear.pair.as_dict()[field.split(".")[2]]
            elif sec not in SCHEMA or k not in SCHEMA[sec]:
                raise bad(f"fields {{base}} or {{section.key}} of scene keys, not {{{field}}}")
            else:
                value = getattr(getattr(scene, sec), k)
        try:
            out.append(format(value, spec or ""))
        except (TypeError, ValueError) as exc:
            raise bad(f"a format spec that suits {field} = {value!r} ({exc})") from None
    nm = re.sub(r"[^A-Za-z0-9_.+\-]", "_", "".join(out))
    if not NAME_RE.fullmatch(nm):
        raise bad(f"names that are valid scene names ({NAME_RULE}), not {nm[:80]!r}")
    return nm


def _cases(raw: dict, grid: Grid):
    """(raw data of the case, draw number or None) for every case, in the grid's order: the axes'
    Cartesian product, each combination ``n`` times with drawn faults when ``[sweep.draw]`` is given
    (one Generator for the whole grid: reproducible)."""
    keys = list(grid.axes)
    draw = grid.draw
    rng = np.random.default_rng(draw["seed"]) if draw else None
    # the background's own stream: adding [sweep.draw.background] leaves the faults' draws as they were
    rng_bg = np.random.default_rng([draw["seed"], BACKGROUND_STREAM]) if draw else None
    draws = range(draw["n"]) if draw else [None]
    for number, (combo, d) in enumerate(itertools.product(itertools.product(*(grid.axes[k] for k in keys)), draws)):
        case = copy.deepcopy(raw)
        for k, v in zip(keys, combo):
            sec, key, *sub = k.split(".")
            if sub:                                     # gear.pair.<key>: into the [gear.pair] table
                case.setdefault(sec, {}).setdefault(key, {})[sub[0]] = v
            else:
                case.setdefault(sec, {})[key] = v
        if d is not None and draw.get("gearboxes"):
            # each drawn case its own gearbox: manufacturing seed = the case's number in the grid (0, 1, ...)
            case.setdefault("manufacturing", {})["seed"] = number
        if grid.growth is not None:
            yield from _growth_cases(case, grid.growth)
            continue
        healthy = copy.deepcopy(case) if d is not None and draw.get("paired_healthy") else None
        if d is not None and draw.get("faults"):
            case.setdefault("gear", {}).update(
                health="faults", faults=draw_faults(draw["faults"], rng, *pair_teeth(case), flank=_loaded_flank(case)))
        if d is not None and draw.get("background"):
            bg = draw_background(draw["background"], rng_bg)
            case.setdefault("background", {}).update(bg)
            if healthy is not None:
                healthy.setdefault("background", {}).update(bg)
        case.setdefault("scenario", {}).pop("name", None)
        yield case, d, False
        if healthy is not None:               # the same gearbox, operating point and background, healthy
            healthy.setdefault("gear", {}).update(health="healthy")
            healthy["gear"].pop("faults", None)
            healthy["scenario"] = {k: v for k, v in case["scenario"].items()}
            yield healthy, d, True


def _loaded_flank(case: dict) -> str:
    """The flank that carries a case's load at its start: drive for a braking load motor (load > 0), coast for
    a driving one (gearcontact_fmu.fault_contact.loaded_flank of the pinion torque, which has the load's sign)."""
    load = (case.get("operating_point") or {}).get("load_torque_Nm", default_of("operating_point.load_torque_Nm"))
    try:
        return loaded_flank(float(load))
    except (TypeError, ValueError):
        return "drive"                      # a bad load is the scene check's to refuse, with its key


def _growth_cases(case: dict, growth: dict):
    """The cases of one axes combination through the fault's life (:func:`growth_stages`): the same gearbox,
    the fault's specification of each stage, its stage and remaining life as scene keys (labels)."""
    for stage, remaining, spec in growth_stages(growth):
        c = copy.deepcopy(case)
        gear = c.setdefault("gear", {})
        if spec is None:
            gear.update(health="healthy")
            gear.pop("faults", None)
        else:
            gear.update(health="faults", faults=[spec])
        c.setdefault("scenario", {}).pop("name", None)
        c["scenario"].update(growth_stage=stage, remaining_life=remaining)
        yield c, ("stage", stage), False


#: the most cases one grid file expands to (a sweep of more is several grid files)
MAX_GRID_CASES = 100_000


def grid_size(grid: Grid) -> int:
    """The number of cases a grid expands to, counted without expanding it."""
    n = 1
    for values in grid.axes.values():
        n *= len(values)
    if grid.draw is not None:
        n *= int(grid.draw["n"]) * (2 if grid.draw.get("paired_healthy") else 1)
    if grid.growth is not None:
        n *= len(grid.growth["stages"]) + (1 if grid.growth.get("healthy") else 0)
    return n


def expand(raw: dict, grid: Grid, resolve_case: Callable[[dict], Scene], base_name: str, src: str) -> list[Scene]:
    """The grid's scenes, each validated by ``resolve_case`` (raw case data -> Scene) and named from the
    template (default ``{base}_{axis}_...``, plus ``_drawNNN`` for drawn cases). Every problem of every
    case is collected and raised together."""
    n_cases = grid_size(grid)
    if n_cases > MAX_GRID_CASES:              # refused at once: expanding it alone would take minutes
        raise ScenarioError([(GRID_SECTION, f"{n_cases} cases", f"a grid of at most {MAX_GRID_CASES} cases "
                              "(split it into several grid files, each its own sweep directory)")], src)
    if grid.draw is not None and grid.draw.get("background"):
        _check_background_values(raw, grid.draw["background"], resolve_case, src)
    scenes, problems, names = [], [], set()
    last_pair = ""
    template = grid.template or "_".join(["{base}"] + ["{" + k + "}" for k in grid.axes])
    for case, d, twin in _cases(raw, grid):
        try:
            sc = resolve_case(case)
        except ScenarioError as exc:
            problems.extend(exc.problems)
            continue
        nm = case_name(template, base_name, sc, src)
        if isinstance(d, tuple):              # a growth stage
            nm += f"_stage{d[1]:02d}"
        elif d is not None:
            nm += f"_draw{d:03d}"
        pair = None
        if d is not None and grid.draw is not None and grid.draw.get("paired_healthy"):
            # the faulty case comes first; its healthy twin (next) is named and measured after it
            if twin:
                pair, nm = last_pair, last_pair + "_healthy"
            else:
                pair = last_pair = nm
        if nm in names:
            raise ScenarioError([(f"{GRID_SECTION}.name", grid.template,
                                  f"a template giving unique names ({nm!r} twice)")], src)
        names.add(nm)
        if grid.expect is not None:          # [sweep.expect."<case name pattern>"]: more checks per case
            from drivetrain.scene.expect import case_expectations

            extra = case_expectations(grid.expect, nm, problems)
            if extra:
                case["expect"] = {**(case.get("expect") or {}), **extra}
                try:
                    sc = resolve_case(case)
                except ScenarioError as exc:
                    problems.extend(exc.problems)
                    continue
        info = dataclasses.replace(sc.scenario, name=nm)
        if pair is not None:                  # a pair is measured with one noise record: its id is its noise_name
            info = dataclasses.replace(info, noise_name=pair)
        scenes.append(dataclasses.replace(sc, scenario=info))
    if grid.expect is not None:
        from drivetrain.scene.expect import unmatched_case_patterns

        problems.extend(unmatched_case_patterns(grid.expect, names))
    if problems:
        raise ScenarioError(list({(k, repr(v), e): (k, v, e) for k, v, e in problems}.values()), src)
    return scenes
