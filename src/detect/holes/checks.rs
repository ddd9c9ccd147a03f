//! Checks of a pose the mask search found, each refusing the board with a [`Refusal`]
//! instead of guessing: where the scan lines end must agree with the fitted outline (ends
//! a few centimetres outside it mean a turned or shifted fit; returns past a side cut off
//! from the board by a gap are a stand beside it, no end); beams must not pass through
//! where the fitted board is solid; no points may lie where the holes should be (a crate
//! face); the two best-seen holes need [`HoleConfig::min_hole_lines`] lines each; most of
//! the sensor's lines across the board's height must return from it (a structure smaller
//! than a board does not); and the beams of every line that crosses the fitted board, taken
//! from the whole sweep at the line's own azimuth step, must return from its solid face
//! and pass through its holes ([`FaceEvidence`]: a post and two patches whose gaps fall on
//! the hole lattice leave the face empty, a wall whose scan lines the plane's points left
//! out fills the holes).
//!
//! A hole counts a line as crossing it when the line leaves and re-enters the board across
//! it with nothing in front hiding the gap, or returns from behind the plane inside it next
//! to a return of its own on the hole's rim ([`Checks::scan_lines_per_hole`]).
//!
//! [`HoleConfig::min_hole_lines`]: super::HoleConfig::min_hole_lines

use crate::geometry::{Se3, Vec3};
use crate::target::{BoardSpec, MAX_HOLES};

use super::plane::BoardPlane;
use super::projection::{Frame, Projection, HOLE_BAND, OUTLINE_CLUTTER};
use super::scan_lines::{line_end, median_step, scan_lines, BEHIND_M};
use super::search::{to_board, Fit};
use super::sweep::{elevation, wrap_azimuth, Sweep, LINE_GAP_RAD};
use super::Refusal;

/// Scan lines that cross each hole, in the room's hole order.
pub(super) type HoleLines = heapless::Vec<u16, MAX_HOLES>;

/// How far a scan line's gap may miss a hole and still count as crossing it (m): the
/// pose's own error on a grazing line. A line that misses the hole leaves no gap, so a
/// generous slack counts no false crossings.
pub(super) const SLACK: f64 = 0.02;
/// How far outside the fitted outline a scan line may end (m): the pose's own error and a
/// beam's footprint over the edge.
const OUTLINE_TOLERANCE: f64 = 0.03;
/// Largest distance (m) of the next return along a scan line for the line to run on rather
/// than end ([`runs_on`]): a few of a line's spacings (2–3 cm at 7 m, more on a surface
/// seen at a slant) plus range noise; a board's edge against what stands behind it is a
/// jump of more than [`super::scan_lines::BEHIND_M`].
const RUN_ON_M: f64 = 0.1;
/// The least gap along a scan line that cuts returns past a board's side off from the
/// board ([`board_ends`]): wider than a line's spacing on any board the room file allows
/// at 8 m, narrower than a stand's distance from the edge that matters.
const DETACHED_GAP_M: f64 = 0.04;

/// How far inside the outline and outside the holes a beam must meet the board for the
/// face check to expect a return from it (m): the pose's error and a beam's footprint.
const FACE_MARGIN_M: f64 = 0.03;
/// Least share of the beams meeting a board's solid face that must return from it
/// ([`FaceEvidence`]).
const MIN_FACE_RETURNS: f64 = 0.8;
/// Most beams a scan line may cross a board with before its step is taken as broken
/// (a line whose returns give no usable step).
const MAX_FACE_BEAMS: f64 = 20_000.0;

/// The checks' workspace, reused from pose to pose.
#[derive(Debug, Default)]
pub(super) struct Checks {
    /// (hole, elevation) of every scan line seen crossing a hole.
    crossings: Vec<(usize, f64)>,
    /// One line's returns as (board x, index), by x.
    run: Vec<(f64, u32)>,
    spacings: Vec<f64>,
}

