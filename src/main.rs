//! `roomcal`: the command line. Thin: parses arguments, calls the library, maps errors
//! to exit codes (0 accepted, 2 bad input, 3 rejected by the quality gate).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::{Args, Parser, Subcommand, ValueEnum};

/// `println!` / `print!` on stdout that tolerate a closed stdout (`roomcal … | head`): the
/// rest of the output is dropped, the command's work, files and exit status are unchanged
/// (Rust ignores SIGPIPE, so `println!` would panic on the broken pipe).
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}
macro_rules! say_raw {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = write!(std::io::stdout(), $($arg)*);
    }};
}

mod cli;

use roomcal::geometry::CameraModel;
use roomcal::sim::{self, SimOptions};
use roomcal::target::LidarModel;

#[derive(Parser)]
#[command(
    name = "roomcal",
    version,
    about = "Calibrates a vehicle's camera and LiDAR together from the boards of a calibration room.",
    after_help = "Example: roomcal calibrate --room room.toml --image image.png --cloud cloud.pcd \
                  --out result.json --report report.png\n\
                  Each subcommand's --help says what it is for, with an example."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Calibrates the camera (and the LiDAR→camera extrinsic) from image/cloud pairs.
    #[command(after_help = "Example: roomcal calibrate --room room.toml --image image.png \
                            --cloud cloud.pcd --out result.json --report report.png --export exports")]
    Calibrate(CalibrateArgs),
    /// Detects the boards in one image and/or one cloud and writes them as JSON.
    #[command(after_help = "Example: roomcal detect --room room.toml --image image.png \
                            --cloud cloud.pcd --out detections.json")]
    Detect(DetectArgs),
    /// Draws a cloud onto an image through a calibration, to check any calibration by eye.
    #[command(
        after_help = "Example: roomcal overlay --calibration result.json --image image.png \
                            --cloud cloud.pcd --out overlay.png"
    )]
    Overlay(OverlayArgs),
    /// Renders a synthetic calibration room with ground truth (image, cloud, truth.json).
    #[command(after_help = "Example: roomcal simulate --room room.toml --out scene --seed 7")]
    Simulate(SimulateArgs),
    /// Surveys the room: every board's pose and the big planes in one room frame, solved
    /// from several visits; writes the room file again with a [survey] table.
    #[command(after_help = "Example: roomcal survey --room room.toml --visit visit-01/image.png \
                            visit-01/cloud.pcd --visit visit-02/image.png visit-02/cloud.pcd \
                            --out surveyed.toml")]
    Survey(SurveyArgs),
    /// Runs the vehicle daemon: notices the room, calibrates, writes the store, serves UDS.
    #[cfg(feature = "daemon")]
    #[command(after_help = "Example: roomcal daemon --config config/replay.toml --once")]
    Daemon(DaemonArgs),
    /// Decodes a LiDAR packet capture (pcap/pcapng) into a PCD cloud (x y z intensity ring).
    #[command(after_help = "Example: roomcal decode --lidar vlp16 capture.pcap --out cloud.pcd")]
    Decode(DecodeArgs),
    /// Asks the daemon over CAN (UDS on ISO-TP) for its status or results, or starts a run.
    #[command(after_help = "Example: roomcal query --endpoint socketcand:127.0.0.1:29536 status")]
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

