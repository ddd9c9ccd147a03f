//! The simulator: a synthetic calibration room with ground truth.
//!
//! [`simulate`] lays the room's boards out in front of the camera (covering the image,
//! corners included, tilted 15–35° in different directions, 3–6 m away), renders the
//! camera frame through the exact inverse of the camera model, ray-casts one LiDAR sweep
//! through the same geometry (holes let the beams through to the wall behind), and
//! records the truth: intrinsics, distortion, LiDAR→camera, board poses, the projected
//! inner corners in the detector's order and the hole centres in the LiDAR frame.
//! Everything is deterministic for a seed.

pub mod capture;
pub mod layout;
pub mod random_room;
pub mod raycast;
pub mod render;
pub mod rig;
pub mod rng;
pub mod structures;
pub mod visits;
pub mod world;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::geometry::{se3::so3_exp, Camera, CameraModel, Se3, Vec3};
use crate::lidar::{Model, Point};
use crate::result::{CameraResult, Extrinsic};
use crate::target::Room;

pub use capture::{write_capture, CaptureFiles};
pub use layout::Layout;
pub use raycast::Firings;
pub use render::ImageNoise;
use rng::Rng;
use world::World;

/// Horizontal field of view when neither the options nor the room give intrinsics.
pub const DEFAULT_HFOV_DEG: f64 = 70.0;
/// Range noise σ of the simulated LiDAR (m).
pub const DEFAULT_RANGE_NOISE_M: f64 = 0.02;
/// How far the true extrinsic strays from the room's nominal one (deg, m, per axis).
const MOUNTING_ERROR: (f64, f64) = (1.5, 0.04);

/// What to simulate beyond the room file.
#[derive(Clone, Debug, PartialEq)]
pub struct SimOptions {
    pub seed: u64,
    /// Boards to place (default: the room's `board.count`).
    pub boards: Option<usize>,
    /// Camera model (default: the room's).
    pub camera_model: Option<CameraModel>,
    /// Horizontal field of view (default: from the room's fx, else [`DEFAULT_HFOV_DEG`]).
    pub hfov_deg: Option<f64>,
    /// Distortion coefficients (default: the room's, else a typical lens of the model).
    pub distortion: Option<Vec<f64>>,
    /// LiDAR model (default: the room's).
    pub lidar: Option<Model>,
    pub range_noise_m: f64,
    pub image: ImageNoise,
    /// How the boards are arranged ([`Layout::Band`] needs a LiDAR).
    pub layout: Layout,
    /// Seed of the rig (the true LiDAR mounting; default: `seed`): scenes with one rig
    /// seed and different seeds are frames of one vehicle in differently set-up rooms.
    pub rig_seed: Option<u64>,
    /// Frames of a standing vehicle: besides the scene's image and sweep, this many
    /// minus one more of the same room, each with its own sensor noise (and each sweep its
    /// own azimuth phase), as the daemon captures them to average and accumulate.
    pub standing_frames: usize,
    /// A room for a rig whose cameras' fields differ: the boards laid out for a narrower
    /// lens, and a ring of more in the outer columns of the room camera's view.
    pub ring: Option<Ring>,
}

/// Boards besides the room's in the outer columns of the room camera's view turned left by
/// `turn_left_deg` ([`layout::lay_out_ring`]); the room's own are then laid out for a lens
/// of `inner_hfov_deg`: a room for a rig whose narrow camera looks ahead and whose widest
/// (the room camera's lens) looks that far left of it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ring {
    pub boards: usize,
    pub inner_hfov_deg: f64,
    pub turn_left_deg: f64,
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions {
            seed: 1,
            boards: None,
            camera_model: None,
            hfov_deg: None,
            distortion: None,
            lidar: None,
            range_noise_m: DEFAULT_RANGE_NOISE_M,
            image: ImageNoise::default(),
            layout: Layout::Grid,
            rig_seed: None,
            standing_frames: 1,
            ring: None,
        }
    }
}