impl Checks {
    /// Cheap checks of a coarse pose (within 2 cm) before it is refined: points deep
    /// inside the holes (no hole pattern there), or fewer than two holes crossed by any
    /// scan line (no refinement can make two of them well seen).
    pub(super) fn rough(
        &mut self,
        coarse: [f64; 3],
        ev: &mut Projection,
        spec: &BoardSpec,
    ) -> Result<(), (Refusal, HoleLines)> {
        let rough = Fit::rough(coarse);
        let in_holes = points_in_holes(&rough, 0.035, &ev.flat, spec);
        if in_holes > 3 + ev.flat.len() / 100 {
            let reason = Refusal::NoHolePattern { points_in_holes: in_holes };
            return Err((reason, heapless::Vec::new()));
        }
        let rough_lines = self.scan_lines_per_hole(&rough, 3.0 * SLACK, ev, spec);
        if rough_lines.iter().filter(|&&l| l >= 1).count() < 2 {
            return Err((Refusal::HolesUnseen { holes_with_two_lines: 0 }, rough_lines));
        }
        Ok(())
    }

    /// Scan-line ends (each line's first and last return along board x on the board: past
    /// returns a gap across the side cuts off, [`board_ends`]) between
    /// [`OUTLINE_TOLERANCE`] and [`OUTLINE_CLUTTER`] outside the fitted outline, and the
    /// ends counted: a line ends where it leaves the board, so a board turned or shifted in
    /// its plane leaves ends outside its outline (ends inside it may be an occluder's).
    /// A line past the board's side whose points there lie off the plane on average and
    /// that runs on beyond them without a jump in range ([`ran_onto_another_surface`])
    /// did not end at an edge: it ran onto a surface crossing the board's plane there at
    /// an angle (a box beside the board), and says nothing of the outline. A line that
    /// goes on in the plane (a wall) or ends at a corner of it still counts (the
    /// random-room study's held-out rooms: a wall's patch placed as a board when every
    /// line running on was excused).
    pub(super) fn line_ends_outside(
        &mut self,
        fit: &Fit,
        frame: Frame,
        (ev, plane): (&mut Projection, &BoardPlane),
        spec: &BoardSpec,
    ) -> (usize, usize) {
        let (hw, hh) = (spec.width / 2.0, spec.height / 2.0);
        // Ends far outside are coplanar clutter the line ran on into (a neighbouring
        // board's edge, a wall), not the pose's error: those do not count.
        let beyond = |d: f64| d > OUTLINE_TOLERANCE && d < OUTLINE_CLUTTER;
        let outside = |(x, y): (f64, f64)| {
            let (dx, dy) = (x.abs() - hw, y.abs() - hh);
            dx < OUTLINE_CLUTTER && dy < OUTLINE_CLUTTER && (beyond(dx) || beyond(dy))
        };
        ev.lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let ev = &*ev;
        let (mut bad, mut ends) = (0, 0);
        let run = &mut self.run;
        for line in scan_lines(&ev.lines).filter(|line| line.len() >= 3) {
            run.clear();
            run.extend(line.iter().map(|&(_, i)| (to_board(fit.pose, &ev.flat[i as usize]).0, i)));
            run.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            let (first, last) = board_ends(run, hw, &mut self.spacings);
            for (i, towards) in [(run[first].1, -1.0), (run[last].1, 1.0)] {
                let p = to_board(fit.pose, &ev.flat[i as usize]);
                let end = (p, i as usize);
                if !outside(p) {
                    ends += 1;
                } else if !ran_onto_another_surface(
                    line,
                    end,
                    towards,
                    (fit, frame),
                    (ev, plane),
                    spec,
                ) {
                    ends += 1;
                    bad += 1;
                }
            }
        }
        (bad, ends)
    }

