//! `roomcal calibrate`: image/cloud pairs (or a standing vehicle's frames and sweeps, or a
//! rig's `NAME=PATH` inputs) → the result file, its YAML, the report picture and exports;
//! exit 0 accepted, 3 rejected.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context};
use clap::Args;

use roomcal::calibrate::rig::{calibrate_rig, LidarInput};
use roomcal::calibrate::{
    calibrate_detecting, CalibrateOptions, Detectors, FrameDetections, LidarAngles,
};
use roomcal::detect::holes::RefusedBoard;
use roomcal::detect::GreyImage;
use roomcal::geometry::body::BodyPose;
use roomcal::lidar::Point;
use roomcal::result::{RigResult, Status};
use roomcal::rig::Rig;
use roomcal::target::Room;

use super::detect::refused_lines;
use super::io::{
    check_image_sized, load_cloud, load_clouds, load_image, mean_image, result_json, write_result,
};
use super::progress::Progress;
use super::rig::{RigDetections, RigInputs};
use super::{bad_input, rejected, summary, Failure};

#[derive(Args)]
pub struct CalibrateArgs {
    /// The room file.
    #[arg(long)]
    room: PathBuf,
    /// A camera frame (PNG or JPEG); repeat for several. Image i pairs with cloud i.
    #[arg(long, required_unless_present = "detections")]
    image: Vec<PathBuf>,
    /// A detections file (JSON, as `roomcal detect` writes it, or another tool's in that
    /// form) to solve instead of images and clouds.
    #[arg(long, value_name = "JSON", conflicts_with_all = ["image", "cloud", "standing", "rig", "report", "lidar_calibration"])]
    detections: Option<PathBuf>,
    /// A LiDAR cloud (PCD, or a pcap/pcapng capture of the room's model); repeat for several.
    #[arg(long)]
    cloud: Vec<PathBuf>,
    /// The result file (JSON); an OpenCV-style YAML is written beside it.
    #[arg(long, default_value = "result.json")]
    out: PathBuf,
    /// Draw the overlay report (PNG): LiDAR points, corners, both sensors' hole centres.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Intrinsics from the corners first, then the extrinsic with them fixed.
    #[arg(long)]
    two_stage: bool,
    /// Ignore the room's `[survey]`: every board gets its own pose (the free-board model).
    #[arg(long)]
    free_boards: bool,
    /// Leave the LiDAR's board-plane points out of the solve (the paper's cost alone).
    #[arg(long)]
    without_planes: bool,
    /// The LiDAR unit's angle corrections (Hesai CSV or Velodyne YAML) for clouds given as
    /// packet captures (default: the model's nominal tables).
    #[arg(long)]
    lidar_calibration: Option<PathBuf>,
    /// The calibration in force (a result file or the store's current.json), for the
    /// quality gate's change limits; with `--rig` a rig's result file (every camera's
    /// intrinsics and every sensor's mounting are checked against it).
    #[arg(long)]
    current: Option<PathBuf>,
    /// The images are frames, and the clouds sweeps, of one standing vehicle: the frames
    /// are averaged and the sweeps accumulated into one frame as the daemon does (any
    /// number of each), instead of image i pairing with cloud i.
    #[arg(long)]
    standing: bool,
    /// Also write the calibration for other stacks into this directory (accepted runs
    /// only): camera.camera_info.yaml (ROS), sensor_kit_calibration.yaml (Autoware),
    /// calib.txt (KITTI).
    #[arg(long, value_name = "DIR")]
    export: Option<PathBuf>,
    /// Print the result file to stdout instead of the summary.
    #[arg(long, conflicts_with = "quiet")]
    json: bool,
    /// Print only the status line (no progress line, no refused-plane sentences).
    #[arg(long)]
    quiet: bool,
    /// A rig file: the vehicle's cameras and LiDARs by name; every --image and --cloud is
    /// then NAME=PATH (several per name: frames of a standing vehicle).
    #[arg(long, value_name = "RIG")]
    rig: Option<PathBuf>,
}