#[derive(Args)]
struct SurveyArgs {
    /// The room file.
    #[arg(long)]
    room: PathBuf,
    /// One visit: its camera frame and its LiDAR cloud (PCD or pcap/pcapng); repeat for
    /// every visit (each its own vehicle, at least 2).
    #[arg(long, num_args = 2, value_names = ["IMAGE", "CLOUD"], required = true,
          action = clap::ArgAction::Append)]
    visit: Vec<PathBuf>,
    /// The LiDAR unit's angle corrections for clouds given as packet captures.
    #[arg(long)]
    lidar_calibration: Option<PathBuf>,
    /// The surveyed room file to write (the room file with a [survey] table).
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
struct DetectArgs {
    /// The room file.
    #[arg(long)]
    room: PathBuf,
    /// A camera frame (PNG or JPEG); with --rig, NAME=IMG, repeatable.
    #[arg(long)]
    image: Vec<PathBuf>,
    /// A LiDAR cloud (PCD or pcap/pcapng); with --rig, NAME=CLOUD, repeatable.
    #[arg(long)]
    cloud: Vec<PathBuf>,
    /// A rig file: the inputs are NAME=PATH of its sensors.
    #[arg(long, value_name = "RIG")]
    rig: Option<PathBuf>,
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
    /// status, sensors, intrinsics[:SENSOR], extrinsic[:SENSOR], quality, start or rollback
    /// (SENSOR: a name or an index from `sensors`).
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
    /// room with new sensor noise (for `calibrate --standing`, as the daemon averages them);
    /// with --visits, every visit gets N frames; with --rig, every camera NAME-2.png, … and
    /// every LiDAR NAME-2.pcd, … (`calibrate --rig --image NAME=… --image NAME=…`).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=100))]
    frames: u16,
    /// A room for a rig whose cameras' fields differ: this many boards more in the outer
    /// columns of the room camera's view (at most 10), the room's own laid out for a lens
    /// of --inner-fov degrees (the rig's narrow camera).
    #[arg(long, requires = "inner_fov", value_parser = clap::value_parser!(u8).range(1..=10))]
    ring_boards: Option<u8>,
    /// With --ring-boards: the horizontal field of view (degrees) the room's own boards are
    /// laid out for.
    #[arg(long, requires = "ring_boards")]
    inner_fov: Option<f64>,
    /// With --ring-boards: the ring's view turned this far left (degrees; negative: right),
    /// as the rig's widest camera looks beside its narrow one.
    #[arg(long, requires = "ring_boards", default_value_t = 0.0, allow_hyphen_values = true)]
    ring_turn: f64,
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
    /// A surveyed room instead of one scene: this many vehicles (each its own camera and
    /// LiDAR mounting, each parked ±0.3 m / ±5° off) visit one fixed room; writes
    /// room-truth.json, room.toml and visit-01/, visit-02/, … (for `roomcal survey`);
    /// with --capture every visit also gets its sweep as the sensor's packets.
    #[arg(long, conflicts_with_all = ["rig_seed"],
          value_parser = clap::value_parser!(u16).range(1..=99))]
    visits: Option<u16>,
    /// With --visits: number the visits from K (visit-K, visit-K+1, …): the very visits a
    /// run with more visits makes (each has its own random stream), so that a study adds
    /// visits to a room without rendering the earlier ones again.
    #[arg(long, requires = "visits", default_value_t = 1,
          value_parser = clap::value_parser!(u16).range(1..=999))]
    first_visit: u16,
    /// A rig file: one vehicle with every camera and LiDAR of the rig, parked once;
    /// writes NAME.png per camera, NAME.pcd per LiDAR, rig-truth.json, room-truth.json
    /// and room.toml. With --visits: the rig is one more vehicle of the visited room,
    /// written to DIR/rig/ (survey the visits, then calibrate the rig in the surveyed room).
    #[arg(long, value_name = "RIG", conflicts_with_all = ["capture", "rig_seed"])]
    rig: Option<PathBuf>,
    /// With --visits and --rig: this many rigs, each its own vehicle (intrinsics, mountings,
    /// parking) parked in the visited room, written to DIR/rig-01/, rig-02/, … (new
    /// vehicles for a study of one survey); without it the one rig goes to DIR/rig/ (the
    /// same as rig-01/).
    #[arg(long, requires_all = ["visits", "rig"],
          value_parser = clap::value_parser!(u16).range(1..=99))]
    rigs: Option<u16>,
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

/// An error with the exit code it maps to; `error: None` when the output already said it.
struct Failure {
    code: u8,
    error: Option<anyhow::Error>,
}

impl Failure {
    fn new(code: u8, error: impl Into<anyhow::Error>) -> Failure {
        Failure { code, error: Some(error.into()) }
    }
}

