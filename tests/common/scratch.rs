//! A test's scratch directory in the system temp dir, removed when the test is done.
//!
//! `Scratch::new("cli-summary")` makes a fresh, empty `<temp>/roomcal-cli-summary-<pid>`
//! (a stale one of that name is removed first) and removes it again when the guard is
//! dropped, so passing tests leave nothing behind in `/tmp`. When the guard is dropped
//! while its thread panics (a failed assert), the directory is kept and its path printed
//! ("kept for inspection: …") so the failing run's files can be read. Bind the guard for the
//! whole test (`let dir = Scratch::new(…)`, not `let _ = …`), and bind it before anything
//! that writes into it, such as a spawned daemon or child process: locals drop in reverse
//! order, so the directory then outlives them. Names carry the test's name so parallel
//! tests in one process never share a directory.
//!
//! Use with `use crate::common::scratch::Scratch;`.
#![allow(dead_code)]

use std::ops::Deref;
use std::path::{Path, PathBuf};

/// A scratch directory that lives as long as this guard (see the module doc).
#[derive(Debug)]
pub struct Scratch {
    path: PathBuf,
}

impl Scratch {
    /// A fresh, empty `<temp>/roomcal-<name>-<pid>`.
    pub fn new(name: &str) -> Self {
        let path = std::env::temp_dir().join(format!("roomcal-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&path);
        std::fs::create_dir_all(&path)
            .unwrap_or_else(|e| panic!("cannot create {}: {e}", path.display()));
        Scratch { path }
    }

    /// The directory.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// A path inside the directory.
    pub fn join(&self, path: impl AsRef<Path>) -> PathBuf {
        self.path.join(path)
    }
}

impl Deref for Scratch {
    type Target = Path;

    fn deref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.path
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("kept for inspection: {}", self.path.display());
        } else if let Err(e) = std::fs::remove_dir_all(&self.path) {
            if e.kind() != std::io::ErrorKind::NotFound {
                eprintln!("could not remove {}: {e}", self.path.display());
            }
        }
    }
}
