//! Board identification in a surveyed room: which surveyed board each camera board of a
//! frame is, from the arrangement alone. Every pairing of one seen board with one
//! surveyed board (and, on a half-turn symmetric board, either of its two orientations)
//! proposes a room→camera pose; the proposal is scored by how many of the other seen
//! boards then land on a surveyed board (one-to-one, within a position and angle gate).
//! The assignment most boards agree on wins — unless a *different* assignment explains
//! as many boards: then the evidence is ambiguous and identification refuses.
//!
//! Missing boards cost nothing (only seen boards are matched), and a vehicle parked off
//! the nominal spot only changes the proposed pose, never the score.

use crate::geometry::se3::so3_exp;
use crate::geometry::{Se3, Vec3};
use crate::solve::init::kabsch_from_pairs;
use crate::target::BoardSpec;

/// A seen board lands on a surveyed one when their centres are this close (m)…
pub const GATE_M: f64 = 0.25;
/// …and their orientations this close (deg). Corner-only poses with start intrinsics
/// are good to a few cm and about a degree; boards stand about a metre apart.
pub const GATE_DEG: f64 = 8.0;

/// Which surveyed board a seen board is, and whether its corners come half-turned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity {
    pub board: usize,
    /// The detector's corner order is the model's turned by 180° about the board normal.
    pub half_turned: bool,
}

/// Why identification refused.
#[derive(Clone, Debug, PartialEq)]
pub enum IdentifyError {
    /// No seen board to identify.
    NothingSeen,
    /// Fewer than two seen boards agree on any room pose.
    TooFewAgree { best: usize, seen: usize },
    /// Two different assignments explain the same number of boards.
    Ambiguous { explained: usize },
}

impl core::fmt::Display for IdentifyError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            IdentifyError::NothingSeen => write!(f, "no board was seen to identify"),
            IdentifyError::TooFewAgree { best, seen } => write!(
                f,
                "the seen boards do not match the survey's arrangement: at most {best} of {seen} agree on one parking pose"
            ),
            IdentifyError::Ambiguous { explained } => write!(
                f,
                "board identification is ambiguous: two different assignments each explain {explained} boards"
            ),
        }
    }
}

/// Identifies every seen board (`seen[i]`: board → camera from its corners) against the
/// surveyed boards (board → room). Returns per seen board its identity (`None`: matches
/// no surveyed board under the winning pose) and the room → camera pose they agree on
/// (Kabsch over the matched boards' corners of the outline).
pub fn identify(
    spec: &BoardSpec,
    surveyed: &[Se3],
    seen: &[Se3],
) -> Result<(Vec<Option<Identity>>, Se3), IdentifyError> {
    if seen.is_empty() {
        return Err(IdentifyError::NothingSeen);
    }
    let turns: &[bool] = if half_turn_symmetric(spec) { &[false, true] } else { &[false] };
    // Every hypothesis's outcome: boards explained, their error, the assignment.
    let mut outcomes: Vec<(usize, f64, Vec<Option<Identity>>)> = Vec::new();
    for pose in seen {
        for in_room in surveyed {
            for &turned in turns {
                let room_to_camera = oriented(pose, turned).compose(&in_room.inverse());
                outcomes.push(explain(&room_to_camera, surveyed, seen, turns));
            }
        }
    }
    let (count, _, assignment) = outcomes
        .iter()
        .max_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)))
        .cloned()
        .ok_or(IdentifyError::NothingSeen)?;
    if count < 2 {
        return Err(IdentifyError::TooFewAgree { best: count, seen: seen.len() });
    }
    if outcomes.iter().any(|(c, _, a)| *c == count && *a != assignment) {
        return Err(IdentifyError::Ambiguous { explained: count });
    }
    let room_to_camera = agreed_pose(spec, surveyed, seen, &assignment)
        .ok_or(IdentifyError::TooFewAgree { best: count, seen: seen.len() })?;
    Ok((assignment, room_to_camera))
}

/// Whether the board looks the same turned by 180° about its normal: checker centred,
/// square colours that map onto themselves, holes that map onto holes.
pub fn half_turn_symmetric(spec: &BoardSpec) -> bool {
    let (cols, rows) = (spec.inner_corners[0], spec.inner_corners[1]);
    let centred = spec.checker_offset.iter().all(|v| v.abs() < 1e-9);
    let colours = (cols + rows) % 2 == 0;
    let holes = spec
        .holes
        .iter()
        .all(|[x, y]| spec.holes.iter().any(|[u, v]| (u + x).abs() < 1e-6 && (v + y).abs() < 1e-6));
    centred && colours && holes
}

/// The pose of the board model whose corners the detector reported: turned by 180°
/// about z when the detector's order is the model's half-turned.
pub fn oriented(pose: &Se3, half_turned: bool) -> Se3 {
    if half_turned {
        pose.compose(&Se3 {
            rotation: so3_exp(&Vec3::new(0.0, 0.0, core::f64::consts::PI)),
            translation: Vec3::zeros(),
        })
    } else {
        *pose
    }
}

/// Under `room_to_camera`, the seen boards that land on a surveyed board (greedy,
/// closest first, one-to-one): how many, their summed normalised error, the assignment.
fn explain(
    room_to_camera: &Se3,
    surveyed: &[Se3],
    seen: &[Se3],
    turns: &[bool],
) -> (usize, f64, Vec<Option<Identity>>) {
    let mut candidates: Vec<(f64, usize, Identity)> = Vec::new();
    for (i, pose) in seen.iter().enumerate() {
        for (k, in_room) in surveyed.iter().enumerate() {
            let expected = room_to_camera.compose(in_room);
            for &turned in turns {
                let got = oriented(pose, turned);
                let shift = (got.translation - expected.translation).norm();
                let angle = rotation_angle_deg(&got, &expected);
                if shift <= GATE_M && angle <= GATE_DEG {
                    let error = shift / GATE_M + angle / GATE_DEG;
                    candidates.push((error, i, Identity { board: k, half_turned: turned }));
                }
            }
        }
    }
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut assignment = vec![None; seen.len()];
    let mut taken = vec![false; surveyed.len()];
    let (mut count, mut total) = (0, 0.0);
    for (error, i, id) in candidates {
        if assignment[i].is_none() && !taken[id.board] {
            assignment[i] = Some(id);
            taken[id.board] = true;
            count += 1;
            total += error;
        }
    }
    (count, total, assignment)
}

fn rotation_angle_deg(a: &Se3, b: &Se3) -> f64 {
    let r = a.rotation.transpose() * b.rotation;
    ((r.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
}

/// Room → camera by Kabsch over the outline corners of every identified board.
fn agreed_pose(
    spec: &BoardSpec,
    surveyed: &[Se3],
    seen: &[Se3],
    assignment: &[Option<Identity>],
) -> Option<Se3> {
    let (w, h) = (spec.width / 2.0, spec.height / 2.0);
    let outline = [
        Vec3::new(-w, -h, 0.0),
        Vec3::new(w, -h, 0.0),
        Vec3::new(w, h, 0.0),
        Vec3::new(-w, h, 0.0),
    ];
    let pairs =
        seen.iter().zip(assignment).filter_map(|(pose, id)| id.map(|id| (pose, id))).flat_map(
            |(pose, id)| {
                let camera = oriented(pose, id.half_turned);
                let room = surveyed[id.board];
                outline.iter().map(move |p| (room.act(p), camera.act(p)))
            },
        );
    kabsch_from_pairs(pairs).ok()
}
