"""The accuracy-cost study: run every studied scene with every setting, compare each run with its scene's
reference (:func:`drivetrain.run.accuracy.compare`), and write the results (shipped with the package), the
report (docs/ACCURACY-COST.md) and one Pareto plot per scene. ``drivetrain accuracy-cost`` is a thin
shell over :func:`run_study`, :func:`report_markdown` and :func:`plot_pareto`.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

from drivetrain.campaigns.provenance import commit_line
from drivetrain.run.accuracy import (DEFAULT, REFERENCE, SETTINGS, STUDY_DURATION_S, STUDY_SCENES, STUDY_SETTLE_S, Setting, compare,
                                 health_class, pair_of, run_name, study_overrides, within)
from drivetrain.run.outputs import read_hdf5
from drivetrain.run.runner import assemble_scene
from drivetrain.scene.load import ScenarioError, load_scene
from drivetrain.models.stability import contact_gears, contact_inputs
from drivetrain.campaigns.sweep import run_sweep
from gearcontact_fmu.contact_map import get_map

# ------------------------------------------------------------------------------------------------
# The study
# ------------------------------------------------------------------------------------------------


def study_scenes(scenes=None, settings=None, extra: tuple[str, ...] = ()) -> tuple[list, dict]:
    """The runs of the study as validated Scenes, and {(scene, setting): why} for the combinations the
    scene schema refuses (an analytic or ideal gear cannot carry a fault)."""
    names = list(scenes or STUDY_SCENES)
    wanted = list(dict.fromkeys([REFERENCE, *(settings or SETTINGS)]))
    unknown = [n for n in names if n not in STUDY_SCENES] + [s for s in wanted if s not in SETTINGS]
    if unknown:
        raise ValueError(f"unknown studied scene or setting: {', '.join(unknown)} (scenes: {', '.join(STUDY_SCENES)}; "
                         f"settings: {', '.join(SETTINGS)})")
    runs, refused = [], {}
    for sc in names:
        for st in wanted:
            path, over = study_overrides(sc, st, extra)
            try:
                runs.append(load_scene(path, over))
            except ScenarioError as exc:
                refused[(sc, st)] = "; ".join(f"{k}: {why}" for k, _, why in exc.problems)
    return runs, refused


def _map_build_s(spec) -> float | None:
    """The contact map's own tabulation time (recorded in the cached map) of a table gear, else None."""
    for comp in contact_gears(spec):
        inp = contact_inputs(comp)
        if inp["fidelity"] != "table":
            return None
        cmap = get_map(inp["gear"], inp["pcm"], inp["resolution"], inp["health"], inp["files"] or None,
                       mesh_units=inp["mesh_units"], build=False, fault_kwargs=inp["fault_kwargs"], grid=inp["grid"])
        return float(cmap.info.get("build_seconds", 0.0)) if cmap is not None else None
    return None


