//! Store: commit, history bound, rejected runs, corruption fallback, rollback, a
//! power-loss test (a child process writing generations, killed with SIGKILL at random
//! instants), and the hostile cases (docs/daemon.md "The store"): temp files left by kills and full disks,
//! generations reused or skipped, invalid records in force, restores logged before failing.

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use roomcal::geometry::CameraModel;
use roomcal::result::{
    CalibrationResult, CameraResult, Extrinsic, Quality, RigResult, Status, Uncertainty,
};
use roomcal::store::{crc32, decode, encode, Store};

use crate::common::scratch::Scratch;

/// A result whose fx encodes `tag`, so a record's content can be checked against its
/// generation.
/// A one-pair room\'s result (no sensors), as the store and the daemon take it.
fn result(tag: f64, status: Status) -> RigResult {
    RigResult::from(CalibrationResult {
        status,
        reason: (status == Status::Rejected).then(|| "corner RMS too high".to_string()),
        camera: CameraResult {
            model: CameraModel::PinholeRadtan,
            width: 1920,
            height: 1200,
            fx: 1000.0 + tag,
            fy: 1000.5 + tag,
            cx: 960.25,
            cy: 600.125,
            distortion: vec![-0.25, 0.0625, 0.001, -0.0005, 0.1 / 3.0],
        },
        lidar_to_camera: Some(Extrinsic {
            rotation: [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]],
            translation: [0.05, 0.42, -0.28],
        }),
        uncertainty: Uncertainty::default(),
        quality: Quality { corner_rms_px: 0.2, hole_rms_px: 0.7, boards: 6 },
        boards: vec![],
        camera_in_room: None,
        projection_uncertainty: None,
    })
}

#[test]
fn a_one_pair_record_holds_the_result_file_and_the_bookkeeping_alone() {
    let dir = Scratch::new("one-pair-record");
    let store = Store::open(dir.path(), 3).unwrap();
    let run = result(1.0, Status::Accepted);
    store.commit(&run, 1_700_000_000).unwrap();
    let mut v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("current.json")).unwrap()).unwrap();
    let fields = v.as_object_mut().unwrap();
    for bookkeeping in ["generation", "time", "crc32"] {
        assert!(fields.remove(bookkeeping).is_some(), "{bookkeeping} written");
    }
    // No empty rig members: the record is the one-pair result file, key for key.
    assert_eq!(v, serde_json::to_value(&run.pair).unwrap());
    assert_eq!(serde_json::to_string(&run).unwrap(), serde_json::to_string(&run.pair).unwrap());
    assert!(store.current().unwrap().unwrap().rig().is_none(), "not a rig's record");
    // A rig's loader names what the one-pair file lacks.
    let path = dir.join("current.json");
    let message = roomcal::result::load_rig(&path).unwrap_err().to_string();
    assert!(message.contains("current.json") && message.contains("not a rig's"), "{message}");
}

#[test]
fn commit_writes_current_history_and_yaml() {
    let dir = Scratch::new("commit");
    let store = Store::open(dir.path(), 3).unwrap();
    assert!(store.current().unwrap().is_none());
    let r1 = store.commit(&result(1.0, Status::Accepted), 1_700_000_000).unwrap();
    assert_eq!(r1.generation, 1);
    let r2 = store.commit(&result(2.0, Status::Accepted), 1_700_000_100).unwrap();
    assert_eq!(r2.generation, 2);
    let cur = store.current().unwrap().unwrap();
    assert_eq!(cur, r2);
    // The file carries the DESIGN field names.
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("current.json")).unwrap()).unwrap();
    assert_eq!(v["generation"], 2);
    assert_eq!(v["time"], 1_700_000_100u64);
    assert_eq!(v["status"], "accepted");
    assert!(v["crc32"].as_str().unwrap().len() == 8);
    let cam = std::fs::read_to_string(dir.join("camera.yaml")).unwrap();
    assert!(
        cam.starts_with("%YAML:1.0") && cam.contains("camera_matrix: !!opencv-matrix"),
        "{cam}"
    );
    assert!(cam.contains("1.002e3"), "fx of generation 2 in {cam}");
    let ext = std::fs::read_to_string(dir.join("extrinsic.yaml")).unwrap();
    assert!(ext.contains("rows: 4") && ext.contains("4.2e-1"), "{ext}");
    // History is bounded.
    for g in 3..=6 {
        store.commit(&result(g as f64, Status::Accepted), 1_700_000_000 + g).unwrap();
    }
    let hist: Vec<u32> = store.history().unwrap().iter().map(|r| r.generation).collect();
    assert_eq!(hist, [4, 5, 6]);
}

