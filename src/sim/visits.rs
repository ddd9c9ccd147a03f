//! A surveyed room's simulation: one fixed room (boards, floor, walls, ceiling, clutter)
//! visited by several vehicles, each with its own camera and LiDAR mounting, each
//! parked a little differently — the input `roomcal survey` solves the room from.
//!
//! Frames: the **room frame** is the one the room was built in: the nominal vehicle's
//! nominal LiDAR frame at the nominal parking spot (x forward, y left, z up; the floor at
//! z = −[`world::LIDAR_HEIGHT`]). A vehicle's frame is that nominal LiDAR frame on the
//! vehicle; its camera sits at the room's nominal mounting in it and its true LiDAR at
//! its own mounting error from there. A visit parks the vehicle frame at
//! `vehicle_to_room` (±0.3 m, ±5° yaw, ±0.5° pitch and roll).
//!
//! The boards are laid out once (the existing layout, through a narrower field of view
//! than the camera's so that every parked vehicle still sees them whole) and stay put;
//! each visit renders and ray-casts through the single-scene simulator's own renderer and
//! ray caster. The same seed gives the same bytes.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::geometry::{se3::so3_exp, Camera, Se3, Vec3};
use crate::result::Extrinsic;
use crate::target::Room;

use super::rng::Rng;
use super::world::World;
use super::{
    band_row_px, board_truth, fits_in_room, layout, occluded_corners, raycast, render, true_camera,
    true_extrinsic, Layout, Scene, SimError, SimOptions, StandingFrame, Truth,
};

/// Most visits one simulation writes.
pub const MAX_VISITS: usize = 99;
/// Highest visit number a room's visits reach ([`simulate_visits_from`]).
pub const MAX_VISIT_NUMBER: usize = 999;
/// Parking error bounds: translation (m, x and y), yaw (deg), pitch and roll (deg).
pub const PARKING_ERROR: (f64, f64, f64) = (0.3, 5.0, 0.5);
/// Per-vehicle spread of the intrinsics about the nominal: focal length (relative),
/// principal point (px), distortion (relative).
const VEHICLE_SPREAD: (f64, f64, f64) = (0.02, 12.0, 0.1);
/// The boards are laid out through a lens this much narrower than the camera's (focal
/// length factor), leaving room at the image border for the parking error.
const LAYOUT_ZOOM: f64 = 1.35;

/// The room's truth (`room-truth.json`): every board and big plane in the room frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RoomTruth {
    pub seed: u64,
    /// How the room frame is defined.
    pub frame: String,
    /// Board → room: `p_room = rotation · p_board + translation`.
    pub boards: Vec<Extrinsic>,
    pub planes: Vec<PlaneTruth>,
}

/// One of the room's big planes: `normal · p_room = offset`, normal pointing out of the room.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlaneTruth {
    pub name: String,
    pub normal: [f64; 3],
    pub offset: f64,
}

/// One visit's truth (`visit-NN/truth.json`): the scene's truth plus where it was parked.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VisitTruth {
    #[serde(flatten)]
    pub scene: Truth,
    /// Room → camera: `p_camera = rotation · p_room + translation`.
    pub room_to_camera: Extrinsic,
}

/// One visit: the scene as the single-scene simulator makes it, plus its parking pose.
#[derive(Clone, Debug)]
pub struct Visit {
    pub scene: Scene,
    pub room_to_camera: Se3,
}

/// A simulated room and its visits.
#[derive(Clone, Debug)]
pub struct Visits {
    pub room: Room,
    pub truth: RoomTruth,
    pub visits: Vec<Visit>,
    /// Where the boards stand, the shell's seed: what another vehicle of the same room
    /// (a rig, [`super::rig::simulate_rig_in`]) sees too.
    pub layout: RoomLayout,
}

/// A room as laid out once: its boards (board → room) and the seed of its shell (floor,
/// walls, ceiling) and clutter.
#[derive(Clone, Debug)]
pub struct RoomLayout {
    pub boards_in_room: Vec<Se3>,
    pub world_seed: u64,
}

