//! The UDS SecurityAccess lockout against a real `roomcal daemon` process: three wrong keys
//! over socketcand lock it, the process is killed with SIGKILL (no chance to save anything
//! then), and the restarted daemon still refuses a seed (requiredTimeDelayNotExpired):
//! the lockout is in STORE/security.json before the third refusal is sent. tests/it/daemon.rs
//! covers the graceful stop in process. Also against real daemon processes: a second daemon on
//! one store, a secret others can read, a full disk while current.json is written (nothing
//! stored, nothing revived at the next start), a file or a dangling link as the store, and
//! SIGTERM in the middle of a run (abandoned, said so, nothing stored).
#![cfg(all(unix, feature = "daemon"))]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use roomcal::service::client::{ClientError, UdsClient};
use roomcal::service::socketcand::SocketcandClient;
use roomcal::service::uds::Session;

use crate::common::fixture;
use crate::common::scratch::Scratch;

/// A replay daemon (manual trigger: no run starts by itself) with its service on `port`.
fn config(dir: &Path, port: u16) -> PathBuf {
    crate::common::service_daemon_config(dir, port, b"kill test secret\n")
}

/// A daemon at INFO whose stderr lines arrive on the receiver as it writes them.
fn spawn_logging(config: &Path) -> (Daemon, std::sync::mpsc::Receiver<String>) {
    use std::io::{BufRead, BufReader};
    let mut daemon = Daemon(
        Command::new(crate::common::BIN)
            .args(["daemon", "--config", config.to_str().unwrap()])
            .env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let (lines, got) = std::sync::mpsc::channel();
    let stderr = daemon.0.stderr.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = lines.send(line);
        }
    });
    (daemon, got)
}

fn spawn(config: &Path) -> Daemon {
    Daemon(
        Command::new(crate::common::BIN)
            .args(["daemon", "--config", config.to_str().unwrap()])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    )
}

/// A spawned daemon, killed when dropped: a failed assert must not leave it running.
struct Daemon(Child);

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

