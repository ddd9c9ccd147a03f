//! Store: commit, history bound, rejected runs, corruption fallback, rollback, and a
//! power-loss test (a child process writing generations, killed with SIGKILL at random
//! instants).

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use roomcal::geometry::CameraModel;
use roomcal::result::{CalibrationResult, CameraResult, Extrinsic, Quality, Status, Uncertainty};
use roomcal::store::{crc32, decode, encode, Store};

/// A result whose fx encodes `tag`, so a record's content can be checked against its
/// generation.
fn result(tag: f64, status: Status) -> CalibrationResult {
    CalibrationResult {
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
    }
}

fn tempdir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("roomcal-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn commit_writes_current_history_and_yaml() {
    let dir = tempdir("commit");
    let store = Store::open(&dir, 3).unwrap();
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
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn rejected_runs_never_replace_current() {
    let dir = tempdir("rejected");
    let store = Store::open(&dir, 2).unwrap();
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
    assert_eq!(rej[1].result.reason.as_deref(), Some("corner RMS too high"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn corrupt_current_falls_back_to_history_and_is_repaired() {
    let dir = tempdir("corrupt");
    let store = Store::open(&dir, 4).unwrap();
    store.commit(&result(1.0, Status::Accepted), 10).unwrap();
    store.commit(&result(2.0, Status::Accepted), 20).unwrap();
    let path = dir.join("current.json");
    // One flipped digit: valid JSON, wrong checksum.
    let text = std::fs::read_to_string(&path).unwrap().replace("1002", "1003");
    assert!(decode(text.as_bytes(), &path).is_err());
    std::fs::write(&path, text).unwrap();
    let cur = store.current().unwrap().unwrap();
    assert_eq!((cur.generation, cur.result.camera.fx), (2, 1002.0));
    assert!(decode(&std::fs::read(&path).unwrap(), &path).is_ok(), "repaired");
    // Truncated JSON, and a corrupt newest history entry: the one before it wins.
    std::fs::write(&path, b"{\"status\": \"acc").unwrap();
    std::fs::write(dir.join("history/gen-000002.json"), b"garbage").unwrap();
    let cur = store.current().unwrap().unwrap();
    assert_eq!(cur.generation, 1);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn rollback_goes_back_one_generation_at_a_time() {
    let dir = tempdir("rollback");
    let store = Store::open(&dir, 8).unwrap();
    assert!(store.rollback(5).is_err(), "nothing to roll back");
    for g in 1..=3 {
        store.commit(&result(g as f64, Status::Accepted), g).unwrap();
    }
    let r = store.rollback(100).unwrap();
    assert_eq!((r.generation, r.restored_from, r.result.camera.fx), (4, Some(2), 1002.0));
    assert_eq!(store.current().unwrap().unwrap(), r);
    let r = store.rollback(101).unwrap();
    assert_eq!((r.generation, r.restored_from, r.result.camera.fx), (5, Some(1), 1001.0));
    assert!(store.rollback(102).is_err(), "generation 1 has no predecessor");
    let _ = std::fs::remove_dir_all(&dir);
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

const CHILD_ENV: &str = "ROOMCAL_STORE_POWERLOSS_DIR";

/// Child side of the power-loss test: writes generations until killed (does nothing in a
/// normal test run).
#[test]
fn powerloss_child() {
    let Ok(dir) = std::env::var(CHILD_ENV) else {
        return;
    };
    let store = Store::open(&dir, 4).unwrap();
    loop {
        let next = store.next_generation().unwrap();
        store.commit(&result(f64::from(next), Status::Accepted), u64::from(next)).unwrap();
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
    let dir = tempdir("powerloss");
    Store::open(&dir, 4).unwrap();
    let exe = std::env::current_exe().unwrap();
    let mut seed = 0x9E37_79B9_7F4A_7C15u64 ^ u64::from(std::process::id());
    let started = Instant::now();
    let mut last = 0u32;
    let mut advanced = 0;
    let rounds = 200;
    for round in 0..rounds {
        let mut child = std::process::Command::new(&exe)
            .args(["--exact", "powerloss_child", "--nocapture", "--test-threads=1"])
            .env(CHILD_ENV, &dir)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        // Up to 30 ms: spans process start-up and several commits.
        std::thread::sleep(Duration::from_micros(next_rand(&mut seed) % 30_000));
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
            rec.result.camera.fx,
            1000.0 + f64::from(rec.generation),
            "round {round}: mixed record"
        );
        assert_eq!(rec.time, u64::from(rec.generation));
        if rec.generation > last {
            advanced += 1;
        }
        last = rec.generation;
        // The history holds the generation in force.
        let hist = Store::open(&dir, 4).unwrap().history().unwrap();
        assert!(hist.iter().any(|r| r.generation == last), "round {round}: {last} not in history");
    }
    println!(
        "power loss: {rounds} SIGKILL rounds, {advanced} advanced, final generation {last}, {:.1} s",
        started.elapsed().as_secs_f64()
    );
    assert!(advanced > rounds / 4, "the child wrote too rarely ({advanced} rounds advanced)");
    let _ = std::fs::remove_dir_all(&dir);
}
