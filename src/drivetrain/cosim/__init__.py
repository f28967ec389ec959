"""Co-simulation of FMUs: one concern per module.

- ``plan``: a SystemSpec checked against the model descriptions -> the exchange plan
- ``slaves``: the FMI backend (fmpy, raw ctypes) and the in-process backend behind the same calls
- ``master``: the stepping loop (``Master``, ``simulate``, ``CosimResult``)
- ``observers``: what the loop calls between chunks of steps (the ``Observer`` interface; the recorder, the
  progress bar, the loop's clock)
- ``energy``: the energy audit of a run

The public names are re-exported here: ``from drivetrain.cosim import simulate``. The FMUs themselves (on disk,
built when missing or stale, their model descriptions) are the building wing's, ``drivetrain.fmu_build.fmus``,
which ranks below the co-simulation (it never imports it); its names are re-exported here too for scripts.
"""
from drivetrain.cosim.energy import ENERGY_FLOOR_J, energy_audit, energy_unavailable
from drivetrain.fmu_build.fmus import (
    ENERGY_VARS,
    PORT_UNITS,
    PORT_VARS,
    STAMP_FILE,
    FMUInfo,
    VarInfo,
    ensure_fmus,
    extracted_dir,
    load_fmu_info,
    record_built,
    sources_hash,
    stale_models,
)
from drivetrain.cosim.master import CosimResult, Master, failure_cause, simulate
from drivetrain.cosim.observers import Chunk, LoopEnd, LoopInfo, Observer
from drivetrain.cosim.plan import ExchangePlan, check_comm_step, check_system
from drivetrain.cosim.slaves import load_slave_class
from drivetrain.errors import ConfigurationError, CosimError

__all__ = ["Master", "simulate", "CosimResult", "Observer", "LoopInfo", "Chunk", "LoopEnd", "ConfigurationError", "CosimError", "check_system",
           "check_comm_step", "ExchangePlan", "ensure_fmus", "record_built", "stale_models", "sources_hash",
           "load_fmu_info", "extracted_dir", "FMUInfo", "VarInfo", "energy_audit", "energy_unavailable",
           "failure_cause", "load_slave_class", "ENERGY_FLOOR_J", "ENERGY_VARS", "PORT_VARS", "PORT_UNITS", "STAMP_FILE"]