/// `roomcal calibrate`: one pair's images and clouds, or with `--rig` every sensor's.
pub fn run(args: CalibrateArgs) -> Result<(), Failure> {
    let room = roomcal::room::load(&args.room).map_err(bad_input)?;
    // Found before the calibration, not after it.
    if let Some(dir) = &args.export {
        if let Some(problem) = roomcal::export::directory_problem(dir) {
            return Err(bad_input(anyhow!("--export {}: {problem}", dir.display())));
        }
    }
    if let Some(rig_path) = &args.rig {
        return run_rig(&room, rig_path, &args);
    }
    let current = match &args.current {
        Some(path) => Some(roomcal::result::load(path).map_err(bad_input)?),
        None => None,
    };
    if let Some(path) = &args.detections {
        return run_detections(room, path, current, &args);
    }
    check_pairs(&args, &room)?;
    let mut progress = Progress::on_stderr("calibrate", steps(&args), args.quiet);
    let (images, clouds) = load_inputs(&args, &room, &mut progress)?;
    let mut detectors = Detectors::new(&room).map_err(bad_input)?;
    let mut frames = Vec::new();
    let mut first = None;
    let count = images.len();
    for (i, frame) in images.into_iter().enumerate() {
        progress.step(&format!("detecting boards, frame {} of {count}", i + 1));
        let image = frame.decode(&room)?;
        let camera = detectors.detect_image(&image).map_err(bad_input)?;
        frames.push(FrameDetections { camera, lidar: Vec::new() });
        // Only the report's frame is kept; the others go once detected.
        if first.is_none() && args.report.is_some() {
            first = Some(image);
        }
    }
    // Room without a LiDAR, or images only: intrinsics only.
    let mut room = room;
    if args.cloud.is_empty() {
        room.lidar = None;
    }
    let sweeps: Vec<&[Point]> = clouds.iter().map(Vec::as_slice).collect();
    progress.step("solving");
    // The LiDAR's boards are found by the calibration: in a surveyed room where the room
    // expects them, from the camera's room pose.
    let options = CalibrateOptions {
        two_stage: args.two_stage,
        current,
        current_rig: None,
        without_planes: args.without_planes,
        free_boards: args.free_boards,
        corner_start: None,
        lidar_angles: lidar_angles(&args.cloud, args.lidar_calibration.as_deref()),
    };
    let (run, refused) = calibrate_detecting(&room, &mut frames, &sweeps, &mut detectors, &options);
    if !args.quiet {
        note_refused(&args, &refused, &mut progress);
    }
    progress.step("writing the results");
    let mut written = write_result(&args.out, &run.result)?;
    if let Some(report) = &args.report {
        let first_refused = refused.first().map_or(&[][..], Vec::as_slice);
        write_report(report, first.as_ref(), &clouds, &run, first_refused)?;
        written.push(report.display().to_string());
    }
    let refused_count = refused.iter().map(Vec::len).sum();
    finish(&args, &room, &frames, &run, refused_count, written, progress)
}

/// `calibrate --detections`: the boards of a detections file solved and gated as a run's
/// own detections would be (without the LiDAR's board-face points, which the file does
/// not hold).
fn run_detections(
    room: Room,
    path: &Path,
    current: Option<roomcal::result::CalibrationResult>,
    args: &CalibrateArgs,
) -> Result<(), Failure> {
    let mut progress = Progress::on_stderr("calibrate", 3, args.quiet);
    progress.step(&format!("reading {}", path.display()));
    let detections = roomcal::result::load_detections(path).map_err(bad_input)?;
    let frames = roomcal::calibrate::frames_from_detections(&room, &detections)
        .with_context(|| format!("detections {}", path.display()))
        .map_err(bad_input)?;
    let mut room = room;
    if frames.iter().all(|f| f.lidar.is_empty()) {
        room.lidar = None;
    }
    progress.step("solving");
    let options = CalibrateOptions {
        two_stage: args.two_stage,
        current,
        without_planes: args.without_planes,
        free_boards: args.free_boards,
        ..CalibrateOptions::default()
    };
    let run = roomcal::calibrate::calibrate(&room, &frames, &options);
    progress.step("writing the results");
    let written = write_result(&args.out, &run.result)?;
    finish(args, &room, &frames, &run, 0, written, progress)
}