def evaluate(run_dir: Path, records: list[dict], scenes: list, refused: dict, meta: dict) -> dict:
    """The study's results from its run directories: per studied scene and setting, the status, the
    errors against the reference (:func:`compare`) and the costs. ``records``: :func:`_records_on_disk`
    (each with its run's summary)."""
    by_name = {r["name"]: r for r in records}
    scene_of = {s.name: s for s in scenes}
    out = {"meta": meta, "scenes": {}}
    # the studied scenes with at least one run on disk
    studied = list(dict.fromkeys(n.split("__")[0] for n in by_name))
    for sc in studied:
        _, over, what = STUDY_SCENES[sc]
        ref_scene = scene_of.get(run_name(sc, REFERENCE))
        rec = {"what": what, "rows": {}}
        if ref_scene is not None:
            rec["speed_rpm"] = ref_scene.operating_point.final_speed_rpm
            rec["health_class"] = health_class(ref_scene)
            pair = pair_of(ref_scene)
            if pair is not None:
                rec["pair"] = pair
        ref = None
        ref_rec = by_name.get(run_name(sc, REFERENCE))
        if ref_rec and ref_rec.get("status") == "ok":
            h = read_hdf5(run_dir / run_name(sc, REFERENCE) / "signals.h5")
            ref = {"time": h["time"], **h["signals"]}
        for st in SETTINGS:
            key = run_name(sc, st)
            if (sc, st) in refused:
                rec["rows"][st] = {"status": "not applicable", "reason": refused[(sc, st)]}
                continue
            r = by_name.get(key)
            if r is None:
                continue
            row = {"status": r.get("status"), "what": SETTINGS[st].what, "overrides": list(SETTINGS[st].overrides)}
            if r.get("status") != "ok":
                row["reason"] = (r.get("failure_cause") or r.get("error") or "")[:300]
                rec["rows"][st] = row
                continue
            summ = r["summary"]
            sim = float(summ.get("sim_time_s") or 0.0)
            # CPU seconds of the loop where recorded: parallel runs on a shared machine slow each other's
            # wall clock, not their CPU time
            loop_s = summ.get("loop_cpu_time_s") or summ["loop_time_s"]
            row["loop_s_per_s"] = float(loop_s) / sim if sim > 0 else None
            row["loop_wall_s_per_s"] = float(summ["loop_time_s"]) / sim if sim > 0 else None
            row["cost_clock"] = "cpu" if summ.get("loop_cpu_time_s") else "wall"
            tb = summ.get("time_breakdown_s") or {}
            map_s = _map_build_s(assemble_scene(scene_of[key])) if key in scene_of else None
            row["build_s"] = float(tb.get("fmu_setup", 0.0)) + float(map_s or 0.0)
            row["map_build_s"] = map_s
            row["energy_residual"] = summ.get("energy_residual")
            if ref is not None:
                h = read_hdf5(run_dir / key / "signals.h5")
                s = scene_of[key]
                row["errors"] = compare(ref, {"time": h["time"], **h["signals"]}, s.time.sample_rate_Hz,
                                        s.time.settle_s, s.operating_point.final_speed_rpm,
                                        wheel=rec.get("health_class") == "wheel")["worst"]
            rec["rows"][st] = row
        out["scenes"][sc] = rec
    return out


def keep_earlier(results: dict, earlier: dict) -> dict:
    """``results`` with the scenes of ``earlier`` (the results file being rewritten) that this study did not
    evaluate kept as they were, in STUDY_SCENES' order: a study run for one scene adds its rows and loses none.
    ``meta["kept_from_earlier"]``: {scene: the command that measured it}."""
    scenes = dict(results.get("scenes", {}))
    kept = {}
    for name, rec in (earlier.get("scenes") or {}).items():
        if name not in scenes and name in STUDY_SCENES:
            scenes[name] = rec
            kept[name] = (earlier.get("meta") or {}).get("kept_from_earlier", {}).get(name) or \
                (earlier.get("meta") or {}).get("command", "an earlier study")
    order = {n: i for i, n in enumerate(STUDY_SCENES)}
    results["scenes"] = dict(sorted(scenes.items(), key=lambda kv: order.get(kv[0], len(order))))
    if kept:
        results.setdefault("meta", {})["kept_from_earlier"] = kept
    return results


def _records_on_disk(run_dir: Path, runs: list) -> list[dict]:
    """A record per run directory with a summary (whichever invocation wrote it), the summary with it."""
    out = []
    for s in runs:
        try:
            summ = json.loads((run_dir / s.name / "summary.json").read_text())
        except (OSError, ValueError):
            continue
        out.append({"name": s.name, "status": summ.get("status", "ok"),
                    "failure_cause": (summ.get("failure") or {}).get("cause"), "summary": summ})
    return out


def run_study(out_dir: Path | str, scenes=None, settings=None, *, workers: int | None = None,
              address: str | None = None, resume: bool = False, fmu_dir: str | Path | None = None,
              backend: str = "fmi", progress: bool = True, meta: dict | None = None,
              evaluate_only: bool = False) -> dict:
    """Run (or, with ``resume``, complete) the study into ``out_dir/runs`` and evaluate it. Online-PCM
    rows are costly by design: they run (``force``) whatever their predicted cost. The evaluation covers
    every run of every studied scene and setting found in ``out_dir/runs``; ``evaluate_only``: run nothing."""
    run_dir = Path(out_dir) / "runs"
    every, every_refused = study_scenes()
    if not evaluate_only:
        runs, _ = study_scenes(scenes, settings)
        run_sweep(runs, run_dir, workers=workers, address=address, backend=backend, fmu_dir=fmu_dir,
                  skip_existing=resume, plots=False, progress=progress, force=True,
                  grid_names=[s.name for s in every])
    # every run of the study found in run_dir is evaluated, whichever invocation made it: a study can be
    # completed piecewise (e.g. the costly pcm row scene by scene)
    return evaluate(run_dir, _records_on_disk(run_dir, every), every, every_refused, dict(meta or {}))


