//! A LiDAR placed by the board faces alone, when it placed no board by its holes (a VLP-16's
//! sixteen lines cross a hole too rarely to resolve it): a survey visit's, and a free-board
//! calibration's.
//!
//! The camera knows every board's pose; the LiDAR sees their faces. Starting from the room's
//! nominal mounting (a vehicle's is off by a degree or two and centimetres: at 6 m a 1.5°
//! turn moves a face 16 cm), each board's face points are cut within a band about where the
//! extrinsic puts the board, and the extrinsic is fitted to them point to plane
//! (Gauss–Newton, held to the nominal by a prior so that a direction the faces leave open
//! stays where the nominal put it); the band then narrows (30, 15, 8 cm). The result is only
//! a start: the faces (cut again at it) enter the survey's bundle, or the free-board joint
//! solve, which solve the extrinsic with everything else and without the prior.
//! Refused (`None`) when fewer than [`MIN_FACES`] faces hold points or the faces' points do
//! not lie on them ([`MAX_FACE_RMS_M`]) — a registration that found something else.

use nalgebra::{SMatrix, SVector};

use crate::calibrate::faces::face_points;
use crate::geometry::se3::{so3_log, so3_plus};
use crate::geometry::{Se3, Vec3};
use crate::lidar::Point;
use crate::solve::linalg::Cholesky;
use crate::solve::PlanePoints;
use crate::target::BoardSpec;

/// Fewest board faces that place a LiDAR (three normals fix a rotation and a translation
/// when they differ; the boards of a room are turned differently).
pub const MIN_FACES: usize = 3;
/// The faces' RMS point-to-plane distance at the last band above which the registration is
/// refused (m): a LiDAR's range noise is 1–3 cm; points spread across an 8 cm band at
/// random would show 4.6 cm.
pub const MAX_FACE_RMS_M: f64 = 0.035;

/// Bands about the predicted faces, widest first (m).
const BANDS_M: [f64; 3] = [0.30, 0.15, 0.08];
/// Gauss–Newton steps per band.
const STEPS: usize = 3;
/// A face point's σ for the fit (m): a LiDAR's range noise.
const POINT_SIGMA_M: f64 = 0.02;
/// How far the nominal mounting may be off (the prior's σ): rotation (rad), translation (m).
const PRIOR_ROTATION_RAD: f64 = 0.035;
const PRIOR_TRANSLATION_M: f64 = 0.05;

/// LiDAR → camera from the faces of the boards at `boards` (board → camera), starting at
/// `nominal`; `None` when the faces do not place it (see the module's doc).
pub fn register_by_faces(
    spec: &BoardSpec,
    boards: &[Se3],
    cloud: &[Point],
    nominal: &Se3,
) -> Option<Se3> {
    let points: Vec<Vec3> = cloud.iter().map(Point::position).collect();
    let mut extrinsic = *nominal;
    for band in BANDS_M {
        for _ in 0..STEPS {
            let faces = faces_at(spec, boards, &points, &extrinsic, band);
            extrinsic = step(&faces, &extrinsic, nominal)?;
        }
    }
    let faces = faces_at(spec, boards, &points, &extrinsic, BANDS_M[BANDS_M.len() - 1]);
    let placed = faces.iter().filter(|(_, f)| f.len() >= PlanePoints::MIN_POINTS).count();
    let rms = face_rms(&faces, &extrinsic);
    (placed >= MIN_FACES && rms <= MAX_FACE_RMS_M).then_some(extrinsic)
}

/// Each board's plane in the camera frame (`n · q = d`) and its face points (LiDAR frame)
/// within `band` of where `extrinsic` puts it.
fn faces_at(
    spec: &BoardSpec,
    boards: &[Se3],
    points: &[Vec3],
    extrinsic: &Se3,
    band: f64,
) -> Vec<((Vec3, f64), Vec<Vec3>)> {
    let camera_to_lidar = extrinsic.inverse();
    boards
        .iter()
        .map(|board| {
            let normal = board.rotation.column(2).into_owned();
            let plane = (normal, normal.dot(&board.translation));
            let at = camera_to_lidar.compose(board);
            (plane, face_points(spec, &at, band, points.iter().copied()))
        })
        .collect()
}

