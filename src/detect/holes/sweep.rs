//! The sweep as the detector keeps it: the returns within range, a census of the sensor's
//! scan lines (elevation bins holding returns: no ring numbers or beam table needed) and
//! every return indexed by scan line and azimuth, which tells what a stretch of a line
//! returned ([`Sweep::returns_in_front`]).

use core::f64::consts::PI;

use crate::geometry::Vec3;
use crate::lidar::Point;

use super::HoleConfig;

/// Largest elevation step (rad) between returns of one scan line ([`line_end`]).
pub(super) const LINE_GAP_RAD: f64 = 0.06 * (PI / 180.0);

/// Elevation bins of the sweep's scan-line census.
const RING_BIN_DEG: f64 = 0.05;
const RING_BINS: usize = (180.0 / RING_BIN_DEG) as usize + 1;

/// The sweep's workspace, sized by the largest sweep seen.
#[derive(Debug, Default)]
pub(super) struct Sweep {
    /// The returns within range, as the sweep holds them (f32: half a `Vec3`'s memory for
    /// the largest buffer a rig's daemon makes; [`point_of`] gives the same f64 values the
    /// sweep's f32 would).
    pts: Vec<[f32; 3]>,
    /// Returns per elevation bin ([`RING_BIN_DEG`]): the census of the scan lines.
    rings: Vec<u32>,
    /// Every return as (azimuth, range, elevation), by elevation bin (bin `k` at
    /// `beams[bin_start[k]..bin_start[k + 1]]`), each bin by azimuth.
    beams: Vec<(f32, f32, f32)>,
    bin_start: Vec<u32>,
    /// The next free slot of each bin while `beams` is filled.
    bin_fill: Vec<u32>,
    /// The census's scan lines, by elevation.
    lines: Vec<ScanLine>,
    /// One line's azimuths while its step is measured.
    azimuths: Vec<f32>,
}

/// One of the sensor's scan lines as the sweep shows it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct ScanLine {
    /// Mean elevation of its returns (rad).
    pub(super) elevation: f64,
    /// The azimuth step (rad) between its returns that most are within: its beams' step in
    /// one sweep (the beams that returned nothing, sky, glass, the far side of a door, do
    /// not stretch it), about their mean spacing in sweeps laid over each other
    /// ([`upper_quartile_step`]).
    pub(super) step: f64,
}

impl Sweep {
    /// Keeps the points within the range limits and learns the sweep's scan lines from them.
    pub(super) fn load(&mut self, points: &[Point], config: &HoleConfig) {
        let (near, far) = config.range_m;
        self.pts.clear();
        // Exactly the sweep's size, not a doubling's slack (the daemon frees it after each
        // run, `release_workspace`).
        self.pts.reserve_exact(points.len());
        for p in points {
            let r = p.position().norm();
            if !r.is_finite() || r < near || r > far {
                continue;
            }
            self.pts.push([p.x, p.y, p.z]);
        }
        self.learn_rings();
        self.index_beams();
        self.learn_lines();
    }

    /// The returns within range.
    pub(super) fn points(&self) -> &[[f32; 3]] {
        &self.pts
    }

    /// Keeps only the returns `keep` accepts; the scan-line census and the beam index stay
    /// the whole sweep's.
    pub(super) fn keep_points(&mut self, keep: impl FnMut(&[f32; 3]) -> bool) {
        self.pts.retain(keep);
    }

    /// Frees the buffers sized by the sweep (the census's fixed bins stay).
    pub(super) fn release(&mut self) {
        self.pts = Vec::new();
        self.beams = Vec::new();
        self.bin_start = Vec::new();
        self.bin_fill = Vec::new();
        self.azimuths = Vec::new();
    }

    /// Returns of the scan line at elevation `e` between azimuths `lo` and `hi` (open
    /// interval, rad) that lie more than `margin` in front of the plane (`c`, `n`, `n·c > 0`).
    pub(super) fn returns_in_front(
        &self,
        e: f64,
        (lo, hi): (f64, f64),
        (c, n): (Vec3, Vec3),
        margin: f64,
    ) -> usize {
        let d = n.dot(&c);
        let (lo, hi) = (lo as f32, hi as f32);
        let mut front = 0usize;
        for bin in ring_bin(e - LINE_GAP_RAD)..=ring_bin(e + LINE_GAP_RAD) {
            let beams = &self.beams[self.bin_start[bin] as usize..self.bin_start[bin + 1] as usize];
            let from = beams.partition_point(|q| q.0 <= lo);
            for &(az, range, el) in beams[from..].iter().take_while(|q| q.0 < hi) {
                let (el, az) = (f64::from(el), f64::from(az));
                if (el - e).abs() >= LINE_GAP_RAD {
                    continue;
                }
                let u = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
                let to_plane = d / n.dot(&u);
                if to_plane > 0.0 && f64::from(range) < to_plane - margin {
                    front += 1;
                }
            }
        }
        front
    }