# ------------------------------------------------------------------------------------------------
# Report
# ------------------------------------------------------------------------------------------------


def pareto_front(points: list[tuple[float, float, str]]) -> set[str]:
    """Names of the points (cost, error, name) no other point beats in both."""
    front, best = set(), float("inf")
    for c, e, n in sorted(points, key=lambda p: (p[0], p[1])):
        if e < best:
            front.add(n)
            best = e
    return front


def row_error(r: dict) -> float:
    """One number for the Pareto plot: the worst of the mean and fluctuation errors [%] and the GMF and
    sideband differences [dB], each against its 1 % / 1 dB scale."""
    e = r.get("errors") or {}
    vals = [abs(e[k]) for k in ("mean_err_pct", "std_err_pct", "gmf_dB", "sideband_dB")
            if e.get(k) is not None and math.isfinite(e[k])]
    return max(vals) if vals else float("nan")


def _fmt(v, spec=".2f", unit=""):
    if v is None:
        return "–"
    if isinstance(v, float) and not math.isfinite(v):
        return "n/a"
    return f"{v:{spec}}{unit}"


INTRO = [
    "**How to read it.** One table per studied scene. Each row is one setting (`drivetrain.run.accuracy.SETTINGS`: "
    "the scene keys it changes are listed there and in `src/drivetrain/data/accuracy_cost.json`). *cost*: CPU "
    "seconds of the co-simulation loop per simulated second on this machine (one core per run; CPU time, because "
    "parallel runs on a shared machine slow each other's wall clock), and the same as a multiple of the "
    "reference's; *build*: one-off seconds (FMU set-up and the contact map's tabulation, paid once per geometry "
    "and cached). The error columns compare the run with the reference run of the same scene over the analysed "
    "window, worse of the two torque channels (drive shaft, propeller shaft): mean torque, fluctuation (standard "
    "deviation) and peak-to-peak [%]; the spectrum at f_GMF and at the first sidebands f_GMF ± f_MSH (± f_PSH for "
    "the wheel fault) [dB]; the spectral distance over 0-5 f_GMF (L2 norm of the amplitude difference over the "
    "reference's) [%]; and the run's own energy residual. A sideband the reference holds less than 20 dB above "
    "its spectral floor (a healthy gear's, at numerical-noise level) is not compared (–). *realism* rows change "
    "what is simulated: their 'error' is what the effect adds, not an approximation.",
    "",
    "**The reference** is the table gear on the converged contact mesh (0.025 mm profile x 1 mm face elements; "
    "the mesh stiffness moves 0.15 % from 0.05 mm to 0.025 mm, docs/GEAR-CONTACT.md) with a contact map of 192 "
    "nodes per pinion pitch, the communication step at 1/48000 s, the gear sub-step at 1 µs and 8 elements per "
    "shaft. Each of these was refined until the next refinement mattered little, one at a time, on the healthy "
    "gear at 250 rpm, the scene with the smallest fluctuation (fluctuation change / f_GMF change): map nodes 48 -> "
    "96 -> 192 -> 384 per pitch: 8.8 % / -1.69 dB, 1.6 % / +0.07 dB, 0.22 % / +0.07 dB; nodes along the "
    "approach 48 -> 96: 0.21 % / +0.06 dB; H 1/24000 -> 1/48000 s: 0.86 % / +0.05 dB; sub-step 1 -> 0.5 µs: "
    "0.01 %; shaft elements 8 -> 16: 0.00 %. The map grid was the unconverged setting of the earlier reference "
    "(48 nodes per pitch): bilinear interpolation between nodes 0.5° apart smears the onset of each tooth pair "
    "and the ripple of the contact elements. The line under each table says how far the reference moves when "
    "refined once more in time and shafts together (`reference_refined`: 1/96000 s, 0.5 µs, 16 elements; "
    "a 384-node map of a faulty pair would take 10-16 min to build on 2 cores, so the map grid's convergence "
    "rests on the healthy scene above). Online PCM at the reference's mesh and steps would take hours per simulated second "
    "(`drivetrain.run.cost`); the table gear is the same PCM contact tabulated over the pinion angle and the "
    "approach (exact at its nodes), and the `pcm` row (online PCM at the default mesh and steps, where it ran) "
    "measures how far the tabulation is from it.",
    "",
]

