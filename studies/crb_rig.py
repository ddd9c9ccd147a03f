#!/usr/bin/env python3
"""The Cramér–Rao bound of a rig calibrated from one frame in a surveyed room (issue 17):
the smallest σ any unbiased calibration reaches for camera → first camera (and the
cameras' intrinsics) from one simulated frame at the measurements' noise.

An independent numpy reference for the joint rig solve (`src/solve/rig.rs`), sharing no
code with it; the camera, pose and plane helpers are `studies/crb_bound.py`'s. From a
`roomcal simulate --rig` scene (rig-truth.json, room-truth.json, room.toml, NAME.pcd) it
builds the joint model at the truth — per camera its 9 intrinsics, the vehicle's room →
first camera (6), every other sensor's mounting (sensor → first camera, 6), every
surveyed board's pose in the room (6) and every surveyed plane (2 tilts, 1 offset) held by
the survey's σ as priors — takes a central-difference Jacobian of the whitened residuals
and inverts JᵀJ. Measurements: every corner of every complete, unoccluded board a camera
sees (σ px per axis); with `--lidars`, each LiDAR's 4 hole centres (σ mm per axis) and its
face points of every board it places (two holes crossed by ≥ 2 scan lines, as
`tests/it/rig_calibrate.rs` detects), and its points on the surveyed floor, walls and
ceiling (crb_bound's six-point summary; both with the range noise times the beam's
incidence cosine, the points moved along their beam onto the true surface so the
residuals vanish at the truth). Without `--lidars` the LiDARs and planes are left out:
their mountings would be free and tell the cameras nothing.

Poses are perturbed as the solver's `perturb_left`: R ← exp(δω) R, t ← t + δt, so a
mounting's δt is its translation error and |δω| its rotation error, and a board's or
plane's prior is the survey's draw in `realistic_survey` (0.5 mm / 0.01° per axis).

    roomcal simulate --room config/room.toml --rig config/rig.toml --seed 1 \\
        --supersample 1 --out /tmp/crbrig/s1
    studies/crb_rig.py /tmp/crbrig/s1 [/tmp/crbrig/s2 ...] [--lidars]

Rows per scene: the survey realistic and exact (boards and planes known). Figures: σ fx
as % of fx and σ cx, cy px per camera; per mounting the worst-axis σ and, in brackets,
the RMS length of the error vector (sqrt of the trace of its 3×3 block: what an error
norm against the truth is compared with). Several scenes end with the RMS over them.
"""
import argparse
import json
import math
import os
import sys
import tomllib

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import crb_bound as cb  # noqa: E402

K = cb.INTRINSICS


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", help="`roomcal simulate --rig` output directories")
    ap.add_argument("--corner-sigma", type=float, default=0.025, help="corner σ px per axis")
    ap.add_argument("--hole-sigma-mm", type=float, default=3.0, help="LiDAR hole-centre σ mm per axis")
    ap.add_argument("--range-sigma", type=float, default=0.02, help="LiDAR range σ m (the simulate run's)")
    ap.add_argument("--survey-sigma", type=float, nargs=2, default=[0.5, 0.01], metavar=("MM", "DEG"),
                    help="the realistic survey's σ per axis, boards and planes")
    ap.add_argument("--lidars", action="store_true", help="add the LiDARs' holes, faces and plane points")
    args = ap.parse_args()
    noise = cb.Noise(args.corner_sigma, args.hole_sigma_mm / 1000, args.range_sigma)
    tally = {}
    for scene in args.scenes:
        model = RigModel(scene, noise, args.lidars, args.survey_sigma)
        print(f"{scene}: {model.describe()}")
        print(f"  {'':22s} " + " ".join(f"{c + ' fx %':>9s} {'cx/cy px':>11s}" for c in model.cameras[:2])
              + "  " + " ".join(f"{s + '→' + model.cameras[0] + ' ° [rms] / mm [rms]':>38s}"
                                for s in model.mounted))
        for name, exact in (("realistic survey", False), ("exact survey", True)):
            s = model.bound(exact)
            for key, value in s.items():
                tally.setdefault((name, key), []).append(value)
            print_row(model, name, s)
    if len(args.scenes) > 1:
        print(f"RMS over {len(args.scenes)} scenes:")
        for name in ("realistic survey", "exact survey"):
            rms = {key: math.sqrt(np.mean(np.square(v))) for (row, key), v in tally.items() if row == name}
            print_row(model, name, rms)


