#!/usr/bin/env python3
"""Calibration in a surveyed room against the free-board model, over many new vehicles
(issue 13, item 7): one simulated seven-board Pandar64 room (`--fov` lens, rendered with
`--supersample`), surveyed by `roomcal survey` from its first `--survey-visits` visits; the
next `--vehicles` visits are new vehicles (own intrinsics, distortion, LiDAR mounting and
parking, not in the survey), each calibrated from one frame and as a standing vehicle
(5 frames + 3 sweeps, 10 + 10: `calibrate --standing`), in the surveyed room and with
`--free-boards` on the same images and sweeps.

Per run, against the visit's truth.json: fx error (%), cx and cy (px), rotation (angle of
the LiDAR→camera error, deg) and translation (norm, mm), overlay (`crb_bound.overlay_px`:
where the result draws LiDAR points at 3, 10 and 30 m depth on a grid over the image,
against where the truth draws them, RMS px). Reported σ against the actual error: z = error
/ σ per quantity (fx, cx, cy one axis; rotation and translation norms over three axes
against √3 × the reported worst-axis σ), its RMS over runs and quantities, and the share of
errors within 3σ. Beside the solver's σ, the Cramér–Rao bound of the same vehicle
(`crb_bound.room_bound` with the survey's own σ as priors, the run's corner noise, 3 mm
holes, the sweep's range noise; `crb_bound.bound` for free boards): their ratio per
quantity, median over vehicles. With `--joint-bound`, also over the bound of a room known only
as a survey of the same visits knows it, jointly (`crb_bound.survey_information`: the survey's
correlated errors, not per-board σ), and that bound's RMS over the vehicles; beside it the
errors a calibration that holds the room by per-board σ (as it does) should show against such a
survey (`crb_bound.per_block_prior_errors`).

One survey is one draw of the room's errors, and every vehicle calibrated in it shares that
draw: `--surveys K` makes K independent surveys of the same room (the first from visits
1..N, the others from visits after the vehicles', simulated one frame each in DIR/room-surveys)
and calibrates every vehicle in each; the table pools them, and a second table gives each
survey's own RMS.

    cargo build --release && studies/surveyed_study.py [--vehicles 10] [--survey-visits 16] \\
        [--seed 1] [--work DIR] [--joint-bound] [--surveys K]

Tables in markdown on stdout; every run's figures in DIR/runs.json.
"""
import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import tomllib

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import crb_bound  # noqa: E402  (the bound and the overlay: one definition, there)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ROOMCAL = os.environ.get("ROOMCAL_BIN", os.path.join(ROOT, "target", "release", "roomcal"))
ROOM = os.path.join(ROOT, "config", "room.toml")
MODES = {"one frame": (1, 1), "standing 5+3": (5, 3), "standing 10+10": (10, 10)}
QUANTITIES = ("fx", "cx", "cy", "rot", "t")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=10)
    ap.add_argument("--survey-visits", type=int, default=16)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--boards", type=int, default=7)
    ap.add_argument("--fov", type=float, default=70.0)
    ap.add_argument("--layout", default="grid")
    ap.add_argument("--supersample", type=int, default=1)
    ap.add_argument("--frames", type=int, default=10,
                    help="frames per visit to simulate (the standing rows need 5 and 10)")
    ap.add_argument("--work", default=None)
    ap.add_argument("--no-bound", action="store_true", help="skip the Cramér–Rao bound per vehicle")
    ap.add_argument("--joint-bound", action="store_true",
                    help="also the bound of a room known only from a survey of the same visits, "
                         "jointly (crb_bound.survey_information), for the surveyed runs")
    ap.add_argument("--surveys", type=int, default=1,
                    help="independent surveys of the same room, each from its own --survey-visits "
                         "visits; every vehicle is calibrated against each (the survey's own error "
                         "is shared by every vehicle calibrated against it: one survey is one draw)")
    args = ap.parse_args()
    work = args.work or tempfile.mkdtemp(prefix="surveyed-study-")
    sim = os.path.join(work, "room")
    visits = args.survey_visits + args.vehicles
    frames = args.frames
    simulate(sim, visits, frames, args)
    surveys = [survey(work, sim, 1, range(1, args.survey_visits + 1))]
    if args.surveys > 1:
        # Further surveys from visits after the vehicles' (one frame each is all a survey
        # reads): the same seed draws the same room and the same first frames.
        more = os.path.join(work, "room-surveys")
        simulate_missing(more, visits + 1, visits + (args.surveys - 1) * args.survey_visits, args)
        for j in range(2, args.surveys + 1):
            first = visits + (j - 2) * args.survey_visits + 1
            surveys.append(survey(work, more, j, range(first, first + args.survey_visits)))
    with open(os.path.join(sim, "room.toml"), "rb") as f:
        board = crb_bound.Board(tomllib.load(f)["board"])
    with open(os.path.join(sim, "room-truth.json")) as f:
        room_truth = json.load(f)
    runs = []
    for j, (surveyed, survey_dir, survey_visits) in enumerate(surveys, start=1):
        priors = crb_bound.load_survey(surveyed, room_truth)
        survey_info = None
        for v in range(args.survey_visits + 1, visits + 1):
            folder = os.path.join(sim, f"visit-{v:02}")
            with open(os.path.join(folder, "truth.json")) as f:
                truth = json.load(f)
            # The bounds read the first sweep's points on the room's planes: read it once.
            bounds = not args.no_bound or args.joint_bound
            cloud = crb_bound.read_pcd_xyz(os.path.join(folder, "cloud.pcd")) if bounds else None
            for mode, (n_images, n_clouds) in MODES.items():
                if max(n_images, n_clouds) > frames:
                    continue  # not simulated (--frames)
                for model in ("surveyed", "free"):
                    if model == "free" and j > 1:
                        continue  # free boards ignore the survey: once is enough
                    result = calibrate(folder, surveyed, n_images, n_clouds, model == "free", work, v, j)
                    r = {"survey": j, "visit": v, "mode": mode, "model": model, "status": result["status"],
                         **errors(result, truth)}
                    if not args.no_bound:
                        r["bound"] = vehicle_bound(truth, room_truth, board, cloud, result, priors,
                                                   model, n_images, n_clouds)
                    if args.joint_bound and model == "surveyed":
                        if survey_info is None:
                            # The survey's visits at this first run's corner noise (the same
                            # renders), 3 mm holes, the sweeps' range noise.
                            survey_info = crb_bound.survey_information(
                                survey_dir, survey_visits, room_truth, board, run_noise(result, truth))
                        r["joint"] = joint_bound(truth, room_truth, board, cloud, result, survey_info, n_clouds)
                        r["per_block"] = per_block_errors(truth, room_truth, board, cloud, result, survey_info,
                                                          priors, n_clouds)
                    runs.append(r)
                    print(f"survey {j} visit {v} {mode} {model}: " + ", ".join(
                        f"{q} {r[q]:.4g} (σ {r['sigma_' + q]:.3g}" +
                        (f", bound {r['bound'][q]:.3g})" if "bound" in r else ")") for q in QUANTITIES) +
                        f", overlay {r['overlay_3']:.2f}/{r['overlay_10']:.2f}/{r['overlay_30']:.2f} px",
                        file=sys.stderr, flush=True)
    with open(os.path.join(work, "runs.json"), "w") as f:
        json.dump(runs, f, indent=1)
    print_tables(runs, args)


