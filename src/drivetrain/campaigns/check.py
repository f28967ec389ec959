"""Scenes as regression tests: run scenes and check them against their ``[expect]`` section and their
baseline (``drivetrain check``), or store baselines (``drivetrain baseline``).

- :func:`check_file` / :func:`check_scenes`: run every case (a scene file is run in this process; a grid
  file's cases, or several scenes, through :func:`drivetrain.campaigns.sweep.run_sweep`), evaluate the expectations
  (:mod:`drivetrain.scene.expect`) and compare with the baseline (:mod:`drivetrain.campaigns.baseline`) when there is
  one; for each failing case write ``<out>/<case>/check_<case>.png`` (the signals concerned against
  the baseline). Returns a :class:`CheckReport` (``ok`` only if every case holds).
- :func:`baseline_file`: run every case of a scene file and store the compact references.

Nothing here prints: progress goes to the ``log`` callback.
"""
from __future__ import annotations

import contextlib
import json
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from drivetrain.campaigns import baseline as B
from drivetrain.scene.expect import Outcome, _fmt, evaluate
from drivetrain.cosim import ConfigurationError, CosimError
from drivetrain.run.outputs import jsonable, read_hdf5, run_title
from drivetrain.run.runner import RunFailedError, run_scene
from drivetrain.scene.load import Scene, load_scenes
from drivetrain.campaigns.sweep import run_sweep


@dataclass
class CaseRun:
    """What a check needs of one run: summary, full-rate signals (None if the run did not start)."""

    scene: Scene
    summary: dict | None
    time: np.ndarray | None = None
    signals: dict | None = None
    units: dict | None = None
    out_dir: Path | None = None
    error: str | None = None               # a run that did not start or crashed (not an FMU failure)


@dataclass
class CaseCheck:
    """The check of one case."""

    name: str
    outcomes: list[Outcome] = field(default_factory=list)
    status: str | None = None              # the run's status ("ok" | "failed"; None: did not run)
    baseline: str | None = None            # the baseline file compared against (None: none)
    scene_changes: list[str] = field(default_factory=list)
    version_changes: list[str] = field(default_factory=list)
    plots: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None and all(o.ok for o in self.outcomes)

    @property
    def failures(self) -> list[Outcome]:
        return [o for o in self.outcomes if not o.ok]

    @property
    def n_checks(self) -> int:
        return len(self.outcomes)

    def report(self) -> str:
        """A failure report (metric, expected, actual, tolerance for every failing check)."""
        lines = [f"{self.name}: {len(self.failures)} of {self.n_checks} checks failed"
                 + (f" (baseline {self.baseline})" if self.baseline else "")]
        if self.error:
            lines.append(f"  run error: {self.error}")
        for o in self.failures:
            lines.append("  " + o.message.split(": ", 1)[1])
        if self.scene_changes:
            lines.append("  scene differs from the baseline: " + "; ".join(self.scene_changes))
        if self.version_changes:
            lines.append("  versions differ from the baseline: " + "; ".join(self.version_changes))
        for p in self.plots:
            lines.append(f"  plot: {p}")
        return "\n".join(lines)


@dataclass
class CheckReport:
    cases: list[CaseCheck]

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.cases)

    @property
    def failed(self) -> list[CaseCheck]:
        return [c for c in self.cases if not c.ok]

    def to_dict(self) -> dict:
        return jsonable({"ok": self.ok, "cases": [
            {"name": c.name, "ok": c.ok, "status": c.status, "baseline": c.baseline, "error": c.error,
             "scene_changes": c.scene_changes, "version_changes": c.version_changes, "plots": c.plots,
             "notes": c.notes,
             "outcomes": [{"key": o.key, "source": o.source, "ok": o.ok, "expected": o.expected,
                           "actual": o.actual, "tolerance": o.tolerance, "deviation": o.deviation,
                           "note": o.note} for o in c.outcomes]} for c in self.cases]})


# --------------------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------------------


