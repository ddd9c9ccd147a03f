#!/usr/bin/env python3
"""What part of a survey moves new vehicles (issue 13): the vehicles of a
`studies/surveyed_study.py` work folder calibrated (one frame, or `--standing FRAMES SWEEPS`)
in its survey as surveyed, with its boards replaced by the simulator's truth, with its planes
replaced, and with both (σ and the joint covariance kept), and the error each leaves: the mean
LiDAR→camera translation error over the vehicles in the LiDAR frame (the error they share,
mm), its spread, and the RMS translation, rotation and overlay errors. Beside them every
surveyed board's and plane's own error against the truth (plane offsets under the vehicle, at
the file's origin).

The truth (`room/room-truth.json`, the simulator's room frame) is put in the survey's frame
(the nominal LiDAR at the visits' mean parking) by the rigid motion that best fits the board
centres (Kabsch), then the one that makes the boards' mean frames agree (as the survey's σ are
given); boards are matched by nearest centre, a board whose surveyed frame is the
truth's half-turned (the symmetric checkerboard) keeps that turn; planes by normal. Planes
are `normal · x = offset` in both files.

    cargo build --release && studies/surveyed_study.py --seed 4 --work DIR
    studies/survey_attribution.py DIR [--vehicles 17 26] [--survey surveyed-2.toml] [--standing 10 10]
"""
import argparse
import json
import math
import os
import sys
import tomllib

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import crb_bound  # noqa: E402  (the boards' mean frame, there)
import surveyed_study as study  # noqa: E402  (one calibrate and one error definition, there)

HALF_TURN = np.diag([-1.0, -1.0, 1.0])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", help="a surveyed_study.py --work folder (surveyed.toml, room/)")
    ap.add_argument("--vehicles", type=int, nargs=2, default=[17, 26], metavar=("FIRST", "LAST"))
    ap.add_argument("--survey", default="surveyed.toml",
                    help="the survey file in WORK (surveyed_study.py --surveys K writes surveyed-K.toml)")
    ap.add_argument("--survey-only", action="store_true",
                    help="the survey's errors and χ² only, no vehicle calibrated")
    ap.add_argument("--standing", type=int, nargs=2, default=[1, 1], metavar=("FRAMES", "SWEEPS"),
                    help="calibrate each vehicle from this many frames and sweeps (calibrate --standing)")
    args = ap.parse_args()
    text = open(os.path.join(args.work, args.survey)).read()
    survey = tomllib.loads(text)["survey"]
    truth = json.load(open(os.path.join(args.work, "room", "room-truth.json")))
    exact = ExactSurvey(survey, truth)
    exact.print_errors()
    exact.print_chi2()
    if args.survey_only:
        return
    head = text[: text.index("[survey]")]
    print("| survey values | mean error x, y, z mm | spread mm | t RMS mm | rot RMS ° | overlay 3/10/30 m px |")
    print("|---|---|---|---|---|---|")
    for name, boards, planes in (("as surveyed", False, False), ("boards exact", True, False),
                                 ("planes exact", False, True), ("both exact", True, True)):
        path = os.path.join(args.work, f"attribution-{int(boards)}{int(planes)}.toml")
        with open(path, "w") as f:
            f.write(head + exact.survey_toml(boards, planes))
        shared, rms = calibrate_vehicles(args.work, path, range(args.vehicles[0], args.vehicles[1] + 1),
                                         *args.standing)
        mean, spread = shared.mean(0), shared.std(0)
        overlay = " / ".join(f"{rms(f'overlay_{d}'):.2f}" for d in crb_bound.OVERLAY_DEPTHS_M)
        print(f"| {name} | {fmt(mean)} | {fmt(spread)} | {rms('t'):.2f} | {rms('rot'):.4f} | {overlay} |",
              flush=True)


def fmt(v):
    return ", ".join(f"{x:.2f}" for x in v)


