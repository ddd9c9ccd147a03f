//! Placement: every hole — well seen or not — placed through the rigid board model at the
//! pose the search found, with an uncertainty each. A hole's σ in the plane is the larger
//! of what the plateau's pose covariance and the edge crossings' give it (each end of a
//! scan line and each side of a gap crossed an edge of the model within one of the line's
//! spacings: a position known to spacing/√12 along the line; the plateau alone can be far
//! too narrow when one row of holes is crossed), plus the plane's offset and tilt errors,
//! the latter divided by the cosine of the beam's incidence (the points were moved along
//! their beams). On the simulator the RMS of error / σ is 0.63 (Pandar64-like) and 0.52
//! (VLP-32C-like) over 12 scenes each (`tests/it/holes_sim.rs`,
//! `sigma_calibration_over_many_scenes`), 0.70–0.79 over 600 random rooms per model:
//! cautious, since many crossings together pin an edge closer than their quantisation
//! taken as Gaussian, where the plateau alone (1.04) left 4–18 holes per 200 rooms beyond
//! 3σ against 0–10 now.

use crate::geometry::{Mat3, Se3, Vec3};
use crate::target::BoardSpec;

use super::checks::HoleLines;
use super::projection::{Frame, Projection};
use super::scan_lines::scan_lines;
use super::search::{to_board, Fit};
use super::LidarBoard;

/// The placement's workspace, reused from board to board.
#[derive(Debug, Default)]
pub(super) struct Placement {
    /// One scan line's returns in board coordinates ([`Placement::edge_covariance`]).
    line_points: Vec<[f64; 2]>,
    /// One line's returns as (plane x, index), by x.
    run: Vec<(f64, u32)>,
    spacings: Vec<f64>,
}

impl Placement {
    /// Covariance of the in-plane pose (x, y, yaw; row-major 3×3) that the scan lines'
    /// edge crossings allow, whatever the search: where a line leaves or re-enters the
    /// board (its ends, the sides of its gaps) it crossed an edge of the model (outline or
    /// hole) somewhere within one of its own spacings, a position known to that spacing
    /// over √12 along the line. Each crossing that lies near an edge at `fit` pins the pose
    /// along that edge's normal, and its distance from the board's centre pins the yaw;
    /// crossings far from every edge (an occluder's) pin nothing. `None` when the
    /// crossings leave a direction free. The mask's plateau can be far narrower than this
    /// when only one row of holes is crossed (the random-room study's VLP-32C room 383: a board placed
    /// turned 3°, its plateau's yaw σ 0.37°).
    pub(super) fn edge_covariance(
        &mut self,
        fit: &Fit,
        ev: &mut Projection,
        spec: &BoardSpec,
    ) -> Option<[f64; 9]> {
        let (hw, hh, r) = (spec.width / 2.0, spec.height / 2.0, spec.hole_radius);
        let (sy, cy) = fit.pose[2].sin_cos();
        let mut info = Mat3::zeros();
        ev.lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        for line in scan_lines(&ev.lines).filter(|line| line.len() >= 3) {
            self.line_points.clear();
            let flat = &ev.flat;
            self.run.clear();
            self.run.extend(line.iter().map(|&(_, i)| (flat[i as usize][0], i)));
            self.run.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            self.line_points.extend(self.run.iter().map(|&(_, i)| {
                let (x, y) = to_board(fit.pose, &flat[i as usize]);
                [x, y]
            }));
            let pts = &self.line_points;
            self.spacings.clear();
            self.spacings
                .extend(pts.windows(2).map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1])));
            let mid = self.spacings.len() / 2;
            let spacing = *self.spacings.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
            if spacing.is_nan() || spacing <= 1e-4 {
                continue;
            }
            // Where the line crosses the model's edges: its two ends, outwards, and either
            // side of every gap wider than its sampling, inwards.
            let along = |a: &[f64; 2], b: &[f64; 2]| {
                let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
                let l = dx.hypot(dy).max(1e-9);
                [dx / l, dy / l]
            };
            let last = pts.len() - 1;
            let mut crossings: heapless::Vec<([f64; 2], [f64; 2]), 64> = heapless::Vec::new();
            let s0 = along(&pts[1], &pts[0]);
            let _ = crossings.push((pts[0], s0));
            let s1 = along(&pts[last - 1], &pts[last]);
            let _ = crossings.push((pts[last], s1));
            for w in pts.windows(2) {
                let d = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
                if d > 1.5 * spacing {
                    let s = along(&w[0], &w[1]);
                    let _ = crossings.push((w[0], s));
                    let _ = crossings.push((w[1], [-s[0], -s[1]]));
                }
            }
            let sigma2 = (spacing * spacing / 12.0).max(0.002f64.powi(2));
            for &(p, s) in &crossings {
                // The crossing lies half a spacing beyond the return, on average.
                let q = [p[0] + s[0] * spacing / 2.0, p[1] + s[1] * spacing / 2.0];
                let Some((distance, m)) = nearest_edge(q, s, (hw, hh, r), &spec.holes) else {
                    continue;
                };
                if distance > spacing.max(0.02) {
                    continue;
                }
                let cos = (m[0] * s[0] + m[1] * s[1]).abs();
                // d(distance)/d(x, y, yaw): the edge's normal in the plane frame, and the
                // turn of the point about the board's centre.
                let g = Vec3::new(
                    -(cy * m[0] - sy * m[1]),
                    -(sy * m[0] + cy * m[1]),
                    -(m[0] * -q[1] + m[1] * q[0]),
                );
                info += g * g.transpose() / (sigma2 * cos * cos);
            }
        }
        let cov = info.try_inverse()?;
        let mut out = [0.0; 9];
        for i in 0..3 {
            for j in 0..3 {
                out[i * 3 + j] = cov[(i, j)];
            }
        }
        out.iter().all(|v| v.is_finite()).then_some(out)
    }
}