    /// Scan lines (clusters of elevation angle) that leave and re-enter the board across
    /// each hole.
    #[inline(never)]
    pub(super) fn scan_lines_per_hole(
        &mut self,
        fit: &Fit,
        slack: f64,
        ev: &mut Projection,
        spec: &BoardSpec,
    ) -> HoleLines {
        self.crossings.clear();
        ev.lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let ev = &*ev;
        let r = spec.hole_radius;
        let band = HOLE_BAND;
        let mut start = 0;
        while start < ev.lines.len() {
            let end = line_end(&ev.lines, start);
            let spacing = self.median_spacing(fit, &ev.lines[start..end], &ev.flat);
            for (k, h) in spec.holes.iter().enumerate() {
                // Nearest points on either side of the hole along board x.
                let (mut left, mut right) = (None::<(f64, f64)>, None::<(f64, f64)>);
                for &(_, i) in &ev.lines[start..end] {
                    let (x, y) = to_board(fit.pose, &ev.flat[i as usize]);
                    let (dx, dy) = (x - h[0], y - h[1]);
                    let dist = dx.hypot(dy);
                    if dist < r - slack || dist > r + band {
                        continue;
                    }
                    if dx < 0.0 && left.is_none_or(|l| dx > l.0) {
                        left = Some((dx, dy));
                    } else if dx >= 0.0 && right.is_none_or(|l| dx < l.0) {
                        right = Some((dx, dy));
                    }
                }
                if let (Some(a), Some(b)) = (left, right) {
                    // A gap wider than the line's sampling whose chord meets the hole
                    // (allowing for the pose's own error on a grazing line), and that
                    // nothing in front hid.
                    let wide = (b.0 - a.0).hypot(b.1 - a.1) > 1.5 * spacing;
                    let e = ev.lines[start].0;
                    if wide
                        && segment_distance(a, b) < r + slack
                        && !hidden_between(fit, e, h, (a.0, b.0), ev, spec)
                    {
                        self.crossings.push((k, e));
                    }
                }
            }
            start = end;
        }
        self.see_through_crossings(fit, slack, ev, spec);
        self.count_crossings(spec)
    }

    /// Adds to `crossings` the lines with a see-through point inside a hole at `fit`
    /// (within the hole's radius, widened by a loose `slack`'s excess over [`SLACK`]) and
    /// a return of their own on the board at the hole's rim: the hole is in the board as
    /// that line saw it, not beside it. `lines` must be sorted by elevation.
    fn see_through_crossings(&mut self, fit: &Fit, slack: f64, ev: &Projection, spec: &BoardSpec) {
        let r = spec.hole_radius + (slack - SLACK).max(0.0);
        let rim = spec.hole_radius + HOLE_BAND;
        let mut start = 0;
        while start < ev.through_lines.len() {
            let end = line_end(&ev.through_lines, start);
            let e = ev.through_lines[start].0;
            let from = ev.lines.partition_point(|l| l.0 < e - LINE_GAP_RAD);
            let last = ev.through_lines[end - 1].0;
            let to = ev.lines.partition_point(|l| l.0 < last + LINE_GAP_RAD);
            for (k, h) in spec.holes.iter().enumerate() {
                let near = |p: &[f64; 2], reach: f64| {
                    let (x, y) = to_board(fit.pose, p);
                    (x - h[0]).hypot(y - h[1]) < reach
                };
                let inside = ev.through_lines[start..end]
                    .iter()
                    .any(|&(_, i)| near(&ev.through[i as usize], r));
                let on_rim = inside
                    && ev.lines[from..to].iter().any(|&(_, i)| near(&ev.flat[i as usize], rim));
                if on_rim {
                    self.crossings.push((k, ev.through_lines[start].0));
                }
            }
            start = end;
        }
    }

    /// Distinct scan lines (elevations 0.06° apart) per hole in `crossings`: a line seen
    /// both as a gap and through the hole counts once.
    fn count_crossings(&mut self, spec: &BoardSpec) -> HoleLines {
        let mut counts: HoleLines = heapless::Vec::new();
        for _ in 0..spec.holes.len() {
            let _ = counts.push(0);
        }
        self.crossings.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        let mut last: Option<(usize, f64)> = None;
        for &(k, e) in &self.crossings {
            let same = last.is_some_and(|(lk, le)| lk == k && e - le < LINE_GAP_RAD);
            if !same {
                counts[k] += 1;
            }
            last = Some((k, e));
        }
        counts
    }

