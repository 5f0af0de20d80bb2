"""Runs every C unit test binary (build/tests/test_*) and reports its checks."""
import pytest

from conftest import BUILD, run

TESTS = sorted(p for p in (BUILD / "tests").glob("test_*") if p.is_file())


def test_c_tests_were_built():
    # tests/module.mk lists them; an empty list would silently test nothing.
    assert len(TESTS) >= 5, TESTS


@pytest.mark.parametrize("binary", TESTS, ids=[p.name for p in TESTS])
def test_c_unit(binary):
    p = run([binary], check=False, timeout=120)
    assert p.returncode == 0, f"{binary.name} failed:\n{p.stdout}\n{p.stderr}"
    assert " 0 failed" in p.stdout
