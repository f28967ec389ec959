"""The drivetrain's models and what is known of them before a step is taken.

``components`` (shaft line, upper transmission, motors and load: pure models, each parameter declared
once), ``fmu_variables`` (what their FMUs declare, plain data read by both builds), ``fmishell`` (the FMI
plumbing of their pythonfmu slaves: what an FMU bundles), ``eigen``
(natural frequencies, linearised co-simulation maps), ``stability`` (the cut checks before any step).
Imports ``rig`` and below.
"""
