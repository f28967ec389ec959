"""What every FMU of this project bundles besides its model: the FMI-side runtime.

- ``guard``: the work-around for pythonfmu 0.7.0's exit-time double release, the FMI logger's text
  escaping (user text is never a printf format) and the value-reference guard (FMI 2.0 error
  semantics for unknown value references), and the slave's side of the FMI wrapper built in front of
  pythonfmu's export library (``EXPORT_LIBRARY``, the hidden ``FAIL_CHANNEL``; drivetrain.fmu_build.fmi_wrapper).
- ``slave_template``: the one template the drivetrain component slaves (FlexibleShaft,
  UpperTransmission, MotorLoad) are generated from at build time (``drivetrain.fmu_build.build``).
- :func:`check_runtime`: the first thing a slave script does after finding its packages: it names
  a missing Python package where a host shows it.

The physics packages (``gearcontact_fmu``, ``drivetrain``'s models) never import pythonfmu; only the
FMU shells (``gearcontact_fmu/slaves/GearContact.py``, ``drivetrain.models.fmishell``) and this package do.
"""
import importlib.util
import sys
from pathlib import Path

#: the third-party packages the bundled code imports in the host's Python (pythonfmu's slave base,
#: numpy, numba's JIT, scipy's filters, trimesh's mesh IO); resources/requirements.txt pins them
RUNTIME_PACKAGES = ("pythonfmu", "numpy", "numba", "scipy", "trimesh")


def check_runtime(model: str, resources: str | Path) -> None:
    """Find every runtime package (without importing it); when one is missing, write which and what to
    install to the host's stderr and raise ImportError with the same text. The one place an FMU writes to stderr:
    pythonfmu 0.7.0 forwards no log message unless debug logging is on, and a failed import leaves a
    host with only "Failed to instantiate model"."""
    missing = []
    for pkg in RUNTIME_PACKAGES:
        try:
            found = importlib.util.find_spec(pkg) is not None
        except (ImportError, ValueError):         # a package set to None in sys.modules, a broken one
            found = False
        if not found:
            missing.append(pkg)
    if missing:
        msg = (f"{model} FMU: the host's Python {sys.version.split()[0]} has no module named "
               f"{', '.join(repr(m) for m in missing)}. Install the packages of {Path(resources) / 'requirements.txt'} "
               "(python -m pip install -r requirements.txt) in the Python the host runs.")
        sys.stderr.write(msg + "\n")
        sys.stderr.flush()
        raise ImportError(msg)