/// A run's end: its exports when accepted, the summary (or the result file, or the status
/// line) on stdout, and the exit for its verdict.
fn finish(
    args: &CalibrateArgs,
    room: &Room,
    frames: &[FrameDetections],
    run: &roomcal::calibrate::Calibration,
    refused_count: usize,
    mut written: Vec<String>,
    progress: Progress,
) -> Result<(), Failure> {
    let accepted = run.result.status == Status::Accepted;
    if let Some(dir) = args.export.as_ref().filter(|_| accepted) {
        let files = roomcal::export::write_dir(dir, &roomcal::export::files(&run.result))
            .map_err(bad_input)?;
        written.extend(files.iter().map(|f| f.display().to_string()));
    }
    progress.finish(); // the line is cleared before the summary
    if args.json {
        say_raw!("{}", result_json(&run.result));
    } else if args.quiet {
        say!("{}", summary::status_line(&run.result));
    } else {
        for line in summary::lines(room, frames, run, refused_count, &written) {
            say!("{line}");
        }
        if let Some(dir) = args.export.as_ref().filter(|_| !accepted) {
            say!("  not written {}: a rejected calibration is not exported", dir.display());
        }
    }
    verdict(run.result.status)
}

/// The clouds' beam angles: the model's nominal table when a packet capture is decoded
/// without the unit's angle file.
fn lidar_angles(clouds: &[PathBuf], angle_file: Option<&Path>) -> LidarAngles {
    let decoded_here = clouds.iter().any(|c| roomcal::lidar::is_packet_capture(c));
    LidarAngles::of(decoded_here, angle_file.is_some())
}

/// Image i pairs with cloud i (unless standing), and clouds need the room's LiDAR.
fn check_pairs(args: &CalibrateArgs, room: &Room) -> Result<(), Failure> {
    if !args.standing && !args.cloud.is_empty() && args.cloud.len() != args.image.len() {
        return Err(bad_input(anyhow!(
            "{} images and {} clouds: image i pairs with cloud i, give as many of each",
            args.image.len(),
            args.cloud.len()
        )));
    }
    if !args.cloud.is_empty() && room.lidar.is_none() {
        return Err(bad_input(anyhow!(
            "{}: clouds given but the room has no [lidar] table",
            args.room.display()
        )));
    }
    Ok(())
}

/// The steps `calibrate` shows progress for: each file read, each frame's detection (a
/// standing vehicle's frames are one), the solve and the writing.
fn steps(args: &CalibrateArgs) -> usize {
    let frames = if args.standing { 1 } else { args.image.len() };
    args.image.len() + args.cloud.len() + frames + 2
}

/// A camera frame of the run: a standing vehicle's mean, or a file whose header was
/// checked and whose pixels are decoded when its frame is detected, so one frame is held
/// at a time whatever the number of files.
enum Frame {
    Mean(GreyImage),
    File(PathBuf),
}

impl Frame {
    fn decode(self, room: &Room) -> Result<GreyImage, Failure> {
        match self {
            Frame::Mean(image) => Ok(image),
            Frame::File(path) => load_image(room, &path),
        }
    }
}

/// Every image's header checked and every cloud read; a standing vehicle's as one frame
/// (images averaged as they are read, sweeps accumulated).
fn load_inputs(
    args: &CalibrateArgs,
    room: &Room,
    progress: &mut Progress,
) -> Result<(Vec<Frame>, Vec<Vec<Point>>), Failure> {
    let size = (room.camera.width, room.camera.height);
    let whose = "the room's camera";
    let images = if args.standing {
        let step = |path: &Path| progress.step(&format!("reading {}", path.display()));
        mean_image(&args.image, size, whose, step)?.map(Frame::Mean).into_iter().collect()
    } else {
        let mut files = Vec::with_capacity(args.image.len());
        for path in &args.image {
            progress.step(&format!("reading {}", path.display()));
            check_image_sized(path, size, whose)?;
            files.push(Frame::File(path.clone()));
        }
        files
    };
    let clouds = load_clouds(&args.cloud, |path| {
        progress.step(&format!("reading {}", path.display()));
        load_cloud(room, path, args.lidar_calibration.as_deref())
    })?;
    if !args.standing {
        return Ok((images, clouds));
    }
    let cloud = roomcal::lidar::accumulate_sweeps(clouds);
    let clouds = if cloud.is_empty() { Vec::new() } else { vec![cloud] };
    Ok((images, clouds))
}

