//! `calibrate --rig` and `detect --rig`: a rig's `NAME=PATH` inputs checked against the
//! rig file (unknown name, a camera's name given to `--cloud` or a LiDAR's to `--image`,
//! a sensor without data, a missing `NAME=`: exit 2 naming it), each sensor's frames of
//! the standing vehicle averaged (images) or accumulated (sweeps), detected in the
//! sensor's own pair room, and calibrated by `calibrate::rig`.

use std::path::{Path, PathBuf};

use anyhow::anyhow;

use roomcal::calibrate::rig::{calibrate_rig, LidarInput};
use roomcal::calibrate::{
    expected_in_rig_lidars, CalibrateOptions, CameraBoard, CornerStart, Detectors, LidarBoard,
};
use roomcal::detect::GreyImage;
use roomcal::geometry::Se3;
use roomcal::lidar::Point;
use roomcal::result::{BoardDetection, Detections, RigResult, Status};
use roomcal::rig::{Rig, SensorKind};
use roomcal::target::Room;

use crate::{bad_input, load_image_sized, standing_frame, Failure};

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
fn camera_frame(rig: &Rig, c: usize, paths: &[PathBuf]) -> Result<Option<GreyImage>, Failure> {
    let spec = &rig.cameras[c].spec;
    let whose = format!("camera `{}` of the rig", rig.cameras[c].name);
    let images = paths
        .iter()
        .map(|p| load_image_sized(p, (spec.width, spec.height), &whose))
        .collect::<Result<Vec<_>, _>>()?;
    let (frames, _) = standing_frame(images, Vec::new());
    Ok(frames.into_iter().next())
}

/// The rig's report pictures, one per camera ([`roomcal::report::camera_path`]: `report.png`
/// → `report-front.png`): the camera's frame (its frames averaged) with every LiDAR's sweep
/// and hole centres drawn through the solved rig, its corners and the verdicts
/// ([`roomcal::report::rig_camera_report`]). A camera without
/// a solved model is left out. Returns the files written.
pub fn write_reports(
    report: &Path,
    rig: &Rig,
    inputs: &RigInputs,
    detections: &RigDetections,
    result: &RigResult,
) -> Result<Vec<PathBuf>, Failure> {
    let sweeps: Vec<&[Point]> = detections.lidars.iter().map(|(_, c)| c.as_slice()).collect();
    let lidar_boards: Vec<&[LidarBoard]> =
        detections.lidars.iter().map(|(b, _)| b.as_slice()).collect();
    let mut written = Vec::new();
    for (c, camera) in rig.cameras.iter().enumerate() {
        let Some(frame) = camera_frame(rig, c, &inputs.images[c])? else { continue };
        let marks = roomcal::report::RigMarks {
            corners: &detections.cameras[c],
            sweeps: &sweeps,
            lidar_boards: &lidar_boards,
        };
        let Some(picture) = roomcal::report::rig_camera_report(rig, result, c, &frame.data, &marks)
        else {
            continue;
        };
        let path = roomcal::report::camera_path(report, &camera.name);
        picture
            .save(&path)
            .map_err(|e| bad_input(anyhow!("writing the report {}: {e}", path.display())))?;
        written.push(path);
    }
    Ok(written)
}

/// LiDAR `l`'s sweeps, read and accumulated into one cloud.
fn load_lidar(
    rig: &Rig,
    l: usize,
    paths: &[PathBuf],
    angles: Option<&Path>,
) -> Result<Vec<Point>, Failure> {
    let model = rig.lidars[l].model.packet_model();
    let mut cloud = Vec::new();
    for path in paths {
        cloud.extend(roomcal::lidar::read_cloud(path, model, angles).map_err(bad_input)?);
    }
    Ok(cloud)
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

/// Where `calibrate --rig` writes: the result file, the exports (accepted runs only), the
/// result on stdout instead of the summary (`json`), or only the status line (`quiet`).
#[derive(Clone, Copy, Debug)]
pub struct RigOutputs<'a> {
    pub out: &'a Path,
    pub export: Option<&'a Path>,
    /// The report pictures ([`write_reports`]) and the inputs they are drawn on.
    pub report: Option<(&'a Path, &'a RigInputs)>,
    pub json: bool,
    pub quiet: bool,
}

