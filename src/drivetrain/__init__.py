"""Co-simulated drivetrain of the azimuth-thruster test rig: component models, FMUs, master,
scenarios and the ``drivetrain`` command line."""

__version__ = "0.1.0"