/// The refused LiDAR planes as sentences that stay above the progress line.
fn note_refused(args: &CalibrateArgs, refused: &[Vec<RefusedBoard>], progress: &mut Progress) {
    for (i, planes) in refused.iter().enumerate() {
        let name = match args.standing {
            true => "the accumulated sweeps".to_string(),
            false => args.cloud[i].display().to_string(),
        };
        for line in refused_lines(&name, planes) {
            progress.note(&line);
        }
    }
}

/// The report picture of the first frame (see `roomcal::report::ReportInput::calibration`).
fn write_report(
    path: &Path,
    first: Option<&GreyImage>,
    clouds: &[Vec<Point>],
    run: &roomcal::calibrate::Calibration,
    refused: &[RefusedBoard],
) -> Result<(), Failure> {
    let Some(first) = first else { return Ok(()) };
    let cloud: Vec<&[Point]> = clouds.first().map(|c| c.as_slice()).into_iter().collect();
    let input = roomcal::report::ReportInput::calibration(&first.data, &cloud, run, refused);
    roomcal::report::report(&input)
        .save(path)
        .with_context(|| format!("writing the report {}", path.display()))
        .map_err(bad_input)
}

/// The exit of a run: 0 accepted, 3 rejected (the output has said why).
fn verdict(status: Status) -> Result<(), Failure> {
    match status {
        Status::Accepted => Ok(()),
        Status::Rejected => Err(rejected()),
    }
}

/// `calibrate --rig`: every sensor of the rig by name; writes the rig's result file (and
/// its exports and report pictures).
fn run_rig(room: &Room, rig_path: &Path, args: &CalibrateArgs) -> Result<(), Failure> {
    let rig = roomcal::rig::load(rig_path).map_err(bad_input)?;
    if !rig.lidars.is_empty() && room.board.holes.is_empty() {
        return Err(bad_input(anyhow!(
            "{}: the rig has LiDARs but the room's boards have no holes (`board.holes`)",
            args.room.display()
        )));
    }
    let current_rig = match &args.current {
        Some(path) => Some(roomcal::result::load_rig(path).map_err(bad_input)?),
        None => None,
    };
    let inputs = super::rig::inputs(&rig, rig_path, &args.image, &args.cloud, true)?;
    let angles = args.lidar_calibration.as_deref();
    let detections = super::rig::detect_all(room, &rig, &inputs, angles, args.free_boards)?;
    let options = CalibrateOptions {
        two_stage: args.two_stage,
        current: None,
        current_rig,
        without_planes: args.without_planes,
        free_boards: args.free_boards,
        // The first camera's start, made to find the LiDARs' boards, is not made again.
        corner_start: detections.first_start.clone(),
        lidar_angles: lidar_angles(&inputs.clouds.concat(), angles),
    };
    let lidars: Vec<LidarInput<'_>> =
        detections.lidars.iter().map(|(boards, cloud)| LidarInput { boards, cloud }).collect();
    let run = calibrate_rig(room, &rig, &detections.cameras, &lidars, &options);
    let result = &run.result;
    let json = result_json(result);
    let out = &args.out;
    std::fs::write(out, &json).map_err(|e| bad_input(anyhow!("writing {}: {e}", out.display())))?;
    let accepted = result.pair.status == Status::Accepted;
    let mut written = Vec::new();
    if let Some(dir) = args.export.as_deref().filter(|_| accepted) {
        written = roomcal::export::write_dir(dir, &roomcal::export::rig_files(result))
            .map_err(bad_input)?;
    }
    if let Some(report) = &args.report {
        written.extend(write_rig_reports(report, &rig, &inputs, &detections, result)?);
    }
    if args.json {
        say_raw!("{json}");
    } else {
        print_rig_summary(result, args.quiet, out, &written);
    }
    verdict(result.pair.status)
}

