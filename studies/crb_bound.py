#!/usr/bin/env python3
"""The Cramér–Rao bound of a simulated calibration scene: the smallest σ any unbiased
calibration can reach from that frame's measurements at their noise (issue 5).

An independent reference for `roomcal calibrate`: it shares no code with the solver. From a
scene's truth.json (board poses, camera, LiDAR mounting) it builds the measurement model
in numpy — checkerboard corners in the image (radtan 5, σ px), the LiDAR's hole centres in
3-D (σ mm), and each LiDAR board's face points against the board plane (range noise times
the beam's incidence cosine, one row per point, summarised on a 12×10 grid) — takes a
central-difference Jacobian at the truth over every parameter the solver estimates
(fx fy cx cy k1 k2 p1 p2 k3, every board pose, LiDAR→camera) and inverts JᵀWJ. The
bound is reached by a maximum-likelihood fit when the model is right; the solver's
reported σ and its actual errors should sit at it.

Which boards the LiDAR places and the corner σ are taken from roomcal's result.json
beside truth.json when there is one (run `roomcal calibrate` first), else every board
with two holes crossed by two scan lines and --corner-sigma.

`--what-if` adds rows with one assumption changed (tangential distortion known, image
features on the board outline and hole rims, several sweeps and frames of a standing
vehicle, a noise-free camera or LiDAR): what would have to change to reach a target.

    roomcal simulate --room config/room.toml --layout band --seed 1 --out /tmp/s1
    roomcal calibrate --room config/room.toml --image /tmp/s1/image.png \\
        --cloud /tmp/s1/cloud.pcd --out /tmp/s1/result.json
    studies/crb_bound.py --room config/room.toml /tmp/s1 [--what-if]

`--surveyed` takes visit folders of `roomcal simulate --visits N` (room-truth.json one level
up) and adds the surveyed room (issue 13): one room→camera pose instead of a pose per board,
the boards (and the room's planes, their LiDAR points read from the visit's cloud.pcd) known
exactly or with the survey's σ as priors, and a standing vehicle (5 frames + 3 sweeps,
10 + 10: one pose, the corner noise over √frames, the LiDAR's over √sweeps). `--survey
SURVEYED.toml` takes every board's and plane's σ from a survey `roomcal survey` wrote (boards
matched to the truth by position, planes by normal) for rows the solver's σ can be held to.

    roomcal simulate --room config/room.toml --visits 2 --seed 1 --out /tmp/v
    studies/crb_bound.py --room config/room.toml --surveyed /tmp/v/visit-02 [--survey S.toml]

`--survey-visits N` bounds the room as a survey of the same room's visits 1..N would know it,
jointly: each survey visit's information about every board and plane, its own 21
parameters (intrinsics, LiDAR→camera, room→camera) marginalised, summed over the visits
(`survey_information`; board 0 fixes the gauge, which changes no figure here), then added to
the new vehicle's. Per-board σ as independent priors (`--survey`) cannot say that the
survey's errors are correlated (its planes turn together against its boards); this can. It
also prints the survey's own bound in the boards' mean frame, for `roomcal survey`'s σ. With
`--survey` too, each joint row is followed by what a calibration holding every board and plane
by the file's own σ (independent priors, as `roomcal calibrate` does) should show when the
survey's errors are those of its joint bound (`per_block_prior_errors`, a sandwich covariance,
not a bound): the price of writing the survey as per-board σ.

    roomcal simulate --room config/room.toml --visits 17 --seed 1 --out /tmp/v
    studies/crb_bound.py --room config/room.toml --surveyed /tmp/v/visit-17 --survey-visits 16

Figures: σ fx as % of fx, σ cx and cy in px, rotation and translation as the worst axis
(what roomcal reports) and, in brackets, the RMS length of the error vector (what an
error against the truth is compared with); overlay: the RMS over the image of where the
result draws a LiDAR point at 3, 10 and 30 m depth against the truth (`overlay_px`; its σ from the
covariance of intrinsics and extrinsic).
"""
import argparse
import json
import math
import os
import sys
import tomllib

import numpy as np

INTRINSICS = 9
P1, P2 = 6, 7


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", help="scene directories (truth.json, optional result.json)")
    ap.add_argument("--room", required=True, help="the room file the scenes were simulated from")
    ap.add_argument("--corner-sigma", type=float, default=0.042, help="corner σ px without a result.json")
    ap.add_argument("--hole-sigma-mm", type=float, default=3.0,
                    help="LiDAR hole-centre σ per axis (mm); issue 4 measured 2.9 mm mean error")
    ap.add_argument("--what-if", action="store_true", help="add rows with one assumption changed")
    ap.add_argument("--result", default="result.json", help="roomcal's result file name in each scene")
    ap.add_argument("--surveyed", action="store_true",
                    help="the scenes are visits of a simulated room: add the surveyed-room rows")
    ap.add_argument("--board-sigma", type=float, nargs=2, default=[0.5, 0.01], metavar=("MM", "DEG"),
                    help="the realistic survey's board σ per axis")
    ap.add_argument("--plane-sigma", type=float, nargs=2, default=[2.0, 0.01], metavar=("MM", "DEG"),
                    help="the realistic survey's plane σ")
    ap.add_argument("--survey", help="a surveyed room file: rows with its σ for every board and plane")
    ap.add_argument("--survey-visits", type=int, metavar="N",
                    help="with --surveyed: rows bounded by a survey of the room's visits 1..N "
                         "(the survey's own joint information, not per-board σ)")
    args = ap.parse_args()
    with open(args.room, "rb") as f:
        board = Board(tomllib.load(f)["board"])
    for scene in args.scenes:
        if args.surveyed:
            report_surveyed(scene, board, args)
        else:
            report(scene, board, args)


