//! `roomcal`: the command line. Thin: parses arguments, calls the library, maps errors
//! to exit codes (0 accepted, 2 bad input, 3 rejected by the quality gate).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, Parser, Subcommand, ValueEnum};

use roomcal::geometry::CameraModel;
use roomcal::sim::{self, SimOptions};
use roomcal::target::LidarModel;

#[derive(Parser)]
#[command(
    name = "roomcal",
    version,
    about = "Joint camera intrinsic and LiDAR-camera extrinsic calibration"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Calibrate the camera (and the LiDAR→camera extrinsic) from image/cloud pairs.
    Calibrate(CalibrateArgs),
    /// Detect the boards in one image and/or one cloud and write them as JSON.
    Detect(DetectArgs),
    /// Draw a cloud onto an image through a calibration (a result file) as a PNG: the
    /// check by eye of any calibration on any scene, boards or none.
    Overlay(OverlayArgs),
    /// Render a synthetic calibration room with ground truth (image.png, cloud.pcd, truth.json).
    Simulate(SimulateArgs),
    /// Run the vehicle daemon: notice the room, calibrate, write the store, serve UDS.
    #[cfg(feature = "daemon")]
    Daemon(DaemonArgs),
    /// Decode a LiDAR packet capture (pcap/pcapng) into a PCD cloud (x y z intensity ring).
    Decode(DecodeArgs),
    /// Ask the daemon over CAN (UDS on ISO-TP): status, results, start a run, roll back.
    Query(QueryArgs),
}

#[derive(Args)]
struct CalibrateArgs {
    /// The room file.
    #[arg(long)]
    room: PathBuf,
    /// A camera frame (PNG or JPEG); repeat for several. Image i pairs with cloud i.
    #[arg(long, required = true)]
    image: Vec<PathBuf>,
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
    /// Leave the LiDAR's board-plane points out of the solve (the paper's cost alone).
    #[arg(long)]
    without_planes: bool,
    /// The LiDAR unit's angle corrections (Hesai CSV or Velodyne YAML) for clouds given as
    /// packet captures (default: the model's nominal tables).
    #[arg(long)]
    lidar_calibration: Option<PathBuf>,
    /// The calibration in force (a result file or the store's current.json), for the
    /// quality gate's change limits.
    #[arg(long)]
    current: Option<PathBuf>,
    /// The images are frames, and the clouds sweeps, of one standing vehicle: the frames
    /// are averaged and the sweeps accumulated into one frame as the daemon does (any
    /// number of each), instead of image i pairing with cloud i.
    #[arg(long)]
    standing: bool,
}

