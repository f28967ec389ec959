"""The former home of the co-simulation master, kept so that scripts importing ``drivetrain.master``
keep working. The code lives in :mod:`drivetrain.cosim` (fmus, plan, slaves, master, energy)."""
from drivetrain.cosim import *  # noqa: F401,F403
from drivetrain.cosim import __all__  # noqa: F401