/// One Gauss–Newton step of the extrinsic over the faces' points, with the prior to
/// `nominal`; `None` when fewer than [`MIN_FACES`] faces hold points.
fn step(faces: &[((Vec3, f64), Vec<Vec3>)], extrinsic: &Se3, nominal: &Se3) -> Option<Se3> {
    let held = faces.iter().filter(|(_, f)| f.len() >= PlanePoints::MIN_POINTS).count();
    if held < MIN_FACES {
        return None;
    }
    let mut h = SMatrix::<f64, 6, 6>::zeros();
    let mut g = SVector::<f64, 6>::zeros();
    let w = 1.0 / (POINT_SIGMA_M * POINT_SIGMA_M);
    for ((normal, offset), points) in
        faces.iter().filter(|(_, f)| f.len() >= PlanePoints::MIN_POINTS)
    {
        for p in points {
            let turned = extrinsic.rotation * p;
            let r = normal.dot(&(turned + extrinsic.translation)) - offset;
            // q' = exp(ω) R p + t + δt: ∂r/∂ω = (R p) × n, ∂r/∂δt = n.
            let j = SVector::<f64, 6>::from_iterator(
                turned.cross(normal).iter().chain(normal.iter()).copied(),
            );
            h += w * j * j.transpose();
            g += w * r * j;
        }
    }
    // The prior: the rotation and translation away from the nominal, each whitened.
    let omega = so3_log(&(extrinsic.rotation * nominal.rotation.transpose()));
    let dt = extrinsic.translation - nominal.translation;
    let (wr, wt) = (PRIOR_ROTATION_RAD.powi(-2), PRIOR_TRANSLATION_M.powi(-2));
    for k in 0..3 {
        h[(k, k)] += wr;
        g[k] += wr * omega[k];
        h[(k + 3, k + 3)] += wt;
        g[k + 3] += wt * dt[k];
    }
    let delta = -Cholesky::new(&h).ok()?.solve(&g);
    // Left-perturbed, as the solver's: R ← exp(δω) R, t ← t + δt.
    let moved = Se3 {
        rotation: so3_plus(&extrinsic.rotation, &Vec3::new(delta[0], delta[1], delta[2])),
        translation: extrinsic.translation + Vec3::new(delta[3], delta[4], delta[5]),
    };
    delta.iter().all(|x| x.is_finite()).then_some(moved)
}

