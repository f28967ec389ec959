"""``drivetrain detectability``: which fault labels carry a signal, over gearboxes, for every indicator.

The study: each fault family (the seven kinds of gearcontact_fmu.fault_specs on the pinion and on the wheel,
at their default size and at :data:`SMALL` of it; the missing tooth has no size) at :data:`SPEEDS_RPM` x
:data:`LOADS_NM`, on ``gearboxes`` gearboxes (manufacturing, background and instrument seeds 0..N-1), and the
same gearboxes healthy at each operating point. Every run is the record scene
(``scenarios/validation/rig_record_500rpm.toml``: the rig's measured background, errors, compliance, profile
deviation, rig sensors) at the operating point; ``background = "off"`` runs the same without the background
(record_check.BACKGROUND_OFF), for what the background changes. Each gearbox runs healthy twice at each
operating point: once with the faulty runs' noise record (``scenario.noise_name``: faulty minus healthy is the
fault's own signal) and once with a noise record of its own, the **baseline** (:data:`BASELINE`), as a
monitoring system has it: measured on another day.

Where the fault sits: tooth 0 of its member. The manufacturing draw numbers the pair from its most loaded
pinion tooth (the most advanced one carries the most load), where a flank fracture starts
(docs/GEAR-CONTACT.md, "Pitch errors and the mild fault"); the same rule for every gearbox, chosen before any
run.

For each family, operating point and indicator (drivetrain.campaigns.features: TSA per shaft and the gear
metrics, the amplitudes at the characteristic frequencies, per torque transducer):
* **paired AUC**: over gearboxes, the fraction whose indicator rose with the fault against the gearbox's own
  baseline (a monitoring system);
* **unpaired AUC**: baselines against faulty runs over all gearboxes (a classifier that sees a population);
* **own effect**: the paired AUC against the healthy run with the same noise record: whether the fault moves
  an indicator the same way in every gearbox at all, noise aside. It is not detectability: with the noise
  shared, any consistent change however small separates (the first full study compared with it and found
  77 of 156 cells "detectable"; that comparison was replaced by the baseline before its report was
  committed, and the report shows both);
* **change score** (two-sided, rig.indicators.change_auc): the AUC of the faulty runs' absolute changes from
  their gearbox's baseline, |faulty - baseline|, against the healthy runs' |healthy - baseline| (the spread
  between two days without a fault): a change of either sign counts, and it must stand out of the day-to-day
  spread;
both rig.indicators; an indicator that falls with the fault reads below 0.5, so the report uses the
separability max(AUC, 1 - AUC). The rule (since issue 40): a label **carries a detectable signal** at an
operating point when its best indicator's change score is >= :data:`DETECTABLE` (0.9), or the chance level
of the best of the cell's indicators where that is higher (rig.indicators.chance_change); the report gives
the family-wise verdict too (the chance level of the best of every indicator of every cell). Before, the
rule was the paired separability (the fraction of gearboxes whose indicator *rose*): with manufacturing
errors a fault's sideband adds to an error sideband with a gearbox-dependent phase, so a line that moves
+-10 dB in every gearbox scored at chance; it is reported beside (``paired``, ``rose``). The older rule's
words, kept for the tables computed with it: a label carries a detectable signal at
an operating point when its best indicator's paired separability is >= :data:`DETECTABLE` (0.9), and is
**separable in a population** when its best unpaired separability is >= 0.9. The best of many indicators
reaches a separability by chance too; where that chance level (rig.indicators.chance_separability and
chance_unpaired: what 5 % of healthy-vs-healthy comparisons would reach, for this many gearboxes and
indicators) is higher than 0.9, it is the threshold (refined before any of the full study's results were
read: with 20 gearboxes and about 60 indicators the paired chance level is 0.9 itself).
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivetrain.campaigns.provenance import commit_line
from drivetrain.campaigns import GEARBOXES, record_check
from drivetrain.rig import indicators as ci
from drivetrain.rig.data import PAPER_LOADS_NM, PAPER_SPEEDS_RPM
from gearcontact_fmu.fault_specs import FAULT_KINDS

SPEEDS_RPM = PAPER_SPEEDS_RPM[1::2]     #: 500, 1000, 1500 rpm: every other of the paper's
LOADS_NM = PAPER_LOADS_NM[1:]           #: 0.71, 1.31 N·m: the paper's two heavier
MEMBERS = ("pinion", "wheel")
#: the small size: every size key of a kind at this fraction of its default
SMALL = 0.5
#: the rule: separability (max(AUC, 1 - AUC)) of the best indicator
DETECTABLE = 0.9
#: keys of a fault kind that are its size (the others place it)
SIZE_KEYS = ("width_mm", "depth_mm", "radius_mm", "length_mm", "height_mm", "depth_um")


@dataclass(frozen=True)
class Family:
    kind: str
    member: str
    size: str                   # "default" | "small" | "x<factor>" (every size key at factor x its default)

    @property
    def name(self) -> str:
        return f"{self.kind}_{self.member}_{self.size}"

    @property
    def factor(self) -> float:
        """The size as a factor of the kind's default sizes."""
        if self.size == "default":
            return 1.0
        if self.size == "small":
            return SMALL
        if self.size.startswith("x"):
            return float(self.size[1:])
        raise ValueError(f"size {self.size!r}: default, small or x<factor>")

    def fault(self) -> dict:
        """The fault specification: tooth 0 of the member, the kind's defaults, every size key scaled by
        :attr:`factor`."""
        spec = {"kind": self.kind, "member": self.member, "tooth": 0}
        if self.factor != 1.0:
            for k, v in FAULT_KINDS[self.kind].items():
                if k in SIZE_KEYS and isinstance(v, (int, float)) and v:
                    spec[k] = float(v) * self.factor
        return spec


