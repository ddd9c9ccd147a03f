//! The room's big planes in a LiDAR sweep: floor, walls, ceiling and any other large flat
//! surface that is not a board — the survey's plane measurements.
//!
//! RANSAC, largest plane first: plane hypotheses from three points of what is left are
//! scored on a thinned copy of the cloud, the best is refitted to all its inliers (the
//! scatter's smallest eigenvector) and its inliers re-collected twice, then removed. A
//! plane is kept only when its points spread like a room surface, not a board
//! ([`PlaneConfig::min_long_spread_m`], [`PlaneConfig::min_spread_m`]). Sampling is
//! seeded, so the same cloud gives the same planes. Non-finite points are ignored; no cloud panics.
//!
//! The measurement each plane gives is then collected once more from the whole cloud
//! ([`select_plane_points`], shared with the calibration in a surveyed room): a point near
//! two planes (where a wall meets the floor) is neither's, since it would pull the one
//! seen at a grazing angle towards the other by centimetres; what stands on a plane (a box,
//! a pole) is trimmed away ([`trimmed_plane_points`]); and each point is weighted by its own
//! noise along the normal ([`PlanePoints::along_beams`]): range noise moves a point seen at
//! a grazing angle little off the plane.

use crate::geometry::{Mat3, Vec3};
use crate::lidar::Point;
use crate::solve::problem::{incidence2_of, BeamSample};
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
    /// Least σ of a point along the normal (m), whatever its incidence
    /// ([`PlanePoints::along_beams`]).
    pub floor_sigma_m: f64,
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
            floor_sigma_m: PLANE_FLOOR_SIGMA_M,
        }
    }
}

/// One big plane found in the sweep (LiDAR frame): `normal · p = offset`, the normal
/// pointing away from the sensor (offset > 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FoundPlane {
    pub normal: Vec3,
    pub offset: f64,
    /// The plane's points summarised for the point-to-plane term, each weighted along its
    /// beam ([`PlanePoints::along_beams`]).
    pub points: PlanePoints,
    /// Standard deviations of the inliers along the plane's two in-plane axes (m),
    /// larger first.
    pub spread_m: [f64; 2],
}

/// Least σ of a plane point along the normal (m): beam angle, footprint and a surface that
/// is not quite flat; a point seen at a grazing angle is trusted no more than this.
pub const PLANE_FLOOR_SIGMA_M: f64 = 0.002;

/// Which points are a plane's: `|e| ≤ 3σ` with `σ² = σ_r²·cos²θ + floor²` (range noise `σ_r`
/// along a beam of incidence θ), or one band for every point before `σ_r` is known.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneCut {
    range2: f64,
    floor2: f64,
}

impl PlaneCut {
    /// Every point within `half_width_m` of the plane.
    pub fn band(half_width_m: f64) -> Self {
        PlaneCut { range2: 0.0, floor2: (half_width_m / 3.0).powi(2) }
    }

    /// 3σ of each point's own noise, as a selection summarised by
    /// [`PlanePoints::along_beams`] with `floor_m` measured it (its weight-1 σ is
    /// `√(σ_r² + floor²)`).
    pub fn measured(points: &PlanePoints, floor_m: f64) -> Self {
        let floor2 = floor_m * floor_m;
        PlaneCut { range2: (points.sigma_m * points.sigma_m - floor2).max(0.0), floor2 }
    }

    /// Whether a point `residual` off the plane, seen along a beam of squared incidence
    /// cosine `cos2`, is the plane's.
    pub fn admits(&self, residual: f64, cos2: f64) -> bool {
        residual * residual <= 9.0 * (self.range2 * cos2 + self.floor2)
    }
}

/// One plane to collect points for (sensor frame): `normal · p = offset`, and its cut.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlaneSelection {
    pub normal: Vec3,
    pub offset: f64,
    pub cut: PlaneCut,
}

/// A selected point as the cloud holds it (f32: half the memory of a `Vec3`, and the cloud
/// has no more precision to keep); a floor seen by a roof LiDAR is 10⁵ of them.
pub type PlanePoint = [f32; 3];