/// Why a scene could not be simulated or written.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("cannot lay out {count} boards without overlap or leaving the image (board {board} did not fit); use fewer boards or a wider field of view")]
    Layout { count: usize, board: usize },
    /// The room's LiDAR model (`None`: `pcd`) has no beam table.
    #[error(
        "the simulator has no beam table for LiDAR model {} (use pandar64, pandar40p, vlp32c or vlp16)",
        capitalised(Model::file_name(*.0))
    )]
    NoBeamTable(Option<Model>),
    #[error("distortion needs {expected} coefficients for this camera model, got {got}")]
    Distortion { expected: usize, got: usize },
    #[error("field of view {0}° is out of range (10–170°)")]
    FieldOfView(f64),
    #[error("{path}: {message}")]
    Write { path: PathBuf, message: String },
    #[error("cannot encode the {model:?} sweep as packets: {message}")]
    Encode { model: crate::lidar::Model, message: String },
    #[error("the scene has no LiDAR sweep to write as a capture (the room has no [lidar])")]
    NoSweep,
    #[error("the band layout aims boards at the LiDAR's dense band, but the room has no [lidar]")]
    BandWithoutLidar,
    #[error("--visits {0}: a surveyed room is simulated with 1 to {max} visits", max = visits::MAX_VISITS)]
    Visits(usize),
    #[error("--first-visit {first} with --visits {count}: visits are numbered up to {max}", max = visits::MAX_VISIT_NUMBER)]
    VisitNumber { first: usize, count: usize },
    #[error("a ring of boards is laid out for a room's vehicles or a rig: give --visits or --rig")]
    RingWithoutVehicles,
}

/// `name` with its first letter upper case: the message has always named the model so
/// (`Pandar64`, `Pandarxt32`, `Pcd`).
fn capitalised(name: &str) -> String {
    let mut chars = name.chars();
    chars.next().map(|c| c.to_ascii_uppercase()).into_iter().chain(chars).collect()
}

impl SimError {
    /// Writing `path` failed with `e`.
    pub fn write(path: &Path, e: &dyn std::fmt::Display) -> Self {
        SimError::Write { path: path.to_owned(), message: e.to_string() }
    }
}

/// The ground truth of one scene (`truth.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Truth {
    pub seed: u64,
    pub camera: CameraResult,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lidar_model: Option<Model>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lidar_to_camera: Option<Extrinsic>,
    pub range_noise_m: f64,
    pub image_noise_grey: f64,
    pub image_blur_px: f64,
    pub boards: Vec<BoardTruth>,
}

/// The truth about one board.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BoardTruth {
    /// Board → camera: `p_camera = rotation · p_board + translation`.
    pub board_to_camera: Extrinsic,
    /// Every inner corner projected into the image, row-major (the detector's order).
    pub corners_px: Vec<[f64; 2]>,
    /// Hole centres projected into the image.
    pub holes_px: Vec<[f64; 2]>,
    /// Hole centres in the LiDAR frame (m); empty without a LiDAR.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub holes_lidar: Vec<[f64; 3]>,
    /// LiDAR returns on the board.
    #[serde(default)]
    pub lidar_points: usize,
    /// Inner corners hidden from the camera by something in front (0 for a clear view).
    #[serde(default)]
    pub occluded_corners: usize,
    /// Per hole: how many scan lines (rings) passed through it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub hole_scan_lines: Vec<usize>,
}

/// One simulated scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The room as simulated (with the options' overrides applied).
    pub room: Room,
    /// Grey frame, row-major.
    pub image: Vec<u8>,
    /// The LiDAR sweep (absent for an intrinsics-only room).
    pub cloud: Option<Vec<Point>>,
    /// The same sweep as the sensor reports it, for packet captures (with `cloud`).
    pub firings: Option<Firings>,
    /// The standing vehicle's further frames and sweeps ([`SimOptions::standing_frames`]).
    pub more: Vec<StandingFrame>,
    pub truth: Truth,
}

/// One more frame and sweep of a standing vehicle: the same room, new sensor noise.
#[derive(Clone, Debug)]
pub struct StandingFrame {
    /// Grey frame, row-major.
    pub image: Vec<u8>,
    /// The sweep (absent for an intrinsics-only room).
    pub cloud: Option<Vec<Point>>,
}

/// `room` with the sensor models `options` override (`--camera-model`, `--lidar`).
pub(crate) fn with_options_models(room: &Room, options: &SimOptions) -> Room {
    let mut room = room.clone();
    if let Some(model) = options.camera_model {
        room.camera.model = model;
    }
    if let (Some(model), Some(lidar)) = (options.lidar, room.lidar.as_mut()) {
        lidar.model = Some(model);
    }
    room
}

