"""tools/deps.sh --check, which make runs before every build: it passes on this
environment, and names a pinned Python package (an oracle of the tests, a baseline of
the benchmarks) that is not installed or at another version."""
import os
import shutil

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
    for f in ("deps.sh", "script-args.sh"):
        shutil.copy(ROOT / "tools" / f, tmp_path / "tools" / f)
    os.symlink(ROOT / ".venv", tmp_path / ".venv")
    req = (ROOT / "tools" / "requirements.txt").read_text()
    assert "pyubx2==" in req and "small_gicp==" in req
    req = req.replace("pyubx2==", "pyubx2-not-installed==").replace("small_gicp==", "small_gicp==0.0.0+")
    (tmp_path / "tools" / "requirements.txt").write_text(req)
    p = check(tmp_path)
    assert p.returncode == 1
    assert "pyubx2-not-installed" in p.stderr and "not installed" in p.stderr, p.stderr
    assert "small_gicp==0.0.0+" in p.stderr and "installed 1." in p.stderr, p.stderr
