"""Scenes: what a run is.

``load`` (the schema, validation, ``--set`` overrides, grids -> Scene), ``expect`` (the ``[expect]``
and ``[check]`` vocabulary). Imports ``rig`` and below, and the gear's specification modules.
"""
