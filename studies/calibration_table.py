#!/usr/bin/env python3
"""Accuracy tables of `roomcal calibrate` against the simulator's truth (issue 5): one frame
per scene, for the design's room (six boards, Pandar64-like, 70° FOV) in the grid and the
band layout, and in the band layout a 90° FOV lens, a VLP-32C-like LiDAR and four boards; each scene solved jointly (corners + hole term +
board planes), with the paper's cost alone (--without-planes) and in two stages
(--two-stage, the paper's ablation). Prints Markdown tables of the errors against the truth
(mean and worst over the seeds), the mean reported σ, and the overlay error: how far
from the truth the result draws LiDAR points 10 m out (mean px over a grid of the image),
which is what a fusion stack sees; intrinsic and extrinsic errors partly cancel in it.
Also a standing vehicle (`simulate --frames 10`, `calibrate --standing`): the daemon's
default capture (5 frames averaged, 3 sweeps accumulated) and 10 of each.

    cargo build --release && studies/calibration_table.py [--seeds 1 2 3] [--work DIR]
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOMCAL = os.path.join(ROOT, "target", "release", "roomcal")
ROOM = os.path.join(ROOT, "config", "room.toml")

SCENES = [
    ("six boards, Pandar64, 70° FOV, grid layout", []),
    ("six boards, Pandar64, 70° FOV, band layout", ["--layout", "band"]),
    ("six boards, Pandar64, 90° FOV, band layout", ["--fov", "90", "--layout", "band"]),
    ("six boards, VLP-32C, 70° FOV, band layout", ["--lidar", "vlp32c", "--layout", "band"]),
    ("four boards, Pandar64, 70° FOV, band layout", ["--boards", "4", "--layout", "band"]),
]
MODES = [
    ("joint", []),
    ("paper's cost (no planes)", ["--without-planes"]),
    ("two-stage", ["--two-stage"]),
]


def rotation_angle_deg(a, b):
    """Angle of a·bᵀ (3×3 lists)."""
    m = [[sum(a[i][k] * b[j][k] for k in range(3)) for j in range(3)] for i in range(3)]
    c = max(-1.0, min(1.0, (m[0][0] + m[1][1] + m[2][2] - 1.0) / 2.0))
    return math.degrees(math.acos(c))


def project(camera, p):
    """Pixel of a camera-frame point through a pinhole-radtan or fisheye camera (JSON)."""
    x, y, z = p
    if z <= 1e-6:
        return None
    a, b = x / z, y / z
    d = camera["distortion"]
    if camera["model"] == "fisheye":
        r = math.hypot(a, b)
        th = math.atan(r)
        th_d = th * (1 + d[0] * th**2 + d[1] * th**4 + d[2] * th**6 + d[3] * th**8)
        s = th_d / r if r > 1e-12 else 1.0
        u, v = a * s, b * s
    else:
        k1, k2, p1, p2, k3 = d
        r2 = a * a + b * b
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        u = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
        v = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    return camera["fx"] * u + camera["cx"], camera["fy"] * v + camera["cy"]


def apply(ext, p):
    r, t = ext["rotation"], ext["translation"]
    return [sum(r[i][k] * p[k] for k in range(3)) + t[i] for i in range(3)]


def overlay_error_px(result, truth, depth):
    """Mean pixel distance between where the truth and the result put LiDAR points that
    the true camera sees on a 9×7 grid over the image at `depth` metres: what a fusion
    stack drawing the LiDAR into the image would be off by."""
    c, tc = result["camera"], truth["camera"]
    ext, text = result["lidar_to_camera"], truth["lidar_to_camera"]
    rt = text["rotation"]
    errs = []
    for i in range(9):
        for j in range(7):
            # Camera-frame point on the true ray through a pixel (undistorted approx.).
            u = (i + 0.5) / 9 * tc["width"]
            v = (j + 0.5) / 7 * tc["height"]
            pc = [(u - tc["cx"]) / tc["fx"] * depth, (v - tc["cy"]) / tc["fy"] * depth, depth]
            # Into the LiDAR frame with the true extrinsic: p_l = Rᵀ (p_c − t).
            d = [pc[k] - text["translation"][k] for k in range(3)]
            pl = [sum(rt[k][i2] * d[k] for k in range(3)) for i2 in range(3)]
            a, b = project(tc, pc), project(c, apply(ext, pl))
            if a and b and 0 <= a[0] < tc["width"] and 0 <= a[1] < tc["height"]:
                errs.append(math.dist(a, b))
    return sum(errs) / len(errs) if errs else float("nan")


def errors(result, truth):
    c, t = result["camera"], truth["camera"]
    e = {
        "fx %": 100 * max(abs(c["fx"] - t["fx"]) / t["fx"], abs(c["fy"] - t["fy"]) / t["fy"]),
        "cx,cy px": max(abs(c["cx"] - t["cx"]), abs(c["cy"] - t["cy"])),
    }
    r, tr = result.get("lidar_to_camera"), truth.get("lidar_to_camera")
    if r and tr:
        e["rot °"] = rotation_angle_deg(r["rotation"], tr["rotation"])
        e["trans mm"] = 1000 * math.dist(r["translation"], tr["translation"])
        e["overlay px @10 m"] = overlay_error_px(result, truth, 10.0)
    u = result["uncertainty"]
    e["σ fx %"] = 100 * u["fx"] / c["fx"]
    e["σ cx px"] = max(u["cx"], u["cy"])
    e["σ rot °"] = u["rotation_deg"]
    e["σ trans mm"] = 1000 * u["translation_m"]
    return e


def run(cmd):
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode not in (0, 3):
        sys.exit(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stderr}")
    return p.returncode


def table(name, runs, note=""):
    """Prints one scene's table; `runs[mode]` lists (exit status, errors) per seed."""
    keys = ["fx %", "cx,cy px", "rot °", "trans mm", "overlay px @10 m", "σ fx %", "σ cx px", "σ rot °", "σ trans mm"]
    print(f"### {name}{note}\n")
    print("| mode | accepted | " + " | ".join(f"{k} mean" if k.startswith("σ") else f"{k} mean / worst" for k in keys) + " |")
    print("|---" * (len(keys) + 2) + "|")
    for mode, _ in MODES:
        got = runs[mode]
        accepted = sum(1 for s, _ in got if s == 0)
        cells = []
        for k in keys:
            vals = [e[k] for _, e in got if k in e]
            if not vals:
                cells.append("–")
            elif k.startswith("σ"):
                cells.append(f"{sum(vals) / len(vals):.3g}")
            else:
                cells.append(f"{sum(vals) / len(vals):.3g} / {max(vals):.3g}")
        print(f"| {mode} | {accepted}/{len(got)} | " + " | ".join(cells) + " |")
    print()


