#!/usr/bin/env python3
"""What a room's range noise did to its boards, visit by visit (first used to trace the
square board's room). Needs the room simulated twice with one seed: as it was
(`roomcal simulate --visits N …`) and without range noise (the same command with
`--range-noise 0`, another --out); both then cast the same beams, so the difference of
their ranges is each point's noise.

    studies/sweep_noise_trace.py NOISY_DIR NOISE_FREE_DIR [--visits 1-8] [--boards 1 3]

Per board (truth order), over the visits:
- face tilt: the least-squares plane of its face points against the truth, about the
  board's x and y axes (deg, mean ± its standard error), with the points cut where they
  appear (as `calibrate::detectors::plane_points`) and where their beams meet the board;
- the noise's slope across the board: per visit the regression of the points' range noise
  on their board y, in units of its own σ (2 cm noise: `σ_r / √Σ(y − ȳ)²`); its mean over the
  visits, and how often the same statistic on the same beams shifted in azimuth (other
  draws of the same generator) is as large;
- the LiDAR hole centres `roomcal detect` gives on the noise-free sweep against the truth
  (mean error along the beam, sideways and vertical, mm): the part of the holes' error the
  scan lines alone make.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import tomllib

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from crb_bound import read_pcd_xyz  # noqa: E402  (one PCD reader for the scripts)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOMCAL = os.environ.get("ROOMCAL_BIN", os.path.join(ROOT, "target", "release", "roomcal"))
EDGE_MARGIN_M = 0.03  # calibrate::detectors::PLANE_EDGE_MARGIN_M
RANGE_NOISE_M = 0.02  # the simulator's default
SHIFT_STEP = 7  # firing sequences between two shifted draws


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("noisy")
    ap.add_argument("noise_free")
    ap.add_argument("--visits", default=None, help="first-last (default: every visit)")
    ap.add_argument("--boards", type=int, nargs="*", default=None, help="truth board indices (default: all)")
    args = ap.parse_args()
    with open(os.path.join(args.noisy, "room.toml"), "rb") as f:
        board = tomllib.load(f)["board"]
    visits = visit_numbers(args.noisy, args.visits)
    per_board = {}
    for v in visits:
        noisy, clean, truth = load_visit(args.noisy, args.noise_free, v)
        for k, pose in enumerate(board_poses(truth)):
            if args.boards is None or k in args.boards:
                row = trace_face(board, pose, noisy, clean)
                if row is not None:
                    per_board.setdefault(k, []).append(row)
    for k, rows in sorted(per_board.items()):
        print_board(k, rows)
    print_holes(args.noise_free, visits, args.boards)


def visit_numbers(folder, span):
    found = sorted(int(d.split("-")[1]) for d in os.listdir(folder) if d.startswith("visit-"))
    if span is None:
        return found
    first, last = (int(x) for x in span.split("-"))
    return [v for v in found if first <= v <= last]


def load_visit(noisy_dir, clean_dir, v):
    name = f"visit-{v:02}"
    noisy = read_pcd_xyz(os.path.join(noisy_dir, name, "cloud.pcd"))
    clean = read_pcd_xyz(os.path.join(clean_dir, name, "cloud.pcd"))
    with open(os.path.join(noisy_dir, name, "truth.json")) as f:
        truth = json.load(f)
    if len(noisy) != len(clean):
        sys.exit(f"{name}: {len(noisy)} points against {len(clean)} noise-free: not the same beams (same seed?)")
    return noisy, clean, truth


def board_poses(truth):
    """Every board → LiDAR pose (rotation, translation) of a visit's truth."""
    r_lc = np.array(truth["lidar_to_camera"]["rotation"])
    t_lc = np.array(truth["lidar_to_camera"]["translation"])
    for b in truth["boards"]:
        r_bc = np.array(b["board_to_camera"]["rotation"])
        t_bc = np.array(b["board_to_camera"]["translation"])
        yield r_lc.T @ r_bc, r_lc.T @ (t_bc - t_lc)


def on_face(board, xy):
    """Inside the outline and clear of every hole by the plane term's margin."""
    keep = (np.abs(xy[:, 0]) <= board["width"] / 2 - EDGE_MARGIN_M) & \
           (np.abs(xy[:, 1]) <= board["height"] / 2 - EDGE_MARGIN_M)
    for h in board["holes"]:
        keep &= np.linalg.norm(xy - np.array(h), axis=1) >= board["hole_radius"] + EDGE_MARGIN_M
    return keep


def tilt_deg(points_board):
    """The least-squares plane's turn about the board's x and y axes (deg)."""
    centred = points_board - points_board.mean(0)
    n = np.linalg.svd(centred, full_matrices=False)[2][2]
    n = n if n[2] > 0 else -n
    return np.degrees([-np.arctan2(n[1], n[2]), np.arctan2(n[0], n[2])])


