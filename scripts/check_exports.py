#!/usr/bin/env python3
"""Reads roomcal's exports for other stacks back with PyYAML (an independent reader) and
compares every number with the result file to 1e-9.

Runs `roomcal calibrate --export` on the bundled fixtures (the six-board pinhole room with
its LiDAR, and the intrinsics-only fisheye room) and checks, per run:
  camera.camera_info.yaml     ROS camera_info keys, K, D, R = I, P = [K | 0]
  sensor_kit_calibration.yaml Autoware shape; camera/camera_link in the LiDAR frame, which
                              composed with camera_link -> optical gives lidar_to_camera
  calib.txt                   KITTI P0 and Tr_velo_to_cam, row-major
One line per check; exit status 1 on any failure.

  scripts/check_exports.py --bin target/release/roomcal
"""

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

TOLERANCE = 1e-9
ROOT = Path(__file__).resolve().parent.parent
# p_optical = OPTICAL_FROM_LINK @ p_link (REP 103: camera_link x forward, y left, z up).
OPTICAL_FROM_LINK = [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]
failures = []


def check(ok, what):
    print(("ok    " if ok else "FAIL  ") + what)
    if not ok:
        failures.append(what)


def close(got, want):
    return len(got) == len(want) and all(abs(g - w) <= TOLERANCE for g, w in zip(got, want))


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def transpose(a):
    return [[a[j][i] for j in range(3)] for i in range(3)]


def rpy_matrix(roll, pitch, yaw):
    """URDF fixed-axis roll-pitch-yaw: Rz(yaw) Ry(pitch) Rx(roll)."""
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    sy, cy = math.sin(yaw), math.cos(yaw)
    return [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]


def check_camera_info(name, doc, result):
    cam = result["camera"]
    k = [cam["fx"], 0.0, cam["cx"], 0.0, cam["fy"], cam["cy"], 0.0, 0.0, 1.0]
    p = [cam["fx"], 0.0, cam["cx"], 0.0, 0.0, cam["fy"], cam["cy"], 0.0, 0.0, 0.0, 1.0, 0.0]
    model = {"pinhole-radtan": "plumb_bob", "fisheye": "equidistant"}[cam["model"]]
    check(doc["image_width"] == cam["width"] and doc["image_height"] == cam["height"],
          f"{name}: image size {doc['image_width']}x{doc['image_height']}")
    check(doc["camera_name"] == "camera", f"{name}: camera_name {doc['camera_name']}")
    check(doc["distortion_model"] == model, f"{name}: distortion_model {doc['distortion_model']}")
    for key, rows, cols, want in [
        ("camera_matrix", 3, 3, k),
        ("distortion_coefficients", 1, len(cam["distortion"]), cam["distortion"]),
        ("rectification_matrix", 3, 3, [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]),
        ("projection_matrix", 3, 4, p),
    ]:
        m = doc[key]
        check(m["rows"] == rows and m["cols"] == cols and close(m["data"], want),
              f"{name}: {key} ({rows}x{cols}) equals the result file's")


def check_sensor_kit(name, doc, result):
    kit = doc["sensor_kit_base_link"]
    lidar = kit["lidar"]
    check(all(lidar[k] == 0.0 for k in ("x", "y", "z", "roll", "pitch", "yaw")),
          f"{name}: lidar is the parent frame (identity)")
    cam = kit["camera/camera_link"]
    a = rpy_matrix(cam["roll"], cam["pitch"], cam["yaw"])
    b = [cam["x"], cam["y"], cam["z"]]
    # p_lidar = A p_link + b  =>  lidar -> optical: R = M A^T, t = -R b.
    r = matmul(OPTICAL_FROM_LINK, transpose(a))
    t = [-sum(r[i][k] * b[k] for k in range(3)) for i in range(3)]
    e = result["lidar_to_camera"]
    check(close(sum(r, []), sum(e["rotation"], [])),
          f"{name}: camera_link rpy composed with camera_link->optical gives the rotation")
    check(close(t, e["translation"]), f"{name}: camera_link position gives the translation")


def check_kitti(name, text, result):
    lines = dict(line.split(":", 1) for line in text.splitlines())
    cam = result["camera"]
    p0 = [cam["fx"], 0.0, cam["cx"], 0.0, 0.0, cam["fy"], cam["cy"], 0.0, 0.0, 0.0, 1.0, 0.0]
    check(close([float(v) for v in lines["P0"].split()], p0), f"{name}: P0 = [K | 0]")
    e = result.get("lidar_to_camera")
    if e is None:
        check("Tr_velo_to_cam" not in lines, f"{name}: no Tr_velo_to_cam without a LiDAR")
        return
    tr = [v for row, t in zip(e["rotation"], e["translation"]) for v in row + [t]]
    check(close([float(v) for v in lines["Tr_velo_to_cam"].split()], tr),
          f"{name}: Tr_velo_to_cam = [R | t] row-major")


def run_fixture(binary, name, room, images, clouds, work):
    out, exports = work / f"{name}.json", work / f"{name}-exports"
    cmd = [binary, "calibrate", "--room", str(room), "--out", str(out), "--export", str(exports), "--quiet"]
    for image in images:
        cmd += ["--image", str(image)]
    for cloud in clouds:
        cmd += ["--cloud", str(cloud)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    check(done.returncode == 0, f"{name}: calibrate accepted ({done.stdout.strip()}{done.stderr.strip()})")
    if done.returncode != 0:
        return
    result = json.loads(out.read_text())
    check_camera_info(name, yaml.safe_load((exports / "camera.camera_info.yaml").read_text()), result)
    kit = exports / "sensor_kit_calibration.yaml"
    if "lidar_to_camera" in result:
        check_sensor_kit(name, yaml.safe_load(kit.read_text()), result)
    else:
        check(not kit.exists(), f"{name}: no sensor_kit_calibration.yaml without a LiDAR")
    check_kitti(name, (exports / "calib.txt").read_text(), result)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bin", default=str(ROOT / "target/release/roomcal"), help="the roomcal binary")
    args = parser.parse_args()
    fixtures = ROOT / "fixtures"
    six = fixtures / "six-boards-pandar64"
    fisheye = fixtures / "intrinsics-fisheye"
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        run_fixture(args.bin, "six-boards-pandar64", six / "room.toml", [six / "image.png"], [six / "cloud.pcd"], work)
        run_fixture(args.bin, "intrinsics-fisheye", fisheye / "room.toml", [fisheye / "image.png"], [], work)
    print(f"{'FAILED' if failures else 'passed'}: {len(failures)} failure(s)")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