#[derive(Args)]
struct DetectArgs {
    /// The room file.
    #[arg(long)]
    room: PathBuf,
    /// A camera frame (PNG or JPEG).
    #[arg(long)]
    image: Option<PathBuf>,
    /// A LiDAR cloud (PCD or pcap/pcapng).
    #[arg(long)]
    cloud: Option<PathBuf>,
    /// The LiDAR unit's angle corrections (Hesai CSV or Velodyne YAML) for clouds given as
    /// packet captures (default: the model's nominal tables).
    #[arg(long)]
    lidar_calibration: Option<PathBuf>,
    /// Where to write the detections (JSON).
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
struct OverlayArgs {
    /// The calibration: a result file (`roomcal calibrate --out`, or the store's current.json).
    #[arg(long)]
    calibration: PathBuf,
    /// The camera frame (PNG or JPEG), of the calibration's image size.
    #[arg(long)]
    image: PathBuf,
    /// The LiDAR cloud (PCD).
    #[arg(long)]
    cloud: PathBuf,
    /// Where to write the overlay (PNG).
    #[arg(long)]
    out: PathBuf,
}

#[cfg(feature = "daemon")]
#[derive(Args)]
struct DaemonArgs {
    /// The daemon configuration (TOML).
    #[arg(long)]
    config: PathBuf,
    /// Exit after the first calibration run ends.
    #[arg(long)]
    once: bool,
}

#[derive(Args)]
struct DecodeArgs {
    /// LiDAR model: pandar64, pandar40p, pandarxt32, pandarqt64, vlp16, vlp32c, hdl32e, ouster.
    #[arg(long)]
    lidar: String,
    /// The unit's angle corrections (Hesai CSV or Velodyne YAML; for ouster the sensor's
    /// metadata json); default: nominal table.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// How Velodyne firing azimuths are interpolated: `manual` (the user manuals' firing
    /// timing, the default) or `nebula` (tier4/nebula's, to reproduce its clouds).
    #[arg(long, value_enum, default_value = "manual")]
    velodyne_interpolation: InterpolationArg,
    /// The capture.
    capture: PathBuf,
    /// Output PCD (binary).
    #[arg(long)]
    out: PathBuf,
}

#[derive(Clone, Copy, ValueEnum)]
enum InterpolationArg {
    Manual,
    Nebula,
}

#[derive(Args)]
struct QueryArgs {
    /// `socketcand:HOST:PORT[/CHANNEL]` or `socketcan:IFACE`.
    #[arg(long)]
    endpoint: String,
    /// status, intrinsics, extrinsic, quality, start or rollback.
    #[arg(default_value = "status")]
    command: String,
    /// The vehicle secret (needed for start and rollback).
    #[arg(long)]
    secret_file: Option<PathBuf>,
    /// CAN ID of requests (hex with 0x, or decimal).
    #[arg(long, default_value = "0x7A0", value_parser = parse_can_id)]
    request_id: u32,
    /// CAN ID of responses.
    #[arg(long, default_value = "0x7A8", value_parser = parse_can_id)]
    response_id: u32,
}

fn parse_can_id(text: &str) -> Result<u32, String> {
    let parsed = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16),
        None => text.parse(),
    };
    parsed.ok().filter(|&id| id < (1 << 29)).ok_or_else(|| format!("`{text}` is not a CAN ID"))
}

#[derive(Args)]
struct SimulateArgs {
    /// The room file.
    #[arg(long)]
    room: PathBuf,
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
    /// Seed: the same seed gives the same scene.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Boards to place (default: the room's board.count).
    #[arg(long)]
    boards: Option<usize>,
    /// Camera model (default: the room's).
    #[arg(long, value_enum)]
    camera_model: Option<CameraArg>,
    /// Horizontal field of view in degrees (default: the room's fx, else 70).
    #[arg(long)]
    fov: Option<f64>,
    /// Distortion coefficients, comma separated (k1,k2,p1,p2,k3 or fisheye k1,k2,k3,k4).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    distortion: Option<Vec<f64>>,
    /// LiDAR model (default: the room's).
    #[arg(long, value_enum)]
    lidar: Option<LidarArg>,
    /// Board arrangement: a grid over the image, or a row at the LiDAR's dense band plus
    /// two boards in the top corners.
    #[arg(long, value_enum, default_value = "grid")]
    layout: LayoutArg,
    /// Seed of the rig's true LiDAR mounting (default: --seed): scenes with one rig seed
    /// are frames of one vehicle, for multi-frame calibrations.
    #[arg(long)]
    rig_seed: Option<u64>,
    /// Frames of a standing vehicle: also image-2.png, cloud-2.pcd, … up to N, the same
    /// room with new sensor noise (for `calibrate --standing`, as the daemon averages them).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=100))]
    frames: u16,
    /// LiDAR range noise sigma (m).
    #[arg(long, default_value_t = sim::DEFAULT_RANGE_NOISE_M)]
    range_noise: f64,
    /// Image sensor noise sigma (grey levels).
    #[arg(long, default_value_t = sim::ImageNoise::default().noise_grey)]
    image_noise: f64,
    /// Lens blur sigma (pixels).
    #[arg(long, default_value_t = sim::ImageNoise::default().blur_px)]
    blur: f64,
    /// Sub-samples per pixel along each axis.
    #[arg(long, default_value_t = sim::ImageNoise::default().supersample)]
    supersample: u32,
    /// Light fall-off at the image corners (0 = none).
    #[arg(long, default_value_t = sim::ImageNoise::default().vignetting)]
    vignetting: f64,
    /// Also write the sweep as the sensor's packets: cloud.pcap, and for the Pandar64 the
    /// unit's angle corrections (angles.csv, for `decode --calibration`).
    #[arg(long)]
    capture: bool,
}