def simulate(sim, visits, frames, args):
    """The study's room and its visits (kept when already there)."""
    if not os.path.exists(os.path.join(sim, "room-truth.json")):
        run(simulate_command(sim, visits, frames, args))


def simulate_missing(sim, first, last, args):
    """Visits `first..=last` of the study's room, one frame each, rendering only those not
    there yet (`simulate --first-visit`): more surveys cost only their own visits."""
    missing = [v for v in range(first, last + 1)
               if not os.path.exists(os.path.join(sim, f"visit-{v:02}", "truth.json"))]
    while missing:
        # One contiguous run of missing visits per call, at most 99 (simulate's limit).
        start, count = missing[0], 1
        while count < min(len(missing), 99) and missing[count] == start + count:
            count += 1
        run(simulate_command(sim, count, 1, args) + ["--first-visit", str(start)])
        missing = missing[count:]


def simulate_command(sim, visits, frames, args):
    """`roomcal simulate` of the study's room (one place: every folder of a study must hold
    the same room)."""
    return [ROOMCAL, "simulate", "--room", ROOM, "--out", sim, "--visits", str(visits), "--frames", str(frames),
            "--seed", str(args.seed), "--boards", str(args.boards), "--lidar", "pandar64", "--fov", str(args.fov),
            "--layout", args.layout, "--supersample", str(args.supersample)]


