#!/usr/bin/env python3
"""Survey accuracy and speed (issue 13): `roomcal survey` on 4, 8, 16 and 32 simulated
visits of the design's room (six boards, 1920×1200 camera, Pandar64; every visit its own
vehicle parked ±0.3 m / ±5° off; images rendered with --supersample 1). The first N visits
of one simulation of the largest N are surveyed, so every row sees the same room. Each
surveyed board and plane is compared with the simulator's room-truth.json expressed in the
survey's frame (the boards' mean, as the σ are): board position error (norm, mm) and
orientation error (angle, deg), RMS over the boards; plane offset error (mm) and normal error (deg), RMS over
the surveyed planes; beside them the mean reported σ and the share of errors within 3σ
(each axis against the largest-axis σ). Wall time is that of the whole `roomcal survey`
command (load, detect, free-board calibration and plane search per visit on every core,
chaining, the bundle), measured here around the process, with its CPU time (user + system)
beside it: on a shared machine the wall time says more about the other jobs than about us.

    cargo build --release && studies/survey_study.py [--visits 4 8 16 32] [--seeds 1] [--work DIR] [--bound]

`--bound` adds the survey's own Cramér–Rao bound (`crb_bound.survey_information`: every
visit's information about the boards and planes, its own parameters marginalised; corners at
the survey's reported corner RMS per axis, holes 3 mm, the sweeps' range noise) in the same
mean frame (boards and planes alike): the RMS over boards of the worst-axis position and
rotation σ, and over the survey's planes (matched to the truth's by normal) of the normal's.
"""
import argparse
import re
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import resource
import tomllib

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOMCAL = os.environ.get("ROOMCAL_BIN", os.path.join(ROOT, "target", "release", "roomcal"))
ROOM = os.path.join(ROOT, "config", "room.toml")


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def transpose(a):
    return [[a[j][i] for j in range(3)] for i in range(3)]


def apply(r, v):
    return [sum(r[i][k] * v[k] for k in range(3)) for i in range(3)]


def sub(a, b):
    return [x - y for x, y in zip(a, b)]


def norm(v):
    return math.sqrt(sum(x * x for x in v))


def compose(a, b):
    """(R, t) ∘ (R', t') = (R R', R t' + t)."""
    return (matmul(a[0], b[0]), [x + y for x, y in zip(apply(a[0], b[1]), a[1])])


def inverse(a):
    rt = transpose(a[0])
    return (rt, [-x for x in apply(rt, a[1])])


HALF_TURN = ([[-1, 0, 0], [0, -1, 0], [0, 0, 1]], [0, 0, 0])


def angle_deg(r):
    c = max(-1.0, min(1.0, (r[0][0] + r[1][1] + r[2][2] - 1) / 2))
    return math.degrees(math.acos(c))


def rms(values):
    return math.sqrt(sum(v * v for v in values) / len(values)) if values else float("nan")


def so3_log(r):
    c = max(-1.0, min(1.0, (r[0][0] + r[1][1] + r[2][2] - 1) / 2))
    angle = math.acos(c)
    axis = [r[2][1] - r[1][2], r[0][2] - r[2][0], r[1][0] - r[0][1]]
    s = math.sin(angle)
    if s < 1e-12:
        return [0.0, 0.0, 0.0] if angle < 1.0 else None  # a half turn never arises here
    return [angle * a / (2 * s) for a in axis]