fn bad_input(error: impl Into<anyhow::Error>) -> Failure {
    Failure::new(2, error)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let outcome = match cli.command {
        Command::Calibrate(args) => calibrate(args),
        Command::Detect(args) => detect(args),
        Command::Overlay(args) => overlay(args),
        Command::Simulate(args) => simulate(args),
        Command::Survey(args) => survey(args),
        #[cfg(feature = "daemon")]
        Command::Daemon(args) => daemon(args),
        Command::Decode(args) => decode(args),
        Command::Query(args) => query(args),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure { code, error }) => {
            if let Some(error) = error {
                eprintln!("roomcal: {}", describe(&error));
            }
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
        ring: args.ring_boards.zip(args.inner_fov).map(|(boards, inner_hfov_deg)| sim::Ring {
            boards: usize::from(boards),
            inner_hfov_deg,
            turn_left_deg: args.ring_turn,
        }),
        image: sim::ImageNoise {
            supersample: args.supersample,
            blur_px: args.blur,
            noise_grey: args.image_noise,
            vignetting: args.vignetting,
            ..sim::ImageNoise::default()
        },
    };
    let mut layout = None;
    if let Some(visits) = args.visits {
        let count = usize::from(visits);
        let numbers = (usize::from(args.first_visit) - 1, count);
        let visits =
            simulate_visits(&room, &options, numbers, args.capture, (&args.room, &args.out))?;
        layout = Some(visits.layout);
    }
    if let Some(rig_path) = &args.rig {
        let rig = roomcal::rig::load(rig_path).map_err(bad_input)?;
        let context = || format!("simulating {} in {}", rig_path.display(), args.room.display());
        let vehicles = match (args.rigs, layout.as_ref()) {
            (Some(count), Some(layout)) => (1..=count)
                .map(|k| {
                    let simulated =
                        sim::rig::simulate_rig_vehicle(&room, &rig, &options, layout, k);
                    Ok((args.out.join(format!("rig-{k:02}")), simulated.with_context(context)?))
                })
                .collect::<anyhow::Result<Vec<_>>>(),
            (_, layout) => sim::rig::simulate_rig_in(&room, &rig, &options, layout)
                .with_context(context)
                .map(|simulated| {
                    let out = match layout {
                        Some(_) => args.out.join("rig"),
                        None => args.out.clone(),
                    };
                    vec![(out, simulated)]
                }),
        }
        .map_err(bad_input)?;
        for (out, simulated) in &vehicles {
            let written = sim::rig::write_rig(simulated, out).map_err(bad_input)?;
            say!(
                "simulated a rig of {} cameras and {} LiDARs in a room of {} boards -> {} ({} files)",
                rig.cameras.len(),
                rig.lidars.len(),
                simulated.room_truth.boards.len(),
                out.display(),
                written.len()
            );
        }
    }
    if args.visits.is_some() || args.rig.is_some() {
        return Ok(());
    }
    let scene = sim::simulate(&room, &options)
        .with_context(|| format!("simulating {}", args.room.display()))
        .map_err(bad_input)?;
    sim::write_scene(&scene, &args.out).map_err(bad_input)?;
    let t = &scene.truth;
    say!(
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
        say!(
            "capture: {}{}",
            files.capture.display(),
            files.calibration.map_or(String::new(), |c| format!(" (angles: {})", c.display()))
        );
    }
    Ok(())
}

