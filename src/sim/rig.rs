//! A rig's simulation: one vehicle with several cameras and LiDARs, parked once in one
//! room (`roomcal simulate --rig`). Every camera renders one frame and every LiDAR casts
//! one sweep of the same room, through the single-scene renderer and ray caster.
//!
//! Frames: the **vehicle frame** is the rig's first LiDAR's nominal frame (without a
//! LiDAR, the room file's nominal LiDAR frame); the **room frame** is the vehicle frame at
//! the nominal parking spot, as in [`super::visits`], so the room file's parking box holds.
//! The first camera sits at its nominal pose in the vehicle frame; every other sensor at
//! its true mounting relative to the first camera (the rig file's nominal, off by up to
//! 1.5° and 4 cm per axis). Each camera has its own intrinsics (the rig file's, else its
//! field of view, spread as units of one model differ), the vehicle its parking error.
//! The boards are laid out for the first camera (through a narrower lens, see `visits`).
//! The same seed gives the same bytes.
//!
//! A standing vehicle ([`SimOptions::standing_frames`] = N): every camera renders N − 1
//! more frames and every LiDAR casts N − 1 more sweeps (each from its own start azimuth
//! within a step) of the same parking with new sensor noise, from their own forks, so the
//! first frame and sweep are the same bytes with or without them.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::geometry::{Camera, Se3};
use crate::lidar::{Model, Point};
use crate::result::{CameraResult, Extrinsic};
use crate::rig::Rig;
use crate::target::Room;

use super::rng::Rng;
use super::visits::{
    board_truth_visible, lay_out_room, parking_pose, vehicle_camera, RoomLayout, RoomTruth,
};
use super::world::World;
use super::{
    occluded_corners, perturbed_mounting, raycast, render, true_camera, true_extrinsic, BoardTruth,
    SimError, SimOptions,
};

/// The fork of the seed's stream the first rig parked in a visited room draws from; the
/// k-th draws from this + k − 1 (the visits draw from 100 + k, k < 100).
const RIG_IN_VISITED_ROOM: u64 = 900;

/// A simulated rig: the room, every camera's frame and every LiDAR's sweep, the truth.
#[derive(Clone, Debug)]
pub struct RigSimulation {
    /// The room as simulated (its board count the options').
    pub room: Room,
    pub rig: Rig,
    pub room_truth: RoomTruth,
    /// Per rig camera, its grey frame (row-major).
    pub images: Vec<Vec<u8>>,
    /// Per rig LiDAR, its sweep.
    pub clouds: Vec<Vec<Point>>,
    /// A standing vehicle's further frames: per camera, frames 2, 3, … (empty for one).
    pub more_images: Vec<Vec<Vec<u8>>>,
    /// …and per LiDAR its further sweeps.
    pub more_clouds: Vec<Vec<Vec<Point>>>,
    pub truth: RigTruth,
}

/// The rig's truth (`rig-truth.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RigTruth {
    pub seed: u64,
    /// Vehicle frame → room frame (the parking pose).
    pub vehicle_to_room: Extrinsic,
    /// Per sensor name.
    pub sensors: BTreeMap<String, SensorTruth>,
}

/// One sensor's truth.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorTruth {
    /// Cameras: the true intrinsics and distortion.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraResult>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lidar_model: Option<Model>,
    /// Sensor → first camera, the true mounting: `p_first = rotation · p + translation`.
    pub to_reference: Extrinsic,
    /// Room → sensor: `p_sensor = rotation · p_room + translation`.
    pub room_to_sensor: Extrinsic,
    /// Per board, as the single-scene truth gives it: cameras carry the pixels (and
    /// `board_to_camera`, here board → this sensor), LiDARs the hole centres in their
    /// frame and the scan lines through each hole.
    pub boards: Vec<BoardTruth>,
}

