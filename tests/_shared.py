"""Constants shared by the tests of several wings (tests/<wing>/): the checkout's root, the example scene,
and a short run of it at a coarse contact mesh."""
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "scenarios" / "example.toml"
# a short run at a coarse contact mesh (the contact map of this resolution builds in about a minute;
# the converged default is covered by tests/gear_contact/test_pcm_pair.py and the slow runs)
SHORT = ["time.duration_s=0.03", "time.settle_s=0.01", "outputs.plots=false", "outputs.aalto_csv=false",
         "numerics.profile_element_mm=0.2", "numerics.max_substep_s=2e-6"]


def accuracy_results():
    """A small accuracy-cost result table (the shape of drivetrain/data/accuracy_cost.json) whose choices are
    known: the cheapest setting within 1 % or 5 % differs per scene (tests/run/test_accuracy.py, the CLI's)."""
    def row(cost, err):
        return {"status": "ok", "loop_s_per_s": cost,
                "errors": {"mean_err_pct": err, "std_err_pct": err, "gmf_dB": err, "sideband_dB": None}}
    return {"scenes": {
        "healthy_1500rpm": {"health_class": "healthy", "speed_rpm": 1500.0,
                            "rows": {"reference": row(4.0, 0.0), "default": row(2.0, 0.5), "fast": row(0.9, 3.0),
                                     "tooth_compliance": row(0.1, 0.0)}},
        "severe_250rpm": {"health_class": "severe", "speed_rpm": 250.0,
                          "rows": {"reference": row(4.0, 0.0), "default": row(2.0, 2.0), "fast": row(0.9, 8.0)}},
    }}