def simulate(work, name, seed, sim_args):
    scene = os.path.join(work, f"{name.replace(' ', '_').replace(',', '')}-{seed}")
    if not os.path.exists(os.path.join(scene, "truth.json")):
        run([ROOMCAL, "simulate", "--room", ROOM, "--out", scene, "--seed", str(seed)] + sim_args)
    return scene


def calibrate(scenes, out, mode_args, standing=None):
    """Runs `roomcal calibrate` on the scenes' image/cloud pairs, or with `standing` =
    (frames, sweeps) on that many frames and sweeps of the one scene; (status, result)."""
    pairs = []
    for scene in scenes:
        pairs += ["--image", os.path.join(scene, "image.png"), "--cloud", os.path.join(scene, "cloud.pcd")]
    if standing:
        frames, sweeps = standing
        suffix = lambda k: "" if k == 1 else f"-{k}"
        pairs = [a for k in range(1, frames + 1) for a in ("--image", os.path.join(scenes[0], f"image{suffix(k)}.png"))]
        pairs += [a for k in range(1, sweeps + 1) for a in ("--cloud", os.path.join(scenes[0], f"cloud{suffix(k)}.pcd"))]
        mode_args = mode_args + ["--standing"]
    status = run([ROOMCAL, "calibrate", "--room", os.path.join(scenes[0], "room.toml"), "--out", out] + pairs + mode_args)
    with open(out) as f:
        return status, json.load(f)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--work", default=None)
    ap.add_argument("--only", default="", help="run only the scenes whose name contains this")
    args = ap.parse_args()
    work = args.work or tempfile.mkdtemp(prefix="roomcal-table-")
    print(f"seeds {args.seeds}; scenes in {work}\n")
    for name, sim_args in [s for s in SCENES if args.only in s[0]]:
        runs = {m: [] for m, _ in MODES}
        placed = []
        for seed in args.seeds:
            scene = simulate(work, name, seed, sim_args)
            with open(os.path.join(scene, "truth.json")) as f:
                truth = json.load(f)
            for mode, mode_args in MODES:
                out = os.path.join(scene, f"result-{mode.split()[0].strip(chr(39))}.json")
                status, result = calibrate([scene], out, mode_args)
                if mode == "joint":
                    placed.append(sum(1 for b in result["boards"] if b.get("holes_lidar")))
                runs[mode].append((status, errors(result, truth)))
        table(name, runs, f" (LiDAR boards placed per seed: {placed})")
    # Several frames of one vehicle: rooms set up differently, the same rig.
    name = "three frames of one rig, six boards, Pandar64, 70° FOV, band layout"
    if args.only in name:
        runs = {m: [] for m, _ in MODES}
        for rig in args.seeds:
            seeds = [100 * rig + k for k in range(3)]
            scenes = [simulate(work, f"rig {rig}", s, ["--layout", "band", "--rig-seed", str(rig)]) for s in seeds]
            with open(os.path.join(scenes[0], "truth.json")) as f:
                truth = json.load(f)
            for mode, mode_args in MODES:
                out = os.path.join(scenes[0], f"result-3-{mode.split()[0].strip(chr(39))}.json")
                status, result = calibrate(scenes, out, mode_args)
                runs[mode].append((status, errors(result, truth)))
        table(name, runs, f" (rigs {args.seeds})")
    # A standing vehicle: several frames and sweeps of one room, as the daemon captures.
    for frames, sweeps, what in [(5, 3, "the daemon's default capture"), (10, 10, "ten of each")]:
        name = f"standing vehicle, {frames} frames + {sweeps} sweeps ({what}), six boards, Pandar64, band layout"
        if args.only not in name:
            continue
        runs = {m: [] for m, _ in MODES}
        for seed in args.seeds:
            scene = simulate(work, "standing", seed, ["--layout", "band", "--frames", "10"])
            with open(os.path.join(scene, "truth.json")) as f:
                truth = json.load(f)
            for mode, mode_args in MODES:
                out = os.path.join(scene, f"result-{frames}-{sweeps}-{mode.split()[0].strip(chr(39))}.json")
                status, result = calibrate([scene], out, mode_args, standing=(frames, sweeps))
                runs[mode].append((status, errors(result, truth)))
        table(name, runs)



if __name__ == "__main__":
    main()