/// Simulates one scene of `room`.
pub fn simulate(room: &Room, options: &SimOptions) -> Result<Scene, SimError> {
    if options.ring.is_some() {
        return Err(SimError::RingWithoutVehicles);
    }
    let mut room = with_options_models(room, options);
    let mut rng = Rng::new(options.seed);
    let camera = true_camera(&room, options)?;
    // The rig (the LiDAR's true mounting) follows `rig_seed` when given, so several
    // scenes can be frames of one vehicle.
    let lidar_to_camera = match options.rig_seed {
        Some(rig) => true_extrinsic(&room, &mut Rng::new(rig).fork(1)),
        None => true_extrinsic(&room, &mut rng.fork(1)),
    };
    let camera_in_lidar = lidar_to_camera.inverse();
    let count = options.boards.unwrap_or(room.board.count as usize);
    // The room written beside the scene is the room as simulated: its board count too.
    room.board.count = count as u32;
    let fits = |board_to_camera: &Se3| fits_in_room(&room, &camera_in_lidar, board_to_camera);
    let band_row = match (options.layout, &room.lidar) {
        (Layout::Grid, _) => None,
        (Layout::Band, None) => return Err(SimError::BandWithoutLidar),
        (Layout::Band, Some(lidar)) => {
            let elevations = lidar
                .model
                .and_then(raycast::beam_elevations)
                .ok_or(SimError::NoBeamTable(lidar.model))?;
            Some(band_row_px(&camera, &lidar_to_camera, elevations))
        }
    };
    let poses = layout::lay_out(&room.board, &camera, count, band_row, &mut rng.fork(2), &fits)?;
    let in_lidar: Vec<Se3> = poses.iter().map(|p| camera_in_lidar.compose(p)).collect();
    let world = World::new(&room.board, in_lidar.clone(), &mut rng.fork(3));
    let image = render::render(&world, &camera, &camera_in_lidar, &options.image, &mut rng.fork(4));
    let beams = room
        .lidar
        .as_ref()
        .map(|lidar| {
            lidar.model.and_then(raycast::calibration).ok_or(SimError::NoBeamTable(lidar.model))
        })
        .transpose()?;
    let (cloud, firings, sweep_truth) = match &beams {
        Some(cal) => {
            let cast = raycast::sweep(&world, cal, options.range_noise_m, 0, &mut rng.fork(5));
            (Some(cast.points), Some(cast.firings), Some(cast.truth))
        }
        None => (None, None, None),
    };
    // Forked after everything above, so the first frame is the same with or without more.
    let mut standing = rng.fork(6);
    let frames = options.standing_frames.max(1);
    let more = (1..frames)
        .map(|k| {
            let image =
                render::render(&world, &camera, &camera_in_lidar, &options.image, &mut standing);
            let phase = (k * usize::from(raycast::AZIMUTH_STEP) / frames) as u16;
            let cloud = beams.as_ref().map(|cal| {
                raycast::sweep(&world, cal, options.range_noise_m, phase, &mut standing).points
            });
            StandingFrame { image, cloud }
        })
        .collect();
    let boards = poses
        .iter()
        .zip(&in_lidar)
        .enumerate()
        .map(|(i, (to_camera, to_lidar))| {
            let mut truth = board_truth(
                &room,
                &camera,
                to_camera,
                to_lidar,
                sweep_truth.as_ref().map(|t| (t, i)),
            );
            truth.occluded_corners = occluded_corners(&world, i, &camera_in_lidar);
            truth
        })
        .collect();
    let truth = Truth {
        seed: options.seed,
        camera: CameraResult::from_camera(&camera),
        lidar_model: room.lidar.as_ref().and_then(|l| l.model),
        lidar_to_camera: room.lidar.as_ref().map(|_| Extrinsic::from_se3(&lidar_to_camera)),
        range_noise_m: options.range_noise_m,
        image_noise_grey: options.image.noise_grey,
        image_blur_px: options.image.blur_px,
        boards,
    };
    Ok(Scene { room, image, cloud, firings, more, truth })
}

/// Width of the densest band of beams the band layout aims at (degrees).
const DENSE_BAND_DEG: f64 = 8.0;

/// The image row where the LiDAR's densest `DENSE_BAND_DEG` of beams cross straight ahead,
/// 4.5 m out (the middle of the boards' distances).
fn band_row_px(camera: &Camera, lidar_to_camera: &Se3, elevations: &[f64]) -> f64 {
    let in_band =
        |low: f64| elevations.iter().filter(|&&e| e >= low && e <= low + DENSE_BAND_DEG).count();
    let lowest = elevations.iter().copied().fold(f64::MAX, f64::min);
    let low =
        (0..400).map(|k| lowest + k as f64 * 0.1).max_by_key(|&low| in_band(low)).unwrap_or(lowest);
    let centre = (low + DENSE_BAND_DEG / 2.0).to_radians();
    let ahead = Vec3::new(centre.cos(), 0.0, centre.sin()) * 4.5;
    camera
        .project(&lidar_to_camera.act(&ahead))
        .map_or(camera.height as f64 / 2.0, |px| px.y.clamp(0.0, camera.height as f64))
}

