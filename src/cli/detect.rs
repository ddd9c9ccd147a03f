//! `roomcal detect`: the boards in one image and/or one cloud (or a rig's `NAME=PATH`
//! inputs) as a detections file; in a surveyed room each named by its surveyed board.

use std::path::PathBuf;

use anyhow::{anyhow, Context};
use clap::Args;

use roomcal::calibrate::{detect_frame, Detectors, Identification};
use roomcal::detect::holes::RefusedBoard;
use roomcal::result::Detections;
use roomcal::rig::Rig;

use super::io::{load_cloud, load_image, result_json};
use super::rig::{RigDetections, RigInputs};
use super::{bad_input, Failure};

#[derive(Args)]
pub struct DetectArgs {
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

/// `roomcal detect`: writes the detections and prints how many boards each sensor saw.
pub fn run(args: DetectArgs) -> Result<(), Failure> {
    let room = roomcal::room::load(&args.room).map_err(bad_input)?;
    if args.image.is_empty() && args.cloud.is_empty() {
        return Err(bad_input(anyhow!("give --image, --cloud or both")));
    }
    if args.rig.is_some() {
        return run_rig(&room, &args);
    }
    if args.image.len() > 1 || args.cloud.len() > 1 {
        return Err(bad_input(anyhow!(
            "give one --image and one --cloud (several only with --rig, as NAME=PATH)"
        )));
    }
    let mut detectors = Detectors::new(&room).map_err(bad_input)?;
    let camera = match args.image.first() {
        Some(path) => Some(detectors.detect_image(&load_image(&room, path)?).map_err(bad_input)?),
        None => None,
    };
    let cloud = match args.cloud.first() {
        Some(path) => Some(load_cloud(&room, path, args.lidar_calibration.as_deref())?),
        None => None,
    };
    let report = detect_frame(&room, &mut detectors, camera, cloud.as_deref());
    if let Some(path) = args.cloud.first() {
        for line in refused_lines(&path.display().to_string(), &report.refused) {
            eprintln!("{line}");
        }
    }
    match &report.identities {
        Identification::Failed(reason) => {
            eprintln!("{}: the boards could not be identified: {reason}", args.room.display())
        }
        Identification::NeedsImage => eprintln!(
            "{}: the LiDAR's boards are identified through the camera's room pose: give --image too",
            args.room.display()
        ),
        Identification::Identified(ids) => ids.notes.iter().for_each(|note| eprintln!("{note}")),
        Identification::NotSurveyed => {}
    }
    let out = report.detections();
    write(&args.out, &result_json(&out))?;
    let cameras = out.boards.iter().filter(|b| !b.corners_px.is_empty()).count();
    say!(
        "{} camera boards, {} LiDAR boards -> {}",
        cameras,
        out.boards.len() - cameras,
        args.out.display()
    );
    if report.identified().is_some() {
        for line in identity_lines(&out) {
            say!("{line}");
        }
    }
    Ok(())
}

/// A refused LiDAR plane as a sentence: the file, where the plane is, why it is not a
/// board, and what to do.
pub fn refused_message(cloud: &str, plane: &RefusedBoard) -> String {
    format!("{cloud}: {plane}; not used as a board ({})", plane.reason.advice())
}

/// Refused planes of one cloud listed per reason, at most this many each; the rest of a
/// reason's planes (a standing vehicle's walls and floor) are summed up in one line.
const LISTED_PER_REASON: usize = 3;

/// The sentences for `cloud`'s refused planes: [`refused_message`] for the first
/// [`LISTED_PER_REASON`] planes refused for each piece of advice, one line for the rest.
pub fn refused_lines(cloud: &str, planes: &[RefusedBoard]) -> Vec<String> {
    let mut advices: Vec<&'static str> = Vec::new();
    for plane in planes {
        if !advices.contains(&plane.reason.advice()) {
            advices.push(plane.reason.advice());
        }
    }
    let mut lines = Vec::new();
    for advice in advices {
        let alike: Vec<&RefusedBoard> =
            planes.iter().filter(|p| p.reason.advice() == advice).collect();
        // A summary line in place of a single plane's sentence would say less in as much.
        let listed =
            if alike.len() > LISTED_PER_REASON + 1 { LISTED_PER_REASON } else { alike.len() };
        lines.extend(alike.iter().take(listed).map(|p| refused_message(cloud, p)));
        if let Some(more) = alike.len().checked_sub(listed).filter(|&n| n > 0) {
            lines.push(format!(
                "{cloud}: {more} more plane(s) refused likewise, not listed ({advice}; the \
                 report picture of `calibrate --report` marks them all)"
            ));
        }
    }
    lines
}

/// One line per board of a surveyed room's detections: which surveyed board it is.
fn identity_lines(detections: &Detections) -> Vec<String> {
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

/// `detect --rig`: every sensor's detections by its name.
fn run_rig(room: &roomcal::target::Room, args: &DetectArgs) -> Result<(), Failure> {
    let rig_path = args.rig.as_deref().expect("called with --rig");
    let rig = roomcal::rig::load(rig_path).map_err(bad_input)?;
    let inputs = super::rig::inputs(&rig, rig_path, &args.image, &args.cloud, false)?;
    let angles = args.lidar_calibration.as_deref();
    let detections = super::rig::detect_all(room, &rig, &inputs, angles, false)?;
    write(&args.out, &rig_detections_json(&rig, &inputs, &detections))?;
    say!(
        "detections of {} sensors -> {}",
        rig.cameras.len() + rig.lidars.len(),
        args.out.display()
    );
    Ok(())
}

fn write(path: &std::path::Path, text: &str) -> Result<(), Failure> {
    std::fs::write(path, text)
        .with_context(|| format!("writing {}", path.display()))
        .map_err(bad_input)
}

/// `roomcal detect --rig`: `{"sensors": {NAME: {"boards": [...]}}}`, each sensor's
/// detections in the one-pair form (a sensor without inputs left out).
fn rig_detections_json(rig: &Rig, inputs: &RigInputs, detections: &RigDetections) -> String {
    let mut sensors = serde_json::Map::new();
    for (c, boards) in detections.cameras.iter().enumerate() {
        if inputs.images[c].is_empty() {
            continue;
        }
        let boards = boards.iter().map(|b| b.detection()).collect();
        let value = serde_json::to_value(Detections { boards }).expect("detections serialise");
        sensors.insert(rig.cameras[c].name.to_string(), value);
    }
    for (l, (boards, _)) in detections.lidars.iter().enumerate() {
        if inputs.clouds[l].is_empty() {
            continue;
        }
        let boards = boards.iter().map(|b| b.detection()).collect();
        let value = serde_json::to_value(Detections { boards }).expect("detections serialise");
        sensors.insert(rig.lidars[l].name.to_string(), value);
    }
    result_json(&serde_json::json!({ "sensors": sensors }))
}
