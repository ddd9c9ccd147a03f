//! The board of OpenCalib's joint-calibration sample (../shared/data/holeboard-real) as
//! far as the LiDAR sees it, for the hole detector's real-frame test and bench.

use roomcal::target::BoardSpec;

/// 1.2 m square, four 0.11 m holes on a 0.6 m grid (its checkerboard does not matter here).
pub fn opencalib_board() -> BoardSpec {
    let mut holes = heapless::Vec::new();
    for h in [[-0.3, -0.3], [0.3, -0.3], [-0.3, 0.3], [0.3, 0.3]] {
        holes.push(h).expect("four holes fit");
    }
    BoardSpec {
        width: 1.2,
        height: 1.2,
        inner_corners: [2, 2],
        square: 0.05,
        hole_radius: 0.11,
        holes,
        count: 1,
        checker_offset: [0.0, 0.0],
    }
}

/// The sample's folder: `../shared/data/holeboard-real` from the repo root, or under
/// `ROOMCAL_SHARED` (a worktree elsewhere names the shared folder with it).
pub fn opencalib_data_dir() -> std::path::PathBuf {
    std::env::var_os("ROOMCAL_SHARED")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared"))
        .join("data/holeboard-real")
}
