//! Several `roomcal daemon --once` started together on one store (config/replay.toml with
//! its store moved to a scratch directory): one at a time writes the store, the others are
//! refused naming the holder's pid, and every accepted run has a generation of its own —
//! none lost, none reused (docs/daemon.md, "One writer").
#![cfg(all(unix, feature = "daemon"))]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use crate::common::scratch::Scratch;
use crate::common::{root, BIN};

/// config/replay.toml with its relative paths made absolute and its store in `dir/store`.
fn replay_config(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(root().join("config/replay.toml")).unwrap();
    let fixtures = root().join("fixtures");
    let mut out = String::new();
    for line in text.lines() {
        if line.starts_with("store = ") {
            out.push_str(&format!("store = {:?}\n", dir.join("store")));
        } else {
            out.push_str(&line.replace("../fixtures", fixtures.to_str().unwrap()));
            out.push('\n');
        }
    }
    let path = dir.join("replay.toml");
    std::fs::write(&path, out).unwrap();
    path
}

/// How one `--once` ended.
struct Ended {
    pid: u32,
    code: Option<i32>,
    stdout: String,
    stderr: String,
}

impl Ended {
    /// The generation its summary says is in force, when it accepted a run.
    fn accepted_generation(&self) -> Option<u32> {
        let line = self.stdout.lines().find(|l| l.contains("1 accepted"))?;
        let at = line.rfind("generation ")? + "generation ".len();
        line[at..].split_whitespace().next()?.parse().ok()
    }
}

/// Starts `n` `daemon --once` on `config` together and waits for all of them.
fn start_together(config: &Path, n: usize) -> Vec<Ended> {
    let children: Vec<_> = (0..n)
        .map(|_| {
            Command::new(BIN)
                .args(["daemon", "--once", "--config", config.to_str().unwrap()])
                .env("RUST_LOG", "warn")
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    children
        .into_iter()
        .map(|child| {
            let pid = child.id();
            let out = child.wait_with_output().unwrap();
            Ended {
                pid,
                code: out.status.code(),
                stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
                stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
            }
        })
        .collect()
}

/// Generation numbers of `STORE/history/gen-N.json`.
fn history(store: &Path) -> BTreeSet<u32> {
    std::fs::read_dir(store.join("history"))
        .unwrap()
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            name.strip_prefix("gen-")?.strip_suffix(".json")?.parse().ok()
        })
        .collect()
}

#[test]
fn six_once_runs_together_never_lose_or_reuse_a_generation() {
    let dir = Scratch::new("six-once");
    let config = replay_config(&dir);
    let store = dir.join("store");
    let mut claimed = Vec::new();
    for round in 1..=2 {
        let ended = start_together(&config, 6);
        let mut accepted = Vec::new();
        for e in &ended {
            match e.accepted_generation() {
                Some(g) => {
                    assert_eq!(e.code, Some(0), "{}{}", e.stdout, e.stderr);
                    accepted.push((e.pid, g));
                }
                None => {
                    // Refused: it says so, naming a process that held the store.
                    assert_eq!(e.code, Some(1), "round {round}: {}{}", e.stdout, e.stderr);
                    let named = accepted_pids(&ended).any(|pid| {
                        e.stderr.contains(&format!("another roomcal process (pid {pid})"))
                    });
                    assert!(named, "round {round}: not refused naming the holder: {}", e.stderr);
                }
            }
        }
        println!("round {round}: generations accepted {accepted:?}");
        assert!(!accepted.is_empty(), "round {round}: no run was accepted");
        claimed.extend(accepted.iter().map(|&(_, g)| g));
    }
    let distinct: BTreeSet<u32> = claimed.iter().copied().collect();
    assert_eq!(distinct.len(), claimed.len(), "a generation was claimed twice: {claimed:?}");
    let expected: BTreeSet<u32> = (1..=claimed.len() as u32).collect();
    assert_eq!(distinct, expected, "generations claimed {claimed:?}");
    assert_eq!(history(&store), expected, "history holds every accepted run, and only those");
    let current: serde_json::Value =
        serde_json::from_slice(&std::fs::read(store.join("current.json")).unwrap()).unwrap();
    assert_eq!(current["generation"], claimed.len());
}

/// The pids of the runs that accepted (the ones that held the store).
fn accepted_pids(ended: &[Ended]) -> impl Iterator<Item = u32> + '_ {
    ended.iter().filter(|e| e.accepted_generation().is_some()).map(|e| e.pid)
}