GUIDE = [
    "## Which setting for what",
    "",
    "- **Mean torques** (calibration, efficiency maps): every setting is within a few hundredths of a per cent "
    "of the reference, even the paper's 0.5 mm mesh, rigid shafts and the ideal gear (the table above). Take the "
    "cheapest.",
    "- **Fluctuation and spectra** (condition monitoring, ML datasets): the contact mesh and the contact map's "
    "grid decide, together. The paper's 0.5 mm profile elements are off by 10-1100 %, 0.2 mm by up to ~140 % "
    "and 0.1 mm by up to ~65 %, worst at low speed (a few facets carry the whole ~0.3 mm contact strip, so the "
    "stiffness jumps with the angle). The defaults (0.05 mm, 48 map nodes per pitch) are 0.4-5.4 % off and "
    "within 1.9 dB at f_GMF (most for the healthy and faulty gears at 250 rpm). Refining only one of the two "
    "does not help: the 0.025 mm mesh on the default 48-node map is 1-10 % off (the finer ripple of the contact "
    "elements falls between the nodes), and 96 or 192 nodes on the default mesh are 0.4-6.4 % off (the mesh's "
    "own ripple is then resolved). The communication step and the sub-step come next (1/6000 s: up to 8 %); the "
    "integrator (rk4 in place of ros2) and the number of shaft elements change nothing that matters (1 to 8 "
    "agree); rigid shafts remove the shaft modes and are a different model, not an approximation. Without the "
    "energy correction the energy residual grows 100-1000x.",
    "- **Let the run choose**: `drivetrain run SCENE --tolerance 5%` (or `numerics.tolerance_pct = 5` in the "
    "scene) takes the cheapest setting whose measured error for the closest studied scene (same health class, "
    "nearest speed) is within 5 % on the mean torques and the fluctuation and 5 dB at f_GMF and the resolved "
    "sidebands; the summary's `accuracy_choice` says which and why. Realism effects are never chosen.",
    "- **1 %**: the mean torques are within 1 % everywhere, but the fluctuation of the 250 rpm scenes moves by "
    "more than 1 % between the cheap settings and the reference, so a 1 % tolerance keeps the reference there. "
    "On the 1500 rpm scenes and the wheel fault a setting at 0.19-0.38x the reference is within 1 % and 1 dB. "
    "None of the cheaper settings costs 1/100 of the reference: the reference is itself a table gear at 8-11 s "
    "per simulated second. Against online PCM at the reference's mesh and steps (the `pcm` row, 30x the "
    "reference at the default mesh and 5 µs, times about 3 for the 4x finer mesh and 5 for the 1 µs sub-steps: "
    "several thousand seconds per simulated second, the figure the issue's 1/100 had in mind) every table "
    "setting costs under 1/1000, and the default is within 1 % on the means and within 1 dB on the sidebands "
    "where the reference resolves them, in every studied scene.",
    "- **Not studied yet**: online PCM ran on one scene (4.5 s of it cost about 30 min of one core). Add a "
    "scene's row with `drivetrain accuracy-cost --scenes NAME --settings pcm --resume` (the study evaluates every "
    "run in its directory, so rows can be added piecewise). A 384-node map of a faulty pair takes 10-16 min to "
    "build on 2 cores, so the map grid's convergence (192 -> 384 nodes: 0.22 %) was measured on the healthy gear only.",
]