impl RoomLayout {
    /// The room's truth (`room-truth.json`) of a simulation seeded `seed`; `frame` says
    /// what its room frame is.
    pub fn truth(&self, room: &Room, seed: u64, frame: &str) -> RoomTruth {
        let planes =
            World::new(&room.board, Vec::new(), &mut Rng::new(self.world_seed)).shell_planes();
        RoomTruth {
            seed,
            frame: frame.into(),
            boards: self.boards_in_room.iter().map(Extrinsic::from_se3).collect(),
            planes: planes
                .iter()
                .map(|(name, n, offset)| PlaneTruth {
                    name: (*name).into(),
                    normal: [n.x, n.y, n.z],
                    offset: *offset,
                })
                .collect(),
        }
    }
}

/// Simulates `count` visits of one room (`options.seed` fixes the room and every visit).
/// `options.rig_seed` does not apply: every visit is its own vehicle;
/// `options.standing_frames` gives each visit that many frames (a standing vehicle).
pub fn simulate_visits(
    room: &Room,
    options: &SimOptions,
    count: usize,
) -> Result<Visits, SimError> {
    let mut visits = Vec::with_capacity(count);
    let mut simulated = simulate_visits_each(room, options, count, |_, visit| {
        visits.push(visit);
        Ok(())
    })?;
    simulated.visits = visits;
    Ok(simulated)
}

/// [`simulate_visits`] that hands each visit to `each` as it is made (`k` 0-based, in
/// order; the same visits, the same random streams) instead of keeping them: the room, its
/// truth and layout come back with `visits` empty. Memory for one visit however many are
/// made: 26 standing visits of 10 frames are a gigabyte of renders.
pub fn simulate_visits_each(
    room: &Room,
    options: &SimOptions,
    count: usize,
    each: impl FnMut(usize, Visit) -> Result<(), SimError>,
) -> Result<Visits, SimError> {
    simulate_visits_from(room, options, 0, count, each)
}

/// [`simulate_visits_each`] of visits `first..first + count` (0-based) only: each visit
/// has its own random stream (the earlier visits' are forked and skipped, not rendered),
/// so these are exactly the visits a run of `first + count` makes, and a study can add
/// visits to a room without rendering the earlier ones again. `each` gets the visit's own
/// index (`first`, `first + 1`, …).
pub fn simulate_visits_from(
    room: &Room,
    options: &SimOptions,
    first: usize,
    count: usize,
    mut each: impl FnMut(usize, Visit) -> Result<(), SimError>,
) -> Result<Visits, SimError> {
    if count == 0 || count > MAX_VISITS {
        return Err(SimError::Visits(count));
    }
    if first.saturating_add(count) > MAX_VISIT_NUMBER {
        return Err(SimError::VisitNumber { first: first.saturating_add(1), count });
    }
    let mut room = super::with_options_models(room, options);
    let mut rng = Rng::new(options.seed);
    let nominal_camera = true_camera(&room, options)?;
    // The nominal vehicle: no mounting error (the room file's nominal mounting).
    let nominal_lidar_to_camera = nominal_mounting(&room);
    let camera_in_vehicle = nominal_lidar_to_camera.inverse();
    let count_boards = options.boards.unwrap_or(room.board.count as usize);
    room.board.count = count_boards as u32;
    let boards_in_room =
        lay_out_room(&room, options, &nominal_camera, &camera_in_vehicle, &mut rng)?;
    room.board.count = boards_in_room.len() as u32;
    let layout = RoomLayout { boards_in_room, world_seed: rng.next_u64() };
    let truth = layout.truth(
        &room,
        options.seed,
        "the nominal vehicle's nominal LiDAR frame at the nominal parking spot \
         (x forward, y left, z up)",
    );
    let vehicle = VehicleContext {
        room: &room,
        options,
        nominal_camera: &nominal_camera,
        camera_in_vehicle: &camera_in_vehicle,
        boards_in_room: &layout.boards_in_room,
        world_seed: layout.world_seed,
    };
    for k in 0..first + count {
        // Every visit's stream is forked in turn (a fork advances the room's generator),
        // the earlier ones only to be skipped.
        let mut stream = rng.fork(100 + k as u64);
        if k >= first {
            each(k, vehicle.visit(&mut stream)?)?;
        }
    }
    Ok(Visits { room, truth, visits: Vec::new(), layout })
}

