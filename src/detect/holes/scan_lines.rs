//! Scan lines on a board's plane: of each line only its longest run without a gap wider
//! than a hole is kept (a gap that returns in front of the plane hide joins the run: a
//! board behind another is left in pieces between the occluder's edges; an end next to an
//! occluder loses its last 8 cm's returns in front of the plane, which may be the
//! occluder's side closing in on it), and lines shorter than a fifth of the board drop
//! out (poles, stands, clutter touching the plane; a line through a rolled board's corner
//! hole, or across a partly hidden board, is shorter than the width but kept).
//!
//! A scan line is told by its elevation: the returns of one line lie closer than
//! [`LINE_GAP_RAD`] in elevation to the next ([`scan_lines`]).

use core::f64::consts::PI;

use crate::geometry::Vec3;
use crate::target::BoardSpec;

use super::sweep::{elevation, wrap_azimuth, Sweep, LINE_GAP_RAD};
use super::HoleConfig;

/// How far beyond the plane along its beam a return must lie to be a see-through point
/// (m): well over the range noise (2 cm σ) and the plane's thickness.
pub(super) const BEHIND_M: f64 = 0.15;

/// Shortest scan-line run kept on a board, as a fraction of its width: a line through a
/// corner hole of a rolled board leaves through the bottom edge soon after, and one across
/// a partly hidden board ends at the occluder; poles and stands are far narrower. At a
/// quarter, the 21–25 cm that an occluder left of a 1 m board's lines beside a hole dropped
/// them and with them the hole (the random-room study's Pandar40P room 231). A fifth found
/// 1–8 more boards per model over the study's rooms 1–600 and placed none wrong; 15 % found
/// a few more still, but placed two structures 7.5 m away in the real OpenCalib frame as
/// boards (`tests/it/holes_real.rs`): their shorter runs filled the lines that
/// [`super::Refusal::LinesMissing`] counts (28 of 47 lines at a fifth, 15 at a quarter, 36
/// needed).
const MIN_RUN: f64 = 0.2;
/// What a scan line's end next to an occluder loses (m): the occluder's side may close in on
/// the plane there ([`ScanLines::unoccluded_part`]).
const OCCLUDED_END_M: f64 = 0.08;
/// How far in front of the plane such an end's returns must lie to be dropped (m): a
/// range σ.
const OCCLUDED_FRONT_M: f64 = 0.02;

/// The scan-line workspace: one board's lines, reused from board to board.
#[derive(Debug, Default)]
pub(super) struct ScanLines {
    /// The board's returns as (elevation, index), by elevation.
    lines: Vec<(f64, u32)>,
    /// One line's returns as (azimuth, index), by azimuth.
    run: Vec<(f64, u32)>,
    spacings: Vec<f64>,
    keep: Vec<bool>,
}

