//! Mask search (the paper's idea): the board model (outline minus holes, [`Mask`]) is slid
//! over the projected points in (x, y, yaw); the score counts returns on solid board and gap
//! points in holes, and penalises returns in holes, gap points on solid board, see-through
//! points on solid board and anything outside the outline.
//!
//! The coarse grid keeps up to four distinct optima (a board whose lines cross one row of
//! holes only has rivals a hole spacing apart); each is refined on the medium grid and
//! scored on every point there, those near the best are refined on the fine grid and
//! scored again, and the best is kept only when it leads every distinct rival by a margin
//! ([`margin`], [`same_holes`]). When coplanar clutter beside the board (a neighbouring
//! board's edge) widens the points beyond the outline, the coarse centres span where the
//! board lies within them.
//!
//! Each grid scores only the points within its window's reach of an edge, the points
//! turned once per yaw; per yaw the centres lie on a lattice along the turned board's axes,
//! so a point's mask column and row are found once and each centre costs one table lookup
//! ([`Mask::score_lattice`]). The final estimate is the centroid of the fine grid's top
//! plateau (every pose the points cannot tell from the best), its spread the pose
//! covariance. A plateau wider than the window walks on at a coarser step.

use core::f64::consts::PI;

use crate::target::BoardSpec;

use super::mask::{Evidence, Mask, MAX_LATTICE};
use super::projection::Projection;

/// Translation step of the coarse search (m).
const COARSE_STEP: f64 = 0.02;
/// Returns the coarse search scores (of a subsample); more would only cost time.
const COARSE_POINTS: usize = 400;
/// Most points the medium grid (and each step of a walk) scores.
const MEDIUM_POINTS: usize = 600;
/// Most distinct coarse optima refined and compared.
pub(super) const CANDIDATES: usize = 4;
/// Two poses whose centres lie this far apart (or whose yaws differ by [`DISTINCT_YAW`])
/// are distinct optima (m).
const DISTINCT_M: f64 = 0.05;
const DISTINCT_YAW: f64 = 5.0 * PI / 180.0;
/// Least score lead of the best pose over a distinct rival (see [`margin`]).
const AMBIGUITY_MARGIN: i64 = 8;
/// The coarse yaws tried about an expected board's (degrees either side): its yaw in the
/// plane is off by the mounting's error about the board's normal (a degree or two for a
/// nominal mounting; a LiDAR mounted 10° off is still found), and the coarse step is 4°.
pub const EXPECTED_YAW_DEG: f64 = 14.0;

/// Result of a grid search: pose (x, y, yaw) in the plane frame, its covariance
/// (row-major 3×3) and whether the plateau reached the window's edge.
#[derive(Clone, Copy, Debug)]
pub(super) struct Fit {
    pub(super) pose: [f64; 3],
    pub(super) cov: [f64; 9],
    pub(super) at_window_edge: bool,
}

impl Fit {
    /// A pose without a spread of its own (a coarse optimum's).
    pub(super) fn rough(pose: [f64; 3]) -> Fit {
        Fit { pose, cov: [0.0; 9], at_window_edge: false }
    }
}

/// Scored poses (x, y, yaw), best first.
pub(super) type Candidates = heapless::Vec<(i64, [f64; 3]), CANDIDATES>;

/// The search workspace: the masks, the yaws tried and the evidence as each grid samples
/// and turns it, reused from plane to plane.
#[derive(Debug)]
pub(super) struct Search {
    mask: Mask,
    coarse_mask: Mask,
    yaws: Vec<f64>,
    sample: Vec<[f64; 2]>,
    gap_sample: Vec<[f64; 2]>,
    through_sample: Vec<[f64; 2]>,
    turned: Vec<[f64; 2]>,
    turned_gaps: Vec<[f64; 2]>,
    turned_through: Vec<[f64; 2]>,
    lattice: Vec<i32>,
}

impl Search {
    /// The search for boards of `spec`: yaws ±40° about the "y down" convention, and the
    /// same turned by 180° when the hole pattern is not `symmetric` under that turn.
    pub(super) fn new(spec: &BoardSpec, symmetric: bool) -> Self {
        let mut yaws = Vec::new();
        let turns: &[f64] = if symmetric { &[0.0] } else { &[0.0, 180.0] };
        for &turn in turns {
            for k in -10..=10 {
                yaws.push((turn + 4.0 * k as f64).to_radians());
            }
        }
        Search {
            mask: Mask::new(spec, 0.002),
            coarse_mask: Mask::new(spec, 0.01),
            yaws,
            sample: Vec::new(),
            gap_sample: Vec::new(),
            through_sample: Vec::new(),
            turned: Vec::new(),
            turned_gaps: Vec::new(),
            turned_through: Vec::new(),
            lattice: Vec::new(),
        }
    }