def report_markdown(results: dict, figures: dict[str, str]) -> str:
    meta = results.get("meta", {})
    out = ["# What accuracy costs in time", "",
           f"Regenerate: `{meta.get('command', 'drivetrain accuracy-cost')}` ({meta.get('wall_time_s', 0) / 60:.0f} min "
           f"on {meta.get('workers', '?')} workers here; `--resume` reuses finished runs; the report goes to `--out`, "
           "`--update-shipped` rewrites this page and the results `run --tolerance` reads). Each scene runs "
           f"{meta.get('duration_s', STUDY_DURATION_S):g} s, of which the last "
           f"{meta.get('duration_s', STUDY_DURATION_S) - meta.get('settle_s', STUDY_SETTLE_S):g} s are compared "
           "with the same scene's reference run.", "", commit_line(), ""]
    kept = meta.get("kept_from_earlier") or {}
    if kept:
        whom: dict = {}
        for scene, cmd in kept.items():
            whom.setdefault(cmd, []).append(scene)
        out += ["Scenes measured by an earlier study and kept as they were: " + "; ".join(
            f"{', '.join(scenes)} (`{cmd}`)" for cmd, scenes in whom.items()) + ".", ""]
    out += INTRO
    for name, sc in results.get("scenes", {}).items():
        rows = sc["rows"]
        ref_cost = (rows.get(REFERENCE) or {}).get("loop_s_per_s")
        out += ["", f"## {name}: {sc.get('what', '')}", ""]
        if name in figures:
            out += [f"![error against cost, {name}]({figures[name]})", ""]
        out += ["| setting | cost [s/s] | x reference | build [s] | mean | fluct. (std) | ptp | GMF | sidebands | "
                "spectral dist. | energy res. |",
                "|---|---|---|---|---|---|---|---|---|---|---|"]
        for s, r in rows.items():
            if r.get("status") != "ok":
                out.append(f"| {s} | {r.get('status', '?')}: {r.get('reason', '')} |" + " |" * 9)
                continue
            e = r.get("errors") or {}
            mark = "" if SETTINGS.get(s) is None or SETTINGS[s].choosable else " (realism)"
            dagger = "†" if r.get("cost_clock") == "wall" else ""
            out.append(
                f"| {s}{mark} | {_fmt(r.get('loop_s_per_s'), '.3g')}{dagger} | "
                f"{_fmt(r['loop_s_per_s'] / ref_cost if ref_cost else None, '.2g')} | "
                f"{_fmt(r.get('build_s'), '.3g')} | {_fmt(e.get('mean_err_pct'), '.3f', ' %')} | "
                f"{_fmt(e.get('std_err_pct'), '.2f', ' %')} | {_fmt(e.get('ptp_err_pct'), '.1f', ' %')} | "
                f"{_fmt(e.get('gmf_dB'), '+.2f', ' dB')} | {_fmt(e.get('sideband_dB'), '+.2f', ' dB')} | "
                f"{_fmt(e.get('spectral_distance_pct'), '.1f', ' %')} | {_fmt(r.get('energy_residual'), '.1e')} |")
        fine = rows.get("reference_refined") or {}
        if fine.get("status") == "ok" and fine.get("errors"):
            e = fine["errors"]
            worst = max(abs(e[k]) for k in ("mean_err_pct", "std_err_pct", "gmf_dB") if e.get(k) is not None)
            out += ["", f"Convergence of the reference: refined once more (`reference_refined`), the mean torques move "
                        f"{e['mean_err_pct']:.3f} %, the fluctuation {e['std_err_pct']:.2f} %, f_GMF "
                        f"{e['gmf_dB']:+.2f} dB" + (f", the sidebands {e['sideband_dB']:+.2f} dB"
                                                    if e.get("sideband_dB") is not None else "")
                        + (": within 0.5 % / 0.05 dB." if worst < 0.5 and abs(e["gmf_dB"]) < 0.05 else
                           ": **not** within 0.5 %.")]
        if any(r.get("cost_clock") == "wall" for r in rows.values() if r.get("status") == "ok"):
            out += ["", "Costs marked † are wall-clock loop times measured while other runs shared the cores "
                        "(those runs predate the CPU-time record): read them as upper bounds."]
        for T in (1.0, 5.0):
            ok = [s for s, r in rows.items() if s in SETTINGS and SETTINGS[s].choosable and r.get("status") == "ok"
                  and (s == REFERENCE or within(r.get("errors") or {}, T))]
            if ok:
                best = min(ok, key=lambda s: rows[s]["loop_s_per_s"])
                cost = rows[best]["loop_s_per_s"]
                own = (rows.get(DEFAULT) or {}).get("loop_s_per_s")      # what the scene costs as it is
                vs = ([f"{cost / own:.2g}x the scene's defaults"] if own else []) + \
                     ([f"{cost / ref_cost:.2g}x the reference"] if ref_cost else [])
                out.append("")
                out.append(f"Within {T:g} % / {T:g} dB: cheapest `{best}` ({cost:.3g} s/s"
                           + "".join(f", {v}" for v in vs) + ").")
    out += ["", *_overview(results), "", *GUIDE]
    return "\n".join(out) + "\n"


