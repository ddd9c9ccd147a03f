#!/usr/bin/env python3
"""Speed of `roomcal survey` (the target: 32 visits in <= 10 s on two cores).

One simulation of the design's room (six boards, 1920x1200, Pandar64, --supersample 1,
seed 1) with the largest number of visits asked for; the first N visits are surveyed for
each N. Every run is timed around the process: wall seconds and CPU seconds (user + system
of the child). The reference, in the same run of this script, is one free-board
`roomcal calibrate` of visit 1 (the same image and cloud, the work the survey does per
visit before its bundle): the ratios survey / reference say how the survey scales on
whatever machine this runs on, and stay comparable when the machine is shared.
Medians over --runs runs. Stdout is a markdown table.

    cargo build --release && scripts/bench_survey.py [--visits 8 16 32] [--runs 3] [--work DIR]
"""
import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOMCAL = os.path.join(ROOT, "target", "release", "roomcal")
ROOM = os.path.join(ROOT, "config", "room.toml")


def timed(args, ok=(0,)):
    """(wall s, CPU s, exit status) of one run of `args`, which must exit with one of `ok`."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.monotonic()
    run = subprocess.run(args, capture_output=True, text=True)
    wall = time.monotonic() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if run.returncode not in ok:
        sys.exit(f"{' '.join(args[:2])} failed ({run.returncode}): {run.stderr}{run.stdout}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, run.returncode


def median_timed(args, runs):
    times = [timed(args) for _ in range(runs)]
    return statistics.median(t[0] for t in times), statistics.median(t[1] for t in times)


def visit(sim_dir, v):
    folder = os.path.join(sim_dir, f"visit-{v:02}")
    return os.path.join(folder, "image.png"), os.path.join(folder, "cloud.pcd")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--visits", type=int, nargs="+", default=[8, 16, 32])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--work", default=None)
    args = parser.parse_args()
    work = args.work or tempfile.mkdtemp(prefix="bench-survey-")
    sim_dir = os.path.join(work, f"room-seed{args.seed}-{max(args.visits)}")
    if not os.path.exists(os.path.join(sim_dir, "room-truth.json")):
        subprocess.run([ROOMCAL, "simulate", "--room", ROOM, "--out", sim_dir, "--visits",
                        str(max(args.visits)), "--supersample", "1", "--seed", str(args.seed)],
                       check=True, capture_output=True)
    room = os.path.join(sim_dir, "room.toml")
    image, cloud = visit(sim_dir, 1)
    out = os.path.join(work, "reference.json")
    reference = median_timed([ROOMCAL, "calibrate", "--room", room, "--image", image, "--cloud", cloud,
                              "--out", out, "--quiet"], args.runs)
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start; "
          f"median of {args.runs} runs")
    print(f"reference: one free-board `roomcal calibrate` of visit 1: {reference[0]:.2f} s wall, "
          f"{reference[1]:.2f} s CPU")
    print()
    print("| visits | wall s | CPU s | wall / reference | CPU / reference | CPU per visit / reference |")
    print("|---|---|---|---|---|---|")
    for count in args.visits:
        cmd = [ROOMCAL, "survey", "--room", room, "--out", os.path.join(work, f"surveyed-{count}.toml")]
        for v in range(1, count + 1):
            cmd += ["--visit", *visit(sim_dir, v)]
        wall, cpu = median_timed(cmd, args.runs)
        print(f"| {count} | {wall:.2f} | {cpu:.2f} | {wall / reference[0]:.1f} | {cpu / reference[1]:.1f} "
              f"| {cpu / count / reference[1]:.2f} |", flush=True)


if __name__ == "__main__":
    main()
