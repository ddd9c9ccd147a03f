#!/usr/bin/env python3
"""What the LiDAR's range noise alone does to a survey (issue 13): one room simulated
without range noise (`roomcal simulate --visits N --range-noise 0`), then K redraws of
Gaussian range noise along every point's own beam on those same sweeps (the images kept),
each surveyed by `roomcal survey`. Over the draws, per board and plane: the mean error
against the truth (a bias, with its standard error), its spread, and the σ the survey
wrote; and the survey's χ² against its own joint covariance (`survey_attribution.py`'s),
everything, boards and planes, averaged over the draws (about the number of modes when
the σ are honest). The noise-free survey itself is reported first: what the scan pattern
and the images leave.

    roomcal simulate --room config/room.toml --out NF/room --visits 16 --seed 1 \\
        --boards 7 --lidar pandar64 --fov 70 --layout grid --range-noise 0
    studies/survey_noise_mc.py NF [--draws 12] [--sigma 0.02] [--work DIR]

The draws' work folders (DIR/k/room/visit-XX/cloud.pcd, DIR/k/surveyed.toml) are kept.
"""
import argparse
import glob
import json
import os
import shutil
import subprocess
import sys
import tempfile
import tomllib

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import crb_bound  # noqa: E402  (rotation vectors, there)
import survey_attribution as attribution  # noqa: E402  (the truth in the survey's frame, χ²)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOMCAL = os.environ.get("ROOMCAL_BIN", os.path.join(ROOT, "target", "release", "roomcal"))
PCD_POINT = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<u2")])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("noise_free", help="a folder holding room/ (simulated with --range-noise 0)")
    ap.add_argument("--draws", type=int, default=12)
    ap.add_argument("--sigma", type=float, default=0.02, help="range noise σ (m), the simulator's default")
    ap.add_argument("--work", default=None)
    args = ap.parse_args()
    work = args.work or tempfile.mkdtemp(prefix="survey-noise-mc-")
    room = os.path.join(args.noise_free, "room")
    visits = sorted(glob.glob(os.path.join(room, "visit-*")))
    survey(room, visits, [os.path.join(v, "cloud.pcd") for v in visits], os.path.join(args.noise_free, "surveyed.toml"))
    print("noise-free survey:")
    report([args.noise_free])
    draws = []
    for k in range(args.draws):
        folder = os.path.join(work, str(k))
        os.makedirs(os.path.join(folder, "room"), exist_ok=True)
        shutil.copy(os.path.join(room, "room-truth.json"), os.path.join(folder, "room"))
        rng = np.random.default_rng(1000 + k)
        clouds = []
        for v in visits:
            out = os.path.join(folder, "room", os.path.basename(v), "cloud.pcd")
            os.makedirs(os.path.dirname(out), exist_ok=True)
            redraw(os.path.join(v, "cloud.pcd"), out, args.sigma, rng)
            clouds.append(out)
        survey(room, visits, clouds, os.path.join(folder, "surveyed.toml"))
        draws.append(folder)
    print(f"\n{args.draws} draws of {args.sigma * 1000:.0f} mm range noise (work: {work}):")
    report(draws)


def redraw(src, dst, sigma, rng):
    """`src`'s points moved along their own beams by N(0, σ²) (a point at the origin kept)."""
    raw = open(src, "rb").read()
    start = raw.index(b"DATA binary\n") + len(b"DATA binary\n")
    points = np.frombuffer(raw[start:], dtype=PCD_POINT).copy()
    p = np.stack([points["x"], points["y"], points["z"]], 1).astype(np.float64)
    r = np.linalg.norm(p, axis=1)
    scale = np.ones_like(r)
    hit = r > 0
    scale[hit] = (r[hit] + sigma * rng.standard_normal(hit.sum())) / r[hit]
    p *= scale[:, None]
    points["x"], points["y"], points["z"] = p[:, 0], p[:, 1], p[:, 2]
    with open(dst, "wb") as f:
        f.write(raw[:start] + points.tobytes())


def survey(room, visits, clouds, out):
    cmd = [ROOMCAL, "survey", "--room", os.path.join(room, "room.toml"), "--out", out]
    for v, cloud in zip(visits, clouds):
        cmd += ["--visit", os.path.join(v, "image.png"), cloud]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"survey {out} failed: {done.stderr.strip()}")


def report(folders):
    """Per board and plane over the surveys in `folders`: mean error ± its standard error,
    spread, the written σ; then the mean χ²."""
    rows, chi2 = {}, {"everything": [], "boards": [], "planes": []}
    truth = None
    for folder in folders:
        survey = tomllib.load(open(os.path.join(folder, "surveyed.toml"), "rb"))["survey"]
        if truth is None:
            truth = json.load(open(os.path.join(folder, "room", "room-truth.json")))
        exact = attribution.ExactSurvey(survey, truth)
        for i, ((rs, ts), (r, t)) in enumerate(zip(exact.boards, exact.truth_boards)):
            b = survey["boards"][i]
            rows.setdefault(f"board {i}", []).append(
                [*((ts - t) * 1000), *np.degrees(crb_bound.rotation_vector(rs @ r.T)), b["sigma_m"] * 1000, b["sigma_deg"]])
        for p, near in zip(survey["planes"], exact.truth_planes):
            if near is None:
                continue
            normal, offset = near
            turn = np.degrees(np.cross(normal, np.array(p["normal"])))
            rows.setdefault(p["name"], []).append(
                [(p["offset"] - offset) * 1000, *turn, p["sigma_m"] * 1000, p["sigma_deg"]])
        for name, (value, modes) in exact.chi2().items():
            chi2[name].append((value, modes))
    n = len(folders)
    print("| entry | mean error (board: x y z mm, ωx ωy ωz °; plane: offset mm, ωx ωy ωz °) | ± (standard error) | spread | σ written mm / ° |")
    print("|---|---|---|---|---|")
    for name, v in rows.items():
        v = np.array(v)
        mean, spread = v.mean(0), v.std(0, ddof=1) if n > 1 else np.zeros(v.shape[1])
        numbers = lambda a: " ".join(f"{x:+.4f}" if abs(x) < 0.1 else f"{x:+.2f}" for x in a)
        error_of_mean = numbers(spread[:-2] / np.sqrt(n)) if n > 1 else "–"
        spread_text = numbers(spread[:-2]) if n > 1 else "–"
        print(f"| {name} | {numbers(mean[:-2])} | {error_of_mean} | {spread_text} | {mean[-2]:.3f} / {mean[-1]:.4f} |")
    for name, values in chi2.items():
        if values:
            print(f"χ² {name}: {np.mean([c for c, _ in values]):.1f} over {values[0][1]} modes (mean of {n})")


if __name__ == "__main__":
    main()
