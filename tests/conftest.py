"""Session-wide test settings.

The test process loads dozens of pythonfmu 0.7.0 FMUs (fmpy and the in-process backend). pythonfmu's
export library releases its interpreter state twice when the process exits; ``fmu_runtime.guard`` pins
the state of every library whose slave it instantiates, but a library loaded without a successful
instantiation (the refusal tests) is not pinned, and glibc may then abort the process at exit
("corrupted double-linked list", rc 134) after every test passed (seen once in about ten full runs).
So the pytest process ends with ``os._exit`` and pytest's own exit status, after pytest has finished
everything (reports, summaries, junit XML): no C++ static destructor runs, and a green run stays green.
Set ``BEVEL_TESTS_NORMAL_EXIT=1`` to exit normally (e.g. to reproduce the exit-time crash).
"""
import os
import sys

import pytest

_EXIT = {"status": None}


def pytest_sessionfinish(session, exitstatus):
    _EXIT["status"] = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    if _EXIT["status"] is None or os.environ.get("BEVEL_TESTS_NORMAL_EXIT", "").strip() not in ("", "0"):
        return
    if hasattr(config, "workerinput"):       # a pytest-xdist worker: its controller decides
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(_EXIT["status"])


# The FMUs the tests share, each built once per test run (a pythonfmu FMU takes ~7 s to build, a native
# line FMU ~1 s, the native gear ~5 s). Tests that check a build, its cache or its staleness build into a
# directory of their own (tmp_path); the others read or run these and never write into their directory.

@pytest.fixture(scope="session")
def fmu_dir(tmp_path_factory):
    """A private FMU directory shared by every test that runs scenes or systems through the master or reads the
    drivetrain's FMUs (built on demand into it, once per session), so that tests never rewrite the shared
    fmus/."""
    return tmp_path_factory.mktemp("fmus_session")


@pytest.fixture(scope="session")
def pythonfmu_fmus(fmu_dir):
    """{model: path} of the four drivetrain FMUs, pythonfmu build, built once per session into ``fmu_dir``."""
    from drivetrain.fmu_build.fmus import ensure_fmus
    from drivetrain.fmu_build.native_line import MODELS as LINE_MODELS

    return ensure_fmus(["GearContact", *LINE_MODELS], fmu_dir)


@pytest.fixture(scope="session")
def mt_fmus(tmp_path_factory):
    """{model: path} of the small test FMUs of tests/_cosim_test_fmus.py (MTInertia, MTSpring, ...), built
    once per session for the tests of the master, the runner and the sweeps."""
    from _cosim_test_fmus import build_test_fmus

    return build_test_fmus(tmp_path_factory.mktemp("mt_fmus"))


@pytest.fixture(scope="session")
def native_cache_dir(tmp_path_factory):
    """A private cache of native FMUs (drivetrain.fmu_build.native_line.native_fmus) shared by the tests that run
    native FMUs without testing their build or its cache: each build (the example's gear: ~5 s) happens
    once per session. Tests of the build and the cache use a directory of their own."""
    return tmp_path_factory.mktemp("native_session")


@pytest.fixture(scope="session")
def fmus_both_builds(pythonfmu_fmus, tmp_path_factory):
    """{(build, model): path} of the four FMUs in both builds, built once per session for the tests that read
    or run them without testing their build: "pythonfmu" (``pythonfmu_fmus``) and, with a C toolchain,
    "native" (GearContact with its at-rest defaults). Without a toolchain the native entries are absent (and
    the pythonfmu FMUs carry no FMI wrapper)."""
    from drivetrain.fmu_build.native_gear import build_native_gear
    from drivetrain.fmu_build.native_line import MODELS as LINE_MODELS, build_native_line, toolchain_problems

    out = {("pythonfmu", m): p for m, p in pythonfmu_fmus.items()}
    if not toolchain_problems():
        d = tmp_path_factory.mktemp("native_both_builds")
        for m in LINE_MODELS:
            out[("native", m)] = build_native_line(m, d / f"{m}.fmu")
        out[("native", "GearContact")] = build_native_gear({}, d / "GearContact.fmu")
    return out


@pytest.fixture(scope="module")
def maps_tabulated_in_this_process():
    """Contact maps tabulated in the test's own process for a whole module (``$BEVEL_MAP_WORKERS`` = 1): for the
    small maps of the map tests threads per map gain little, and the threads are not what they
    test. A module asks for it with ``pytestmark = pytest.mark.usefixtures(...)``."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("BEVEL_MAP_WORKERS", "1")
        yield


@pytest.fixture
def contact_maps_read_once():
    """``_shared.contact_map_read_once`` around one test."""
    from _shared import contact_map_read_once

    with contact_map_read_once():
        yield


#: the tests that run the contact engine (node-id prefixes: a folder or a module), scheduled as one unit of
#: pytest-xdist's ``--dist loadscope``, so in one worker: the contact-map and online-PCM tests compile the engine
#: (about 30 s of one core from a cold numba cache) and load it; as modules spread over the workers, every worker
#: compiled it. Together, it compiles once per run, and the other workers take the other modules meanwhile (the
#: unit is the largest, so it starts first; it holds well under half of the suite's time).
ENGINE_TESTS = ("tests/gear_contact/", "tests/run/test_scene_effects.py", "tests/run/test_failure_stability.py",
                "tests/cli/test_hostile_inputs.py", "tests/fmu_build/test_native_gear.py")


def pytest_xdist_make_scheduler(config, log):
    """``--dist loadscope`` (pyproject's addopts), with the tests of :data:`ENGINE_TESTS` one scope."""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class EngineScope(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return "contact engine" if nodeid.startswith(ENGINE_TESTS) else super()._split_scope(nodeid)

    return EngineScope(config, log)


def pytest_xdist_auto_num_workers(config):
    """``-n auto`` (the default run, pyproject's addopts): one worker per CPU this process may use, at most 8
    (each worker builds the session's FMUs once; beyond 8 those builds outweigh the gain)."""
    return max(1, min(8, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))
