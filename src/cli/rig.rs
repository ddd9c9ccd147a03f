//! A rig's inputs (`calibrate --rig`, `detect --rig`): the `NAME=PATH` values of `--image`
//! and `--cloud` checked against the rig file (unknown name, a camera's name given to
//! `--cloud` or a LiDAR's to `--image`, a sensor without data, a missing `NAME=`: exit 2
//! naming it), each sensor's frames of the standing vehicle averaged (images) or
//! accumulated (sweeps), and detected in the sensor's own pair room.

use std::path::{Path, PathBuf};

use anyhow::anyhow;

use roomcal::calibrate::{expected_in_rig_lidars, CameraBoard, CornerStart, Detectors, LidarBoard};
use roomcal::detect::GreyImage;
use roomcal::geometry::Se3;
use roomcal::lidar::Point;
use roomcal::rig::{Rig, SensorKind};
use roomcal::target::Room;

use super::io::{load_clouds, mean_image};
use super::{bad_input, Failure};

/// Every sensor's inputs, in the rig's order.
#[derive(Debug)]
pub struct RigInputs {
    pub images: Vec<Vec<PathBuf>>,
    pub clouds: Vec<Vec<PathBuf>>,
}

/// Splits `NAME=PATH` values of `--image` and `--cloud` by sensor and checks them.
/// `require_all`: every sensor must have data (calibrate; detect takes any subset).
pub fn inputs(
    rig: &Rig,
    rig_path: &Path,
    images: &[PathBuf],
    clouds: &[PathBuf],
    require_all: bool,
) -> Result<RigInputs, Failure> {
    let mut out = RigInputs {
        images: vec![Vec::new(); rig.cameras.len()],
        clouds: vec![Vec::new(); rig.lidars.len()],
    };
    for (flag, values, wanted) in
        [("--image", images, SensorKind::Camera), ("--cloud", clouds, SensorKind::Lidar)]
    {
        for value in values {
            let text = value.to_string_lossy();
            let Some((name, path)) = text.split_once('=') else {
                return Err(bad_input(anyhow!(
                    "{flag} {text}: with --rig every input is NAME=PATH (a sensor of {})",
                    rig_path.display()
                )));
            };
            let (kind, index) = rig.find(name).ok_or_else(|| {
                bad_input(anyhow!(
                    "{flag} {text}: unknown sensor `{name}`: {} has {}",
                    rig_path.display(),
                    sensor_list(rig)
                ))
            })?;
            if kind != wanted {
                let other = if kind == SensorKind::Camera { "--image" } else { "--cloud" };
                return Err(bad_input(anyhow!(
                    "{flag} {text}: `{name}` is a {kind} in {}; give its data to {other}",
                    rig_path.display()
                )));
            }
            let slot = match kind {
                SensorKind::Camera => &mut out.images[index],
                SensorKind::Lidar => &mut out.clouds[index],
            };
            slot.push(PathBuf::from(path));
        }
    }
    if require_all {
        let cameras =
            rig.cameras.iter().zip(&out.images).map(|(c, v)| ("camera", &c.name, "--image", v));
        let lidars =
            rig.lidars.iter().zip(&out.clouds).map(|(l, v)| ("lidar", &l.name, "--cloud", v));
        if let Some((kind, name, flag, _)) = cameras.chain(lidars).find(|(_, _, _, v)| v.is_empty())
        {
            return Err(bad_input(anyhow!(
                "{kind} `{name}` of {} has no data: give {flag} {name}=PATH",
                rig_path.display()
            )));
        }
    }
    Ok(out)
}

fn sensor_list(rig: &Rig) -> String {
    let names = |v: Vec<&str>| if v.is_empty() { "none".to_string() } else { v.join(", ") };
    format!(
        "cameras {} and LiDARs {}",
        names(rig.cameras.iter().map(|c| c.name.as_str()).collect()),
        names(rig.lidars.iter().map(|l| l.name.as_str()).collect())
    )
}

/// Each camera's boards and each LiDAR's boards and accumulated sweep.
pub struct RigDetections {
    pub cameras: Vec<Vec<CameraBoard>>,
    pub lidars: Vec<(Vec<LidarBoard>, Vec<Point>)>,
    /// The first camera's start from its corners when it was made to find the LiDARs'
    /// boards ([`expected_in_rig_lidars`]): give it to the calibration as
    /// `CalibrateOptions::corner_start`, which then does not make it again.
    pub first_start: Option<CornerStart>,
}