class Board:
    """The room's board: corners, holes and face sample points in the board frame."""

    def __init__(self, spec):
        cols, rows = spec["inner_corners"]
        sq = spec["square"]
        ox, oy = spec.get("checker_offset", [0.0, 0.0])
        self.corners = np.array([[ox + (c - (cols - 1) / 2) * sq, oy + (r - (rows - 1) / 2) * sq, 0.0]
                                 for r in range(rows) for c in range(cols)])
        self.holes = np.array([[h[0], h[1], 0.0] for h in spec["holes"]])
        w, h, rad = spec["width"], spec["height"], spec["hole_radius"]
        self.width, self.height = w, h
        self.outline = np.array([[sx * w / 2, sy * h / 2, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
        # The face the plane term uses: inside the outline, clear of the holes (3 cm margins).
        grid = [[x, y, 0.0] for x in np.linspace(-w / 2 + 0.03, w / 2 - 0.03, 12)
                for y in np.linspace(-h / 2 + 0.03, h / 2 - 0.03, 10)]
        self.face = np.array([p for p in grid
                              if min(math.hypot(p[0] - q[0], p[1] - q[1]) for q in self.holes) > rad + 0.03])


def report(scene, board, args):
    with open(os.path.join(scene, "truth.json")) as f:
        truth = json.load(f)
    result = None
    path = os.path.join(scene, args.result)
    if os.path.exists(path):
        with open(path) as f:
            result = json.load(f)
    noise = Noise(
        corner_px=result["quality"]["corner_rms_px"] if result else args.corner_sigma,
        hole_m=args.hole_sigma_mm / 1000.0,
        range_m=truth["range_noise_m"],
    )
    placed = lidar_placed(truth, result)
    print(f"{scene}: corners σ {noise.corner_px:.3f} px, LiDAR boards {sum(placed)}/{len(placed)}, "
          f"holes σ {noise.hole_m * 1000:.1f} mm, range σ {noise.range_m * 100:.1f} cm")
    print(f"  {'':44s} {'fx %':>7s} {'cx px':>6s} {'cy px':>6s} {'rot °':>15s} {'trans mm':>13s}")
    rows = [("Cramér–Rao bound, as measured", {})]
    if args.what_if:
        rows += WHAT_IF
    for name, change in rows:
        s = bound(truth, board, noise.changed(change), placed if "all_lidar" not in change else [True] * len(placed))
        print(f"  {name:44s} {s['fx']:7.3f} {s['cx']:6.2f} {s['cy']:6.2f} "
              f"{s['rot']:6.3f} [{s['rot_rms']:6.3f}] {s['t']:5.1f} [{s['t_rms']:5.1f}]")
    if result:
        u, cam, tcam = result["uncertainty"], result["camera"], truth["camera"]
        print(f"  {'roomcal reported σ':44s} {100 * u['fx'] / cam['fx']:7.3f} {u['cx']:6.2f} {u['cy']:6.2f} "
              f"{u['rotation_deg']:6.3f}{'':10s}{1000 * u['translation_m']:5.1f}")
        if result.get("lidar_to_camera"):
            rot, t = extrinsic_error(result["lidar_to_camera"], truth["lidar_to_camera"])
            print(f"  {'roomcal actual error':44s} {100 * abs(cam['fx'] / tcam['fx'] - 1):7.3f} "
                  f"{abs(cam['cx'] - tcam['cx']):6.2f} {abs(cam['cy'] - tcam['cy']):6.2f} "
                  f"{'':7s}[{rot:6.3f}] {'':5s} [{1000 * t:5.1f}]")


def report_surveyed(scene, board, args):
    """The surveyed-room rows of one visit: free boards, boards surveyed (exact), + board
    faces, + planes (exact), the realistic survey, and standing vehicles."""
    with open(os.path.join(scene, "truth.json")) as f:
        truth = json.load(f)
    with open(os.path.join(os.path.dirname(os.path.abspath(scene)), "room-truth.json")) as f:
        room = json.load(f)
    result = None
    if os.path.exists(os.path.join(scene, args.result)):
        with open(os.path.join(scene, args.result)) as f:
            result = json.load(f)
    # The result's corner RMS is of the 2-D error: per axis it is that over √2.
    noise = Noise(
        corner_px=result["quality"]["corner_rms_px"] / math.sqrt(2) if result else args.corner_sigma,
        hole_m=args.hole_sigma_mm / 1000.0,
        range_m=truth["range_noise_m"],
    )
    placed = lidar_placed(truth, result)
    cloud = read_pcd_xyz(os.path.join(scene, "cloud.pcd"))
    print(f"{scene}: corners σ {noise.corner_px:.3f} px, boards {len(placed)}, LiDAR holes on "
          f"{sum(placed)}, holes σ {noise.hole_m * 1000:.1f} mm, range σ {noise.range_m * 100:.1f} cm")
    print(f"  {'':52s} {'fx %':>6s} {'cx px':>6s} {'cy px':>6s} {'rot ° [RMS]':>14s} {'t mm [RMS]':>12s}  "
          "overlay 3/10/30 m px")
    survey = load_survey(args.survey, room) if args.survey else None
    realistic = {"boards": [tuple(args.board_sigma)] * len(room["boards"]),
                 "planes": [tuple(args.plane_sigma)] * len(room["planes"])}
    rows = [
        ("boards free (today)", None),
        ("board poses surveyed (exact)", dict(faces=False, planes=False)),
        ("+ face points of every board the LiDAR hits", dict(faces=True, planes=False)),
        ("+ floor, walls, ceiling surveyed (exact)", dict(faces=True, planes=True)),
        (f"realistic: boards ±{args.board_sigma[0]} mm/{args.board_sigma[1]}°, "
         f"planes ±{args.plane_sigma[0]} mm/{args.plane_sigma[1]}°", dict(priors=realistic)),
        ("  same, standing (5 frames + 3 sweeps)", dict(priors=realistic, frames=5, sweeps=3)),
        ("  same, standing (10 frames + 10 sweeps)", dict(priors=realistic, frames=10, sweeps=10)),
    ]
    if survey:
        rows += [
            (f"the survey's σ ({os.path.basename(args.survey)})", dict(priors=survey)),
            ("  same, standing (5 frames + 3 sweeps)", dict(priors=survey, frames=5, sweeps=3)),
            ("  same, standing (10 frames + 10 sweeps)", dict(priors=survey, frames=10, sweeps=10)),
        ]
    for name, options in rows:
        s = bound(truth, board, noise, placed) if options is None else \
            room_bound(truth, room, board, noise, placed, cloud, **options)
        print_row(name, s)
    if args.survey_visits:
        room_dir = os.path.dirname(os.path.abspath(scene))
        info = survey_information(room_dir, args.survey_visits, room, board, noise)
        print(f"  a survey of visits 1–{args.survey_visits}, its own bound in the boards' mean frame: "
              + survey_summary_text(survey_summary(info, room)))
        for name, frames, sweeps in (("one frame", 1, 1), ("standing (5 frames + 3 sweeps)", 5, 3),
                                     ("standing (10 frames + 10 sweeps)", 10, 10)):
            s = surveyed_by_visits_bound(truth, room, board, noise, placed, cloud, info, frames, sweeps)
            print_row(f"surveyed from {args.survey_visits} visits (joint), {name}", s)
            if survey:
                # Not a bound: what per-board σ make of the same survey's correlated errors.
                s = per_block_prior_errors(truth, room, board, noise, placed, cloud, info, survey, frames, sweeps)
                print_row(f"  expected with the file's per-board σ as priors", s)
    if result:
        u, cam = result["uncertainty"], result["camera"]
        print(f"  {'roomcal reported σ':52s} {100 * u['fx'] / cam['fx']:6.3f} {u['cx']:6.2f} {u['cy']:6.2f} "
              f"{u['rotation_deg']:6.3f} {1000 * u['translation_m']:5.1f}")


def print_row(name, s):
    print(f"  {name:52s} {s['fx']:6.3f} {s['cx']:6.2f} {s['cy']:6.2f} {s['rot']:6.3f} [{s['rot_rms']:.3f}] "
          f"{s['t']:5.1f} [{s['t_rms']:4.1f}]  " + " / ".join(f"{s[f'overlay_{d}']:.2f}" for d in OVERLAY_DEPTHS_M))


def standing(noise, frames, sweeps):
    """The noise of a standing vehicle: its frames average the corners, its sweeps the
    LiDAR's holes and ranges."""
    noise = noise.changed({"scale_corner": 1 / math.sqrt(frames)})
    noise.hole_m /= math.sqrt(sweeps)
    noise.range_m /= math.sqrt(sweeps)
    return noise


def room_bound(truth, room, board, noise, placed, cloud, faces=True, planes=True, priors=None,
               frames=1, sweeps=1):
    """σ of the main parameters of the surveyed-room model at the truth. `priors` (per room
    board and plane: (σ mm, σ deg), `None` for one the survey lacks) makes boards and planes
    unknowns held by their survey σ; without it they are exact (`planes` says whether the
    planes' points count at all). A standing vehicle's frames and sweeps divide the noise."""
    noise = standing(noise, frames, sweeps)
    model = RoomModel(truth, room, board, noise, placed, cloud, faces, planes or priors is not None, priors)
    keep = list(range(model.size))
    return summary(truth, fisher_covariance(model, keep), INTRINSICS)


# A "free" prior (mm, deg): boards and planes as unknowns the visit alone measures. Weak
# enough to add nothing a measurement does, strong enough to keep JᵀJ invertible.
FREE_PRIOR = (1.0e5, 10.0)


def room_information(truth, room, board, noise, placed, cloud, frames=1, sweeps=1):
    """One visit's Fisher information over [its 21 parameters, every room board (6 each),
    every room plane (3 each, by the room's plane index)]: the boards and planes are
    unknowns only the visit's measurements hold (a plane the sweep misses has none)."""
    noise = standing(noise, frames, sweeps)
    free = {"boards": [FREE_PRIOR] * len(room["boards"]), "planes": [FREE_PRIOR] * len(room["planes"])}
    model = RoomModel(truth, room, board, noise, placed, cloud, True, True, free)
    jac = numeric_jacobian(model.residuals, np.zeros(model.size))
    local = jac.T @ jac
    # Scatter the model's plane slots (only the planes its sweep holds) to the room's.
    nb, npl = len(room["boards"]), len(room["planes"])
    index = list(range(INTRINSICS + 12 + 6 * nb))
    for i, *_ in model.planes:
        index += [INTRINSICS + 12 + 6 * nb + 3 * i + k for k in range(3)]
    size = INTRINSICS + 12 + 6 * nb + 3 * npl
    info = np.zeros((size, size))
    info[np.ix_(index, index)] = local
    return info


def survey_information(room_dir, visits, room, board, noise):
    """The information a survey of a simulated room's `visits` (their numbers; an int n
    means visits 1..n) holds about its boards and planes: each visit's [`room_information`] with the visit's own 21 parameters
    marginalised (Schur complement), summed. Board 0 is the gauge (its rows are kept; the
    caller drops them): a rigid motion of the whole room changes no measurement."""
    numbers = range(1, visits + 1) if isinstance(visits, int) else visits
    return sum(visit_survey_information(os.path.join(room_dir, f"visit-{v:02}"), room, board, noise)
               for v in numbers)


def visit_survey_information(scene, room, board, noise):
    """One survey visit's share of [`survey_information`]: its information about the room's
    boards and planes with its own 21 parameters marginalised."""
    with open(os.path.join(scene, "truth.json")) as f:
        truth = json.load(f)
    cloud = read_pcd_xyz(os.path.join(scene, "cloud.pcd"))
    info = room_information(truth, room, board, noise, lidar_placed(truth, None), cloud)
    own = INTRINSICS + 12
    a, b, c = info[:own, :own], info[:own, own:], info[own:, own:]
    return c - b.T @ np.linalg.solve(a, b)


def surveyed_by_visits_bound(truth, room, board, noise, placed, cloud, survey_info, frames, sweeps):
    """σ of a new vehicle's calibration in a room whose boards and planes are known only as
    the survey's information `survey_info` says, jointly (their errors correlated as the
    survey's are), rather than board by board."""
    info = room_information(truth, room, board, noise, placed, cloud, frames, sweeps)
    own = INTRINSICS + 12
    info[own:, own:] += survey_info
    # Board 0 is the gauge; a plane no sweep saw has no information and no part here.
    keep = [k for k in range(len(info)) if not own <= k < own + 6 and info[k, k] > 0]
    cov = np.zeros_like(info)
    cov[np.ix_(keep, keep)] = np.linalg.inv(info[np.ix_(keep, keep)])
    return summary(truth, cov, INTRINSICS)


def per_block_prior_errors(truth, room, board, noise, placed, cloud, survey_info, priors, frames, sweeps):
    """The errors to expect of a new vehicle's calibration that holds each board and plane
    by its own σ (`priors`, as a `[survey]` table gives them and `roomcal calibrate` uses
    them: independent, isotropic) when the survey's errors are those of its joint
    information `survey_info` (correlated: its planes turn together against its boards).
    Not a bound: the covariance of that estimator, `A⁻¹ (V + P C P) A⁻¹` with `V` the
    vehicle's information, `P` the priors', `C` the survey's covariance (board 0 its gauge:
    a rigid motion of the whole room moves no vehicle parameter) and `A = V + P`."""
    info = room_information(truth, room, board, noise, placed, cloud, frames, sweeps)
    own = INTRINSICS + 12
    weights = []
    for sigma in priors["boards"]:
        mm, deg = sigma if sigma is not None else FREE_PRIOR
        weights += [math.radians(deg) ** -2] * 3 + [(mm / 1000) ** -2] * 3
    for sigma in priors["planes"]:
        mm, deg = sigma if sigma is not None else FREE_PRIOR
        weights += [math.radians(deg) ** -2] * 2 + [(mm / 1000) ** -2]
    prior = np.zeros_like(info)
    prior[own:, own:] = np.diag(weights)
    seen = [k for k in range(6, len(survey_info)) if survey_info[k, k] > 0]
    survey_cov = np.zeros_like(survey_info)
    survey_cov[np.ix_(seen, seen)] = np.linalg.inv(survey_info[np.ix_(seen, seen)])
    spread = np.zeros_like(info)
    spread[own:, own:] = survey_cov
    # Every parameter is held by its prior at least (a plane the survey lacks by the free
    # one), so A is invertible; one the survey did not see has no error from it.
    a_inv = np.linalg.inv(info + prior)
    cov = a_inv @ (info + prior @ spread @ prior) @ a_inv
    return summary(truth, cov, INTRINSICS)


def survey_summary(survey_info, room, planes=None):
    """RMS over the boards of the survey bound's position (worst axis, mm) and rotation
    (worst axis, deg) σ, and over the planes of the normal's σ (worst axis, deg): the room
    planes `planes` (indices) when given, else every plane a sweep holds. Boards and planes
    alike are taken relative to the boards' mean frame, as `roomcal survey` reports them
    (a plane's normal turned with that frame: in board 0's gauge it would carry board 0's
    own turn)."""
    nb = len(room["boards"])
    keep = [k for k in range(6, len(survey_info)) if survey_info[k, k] > 0]
    cov = np.zeros_like(survey_info)
    cov[np.ix_(keep, keep)] = np.linalg.inv(survey_info[np.ix_(keep, keep)])
    boards = [pose(b) for b in room["boards"]]
    normals0 = [np.array(p["normal"], dtype=float) for p in room["planes"]]
    held = [j for j in range(len(normals0)) if survey_info[6 * nb + 3 * j, 6 * nb + 3 * j] > 0
            and (planes is None or j in planes)]

    def in_mean_frame(poses):
        mr, mt = mean_frame(poses)
        return mr, [(mr.T @ r, mr.T @ (t - mt)) for r, t in poses]

    mr0, truth = in_mean_frame(boards)

    def relative(x):
        mr, moved = in_mean_frame([perturb(b, x[6 * i:6 * i + 6]) for i, b in enumerate(boards)])
        out = [np.concatenate([rotation_vector(r @ r0.T), t - t0]) for (r, t), (r0, t0) in zip(moved, truth)]
        for j in held:
            at = 6 * nb + 3 * j
            n = rodrigues(tangent_basis(normals0[j]) @ x[at:at + 2]) @ normals0[j]
            # The small turn of the normal in the mean frame (a vector across it, rad).
            out.append(np.cross(mr0.T @ normals0[j], mr.T @ n))
        return np.concatenate(out)

    jac = numeric_jacobian(relative, np.zeros(len(survey_info)))
    rel = jac @ cov @ jac.T
    d = np.diag(rel)
    rot = [math.degrees(math.sqrt(d[6 * i:6 * i + 3].max())) for i in range(nb)]
    pos = [1000 * math.sqrt(d[6 * i + 3:6 * i + 6].max()) for i in range(nb)]
    normals = [math.degrees(math.sqrt(max(np.linalg.eigvalsh(rel[a:a + 3, a:a + 3]).max(), 0.0)))
               for a in (6 * nb + 3 * k for k in range(len(held)))]
    rms = lambda xs: math.sqrt(sum(x * x for x in xs) / len(xs)) if xs else float("nan")
    return {"pos_mm": rms(pos), "rot_deg": rms(rot), "normal_deg": rms(normals), "planes": len(normals)}


def survey_summary_text(s):
    return (f"boards σ {s['pos_mm']:.2f} mm / {s['rot_deg']:.4f}° RMS of the worst axis, "
            f"plane normals σ {s['normal_deg']:.4f}° ({s['planes']} planes)")


def mean_frame(poses):
    """The boards' mean frame: rotation the projection of the mean rotation matrix onto
    SO(3) (the Karcher mean to first order), origin the mean of the centres."""
    u, _, vt = np.linalg.svd(sum(r for r, _ in poses))
    r = u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt
    return r, sum(t for _, t in poses) / len(poses)


def rotation_vector(r):
    angle = math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2)))
    if angle < 1e-12:
        return np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2
    return angle / (2 * math.sin(angle)) * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])