/// Board → LiDAR for an in-plane pose (x, y, yaw) in the plane frame (c; ex, ey, n).
pub(super) fn pose([tx, ty, yaw]: [f64; 3], (c, ex, ey, n): Frame) -> Se3 {
    let (s, co) = yaw.sin_cos();
    let bx = ex * co + ey * s;
    let by = -ex * s + ey * co;
    Se3 { rotation: Mat3::from_columns(&[bx, by, n]), translation: c + ex * tx + ey * ty }
}

/// The plane's uncertainty: its offset along the normal and its tilt about either in-plane
/// axis, from the RMS `rms` of its `points` points and their spread in the plane (`flat`).
pub(super) fn plane_sigma(flat: &[[f64; 2]], rms: f64, points: usize) -> [f64; 3] {
    let (su, sv) = flat.iter().fold((0.0, 0.0), |(a, b), p| (a + p[0] * p[0], b + p[1] * p[1]));
    [rms / (points as f64).sqrt(), rms / su.sqrt(), rms / sv.sqrt()]
}

/// The placed board at `fit`; each hole's σ in the plane is the larger of what the
/// plateau's spread and the edge crossings' covariance `edges` give it (two estimates
/// of one spread: the more cautious is kept, not their sum).
pub(super) fn board(
    fit: &Fit,
    edges: &[f64; 9],
    (c, ex, ey, n): Frame,
    (plane_sigma, rms, inliers): ([f64; 3], f64, usize),
    lines: HoleLines,
    spec: &BoardSpec,
) -> LidarBoard {
    let pose = pose(fit.pose, (c, ex, ey, n));
    let (s, co) = fit.pose[2].sin_cos();
    let mut holes = heapless::Vec::new();
    let mut sigma = heapless::Vec::new();
    let cv = &fit.cov;
    for h in &spec.holes {
        let centre = pose.act(&Vec3::new(h[0], h[1], 0.0));
        let _ = holes.push(centre);
        // Hole offset in the plane frame; its Jacobian wrt (tx, ty, yaw).
        let (px, py) = (co * h[0] - s * h[1], s * h[0] + co * h[1]);
        let j = [[1.0, 0.0, -py], [0.0, 1.0, px]];
        let in_plane = |cv: &[f64; 9]| {
            let mut var = 0.0;
            for row in &j {
                for a in 0..3 {
                    for b in 0..3 {
                        var += row[a] * cv[a * 3 + b] * row[b];
                    }
                }
            }
            var
        };
        let mut var = in_plane(cv).max(in_plane(edges));
        // The plane's offset, and its tilts times the hole's lever arm. The points
        // were moved along their beams onto the plane, so a plane error δ along the
        // normal moves the hole by δ / cos(incidence) along its beam.
        let (lu, lv) = (fit.pose[0] + px, fit.pose[1] + py);
        let [offset, tilt_u, tilt_v] = plane_sigma;
        let cos = n.dot(&centre.normalize()).abs().max(0.3);
        var += (offset * offset + (lu * tilt_u).powi(2) + (lv * tilt_v).powi(2)) / (cos * cos);
        let _ = sigma.push(var.sqrt());
    }
    LidarBoard {
        holes,
        hole_sigma_m: sigma,
        hole_scan_lines: lines,
        pose,
        normal: n,
        inliers,
        plane_rms_m: rms,
        pose_sigma: [0, 4, 8].map(|k| cv[k].max(edges[k]).sqrt()),
    }
}