def _overview(results: dict) -> list[str]:
    """Each setting across the studied scenes: the range of its errors and costs."""
    scenes = results.get("scenes", {})
    lines = ["## Every setting across the studied scenes", "",
             "Ranges over the scenes where the setting ran (min – max).", "",
             "| setting | cost [s/s] | x reference | mean | fluct. (std) | GMF | sidebands | scenes within 1 % / 1 dB |",
             "|---|---|---|---|---|---|---|---|"]

    def rng(vals, spec, unit="", absolute=False):
        v = [abs(x) if absolute else x for x in vals if x is not None and math.isfinite(x)]
        return f"{min(v):{spec}} – {max(v):{spec}}{unit}" if v else "–"

    for st, setting in SETTINGS.items():
        rows = [(sc, sc_rec["rows"][st], sc_rec["rows"].get(REFERENCE, {}))
                for sc, sc_rec in scenes.items() if (sc_rec["rows"].get(st) or {}).get("status") == "ok"]
        if not rows:
            continue
        err = lambda k: [(r.get("errors") or {}).get(k) for _, r, _ in rows]  # noqa: E731
        rel = [r["loop_s_per_s"] / ref["loop_s_per_s"] for _, r, ref in rows if ref.get("loop_s_per_s")]
        ok = sum(within(r.get("errors") or {}, 1.0) for _, r, _ in rows)
        mark = "" if setting.choosable else " (realism)"
        lines.append(f"| {st}{mark} | {rng([r['loop_s_per_s'] for _, r, _ in rows], '.3g')} | {rng(rel, '.2g')} | "
                     f"{rng(err('mean_err_pct'), '.3f', ' %')} | {rng(err('std_err_pct'), '.2f', ' %')} | "
                     f"{rng(err('gmf_dB'), '.2f', ' dB', True)} | {rng(err('sideband_dB'), '.2f', ' dB', True)} | "
                     f"{ok}/{len(rows)} |")
    return lines


def plot_pareto(results: dict, out_dir: Path) -> dict[str, str]:
    """One PNG per scene: error (row_error) against cost, the Pareto front marked. {scene: file name}."""
    from drivetrain.run.outputs import _finish, _mpl

    plt = _mpl()

    out_dir.mkdir(parents=True, exist_ok=True)
    files = {}
    for name, sc in results.get("scenes", {}).items():
        pts = [(r["loop_s_per_s"], max(row_error(r), 1e-4), s) for s, r in sc["rows"].items()
               if r.get("status") == "ok" and s != REFERENCE and math.isfinite(row_error(r))
               and SETTINGS.get(s, Setting(s, "", (), "")).choosable]
        if not pts:
            continue
        front = pareto_front(pts)
        fig, ax = plt.subplots(figsize=(7, 4.5))
        for c, e, s in pts:
            ax.scatter(c, e, color="tab:red" if s in front else "tab:blue", zorder=3)
            ax.annotate(s, (c, e), fontsize=7, xytext=(3, 3), textcoords="offset points")
        fp = sorted((c, e) for c, e, s in pts if s in front)
        ax.step([p[0] for p in fp], [p[1] for p in fp], where="post", color="tab:red", lw=1, label="Pareto front")
        ax.axhline(1.0, color="gray", lw=0.8, ls="--", label="1 % / 1 dB")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("cost [loop CPU s per simulated s]")
        ax.set_ylabel("worst error [% or dB] vs reference")
        ax.set_title(f"{name}: accuracy against cost")
        ax.legend(fontsize=8)
        fn = f"accuracy_{name}.png"
        _finish(plt, fig, out_dir / fn, "")
        files[name] = fn
    return files


__all__ = ["run_study", "study_scenes", "evaluate", "report_markdown", "plot_pareto", "pareto_front", "row_error"]
