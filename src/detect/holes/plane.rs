//! The board's plane: fitted on the points gathered about a start plane (a plane group's,
//! or where a board is expected) once only the board's scan-line runs are kept
//! ([`ScanLines::keep_board_runs`]), and the points gathered again about the fit while it
//! still moves: the start plane, from voxels that may cover part of the board, can be
//! degrees off. The fit is along the beams ([`fit_plane`]): unbiased for range noise.

use crate::geometry::{Mat3, Vec3};
use crate::target::BoardSpec;

use super::scan_lines::{scan_lines, ScanLines};
use super::search::{to_board, Fit};
use super::sweep::{elevation, Sweep};
use super::HoleConfig;

/// A fitted plane: a point on it (the points' centroid moved onto it), its unit normal and
/// the RMS distance of the points from it.
pub(super) type PlaneFit = (Vec3, Vec3, f64);

/// A board's points are gathered again about their refitted plane while it moves more than
/// [`REGATHER_ANGLE_RAD`] from the plane they were gathered about, at most this often.
const REGATHER_ROUNDS: usize = 3;
/// The turn (rad) of a refitted plane beyond which the board's points are gathered, or the
/// board placed, again on it.
pub(super) const REGATHER_ANGLE_RAD: f64 = 0.3 * core::f64::consts::PI / 180.0;
/// A scan line whose mean residual from the board's plane exceeds this many of its σ is
/// left out of the plane fit ([`BoardPlane::lines_agreeing`]): about 1 in 2000 lines of
/// pure noise.
const LINE_Z: f64 = 3.5;

/// The plane workspace: one board's points and the fit's scratch.
#[derive(Debug, Default)]
pub(super) struct BoardPlane {
    /// The board's points (LiDAR frame), within the band of the fitted plane.
    pub(super) points: Vec<Vec3>,
    /// Half-width (m) of the band about the board's plane that `points` was last cut to.
    pub(super) band: f64,
    residuals: Vec<f64>,
    /// The points within the band as (elevation, index), by elevation.
    lines: Vec<(f64, u32)>,
    keep: Vec<bool>,
    /// The returns on a placed board ([`BoardPlane::within_outline`]).
    on_board: Vec<Vec3>,
}

impl BoardPlane {
    /// Gathers the points (`gather` fills `points` about a plane) about the plane `start`,
    /// fits the board's plane on them ([`BoardPlane::fit`]) and gathers again about the
    /// fit while it moves: the plane gathered about may be degrees off (a group's, from
    /// planar voxels that cover part of the board: 5° on boards pitched 26–34° at 6–8 m in
    /// the random-room study, whose band left the board's far end out and whose refit, on
    /// the rest, stayed 2° off, putting holes off the tilt axis 2–4 cm out; or an expected
    /// pose's).
    pub(super) fn settle(
        &mut self,
        start: (Vec3, Vec3),
        mut gather: impl FnMut(&mut Vec<Vec3>, (Vec3, Vec3)),
        runs: &mut ScanLines,
        sweep: &Sweep,
        board: (&BoardSpec, &HoleConfig),
    ) -> Option<PlaneFit> {
        gather(&mut self.points, start);
        let mut plane = self.fit(start, runs, sweep, board)?;
        let mut previous = start.1;
        for _ in 0..REGATHER_ROUNDS {
            if plane.1.angle(&previous) < REGATHER_ANGLE_RAD {
                break;
            }
            previous = plane.1;
            gather(&mut self.points, (plane.0, plane.1));
            let Some(refit) = self.fit((plane.0, plane.1), runs, sweep, board) else { break };
            plane = refit;
        }
        Some(plane)
    }

    /// Frees the buffers sized by the last sweep.
    pub(super) fn release(&mut self) {
        self.points = Vec::new();
        self.on_board = Vec::new();
    }

    /// The plane (centroid, normal away from the sensor, RMS) of the returns in `points`
    /// that lie on the board placed at `fit` (within its outline, outside its holes) on the
    /// plane (`c`, `n`) that `flat` (each point's plane-frame position) was projected onto;
    /// `None` with too few of them.
    pub(super) fn within_outline(
        &mut self,
        fit: &Fit,
        (c, n): (Vec3, Vec3),
        flat: &[[f64; 2]],
        (spec, config): (&BoardSpec, &HoleConfig),
    ) -> Option<PlaneFit> {
        let (hw, hh, r) = (spec.width / 2.0, spec.height / 2.0, spec.hole_radius);
        self.on_board.clear();
        for (p, f) in self.points.iter().zip(flat) {
            let (x, y) = to_board(fit.pose, f);
            let solid = spec.holes.iter().all(|h| (x - h[0]).hypot(y - h[1]) > r);
            if x.abs() <= hw && y.abs() <= hh && solid {
                self.on_board.push(*p);
            }
        }
        if self.on_board.len() < config.min_points {
            return None;
        }
        let (c, n, rms) = fit_plane(&self.on_board, c, n)?;
        Some((c, if n.dot(&c) < 0.0 { -n } else { n }, rms))
    }

