//! The room's big planes in a LiDAR sweep: floor, walls, ceiling and any other large flat
//! surface that is not a board — the survey's plane measurements.
//!
//! RANSAC, largest plane first: plane hypotheses from three points of what is left are
//! scored on a thinned copy of the cloud, the best is refitted to all its inliers (the
//! scatter's smallest eigenvector) and its inliers re-collected twice, then removed. A
//! plane is kept only when its points spread like a room surface, not a board
//! ([`PlaneConfig::min_long_spread_m`], [`PlaneConfig::min_spread_m`]). Sampling is
//! seeded, so the same cloud gives the same planes. Non-finite points are ignored; no cloud panics.

use crate::geometry::{Mat3, Vec3};
use crate::lidar::Point;
use crate::solve::PlanePoints;

/// How planes are searched for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneConfig {
    /// Largest point-to-plane distance of an inlier (m): a few range-noise σ.
    pub inlier_m: f64,
    /// Fewest points a plane needs.
    pub min_points: usize,
    /// Smallest standard deviations of the points along the plane's longer and shorter
    /// in-plane axes (m): what tells a room surface from a board (a 1.2 × 1.0 m board
    /// spreads at most 0.35 and 0.29 m; a wall the sweep crosses 4.5 and 0.7 m, measured
    /// on simulated Pandar64 sweeps).
    pub min_long_spread_m: f64,
    pub min_spread_m: f64,
    /// Hypotheses tried per plane.
    pub hypotheses: usize,
    /// Most planes returned.
    pub max_planes: usize,
}

impl Default for PlaneConfig {
    fn default() -> Self {
        PlaneConfig {
            inlier_m: 0.06,
            min_points: 1500,
            min_long_spread_m: 1.0,
            min_spread_m: 0.45,
            hypotheses: 400,
            max_planes: 8,
        }
    }
}

/// One big plane found in the sweep (LiDAR frame): `normal · p = offset`, the normal
/// pointing away from the sensor (offset > 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FoundPlane {
    pub normal: Vec3,
    pub offset: f64,
    /// The inliers summarised for the point-to-plane term, their RMS distance as σ.
    pub points: PlanePoints,
    /// Standard deviations of the inliers along the plane's two in-plane axes (m),
    /// larger first.
    pub spread_m: [f64; 2],
}

/// Draws in a row that give no plane before the search stops.
const MAX_FAILURES: usize = 3;

/// Every big plane in `cloud`, largest (most points) first.
pub fn find_planes(cloud: &[Point], config: &PlaneConfig) -> Vec<FoundPlane> {
    let mut left: Vec<Vec3> = cloud
        .iter()
        .map(|p| Vec3::new(p.x as f64, p.y as f64, p.z as f64))
        .filter(|p| p.iter().all(|v| v.is_finite()) && p.norm() > 1e-3)
        .collect();
    let mut rng = SplitMix(0x5EED_0F91_A7E5);
    let mut found = Vec::new();
    let mut failures = 0;
    // Rejected (board-sized) planes are removed too; bound the rounds all the same.
    for _ in 0..4 * config.max_planes.max(1) {
        if found.len() >= config.max_planes || left.len() < config.min_points.max(3) {
            break;
        }
        let Some((normal, offset)) = best_hypothesis(&left, config, &mut rng) else { break };
        // A hypothesis across two surfaces can refit to few points: draw again.
        let Some((plane, inliers)) = refine(&left, normal, offset, config.inlier_m) else {
            failures += 1;
            if failures >= MAX_FAILURES {
                break;
            }
            continue;
        };
        if inliers.len() < config.min_points {
            failures += 1;
            if failures >= MAX_FAILURES {
                break;
            }
            continue;
        }
        failures = 0;
        let is_room_surface = plane.spread_m[0] >= config.min_long_spread_m
            && plane.spread_m[1] >= config.min_spread_m;
        let mut keep = inliers.iter().peekable();
        let mut index = 0;
        left.retain(|_| {
            let drop = keep.next_if(|&&i| i == index).is_some();
            index += 1;
            !drop
        });
        if is_room_surface {
            found.push(plane);
        }
    }
    found
}

