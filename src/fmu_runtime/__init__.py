"""What every FMU of this project bundles besides its model: the FMI-side runtime.

- ``guard``: the work-around for pythonfmu 0.7.0's exit-time double release, the FMI logger's text
  escaping (user text is never a printf format) and the value-reference guard (FMI 2.0 error
  semantics for unknown value references).
- ``slave_template``: the one template the drivetrain component slaves (FlexibleShaft,
  UpperTransmission, MotorLoad) are generated from at build time (``drivetrain.fmubuild``).

The physics packages (``gearcontact_fmu``, ``drivetrain``'s models) never import pythonfmu; only the
FMU shells (``gearcontact_fmu/slaves/GearContact.py``, ``drivetrain.fmishell``) and this package do.
"""
