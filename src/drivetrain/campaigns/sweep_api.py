"""A sweep from Python (``from drivetrain import sweep``): scene or grid files, or scenes -> :class:`SweepResult`.

A plain function over :func:`drivetrain.campaigns.sweep.run_sweep` (the runs, the manifest) and
:mod:`drivetrain.campaigns.dataset` (the runs as one table): ``sweep(["grid.toml"], "out/grid").to_dataframe()``
is the dataset ``drivetrain dataset out/grid`` writes, as a pandas DataFrame.
"""
from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

from drivetrain.campaigns.dataset import export
from drivetrain.campaigns.sweep import run_sweep
from drivetrain.scene.load import Scene, load_scenes


@dataclass
class SweepResult:
    """What a sweep produced: its directory (one sub-directory per run, manifest.json) and its manifest."""

    out_dir: Path
    manifest: dict

    @property
    def runs(self) -> list[dict]:
        """One record per run (name, status, labels, wall time, mean torques, ...; manifest.json's "runs")."""
        return self.manifest.get("runs", [])

    def to_dataframe(self, settled_only: bool = False):
        """Every run's signals and labels as one pandas DataFrame, the layout of ``drivetrain dataset``
        (docs/SCENARIOS.md): one row per sample, columns ``run``, ``time_s``, ``settled``, one per channel
        and one per label (the scene keys as ``section.key``, the condition indicators); every column's
        unit in ``df.attrs["units"]`` ("1" dimensionless, "" text). ``settled_only``: the samples after each
        run's ``time.settle_s`` only."""
        from drivetrain.campaigns.loaders import load_dataset

        with tempfile.TemporaryDirectory(prefix="drivetrain_sweep_") as tmp:
            path = export(self.out_dir, "parquet", Path(tmp) / "dataset.parquet", settled_only=settled_only,
                          card=False)
            return load_dataset(path)


def sweep(scenes: str | Path | Scene | Iterable[str | Path | Scene], out_dir: str | Path, *,
          overrides: list[str] | tuple[str, ...] = (), **options) -> SweepResult:
    """Run every scene (a grid file expands to its cases) into ``out_dir``; returns a :class:`SweepResult`.

    ``scenes``: a scene or grid file, a Scene, or a list of them; ``overrides``: ``"key=value"`` changes of
    every file's scenes (as ``--set``); ``options``: those of :func:`drivetrain.campaigns.sweep.run_sweep`
    (``workers``, ``backend``, ``skip_existing``, ``plots``, ``progress``, ``fmu_dir``, ``force``, ...).
    """
    items = [scenes] if isinstance(scenes, (str, Path, Scene)) else list(scenes)
    loaded: list[Scene] = []
    for item in items:
        loaded += [item] if isinstance(item, Scene) else load_scenes(item, overrides)
    manifest = run_sweep(loaded, out_dir, **options)
    return SweepResult(Path(out_dir), manifest)


__all__ = ["sweep", "SweepResult"]
