#!/usr/bin/env python3
"""The Cramér–Rao bound of a simulated calibration scene: the smallest σ any unbiased
calibration can reach from that frame's measurements at their noise (issue 5).

An independent reference for `roomcal calibrate`: it shares no code with the solver. From a
scene's truth.json (board poses, camera, LiDAR mounting) it builds the measurement model
in numpy — checkerboard corners in the image (radtan 5, σ px), the LiDAR's hole centres in
3-D (σ mm), and each LiDAR board's face points against the board plane (range noise times
the beam's incidence cosine, one row per point, summarised on a 12×10 grid) — takes a
central-difference Jacobian at the truth over every parameter the solver estimates
(fx fy cx cy k1 k2 p1 p2 k3, every board pose, LiDAR→camera) and inverts JᵀWJ. The
bound is reached by a maximum-likelihood fit when the model is right; the solver's
reported σ and its actual errors should sit at it.

Which boards the LiDAR places and the corner σ are taken from roomcal's result.json
beside truth.json when there is one (run `roomcal calibrate` first), else every board
with two holes crossed by two scan lines and --corner-sigma.

`--what-if` adds rows with one assumption changed (tangential distortion known, image
features on the board outline and hole rims, several sweeps and frames of a standing
vehicle, a noise-free camera or LiDAR): what would have to change to reach a target.

    roomcal simulate --room config/room.toml --layout band --seed 1 --out /tmp/s1
    roomcal calibrate --room config/room.toml --image /tmp/s1/image.png \\
        --cloud /tmp/s1/cloud.pcd --out /tmp/s1/result.json
    scripts/crb_bound.py --room config/room.toml /tmp/s1 [--what-if]

Figures: σ fx as % of fx, σ cx and cy in px, rotation and translation as the worst axis
(what roomcal reports) and, in brackets, the RMS length of the error vector (what an
error against the truth is compared with).
"""
import argparse
import json
import math
import os
import sys
import tomllib

import numpy as np

INTRINSICS = 9
P1, P2 = 6, 7


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", help="scene directories (truth.json, optional result.json)")
    ap.add_argument("--room", required=True, help="the room file the scenes were simulated from")
    ap.add_argument("--corner-sigma", type=float, default=0.042, help="corner σ px without a result.json")
    ap.add_argument("--hole-sigma-mm", type=float, default=3.0,
                    help="LiDAR hole-centre σ per axis (mm); issue 4 measured 2.9 mm mean error")
    ap.add_argument("--what-if", action="store_true", help="add rows with one assumption changed")
    ap.add_argument("--result", default="result.json", help="roomcal's result file name in each scene")
    args = ap.parse_args()
    with open(args.room, "rb") as f:
        board = Board(tomllib.load(f)["board"])
    for scene in args.scenes:
        report(scene, board, args)