def families(kinds=None, members=MEMBERS, sizes=("default", "small")) -> list[Family]:
    """The studied families; the missing tooth only at its one size."""
    out = []
    for kind in kinds or tuple(FAULT_KINDS):
        for member in members:
            for size in sizes:
                if size == "small" and not any(k in SIZE_KEYS for k in FAULT_KINDS[kind]):
                    continue
                out.append(Family(kind, member, size))
    return out


#: the healthy run of a gearbox measured with a noise record of its own (the monitoring baseline)
BASELINE = "baseline"


def case_names(fam: Family | str | None, speed: float, load: float, gearbox: int) -> tuple[str, str]:
    """(run name, noise name) of a faulty (``fam``) or healthy (None) run, which share one noise record, or of
    the gearbox's healthy baseline (:data:`BASELINE`), measured with another."""
    if fam == BASELINE:
        op = f"{speed:g}rpm_{load:g}Nm_gb{gearbox}"
        return f"{BASELINE}_{op}", f"{BASELINE}_noise_{op}"
    op = f"{speed:g}rpm_{load:g}Nm_gb{gearbox}"
    return (f"{fam.name if fam else 'healthy'}_{op}", f"noise_{op}")


@dataclass
class Study:
    """What a study runs: its families, operating points, gearboxes, run length and background."""

    families: list
    speeds: tuple = SPEEDS_RPM
    loads: tuple = LOADS_NM
    gearboxes: int = GEARBOXES
    duration_s: float = 7.0
    settle_s: float = 1.0
    background: str = "on"
    overrides: tuple = field(default_factory=tuple)

    def scenes(self) -> list:
        from drivetrain.scene.load import load_scene

        common = [f"time.duration_s={self.duration_s}", f"time.settle_s={self.settle_s}", "outputs.plots=false",
                  "outputs.aalto_csv=false", "outputs.variables=[]"]
        if self.background == "off":
            common += list(record_check.BACKGROUND_OFF)
        out = []
        for speed in self.speeds:
            for load in self.loads:
                for gb in range(self.gearboxes):
                    seeds = [f"manufacturing.seed={gb}", f"background.seed={gb}", f"instruments.seed={gb}",
                             f"operating_point.drive_speed_rpm={speed}", f"operating_point.load_torque_Nm={load}"]
                    for fam in [BASELINE, None, *self.families]:
                        name, noise = case_names(fam, speed, load, gb)
                        gear = (['gear.health="healthy"'] if fam is None or fam == BASELINE else
                                ['gear.health="faults"', f"gear.faults=[{_toml_inline(fam.fault())}]"])
                        out.append(load_scene(record_check.RECORD_SCENE, overrides=[
                            *common, *seeds, *gear, *self.overrides, f'scenario.name="{name}"',
                            f'scenario.noise_name="{noise}"']))
        return out


def _toml_inline(d: dict) -> str:
    items = []
    for k, v in d.items():
        items.append(f'{k} = "{v}"' if isinstance(v, str) else f"{k} = {v!r}")
    return "{" + ", ".join(items) + "}"