    /// Keeps the board's scan-line runs in `points` (see [`ScanLines::keep_board_runs`]),
    /// refits their plane (starting from `c`, `n`) and keeps the points within its band:
    /// the plane's centroid, normal (towards the sensor's far side, `n·c > 0`) and RMS.
    fn fit(
        &mut self,
        (c, n): (Vec3, Vec3),
        runs: &mut ScanLines,
        sweep: &Sweep,
        board: (&BoardSpec, &HoleConfig),
    ) -> Option<PlaneFit> {
        let (mut c, mut n, mut rms) = (c, n, 0.0);
        runs.keep_board_runs(&mut self.points, (c, n), sweep, board);
        let tolerance = board.1.plane_tolerance_m;
        // The band kept about the plane is three robust σ of the residuals (their median
        // absolute value): clutter touching the board a few centimetres off its plane (a box
        // at its foot) inflates the RMS and would stay within 3 RMS, tilting the plane.
        // Each pass chooses its band from every gathered point, so points an earlier,
        // tilted band left out come back (cutting one tail of the noise at a board's end
        // would keep the plane tilted); the plane is fitted on the points in the band on
        // scan lines that agree with it (`points[..fitted]`, [`BoardPlane::lines_agreeing`]).
        let mut fitted = self.points.len();
        let mut keep = tolerance;
        for pass in 0..4 {
            (c, n, rms) = fit_plane(&self.points[..fitted], c, n)?;
            if pass == 3 {
                break;
            }
            self.residuals.clear();
            self.residuals.extend(self.points[..fitted].iter().map(|p| n.dot(&(p - c)).abs()));
            let mid = self.residuals.len() / 2;
            let mad = *self.residuals.select_nth_unstable_by(mid, f64::total_cmp).1;
            keep = (3.0 * 1.4826 * mad).clamp(0.01, tolerance);
            fitted = self.lines_agreeing((c, n), keep, 1.4826 * mad);
        }
        self.points.retain(|p| n.dot(&(p - c)).abs() < keep);
        self.band = keep;
        if n.dot(&c) < 0.0 {
            n = -n;
        }
        Some((c, n, rms))
    }

    /// Moves the points within `band` of the plane (`c`, `n`) on scan lines whose mean
    /// residual (of those points) is within [`LINE_Z`] of its σ (σ the points' own /
    /// √count) to the front of `points` and returns how many there are. Range noise is
    /// zero-mean along every line, so a line off the plane on average carries something
    /// else within the band: the edge of an occluder in front, clutter at the board's foot,
    /// a surface crossing the plane at a shallow angle. Left in the fit they tilt the plane
    /// by degrees, turning the projected points and so the hole mask's fit. When most
    /// points in the band disagree the plane itself is in doubt: all of them are fitted.
    fn lines_agreeing(&mut self, (c, n): (Vec3, Vec3), band: f64, sigma: f64) -> usize {
        self.lines.clear();
        for (i, p) in self.points.iter().enumerate() {
            if n.dot(&(p - c)).abs() < band {
                self.lines.push((elevation(p), i as u32));
            }
        }
        self.lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        self.keep.clear();
        self.keep.resize(self.points.len(), false);
        let mut agreeing = 0;
        for line in scan_lines(&self.lines) {
            let sum: f64 = line.iter().map(|&(_, i)| n.dot(&(self.points[i as usize] - c))).sum();
            let count = line.len() as f64;
            if (sum / count).abs() <= LINE_Z * sigma / count.sqrt() {
                agreeing += line.len();
                for &(_, i) in line {
                    self.keep[i as usize] = true;
                }
            }
        }
        if 2 * agreeing < self.lines.len() {
            for &(_, i) in &self.lines {
                self.keep[i as usize] = true;
            }
        }
        // The chosen points first, swapped in place (no buffer; every later step sorts).
        let mut next = 0;
        for i in 0..self.points.len() {
            if self.keep[i] {
                self.points.swap(next, i);
                self.keep.swap(next, i);
                next += 1;
            }
        }
        next
    }
}