/// The rig's status line; unless `quiet`, a line per sensor and per extrinsic and the
/// files written.
fn print_rig_summary(result: &RigResult, quiet: bool, out: &Path, written: &[PathBuf]) {
    match result.pair.status {
        Status::Accepted => {
            say!("roomcal calibrate: accepted (rig of {} sensors)", result.sensors.len())
        }
        Status::Rejected => say!(
            "roomcal calibrate: rejected: {}",
            result.pair.reason.as_deref().unwrap_or("rejected")
        ),
    }
    if quiet {
        return;
    }
    for (name, sensor) in &result.sensors {
        let verdict = match sensor.status {
            Status::Accepted => "accepted".to_string(),
            Status::Rejected => format!("rejected: {}", sensor.reason.as_deref().unwrap_or("")),
        };
        match (&sensor.camera, &sensor.uncertainty) {
            (Some(c), Some(u)) => say!(
                "  camera {name}: fx {:.3} fy {:.3} px (σ {:.3} {:.3}), cx {:.3} cy {:.3} px (σ {:.3} {:.3}); {verdict}",
                c.fx, c.fy, u.fx, u.fy, c.cx, c.cy, u.cx, u.cy
            ),
            _ => say!("  LiDAR {name}: {verdict}"),
        }
    }
    // Each mounting as the one-pair summary gives a LiDAR's: in the first camera's body
    // frame (a camera's own optical axes turned to its body axes).
    for e in &result.extrinsics {
        let is_camera = result.sensors.get(&e.from).is_some_and(|s| s.camera.is_some());
        say!(
            "  {} in {}'s body frame: {} (σ {:.3}°, {:.1} mm, largest axis)",
            e.from,
            e.to,
            BodyPose::of(&e.to_se3(), is_camera),
            e.sigma_rotation_deg,
            e.sigma_translation_m * 1000.0
        );
    }
    say!("  written     {}", out.display());
    for path in written {
        say!("  written     {}", path.display());
    }
}

/// The rig's report pictures, one per camera ([`roomcal::report::camera_path`]: `report.png`
/// → `report-front.png`): the camera's frame (its frames averaged) with every LiDAR's sweep
/// and hole centres drawn through the solved rig, its corners and the verdicts
/// ([`roomcal::report::ReportInput::rig`]). A camera without a solved model is left out.
/// Returns the files written.
fn write_rig_reports(
    report: &Path,
    rig: &Rig,
    inputs: &RigInputs,
    detections: &RigDetections,
    result: &RigResult,
) -> Result<Vec<PathBuf>, Failure> {
    let sweeps: Vec<&[Point]> = detections.lidars.iter().map(|(_, c)| c.as_slice()).collect();
    let lidar_boards: Vec<&[roomcal::calibrate::LidarBoard]> =
        detections.lidars.iter().map(|(b, _)| b.as_slice()).collect();
    let mut written = Vec::new();
    for (c, camera) in rig.cameras.iter().enumerate() {
        let Some(frame) = super::rig::camera_frame(rig, c, &inputs.images[c])? else { continue };
        let marks = roomcal::report::RigMarks {
            corners: &detections.cameras[c],
            sweeps: &sweeps,
            lidar_boards: &lidar_boards,
        };
        let input = roomcal::report::ReportInput::rig(rig, result, c, &frame.data, &marks);
        let Some(picture) = input.as_ref().map(roomcal::report::report) else { continue };
        let path = roomcal::report::camera_path(report, &camera.name);
        picture
            .save(&path)
            .map_err(|e| bad_input(anyhow!("writing the report {}: {e}", path.display())))?;
        written.push(path);
    }
    Ok(written)
}