impl ScanLines {
    /// Keeps of each scan line in `seg` only its longest run without a gap wider than a
    /// hole, or a gap the line's returns in front of the plane (`c`, `n`) hide
    /// ([`ScanLines::hidden_stretch`]), and drops lines whose run is shorter than
    /// [`MIN_RUN`] of the board's width: a pole or stand below the board, a corner grazed,
    /// coplanar clutter beside it. Every line across a board spans its width in one run,
    /// broken only by the holes and what stands in front of it, unless it leaves through
    /// the top or bottom edge. (A board behind another, Pandar40P room 303: the pieces
    /// either side of its holes left between the occluder's edges, 17–20 cm of a 1.2 m
    /// board, were each too short, and the lines crossing two holes were dropped.)
    #[inline(never)]
    pub(super) fn keep_board_runs(
        &mut self,
        seg: &mut Vec<Vec3>,
        plane: (Vec3, Vec3),
        sweep: &Sweep,
        (spec, config): (&BoardSpec, &HoleConfig),
    ) {
        let Some(first) = seg.first() else { return };
        let towards = first.y.atan2(first.x);
        self.lines.clear();
        for (i, p) in seg.iter().enumerate() {
            self.lines.push((elevation(p), i as u32));
        }
        self.lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        self.keep.clear();
        self.keep.resize(seg.len(), false);
        let min_run = MIN_RUN * spec.width;
        // A hole's chord, the line's spacing on either side (2–4 cm) and range noise.
        let max_gap = 2.0 * spec.hole_radius + 0.15;
        let mut start = 0;
        while start < self.lines.len() {
            let end = line_end(&self.lines, start);
            // The line's points by azimuth (relative to the plane's first point, so a
            // board behind the sensor does not wrap).
            self.run.clear();
            for &(_, i) in &self.lines[start..end] {
                let p = &seg[i as usize];
                self.run.push((wrap_azimuth(p.y.atan2(p.x) - towards), i));
            }
            start = end;
            self.run.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            // The line's azimuth step, found only when a gap needs it.
            let mut step = None;
            let (mut best, mut from) = ((0, 0, 0.0), 0);
            for k in 1..=self.run.len() {
                let split = k < self.run.len() && {
                    let (a, b) = (seg[self.run[k - 1].1 as usize], seg[self.run[k].1 as usize]);
                    let gap = (b - a).norm();
                    gap > max_gap
                        && (gap > spec.width || {
                            let step = *step
                                .get_or_insert_with(|| median_step(&self.run, &mut self.spacings));
                            !hidden_stretch(&a, &b, plane, step, sweep, spec)
                        })
                };
                if k == self.run.len() || split {
                    let len =
                        (seg[self.run[k - 1].1 as usize] - seg[self.run[from].1 as usize]).norm();
                    if len > best.2 {
                        best = (from, k, len);
                    }
                    from = k;
                }
            }
            if best.2 >= min_run {
                let step = *step.get_or_insert_with(|| median_step(&self.run, &mut self.spacings));
                let (from, to) =
                    self.unoccluded_part(seg, (best.0, best.1), plane, step, sweep, config);
                for &(_, i) in &self.run[from..to] {
                    self.keep[i as usize] = true;
                }
            }
        }
        let mut k = 0;
        let keep = &self.keep;
        seg.retain(|_| {
            k += 1;
            keep[k - 1]
        });
    }

    /// The part of the run `run[from..to]` (one line's returns by azimuth, `step` apart)
    /// left when each end next to an occluder loses its last [`OCCLUDED_END_M`]: where the
    /// line's next beams beyond an end return from in front of the plane (beyond its band),
    /// the returns just inside that end may be the occluder's own side closing in on the
    /// plane. The random-room study's room 783 (Pandar40P and VLP-32C): half a board
    /// hidden by a box 16–23 cm in front, whose side reached within 2–7 cm of the plane
    /// along the seen half's edge; in the band, those returns tilted the plane fitted on
    /// that half 1.5–1.8° and put its unseen holes 2 cm out.
    fn unoccluded_part(
        &self,
        seg: &[Vec3],
        (from, to): (usize, usize),
        plane: (Vec3, Vec3),
        step: f64,
        sweep: &Sweep,
        config: &HoleConfig,
    ) -> (usize, usize) {
        let (mut from, mut to) = (from, to);
        if to - from < 2 || step <= 0.0 {
            return (from, to);
        }
        let margin = config.plane_tolerance_m;
        let beyond = 3.0 * step;
        let (c, n) = plane;
        let forward = if n.dot(&c) < 0.0 { n } else { -n };
        let in_front = |p: &Vec3, end: &Vec3| {
            (p - end).norm() < OCCLUDED_END_M && forward.dot(&(p - c)) > OCCLUDED_FRONT_M
        };
        let first = seg[self.run[from].1 as usize];
        let az = first.y.atan2(first.x);
        if az - beyond > -PI
            && sweep.returns_in_front(elevation(&first), (az - beyond, az), plane, margin) > 0
        {
            while from < to && in_front(&seg[self.run[from].1 as usize], &first) {
                from += 1;
            }
        }
        let last = seg[self.run[to - 1].1 as usize];
        let az = last.y.atan2(last.x);
        if az + beyond < PI
            && sweep.returns_in_front(elevation(&last), (az, az + beyond), plane, margin) > 0
        {
            while to > from && in_front(&seg[self.run[to - 1].1 as usize], &last) {
                to -= 1;
            }
        }
        (from, to)
    }
}

