"""The rig: what it is and how it is measured.

``data`` (constants, sensors, the public lumped model, its lumping and partition into FMUs, the
calibration, the steady state, the measured mean-torque table), ``instruments`` (encoders and torque
transducers as seeded models), ``signals`` (filters, spectra, the characteristic frequencies).
Imports only ``drivetrain.errors``/``system`` and ``gearcontact_fmu``.
"""