def trace_face(board, pose, noisy, clean):
    rotation, translation = pose
    seen = (noisy - translation) @ rotation  # where the points appear, board frame
    true = (clean - translation) @ rotation  # where their beams meet the board
    cut_seen = (np.abs(seen[:, 2]) <= 0.06) & on_face(board, seen[:, :2])
    cut_true = (np.abs(true[:, 2]) <= 0.01) & on_face(board, true[:, :2])
    if cut_true.sum() < 30 or cut_seen.sum() < 30:
        return None
    noise = np.linalg.norm(noisy, axis=1) - np.linalg.norm(clean, axis=1)
    index = np.nonzero(cut_true)[0]
    y = true[index, 1] - true[index, 1].mean()
    sigma = RANGE_NOISE_M / np.sqrt((y * y).sum())

    def slope_z(shift):
        return np.dot(y, noise[(index + shift) % len(noise)]) / (y * y).sum() / sigma

    # Shifted by whole firing sequences: the same beams' geometry, other noise draws.
    lasers = len(noise) // 1800 if len(noise) % 1800 == 0 else 1
    shifts = [s * lasers for s in range(SHIFT_STEP, 1800, SHIFT_STEP)]
    return {"seen": tilt_deg(seen[cut_seen]), "true": tilt_deg(seen[cut_true]), "points": len(index),
            "slope_z": slope_z(0), "shifted": [slope_z(s) for s in shifts]}


def print_board(k, rows):
    n = len(rows)
    seen = np.array([r["seen"] for r in rows])
    true = np.array([r["true"] for r in rows])
    sem = lambda a: a.std(0) / np.sqrt(n)  # noqa: E731
    z = np.mean([r["slope_z"] for r in rows])
    shifted = np.mean([r["shifted"] for r in rows], axis=0)  # per shift, mean over the visits
    rarer = np.mean(np.abs(shifted) >= abs(z))
    print(f"board {k}: {n} visits, ~{np.mean([r['points'] for r in rows]):.0f} face points")
    print(f"  face tilt about x / y, cut where they appear: {seen[:, 0].mean():+.3f} ± {sem(seen)[0]:.3f} / "
          f"{seen[:, 1].mean():+.3f} ± {sem(seen)[1]:.3f}°; where their beams meet it: "
          f"{true[:, 0].mean():+.3f} ± {sem(true)[0]:.3f} / {true[:, 1].mean():+.3f} ± {sem(true)[1]:.3f}°")
    print(f"  noise slope across the board: mean {z:+.2f}σ per visit ({z * np.sqrt(n):+.2f}σ for the mean); "
          f"other draws: sd {shifted.std():.2f}, {rarer * len(shifted):.0f} of {len(shifted)} as large")


def print_holes(clean_dir, visits, boards):
    errors = {}
    with tempfile.TemporaryDirectory() as work:
        for v in visits:
            folder = os.path.join(clean_dir, f"visit-{v:02}")
            out = os.path.join(work, f"{v}.json")
            done = subprocess.run([ROOMCAL, "detect", "--room", os.path.join(clean_dir, "room.toml"),
                                   "--cloud", os.path.join(folder, "cloud.pcd"), "--out", out],
                                  capture_output=True, text=True)
            if done.returncode != 0:
                continue
            with open(out) as f:
                found = json.load(f)["boards"]
            with open(os.path.join(folder, "truth.json")) as f:
                truth = [(k, np.array(b["holes_lidar"])) for k, b in enumerate(json.load(f)["boards"])
                         if b.get("holes_lidar")]
            for b in found:
                holes = np.array(b.get("holes_lidar") or [])
                if len(holes) == 0 or not truth:
                    continue
                k, true = min(truth, key=lambda kt: np.linalg.norm(kt[1].mean(0) - holes.mean(0)))
                if np.linalg.norm(true.mean(0) - holes.mean(0)) > 0.2 or (boards and k not in boards):
                    continue
                for p in holes:
                    q = true[np.argmin(np.linalg.norm(true - p, axis=1))]
                    beam = q / np.linalg.norm(q)
                    side = np.cross([0.0, 0.0, 1.0], beam)
                    side /= np.linalg.norm(side)
                    errors.setdefault(k, []).append([(p - q) @ beam, (p - q) @ side, (p - q) @ np.cross(beam, side)])
    print("noise-free hole centres (roomcal detect) against the truth, mm: mean ± standard error (RMS)")
    for k, e in sorted(errors.items()):
        e = np.array(e) * 1e3
        cells = [f"{name} {e[:, i].mean():+.2f} ± {e[:, i].std() / np.sqrt(len(e)):.2f} ({np.sqrt((e[:, i] ** 2).mean()):.2f})"
                 for i, name in enumerate(("along the beam", "sideways", "vertical"))]
        print(f"  board {k}, {len(e)} holes: " + ", ".join(cells))


if __name__ == "__main__":
    sys.exit(main())
