"""Many runs: sweeps and datasets, the stress campaign, the paper's validation, the accuracy-cost
study, the calibration, scenes as regression checks (baselines). Imports ``run`` and below.
"""

#: gearboxes (manufacturing, background and instrument seeds 0..N-1) a population statement runs over by
#: default: each check of ``drivetrain validate``, each cell of ``drivetrain detectability``
GEARBOXES = 20
