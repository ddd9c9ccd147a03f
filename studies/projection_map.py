#!/usr/bin/env python3
"""Does the result file's projection map (`projection_uncertainty`) hold up against the truth?

At every grid pixel of an accepted result's map, a point `range_m` along the TRUE camera's
ray is held in the true LiDAR frame (in the camera frame for an intrinsics-only map) and
drawn by the solved calibration; its distance from the pixel, over the map's 1σ there, is
one sample. An honest map gives ratios like the norm of a 2-D normal over its larger axis's
σ (median about 1.2, 3 exceeded about 1 % of the time for an isotropic one).

    studies/projection_map.py RESULT.json TRUTH.json [RESULT.json TRUTH.json ...]

Results come from `roomcal calibrate` of `roomcal simulate` scenes (the scene's truth.json).
"""
import json
import sys

import numpy as np

from crb_bound import camera_vector, pose, project


def unproject(camera, pixel):
    """The unit ray of `pixel` through `camera` (Gauss–Newton on the normalised point)."""
    k = camera_vector(camera)
    xy = np.array([(pixel[0] - camera["cx"]) / camera["fx"], (pixel[1] - camera["cy"]) / camera["fy"]])

    def drawn(v):
        return project(k, np.array([[v[0], v[1], 1.0]]))[0]

    for _ in range(50):
        f = drawn(xy) - pixel
        if np.linalg.norm(f) < 1e-10:
            break
        h = 1e-7
        j = np.column_stack([(drawn(xy + e) - drawn(xy - e)) / (2 * h) for e in np.eye(2) * h])
        xy = xy - np.linalg.solve(j, f)
    ray = np.array([xy[0], xy[1], 1.0])
    return ray / np.linalg.norm(ray)


def ratios(result, truth):
    """Error over σ at every grid pixel of an accepted result's map."""
    m = result.get("projection_uncertainty")
    if not m or result["status"] != "accepted":
        return []
    identity = (np.eye(3), np.zeros(3))
    true_pose = pose(truth["lidar_to_camera"]) if m["lidar"] else identity
    solved_pose = pose(result["lidar_to_camera"]) if m["lidar"] else identity
    k = camera_vector(result["camera"])
    out = []
    for i, v in enumerate(m["rows"]):
        for j, u in enumerate(m["columns"]):
            sigma = m["sigma_px"][i][j]
            if sigma is None:
                continue
            in_camera = unproject(truth["camera"], np.array([u, v])) * m["range_m"]
            in_lidar = true_pose[0].T @ (in_camera - true_pose[1])
            drawn = project(k, (solved_pose[0] @ in_lidar + solved_pose[1])[None, :])[0]
            out.append(np.linalg.norm(drawn - [u, v]) / sigma)
    return out


def main():
    args = sys.argv[1:]
    if not args or len(args) % 2 or args[0] in ("-h", "--help"):
        print(__doc__)
        sys.exit(2)
    every = []
    for result_path, truth_path in zip(args[::2], args[1::2]):
        r = ratios(json.load(open(result_path)), json.load(open(truth_path)))
        if r:
            print(f"{result_path}: worst error/σ {max(r):.2f} over {len(r)} grid pixels")
            every += r
        else:
            print(f"{result_path}: not accepted, or no map")
    if every:
        z = np.array(every)
        print(f"{len(z)} grid pixels: error/σ median {np.median(z):.2f}, 95th percentile "
              f"{np.percentile(z, 95):.2f}, max {z.max():.2f}, above 3: {np.mean(z > 3) * 100:.1f} %")


if __name__ == "__main__":
    main()
