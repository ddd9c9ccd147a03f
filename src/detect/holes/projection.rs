//! Ray projection: the evidence the mask search and the checks weigh, in the plane's own
//! frame. Each of the board's points is moved along its own beam onto the fitted plane:
//! the beam direction is exact and the range noise lies along it, so the projected points
//! carry no range noise in the plane (the key to millimetre hole centres).
//!
//! - **Gap points**: where a line leaves the plane for about a hole's width and comes
//!   back, points laid at the line's own spacing: evidence of a hole even when the lines
//!   are sparse; none where the line's beams returned from in front of the plane (an
//!   occluder: the board may be solid behind it, and a stretch hidden beside a hole would
//!   widen the hole's gap).
//! - **See-through points**: returns from behind the plane whose beams crossed it near the
//!   board, moved along their beams onto it. Such a beam met no board there: beams passing
//!   beside the outline pin its edges, and a line that runs into a hole whose far side is
//!   hidden still shows the hole.
//! - **Front points**: returns in front of the plane (an occluder's), moved the same way:
//!   where a gap is hidden, not a hole.
//!
//! Before any search the points' extent must fit the board ([`Projection::extent_fits`]).

use crate::geometry::Vec3;
use crate::target::BoardSpec;

use super::scan_lines::{line_end, BEHIND_M};
use super::sweep::{elevation, point_of, Sweep, LINE_GAP_RAD};
use super::HoleConfig;

/// A plane frame: a point on the plane (its origin), the in-plane axes x and y (y as
/// close to the LiDAR's down as the plane allows) and the normal.
pub(super) type Frame = (Vec3, Vec3, Vec3, Vec3);

/// How far outside a hole's edge a scan line's last return before the hole may lie (m).
pub(super) const HOLE_BAND: f64 = 0.06;
/// Scan-line ends farther outside the outline than this are clutter beside the board (m).
pub(super) const OUTLINE_CLUTTER: f64 = 0.12;

/// How near the examined plane (m) a return must lie to be kept in `aside`.
const ASIDE_M: f64 = 0.3;
/// Least part of the board's width the points must span: a board partly hidden behind
/// another shows a third of it or more; the mask search and the hole checks judge the rest.
const MIN_WIDTH_SEEN: f64 = 0.35;
/// Least share of a plane's points inside one board-sized window for a plane larger than
/// the board to be searched for one ([`Projection::extent_fits`]).
const BOARD_WINDOW_SHARE: f64 = 0.85;

/// The projection workspace: one plane's evidence, reused from plane to plane.
#[derive(Debug, Default)]
pub(super) struct Projection {
    /// The board's points projected along their beams (plane frame); `flat[i]` is the
    /// plane's `points[i]`.
    pub(super) flat: Vec<[f64; 2]>,
    /// Each of `flat`'s elevations and index (sorted by elevation by whoever needs it so).
    pub(super) lines: Vec<(f64, u32)>,
    /// Gap points (plane frame).
    pub(super) gaps: Vec<[f64; 2]>,
    /// See-through points (plane frame), with their elevations in `through_lines`, sorted.
    pub(super) through: Vec<[f64; 2]>,
    pub(super) through_lines: Vec<(f64, u32)>,
    /// Returns in front of the plane examined (an occluder's), moved along their beams
    /// onto it (plane frame, with their elevations in `front_lines`, sorted).
    pub(super) front: Vec<[f64; 2]>,
    pub(super) front_lines: Vec<(f64, u32)>,
    /// Returns near the plane examined, on it or off it ([`Projection::find_see_through`]).
    pub(super) aside: Vec<Vec3>,
    hist: Vec<u32>,
}

impl Projection {
    /// The board frame of the plane (`c`, `n`) — `y` as close to the LiDAR's down as the
    /// plane allows — with `seg` projected along its beams into `flat` and each point's
    /// elevation in `lines`.
    pub(super) fn flatten(&mut self, seg: &[Vec3], (c, n): (Vec3, Vec3)) -> Frame {
        let down = Vec3::new(0.0, 0.0, -1.0);
        let mut ey = down - n * n.dot(&down);
        if ey.norm() < 0.2 {
            ey = Vec3::new(-1.0, 0.0, 0.0) - n * (-n.x);
        }
        let ey = ey.normalize();
        let ex = ey.cross(&n);
        // Ray projection onto the plane n·p = d.
        let d = n.dot(&c);
        self.flat.clear();
        self.lines.clear();
        for p in seg {
            // `flat[i]` is `seg[i]`'s: a beam along the plane (never on a board) unprojected.
            let s = n.dot(p);
            let q = if s.abs() < 1e-6 { p - c } else { p * (d / s) - c };
            self.flat.push([q.dot(&ex), q.dot(&ey)]);
            self.lines.push((elevation(p), self.flat.len() as u32 - 1));
        }
        (c, ex, ey, n)
    }

