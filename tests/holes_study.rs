//! The LiDAR board detector over randomised rooms it was not tuned on (issue 14): board
//! sizes, hole layouts, tilts, rolls, depths, mounting heights, clutter and three LiDAR
//! models from `roomcal::sim::random_room`. Per model it prints placeable boards found,
//! false placements, hole error mean / worst and the refusal reasons, and asserts the
//! issue's targets: no false placement, ≥ 98 % of the placeable boards found, mean hole
//! error ≤ 4 mm (Pandar64, one sweep, 2 cm range noise).
//!
//! `cargo test --test holes_study -- --nocapture` runs the reduced study (20 rooms per
//! model); `cargo test --test holes_study -- --ignored --nocapture` the full one (200 per
//! model, a few minutes). A placement is false when a hole lies more than
//! [`FALSE_HOLE_M`] from its true centre (a wrong hole order included) or the placed board
//! is no board at all.

use std::collections::BTreeMap;

use roomcal::detect::holes::{HoleConfig, HoleDetector, LidarBoard};
use roomcal::sim::random_room::{issue_room, random_room, RandomBoard, RandomRoom};
use roomcal::target::LidarModel;

/// A placed hole farther than this from the truth makes the placement false (m).
const FALSE_HOLE_M: f64 = 0.02;
const NOISE_M: f64 = 0.02;
const MODELS: [(&str, LidarModel); 3] = [
    ("Pandar64", LidarModel::Pandar64),
    ("Pandar40P", LidarModel::Pandar40p),
    ("VLP-32C", LidarModel::Vlp32c),
];

/// Figures of one model over its rooms.
#[derive(Debug, Default)]
struct Figures {
    rooms: usize,
    boards: usize,
    placeable: usize,
    found_placeable: usize,
    found_other: usize,
    false_placements: usize,
    hole_errors_mm: Vec<f64>,
    /// Holes farther from the truth than 3 of their σ.
    beyond_3_sigma: usize,
    /// Why the placeable boards that were not placed were refused.
    missed: BTreeMap<String, usize>,
    /// Every refusal's reason (of any plane).
    refusals: BTreeMap<String, usize>,
}

impl Figures {
    fn found_percent(&self) -> f64 {
        100.0 * self.found_placeable as f64 / self.placeable.max(1) as f64
    }

    fn mean_error_mm(&self) -> f64 {
        self.hole_errors_mm.iter().sum::<f64>() / self.hole_errors_mm.len().max(1) as f64
    }

    fn worst_error_mm(&self) -> f64 {
        self.hole_errors_mm.iter().copied().fold(0.0, f64::max)
    }

    fn print(&self, name: &str) {
        println!(
            "{name}: {} rooms, {} boards, {} placeable, found {} ({:.1} %) + {} others, \
             false placements {}, hole error mean {:.2} mm worst {:.2} mm, holes beyond 3σ {}",
            self.rooms,
            self.boards,
            self.placeable,
            self.found_placeable,
            self.found_percent(),
            self.found_other,
            self.false_placements,
            self.mean_error_mm(),
            self.worst_error_mm(),
            self.beyond_3_sigma
        );
        println!("  placeable boards missed, by reason: {:?}", self.missed);
        println!("  refusals of any plane, by reason: {:?}", self.refusals);
    }
}

/// The refusal's kind (its variant name).
fn kind(reason: &impl std::fmt::Debug) -> String {
    let s = format!("{reason:?}");
    s.split([' ', '{', '(']).next().unwrap_or_default().to_owned()
}

/// Per-hole errors (m) of `found` against the truth board nearest its centre, when one is
/// within 0.3 m.
fn match_truth(found: &LidarBoard, truth: &[RandomBoard]) -> Option<(usize, Vec<f64>)> {
    let (i, t) = truth.iter().enumerate().min_by(|a, b| {
        let d = |t: &RandomBoard| (t.pose.translation - found.pose.translation).norm();
        d(a.1).total_cmp(&d(b.1))
    })?;
    if (t.pose.translation - found.pose.translation).norm() > 0.3 {
        return None;
    }
    Some((i, found.holes.iter().zip(&t.holes).map(|(h, th)| (h - th).norm()).collect()))
}