def load_survey(path, room):
    """σ (mm, deg) per room-truth board and plane from a surveyed room file: each surveyed
    board matched to the truth board nearest it (the file's frame is the nominal LiDAR frame
    at the visits' mean parking spot, the truth's at the nominal spot: centimetres apart,
    boards metres apart), each plane to the truth plane of the nearest normal."""
    with open(path, "rb") as f:
        survey = tomllib.load(f)["survey"]
    boards = [None] * len(room["boards"])
    for b in survey["boards"]:
        k = min(range(len(room["boards"])),
                key=lambda i: np.linalg.norm(np.array(room["boards"][i]["translation"]) - b["translation"]))
        boards[k] = (1000 * b["sigma_m"], b["sigma_deg"])
    planes = [None] * len(room["planes"])
    for p in survey.get("planes", []):
        k = max(range(len(room["planes"])), key=lambda i: np.dot(room["planes"][i]["normal"], p["normal"]))
        planes[k] = (1000 * p["sigma_m"], p["sigma_deg"])
    return {"boards": boards, "planes": planes}


class RoomModel:
    """Whitened residuals of one frame in a surveyed room as a function of a perturbation of
    the truth: [intrinsics (9), LiDAR→camera (6), room→camera (6), then with priors every
    board's pose in the room (6 each) and every plane (δφ across its normal, δd)], poses
    perturbed on the left. Measurements: corners of every board, the LiDAR's hole centres of
    placed boards, face points of every board the LiDAR hits (`faces`), the planes' points
    (`planes`), and the priors."""

    def __init__(self, truth, room, board, noise, placed, cloud, faces, planes, priors):
        self.k0 = camera_vector(truth["camera"])
        self.lidar = pose(truth["lidar_to_camera"])
        self.room_to_camera = pose(truth["room_to_camera"])
        self.boards = [pose(b) for b in room["boards"]]
        self.board, self.noise, self.placed, self.faces = board, noise, placed, faces
        self.priors = priors
        self.points = [b["lidar_points"] for b in truth["boards"]]
        rl, tl = self.lidar
        poses_c = [compose(self.room_to_camera, b) for b in self.boards]
        self.holes_l = [(rl.T @ (transform(p, board.holes) - tl).T).T for p in poses_c]
        self.face_l = [(rl.T @ (transform(p, board.face) - tl).T).T for p in poses_c]
        self.normal_sigma = [noise.range_m * incidence_cosine(p, self.lidar) for p in poses_c]
        self.planes = []
        if planes:
            room_to_lidar = compose(invert(self.lidar), self.room_to_camera)
            for i, p in enumerate(room["planes"]):
                if priors is not None and priors["planes"][i] is None:
                    continue
                summary_points = plane_summary(cloud, room_to_lidar, p, poses_c, self.lidar, board, noise.range_m)
                if summary_points is not None:
                    self.planes.append((i, np.array(p["normal"]), p["offset"], *summary_points))
        self.n_boards = len(self.boards) if priors is not None else 0
        self.n_planes = len(self.planes) if priors is not None else 0
        self.size = INTRINSICS + 12 + 6 * self.n_boards + 3 * self.n_planes

    def residuals(self, x):
        k = self.k0 + x[:INTRINSICS]
        lidar = perturb(self.lidar, x[INTRINSICS:INTRINSICS + 6])
        room = perturb(self.room_to_camera, x[INTRINSICS + 6:INTRINSICS + 12])
        at = INTRINSICS + 12
        out = []
        for i, b0 in enumerate(self.boards):
            b = b0
            if self.n_boards:
                d = x[at + 6 * i:at + 6 * i + 6]
                b = perturb(b0, d)
                sigma = self.priors["boards"][i]
                if sigma is None:
                    sigma = (1e3, 1e3)  # a board the survey lacks: free
                out.append(np.concatenate([d[:3] / math.radians(sigma[1]), d[3:] / (sigma[0] / 1000)]))
            p = compose(room, b)
            out.append(project(k, transform(p, self.board.corners)).ravel() / self.noise.corner_px)
            rl, tl = lidar
            if self.placed[i]:
                holes_c = (rl @ self.holes_l[i].T).T + tl
                out.append((holes_c - transform(p, self.board.holes)).ravel() / self.noise.hole_m)
            if self.points[i] > 0 and (self.faces or self.placed[i]):
                weight = math.sqrt(self.points[i] / len(self.board.face))
                face_c = (rl @ self.face_l[i].T).T + tl
                normal = p[0][:, 2]
                out.append(weight * (face_c @ normal - normal @ p[1]) / self.normal_sigma[i])
        at += 6 * self.n_boards
        camera_to_room = invert(room)
        lidar_to_room = compose(camera_to_room, lidar)
        for j, (i, n0, d0, pts, weights) in enumerate(self.planes):
            n, d = n0, d0
            if self.n_planes:
                delta = x[at + 3 * j:at + 3 * j + 3]
                n = rodrigues(tangent_basis(n0) @ delta[:2]) @ n0
                d = d0 + delta[2]
                sigma = self.priors["planes"][i]
                out.append(np.array([delta[0], delta[1]]) / math.radians(sigma[1]))
                out.append(np.array([delta[2] / (sigma[0] / 1000)]))
            out.append(weights * (transform(lidar_to_room, pts) @ n - d))
        return np.concatenate(out)


