"""What accuracy costs in time: every fidelity level and numerical setting, error against a reference
and wall time, measured in one run.

The scene is the hard one of the paper's grid (severe fault, 1500 rpm, 1.31 N·m). The reference is
the online PCM gear (the most faithful model; its cost limits the scene to a fraction of a second). For each variant the script runs the
same scene through the co-simulation master (FMI backend) and reports, against the reference, the
error of the mean propeller-shaft and drive-shaft torques, of the torque fluctuation (RMS of the
mean-free signal) and of the spectrum at the gear-mesh frequency and its first sidebands, plus the
cost as wall seconds per simulated second (1 / real-time factor).

    python benchmarks/pcm_vs_table.py                   # writes docs/pcm_vs_table.md and .png
    python benchmarks/pcm_vs_table.py --quick          # shorter scene, fewer variants

Read the table: go down the "cost" column to what you can afford; the error columns say what you
give up against the reference. The first row is the reference itself (its own error is zero by
definition; its step-halving error is given in the note under the table).
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from drivetrain.run.runner import run_scene
from drivetrain.scene.load import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenarios" / "hard" / "missing_tooth_1500rpm.toml"


def variants(quick: bool):
    """(label, overrides) pairs; the first is the reference."""
    ref = ["effects.mesh_contact=pcm", "numerics.max_substep_s=2e-6"]
    v = [
        ("reference: pcm, H = 1/12000 s, sub-step 2 µs", ref),
        ("table, H = 1/12000 s, sub-step 2 µs", ["effects.mesh_contact=table", "numerics.max_substep_s=2e-6"]),
        ("table, H = 1/12000 s, sub-step 1 µs", ["effects.mesh_contact=table", "numerics.max_substep_s=1e-6"]),
        ("table, H = 1/12000 s, sub-step 5 µs (default)", ["effects.mesh_contact=table",
                                                          "numerics.max_substep_s=5e-6"]),
        ("table, H = 1/24000 s, sub-step 1 µs", ["effects.mesh_contact=table", "numerics.max_substep_s=1e-6",
                                                "numerics.comm_step_s=4.1666666666666665e-05"]),
        ("table, H = 1/6000 s, sub-step 5 µs", ["effects.mesh_contact=table",
                                               "numerics.comm_step_s=1.6666666666666666e-04"]),
        ("table, rigid shafts (other defaults)", ["effects.mesh_contact=table", "effects.shaft_flexibility=rigid"]),
        ("table, no friction (other defaults)", ["effects.mesh_contact=table", "effects.friction=false"]),
        ("analytic (ISO 6336, healthy geometry)", ["effects.mesh_contact=analytic", "gear.health=healthy"]),
        ("ideal gear, rigid shafts", ["effects.mesh_contact=ideal", "gear.health=healthy",
                                      "effects.shaft_flexibility=rigid"]),
    ]
    if quick:
        v = [v[0], v[1], v[5], v[8], v[9]]
    return v


def band_amplitude(t, x, f0, rel_bw=0.02):
    """Peak amplitude of the Hann-windowed spectrum within ±rel_bw·f0 of f0."""
    x = np.asarray(x) - np.mean(x)
    w = np.hanning(len(x))
    X = np.abs(np.fft.rfft(x * w)) * 2.0 / np.sum(w)
    f = np.fft.rfftfreq(len(x), t[1] - t[0])
    sel = np.abs(f - f0) <= max(rel_bw * f0, 2 * (f[1] - f[0]))
    return float(X[sel].max()) if sel.any() else 0.0


def metrics(res):
    t = res.time
    settle = res.scene.time.settle_s
    keep = t >= settle
    t = t[keep]
    cf = res.summary["characteristic_frequencies"]
    f_gmf, f_msh = cf["f_GMF"], cf["f_MSH"]
    # cost of the stepping loop per simulated second (one-time FMU build and contact-map build excluded)
    m = {"wall_per_sim_s": res.summary["loop_time_s"] / res.summary["sim_time_s"],
         "energy_residual": res.summary["energy_residual"]}
    for ch in ("propeller_shaft_torque", "drive_shaft_torque"):
        x = np.asarray(res.signals[ch])[keep]
        m[ch + ".mean"] = float(np.mean(x))
        m[ch + ".rms_ac"] = float(np.std(x))
        m[ch + ".gmf"] = band_amplitude(t, x, f_gmf)
        m[ch + ".sb"] = band_amplitude(t, x, f_gmf - f_msh) + band_amplitude(t, x, f_gmf + f_msh)
    return m


def rel(a, b):
    return abs(a - b) / abs(b) if b else float("nan")


def db(a, b):
    return 20 * math.log10(max(a, 1e-300) / max(b, 1e-300))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter scene and fewer variants")
    ap.add_argument("--duration", type=float, default=None, help="scene duration [s] (default 0.6, quick 0.4)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "pcm_vs_table"), help="output path stem (.md, .png)")
    args = ap.parse_args(argv)
    duration = args.duration or (0.4 if args.quick else 0.6)
    settle = 0.5 * duration
    common = [f"time.duration_s={duration}", f"time.settle_s={settle}", "outputs.plots=false",
              "outputs.aalto_csv=false"]
    rows = []
    for label, ov in variants(args.quick):
        scene = load_scene(SCENE, overrides=common + ov)
        t0 = time.perf_counter()
        res = run_scene(scene, out_dir=None, progress=False, force=True)   # the reference is costly by design
        m = metrics(res)
        m["label"] = label
        m["wall_total_s"] = time.perf_counter() - t0
        rows.append(m)
        print(f"{label:48s} cost {m['wall_per_sim_s']:8.2f} s/s   "
              f"PSH mean {m['propeller_shaft_torque.mean']:8.4f} N·m  rms {m['propeller_shaft_torque.rms_ac']:.4f}",
              flush=True)
    ref = rows[0]
    lines = [
        "# Accuracy against cost",
        "",
        f"Scene: `{SCENE.relative_to(ROOT)}` (severe fault, 1500 rpm, 1.31 N·m), {duration:g} s, statistics after "
        f"{settle:g} s. Reference: the first row. Regenerate: `python benchmarks/pcm_vs_table.py`.",
        "",
        "| variant | cost [loop s / sim s] | PSH mean err | DSH mean err | PSH fluct. err | GMF amp. [dB] | sidebands [dB] | energy residual |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for m in rows:
        lines.append(
            f"| {m['label']} | {m['wall_per_sim_s']:.2f} | "
            f"{100 * rel(m['propeller_shaft_torque.mean'], ref['propeller_shaft_torque.mean']):.2f} % | "
            f"{100 * rel(m['drive_shaft_torque.mean'], ref['drive_shaft_torque.mean']):.2f} % | "
            f"{100 * rel(m['propeller_shaft_torque.rms_ac'], ref['propeller_shaft_torque.rms_ac']):.1f} % | "
            f"{db(m['propeller_shaft_torque.gmf'], ref['propeller_shaft_torque.gmf']):+.1f} | "
            f"{db(m['propeller_shaft_torque.sb'], ref['propeller_shaft_torque.sb']):+.1f} | "
            f"{m['energy_residual']:.1e} |")
    lines += ["", "Columns: relative error of the mean propeller-shaft (PSH) and drive-shaft (DSH) torque; of the "
              "PSH torque fluctuation (standard deviation); level of the PSH spectrum at f_GMF and at the first "
              "sidebands f_GMF ± f_MSH relative to the reference (0 dB = same); the run's energy-audit residual. "
              "The analytic and ideal rows simulate the healthy geometry (they cannot represent the fault): their "
              "sideband row shows what ignoring the fault costs."]
    md = Path(args.out + ".md")
    md.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(8, 5))
        for m in rows[1:]:
            err = max(rel(m["propeller_shaft_torque.rms_ac"], ref["propeller_shaft_torque.rms_ac"]), 1e-5)
            ax.loglog(m["wall_per_sim_s"], 100 * err, "o")
            ax.annotate(m["label"], (m["wall_per_sim_s"], 100 * err), fontsize=7, xytext=(4, 2),
                        textcoords="offset points")
        ax.axvline(1.0, color="gray", lw=0.8, ls="--")
        ax.set_xlabel("cost [loop wall s per simulated s]  (left of the dashed line: faster than real time)")
        ax.set_ylabel("error of the propeller-shaft torque fluctuation [%]")
        ax.set_title("Accuracy against cost (reference: online PCM, fine steps)")
        ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        fig.savefig(args.out + ".png", dpi=120)
        print(f"wrote {md} and {args.out}.png")
    except Exception as exc:  # plotting is optional for the table
        print(f"plot not written: {exc}")


if __name__ == "__main__":
    main()
