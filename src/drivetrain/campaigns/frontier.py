"""``drivetrain frontier``: the detectability frontier, the smallest detectable size of each fault family.

What. A **cell** is a fault kind on one member at one operating point (drive speed, load at the load motor).
Its sizes form a **ladder** (:data:`LADDER`: every size key of the kind at these factors of its default, from
the family's smallest to severe; the missing tooth has one size). A size is judged as a cell of
``drivetrain detectability`` is (:mod:`drivetrain.campaigns.detectability`): ``gearboxes`` gearboxes, each
run faulty, healthy with the faulty run's noise record and healthy with a record of its own (the baseline);
detectable when the best indicator's two-sided change score reaches max(0.9, the chance level of the best
of the cell's indicators) (detectability.verdicts). The **frontier** of a cell is the smallest detectable
size of its ladder, "beyond" when even severe is not detectable.

Why this design (the budget). The full grid, 7 kinds x 2 members x 5 sizes x speeds x loads x 20 gearboxes at
20 s, is over 13,000 runs and 30 core-hours on this machine. The frontier needs only the sizes around the
threshold. Per cell: the largest size first (not detectable: the frontier lies beyond severe, the cell
stops), then the smallest (detectable: the frontier is at or below it, the cell stops), then bisection
between the largest undetectable and the smallest detectable size. A ladder of 5 sizes costs a cell 1 to
4 sizes (at most 2 + ceil(log2 4)); the healthy and baseline runs of an operating point serve every cell there.

How the design can bias the frontier. Bisection assumes detectability grows with size. A non-monotone cell
(a pit that grows out of the loaded contact region, a line that cancels an error line at one size) gets a
frontier at one of its thresholds: the report flags a cell whose verdicts were not monotone over the sizes
it ran. A verdict near the threshold rests on 20 gearboxes and is noisy: the frontier is uncertain by about
one ladder step. A cell stopped at severe says "not detectable up to severe", a statement about this
ladder; one stopped at the smallest says "at or below", not where below.

How it runs. In rounds: every pending (cell, size) of a round runs as one sweep into one directory (local
processes or Dask: drivetrain.campaigns.sweep); finished runs are reused by their fingerprint, so a study
killed and started again takes the same decisions from the same runs and runs only what is missing. Each
run's indicators are computed once and kept beside its signals (``features.json``); the verdicts of the
round decide the next one.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

from drivetrain.campaigns import GEARBOXES
from drivetrain.campaigns import detectability as D
from drivetrain.campaigns.provenance import commit_line
from drivetrain.rig.data import PAPER_LOADS_NM, PAPER_MAX_LOAD_NM, PAPER_MAX_SPEED_RPM, PAPER_SPEEDS_RPM
from gearcontact_fmu.fault_specs import FAULT_KINDS

#: the size ladder: factors of each kind's default sizes, smallest to severe
LADDER = (0.25, 0.5, 1.0, 1.5, 2.0)
#: drive speeds [rpm]: the paper's 500 and its highest, 1500
SPEEDS_RPM = (PAPER_SPEEDS_RPM[1], PAPER_MAX_SPEED_RPM)
#: load-motor torques [N·m]: the paper's lightest and heaviest, and the load motor's nominal 11.9
LOADS_NM = (PAPER_LOADS_NM[0], PAPER_MAX_LOAD_NM, 11.9)
#: where the frontier lies beyond the ladder (not detectable even at its largest size)
BEYOND = "beyond"
FEATURES_CACHE = "features.json"


@dataclass(frozen=True)
class Cell:
    kind: str
    member: str
    speed_rpm: float
    load_Nm: float

    @property
    def sized(self) -> bool:
        return any(k in D.SIZE_KEYS for k in FAULT_KINDS[self.kind])

    def family(self, factor: float) -> D.Family:
        return D.Family(self.kind, self.member, f"x{factor:g}" if self.sized else "default")


def next_index(verdicts: dict[int, bool], n: int) -> int | None:
    """The ladder index a cell judges next, given its verdicts so far ({index: detectable}) on a ladder of
    ``n`` sizes, or None when its frontier is known: the largest first, then the smallest, then bisection
    between the largest undetectable and the smallest detectable size above it."""
    top = n - 1
    if top not in verdicts:
        return top
    if not verdicts[top]:
        return None
    if n == 1 or 0 not in verdicts:
        return None if n == 1 else 0
    if verdicts[0]:
        return None
    hi = min(i for i, v in verdicts.items() if v)
    lo = max(i for i, v in verdicts.items() if not v and i < hi)
    return None if hi - lo <= 1 else (lo + hi) // 2


def frontier_index(verdicts: dict[int, bool], n: int):
    """The frontier of a finished cell: the smallest detectable index, or :data:`BEYOND`."""
    found = [i for i, v in verdicts.items() if v]
    return min(found) if found else BEYOND


def monotone(verdicts: dict[int, bool]) -> bool:
    """Whether the sizes a cell ran were detectable from some size on and not below it."""
    seq = [verdicts[i] for i in sorted(verdicts)]
    return all(not a or b for a, b in zip(seq, seq[1:]))


@dataclass
class FrontierStudy:
    """What a frontier study covers: fault kinds and members, operating points, gearboxes, run length,
    ladder and background, and the scene overrides every run gets."""

    kinds: tuple = tuple(FAULT_KINDS)
    members: tuple = D.MEMBERS
    speeds: tuple = SPEEDS_RPM
    loads: tuple = LOADS_NM
    gearboxes: int = GEARBOXES
    duration_s: float = 20.0
    settle_s: float = 2.0
    ladder: tuple = LADDER
    background: str = "on"
    overrides: tuple = field(default_factory=tuple)

    def cells(self) -> list[Cell]:
        return [Cell(k, m, s, l) for k in self.kinds for m in self.members for s in self.speeds for l in self.loads]

    def ladder_of(self, cell: Cell) -> tuple:
        return tuple(self.ladder) if cell.sized else (1.0,)

    def scenes(self, pending: list[tuple[Cell, int]]) -> list:
        """The runs of one round: the pending sizes' faulty runs and the healthy and baseline runs of their
        operating points (the same scenes in every round: reused)."""
        out, seen = [], set()
        ops = sorted({(c.speed_rpm, c.load_Nm) for c, _ in pending})
        for speed, load in ops:
            fams = [c.family(self.ladder_of(c)[i]) for c, i in pending if (c.speed_rpm, c.load_Nm) == (speed, load)]
            study = D.Study(list(dict.fromkeys(fams)), (speed,), (load,), self.gearboxes, self.duration_s,
                            self.settle_s, self.background, tuple(self.overrides))
            for sc in study.scenes():
                if sc.name not in seen:
                    seen.add(sc.name)
                    out.append(sc)
        return out


def run_features(runs_dir: Path, names: list[str]) -> list[dict]:
    """The indicator rows (detectability's feature rows: labels and indicators) of these runs, each computed
    once and kept in its directory (``features.json``, valid while its signals.h5 is unchanged)."""
    from drivetrain.campaigns.dataset import read_run
    from drivetrain.campaigns.features import indicator_columns

    rows = []
    for name in names:
        d = runs_dir / name
        sig = d / "signals.h5"
        if not sig.is_file():
            continue
        st = sig.stat()
        stamp = f"{st.st_mtime_ns}:{st.st_size}"
        cache = d / FEATURES_CACHE
        if cache.is_file():
            try:
                got = json.loads(cache.read_text())
                if got.get("stamp") == stamp:
                    rows.append(got["row"])
                    continue
            except (OSError, ValueError, KeyError):
                pass
        r = read_run(sig, {"name": name})
        row = {**r["labels"], **indicator_columns(r, runs_dir)}
        cache.write_text(json.dumps({"stamp": stamp, "row": row}, default=str))
        rows.append(row)
    return rows


def judge(rows: list[dict], pending: list[tuple[Cell, int]], study: FrontierStudy) -> dict:
    """{(cell, index): verdict row of detectability.verdicts} for the pending sizes."""
    out = {}
    for cell, i in pending:
        fam = cell.family(study.ladder_of(cell)[i])
        s = D.Study([fam], (cell.speed_rpm,), (cell.load_Nm,), study.gearboxes)
        v = D.verdicts(D.auc_table(rows, s))
        if v:
            out[(cell, i)] = v[0]
    return out


def run_frontier(study: FrontierStudy, out_dir: Path | str, *, workers: int | None = None, address: str | None = None,
                 backend: str = "fmi", fmu_dir=None, progress: bool = True, log=None) -> dict:
    """Run the study round by round (module docstring); returns {"cells": [...], "rounds": [...], "runs": n}.
    Every run lands in ``out_dir/runs`` (a sweep directory, resumable)."""
    from drivetrain.campaigns.sweep import run_sweep

    runs_dir = Path(out_dir) / "runs"
    verdicts: dict[Cell, dict[int, bool]] = {c: {} for c in study.cells()}
    rows_of: dict[tuple, dict] = {}
    rounds, all_names = [], []
    while True:
        pending = [(c, i) for c, v in verdicts.items() if (i := next_index(v, len(study.ladder_of(c)))) is not None]
        if not pending:
            break
        t0 = time.perf_counter()
        scenes = study.scenes(pending)
        all_names += [s.name for s in scenes if s.name not in all_names]
        manifest = run_sweep(scenes, runs_dir, workers=workers, address=address, backend=backend, fmu_dir=fmu_dir,
                             skip_existing=True, plots=False, progress=progress, grid_names=all_names)
        failed = [r["name"] for r in manifest["runs"] if r.get("status") != "ok" and r["name"] in
                  {s.name for s in scenes}]
        rows = run_features(runs_dir, [s.name for s in scenes])
        judged = judge(rows, pending, study)
        for (cell, i) in pending:
            row = judged.get((cell, i))
            verdicts[cell][i] = bool(row and row["detectable"])
            if row is not None:
                rows_of[(cell, i)] = row
        rounds.append({"sizes": len(pending), "runs": len(scenes), "failed": failed,
                       "reused": int(manifest.get("reused_runs") or 0), "wall_time_s": time.perf_counter() - t0})
        if log:
            log(f"frontier round {len(rounds)}: {len(pending)} sizes, {len(scenes)} runs "
                f"({rounds[-1]['reused']} reused, {len(failed)} failed), {rounds[-1]['wall_time_s']:.0f} s")
    cells = []
    for cell, v in verdicts.items():
        lad = study.ladder_of(cell)
        fi = frontier_index(v, len(lad))
        cells.append({"kind": cell.kind, "member": cell.member, "speed_rpm": cell.speed_rpm, "load_Nm": cell.load_Nm,
                      "frontier_factor": None if fi == BEYOND else lad[fi], "beyond": fi == BEYOND,
                      "at_or_below_smallest": fi == 0 and len(lad) > 1,
                      "sizes_run": {f"{lad[i]:g}": bool(d) for i, d in sorted(v.items())},
                      "scores": {f"{lad[i]:g}": rows_of[(cell, i)]["change"] for i in sorted(v) if (cell, i) in rows_of},
                      "monotone": monotone(v),
                      "spec": cell.family(lad[fi if fi != BEYOND else -1]).fault()})
    return {"cells": cells, "rounds": rounds, "runs": len(all_names)}


def _size_text(c: dict) -> str:
    if c["beyond"]:
        return "not detectable up to severe"
    f = c["frontier_factor"]
    keys = {k: float(v) * f for k, v in FAULT_KINDS[c["kind"]].items()
            if k in D.SIZE_KEYS and isinstance(v, (int, float)) and v}
    sizes = ", ".join(f"{k} {v:.3g}" for k, v in keys.items()) or "its one size"
    return ("<= " if c["at_or_below_smallest"] else "") + f"x{c['frontier_factor']:g} ({sizes})"


def report_markdown(result: dict, study: FrontierStudy, meta: dict, figure: str | None = None) -> str:
    """The frontier as a table (and the figure), with the design's words on bias."""
    cells = result["cells"]
    lines = ["# The detectability frontier", "",
             "Generated by `drivetrain frontier` (src/drivetrain/campaigns/frontier.py: the design, its cost and its "
             "bias in the module docstring).", "",
             f"- command: `{meta.get('command', '')}`", commit_line(),
             f"- {len(cells)} cells: {len(study.kinds)} kinds x {len(study.members)} members x speeds "
             f"{', '.join(f'{s:g}' for s in study.speeds)} rpm x loads {', '.join(f'{x:g}' for x in study.loads)} N·m "
             f"at the load motor; ladder x{', x'.join(f'{f:g}' for f in study.ladder)} of each kind's default "
             f"sizes; {study.gearboxes} gearboxes; runs of {study.duration_s:g} s (settle {study.settle_s:g} s), "
             f"background {study.background}",
             f"- {result['runs']} runs in {len(result['rounds'])} rounds; wall time "
             f"{meta.get('wall_time_s', float('nan')) / 60:.1f} min on {meta.get('workers')} worker(s), "
             f"{meta.get('core_hours', float('nan')):.2f} core-hours",
             f"- frontier found in {sum(not c['beyond'] for c in cells)} cells, beyond severe in "
             f"{sum(c['beyond'] for c in cells)}; verdicts not monotone in {sum(not c['monotone'] for c in cells)}", ""]
    if figure:
        lines += [f"![frontier]({figure})", ""]
    lines += ["| kind | member | speed | load | smallest detectable size | change score by size run | monotone |",
              "|---|---|---|---|---|---|---|"]
    for c in sorted(cells, key=lambda c: (c["kind"], c["member"], c["speed_rpm"], c["load_Nm"])):
        scores = ", ".join(f"x{k}: {v:.2f}" for k, v in c["scores"].items())
        lines.append(f"| {c['kind']} | {c['member']} | {c['speed_rpm']:g} rpm | {c['load_Nm']:g} N·m | "
                     f"{_size_text(c)} | {scores} | {'yes' if c['monotone'] else '**no**'} |")
    return "\n".join(lines) + "\n"


#: the rule of the paired study the frontier replaces (docs/DETECTABILITY.md before issue 40): a cell was
#: detectable when the best indicator's paired rise reached 0.9
OLD_PAIRED_THRESHOLD = 0.9


def compare_markdown(result: dict, auc_csv: Path | str) -> str:
    """What moved, family by family, against an earlier paired study's AUC table (``drivetrain detectability``'s
    ``*_auc.csv``, one row per family, operating point and indicator): at each frontier cell's operating point,
    the earlier best paired rise of the family at its default size and its verdict, against the frontier's
    verdict at x1 (the default size: detectable when the frontier lies at or below it) and the change score
    there if x1 was run. Cells the earlier study did not run are left out."""
    import csv

    best: dict[tuple, float] = {}
    with open(auc_csv, newline="") as f:
        for r in csv.DictReader(f):
            if r.get("size") != "default":
                continue
            try:
                key = (r["kind"], r["member"], float(r["speed_rpm"]), float(r["load_Nm"]))
                a = float(r["paired_auc"])
            except (KeyError, ValueError):
                continue
            if math.isfinite(a):
                best[key] = max(best.get(key, 0.0), a)
    rows, moved = [], {"gained": 0, "lost": 0, "same": 0}
    for c in sorted(result["cells"], key=lambda c: (c["kind"], c["member"], c["speed_rpm"], c["load_Nm"])):
        key = (c["kind"], c["member"], float(c["speed_rpm"]), float(c["load_Nm"]))
        if key not in best:
            continue
        before = best[key] >= OLD_PAIRED_THRESHOLD
        now = (not c["beyond"]) and c["frontier_factor"] is not None and c["frontier_factor"] <= 1.0
        score = c["scores"].get("1")
        what = "same" if before == now else ("gained" if now else "lost")
        moved[what] += 1
        rows.append(f"| {c['kind']} | {c['member']} | {c['speed_rpm']:g} rpm | {c['load_Nm']:g} N·m | "
                    f"{best[key]:.2f} ({'yes' if before else 'no'}) | "
                    f"{'–' if score is None else f'{score:.2f}'} ({'yes' if now else 'no'}) | "
                    f"{_size_text(c)} | {what} |")
    head = [f"Against `{Path(auc_csv).name}` (the paired rule: best paired rise >= {OLD_PAIRED_THRESHOLD:g}), at the "
            f"default size: {moved['gained']} cells gained, {moved['lost']} lost, {moved['same']} the same. The frontier's "
            "verdict at x1 is read from its bisection (monotone cells: detectable at x1 when the frontier is at or "
            "below x1); its change score at x1 is shown where x1 was run.", "",
            "| kind | member | speed | load | before: best paired rise (detectable) | now: change score at x1 (detectable) "
            "| frontier | moved |", "|---|---|---|---|---|---|---|---|"]
    return "\n".join(head + rows) + "\n"


def plot(result: dict, study: FrontierStudy, path: Path) -> Path:
    """The frontier factor per family (rows) and operating point (columns); blank: beyond severe."""
    import numpy as np

    from drivetrain.run.outputs import _finish, _mpl

    plt = _mpl()
    fams = sorted({(c["kind"], c["member"]) for c in result["cells"]})
    ops = [(s, l) for s in study.speeds for l in study.loads]
    m = np.full((len(fams), len(ops)), np.nan)
    for c in result["cells"]:
        if not c["beyond"]:
            m[fams.index((c["kind"], c["member"])), ops.index((c["speed_rpm"], c["load_Nm"]))] = c["frontier_factor"]
    fig, ax = plt.subplots(figsize=(1.2 * len(ops) + 3, 0.35 * len(fams) + 2))
    im = ax.imshow(m, cmap="viridis_r", aspect="auto", vmin=min(study.ladder), vmax=max(study.ladder))
    ax.set_xticks(range(len(ops)), [f"{s:g} rpm\n{l:g} N·m" for s, l in ops], fontsize=7)
    ax.set_yticks(range(len(fams)), [f"{k} ({mb})" for k, mb in fams], fontsize=7)
    for i in range(len(fams)):
        for j in range(len(ops)):
            ax.text(j, i, "–" if not math.isfinite(m[i, j]) else f"x{m[i, j]:g}", ha="center", va="center", fontsize=6)
    fig.colorbar(im, ax=ax, label="smallest detectable size (x default)")
    return _finish(plt, fig, path, f"detectability frontier over {study.gearboxes} gearboxes ('–': beyond severe)")


__all__ = ["Cell", "FrontierStudy", "LADDER", "BEYOND", "next_index", "frontier_index", "monotone", "run_frontier",
           "run_features", "report_markdown", "compare_markdown", "plot"]
