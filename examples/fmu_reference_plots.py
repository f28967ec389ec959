"""The reference plots every FMU ships (documentation/reference.png; drivetrain.fmu_build.fmu_docs): each FMU's
DefaultExperiment with its shipped example input, run by fmpy.simulate_fmu, plotted; written to
src/drivetrain/fmu_build/reference_plots/<Model>.png (pythonfmu) and <Model>-native.png, committed.

    python examples/fmu_reference_plots.py            # builds the FMUs into a temporary directory first

Then build the FMUs again (drivetrain build-fmus, drivetrain build-native) to ship the new plots.
"""
import io
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import fmpy  # noqa: E402
from drivetrain.fmu_build.build import build_all  # noqa: E402
from drivetrain.fmu_build.fmu_docs import EXAMPLE_CSV, PLOT_DIR, PLOT_VARIABLES, reference_plot  # noqa: E402
from drivetrain.fmu_build.native_gear import build_native_gear  # noqa: E402
from drivetrain.fmu_build.native_line import MODELS, build_native_line  # noqa: E402


def plot(path: Path, native: bool) -> float:
    with zipfile.ZipFile(path) as z:
        inp = np.genfromtxt(io.BytesIO(z.read(EXAMPLE_CSV)), delimiter=",", names=True)
    model = path.stem
    t0 = time.perf_counter()
    res = fmpy.simulate_fmu(str(path), input=inp)
    cost = time.perf_counter() - t0
    md = fmpy.read_model_description(str(path))
    units = {v.name: v.unit or "" for v in md.modelVariables}
    names = PLOT_VARIABLES[model]
    fig, axes = plt.subplots(len(names), 1, figsize=(7, 1.6 * len(names) + 0.6), sharex=True)
    for ax, n in zip(axes, names):
        ax.plot(res["time"], res[n], lw=1)
        ax.set_ylabel(f"{n}\n[{units.get(n, '')}]", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{model}{' (native)' if native else ''}: DefaultExperiment with documentation/example_input.csv",
                 fontsize=9)
    fig.tight_layout()
    PLOT_DIR.mkdir(exist_ok=True)
    fig.savefig(reference_plot(model, native), dpi=80)
    plt.close(fig)
    return cost


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        built = [(p, False) for p in build_all(tmp)]
        for m in MODELS:
            built.append((build_native_line(m, tmp / "native" / f"{m}.fmu"), True))
        built.append((build_native_gear({}, tmp / "native" / "GearContact.fmu"), True))
        for path, native in built:
            cost = plot(Path(path), native)
            print(f"{reference_plot(Path(path).stem, native)}: the run took {cost:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