#[test]
fn rejected_runs_never_replace_current() {
    let dir = Scratch::new("rejected");
    let store = Store::open(dir.path(), 2).unwrap();
    store.commit(&result(1.0, Status::Accepted), 10).unwrap();
    let before = std::fs::read(dir.join("current.json")).unwrap();
    assert!(store.commit(&result(9.0, Status::Rejected), 20).is_err());
    for t in 0..4 {
        store.record_rejected(&result(9.0, Status::Rejected), 20 + t).unwrap();
    }
    assert_eq!(std::fs::read(dir.join("current.json")).unwrap(), before);
    let rej = store.rejected().unwrap();
    assert_eq!(rej.len(), 2, "bounded");
    assert_eq!(rej[1].time, 23);
    assert_eq!(rej[1].result.pair.reason.as_deref(), Some("corner RMS too high"));
}

#[test]
fn corrupt_current_falls_back_to_history_and_is_repaired() {
    let dir = Scratch::new("corrupt");
    let store = Store::open(dir.path(), 4).unwrap();
    store.commit(&result(1.0, Status::Accepted), 10).unwrap();
    store.commit(&result(2.0, Status::Accepted), 20).unwrap();
    let path = dir.join("current.json");
    // One flipped digit: valid JSON, wrong checksum.
    let text = std::fs::read_to_string(&path).unwrap().replace("1002", "1003");
    assert!(decode(text.as_bytes(), &path).is_err());
    std::fs::write(&path, text).unwrap();
    let cur = store.current().unwrap().unwrap();
    assert_eq!((cur.generation, cur.result.pair.camera.fx), (2, 1002.0));
    assert!(decode(&std::fs::read(&path).unwrap(), &path).is_ok(), "repaired");
    // Truncated JSON, and a corrupt newest history entry: the one before it wins.
    std::fs::write(&path, b"{\"status\": \"acc").unwrap();
    std::fs::write(dir.join("history/gen-000002.json"), b"garbage").unwrap();
    let cur = store.current().unwrap().unwrap();
    assert_eq!(cur.generation, 1);
}

#[test]
fn rollback_goes_back_one_generation_at_a_time() {
    let dir = Scratch::new("rollback");
    let store = Store::open(dir.path(), 8).unwrap();
    assert!(store.rollback(5).is_err(), "nothing to roll back");
    for g in 1..=3 {
        store.commit(&result(g as f64, Status::Accepted), g).unwrap();
    }
    let r = store.rollback(100).unwrap();
    assert_eq!((r.generation, r.restored_from, r.result.pair.camera.fx), (4, Some(2), 1002.0));
    assert_eq!(store.current().unwrap().unwrap(), r);
    let r = store.rollback(101).unwrap();
    assert_eq!((r.generation, r.restored_from, r.result.pair.camera.fx), (5, Some(1), 1001.0));
    assert!(store.rollback(102).is_err(), "generation 1 has no predecessor");
}

#[test]
fn encoding_is_checksummed_canonical_json() {
    let store_rec = roomcal::store::Record {
        result: result(0.5, Status::Accepted),
        generation: 7,
        time: 1,
        restored_from: None,
    };
    let bytes = encode(&store_rec);
    let text = String::from_utf8(bytes.clone()).unwrap();
    let canonical = serde_json::to_string_pretty(&store_rec).unwrap();
    assert!(text.contains(&format!("\"crc32\": \"{:08x}\"", crc32(canonical.as_bytes()))));
    assert_eq!(decode(&bytes, Path::new("x")).unwrap(), store_rec);
    let mut cut = bytes.clone();
    cut.truncate(bytes.len() / 2);
    assert!(decode(&cut, Path::new("x")).is_err());
}