def plane_summary(cloud, room_to_lidar, plane, boards_c, lidar, board, range_m):
    """The sweep's points on one truth plane (within 2.5σ of it, off every board), as six
    points with weights that carry their count, mean and scatter: the point-to-plane term's
    information is a function of those alone. Each point's noise along the normal is the
    range noise times the beam's incidence cosine. `None` when fewer than 50 points."""
    if cloud is None or len(cloud) == 0:
        return None
    r, t = room_to_lidar
    n = r @ np.array(plane["normal"])
    d = plane["offset"] + n @ t
    dist = cloud @ n - d
    on = np.abs(dist) < 2.5 * range_m
    rl, tl = lidar
    for p in boards_c:
        # Points on or just in front of a board face are the board's, not the plane's.
        local = (p[0].T @ ((rl @ cloud.T).T + tl - p[1]).T).T
        inside = (np.abs(local[:, 0]) < board.width / 2 + 0.1) & (np.abs(local[:, 1]) < board.height / 2 + 0.1) \
            & (np.abs(local[:, 2]) < 0.3)
        on &= ~inside
    pts = cloud[on]
    if len(pts) < 50:
        return None
    cosine = np.abs(pts @ n) / np.linalg.norm(pts, axis=1)
    w = 1.0 / (range_m * np.maximum(cosine, 0.02)) ** 2
    total = w.sum()
    mean = (w[:, None] * pts).sum(0) / total
    centred = pts - mean
    scatter = (w[:, None, None] * centred[:, :, None] * centred[:, None, :]).sum(0) / total
    values, vectors = np.linalg.eigh(scatter)
    six = [mean + sgn * math.sqrt(3 * max(v, 0.0)) * vectors[:, k] for k in range(3) for sgn in (1, -1)
           for v in [values[k]]]
    return np.array(six), np.full(6, math.sqrt(total / 6))