    /// Median spacing along board x of the returns of the scan line `line` (the holes' own
    /// gaps do not stretch it, as they would a mean).
    fn median_spacing(&mut self, fit: &Fit, line: &[(f64, u32)], flat: &[[f64; 2]]) -> f64 {
        self.run.clear();
        for &(_, i) in line {
            self.run.push((to_board(fit.pose, &flat[i as usize]).0, i));
        }
        self.run.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        median_step(&self.run, &mut self.spacings)
    }
}

/// Points of `flat` clearly inside a hole (`margin` within its edge) at the fitted pose.
#[inline(never)]
pub(super) fn points_in_holes(
    fit: &Fit,
    margin: f64,
    flat: &[[f64; 2]],
    spec: &BoardSpec,
) -> usize {
    let r = (spec.hole_radius - margin).max(0.3 * spec.hole_radius);
    flat.iter()
        .filter(|p| {
            let (x, y) = to_board(fit.pose, p);
            spec.holes.iter().any(|h| (x - h[0]).hypot(y - h[1]) < r)
        })
        .count()
}

/// See-through points (`through`) clearly on solid board at the fitted pose (2 cm inside
/// the outline and outside the holes): beams that crossed the plane where the board should
/// have returned them.
pub(super) fn through_solid(fit: &Fit, through: &[[f64; 2]], spec: &BoardSpec) -> usize {
    let (hw, hh) = (spec.width / 2.0 - 0.02, spec.height / 2.0 - 0.02);
    let r = spec.hole_radius + 0.02;
    let solid = |p: &[f64; 2]| {
        let (x, y) = to_board(fit.pose, p);
        x.abs() < hw && y.abs() < hh && spec.holes.iter().all(|h| (x - h[0]).hypot(y - h[1]) > r)
    };
    through.iter().filter(|p| solid(p)).count()
}

/// What the sensor's beams say of a board at `pose` (board → LiDAR), stepping along each
/// scan line by its own azimuth step through the whole sweep (not only the plane's points):
/// a board returns nearly every beam that meets its solid face and none of those that
/// meet its holes. A post, a rail or two patches whose gaps fall on the hole lattice leave
/// most of the face empty; a wall whose scan lines were split from the plane fills the
/// holes. Beams hidden by a return in front of the board say nothing.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(super) struct FaceEvidence {
    /// Beams meeting the solid face ([`FACE_MARGIN_M`] inside the outline and outside the
    /// holes), and of them those that returned from the board (within [`BEHIND_M`] of it
    /// along the beam).
    pub(super) solid: usize,
    pub(super) solid_returned: usize,
    /// Per hole: beams meeting it ([`FACE_MARGIN_M`] inside its edge), and of them those
    /// that returned from the board's plane (within the band of its points).
    pub(super) holes: heapless::Vec<(usize, usize), MAX_HOLES>,
}

/// Where on a board a beam meets it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum FacePart {
    Solid,
    Hole(usize),
}

