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
    /// Render a synthetic calibration room with ground truth (image.png, cloud.pcd, truth.json).
    Simulate(SimulateArgs),
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
        Command::Simulate(args) => simulate(args),
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure { code, error }) => {
            eprintln!("roomcal: {error:#}");
            ExitCode::from(code)
        }
    }
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
    Ok(())
}
