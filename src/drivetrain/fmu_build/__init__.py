"""Building the FMUs of the project: one concern per module.

- ``build``: every pythonfmu FMU (slave scripts, bundled sources, the final modelDescription)
- ``bundle``: what runs inside an FMU, derived from the imports (the bundle and its staleness)
- ``fmu_docs``: what an FMU ships for a user (documentation, example input, reference plot, requirements)
- ``fmi_wrapper``: the C binary in front of pythonfmu's export library (``native/pythonfmu_wrapper.c``)
- ``fmi_headers``: the FMI runtime's C headers (``fmu_runtime/native``) every C build compiles
- ``native_gear``, ``native_line``: the Python-free FMUs (``native/line_native.c``; the gear's C model is
  ``gearcontact_fmu/native``)
- ``fmus``: FMUs on disk: where they live, built when missing or stale (the build stamp), extracted, their
  model descriptions read

The co-simulation (``drivetrain.cosim``) ranks above this wing: its master asks ``fmus`` for the FMUs of a
system (built when missing or stale) and reads their model descriptions; nothing here imports the
co-simulation (docs/ARCHITECTURE.md, "Which way the imports go"). The modules are imported by name
(``from drivetrain.fmu_build.fmus import ensure_fmus``): importing the wing loads none of them.
"""
