"""The dataset card, ``DATASET.md``, written beside every exported dataset (``drivetrain dataset``).

It says what the data is without the scene files: which code made it (version, commit), from which grid files
with which ``--set`` overrides and seeds; the counts per label, per gearbox and per operating point, and per
split; every column with its unit and meaning; how many faulty runs carry contact; what the shipped
detectability map (docs/DETECTABILITY.md, its table docs/detectability_auc.csv) says of each label family; and
how to load it.
"""
from __future__ import annotations

import datetime
import json
from collections import Counter
from pathlib import Path

from drivetrain.campaigns.splits import CLASS_COLUMNS, SPLITS

CARD_FILE = "DATASET.md"
#: the shipped detectability table (a source checkout's docs/; an installed package has none)
DETECTABILITY_CSV = Path(__file__).resolve().parents[3] / "docs" / "detectability_auc.csv"

#: the meaning of the columns every run has (the scene keys' come from the schema, a channel's from the rig)
BASE_COLUMNS = {
    "run": "the run's name (its folder in the sweep directory)",
    "time_s": "sample time from the run's start",
    "settled": "the sample is at or after time.settle_s (outside the start-up transient)",
    "status": "ok, or failed / interrupted (the completed part of the run)",
    "failure_time_s": "when the run failed (empty: it did not)",
    "energy_residual": "the co-simulation's relative energy-audit residual",
}
FAULT_KEYS = {
    "kind": "fault family", "member": "the gear that carries it (pinion or wheel)", "tooth": "tooth index",
    "flank": "flank (drive or coast)", "contact_share": "share of the fault's flank area inside the loaded contact "
    "region over a mesh cycle (0: the load never runs over it)", "mesh_torque_drop": "largest relative drop of mesh "
    "torque at fixed mesh coordinate", "loaded_flank": "the flank that carries the run's load",
}


def column_meaning(name: str) -> str:
    """What a dataset column is, in a few words."""
    from drivetrain.rig.data import RIG_SENSORS
    from drivetrain.scene.schema import SCHEMA

    if name in BASE_COLUMNS:
        return BASE_COLUMNS[name]
    if name in CLASS_COLUMNS:
        return CLASS_COLUMNS[name]
    if name in RIG_SENSORS:
        return RIG_SENSORS[name][1]
    head, _, tail = name.partition(".")
    if head == "label" and tail:              # a label renamed beside a channel of the same name
        return column_meaning(tail)
    key = SCHEMA.get(head, {}).get(tail) if tail else None
    if key is not None:
        return " ".join((key.doc or f"scene key [{head}] {tail}").split())
    if head.startswith("fault") and head[5:].isdigit():
        return f"fault {head[5:]}: " + FAULT_KEYS.get(tail, f"its {tail.replace('_', ' ')}")
    if head == "SBR_dB":
        return f"signal-to-background ratio of the fault in {tail} against its healthy twin"
    if head.startswith("amp_"):
        return f"amplitude of {tail} at {head[4:]} (Hann spectrum, settled part)"
    if tail:
        return f"condition indicator {head} of {tail} (campaigns.features, rig.indicators)"
    return ""


def _detectability(labels: list[str]) -> list[str]:
    """Per label family of the data, the shipped map's verdict: in how many of its cells (operating points,
    default and small size) the family carries a detectable change (docs/DETECTABILITY.md's rule)."""
    if not DETECTABILITY_CSV.is_file():
        return ["The shipped detectability map (docs/detectability_auc.csv) is not installed with this package."]
    from drivetrain.campaigns.detectability import read_table_csv, verdicts

    cells: dict = {}
    for v in verdicts(read_table_csv(DETECTABILITY_CSV)):
        parts = v["family"].rsplit("_", 2)                 # <kind>_<member>_<size>; a kind may hold "_"
        if len(parts) == 3:
            kind, member, size = parts
            cells.setdefault(f"{kind}/{member}", []).append((size, bool(v["detectable"]), bool(v["population"])))
    lines = ["| label | cells | detectable | separable in a population |", "|---|---|---|---|"]
    for fam in sorted({p for lab in labels for p in lab.split("+") if p not in ("healthy", "mesh")}):
        cs = cells.get(fam)
        if not cs:
            lines.append(f"| {fam} | not in the map | | |")
            continue
        lines.append(f"| {fam} | {len(cs)} | {sum(d for _, d, _ in cs)} | {sum(p for _, _, p in cs)} |")
    return ["From the shipped map (docs/DETECTABILITY.md: 20 gearboxes per cell under the rig's measured "
            "background, default and half size at its speeds and loads; a label family detectable in few cells "
            "is a label without a signal unless the background is lowered):", "", *lines]


def _grid_lines(sweep_dir: Path) -> list[str]:
    try:
        manifest = json.loads((Path(sweep_dir) / "manifest.json").read_text())
    except (OSError, ValueError):
        return ["- grid: the sweep's manifest.json is not readable"]
    out = [f"- sweep: `{sweep_dir}` ({manifest.get('n_runs', '?')} runs listed, complete: "
           f"{manifest.get('complete')}), backend {manifest.get('backend')}, computed by commit "
           f"{manifest.get('code_commit', 'unknown')}"]
    for f in manifest.get("scene_files") or []:
        out.append(f"- scene or grid file: `{f}`")
        grid = _grid_table(Path(f))
        if grid:
            out.append(f"  - its [sweep] as the file has it (a `--set sweep.*` of the sweep changed it; the counts "
                       f"below are what ran): `{json.dumps(grid, sort_keys=True)}`")
    if manifest.get("overrides"):
        out.append("- overrides: " + " ".join(f"`--set {o}`" for o in manifest["overrides"]))
    return out


