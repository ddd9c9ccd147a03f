//! Structures that are no board (`roomcal::sim::structures`): a post and two patches whose
//! gaps fall on the board's hole lattice, fences, railings, shelving, window mullions and
//! a wall with a doorway, each swept alone in an empty room by every simulated LiDAR model
//! at several places, for three boards (the design room's, OpenCalib's 1.2 m board with
//! 0.11 m holes on a 0.6 m square, and the study's 1.4 × 1.1 m board). No board may be
//! placed on any of them.
//!
//! `ROOMCAL_STRUCTURES_SITES=9 cargo test --release --test it holes_structures::` sweeps
//! more places per structure and model (one by default).

use roomcal::detect::holes::{HoleConfig, HoleDetector, LidarBoard};
use roomcal::geometry::Se3;
use roomcal::lidar::Model;
use roomcal::sim::random_room::{issue_board, opencalib_board};
use roomcal::sim::raycast;
use roomcal::sim::rng::Rng;
use roomcal::sim::structures::{self, Site, Structure};
use roomcal::sim::world::World;
use roomcal::target::BoardSpec;

const MODELS: [Model; 3] = [Model::Pandar64, Model::Pandar40p, Model::Vlp32c];

/// The boards a structure is judged against: whose hole lattice it copies, whose size the
/// detector looks for.
fn boards() -> [(&'static str, BoardSpec); 3] {
    let design =
        roomcal::room::load(std::path::Path::new("config/room.toml")).expect("the design room");
    [("design", design.board), ("OpenCalib", opencalib_board()), ("study", issue_board())]
}

/// The `k`-th place a structure is tried at: 3–8 m away, up to 40° to either side.
fn site(k: usize) -> Site {
    let range = 3.0 + (k as f64 * 2.3) % 5.0;
    let azimuth = (((k as f64 * 37.0) % 80.0) - 40.0).to_radians();
    Site { x: range * azimuth.cos(), y: range * azimuth.sin(), floor_z: -1.6 }
}

/// The boards `model` finds in an empty room (walls 12 m ahead and 8 m to the sides, the
/// world's two crates) holding `kind` alone at `site`.
fn placed_on(
    kind: Structure,
    spec: &BoardSpec,
    model: Model,
    site: Site,
    seed: u64,
) -> Vec<LidarBoard> {
    let mut rng = Rng::new(seed);
    let mut world: World =
        World::new(spec, Vec::<Se3>::new(), &mut rng.fork(1)).with_shell(-1.6, 1.8, 12.0, 8.0);
    structures::add(&mut world, kind, spec, site, &mut rng.fork(2));
    let cal = raycast::calibration(model).expect("a simulated model");
    let cloud = raycast::sweep(&world, &cal, 0.02, 0, &mut rng.fork(3)).points;
    let mut detector = HoleDetector::new(spec, HoleConfig::default());
    let mut found = Vec::new();
    detector.detect(&cloud, &mut found);
    found
}

/// Every model and board, at `sites` places each: no board placed.
fn nothing_placed_on(kind: Structure, sites: usize) {
    let mut false_boards = Vec::new();
    for (b, (name, spec)) in boards().iter().enumerate() {
        for (m, &model) in MODELS.iter().enumerate() {
            for k in 0..sites {
                let at = site(b * 7 + m * 3 + k);
                let found = placed_on(kind, spec, model, at, (b * 100 + m * 10 + k) as u64);
                for board in found {
                    false_boards.push(format!(
                        "{model:?}, {name} board, structure at ({:.1}, {:.1}): board at {:.2?}",
                        at.x,
                        at.y,
                        board.pose.translation.as_slice()
                    ));
                }
            }
        }
    }
    assert!(
        false_boards.is_empty(),
        "{kind:?}: {} false board(s):\n{}",
        false_boards.len(),
        false_boards.join("\n")
    );
}

/// The sites per structure: `ROOMCAL_STRUCTURES_SITES`, one by default.
fn sites() -> usize {
    std::env::var("ROOMCAL_STRUCTURES_SITES").ok().and_then(|v| v.parse().ok()).unwrap_or(1)
}

#[test]
fn a_post_and_two_patches_on_the_hole_lattice_is_no_board() {
    nothing_placed_on(Structure::PostAndPatches, sites());
}

#[test]
fn a_fence_is_no_board() {
    nothing_placed_on(Structure::Fence, sites());
}

#[test]
fn a_railing_is_no_board() {
    nothing_placed_on(Structure::Railing, sites());
}

#[test]
fn shelving_is_no_board() {
    nothing_placed_on(Structure::Shelving, sites());
}

#[test]
fn window_mullions_are_no_board() {
    nothing_placed_on(Structure::Window, sites());
}

#[test]
fn a_wall_with_a_doorway_is_no_board() {
    nothing_placed_on(Structure::Doorway, sites());
}
