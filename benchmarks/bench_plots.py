"""What a run's plots cost: the example scene's two PNGs (torque waveforms, spectra), in this tree and in
another git revision, side by side (README, "What a run gives you").

    python benchmarks/bench_plots.py --against REV [--rounds 3] [--signals out/example/signals.h5]
    python benchmarks/bench_plots.py --against REV --runs        # also whole `drivetrain run --native` runs
    python benchmarks/bench_plots.py --against-tree DIR          # DIR: a checkout of the other revision

The plots are drawn from one run's ``signals.h5`` (the example scene, 20 s; run once with ``--native`` when
``--signals`` is not given): each round, in a fresh process of each tree (the trees taking turns), the
spectra are computed as the run computes them and the tree's ``plot_torques`` and ``plot_spectra`` write
their PNGs; the time from the first plot call to the last PNG is the plot time (matplotlib's import
included, as a run pays it), wall and CPU time of the process (the CPU time is less moved by other work
on the machine). ``--runs``: the example scene run through ``drivetrain run --native`` in each
tree, with plots and with ``--no-plots``: the wall times and ``write_time_s`` of its summary. Best of the
rounds; the machines are shared and noisy, ratios taken in one run hold.
"""
import argparse
import contextlib
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

_PLOTS = r"""
import json, sys, time
import numpy as np
from drivetrain.run import outputs as O
from drivetrain.rig.signals import amplitude_spectrum
from drivetrain.scene.load import load_scene
h = O.read_hdf5(sys.argv[1])
out = sys.argv[2]
scene = load_scene(sys.argv[3])
s = json.loads(h["attrs"]["summary_json"])
cf, settle, fs = s["characteristic_frequencies"], float(h["attrs"]["settle_s"]), float(h["attrs"]["sample_rate_Hz"])
t = h["time"]
torques = {k: h["signals"][k] for k in ("drive_shaft_torque", "propeller_shaft_torque")}
spectra = {k: amplitude_spectrum(x[t >= settle], fs, lowpass_Hz=5.0 * cf["f_GMF"]) for k, x in torques.items()}
title = (lambda what: O.run_title(scene, what)) if hasattr(O, "run_title") else (lambda what: f"{scene.name}: {what}")
t0, c0 = time.perf_counter(), time.process_time()
O.plot_torques(f"{out}/torques.png", t, torques, settle, cf, title=title("torque waveforms"))
t1 = time.perf_counter()
O.plot_spectra(f"{out}/spectra.png", spectra, cf, title=title("spectra"))
t2, c2 = time.perf_counter(), time.process_time()
print("RESULT " + json.dumps({"torques_s": t1 - t0, "spectra_s": t2 - t1, "plots_s": t2 - t0, "cpu_s": c2 - c0}))
"""


def _run(tree: Path, scene: Path, out: Path, fmu_dir: Path, plots: bool) -> dict:
    import os

    env = dict(os.environ, PYTHONPATH=str(tree / "src"))
    cmd = [sys.executable, "-m", "drivetrain", "run", str(scene), "--native", "--quiet", "--out", str(out),
           "--fmu-dir", str(fmu_dir), *([] if plots else ["--no-plots"])]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=tree)
    wall = time.perf_counter() - t0
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed in {tree}:\n{proc.stderr[-3000:]}")
    s = json.loads((out / "summary.json").read_text())
    return {"wall_s": wall, "write_time_s": s.get("write_time_s")}


def main() -> None:
    from _trees import ROOT, run_in_tree, worktree

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    other = ap.add_mutually_exclusive_group(required=True)
    other.add_argument("--against", metavar="REV", help="git revision to compare with (side by side)")
    other.add_argument("--against-tree", metavar="DIR", type=Path, help="a checkout of the revision to compare with")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--signals", type=Path, help="a signals.h5 of the example scene (default: run it once)")
    ap.add_argument("--runs", action="store_true", help="also whole `drivetrain run --native` runs, with and without plots")
    args = ap.parse_args()
    scene = ROOT / "scenarios" / "example.toml"
    with tempfile.TemporaryDirectory(prefix="bench_plots_") as tmp, \
            (worktree(args.against) if args.against else contextlib.nullcontext(args.against_tree.resolve())) as wt:
        tmp = Path(tmp)
        trees = {"this tree": ROOT, (args.against or "").strip()[:12] or str(args.against_tree): wt}
        if args.signals is None:
            _run(ROOT, scene, tmp / "example", tmp / "fmus_here", plots=False)
            args.signals = tmp / "example" / "signals.h5"
        plot_t = {k: [] for k in trees}
        run_t = {(k, p): [] for k in trees for p in (True, False)}
        for r in range(args.rounds):
            for i, (key, tree) in enumerate(trees.items()):
                d = tmp / f"plots_{r}_{i}"
                d.mkdir()
                plot_t[key].append(run_in_tree(tree, _PLOTS, [str(args.signals.resolve()), str(d), str(scene)]))
                if args.runs:
                    for plots in (True, False):
                        run_t[(key, plots)].append(_run(tree, scene, d / ("run" if plots else "run_np"),
                                                        tmp / f"fmus_{i}", plots))
        print("| tree | torques.png [s] | spectra.png [s] | both plots [s] | both plots, CPU [s] |")
        print("|---|---|---|---|---|")
        for key, rows in plot_t.items():
            best = min(rows, key=lambda x: x["plots_s"])
            cpu = min(x["cpu_s"] for x in rows)
            print(f"| {key} | {best['torques_s']:.2f} | {best['spectra_s']:.2f} | {best['plots_s']:.2f} | {cpu:.2f} |")
        if args.runs:
            print()
            print("| tree | run with plots: wall [s] | write_time_s | --no-plots: wall [s] | write_time_s |")
            print("|---|---|---|---|---|")
            for key in trees:
                a = min(run_t[(key, True)], key=lambda x: x["wall_s"])
                b = min(run_t[(key, False)], key=lambda x: x["wall_s"])
                print(f"| {key} | {a['wall_s']:.2f} | {a['write_time_s']:.2f} | {b['wall_s']:.2f} | "
                      f"{b['write_time_s']:.2f} |")


if __name__ == "__main__":
    main()