#[derive(Clone, Copy, ValueEnum)]
enum CameraArg {
    PinholeRadtan,
    Fisheye,
}

#[derive(Clone, Copy, ValueEnum)]
enum LidarArg {
    Pandar64,
    Vlp32c,
    Vlp16,
}

#[derive(Clone, Copy, ValueEnum)]
enum LayoutArg {
    Grid,
    Band,
}

/// An error with the exit code it maps to.
struct Failure {
    code: u8,
    error: anyhow::Error,
}

fn bad_input(error: impl Into<anyhow::Error>) -> Failure {
    Failure { code: 2, error: error.into() }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let outcome = match cli.command {
        Command::Calibrate(args) => calibrate(args),
        Command::Detect(args) => detect(args),
        Command::Overlay(args) => overlay(args),
        Command::Simulate(args) => simulate(args),
        #[cfg(feature = "daemon")]
        Command::Daemon(args) => daemon(args),
        Command::Decode(args) => decode(args),
        Command::Query(args) => query(args),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure { code, error }) => {
            eprintln!("roomcal: {}", describe(&error));
            ExitCode::from(code)
        }
    }
}

/// The error and its causes on one line, leaving out a cause its parent already quotes
/// (our file errors put their source in their own message).
fn describe(error: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in error.chain() {
        let part = cause.to_string();
        if !text.contains(&part) {
            if !text.is_empty() {
                text.push_str(": ");
            }
            text.push_str(&part);
        }
    }
    text
}

fn simulate(args: SimulateArgs) -> Result<(), Failure> {
    let room = roomcal::room::load(&args.room).map_err(bad_input)?;
    let options = SimOptions {
        seed: args.seed,
        boards: args.boards,
        camera_model: args.camera_model.map(|m| match m {
            CameraArg::PinholeRadtan => CameraModel::PinholeRadtan,
            CameraArg::Fisheye => CameraModel::Fisheye,
        }),
        hfov_deg: args.fov,
        distortion: args.distortion,
        lidar: args.lidar.map(|m| match m {
            LidarArg::Pandar64 => LidarModel::Pandar64,
            LidarArg::Vlp32c => LidarModel::Vlp32c,
            LidarArg::Vlp16 => LidarModel::Vlp16,
        }),
        range_noise_m: args.range_noise,
        layout: match args.layout {
            LayoutArg::Grid => sim::Layout::Grid,
            LayoutArg::Band => sim::Layout::Band,
        },
        rig_seed: args.rig_seed,
        standing_frames: usize::from(args.frames),
        image: sim::ImageNoise {
            supersample: args.supersample,
            blur_px: args.blur,
            noise_grey: args.image_noise,
            vignetting: args.vignetting,
            ..sim::ImageNoise::default()
        },
    };
    let scene = sim::simulate(&room, &options)
        .with_context(|| format!("simulating {}", args.room.display()))
        .map_err(bad_input)?;
    sim::write_scene(&scene, &args.out).map_err(bad_input)?;
    let t = &scene.truth;
    println!(
        "simulated {} boards ({} {}x{}, fx {:.2} fy {:.2} cx {:.2} cy {:.2}){} -> {}",
        t.boards.len(),
        match t.camera.model {
            CameraModel::PinholeRadtan => "pinhole-radtan",
            CameraModel::Fisheye => "fisheye",
        },
        t.camera.width,
        t.camera.height,
        t.camera.fx,
        t.camera.fy,
        t.camera.cx,
        t.camera.cy,
        scene.cloud.as_ref().map_or(String::new(), |c| format!(", {} LiDAR points", c.len())),
        args.out.display()
    );
    if args.capture {
        let files = sim::write_capture(&scene, &args.out).map_err(bad_input)?;
        println!(
            "capture: {}{}",
            files.capture.display(),
            files.calibration.map_or(String::new(), |c| format!(" (angles: {})", c.display()))
        );
    }
    Ok(())
}

