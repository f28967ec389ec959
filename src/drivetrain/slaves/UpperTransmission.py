"""UpperTransmission: FMI 2.0 co-simulation FMU of the azimuth-thruster drivetrain (pythonfmu slave).

A thin shell: the model is drivetrain.components.UpperTransmission, the FMI shell drivetrain.fmishell (parameters,
flange ports, units, error handling; docs/DRIVETRAIN.md). Package import: the installed
``drivetrain`` when importable, else the copy bundled in ``resources/_bundled``
(``BEVEL_FMU_USE_BUNDLED=1`` forces the bundled copy).
"""
import importlib.util
import os
import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent
_BUNDLED = _HERE / "_bundled"
_FORCE_BUNDLED = os.environ.get("BEVEL_FMU_USE_BUNDLED", "").strip() not in ("", "0")
if _BUNDLED.is_dir() and (_FORCE_BUNDLED or importlib.util.find_spec("drivetrain") is None):
    sys.path.insert(0, str(_BUNDLED))

from drivetrain.fmishell import DESCRIPTIONS, ComponentSlave  # noqa: E402


class UpperTransmission(ComponentSlave):
    MODEL = "UpperTransmission"
    description = DESCRIPTIONS["UpperTransmission"]