/// The harness's name of this module's test `test` (`store::test`), for `--exact` in a
/// child run of this test binary.
fn test_name(test: &str) -> String {
    let module = module_path!().split_once("::").map_or("", |(_, m)| m);
    if module.is_empty() {
        test.to_string()
    } else {
        format!("{module}::{test}")
    }
}

const CHILD_ENV: &str = "ROOMCAL_STORE_POWERLOSS_DIR";

/// Child side of the power-loss test: writes generations until killed (does nothing in a
/// normal test run).
#[test]
fn powerloss_child() {
    let Ok(dir) = std::env::var(CHILD_ENV) else {
        return;
    };
    let store = Store::open(&dir, 4).unwrap();
    println!("writing");
    loop {
        let next = store.next_generation().unwrap();
        store.commit(&result(f64::from(next), Status::Accepted), u64::from(next)).unwrap();
        println!("committed {next}");
    }
}

/// xorshift64*: the kill instants.
fn next_rand(state: &mut u64) -> u64 {
    *state ^= *state >> 12;
    *state ^= *state << 25;
    *state ^= *state >> 27;
    state.wrapping_mul(0x2545_F491_4F6C_DD1D)
}

#[test]
fn power_loss_leaves_old_or_new_generation() {
    let dir = Scratch::new("powerloss");
    Store::open(dir.path(), 4).unwrap();
    let exe = std::env::current_exe().unwrap();
    let mut seed = 0x9E37_79B9_7F4A_7C15u64 ^ u64::from(std::process::id());
    let started = Instant::now();
    let mut last = 0u32;
    let mut advanced = 0;
    let rounds = 200;
    for round in 0..rounds {
        let mut child = std::process::Command::new(&exe)
            .args(["--exact", &test_name("powerloss_child"), "--nocapture", "--test-threads=1"])
            .env(CHILD_ENV, dir.path())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        // After the child has opened the store and made 0, 1 or 2 commits (however long
        // that takes on a loaded machine), up to 5 ms more: a random point of a commit's
        // five fsync'ed writes.
        let mut lines = std::io::BufReader::new(child.stdout.take().unwrap()).lines();
        let commits = next_rand(&mut seed) % 3;
        let mut seen = 0;
        while let Some(Ok(line)) = lines.next() {
            if line.contains("committed") {
                seen += 1;
            }
            if line.trim_end().ends_with("writing") && commits == 0 || seen == commits {
                break;
            }
        }
        std::thread::sleep(Duration::from_micros(next_rand(&mut seed) % 5_000));
        child.kill().unwrap(); // SIGKILL
        child.wait().unwrap();
        let path = dir.join("current.json");
        let Ok(bytes) = std::fs::read(&path) else {
            assert_eq!(last, 0, "round {round}: current.json vanished after generation {last}");
            continue;
        };
        let rec = decode(&bytes, &path)
            .unwrap_or_else(|e| panic!("round {round}: current.json invalid after SIGKILL: {e}"));
        assert!(
            rec.generation >= last,
            "round {round}: went back from {last} to {}",
            rec.generation
        );
        assert_eq!(
            rec.result.pair.camera.fx,
            1000.0 + f64::from(rec.generation),
            "round {round}: mixed record"
        );
        assert_eq!(rec.time, u64::from(rec.generation));
        if rec.generation > last {
            advanced += 1;
        }
        last = rec.generation;
        // The history holds the generation in force.
        let store = Store::open(dir.path(), 4).unwrap();
        let hist = store.history().unwrap();
        assert!(hist.iter().any(|r| r.generation == last), "round {round}: {last} not in history");
        // Reopened, as the daemon restarts: no temporary file is left, and a generation
        // whose update the kill interrupted is completed, so history has no holes (a hole
        // is a number skipped: the 8 → 11 jumps).
        assert_eq!(temp_files(&dir), Vec::<PathBuf>::new(), "round {round}");
        let in_force = store.current().unwrap().map_or(0, |r| r.generation);
        let gens: Vec<u32> = store.history().unwrap().iter().map(|r| r.generation).collect();
        let want: Vec<u32> = (in_force + 1 - gens.len() as u32..=in_force).collect();
        assert_eq!(gens, want, "round {round}: history must end at {in_force} without holes");
        last = in_force;
    }
    println!(
        "power loss: {rounds} SIGKILL rounds, {advanced} advanced, final generation {last}, {:.1} s",
        started.elapsed().as_secs_f64()
    );
    assert!(advanced > rounds / 4, "the child wrote too rarely ({advanced} rounds advanced)");
}

