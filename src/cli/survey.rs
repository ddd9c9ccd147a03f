//! `roomcal survey`: several visits' image/cloud pairs → the room file again with a
//! `[survey]` table; prints per-visit progress and what the survey found, one line per
//! board and plane.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context};
use clap::Args;

use roomcal::calibrate::survey::{prepare_visit, survey, LidarPlacement, Survey, SurveyVisit};
use roomcal::calibrate::{Detectors, FrameDetections};
use roomcal::target::Room;

use super::io::{load_cloud, load_image};
use super::{bad_input, Failure};

#[derive(Args)]
pub struct SurveyArgs {
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

/// `roomcal survey`: every visit prepared (in parallel), the bundle solved, the surveyed
/// room file written.
pub fn run(args: SurveyArgs) -> Result<(), Failure> {
    let room = roomcal::room::load(&args.room).map_err(bad_input)?;
    if room.lidar.is_none() {
        return Err(bad_input(anyhow!(
            "{}: a survey needs the room's LiDAR, the room file has no [lidar] table",
            args.room.display()
        )));
    }
    let pairs: Vec<(&Path, &Path)> =
        args.visit.chunks(2).map(|p| (p[0].as_path(), p[1].as_path())).collect();
    let angles = args.lidar_calibration.as_deref();
    // Visits are independent until the bundle: load, detect and calibrate them in parallel.
    let prepared: Vec<SurveyVisit> = roomcal::parallel::map(&pairs, |index, &(image, cloud)| {
        prepare(&room, index, pairs.len(), (image, cloud), angles)
    })
    .into_iter()
    .collect::<Result<_, _>>()?;
    let mut solved = survey(&room, &prepared).map_err(bad_input)?;
    let surveyed = solved.surveyed_room(room).map_err(bad_input)?;
    std::fs::write(&args.out, roomcal::room::to_toml(&surveyed))
        .with_context(|| format!("writing {}", args.out.display()))
        .map_err(|e| Failure::new(1, e))?;
    for line in lines(&solved, &prepared, &args.out.display().to_string()) {
        say!("{line}");
    }
    Ok(())
}

/// Visit `index` of `count`: its image and cloud read, detected and prepared for the bundle.
fn prepare(
    room: &Room,
    index: usize,
    count: usize,
    (image, cloud): (&Path, &Path),
    angles: Option<&Path>,
) -> Result<SurveyVisit, Failure> {
    let image_data = load_image(room, image)?;
    let points = load_cloud(room, cloud, angles)?;
    let mut detectors = Detectors::new(room).map_err(bad_input)?;
    let frame = FrameDetections {
        camera: detectors.detect_image(&image_data).map_err(bad_input)?,
        lidar: detectors.detect_cloud(&points),
    };
    let visit = prepare_visit(room, index, &frame, &points)
        .with_context(|| format!("{} and {}", image.display(), cloud.display()))
        .map_err(bad_input)?;
    progress(&format!(
        "visit {}/{count}: {} boards, {} room planes ({})",
        index + 1,
        visit.boards.len(),
        visit.planes.len(),
        image.display()
    ));
    Ok(visit)
}

/// A progress line on stderr, only when it is a terminal (logs and pipes stay clean).
fn progress(line: &str) {
    if std::io::stderr().is_terminal() {
        eprintln!("{line}");
    }
}

/// The summary: a status line, how the visits' LiDARs were placed, one line per board and
/// per plane, the file written.
fn lines(survey: &Survey, visits: &[SurveyVisit], written: &str) -> Vec<String> {
    let spec = &survey.spec;
    let mut out = vec![format!(
        "roomcal survey: {} visits, {} boards, {} planes; corners {:.3} px RMS; {} iterations",
        spec.visits,
        spec.boards.len(),
        spec.planes.len(),
        survey.corner_rms_px,
        survey.report.iterations
    )];
    out.push(format!("  room frame: {}", spec.frame));
    out.push(lidar_line(visits));
    for (b, (board, visits)) in spec.boards.iter().zip(&survey.board_visits).enumerate() {
        let [x, y, z] = board.translation;
        // Every board, board 0 too, has its σ relative to the boards' mean frame.
        out.push(format!(
            "  board {b}: at ({x:.4}, {y:.4}, {z:.4}) m, σ {:.2} mm / {:.4}°; seen by {visits} visits",
            board.sigma_m * 1e3,
            board.sigma_deg
        ));
    }
    for (plane, visits) in spec.planes.iter().zip(&survey.plane_visits) {
        let [x, y, z] = plane.normal;
        out.push(format!(
            "  plane {}: normal ({x:.4}, {y:.4}, {z:.4}), offset {:.4} m, σ {:.2} mm / {:.4}°; seen by {visits} visits",
            plane.name,
            plane.offset,
            plane.sigma_m * 1e3,
            plane.sigma_deg
        ));
    }
    out.push(format!("  written {written}"));
    out
}

/// How many visits' LiDARs were placed by holes, by faces alone, and not at all, naming the
/// visits of the last two (numbered from 1, as given).
fn lidar_line(visits: &[SurveyVisit]) -> String {
    let numbers = |kind: LidarPlacement| -> Vec<String> {
        (visits.iter().enumerate())
            .filter(|(_, v)| v.lidar_placement() == kind)
            .map(|(i, _)| (i + 1).to_string())
            .collect()
    };
    let holes = numbers(LidarPlacement::Holes).len();
    let mut line = format!("  LiDAR placed by board holes in {holes} of {} visits", visits.len());
    let faces = numbers(LidarPlacement::Faces);
    if !faces.is_empty() {
        line += &format!(", by the board faces alone in visit(s) {}", faces.join(", "));
    }
    let unplaced = numbers(LidarPlacement::Unplaced);
    if !unplaced.is_empty() {
        line +=
            &format!("; not placed in visit(s) {} (their sweeps add nothing)", unplaced.join(", "));
    }
    line
}