/// Detects the room's boards and adds the outcome to `f`.
fn score(room: &RandomRoom, name: &str, f: &mut Figures) {
    let mut detector = HoleDetector::new(&room.board, HoleConfig::default());
    let mut found = Vec::new();
    detector.detect(&room.cloud, &mut found);
    f.rooms += 1;
    let mut placed = vec![false; room.boards.len()];
    for board in &found {
        let Some((i, err)) = match_truth(board, &room.boards) else {
            f.false_placements += 1;
            println!("  {name} room {}: FALSE board at {:?}", room.seed, board.pose.translation);
            continue;
        };
        if err.iter().any(|&e| e > FALSE_HOLE_M) {
            f.false_placements += 1;
            let t = &room.boards[i];
            println!(
                "  {name} room {} board {i} ({:?}, {:.1} m, yaw {:.0}° pitch {:.0}° roll {:.0}°): \
                 FALSE placement, hole errors {:.0?} mm, lines truth {:?} seen {:?}",
                room.seed,
                room.layout,
                t.range_m,
                t.yaw_deg,
                t.pitch_deg,
                t.roll_deg,
                err.iter().map(|e| e * 1e3).collect::<Vec<_>>(),
                t.hole_scan_lines,
                board.hole_scan_lines
            );
            continue;
        }
        placed[i] = true;
        if room.boards[i].placeable() {
            f.found_placeable += 1;
        } else {
            f.found_other += 1;
        }
        for (e, s) in err.iter().zip(&board.hole_sigma_m) {
            f.hole_errors_mm.push(e * 1e3);
            f.beyond_3_sigma += usize::from(*e > 3.0 * s);
        }
    }
    for r in detector.refused() {
        *f.refusals.entry(kind(&r.reason)).or_default() += 1;
    }
    for (i, t) in room.boards.iter().enumerate() {
        f.boards += 1;
        if !t.placeable() {
            continue;
        }
        f.placeable += 1;
        if placed[i] {
            continue;
        }
        let centre = t.pose.translation;
        let refusal =
            detector.refused().iter().filter(|r| (r.centroid - centre).norm() < 0.5).min_by(
                |a, b| (a.centroid - centre).norm().total_cmp(&(b.centroid - centre).norm()),
            );
        let reason = refusal.map_or("no plane found".to_owned(), |r| kind(&r.reason));
        *f.missed.entry(reason.clone()).or_default() += 1;
        println!(
            "  {name} room {} board {i} ({:?}, {:.1} m, yaw {:.0}° pitch {:.0}° roll {:.0}°{}): \
             MISSED, truth lines {:?}, {} points: {}",
            room.seed,
            room.layout,
            t.range_m,
            t.yaw_deg,
            t.pitch_deg,
            t.roll_deg,
            if t.behind_another { ", behind another" } else { "" },
            t.hole_scan_lines,
            t.points,
            refusal.map_or(reason, |r| r.reason.to_string())
        );
    }
}

/// Runs `rooms` rooms per model; prints and returns the figures.
fn study(rooms: u64) -> Vec<(&'static str, Figures)> {
    MODELS
        .iter()
        .map(|&(name, model)| {
            let mut f = Figures::default();
            for seed in 1..=rooms {
                let room = random_room(seed, model, NOISE_M).expect("the simulator has the model");
                score(&room, name, &mut f);
            }
            f.print(name);
            (name, f)
        })
        .collect()
}

fn assert_targets(figures: &[(&str, Figures)]) {
    for (name, f) in figures {
        assert_eq!(f.false_placements, 0, "{name}: false placements");
        assert!(f.placeable >= 10, "{name}: too few placeable boards to judge ({})", f.placeable);
        assert!(f.found_percent() >= 98.0, "{name}: {:.1} % of placeable found", f.found_percent());
    }
    let (_, p64) = &figures[0];
    assert!(p64.mean_error_mm() <= 4.0, "Pandar64 mean hole error {:.2} mm", p64.mean_error_mm());
}

#[test]
#[ignore = "the detector misses and misplaces boards in these rooms until issue 14 is fixed"]
fn reduced_study_meets_the_targets() {
    assert_targets(&study(20));
}

#[test]
#[ignore = "the full study: 200 rooms per model, several minutes"]
fn full_study_meets_the_targets() {
    assert_targets(&study(200));
}

/// Issue 14's room: every placeable board placed within 4 mm, no board placed wrong.
#[test]
#[ignore = "fails until issue 14 is fixed"]
fn issue_room_places_every_placeable_board_right() {
    let room = issue_room(1, NOISE_M);
    let mut f = Figures::default();
    score(&room, "issue room", &mut f);
    f.print("issue room");
    assert!(f.placeable >= 3, "the issue's room has three placeable boards: {}", f.placeable);
    assert_eq!(f.false_placements, 0);
    assert_eq!(f.found_placeable, f.placeable);
    assert!(f.worst_error_mm() <= 6.0, "worst hole error {:.2} mm", f.worst_error_mm());
}
