//! How far off a projection can be, pixel by pixel: the solve's covariance of the
//! intrinsics (and of the LiDAR → camera extrinsic, when the run solved one) carried
//! through the camera model to the image, on a grid of pixels (as mrcal propagates it).
//!
//! At each grid pixel the solved camera's ray is followed to the map's range; that point
//! is held fixed in the LiDAR's frame (a run with a LiDAR: what matters is where a LiDAR
//! point lands in the image) or in the camera's frame (intrinsics only), and the
//! projection's 2×2 covariance is `J Σ Jᵀ` with `J` the pixel's Jacobian with respect to
//! the shared parameters `[fx fy cx cy d0..d4 | δω δt]` (the extrinsic as the solver
//! perturbs it, on the left). The map holds its worst direction's 1σ in pixels.
//!
//! Outside the boards the distortion polynomial is extrapolated, and its σ grows with
//! it: a camera whose boards covered only the middle of the image gets large values in
//! the corners, which is what the gate ([`super::gate`]) judges over the room's
//! `[quality] region`, instead of the boards' share of the image.

use nalgebra::{SMatrix, Vector2};

use crate::geometry::se3::skew;
use crate::geometry::{Camera, Se3, Vec2, Vec3};
pub use crate::result::{ProjectionMap, Worst};
use crate::solve::{Projector, EXT_ROTATION, EXT_TRANSLATION, INTRINSICS, SHARED};

/// Grid pixels across the image (columns) and down it (rows), the image's borders and
/// corners included: 120 px apart on a 1920×1200 image, fine enough for a map whose
/// values change smoothly, coarse enough for the result file.
pub const GRID: (usize, usize) = (17, 11);

/// The map of `camera` under the shared covariance `covariance` (intrinsics, then
/// the extrinsic `[δω δt]`), at `range_m`; `lidar_to_camera` includes the extrinsic.
pub fn projection_map(
    camera: &Camera,
    covariance: &SMatrix<f64, SHARED, SHARED>,
    lidar_to_camera: Option<&Se3>,
    range_m: f64,
) -> ProjectionMap {
    let (w, h) = (f64::from(camera.width - 1), f64::from(camera.height - 1));
    let along = |n: usize, extent: f64| -> Vec<f64> {
        (0..n).map(|i| extent * i as f64 / (n - 1) as f64).collect()
    };
    let (columns, rows) = (along(GRID.0, w), along(GRID.1, h));
    let sigma_px = rows
        .iter()
        .map(|&v| {
            columns
                .iter()
                .map(|&u| sigma_at(camera, covariance, lidar_to_camera, range_m, &Vec2::new(u, v)))
                .collect()
        })
        .collect();
    ProjectionMap { range_m, lidar: lidar_to_camera.is_some(), columns, rows, sigma_px }
}

/// The projection's worst-direction 1σ (px) at pixel `px`, its point held at `range_m`.
fn sigma_at(
    camera: &Camera,
    covariance: &SMatrix<f64, SHARED, SHARED>,
    lidar_to_camera: Option<&Se3>,
    range_m: f64,
    px: &Vec2,
) -> Option<f64> {
    let p = Projector::unproject(camera, px)? * range_m;
    let (_, d_point, d_intrinsics) = camera.project_with_jacobians(&p)?;
    let mut j = SMatrix::<f64, 2, SHARED>::zeros();
    j.fixed_view_mut::<2, INTRINSICS>(0, 0).copy_from(&d_intrinsics);
    if let Some(extrinsic) = lidar_to_camera {
        // p = exp(δω)·(R p_L) + t + δt: ∂p/∂δω = −[R p_L]×, ∂p/∂δt = I.
        let turned: Vec3 = p - extrinsic.translation;
        j.fixed_view_mut::<2, 3>(0, EXT_ROTATION).copy_from(&(d_point * -skew(&turned)));
        j.fixed_view_mut::<2, 3>(0, EXT_TRANSLATION).copy_from(&d_point);
    }
    let c = j * covariance * j.transpose();
    let worst = largest_eigenvalue2(c[(0, 0)], c[(0, 1)], c[(1, 1)]);
    worst.is_finite().then(|| worst.max(0.0).sqrt())
}

