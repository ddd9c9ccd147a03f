//! `roomcal simulate`: a synthetic calibration room with ground truth — one scene, a room
//! visited by several vehicles (for `survey`), or a rig's vehicle.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Args, ValueEnum};

use roomcal::geometry::CameraModel;
use roomcal::lidar::Model;
use roomcal::sim::{self, SimOptions};
use roomcal::target::Room;

use super::{bad_input, Failure};

#[derive(Args)]
pub struct SimulateArgs {
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
    #[arg(long, value_parser = sim_lidar())]
    lidar: Option<Model>,
    /// Board arrangement: a grid over the image, or a row at the LiDAR's dense band plus
    /// two boards in the top corners; `auto`: the band for one scene of a room with a
    /// LiDAR (where the LiDAR places the boards by their holes), the grid otherwise.
    #[arg(long, value_enum, default_value = "auto")]
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

/// The models `--lidar` offers (the simulator has beam tables for them).
const SIM_LIDARS: [Model; 3] = [Model::Pandar64, Model::Vlp32c, Model::Vlp16];

/// `--lidar`: one of [`SIM_LIDARS`] by its room-file name, exactly.
fn sim_lidar() -> impl TypedValueParser<Value = Model> {
    PossibleValuesParser::new(SIM_LIDARS.map(Model::name))
        .try_map(|name| Model::from_file_name(&name).flatten().ok_or("not a packet model"))
}

#[derive(Clone, Copy, ValueEnum)]
enum LayoutArg {
    Auto,
    Grid,
    Band,
}

/// `roomcal simulate`: a scene, a visited room, or a rig (in a visited room).
pub fn run(args: SimulateArgs) -> Result<(), Failure> {
    let room = roomcal::room::load(&args.room).map_err(bad_input)?;
    let options = options(&args, &room);
    let mut layout = None;
    if let Some(visits) = args.visits {
        let count = usize::from(visits);
        let numbers = (usize::from(args.first_visit) - 1, count);
        let visits =
            simulate_visits(&room, &options, numbers, args.capture, (&args.room, &args.out))?;
        layout = Some(visits.layout);
    }
    if let Some(rig_path) = &args.rig {
        simulate_rigs(&room, rig_path, &options, layout.as_ref(), &args)?;
    }
    if args.visits.is_some() || args.rig.is_some() {
        return Ok(());
    }
    simulate_scene(&room, &options, &args)
}

/// The simulation's options from the command line's.
fn options(args: &SimulateArgs, room: &roomcal::target::Room) -> SimOptions {
    // A scene's boards at the LiDAR's dense band get scan lines across their holes; visits
    // and rigs keep the grid their surveys and rooms were made with.
    let one_scene = args.visits.is_none() && args.rig.is_none() && args.ring_boards.is_none();
    let beams = room.lidar.as_ref().and_then(|l| args.lidar.or(l.model));
    let band = one_scene && beams.and_then(sim::raycast::beam_elevations).is_some();
    SimOptions {
        seed: args.seed,
        boards: args.boards,
        camera_model: args.camera_model.map(|m| match m {
            CameraArg::PinholeRadtan => CameraModel::PinholeRadtan,
            CameraArg::Fisheye => CameraModel::Fisheye,
        }),
        hfov_deg: args.fov,
        distortion: args.distortion.clone(),
        lidar: args.lidar,
        range_noise_m: args.range_noise,
        layout: match args.layout {
            LayoutArg::Auto if band => sim::Layout::Band,
            LayoutArg::Auto | LayoutArg::Grid => sim::Layout::Grid,
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
    }
}

/// One scene (`image.png`, `cloud.pcd`, `truth.json`, with `--capture` the packets).
fn simulate_scene(room: &Room, options: &SimOptions, args: &SimulateArgs) -> Result<(), Failure> {
    let scene = sim::simulate(room, options)
        .with_context(|| format!("simulating {}", args.room.display()))
        .map_err(bad_input)?;
    sim::write_scene(&scene, &args.out).map_err(bad_input)?;
    let t = &scene.truth;
    say!(
        "simulated {} boards ({} {}x{}, fx {:.2} fy {:.2} cx {:.2} cy {:.2}){} -> {}",
        t.boards.len(),
        t.camera.model.name(),
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

/// `simulate --rig`: the rig's vehicle (in the visited room's `layout` when there is
/// one: `--rigs N` vehicles to DIR/rig-01/, …, else one to DIR/rig/), each written.
fn simulate_rigs(
    room: &Room,
    rig_path: &Path,
    options: &SimOptions,
    layout: Option<&sim::visits::RoomLayout>,
    args: &SimulateArgs,
) -> Result<(), Failure> {
    let rig = roomcal::rig::load(rig_path).map_err(bad_input)?;
    let context = || format!("simulating {} in {}", rig_path.display(), args.room.display());
    let vehicles = match (args.rigs, layout) {
        (Some(count), Some(layout)) => (1..=count)
            .map(|k| {
                let simulated = sim::rig::simulate_rig_vehicle(room, &rig, options, layout, k);
                Ok((args.out.join(format!("rig-{k:02}")), simulated.with_context(context)?))
            })
            .collect::<anyhow::Result<Vec<_>>>(),
        (_, layout) => sim::rig::simulate_rig_in(room, &rig, options, layout)
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
    Ok(())
}

/// `simulate --visits N [--first-visit K]`: one room, N visiting vehicles (0-based
/// `first`, then `count`); returns them.
fn simulate_visits(
    room: &Room,
    options: &SimOptions,
    (first, count): (usize, usize),
    capture: bool,
    (room_path, out): (&Path, &Path),
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