def run_case(scene: Scene, out_dir: str | Path | None = None, *, fmu_dir: str | Path | None = None,
             backend: str = "fmi", plots: bool = False, progress: bool = False) -> CaseRun:
    """Run one scene in this process; an FMU failure gives the completed part (status "failed").
    ``progress``: the run's bars (the loop's after 2 s)."""

    try:
        res = run_scene(scene, out_dir, backend=backend, progress=progress, fmu_dir=fmu_dir, plots=plots,
                        log=lambda m: None)
    except RunFailedError as exc:
        res = exc.result
    except (ConfigurationError, CosimError) as exc:
        return CaseRun(scene, None, error=f"{type(exc).__name__}: {exc}")
    return CaseRun(scene, res.summary, res.time, res.signals, res.units, Path(out_dir) if out_dir else None)


def _read_run(scene: Scene, rec: dict) -> CaseRun:
    summ = rec.get("summary")
    if not summ or not Path(summ).is_file():
        return CaseRun(scene, None, error=rec.get("error") or "the run wrote no summary")
    summary = json.loads(Path(summ).read_text())
    sig = rec.get("signals")
    if sig and Path(sig).is_file():
        h = read_hdf5(sig)
        return CaseRun(scene, summary, h["time"], h["signals"], h["units"], Path(rec["out_dir"]))
    return CaseRun(scene, summary, out_dir=Path(rec["out_dir"]))


def run_cases(scenes: list[Scene], out_dir: str | Path, *, fmu_dir: str | Path | None = None, backend: str = "fmi",
              workers: int | None = None, address: str | None = None, progress: bool = False,
              log: Callable[[str], None] | None = None) -> list[CaseRun]:
    """Run the scenes: one in this process, several through the sweep machinery (processes or Dask)."""
    out = Path(out_dir)
    if len(scenes) == 1 and address is None:
        if log:
            log(f"running {scenes[0].name}")
        return [run_case(scenes[0], out / scenes[0].name, fmu_dir=fmu_dir, backend=backend, progress=progress)]

    man = run_sweep(scenes, out, workers=workers, address=address, backend=backend, fmu_dir=fmu_dir,
                    plots=False, progress=progress)
    by_name = {r["name"]: r for r in man["runs"]}
    return [_read_run(s, by_name.get(s.name, {"out_dir": str(out / s.name)})) for s in scenes]


# --------------------------------------------------------------------------------------------------
# Checking
# --------------------------------------------------------------------------------------------------


def _expectation_bands(scene: Scene, failures: list[Outcome]) -> dict:
    """channel -> [(label, lo, hi)] of failed mean/min/max-like expectations, for the plot."""
    bands: dict[str, list] = {}
    for e in scene.expect.items if scene.expect is not None else ():
        if not any(o.key == e.key for o in failures):
            continue
        ch = e.channel or (str(e.path[1]) if e.kind == "summary" and len(e.path) == 3
                           and e.path[0] in ("torque", "channels") else None)
        stat = e.stat or (e.path[2] if e.kind == "summary" and len(e.path) == 3 else None)
        if ch is None or stat not in ("mean", "min", "max"):
            continue
        if e.value is not None and e.numeric:
            if not np.isfinite(e.value):
                continue
            t = e.tolerance() or 0.0
            bands.setdefault(ch, []).append((f"expected {stat}", e.value - t, e.value + t))
        elif e.value is None:
            bands.setdefault(ch, []).append((f"expected {stat} range", e.min, e.max))
    return bands