/// The plane that best explains `points` (LiDAR frame, the sensor at the origin) as ranges
/// measured along their own beams: a point on the board's centroid, the unit normal and the
/// RMS distance of the points from the plane.
///
/// A LiDAR's noise lies along its beams, nearly parallel over one board, so an orthogonal
/// least-squares fit (the smallest eigenvector of the scatter) sees the board's scatter
/// plus σ²·b·bᵀ and turns the normal towards the beam by about σ²·cos θ·sin θ / λ (θ the
/// incidence, λ the points' variance across the few scan lines that cross the board):
/// 1–3° for a board pitched 30° at 7 m. Here the plane is m·x = 1 and each point gives
/// b̂·m = 1/r: the beam direction b̂ is exact and only the inverse range is noisy, so the
/// linear least squares is unbiased. Weights r̂⁴ (r̂ the range the `prior` plane predicts,
/// through `prior_c` with normal `prior_n`) make the residuals those of the range itself,
/// δ(1/r) ≈ −δr/r²; taken from the prior plane rather than the point's own range they carry
/// none of its noise.
fn fit_plane(points: &[Vec3], prior_c: Vec3, prior_n: Vec3) -> Option<PlaneFit> {
    if points.len() < 3 {
        return None;
    }
    let prior_d = prior_n.dot(&prior_c);
    let (mut normal, mut rhs, mut sum) = (Mat3::zeros(), Vec3::zeros(), Vec3::zeros());
    for p in points {
        let r = p.norm();
        if r < 1e-6 {
            continue;
        }
        let b = p / r;
        // A beam nearly along the prior plane predicts no sensible range: its own then.
        let predicted = prior_d / prior_n.dot(&b);
        let r_hat = if (0.5 * r..2.0 * r).contains(&predicted) { predicted } else { r };
        let w = r_hat.powi(4);
        normal += b * b.transpose() * w;
        rhs += b * (w / r);
        sum += p;
    }
    let m = normal.cholesky()?.solve(&rhs);
    let d = 1.0 / m.norm();
    let n = m * d;
    if !(d.is_finite() && n.iter().all(|v| v.is_finite())) {
        return None;
    }
    let centroid = sum / points.len() as f64;
    let c = centroid - n * (n.dot(&centroid) - d);
    let ss: f64 = points.iter().map(|p| (n.dot(p) - d).powi(2)).sum();
    Some((c, n, (ss / points.len() as f64).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::holes::voxels::{smallest_eigen, Moments};

    /// A board pitched 30° at 7 m, crossed by three scan lines 0.15 m apart, its ranges
    /// noisy along the beams (σ 2 cm): the points' scatter across the lines is so small that
    /// the noise's own scatter along the beams turns an orthogonal least-squares normal by
    /// about half a degree; the fit along the beams does not. Also its offset and RMS.
    #[test]
    fn plane_fit_along_the_beams_is_unbiased_for_range_noise() {
        let (pitch, range, sigma) = (30f64.to_radians(), 7.0, 0.02);
        let n_true = Vec3::new(pitch.cos(), 0.0, pitch.sin());
        let d_true = range * pitch.cos();
        let mut rng = crate::sim::rng::Rng::new(14);
        let mut points = Vec::new();
        for line in -1..=1 {
            let elevation = (0.15 * line as f64 / range).atan();
            for k in -20_000..=20_000 {
                let azimuth = 0.5 / range * k as f64 / 20_000.0;
                let (se, ce) = elevation.sin_cos();
                let b = Vec3::new(ce * azimuth.cos(), ce * azimuth.sin(), se);
                let r = d_true / n_true.dot(&b);
                points.push(b * (r + sigma * rng.normal()));
            }
        }
        let tilt = |n: Vec3| n.angle(&n_true).to_degrees();

        // The orthogonal fit, the prior the detector starts from.
        let mut m = Moments::default();
        points.iter().for_each(|p| m.add(p));
        let (c0, cov) = m.mean_cov();
        let (_, n0) = smallest_eigen(&cov);
        let n0 = if n0.dot(&c0) < 0.0 { -n0 } else { n0 };
        println!("orthogonal fit: normal {:.3}° off", tilt(n0));
        assert!(tilt(n0) > 0.3, "the orthogonal fit is biased: {:.3}°", tilt(n0));

        let (c, n, rms) = fit_plane(&points, c0, n0).unwrap();
        // The fitted plane's offset at the board's centre (the origin is 7 m away).
        let offset = n.dot(&(Vec3::new(range, 0.0, 0.0) - c));
        println!("fit along the beams: normal {:.3}° off, offset {:.2} mm", tilt(n), 1e3 * offset);
        assert!(tilt(n) < 0.1, "normal {:.3}° off", tilt(n));
        assert!(offset.abs() < 1e-3, "offset {:.2} mm", 1e3 * offset);
        // The orthogonal distance of range noise σ at incidence θ is σ·cos θ.
        assert!((rms / (sigma * pitch.cos()) - 1.0).abs() < 0.03, "rms {:.2} mm", rms * 1e3);
    }
}