fn decode(args: DecodeArgs) -> Result<(), Failure> {
    let model = roomcal::lidar::Model::from_name(&args.lidar).ok_or_else(|| {
        bad_input(anyhow::anyhow!(
            "--lidar {}: unknown model ({})",
            args.lidar,
            roomcal::lidar::Model::NAMES
        ))
    })?;
    let mut calibration =
        roomcal::lidar::capture_calibration(model, args.calibration.as_deref(), &args.capture)
            .map_err(bad_input)?;
    calibration.interpolation = match args.velodyne_interpolation {
        InterpolationArg::Manual => roomcal::lidar::calibration::Interpolation::Manual,
        InterpolationArg::Nebula => roomcal::lidar::calibration::Interpolation::Nebula,
    };
    let (points, stats, capture) =
        roomcal::lidar::decode_capture_with(&calibration, &args.capture).map_err(bad_input)?;
    roomcal::lidar::pcd::write(&args.out, &points, roomcal::lidar::pcd::PcdFormat::Binary)
        .map_err(bad_input)?;
    println!(
        "{}: {} points from {} packets ({} position, {} dropped; {} UDP datagrams, {} other records) -> {}",
        args.capture.display(),
        points.len(),
        stats.packets,
        stats.position,
        stats.unknown + stats.truncated + stats.oversized + stats.corrupted,
        capture.udp,
        capture.records.saturating_sub(capture.udp),
        args.out.display()
    );
    Ok(())
}

fn query(args: QueryArgs) -> Result<(), Failure> {
    use roomcal::service::client::{query_blocking, QueryCommand, QueryOptions};
    let command: QueryCommand = args.command.parse().map_err(bad_input)?;
    let options = QueryOptions {
        request_id: args.request_id,
        response_id: args.response_id,
        secret_file: args.secret_file,
        ..QueryOptions::new(&args.endpoint)
    };
    let answer = query_blocking(&options, command)
        .with_context(|| format!("query {} over {}", args.command, args.endpoint))
        .map_err(|error| Failure { code: 1, error })?;
    println!("{answer}");
    Ok(())
}

/// A frame read from disk and checked against the room's camera.
fn load_image(
    room: &roomcal::target::Room,
    path: &std::path::Path,
) -> Result<roomcal::detect::GreyImage, Failure> {
    let size = (room.camera.width, room.camera.height);
    load_image_sized(path, size, "the room's camera")
}

/// A frame read from disk that must be `width × height` pixels, like `whose` camera.
fn load_image_sized(
    path: &std::path::Path,
    (width, height): (u32, u32),
    whose: &str,
) -> Result<roomcal::detect::GreyImage, Failure> {
    let image = roomcal::detect::load_grey(path).map_err(bad_input)?;
    if (image.width, image.height) != (width, height) {
        return Err(bad_input(anyhow::anyhow!(
            "image {}: {}x{} pixels, {whose} is {width}x{height}",
            path.display(),
            image.width,
            image.height,
        )));
    }
    Ok(image)
}

/// A cloud read from disk: PCD, or a capture decoded as the room's LiDAR model with the
/// unit's angle file when given.
fn load_cloud(
    room: &roomcal::target::Room,
    path: &std::path::Path,
    angles: Option<&std::path::Path>,
) -> Result<Vec<roomcal::lidar::Point>, Failure> {
    let model = room.lidar.as_ref().and_then(|l| l.model.packet_model());
    roomcal::lidar::read_cloud(path, model, angles).map_err(bad_input)
}

