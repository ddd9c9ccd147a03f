//! Sweep-to-sweep motion, cheaply and robustly: each sweep is binned into a coarse
//! azimuth × ring range image (nearest return per cell) and the motion is the median
//! absolute range change over the cells filled in both. A few moving people or flickering
//! returns do not move the median; the vehicle rolling moves every cell.

use crate::lidar::Point;

/// A coarse range image of one sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct RangeImage {
    az_bins: usize,
    rings: usize,
    /// Nearest range per cell, metres; 0 = empty.
    range: Vec<f32>,
}

/// Fewer common cells than this: no motion figure.
pub const MIN_COMMON_CELLS: usize = 32;

impl RangeImage {
    /// An empty image of `az_bins` azimuth bins × `rings` rings.
    pub fn new(az_bins: usize, rings: usize) -> Self {
        RangeImage {
            az_bins: az_bins.max(1),
            rings: rings.max(1),
            range: vec![0.0; az_bins.max(1) * rings.max(1)],
        }
    }

    /// Replaces the content with `points` (rings beyond the image are ignored).
    pub fn fill(&mut self, points: &[Point]) {
        self.range.fill(0.0);
        for p in points {
            let r = (p.x * p.x + p.y * p.y + p.z * p.z).sqrt();
            let ring = p.ring as usize;
            if !(r > 0.0 && r.is_finite()) || ring >= self.rings {
                continue;
            }
            let az = p.y.atan2(p.x); // −π..π
            let bin = ((az + core::f32::consts::PI) / core::f32::consts::TAU * self.az_bins as f32)
                as usize;
            let cell = &mut self.range[ring * self.az_bins + bin.min(self.az_bins - 1)];
            if *cell == 0.0 || r < *cell {
                *cell = r;
            }
        }
    }

    /// Cells holding a return.
    pub fn filled(&self) -> usize {
        self.range.iter().filter(|&&r| r > 0.0).count()
    }
}

/// Median absolute range change (m) between two images of the same shape; `None` if they
/// differ in shape or share fewer than [`MIN_COMMON_CELLS`] filled cells.
pub fn sweep_motion(a: &RangeImage, b: &RangeImage, scratch: &mut Vec<f32>) -> Option<f32> {
    if a.az_bins != b.az_bins || a.rings != b.rings {
        return None;
    }
    scratch.clear();
    scratch.extend(
        a.range
            .iter()
            .zip(&b.range)
            .filter(|(x, y)| **x > 0.0 && **y > 0.0)
            .map(|(x, y)| (x - y).abs()),
    );
    if scratch.len() < MIN_COMMON_CELLS {
        return None;
    }
    let mid = scratch.len() / 2;
    let (_, m, _) = scratch.select_nth_unstable_by(mid, f32::total_cmp);
    Some(*m)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ring of walls around the sensor at `d` metres (plus `dx` forward shift).
    fn scene(dx: f32, rings: u16) -> Vec<Point> {
        let mut pts = Vec::new();
        for ring in 0..rings {
            for i in 0..720 {
                let a = i as f32 * 0.5f32.to_radians();
                let d = 8.0 + 2.0 * (3.0 * a).sin();
                pts.push(Point {
                    x: d * a.cos() - dx,
                    y: d * a.sin(),
                    z: ring as f32 * 0.1 - 1.0,
                    ring,
                    ..Point::default()
                });
            }
        }
        pts
    }

    #[test]
    fn still_scene_has_no_motion_and_a_shift_shows() {
        let mut a = RangeImage::new(180, 16);
        let mut b = RangeImage::new(180, 16);
        let mut s = Vec::new();
        a.fill(&scene(0.0, 16));
        b.fill(&scene(0.0, 16));
        assert!(a.filled() > 2000);
        assert_eq!(sweep_motion(&a, &b, &mut s), Some(0.0));
        b.fill(&scene(0.10, 16));
        let m = sweep_motion(&a, &b, &mut s).unwrap();
        assert!(m > 0.02 && m < 0.12, "10 cm forward: median range change {m}");
    }

    #[test]
    fn outliers_do_not_move_the_median() {
        let mut a = RangeImage::new(180, 16);
        let mut b = RangeImage::new(180, 16);
        let mut s = Vec::new();
        a.fill(&scene(0.0, 16));
        let mut pts = scene(0.0, 16);
        // A person walking past: 10 % of the returns much nearer.
        for p in pts.iter_mut().step_by(10) {
            p.x *= 0.3;
            p.y *= 0.3;
        }
        b.fill(&pts);
        assert!(sweep_motion(&a, &b, &mut s).unwrap() < 0.005);
    }

    #[test]
    fn too_little_overlap_or_other_shape_gives_none() {
        let a = RangeImage::new(180, 16);
        let mut s = Vec::new();
        assert_eq!(sweep_motion(&a, &a, &mut s), None);
        assert_eq!(sweep_motion(&a, &RangeImage::new(90, 16), &mut s), None);
    }
}