def survey(work, sim, j, numbers):
    """Survey `j` of the room, from the visits `numbers` of `sim` (kept when already there):
    (its room file, the folder and numbers of its visits)."""
    surveyed = os.path.join(work, "surveyed.toml" if j == 1 else f"surveyed-{j}.toml")
    if not os.path.exists(surveyed):
        cmd = [ROOMCAL, "survey", "--room", os.path.join(sim, "room.toml"), "--out", surveyed]
        for v in numbers:
            folder = os.path.join(sim, f"visit-{v:02}")
            cmd += ["--visit", os.path.join(folder, "image.png"), os.path.join(folder, "cloud.pcd")]
        run(cmd)
    return surveyed, sim, numbers


def run(cmd):
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"{' '.join(cmd[:3])} … failed ({done.returncode}): {done.stderr.strip()}")


def calibrate(folder, surveyed, n_images, n_clouds, free, work, visit, survey_number=1):
    """`roomcal calibrate` of one visit's first frames against survey `survey_number`; the
    result file's contents (a rejected run's too: exit 3 still writes it)."""
    which = "free" if free else "surveyed" if survey_number == 1 else f"surveyed{survey_number}"
    name = f"result-{visit:02}-{n_images}x{n_clouds}-{which}.json"
    out = os.path.join(work, name)
    image = lambda k: os.path.join(folder, "image.png" if k == 1 else f"image-{k}.png")
    cloud = lambda k: os.path.join(folder, "cloud.pcd" if k == 1 else f"cloud-{k}.pcd")
    cmd = [ROOMCAL, "calibrate", "--room", surveyed, "--out", out, "--quiet"]
    for k in range(1, n_images + 1):
        cmd += ["--image", image(k)]
    for k in range(1, n_clouds + 1):
        cmd += ["--cloud", cloud(k)]
    if n_images > 1 or n_clouds > 1:
        cmd.append("--standing")
    if free:
        cmd.append("--free-boards")
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode not in (0, 3) or not os.path.exists(out):
        sys.exit(f"calibrate {folder} ({n_images}+{n_clouds}) failed ({done.returncode}): {done.stderr.strip()}")
    with open(out) as f:
        return json.load(f)


def errors(result, truth):
    """Errors against the truth and the reported σ (see the module doc)."""
    cam, tcam, u = result["camera"], truth["camera"], result["uncertainty"]
    got = crb_bound.pose(result["lidar_to_camera"])
    want = crb_bound.pose(truth["lidar_to_camera"])
    rot, t = crb_bound.extrinsic_error(result["lidar_to_camera"], truth["lidar_to_camera"])
    out = {
        "fx": 100 * abs(cam["fx"] / tcam["fx"] - 1),
        "cx": abs(cam["cx"] - tcam["cx"]),
        "cy": abs(cam["cy"] - tcam["cy"]),
        "rot": rot,
        "t": 1000 * t,
        "sigma_fx": 100 * u["fx"] / cam["fx"],
        "sigma_cx": u["cx"],
        "sigma_cy": u["cy"],
        "sigma_rot": u["rotation_deg"],
        "sigma_t": 1000 * u["translation_m"],
        "corner_rms_px": result["quality"]["corner_rms_px"],
    }
    for depth in crb_bound.OVERLAY_DEPTHS_M:
        out[f"overlay_{depth}"] = crb_bound.overlay_px(cam, got, tcam, want, depth)
    for q in QUANTITIES:
        # Rotation and translation: a norm over 3 axes against the worst-axis σ.
        scale = math.sqrt(3) if q in ("rot", "t") else 1.0
        out["z_" + q] = out[q] / (scale * out["sigma_" + q]) if out["sigma_" + q] > 0 else float("inf")
    return out


