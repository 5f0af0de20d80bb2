#!/usr/bin/env python3
"""A keyframe sequence split for the whole localizer: the site (map.pcd) from the even
keyframes, the odd ones imported as the log to localize (LIDAR_SCAN + GROUND_TRUTH, base
poses of --vehicle); with --log even the other way round (the same sequence as a second,
independent trial: the starts are not tuned to one split). For bench-localizer-real and
tests/test_localizer.py alike.

usage: keyframe_site.py --scans DIR --poses POSES.txt --times TIMES.txt --vehicle FILE --out DIR [--log odd|even]

Writes DIR/site/map.pcd (voxel 0.15 m) and DIR/odd/odd.lcm (DIR/even/even.lcm);
DIR/odd/{scans,poses.txt,times.txt} hold the odd keyframes (scans as links). Existing files
under DIR are replaced.
"""
import argparse
import pathlib
import shutil
import subprocess
import sys

BIN = pathlib.Path(__file__).resolve().parents[3] / "build" / "bin"


def lines(path):
    return pathlib.Path(path).read_text().splitlines()


def link_keyframes(scans, poses, times, dest, first):
    """dest/{scans,poses.txt,times.txt}: every 2nd keyframe from index `first` (scans as
    links; the k-th scan in name order goes with the k-th pose and time line)."""
    (dest / "scans").mkdir(parents=True)
    for f in sorted(scans.iterdir())[first::2]:
        (dest / "scans" / f.name).symlink_to(f.resolve())
    (dest / "poses.txt").write_text("\n".join(lines(poses)[first::2]) + "\n")
    (dest / "times.txt").write_text("\n".join(lines(times)[first::2]) + "\n")
    return ["--scans", str(dest / "scans"), "--poses", str(dest / "poses.txt"), "--times", str(dest / "times.txt")]


def split(scans, poses, times, vehicle, out, log="odd"):
    """Builds the site and the log of the `log` keyframes (odd or even) under out; returns
    (site dir, log)."""
    scans, out = pathlib.Path(scans), pathlib.Path(out)
    site, lg, mp = out / "site", out / log, out / "site_keyframes"
    for d in (site, lg, mp):
        shutil.rmtree(d, ignore_errors=True)
    site.mkdir(parents=True)
    first = 1 if log == "odd" else 0
    log_in = link_keyframes(scans, poses, times, lg, first)
    map_in = link_keyframes(scans, poses, times, mp, 1 - first)
    mast = ["--vehicle", str(vehicle), "--quiet"]
    subprocess.run([str(BIN / "import-scans"), *map_in, "--map-out", str(site / "map.pcd"), "--voxel", "0.15",
                    "--out", str(site / "map_keyframes.lcm"), *mast], check=True)
    subprocess.run([str(BIN / "import-scans"), *log_in, "--out", str(lg / f"{log}.lcm"), *mast], check=True)
    return site, lg / f"{log}.lcm"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    for name in ("scans", "poses", "times", "vehicle", "out"):
        ap.add_argument(f"--{name}", required=True)
    ap.add_argument("--log", choices=("odd", "even"), default="odd",
                    help="the keyframes to localize (the site from the others; default odd)")
    a = ap.parse_args()
    try:
        split(a.scans, a.poses, a.times, a.vehicle, a.out, a.log)
    except (OSError, subprocess.CalledProcessError) as e:
        sys.exit(f"keyframe_site.py: {e}")


if __name__ == "__main__":
    main()
