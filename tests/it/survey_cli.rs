//! `roomcal survey` end to end: three simulated visits (written by `roomcal simulate
//! --visits`) give a room file with a `[survey]` that loads and validates, the summary
//! names every board and plane; bad input exits 2 naming the input.

use crate::common::BIN;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn scratch(test: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("survey_cli").join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Three visits of the design's room (one sub-sample per pixel: rendering stays cheap).
fn simulated(dir: &Path) -> PathBuf {
    let out = dir.join("visits");
    let sim = Command::new(BIN)
        .args(["simulate", "--room", concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")])
        .arg("--out")
        .arg(&out)
        .args(["--visits", "3", "--supersample", "1", "--seed", "2"])
        .output()
        .unwrap();
    assert!(sim.status.success(), "simulate: {}", String::from_utf8_lossy(&sim.stderr));
    out
}

fn visit_args(dir: &Path, visits: &[usize]) -> Vec<String> {
    visits
        .iter()
        .flat_map(|v| {
            let folder = dir.join(format!("visit-{v:02}"));
            [
                "--visit".to_string(),
                folder.join("image.png").display().to_string(),
                folder.join("cloud.pcd").display().to_string(),
            ]
        })
        .collect()
}

fn survey(dir: &Path, visits: &[usize], out: &Path) -> Output {
    Command::new(BIN)
        .args(["survey", "--room"])
        .arg(dir.join("room.toml"))
        .args(visit_args(dir, visits))
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn survey_writes_the_room_with_a_survey_and_refuses_bad_input() {
    let dir = scratch("end_to_end");
    let visits = simulated(&dir);
    let out = dir.join("surveyed.toml");
    let run = survey(&visits, &[1, 2, 3], &out);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "survey: {stdout}{}", String::from_utf8_lossy(&run.stderr));
    // Not a terminal: no progress lines.
    assert!(run.stderr.is_empty(), "stderr: {}", String::from_utf8_lossy(&run.stderr));
    let room = roomcal::room::load(&out).expect("the surveyed room file loads and validates");
    let spec = room.survey.expect("[survey] written");
    assert_eq!((spec.visits, spec.boards.len()), (3, 6));
    assert!(spec.frame.starts_with("the nominal LiDAR frame"), "{}", spec.frame);
    // The simulator's room frame is the nominal LiDAR frame at the nominal spot, and the
    // visits park a few centimetres and degrees around it: every board in the file lies
    // where the room truth has one, to within the parking spread.
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(visits.join("room-truth.json")).unwrap())
            .unwrap();
    let truth_centres: Vec<[f64; 3]> = truth["boards"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| core::array::from_fn(|i| b["translation"][i].as_f64().unwrap()))
        .collect();
    for (b, board) in spec.boards.iter().enumerate() {
        let nearest = truth_centres
            .iter()
            .map(|t| (0..3).map(|i| (t[i] - board.translation[i]).powi(2)).sum::<f64>().sqrt())
            .fold(f64::MAX, f64::min);
        assert!(nearest < 0.3, "board {b} is {nearest:.3} m from every truth board: {spec:?}");
    }
    assert!(
        spec.boards[1..].iter().all(|b| b.sigma_m > 0.0 && b.sigma_m < 0.05),
        "{:?}",
        spec.boards
    );
    assert!(stdout.starts_with("roomcal survey: 3 visits, 6 boards"), "{stdout}");
    for b in 1..6 {
        assert!(stdout.contains(&format!("  board {b}: at (")), "{stdout}");
    }
    for plane in &spec.planes {
        assert!(stdout.contains(&format!("  plane {}: normal", plane.name)), "{stdout}");
    }

    // Bad input: exit 2, the input named.
    let refuse = |run: Output, needle: &str| {
        let stderr = String::from_utf8_lossy(&run.stderr).to_string();
        assert_eq!(run.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(needle), "{needle:?} not in {stderr}");
    };
    refuse(survey(&visits, &[1, 2, 1], &dir.join("twice.toml")), "visit 3 is visit 1 again");
    refuse(survey(&visits, &[1], &dir.join("one.toml")), "at least 2 visits");
    refuse(survey(&visits, &[1, 7], &dir.join("missing.toml")), "visit-07");
    let odd = Command::new(BIN)
        .args(["survey", "--room"])
        .arg(visits.join("room.toml"))
        .args(["--visit", "only-an-image.png", "--out"])
        .arg(dir.join("odd.toml"))
        .output()
        .unwrap();
    assert_eq!(odd.status.code(), Some(2));
    assert!(!dir.join("twice.toml").exists() && !dir.join("one.toml").exists());
}