/// `roomcal calibrate --rig`: writes the rig's result file (and its exports); exit 0
/// accepted, 3 rejected.
pub fn calibrate(
    room: &Room,
    rig: &Rig,
    detections: &RigDetections,
    options: &CalibrateOptions,
    outputs: RigOutputs<'_>,
) -> Result<(), Failure> {
    let lidars: Vec<LidarInput<'_>> =
        detections.lidars.iter().map(|(boards, cloud)| LidarInput { boards, cloud }).collect();
    let run = calibrate_rig(room, rig, &detections.cameras, &lidars, options);
    let json = serde_json::to_string_pretty(&run.result).expect("results serialise") + "\n";
    let out = outputs.out;
    std::fs::write(out, &json).map_err(|e| bad_input(anyhow!("writing {}: {e}", out.display())))?;
    let result = &run.result;
    let accepted = result.pair.status == Status::Accepted;
    let mut exported = Vec::new();
    if let Some(dir) = outputs.export.filter(|_| accepted) {
        exported = roomcal::export::write_dir(dir, &roomcal::export::rig_files(result))
            .map_err(bad_input)?;
    }
    if let Some((report, inputs)) = outputs.report {
        exported.extend(write_reports(report, rig, inputs, detections, result)?);
    }
    if outputs.json {
        say_raw!("{json}");
        return verdict(result.pair.status);
    }
    let quiet = outputs.quiet;
    match result.pair.status {
        Status::Accepted => {
            say!("roomcal calibrate: accepted (rig of {} sensors)", result.sensors.len())
        }
        Status::Rejected => say!(
            "roomcal calibrate: rejected: {}",
            result.pair.reason.as_deref().unwrap_or("rejected")
        ),
    }
    if !quiet {
        for (name, sensor) in &result.sensors {
            let verdict = match sensor.status {
                Status::Accepted => "accepted".to_string(),
                Status::Rejected => format!("rejected: {}", sensor.reason.as_deref().unwrap_or("")),
            };
            match (&sensor.camera, &sensor.uncertainty) {
                (Some(c), Some(u)) => say!(
                    "  camera {name}: fx {:.2} ± {:.2} fy {:.2} cx {:.2} ± {:.2} cy {:.2} ± {:.2} px; {verdict}",
                    c.fx, u.fx, c.fy, c.cx, u.cx, c.cy, u.cy
                ),
                _ => say!("  lidar {name}: {verdict}"),
            }
        }
        for e in &result.extrinsics {
            let t = e.translation;
            say!(
                "  {} → {}: translation [{:.4}, {:.4}, {:.4}] m (σ {:.1} mm), σ rotation {:.3}°",
                e.from,
                e.to,
                t[0],
                t[1],
                t[2],
                e.sigma_translation_m * 1000.0,
                e.sigma_rotation_deg
            );
        }
        say!("  wrote {}", out.display());
        for path in &exported {
            say!("  wrote {}", path.display());
        }
    }
    verdict(result.pair.status)
}

/// The exit of a rig run: 0 accepted, 3 rejected.
fn verdict(status: Status) -> Result<(), Failure> {
    match status {
        Status::Accepted => Ok(()),
        Status::Rejected => Err(Failure { code: 3, error: None }),
    }
}

/// `roomcal detect --rig`: `{"sensors": {NAME: {"boards": [...]}}}`, each sensor's
/// detections in the one-pair form.
pub fn detections_json(rig: &Rig, inputs: &RigInputs, detections: &RigDetections) -> String {
    let mut sensors = serde_json::Map::new();
    for (c, boards) in detections.cameras.iter().enumerate() {
        if inputs.images[c].is_empty() {
            continue;
        }
        let boards = boards
            .iter()
            .map(|b| BoardDetection {
                corners_px: b.corners.iter().map(|p| [p.x, p.y]).collect(),
                ..BoardDetection::default()
            })
            .collect();
        let value = serde_json::to_value(Detections { boards }).expect("detections serialise");
        sensors.insert(rig.cameras[c].name.to_string(), value);
    }
    for (l, (boards, _)) in detections.lidars.iter().enumerate() {
        if inputs.clouds[l].is_empty() {
            continue;
        }
        let boards = boards
            .iter()
            .map(|b| BoardDetection {
                holes_lidar: b.holes.iter().map(|h| [h.x, h.y, h.z]).collect(),
                ..BoardDetection::default()
            })
            .collect();
        let value = serde_json::to_value(Detections { boards }).expect("detections serialise");
        sensors.insert(rig.lidars[l].name.to_string(), value);
    }
    let json = serde_json::json!({ "sensors": sensors });
    serde_json::to_string_pretty(&json).expect("detections serialise") + "\n"
}
