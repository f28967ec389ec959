"""What a run stores as JSON: numbers stay numbers (numpy scalars too), a generated profile is described."""
import json
import math

import numpy as np

from drivetrain.campaigns import stress as S
from drivetrain.rig.background import GeneratedProfile
from drivetrain.run.outputs import jsonable


def test_numpy_scalars_are_numbers_and_generated_profiles_are_described():
    # np.float64 has __array__ and shape as a generated profile does: it was stored as
    # {"generated_profile": "np.float64(2148.418)"} inside a profile's rows
    rows = [[0.0, 0.0], [0.018429, np.float64(2148.418)]]
    assert jsonable(rows) == [[0.0, 0.0], [0.018429, 2148.418]]
    assert jsonable({"n": np.int64(3), "b": np.bool_(True), "x": np.float32(0.5), "bad": np.float64("nan")}) == \
        {"n": 3, "b": True, "x": 0.5, "bad": None}
    g = GeneratedProfile(lambda: np.zeros(4), 4, 0.001)
    assert jsonable({"load_profile_Nm": g}) == {"load_profile_Nm": {"generated_profile": repr(g)}}
    assert jsonable(np.array([[0.0, 1.5]])) == [[0.0, 1.5]]


def test_a_stress_campaign_stores_its_draws_as_numbers():
    """Every drawn profile in stress.json is rows of numbers, so `--report-only` can judge it again."""
    for seed in range(3):
        for i in range(60):
            p = json.loads(json.dumps(jsonable(S.draw_random(seed, i))))
            for key in ("speed_profile_rpm", "load_profile_Nm"):
                for row in p.get(key) or []:
                    assert all(isinstance(v, (int, float)) and math.isfinite(v) for v in row), (seed, i, key, row)
            if S.held_standstill_from_s(p) is not None:       # the judge reads them back without error
                assert S.held_standstill_from_s(p) >= 0.0


def test_a_campaign_stored_before_the_fix_is_read_back_as_numbers():
    """stress.json written before the fix held numbers as {"generated_profile": "np.float64(...)"}: `--report-only`
    reads them back as the numbers they were; a real generated profile's description stays as it is."""
    old = {"speed_profile_rpm": [[0.0, 0.0], [0.018429, {"generated_profile": "np.float64(2148.418)"}]],
           "n": {"generated_profile": "np.int64(3)"},
           "load_profile_Nm": {"generated_profile": "GeneratedProfile(4 rows at H = 0.001 s)"}}
    assert S._stored_numbers(old) == {"speed_profile_rpm": [[0.0, 0.0], [0.018429, 2148.418]], "n": 3.0,
                                      "load_profile_Nm": old["load_profile_Nm"]}