    /// Coarse mask search over (x, y, yaw) on a subsample: 4° steps in yaw, 4 cm then
    /// 2 cm in translation. Yaws ±40° about the "y down" convention (and the same turned
    /// by 180° for an asymmetric hole pattern) are tried. Returns the best distinct optima
    /// (best first): a board whose holes leave its pose weak (lines only across one row of
    /// holes, the outline's top and bottom unseen) has several, one a hole spacing from
    /// another, and the subsample cannot be trusted to rank them. With `expected` (the
    /// yaw a board is expected at, [`super::HoleDetector::detect_expected`]) only the yaws within
    /// [`EXPECTED_YAW_DEG`] of it, either way round, are tried.
    #[inline(never)]
    pub(super) fn coarse(
        &mut self,
        ev: &Projection,
        spec: &BoardSpec,
        expected: Option<f64>,
    ) -> Candidates {
        let stride = (ev.flat.len() / COARSE_POINTS).max(1);
        let (hw, hh) = (spec.width / 2.0, spec.height / 2.0);
        let cell = self.coarse_mask.step;
        let mut found = Candidates::new();
        for k in 0..self.yaws.len() {
            let yaw = self.yaws[k];
            if expected.is_some_and(|e| !near_yaw(yaw, e)) {
                continue;
            }
            // The points in board-aligned axes (coarse cells); the board centre is then a
            // plain shift.
            self.sample.clear();
            self.sample.extend(ev.flat.iter().step_by(stride));
            self.gap_sample.clear();
            self.gap_sample.extend(ev.gaps.iter().step_by(stride));
            self.through_sample.clear();
            self.through_sample.extend(ev.through.iter().step_by(stride));
            self.coarse_mask.turn(&self.sample, yaw, &mut self.turned);
            self.coarse_mask.turn(&self.gap_sample, yaw, &mut self.turned_gaps);
            self.coarse_mask.turn(&self.through_sample, yaw, &mut self.turned_through);
            let mut lo = [f64::MAX; 2];
            let mut hi = [f64::MIN; 2];
            for p in &self.turned {
                lo = [lo[0].min(p[0] * cell), lo[1].min(p[1] * cell)];
                hi = [hi[0].max(p[0] * cell), hi[1].max(p[1] * cell)];
            }
            // Board centres for which the board covers the points or, when the points
            // span more than the board (coplanar clutter beside it: a neighbouring board,
            // a wall), for which the board lies within them.
            let range = |lo: f64, hi: f64, half: f64| {
                let (a, b) = (hi - half, lo + half);
                (a.min(b) - 0.04, a.max(b) + 0.04)
            };
            let (ur, vr) = (range(lo[0], hi[0], hw), range(lo[1], hi[1], hh));
            // Centres at twice the coarse step (at most ~100 per yaw: a wide window, little
            // of the board seen, takes larger steps), then the best
            // ones' neighbours at the coarse step; the medium grid recentres from there.
            let area = (ur.1 - ur.0 + COARSE_STEP) * (vr.1 - vr.0 + COARSE_STEP);
            let step = (area / 100.0).sqrt().clamp(2.0 * COARSE_STEP, 4.0 * COARSE_STEP);
            // (A window wider than a lattice holds, never a board's, takes larger steps still.)
            let widest = (ur.1 - ur.0).max(vr.1 - vr.0);
            let step = step.max(widest / (MAX_LATTICE - 1) as f64);
            let n = [((ur.1 - ur.0) / step) as usize + 1, ((vr.1 - vr.0) / step) as usize + 1];
            let first = [ur.0 / cell, vr.0 / cell];
            self.lattice.resize(n[0] * n[1], 0);
            let e = Evidence {
                returns: &self.turned,
                gaps: &self.turned_gaps,
                through: &self.turned_through,
            };
            self.coarse_mask.score_lattice(e, first, step / cell, n, &mut self.lattice);
            let mut here = Candidates::new();
            for i in 0..n[0] {
                for j in 0..n[1] {
                    let (u, v) = (ur.0 + i as f64 * step, vr.0 + j as f64 * step);
                    let score = self.lattice[j * n[0] + i] as i64;
                    keep_best(&mut here, score, [u, v, yaw], 2.0 * step);
                }
            }
            let half = (step / COARSE_STEP / 2.0).ceil() as usize;
            let side = 2 * half + 1;
            for &(_, [u0, v0, _]) in here.iter().take(2) {
                let (u1, v1) = (u0 - half as f64 * COARSE_STEP, v0 - half as f64 * COARSE_STEP);
                let e = self.turned_evidence();
                let mut local_scores = [0i32; 81];
                self.coarse_mask.score_lattice(
                    e,
                    [u1 / cell, v1 / cell],
                    COARSE_STEP / cell,
                    [side, side],
                    &mut local_scores,
                );
                let mut local = (i64::MIN, [0.0; 3]);
                for a in 0..side {
                    for b in 0..side {
                        let score = local_scores[b * side + a] as i64;
                        if score > local.0 {
                            let (u, v) = (u1 + a as f64 * COARSE_STEP, v1 + b as f64 * COARSE_STEP);
                            // The centre back in the plane frame.
                            let (s, c) = yaw.sin_cos();
                            local = (score, [c * u - s * v, s * u + c * v, yaw]);
                        }
                    }
                }
                keep_best(&mut found, local.0, local.1, DISTINCT_M);
            }
        }
        found
    }