def check_run(run: CaseRun, *, base: B.Entry | None = None, baseline_file: str | Path | None = None,
              plot_dir: str | Path | None = None, plots: bool = True) -> CaseCheck:
    """Evaluate one run: expectations, then the baseline entry if given; a plot for a failure."""
    scene = run.scene
    cc = CaseCheck(scene.name, baseline=str(baseline_file) if base is not None and baseline_file else None)
    if run.summary is None:
        cc.error = run.error or "the run did not start"
        cc.outcomes.append(Outcome(scene.name, "run", "run", False, "a completed run", None, "",
                                   note=cc.error))
        return cc
    cc.status = run.summary.get("status")
    spec = scene.expect if scene.expect is not None else ()
    cc.outcomes += evaluate(spec, run.summary, run.time, run.signals, scene_name=scene.name)
    cur = None
    if base is not None:
        if run.time is None or run.signals is None:
            cc.notes.append("no signals to compare with the baseline")
        else:
            cur = B.make_entry(scene, run.summary, run.time, run.signals, run.units,
                               decimation=base.decimation, channels=list(base.signals))
            opts = scene.expect.options if scene.expect is not None else None
            cc.outcomes += B.compare(base, cur, opts)
            cc.scene_changes = B.scene_changes(base, scene)
            cc.version_changes = B.version_changes(base)
    if not cc.outcomes:
        cc.notes.append("nothing to check: no [expect] section and no baseline")
    if plots and not cc.ok and plot_dir is not None and run.time is not None and run.signals is not None:
        chans = list(dict.fromkeys(o.channel for o in cc.failures if o.channel and o.channel in run.signals))
        if not chans:
            from drivetrain.rig.data import TORQUE_SENSORS

            chans = [c for c in TORQUE_SENSORS if c in run.signals]
        if cur is None:
            cur = B.make_entry(scene, run.summary, run.time, run.signals, run.units, channels=chans)
        try:
            p = Path(plot_dir) / f"check_{scene.name}.png"
            p.parent.mkdir(parents=True, exist_ok=True)
            what = f"{len(cc.failures)} check(s) failed" + (" (dashed: baseline)" if base is not None else "")
            B.plot_against_baseline(p, cur, base, chans, title=run_title(scene, what),
                                    expectations=_expectation_bands(scene, cc.failures))
            cc.plots.append(str(p))
        except Exception as exc:  # noqa: BLE001 - the plot is a help, the verdict stands without it
            cc.notes.append(f"no plot: {type(exc).__name__}: {exc}")
    return cc


def load_baseline_for(path: str | Path, scenes: list[Scene], baseline_dir: str | Path | None = None):
    """(baseline file, {case: Entry}) for a scene file, or (path, {}) if there is none."""
    opts = scenes[0].expect.options if scenes and scenes[0].expect is not None else None
    bp = B.baseline_path(path, opts, baseline_dir)
    if not bp.is_file():
        return bp, {}
    return bp, B.read_baseline(bp)["cases"]


def check_scenes(path: str | Path, scenes: list[Scene], *, out_dir: str | Path | None = None,
                 baseline_dir: str | Path | None = None, fmu_dir: str | Path | None = None, backend: str = "fmi",
                 workers: int | None = None, address: str | None = None, plots: bool = True,
                 progress: bool = False, log: Callable[[str], None] | None = None) -> CheckReport:
    """Run and check these cases of the scene file ``path`` (e.g. a subset of a grid)."""
    bp, cases = load_baseline_for(path, scenes, baseline_dir)
    with _run_dir(out_dir, "drivetrain-check-") as (out, keep):
        runs = run_cases(scenes, out, fmu_dir=fmu_dir, backend=backend, workers=workers, address=address,
                         progress=progress, log=log)
        report = []
        for r in runs:
            base = cases.get(r.scene.name)
            cc = check_run(r, base=base, baseline_file=bp, plots=plots and keep,
                           plot_dir=Path(out) / r.scene.name)
            if cases and base is None:
                cc.notes.append(f"no baseline for this case in {bp}")
            report.append(cc)
    return CheckReport(report)


@contextlib.contextmanager
def _run_dir(out_dir, prefix: str):
    """(directory for the runs, whether it is kept): ``out_dir``, or a temporary one removed afterwards."""
    if out_dir is not None:
        yield out_dir, True
        return
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        yield tmp, False


def check_file(path: str | Path, overrides=(), *, only: list[str] | None = None, **kw) -> CheckReport:
    """Run and check every case of a scene or grid file (``only``: fnmatch patterns of case names)."""
    scenes = select(load_scenes(path, overrides), only)
    return check_scenes(path, scenes, **kw)


def select(scenes: list[Scene], only: list[str] | None) -> list[Scene]:
    if not only:
        return scenes
    import fnmatch

    return [s for s in scenes if any(fnmatch.fnmatchcase(s.name, p) for p in only)]


