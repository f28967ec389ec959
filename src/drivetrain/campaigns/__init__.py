"""Many runs: sweeps and datasets, the stress campaign, the paper's validation, the accuracy-cost
study, the calibration, scenes as regression checks (baselines). Imports ``run`` and below.
"""