class Board:
    """The room's board: corners, holes and face sample points in the board frame."""

    def __init__(self, spec):
        cols, rows = spec["inner_corners"]
        sq = spec["square"]
        ox, oy = spec.get("checker_offset", [0.0, 0.0])
        self.corners = np.array([[ox + (c - (cols - 1) / 2) * sq, oy + (r - (rows - 1) / 2) * sq, 0.0]
                                 for r in range(rows) for c in range(cols)])
        self.holes = np.array([[h[0], h[1], 0.0] for h in spec["holes"]])
        w, h, rad = spec["width"], spec["height"], spec["hole_radius"]
        self.outline = np.array([[sx * w / 2, sy * h / 2, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
        # The face the plane term uses: inside the outline, clear of the holes (3 cm margins).
        grid = [[x, y, 0.0] for x in np.linspace(-w / 2 + 0.03, w / 2 - 0.03, 12)
                for y in np.linspace(-h / 2 + 0.03, h / 2 - 0.03, 10)]
        self.face = np.array([p for p in grid
                              if min(math.hypot(p[0] - q[0], p[1] - q[1]) for q in self.holes) > rad + 0.03])


def report(scene, board, args):
    with open(os.path.join(scene, "truth.json")) as f:
        truth = json.load(f)
    result = None
    path = os.path.join(scene, args.result)
    if os.path.exists(path):
        with open(path) as f:
            result = json.load(f)
    noise = Noise(
        corner_px=result["quality"]["corner_rms_px"] if result else args.corner_sigma,
        hole_m=args.hole_sigma_mm / 1000.0,
        range_m=truth["range_noise_m"],
    )
    placed = lidar_placed(truth, result)
    print(f"{scene}: corners σ {noise.corner_px:.3f} px, LiDAR boards {sum(placed)}/{len(placed)}, "
          f"holes σ {noise.hole_m * 1000:.1f} mm, range σ {noise.range_m * 100:.1f} cm")
    print(f"  {'':44s} {'fx %':>7s} {'cx px':>6s} {'cy px':>6s} {'rot °':>15s} {'trans mm':>13s}")
    rows = [("Cramér–Rao bound, as measured", {})]
    if args.what_if:
        rows += WHAT_IF
    for name, change in rows:
        s = bound(truth, board, noise.changed(change), placed if "all_lidar" not in change else [True] * len(placed))
        print(f"  {name:44s} {s['fx']:7.3f} {s['cx']:6.2f} {s['cy']:6.2f} "
              f"{s['rot']:6.3f} [{s['rot_rms']:6.3f}] {s['t']:5.1f} [{s['t_rms']:5.1f}]")
    if result:
        u, cam, tcam = result["uncertainty"], result["camera"], truth["camera"]
        print(f"  {'roomcal reported σ':44s} {100 * u['fx'] / cam['fx']:7.3f} {u['cx']:6.2f} {u['cy']:6.2f} "
              f"{u['rotation_deg']:6.3f}{'':10s}{1000 * u['translation_m']:5.1f}")
        if result.get("lidar_to_camera"):
            rot, t = extrinsic_error(result["lidar_to_camera"], truth["lidar_to_camera"])
            print(f"  {'roomcal actual error':44s} {100 * abs(cam['fx'] / tcam['fx'] - 1):7.3f} "
                  f"{abs(cam['cx'] - tcam['cx']):6.2f} {abs(cam['cy'] - tcam['cy']):6.2f} "
                  f"{'':7s}[{rot:6.3f}] {'':5s} [{1000 * t:5.1f}]")


WHAT_IF = [
    ("tangential distortion known (p1, p2 fixed)", {"fixed": [P1, P2]}),
    ("+ outline corners and hole rims, 0.05 px", {"outline_px": 0.05, "holes_px": 0.05}),
    ("  ... and p1, p2 fixed", {"outline_px": 0.05, "holes_px": 0.05, "fixed": [P1, P2]}),
    ("all boards placed by the LiDAR", {"all_lidar": True}),
    ("10 sweeps and 10 frames of a standing vehicle", {"scale_lidar": 1 / math.sqrt(10), "scale_corner": 1 / math.sqrt(10)}),
    ("  ... and all boards placed by the LiDAR", {"scale_lidar": 1 / math.sqrt(10), "scale_corner": 1 / math.sqrt(10), "all_lidar": True}),
    ("noise-free camera (corners 1e-4 px)", {"corner_px": 1e-4}),
    ("noise-free LiDAR (1e-5 m)", {"hole_m": 1e-5, "range_m": 1e-5}),
    ("  ... and p1, p2 fixed", {"hole_m": 1e-5, "range_m": 1e-5, "fixed": [P1, P2]}),
]


class Noise:
    def __init__(self, corner_px, hole_m, range_m, outline_px=None, holes_px=None, fixed=()):
        self.corner_px, self.hole_m, self.range_m = corner_px, hole_m, range_m
        self.outline_px, self.holes_px, self.fixed = outline_px, holes_px, list(fixed)

    def changed(self, change):
        n = Noise(self.corner_px, self.hole_m, self.range_m, self.outline_px, self.holes_px, self.fixed)
        for key, value in change.items():
            if key == "scale_lidar":
                n.hole_m *= value
                n.range_m *= value
            elif key == "scale_corner":
                n.corner_px *= value
            elif key != "all_lidar":
                setattr(n, key, value)
        return n


def lidar_placed(truth, result):
    """Per truth board: whether the LiDAR placed it (from result.json when present)."""
    boards = truth["boards"]
    if result is None:
        return [sum(1 for lines in b["hole_scan_lines"] if lines >= 2) >= 2 for b in boards]
    placed = [False] * len(boards)
    for used in result.get("boards", []):
        if not used.get("holes_lidar"):
            continue
        centre = np.mean(np.array(used["corners_px"]), axis=0)
        nearest = min(range(len(boards)),
                      key=lambda i: np.linalg.norm(np.mean(np.array(boards[i]["corners_px"]), axis=0) - centre))
        placed[nearest] = True
    return placed


def bound(truth, board, noise, placed):
    """σ of the main parameters from the inverse Fisher information at the truth."""
    model = Model(truth, board, noise, placed)
    x0 = np.zeros(model.size)
    jac = numeric_jacobian(model.residuals, x0)
    keep = [k for k in range(model.size) if k not in noise.fixed]
    cov = np.zeros((model.size, model.size))
    cov[np.ix_(keep, keep)] = np.linalg.inv(jac[:, keep].T @ jac[:, keep])
    d = np.diag(cov)
    rot, t = d[-6:-3], d[-3:]
    return {
        "fx": 100 * math.sqrt(d[0]) / truth["camera"]["fx"],
        "cx": math.sqrt(d[2]),
        "cy": math.sqrt(d[3]),
        "rot": math.degrees(math.sqrt(rot.max())),
        "rot_rms": math.degrees(math.sqrt(rot.sum())),
        "t": 1000 * math.sqrt(t.max()),
        "t_rms": 1000 * math.sqrt(t.sum()),
    }


class Model:
    """Whitened residuals of one frame as a function of a perturbation of the truth:
    [intrinsics (9), board poses (6 each: rotation vector, translation), LiDAR→camera (6)],
    the poses perturbed on the left as the solver does."""

    def __init__(self, truth, board, noise, placed):
        cam = truth["camera"]
        self.k0 = np.array([cam["fx"], cam["fy"], cam["cx"], cam["cy"]] + cam["distortion"])
        self.poses = [pose(b["board_to_camera"]) for b in truth["boards"]]
        self.lidar = pose(truth["lidar_to_camera"])
        self.board, self.noise, self.placed = board, noise, placed
        self.points = [b["lidar_points"] for b in truth["boards"]]
        self.size = INTRINSICS + 6 * len(self.poses) + 6
        # The LiDAR's measurements are fixed data: the truth's hole centres and face points
        # in the LiDAR frame, and each face's noise along the normal.
        rl, tl = self.lidar
        self.holes_l = [(rl.T @ (transform(p, board.holes) - tl).T).T for p in self.poses]
        self.face_l = [(rl.T @ (transform(p, board.face) - tl).T).T for p in self.poses]
        self.normal_sigma = [noise.range_m * incidence_cosine(p, self.lidar) for p in self.poses]

    def residuals(self, x):
        k = self.k0 + x[:INTRINSICS]
        rl, tl = perturb(self.lidar, x[-6:])
        out = []
        for i, p0 in enumerate(self.poses):
            p = perturb(p0, x[INTRINSICS + 6 * i:INTRINSICS + 6 * i + 6])
            out.append(project(k, transform(p, self.board.corners)).ravel() / self.noise.corner_px)
            if self.noise.outline_px:
                out.append(project(k, transform(p, self.board.outline)).ravel() / self.noise.outline_px)
            if self.noise.holes_px:
                out.append(project(k, transform(p, self.board.holes)).ravel() / self.noise.holes_px)
            if not self.placed[i]:
                continue
            holes_c = (rl @ self.holes_l[i].T).T + tl
            out.append((holes_c - transform(p, self.board.holes)).ravel() / self.noise.hole_m)
            # Each grid point stands for its share of the board's LiDAR points.
            weight = math.sqrt(max(self.points[i], 1) / len(self.board.face))
            face_c = (rl @ self.face_l[i].T).T + tl
            normal = p[0][:, 2]
            out.append(weight * (face_c @ normal - normal @ p[1]) / self.normal_sigma[i])
        return np.concatenate(out)


def pose(j):
    return np.array(j["rotation"]), np.array(j["translation"])


def transform(p, pts):
    return (p[0] @ pts.T).T + p[1]


def perturb(p, d):
    r = rodrigues(d[:3])
    return r @ p[0], r @ p[1] + d[3:]


def rodrigues(w):
    th = np.linalg.norm(w)
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * kx + (1 - math.cos(th)) * kx @ kx


def project(k, pts):
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = k
    a, b = pts[:, 0] / pts[:, 2], pts[:, 1] / pts[:, 2]
    r2 = a * a + b * b
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    u = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
    v = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    return np.stack([fx * u + cx, fy * v + cy], 1)


def incidence_cosine(board_pose, lidar):
    """|cos| between the LiDAR's beam to the board centre and the board's normal."""
    rl, tl = lidar
    centre_l = rl.T @ (board_pose[1] - tl)
    normal_l = rl.T @ board_pose[0][:, 2]
    return abs(normal_l @ centre_l) / np.linalg.norm(centre_l)


def numeric_jacobian(f, x0, eps=1e-6):
    cols = []
    for k in range(len(x0)):
        e = np.zeros_like(x0)
        e[k] = eps
        cols.append((f(x0 + e) - f(x0 - e)) / (2 * eps))
    return np.stack(cols, 1)


def extrinsic_error(result, truth):
    """Rotation angle (degrees) and translation distance (m) between two extrinsics."""
    r = np.array(result["rotation"]) @ np.array(truth["rotation"]).T
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2))))
    return angle, float(np.linalg.norm(np.array(result["translation"]) - np.array(truth["translation"])))


if __name__ == "__main__":
    sys.exit(main())