/// Adds `board` to `out` unless a board placed before stands where it does; of two
/// such the one fitted on more returns stays. Two groups can settle on one board: a
/// stand or a box below it grows into a region of its own whose gathered plane turns
/// onto the board's, placing it again a few degrees off on fewer of its returns
/// (the random-room study's Pandar40P room 208, Pandar64 room 347).
pub(super) fn keep_distinct(board: LidarBoard, out: &mut Vec<LidarBoard>, spec: &BoardSpec) {
    let apart = 0.5 * spec.width.min(spec.height);
    let same =
        out.iter().position(|b| (b.pose.translation - board.pose.translation).norm() < apart);
    match same {
        Some(k) if out[k].inliers >= board.inliers => {}
        Some(k) => out[k] = board,
        None => out.push(board),
    }
}

/// Distance from board point `q` to the nearest edge of the model (outline of half-size
/// (`hw`, `hh`), holes of radius `r` at `holes`) that a line along `s` crosses at 30° or
/// more (a line running along an edge does not tell where it is), and that edge's unit
/// normal there.
fn nearest_edge(
    q: [f64; 2],
    s: [f64; 2],
    (hw, hh, r): (f64, f64, f64),
    holes: &[[f64; 2]],
) -> Option<(f64, [f64; 2])> {
    let mut best: Option<(f64, [f64; 2])> = None;
    let mut consider = |d: f64, m: [f64; 2]| {
        let crossed = (m[0] * s[0] + m[1] * s[1]).abs() >= 0.5;
        if crossed && best.is_none_or(|b| d < b.0) {
            best = Some((d, m));
        }
    };
    if q[1].abs() <= hh {
        consider((q[0].abs() - hw).abs(), [q[0].signum(), 0.0]);
    }
    if q[0].abs() <= hw {
        consider((q[1].abs() - hh).abs(), [0.0, q[1].signum()]);
    }
    for h in holes {
        let (dx, dy) = (q[0] - h[0], q[1] - h[1]);
        let l = dx.hypot(dy);
        if l > 1e-9 {
            consider((l - r).abs(), [dx / l, dy / l]);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::holes::test_board;

    /// Scan lines across `spec` at board heights `rows` (plane frame = board frame),
    /// returns every `spacing` from a phase of their own, none in the holes: `flat` and
    /// `lines` as [`Projection::flatten`] leaves them.
    fn scanned(spec: &BoardSpec, rows: &[f64], spacing: f64) -> Projection {
        let mut projection = Projection::default();
        let (hw, r) = (spec.width / 2.0, spec.hole_radius);
        for (k, &y) in rows.iter().enumerate() {
            let phase = (k as f64 * 0.618).fract() * spacing;
            let mut x = -hw + phase;
            while x < hw {
                if spec.holes.iter().all(|h| (x - h[0]).hypot(y - h[1]) > r) {
                    projection.lines.push((k as f64 * 0.01, projection.flat.len() as u32));
                    projection.flat.push([x, y]);
                }
                x += spacing;
            }
        }
        projection
    }

    /// The edge crossings pin the board's turn through the holes and sides they reach:
    /// lines 4 cm apart over both rows of holes leave the yaw to about a tenth of a degree
    /// (the sides' ends, 7 mm each, on levers up to 0.46 m); lines over the lower row
    /// only, a few times less certain; and the position along x to about a spacing over
    /// √12 shared among the crossings.
    #[test]
    fn edge_crossings_pin_the_turn_by_the_rows_they_cross() {
        let spec = test_board();
        let fit = Fit::rough([0.0; 3]);
        let spacing = 0.025;
        let both: Vec<f64> = (0..24).map(|k| -0.46 + 0.04 * k as f64).collect();
        let lower: Vec<f64> = both.iter().copied().filter(|&y| y > 0.2).collect();
        let cov_both = Placement::default()
            .edge_covariance(&fit, &mut scanned(&spec, &both, spacing), &spec)
            .expect("pinned");
        let cov_lower = Placement::default()
            .edge_covariance(&fit, &mut scanned(&spec, &lower, spacing), &spec)
            .expect("pinned");
        let yaw_deg = |c: &[f64; 9]| c[8].sqrt().to_degrees();
        assert!(yaw_deg(&cov_both) < 0.2, "both rows: yaw σ {:.3}°", yaw_deg(&cov_both));
        assert!(
            yaw_deg(&cov_lower) > 2.0 * yaw_deg(&cov_both),
            "lower row {:.3}° against both rows {:.3}°",
            yaw_deg(&cov_lower),
            yaw_deg(&cov_both)
        );
        // 24 lines, each crossing both sides and two hole edges on most: x to about
        // 7 mm / √(4·24).
        let sigma_x = cov_both[0].sqrt();
        assert!(sigma_x > 0.0005 && sigma_x < 0.0015, "σ x {:.2} mm", sigma_x * 1e3);
        // A single line running along the board's top pins nothing about y or the turn.
        let mut top = scanned(&spec, &[-0.49], spacing);
        assert!(Placement::default().edge_covariance(&fit, &mut top, &spec).is_none());
    }
}