/// Writes `image.png`, `cloud.pcd` (binary), `truth.json` and the `room.toml` it came from,
/// and a standing vehicle's further frames as `image-2.png`, `cloud-2.pcd`, … .
pub fn write_scene(scene: &Scene, dir: &Path) -> Result<(), SimError> {
    std::fs::create_dir_all(dir).map_err(|e| SimError::write(dir, &e))?;
    let camera = &scene.truth.camera;
    // Frame 1 is `image.png` / `cloud.pcd`, frame k > 1 `image-k.png` / `cloud-k.pcd`.
    let write_frame = |suffix: &str, image: &[u8], cloud: Option<&Vec<Point>>| {
        let image_path = dir.join(format!("image{suffix}.png"));
        image::GrayImage::from_raw(camera.width, camera.height, image.to_vec())
            .expect("the renderer makes width × height pixels")
            .save(&image_path)
            .map_err(|e| SimError::write(&image_path, &e))?;
        if let Some(cloud) = cloud {
            let cloud_path = dir.join(format!("cloud{suffix}.pcd"));
            crate::lidar::pcd::write(&cloud_path, cloud, crate::lidar::pcd::PcdFormat::Binary)
                .map_err(|e| SimError::write(&cloud_path, &e))?;
        }
        Ok(())
    };
    write_frame("", &scene.image, scene.cloud.as_ref())?;
    for (k, frame) in scene.more.iter().enumerate() {
        write_frame(&format!("-{}", k + 2), &frame.image, frame.cloud.as_ref())?;
    }
    let truth_path = dir.join("truth.json");
    let json = serde_json::to_string_pretty(&scene.truth).expect("truth serialises");
    std::fs::write(&truth_path, json + "\n").map_err(|e| SimError::write(&truth_path, &e))?;
    let room_path = dir.join("room.toml");
    std::fs::write(&room_path, crate::room::to_toml(&scene.room))
        .map_err(|e| SimError::write(&room_path, &e))?;
    Ok(())
}

/// The simulated camera: the room's nominal intrinsics where given, otherwise a lens of
/// the requested field of view whose principal point and aspect are slightly off, as
/// real ones are.
fn true_camera(room: &Room, options: &SimOptions) -> Result<Camera, SimError> {
    let spec = &room.camera;
    let expected = match spec.model {
        CameraModel::PinholeRadtan => 5,
        CameraModel::Fisheye => 4,
    };
    let distortion: Vec<f64> = match (&options.distortion, &spec.distortion) {
        (Some(d), _) => d.clone(),
        (None, Some(d)) => d.iter().copied().collect(),
        (None, None) => match spec.model {
            CameraModel::PinholeRadtan => vec![-0.18, 0.06, 0.0004, -0.0003, -0.008],
            CameraModel::Fisheye => vec![0.05, -0.01, 0.004, -0.001],
        },
    };
    if distortion.len() != expected {
        return Err(SimError::Distortion { expected, got: distortion.len() });
    }
    let mut d = [0.0; 5];
    d[..expected].copy_from_slice(&distortion);
    let nominal = options.hfov_deg.is_none() && spec.fx.is_some();
    if nominal {
        let fx = spec.fx.unwrap_or_default();
        return Ok(Camera {
            model: spec.model,
            width: spec.width,
            height: spec.height,
            fx,
            fy: spec.fy.unwrap_or(fx),
            cx: spec.cx.unwrap_or((spec.width as f64 - 1.0) / 2.0),
            cy: spec.cy.unwrap_or((spec.height as f64 - 1.0) / 2.0),
            distortion: d,
        });
    }
    let hfov = field_of_view(options.hfov_deg.unwrap_or(DEFAULT_HFOV_DEG))?;
    let mut camera = Camera::from_fov(spec.model, spec.width, spec.height, hfov, d);
    camera.fy *= 1.0008;
    camera.cx += 6.5;
    camera.cy -= 4.25;
    Ok(camera)
}

/// `hfov_deg` when the simulator lays boards out for it (10–170°), else
/// [`SimError::FieldOfView`].
pub(crate) fn field_of_view(hfov_deg: f64) -> Result<f64, SimError> {
    match (10.0..=170.0).contains(&hfov_deg) {
        true => Ok(hfov_deg),
        false => Err(SimError::FieldOfView(hfov_deg)),
    }
}