/// The [`FaceEvidence`] of a board at `pose` in `sweep`, its plane's points within `band`
/// of it (m, three of their σ).
pub(super) fn face_evidence(
    pose: &Se3,
    sweep: &Sweep,
    spec: &BoardSpec,
    band: f64,
) -> FaceEvidence {
    let (hw, hh) = (spec.width / 2.0, spec.height / 2.0);
    let corners =
        [(-hw, -hh), (hw, -hh), (-hw, hh), (hw, hh)].map(|(x, y)| pose.act(&Vec3::new(x, y, 0.0)));
    let centre_az = pose.translation.y.atan2(pose.translation.x);
    let (mut az_lo, mut az_hi, mut el_lo, mut el_hi) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for c in &corners {
        let daz = wrap_azimuth(c.y.atan2(c.x) - centre_az);
        (az_lo, az_hi) = (az_lo.min(daz), az_hi.max(daz));
        (el_lo, el_hi) = (el_lo.min(elevation(c)), el_hi.max(elevation(c)));
    }
    let (n, to_board) = (pose.rotation.column(2).into_owned(), pose.inverse());
    let d = n.dot(&pose.translation);
    let mut evidence = FaceEvidence::default();
    evidence.holes.extend(spec.holes.iter().map(|_| (0, 0)));
    for line in sweep.scan_lines().iter().filter(|l| l.elevation > el_lo && l.elevation < el_hi) {
        let (e, step) = (line.elevation, line.step);
        if step <= 0.0 || (az_hi - az_lo) / step > MAX_FACE_BEAMS {
            continue;
        }
        let mut daz = az_lo + step / 2.0;
        while daz < az_hi {
            let az = wrap_azimuth(centre_az + daz);
            daz += step;
            let u = Vec3::new(e.cos() * az.cos(), e.cos() * az.sin(), e.sin());
            let along = n.dot(&u);
            if along.abs() < 1e-3 || d / along <= 0.0 {
                continue;
            }
            let to_plane = d / along;
            let q = to_board.act(&(u * to_plane));
            let Some(part) = face_part(spec, q.x, q.y) else { continue };
            // The face is looked for a step to either side (sweeps laid over each other
            // at unrelated phases leave some steps without a return), a hole at the
            // beam's own azimuth only (its edge is a margin away).
            let reach = if part == FacePart::Solid { step } else { step / 2.0 };
            let (mut on, mut in_band, mut front) = (false, false, false);
            for range in sweep.line_returns(e, (az - reach, az + reach)) {
                on |= (range - to_plane).abs() <= BEHIND_M;
                in_band |= (range - to_plane).abs() <= band;
                front |= range < to_plane - BEHIND_M;
            }
            if front && !on {
                continue;
            }
            match part {
                FacePart::Solid => {
                    evidence.solid += 1;
                    evidence.solid_returned += usize::from(on);
                }
                // Through a hole the next surface may stand close behind (a stand, a
                // wall): only a return within the plane's own band fills the hole.
                FacePart::Hole(k) => {
                    evidence.holes[k].0 += 1;
                    evidence.holes[k].1 += usize::from(in_band);
                }
            }
        }
    }
    evidence
}

impl FaceEvidence {
    /// Whether a board's face shows here: most beams meeting its solid face returned
    /// ([`MIN_FACE_RETURNS`]), and at most one hole is filled ([`FaceEvidence::filled`]:
    /// something may touch a board's plane at one hole, a clamp or a box, but a surface
    /// over two or more is no board's).
    pub(super) fn shows_a_board(&self) -> bool {
        let returned = self.solid_returned as f64 / self.solid.max(1) as f64;
        returned >= MIN_FACE_RETURNS && self.filled() <= 1
    }

    /// Holes most of whose beams (three or more) returned from the board's plane.
    pub(super) fn filled(&self) -> usize {
        self.holes.iter().filter(|&&(beams, filled)| filled >= 3 && 2 * filled > beams).count()
    }
}

/// Where board point (`x`, `y`) lies: on the solid face or in a hole, each
/// [`FACE_MARGIN_M`] from any edge, or near an edge or off the board (`None`).
fn face_part(spec: &BoardSpec, x: f64, y: f64) -> Option<FacePart> {
    let (hw, hh) = (spec.width / 2.0 - FACE_MARGIN_M, spec.height / 2.0 - FACE_MARGIN_M);
    if x.abs() >= hw || y.abs() >= hh {
        return None;
    }
    let distance = |h: &[f64; 2]| (x - h[0]).hypot(y - h[1]);
    let (nearest, d) = spec
        .holes
        .iter()
        .enumerate()
        .map(|(k, h)| (k, distance(h)))
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    if d > spec.hole_radius + FACE_MARGIN_M {
        Some(FacePart::Solid)
    } else if d < spec.hole_radius - FACE_MARGIN_M {
        Some(FacePart::Hole(nearest))
    } else {
        None
    }
}

