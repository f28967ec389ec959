"""pytest plugin: scene files with an ``[expect]`` section or a baseline are test items.

Registered as the ``pytest11`` entry point ``drivetrain`` (pyproject.toml), so with this package
installed ``pytest scenarios/ --junitxml=report.xml`` collects every ``*.toml`` scene under the given
paths that has an ``[expect]`` section (or ``[sweep.expect]`` tables), or a baseline file: one item per
scene, one per case of a grid file (``paper.toml::paper_severe_1500rpm_1.31Nm``). Each item runs its
scene in the test process (pytest-xdist spreads items over workers) and checks it like
``drivetrain check`` (:mod:`drivetrain.campaigns.check`); a failure lists every failing metric with expected,
actual and tolerance, and writes a plot against the baseline. Items of long scenes carry the ``slow``
marker (``[check] slow``, or the duration rule of :func:`drivetrain.scene.expect.is_slow`), so the usual
``-m 'not slow'`` selection applies. Other ``.toml`` files (pyproject.toml, scenes without checks) are
not collected; ``pytest -p no:drivetrain`` or ``--no-drivetrain-scenes`` switches the plugin off.

Options: ``--drivetrain-fmu-dir DIR`` (default ini ``drivetrain_fmu_dir`` or ``<rootdir>/fmus``),
``--drivetrain-baseline-dir DIR``, ``--drivetrain-out DIR`` (failure plots; default pytest's temporary
directory), ``--drivetrain-set KEY=VALUE`` (repeatable override of every scene),
``--drivetrain-backend fmi|inprocess``.
"""
from __future__ import annotations

from pathlib import Path

import pytest


def pytest_addoption(parser):
    g = parser.getgroup("drivetrain", "drivetrain scene checks (scene files as test items)")
    g.addoption("--drivetrain-fmu-dir", default=None, metavar="DIR",
                help="FMU directory for scene checks (built on demand; default: ini drivetrain_fmu_dir or <rootdir>/fmus)")
    g.addoption("--drivetrain-baseline-dir", default=None, metavar="DIR",
                help="baseline files DIR/<scene>.baseline.h5 (default: beside each scene file)")
    g.addoption("--drivetrain-out", default=None, metavar="DIR",
                help="where failing scene checks write their plots (default: pytest's temporary directory)")
    g.addoption("--drivetrain-set", action="append", default=[], metavar="KEY=VALUE",
                help="override a key of every checked scene (repeatable)")
    g.addoption("--drivetrain-backend", default="fmi", choices=("fmi", "inprocess"),
                help="co-simulation backend of scene checks (default fmi)")
    g.addoption("--no-drivetrain-scenes", action="store_true", default=False,
                help="do not collect scene files as test items")
    parser.addini("drivetrain_fmu_dir", "FMU directory for scene checks (relative to the rootdir)", default="")


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: long runs; deselect with -m 'not slow'")
    config.addinivalue_line("markers", "drivetrain_scene: a scene file checked against its [expect] section "
                                       "and baseline (drivetrain.pytest_plugin)")


def _wants_scene(path: Path) -> bool:
    """A scene file with something to check: [expect], [sweep.expect] or a baseline file."""
    from drivetrain.campaigns.baseline import baseline_path
    from drivetrain.scene.load import ScenarioError, read_toml

    try:
        raw = read_toml(path)
    except ScenarioError:
        return False
    grid = raw.get("sweep")
    if "expect" in raw or (isinstance(grid, dict) and "expect" in grid):
        return True
    chk = raw.get("check")
    if isinstance(chk, dict) and isinstance(chk.get("baseline"), str):
        b = Path(chk["baseline"])
        return (b if b.is_absolute() else path.parent / b).is_file()
    return baseline_path(path).is_file()


def pytest_collect_file(file_path, parent):
    if file_path.suffix != ".toml" or parent.config.getoption("no_drivetrain_scenes"):
        return None
    if not _wants_scene(file_path):
        return None
    return SceneFile.from_parent(parent, path=file_path)


class SceneFile(pytest.File):
    """A scene or grid file: one item per case."""

    def collect(self):
        from drivetrain.scene.expect import is_slow
        from drivetrain.scene.load import load_scenes

        scenes = load_scenes(self.path, self.config.getoption("drivetrain_set") or ())
        self._scenes = scenes
        for scene in scenes:
            item = SceneItem.from_parent(self, name=scene.name)
            item.scene = scene
            item.add_marker(pytest.mark.drivetrain_scene)
            if is_slow(scene):
                item.add_marker(pytest.mark.slow)
            yield item

    def baseline(self):
        """(baseline file, {case: Entry}), read once per file (per process)."""
        if not hasattr(self, "_baseline"):
            from drivetrain.campaigns.check import load_baseline_for

            self._baseline = load_baseline_for(self.path, self._scenes,
                                               self.config.getoption("drivetrain_baseline_dir"))
        return self._baseline


class SceneCheckFailed(Exception):
    def __init__(self, case):
        super().__init__(case.report())
        self.case = case


class SceneItem(pytest.Item):
    """One scene (or grid case): run it, check expectations and baseline."""

    scene = None

    def _fmu_dir(self) -> Path:
        opt = self.config.getoption("drivetrain_fmu_dir") or self.config.getini("drivetrain_fmu_dir")
        p = Path(opt) if opt else Path("fmus")
        return p if p.is_absolute() else Path(self.config.rootpath) / p

    def _plot_dir(self) -> Path:
        out = self.config.getoption("drivetrain_out")
        if out:
            return Path(out) / self.scene.name
        factory = getattr(self.config, "_tmp_path_factory", None)
        if factory is not None:
            return factory.getbasetemp() / "drivetrain" / self.scene.name
        import tempfile

        return Path(tempfile.mkdtemp(prefix=f"drivetrain-{self.scene.name}-"))

    def runtest(self):
        from drivetrain.campaigns.check import check_run, run_case

        bp, cases = self.parent.baseline()
        run = run_case(self.scene, None, fmu_dir=self._fmu_dir(),
                       backend=self.config.getoption("drivetrain_backend"))
        base = cases.get(self.scene.name)
        cc = check_run(run, base=base, baseline_file=bp, plot_dir=self._plot_dir())
        self.user_properties.append(("checks", cc.n_checks))
        self.user_properties.append(("failed_checks", len(cc.failures)))
        if base is not None:
            self.user_properties.append(("baseline", str(bp)))
        for o in cc.failures:
            self.user_properties.append((f"failed:{o.key}", o.message.split(": ", 1)[1]))
        for p in cc.plots:
            self.user_properties.append(("plot", p))
        if not cc.ok:
            raise SceneCheckFailed(cc)
        if not cc.outcomes:
            pytest.skip("nothing to check: no [expect] entries and no baseline for this case")

    def repr_failure(self, excinfo, style=None):
        if isinstance(excinfo.value, SceneCheckFailed):
            return str(excinfo.value)
        return super().repr_failure(excinfo, style=style)

    def reportinfo(self):
        return self.path, None, f"scene {self.scene.name}"
