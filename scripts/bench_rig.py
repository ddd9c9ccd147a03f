#!/usr/bin/env python3
"""Speed of a rig's calibration against a one-pair one (the target: a two-camera,
two-LiDAR calibration within 2x the time of a one-pair one), in the same run.

DIR is a rig parked in a surveyed room, made by the whole workflow:
    roomcal simulate --room config/room.toml --rig config/rig.toml --visits 8 --out DIR
    roomcal survey --room DIR/room.toml --visit DIR/visit-01/image.png DIR/visit-01/cloud.pcd ... --out DIR/surveyed.toml
The rig run is `roomcal calibrate --rig RIG` of every sensor in DIR/rig/; the reference is
`roomcal calibrate` of the first camera's image with the first LiDAR's cloud in the same
surveyed room as a one-pair room file (DIR/rig/room.toml, whose [camera]/[lidar] are the rig's
first pair, with the survey's tables appended). The two alternate run by run; wall seconds
(the process, image decoding and detection included) and CPU seconds of the child; medians.
Stdout is a markdown table.

    cargo build --release && scripts/bench_rig.py DIR [--rig config/rig.toml] [--runs 5] [--one-core]

--one-core pins both runs to the first core (the rig's sensors then run one after another):
on two cores the rig's parallel pieces share one physical core's caches and pipelines with
each other, so its CPU seconds grow while its wall seconds shrink; on one core CPU and wall
seconds are the same work.
"""
import argparse
import os
import statistics
import sys

sys.path.insert(0, os.path.dirname(__file__))
from bench_survey import timed  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOMCAL = os.path.join(ROOT, "target", "release", "roomcal")


def pair_room(d):
    """The rig's first pair as a room file, in the surveyed room."""
    surveyed = open(os.path.join(d, "surveyed.toml")).read()
    survey = surveyed[surveyed.index("\n[survey]") :]
    path = os.path.join(d, "pair-surveyed.toml")
    with open(path, "w") as f:
        f.write(open(os.path.join(d, "rig", "room.toml")).read().rstrip() + "\n" + survey)
    return path


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dir")
    ap.add_argument("--rig", default=os.path.join(ROOT, "config", "rig.toml"))
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--one-core", action="store_true")
    a = ap.parse_args()
    if a.one_core:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    rig_dir = os.path.join(a.dir, "rig")
    out = os.path.join(a.dir, "bench-result.json")
    rig_run = [ROOMCAL, "calibrate", "--room", os.path.join(a.dir, "surveyed.toml"), "--rig", a.rig, "--quiet", "--out", out]
    for name, flag, ext in [("front", "--image", "png"), ("wide", "--image", "png"), ("top", "--cloud", "pcd"), ("bumper", "--cloud", "pcd")]:
        rig_run += [flag, f"{name}={os.path.join(rig_dir, name + '.' + ext)}"]
    pair_run = [ROOMCAL, "calibrate", "--room", pair_room(a.dir), "--quiet", "--out", out,
                "--image", os.path.join(rig_dir, "front.png"), "--cloud", os.path.join(rig_dir, "top.pcd")]
    rig, pair = [], []
    for _ in range(a.runs):
        # Exit 3 (rejected by the gate) still did the whole work.
        rig.append(timed(rig_run, ok=(0, 3)))
        pair.append(timed(pair_run, ok=(0, 3)))
    med = lambda xs, i: statistics.median(x[i] for x in xs)
    load = os.getloadavg()[0]
    cores = len(os.sched_getaffinity(0))
    print(f"machine: {os.cpu_count()} cores ({cores} used), load average {load:.1f} at the end; median of {a.runs} runs")
    print()
    print("| run | exit | wall s | CPU s |")
    print("|---|---|---|---|")
    print(f"| one pair (front + top) | {pair[0][2]} | {med(pair, 0):.3f} | {med(pair, 1):.3f} |")
    print(f"| rig (front, wide, top, bumper) | {rig[0][2]} | {med(rig, 0):.3f} | {med(rig, 1):.3f} |")
    print(f"| rig / pair | | {med(rig, 0) / med(pair, 0):.2f} | {med(rig, 1) / med(pair, 1):.2f} |")


if __name__ == "__main__":
    main()