class ExactSurvey:
    """The survey file's values, and the truth's in the survey's frame."""

    def __init__(self, survey, truth):
        self.survey = survey
        self.boards = [(np.array(b["rotation"]), np.array(b["translation"])) for b in survey["boards"]]
        truth_boards = [(np.array(b["rotation"]), np.array(b["translation"])) for b in truth["boards"]]
        match = [int(np.argmin([np.linalg.norm(t - b[1]) for _, t in truth_boards])) for b in self.boards]
        self.rotation, self.shift = kabsch([truth_boards[m][1] for m in match], [b[1] for b in self.boards])
        self.truth_boards = []
        for (rs, _), m in zip(self.boards, match):
            r, t = truth_boards[m]
            r = self.rotation @ r
            if np.trace(r.T @ rs) < 0:
                r = r @ HALF_TURN
            self.truth_boards.append((r, self.rotation @ t + self.shift))
        # Then in the boards' mean frame, as the survey's σ are: centres alone leave the turn
        # about a line through nearly coplanar centres loose (the side walls showed 0.85 mm
        # the same way in four independent surveys; in the mean frame ±0.4–1.5 mm, two each way).
        (ms, ts), (mt, tt) = crb_bound.mean_frame(self.boards), crb_bound.mean_frame(self.truth_boards)
        g_rotation = ms @ mt.T
        g_shift = ts - g_rotation @ tt
        self.truth_boards = [(g_rotation @ r, g_rotation @ t + g_shift) for r, t in self.truth_boards]
        self.rotation, self.shift = g_rotation @ self.rotation, g_rotation @ self.shift + g_shift
        # Each surveyed plane's truth plane: the one within 1° and 5 cm; a large plane that
        # is none of the room's (a box's face) has no truth and keeps its surveyed values.
        self.truth_planes = []
        for p in survey["planes"]:
            n = np.array(p["normal"])
            candidates = [(self.rotation @ np.array(q["normal"]), q) for q in truth["planes"]]
            candidates = [(m, q["offset"] + m @ self.shift) for m, q in candidates]
            near = [(m, o) for m, o in candidates
                    if np.degrees(np.arccos(min(1.0, m @ n))) < 1.0 and abs(o - p["offset"]) < 0.05]
            self.truth_planes.append(near[0] if near else None)

    def print_errors(self):
        angle = np.degrees(np.arccos(min(1.0, (np.trace(self.rotation) - 1) / 2)))
        print(f"survey frame ← truth frame: {angle:.3f}°, {fmt(self.shift * 1000)} mm\n")
        for i, (b, (r, t)) in enumerate(zip(self.survey["boards"], self.truth_boards)):
            rs, ts = self.boards[i]
            turn = np.degrees(np.arccos(min(1.0, (np.trace(r.T @ rs) - 1) / 2)))
            print(f"board {i}: position off ({fmt((ts - t) * 1000)}) mm (σ {b['sigma_m'] * 1000:.2f}), "
                  f"orientation {turn:.4f}° (σ {b['sigma_deg']:.4f})")
        for p, exact in zip(self.survey["planes"], self.truth_planes):
            if exact is None:
                print(f"{p['name']}: none of the room's planes (a box or stand), kept as surveyed")
                continue
            n, offset = exact
            tilt = np.degrees(np.arccos(min(1.0, n @ np.array(p["normal"]))))
            print(f"{p['name']}: offset off {(p['offset'] - offset) * 1000:+.2f} mm at the origin "
                  f"(σ {p['sigma_m'] * 1000:.2f}), normal {tilt:.4f}° (σ {p['sigma_deg']:.4f})")
        print()

    def chi2(self):
        """The survey's error against its own joint covariance (`survey.covariance`): χ² over
        its modes (eigenvalues above 10⁻⁹ of the largest, the room's null directions left out,
        as the calibration does) and their number, for everything and for the boards and the
        planes alone (their marginal covariances); about the number of modes when the σ are
        honest. Empty without a covariance. A plane with no truth counts as exact."""
        rows = self.survey.get("covariance")
        if not rows:
            return {}
        n = len(rows)
        c = np.zeros((n, n))
        for i, row in enumerate(rows):
            c[i, : i + 1] = row
            c[: i + 1, i] = row
        error, planes_at = [], 6 * len(self.boards)
        for (rs, ts), (r, t) in zip(self.boards, self.truth_boards):
            error += list(crb_bound.rotation_vector(rs @ r.T)) + list(ts - t)
        for p, exact in zip(self.survey["planes"], self.truth_planes):
            if exact is None:
                error += [0.0] * 4
                continue
            normal, offset = exact
            error += list(np.cross(normal, np.array(p["normal"]))) + [p["offset"] - offset]
        error = np.array(error)
        parts = {"everything": slice(0, n), "boards": slice(0, planes_at), "planes": slice(planes_at, n)}
        return {name: chi2_over_modes(c[part, part], error[part]) for name, part in parts.items()}

    def print_chi2(self):
        values = self.chi2()
        if not values:
            print("no survey.covariance: no χ²\n")
        for name, (chi2, modes) in values.items():
            print(f"survey χ² over its covariance, {name}: {chi2:.1f} over {modes} modes "
                  f"(error/σ RMS {math.sqrt(chi2 / max(modes, 1)):.2f})")
        print()

    def survey_toml(self, exact_boards, exact_planes):
        s = self.survey
        out = ["[survey]", f"visits = {s['visits']}", f"frame = {json.dumps(s['frame'])}"]
        if "covariance" in s:
            # The survey's joint covariance is kept with the values (what a calibration holds
            # the room by): without it the vehicles would be held by per-board σ alone.
            out.append("covariance = [" + ", ".join(json.dumps(row) for row in s["covariance"]) + "]")
        out.append("")
        for i, b in enumerate(s["boards"]):
            r, t = self.truth_boards[i] if exact_boards else self.boards[i]
            out += ["[[survey.boards]]", f"rotation = {json.dumps(r.tolist())}",
                    f"translation = {json.dumps(t.tolist())}",
                    f"sigma_m = {b['sigma_m']}", f"sigma_deg = {b['sigma_deg']}", ""]
        for p, exact in zip(s["planes"], self.truth_planes):
            normal, off = p["normal"], p["offset"]
            if exact_planes and exact is not None:
                normal, off = exact[0].tolist(), exact[1]
            out += ["[[survey.planes]]", f"name = {json.dumps(p['name'])}",
                    f"normal = {json.dumps(normal)}", f"offset = {off}",
                    f"sigma_m = {p['sigma_m']}", f"sigma_deg = {p['sigma_deg']}", ""]
        return "\n".join(out)


