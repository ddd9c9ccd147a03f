//! Boards where a model of the room expects them: in a surveyed room the camera's room
//! pose and the LiDAR's nominal mounting predict every board's pose in the sweep, so the
//! board is looked for there instead of among every plane of the sweep (no voxel planes,
//! no segments, no mask search on walls and clutter). The placement and its checks are the
//! global detector's own: an expectation narrows where to look, never what counts as a
//! board.
//!
//! The mask search tries only the yaws within [`super::EXPECTED_YAW_DEG`] of the expected
//! board's (either way round): a third of the global search's, which is most of what the
//! expected search costs (the surveyed fixture's run: 1.337 → 1.248 G instructions, the
//! same result).
//!
//! The expected plane may be off by the mounting's error (a few centimetres and a degree or
//! two at the board): the board's own plane is the densest band about it within
//! [`EXPECTED_BAND_M`], then refitted and gathered again until it settles.

use crate::geometry::{Se3, Vec3};

use super::sweep::{point_of, Sweep};
use super::HoleConfig;

/// How far (m) a board may lie from where it is expected, beyond its half diagonal.
pub const EXPECTED_REACH_M: f64 = 0.3;
/// Half-width (m) of the band about the expected plane searched for the board's own.
const EXPECTED_BAND_M: f64 = 0.3;
/// Bin of the offsets along the expected normal (m).
const OFFSET_BIN_M: f64 = 0.01;

/// The expected search's workspace, reused from board to board.
#[derive(Debug, Default)]
pub(super) struct Expected {
    /// The other expected boards' centres near the one searched.
    rivals: Vec<Vec3>,
    /// Points per offset bin along the expected normal.
    hist: Vec<u32>,
}

impl Expected {
    /// Keeps only the points a search about `expected` (within `reach` of a centre) can
    /// use: those whose beam passes within `reach` plus half the board's `diagonal` of an
    /// expected centre, which covers the board's own points and what its holes show behind
    /// it (the see-through points). The placements are the same as on the whole sweep;
    /// every later pass over the points reads a few thousand instead of the sweep.
    pub(super) fn keep_in_sight(sweep: &mut Sweep, expected: &[Se3], reach: f64, diagonal: f64) {
        let sight = reach + diagonal / 2.0;
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
        sweep.keep_points(|p| {
            let p = point_of(p);
            let range = p.norm();
            cones.iter().any(|(towards, cos)| towards.dot(&p) >= cos * range)
        });
    }

    /// Notes the centres of the other `expected` boards within twice `reach` of `centre`:
    /// where two expected boards stand close, each point is the nearer one's, so the search
    /// about one board never fuses it with its neighbour's face.
    pub(super) fn set_rivals(&mut self, expected: &[Se3], centre: Vec3, reach: f64) {
        self.rivals.clear();
        let close = |c: &Vec3| c != &centre && (c - centre).norm() < 2.0 * reach;
        self.rivals.extend(expected.iter().map(|e| e.translation).filter(close));
    }

    /// The plane parallel to the expected board's through the densest band
    /// (twice the plane tolerance wide) of offsets within [`EXPECTED_BAND_M`] of it, among
    /// the points within `reach` of the expected centre; `None` when no point is there.
    pub(super) fn densest_band(
        &mut self,
        pose: &Se3,
        reach: f64,
        sweep: &Sweep,
        config: &HoleConfig,
    ) -> Option<(Vec3, Vec3)> {
        let (c, n) = (pose.translation, pose.rotation.column(2).into_owned());
        let bins = (2.0 * EXPECTED_BAND_M / OFFSET_BIN_M) as usize;
        self.hist.clear();
        self.hist.resize(bins, 0);
        for p in sweep.points().iter().map(point_of) {
            let d = p - c;
            let offset = n.dot(&d);
            let within = d.norm_squared() <= reach * reach && nearest_to(&self.rivals, &p, &c);
            if within && offset.abs() < EXPECTED_BAND_M {
                let bin = ((offset + EXPECTED_BAND_M) / OFFSET_BIN_M) as usize;
                self.hist[bin.min(bins - 1)] += 1;
            }
        }
        let width = ((2.0 * config.plane_tolerance_m / OFFSET_BIN_M) as usize).clamp(1, bins);
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
    pub(super) fn gather(
        &self,
        (centre, radius): (Vec3, f64),
        (c, n): (Vec3, Vec3),
        sweep: &Sweep,
        config: &HoleConfig,
        seg: &mut Vec<Vec3>,
    ) {
        let tol = config.plane_tolerance_m;
        seg.clear();
        let rivals = &self.rivals;
        let within = |p: &Vec3| {
            (p - centre).norm_squared() <= radius * radius && nearest_to(rivals, p, &centre)
        };
        let points = sweep.points().iter().map(point_of);
        seg.extend(points.filter(|p| within(p) && n.dot(&(*p - c)).abs() < tol));
    }
}

/// Whether `p` is at least as near `centre` as every one of `rivals`.
fn nearest_to(rivals: &[Vec3], p: &Vec3, centre: &Vec3) -> bool {
    let own = (p - centre).norm_squared();
    rivals.iter().all(|r| own <= (p - r).norm_squared())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Mat3;
    use crate::lidar::Point;

    /// The band about the board's own plane, 5 cm behind where it is expected, is found
    /// among the returns of a sparser wall 20 cm behind it.
    #[test]
    fn the_densest_band_finds_the_board_off_its_expected_plane() {
        let mut points = Vec::new();
        for (x, share) in [(5.05, 1), (5.2, 3)] {
            for i in -20..=20 {
                for j in (-20..=20).step_by(share) {
                    let (y, z) = (0.02 * i as f64, 0.02 * j as f64);
                    let p = Point { x: x as f32, y: y as f32, z: z as f32, ..Point::default() };
                    points.push(p);
                }
            }
        }
        let mut sweep = Sweep::default();
        let config = HoleConfig::default();
        sweep.load(&points, &config);
        // Board z (its normal) along the LiDAR's x, 5 m ahead.
        let rotation = Mat3::new(0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0);
        let pose = Se3 { rotation, translation: Vec3::new(5.0, 0.0, 0.0) };
        let mut expected = Expected::default();
        expected.set_rivals(&[pose], pose.translation, 1.0);
        let (c, n) = expected.densest_band(&pose, 1.0, &sweep, &config).expect("a band");
        assert!((n - Vec3::x()).norm() < 1e-12);
        assert!((c.x - 5.05).abs() < config.plane_tolerance_m, "band at {:.3} m", c.x);
    }
}