def auc_table(rows: list[dict], study: Study) -> list[dict]:
    """Per family, operating point and indicator column over the gearboxes: the paired AUC against each
    gearbox's healthy baseline (its own noise record: what a monitoring system compares), the paired AUC
    against the healthy run with the faulty run's noise record (the fault's own effect: does the indicator
    move the same way in every gearbox, noise aside), and the unpaired AUC (baselines against faulty runs)."""
    by_name = {r["run"]: r for r in rows}
    cols = sorted({k for r in rows for k in r if "." in k and k.split(".")[0].split("_")[0] in
                   (*ci.METRICS, "amp")})
    out = []
    for fam in study.families:
        for speed in study.speeds:
            for load in study.loads:
                trios = []
                for gb in range(study.gearboxes):
                    f = by_name.get(case_names(fam, speed, load, gb)[0])
                    h = by_name.get(case_names(None, speed, load, gb)[0])
                    b = by_name.get(case_names(BASELINE, speed, load, gb)[0])
                    if f is not None and h is not None and b is not None:
                        trios.append((b, h, f))
                for col in cols:
                    bv, hv, fv = (np.array([_num(t[i].get(col)) for t in trios]) for i in range(3))
                    n = len(trios)
                    out.append({"family": fam.name, "kind": fam.kind, "member": fam.member, "size": fam.size,
                                "speed_rpm": speed, "load_Nm": load, "indicator": col, "n": n,
                                "change_auc": ci.change_auc(bv, hv, fv) if n else float("nan"),
                                "paired_auc": ci.paired_auc(bv, fv) if n else float("nan"),
                                "same_noise_auc": ci.paired_auc(hv, fv) if n else float("nan"),
                                "unpaired_auc": ci.auc(bv, fv) if n else float("nan")})
    return out


def read_table_csv(path: Path) -> list[dict]:
    """An AUC table written by :func:`write_table_csv` (another study's, for :func:`what_moved`)."""
    num = ("speed_rpm", "load_Nm", "change_auc", "paired_auc", "same_noise_auc", "unpaired_auc")
    with open(path, newline="") as fh:
        return [{**r, **{k: float(r[k]) for k in num if k in r}, "n": int(r["n"])} for r in csv.DictReader(fh)]


def what_moved(these: list[dict], other: list[dict], other_label: str) -> list[str]:
    """Markdown: the verdicts of this study against another's (``other``: its verdict rows, e.g. the same study
    with the background off), cell by cell where both have the cell, and per family."""
    key = lambda r: (r["family"], r["speed_rpm"], r["load_Nm"])  # noqa: E731
    mine, theirs = {key(r): r for r in these}, {key(r): r for r in other}
    common = sorted(set(mine) & set(theirs))
    if not common:
        return [f"No cell in common with {other_label}."]
    d_pair = [mine[k]["paired"] - theirs[k]["paired"] for k in common]
    d_unp = [mine[k]["unpaired"] - theirs[k]["unpaired"] for k in common]
    both = sum(mine[k]["detectable"] and theirs[k]["detectable"] for k in common)
    lost = sum(theirs[k]["detectable"] and not mine[k]["detectable"] for k in common)
    won = sum(mine[k]["detectable"] and not theirs[k]["detectable"] for k in common)
    lines = [f"Against {other_label}, over the {len(common)} cells both studies ran: detectable (paired) in both "
             f"{both}, lost here {lost}, gained here {won}; separable in a population here "
             f"{sum(mine[k]['population'] for k in common)}, there {sum(theirs[k]['population'] for k in common)}. "
             f"Best paired separability here minus there: median {np.median(d_pair):+.2f} (p10 "
             f"{np.percentile(d_pair, 10):+.2f}, p90 {np.percentile(d_pair, 90):+.2f}); unpaired: median "
             f"{np.median(d_unp):+.2f} (p10 {np.percentile(d_unp, 10):+.2f}, p90 {np.percentile(d_unp, 90):+.2f}).", "",
             "| family | cells | detectable here | there | population here | there | median change, paired | "
             "unpaired |", "|---|---|---|---|---|---|---|---|"]
    for fam in sorted({k[0] for k in common}):
        ks = [k for k in common if k[0] == fam]
        lines.append(f"| {fam} | {len(ks)} | {sum(mine[k]['detectable'] for k in ks)} | "
                     f"{sum(theirs[k]['detectable'] for k in ks)} | {sum(mine[k]['population'] for k in ks)} | "
                     f"{sum(theirs[k]['population'] for k in ks)} | "
                     f"{np.median([mine[k]['paired'] - theirs[k]['paired'] for k in ks]):+.2f} | "
                     f"{np.median([mine[k]['unpaired'] - theirs[k]['unpaired'] for k in ks]):+.2f} |")
    return lines