def run_noise(result, truth):
    """The noise model of a run: its corner RMS per axis, 3 mm holes, the sweep's ranges."""
    return crb_bound.Noise(corner_px=result["quality"]["corner_rms_px"] / math.sqrt(2),
                           hole_m=0.003, range_m=truth["range_noise_m"])


def joint_bound(truth, room_truth, board, cloud, result, survey_info, n_clouds):
    """The bound of this run with the room known as the survey's joint information says."""
    s = crb_bound.surveyed_by_visits_bound(truth, room_truth, board, run_noise(result, truth),
                                           crb_bound.lidar_placed(truth, result), cloud, survey_info, 1, n_clouds)
    return {q: s[q] for q in ("fx", "cx", "cy", "rot", "t", "t_rms", "rot_rms")} | \
        {f"overlay_{d}": s[f"overlay_{d}"] for d in crb_bound.OVERLAY_DEPTHS_M}


def per_block_errors(truth, room_truth, board, cloud, result, survey_info, priors, n_clouds):
    """The errors this run should show, its room held by per-board σ against a survey whose
    errors are its joint bound's (`crb_bound.per_block_prior_errors`)."""
    s = crb_bound.per_block_prior_errors(truth, room_truth, board, run_noise(result, truth),
                                         crb_bound.lidar_placed(truth, result), cloud, survey_info, priors, 1,
                                         n_clouds)
    return {q: s[q] for q in ("fx", "cx", "cy", "rot", "t", "t_rms", "rot_rms")} | \
        {f"overlay_{d}": s[f"overlay_{d}"] for d in crb_bound.OVERLAY_DEPTHS_M}


def vehicle_bound(truth, room_truth, board, cloud, result, priors, model, n_images, n_clouds):
    """The Cramér–Rao bound of this vehicle's run (the same measurements and noise model)."""
    placed = crb_bound.lidar_placed(truth, result)
    noise = run_noise(result, truth)
    # A standing vehicle's frames are averaged into one image, whose corner noise the run's
    # corner RMS already is; its sweeps are accumulated: n times the points and hole rims.
    if model == "free":
        s = crb_bound.bound(truth, board, crb_bound.standing(noise, 1, n_clouds), placed)
    else:
        s = crb_bound.room_bound(truth, room_truth, board, noise, placed, cloud, priors=priors,
                                 frames=1, sweeps=n_clouds)
    return {"fx": s["fx"], "cx": s["cx"], "cy": s["cy"], "rot": s["rot"], "t": s["t"],
            **{f"overlay_{d}": s[f"overlay_{d}"] for d in crb_bound.OVERLAY_DEPTHS_M}}