/// The larger eigenvalue of the symmetric 2×2 matrix `[[a, b], [b, d]]`.
fn largest_eigenvalue2(a: f64, b: f64, d: f64) -> f64 {
    let mean = 0.5 * (a + d);
    let half_gap = Vector2::new(0.5 * (a - d), b).norm();
    mean + half_gap
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::CameraModel;

    fn camera() -> Camera {
        Camera {
            model: CameraModel::PinholeRadtan,
            width: 1920,
            height: 1200,
            fx: 1400.0,
            fy: 1401.0,
            cx: 955.0,
            cy: 603.0,
            distortion: [-0.2, 0.05, 1e-4, -2e-4, 0.0],
        }
    }

    /// The map's σ against the same covariance carried through a numeric Jacobian: the
    /// point held in the LiDAR frame, each shared parameter nudged (the extrinsic on the
    /// left, as the solver perturbs it), the pixel's covariance by the sandwich.
    #[test]
    fn the_map_matches_a_numeric_propagation() {
        let cam = camera();
        let ext = Se3 {
            rotation: crate::geometry::se3::so3_exp(&Vec3::new(0.02, -0.01, 0.03)),
            translation: Vec3::new(0.1, -0.3, 0.2),
        };
        let mut cov = SMatrix::<f64, SHARED, SHARED>::zeros();
        let sig = [
            2.0, 2.1, 1.0, 0.9, 1e-3, 1e-3, 1e-4, 1e-4, 1e-3, 1e-3, 2e-3, 1e-3, 0.004, 0.003, 0.005,
        ];
        for (i, s) in sig.iter().enumerate() {
            cov[(i, i)] = s * s;
        }
        cov[(0, 1)] = 0.8 * sig[0] * sig[1];
        cov[(1, 0)] = cov[(0, 1)];
        cov[(2, 9)] = 0.3 * sig[2] * sig[9];
        cov[(9, 2)] = cov[(2, 9)];
        let map = projection_map(&cam, &cov, Some(&ext), 8.0);
        let (r, c) = (9, 15);
        let px = Vec2::new(map.columns[c], map.rows[r]);
        let p_cam = cam.unproject(&px).unwrap() * 8.0;
        let p_lidar = ext.inverse().act(&p_cam);
        let project = |x: &[f64; SHARED]| -> Vec2 {
            let mut k = cam;
            let mut intr = Projector::params(&cam);
            for (v, dx) in intr.iter_mut().zip(&x[..INTRINSICS]) {
                *v += dx;
            }
            Projector::set_params(&mut k, &intr);
            let w = Vec3::new(x[9], x[10], x[11]);
            let rotation = crate::geometry::se3::so3_exp(&w) * ext.rotation;
            let t = ext.translation + Vec3::new(x[12], x[13], x[14]);
            k.project(&(rotation * p_lidar + t)).unwrap()
        };
        let mut j = SMatrix::<f64, 2, SHARED>::zeros();
        for i in 0..SHARED {
            let h = 1e-6;
            let (mut plus, mut minus) = ([0.0; SHARED], [0.0; SHARED]);
            plus[i] = h;
            minus[i] = -h;
            let d = (project(&plus) - project(&minus)) / (2.0 * h);
            j[(0, i)] = d.x;
            j[(1, i)] = d.y;
        }
        let cv = j * cov * j.transpose();
        let eig = nalgebra::SymmetricEigen::new(nalgebra::Matrix2::new(
            cv[(0, 0)],
            cv[(0, 1)],
            cv[(1, 0)],
            cv[(1, 1)],
        ));
        let expected = eig.eigenvalues.max().sqrt();
        let got = map.sigma_px[r][c].unwrap();
        assert!((got - expected).abs() < 1e-6 * expected, "map {got} numeric {expected}");
    }

    #[test]
    fn without_a_lidar_the_extrinsic_does_not_count_and_the_range_does_not_matter() {
        let cam = camera();
        let mut cov = SMatrix::<f64, SHARED, SHARED>::zeros();
        cov[(0, 0)] = 4.0;
        cov[(2, 2)] = 1.0;
        cov[(12, 12)] = 1.0; // a metre of translation σ: ignored without a LiDAR
        let near = projection_map(&cam, &cov, None, 2.0);
        let far = projection_map(&cam, &cov, None, 50.0);
        for (a, b) in near.sigma_px.iter().flatten().zip(far.sigma_px.iter().flatten()) {
            assert!((a.unwrap() - b.unwrap()).abs() < 1e-9);
        }
        // Near the principal point cx moves the pixel and fx scales an offset of 4.5 px.
        let centre = near.worst_in([0.5, 0.5, 0.5, 0.5]).unwrap();
        assert_eq!(centre.at_px, Vec2::new(959.5, 599.5));
        assert!((centre.sigma_px - 1.0).abs() < 0.01, "{}", centre.sigma_px);
        let worst = near.worst_in([0.0, 0.0, 1.0, 1.0]).unwrap();
        assert!(worst.at_px.x == 0.0 || worst.at_px.x == 1919.0, "{:?}", worst.at_px);
        assert!(worst.sigma_px > 1.0);
    }

    #[test]
    fn the_worst_value_is_found_inside_the_region_only() {
        let map = ProjectionMap {
            range_m: 10.0,
            lidar: false,
            columns: vec![0.0, 50.0, 99.0],
            rows: vec![0.0, 49.0],
            sigma_px: vec![vec![Some(0.1), Some(0.2), Some(5.0)], vec![Some(0.3), None, Some(0.4)]],
        };
        let all = map.worst_in([0.0, 0.0, 1.0, 1.0]).unwrap();
        assert_eq!((all.sigma_px, all.at_px), (5.0, Vec2::new(99.0, 0.0)));
        let left = map.worst_in([0.0, 0.0, 0.6, 1.0]).unwrap();
        assert_eq!((left.sigma_px, left.at_px), (0.3, Vec2::new(0.0, 49.0)));
        assert!(map.worst_in([0.4, 0.9, 0.6, 1.0]).is_none());
    }

    #[test]
    fn the_largest_eigenvalue_of_a_2x2() {
        assert!((largest_eigenvalue2(4.0, 0.0, 1.0) - 4.0).abs() < 1e-12);
        assert!((largest_eigenvalue2(2.0, 1.0, 2.0) - 3.0).abs() < 1e-12);
    }
}
