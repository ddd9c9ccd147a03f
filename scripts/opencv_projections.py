#!/usr/bin/env python3
"""OpenCV oracle for roomcal's camera models (not needed by `cargo test`).

Generates random cameras (pinhole-radtan k1 k2 p1 p2 k3, and fisheye k1..k4), random
rigid motions (rvec, tvec) and points that land in each model's valid domain, projects
them with cv2.projectPoints / cv2.fisheye.projectPoints and writes inputs and outputs to
tests/data/opencv_projections.json (floats via repr, i.e. full f64 precision).

Requirements: pip install opencv-python-headless numpy   (see scripts/requirements.txt)
Usage: python3 scripts/opencv_projections.py [--seed N] [--out PATH]
"""

import argparse
import json
import math
import os

import cv2
import numpy as np

CAMERAS_PER_MODEL = 12
POINTS_PER_CAMERA = 16


def first_positive_root(coeffs_low_first, limit):
    """Smallest real root in (0, limit] of a polynomial given lowest degree first."""
    roots = np.roots(list(reversed(coeffs_low_first)))
    real = [r.real for r in roots if abs(r.imag) < 1e-12 and 0 < r.real <= limit]
    return min(real) if real else None


def random_motion(rng):
    rvec = rng.normal(size=3)
    rvec *= rng.uniform(0.0, 3.0) / np.linalg.norm(rvec)
    tvec = rng.uniform(-2.0, 2.0, size=3)
    return rvec, tvec


def to_world(p_cam, rvec, tvec):
    """Inverse motion, so that R p_world + t = p_cam."""
    r, _ = cv2.Rodrigues(rvec)
    return (r.T @ (p_cam - tvec).T).T


def intrinsics(rng):
    w, h = int(rng.choice([640, 1280, 1920])), int(rng.choice([480, 800, 1200]))
    f = rng.uniform(300.0, 1500.0)
    fx, fy = f, f * rng.uniform(0.98, 1.02)
    cx, cy = w / 2 + rng.uniform(-30, 30), h / 2 + rng.uniform(-30, 30)
    return w, h, fx, fy, cx, cy


def radtan_case(rng):
    w, h, fx, fy, cx, cy = intrinsics(rng)
    k1, k2, k3 = rng.uniform(-0.4, 0.4), rng.uniform(-0.1, 0.2), rng.uniform(-0.05, 0.05)
    p1, p2 = rng.uniform(-2e-3, 2e-3, size=2)
    dist = [k1, k2, p1, p2, k3]
    fold = first_positive_root([1.0, 3 * k1, 5 * k2, 7 * k3], 1e8)
    r_lim = 1.5 if fold is None else min(1.5, 0.95 * math.sqrt(fold))
    rr = r_lim * np.sqrt(rng.uniform(0, 1, POINTS_PER_CAMERA))
    phi = rng.uniform(0, 2 * math.pi, POINTS_PER_CAMERA)
    z = rng.uniform(0.5, 20.0, POINTS_PER_CAMERA)
    rr[0] = 0.0  # one point on the optical axis
    p_cam = np.stack([rr * np.cos(phi) * z, rr * np.sin(phi) * z, z], axis=1)
    rvec, tvec = random_motion(rng)
    pw = to_world(p_cam, rvec, tvec)
    k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64)
    px, _ = cv2.projectPoints(pw.reshape(-1, 1, 3), rvec, tvec, k, np.array(dist))
    return w, h, [fx, fy, cx, cy], dist, rvec, tvec, pw, px.reshape(-1, 2)


def fisheye_case(rng):
    w, h, fx, fy, cx, cy = intrinsics(rng)
    fx = fy = fx * 0.6
    dist = list(rng.uniform([-0.05, -0.05, -0.02, -0.01], [0.1, 0.05, 0.02, 0.01]))
    fold = first_positive_root([1.0, 3 * dist[0], 5 * dist[1], 7 * dist[2], 9 * dist[3]], 10.0)
    t_lim = math.radians(85.0) if fold is None else min(math.radians(85.0), 0.95 * math.sqrt(fold))
    theta = t_lim * np.sqrt(rng.uniform(0, 1, POINTS_PER_CAMERA))
    phi = rng.uniform(0, 2 * math.pi, POINTS_PER_CAMERA)
    dist_m = rng.uniform(0.5, 20.0, POINTS_PER_CAMERA)
    theta[0] = 0.0
    p_cam = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)
    p_cam *= dist_m[:, None]
    rvec, tvec = random_motion(rng)
    pw = to_world(p_cam, rvec, tvec)
    k = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64)
    px, _ = cv2.fisheye.projectPoints(
        pw.reshape(-1, 1, 3), rvec.reshape(3, 1), tvec.reshape(3, 1), k, np.array(dist)
    )
    return w, h, [fx, fy, cx, cy], dist + [0.0], rvec, tvec, pw, px.reshape(-1, 2)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=20261121)
    here = os.path.dirname(os.path.abspath(__file__))
    ap.add_argument("--out", default=os.path.join(here, "..", "tests", "data", "opencv_projections.json"))
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    cases = []
    for model, make in (("pinhole-radtan", radtan_case), ("fisheye", fisheye_case)):
        for _ in range(CAMERAS_PER_MODEL):
            w, h, k4, dist, rvec, tvec, pw, px = make(rng)
            cases.append({
                "model": model, "width": w, "height": h,
                "fx": float(k4[0]), "fy": float(k4[1]), "cx": float(k4[2]), "cy": float(k4[3]),
                "distortion": [float(d) for d in dist],
                "rvec": [float(v) for v in rvec], "tvec": [float(v) for v in tvec],
                "points": [[float(v) for v in p] for p in pw],
                "pixels": [[float(v) for v in q] for q in px],
            })
    doc = {"generator": "scripts/opencv_projections.py", "opencv": cv2.__version__,
           "seed": args.seed, "cases": cases}
    with open(args.out, "w") as f:
        json.dump(doc, f, separators=(",", ":"))
        f.write("\n")
    print(f"wrote {len(cases)} cameras to {args.out} ({os.path.getsize(args.out)} bytes)")


if __name__ == "__main__":
    main()