fn calibrate(args: CalibrateArgs) -> Result<(), Failure> {
    use roomcal::calibrate::{CalibrateOptions, Detectors, FrameDetections};
    let room = roomcal::room::load(&args.room).map_err(bad_input)?;
    if !args.standing && !args.cloud.is_empty() && args.cloud.len() != args.image.len() {
        return Err(bad_input(anyhow::anyhow!(
            "{} images and {} clouds: image i pairs with cloud i, give as many of each",
            args.image.len(),
            args.cloud.len()
        )));
    }
    if !args.cloud.is_empty() && room.lidar.is_none() {
        return Err(bad_input(anyhow::anyhow!(
            "{}: clouds given but the room has no [lidar] table",
            args.room.display()
        )));
    }
    let current = match &args.current {
        Some(path) => Some(
            std::fs::read_to_string(path)
                .map_err(anyhow::Error::from)
                .and_then(|text| Ok(serde_json::from_str(&text)?))
                .with_context(|| format!("current calibration {}", path.display()))
                .map_err(bad_input)?,
        ),
        None => None,
    };
    let mut images =
        args.image.iter().map(|path| load_image(&room, path)).collect::<Result<Vec<_>, _>>()?;
    let mut clouds = args
        .cloud
        .iter()
        .map(|path| load_cloud(&room, path, args.lidar_calibration.as_deref()))
        .collect::<Result<Vec<_>, _>>()?;
    if args.standing {
        (images, clouds) = standing_frame(images, clouds);
    }
    let mut detectors = Detectors::new(&room).map_err(bad_input)?;
    let mut frames = Vec::new();
    for (i, image) in images.iter().enumerate() {
        let mut frame = FrameDetections {
            camera: detectors.detect_image(image).map_err(bad_input)?,
            lidar: Vec::new(),
        };
        if let Some(cloud) = clouds.get(i) {
            frame.lidar = detectors.detect_cloud(cloud);
            let name = match args.standing {
                true => "the accumulated sweeps".to_string(),
                false => args.cloud[i].display().to_string(),
            };
            for refused in detectors.refused_in_cloud() {
                eprintln!("{name}: a board-sized plane was not placed: {refused:?}");
            }
        }
        frames.push(frame);
    }
    // Room without a LiDAR, or images only: intrinsics only.
    let mut room = room;
    if args.cloud.is_empty() {
        room.lidar = None;
    }
    let run = roomcal::calibrate::calibrate(
        &room,
        &frames,
        &CalibrateOptions {
            two_stage: args.two_stage,
            current,
            without_planes: args.without_planes,
        },
    );
    write_result(&args.out, &run.result)?;
    if let Some(report) = &args.report {
        write_report(report, &images, &clouds, &run)?;
    }
    print_summary(&args, &frames, &run);
    match run.result.status {
        roomcal::result::Status::Accepted => Ok(()),
        roomcal::result::Status::Rejected => Err(Failure {
            code: 3,
            error: anyhow::anyhow!(
                "rejected: {}",
                run.result.reason.as_deref().unwrap_or("no reason given")
            ),
        }),
    }
}

/// One frame of a standing vehicle: its images averaged (every image was loaded at the
/// room's size) and its sweeps accumulated.
fn standing_frame(
    images: Vec<roomcal::detect::GreyImage>,
    clouds: Vec<Vec<roomcal::lidar::Point>>,
) -> (Vec<roomcal::detect::GreyImage>, Vec<Vec<roomcal::lidar::Point>>) {
    let pixels: Vec<&[u8]> = images.iter().map(|i| i.data.as_slice()).collect();
    let averaged = roomcal::capture::mean_pixels(&pixels).map(|data| roomcal::detect::GreyImage {
        width: images[0].width,
        height: images[0].height,
        data,
    });
    let cloud: Vec<roomcal::lidar::Point> = clouds.into_iter().flatten().collect();
    let clouds = if cloud.is_empty() { Vec::new() } else { vec![cloud] };
    (averaged.into_iter().collect(), clouds)
}