def print_tables(runs, args):
    surveys = f"{args.surveys} independent surveys" if args.surveys > 1 else "room surveyed"
    print(f"\n{args.vehicles} new vehicles, {surveys} from {args.survey_visits} visits "
          f"(seed {args.seed}, {args.boards} boards, {args.fov}° lens, supersample {args.supersample})\n")
    print("| run | model | accepted | fx % | cx px | cy px | rot ° | t mm | overlay 3/10/30 m px |"
          " error/σ RMS | within 3σ | σ/bound (fx cx cy rot t) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for mode in MODES:
        for model in ("surveyed", "free"):
            rs = [r for r in runs if r["mode"] == mode and r["model"] == model]
            if not rs:
                continue
            rms = lambda key: math.sqrt(statistics.fmean(r[key] ** 2 for r in rs))
            sig = lambda key: statistics.fmean(r["sigma_" + key] for r in rs)
            zs = [r["z_" + q] for r in rs for q in QUANTITIES]
            within = sum(z <= 3 for z in zs)
            ratio = ""
            if all("bound" in r for r in rs):
                ratio = " ".join(f"{statistics.median(r['sigma_' + q] / r['bound'][q] for r in rs):.2f}"
                                 for q in QUANTITIES)
            if all("joint" in r for r in rs):
                ratio += " · joint " + " ".join(
                    f"{statistics.median(r['sigma_' + q] / r['joint'][q] for r in rs):.2f}" for q in QUANTITIES)
            print(f"| {mode} | {model} | {sum(r['status'] == 'accepted' for r in rs)}/{len(rs)} "
                  f"| {rms('fx'):.3f} ({sig('fx'):.3f}) | {rms('cx'):.2f} ({sig('cx'):.2f}) "
                  f"| {rms('cy'):.2f} ({sig('cy'):.2f}) | {rms('rot'):.3f} ({sig('rot'):.3f}) "
                  f"| {rms('t'):.2f} ({sig('t'):.2f}) "
                  f"| {rms('overlay_3'):.2f} / {rms('overlay_10'):.2f} / {rms('overlay_30'):.2f} "
                  f"| {math.sqrt(statistics.fmean(z * z for z in zs)):.2f} | {within}/{len(zs)} | {ratio} |")
    print("\nfigures: RMS over the vehicles" + (" and surveys" if args.surveys > 1 else "") +
          " (mean reported σ in brackets); σ/bound: the median over "
          "vehicles of the reported σ over the Cramér–Rao bound of that run (· joint: over the bound "
          "with the room known from the survey's visits jointly)")
    if args.surveys > 1:
        print_per_survey(runs)
    for mode in MODES:
        for key, what in (("joint", "joint bound"),
                          ("per_block", "expected of per-board priors against the survey's joint errors")):
            rs = [r for r in runs if r["mode"] == mode and key in r]
            if rs:
                rms = lambda q: math.sqrt(statistics.fmean(r[key][q] ** 2 for r in rs))
                print(f"\n{what}, {mode}, RMS over the vehicles: fx {rms('fx'):.3f} %, cx {rms('cx'):.2f} px, "
                      f"cy {rms('cy'):.2f} px, rot {rms('rot'):.3f}° (RMS length {rms('rot_rms'):.3f}°), "
                      f"t {rms('t'):.2f} mm (RMS length {rms('t_rms'):.2f} mm), overlay "
                      + " / ".join(f"{rms(f'overlay_{d}'):.2f}" for d in crb_bound.OVERLAY_DEPTHS_M) + " px")


def print_per_survey(runs):
    """The surveyed runs survey by survey: how much of the error one survey's draw shares."""
    print("\n| survey | run | fx % | cx px | cy px | rot ° | t mm | overlay 3/10/30 m px |")
    print("|---|---|---|---|---|---|---|---|")
    for j in sorted({r["survey"] for r in runs}):
        for mode in MODES:
            rs = [r for r in runs if r["survey"] == j and r["mode"] == mode and r["model"] == "surveyed"]
            if rs:
                rms = lambda key: math.sqrt(statistics.fmean(r[key] ** 2 for r in rs))
                print(f"| {j} | {mode} | {rms('fx'):.3f} | {rms('cx'):.2f} | {rms('cy'):.2f} | {rms('rot'):.3f} "
                      f"| {rms('t'):.2f} | {rms('overlay_3'):.2f} / {rms('overlay_10'):.2f} / "
                      f"{rms('overlay_30'):.2f} |")


if __name__ == "__main__":
    main()