def tangent_basis(n):
    axis = np.eye(3)[int(np.argmin(np.abs(n)))]
    b1 = np.cross(n, axis)
    b1 /= np.linalg.norm(b1)
    return np.stack([b1, np.cross(n, b1)], 1)


def compose(a, b):
    return a[0] @ b[0], a[0] @ b[1] + a[1]


def invert(a):
    return a[0].T, -a[0].T @ a[1]


def read_pcd_xyz(path):
    """x y z (float32) of a PCD file, ascii or binary (the simulator writes binary)."""
    if not os.path.exists(path):
        return None
    with open(path, "rb") as f:
        raw = f.read()
    header, fields, sizes, types, counts, points = {}, [], [], [], [], 0
    at = 0
    while True:
        end = raw.index(b"\n", at)
        line = raw[at:end].decode().strip()
        at = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key] = values
        if key == "DATA":
            break
    fields, sizes, types = header["FIELDS"], [int(v) for v in header["SIZE"]], header["TYPE"]
    counts = [int(v) for v in header.get("COUNT", ["1"] * len(fields))]
    points = int(header["POINTS"][0])
    if header["DATA"][0] == "ascii":
        rows = np.loadtxt(raw[at:].decode().splitlines(), ndmin=2)
        return rows[:, [fields.index(c) for c in "xyz"]].astype(float)
    if header["DATA"][0] != "binary":
        sys.exit(f"{path}: PCD DATA {header['DATA'][0]} is not read here (ascii or binary)")
    kinds = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 1): "<u1", ("U", 2): "<u2", ("U", 4): "<u4",
             ("I", 1): "<i1", ("I", 2): "<i2", ("I", 4): "<i4"}
    dtype = np.dtype([(name, kinds[(ty, size)], (count,)) for name, ty, size, count
                      in zip(fields, types, sizes, counts)])
    data = np.frombuffer(raw, dtype=dtype, count=points, offset=at)
    return np.stack([data[c][:, 0].astype(float) for c in "xyz"], 1)