fn write_result(
    path: &std::path::Path,
    result: &roomcal::result::CalibrationResult,
) -> Result<(), Failure> {
    let json = serde_json::to_string_pretty(result).expect("results serialise") + "\n";
    let yaml_path = path.with_extension("yaml");
    std::fs::write(path, json)
        .and_then(|()| std::fs::write(&yaml_path, result.to_opencv_yaml()))
        .with_context(|| format!("writing {} and {}", path.display(), yaml_path.display()))
        .map_err(bad_input)
}

fn write_report(
    path: &std::path::Path,
    images: &[roomcal::detect::GreyImage],
    clouds: &[Vec<roomcal::lidar::Point>],
    run: &roomcal::calibrate::Calibration,
) -> Result<(), Failure> {
    let Some(first) = images.first() else { return Ok(()) };
    let boards: Vec<roomcal::report::ReportBoard<'_>> = run
        .boards
        .iter()
        .filter(|b| b.frame == 0)
        .map(|b| roomcal::report::ReportBoard {
            corners: &b.corners,
            holes_camera: run.holes_in_camera(b),
            holes_lidar: &b.holes_lidar,
        })
        .collect();
    let cloud: Vec<&[roomcal::lidar::Point]> =
        clouds.first().map(|c| c.as_slice()).into_iter().collect();
    roomcal::report::overlay(
        &first.data,
        &run.camera,
        run.lidar_to_camera.as_ref(),
        &cloud,
        &boards,
    )
    .save(path)
    .with_context(|| format!("writing the report {}", path.display()))
    .map_err(bad_input)
}

fn print_summary(
    args: &CalibrateArgs,
    frames: &[roomcal::calibrate::FrameDetections],
    run: &roomcal::calibrate::Calibration,
) {
    let r = &run.result;
    let c = &r.camera;
    let u = &r.uncertainty;
    let seen: usize = frames.iter().map(|f| f.camera.len()).sum();
    let placed: usize = frames.iter().map(|f| f.lidar.len()).sum();
    println!("roomcal calibrate: {} frame(s), {seen} complete camera boards, {placed} LiDAR boards placed", frames.len());
    println!(
        "  status      {:?}{}",
        r.status,
        r.reason.as_ref().map_or(String::new(), |why| format!(": {why}"))
    );
    println!("  fx fy       {:.3} {:.3} px   (σ {:.3} {:.3})", c.fx, c.fy, u.fx, u.fy);
    println!("  cx cy       {:.3} {:.3} px   (σ {:.3} {:.3})", c.cx, c.cy, u.cx, u.cy);
    println!(
        "  distortion  {:?}",
        c.distortion.iter().map(|d| format!("{d:.5}")).collect::<Vec<_>>()
    );
    if let Some(e) = &r.lidar_to_camera {
        let t = e.to_se3();
        let rvec = roomcal::geometry::se3::so3_log(&t.rotation).map(f64::to_degrees);
        println!(
            "  rotation    [{:.4} {:.4} {:.4}]° (rotation vector, σ {:.4}°)",
            rvec.x, rvec.y, rvec.z, u.rotation_deg
        );
        println!(
            "  translation [{:.4} {:.4} {:.4}] m (σ {:.1} mm)",
            e.translation[0],
            e.translation[1],
            e.translation[2],
            u.translation_m * 1000.0
        );
    }
    println!("  residuals   corners {:.3} px RMS, holes {:.3} px RMS, {} boards used, {} solver iterations", r.quality.corner_rms_px, r.quality.hole_rms_px, r.quality.boards, run.iterations);
    println!(
        "  written     {} (+ {})",
        args.out.display(),
        args.out.with_extension("yaml").display()
    );
}