    /// Frees the buffers sized by the last sweep.
    pub(super) fn release(&mut self) {
        self.aside = Vec::new();
    }

    /// See-through points: returns from behind the plane (beyond it along their beams by
    /// more than the range noise) whose beams crossed it within the board's reach (half
    /// its `diagonal`), moved along their beams onto the plane (plane frame, into
    /// `through`; their elevations in `through_lines`, sorted). Such a beam met no board
    /// where it crossed the plane: that spot is a hole or beside the board, never solid
    /// board. This is the evidence a line leaves where it runs into a hole and the board
    /// beyond is hidden or too narrow to return (a corner hole a few centimetres from the
    /// edge), and where lines pass just beside the outline. Returns as far in front of the
    /// plane (an occluder's) go the same way into `front` and `front_lines`: where a gap is
    /// hidden, not a hole ([`Projection::find_gaps`]). The returns within [`ASIDE_M`] of
    /// the plane, on it or not, go into `aside`: where a scan line runs on past the board's
    /// points (the outline check).
    #[inline(never)]
    pub(super) fn find_see_through(&mut self, (c, ex, ey, n): Frame, sweep: &Sweep, diagonal: f64) {
        self.through.clear();
        self.through_lines.clear();
        self.front.clear();
        self.front_lines.clear();
        self.aside.clear();
        let d = n.dot(&c);
        let reach2 = (diagonal / 2.0).powi(2);
        let aside2 = (diagonal / 2.0 + OUTLINE_CLUTTER).powi(2);
        for p in sweep.points().iter().map(point_of) {
            let s = n.dot(&p);
            if (s - d).abs() < ASIDE_M && d > 0.0 && (p * (d / s) - c).norm_squared() < aside2 {
                self.aside.push(p);
            }
            if s <= 0.0 || d <= 0.0 {
                continue;
            }
            let t = d / s;
            let q = p * t - c;
            if q.norm_squared() > reach2 || (1.0 - t).abs() * p.norm() < BEHIND_M {
                continue;
            }
            if t < 1.0 {
                self.through_lines.push((elevation(&p), self.through.len() as u32));
                self.through.push([q.dot(&ex), q.dot(&ey)]);
            } else {
                self.front_lines.push((elevation(&p), self.front.len() as u32));
                self.front.push([q.dot(&ex), q.dot(&ey)]);
            }
        }
        self.through_lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        self.front_lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    }

