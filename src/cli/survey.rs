//! `roomcal survey`'s printed summary and its per-visit progress: what the survey found,
//! one line per board and plane.

use std::io::IsTerminal;

use roomcal::calibrate::survey::{LidarPlacement, Survey, SurveyVisit};

/// A progress line on stderr, only when it is a terminal (logs and pipes stay clean).
pub fn progress(line: &str) {
    if std::io::stderr().is_terminal() {
        eprintln!("{line}");
    }
}

/// The summary: a status line, how the visits' LiDARs were placed, one line per board and
/// per plane, the file written.
pub fn lines(survey: &Survey, visits: &[SurveyVisit], written: &str) -> Vec<String> {
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
