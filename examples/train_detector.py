"""Train a fault detector on a simulated dataset, test it on held-out gearboxes and on the rig's measured
healthy record (issue 43, a worked example for ML users).

    pip install -e ".[ml]"                     # scikit-learn
    python examples/train_detector.py --out out/detector [--draws 12] [--duration 6] [--backend native]
    python examples/train_detector.py --dataset out/x/dataset.parquet --out out/detector   # an exported dataset

Without ``--dataset`` it first makes a small one: the shipped random-fault grid
(scenarios/datasets/random_faults.toml, the rig's measured background and sensors) at the measured record's
operating point (500 rpm, load motor 1.31 N·m), ``--draws`` faults, each with its gearbox's healthy twin
(``--set sweep.draw.n=... sweep.draw.paired_healthy=true``), exported with ``drivetrain dataset --settled-only``
(its ``split`` column puts each gearbox in one of train / validation / test).

Then, on windows of ``--window-s`` of both torque channels (``drivetrain.windows``, read run by run): a few
features per channel (standard deviation, kurtosis, crest factor, and the Hann amplitudes at the rig's
characteristic frequencies, the shaft orders and f_GMF with its sidebands; the mean is left out: the rig's
losses move it from campaign to campaign), a random forest on the ``label`` column (healthy or
``<kind>/<member>``) fitted on the train gearboxes; printed: the accuracy per label on the test gearboxes, the
detection rate (a faulty window called faulty) and the false-alarm rate (a healthy one called faulty), and the
false-alarm rate on the rig's measured healthy record (src/drivetrain/data/rig_records, cut into the same
windows): a detector trained on our healthy runs should take the real rig's healthy signals as healthy.
Writes ``OUT/confusion.png`` and ``OUT/detector.json``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

CHANNELS = ("drive_shaft_torque", "propeller_shaft_torque")
GRID = Path(__file__).resolve().parents[1] / "scenarios" / "datasets" / "random_faults.toml"


def features(x: np.ndarray, fs: float, speed_rpm: float) -> np.ndarray:
    """Features of one window (samples x channels): per channel std, kurtosis, crest factor and the log
    amplitudes at the characteristic frequencies (drivetrain.rig.signals, the plots' Hann convention)."""
    from drivetrain.rig.signals import amplitude_near, amplitude_spectrum, characteristic_frequencies

    cf = characteristic_frequencies(speed_rpm)
    lines = [cf["f_PSH"], cf["f_MSH"], 2 * cf["f_MSH"], cf["f_DSH"], cf["f_GMF"], 2 * cf["f_GMF"],
             cf["f_GMF"] - cf["f_MSH"], cf["f_GMF"] + cf["f_MSH"], cf["f_GMF"] - cf["f_PSH"], cf["f_GMF"] + cf["f_PSH"]]
    out = []
    for c in range(x.shape[1]):
        v = x[:, c].astype(float) - x[:, c].mean()
        sd = v.std() + 1e-12
        out += [np.log(sd), np.mean(v ** 4) / sd ** 4, np.abs(v).max() / sd]
        f, a = amplitude_spectrum(v, fs)
        out += [np.log(amplitude_near(f, a, fl, bins=1) + 1e-12) for fl in lines]
    return np.asarray(out)


def make_dataset(out: Path, draws: int, duration_s: float, backend: str) -> Path:
    """The small grid of the module docstring, swept and exported; returns dataset.parquet."""
    from drivetrain import sweep
    from drivetrain.campaigns.dataset import export

    overrides = [f"sweep.draw.n={draws}", "sweep.draw.paired_healthy=true",
                 "sweep.axes.operating_point.drive_speed_rpm=[500.0]",
                 "sweep.axes.operating_point.load_torque_Nm=[1.31]",
                 f"time.duration_s={duration_s}", f"time.settle_s={min(2.0, duration_s / 3):g}"]
    t0 = time.perf_counter()
    runs = sweep(str(GRID), out / "sweep", overrides=overrides, backend=backend, plots=False, skip_existing=True)
    print(f"sweep: {len(runs.runs)} runs in {time.perf_counter() - t0:.0f} s -> {out / 'sweep'}")
    return export(out / "sweep", "parquet", out / "dataset" / "dataset.parquet", settled_only=True,
                  split_fractions=(0.6, 0.0, 0.4))


def simulated_windows(dataset: Path, length: int):
    """(X, labels, splits, runs) of every window of the dataset, one run read at a time."""
    from drivetrain import windows

    X, y, split, runs = [], [], [], []
    for w in windows(dataset, list(CHANNELS), length=length, hop=length // 2):
        fs = float(w.labels["time.sample_rate_Hz"])
        speed = float(w.labels["operating_point.drive_speed_rpm"])
        for x in w.x:
            X.append(features(x, fs, speed))
            y.append(w.label)
            split.append(w.split)
            runs.append(w.run)
    return np.array(X), np.array(y), np.array(split), np.array(runs)


def record_windows(length: int, fs_model: float):
    """The measured healthy record cut into windows of ``length`` samples (half overlapping), after its filter
    start-up (rig.record.SKIP_S), as feature rows."""
    from drivetrain.rig import record as rec

    r = rec.load_record()
    skip = int(round(rec.SKIP_S * r.fs))
    data = np.stack([r.channels[c][skip:] for c in CHANNELS], axis=1)
    starts = range(0, len(data) - length + 1, length // 2)
    return np.array([features(data[s:s + length], r.fs, rec.RECORD_SPEED_RPM) for s in starts])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/detector", help="where the sweep, dataset and results go")
    ap.add_argument("--dataset", default=None, help="an exported dataset.parquet to train on (no sweep)")
    ap.add_argument("--draws", type=int, default=12, help="drawn faults (each with its healthy twin; default 12)")
    ap.add_argument("--duration", type=float, default=6.0, help="simulated seconds per run (default 6)")
    ap.add_argument("--window-s", type=float, default=0.5, help="window length [s] (default 0.5)")
    ap.add_argument("--backend", default="native", help="sweep backend (default native)")
    args = ap.parse_args(argv)
    try:
        from sklearn.ensemble import RandomForestClassifier
        from sklearn.metrics import ConfusionMatrixDisplay
    except ImportError:
        print("this example needs scikit-learn: pip install -e '.[ml]'", file=sys.stderr)
        return 2
    out = Path(args.out)
    dataset = Path(args.dataset) if args.dataset else make_dataset(out, args.draws, args.duration, args.backend)
    fs = 3012.0
    length = int(round(args.window_s * fs))
    X, y, split, runs = simulated_windows(dataset, length)
    train, test = split == "train", split == "test"
    if not train.any() or not test.any():
        print(f"error: the dataset needs gearboxes in train and test (splits: {sorted(set(split))})", file=sys.stderr)
        return 2
    clf = RandomForestClassifier(n_estimators=300, class_weight="balanced", random_state=0, n_jobs=1)
    clf.fit(X[train], y[train])
    pred = clf.predict(X[test])
    yt = y[test]
    print(f"{len(X)} windows of {args.window_s:g} s from {len(set(runs))} runs; train {train.sum()} windows, "
          f"test {test.sum()} (gearboxes never in both)")
    print(f"{'label':28s} {'test windows':>12s} {'accuracy':>9s} {'called faulty':>14s}")
    result = {"labels": {}}
    for lab in sorted(set(yt)):
        m = yt == lab
        acc = float(np.mean(pred[m] == lab))
        faulty = float(np.mean(pred[m] != "healthy"))
        result["labels"][lab] = {"windows": int(m.sum()), "accuracy": acc, "called_faulty": faulty}
        print(f"{lab:28s} {int(m.sum()):12d} {acc:9.2f} {faulty:14.2f}")
    healthy = yt == "healthy"
    det = float(np.mean(pred[~healthy] != "healthy")) if (~healthy).any() else float("nan")
    fa_sim = float(np.mean(pred[healthy] != "healthy")) if healthy.any() else float("nan")
    R = record_windows(length, fs)
    fa_rec = float(np.mean(clf.predict(R) != "healthy"))
    result.update(detection_rate=det, false_alarm_simulated=fa_sim, false_alarm_measured=fa_rec,
                  measured_windows=len(R), window_s=args.window_s, dataset=str(dataset))
    print(f"detection rate (faulty test windows called faulty): {det:.2f}")
    print(f"false-alarm rate, simulated healthy test windows: {fa_sim:.2f}")
    print(f"false-alarm rate, the rig's measured healthy record ({len(R)} windows of {args.window_s:g} s, "
          f"500 rpm, load motor 1.31 N·m): {fa_rec:.2f}")
    out.mkdir(parents=True, exist_ok=True)
    import matplotlib

    matplotlib.use("Agg")
    labels = sorted(set(y[train]) | set(yt))
    disp = ConfusionMatrixDisplay.from_predictions(yt, pred, labels=labels, xticks_rotation=60, colorbar=False)
    disp.figure_.set_size_inches(1.0 + 0.55 * len(labels), 1.0 + 0.5 * len(labels))
    disp.ax_.set_title("test gearboxes: true label vs predicted (windows)", fontsize=9)
    disp.figure_.tight_layout()
    disp.figure_.savefig(out / "confusion.png", dpi=110)
    (out / "detector.json").write_text(json.dumps(result, indent=1))
    print(f"wrote {out / 'confusion.png'} and {out / 'detector.json'}")
    return 0


if __name__ == "__main__":      # a sweep's worker processes import this file again
    sys.exit(main())