    /// Gap points: where a scan line crossing the plane returned nothing between two of its
    /// returns over about a hole's width, points at the line's own spacing (plane frame).
    /// They tell the mask search where the holes are even when the lines are sparse.
    /// Returns how many gaps could be a line crossing a hole by the (looser) measure of
    /// the hole checks (`Checks::scan_lines_per_hole`).
    #[inline(never)]
    pub(super) fn find_gaps(&mut self, spec: &BoardSpec) -> usize {
        let mut chords = 0;
        self.gaps.clear();
        let (lines, flat) = (&mut self.lines, &self.flat);
        lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let max_chord = 2.0 * spec.hole_radius + 0.01;
        let loose_chord = 2.0 * (spec.hole_radius + HOLE_BAND) + 0.01;
        let mut start = 0;
        while start < lines.len() {
            let end = line_end(lines, start);
            let line = &mut lines[start..end];
            start = end;
            if line.len() < 4 {
                continue;
            }
            line.sort_unstable_by(|a, b| flat[a.1 as usize][0].total_cmp(&flat[b.1 as usize][0]));
            let (first, last) = (flat[line[0].1 as usize], flat[line[line.len() - 1].1 as usize]);
            let spacing = (last[0] - first[0]) / (line.len() - 1) as f64;
            for w in line.windows(2) {
                let (a, b) = (flat[w[0].1 as usize], flat[w[1].1 as usize]);
                let d = (b[0] - a[0]).hypot(b[1] - a[1]);
                // The line's spacing along the board's x is at most 1.3× shorter (40° yaw).
                if d > 1.1 * spacing && d < loose_chord + 2.0 * spacing {
                    chords += 1;
                }
                // A hole's chord plus up to a spacing on either side.
                if d <= 2.0 * spacing || d >= max_chord + 2.0 * spacing {
                    continue;
                }
                let k = (d / spacing) as usize - 1;
                let e = w[0].0;
                let from = self.front_lines.partition_point(|l| l.0 < e - LINE_GAP_RAD);
                let to = self.front_lines.partition_point(|l| l.0 < e + LINE_GAP_RAD);
                let occluders = &self.front_lines[from..to];
                for j in 1..=k {
                    let f = j as f64 / (k + 1) as f64;
                    let g = [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])];
                    // A beam there returned from in front of the plane: the board may be
                    // solid behind the occluder, so the gap says nothing of a hole.
                    let hidden = occluders.iter().any(|&(_, i)| {
                        let o = self.front[i as usize];
                        (o[0] - g[0]).hypot(o[1] - g[1]) < spacing
                    });
                    if !hidden {
                        self.gaps.push(g);
                    }
                }
            }
        }
        chords
    }

    /// Whether the points' smallest bounding rectangle fits the board outline, a few
    /// stray points (3 %: clutter touching the plane, an occluder's edge) left out on
    /// each side, or, for points up to twice the board's size, whether one board-sized
    /// window holds [`BOARD_WINDOW_SHARE`] of them; the mask search weighs the rest.
    #[inline(never)]
    pub(super) fn extent_fits(&mut self, spec: &BoardSpec, config: &HoleConfig) -> bool {
        let tol = config.size_tolerance_m;
        let trim = 3 + self.flat.len() * 3 / 100;
        let mut best = (f64::MAX, 0.0, 0.0);
        for k in -15..=15 {
            let (s, co) = (k as f64 * 3.0).to_radians().sin_cos();
            let a = self.trimmed_span(|p| co * p[0] + s * p[1], trim);
            let b = self.trimmed_span(|p| -s * p[0] + co * p[1], trim);
            if a * b < best.0 {
                best = (a * b, a, b);
            }
        }
        let (_, a, b) = best;
        // Every scan line across the board spans its width unless something hides part of it;
        // the height may be covered only in part.
        if a < MIN_WIDTH_SEEN * spec.width {
            return false;
        }
        if a <= spec.width + tol && b <= spec.height + tol {
            return true;
        }
        // Wider or taller than the board: a board with clutter in its plane beside or below
        // it (a box it stands by, the floor's crossing of its plane under a pitched board,
        // a stand) or no board. The random-room study missed 10 of 606 placeable boards so.
        // The mask search places a board among such points; it is tried when one
        // board-sized window holds nearly all of them.
        let (w, h) = (spec.width + tol, spec.height + tol);
        a <= 2.0 * w && b <= 2.0 * h && self.board_window_share(w, h) >= BOARD_WINDOW_SHARE
    }

    /// Largest share of `flat` inside one `w` × `h` window, turned in 3° steps up to ±45°
    /// (counted on a 4 cm grid through a summed-area table kept in `hist`).
    fn board_window_share(&mut self, w: f64, h: f64) -> f64 {
        const CELL: f64 = 0.04;
        const SIDE: usize = 128;
        let (kw, kh) = (((w / CELL).round() as usize).max(1), ((h / CELL).round() as usize).max(1));
        let mut most = 0;
        for k in -15..=15 {
            let (s, co) = (k as f64 * 3.0).to_radians().sin_cos();
            let turn = |p: &[f64; 2]| (co * p[0] + s * p[1], -s * p[0] + co * p[1]);
            let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
            for p in &self.flat {
                let (u, v) = turn(p);
                (lo, hi) = ([lo[0].min(u), lo[1].min(v)], [hi[0].max(u), hi[1].max(v)]);
            }
            let cells = |d: usize| (((hi[d] - lo[d]) / CELL) as usize + 1).min(SIDE);
            let (nu, nv) = (cells(0), cells(1));
            // The table's row and column 0 stay zero: entry (i, j) sums the cells < (i, j).
            let stride = nu + 1;
            self.hist.clear();
            self.hist.resize(stride * (nv + 1), 0);
            for p in &self.flat {
                let (u, v) = turn(p);
                let (i, j) = (((u - lo[0]) / CELL) as usize, ((v - lo[1]) / CELL) as usize);
                if i < nu && j < nv {
                    self.hist[(j + 1) * stride + i + 1] += 1;
                }
            }
            for j in 1..=nv {
                for i in 1..=nu {
                    self.hist[j * stride + i] += self.hist[j * stride + i - 1]
                        + self.hist[(j - 1) * stride + i]
                        - self.hist[(j - 1) * stride + i - 1];
                }
            }
            let at = |i: usize, j: usize| self.hist[j * stride + i];
            for j in kh.min(nv)..=nv {
                for i in kw.min(nu)..=nu {
                    let (i0, j0) = (i - kw.min(i), j - kh.min(j));
                    most = most.max(at(i, j) + at(i0, j0) - at(i0, j) - at(i, j0));
                }
            }
        }
        most as f64 / self.flat.len().max(1) as f64
    }

    /// Span of `f` over `flat` without the `trim` lowest and highest values (1 cm bins).
    fn trimmed_span(&mut self, f: impl Fn(&[f64; 2]) -> f64, trim: usize) -> f64 {
        let (mut lo, mut hi) = (f64::MAX, f64::MIN);
        for p in &self.flat {
            let x = f(p);
            (lo, hi) = (lo.min(x), hi.max(x));
        }
        let bins = ((hi - lo) / 0.01) as usize + 1;
        if bins > 1000 {
            return hi - lo; // far larger than any board
        }
        self.hist.clear();
        self.hist.resize(bins, 0);
        for p in &self.flat {
            self.hist[((f(p) - lo) / 0.01) as usize] += 1;
        }
        let first = cut(self.hist.iter(), trim);
        let last = bins - 1 - cut(self.hist.iter().rev(), trim);
        (last.saturating_sub(first)) as f64 * 0.01
    }
}