fn overlay(args: OverlayArgs) -> Result<(), Failure> {
    let text = std::fs::read_to_string(&args.calibration)
        .with_context(|| format!("reading {}", args.calibration.display()))
        .map_err(bad_input)?;
    let result: roomcal::result::CalibrationResult = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a calibration result", args.calibration.display()))
        .map_err(bad_input)?;
    let Some(extrinsic) = &result.lidar_to_camera else {
        return Err(bad_input(anyhow::anyhow!(
            "{}: the calibration has no LiDAR→camera extrinsic",
            args.calibration.display()
        )));
    };
    let camera = result.camera.to_camera();
    let size = (camera.width, camera.height);
    let image = load_image_sized(&args.image, size, "the calibration's camera")?;
    let cloud = roomcal::lidar::read_cloud(&args.cloud, None, None).map_err(bad_input)?;
    roomcal::report::overlay(&image.data, &camera, Some(&extrinsic.to_se3()), &[&cloud], &[])
        .save(&args.out)
        .with_context(|| format!("writing the overlay {}", args.out.display()))
        .map_err(bad_input)?;
    println!("overlay of {} points written to {}", cloud.len(), args.out.display());
    Ok(())
}

fn detect(args: DetectArgs) -> Result<(), Failure> {
    use roomcal::result::{BoardDetection, Detections};
    let room = roomcal::room::load(&args.room).map_err(bad_input)?;
    if args.image.is_none() && args.cloud.is_none() {
        return Err(bad_input(anyhow::anyhow!("give --image, --cloud or both")));
    }
    let mut detectors = roomcal::calibrate::Detectors::new(&room).map_err(bad_input)?;
    let mut out = Detections::default();
    if let Some(path) = &args.image {
        let image = load_image(&room, path)?;
        for board in detectors.detect_image(&image).map_err(bad_input)? {
            out.boards.push(BoardDetection {
                frame: 0,
                corners_px: board.corners.iter().map(|c| [c.x, c.y]).collect(),
                holes_lidar: Vec::new(),
            });
        }
    }
    if let Some(path) = &args.cloud {
        let cloud = load_cloud(&room, path, args.lidar_calibration.as_deref())?;
        for board in detectors.detect_cloud(&cloud) {
            out.boards.push(BoardDetection {
                frame: 0,
                corners_px: Vec::new(),
                holes_lidar: board.holes.iter().map(|h| [h.x, h.y, h.z]).collect(),
            });
        }
        for refused in detectors.refused_in_cloud() {
            eprintln!("{}: a board-sized plane was not placed: {refused:?}", path.display());
        }
    }
    let json = serde_json::to_string_pretty(&out).expect("detections serialise") + "\n";
    std::fs::write(&args.out, json)
        .with_context(|| format!("writing {}", args.out.display()))
        .map_err(bad_input)?;
    let cameras = out.boards.iter().filter(|b| !b.corners_px.is_empty()).count();
    println!(
        "{} camera boards, {} LiDAR boards -> {}",
        cameras,
        out.boards.len() - cameras,
        args.out.display()
    );
    Ok(())
}

/// Resolves on SIGINT (a terminal) or SIGTERM (`systemctl stop`): either stops the daemon
/// gracefully, between store writes.
#[cfg(feature = "daemon")]
async fn stop_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        if let Ok(mut term) = signal(SignalKind::terminate()) {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = term.recv() => {}
            }
            return;
        }
    }
    let _ = tokio::signal::ctrl_c().await;
}

#[cfg(feature = "daemon")]
fn daemon(args: DaemonArgs) -> Result<(), Failure> {
    use roomcal::daemon::{room_calibrator::RoomCalibrator, RunOptions};
    roomcal::daemon::init_logging();
    let config = roomcal::daemon::config::load(&args.config).map_err(bad_input)?;
    let room = roomcal::room::load(&config.room).map_err(bad_input)?;
    let calibrator = RoomCalibrator::new(room).map_err(bad_input)?;
    let runtime = tokio::runtime::Runtime::new()
        .context("starting the async runtime")
        .map_err(|error| Failure { code: 1, error })?;
    let summary = runtime
        .block_on(roomcal::daemon::run(
            config,
            calibrator,
            RunOptions { once: args.once },
            stop_signal(),
        ))
        .map_err(|e| Failure { code: 1, error: e.into() })?;
    println!(
        "roomcal daemon: {} run(s): {} accepted, {} rejected, {} failed; generation {} in force",
        summary.runs, summary.accepted, summary.rejected, summary.failed, summary.generation
    );
    Ok(())
}
