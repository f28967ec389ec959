"""Results are bit-identical across refactoring: short in-process runs hash to the stored values.

The hashes in tests/data/bit_identity.json were written by ``python benchmarks/bit_identity.py --store``
(which also compares this tree with any git revision, FMI backend included), one entry per platform.
Floating-point results depend on the numpy/numba builds and the processor numba compiles for, so the
comparison is exact on a platform that stored them and skipped (with the reason) elsewhere; store after
checking a tree side by side with ``--against``, re-store after a deliberate change of results.
"""
import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _bench():
    spec = importlib.util.spec_from_file_location("bit_identity", ROOT / "benchmarks" / "bit_identity.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_short_runs_hash_as_stored(tmp_path, fmu_dir):
    bench = _bench()
    here = bench.platform_key()
    entries = [e for e in bench.stored_entries() if e["platform"] == here]
    if not entries:
        pytest.skip(f"stored on {[e['platform'] for e in bench.stored_entries()]}, this is {here}: run "
                    "python benchmarks/bit_identity.py --against REV (side by side), then --store")
    stored = entries[0]
    cases = {n: (c["scene"], c["set"], c["backend"]) for n, c in stored["cases"].items()}
    assert cases and all(b == "inprocess" for _, _, b in cases.values())
    got = bench.hashes(ROOT, cases, str(fmu_dir))
    for name, case in stored["cases"].items():
        assert got[name]["samples"] == case["samples"] and got[name]["signals"] == case["signals"], name
        assert got[name]["sha256"] == case["sha256"], f"{name}: results changed ({got[name]['sha256'][:16]} vs stored {case['sha256'][:16]})"