    /// The evidence turned by [`Mask::turn`] (`turned`, `turned_gaps`, `turned_through`).
    fn turned_evidence(&self) -> Evidence<'_> {
        Evidence { returns: &self.turned, gaps: &self.turned_gaps, through: &self.turned_through }
    }

    /// The mask score of every return and gap point at `pose`: what the candidates'
    /// poses are compared by.
    pub(super) fn full_score(&mut self, ev: &Projection, pose: [f64; 3]) -> i64 {
        self.mask.turn(&ev.flat, pose[2], &mut self.turned);
        self.mask.turn(&ev.gaps, pose[2], &mut self.turned_gaps);
        self.mask.turn(&ev.through, pose[2], &mut self.turned_through);
        self.mask.score_turned(self.turned_evidence(), [pose[0], pose[1]], pose[2])
    }

    /// The medium grid around the coarse pose (5 mm, 0.5° cells, on a subsample): where
    /// the plateau lies. Only points near an edge of the model can change their mask value
    /// within a window; the rest add a constant, so each grid scores only the points
    /// within its window's reach of an edge.
    #[inline(never)]
    pub(super) fn medium(&mut self, ev: &Projection, spec: &BoardSpec, coarse: [f64; 3]) -> Fit {
        let medium_step = (0.005, 0.5f64.to_radians());
        self.near_edges(ev, spec, coarse, 0.07);
        // The medium grid only finds the plateau (5 mm, 0.5° cells): a subsample will do.
        self.thin_sample(MEDIUM_POINTS);
        let mut medium = self.grid(coarse, medium_step, 4);
        for _ in 0..2 {
            if !medium.at_window_edge {
                break;
            }
            medium = self.grid(medium.pose, medium_step, 4);
        }
        medium
    }

    /// The fine grid around the medium pose (every point near an edge), walked on at a
    /// coarser step while its plateau reaches the window's edge.
    #[inline(never)]
    pub(super) fn fine(&mut self, ev: &Projection, spec: &BoardSpec, medium: [f64; 3]) -> Fit {
        // The fine window reaches 9 mm and 0.36° (5 mm at the board's corners).
        self.near_edges(ev, spec, medium, 0.02);
        let fine = self.grid(medium, (0.0015, 0.06f64.to_radians()), 6);
        if !fine.at_window_edge {
            return fine;
        }
        // A plateau wider than the fine window (or a coarse yaw a few degrees off, which
        // an occluded board can cause): a wide window at a coarser step, walked on over a
        // subsample (each step of the walk only recentres), then scored once on every
        // point near an edge for the plateau and its spread.
        let walk_step = (0.004, 0.3f64.to_radians());
        let mut pose = fine.pose;
        for _ in 0..6 {
            self.near_edges(ev, spec, pose, 0.07);
            self.thin_sample(MEDIUM_POINTS);
            let walked = self.grid(pose, walk_step, 8);
            pose = walked.pose;
            if !walked.at_window_edge {
                break;
            }
        }
        self.near_edges(ev, spec, pose, 0.07);
        self.grid(pose, walk_step, 8)
    }

    /// Keeps every k-th of `sample`, `gap_sample` and `through_sample` so that about
    /// `budget` points of evidence remain.
    fn thin_sample(&mut self, budget: usize) {
        let evidence = self.sample.len() + self.gap_sample.len() + self.through_sample.len();
        let stride = evidence / budget + 1;
        if stride > 1 {
            keep_every(&mut self.sample, stride);
            keep_every(&mut self.gap_sample, stride);
            keep_every(&mut self.through_sample, stride);
        }
    }

    /// Returns and gap points within `near` of the model's outline or a hole's edge at
    /// `pose`, into `sample`, `gap_sample` and `through_sample`.
    fn near_edges(&mut self, ev: &Projection, spec: &BoardSpec, pose: [f64; 3], near: f64) {
        let (hw, hh, r) = (spec.width / 2.0, spec.height / 2.0, spec.hole_radius);
        let close = |p: &[f64; 2]| {
            let (x, y) = to_board(pose, p);
            let outline = (x.abs() - hw).abs() < near || (y.abs() - hh).abs() < near;
            outline || spec.holes.iter().any(|h| ((x - h[0]).hypot(y - h[1]) - r).abs() < near)
        };
        self.sample.clear();
        self.sample.extend(ev.flat.iter().filter(|p| close(p)));
        self.gap_sample.clear();
        self.gap_sample.extend(ev.gaps.iter().filter(|p| close(p)));
        self.through_sample.clear();
        self.through_sample.extend(ev.through.iter().filter(|p| close(p)));
    }

    /// Scores the (2k+1)³ grid around `centre`, `step` = (translation in fine-mask cells,
    /// yaw in radians); returns the plateau centroid and spread. Per yaw the centres lie on
    /// a lattice along the turned board's axes (whole cells apart: [`Mask::score_lattice`]).
    #[inline(never)]
    fn grid(&mut self, centre: [f64; 3], (step, yaw_step): (f64, f64), k: i32) -> Fit {
        let span = (2 * k + 1) as usize;
        let mut scores = [0i64; 17 * 17 * 17];
        let mut turns = [(0.0, 0.0); 17];
        let mut max = i64::MIN;
        let off = |i: usize| (i as i32 - k) as f64;
        for g in 0..span {
            // Per yaw the points are turned once; each centre is then a plain shift.
            let yaw = centre[2] + off(g) * yaw_step;
            turns[g] = yaw.sin_cos();
            self.mask.turn(&self.sample, yaw, &mut self.turned);
            self.mask.turn(&self.gap_sample, yaw, &mut self.turned_gaps);
            self.mask.turn(&self.through_sample, yaw, &mut self.turned_through);
            let u = self.mask.turned_centre([centre[0], centre[1]], yaw);
            let reach = k as f64 * step / self.mask.step;
            let first = [u[0] - reach, u[1] - reach];
            let mut block = [0i32; 17 * 17];
            let cells = step / self.mask.step;
            self.mask.score_lattice(self.turned_evidence(), first, cells, [span, span], &mut block);
            for a in 0..span {
                for b in 0..span {
                    let sc = block[b * span + a] as i64;
                    scores[(a * span + b) * span + g] = sc;
                    max = max.max(sc);
                }
            }
        }
        // Weights fall by e per penalty unit below the best: the plateau dominates.
        let mut w_sum = 0.0;
        let mut mean = [0.0; 3];
        let mut second = [0.0; 6];
        let mut edge = false;
        for a in 0..span {
            for b in 0..span {
                for g in 0..span {
                    let sc = scores[(a * span + b) * span + g];
                    let w = ((sc - max) as f64).exp();
                    if w < 1e-6 {
                        continue;
                    }
                    // The centre's offset along the turned axes, back in the plane frame.
                    let (s, c) = turns[g];
                    let (du, dv) = (off(a) * step, off(b) * step);
                    let x = [c * du - s * dv, s * du + c * dv, off(g) * yaw_step];
                    if w > 0.1 && [a, b, g].iter().any(|&i| i == 0 || i == span - 1) {
                        edge = true;
                    }
                    w_sum += w;
                    for i in 0..3 {
                        mean[i] += w * x[i];
                    }
                    let mut n = 0;
                    for i in 0..3 {
                        for j in i..3 {
                            second[n] += w * x[i] * x[j];
                            n += 1;
                        }
                    }
                }
            }
        }
        for m in mean.iter_mut() {
            *m /= w_sum;
        }
        let mut cov = [0.0; 9];
        let mut n = 0;
        for i in 0..3 {
            for j in i..3 {
                // A one-cell plateau still has the grid's own quantisation spread.
                let cell = [step, step, yaw_step][i];
                let q = if i == j { cell * cell / 12.0 } else { 0.0 };
                let c = second[n] / w_sum - mean[i] * mean[j] + q;
                cov[i * 3 + j] = c;
                cov[j * 3 + i] = c;
                n += 1;
            }
        }
        let pose = [centre[0] + mean[0], centre[1] + mean[1], centre[2] + mean[2]];
        Fit { pose, cov, at_window_edge: edge }
    }
}

