"""No silent first run: a cold numba cache is detected and its compile reported through the
progress factory; a cached kernel is not."""
import importlib.util
import sys

import numba
import pytest

from gearcontact_fmu import compile_notice, progress

KERNEL = """
from numba import njit

@njit(cache=True)
def kernel(x):
    return 2.0 * x + 1.0
"""


def _load(path, name):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture
def bars(monkeypatch):
    made = []

    class Bar:
        def __init__(self, desc, total, **info):
            self.desc, self.total, self.info, self.n, self.closed = desc, total, info, 0, False
            made.append(self)

        def update(self, n=1):
            self.n += n

        def close(self):
            self.closed = True

    monkeypatch.setattr(progress, "_FACTORY", Bar)
    return made


def test_a_cold_kernel_is_reported_while_it_compiles_and_a_cached_one_is_not(tmp_path, monkeypatch, bars):
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path / "numba_cache"))
    src = tmp_path / "fresh_kernels.py"
    src.write_text(KERNEL)
    mod = _load(src, "fresh_kernels_a")
    assert compile_notice.kernels_cold(mod.kernel)
    with compile_notice.compiling(mod.kernel):
        assert mod.kernel(1.0) == 3.0
    assert len(bars) == 1 and bars[0].closed and bars[0].total == compile_notice.COLD_COMPILE_S
    assert "compiling the contact kernels" in bars[0].desc and str(tmp_path / "numba_cache") in bars[0].desc
    assert not compile_notice.kernels_cold(mod.kernel)              # compiled in this process
    again = _load(src, "fresh_kernels_b")                           # a new process's view: from the disk cache
    assert not again.kernel.signatures and not compile_notice.kernels_cold(again.kernel)
    with compile_notice.compiling(again.kernel):
        again.kernel(2.0)
    assert len(bars) == 1                                           # nothing said for a cached kernel


def test_the_map_builder_says_so():
    from gearcontact_fmu import contact_map

    assert isinstance(contact_map.kernels_cold(), bool)
    assert "numba" in contact_map.compile_notice_text() and f"{compile_notice.COLD_COMPILE_S} s" in contact_map.compile_notice_text()