def so3_exp(w):
    angle = norm(w)
    if angle < 1e-15:
        return [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
    k = [x / angle for x in w]
    kx = [[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]]
    kk = matmul(kx, kx)
    return [[(i == j) + math.sin(angle) * kx[i][j] + (1 - math.cos(angle)) * kk[i][j] for j in range(3)]
            for i in range(3)]


def mean_pose(poses):
    """The boards' mean frame as `roomcal survey` defines it (src/calibrate/survey/gauge.rs):
    the rotation where the boards' offsets log(R_b Rᵀ) sum to zero, the mean translation."""
    r = poses[0][0]
    for _ in range(50):
        logs = [so3_log(matmul(p[0], transpose(r))) for p in poses]
        step = [sum(w[i] for w in logs) / len(poses) for i in range(3)]
        r = matmul(so3_exp(step), r)
        if norm(step) < 1e-15:
            break
    return (r, [sum(p[1][i] for p in poses) / len(poses) for i in range(3)])


def matched_truth(truth_boards, ours):
    """The truth board each of ours is (nearest centre: the file's frame and the truth's are
    the nominal LiDAR frame at the mean and at the nominal parking spot, centimetres apart,
    the boards metres apart), read half-turned where ours is."""
    out = []
    for b in ours:
        _, k = min((norm(sub(t[1], b[1])), k) for k, t in enumerate(truth_boards))
        t = truth_boards[k]
        if angle_deg(matmul(transpose(t[0]), b[0])) > 90:
            t = compose(t, HALF_TURN)
        out.append(t)
    return out


def plane_in(frame, plane):
    """A plane n · p = d in `frame` (p_old = frame · p_new)."""
    n = plane["normal"]
    return {"normal": apply(transpose(frame[0]), n),
            "offset": plane["offset"] - sum(x * y for x, y in zip(n, frame[1]))}


def study(sim_dir, count, work):
    out = os.path.join(work, f"surveyed-{count}.toml")
    args = [ROOMCAL, "survey", "--room", os.path.join(sim_dir, "room.toml"), "--out", out]
    for v in range(1, count + 1):
        folder = os.path.join(sim_dir, f"visit-{v:02}")
        args += ["--visit", os.path.join(folder, "image.png"), os.path.join(folder, "cloud.pcd")]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.monotonic()
    run = subprocess.run(args, capture_output=True, text=True)
    wall = time.monotonic() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if run.returncode != 0:
        sys.exit(f"survey of {count} visits failed: {run.stderr}")
    with open(out, "rb") as f:
        survey = tomllib.load(f)["survey"]
    with open(os.path.join(sim_dir, "room-truth.json")) as f:
        truth = json.load(f)
    ours = [(b["rotation"], b["translation"]) for b in survey["boards"]]
    truth_boards = [(b["rotation"], b["translation"]) for b in truth["boards"]]
    matched = matched_truth(truth_boards, ours)
    # The σ are relative to the boards' mean frame: the errors are taken there, the
    # truth's in the mean frame of the same boards.
    mine_frame, truth_frame = mean_pose(ours), mean_pose(matched)
    ours = [compose(inverse(mine_frame), b) for b in ours]
    matched = [compose(inverse(truth_frame), t) for t in matched]
    pos, rot, within, total = [], [], 0, 0
    for b, t, spec in zip(ours, matched, survey["boards"]):
        d = sub(b[1], t[1])
        a = angle_deg(matmul(b[0], transpose(t[0])))
        pos.append(norm(d))
        rot.append(a)
        within += max(abs(x) for x in d) <= 3 * spec["sigma_m"]
        within += a <= 3 * spec["sigma_deg"] * math.sqrt(3)  # the angle is a norm over 3 axes
        total += 2
    off, turn, kept = [], [], []
    truth_planes = [plane_in(truth_frame, tp) for tp in truth["planes"]]
    for plane in survey.get("planes", []):
        mine = plane_in(mine_frame, plane)
        best = None
        for k, tp in enumerate(truth_planes):
            ang = math.degrees(math.acos(max(-1, min(1, sum(x * y for x, y in zip(tp["normal"], mine["normal"]))))))
            if best is None or ang < best[0]:
                best = (ang, abs(tp["offset"] - mine["offset"]), k)
        kept.append(best[2])
        turn.append(best[0])
        off.append(best[1])
        within += best[1] <= 3 * plane["sigma_m"]
        within += best[0] <= 3 * plane["sigma_deg"]
        total += 2
    boards = survey["boards"]
    planes = survey.get("planes", [])
    mean = lambda xs: sum(xs) / len(xs) if xs else float("nan")
    corners = re.search(r"corners ([0-9.]+) px RMS", run.stdout + run.stderr)
    return {
        "corner_rms_px": float(corners.group(1)) if corners else float("nan"),
        "visits": count,
        "wall_s": wall,
        "cpu_s": cpu,
        "pos_mm": rms(pos) * 1e3,
        "pos_sigma_mm": mean([b["sigma_m"] for b in boards]) * 1e3,
        "rot_deg": rms(rot),
        "rot_sigma_deg": mean([b["sigma_deg"] for b in boards]),
        "planes": len(planes),
        "plane_mm": rms(off) * 1e3,
        "plane_sigma_mm": mean([p["sigma_m"] for p in planes]) * 1e3,
        "plane_deg": rms(turn),
        "plane_sigma_deg": mean([p["sigma_deg"] for p in planes]),
        "within_3_sigma": f"{within}/{total}",
        "truth_planes": kept,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--visits", type=int, nargs="+", default=[4, 8, 16, 32])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    parser.add_argument("--work", default=None)
    parser.add_argument("--bound", action="store_true", help="add the survey's own Cramér–Rao bound")
    args = parser.parse_args()
    work = args.work or tempfile.mkdtemp(prefix="survey-study-")
    bound_head = " bound σ pos mm / rot ° / normal ° |" if args.bound else ""
    print("| seed | visits | wall s | CPU s | board pos RMS mm (σ) | board rot RMS ° (σ) | planes | plane offset RMS mm (σ) | plane normal RMS ° (σ) | within 3σ |" + bound_head)
    print("|---|---|---|---|---|---|---|---|---|---|" + ("---|" if args.bound else ""))
    for seed in args.seeds:
        sim_dir = os.path.join(work, f"room-seed{seed}-{max(args.visits)}")
        if not os.path.exists(os.path.join(sim_dir, "room-truth.json")):
            subprocess.run([ROOMCAL, "simulate", "--room", ROOM, "--out", sim_dir, "--visits",
                            str(max(args.visits)), "--supersample", "1", "--seed", str(seed)],
                           check=True, capture_output=True)
        infos = []
        for count in args.visits:
            r = study(sim_dir, count, work)
            bound = ""
            if args.bound:
                b = survey_bound(sim_dir, count, r["corner_rms_px"] / math.sqrt(2), infos, r["truth_planes"])
                bound = f" {b['pos_mm']:.2f} / {b['rot_deg']:.4f} / {b['normal_deg']:.4f} |"
            print(f"| {seed} | {r['visits']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['pos_mm']:.2f} ({r['pos_sigma_mm']:.2f}) "
                  f"| {r['rot_deg']:.4f} ({r['rot_sigma_deg']:.4f}) | {r['planes']} "
                  f"| {r['plane_mm']:.2f} ({r['plane_sigma_mm']:.2f}) | {r['plane_deg']:.4f} ({r['plane_sigma_deg']:.4f}) "
                  f"| {r['within_3_sigma']} |{bound}", flush=True)


def survey_bound(sim_dir, count, corner_px, infos, planes):
    """The survey bound of visits 1..`count` (`infos`: the visits' information so far, kept
    between calls; the first call's corner noise stands for every visit), over the room-truth
    planes `planes` (the survey's own, matched by normal: a plane the survey's plane search
    did not keep, as a ceiling a few sweeps graze, has no σ of the survey to set beside)."""
    import crb_bound  # numpy: only with --bound
    with open(os.path.join(sim_dir, "room-truth.json")) as f:
        room = json.load(f)
    with open(os.path.join(sim_dir, "room.toml"), "rb") as f:
        board = crb_bound.Board(tomllib.load(f)["board"])
    while len(infos) < count:
        scene = os.path.join(sim_dir, f"visit-{len(infos) + 1:02}")
        with open(os.path.join(scene, "truth.json")) as f:
            range_m = json.load(f)["range_noise_m"]
        noise = crb_bound.Noise(corner_px=corner_px, hole_m=0.003, range_m=range_m)
        infos.append(crb_bound.visit_survey_information(scene, room, board, noise))
    return crb_bound.survey_summary(sum(infos[:count]), room, planes)


if __name__ == "__main__":
    main()