/// Scan lines on the plane (elevation clusters in `lines`, sorted) and the sensor's lines
/// whose elevation lies within the board's height at `pose`.
pub(super) fn lines_over_outline(
    pose: &Se3,
    lines: &[(f64, u32)],
    sweep: &Sweep,
    spec: &BoardSpec,
) -> (usize, usize) {
    // Lines that cross the board's middle (its top and bottom edges' midpoints, 3 cm
    // in): those cross the whole width, corners clipped at a tilt do not count.
    let hh = spec.height / 2.0 - 0.03;
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for (x, y) in [(0.0, -hh), (0.0, hh)] {
        let p = pose.act(&Vec3::new(x, y, 0.0));
        let e = elevation(&p);
        (lo, hi) = (lo.min(e), hi.max(e));
    }
    let expected = sweep.lines_between(lo, hi);
    let seen = scan_lines(lines).filter(|line| line.len() >= 3).count();
    (seen, expected)
}

/// Whether scan `line`, whose end `(p, i)` (board coordinates, index in the plane's points)
/// lies past the board's side (`towards` +1 or −1 along board x, at `fit`, plane frame
/// `frame`), ran on there onto a surface crossing the board's plane: its points beyond
/// the side lie off the plane on average, by more than 2.5 of their mean's σ (the plane's
/// band being 3σ), and it goes on beyond them off the plane ([`runs_on`]).
fn ran_onto_another_surface(
    line: &[(f64, u32)],
    ((_, y), i): ((f64, f64), usize),
    towards: f64,
    (fit, frame): (&Fit, Frame),
    (ev, plane): (&Projection, &BoardPlane),
    spec: &BoardSpec,
) -> bool {
    let (hw, hh) = (spec.width / 2.0, spec.height / 2.0);
    if y.abs() - hh > OUTLINE_TOLERANCE {
        return false; // above or below the board: the whole line is outside
    }
    let (c, _, _, n) = frame;
    let (mut sum, mut count) = (0.0, 0.0);
    for &(_, k) in line {
        let x = to_board(fit.pose, &ev.flat[k as usize]).0;
        if towards * x > hw + OUTLINE_TOLERANCE {
            sum += n.dot(&(plane.points[k as usize] - c));
            count += 1.0;
        }
    }
    let sigma = plane.band / 3.0;
    let turns_off = count >= 2.0 && (sum / count).abs() > 2.5 * sigma / f64::sqrt(count);
    turns_off && runs_on(i, towards, (fit, frame), (ev, plane))
}

/// Whether the scan line through the plane's point `i` goes on beyond it along the board's
/// x (`towards` +1 or −1, at `fit`, plane frame `frame`) off the board's plane: its next
/// return in `aside` lies within [`RUN_ON_M`] of it and outside the band the points were
/// cut to. The line then turned onto another surface without a jump in range; a line that
/// goes on in the plane (a wall beyond a window of it) did not.
fn runs_on(
    i: usize,
    towards: f64,
    (fit, (c, ex, ey, n)): (&Fit, Frame),
    (ev, plane): (&Projection, &BoardPlane),
) -> bool {
    let p = plane.points[i];
    let (e, d) = (elevation(&p), n.dot(&c));
    let board_x = |q: &Vec3| {
        let f = q * (d / n.dot(q)) - c;
        to_board(fit.pose, &[f.dot(&ex), f.dot(&ey)]).0
    };
    let x = board_x(&p);
    let next = ev
        .aside
        .iter()
        .filter(|q| (elevation(q) - e).abs() < LINE_GAP_RAD && towards * (board_x(q) - x) > 0.002)
        .map(|q| ((q - p).norm(), q))
        .min_by(|a, b| a.0.total_cmp(&b.0));
    next.is_some_and(|(distance, q)| distance < RUN_ON_M && n.dot(&(q - c)).abs() >= plane.band)
}

