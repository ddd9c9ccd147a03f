#!/usr/bin/env python3
"""End-to-end speed and accuracy of `roomcal calibrate` against OpenCV on the same scene,
in the same run: OpenCV finds every board (findChessboardCornersSB, masking each found
board and searching again, from bench_chessboard.py) and runs calibrateCamera with one
view per board; roomcal runs the whole `calibrate` command (image decode, detection,
start, joint solve, gate, result files). Both are compared with the scene's truth.

In the same run, the surveyed room against the free boards: the
surveyed fixture's scene (SURVEYED_DIR, its room file has a `[survey]`) calibrated in the
surveyed room and again with `--free-boards` (today's model), the same image and cloud,
alternating run by run; the ratio surveyed / free is the figure (target <= 1).

Usage (from the repository root, after `cargo build --release`):
    python3 scripts/bench_calibrate.py [SCENE_DIR] [--runs N] [--surveyed SURVEYED_DIR]
SCENE_DIR defaults to fixtures/six-boards-pandar64, SURVEYED_DIR to
fixtures/surveyed-pandar64. Needs opencv-python-headless, numpy.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import tomllib

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from bench_chessboard import opencv_all_boards  # noqa: E402

ROOMCAL = os.path.join("target", "release", "roomcal")


def run_roomcal(scene, out, with_cloud, extra=()):
    cmd = [ROOMCAL, "calibrate", "--room", f"{scene}/room.toml", "--image", f"{scene}/image.png", "--out", out]
    if with_cloud and os.path.exists(f"{scene}/cloud.pcd"):
        cmd += ["--cloud", f"{scene}/cloud.pcd"]
    elif with_cloud:  # the surveyed fixture ships its sweep as the capture only
        cmd += ["--cloud", f"{scene}/cloud.pcap", "--lidar-calibration", f"{scene}/angles.csv"]
    cmd += list(extra)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=False, capture_output=True)
    return time.perf_counter() - t0, json.load(open(out))


def run_opencv(scene, room):
    cols, rows = room["board"]["inner_corners"]
    square = room["board"]["square"]
    t0 = time.perf_counter()
    grey = cv2.imread(f"{scene}/image.png", cv2.IMREAD_GRAYSCALE)
    boards = opencv_all_boards(grey, cols, rows, cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_ACCURACY)
    grid = np.zeros((cols * rows, 3), np.float32)
    grid[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square
    obj = [grid] * len(boards)
    pts = [b.astype(np.float32).reshape(-1, 1, 2) for b in boards]
    h, w = grey.shape
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, pts, (w, h), None, None)
    return time.perf_counter() - t0, len(boards), K, dist.ravel(), rms


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", nargs="?", default="fixtures/six-boards-pandar64")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--surveyed", default="fixtures/surveyed-pandar64")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    room = tomllib.load(open(f"{args.scene}/room.toml", "rb"))
    truth = json.load(open(f"{args.scene}/truth.json"))["camera"]
    out = os.path.join(tempfile.mkdtemp(), "result.json")
    ours_i, ours_j, cv, surveyed, free = [], [], [], [], []
    for _ in range(args.runs):
        t, res_s = run_roomcal(args.surveyed, out, with_cloud=True)
        surveyed.append(t)
        t, res_f = run_roomcal(args.surveyed, out, with_cloud=True, extra=["--free-boards"])
        free.append(t)
        t, res_i = run_roomcal(args.scene, out, with_cloud=False)
        ours_i.append(t)
        t, res_j = run_roomcal(args.scene, out, with_cloud=True)
        ours_j.append(t)
        t, n, K, dist, rms = run_opencv(args.scene, room)
        cv.append(t)

    def err(fx, fy, cx, cy):
        return (f"fx {100 * (fx - truth['fx']) / truth['fx']:+.3f} %, fy {100 * (fy - truth['fy']) / truth['fy']:+.3f} %, "
                f"cx {cx - truth['cx']:+.2f} px, cy {cy - truth['cy']:+.2f} px")

    ci, cj = res_i["camera"], res_j["camera"]
    print(f"scene {args.scene}, median of {args.runs} runs, one thread for OpenCV")
    print(f"roomcal calibrate, intrinsics only : {1e3 * np.median(ours_i):8.1f} ms  {err(ci['fx'], ci['fy'], ci['cx'], ci['cy'])}")
    print(f"roomcal calibrate, joint with cloud: {1e3 * np.median(ours_j):8.1f} ms  {err(cj['fx'], cj['fy'], cj['cx'], cj['cy'])}")
    print(f"OpenCV SB x{n} + calibrateCamera  : {1e3 * np.median(cv):8.1f} ms  {err(K[0, 0], K[1, 1], K[0, 2], K[1, 2])} (RMS {rms:.3f} px)")
    print(f"ratio OpenCV / roomcal (intrinsics only): {np.median(cv) / np.median(ours_i):.1f}x; "
          f"OpenCV / roomcal joint: {np.median(cv) / np.median(ours_j):.1f}x")
    st = json.load(open(f"{args.surveyed}/truth.json"))["camera"]
    if "camera_in_room" in res_f:
        sys.exit("--free-boards gave camera_in_room: the free model was not used")
    if "camera_in_room" not in res_s:
        sys.exit(f"{args.surveyed}/room.toml: the calibration did not use a survey (no camera_in_room)")

    def err_s(res):
        c = res["camera"]
        return (f"fx {100 * (c['fx'] - st['fx']) / st['fx']:+.3f} %, cx {c['cx'] - st['cx']:+.2f} px, "
                f"cy {c['cy'] - st['cy']:+.2f} px; {res['status']}")
    print(f"scene {args.surveyed}, median of {args.runs} runs, alternating")
    print(f"roomcal calibrate, surveyed room    : {1e3 * np.median(surveyed):8.1f} ms  {err_s(res_s)}")
    print(f"roomcal calibrate, --free-boards    : {1e3 * np.median(free):8.1f} ms  {err_s(res_f)}")
    print(f"ratio surveyed / free: {np.median(surveyed) / np.median(free):.2f}")


if __name__ == "__main__":
    main()
