"""Co-simulated drivetrain of the azimuth-thruster test rig: component models, FMUs, master,
scenarios and the ``drivetrain`` command line.

The Python API (README "Python API"), loaded on first use so that ``import drivetrain`` stays cheap::

    from drivetrain import load_scene, run_scene, sweep
    result = run_scene(load_scene("scenarios/example.toml", ["time.duration_s=0.5"]), backend="native")
    df = result.to_dataframe()              # units in df.attrs["units"]
"""

__version__ = "0.1.0"

#: the public names -> the module that defines them (imported by :func:`__getattr__` when first asked for;
#: by name, not by an import statement, so that this package's top stays free of the wings below it)
_API = {
    "load_scene": "drivetrain.scene.load",
    "load_scenes": "drivetrain.scene.load",
    "Scene": "drivetrain.scene.load",
    "run_scene": "drivetrain.run.runner",
    "RunResult": "drivetrain.run.runner",
    "sweep": "drivetrain.campaigns.sweep_api",
    "SweepResult": "drivetrain.campaigns.sweep_api",
    "load_dataset": "drivetrain.campaigns.loaders",
    "windows": "drivetrain.campaigns.loaders",
    "spectrum": "drivetrain.campaigns.loaders",
}

__all__ = ["__version__", *_API]


def __getattr__(name: str):
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'drivetrain' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_API})
