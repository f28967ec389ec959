"""One run of a scene.

``assemble`` (Scene -> SystemSpec: only what the scene's effects need), ``cost`` (the predicted wall
time and the refusal), ``accuracy`` (the accuracy-cost vocabulary and the choice within a tolerance),
``runner`` (run_scene -> RunResult), ``outputs`` (HDF5, summary, plots). Imports ``cosim`` and below.
"""