def format_table(report: CheckReport, all_rows: bool = False, width: int = 60) -> str:
    """The table of a check: every failing check (``all_rows``: every check) with case, metric, source,
    expected, actual, tolerance and deviation; then per case its verdict, scene/version changes, plots."""
    def cut(s: str, n: int) -> str:
        s = str(s)
        return s if len(s) <= n else s[: n - 1] + "…"

    rows = []
    for c in report.cases:
        for o in c.outcomes:
            if all_rows or not o.ok:
                act = "missing" if o.actual is None else (f"{o.actual:.6g}" if isinstance(o.actual, float)
                                                          else _fmt(o.actual))
                rows.append(("ok" if o.ok else "FAIL", c.name, cut(o.key, width), o.source, cut(o.expected, 30),
                             cut(act, 16), cut(o.tolerance, 24), cut(o.deviation or o.note, 40)))
    lines = []
    if rows:
        head = ("", "case", "check", "source", "expected", "actual", "tolerance", "deviation")
        w = [max(len(str(r[i])) for r in rows + [head]) for i in range(len(head))]
        lines.append("  ".join(h.ljust(w[i]) for i, h in enumerate(head)).rstrip())
        for r in rows:
            lines.append("  ".join(str(x).ljust(w[i]) for i, x in enumerate(r)).rstrip())
        lines.append("")
    for c in report.cases:
        verdict = "ok" if c.ok else "FAILED"
        nb = sum(o.source == "baseline" for o in c.outcomes)
        lines.append(f"{c.name}: {verdict}: {c.n_checks - len(c.failures)}/{c.n_checks} checks hold"
                     + (f" ({nb} against {c.baseline})" if c.baseline else "")
                     + (f"; run status {c.status}" if c.status not in (None, "ok") else ""))
        if c.error:
            lines.append(f"  run error: {c.error}")
        for o in c.failures:
            if o.note and o.source != "baseline":
                lines.append(f"  {o.key}: {o.note}")
        if c.scene_changes:
            lines.append("  scene differs from the baseline: " + "; ".join(c.scene_changes))
        if c.version_changes and not c.ok:
            lines.append("  versions differ from the baseline: " + "; ".join(c.version_changes))
        for n in c.notes:
            lines.append(f"  note: {n}")
        for p in c.plots:
            lines.append(f"  plot: {p}")
    n_ok = sum(c.ok for c in report.cases)
    lines.append(f"{n_ok}/{len(report.cases)} cases hold")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------------
# Baselines
# --------------------------------------------------------------------------------------------------


@dataclass
class BaselineResult:
    path: Path
    stored: list[str]
    failed: dict[str, str]                 # case -> why it was not stored


def baseline_file(path: str | Path, overrides=(), *, only: list[str] | None = None,
                  baseline_dir: str | Path | None = None, out_dir: str | Path | None = None,
                  fmu_dir: str | Path | None = None, backend: str = "fmi", workers: int | None = None,
                  address: str | None = None, progress: bool = False, allow_failed: bool = False,
                  log: Callable[[str], None] | None = None) -> BaselineResult:
    """Run every case (or ``only``) of a scene file and store their compact references in its baseline
    file (cases already there and not run are kept). A failed run is not stored unless ``allow_failed``."""
    scenes = select(load_scenes(path, overrides), only)
    opts = scenes[0].expect.options if scenes and scenes[0].expect is not None else None
    bp = B.baseline_path(path, opts, baseline_dir)
    with _run_dir(out_dir, "drivetrain-baseline-") as (out, _):
        runs = run_cases(scenes, out, fmu_dir=fmu_dir, backend=backend, workers=workers, address=address,
                         progress=progress, log=log)
        entries, failed = [], {}
        for r in runs:
            if r.summary is None or r.time is None or r.signals is None:
                failed[r.scene.name] = r.error or "no signals"
            elif r.summary.get("status") != "ok" and not allow_failed:
                f = r.summary.get("failure") or {}
                failed[r.scene.name] = f"the run failed at t = {f.get('time_s')} s: {f.get('cause')}"
            else:
                entries.append(B.make_entry(r.scene, r.summary, r.time, r.signals, r.units))
    if entries:
        B.write_baseline(bp, entries, source=Path(path).resolve())
    return BaselineResult(bp, [e.name for e in entries], failed)


__all__ = ["CaseRun", "CaseCheck", "CheckReport", "BaselineResult", "run_case", "run_cases", "check_run",
           "check_scenes", "check_file", "baseline_file", "load_baseline_for", "select"]