/// Simulates `rig` parked once in `room` (`options.seed` fixes everything), the boards
/// laid out for its first camera.
pub fn simulate_rig(
    room: &Room,
    rig: &Rig,
    options: &SimOptions,
) -> Result<RigSimulation, SimError> {
    simulate_rig_in(room, rig, options, None)
}

/// [`simulate_rig`] in a room already laid out (`layout`, e.g. the one
/// [`super::visits::simulate_visits`] surveyed with the same options): the rig is one more
/// vehicle of that room, with a vehicle of its own (its random stream apart from the
/// visits'). `None`: the boards are laid out for the rig's first camera.
pub fn simulate_rig_in(
    room: &Room,
    rig: &Rig,
    options: &SimOptions,
    layout: Option<&RoomLayout>,
) -> Result<RigSimulation, SimError> {
    let rng = match layout {
        None => Rng::new(options.seed),
        Some(_) => Rng::new(options.seed).fork(RIG_IN_VISITED_ROOM),
    };
    simulate_from(room, rig, options, layout, rng)
}

/// The `vehicle`-th rig (from 1) parked in the visited room `layout`: each its own vehicle
/// (intrinsics, mountings, parking) in the same room, for a study over new vehicles in one
/// survey. Vehicle 1 is [`simulate_rig_in`]'s rig.
pub fn simulate_rig_vehicle(
    room: &Room,
    rig: &Rig,
    options: &SimOptions,
    layout: &RoomLayout,
    vehicle: u16,
) -> Result<RigSimulation, SimError> {
    let fork = RIG_IN_VISITED_ROOM + u64::from(vehicle.max(1)) - 1;
    simulate_from(room, rig, options, Some(layout), Rng::new(options.seed).fork(fork))
}