/// Whether the stretch of a scan line between its returns `a` and `b` on the plane
/// (`c`, `n`), its beams `step` (rad of azimuth) apart, was hidden by something in
/// front: all of it but a hole's chord (what may have been seen through) returned
/// from more than [`BEHIND_M`] in front of the plane.
fn hidden_stretch(
    a: &Vec3,
    b: &Vec3,
    (c, n): (Vec3, Vec3),
    step: f64,
    sweep: &Sweep,
    spec: &BoardSpec,
) -> bool {
    let (e, d) = (elevation(a), n.dot(&c));
    let (az_a, az_b) = (a.y.atan2(a.x), b.y.atan2(b.x));
    if (az_a - az_b).abs() > PI || d <= 0.0 || step <= 0.0 {
        return false; // across the sensor's back, or a plane through the sensor
    }
    let (lo, hi) = (az_a.min(az_b), az_a.max(az_b));
    let front = sweep.returns_in_front(e, (lo, hi), (c, n), BEHIND_M);
    // The stretch and a hole's chord (with a spacing either side) in azimuth.
    let stretch = hi - lo;
    let chord = (2.0 * spec.hole_radius) / a.norm().min(b.norm()) + 2.0 * step;
    front > 0 && front as f64 * step >= stretch - chord
}

/// End of the scan line (run of elevations closer than [`LINE_GAP_RAD`] to the previous)
/// that starts at `start` in `lines` sorted by elevation.
pub(super) fn line_end(lines: &[(f64, u32)], start: usize) -> usize {
    let mut end = start + 1;
    while end < lines.len() && lines[end].0 - lines[end - 1].0 < LINE_GAP_RAD {
        end += 1;
    }
    end
}

/// The scan lines of `lines` (sorted by elevation), each as its slice: runs of elevations
/// closer than [`LINE_GAP_RAD`] to the previous ([`line_end`]).
pub(super) fn scan_lines(lines: &[(f64, u32)]) -> impl Iterator<Item = &[(f64, u32)]> {
    let mut start = 0;
    core::iter::from_fn(move || {
        (start < lines.len()).then(|| {
            let end = line_end(lines, start);
            let line = &lines[start..end];
            start = end;
            line
        })
    })
}

/// The median step between consecutive values of `run` (sorted by its first field), 0
/// for fewer than two: a scan line's spacing, which its holes' gaps do not stretch as
/// they would a mean. `steps` is scratch.
pub(super) fn median_step(run: &[(f64, u32)], steps: &mut Vec<f64>) -> f64 {
    steps.clear();
    steps.extend(run.windows(2).map(|w| w[1].0 - w[0].0));
    if steps.is_empty() {
        return 0.0;
    }
    let mid = steps.len() / 2;
    *steps.select_nth_unstable_by(mid, f64::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Returns closer than [`LINE_GAP_RAD`] in elevation to the previous are one line.
    #[test]
    fn scan_lines_split_where_the_elevation_jumps() {
        let step = LINE_GAP_RAD / 2.0;
        let lines = [(0.0, 0), (step, 1), (2.0 * step, 2), (0.01, 3), (0.01 + step, 4), (0.02, 5)];
        let lengths: Vec<usize> = scan_lines(&lines).map(<[_]>::len).collect();
        assert_eq!(lengths, [3, 2, 1]);
        assert_eq!(line_end(&lines, 3), 5);
    }

    /// A line's spacing is its median step: a hole's gap does not stretch it.
    #[test]
    fn median_step_ignores_the_gap_of_a_hole() {
        let mut run: Vec<(f64, u32)> = (0..10).map(|k| (0.02 * k as f64, k)).collect();
        run.extend((0..5).map(|k| (0.5 + 0.02 * k as f64, 10 + k)));
        let mut scratch = Vec::new();
        assert!((median_step(&run, &mut scratch) - 0.02).abs() < 1e-12);
        assert_eq!(median_step(&run[..1], &mut scratch), 0.0);
    }
}