def _num(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def verdicts(table: list[dict]) -> list[dict]:
    """Per family and operating point: the best indicator by two-sided change score (:func:`ci.change_auc`),
    by paired ("rose") and by unpaired separability, and the rule's verdicts: ``detectable`` when the best
    change score reaches max(DETECTABLE, the chance level of the best of this cell's indicators), and
    ``detectable_familywise`` against the chance level of the best of every indicator of every cell of the
    table (the study as one family of tests). A table of a study before the two-sided score (no
    ``change_auc``) keeps its old rule: ``detectable`` is its paired verdict, ``rule`` says which."""
    groups: dict = {}
    for row in table:
        groups.setdefault((row["family"], row["speed_rpm"], row["load_Nm"]), []).append(row)
    n_tests = sum(1 for r in table if math.isfinite(r.get("paired_auc", float("nan"))))
    out = []
    for (fam, speed, load), rs in groups.items():
        ok = [r for r in rs if math.isfinite(r["paired_auc"])]
        if not ok:
            continue
        bp = max(ok, key=lambda r: ci.separability(r["paired_auc"]))
        bu = max(ok, key=lambda r: ci.separability(r["unpaired_auc"]))
        own = max((ci.separability(r.get("same_noise_auc", float("nan"))) for r in ok), default=float("nan"))
        need_p = max(DETECTABLE, ci.chance_separability(bp["n"], len(ok)))
        need_u = max(DETECTABLE, ci.chance_unpaired(bp["n"], bp["n"], len(ok)))
        two_sided = any(math.isfinite(r.get("change_auc", float("nan"))) for r in ok)
        if two_sided:
            bc = max(ok, key=lambda r: _num(r.get("change_auc")) if math.isfinite(_num(r.get("change_auc"))) else -1.0)
            change = _num(bc["change_auc"])
            need_c = max(DETECTABLE, ci.chance_change(bc["n"], len(ok)))
            need_fw = max(DETECTABLE, ci.chance_change(bc["n"], n_tests))
        else:
            bc, change, need_c, need_fw = bp, float("nan"), float("nan"), float("nan")
        rose = ci.separability(bp["paired_auc"]) >= need_p
        out.append({"family": fam, "speed_rpm": speed, "load_Nm": load, "n": bp["n"],
                    "best_change": bc["indicator"], "change": change, "need_change": need_c,
                    "need_change_familywise": need_fw,
                    "best_paired": bp["indicator"], "paired": ci.separability(bp["paired_auc"]),
                    "best_unpaired": bu["indicator"], "unpaired": ci.separability(bu["unpaired_auc"]),
                    "need_paired": need_p, "need_unpaired": need_u, "same_noise": own,
                    "rule": "two-sided change" if two_sided else "paired rise (before issue 40)",
                    "detectable": change >= need_c if two_sided else rose,
                    "detectable_familywise": change >= need_fw if two_sided else rose,
                    "rose": rose,
                    "population": ci.separability(bu["unpaired_auc"]) >= need_u})
    return out


def write_table_csv(table: list[dict], path: Path) -> Path:
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(table[0]))
        w.writeheader()
        w.writerows(table)
    return path


def plot(verdict_rows: list[dict], study: Study, path: Path) -> Path:
    """Best paired and unpaired separability per family (rows) and operating point (columns)."""
    from drivetrain.run.outputs import _finish, _mpl

    plt = _mpl()
    fams = [f.name for f in study.families]
    ops = [(s, l) for s in study.speeds for l in study.loads]
    fig, axes = plt.subplots(1, 3, figsize=(14, 0.35 * len(fams) + 2.5), gridspec_kw={"width_ratios": [1, 1, 0.03]})
    for ax, key, title in ((axes[0], "paired", "paired (the gearbox's own healthy baseline)"),
                           (axes[1], "unpaired", "unpaired (any healthy gearbox)")):
        m = np.full((len(fams), len(ops)), np.nan)
        for r in verdict_rows:
            m[fams.index(r["family"]), ops.index((r["speed_rpm"], r["load_Nm"]))] = r[key]
        im = ax.imshow(m, vmin=0.5, vmax=1.0, cmap="viridis", aspect="auto")
        ax.set_xticks(range(len(ops)), [f"{s:g} rpm\n{l:g} N·m" for s, l in ops], fontsize=7)
        ax.set_yticks(range(len(fams)), fams, fontsize=7)
        ax.set_title(f"best indicator's separability, {title}", fontsize=9)
        for i in range(len(fams)):
            for j in range(len(ops)):
                if np.isfinite(m[i, j]):
                    ax.text(j, i, f"{m[i, j]:.2f}", ha="center", va="center", fontsize=6,
                            color="w" if m[i, j] < 0.8 else "k")
    axes[1].set_yticks(range(len(fams)), [])
    fig.colorbar(im, cax=axes[2], label="max(AUC, 1 - AUC)")
    return _finish(plt, fig, path, f"detectability over {study.gearboxes} gearboxes (background {study.background})")