    /// The sensor's scan lines as this sweep shows them, by elevation.
    pub(super) fn scan_lines(&self) -> &[ScanLine] {
        &self.lines
    }

    /// Ranges of the returns of the scan line at elevation `e` between azimuths `lo` and
    /// `hi` (rad, half-open).
    pub(super) fn line_returns(
        &self,
        e: f64,
        (lo, hi): (f64, f64),
    ) -> impl Iterator<Item = f64> + '_ {
        let (lo, hi) = (lo as f32, hi as f32);
        (ring_bin(e - LINE_GAP_RAD)..=ring_bin(e + LINE_GAP_RAD)).flat_map(move |bin| {
            let beams = &self.beams[self.bin_start[bin] as usize..self.bin_start[bin + 1] as usize];
            let from = beams.partition_point(|q| q.0 < lo);
            beams[from..]
                .iter()
                .take_while(move |q| q.0 < hi)
                .filter(move |q| (f64::from(q.2) - e).abs() < LINE_GAP_RAD)
                .map(|q| f64::from(q.1))
        })
    }

    /// The sensor's scan lines with an elevation between `lo` and `hi` (rad): runs of
    /// occupied census bins, each with a few returns (not a stray point).
    pub(super) fn lines_between(&self, lo: f64, hi: f64) -> usize {
        let mut lines = 0;
        let mut inside = false;
        for b in ring_bin(lo)..=ring_bin(hi) {
            let occupied = self.rings[b] >= 3;
            if occupied && !inside {
                lines += 1;
            }
            inside = occupied;
        }
        lines
    }

    /// The sensor's scan lines as seen in this sweep: elevation bins (0.05°) holding
    /// returns, so no ring numbers or beam table are needed.
    #[inline(never)]
    fn learn_rings(&mut self) {
        self.rings.clear();
        self.rings.resize(RING_BINS, 0);
        for p in self.pts.iter().map(point_of) {
            self.rings[ring_bin(elevation(&p))] += 1;
        }
    }

    /// Fills `beams` from `pts`: a counting sort by elevation bin (`rings` holds the
    /// counts), then each bin by azimuth (an unstable sort: it allocates nothing). A
    /// counting sort first, as the sweep's bins are few and large, instead of one sort of
    /// every return on (bin, azimuth).
    #[inline(never)]
    fn index_beams(&mut self) {
        self.bin_start.clear();
        self.bin_start.push(0);
        for &count in &self.rings {
            let last = *self.bin_start.last().unwrap_or(&0);
            self.bin_start.push(last + count);
        }
        self.beams.clear();
        self.beams.resize(self.pts.len(), (0.0, 0.0, 0.0));
        self.bin_fill.clear();
        self.bin_fill.extend_from_slice(&self.bin_start);
        for p in self.pts.iter().map(point_of) {
            let e = elevation(&p);
            let slot = &mut self.bin_fill[ring_bin(e)];
            self.beams[*slot as usize] = (p.y.atan2(p.x) as f32, p.norm() as f32, e as f32);
            *slot += 1;
        }
        for k in 0..RING_BINS {
            let (from, to) = (self.bin_start[k] as usize, self.bin_start[k + 1] as usize);
            self.beams[from..to].sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        }
    }

    /// The census's scan lines ([`ScanLine`]): each run of occupied elevation bins, as in
    /// [`Sweep::lines_between`], with its mean elevation and azimuth step.
    #[inline(never)]
    fn learn_lines(&mut self) {
        self.lines.clear();
        let mut b = 0;
        while b < RING_BINS {
            if self.rings[b] < 3 {
                b += 1;
                continue;
            }
            let first = b;
            while b < RING_BINS && self.rings[b] >= 3 {
                b += 1;
            }
            let beams = &self.beams[self.bin_start[first] as usize..self.bin_start[b] as usize];
            let elevation = beams.iter().map(|q| f64::from(q.2)).sum::<f64>() / beams.len() as f64;
            self.azimuths.clear();
            self.azimuths.extend(beams.iter().map(|q| q.0));
            // A bin is sorted by azimuth already; a line over several bins is merged here.
            if b - first > 1 {
                self.azimuths.sort_unstable_by(f32::total_cmp);
            }
            let step = upper_quartile_step(&mut self.azimuths);
            self.lines.push(ScanLine { elevation, step });
        }
    }
}