/// Whether a return in front of the plane on the scan line at elevation `e` lies
/// within the hole at `h` between board x `h.x + from` and `h.x + to` at `fit`: the
/// line's gap there was hidden by an occluder, and says nothing of a hole (Pandar64
/// room 536: a box face's line, whose stretch behind a stand was kept, read as crossing
/// a hole that the mask put on it).
fn hidden_between(
    fit: &Fit,
    e: f64,
    h: &[f64; 2],
    (from, to): (f64, f64),
    ev: &Projection,
    spec: &BoardSpec,
) -> bool {
    let first = ev.front_lines.partition_point(|l| l.0 < e - LINE_GAP_RAD);
    ev.front_lines[first..].iter().take_while(|l| l.0 < e + LINE_GAP_RAD).any(|&(_, i)| {
        let (x, y) = to_board(fit.pose, &ev.front[i as usize]);
        let (dx, dy) = (x - h[0], y - h[1]);
        dx > from && dx < to && dx.hypot(dy) < spec.hole_radius + HOLE_BAND
    })
}

/// Indices in `run` (one scan line's returns as (board x, index), sorted by x) of the
/// line's two ends on the board of half-width `hw`. Returns past a side that a gap of
/// three spacings (and at least [`DETACHED_GAP_M`]) cuts off from the rest, the gap's
/// inner side within the outline, are something standing beside the board (a stand's
/// pole a few centimetres off its edge, the random-room study's Pandar64 room 247): the
/// line left the board at the gap. `spacings` is scratch.
fn board_ends(run: &[(f64, u32)], hw: f64, spacings: &mut Vec<f64>) -> (usize, usize) {
    let side = hw + OUTLINE_TOLERANCE;
    let (low, high) = (
        run.iter().take_while(|p| p.0 < -side).count(),
        run.iter().rev().take_while(|p| p.0 > side).count(),
    );
    let last = run.len() - 1;
    if low == 0 && high == 0 {
        return (0, last);
    }
    let gap = (3.0 * median_step(run, spacings)).max(DETACHED_GAP_M);
    let cut_off = |outer: usize, inner: usize| (run[inner].0 - run[outer].0).abs() > gap;
    let first = if low > 0 && low <= last && cut_off(low - 1, low) { low } else { 0 };
    let end = if high > 0 && high <= last && cut_off(last + 1 - high, last - high) {
        last - high
    } else {
        last
    };
    (first, end)
}