/// Temporary files in the store's three directories.
fn temp_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for d in [dir.to_path_buf(), dir.join("history"), dir.join("rejected")] {
        for e in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            if e.file_name().to_string_lossy().contains(".tmp-") {
                out.push(e.path());
            }
        }
    }
    out
}

/// The id of a process that has exited (a child, reaped).
fn dead_pid() -> u32 {
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let pid = child.id();
    child.wait().unwrap();
    pid
}

#[test]
fn temp_files_of_dead_writers_are_removed_at_open() {
    let dir = Scratch::new("tempclean");
    Store::open(dir.path(), 4).unwrap().commit(&result(1.0, Status::Accepted), 1).unwrap();
    let dead = dead_pid();
    let stale = [
        dir.join(format!(".current.json.tmp-{dead}")),
        dir.join(format!("history/.gen-000002.json.tmp-{dead}-7")),
        dir.join(format!("rejected/.run-000000000005-0000.json.tmp-{dead}")),
    ];
    let ours = dir.join(format!(".camera.yaml.tmp-{}-99", std::process::id()));
    for p in stale.iter().chain([&ours]) {
        std::fs::write(p, b"half a record").unwrap();
    }
    let store = Store::open(dir.path(), 4).unwrap();
    assert_eq!(temp_files(&dir), [ours], "only this process's own temp file stays");
    assert_eq!(store.current().unwrap().unwrap().generation, 1);
}

const FULL_ENV: &str = "ROOMCAL_STORE_FULL_DIR";

/// Child side of the full-disk test: runs under a 512-byte file size limit, so the record
/// write fails part-way (EFBIG, as ENOSPC would); prints the error.
#[test]
fn full_store_child() {
    let Ok(dir) = std::env::var(FULL_ENV) else {
        return;
    };
    let store = Store::open(&dir, 4).unwrap();
    let err = store.commit(&result(1.0, Status::Accepted), 1).unwrap_err();
    println!("FULL-STORE-ERROR {err}");
}

#[test]
fn failed_write_leaves_no_temp_file() {
    let dir = Scratch::new("full");
    Store::open(dir.path(), 4).unwrap();
    let exe = std::env::current_exe().unwrap();
    // SIGXFSZ ignored: the write returns EFBIG instead of killing the process.
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg("trap '' XFSZ; ulimit -f 1; exec \"$0\" --exact \"$1\" --nocapture")
        .arg(&exe)
        .arg(test_name("full_store_child"))
        .env(FULL_ENV, dir.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}{}", String::from_utf8_lossy(&out.stderr));
    let line = stdout.lines().find(|l| l.starts_with("FULL-STORE-ERROR")).expect("child ran");
    println!("{line}");
    assert!(line.contains("gen-000001.json"), "the error names the file: {line}");
    assert_eq!(temp_files(&dir), Vec::<PathBuf>::new(), "the partial temp file was removed");
    assert!(!dir.join("current.json").exists());
}

#[test]
fn interrupted_update_is_completed_not_skipped() {
    let dir = Scratch::new("interrupted");
    let store = Store::open(dir.path(), 16).unwrap();
    for g in 1..=8u32 {
        store.commit(&result(f64::from(g), Status::Accepted), u64::from(g)).unwrap();
    }
    // A kill after the history write of generation 9, before current.json was replaced.
    let nine = roomcal::store::Record {
        result: result(9.0, Status::Accepted),
        generation: 9,
        time: 9,
        restored_from: None,
    };
    std::fs::write(dir.join("history/gen-000009.json"), encode(&nine)).unwrap();
    let store = Store::open(dir.path(), 16).unwrap();
    assert_eq!(store.current().unwrap().unwrap(), nine, "completed, not skipped");
    let path = dir.join("current.json");
    assert_eq!(decode(&std::fs::read(&path).unwrap(), &path).unwrap().generation, 9);
    let next = store.commit(&result(10.0, Status::Accepted), 10).unwrap();
    assert_eq!(next.generation, 10, "no jump over an unseen generation");
}