def _grid_table(path: Path) -> dict | None:
    from drivetrain.scene.load import read_toml

    try:
        return read_toml(path).get("sweep")
    except Exception:  # noqa: BLE001 - a grid file moved or changed since: the card says nothing of it
        return None


def _count_table(title: str, counts: Counter, limit: int = 40) -> list[str]:
    rows = [f"| {title} | runs |", "|---|---|"]
    for k, n in sorted(counts.items(), key=lambda kv: (-kv[1], str(kv[0])))[:limit]:
        rows.append(f"| {k} | {n} |")
    if len(counts) > limit:
        rows.append(f"| ... {len(counts) - limit} more | {sum(sorted(counts.values(), reverse=True)[limit:])} |")
    return rows


def card_markdown(runs: list[dict], data_path: Path, fmt: str, sweep_dir: Path, settled_only: bool,
                  split: tuple, columns: dict[str, str], contact: str) -> str:
    """The card's text. ``columns``: every column of the written data -> its unit."""
    from drivetrain import __version__
    from drivetrain.campaigns.provenance import code_commit
    from drivetrain.run.outputs import load_text

    labs = [r["labels"] for r in runs]
    per_label = Counter(lab["label"] for lab in labs)
    per_split = Counter(lab["split"] for lab in labs)
    boxes = Counter(lab["gearbox"] for lab in labs)
    op = Counter(f"{lab.get('operating_point.drive_speed_rpm')} rpm, "
                 f"{load_text(lab.get('operating_point.load_torque_Nm'))}" for lab in labs)
    seeds = {k: sorted({lab.get(k) for lab in labs if lab.get(k) is not None})
             for k in ("manufacturing.seed", "background.seed", "instruments.seed")}
    split_boxes = {s: len({lab["gearbox"] for lab in labs if lab["split"] == s}) for s in SPLITS}
    name = data_path.name
    load = {"parquet": ['from drivetrain import load_dataset', f'df = load_dataset("{name}")            '
                        '# units in df.attrs["units"]', 'train = df[df["split"] == "train"]',
                        f'# or: pandas.read_parquet("{name}").attrs["units"]'],
            "hdf5": ['from drivetrain import load_dataset', f'df = load_dataset("{name}")',
                     f'# or: h5py.File("{name}")["labels/label"], ["runs/<run>/<channel>"].attrs["unit"]'],
            "aalto": ['import pandas as pd', f'labels = pd.read_csv("{name}/labels.csv")   # one row per run',
                      f'signals = pd.read_csv("{name}/<run>.csv")']}[fmt]
    lines = [
        f"# Dataset card: {name}",
        "",
        f"Written {datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds')} by drivetrain "
        f"{__version__}, commit {code_commit()} (`drivetrain dataset --format {fmt}"
        f"{' --settled-only' if settled_only else ''}`).",
        "",
        "## Source",
        *_grid_lines(Path(sweep_dir)),
        "- seeds in the data: " + "; ".join(f"{k} {_seed_text(v)}" for k, v in seeds.items()),
        f"- split: fractions (train, validation, test) {split[0]}, seed {split[1]}, drawn per gearbox: "
        + ", ".join(f"{s} {per_split.get(s, 0)} runs of {split_boxes[s]} gearboxes" for s in SPLITS),
        "",
        f"## Counts ({len(runs)} runs, {len(boxes)} gearboxes, {sum(lab['faulty'] for lab in labs)} faulty)",
        "",
        *_count_table("label", per_label), "",
        *_count_table("operating point", op), "",
        *_count_table("gearbox", boxes, limit=20), "",
        "## Fault contact",
        "",
        contact + ". A fault without contact is a label without physics: filter on "
        "`fault0.contact_share > 0` to keep only the faults the load runs over.",
        "",
        "## Detectability of the label families",
        "",
        *_detectability(list(per_label)),
        "",
        "## Columns",
        "",
        "| column | unit | meaning |", "|---|---|---|",
        *(f"| `{c}` | {u or '—'} | {column_meaning(c)} |" for c, u in columns.items()),
        "",
        "Units as the FMUs spell them (\"1\" dimensionless, — text or a switch). A setting whose effect is off in a "
        "run is empty there, not its unused default.",
        "",
        "## How to load it",
        "",
        "```python",
        *load,
        "```",
        "",
        "Windows for deep learning, run by run (never the whole file in memory): "
        "`drivetrain.windows(path, [\"propeller_shaft_torque\"], length=3012)` yields per run "
        "`x` (windows, length, channels), `label`, `faulty`, `split` (docs/SCENARIOS.md, \"Reading a dataset back\").",
    ]
    return "\n".join(lines) + "\n"


def _seed_text(values: list) -> str:
    if not values:
        return "— (not acting)"
    if len(values) > 8:
        return f"{len(values)} values, {values[0]}..{values[-1]}"
    return ", ".join(str(v) for v in values)


def write_card(runs: list[dict], data_path: Path, fmt: str, sweep_dir, columns: dict, contact: str,
               settled_only: bool = False, split: tuple = ((0.7, 0.15, 0.15), 0)) -> Path:
    """``DATASET.md`` beside the data (in the aalto directory for that format); returns its path. ``columns``:
    every column of the written data -> its unit; ``contact``: the sentence on the faults' contact."""
    data_path = Path(data_path)
    card = (data_path if fmt == "aalto" else data_path.parent) / CARD_FILE
    tmp = card.with_name(card.name + ".tmp")
    tmp.write_text(card_markdown(runs, data_path, fmt, Path(sweep_dir), settled_only, split, columns, contact),
                   encoding="utf-8")
    tmp.replace(card)
    return card


__all__ = ["write_card", "card_markdown", "column_meaning", "CARD_FILE"]
