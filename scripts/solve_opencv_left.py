#!/usr/bin/env python3
"""Oracle for tests/it/solve_opencv.rs: OpenCV's corners and calibration of the real
`chessboard/opencv-left` views (../shared/data), so roomcal's solver can be compared with
OpenCV on identical corners. Not needed by `cargo test` (its output is committed).

Writes tests/solve_data/opencv_left.txt:
  # comment lines: OpenCV version, flags, expected fx fy cx cy k1 k2 p1 p2 k3, RMS
  expect fx fy cx cy k1 k2 p1 p2 k3 rms
  sigma fx fy cx cy   (OpenCV's stdDeviationsIntrinsics)
  corner VIEW X Y     (pixels; view order = file order; corner order = OpenCV's, row-major
                       over the 9x6 inner corners, object point (col, row) * 25 mm)

Run from the crate root: python3 scripts/solve_opencv_left.py
"""
import glob
import os

import cv2
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "..", "shared", "data", "chessboard", "opencv-left")
OUT = os.path.join(ROOT, "tests", "solve_data", "opencv_left.txt")
COLS, ROWS, SQUARE = 9, 6, 0.025


def main():
    objp = np.zeros((ROWS * COLS, 3), np.float32)
    objp[:, :2] = np.mgrid[0:COLS, 0:ROWS].T.reshape(-1, 2) * SQUARE
    obj, img, names = [], [], []
    size = None
    for path in sorted(glob.glob(os.path.join(DATA, "left*.jpg"))):
        grey = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        size = grey.shape[::-1]
        ok, corners = cv2.findChessboardCorners(grey, (COLS, ROWS))
        if not ok:
            continue
        term = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-3)
        corners = cv2.cornerSubPix(grey, corners, (11, 11), (-1, -1), term)
        obj.append(objp)
        img.append(corners)
        names.append(os.path.basename(path))
    term = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 200, 1e-12)
    rms, k, d, _, _, std, _, _ = cv2.calibrateCameraExtended(
        obj, img, size, None, None, flags=0, criteria=term)
    d = d.ravel()
    std = std.ravel()
    with open(OUT, "w") as f:
        f.write(f"# OpenCV {cv2.__version__} corners (findChessboardCorners + cornerSubPix 11x11)\n")
        f.write(f"# views: {' '.join(names)}\n")
        f.write("# calibrateCamera flags=0 (free aspect, k1 k2 p1 p2 k3), 200 iterations\n")
        f.write("expect %.6f %.6f %.6f %.6f %.8f %.8f %.8f %.8f %.8f %.6f\n" % (
            k[0, 0], k[1, 1], k[0, 2], k[1, 2], d[0], d[1], d[2], d[3], d[4], rms))
        f.write("sigma %.6f %.6f %.6f %.6f\n" % tuple(std[:4]))
        for v, c in enumerate(img):
            for x, y in c.reshape(-1, 2):
                f.write(f"corner {v} {x:.4f} {y:.4f}\n")
    print(f"{len(img)} views, RMS {rms:.4f}, K {k[0,0]:.3f} {k[1,1]:.3f} {k[0,2]:.3f} {k[1,2]:.3f}, d {d}")


if __name__ == "__main__":
    main()