async fn connect(port: u16) -> UdsClient<SocketcandClient> {
    for _ in 0..100 {
        if let Ok(t) = SocketcandClient::connect(&format!("127.0.0.1:{port}"), "can0").await {
            return UdsClient::with_defaults(t);
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("no daemon listening on 127.0.0.1:{port} after 10 s");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lockout_survives_sigkill_of_the_daemon() {
    let dir = Scratch::new("lockout-kill");
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let config = config(&dir, port);

    let mut daemon = spawn(&config);
    let mut c = connect(port).await;
    c.session(Session::Extended).await.unwrap();
    let mut nrcs = Vec::new();
    for _ in 0..3 {
        match c.unlock(b"wrong").await {
            Err(ClientError::Negative { service: 0x27, nrc }) => nrcs.push(nrc),
            other => panic!("expected a negative response, got {other:?}"),
        }
    }
    // invalidKey, invalidKey, exceededNumberOfAttempts.
    assert_eq!(nrcs, [0x35, 0x35, 0x36]);
    daemon.0.kill().unwrap(); // SIGKILL
    let status = daemon.0.wait().unwrap();
    assert_eq!(std::os::unix::process::ExitStatusExt::signal(&status), Some(9));
    drop(c);
    let record = std::fs::read_to_string(dir.join("store/security.json")).unwrap();
    println!("security.json after SIGKILL: {record}");

    let daemon = spawn(&config);
    let mut c = connect(port).await;
    c.session(Session::Extended).await.unwrap();
    let answer = c.request(&[0x27, 0x01]).await;
    drop(daemon);
    match answer {
        Err(ClientError::Negative { service: 0x27, nrc: 0x37 }) => {}
        other => panic!("expected requiredTimeDelayNotExpired after SIGKILL, got {other:?}"),
    }
}

/// The config of [`config`] with the service moved from `port` to `other`: a second daemon
/// on the same store.
fn second_config(dir: &Path, config: &Path, port: u16, other: u16) -> PathBuf {
    let text = std::fs::read_to_string(config).unwrap();
    let text = text.replace(&format!("127.0.0.1:{port}\""), &format!("127.0.0.1:{other}\""));
    let path = dir.join("roomcal-2.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_daemon_on_one_store_is_refused_naming_the_first() {
    let dir = Scratch::new("store-lock");
    let port = free_port();
    let config = config(&dir, port);
    let first = spawn(&config);
    // Serving means the first holds the store's lock (taken before any task starts).
    drop(connect(port).await);
    let second = second_config(&dir, &config, port, free_port());
    let out = Command::new(crate::common::BIN)
        .args(["daemon", "--once", "--config", second.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "the second daemon ran: {stderr}");
    let pid = format!("pid {}", first.0.id());
    assert!(stderr.contains(&pid) && stderr.contains("one process at a time"), "{stderr}");
    drop(first);
}

#[test]
fn a_secret_others_can_read_leaves_the_service_off_and_says_why() {
    use std::os::unix::fs::PermissionsExt;
    let dir = Scratch::new("secret-mode");
    let port = free_port();
    let config = config(&dir, port);
    std::fs::set_permissions(dir.join("secret"), std::fs::Permissions::from_mode(0o644)).unwrap();
    let (daemon, got) = spawn_logging(&config);
    let deadline = std::time::Instant::now() + Duration::from_secs(20);
    let said = loop {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        match got.recv_timeout(left) {
            Ok(line) if line.contains("service disabled") => break line,
            Ok(_) => {}
            Err(_) => panic!("no `service disabled` line within 20 s"),
        }
    };
    assert!(said.contains("mode 0644") && said.contains("chmod 600"), "{said}");
    assert!(std::net::TcpStream::connect(("127.0.0.1", port)).is_err(), "the service listens");
    drop(daemon);
}

/// A replay daemon in `dir` (the six-board fixture, PCD cloud) with its store at `store`:
/// it calibrates by itself (auto trigger) once the scene is still; `extra` goes into its
/// `[trigger]` table.
fn auto_config(dir: &Path, store: &Path, extra: &str) -> PathBuf {
    let text = format!(
        "room = {:?}\nstore = {:?}\n[camera]\nsource = \"replay:{}\"\n[lidar]\nsource = \"replay:{}\"\n\
         [trigger]\nmode = \"auto\"\nsettle_s = 1.0\nsweeps = 1\nmin_boards = 6\n{extra}",
        fixture("six-boards-pandar64/room.toml"),
        store,
        fixture("six-boards-pandar64/image.png").display(),
        fixture("six-boards-pandar64/cloud.pcd").display(),
    );
    let path = dir.join("auto.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// Runs `daemon --once` on `config` to the end: exit code, stdout + stderr.
fn once(config: &Path) -> (Option<i32>, String) {
    let out = Command::new(crate::common::BIN)
        .args(["daemon", "--once", "--config", config.to_str().unwrap()])
        .env("RUST_LOG", "info")
        .output()
        .unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    (out.status.code(), text)
}

/// `gen-N.json` names in `store/history`.
fn history_names(store: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(store.join("history"))
        .map(|d| d.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    names.retain(|n| n.starts_with("gen-"));
    names.sort();
    names
}

#[test]
fn a_full_disk_at_current_json_stores_nothing_and_the_next_start_does_not_revive_it() {
    let dir = Scratch::new("full-current");
    let store = dir.join("store");
    std::fs::create_dir(&store).unwrap();
    let config = auto_config(&dir, &store, "");
    let child = Command::new(crate::common::BIN)
        .args(["daemon", "--once", "--config", config.to_str().unwrap()])
        .env("RUST_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The store writes current.json through `.current.json.tmp-PID-N`; those names lead to
    // /dev/full, so that write (and only that one) fails with ENOSPC, as on a full disk.
    // The daemon writes nothing before its run, seconds after it starts.
    for n in 0..64 {
        let tmp = store.join(format!(".current.json.tmp-{}-{n}", child.id()));
        std::os::unix::fs::symlink("/dev/full", tmp).unwrap();
    }
    let out = child.wait_with_output().unwrap();
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    println!("{text}");
    assert_eq!(out.status.code(), Some(1), "{text}");
    assert!(text.contains("No space left on device"), "not the full disk: {text}");
    assert!(text.contains("current.json") && text.contains("not stored"), "{text}");
    assert!(!store.join("current.json").exists());
    assert_eq!(history_names(&store), Vec::<String>::new(), "a run not stored is in history");

    // The next start: nothing revived; its own run is the first generation.
    let (code, text) = once(&config);
    println!("{text}");
    assert_eq!(code, Some(0), "{text}");
    assert!(!text.contains("completed and in force"), "the unstored run was revived: {text}");
    assert!(text.contains("1 accepted") && text.contains("generation 1 in force"), "{text}");
    assert_eq!(history_names(&store), ["gen-000001.json"]);
}

#[test]
fn a_dangling_link_or_a_file_as_the_store_is_named_and_explained() {
    let dir = Scratch::new("store-path");
    let link = dir.join("store-link");
    let missing = dir.join("unmounted/roomcal");
    std::os::unix::fs::symlink(&missing, &link).unwrap();
    let (code, text) = once(&auto_config(&dir, &link, ""));
    assert_eq!(code, Some(1), "{text}");
    let line = text.lines().find(|l| l.contains("roomcal:")).unwrap_or(&text);
    assert!(
        line.contains(&link.display().to_string())
            && line.contains(&format!(
                "a symbolic link to {}, which does not exist",
                missing.display()
            )),
        "{text}"
    );
    assert!(!text.contains("os error 17"), "{text}");
    assert!(!missing.exists(), "the link's target was created");

    let file = dir.join("store-file");
    std::fs::write(&file, b"not a store").unwrap();
    let (code, text) = once(&auto_config(&dir, &file, ""));
    assert_eq!(code, Some(1), "{text}");
    assert!(
        text.contains(&format!("store {}: is a file, not a directory", file.display())),
        "{text}"
    );
}

#[test]
fn sigterm_during_a_run_says_it_was_abandoned_and_stores_nothing() {
    let dir = Scratch::new("sigterm-run");
    let store = dir.join("store");
    // 100 frames at 10 fps: the capture lasts 10 s, so the stop lands in the middle of it.
    let config = auto_config(&dir, &store, "frames = 100\ncapture_timeout_s = 60.0\n");
    let (mut daemon, got) = spawn_logging(&config);
    // Seeing the room takes a debug build seconds, more on a loaded machine.
    let deadline = std::time::Instant::now() + Duration::from_secs(120);
    let mut before = Vec::new();
    loop {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        match got.recv_timeout(left) {
            Ok(line) if line.contains("capturing 100 frames") => break,
            Ok(line) => before.push(line),
            Err(_) => panic!("no run started within 120 s: {}", before.join("\n")),
        }
    }
    let pid = daemon.0.id().to_string();
    assert!(Command::new("kill").args(["-TERM", &pid]).status().unwrap().success());
    let status = daemon.0.wait().unwrap();
    let rest: Vec<String> = got.iter().collect();
    let text = rest.join("\n");
    println!("{text}");
    assert_eq!(status.code(), Some(0), "a graceful stop: {text}");
    let said = rest.iter().find(|l| l.contains("abandoned")).unwrap_or_else(|| {
        panic!("no line says the run was abandoned: {text}");
    });
    assert!(said.contains("WARN") && said.contains("nothing of it was stored"), "{said}");
    assert!(!store.join("current.json").exists(), "{text}");
    assert_eq!(history_names(&store), Vec::<String>::new());
    let reopened = roomcal::store::Store::open(&store, 4).unwrap();
    assert_eq!(reopened.current().unwrap(), None, "the store is valid and holds nothing");
}
