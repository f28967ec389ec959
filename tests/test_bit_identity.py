"""Results are bit-identical across refactoring: short in-process runs hash to the stored values.

The hashes in tests/data/bit_identity.json were written by ``python benchmarks/bit_identity.py --store``
(which also compares this tree with any git revision, FMI backend included). Floating-point results
depend on the numpy/numba builds and the machine, so the comparison is exact on the platform that
stored them and skipped (with the reason) elsewhere; re-store after a deliberate change of results.
"""
import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STORE = ROOT / "tests" / "data" / "bit_identity.json"


def _bench():
    spec = importlib.util.spec_from_file_location("bit_identity", ROOT / "benchmarks" / "bit_identity.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_short_runs_hash_as_stored(tmp_path):
    bench = _bench()
    stored = json.loads(STORE.read_text())
    if stored["platform"] != bench.platform_key():
        pytest.skip(f"stored on {stored['platform']}, this is {bench.platform_key()}")
    cases = {n: (c["scene"], c["set"], c["backend"]) for n, c in stored["cases"].items()}
    assert cases and all(b == "inprocess" for _, _, b in cases.values())
    got = bench.hashes(ROOT, cases, str(tmp_path / "fmus"))
    for name, case in stored["cases"].items():
        assert got[name]["samples"] == case["samples"] and got[name]["signals"] == case["signals"], name
        assert got[name]["sha256"] == case["sha256"], f"{name}: results changed ({got[name]['sha256'][:16]} vs stored {case['sha256'][:16]})"