/// The third quartile of the positive steps between sorted `azimuths` (rad), computed
/// in place; zero when there is none. A dual-return sensor's second return at the same
/// azimuth is no step. One sweep's steps are all the beams' step but where beams returned
/// nothing (one longer step each, far fewer than a quarter of them in a room); in sweeps
/// of a standing vehicle laid over each other at unrelated phases the steps are the
/// sweeps' interleaving, whose third quartile is over their mean.
fn upper_quartile_step(azimuths: &mut Vec<f32>) -> f64 {
    // Steps below 0.005° are a second return of one beam, not the next beam.
    const SAME_BEAM_RAD: f32 = 0.005 * (PI as f32 / 180.0);
    let mut kept = 0;
    for k in 1..azimuths.len() {
        let step = azimuths[k] - azimuths[k - 1];
        if step > SAME_BEAM_RAD {
            azimuths[kept] = step;
            kept += 1;
        }
    }
    azimuths.truncate(kept);
    if azimuths.is_empty() {
        return 0.0;
    }
    let at = azimuths.len() * 3 / 4;
    f64::from(*azimuths.select_nth_unstable_by(at, f32::total_cmp).1)
}

/// A return as the detector keeps it, in the solver's type (the same values as the
/// sweep's f32 converted directly).
pub(super) fn point_of(p: &[f32; 3]) -> Vec3 {
    Vec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

/// Azimuth difference `a` (rad, within 2π of the interval) brought into [−π, π]: the way
/// round that is shorter. Values already in it are returned as they are.
pub(super) fn wrap_azimuth(a: f64) -> f64 {
    if a > PI {
        a - 2.0 * PI
    } else if a < -PI {
        a + 2.0 * PI
    } else {
        a
    }
}

/// Elevation angle of `p` seen from the sensor (rad): what tells its scan line.
pub(super) fn elevation(p: &Vec3) -> f64 {
    p.z.atan2(p.x.hypot(p.y))
}

/// The elevation bin ([`RING_BIN_DEG`]) of elevation `e` (rad).
fn ring_bin(e: f64) -> usize {
    (((e.to_degrees() + 90.0) / RING_BIN_DEG) as usize).min(RING_BINS - 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Returns on `rings` elevations (degrees), `per_ring` each, 5 m ahead.
    fn rings(elevations: &[f64], per_ring: usize) -> Vec<Point> {
        let mut points = Vec::new();
        for &e in elevations {
            let e = e.to_radians();
            for k in 0..per_ring {
                let az = (k as f64 * 0.2 - 10.0).to_radians();
                let p = Vec3::new(e.cos() * az.cos(), e.cos() * az.sin(), e.sin()) * 5.0;
                points.push(Point {
                    x: p.x as f32,
                    y: p.y as f32,
                    z: p.z as f32,
                    ..Point::default()
                });
            }
        }
        points
    }

    /// The census counts the lines between two elevations, not a stray return.
    #[test]
    fn the_census_counts_scan_lines_between_elevations() {
        let mut points = rings(&[-2.0, -1.0, 0.0, 1.0, 4.0], 50);
        points.extend(rings(&[2.5], 1));
        let mut sweep = Sweep::default();
        sweep.load(&points, &HoleConfig::default());
        assert_eq!(sweep.points().len(), points.len());
        let between = |lo: f64, hi: f64| sweep.lines_between(lo.to_radians(), hi.to_radians());
        assert_eq!(between(-1.5, 3.0), 3);
        assert_eq!(between(-3.0, 5.0), 5);
    }

    /// Returns of a line in front of a plane count within the azimuths asked, those on it
    /// and beyond do not.
    #[test]
    fn returns_in_front_count_the_line_between_two_azimuths() {
        let mut sweep = Sweep::default();
        sweep.load(&rings(&[0.0], 101), &HoleConfig::default());
        // The plane x = 6 m: the returns, 5 m away, lie about 1 m in front of it.
        let plane = (Vec3::new(6.0, 0.0, 0.0), Vec3::new(1.0, 0.0, 0.0));
        let (lo, hi) = ((-1.05f64).to_radians(), 1.05f64.to_radians());
        assert_eq!(sweep.returns_in_front(0.0, (lo, hi), plane, 0.5), 11);
        assert_eq!(sweep.returns_in_front(0.0, (lo, hi), plane, 1.5), 0);
        assert_eq!(sweep.returns_in_front(0.5f64.to_radians(), (lo, hi), plane, 0.5), 0);
    }
}
