//! Chaining boards across visits: which board of one visit is which board of another,
//! from the arrangement alone. Each visit's free-board calibration places its boards in
//! its own camera frame; the vehicle is parked a little differently every time, so the
//! visits differ by an unknown rigid motion. One board pair (and whether the symmetric
//! checkerboard was seen half-turned) fixes a hypothesis of that motion; the hypothesis
//! that brings most board centres onto each other wins, its matches label the boards,
//! and the motion is then refitted to every matched board (Kabsch over their outlines).
//! Boards no earlier visit saw become new room boards.

use crate::geometry::{se3::so3_exp, Se3, Vec3};
use crate::solve::init::kabsch_from_pairs;

/// Two board centres closer than this (m) under a visit-to-visit motion are one board.
/// A free-board calibration places boards 5 m away to a few centimetres (more when its
/// LiDAR gave nothing and depth rests on the focal length alone); boards stand more
/// than a board's width (1 m) apart.
pub const CHAIN_GATE_M: f64 = 0.35;

/// Where a visit's board sits in the room's list of boards.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChainedBoard {
    /// Index among the room's boards (visit 0's boards first, in its order).
    pub room_board: usize,
    /// The detection's frame is the room board's turned half a turn about its normal
    /// (the symmetric checkerboard read from the other corner).
    pub half_turned: bool,
}

/// The chained room: labels per visit, the room's boards and every visit's camera placed
/// in the reference (first visit's) camera frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Chain {
    /// `labels[v][i]`: visit `v`'s board `i`.
    pub labels: Vec<Vec<ChainedBoard>>,
    /// Room board → reference camera, as first placed.
    pub boards: Vec<Se3>,
    /// Visit camera → reference camera (identity for visit 0).
    pub visit_to_reference: Vec<Se3>,
}

/// Why the boards of a visit could not be chained.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChainError {
    /// Fewer than two of this visit's boards match boards of earlier visits.
    Unchained { visit: usize, matched: usize },
}

impl core::fmt::Display for ChainError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ChainError::Unchained { visit, matched } => write!(
                f,
                "visit {visit}: only {matched} of its boards match boards of the earlier visits \
                 (2 needed to place it in the room)"
            ),
        }
    }
}

impl std::error::Error for ChainError {}

/// Labels every board of every visit; `visits[v]` holds visit `v`'s board → camera poses.
pub fn chain_boards(visits: &[Vec<Se3>]) -> Result<Chain, ChainError> {
    let Some(first) = visits.first() else {
        return Ok(Chain {
            labels: Vec::new(),
            boards: Vec::new(),
            visit_to_reference: Vec::new(),
        });
    };
    let mut room: Vec<Se3> = first.clone();
    let mut labels = vec![(0..first.len())
        .map(|room_board| ChainedBoard { room_board, half_turned: false })
        .collect::<Vec<_>>()];
    let mut motions = vec![Se3::identity()];
    for (v, boards) in visits.iter().enumerate().skip(1) {
        let (hypothesis, matched) = best_motion(&room, boards);
        if matched < 2 {
            return Err(ChainError::Unchained { visit: v, matched });
        }
        let visit = label(&room, boards, &hypothesis);
        let motion = refit(&room, boards, &visit, &hypothesis);
        // Boards seen first here join the room where the refitted motion puts them.
        let mut visit_labels = Vec::with_capacity(boards.len());
        for (pose, found) in boards.iter().zip(visit) {
            visit_labels.push(match found {
                Some(label) => label,
                None => {
                    room.push(motion.compose(pose));
                    ChainedBoard { room_board: room.len() - 1, half_turned: false }
                }
            });
        }
        labels.push(visit_labels);
        motions.push(motion);
    }
    Ok(Chain { labels, boards: room, visit_to_reference: motions })
}

/// Half a turn about the board's normal (z): the symmetric checkerboard's other reading.
pub fn half_turn() -> Se3 {
    Se3 {
        rotation: so3_exp(&Vec3::new(0.0, 0.0, core::f64::consts::PI)),
        translation: Vec3::zeros(),
    }
}

/// Each board's room label under `motion` (`None`: no room board within the gate).
fn label(room: &[Se3], boards: &[Se3], motion: &Se3) -> Vec<Option<ChainedBoard>> {
    let mut taken = vec![false; room.len()];
    boards
        .iter()
        .map(|pose| {
            let placed = motion.compose(pose);
            nearest(room, &placed.translation, &taken).map(|j| {
                taken[j] = true;
                ChainedBoard { room_board: j, half_turned: is_half_turn(&room[j], &placed) }
            })
        })
        .collect()
}

/// The visit → reference motion fitted to the outlines of every matched board (the
/// hypothesis rests on one board's pose; all of them are better).
fn refit(room: &[Se3], boards: &[Se3], labels: &[Option<ChainedBoard>], hypothesis: &Se3) -> Se3 {
    let outline = [
        Vec3::new(-0.5, -0.4, 0.0),
        Vec3::new(0.5, -0.4, 0.0),
        Vec3::new(0.5, 0.4, 0.0),
        Vec3::new(-0.5, 0.4, 0.0),
        Vec3::zeros(),
    ];
    let pairs = boards.iter().zip(labels).filter_map(|(pose, l)| l.map(|l| (pose, l))).flat_map(
        move |(pose, l)| {
            let seen = if l.half_turned { pose.compose(&half_turn()) } else { *pose };
            let target = room[l.room_board];
            outline.into_iter().map(move |p| (seen.act(&p), target.act(&p)))
        },
    );
    kabsch_from_pairs(pairs).unwrap_or(*hypothesis)
}

/// The visit → reference camera motion under which most of `boards`' centres land on
/// `room`'s, and how many do.
fn best_motion(room: &[Se3], boards: &[Se3]) -> (Se3, usize) {
    let mut best = (Se3::identity(), 0usize, f64::INFINITY);
    for reference in room {
        for seen in boards {
            for turn in [Se3::identity(), half_turn()] {
                let motion = reference.compose(&turn).compose(&seen.inverse());
                let (count, spread) = agreement(room, boards, &motion);
                if count > best.1 || (count == best.1 && spread < best.2) {
                    best = (motion, count, spread);
                }
            }
        }
    }
    (best.0, best.1)
}

/// Board centres that land within the gate of a room board, and their summed distance.
fn agreement(room: &[Se3], boards: &[Se3], motion: &Se3) -> (usize, f64) {
    let mut taken = vec![false; room.len()];
    let (mut count, mut spread) = (0, 0.0);
    for pose in boards {
        let centre = motion.act(&pose.translation);
        if let Some(j) = nearest(room, &centre, &taken) {
            taken[j] = true;
            count += 1;
            spread += (room[j].translation - centre).norm();
        }
    }
    (count, spread)
}

/// The nearest room board not yet taken within the gate.
fn nearest(room: &[Se3], centre: &Vec3, taken: &[bool]) -> Option<usize> {
    (0..room.len())
        .filter(|&j| !taken[j])
        .map(|j| (j, (room[j].translation - centre).norm()))
        .filter(|&(_, d)| d <= CHAIN_GATE_M)
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(j, _)| j)
}

/// Whether `placed`'s frame is `room`'s turned by about half a turn (nearer π than 0).
fn is_half_turn(room: &Se3, placed: &Se3) -> bool {
    let relative = room.rotation.transpose() * placed.rotation;
    relative.trace() < 1.0
}