/// The three-point hypothesis with most inliers on a thinned copy of `points`.
fn best_hypothesis(
    points: &[Vec3],
    config: &PlaneConfig,
    rng: &mut SplitMix,
) -> Option<(Vec3, f64)> {
    const SCORE_POINTS: usize = 4000;
    let stride = (points.len() / SCORE_POINTS).max(1);
    // Scored on a contiguous copy: every hypothesis reads the same few thousand points,
    // which then stay in cache instead of being gathered a stride apart each time.
    let thinned: Vec<Vec3> = points.iter().step_by(stride).copied().collect();
    let mut best: Option<(usize, Vec3, f64)> = None;
    for _ in 0..config.hypotheses {
        let [a, b, c] = [0; 3].map(|_| points[rng.below(points.len())]);
        let n = (b - a).cross(&(c - a));
        let length = n.norm();
        // Nearly collinear samples (or NaN from overflowing points) give no plane.
        let enough = length > 1e-4 * (b - a).norm_squared().max(1e-9);
        if !enough {
            continue;
        }
        let n = n / length;
        let d = n.dot(&a);
        let score = thinned.iter().filter(|p| (n.dot(p) - d).abs() <= config.inlier_m).count();
        if best.is_none_or(|(s, _, _)| score > s) {
            best = Some((score, n, d));
        }
    }
    best.map(|(_, n, d)| (n, d))
}

/// Least-squares refit to the inliers, twice; the plane and the inliers' indices
/// (ascending). `None` for fewer than three inliers or a degenerate scatter.
fn refine(
    points: &[Vec3],
    mut normal: Vec3,
    mut offset: f64,
    inlier_m: f64,
) -> Option<(FoundPlane, Vec<usize>)> {
    let mut result = None;
    for _ in 0..3 {
        let inliers: Vec<usize> = (0..points.len())
            .filter(|&i| (normal.dot(&points[i]) - offset).abs() <= inlier_m)
            .collect();
        if inliers.len() < 3 {
            return None;
        }
        let (centroid, axes, variances) = principal_axes(inliers.iter().map(|&i| points[i]))?;
        normal = axes.column(2).into_owned();
        offset = normal.dot(&centroid);
        if offset < 0.0 {
            (normal, offset) = (-normal, -offset);
        }
        let rms = libm::sqrt(variances[2].max(0.0));
        let summary = PlanePoints::from_points(inliers.iter().map(|&i| points[i]), rms.max(1e-4))?;
        let spread_m = [libm::sqrt(variances[0].max(0.0)), libm::sqrt(variances[1].max(0.0))];
        result = Some((FoundPlane { normal, offset, points: summary, spread_m }, inliers));
    }
    result
}

/// Centroid, principal axes (columns, by decreasing variance) and the variances.
fn principal_axes(points: impl Iterator<Item = Vec3> + Clone) -> Option<(Vec3, Mat3, [f64; 3])> {
    let n = points.clone().count() as f64;
    let centroid = points.clone().sum::<Vec3>() / n;
    let scatter = points.map(|p| (p - centroid) * (p - centroid).transpose()).sum::<Mat3>() / n;
    if !scatter.iter().all(|v| v.is_finite()) {
        return None;
    }
    let eigen = nalgebra::SymmetricEigen::new(scatter);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
    let axes = Mat3::from_columns(&order.map(|k| eigen.eigenvectors.column(k).into_owned()));
    Some((centroid, axes, order.map(|k| eigen.eigenvalues[k])))
}

/// SplitMix64: a seeded, dependency-free sampler for the hypotheses.
struct SplitMix(u64);

impl SplitMix {
    /// Uniform index below `n` (n > 0).
    fn below(&mut self, n: usize) -> usize {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) % n as u64) as usize
    }
}
