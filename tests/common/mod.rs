//! Helpers shared by the test crates (`tests/it`, `tests/alloc`): each crate declares
//! `#[path = "../common/mod.rs"] mod common;` once and its modules use `crate::common::…`.
#![allow(dead_code)]

pub mod band_room;
pub mod gauss;
pub mod impair;
pub mod md5;
pub mod opencalib;
pub mod pcap_data;
pub mod png;
pub mod render;
pub mod results;
pub mod rig_scene;
pub mod scratch;
pub mod solve_common;
pub mod stack;
pub mod truth;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The `roomcal` binary of this build.
pub const BIN: &str = env!("CARGO_BIN_EXE_roomcal");

/// Runs `roomcal ARGS` to the end; returns its exit code (-1 when a signal ended it), its
/// stdout and its stderr.
pub fn roomcal<S: AsRef<OsStr>>(args: &[S]) -> (i32, String, String) {
    let out = Command::new(BIN).args(args).output().expect("roomcal runs");
    let text = |bytes: &[u8]| String::from_utf8_lossy(bytes).into_owned();
    (out.status.code().unwrap_or(-1), text(&out.stdout), text(&out.stderr))
}

/// Says that a test skipped its work, and why, where `cargo test` shows it: written to the
/// process's stderr directly, past the harness's capture of `println!`/`eprintln!` (which
/// would hide it behind a passing test). The test thread's name is the test's.
pub fn skipped(why: impl std::fmt::Display) {
    use std::io::Write;
    let thread = std::thread::current();
    let test = thread.name().unwrap_or("a test");
    let _ = writeln!(std::io::stderr().lock(), "SKIPPED {test}: {why}");
}

/// A fixture file or folder: `fixtures/PATH` in the repository, e.g.
/// `fixture("six-boards-pandar64/cloud.pcd")`.
pub fn fixture(path: &str) -> PathBuf {
    root().join("fixtures").join(path)
}

/// The repository (the crate's manifest folder).
pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Writes a vehicle secret as a vehicle holds it: readable by its owner only (mode 0600; the
/// daemon refuses a secret group or others can read).
pub fn write_secret(path: &Path, secret: &[u8]) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::write(path, secret).unwrap();
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o600)).unwrap();
}

/// A replay daemon's configuration in `dir` (the six-board fixture, manual trigger: no run
/// starts by itself) with its service on socketcand `127.0.0.1:port` and a secret of
/// `secret` in `dir/secret`; the store is `dir/store`. Returns the file's path.
pub fn service_daemon_config(dir: &Path, port: u16, secret: &[u8]) -> PathBuf {
    write_secret(&dir.join("secret"), secret);
    let text = format!(
        "room = {:?}\nstore = {:?}\n[camera]\nsource = \"replay:{}\"\n[lidar]\nsource = \"replay:{}\"\n\
         [trigger]\nmode = \"manual\"\nsweeps = 1\n[service]\ntransport = \"socketcand:127.0.0.1:{port}\"\n\
         secret_file = {:?}\n",
        fixture("six-boards-pandar64/room.toml"),
        dir.join("store"),
        fixture("six-boards-pandar64/image.png").display(),
        fixture("six-boards-pandar64/cloud.pcd").display(),
        dir.join("secret"),
    );
    let path = dir.join("roomcal.toml");
    std::fs::write(&path, text).unwrap();
    path
}
