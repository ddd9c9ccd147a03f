#!/usr/bin/env python3
"""Faults a calibration line meets, injected into simulated runs: is a wrong calibration
ever accepted?

Two rooms. The design room with free boards (`config/room.toml`, a Pandar64 whose sweep
is decoded from its packets): one scene per seed. The bundled surveyed room
(`fixtures/surveyed-pandar64/room.toml`, surveyed from visits 1-8 of seed 13): new vehicles
visiting it (visits 10, 11, ... of the same room, `simulate --first-visit`). Each scene is
calibrated clean and with one fault:

- `nominal angles`: the capture decoded without the unit's angle file;
- `other unit's angles`: decoded with another unit's angle file;
- `mounting 5°`: the room file's nominal LiDAR mounting turned 5° (yaw, then pitch);
- `square +1 %`: the room file's checker square 1 % too large (a board printed at 101 %);
- `fx prior 1 %`: the room file's nominal fx 1 % off;
- `moved board` (surveyed room): one board 5 cm away from where the survey has it.

Every accepted run is compared with the truth as `surveyed_study.errors` does (fx, cx, cy
on their axis; rotation and translation norms against √3 × the worst-axis σ). What must
hold: no accepted run beyond 3σ in any quantity; the clean runs accepted.

    cargo build --release && studies/fault_injection.py [--seeds 25] [--work DIR]

A markdown table on stdout; every run's figures in DIR/faults.json.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import tomllib

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import surveyed_study as study  # noqa: E402  (one error definition, there)

ROOMCAL = study.ROOMCAL
DESIGN = os.path.join(study.ROOT, "config", "room.toml")
SURVEYED = os.path.join(study.ROOT, "fixtures", "surveyed-pandar64", "room.toml")
SURVEY_SEED, FIRST_NEW_VISIT = 13, 10


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=25, help="scenes per room")
    ap.add_argument("--work", default=None, help="folder for the scenes (default: a new temporary one)")
    args = ap.parse_args()
    work = args.work or tempfile.mkdtemp(prefix="roomcal-faults-")
    os.makedirs(work, exist_ok=True)
    runs = []
    scenes = free_scenes(work, args.seeds) + surveyed_scenes(work, args.seeds)
    for room, room_file, scene, other in scenes:
        for fault, room_text, angles in faults(room, room_file, scene, other):
            edited = os.path.join(scene, "room-" + fault.replace(" ", "-").replace("%", "pc").replace("'", "") + ".toml")
            with open(edited, "w") as f:
                f.write(room_text)
            run = calibrate(scene, edited, angles)
            run.update(room=room, fault=fault, scene=os.path.basename(scene))
            runs.append(run)
    with open(os.path.join(work, "faults.json"), "w") as f:
        json.dump(runs, f, indent=1)
    print_table(runs, args, work)


def free_scenes(work, seeds):
    """The design room, one scene per seed: (room, its file, the scene, another unit's angles)."""
    out = []
    for seed in range(1, seeds + 1):
        scene = os.path.join(work, f"free-{seed:03}")
        if not os.path.exists(os.path.join(scene, "truth.json")):
            run([ROOMCAL, "simulate", "--room", DESIGN, "--out", scene, "--seed", str(seed),
                 "--supersample", "1", "--capture"])
        out.append(scene)
    return [("free boards", DESIGN, s, os.path.join(out[(i + 1) % len(out)], "angles.csv"))
            for i, s in enumerate(out)]


def surveyed_scenes(work, count):
    """New vehicles in the bundled surveyed room."""
    sim = os.path.join(work, "surveyed")
    last = FIRST_NEW_VISIT + count - 1
    if not os.path.exists(os.path.join(sim, f"visit-{last:02}", "truth.json")):
        run([ROOMCAL, "simulate", "--room", DESIGN, "--out", sim, "--visits", str(count), "--first-visit",
             str(FIRST_NEW_VISIT), "--seed", str(SURVEY_SEED), "--supersample", "1", "--capture"])
    visits = [os.path.join(sim, f"visit-{v:02}") for v in range(FIRST_NEW_VISIT, last + 1)]
    return [("surveyed", SURVEYED, v, os.path.join(visits[(i + 1) % len(visits)], "angles.csv"))
            for i, v in enumerate(visits)]


def faults(room, room_file, scene, other_angles):
    """(fault, room file text, angle file or None) for one scene."""
    with open(room_file) as f:
        text = f.read()
    own = os.path.join(scene, "angles.csv")
    parsed = tomllib.loads(text)
    rotation = parsed["lidar"]["rotation"]
    square = parsed["board"]["square"]
    fx = truth_fx(scene)
    out = [
        ("clean", text, own),
        ("nominal angles", text, None),
        ("other unit's angles", text, other_angles),
        ("mounting 5° yaw", replace_key(text, "lidar", "rotation", matrix(turned(rotation, 2, 5.0))), own),
        ("mounting 5° pitch", replace_key(text, "lidar", "rotation", matrix(turned(rotation, 1, 5.0))), own),
        ("square +1 %", replace_key(text, "board", "square", repr(square * 1.01)), own),
        ("fx prior 1 %", with_key(text, "camera", "fx", repr(fx * 1.01)), own),
    ]
    if room == "surveyed":
        out.append(("moved board", moved_board(text, 2, 0.05), own))
    return out


def calibrate(scene, room_file, angles):
    out = os.path.join(scene, "result.json")
    cmd = [ROOMCAL, "calibrate", "--room", room_file, "--image", os.path.join(scene, "image.png"),
           "--cloud", os.path.join(scene, "cloud.pcap"), "--out", out, "--quiet"]
    if angles:
        cmd += ["--lidar-calibration", angles]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode not in (0, 3):
        return {"status": "error", "reason": done.stderr.strip().splitlines()[-1:]}
    with open(out) as f:
        result = json.load(f)
    with open(os.path.join(scene, "truth.json")) as f:
        truth = json.load(f)
    row = {"status": result["status"]}
    if result["status"] == "accepted":
        row.update(study.errors(result, truth))
    else:
        row["reason"] = result.get("reason", "")
    return row


def truth_fx(scene):
    with open(os.path.join(scene, "truth.json")) as f:
        return json.load(f)["camera"]["fx"]


def turned(rotation, axis, degrees):
    """`rotation` (LiDAR → camera) followed by a turn of the LiDAR about its own `axis`."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    turn = {2: [[c, -s, 0], [s, c, 0], [0, 0, 1]], 1: [[c, 0, s], [0, 1, 0], [-s, 0, c]]}[axis]
    return [[sum(rotation[i][k] * turn[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def matrix(m):
    return "[" + ", ".join("[" + ", ".join(repr(v) for v in row) + "]" for row in m) + "]"


def replace_key(text, section, key, value):
    """`text` with `key` of `[section]` set to `value` (the old value may span lines)."""
    lines, out, i, current = text.splitlines(keepends=True), [], 0, None
    while i < len(lines):
        line, stripped = lines[i], lines[i].strip()
        if stripped.startswith("["):
            current = stripped
        if current == f"[{section}]" and stripped.split("=")[0].strip() == key and "=" in stripped:
            depth = line.count("[") - line.count("]")
            while depth > 0:
                i += 1
                depth += lines[i].count("[") - lines[i].count("]")
            out.append(f"{key} = {value}\n")
        else:
            out.append(line)
        i += 1
    return "".join(out)


def with_key(text, section, key, value):
    """`text` with `key = value` in `[section]` (added after its header when absent)."""
    if key in tomllib.loads(text).get(section, {}):
        return replace_key(text, section, key, value)
    return text.replace(f"[{section}]\n", f"[{section}]\n{key} = {value}\n", 1)


def moved_board(text, board, metres):
    """The survey's board `board` moved `metres` along the room's x (the survey is stale)."""
    lines, seen, moving = text.splitlines(keepends=True), -1, False
    for i, line in enumerate(lines):
        stripped = line.strip()
        if stripped == "[[survey.boards]]":
            seen += 1
        if seen == board and stripped == "translation = [":
            moving = True
            continue
        if moving:
            value = float(stripped.rstrip(","))
            lines[i] = f"    {value + metres!r},\n"
            break
    return "".join(lines)


def run(cmd):
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{' '.join(cmd[:3])} … failed ({done.returncode}): {done.stderr.strip()}")


def print_table(runs, args, work):
    print(f"\n{args.seeds} scenes per room; figures in {work}/faults.json\n")
    print("| room | fault | runs | accepted | accepted beyond 3σ | worst accepted z | most common refusal |")
    print("|---|---|---|---|---|---|---|")
    keys = []
    for r in runs:
        if (r["room"], r["fault"]) not in keys:
            keys.append((r["room"], r["fault"]))
    for room, fault in keys:
        rows = [r for r in runs if r["room"] == room and r["fault"] == fault]
        ok = [r for r in rows if r["status"] == "accepted"]
        z = [max(r["z_" + q] for q in study.QUANTITIES) for r in ok]
        beyond = sum(1 for v in z if v > 3)
        reasons = {}
        for r in rows:
            if r["status"] != "accepted":
                key = str(r.get("reason", ""))[:70]
                reasons[key] = reasons.get(key, 0) + 1
        common = max(reasons.items(), key=lambda kv: kv[1]) if reasons else ("", 0)
        worst = f"{max(z):.1f}" if z else "-"
        refusal = f"{common[1]}× {common[0]}" if common[1] else "-"
        print(f"| {room} | {fault} | {len(rows)} | {len(ok)} | {beyond} | {worst} | {refusal} |")
    bad = [r for r in runs if r["status"] == "accepted" and any(r["z_" + q] > 3 for q in study.QUANTITIES)]
    if bad:
        print("\nAccepted beyond 3σ:")
        for r in bad:
            zs = ", ".join(f"{q} {r['z_' + q]:.1f}" for q in study.QUANTITIES)
            print(f"- {r['room']} / {r['fault']} / {r['scene']}: {zs}")


if __name__ == "__main__":
    main()
