//! Boards where a model of the room expects them: in a surveyed room the camera's room
//! pose and the LiDAR's nominal mounting predict every board's pose in the sweep, so the
//! board is looked for there instead of among every plane of the sweep (no voxel planes,
//! no segments, no mask search on walls and clutter). The placement and its checks are the
//! global detector's own ([`HoleDetector::examine`]): an expectation narrows where to
//! look, never what counts as a board.
//!
//! The mask search tries only the yaws within [`super::EXPECTED_YAW_DEG`] of the expected
//! board's (either way round): a third of the global search's, which is most of what the
//! expected search costs (the surveyed fixture's run: 1.337 → 1.248 G instructions, the
//! same result).
//!
//! The expected plane may be off by the mounting's error (a few centimetres and a degree or
//! two at the board): the board's own plane is the densest band about it within
//! [`EXPECTED_BAND_M`], then refitted and gathered again until it settles.

use super::{point_of, HoleDetector, LidarBoard, Point, Region, Se3, Vec3};

/// How far (m) a board may lie from where it is expected, beyond its half diagonal.
pub const EXPECTED_REACH_M: f64 = 0.3;
/// Half-width (m) of the band about the expected plane searched for the board's own.
const EXPECTED_BAND_M: f64 = 0.3;
/// Bin of the offsets along the expected normal (m).
const OFFSET_BIN_M: f64 = 0.01;

impl HoleDetector {
    /// Places the board expected at each of `expected` (board → LiDAR) in `points`: `out[i]`
    /// is the board placed within its half diagonal and 0.3 m of `expected[i]`, or `None` (the
    /// reason, if a plane was there, in [`HoleDetector::refused`]).
    pub fn detect_expected(
        &mut self,
        points: &[Point],
        expected: &[Se3],
        out: &mut Vec<Option<LidarBoard>>,
    ) {
        out.clear();
        self.refused.clear();
        self.load(points);
        let reach = self.board_diagonal() / 2.0 + EXPECTED_REACH_M;
        self.keep_in_sight(expected, reach);
        let mut placed = Vec::with_capacity(1);
        for pose in expected {
            placed.clear();
            let centre = pose.translation;
            // Where two expected boards stand close, each point is the nearer one's: the
            // search about one board never fuses it with its neighbour's face.
            self.rivals.clear();
            let close = |c: &Vec3| c != &centre && (c - centre).norm() < 2.0 * reach;
            self.rivals.extend(expected.iter().map(|e| e.translation).filter(close));
            if let Some(start) = self.densest_band(pose, reach) {
                if let Some(plane) = self.settled_plane(Region::Ball(centre, reach), start) {
                    self.expected_axis = Some(pose.rotation.column(0).into_owned());
                    self.examine(plane, &mut placed);
                    self.expected_axis = None;
                }
            }
            let near = |b: &LidarBoard| (b.pose.translation - centre).norm() <= reach;
            out.push(placed.pop().filter(near));
        }
    }

    /// Keeps only the points a search about `expected` (within `reach` of a centre) can
    /// use: those whose beam passes within `reach` plus half the board's diagonal of an
    /// expected centre, which covers the board's own points and what its holes show behind
    /// it ([`HoleDetector::find_see_through`]). The placements are the same as on the whole
    /// sweep; every later pass over the points reads a few thousand instead of the sweep.
    /// The points' voxel keys are dropped (the expected search uses none).
    fn keep_in_sight(&mut self, expected: &[Se3], reach: f64) {
        let sight = reach + self.board_diagonal() / 2.0;
        // Per expected centre: its direction and the cosine of the cone it subtends.
        let cones: Vec<(Vec3, f64)> = expected
            .iter()
            .map(|pose| {
                let range = pose.translation.norm();
                match sight < range {
                    true => (pose.translation / range, (1.0 - (sight / range).powi(2)).sqrt()),
                    false => (Vec3::zeros(), -1.0),
                }
            })
            .collect();
        self.pts.retain(|p| {
            let p = point_of(p);
            let range = p.norm();
            cones.iter().any(|(towards, cos)| towards.dot(&p) >= cos * range)
        });
        self.keys.clear();
    }

    /// The plane parallel to the expected board's through the densest band
    /// (twice the plane tolerance wide) of offsets within [`EXPECTED_BAND_M`] of it, among
    /// the points within `reach` of the expected centre; `None` when no point is there.
    fn densest_band(&mut self, pose: &Se3, reach: f64) -> Option<(Vec3, Vec3)> {
        let (c, n) = (pose.translation, pose.rotation.column(2).into_owned());
        let bins = (2.0 * EXPECTED_BAND_M / OFFSET_BIN_M) as usize;
        self.hist.clear();
        self.hist.resize(bins, 0);
        for p in self.pts.iter().map(point_of) {
            let d = p - c;
            let offset = n.dot(&d);
            let within = d.norm_squared() <= reach * reach && nearest_to(&self.rivals, &p, &c);
            if within && offset.abs() < EXPECTED_BAND_M {
                let bin = ((offset + EXPECTED_BAND_M) / OFFSET_BIN_M) as usize;
                self.hist[bin.min(bins - 1)] += 1;
            }
        }
        let width = ((2.0 * self.config.plane_tolerance_m / OFFSET_BIN_M) as usize).clamp(1, bins);
        let (mut count, mut best) = (self.hist[..width].iter().sum::<u32>(), (0, 0));
        for start in 0..=bins - width {
            if start > 0 {
                count = count + self.hist[start + width - 1] - self.hist[start - 1];
            }
            if count > best.1 {
                best = (start, count);
            }
        }
        if best.1 == 0 {
            return None;
        }
        let offset = -EXPECTED_BAND_M + (best.0 as f64 + width as f64 / 2.0) * OFFSET_BIN_M;
        Some((c + n * offset, n))
    }

    /// Collects into `seg` every point within the plane tolerance of the plane (`c`, `n`)
    /// and within `radius` of `centre`, nearer it than any other expected board's.
    pub(super) fn gather_in_ball(&mut self, centre: Vec3, radius: f64, (c, n): (Vec3, Vec3)) {
        let tol = self.config.plane_tolerance_m;
        self.seg.clear();
        let rivals = &self.rivals;
        let within = |p: &Vec3| {
            (p - centre).norm_squared() <= radius * radius && nearest_to(rivals, p, &centre)
        };
        let points = self.pts.iter().map(point_of);
        self.seg.extend(points.filter(|p| within(p) && n.dot(&(*p - c)).abs() < tol));
    }
}

/// Whether `p` is at least as near `centre` as every one of `rivals`.
fn nearest_to(rivals: &[Vec3], p: &Vec3, centre: &Vec3) -> bool {
    let own = (p - centre).norm_squared();
    rivals.iter().all(|r| own <= (p - r).norm_squared())
}