/// Distance from the origin to the segment a–b.
fn segment_distance(a: (f64, f64), b: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let l2 = dx * dx + dy * dy;
    let t = if l2 > 0.0 { (-(a.0 * dx + a.1 * dy) / l2).clamp(0.0, 1.0) } else { 0.0 };
    (a.0 + t * dx).hypot(a.1 + t * dy)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A line's returns past a side, cut off from the board by a gap of more than three
    /// spacings (a stand beside it), are not its end; past a side with no such gap, or a
    /// gap inside the outline (a hole), they are.
    #[test]
    fn returns_cut_off_past_a_side_are_no_end_of_the_line() {
        let line = |xs: &[f64]| -> Vec<(f64, u32)> {
            xs.iter().enumerate().map(|(k, &x)| (x, k as u32)).collect()
        };
        let mut scratch = Vec::new();
        let board: Vec<f64> = (0..=40).map(|k| -0.5 + 0.025 * k as f64).collect();
        let stand_both = [&[-0.62, -0.61][..], &board, &[0.58]].concat();
        assert_eq!(board_ends(&line(&stand_both), 0.5, &mut scratch), (2, 42));
        let running_on = [&board[..], &[0.525, 0.55, 0.575]].concat();
        assert_eq!(board_ends(&line(&running_on), 0.5, &mut scratch), (0, 43));
        let hole: Vec<f64> = board.iter().copied().filter(|x| (x - 0.3).abs() > 0.1).collect();
        let hole_then_stand = [&hole[..], &[0.6]].concat();
        let n = hole_then_stand.len();
        assert_eq!(board_ends(&line(&hole_then_stand), 0.5, &mut scratch), (0, n - 2));
        let all_past = line(&[0.6, 0.61, 0.7]);
        assert_eq!(board_ends(&all_past, 0.5, &mut scratch), (0, 2));
    }

    /// The face evidence at [`facing_at_5_m`], for OpenCalib's board, of what a Pandar64
    /// sweeps in a room holding `boards` (board → LiDAR) and what `scene` adds: one sweep
    /// at each of `phases` (0.01°), laid over each other.
    fn evidence_of(
        boards: Vec<Se3>,
        phases: &[u16],
        scene: fn(&mut crate::sim::world::World, &BoardSpec),
    ) -> FaceEvidence {
        use crate::sim::{raycast, rng::Rng, world::World};
        let spec = crate::sim::random_room::opencalib_board();
        let mut rng = Rng::new(5);
        let mut world =
            World::new(&spec, boards, &mut rng.fork(1)).with_shell(-1.6, 1.8, 12.0, 8.0);
        scene(&mut world, &spec);
        let cal = raycast::calibration(crate::lidar::Model::Pandar64).expect("a simulated model");
        let cloud: Vec<_> = phases
            .iter()
            .flat_map(|&phase| raycast::sweep(&world, &cal, 0.02, phase, &mut rng.fork(2)).points)
            .collect();
        let mut sweep = Sweep::default();
        sweep.load(&cloud, &super::super::HoleConfig::default());
        face_evidence(&facing_at_5_m(), &sweep, &spec, 0.06)
    }

    /// The board → LiDAR pose of a board 5 m ahead facing the sensor: board x to the
    /// sensor's right, y down, the normal away from the sensor.
    fn facing_at_5_m() -> Se3 {
        let rotation = crate::geometry::Mat3::from_columns(&[-Vec3::y(), -Vec3::z(), Vec3::x()]);
        Se3 { rotation, translation: Vec3::new(5.0, 0.0, 0.0) }
    }

    /// A board's face returns every beam that meets it, and its holes none: in one sweep,
    /// and in three laid over each other at unrelated phases, or at nearly one phase.
    #[test]
    fn a_boards_face_shows_a_board() {
        for phases in [&[0][..], &[0, 7, 13], &[0, 1]] {
            let e = evidence_of(vec![facing_at_5_m()], phases, |_, _| {});
            assert!(e.solid > 500, "{phases:?}: {e:?}");
            assert!(e.solid_returned as f64 > 0.98 * e.solid as f64, "{phases:?}: {e:?}");
            assert!(
                e.holes.iter().all(|&(beams, filled)| beams > 5 && filled == 0),
                "{phases:?}: {e:?}"
            );
            assert!(e.shows_a_board());
        }
    }

    /// A post and two patches whose gaps fall on the holes leave most of the face empty.
    #[test]
    fn a_post_and_patches_on_the_hole_lattice_leave_the_face_empty() {
        let e = evidence_of(Vec::new(), &[0], |world, spec| {
            let site = crate::sim::structures::Site { x: 5.0, y: 0.0, floor_z: -1.6 };
            let kind = crate::sim::structures::Structure::PostAndPatches;
            crate::sim::structures::add(world, kind, spec, site, &mut crate::sim::rng::Rng::new(1));
        });
        assert!(e.solid > 500, "{e:?}");
        assert!((e.solid_returned as f64) < 0.6 * e.solid as f64, "{e:?}");
        assert!(!e.shows_a_board());
    }

    /// A wall where the board would be fills its holes.
    #[test]
    fn a_wall_fills_the_holes() {
        let e = evidence_of(Vec::new(), &[0], |world, _| {
            world.add_box(Vec3::new(5.0, -2.0, -1.6), Vec3::new(5.1, 2.0, 1.5));
        });
        assert!(e.solid_returned as f64 > 0.98 * e.solid as f64, "{e:?}");
        assert_eq!(e.filled(), 4, "{e:?}");
        assert!(!e.shows_a_board());
    }
}