/// Writes `room-truth.json`, the simulated `room.toml` and one folder `visit-NN`
/// (`visit-01` …) per visit with `image.png`, `cloud.pcd`, `truth.json` (with
/// `room_to_camera`) and `room.toml`.
pub fn write_visits(visits: &Visits, dir: &Path) -> Result<(), SimError> {
    for (k, visit) in visits.visits.iter().enumerate() {
        write_visit(visit, k, dir)?;
    }
    write_room(visits, dir)
}

/// Visit `k`'s folder of [`write_visits`] (`visit-NN`, created with `dir`).
pub fn write_visit(visit: &Visit, k: usize, dir: &Path) -> Result<(), SimError> {
    let folder = dir.join(visit_folder(k));
    super::write_scene(&visit.scene, &folder)?;
    let truth = VisitTruth {
        scene: visit.scene.truth.clone(),
        room_to_camera: Extrinsic::from_se3(&visit.room_to_camera),
    };
    let path = folder.join("truth.json");
    let json = serde_json::to_string_pretty(&truth).expect("truth serialises");
    std::fs::write(&path, json + "\n").map_err(|e| SimError::write(&path, &e))
}

/// The room's files of [`write_visits`]: `room-truth.json` and `room.toml` in `dir`.
pub fn write_room(visits: &Visits, dir: &Path) -> Result<(), SimError> {
    std::fs::create_dir_all(dir).map_err(|e| SimError::write(dir, &e))?;
    let path = dir.join("room-truth.json");
    let json = serde_json::to_string_pretty(&visits.truth).expect("truth serialises");
    std::fs::write(&path, json + "\n").map_err(|e| SimError::write(&path, &e))?;
    let path = dir.join("room.toml");
    std::fs::write(&path, crate::room::to_toml(&visits.room))
        .map_err(|e| SimError::write(&path, &e))
}

/// The folder name of visit `index` (0-based): `visit-01`, `visit-02`, ….
pub fn visit_folder(index: usize) -> String {
    format!("visit-{:02}", index + 1)
}

/// Board → room poses: the single-scene layout for the nominal vehicle at the nominal
/// spot, through a narrower lens.
pub(super) fn lay_out_room(
    room: &Room,
    options: &SimOptions,
    nominal_camera: &Camera,
    camera_in_vehicle: &Se3,
    rng: &mut Rng,
) -> Result<Vec<Se3>, SimError> {
    let mut narrow = *nominal_camera;
    narrow.fx *= LAYOUT_ZOOM;
    narrow.fy *= LAYOUT_ZOOM;
    // With a ring, the room's own boards are laid out for the narrower lens.
    let inner = match options.ring {
        None => narrow,
        Some(ring) => {
            let hfov = super::field_of_view(ring.inner_hfov_deg)?;
            let (w, h) = (narrow.width, narrow.height);
            let fx = Camera::from_fov(narrow.model, w, h, hfov, [0.0; 5]).fx * LAYOUT_ZOOM;
            let mut inner = narrow;
            (inner.fx, inner.fy) = (fx, fx * narrow.fy / narrow.fx);
            inner
        }
    };
    let lidar_to_camera = camera_in_vehicle.inverse();
    let band_row = match (options.layout, &room.lidar) {
        (Layout::Grid, _) => None,
        (Layout::Band, None) => return Err(SimError::BandWithoutLidar),
        (Layout::Band, Some(lidar)) => {
            let elevations = lidar
                .model
                .and_then(raycast::beam_elevations)
                .ok_or(SimError::NoBeamTable(lidar.model))?;
            Some(band_row_px(&inner, &lidar_to_camera, elevations))
        }
    };
    let fits = |board_to_camera: &Se3| fits_in_room(room, camera_in_vehicle, board_to_camera);
    let count = room.board.count as usize;
    let mut poses = layout::lay_out(&room.board, &inner, count, band_row, &mut rng.fork(2), &fits)?;
    if let Some(ring) = options.ring {
        let spec = &room.board;
        // To the edge of the room camera's view, turned as the rig's widest camera is (a
        // vehicle parked off loses a column of them; every one stays in most visits: a
        // lens narrowed by a tenth failed to fit a lower corner's board into the room).
        let turn = Se3::from_rvec_t(
            &Vec3::new(0.0, -ring.turn_left_deg.to_radians(), 0.0),
            &Vec3::zeros(),
        );
        let in_turned: Vec<Se3> = poses.iter().map(|p| turn.inverse().compose(p)).collect();
        let fits_turned = |p: &Se3| fits(&turn.compose(p));
        let more = layout::lay_out_ring(
            spec,
            nominal_camera,
            ring.boards,
            &in_turned,
            &mut rng.fork(3),
            &fits_turned,
        )?;
        poses.extend(more.iter().map(|p| turn.compose(p)));
    }
    Ok(poses.iter().map(|p| camera_in_vehicle.compose(p)).collect())
}

