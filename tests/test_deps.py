"""tools/deps.sh --check, which make runs before every build: it passes on this
environment, and names a pinned Python package (an oracle of the tests, a baseline of
the benchmarks) that is not installed or at another version. And the project's shell
scripts: --help prints their usage and does nothing else; an option they do not take is
an error."""
import os
import shutil

import pytest

from conftest import ROOT, run


def check(tree):
    return run(["bash", tree / "tools" / "deps.sh", "--check"], check=False, timeout=120)


def test_check_passes_on_this_environment():
    p = check(ROOT)
    assert p.returncode == 0, p.stderr


def test_check_names_a_missing_oracle_and_a_wrong_version(tmp_path):
    # a copy of the project's deps.sh and requirements beside the same .venv, with the
    # requirements changed as if pyubx2 were uninstalled and small_gicp were another version
    (tmp_path / "tools").mkdir()
    shutil.copy(ROOT / "tools" / "deps.sh", tmp_path / "tools" / "deps.sh")
    os.symlink(ROOT / ".venv", tmp_path / ".venv")
    req = (ROOT / "tools" / "requirements.txt").read_text()
    assert "pyubx2==" in req and "small_gicp==" in req
    req = req.replace("pyubx2==", "pyubx2-not-installed==").replace("small_gicp==", "small_gicp==0.0.0+")
    (tmp_path / "tools" / "requirements.txt").write_text(req)
    p = check(tmp_path)
    assert p.returncode == 1
    assert "pyubx2-not-installed" in p.stderr and "not installed" in p.stderr, p.stderr
    assert "small_gicp==0.0.0+" in p.stderr and "installed 1." in p.stderr, p.stderr


@pytest.mark.parametrize("script, usage, refused", [
    ("tools/deps.sh", "tools/deps.sh [--check]", "unknown option"),
    ("tools/demo.sh", "tools/demo.sh [OUT_DIR]", "unknown option"),
    ("tools/demo-study.sh", "tools/demo-study.sh [OUT_DIR]", "unknown option"),
    ("tools/demo-study-report.sh", "tools/demo-study-report.sh OUT_DIR LAB_LOG... -- ROAD_RECORDING...",
     "unknown option"),
    ("modules/ouster/bench/bench.sh", "make bench-ouster", "unknown argument"),
    ("tests/fuzz/run.sh", "make fuzz", "unknown argument"),
])
def test_scripts_help_and_unknown_options(script, usage, refused, tmp_path):
    # --help prints the header (its usage line among it) and does nothing else. Before,
    # demo.sh and demo-study.sh took "--help" for their output folder (`mkdir -p --help`
    # printed mkdir's help, and a 300 MB drive went into ./--help), and deps.sh went on
    # to install
    p = run(["bash", ROOT / script, "--help"], check=False, timeout=30, cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert usage in p.stdout, p.stdout
    assert not p.stdout.startswith("#!") and "set -euo" not in p.stdout, p.stdout
    p = run(["bash", ROOT / script, "--no-such-option"], check=False, timeout=30, cwd=tmp_path)
    assert p.returncode == 2
    assert f"{script.rsplit('/', 1)[-1]}: {refused} '--no-such-option'" in p.stderr, p.stderr
    # the scripts work from the checkout's top: nothing may be made there under either name
    assert not (ROOT / "--help").exists() and not (ROOT / "--no-such-option").exists()