/// A selected point in the solver's type.
pub fn plane_point(p: &PlanePoint) -> Vec3 {
    Vec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

/// The points of `cloud` (sensor frame, the sensor at the origin) on each of `planes`: a
/// point is a plane's when its cut admits it, no other plane's cut does, and `keep` says
/// yes (e.g. it is clear of every board). One pass, one dot product per point and plane.
pub fn select_plane_points<'a>(
    cloud: impl Iterator<Item = &'a Point>,
    planes: &[PlaneSelection],
    keep: impl Fn(&Vec3) -> bool,
) -> Vec<Vec<PlanePoint>> {
    let mut selected: Vec<Vec<PlanePoint>> = vec![Vec::new(); planes.len()];
    for p in cloud {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            continue;
        }
        let q = p.position();
        let r2 = q.norm_squared();
        let mut within = planes.iter().enumerate().filter(|(_, plane)| {
            let along = plane.normal.dot(&q);
            plane.cut.admits(along - plane.offset, incidence2_of(along, r2))
        });
        if let (Some((only, _)), None) = (within.next(), within.next()) {
            if keep(&q) {
                selected[only].push([p.x, p.y, p.z]);
            }
        }
    }
    selected
}

/// Draws in a row that give no plane before the search stops.
const MAX_FAILURES: usize = 3;

/// Every big plane in `cloud`, largest (most points) first.
pub fn find_planes(cloud: &[Point], config: &PlaneConfig) -> Vec<FoundPlane> {
    let mut left: Vec<Vec3> = cloud
        .iter()
        .map(Point::position)
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
    exclusive_measurements(cloud, found, config)
}

/// Each found plane's points collected again from the whole cloud, each point on one plane
/// only (in the search's band), then trimmed ([`trimmed_plane_points`]). A plane left with
/// too few points is dropped.
fn exclusive_measurements(
    cloud: &[Point],
    found: Vec<FoundPlane>,
    config: &PlaneConfig,
) -> Vec<FoundPlane> {
    let selections: Vec<PlaneSelection> = (found.iter())
        .map(|p| PlaneSelection {
            normal: p.normal,
            offset: p.offset,
            cut: PlaneCut::band(config.inlier_m),
        })
        .collect();
    let points = select_plane_points(cloud.iter(), &selections, |_| true);
    (found.into_iter().zip(&points))
        .filter_map(|(plane, points)| {
            let summary =
                trimmed_plane_points(points, &plane.normal, plane.offset, config.floor_sigma_m)?;
            let (normal, offset) = summary.fitted_plane_towards(&plane.normal);
            let enough = summary.count >= config.min_points;
            enough.then_some(FoundPlane { normal, offset, points: summary, ..plane })
        })
        .collect()
}

/// Rounds of [`trimmed_plane_points`] (it settles in two or three).
const TRIM_ROUNDS: usize = 4;

/// `points` (sensor frame), candidates for the plane `normal · p = offset`, without what is
/// not the plane's, summarised along the beams ([`PlanePoints::along_beams`]): the plane is
/// fitted to the points kept, the points beyond 3σ of their own noise about it dropped, and
/// again, at most `TRIM_ROUNDS` (4) times. What stands on a floor or against a wall (a box,
/// a pole, a board's foot) leaves points a few centimetres off it, all on one side: kept, a
/// few hundred of them move a floor by millimetres.
pub fn trimmed_plane_points(
    points: &[PlanePoint],
    normal: &Vec3,
    offset: f64,
    floor_m: f64,
) -> Option<PlanePoints> {
    let all = points.iter().map(plane_point);
    // Every round measures every point against the last fit once, keeps those its cut
    // admits, and summarises them from here (two passes over the kept, none over the rest).
    let mut kept: Vec<BeamSample> = Vec::with_capacity(points.len());
    kept.extend(all.clone().map(|q| BeamSample::of(q, normal, offset)));
    let mut summary = PlanePoints::from_beam_samples(kept.iter().copied(), floor_m)?;
    for _ in 0..TRIM_ROUNDS {
        let (n, d) = summary.fitted_plane_towards(normal);
        let cut = PlaneCut::measured(&summary, floor_m);
        kept.clear();
        let measured = all.clone().map(|q| BeamSample::of(q, &n, d));
        kept.extend(measured.filter(|s| cut.admits(s.residual, s.cos2)));
        let next = PlanePoints::from_beam_samples(kept.iter().copied(), floor_m)?;
        let settled = next.count == summary.count;
        summary = next;
        if settled {
            break;
        }
    }
    Some(summary)
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