#[test]
fn generations_are_never_reused() {
    // Both current.json and the newest history entry corrupt (each a flipped digit, so
    // the JSON still parses), then the newest history entry truncated as well.
    let dir = Scratch::new("reuse");
    let store = Store::open(dir.path(), 8).unwrap();
    for g in 1..=3u32 {
        store.commit(&result(f64::from(g), Status::Accepted), u64::from(g)).unwrap();
    }
    let flip = |p: PathBuf| {
        let text = std::fs::read_to_string(&p).unwrap().replace("1003", "1004");
        std::fs::write(p, text).unwrap();
    };
    flip(dir.join("current.json"));
    flip(dir.join("history/gen-000003.json"));
    assert_eq!(store.current().unwrap().unwrap().generation, 2, "newest valid in force");
    let r = store.commit(&result(4.0, Status::Accepted), 4).unwrap();
    assert_eq!(r.generation, 4, "3 was used, even if its records are corrupt");
    std::fs::write(dir.join("current.json"), b"{\"gen").unwrap();
    std::fs::write(dir.join("history/gen-000004.json"), b"").unwrap();
    assert_eq!(store.commit(&result(5.0, Status::Accepted), 5).unwrap().generation, 5);
    drop(dir);

    // History deleted, current.json emptied: the rejected runs' names remember the number.
    let dir = Scratch::new("reuse-deleted");
    let store = Store::open(dir.path(), 8).unwrap();
    for g in 1..=3u32 {
        store.commit(&result(f64::from(g), Status::Accepted), u64::from(g)).unwrap();
    }
    store.record_rejected(&result(9.0, Status::Rejected), 10).unwrap();
    std::fs::remove_dir_all(dir.join("history")).unwrap();
    std::fs::write(dir.join("current.json"), b"").unwrap();
    assert!(store.current().unwrap().is_none(), "nothing valid is left");
    let r = store.commit(&result(4.0, Status::Accepted), 11).unwrap();
    assert_eq!(r.generation, 4, "not 1 again");
    assert!(
        dir.join("history/gen-000004.json").exists()
            && !dir.join("history/gen-000001.json").exists()
    );
    // History deleted while current.json is fine: the sequence continues from it.
    std::fs::remove_dir_all(dir.join("history")).unwrap();
    assert_eq!(store.commit(&result(5.0, Status::Accepted), 12).unwrap().generation, 5);
}

#[test]
fn the_last_generation_is_refused_not_overwritten() {
    let dir = Scratch::new("u32max");
    let store = Store::open(dir.path(), 4).unwrap();
    let near = roomcal::store::Record {
        result: result(1.0, Status::Accepted),
        generation: u32::MAX - 1,
        time: 1,
        restored_from: None,
    };
    std::fs::write(dir.join(format!("history/gen-{:06}.json", u32::MAX - 1)), encode(&near))
        .unwrap();
    std::fs::write(dir.join("current.json"), encode(&near)).unwrap();
    let last = store.commit(&result(2.0, Status::Accepted), 2).unwrap();
    assert_eq!(last.generation, u32::MAX);
    let before = std::fs::read(dir.join("current.json")).unwrap();
    let err = store.commit(&result(3.0, Status::Accepted), 3).unwrap_err();
    let text = err.to_string();
    assert!(text.contains("4294967295") && text.contains("refusing"), "{text}");
    assert!(store.rollback(4).is_err(), "a rollback needs a generation too");
    assert_eq!(std::fs::read(dir.join("current.json")).unwrap(), before, "left as it was");
    // History is pruned by generation, not by name (gen-4294967295 sorts before gen-5).
    let hist: Vec<u32> = store.history().unwrap().iter().map(|r| r.generation).collect();
    assert_eq!(hist, [u32::MAX - 1, u32::MAX]);
    println!("{text}");
}