/// RMS point-to-plane distance of every face's points at `extrinsic` (m).
fn face_rms(faces: &[((Vec3, f64), Vec<Vec3>)], extrinsic: &Se3) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for ((normal, offset), points) in faces {
        for p in points {
            sum += (normal.dot(&extrinsic.act(p)) - offset).powi(2);
            n += 1;
        }
    }
    if n == 0 {
        f64::INFINITY
    } else {
        (sum / n as f64).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::se3::so3_exp;
    use crate::geometry::Mat3;
    use crate::sim::rng::Rng as Noise;

    fn spec() -> BoardSpec {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml");
        crate::room::load(std::path::Path::new(path)).unwrap().board
    }

    fn turn(x_deg: f64, y_deg: f64, z_deg: f64) -> Mat3 {
        so3_exp(&Vec3::new(x_deg, y_deg, z_deg).map(f64::to_radians))
    }

    /// Six boards 5–6 m ahead of the camera (z forward), two rows, each turned its own way.
    fn boards() -> Vec<Se3> {
        (0..6)
            .map(|b| {
                let (col, row) = ((b % 3) as f64 - 1.0, (b / 3) as f64);
                Se3 {
                    rotation: turn(12.0 * (row - 0.5), 25.0 * col, 3.0 * col),
                    translation: Vec3::new(1.8 * col, 1.2 * row - 0.6, 5.5 + 0.3 * col),
                }
            })
            .collect()
    }

    /// A sweep of `boards` (board → camera) through the LiDAR at `lidar_to_camera`: every
    /// board's face on a 3 cm grid, moved along its beam by `range_sigma` of noise, and a
    /// wall 9 m behind the boards.
    fn sweep(
        spec: &BoardSpec,
        boards: &[Se3],
        lidar_to_camera: &Se3,
        range_sigma: f64,
    ) -> Vec<Point> {
        let to_lidar = lidar_to_camera.inverse();
        let mut noise = Noise::new(7);
        let mut out = Vec::new();
        let mut push = |p: Vec3, noise: &mut Noise| {
            let moved = p + p.normalize() * range_sigma * noise.normal();
            out.push(Point {
                x: moved.x as f32,
                y: moved.y as f32,
                z: moved.z as f32,
                ..Point::default()
            });
        };
        for board in boards {
            let to = to_lidar.compose(board);
            for i in 0..(spec.width / 0.03) as usize {
                for j in 0..(spec.height / 0.03) as usize {
                    let x = -spec.width / 2.0 + 0.03 * i as f64;
                    let y = -spec.height / 2.0 + 0.03 * j as f64;
                    let on_board = (0..spec.holes.len())
                        .all(|h| (spec.hole(h) - Vec3::new(x, y, 0.0)).norm() > spec.hole_radius);
                    if on_board {
                        push(to.act(&Vec3::new(x, y, 0.0)), &mut noise);
                    }
                }
            }
        }
        for i in 0..60 {
            for j in 0..30 {
                let wall = Vec3::new(-6.0 + 0.2 * i as f64, -3.0 + 0.2 * j as f64, 15.0);
                push(to_lidar.act(&wall), &mut noise);
            }
        }
        out
    }

    /// The mounting as a vehicle's is off the nominal: 1.5° and 4 cm.
    fn truth_and_nominal() -> (Se3, Se3) {
        let nominal =
            Se3 { rotation: turn(-90.0, 0.0, -90.0), translation: Vec3::new(0.0, -0.3, -0.1) };
        let truth = Se3 {
            rotation: turn(0.9, -0.8, 0.9) * nominal.rotation,
            translation: nominal.translation + Vec3::new(0.025, -0.02, 0.023),
        };
        (truth, nominal)
    }

    fn off(a: &Se3, b: &Se3) -> (f64, f64) {
        let angle = so3_log(&(a.rotation * b.rotation.transpose())).norm().to_degrees();
        (angle, (a.translation - b.translation).norm())
    }

    #[test]
    fn board_faces_place_a_lidar_mounted_off_its_nominal() {
        let (spec, boards) = (spec(), boards());
        let (truth, nominal) = truth_and_nominal();
        let (start_deg, start_m) = off(&nominal, &truth);
        let cloud = sweep(&spec, &boards, &truth, 0.02);
        let found = register_by_faces(&spec, &boards, &cloud, &nominal).expect("not placed");
        let (deg, m) = off(&found, &truth);
        println!(
            "start {start_deg:.3}° {:.1} mm, placed {deg:.4}° {:.1} mm",
            start_m * 1e3,
            m * 1e3
        );
        assert!(start_deg > 1.4 && start_m > 0.035);
        // Faces hold a LiDAR least along themselves (these boards are turned at most 25°
        // from the camera, 6° up or down; measured 0.08° and 6 mm): what the bundle's start
        // needs is its faces within their 10 cm cut, 2 cm at 6 m for 0.2°.
        assert!(deg < 0.2 && m < 0.015, "placed {deg:.4}° and {:.1} mm off", m * 1e3);
    }

    #[test]
    fn a_sweep_without_the_faces_places_nothing() {
        let (spec, boards) = (spec(), boards());
        let (truth, nominal) = truth_and_nominal();
        // Only the wall: no face holds a point.
        let wall_only: Vec<Point> = sweep(&spec, &[], &truth, 0.02);
        assert_eq!(register_by_faces(&spec, &boards, &wall_only, &nominal), None);
        // Points scattered through 30 cm slabs about the boards: no plane to fit.
        let mut noise = Noise::new(3);
        let scattered: Vec<Point> = sweep(&spec, &boards, &truth, 0.0)
            .into_iter()
            .map(|p| {
                let v = p.position();
                let moved = v + v.normalize() * 0.3 * (noise.uniform() - 0.5);
                Point { x: moved.x as f32, y: moved.y as f32, z: moved.z as f32, ..p }
            })
            .collect();
        assert_eq!(register_by_faces(&spec, &boards, &scattered, &nominal), None);
        // Two faces: too few.
        let two = sweep(&spec, &boards[..2], &truth, 0.02);
        assert_eq!(register_by_faces(&spec, &boards, &two, &nominal), None);
    }
}