WHAT_IF = [
    ("tangential distortion known (p1, p2 fixed)", {"fixed": [P1, P2]}),
    ("+ outline corners and hole rims, 0.05 px", {"outline_px": 0.05, "holes_px": 0.05}),
    ("  ... and p1, p2 fixed", {"outline_px": 0.05, "holes_px": 0.05, "fixed": [P1, P2]}),
    ("all boards placed by the LiDAR", {"all_lidar": True}),
    ("10 sweeps and 10 frames of a standing vehicle", {"scale_lidar": 1 / math.sqrt(10), "scale_corner": 1 / math.sqrt(10)}),
    ("  ... and all boards placed by the LiDAR", {"scale_lidar": 1 / math.sqrt(10), "scale_corner": 1 / math.sqrt(10), "all_lidar": True}),
    ("noise-free camera (corners 1e-4 px)", {"corner_px": 1e-4}),
    ("noise-free LiDAR (1e-5 m)", {"hole_m": 1e-5, "range_m": 1e-5}),
    ("  ... and p1, p2 fixed", {"hole_m": 1e-5, "range_m": 1e-5, "fixed": [P1, P2]}),
]


class Noise:
    def __init__(self, corner_px, hole_m, range_m, outline_px=None, holes_px=None, fixed=()):
        self.corner_px, self.hole_m, self.range_m = corner_px, hole_m, range_m
        self.outline_px, self.holes_px, self.fixed = outline_px, holes_px, list(fixed)

    def changed(self, change):
        n = Noise(self.corner_px, self.hole_m, self.range_m, self.outline_px, self.holes_px, self.fixed)
        for key, value in change.items():
            if key == "scale_lidar":
                n.hole_m *= value
                n.range_m *= value
            elif key == "scale_corner":
                n.corner_px *= value
            elif key != "all_lidar":
                setattr(n, key, value)
        return n