#[test]
fn an_invalid_calibration_with_a_valid_checksum_is_not_in_force() {
    let dir = Scratch::new("invalid");
    let store = Store::open(dir.path(), 4).unwrap();
    store.commit(&result(1.0, Status::Accepted), 1).unwrap();
    store.commit(&result(2.0, Status::Accepted), 2).unwrap();
    let mut bogus = result(0.0, Status::Accepted);
    bogus.pair.camera.fx = -5.0;
    let hand_made =
        roomcal::store::Record { result: bogus, generation: 3, time: 3, restored_from: None };
    let path = dir.join("current.json");
    std::fs::write(&path, encode(&hand_made)).unwrap();
    assert!(decode(&std::fs::read(&path).unwrap(), &path).is_ok(), "the checksum holds");
    let cur = store.current().unwrap().unwrap();
    assert_eq!((cur.generation, cur.result.pair.camera.fx), (2, 1002.0), "newest valid history");
    assert_eq!(decode(&std::fs::read(&path).unwrap(), &path).unwrap(), cur, "rewritten");
    assert_eq!(store.commit(&result(4.0, Status::Accepted), 4).unwrap().generation, 4);
    // The validator's reasons, one per kind of nonsense.
    use roomcal::store::is_valid_calibration;
    let pair = |status| result(0.0, status).pair;
    let why = |r| is_valid_calibration(&r).unwrap_err().to_string();
    let mut r = pair(Status::Accepted);
    assert_eq!(is_valid_calibration(&r), Ok(()));
    r.camera.cx = f64::NAN;
    assert!(why(r).contains("cx"));
    let mut r = pair(Status::Accepted);
    r.lidar_to_camera.as_mut().unwrap().rotation[0][1] = 0.5;
    assert!(why(r).contains("rotation"));
    let mut r = pair(Status::Accepted);
    r.camera.distortion.push(f64::INFINITY);
    assert!(why(r).contains("distortion"));
    let refused = is_valid_calibration(&pair(Status::Rejected));
    assert_eq!(refused, Err(roomcal::store::InvalidRecord::NotAccepted));
}

#[test]
fn a_held_record_restores_an_emptied_current_json() {
    let dir = Scratch::new("verify");
    let store = Store::open(dir.path(), 4).unwrap();
    let rec = store.commit(&result(1.0, Status::Accepted), 1).unwrap();
    let path = dir.join("current.json");
    assert_eq!(store.verify_current(Some(&rec)).unwrap(), Some(rec.clone()));
    for damage in [&b""[..], b"{\"generation\": 1", b"garbage"] {
        std::fs::write(&path, damage).unwrap();
        assert_eq!(store.verify_current(Some(&rec)).unwrap(), Some(rec.clone()));
        assert_eq!(std::fs::read(&path).unwrap(), encode(&rec), "restored");
    }
    // A newer valid record written by someone else is taken, not overwritten.
    let newer =
        Store::open(dir.path(), 4).unwrap().commit(&result(2.0, Status::Accepted), 2).unwrap();
    assert_eq!(store.verify_current(Some(&rec)).unwrap(), Some(newer));
}