def report_markdown(verdict_rows: list[dict], study: Study, meta: dict, figure: str | None, table_csv: str,
                    moved: list[str] | None = None) -> str:
    n_det = sum(r["detectable"] for r in verdict_rows)
    n_pop = sum(r["population"] for r in verdict_rows)
    lines = ["# Detectability of the fault labels over gearboxes", "",
             "Generated by `drivetrain detectability` (src/drivetrain/campaigns/detectability.py); do not edit by "
             "hand. The study, the indicators, the AUCs and the rule: that module's docstring.", "",
             f"- command: `{meta.get('command', '')}`",
             commit_line(),
             f"- runs: {meta.get('n_runs')} of {study.duration_s:g} s (settle {study.settle_s:g} s), "
             f"{study.gearboxes} gearboxes, background {study.background}",
             f"- wall time: {meta.get('wall_time_s', float('nan')) / 60:.1f} min on {meta.get('workers')} worker(s)"
             + (f" (this invocation: {meta['reused']} of the runs reused from an earlier one; the runs' own times "
                f"add up to {meta.get('runs_time_s', 0.0) / 60:.0f} min)" if meta.get("reused") else ""),
             f"- rule: detectable when the best indicator's two-sided change score (|faulty - baseline| against "
             f"|healthy - baseline| over gearboxes, rig.indicators.change_auc) >= {DETECTABLE}, raised to the chance "
             f"level of the best of the cell's indicators where that is higher (here "
             f"{max((r['need_change'] for r in verdict_rows), default=float('nan')):.2f}), and family-wise against "
             f"the best of every indicator of every cell ("
             f"{max((r['need_change_familywise'] for r in verdict_rows), default=float('nan')):.2f}); the paired "
             f"rise (the rule before issue 40: the fraction of gearboxes whose indicator rose, >= "
             f"{max((r['need_paired'] for r in verdict_rows), default=float('nan')):.2f}) and the unpaired "
             f"separability (a population, >= {max((r['need_unpaired'] for r in verdict_rows), default=float('nan')):.2f})"
             " are reported beside it",
             f"- outcome: {n_det} of {len(verdict_rows)} family x operating point cells carry a detectable change "
             f"({sum(r.get('detectable_familywise', False) for r in verdict_rows)} family-wise; the paired rise: "
             f"{sum(r.get('rose', False) for r in verdict_rows)}), {n_pop} are separable in a population",
             f"- every indicator's AUCs: [{table_csv}]({table_csv})", ""]
    if figure:
        lines += [f"![detectability]({figure})", ""]
    if moved:
        lines += ["## What the measured background moved", "", *moved, ""]
    lines += ["| family | speed | load | best change indicator | change (two-sided) | paired rise | "
              "best unpaired indicator | unpaired | own effect (same noise) | verdict |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(verdict_rows, key=lambda r: (r["family"], r["speed_rpm"], r["load_Nm"])):
        verdict = ("detectable, separable in a population" if r["population"] else
                   "detectable against its own gearbox only" if r["detectable"] else "**no detectable signal**")
        lines.append(f"| {r['family']} | {r['speed_rpm']:g} rpm | {r['load_Nm']:g} N·m | {r.get('best_change', '–')} | "
                     f"{r.get('change', float('nan')):.2f} | {r['paired']:.2f} | {r['best_unpaired']} | "
                     f"{r['unpaired']:.2f} | {r.get('same_noise', float('nan')):.2f} | {verdict} |")
    return "\n".join(lines) + "\n"


__all__ = ["Family", "Study", "families", "case_names", "BASELINE", "auc_table", "verdicts", "plot", "report_markdown",
           "write_table_csv", "read_table_csv", "what_moved", "SPEEDS_RPM", "LOADS_NM", "DETECTABLE", "SMALL"]