/// `simulate --visits N [--first-visit K]`: one room, N visiting vehicles (0-based
/// `first`, then `count`); returns them.
fn simulate_visits(
    room: &roomcal::target::Room,
    options: &SimOptions,
    (first, count): (usize, usize),
    capture: bool,
    (room_path, out): (&std::path::Path, &std::path::Path),
) -> Result<sim::visits::Visits, Failure> {
    // Each visit written as it is made: memory for one visit, and the folders show
    // the progress.
    let visits = sim::visits::simulate_visits_from(room, options, first, count, |k, visit| {
        sim::visits::write_visit(&visit, k, out)?;
        if capture {
            sim::write_capture(&visit.scene, &out.join(sim::visits::visit_folder(k)))?;
        }
        Ok(())
    })
    .with_context(|| format!("simulating {}", room_path.display()))
    .map_err(bad_input)?;
    sim::visits::write_room(&visits, out).map_err(bad_input)?;
    say!(
        "simulated a room of {} boards and {} planes, {count} visits{} -> {}",
        visits.truth.boards.len(),
        visits.truth.planes.len(),
        if first > 0 { format!(" (from visit {})", first + 1) } else { String::new() },
        out.display()
    );
    Ok(visits)
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
    say!(
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
        .map_err(|error| Failure::new(1, error))?;
    say!("{answer}");
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
    // The header's size first: a frame of the wrong size is refused before it is decoded.
    let (got_width, got_height) = roomcal::detect::image_size(path).map_err(bad_input)?;
    if (got_width, got_height) != (width, height) {
        return Err(bad_input(anyhow::anyhow!(
            "image {}: {got_width}x{got_height} pixels, {whose} is {width}x{height}",
            path.display(),
        )));
    }
    roomcal::detect::load_grey(path).map_err(bad_input)
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
    if let Some(rig_path) = &args.rig {
        return calibrate_rig(&room, rig_path, &args);
    }
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
        Some(path) => Some(roomcal::result::load(path).map_err(bad_input)?),
        None => None,
    };
    let mut progress = cli::progress::Progress::on_stderr("calibrate", steps(&args), args.quiet);
    let mut images = args
        .image
        .iter()
        .map(|path| {
            progress.step(&format!("reading {}", path.display()));
            load_image(&room, path)
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut clouds = args
        .cloud
        .iter()
        .map(|path| {
            progress.step(&format!("reading {}", path.display()));
            load_cloud(&room, path, args.lidar_calibration.as_deref())
        })
        .collect::<Result<Vec<_>, _>>()?;
    if args.standing {
        (images, clouds) = standing_frame(images, clouds);
    }
    let mut detectors = Detectors::new(&room).map_err(bad_input)?;
    let mut frames = Vec::new();
    for (i, image) in images.iter().enumerate() {
        progress.step(&format!("detecting boards, frame {} of {}", i + 1, images.len()));
        let camera = detectors.detect_image(image).map_err(bad_input)?;
        frames.push(FrameDetections { camera, lidar: Vec::new() });
    }
    // Room without a LiDAR, or images only: intrinsics only.
    let mut room = room;
    if args.cloud.is_empty() {
        room.lidar = None;
    }
    let sweeps: Vec<&[roomcal::lidar::Point]> = clouds.iter().map(Vec::as_slice).collect();
    progress.step("solving");
    // The LiDAR's boards are found by the calibration: in a surveyed room where the room
    // expects them, from the camera's room pose.
    let (run, refused) = roomcal::calibrate::calibrate_detecting(
        &room,
        &mut frames,
        &sweeps,
        &mut detectors,
        &CalibrateOptions {
            two_stage: args.two_stage,
            current,
            current_rig: None,
            without_planes: args.without_planes,
            free_boards: args.free_boards,
            corner_start: None,
        },
    );
    if !args.quiet {
        for (i, planes) in refused.iter().enumerate() {
            let name = match args.standing {
                true => "the accumulated sweeps".to_string(),
                false => args.cloud[i].display().to_string(),
            };
            for plane in planes {
                progress.note(&refused_message(&name, plane));
            }
        }
    }
    progress.step("writing the results");
    let mut written = write_result(&args.out, &run.result)?;
    if let Some(report) = &args.report {
        let first_refused = refused.first().map_or(&[][..], Vec::as_slice);
        write_report(report, &images, &clouds, &run, first_refused)?;
        written.push(report.display().to_string());
    }
    let accepted = run.result.status == roomcal::result::Status::Accepted;
    if let Some(dir) = args.export.as_ref().filter(|_| accepted) {
        let files = roomcal::export::write_dir(dir, &roomcal::export::files(&run.result))
            .map_err(bad_input)?;
        written.extend(files.iter().map(|f| f.display().to_string()));
    }
    progress.finish(); // the line is cleared before the summary
    if args.json {
        say_raw!("{}", result_json(&run.result));
    } else if args.quiet {
        say!("{}", cli::summary::status_line(&run.result));
    } else {
        let refused_count = refused.iter().map(Vec::len).sum();
        for line in cli::summary::lines(&room, &frames, &run, refused_count, &written) {
            say!("{line}");
        }
        if let Some(dir) = args.export.as_ref().filter(|_| !accepted) {
            say!("  not written {}: a rejected calibration is not exported", dir.display());
        }
    }
    match run.result.status {
        roomcal::result::Status::Accepted => Ok(()),
        // The status line (or the JSON's status and reason) has said why.
        roomcal::result::Status::Rejected => Err(Failure { code: 3, error: None }),
    }
}

/// `calibrate --rig`: every sensor of the rig by name (`cli::rig`).
fn calibrate_rig(
    room: &roomcal::target::Room,
    rig_path: &std::path::Path,
    args: &CalibrateArgs,
) -> Result<(), Failure> {
    let rig = roomcal::rig::load(rig_path).map_err(bad_input)?;
    if !rig.lidars.is_empty() && room.board.holes.is_empty() {
        return Err(bad_input(anyhow::anyhow!(
            "{}: the rig has LiDARs but the room's boards have no holes (`board.holes`)",
            args.room.display()
        )));
    }
    let current_rig = match &args.current {
        Some(path) => Some(roomcal::result::load_rig(path).map_err(bad_input)?),
        None => None,
    };
    let inputs = cli::rig::inputs(&rig, rig_path, &args.image, &args.cloud, true)?;
    let angles = args.lidar_calibration.as_deref();
    let detections = cli::rig::detect_all(room, &rig, &inputs, angles, args.free_boards)?;
    let options = roomcal::calibrate::CalibrateOptions {
        two_stage: args.two_stage,
        current: None,
        current_rig,
        without_planes: args.without_planes,
        free_boards: args.free_boards,
        // The first camera's start, made to find the LiDARs' boards, is not made again.
        corner_start: detections.first_start.clone(),
    };
    let outputs = cli::rig::RigOutputs {
        out: &args.out,
        export: args.export.as_deref(),
        report: args.report.as_deref().map(|r| (r, &inputs)),
        json: args.json,
        quiet: args.quiet,
    };
    cli::rig::calibrate(room, &rig, &detections, &options, outputs)
}

fn survey(args: SurveyArgs) -> Result<(), Failure> {
    use roomcal::calibrate::survey::{prepare_visit, survey};
    let room = roomcal::room::load(&args.room).map_err(bad_input)?;
    if room.lidar.is_none() {
        return Err(bad_input(anyhow::anyhow!(
            "{}: a survey needs the room's LiDAR, the room file has no [lidar] table",
            args.room.display()
        )));
    }
    let pairs: Vec<(&std::path::Path, &std::path::Path)> =
        args.visit.chunks(2).map(|p| (p[0].as_path(), p[1].as_path())).collect();
    let angles = args.lidar_calibration.as_deref();
    let count = pairs.len();
    // Visits are independent until the bundle: load, detect and calibrate them in parallel.
    let prepared = parallel_map(&pairs, |index, (image, cloud)| {
        let image_data = load_image(&room, image)?;
        let points = load_cloud(&room, cloud, angles)?;
        let mut detectors = roomcal::calibrate::Detectors::new(&room).map_err(bad_input)?;
        let frame = roomcal::calibrate::FrameDetections {
            camera: detectors.detect_image(&image_data).map_err(bad_input)?,
            lidar: detectors.detect_cloud(&points),
        };
        let visit = prepare_visit(&room, index, &frame, &points)
            .with_context(|| format!("{} and {}", image.display(), cloud.display()))
            .map_err(bad_input)?;
        cli::survey::progress(&format!(
            "visit {}/{count}: {} boards, {} room planes ({})",
            index + 1,
            visit.boards.len(),
            visit.planes.len(),
            image.display()
        ));
        Ok(visit)
    })?;
    let mut solved = survey(&room, &prepared).map_err(bad_input)?;
    // The file's room frame is the nominal LiDAR frame at the visits' mean parking spot
    // (the parking box's reference), not the survey's own frame (the boards' mean).
    let lidar = room.lidar.as_ref().expect("checked above: the room has a LiDAR");
    solved.spec = solved.in_parking_frame(lidar);
    solved.spec.validate(room.board.count).map_err(bad_input)?;
    let mut surveyed = room;
    surveyed.survey = Some(solved.spec.clone());
    std::fs::write(&args.out, roomcal::room::to_toml(&surveyed))
        .with_context(|| format!("writing {}", args.out.display()))
        .map_err(|e| Failure::new(1, e))?;
    for line in cli::survey::lines(&solved, &prepared, &args.out.display().to_string()) {
        say!("{line}");
    }
    Ok(())
}

/// `f(index, item)` over `items` on every core ([`roomcal::parallel::map`]); the results
/// in order, or the first failure in the items' order.
fn parallel_map<T: Sync, R: Send>(
    items: &[T],
    f: impl Fn(usize, &T) -> Result<R, Failure> + Sync,
) -> Result<Vec<R>, Failure> {
    roomcal::parallel::map(items, f).into_iter().collect()
}

/// The steps `calibrate` shows progress for: each file read, each frame's detection (a
/// standing vehicle's frames are one), the solve and the writing.
fn steps(args: &CalibrateArgs) -> usize {
    let frames = if args.standing { 1 } else { args.image.len() };
    args.image.len() + args.cloud.len() + frames + 2
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

/// A refused LiDAR plane as a sentence: the file, where the plane is, why it is not a
/// board, and what to do.
fn refused_message(cloud: &str, plane: &roomcal::detect::holes::RefusedBoard) -> String {
    format!("{cloud}: {plane}; not used as a board ({})", plane.reason.advice())
}

/// The result file's text.
fn result_json(result: &roomcal::result::CalibrationResult) -> String {
    serde_json::to_string_pretty(result).expect("results serialise") + "\n"
}

/// Writes the result file and its OpenCV YAML beside it; returns both paths.
fn write_result(
    path: &std::path::Path,
    result: &roomcal::result::CalibrationResult,
) -> Result<Vec<String>, Failure> {
    let yaml_path = path.with_extension("yaml");
    std::fs::write(path, result_json(result))
        .and_then(|()| std::fs::write(&yaml_path, result.to_opencv_yaml()))
        .with_context(|| format!("writing {} and {}", path.display(), yaml_path.display()))
        .map_err(bad_input)?;
    Ok(vec![path.display().to_string(), yaml_path.display().to_string()])
}

/// The report picture of the first frame (see `roomcal::report::calibration_report`).
fn write_report(
    path: &std::path::Path,
    images: &[roomcal::detect::GreyImage],
    clouds: &[Vec<roomcal::lidar::Point>],
    run: &roomcal::calibrate::Calibration,
    refused: &[roomcal::detect::holes::RefusedBoard],
) -> Result<(), Failure> {
    let Some(first) = images.first() else { return Ok(()) };
    let cloud: Vec<&[roomcal::lidar::Point]> =
        clouds.first().map(|c| c.as_slice()).into_iter().collect();
    roomcal::report::calibration_report(&first.data, &cloud, run, refused)
        .save(path)
        .with_context(|| format!("writing the report {}", path.display()))
        .map_err(bad_input)
}

fn overlay(args: OverlayArgs) -> Result<(), Failure> {
    let result = roomcal::result::load(&args.calibration).map_err(bad_input)?;
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
    say!("overlay of {} points written to {}", cloud.len(), args.out.display());
    Ok(())
}

fn detect(args: DetectArgs) -> Result<(), Failure> {
    use roomcal::result::{BoardDetection, Detections};
    let room = roomcal::room::load(&args.room).map_err(bad_input)?;
    if args.image.is_empty() && args.cloud.is_empty() {
        return Err(bad_input(anyhow::anyhow!("give --image, --cloud or both")));
    }
    if let Some(rig_path) = &args.rig {
        let rig = roomcal::rig::load(rig_path).map_err(bad_input)?;
        let inputs = cli::rig::inputs(&rig, rig_path, &args.image, &args.cloud, false)?;
        let angles = args.lidar_calibration.as_deref();
        let detections = cli::rig::detect_all(&room, &rig, &inputs, angles, false)?;
        let json = cli::rig::detections_json(&rig, &inputs, &detections);
        std::fs::write(&args.out, json)
            .with_context(|| format!("writing {}", args.out.display()))
            .map_err(bad_input)?;
        say!(
            "detections of {} sensors -> {}",
            rig.cameras.len() + rig.lidars.len(),
            args.out.display()
        );
        return Ok(());
    }
    if args.image.len() > 1 || args.cloud.len() > 1 {
        return Err(bad_input(anyhow::anyhow!(
            "give one --image and one --cloud (several only with --rig, as NAME=PATH)"
        )));
    }
    let mut detectors = roomcal::calibrate::Detectors::new(&room).map_err(bad_input)?;
    let mut frame = roomcal::calibrate::FrameDetections::default();
    if let Some(path) = args.image.first() {
        let image = load_image(&room, path)?;
        frame.camera = detectors.detect_image(&image).map_err(bad_input)?;
    }
    if let Some(path) = args.cloud.first() {
        let cloud = load_cloud(&room, path, args.lidar_calibration.as_deref())?;
        let refused = match (&room.survey, args.image.is_empty()) {
            // In a surveyed room the LiDAR's boards are found where the calibration finds
            // them: where the room expects them, from the camera's room pose.
            (Some(_), false) => {
                let mut frames = [std::mem::take(&mut frame)];
                let options = roomcal::calibrate::CalibrateOptions::default();
                let clouds = [cloud.as_slice()];
                let (_, refused) = roomcal::calibrate::calibrate_detecting(
                    &room,
                    &mut frames,
                    &clouds,
                    &mut detectors,
                    &options,
                );
                [frame] = frames;
                refused.into_iter().next().unwrap_or_default()
            }
            _ => {
                frame.lidar = detectors.detect_cloud(&cloud);
                detectors.refused_in_cloud().to_vec()
            }
        };
        for refused in &refused {
            eprintln!("{}", refused_message(&path.display().to_string(), refused));
        }
    }
    // In a surveyed room every board is named by its surveyed board; a frame that cannot
    // be identified is still reported (its detections without identities), with why.
    let identities = match (&room.survey, !args.image.is_empty()) {
        (Some(survey), true) => {
            match roomcal::calibrate::identify_detections(&room, survey, &frame) {
                Ok(ids) => Some(ids),
                Err(reason) => {
                    eprintln!(
                        "{}: the boards could not be identified: {reason}",
                        args.room.display()
                    );
                    None
                }
            }
        }
        (Some(_), false) => {
            eprintln!("{}: the LiDAR's boards are identified through the camera's room pose: give --image too", args.room.display());
            None
        }
        (None, _) => None,
    };
    let mut out = Detections::default();
    for (i, board) in frame.camera.iter().enumerate() {
        let id = identities.as_ref().and_then(|ids| ids.camera[i]);
        out.boards.push(BoardDetection {
            corners_px: board.corners.iter().map(|c| [c.x, c.y]).collect(),
            surveyed_board: id.map(|id| id.board as u32),
            half_turned: id.is_some_and(|id| id.half_turned),
            ..BoardDetection::default()
        });
    }
    for (l, board) in frame.lidar.iter().enumerate() {
        out.boards.push(BoardDetection {
            holes_lidar: board.holes.iter().map(|h| [h.x, h.y, h.z]).collect(),
            surveyed_board: identities.as_ref().and_then(|ids| ids.lidar[l]).map(|k| k as u32),
            ..BoardDetection::default()
        });
    }
    for note in identities.iter().flat_map(|ids| &ids.notes) {
        eprintln!("{note}");
    }
    let json = serde_json::to_string_pretty(&out).expect("detections serialise") + "\n";
    std::fs::write(&args.out, json)
        .with_context(|| format!("writing {}", args.out.display()))
        .map_err(bad_input)?;
    let cameras = out.boards.iter().filter(|b| !b.corners_px.is_empty()).count();
    say!(
        "{} camera boards, {} LiDAR boards -> {}",
        cameras,
        out.boards.len() - cameras,
        args.out.display()
    );
    if identities.is_some() {
        for line in identity_lines(&out) {
            say!("{line}");
        }
    }
    Ok(())
}

/// One line per board of a surveyed room's detections: which surveyed board it is.
fn identity_lines(detections: &roomcal::result::Detections) -> Vec<String> {
    let mut counts = [0usize; 2];
    detections
        .boards
        .iter()
        .map(|b| {
            let sensor = usize::from(b.corners_px.is_empty());
            let index = counts[sensor];
            counts[sensor] += 1;
            let name = ["camera", "LiDAR"][sensor];
            match b.surveyed_board {
                Some(k) if b.half_turned => {
                    format!("  {name} board {index}: surveyed board {k} (read half-turned)")
                }
                Some(k) => format!("  {name} board {index}: surveyed board {k}"),
                None => format!("  {name} board {index}: matches no surveyed board"),
            }
        })
        .collect()
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

/// Keeps glibc's allocator from holding on to freed memory (the daemon's peak RSS, issue
/// 17). By default glibc raises its mmap threshold whenever a large block is freed, so the
/// later frame- and sweep-sized buffers come from the heap and stay resident after use, and
/// each thread that allocates may get an arena of its own. A fixed 256 KiB threshold hands
/// every large buffer back to the kernel when it is freed, and two arenas bound the
/// threads' slack. The rig daemon's peak RSS (two 1920×1200 cameras, two LiDARs): 96–104 MB
/// without, 81–83 MB with (README, "Speed and memory").
#[cfg(all(feature = "daemon", target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
fn bound_allocator_slack() {
    use std::ffi::c_int;
    extern "C" {
        fn mallopt(param: c_int, value: c_int) -> c_int;
    }
    const M_MMAP_THRESHOLD: c_int = -3;
    const M_ARENA_MAX: c_int = -8;
    // SAFETY: mallopt only sets the allocator's parameters (glibc, <malloc.h>); it is called
    // before the runtime starts any thread. A refused setting (return 0) keeps the default.
    unsafe {
        mallopt(M_MMAP_THRESHOLD, 256 * 1024);
        mallopt(M_ARENA_MAX, 2);
    }
}

/// Other allocators keep their own policy.
#[cfg(all(feature = "daemon", not(all(target_os = "linux", target_env = "gnu"))))]
fn bound_allocator_slack() {}

#[cfg(feature = "daemon")]
fn daemon(args: DaemonArgs) -> Result<(), Failure> {
    use roomcal::daemon::{room_calibrator::RoomCalibrator, RunOptions};
    bound_allocator_slack();
    roomcal::daemon::init_logging();
    let config = roomcal::daemon::config::load(&args.config).map_err(bad_input)?;
    let room = roomcal::room::load(&config.room).map_err(bad_input)?;
    let mut calibrator = RoomCalibrator::new(room).map_err(bad_input)?;
    if let Some(rig) = &config.rig {
        calibrator = calibrator.with_rig(rig.rig.clone()).map_err(bad_input)?;
    }
    // A rig's report is one picture per camera, `last-run-NAME.png`.
    calibrator = calibrator.with_report(config.store.join("last-run.png"));
    let runtime = tokio::runtime::Runtime::new()
        .context("starting the async runtime")
        .map_err(|error| Failure::new(1, error))?;
    let summary = runtime
        .block_on(roomcal::daemon::run(
            config,
            calibrator,
            RunOptions { once: args.once },
            stop_signal(),
        ))
        .map_err(|e| Failure::new(1, e))?;
    say!(
        "roomcal daemon: {} run(s): {} accepted, {} rejected, {} failed; generation {} in force",
        summary.runs,
        summary.accepted,
        summary.rejected,
        summary.failed,
        summary.generation
    );
    Ok(())
}
