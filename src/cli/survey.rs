//! `roomcal survey`'s printed summary and its per-visit progress: what the survey found,
//! one line per board and plane.

use std::io::IsTerminal;

use roomcal::calibrate::survey::Survey;

/// A progress line on stderr, only when it is a terminal (logs and pipes stay clean).
pub fn progress(line: &str) {
    if std::io::stderr().is_terminal() {
        eprintln!("{line}");
    }
}

/// The summary: a status line, one line per board and per plane, the file written.
pub fn lines(survey: &Survey, written: &str) -> Vec<String> {
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