def chi2_over_modes(c, e):
    """eᵀ C⁺ e over C's eigenvectors above 10⁻⁹ of its largest eigenvalue, and their number."""
    values, vectors = np.linalg.eigh(c)
    keep = values > 1e-9 * values.max()
    a = vectors[:, keep].T @ e
    return float(np.sum(a * a / values[keep])), int(keep.sum())


def kabsch(p, q):
    """The rigid motion (R, t) with q ≈ R p + t, least squares."""
    p, q = np.array(p), np.array(q)
    pc, qc = p.mean(0), q.mean(0)
    u, _, vt = np.linalg.svd((p - pc).T @ (q - qc))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    r = vt.T @ d @ u.T
    return r, qc - r @ pc


def calibrate_vehicles(work, room, visits, frames=1, sweeps=1):
    """Each vehicle's LiDAR-frame translation error (mm), and the RMS over the vehicles of any
    of `surveyed_study.errors`' figures (a function of its name)."""
    shared, errors = [], []
    for v in visits:
        folder = os.path.join(work, "room", f"visit-{v:02}")
        truth = json.load(open(os.path.join(folder, "truth.json")))
        result = study.calibrate(folder, room, frames, sweeps, False, work, 1000 + v)
        errors.append(study.errors(result, truth))
        want, got = truth["lidar_to_camera"], result["lidar_to_camera"]
        delta = np.array(got["translation"]) - np.array(want["translation"])
        shared.append(np.array(want["rotation"]).T @ delta * 1000)
    return np.array(shared), lambda k: float(np.sqrt(np.mean([e[k] ** 2 for e in errors])))


if __name__ == "__main__":
    main()