/// How much better than any distinct rival the best pose must score: a few returns or
/// gap points of evidence, more on a board with many (`returns`) points.
pub(super) fn margin(returns: usize) -> i64 {
    AMBIGUITY_MARGIN + (returns / 200) as i64
}

/// Whether two fits put every hole within 1.5 cm of the other's: one optimum.
pub(super) fn same_holes(spec: &BoardSpec, a: &Fit, b: &Fit) -> bool {
    spec.holes.iter().all(|h| {
        let at = |f: &Fit| {
            let (s, c) = f.pose[2].sin_cos();
            (f.pose[0] + c * h[0] - s * h[1], f.pose[1] + s * h[0] + c * h[1])
        };
        let (pa, pb) = (at(a), at(b));
        (pa.0 - pb.0).hypot(pa.1 - pb.1) < 0.015
    })
}

/// Board-frame coordinates of plane-frame point `p` for pose (x, y, yaw).
pub(super) fn to_board(pose: [f64; 3], p: &[f64; 2]) -> (f64, f64) {
    let (s, c) = pose[2].sin_cos();
    let (dx, dy) = (p[0] - pose[0], p[1] - pose[1]);
    (c * dx + s * dy, -s * dx + c * dy)
}

/// Whether `yaw` lies within [`EXPECTED_YAW_DEG`] of `expected`, either way round (the
/// expected axis is a direction in the room; which way the detector's axis points along
/// it is the board's half-turn, which the mask search settles).
fn near_yaw(yaw: f64, expected: f64) -> bool {
    let off = (yaw - expected).rem_euclid(PI);
    off.min(PI - off) <= EXPECTED_YAW_DEG.to_radians()
}

