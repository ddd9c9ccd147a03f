#!/usr/bin/env python3
"""Surveys and surveyed calibrations in rooms unlike the project's own (issue 13): other
boards (issue 14's 1.4 m board with 0.1 m squares and 0.1 m holes, a square board with its
holes on a 0.6 m grid), other LiDARs (VLP-32C, VLP-16), the band layout, wide and fisheye
lenses. Each room: `roomcal simulate --visits`, `roomcal survey` from its first
`--survey-visits` visits, then every later visit (a new vehicle) calibrated from one frame
in the surveyed room. Renders are `--supersample 1` by default (the renderer integrates the
checker over each sample's footprint: corners within 0.007 px of the truth noise-free,
`tests/it/sim_scene.rs`).

What must hold in every room: the survey is made or refused with a reason, and every
calibration is either refused or within 3σ of the truth in every quantity (fx, cx, cy one
axis; rotation and translation norms against √3 × the worst-axis σ, as
`surveyed_study.py`). A result beyond 3σ is a silently wrong one and is listed.

    cargo build --release && studies/surveyed_rooms.py [--work DIR] [--rooms N] \\
        [--survey-visits 8] [--vehicles 3] [--supersample 1] [--only K ...]

A markdown table on stdout, one row per room; the run's figures in DIR/rooms.json.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import surveyed_study as study  # noqa: E402  (one error definition, there)

ROOM = os.path.join(study.ROOT, "config", "room.toml")

# Boards: the room file's [board] lines that change (the design's board is the file's own).
BOARDS = {
    "design": {},
    "1.4 m": {"width": "1.4", "height": "1.1", "inner_corners": "[8, 6]", "square": "0.1",
              "hole_radius": "0.1", "holes": "[[-0.55, -0.38], [0.55, -0.38], [-0.55, 0.38], [0.55, 0.38]]"},
    "square": {"width": "1.2", "height": "1.2", "inner_corners": "[5, 5]", "square": "0.07",
               "hole_radius": "0.11", "holes": "[[-0.3, -0.3], [0.3, -0.3], [-0.3, 0.3], [0.3, 0.3]]"},
}

# (board, LiDAR, layout, lens): the lens a horizontal field of view, or "fisheye".
ROOMS = [
    ("design", "pandar64", "grid", "70"),
    ("design", "vlp32c", "grid", "70"),
    ("design", "vlp16", "grid", "90"),
    ("design", "pandar64", "band", "90"),
    ("1.4 m", "pandar64", "grid", "70"),
    ("1.4 m", "vlp32c", "band", "90"),
    ("1.4 m", "pandar64", "grid", "fisheye"),
    ("square", "pandar64", "grid", "70"),
    ("design", "pandar64", "grid", "fisheye"),
    ("1.4 m", "vlp16", "grid", "90"),
]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default=None, help="folder for the rooms (default: a new temporary one)")
    ap.add_argument("--rooms", type=int, default=len(ROOMS), help="the first N rooms of the list")
    ap.add_argument("--only", type=int, nargs="*", default=None, help="only these rooms (1-based)")
    ap.add_argument("--survey-visits", type=int, default=8)
    ap.add_argument("--vehicles", type=int, default=3)
    ap.add_argument("--seed", type=int, default=11, help="room k is drawn with seed + k")
    ap.add_argument("--supersample", type=int, default=1)
    args = ap.parse_args()
    work = args.work or tempfile.mkdtemp(prefix="surveyed-rooms-")
    rows = []
    for k, (board, lidar, layout, lens) in enumerate(ROOMS[: args.rooms]):
        if args.only and k + 1 not in args.only:
            continue
        name = f"{board} board, {lidar}, {layout}, {lens if lens == 'fisheye' else lens + '°'}"
        folder = os.path.join(work, f"room-{k + 1:02}")
        row = {"room": name, "seed": args.seed + k, **one_room(folder, board, lidar, layout, lens, args.seed + k, args)}
        rows.append(row)
        print(f"{name}: {summary(row)}", file=sys.stderr, flush=True)
    with open(os.path.join(work, "rooms.json"), "w") as f:
        json.dump(rows, f, indent=1)
    print_table(rows, args)


def one_room(folder, board, lidar, layout, lens, seed, args):
    """Simulate, survey and calibrate one room: its outcome."""
    visits = args.survey_visits + args.vehicles
    if not os.path.exists(os.path.join(folder, "room-truth.json")):
        os.makedirs(folder, exist_ok=True)
        room = os.path.join(folder, "design.toml")
        with open(room, "w") as f:
            f.write(with_board(BOARDS[board]))
        lens_args = ["--camera-model", "fisheye", "--fov", "120"] if lens == "fisheye" else ["--fov", lens]
        done = subprocess.run([study.ROOMCAL, "simulate", "--room", room, "--out", folder, "--visits", str(visits),
                               "--seed", str(seed), "--lidar", lidar, "--layout", layout,
                               "--supersample", str(args.supersample)] + lens_args, capture_output=True, text=True)
        if done.returncode != 0:
            return {"survey": "not simulated", "reason": last_line(done.stderr)}
    surveyed = os.path.join(folder, "surveyed.toml")
    cmd = [study.ROOMCAL, "survey", "--room", os.path.join(folder, "room.toml"), "--out", surveyed]
    for v in range(1, args.survey_visits + 1):
        visit = os.path.join(folder, f"visit-{v:02}")
        cmd += ["--visit", os.path.join(visit, "image.png"), os.path.join(visit, "cloud.pcd")]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        return {"survey": "refused", "reason": last_line(done.stderr)}
    runs = []
    for v in range(args.survey_visits + 1, visits + 1):
        visit = os.path.join(folder, f"visit-{v:02}")
        result = study.calibrate(visit, surveyed, 1, 1, False, folder, v)
        with open(os.path.join(visit, "truth.json")) as f:
            truth = json.load(f)
        run = {"visit": v, "status": result["status"]}
        if result["status"] == "accepted":
            run.update(study.errors(result, truth))
        else:
            run["reason"] = result.get("reason", "")
        runs.append(run)
    return {"survey": "made", "runs": runs}


def last_line(text):
    lines = text.strip().splitlines()
    return lines[-1] if lines else "?"


def with_board(changes):
    """The design room file with the [board] lines in `changes` replaced."""
    lines, in_board = [], False
    with open(ROOM) as f:
        for line in f:
            stripped = line.strip()
            if stripped.startswith("["):
                in_board = stripped == "[board]"
            key = stripped.split("=")[0].strip()
            if in_board and key in changes:
                line = f"{key} = {changes[key]}\n"
            lines.append(line)
    return "".join(lines)


def accepted(row):
    return [r for r in row.get("runs", []) if r["status"] == "accepted"]


def beyond_3_sigma(run):
    return [q for q in study.QUANTITIES if run["z_" + q] > 3]


def rms(values):
    values = list(values)
    return math.sqrt(sum(v * v for v in values) / len(values)) if values else float("nan")


def summary(row):
    if row["survey"] != "made":
        return f"survey {row['survey']}: {row['reason']}"
    ok = accepted(row)
    wrong = sum(1 for r in ok if beyond_3_sigma(r))
    return (f"{len(ok)}/{len(row['runs'])} accepted, rot {rms(r['rot'] for r in ok):.3f}°, "
            f"t {rms(r['t'] for r in ok):.2f} mm, beyond 3σ {wrong}")


def print_table(rows, args):
    print(f"\n{len(rows)} rooms, each surveyed from {args.survey_visits} visits, {args.vehicles} new vehicles "
          "calibrated from one frame each\n")
    print("| room | survey | accepted | fx % | cx / cy px | rot ° | t mm | overlay 3/10/30 m px | worst error/σ | beyond 3σ |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        if row["survey"] != "made":
            print(f"| {row['room']} | {row['survey']}: {row['reason']} | | | | | | | | |")
            continue
        ok = accepted(row)
        # Each distinct reason once (the vehicles of a room are often refused alike).
        refused = sorted({r["reason"] for r in row["runs"] if r["status"] != "accepted"})
        worst = max((r["z_" + q] for r in ok for q in study.QUANTITIES), default=float("nan"))
        wrong = [f"visit {r['visit']}: {', '.join(beyond_3_sigma(r))}" for r in ok if beyond_3_sigma(r)]
        overlay = " / ".join(f"{rms(r[f'overlay_{d}'] for r in ok):.2f}" for d in (3, 10, 30))
        print(f"| {row['room']} | made | {len(ok)}/{len(row['runs'])}{' (' + '; '.join(refused) + ')' if refused else ''} "
              f"| {rms(r['fx'] for r in ok):.3f} | {rms(r['cx'] for r in ok):.2f} / {rms(r['cy'] for r in ok):.2f} "
              f"| {rms(r['rot'] for r in ok):.3f} | {rms(r['t'] for r in ok):.2f} | {overlay} | {worst:.2f} "
              f"| {len(wrong)}{' (' + '; '.join(wrong) + ')' if wrong else ''} |")
    print("\nfigures: RMS over the room's accepted vehicles; error/σ as `surveyed_study.py` (rotation and "
          "translation norms against √3 × the worst-axis σ)")


if __name__ == "__main__":
    sys.exit(main())
