#!/usr/bin/env python3
"""Converts an OpenCalib intrinsic + LiDAR-to-camera extrinsic pair (JSON) into a roomcal
result file, so `roomcal overlay` can draw a published calibration, e.g.

    scripts/opencalib_to_result.py ../shared/data/road-overlay --height 1200 > /tmp/road.json
    roomcal overlay --calibration /tmp/road.json --image ../shared/data/road-overlay/0.png \\
        --cloud ../shared/data/road-overlay/0.pcd --out /tmp/road-overlay.png

(the sample's intrinsic file says 1080 rows; its image has 1200, hence --height).
"""
import argparse
import glob
import json
import os


def only(pattern):
    found = glob.glob(pattern)
    if len(found) != 1:
        raise SystemExit(f"expected one file matching {pattern}, found {found}")
    with open(found[0]) as f:
        return next(iter(json.load(f).values()))["param"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder")
    ap.add_argument("--height", type=int, help="image rows, when the file's are wrong")
    args = ap.parse_args()
    intr = only(os.path.join(args.folder, "*-intrinsic.json"))
    extr = only(os.path.join(args.folder, "*-extrinsic.json"))
    k = intr["cam_K"]["data"]
    d = intr["cam_dist"]["data"][0]
    t = extr["sensor_calib"]["data"]
    result = {
        "status": "accepted",
        "camera": {
            "model": "pinhole-radtan",
            "width": intr["img_dist_w"],
            "height": args.height or intr["img_dist_h"],
            "fx": k[0][0], "fy": k[1][1], "cx": k[0][2], "cy": k[1][2],
            "distortion": (list(d) + [0.0] * 5)[:5],
        },
        "lidar_to_camera": {
            "rotation": [row[:3] for row in t[:3]],
            "translation": [row[3] for row in t[:3]],
        },
        "uncertainty": {"fx": 0, "fy": 0, "cx": 0, "cy": 0, "rotation_deg": 0, "translation_m": 0},
        "quality": {"corner_rms_px": 0, "hole_rms_px": 0, "boards": 0},
        "boards": [],
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