/// The true LiDAR → camera motion: the room's nominal mounting, off by a little, as a
/// real vehicle's is. Without a LiDAR the room's frame is still a level one (x forward,
/// z up) and the camera looks straight ahead along its x axis.
fn true_extrinsic(room: &Room, rng: &mut Rng) -> Se3 {
    let Some(lidar) = &room.lidar else {
        let looking_forward =
            crate::geometry::Mat3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
        return Se3 { rotation: looking_forward, translation: Vec3::zeros() };
    };
    let nominal =
        Se3 { rotation: lidar.rotation_matrix(), translation: lidar.translation_vector() };
    perturbed_mounting(&nominal, rng)
}

/// A sensor's true mounting: `nominal` off by up to [`MOUNTING_ERROR`] per axis.
fn perturbed_mounting(nominal: &Se3, rng: &mut Rng) -> Se3 {
    let (deg, m) = MOUNTING_ERROR;
    let error = Vec3::new(rng.range(-deg, deg), rng.range(-deg, deg), rng.range(-deg, deg))
        .map(f64::to_radians);
    let shift = Vec3::new(rng.range(-m, m), rng.range(-m, m), rng.range(-m, m));
    Se3 { rotation: so3_exp(&error) * nominal.rotation, translation: nominal.translation + shift }
}

/// Whether the whole board outline stays at least 10 cm clear of the floor and ceiling.
fn fits_in_room(room: &Room, camera_in_lidar: &Se3, board_to_camera: &Se3) -> bool {
    let (hw, hh) = (room.board.width / 2.0, room.board.height / 2.0);
    [(-hw, -hh), (hw, -hh), (-hw, hh), (hw, hh)].iter().all(|&(x, y)| {
        let p = camera_in_lidar.act(&board_to_camera.act(&Vec3::new(x, y, 0.0)));
        p.z > -world::LIDAR_HEIGHT + 0.1 && p.z < world::CEILING_Z - 0.1
    })
}

/// How many of board `index`'s inner corners something else hides from the camera.
fn occluded_corners(world: &World, index: usize, camera_in_lidar: &Se3) -> usize {
    let spec = &world.board;
    let origin = camera_in_lidar.translation;
    (0..spec.corner_count())
        .filter(|&c| {
            let corner = world.boards[index].act(&spec.corner(c));
            let (dir, distance) = ((corner - origin).normalize(), (corner - origin).norm());
            !world.cast(&origin, &dir).is_some_and(|hit| {
                matches!(hit.surface, world::Surface::Board { index: i, .. } if i == index)
                    && (hit.distance - distance).abs() < 1e-6
            })
        })
        .count()
}

fn board_truth(
    room: &Room,
    camera: &Camera,
    to_camera: &Se3,
    to_lidar: &Se3,
    sweep: Option<(&raycast::SweepTruth, usize)>,
) -> BoardTruth {
    let spec = &room.board;
    let project = |p: Vec3| {
        let px =
            camera.project(&to_camera.act(&p)).expect("laid-out boards project into the image");
        [px.x, px.y]
    };
    let holes = || (0..spec.holes.len()).map(|h| spec.hole(h));
    BoardTruth {
        board_to_camera: Extrinsic::from_se3(to_camera),
        corners_px: (0..spec.corner_count()).map(|i| project(spec.corner(i))).collect(),
        holes_px: holes().map(project).collect(),
        holes_lidar: match sweep {
            Some(_) => holes().map(|h| to_lidar.act(&h).into()).collect(),
            None => Vec::new(),
        },
        occluded_corners: 0,
        lidar_points: sweep.map_or(0, |(t, i)| t.board_points[i]),
        hole_scan_lines: sweep.map_or(Vec::new(), |(t, i)| t.hole_rings[i].clone()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_beam_table_names_the_model_as_it_always_has() {
        for (model, shown) in [
            (Some(Model::Hdl32e), "Hdl32e"),
            (Some(Model::PandarXt32), "Pandarxt32"),
            (Some(Model::PandarQt64), "Pandarqt64"),
            (Some(Model::Ouster), "Ouster"),
            (None, "Pcd"),
        ] {
            assert_eq!(
                SimError::NoBeamTable(model).to_string(),
                format!(
                    "the simulator has no beam table for LiDAR model {shown} \
                     (use pandar64, pandar40p, vlp32c or vlp16)"
                )
            );
            assert!(model.and_then(raycast::calibration).is_none());
            assert!(model.and_then(raycast::beam_elevations).is_none());
        }
    }
}