/// What every visit shares.
struct VehicleContext<'a> {
    room: &'a Room,
    options: &'a SimOptions,
    nominal_camera: &'a Camera,
    camera_in_vehicle: &'a Se3,
    boards_in_room: &'a [Se3],
    world_seed: u64,
}

impl VehicleContext<'_> {
    /// One vehicle, parked once: its own camera and mounting, its own parking error.
    fn visit(&self, rng: &mut Rng) -> Result<Visit, SimError> {
        let camera = vehicle_camera(self.nominal_camera, &mut rng.fork(1));
        let lidar_to_camera = true_extrinsic(self.room, &mut rng.fork(2));
        let vehicle_to_room = parking_pose(&mut rng.fork(3));
        let camera_to_room = vehicle_to_room.compose(self.camera_in_vehicle);
        let lidar_to_room = camera_to_room.compose(&lidar_to_camera);
        let room_to_camera = camera_to_room.inverse();
        let room_to_lidar = lidar_to_room.inverse();
        let to_camera: Vec<Se3> =
            self.boards_in_room.iter().map(|b| room_to_camera.compose(b)).collect();
        let to_lidar: Vec<Se3> =
            self.boards_in_room.iter().map(|b| room_to_lidar.compose(b)).collect();
        let world = World::new(&self.room.board, to_lidar.clone(), &mut Rng::new(self.world_seed))
            .placed(lidar_to_room);
        let camera_in_lidar = lidar_to_camera.inverse();
        let options = self.options;
        let image =
            render::render(&world, &camera, &camera_in_lidar, &options.image, &mut rng.fork(4));
        let (cloud, sweep_truth) = match &self.room.lidar {
            Some(lidar) => {
                let cal = lidar
                    .model
                    .and_then(raycast::calibration)
                    .ok_or(SimError::NoBeamTable(lidar.model))?;
                let phase = (rng.next_u64() % u64::from(raycast::AZIMUTH_STEP)) as u16;
                let cast =
                    raycast::sweep(&world, &cal, options.range_noise_m, phase, &mut rng.fork(5));
                (Some((cast.points, cast.firings)), Some(cast.truth))
            }
            None => (None, None),
        };
        let boards = to_camera
            .iter()
            .zip(&to_lidar)
            .enumerate()
            .map(|(i, (c, l))| {
                let sweep = sweep_truth.as_ref().map(|t| (t, i));
                let mut truth = board_truth_visible(self.room, &camera, c, l, sweep);
                truth.occluded_corners = occluded_corners(&world, i, &camera_in_lidar);
                truth
            })
            .collect();
        let truth = Truth {
            seed: options.seed,
            camera: crate::result::CameraResult::from_camera(&camera),
            lidar_model: self.room.lidar.as_ref().and_then(|l| l.model),
            lidar_to_camera: self
                .room
                .lidar
                .as_ref()
                .map(|_| Extrinsic::from_se3(&lidar_to_camera)),
            range_noise_m: options.range_noise_m,
            image_noise_grey: options.image.noise_grey,
            image_blur_px: options.image.blur_px,
            boards,
        };
        let (cloud, firings) = cloud.map_or((None, None), |(p, f)| (Some(p), Some(f)));
        let more = self.standing_frames(&world, &camera, &camera_in_lidar, &mut rng.fork(6))?;
        let scene = Scene { room: self.room.clone(), image, cloud, firings, more, truth };
        Ok(Visit { scene, room_to_camera })
    }
}