/// Captures the store's log lines during `f`.
#[cfg(feature = "daemon")]
fn logs_of<T>(f: impl FnOnce() -> T) -> (T, String) {
    use std::sync::{Arc, Mutex};
    #[derive(Clone, Default)]
    struct Buf(Arc<Mutex<Vec<u8>>>);
    impl std::io::Write for Buf {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    let buf = Buf::default();
    let writer = buf.clone();
    let subscriber =
        tracing_subscriber::fmt().with_writer(move || writer.clone()).with_ansi(false).finish();
    let out = tracing::subscriber::with_default(subscriber, f);
    let text = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
    (out, text)
}

#[cfg(feature = "daemon")]
#[test]
fn restore_is_logged_only_after_it_succeeded() {
    let dir = Scratch::new("restorelog");
    let store = Store::open(dir.path(), 4).unwrap();
    for g in 1..=3u32 {
        store.commit(&result(f64::from(g), Status::Accepted), u64::from(g)).unwrap();
    }
    // current.json replaced by a directory: it cannot be read or restored.
    std::fs::remove_file(dir.join("current.json")).unwrap();
    std::fs::create_dir(dir.join("current.json")).unwrap();
    let (got, log) = logs_of(|| store.current());
    let err = got.unwrap_err().to_string();
    assert!(err.contains("current.json"), "{err}");
    assert!(!log.contains("restored"), "claimed a restore that failed: {log}");
    // Emptied instead: restored, and said so.
    std::fs::remove_dir(dir.join("current.json")).unwrap();
    std::fs::write(dir.join("current.json"), b"").unwrap();
    let (got, log) = logs_of(|| store.current());
    assert_eq!(got.unwrap().unwrap().generation, 3);
    assert!(log.contains("restored generation 3 from history"), "{log}");
}

const VIEWS_FULL_ENV: &str = "ROOMCAL_STORE_VIEWS_FULL_DIR";

/// Child side of the full-disk-after-current.json test: commits generation 1, then
/// generation 2 with every `.camera.yaml.tmp-PID-N` this process could write leading to
/// /dev/full (ENOSPC once current.json is already replaced); prints the error.
#[test]
fn views_full_child() {
    let Ok(dir) = std::env::var(VIEWS_FULL_ENV) else {
        return;
    };
    let store = Store::open(&dir, 4).unwrap();
    store.commit(&result(1.0, Status::Accepted), 1).unwrap();
    for n in 0..64 {
        let tmp = Path::new(&dir).join(format!(".camera.yaml.tmp-{}-{n}", std::process::id()));
        std::os::unix::fs::symlink("/dev/full", tmp).unwrap();
    }
    let err = store.commit(&result(2.0, Status::Accepted), 2).unwrap_err();
    println!("VIEWS-FULL-ERROR {err}");
}

#[cfg(unix)]
#[test]
fn a_full_disk_after_current_json_says_the_generation_is_in_force() {
    let dir = Scratch::new("views-full");
    let exe = std::env::current_exe().unwrap();
    let out = std::process::Command::new(exe)
        .args(["--exact", &test_name("views_full_child"), "--nocapture"])
        .env(VIEWS_FULL_ENV, dir.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}{}", String::from_utf8_lossy(&out.stderr));
    let line = stdout.lines().find(|l| l.starts_with("VIEWS-FULL-ERROR")).expect("child ran");
    println!("{line}");
    assert!(line.contains("No space left on device") && line.contains("camera.yaml"), "{line}");
    assert!(line.contains("generation 2 is in force"), "the message hides what holds: {line}");
    let store = Store::open(dir.path(), 4).unwrap();
    assert_eq!(store.current().unwrap().unwrap().generation, 2, "as the message says");
    assert_eq!(store.next_generation().unwrap(), 3);
}

#[test]
fn export_to_a_file_is_refused_before_calibrating_and_named() {
    // The store's directory and `calibrate --export DIR` share the check of a path that
    // must be a directory.
    let dir = Scratch::new("export-file");
    let file = dir.join("exports");
    std::fs::write(&file, b"a file").unwrap();
    let out = dir.join("result.json");
    let fixture = crate::common::fixture;
    let (code, _, stderr) = crate::common::roomcal(&[
        "calibrate".as_ref(),
        "--room".as_ref(),
        fixture("six-boards-pandar64/room.toml").as_os_str(),
        "--image".as_ref(),
        fixture("six-boards-pandar64/image.png").as_os_str(),
        "--cloud".as_ref(),
        fixture("six-boards-pandar64/cloud.pcd").as_os_str(),
        "--quiet".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
        "--export".as_ref(),
        file.as_os_str(),
    ]);
    assert_eq!(code, 2, "{stderr}");
    assert!(
        stderr.contains(&format!("--export {}: is a file, not a directory", file.display())),
        "{stderr}"
    );
    assert!(!out.exists(), "calibrated before finding the export directory unusable");
    assert_eq!(std::fs::read(&file).unwrap(), b"a file");
}