def lidar_placed(truth, result):
    """Per truth board: whether the LiDAR placed it (from result.json when present)."""
    boards = truth["boards"]
    if result is None:
        return [sum(1 for lines in b["hole_scan_lines"] if lines >= 2) >= 2 for b in boards]
    placed = [False] * len(boards)
    for used in result.get("boards", []):
        if not used.get("holes_lidar"):
            continue
        centre = np.mean(np.array(used["corners_px"]), axis=0)
        nearest = min(range(len(boards)),
                      key=lambda i: np.linalg.norm(np.mean(np.array(boards[i]["corners_px"]), axis=0) - centre))
        placed[nearest] = True
    return placed


def bound(truth, board, noise, placed):
    """σ of the main parameters from the inverse Fisher information at the truth."""
    model = Model(truth, board, noise, placed)
    keep = [k for k in range(model.size) if k not in noise.fixed]
    return summary(truth, fisher_covariance(model, keep), model.size - 6)


def fisher_covariance(model, keep):
    """The inverse of JᵀJ (whitened residuals) over the parameters `keep`, zero elsewhere."""
    jac = numeric_jacobian(model.residuals, np.zeros(model.size))
    cov = np.zeros((model.size, model.size))
    cov[np.ix_(keep, keep)] = np.linalg.inv(jac[:, keep].T @ jac[:, keep])
    return cov


def summary(truth, cov, ext):
    """The reported figures from a covariance whose intrinsics are its first 9 parameters
    and whose LiDAR→camera (δω, δt) starts at `ext`."""
    d = np.diag(cov)
    rot, t = d[ext:ext + 3], d[ext + 3:ext + 6]
    out = {
        "fx": 100 * math.sqrt(d[0]) / truth["camera"]["fx"],
        "cx": math.sqrt(d[2]),
        "cy": math.sqrt(d[3]),
        "rot": math.degrees(math.sqrt(rot.max())),
        "rot_rms": math.degrees(math.sqrt(rot.sum())),
        "t": 1000 * math.sqrt(t.max()),
        "t_rms": 1000 * math.sqrt(t.sum()),
    }
    idx = list(range(INTRINSICS)) + list(range(ext, ext + 6))
    sub = cov[np.ix_(idx, idx)]
    for depth in OVERLAY_DEPTHS_M:
        jac = overlay_jacobian(truth, depth)
        out[f"overlay_{depth}"] = math.sqrt(max(np.trace(jac @ sub @ jac.T), 0.0) / (jac.shape[0] / 2))
    return out


# Depths (m, along the camera's axis) at which the overlay is measured.
OVERLAY_DEPTHS_M = (3, 10, 30)
# The overlay's grid over the image (columns, rows).
OVERLAY_GRID = (16, 10)


def overlay_points(camera, depth):
    """Camera-frame points at `depth` on a grid over the image (the undistorted extent)."""
    cols, rows = OVERLAY_GRID
    xs = (np.linspace(0, camera["width"], cols) - camera["cx"]) / camera["fx"]
    ys = (np.linspace(0, camera["height"], rows) - camera["cy"]) / camera["fy"]
    return np.array([[x * depth, y * depth, depth] for y in ys for x in xs])


def overlay_px(camera, lidar_to_camera, true_camera, true_lidar_to_camera, depth):
    """Where `camera` and `lidar_to_camera` draw the LiDAR points that lie at `depth` on the
    truth's grid over the image, against where the truth draws them: RMS over the grid (px)."""
    k_true = camera_vector(true_camera)
    pts_c = overlay_points(true_camera, depth)
    rt, tt = true_lidar_to_camera
    pts_l = (rt.T @ (pts_c - tt).T).T
    r, t = lidar_to_camera
    drawn = project(camera_vector(camera), (r @ pts_l.T).T + t)
    diff = drawn - project(k_true, pts_c)
    return float(np.sqrt(np.mean(np.sum(diff * diff, axis=1))))