fn simulate_from(
    room: &Room,
    rig: &Rig,
    options: &SimOptions,
    layout: Option<&RoomLayout>,
    mut rng: Rng,
) -> Result<RigSimulation, SimError> {
    let first_lidar = (!rig.lidars.is_empty()).then_some(0);
    let mut room = rig.pair_room(room, 0, first_lidar);
    room.board.count = options.boards.unwrap_or(room.board.count as usize) as u32;
    // Without a LiDAR, `true_extrinsic` gives the level forward-looking frame.
    let reference_in_vehicle = match first_lidar {
        Some(l) => rig.lidars[l].to_reference.inverse(),
        None => true_extrinsic(&room, &mut Rng::new(0)).inverse(),
    };
    let laid_out = layout.is_some();
    let layout = match layout {
        Some(given) => given.clone(),
        None => {
            let nominal_first = true_camera(&room, options)?;
            let boards_in_room = lay_out_room(
                &room,
                options,
                &nominal_first,
                &reference_in_vehicle,
                &mut rng.fork(1),
            )?;
            RoomLayout { boards_in_room, world_seed: rng.next_u64() }
        }
    };
    room.board.count = layout.boards_in_room.len() as u32;
    let (boards_in_room, world_seed) = (&layout.boards_in_room, layout.world_seed);
    let vehicle_to_room = parking_pose(&mut rng.fork(2));
    let reference_to_room = vehicle_to_room.compose(&reference_in_vehicle);
    let mut truth = RigTruth {
        seed: options.seed,
        vehicle_to_room: Extrinsic::from_se3(&vehicle_to_room),
        sensors: BTreeMap::new(),
    };
    let scene = SceneContext { room: &room, options, boards_in_room, world_seed };
    let further = options.standing_frames.max(1) - 1;
    let (mut images, mut more_images, mut more_clouds) = (Vec::new(), Vec::new(), Vec::new());
    for (c, camera) in rig.cameras.iter().enumerate() {
        let mut sensor_rng = rng.fork(10 + c as u64);
        let to_reference = match c {
            0 => Se3::identity(),
            _ => perturbed_mounting(&camera.to_reference, &mut sensor_rng.fork(1)),
        };
        let pair = rig.pair_room(&room, c, None);
        let intrinsics = vehicle_camera(&true_camera(&pair, options)?, &mut sensor_rng.fork(2));
        let room_to_camera = reference_to_room.compose(&to_reference).inverse();
        let (image, boards) = scene.camera_view(&intrinsics, &room_to_camera, &mut sensor_rng)?;
        images.push(image);
        let mut standing = sensor_rng.fork(6);
        more_images.push(
            (0..further)
                .map(|_| {
                    scene.camera_view(&intrinsics, &room_to_camera, &mut standing).map(|v| v.0)
                })
                .collect::<Result<Vec<_>, _>>()?,
        );
        let sensor = SensorTruth {
            camera: Some(CameraResult::from_camera(&intrinsics)),
            lidar_model: None,
            to_reference: Extrinsic::from_se3(&to_reference),
            room_to_sensor: Extrinsic::from_se3(&room_to_camera),
            boards,
        };
        truth.sensors.insert(camera.name.to_string(), sensor);
    }
    let mut clouds = Vec::new();
    for (l, lidar) in rig.lidars.iter().enumerate() {
        let mut sensor_rng = rng.fork(50 + l as u64);
        let to_reference = perturbed_mounting(&lidar.to_reference, &mut sensor_rng.fork(1));
        let room_to_lidar = reference_to_room.compose(&to_reference).inverse();
        let (cloud, boards) = scene.lidar_view(lidar.model, &room_to_lidar, &mut sensor_rng)?;
        clouds.push(cloud);
        let mut standing = sensor_rng.fork(6);
        more_clouds.push(
            (0..further)
                .map(|_| scene.lidar_view(lidar.model, &room_to_lidar, &mut standing).map(|v| v.0))
                .collect::<Result<Vec<_>, _>>()?,
        );
        let sensor = SensorTruth {
            camera: None,
            lidar_model: lidar.model,
            to_reference: Extrinsic::from_se3(&to_reference),
            room_to_sensor: Extrinsic::from_se3(&room_to_lidar),
            boards,
        };
        truth.sensors.insert(lidar.name.to_string(), sensor);
    }
    let frame = match laid_out {
        true => {
            "the visited room's frame: the nominal vehicle's nominal LiDAR frame at the \
                 nominal parking spot (x forward, y left, z up)"
        }
        false => {
            "the rig's vehicle frame (its first LiDAR's nominal frame) at the nominal \
                  parking spot (x forward, y left, z up)"
        }
    };
    let room_truth = layout.truth(&room, options.seed, frame);
    Ok(RigSimulation {
        room,
        rig: rig.clone(),
        room_truth,
        images,
        clouds,
        more_images,
        more_clouds,
        truth,
    })
}

/// Writes `NAME.png` per camera, `NAME.pcd` per LiDAR (a standing vehicle's frame k > 1
/// as `NAME-k.png`, `NAME-k.pcd`), `rig-truth.json`, `room-truth.json` and the simulated
/// `room.toml` (the room's `[camera]`/`[lidar]` are the rig's first pair).
pub fn write_rig(sim: &RigSimulation, dir: &Path) -> Result<Vec<std::path::PathBuf>, SimError> {
    std::fs::create_dir_all(dir).map_err(|e| SimError::write(dir, &e))?;
    let mut written = Vec::new();
    let frame_name = |name: &str, k: usize, extension: &str| match k {
        1 => format!("{name}.{extension}"),
        _ => format!("{name}-{k}.{extension}"),
    };
    for (c, camera) in sim.rig.cameras.iter().enumerate() {
        let more = sim.more_images.get(c).map_or(&[][..], Vec::as_slice);
        for (k, image) in std::iter::once(&sim.images[c]).chain(more).enumerate() {
            let path = dir.join(frame_name(camera.name.as_str(), k + 1, "png"));
            image::GrayImage::from_raw(camera.spec.width, camera.spec.height, image.clone())
                .expect("the renderer makes width × height pixels")
                .save(&path)
                .map_err(|e| SimError::write(&path, &e))?;
            written.push(path);
        }
    }
    for (l, lidar) in sim.rig.lidars.iter().enumerate() {
        let more = sim.more_clouds.get(l).map_or(&[][..], Vec::as_slice);
        for (k, cloud) in std::iter::once(&sim.clouds[l]).chain(more).enumerate() {
            let path = dir.join(frame_name(lidar.name.as_str(), k + 1, "pcd"));
            crate::lidar::pcd::write(&path, cloud, crate::lidar::pcd::PcdFormat::Binary)
                .map_err(|e| SimError::write(&path, &e))?;
            written.push(path);
        }
    }
    for (name, text) in [
        ("rig-truth.json", pretty_json(&sim.truth)),
        ("room-truth.json", pretty_json(&sim.room_truth)),
        ("room.toml", crate::room::to_toml(&sim.room)),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, text).map_err(|e| SimError::write(&path, &e))?;
        written.push(path);
    }
    Ok(written)
}