impl VehicleContext<'_> {
    /// The standing vehicle's further frames and sweeps ([`SimOptions::standing_frames`]):
    /// the same parking, new sensor noise, the sweeps' start azimuths spread over a step
    /// (as [`super::simulate`] makes them). From their own fork of the visit's generator, so
    /// a visit's first frame is the same with or without them.
    fn standing_frames(
        &self,
        world: &World,
        camera: &Camera,
        camera_in_lidar: &Se3,
        rng: &mut Rng,
    ) -> Result<Vec<StandingFrame>, SimError> {
        let frames = self.options.standing_frames.max(1);
        let beams = match &self.room.lidar {
            Some(lidar) if frames > 1 => Some(
                lidar
                    .model
                    .and_then(raycast::calibration)
                    .ok_or(SimError::NoBeamTable(lidar.model))?,
            ),
            _ => None,
        };
        Ok((1..frames)
            .map(|k| {
                let image =
                    render::render(world, camera, camera_in_lidar, &self.options.image, rng);
                let phase = (k * usize::from(raycast::AZIMUTH_STEP) / frames) as u16;
                let cloud = beams.as_ref().map(|cal| {
                    raycast::sweep(world, cal, self.options.range_noise_m, phase, rng).points
                });
                StandingFrame { image, cloud }
            })
            .collect())
    }
}

/// A board's truth; a board this vehicle's camera cannot project (it does not happen with
/// the parking error's bounds, but nothing here may panic) gets no pixels.
pub(super) fn board_truth_visible(
    room: &Room,
    camera: &Camera,
    to_camera: &Se3,
    to_lidar: &Se3,
    sweep: Option<(&raycast::SweepTruth, usize)>,
) -> super::BoardTruth {
    let spec = &room.board;
    let projects = (0..spec.corner_count())
        .map(|i| spec.corner(i))
        .chain((0..spec.holes.len()).map(|h| spec.hole(h)))
        .all(|p| camera.project(&to_camera.act(&p)).is_some());
    if projects {
        return board_truth(room, camera, to_camera, to_lidar, sweep);
    }
    super::BoardTruth {
        board_to_camera: Extrinsic::from_se3(to_camera),
        corners_px: Vec::new(),
        holes_px: Vec::new(),
        holes_lidar: match sweep {
            Some(_) => (0..spec.holes.len()).map(|h| to_lidar.act(&spec.hole(h)).into()).collect(),
            None => Vec::new(),
        },
        lidar_points: sweep.map_or(0, |(t, i)| t.board_points[i]),
        occluded_corners: 0,
        hole_scan_lines: sweep.map_or(Vec::new(), |(t, i)| t.hole_rings[i].clone()),
    }
}

/// A vehicle's camera: the nominal one with its own focal length, principal point and
/// distortion, as units of one camera model differ.
pub(super) fn vehicle_camera(nominal: &Camera, rng: &mut Rng) -> Camera {
    let (focal, principal, distortion) = VEHICLE_SPREAD;
    let mut camera = *nominal;
    let scale = 1.0 + rng.range(-focal, focal);
    camera.fx *= scale;
    camera.fy *= scale * (1.0 + rng.range(-0.001, 0.001));
    camera.cx += rng.range(-principal, principal);
    camera.cy += rng.range(-principal, principal);
    for d in camera.distortion.iter_mut() {
        *d *= 1.0 + rng.range(-distortion, distortion);
    }
    camera
}

/// Where a visit parks the vehicle frame in the room.
pub(super) fn parking_pose(rng: &mut Rng) -> Se3 {
    let (shift, yaw, tilt) = PARKING_ERROR;
    let angles = Vec3::new(
        rng.range(-tilt, tilt).to_radians(),
        rng.range(-tilt, tilt).to_radians(),
        rng.range(-yaw, yaw).to_radians(),
    );
    let translation = Vec3::new(rng.range(-shift, shift), rng.range(-shift, shift), 0.0);
    Se3 { rotation: so3_exp(&angles), translation }
}

/// The room file's nominal LiDAR → camera mounting (the level forward-looking frame of
/// the single-scene simulator without a LiDAR).
fn nominal_mounting(room: &Room) -> Se3 {
    match &room.lidar {
        Some(lidar) => {
            Se3 { rotation: lidar.rotation_matrix(), translation: lidar.translation_vector() }
        }
        None => true_extrinsic(room, &mut Rng::new(0)),
    }
}