/// Loads and detects every sensor's data (frames averaged, sweeps accumulated), the
/// sensors spread over the cores: the cameras (and the sweeps' loading) first, then the
/// LiDARs, in a surveyed room (unless `free_boards`) where the first camera's boards say
/// the room's boards are ([`expected_in_rig_lidars`]), as the daemon does.
pub fn detect_all(
    room: &Room,
    rig: &Rig,
    inputs: &RigInputs,
    angles: Option<&Path>,
    free_boards: bool,
) -> Result<RigDetections, Failure> {
    let cameras = (0..rig.cameras.len()).map(Sensor::Camera);
    let sensors: Vec<Sensor> = cameras.chain((0..rig.lidars.len()).map(Sensor::Lidar)).collect();
    let loaded = roomcal::parallel::map(&sensors, |_, sensor| match *sensor {
        Sensor::Camera(c) => detect_camera(room, rig, c, &inputs.images[c]).map(Loaded::Camera),
        Sensor::Lidar(l) => load_lidar(rig, l, &inputs.clouds[l], angles).map(Loaded::Lidar),
    });
    let mut out = RigDetections { cameras: Vec::new(), lidars: Vec::new(), first_start: None };
    let mut clouds = Vec::new();
    for loaded in loaded {
        match loaded? {
            Loaded::Camera(boards) => out.cameras.push(boards),
            Loaded::Lidar(cloud) => clouds.push(cloud),
        }
    }
    let first = out.cameras.first().map_or(&[][..], Vec::as_slice);
    let expected = expected_in_rig_lidars(room, rig, first, free_boards);
    let found = roomcal::parallel::map(&clouds, |l, cloud| {
        let at = expected.as_ref().and_then(|e| e.lidars.get(l)).map(Vec::as_slice);
        detect_lidar(room, rig, l, cloud, at)
    });
    for (boards, cloud) in found.into_iter().zip(clouds) {
        out.lidars.push((boards?, cloud));
    }
    out.first_start = expected.map(|e| e.first_start);
    Ok(out)
}

/// One sensor of the rig, by its index among its kind.
enum Sensor {
    Camera(usize),
    Lidar(usize),
}

/// What one sensor's data showed: a camera's boards, a LiDAR's sweep (detected next).
enum Loaded {
    Camera(Vec<CameraBoard>),
    Lidar(Vec<Point>),
}

/// Camera `c`'s boards in its frames (averaged: a standing vehicle's).
fn detect_camera(
    room: &Room,
    rig: &Rig,
    c: usize,
    paths: &[PathBuf],
) -> Result<Vec<CameraBoard>, Failure> {
    let Some(frame) = camera_frame(rig, c, paths)? else { return Ok(Vec::new()) };
    let mut detectors = Detectors::new(&rig.pair_room(room, c, None)).map_err(bad_input)?;
    detectors.detect_image(&frame).map_err(bad_input)
}

/// Camera `c`'s frames averaged into one (a standing vehicle's), `None` without frames.
pub fn camera_frame(rig: &Rig, c: usize, paths: &[PathBuf]) -> Result<Option<GreyImage>, Failure> {
    let spec = &rig.cameras[c].spec;
    let whose = format!("camera `{}` of the rig", rig.cameras[c].name);
    mean_image(paths, (spec.width, spec.height), &whose, |_| {})
}

/// LiDAR `l`'s sweeps, read and accumulated into one cloud.
fn load_lidar(
    rig: &Rig,
    l: usize,
    paths: &[PathBuf],
    angles: Option<&Path>,
) -> Result<Vec<Point>, Failure> {
    let model = rig.lidars[l].model;
    let sweeps = load_clouds(paths, |path| {
        roomcal::lidar::read_cloud(path, model, angles).map_err(bad_input)
    })?;
    Ok(roomcal::lidar::accumulate_sweeps(sweeps))
}

/// LiDAR `l`'s boards in its sweep: at `expected` when given (the global search when that
/// places fewer than two), else by global search.
fn detect_lidar(
    room: &Room,
    rig: &Rig,
    l: usize,
    cloud: &[Point],
    expected: Option<&[Se3]>,
) -> Result<Vec<LidarBoard>, Failure> {
    if cloud.is_empty() {
        return Ok(Vec::new());
    }
    let mut detectors = Detectors::new(&rig.pair_room(room, 0, Some(l))).map_err(bad_input)?;
    Ok(detectors.detect_where_expected(cloud, expected))
}
