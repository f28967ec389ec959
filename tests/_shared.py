"""Constants and helpers shared by the tests of several wings (tests/<wing>/): the checkout's root, the example
scene, a short run of it at a coarse contact mesh, test kernels that call a mesh kernel."""
import contextlib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "scenarios" / "example.toml"
# a short run at a coarse contact mesh (the contact map of this resolution builds in about a minute;
# the converged default is covered by tests/gear_contact/test_pcm_pair.py and the slow runs)
SHORT = ["time.duration_s=0.03", "time.settle_s=0.01", "outputs.plots=false", "outputs.aalto_csv=false",
         "numerics.profile_element_mm=0.2", "numerics.max_substep_s=2e-6"]


_POINTER_KERNELS: dict = {}


def through_pointer(py_func, mesh_eval, data, ret, *rest):
    """``py_func(mesh_eval, data, *rest) -> ret`` compiled (and cached on disk) with the mesh kernel as a typed
    first-class function argument, as the gear stage takes it (``mesh_models.base.eval_signature``): it calls
    the compiled kernel through its pointer. Given as a dispatcher, the kernel (the contact engine, or a closure
    of ``manufacturing.with_errors``) would be compiled into the test kernel every session (~3-4 s), and numba
    cannot cache that. One compile per function and signature in a process."""
    from numba import njit, typeof, types

    from gearcontact_fmu.mesh_models.base import eval_signature

    data_type = typeof(data)
    sig = ret(types.FunctionType(eval_signature(mesh_eval, data_type)), data_type, *rest)
    key = (py_func, sig)
    if key not in _POINTER_KERNELS:
        _POINTER_KERNELS[key] = njit(sig, cache=True)(py_func)
    return _POINTER_KERNELS[key]


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


@contextlib.contextmanager
def contact_map_read_once():
    """While open, ``gearcontact_fmu.contact_map.load_map`` reads and checks each contact-map file once per file
    state (path, size, mtime) and per layout asked for, and hands every later caller a deep copy of the map the
    real reader returned (the same arrays any read of those bytes gives). For tests of what calls it many times
    (the record calibration assembles the drivetrain ~300 times, each assembly re-reading the rig pair's map:
    11 of its 17 s), not for tests of the map cache itself."""
    import copy

    import pytest

    from gearcontact_fmu import contact_map

    real, memo = contact_map.load_map, {}

    def load_map(path, gear, pcm, grid, n_rev=1):
        st = Path(path).stat()
        key = (str(path), st.st_size, st.st_mtime_ns, gear, pcm, grid, n_rev)
        if key not in memo:
            memo[key] = real(path, gear, pcm, grid, n_rev)
        return copy.deepcopy(memo[key])

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(contact_map, "load_map", load_map)
        yield