fn pretty_json(value: &impl Serialize) -> String {
    serde_json::to_string_pretty(value).expect("truth serialises") + "\n"
}

/// What every sensor's view shares: the room, its boards in the room frame, its clutter.
struct SceneContext<'a> {
    room: &'a Room,
    options: &'a SimOptions,
    boards_in_room: &'a [Se3],
    world_seed: u64,
}

impl SceneContext<'_> {
    /// The room as seen from a sensor at `room_to_sensor` (boards in the sensor's frame).
    fn world(&self, room_to_sensor: &Se3) -> (World, Vec<Se3>) {
        let to_sensor: Vec<Se3> =
            self.boards_in_room.iter().map(|b| room_to_sensor.compose(b)).collect();
        let world = World::new(&self.room.board, to_sensor.clone(), &mut Rng::new(self.world_seed))
            .placed(room_to_sensor.inverse());
        (world, to_sensor)
    }

    /// A camera's frame and its boards' truth.
    fn camera_view(
        &self,
        camera: &Camera,
        room_to_camera: &Se3,
        rng: &mut Rng,
    ) -> Result<(Vec<u8>, Vec<BoardTruth>), SimError> {
        let (world, to_camera) = self.world(room_to_camera);
        let here = Se3::identity();
        let image = render::render(&world, camera, &here, &self.options.image, &mut rng.fork(4));
        let boards = to_camera
            .iter()
            .enumerate()
            .map(|(i, pose)| {
                let mut truth = board_truth_visible(self.room, camera, pose, pose, None);
                truth.occluded_corners = occluded_corners(&world, i, &here);
                truth
            })
            .collect();
        Ok((image, boards))
    }

    /// A LiDAR's sweep and its boards' truth (hole centres in its frame, scan lines).
    fn lidar_view(
        &self,
        model: Option<Model>,
        room_to_lidar: &Se3,
        rng: &mut Rng,
    ) -> Result<(Vec<Point>, Vec<BoardTruth>), SimError> {
        let (world, to_lidar) = self.world(room_to_lidar);
        let cal = model.and_then(raycast::calibration).ok_or(SimError::NoBeamTable(model))?;
        let phase = (rng.next_u64() % u64::from(raycast::AZIMUTH_STEP)) as u16;
        let cast =
            raycast::sweep(&world, &cal, self.options.range_noise_m, phase, &mut rng.fork(5));
        let spec = &self.room.board;
        let boards = to_lidar
            .iter()
            .enumerate()
            .map(|(i, pose)| BoardTruth {
                board_to_camera: Extrinsic::from_se3(pose),
                corners_px: Vec::new(),
                holes_px: Vec::new(),
                holes_lidar: (0..spec.holes.len())
                    .map(|h| pose.act(&spec.hole(h)).into())
                    .collect(),
                lidar_points: cast.truth.board_points[i],
                occluded_corners: 0,
                hole_scan_lines: cast.truth.hole_rings[i].clone(),
            })
            .collect();
        Ok((cast.points, boards))
    }
}
