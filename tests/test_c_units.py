"""Runs every C unit test the makefiles declare (`$(call c_test,test_NAME,...)` or
`cxx_test`) from build/tests/ and reports its checks. The list comes from the makefiles,
not from what happens to lie in build/tests: a test that was not built fails, and a
stale binary of a removed test is not run."""
import re

import pytest

from conftest import BUILD, ROOT, run

DECLARED = sorted({m for mk in ROOT.glob("**/*.mk") if ".venv" not in mk.parts and "build" not in mk.parts
                   for m in re.findall(r"call c(?:xx)?_test,(test_\w+)", mk.read_text())})


def test_the_makefiles_declare_the_unit_tests():
    # 14 declared when this was written; an empty or much shorter list would test little
    assert len(DECLARED) >= 14, DECLARED


@pytest.mark.parametrize("name", DECLARED)
def test_c_unit(name):
    binary = BUILD / "tests" / name
    assert binary.is_file(), f"{binary} not built: make test builds every declared unit test"
    p = run([binary], check=False, timeout=120)
    assert p.returncode == 0, f"{name} failed:\n{p.stdout}\n{p.stderr}"
    assert " 0 failed" in p.stdout