def overlay_jacobian(truth, depth):
    """∂(overlay pixels)/∂[intrinsics, LiDAR→camera δω δt] at the truth."""
    cam = truth["camera"]
    k0 = camera_vector(cam)
    pts_c = overlay_points(cam, depth)
    lidar = pose(truth["lidar_to_camera"])
    pts_l = (lidar[0].T @ (pts_c - lidar[1]).T).T

    def drawn(x):
        r, t = perturb(lidar, x[INTRINSICS:])
        return project(k0 + x[:INTRINSICS], (r @ pts_l.T).T + t).ravel()

    return numeric_jacobian(drawn, np.zeros(INTRINSICS + 6))


def camera_vector(cam):
    return np.array([cam["fx"], cam["fy"], cam["cx"], cam["cy"]] + list(cam["distortion"]))


class Model:
    """Whitened residuals of one frame as a function of a perturbation of the truth:
    [intrinsics (9), board poses (6 each: rotation vector, translation), LiDAR→camera (6)],
    the poses perturbed on the left as the solver does."""

    def __init__(self, truth, board, noise, placed):
        cam = truth["camera"]
        self.k0 = np.array([cam["fx"], cam["fy"], cam["cx"], cam["cy"]] + cam["distortion"])
        self.poses = [pose(b["board_to_camera"]) for b in truth["boards"]]
        self.lidar = pose(truth["lidar_to_camera"])
        self.board, self.noise, self.placed = board, noise, placed
        self.points = [b["lidar_points"] for b in truth["boards"]]
        self.size = INTRINSICS + 6 * len(self.poses) + 6
        # The LiDAR's measurements are fixed data: the truth's hole centres and face points
        # in the LiDAR frame, and each face's noise along the normal.
        rl, tl = self.lidar
        self.holes_l = [(rl.T @ (transform(p, board.holes) - tl).T).T for p in self.poses]
        self.face_l = [(rl.T @ (transform(p, board.face) - tl).T).T for p in self.poses]
        self.normal_sigma = [noise.range_m * incidence_cosine(p, self.lidar) for p in self.poses]

    def residuals(self, x):
        k = self.k0 + x[:INTRINSICS]
        rl, tl = perturb(self.lidar, x[-6:])
        out = []
        for i, p0 in enumerate(self.poses):
            p = perturb(p0, x[INTRINSICS + 6 * i:INTRINSICS + 6 * i + 6])
            out.append(project(k, transform(p, self.board.corners)).ravel() / self.noise.corner_px)
            if self.noise.outline_px:
                out.append(project(k, transform(p, self.board.outline)).ravel() / self.noise.outline_px)
            if self.noise.holes_px:
                out.append(project(k, transform(p, self.board.holes)).ravel() / self.noise.holes_px)
            if not self.placed[i]:
                continue
            holes_c = (rl @ self.holes_l[i].T).T + tl
            out.append((holes_c - transform(p, self.board.holes)).ravel() / self.noise.hole_m)
            # Each grid point stands for its share of the board's LiDAR points.
            weight = math.sqrt(max(self.points[i], 1) / len(self.board.face))
            face_c = (rl @ self.face_l[i].T).T + tl
            normal = p[0][:, 2]
            out.append(weight * (face_c @ normal - normal @ p[1]) / self.normal_sigma[i])
        return np.concatenate(out)


def pose(j):
    return np.array(j["rotation"]), np.array(j["translation"])


def transform(p, pts):
    return (p[0] @ pts.T).T + p[1]


def perturb(p, d):
    r = rodrigues(d[:3])
    return r @ p[0], r @ p[1] + d[3:]


def rodrigues(w):
    th = np.linalg.norm(w)
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * kx + (1 - math.cos(th)) * kx @ kx


def project(k, pts):
    """Pixels of camera-frame points through intrinsics `k`: fx fy cx cy and the radtan
    k1 k2 p1 p2 k3, or (8 numbers) the fisheye (equidistant) k1..k4."""
    if len(k) == 8:
        return project_fisheye(k, pts)
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = k
    a, b = pts[:, 0] / pts[:, 2], pts[:, 1] / pts[:, 2]
    r2 = a * a + b * b
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    u = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
    v = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    return np.stack([fx * u + cx, fy * v + cy], 1)


def project_fisheye(k, pts):
    """The fisheye model: θ the angle off the axis, θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)
    along the point's azimuth (OpenCV's fisheye, as roomcal's `fisheye`)."""
    fx, fy, cx, cy, k1, k2, k3, k4 = k
    a, b = pts[:, 0] / pts[:, 2], pts[:, 1] / pts[:, 2]
    r = np.sqrt(a * a + b * b)
    theta = np.arctan(r)
    t2 = theta * theta
    theta_d = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    scale = np.where(r > 1e-12, theta_d / np.maximum(r, 1e-12), 1.0)
    return np.stack([fx * a * scale + cx, fy * b * scale + cy], 1)


def incidence_cosine(board_pose, lidar):
    """|cos| between the LiDAR's beam to the board centre and the board's normal."""
    rl, tl = lidar
    centre_l = rl.T @ (board_pose[1] - tl)
    normal_l = rl.T @ board_pose[0][:, 2]
    return abs(normal_l @ centre_l) / np.linalg.norm(centre_l)


def numeric_jacobian(f, x0, eps=1e-6):
    cols = []
    for k in range(len(x0)):
        e = np.zeros_like(x0)
        e[k] = eps
        cols.append((f(x0 + e) - f(x0 - e)) / (2 * eps))
    return np.stack(cols, 1)


def extrinsic_error(result, truth):
    """Rotation angle (degrees) and translation distance (m) between two extrinsics."""
    r = np.array(result["rotation"]) @ np.array(truth["rotation"]).T
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2))))
    return angle, float(np.linalg.norm(np.array(result["translation"]) - np.array(truth["translation"])))


if __name__ == "__main__":
    sys.exit(main())
