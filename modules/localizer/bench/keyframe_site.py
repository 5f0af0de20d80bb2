#!/usr/bin/env python3
"""A keyframe sequence split for the whole localizer: the site (map.pcd) from the even
keyframes, the odd ones imported as the log to localize (LIDAR_SCAN + GROUND_TRUTH, base
poses of --vehicle). For bench-localizer-real and tests/test_localizer.py alike.

usage: keyframe_site.py --scans DIR --poses POSES.txt --times TIMES.txt --vehicle FILE --out DIR

Writes DIR/site/map.pcd (voxel 0.15 m) and DIR/odd/odd.lcm; DIR/odd/{scans,poses.txt,times.txt}
hold the odd keyframes (scans as links). Existing files under DIR are replaced.
"""
import argparse
import pathlib
import shutil
import subprocess
import sys

BIN = pathlib.Path(__file__).resolve().parents[3] / "build" / "bin"


def lines(path):
    return pathlib.Path(path).read_text().splitlines()


def split(scans, poses, times, vehicle, out):
    """Builds the site and the odd log under out; returns (site dir, odd log)."""
    scans, out = pathlib.Path(scans), pathlib.Path(out)
    site, odd = out / "site", out / "odd"
    for d in (site, odd):
        shutil.rmtree(d, ignore_errors=True)
    site.mkdir(parents=True)
    (odd / "scans").mkdir(parents=True)
    # the 2nd, 4th, ... scan in name order goes with the 2nd, 4th, ... pose and time line
    for f in sorted(scans.iterdir())[1::2]:
        (odd / "scans" / f.name).symlink_to(f.resolve())
    (odd / "poses.txt").write_text("\n".join(lines(poses)[1::2]) + "\n")
    (odd / "times.txt").write_text("\n".join(lines(times)[1::2]) + "\n")
    mast = ["--vehicle", str(vehicle), "--quiet"]
    subprocess.run([str(BIN / "import-scans"), "--scans", str(scans), "--poses", str(poses), "--times", str(times),
                    "--every", "2", "--map-out", str(site / "map.pcd"), "--voxel", "0.15",
                    "--out", str(site / "even.lcm"), *mast], check=True)
    subprocess.run([str(BIN / "import-scans"), "--scans", str(odd / "scans"), "--poses", str(odd / "poses.txt"),
                    "--times", str(odd / "times.txt"), "--out", str(odd / "odd.lcm"), *mast], check=True)
    return site, odd / "odd.lcm"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    for name in ("scans", "poses", "times", "vehicle", "out"):
        ap.add_argument(f"--{name}", required=True)
    a = ap.parse_args()
    try:
        split(a.scans, a.poses, a.times, a.vehicle, a.out)
    except (OSError, subprocess.CalledProcessError) as e:
        sys.exit(f"keyframe_site.py: {e}")


if __name__ == "__main__":
    main()
