"""Start-up and a short run as a user waits for them: ``drivetrain run --help``, ``import drivetrain.run``
(and ``drivetrain.run.runner``, what ``drivetrain run`` loads) and a warm 0.5 s native run of the example
with plots, each in a fresh process and timed from outside (best of the rounds); for the run also the wall
time the command printed itself (it should be the measured one: issue 31). docs/MASTER.md ("Where a command's wall
time goes") has the figures.

    python benchmarks/bench_startup.py                     # this tree, about 1 minute on 2 cores
    python benchmarks/bench_startup.py --against REV       # this tree and git revision REV, side by side

``--against REV``: the same measurements in a temporary git worktree of REV, the trees taking turns in each
round, and the ratios REV / this tree (the machines are shared and noisy: ratios taken in one run hold).
Each tree builds its native FMUs once into a directory of its own before the rounds (the run is warm).
"""
import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _trees import ROOT, worktree  # noqa: E402

RUN_S = 0.5


def _measurements(tree: Path, scratch: Path) -> dict[str, list[str]]:
    """name -> the command (a fresh Python process of ``tree``)."""
    py = [sys.executable]
    run = [*py, "-m", "drivetrain", "run", str(tree / "scenarios" / "example.toml"), "--native", "--set",
           f"time.duration_s={RUN_S:g}", "--out", str(scratch / "out"), "--fmu-dir", str(scratch / "fmus")]
    return {"drivetrain run --help": [*py, "-m", "drivetrain", "run", "--help"],
            "import drivetrain.run": [*py, "-c", "import drivetrain.run"],
            "import drivetrain.run.runner": [*py, "-c", "import drivetrain.run.runner"],
            f"run {RUN_S:g} s native, plots (warm)": run}


def _timed(tree: Path, cmd: list[str], cwd: Path) -> tuple[float, float | None]:
    """(wall time measured from outside, the wall time the command printed: "simulated in X s")."""
    env = dict(os.environ, PYTHONPATH=str(tree / "src"))
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed in {tree} (rc {proc.returncode}):\n{proc.stderr[-3000:]}")
    m = re.search(r"simulated in ([0-9.e+-]+) s", proc.stdout)
    return wall, float(m.group(1)) if m else None


def measure(trees: dict[str, Path], rounds: int) -> dict:
    """{label: {measurement: (best wall, printed wall of that round)}}, the trees taking turns."""
    with tempfile.TemporaryDirectory(prefix="bench_startup_") as tmp:
        scratch = {label: Path(tmp) / f"t{i}" for i, label in enumerate(trees)}
        cmds = {label: _measurements(tree, scratch[label]) for label, tree in trees.items()}
        for label, tree in trees.items():          # warm: the native FMUs, numba caches, the contact map
            scratch[label].mkdir()
            _timed(tree, list(cmds[label].values())[-1], scratch[label])
        best: dict = {label: {} for label in trees}
        for _ in range(rounds):
            for name in next(iter(cmds.values())):
                for label, tree in trees.items():
                    wall, printed = _timed(tree, cmds[label][name], scratch[label])
                    if name not in best[label] or wall < best[label][name][0]:
                        best[label][name] = (wall, printed)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", metavar="REV", help="git revision to compare with (side by side)")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    if not args.against:
        best = measure({"this tree": ROOT}, args.rounds)["this tree"]
        print("| measurement | wall [s] | printed by the command [s] |")
        print("|---|---|---|")
        for name, (wall, printed) in best.items():
            print(f"| {name} | {wall:.2f} | {'' if printed is None else f'{printed:.2f}'} |")
        return
    rev = args.against
    with worktree(rev) as wt:
        best = measure({"here": ROOT, "there": wt}, args.rounds)
    print(f"| measurement | this tree [s] | {rev[:12]} [s] | {rev[:12]} / this tree |")
    print("|---|---|---|---|")
    for name, (here, p_here) in best["here"].items():
        there, p_there = best["there"][name]
        print(f"| {name} | {here:.2f} | {there:.2f} | {there / here:.2f} |")
        if p_here is not None or p_there is not None:
            f = (lambda x: "-" if x is None else f"{x:.2f}")
            print(f"| (the same run: wall time printed by the command) | {f(p_here)} | {f(p_there)} | |")


if __name__ == "__main__":
    main()
