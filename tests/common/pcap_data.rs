//! Where the shared real captures are (`../shared/data/pcap` from the repo root; a worktree
//! elsewhere names the shared folder with `ROOMCAL_SHARED`), and finding files in them.

use std::path::{Path, PathBuf};

/// `../shared/data/pcap/FOLDER`, or `None` (after saying so) when it is absent.
pub fn data_dir(folder: &str) -> Option<PathBuf> {
    let shared = std::env::var_os("ROOMCAL_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared"));
    let dir = shared.join("data/pcap").join(folder);
    if dir.is_dir() {
        Some(dir)
    } else {
        crate::common::skipped(format_args!("{} is absent", dir.display()));
        None
    }
}

/// The one file of `dir` whose name ends in `.EXT` (any, if several).
pub fn file_with(dir: &Path, ext: &str) -> PathBuf {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == ext))
        .unwrap_or_else(|| panic!("no .{ext} in {}", dir.display()))
}