/// The first bin after the lowest `trim` counts.
fn cut<'a>(counts: impl Iterator<Item = &'a u32>, trim: usize) -> usize {
    let mut seen = 0;
    for (i, &c) in counts.enumerate() {
        seen += c as usize;
        if seen > trim {
            return i;
        }
    }
    0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::holes::test_board;

    /// A return on the plane and one farther along its beam land on the same spot, in a
    /// frame whose x points right and y down as the sensor sees a plane ahead.
    #[test]
    fn points_move_along_their_beams_onto_the_plane() {
        let mut projection = Projection::default();
        let on = Vec3::new(5.0, -0.2, -0.1);
        let plane = (Vec3::new(5.0, 0.0, 0.0), Vec3::x());
        let (_, ex, ey, _) = projection.flatten(&[on, on * 1.01], plane);
        assert!((ex + Vec3::y()).norm() < 1e-12 && (ey + Vec3::z()).norm() < 1e-12);
        for f in &projection.flat {
            assert!((f[0] - 0.2).abs() < 1e-12 && (f[1] - 0.1).abs() < 1e-12, "{f:?}");
        }
        assert_eq!(projection.lines.len(), 2);
    }

    /// A line with a hole-wide gap counts one chord and gets gap points across it, at
    /// about its spacing.
    #[test]
    fn a_line_across_a_hole_leaves_gap_points_in_it() {
        let spec = test_board();
        let mut projection = Projection::default();
        for k in 0..=50 {
            let x = -0.5 + 0.02 * k as f64;
            // Nothing within 9 cm of the hole's centre (its 8 cm radius and a margin).
            if (x - 0.2f64).abs() > 0.09 {
                projection.lines.push((0.0, projection.flat.len() as u32));
                projection.flat.push([x, 0.1]);
            }
        }
        assert_eq!(projection.find_gaps(&spec), 1);
        assert_eq!(projection.gaps.len(), 7);
        for g in &projection.gaps {
            assert!((g[0] - 0.2).abs() < spec.hole_radius && g[1] == 0.1, "{g:?}");
        }
    }
}
