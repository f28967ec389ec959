"""UpperTransmission: FMI 2.0 co-simulation FMU of the azimuth-thruster drivetrain (pythonfmu slave).

A thin shell: the model is drivetrain.components.UpperTransmission, the FMI plumbing drivetrain.fmishell (parameters,
flange ports, units, error handling; docs/DRIVETRAIN.md). The class derives from Fmi2Slave directly
(pythonfmu finds the slave class by that pattern in this file). Package import: the installed
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

from pythonfmu import Fmi2Slave  # noqa: E402

from drivetrain import fmishell  # noqa: E402


class UpperTransmission(Fmi2Slave):
    description = fmishell.DESCRIPTIONS["UpperTransmission"]
    author = "bevel-drivetrain"
    version = "0.1.0"
    units = fmishell.UNITS          # read by drivetrain.fmubuild (modelDescription units)
    default_experiment = fmishell.DEFAULT_EXPERIMENT

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        fmishell.init_slave(self, "UpperTransmission", kwargs)

    def enter_initialization_mode(self):
        fmishell.enter_init(self)

    def exit_initialization_mode(self):
        fmishell.exit_init(self)

    def do_step(self, current_time, step_size):
        return fmishell.do_step(self, current_time, step_size)
