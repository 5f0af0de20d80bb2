"""Every Python script of the benches and tools loads: its imports resolve from where it
stands (a bench moved into modules/NAME/bench/ once kept a path to modules/modules/webui,
and `make bench-localizer-real` stopped at its first step with nobody told). Scripts with
options answer --help; the others are imported under another name, so their main does not
run (a bench would take minutes). The shell scripts answer --help and refuse what they do
not take (tools/script-args.sh)."""
import subprocess
import sys

import pytest

from conftest import ROOT, run

# needs ouster-sdk, which make bench-ouster installs into a virtual environment of its own
OWN_ENVIRONMENT = {"modules/ouster/bench/sdk_baseline.py"}

SCRIPTS = sorted(str(p.relative_to(ROOT)) for pattern in ("modules/*/bench/*.py", "tools/*/*.py", "tools/*.py")
                 for p in ROOT.glob(pattern) if str(p.relative_to(ROOT)) not in OWN_ENVIRONMENT)


def test_scripts_found():
    # the glob itself must not come back empty (a moved folder would pass every case below)
    assert len(SCRIPTS) >= 20, SCRIPTS


@pytest.mark.parametrize("script", SCRIPTS)
def test_script_loads(script):
    path = ROOT / script
    text = path.read_text()
    if "argparse" in text and '__name__ == "__main__"' in text:
        r = subprocess.run([sys.executable, path, "--help"], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0 and "usage" in r.stdout, f"{script} --help: rc {r.returncode}\n{r.stdout}\n{r.stderr}"
    else:
        # as python does for `python script.py`: the script's folder first on the path
        probe = ("import importlib.util, sys; sys.path.insert(0, sys.argv[2]); "
                 "s = importlib.util.spec_from_file_location('script_under_test', sys.argv[1]); "
                 "s.loader.exec_module(importlib.util.module_from_spec(s))")
        r = subprocess.run([sys.executable, "-c", probe, path, path.parent], capture_output=True, text=True,
                           timeout=120, cwd=ROOT)
        assert r.returncode == 0, f"{script} does not import: rc {r.returncode}\n{r.stderr}"


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
