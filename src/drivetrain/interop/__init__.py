"""Our systems for other FMI tools: ``ssp`` (an SSP 1.0 archive of a scene's system) and
``container`` (an FMU container of it). Imports ``run`` and below.
"""