def print_row(model, name, s):
    cams = " ".join(f"{s[c + ' fx']:9.4f} {s[c + ' cx']:5.2f}/{s[c + ' cy']:5.2f}" for c in model.cameras[:2])
    mounts = " ".join(f"{s[m + ' rot']:7.4f} [{s[m + ' rot_rms']:6.4f}] / {s[m + ' t']:5.2f} "
                      f"[{s[m + ' t_rms']:5.2f}]      " for m in model.mounted)
    print(f"  {name:22s} {cams}  {mounts}")


def decoupled(p, d):
    """The solver's left perturbation: R ← exp(δω) R, t ← t + δt."""
    return cb.rodrigues(d[:3]) @ p[0], p[1] + d[3:]


class RigModel:
    """Whitened residuals of one rig frame as a function of a perturbation of the truth:
    [intrinsics (9 per camera), room → first camera (6), sensor → first camera (6 per
    other camera, then per LiDAR with --lidars), boards (6 each), planes (3 each, with
    --lidars)]."""

    def __init__(self, scene, noise, lidars, survey_sigma):
        with open(os.path.join(scene, "rig-truth.json")) as f:
            truth = json.load(f)
        with open(os.path.join(scene, "room-truth.json")) as f:
            room = json.load(f)
        with open(os.path.join(scene, "room.toml"), "rb") as f:
            self.board = cb.Board(tomllib.load(f)["board"])
        self.noise, self.sigma_m, self.sigma_rad = noise, survey_sigma[0] / 1000, math.radians(survey_sigma[1])
        sensors = truth["sensors"]
        self.cameras = [n for n, s in sensors.items() if "camera" in s]
        first = [n for n in self.cameras if np.allclose(sensors[n]["to_reference"]["rotation"], np.eye(3))
                 and np.allclose(sensors[n]["to_reference"]["translation"], 0)]
        self.cameras.sort(key=lambda n: n not in first[:1])  # the reference camera first
        self.lidars = [n for n, s in sensors.items() if "camera" not in s] if lidars else []
        self.mounted = self.cameras[1:] + self.lidars
        self.k0 = [cb.camera_vector(sensors[c]["camera"]) for c in self.cameras]
        self.room_to_first = cb.pose(sensors[self.cameras[0]]["room_to_sensor"])
        self.mount0 = [cb.pose(sensors[m]["to_reference"]) for m in self.mounted]
        self.boards0 = [cb.pose(b) for b in room["boards"]]
        # Per camera: (board index, measured corners) of complete, unoccluded boards: every
        # corner inside the image (the truth projects a board beyond the view too).
        def whole(b, camera):
            corners = np.array(b["corners_px"]).reshape(-1, 2)
            inside = (corners[:, 0] >= 0) & (corners[:, 0] < camera["width"]) \
                & (corners[:, 1] >= 0) & (corners[:, 1] < camera["height"])
            return len(corners) > 0 and b["occluded_corners"] == 0 and inside.all()
        self.seen = [[(i, np.array(b["corners_px"])) for i, b in enumerate(sensors[c]["boards"])
                      if whole(b, sensors[c]["camera"])] for c in self.cameras]
        # Per LiDAR: placed boards (index, hole centres, face points and their weights), planes.
        self.placed, self.planes = [], []
        for l in self.lidars:
            cloud = cb.read_pcd_xyz(os.path.join(scene, f"{l}.pcd"))
            room_to_l = cb.pose(sensors[l]["room_to_sensor"])
            on = []
            for i, b in enumerate(sensors[l]["boards"]):
                if sum(1 for n in b["hole_scan_lines"] if n >= 2) >= 2:
                    pts, w = self.face_points(cloud, cb.pose(b["board_to_camera"]))
                    on.append((i, np.array(b["holes_lidar"]), pts, w))
            self.placed.append(on)
            boards_l = [cb.compose(room_to_l, b) for b in self.boards0]
            planes = []
            for j, p in enumerate(room["planes"]):
                n = room_to_l[0] @ np.array(p["normal"])
                d = p["offset"] + n @ room_to_l[1]
                near = cloud[np.abs(cloud @ n - d) < 2.5 * noise.range_m]
                near = near * (d / (near @ n))[:, None]  # onto the true plane along each beam
                s = cb.plane_summary(near, room_to_l, p, boards_l, (np.eye(3), np.zeros(3)),
                                     self.board, noise.range_m)
                if s is not None:
                    planes.append((j, np.array(p["normal"]), p["offset"], *s))
            self.planes.append(planes)
        self.plane_ids = sorted({j for ps in self.planes for j, *_ in ps})
        self.n_cam, self.n_mount, self.n_boards = len(self.cameras), len(self.mounted), len(self.boards0)
        self.at_mount = K * self.n_cam + 6
        self.at_boards = self.at_mount + 6 * self.n_mount
        self.at_planes = self.at_boards + 6 * self.n_boards
        self.size = self.at_planes + 3 * len(self.plane_ids)
        self.cloud_check = self.check_noise(scene) if lidars else None

    def face_points(self, cloud, board_to_l):
        """A placed board's face points (`plane_points`' selection: 3 cm clear of the edges
        and holes, within 6 cm of the face), moved along their beams onto the true face,
        and each one's weight 1 / (range σ × incidence cosine)."""
        r, t = board_to_l
        local = (r.T @ (cloud - t).T).T
        b = self.board
        keep = (np.abs(local[:, 2]) <= 0.06) & (np.abs(local[:, 0]) <= b.width / 2 - 0.03) \
            & (np.abs(local[:, 1]) <= b.height / 2 - 0.03)
        for h in b.holes:
            keep &= np.hypot(local[:, 0] - h[0], local[:, 1] - h[1]) >= 0.08 + 0.03
        pts = cloud[keep]
        n = r[:, 2]
        pts = pts * ((n @ t) / (pts @ n))[:, None]
        cosine = np.abs(pts @ n) / np.linalg.norm(pts, axis=1)
        return pts, 1.0 / (self.noise.range_m * np.maximum(cosine, 0.02))

    def check_noise(self, scene):
        """RMS of the whitened distances of the raw (noisy) face points to the true board
        faces: ≈ 1 when the noise model (range σ × incidence cosine) is the simulator's."""
        out = []
        for l, on in zip(self.lidars, self.placed):
            cloud = cb.read_pcd_xyz(os.path.join(scene, f"{l}.pcd"))
            with open(os.path.join(scene, "rig-truth.json")) as f:
                boards = json.load(f)["sensors"][l]["boards"]
            for i, _, pts, w in on:
                r, t = cb.pose(boards[i]["board_to_camera"])
                local = (r.T @ (cloud - t).T).T
                b = self.board
                keep = (np.abs(local[:, 2]) <= 0.06) & (np.abs(local[:, 0]) <= b.width / 2 - 0.03) \
                    & (np.abs(local[:, 1]) <= b.height / 2 - 0.03)
                for h in b.holes:
                    keep &= np.hypot(local[:, 0] - h[0], local[:, 1] - h[1]) >= 0.11
                out.append(local[keep, 2] * w)
        return float(np.sqrt(np.mean(np.square(np.concatenate(out))))) if out else None

    def describe(self):
        seen = ", ".join(f"{c} {len(s)} boards" for c, s in zip(self.cameras, self.seen))
        placed = ", ".join(f"{l} places {len(p)} ({sum(len(q[2]) for q in p)} face pts), "
                           f"{len(ps)} planes" for l, p, ps in zip(self.lidars, self.placed, self.planes))
        r = self.residuals(np.zeros(self.size))
        text = f"{seen}{'; ' + placed if placed else ''}; {self.size} parameters, {len(r)} residuals, " \
               f"max |r| at the truth {np.abs(r).max():.1e} σ"
        if self.cloud_check:
            text += f"; raw face points' whitened RMS {self.cloud_check:.2f}"
        return text

    def residuals(self, x):
        room_to_first = decoupled(self.room_to_first, x[K * self.n_cam:K * self.n_cam + 6])
        mounts = [decoupled(m, x[self.at_mount + 6 * k:self.at_mount + 6 * k + 6])
                  for k, m in enumerate(self.mount0)]
        room_to = [room_to_first] + [cb.compose(cb.invert(m), room_to_first) for m in mounts]
        boards, out = [], []
        for i, b0 in enumerate(self.boards0):
            d = x[self.at_boards + 6 * i:self.at_boards + 6 * i + 6]
            boards.append(decoupled(b0, d))
            out.append(np.concatenate([d[:3] / self.sigma_rad, d[3:] / self.sigma_m]))
        for c in range(self.n_cam):
            k = self.k0[c] + x[K * c:K * c + K]
            for i, measured in self.seen[c]:
                p = cb.compose(room_to[c], boards[i])
                out.append((cb.project(k, cb.transform(p, self.board.corners)) - measured).ravel()
                           / self.noise.corner_px)
        planes = {}
        for q, j in enumerate(self.plane_ids):
            delta = x[self.at_planes + 3 * q:self.at_planes + 3 * q + 3]
            planes[j] = delta
            out.append(np.array([delta[0] / self.sigma_rad, delta[1] / self.sigma_rad, delta[2] / self.sigma_m]))
        for l in range(len(self.lidars)):
            room_to_l = room_to[self.n_cam + l]
            for i, holes, pts, w in self.placed[l]:
                p = cb.compose(room_to_l, boards[i])
                out.append((cb.transform(p, self.board.holes) - holes).ravel() / self.noise.hole_m)
                n = p[0][:, 2]
                out.append(w * (pts @ n - n @ p[1]))
            l_to_room = cb.invert(room_to_l)
            for j, n0, d0, pts, w in self.planes[l]:
                delta = planes[j]
                n = cb.rodrigues(cb.tangent_basis(n0) @ delta[:2]) @ n0
                out.append(w * (cb.transform(l_to_room, pts) @ n - d0 - delta[2]))
        return np.concatenate(out)

    def bound(self, exact):
        """σ at the truth; `exact`: the boards and planes known (left out of the fit)."""
        keep = list(range(self.at_boards if exact else self.size))
        cov = cb.fisher_covariance(self, keep)
        d = np.diag(cov)
        out = {}
        for c, name in enumerate(self.cameras):
            out[name + " fx"] = 100 * math.sqrt(d[K * c]) / self.k0[c][0]
            out[name + " cx"] = math.sqrt(d[K * c + 2])
            out[name + " cy"] = math.sqrt(d[K * c + 3])
        for k, name in enumerate(self.mounted):
            rot = d[self.at_mount + 6 * k:self.at_mount + 6 * k + 3]
            t = d[self.at_mount + 6 * k + 3:self.at_mount + 6 * k + 6]
            out[name + " rot"] = math.degrees(math.sqrt(rot.max()))
            out[name + " rot_rms"] = math.degrees(math.sqrt(rot.sum()))
            out[name + " t"] = 1000 * math.sqrt(t.max())
            out[name + " t_rms"] = 1000 * math.sqrt(t.sum())
        return out


if __name__ == "__main__":
    sys.exit(main())