/// Whether two in-plane poses are one optimum.
fn same_optimum(a: &[f64; 3], b: &[f64; 3], apart_m: f64) -> bool {
    (a[0] - b[0]).hypot(a[1] - b[1]) < apart_m && (a[2] - b[2]).abs() < DISTINCT_YAW
}

/// Adds `pose` to the best-first list `list` of distinct optima: it replaces a worse pose
/// of its own optimum, or the worst when the list is full.
fn keep_best(list: &mut Candidates, score: i64, pose: [f64; 3], apart_m: f64) {
    if let Some(k) = list.iter().position(|(_, p)| same_optimum(p, &pose, apart_m)) {
        if list[k].0 >= score {
            return;
        }
        list.remove(k);
    } else if list.is_full() {
        if list[CANDIDATES - 1].0 >= score {
            return;
        }
        list.pop();
    }
    let at = list.iter().position(|(s, _)| *s < score).unwrap_or(list.len());
    let _ = list.insert(at, (score, pose));
}

/// Keeps every `stride`-th element of `v`, in order.
fn keep_every<T: Copy>(v: &mut Vec<T>, stride: usize) {
    let mut i = 0;
    v.retain(|_| {
        i += 1;
        (i - 1) % stride == 0
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The list keeps the best of each optimum, best first, and at most [`CANDIDATES`].
    #[test]
    fn keep_best_keeps_distinct_optima_best_first() {
        let mut list = Candidates::new();
        keep_best(&mut list, 10, [0.0, 0.0, 0.0], DISTINCT_M);
        keep_best(&mut list, 12, [0.01, 0.0, 0.0], DISTINCT_M); // the same optimum, better
        keep_best(&mut list, 11, [0.3, 0.0, 0.0], DISTINCT_M);
        keep_best(&mut list, 9, [0.0, 0.0, 0.2], DISTINCT_M); // turned: another optimum
        keep_best(&mut list, 5, [0.6, 0.0, 0.0], DISTINCT_M);
        keep_best(&mut list, 1, [0.9, 0.0, 0.0], DISTINCT_M); // worse than a full list's worst
        let scores: Vec<i64> = list.iter().map(|c| c.0).collect();
        assert_eq!(scores, [12, 11, 9, 5]);
        assert_eq!(list[0].1, [0.01, 0.0, 0.0]);
    }

    /// An expected yaw admits the yaws near it either way round, and no others.
    #[test]
    fn near_yaw_holds_either_way_round() {
        let e = 10f64.to_radians();
        assert!(near_yaw(e + 13f64.to_radians(), e));
        assert!(near_yaw(e + PI - 13f64.to_radians(), e));
        assert!(!near_yaw(e + 15f64.to_radians(), e));
        assert!(!near_yaw(e + PI / 2.0, e));
    }
}
