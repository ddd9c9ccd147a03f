#!/usr/bin/env python3
"""Speed and accuracy of roomcal's chessboard detector against OpenCV's
findChessboardCornersSB on the same simulated frames, in the same run.

Usage (from the repository root):
    python3 scripts/bench_chessboard.py SCENE_DIR [SCENE_DIR ...] [--runs N] [--cv-threads N]
    python3 scripts/bench_chessboard.py --real ../shared/data/chessboard/opencv-left

With --real (OpenCV's left01-14, 9x6, no ground truth): both detectors' corners feed
cv2.calibrateCamera with the same model; the RMS reprojection error says which corners
are more consistent with a real lens, and the mean distance between the two sets is shown.

A scene directory is what `roomcal simulate --out DIR` writes: image.png, truth.json,
room.toml. roomcal is timed by `cargo bench --bench chessboard` (release profile, one
thread, workspace reused, median of N frames). OpenCV finds one board per call, so it is
called again with every found board masked out until it finds none (or 16); that whole
loop is timed (best of 3). Corner errors are order-agnostic: each true corner against the
nearest reported corner within 2 px; a board counts as found when all its corners match.
Needs: pip install opencv-python-headless numpy.
"""
import argparse
import json
import os
import subprocess
import sys
import time
import tomllib

import cv2
import numpy as np


def ours(image, cols, rows, runs):
    cmd = ["cargo", "bench", "-q", "--bench", "chessboard", "--", image, str(cols), str(rows), str(runs)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    res = json.loads(out.strip().splitlines()[-1])
    corners = [np.array([c[:2] for c in b["corners"]]).reshape(-1, 2) for b in res["boards"]]
    return res["median_ms"], corners


def opencv_all_boards(grey, cols, rows, flags):
    """Every board: find one, mask it (its hull grown by one square), search again."""
    img = grey.copy()
    fill = int(np.median(grey))
    boards = []
    while len(boards) < 16:
        found, corners = cv2.findChessboardCornersSB(img, (cols, rows), flags=flags)
        if not found:
            break
        pts = corners.reshape(-1, 2)
        boards.append(pts.astype(np.float64))
        centre = pts.mean(axis=0)
        grow = (max(cols, rows) + 1.5) / max(max(cols, rows) - 1, 1)
        hull = cv2.convexHull(((pts - centre) * grow + centre).astype(np.int32))
        cv2.fillConvexPoly(img, hull, fill)
    return boards


def errors(truth_boards, found):
    allpts = np.concatenate(found) if found else np.zeros((0, 2))
    errs, complete = [], 0
    for t in truth_boards:
        if len(allpts) == 0:
            continue
        d = np.sqrt(((t[:, None, :] - allpts[None, :, :]) ** 2).sum(-1)).min(axis=1)
        ok = d < 2.0
        errs.extend(d[ok])
        complete += bool(ok.all())
    e = np.array(errs) if errs else np.array([np.nan])
    return complete, len(errs), float(e.mean()), float(e.max())


def real(folder, runs):
    files = sorted(f for f in os.listdir(folder) if f.endswith(".jpg"))
    ours_pts, cv_pts, obj, dists, t_ours, t_cv = [], [], [], [], [], []
    grid = np.zeros((54, 3), np.float32)
    grid[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2) * 25.0
    for f in files:
        path = os.path.join(folder, f)
        grey = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        ms, found = ours(path, 9, 6, runs)
        t_ours.append(ms)
        t0 = time.perf_counter()
        ok, c = cv2.findChessboardCornersSB(grey, (9, 6), flags=cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        t_cv.append((time.perf_counter() - t0) * 1e3)
        mine = [b for b in found if len(b) == 54]
        if not ok or not mine:
            print(f"  {f}: roomcal {len(mine)} complete, OpenCV found {ok}")
            continue
        a, b = mine[0], c.reshape(-1, 2).astype(np.float64)
        d = np.sqrt(((a[:, None] - b[None]) ** 2).sum(-1)).min(1)
        dists.extend(d)
        ours_pts.append(a.astype(np.float32).reshape(-1, 1, 2))
        cv_pts.append(b.astype(np.float32).reshape(-1, 1, 2))
        obj.append(grid)
    print(f"{len(obj)} images with both; mean |roomcal - OpenCV| {np.mean(dists):.4f} px, max {np.max(dists):.4f} px")
    print(f"time per 640x480 image: roomcal {np.median(t_ours):.2f} ms, OpenCV SB exhaustive+accuracy {np.median(t_cv):.2f} ms")
    flags = cv2.CALIB_FIX_ASPECT_RATIO
    for name, pts in (("roomcal", ours_pts), ("OpenCV SB", cv_pts)):
        # roomcal numbers corners by square colour; reorder OpenCV-independent: calibrate per set.
        rms, K, dist, _, _ = cv2.calibrateCamera(obj, pts, (640, 480), None, None, flags=flags)
        print(f"  calibrateCamera with {name:10s} corners: RMS {rms:.4f} px, fx {K[0,0]:.2f} cx {K[0,2]:.2f} cy {K[1,2]:.2f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--real", help="folder of OpenCV's left*.jpg (9x6)")
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--cv-threads", type=int, default=1)
    args = ap.parse_args()
    cv2.setNumThreads(args.cv_threads)
    if args.real:
        real(args.real, args.runs)
    configs = {
        "SB default": cv2.CALIB_CB_NORMALIZE_IMAGE,
        "SB exhaustive+accuracy": cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY,
    }
    for scene in args.scenes:
        image = os.path.join(scene, "image.png")
        truth = json.load(open(os.path.join(scene, "truth.json")))
        room = tomllib.load(open(os.path.join(scene, "room.toml"), "rb"))
        cols, rows = room["board"]["inner_corners"]
        truth_boards = [np.array(b["corners_px"]) for b in truth["boards"]]
        grey = cv2.imread(image, cv2.IMREAD_GRAYSCALE)
        n_corners = sum(len(t) for t in truth_boards)
        print(f"\n{scene}: {grey.shape[1]}x{grey.shape[0]}, {len(truth_boards)} boards {cols}x{rows}, {n_corners} corners")
        ms, found = ours(image, cols, rows, args.runs)
        c, n, mean, mx = errors(truth_boards, found)
        print(f"  roomcal               {ms:9.2f} ms  boards {c}/{len(truth_boards)}  corners {n}/{n_corners}  mean {mean:.4f} px  max {mx:.4f} px")
        for name, flags in configs.items():
            best = float("inf")
            for _ in range(3):
                t0 = time.perf_counter()
                boards = opencv_all_boards(grey, cols, rows, flags)
                best = min(best, (time.perf_counter() - t0) * 1e3)
            c, n, mean, mx = errors(truth_boards, boards)
            print(f"  OpenCV {name:22s} {best:9.2f} ms  boards {c}/{len(truth_boards)}  corners {n}/{n_corners}  mean {mean:.4f} px  max {mx:.4f} px  ratio {best / ms:6.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
