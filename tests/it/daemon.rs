//! Daemon end to end on tokio's paused clock with a fake calibrator: replay sources →
//! auto-trigger → store written → once-mode exit; a rejected run leaves current.json
//! untouched; manual mode waits for a request; a missing camera device is retried, not
//! fatal; the UDS backend answers from the store.

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use roomcal::capture::GreyFrame;
use roomcal::daemon::{self, config, CalibrationOutcome, Calibrator, Daemon, RunOptions};
use roomcal::detect::DetectError;
use roomcal::geometry::CameraModel;
use roomcal::lidar::{pcd, Point};
use roomcal::result::{
    CalibrationResult, CameraResult, Extrinsic, Quality, RigResult, Status, Uncertainty,
};
use roomcal::service::uds::{Backend, DaemonState, Refusal, SensorTable};
use roomcal::store::Store;

use crate::common::results;

use crate::common::scratch::Scratch;

/// A one-pair room\'s result (no sensors), as the store and the daemon take it.
fn result(fx: f64, status: Status) -> RigResult {
    RigResult::from(CalibrationResult {
        status,
        reason: (status == Status::Rejected).then(|| "hole RMS 4.2 px > 2 px".into()),
        camera: CameraResult {
            model: CameraModel::PinholeRadtan,
            // A real camera's size: the store only puts a valid calibration in force, and
            // the fake's focal length (500 px + the sweep's point count) must fit its scale.
            width: 1920,
            height: 1200,
            fx,
            fy: fx,
            cx: 960.0,
            cy: 600.0,
            distortion: vec![0.1, -0.01, 0.0, 0.0, 0.0],
        },
        lidar_to_camera: Some(Extrinsic {
            rotation: [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]],
            translation: [0.05, 0.42, -0.28],
        }),
        uncertainty: Uncertainty::default(),
        quality: Quality { corner_rms_px: 0.25, hole_rms_px: 0.5, boards: 6 },
        boards: vec![],
        camera_in_room: None,
        projection_uncertainty: None,
    })
}

/// Sees `boards` boards; answers every run with `status`; counts calls.
struct Fake {
    boards: usize,
    status: Status,
    counts: Arc<AtomicUsize>,
    runs: Arc<AtomicUsize>,
    frames_px: Arc<AtomicUsize>,
}

impl Calibrator for Fake {
    fn count_boards(&mut self, _camera: usize, _frame: &GreyFrame) -> Result<usize, DetectError> {
        self.counts.fetch_add(1, Ordering::SeqCst);
        Ok(self.boards)
    }

    fn calibrate(
        &mut self,
        frames: &[GreyFrame],
        sweeps: &[Vec<Point>],
        _current: Option<&RigResult>,
    ) -> CalibrationOutcome {
        self.runs.fetch_add(1, Ordering::SeqCst);
        self.frames_px.store(frames[0].pixels.len(), Ordering::SeqCst);
        assert_eq!(sweeps.len(), 1);
        CalibrationOutcome::Done(Box::new(result(500.0 + sweeps[0].len() as f64, self.status)))
    }
}

fn fake(boards: usize, status: Status) -> (Fake, Arc<AtomicUsize>, Arc<AtomicUsize>) {
    let counts = Arc::new(AtomicUsize::new(0));
    let runs = Arc::new(AtomicUsize::new(0));
    let f = Fake {
        boards,
        status,
        counts: counts.clone(),
        runs: runs.clone(),
        frames_px: Arc::default(),
    };
    (f, counts, runs)
}

/// A scene folder: room.toml, one PNG, one PCD (a still room), roomcal.toml.
fn scene(name: &str, extra: &str) -> (Scratch, config::Config) {
    let dir = Scratch::new(&format!("daemon-{name}"));
    std::fs::create_dir_all(dir.join("frames")).unwrap();
    let room =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/room.toml")).unwrap();
    std::fs::write(dir.join("room.toml"), room).unwrap();
    image::GrayImage::from_fn(64, 48, |x, y| image::Luma([((x / 8 + y / 8) % 2 * 200) as u8]))
        .save(dir.join("frames/a.png"))
        .unwrap();
    let mut pts = Vec::new();
    for ring in 0..16u16 {
        for i in 0..720 {
            let a = (i as f32 * 0.5).to_radians();
            let d = 6.0 + (2.0 * a).cos();
            pts.push(Point {
                x: d * a.cos(),
                y: d * a.sin(),
                z: f32::from(ring) * 0.1,
                ring,
                ..Point::default()
            });
        }
    }
    pcd::write(dir.join("cloud.pcd"), &pts, pcd::PcdFormat::Binary).unwrap();
    let text = format!(
        "room = \"room.toml\"\nstore = \"store\"\n[camera]\nsource = \"replay:frames\"\n\
         [lidar]\nsource = \"replay:cloud.pcd\"\n[trigger]\nsettle_s = 2.0\nframes = 3\nsweeps = 2\n{extra}"
    );
    let path = dir.join("roomcal.toml");
    std::fs::write(&path, &text).unwrap();
    (dir, config::load(&path).unwrap())
}

/// `--once` without giving up: the tests end the run themselves.
const ONCE: RunOptions = RunOptions { once: true, give_up_after: None };

#[tokio::test(start_paused = true)]
async fn once_gives_up_saying_the_room_was_never_seen() {
    let (dir, cfg) = scene("give-up", "");
    let (cal, _, runs) = fake(5, Status::Accepted); // the room has 6
    let options = RunOptions { once: true, give_up_after: Some(Duration::from_secs(20)) };
    let t0 = tokio::time::Instant::now();
    let err = daemon::run(cfg, cal, options, std::future::pending()).await.unwrap_err();
    let took = t0.elapsed();
    let message = err.to_string();
    assert!(matches!(err, daemon::DaemonError::GaveUp { seconds: 20, .. }), "{message}");
    assert!(message.contains("the room was never seen: 5 of 6 boards seen"), "{message}");
    assert!(took >= Duration::from_secs(20) && took < Duration::from_secs(22), "{took:?}");
    assert_eq!(runs.load(Ordering::SeqCst), 0);
    assert!(current_bytes(&dir).is_none());
}

#[tokio::test(start_paused = true)]
async fn frames_of_another_size_are_named_and_the_run_gives_up_on_them() {
    let (_dir, cfg) = scene("frame-size", "");
    let room = roomcal::room::load(&cfg.room).unwrap();
    let (width, height) = (room.camera.width, room.camera.height);
    let cal = roomcal::daemon::room_calibrator::RoomCalibrator::new(room).unwrap();
    let options = RunOptions { once: true, give_up_after: Some(Duration::from_secs(5)) };
    let err = daemon::run(cfg, cal, options, std::future::pending()).await.unwrap_err();
    let message = err.to_string();
    let size = format!("its frames are 64x48, the room's camera is {width}x{height}");
    assert!(message.contains(&size) && message.contains("gave up after 5 s"), "{message}");
}

fn current_bytes(dir: &Path) -> Option<Vec<u8>> {
    std::fs::read(dir.join("store/current.json")).ok()
}

#[tokio::test(start_paused = true)]
async fn replay_auto_trigger_stores_a_generation_and_exits_once() {
    let (dir, cfg) = scene("auto", "");
    let (cal, counts, runs) = fake(6, Status::Accepted);
    let t0 = tokio::time::Instant::now();
    let summary = daemon::run(cfg, cal, ONCE, std::future::pending()).await.unwrap();
    let took = t0.elapsed();
    assert_eq!((summary.runs, summary.accepted, summary.generation()), (1, 1, 1));
    assert_eq!(runs.load(Ordering::SeqCst), 1);
    // Settling needs 2 s of still sweeps after the room was seen; the board count runs ~1 Hz.
    assert!(took >= Duration::from_secs(2) && took < Duration::from_secs(10), "{took:?}");
    assert!(counts.load(Ordering::SeqCst) >= 2);
    let store = Store::open(dir.join("store"), 4).unwrap();
    let cur = store.current().unwrap().unwrap();
    assert_eq!(cur.generation, 1);
    // Two accumulated sweeps of 16 × 720 points.
    assert_eq!(cur.result.pair.camera.fx, 500.0 + 2.0 * 16.0 * 720.0);
    assert!(dir.join("store/camera.yaml").exists());
}

#[tokio::test(start_paused = true)]
async fn too_few_boards_never_trigger() {
    let (dir, cfg) = scene("few", "");
    let (cal, counts, runs) = fake(5, Status::Accepted); // the room has 6
    let summary =
        daemon::run(cfg, cal, ONCE, tokio::time::sleep(Duration::from_secs(30))).await.unwrap();
    assert_eq!(summary.runs, 0);
    assert_eq!(runs.load(Ordering::SeqCst), 0);
    assert!(counts.load(Ordering::SeqCst) >= 25, "about one detection pass a second");
    assert!(current_bytes(&dir).is_none());
}

#[tokio::test(start_paused = true)]
async fn rejected_run_leaves_current_untouched() {
    let (dir, cfg) = scene("rejected", "");
    let store = Store::open(dir.join("store"), 4).unwrap();
    store.commit(&result(900.0, Status::Accepted), 1_700_000_000).unwrap();
    let before = current_bytes(&dir).unwrap();
    let (cal, _, runs) = fake(6, Status::Rejected);
    let summary = daemon::run(cfg, cal, ONCE, std::future::pending()).await.unwrap();
    assert_eq!((summary.runs, summary.rejected, summary.generation()), (1, 1, 1));
    assert_eq!(runs.load(Ordering::SeqCst), 1);
    assert_eq!(current_bytes(&dir).unwrap(), before);
    let rejected = store.rejected().unwrap();
    assert_eq!(rejected.len(), 1);
    assert_eq!(rejected[0].result.pair.status, Status::Rejected);
}

#[tokio::test(start_paused = true)]
async fn manual_mode_runs_only_on_request_and_latches_in_auto() {
    let (dir, cfg) = scene("manual", "mode = \"manual\"\n");
    let (cal, _, runs) = fake(6, Status::Accepted);
    let (d, handle) = Daemon::new(cfg, cal, RunOptions::default());
    let task = tokio::spawn(d.run(tokio::time::sleep(Duration::from_secs(60))));
    tokio::time::sleep(Duration::from_secs(20)).await;
    assert_eq!(runs.load(Ordering::SeqCst), 0, "manual: no run without a request");
    assert_eq!(handle.shared().state, DaemonState::RoomSeen);
    assert!(handle.request_calibration());
    tokio::time::sleep(Duration::from_secs(5)).await;
    assert_eq!(runs.load(Ordering::SeqCst), 1);
    assert_eq!(handle.shared().state, DaemonState::Accepted);
    assert_eq!(handle.shared().current.unwrap().generation, 1);
    let summary = task.await.unwrap().unwrap();
    assert_eq!(summary.accepted, 1, "one run in 60 s");
    drop(dir);

    // Auto mode: one run per visit, however long the vehicle stays.
    let (_dir, cfg) = scene("latch", "");
    let (cal, _, runs) = fake(6, Status::Accepted);
    let s =
        daemon::run(cfg, cal, RunOptions::default(), tokio::time::sleep(Duration::from_secs(60)))
            .await
            .unwrap();
    assert_eq!((s.runs, runs.load(Ordering::SeqCst)), (1, 1));
}

#[tokio::test(start_paused = true)]
async fn missing_camera_device_is_named_and_retried() {
    let (_dir, mut cfg) = scene("nodev", "");
    cfg.camera = config::CameraSource::V4l2("/dev/video-roomcal-missing".into());
    let err = daemon::open_camera(&cfg).err().unwrap().to_string();
    assert!(err.contains("/dev/video-roomcal-missing"), "{err}");
    let (cal, counts, _) = fake(6, Status::Accepted);
    let s =
        daemon::run(cfg, cal, ONCE, tokio::time::sleep(Duration::from_secs(120))).await.unwrap();
    assert_eq!(s.runs, 0);
    assert_eq!(counts.load(Ordering::SeqCst), 0, "no frames, no detection");
}

/// A rig in force: the sensor table and the per-sensor DIDs describe it (cameras, then
/// LiDARs, in the rig's order), whatever vehicle the daemon was configured with; the
/// fixed DIDs keep describing the first camera and first LiDAR.
#[test]
fn backend_serves_the_rig_in_force_sensor_by_sensor() {
    use roomcal::service::uds::SensorKind;
    let dir = Scratch::new("daemon-rig");
    let store = Store::open(dir.path(), 4).unwrap();
    let rig = results::rig_result();
    let rec = store.commit(&rig, 1_700_000_000).unwrap();
    let shared = Arc::new(std::sync::Mutex::new(daemon::Shared {
        current: Some(rec),
        ..Default::default()
    }));
    let (tx, _rx) = tokio::sync::mpsc::channel(1);
    let b = daemon::DaemonBackend::new(shared, tx, store, SensorTable::one_pair(true));
    let table = b.sensors();
    let listed: Vec<(SensorKind, &str)> =
        table.sensors.iter().map(|s| (s.kind, s.name.as_str())).collect();
    assert_eq!(
        listed,
        [
            (SensorKind::Camera, "front"),
            (SensorKind::Camera, "wide"),
            (SensorKind::Lidar, "top"),
            (SensorKind::Lidar, "bumper")
        ]
    );
    let wide = b.sensor_intrinsics(1).expect("the wide camera's intrinsics");
    assert_eq!((wide.fx, wide.cy), (961.25, 604.125));
    assert_eq!(b.sensor_intrinsics(0), b.intrinsics(), "0xC200 = 0xC002");
    assert_eq!(b.sensor_intrinsics(2), None, "a LiDAR has no intrinsics");
    assert_eq!(b.sensor_intrinsics(4), None, "past the table");
    assert_eq!(b.sensor_extrinsic(2), b.extrinsic(), "0xC302 (top) = 0xC003");
    let bumper = b.sensor_extrinsic(3).expect("the bumper LiDAR's extrinsic");
    assert_eq!(bumper.translation, [0.05, 1.52, 0.72]);
    let front = b.sensor_extrinsic(0).unwrap();
    assert_eq!((front.rotation, front.translation), ([1.0, 0.0, 0.0, 0.0], [0.0; 3]));
    assert_eq!(b.sensor_extrinsic(4), None);
}

#[test]
fn backend_answers_from_the_store_and_rolls_back() {
    let dir = Scratch::new("daemon-backend");
    let store = Store::open(dir.path(), 4).unwrap();
    store.commit(&result(800.0, Status::Accepted), 1_700_000_000).unwrap();
    let rec = store.commit(&result(810.0, Status::Accepted), 1_700_000_100).unwrap();
    let shared = Arc::new(std::sync::Mutex::new(daemon::Shared {
        current: Some(rec),
        ..Default::default()
    }));
    let (tx, mut rx) = tokio::sync::mpsc::channel(1);
    let mut b =
        daemon::DaemonBackend::new(shared.clone(), tx, store.clone(), SensorTable::one_pair(true));
    let st = b.state();
    assert_eq!((st.state, st.generation, st.time), (DaemonState::Idle, 2, 1_700_000_100));
    let k = b.intrinsics().unwrap();
    assert_eq!((k.fx, k.cx, k.distortion.len()), (810.0, 960.0, 5));
    let e = b.extrinsic().unwrap();
    // The quaternion turns back into the stored rotation matrix.
    let q = e.rotation.map(f64::from);
    let r = roomcal::geometry::se3::quaternion_to_rotation(&q).unwrap();
    let want = [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]];
    for (i, row) in want.iter().enumerate() {
        for (j, w) in row.iter().enumerate() {
            assert!((r[(i, j)] - w).abs() < 1e-6, "{:?} → {r}", e.rotation);
        }
    }
    assert_eq!(e.translation, [0.05, 0.42, -0.28]);
    assert_eq!(b.quality().unwrap().boards, 6);
    // The one-pair rig's per-sensor DIDs serve the same records.
    assert_eq!(b.sensors(), SensorTable::one_pair(true));
    assert_eq!(b.sensor_intrinsics(0), Some(k));
    assert_eq!(b.sensor_extrinsic(1), Some(e));
    assert_eq!((b.sensor_intrinsics(1), b.sensor_extrinsic(2)), (None, None));
    // Start = a run request; finished once the daemon counts a run.
    b.start_calibration().unwrap();
    assert!(rx.try_recv().is_ok());
    assert!(b.calibration_finished().is_none());
    {
        let mut s = shared.lock().unwrap();
        s.runs = 1;
        s.last =
            Some(roomcal::service::uds::Outcome { state: DaemonState::Accepted, generation: 3 });
    }
    assert_eq!(b.calibration_finished().unwrap().generation, 3);
    shared.lock().unwrap().state = DaemonState::Solving;
    assert_eq!(b.start_calibration(), Err(Refusal::Busy));
    shared.lock().unwrap().state = DaemonState::Idle;
    // Rollback puts generation 1's calibration back as generation 3.
    assert_eq!(b.rollback(), Ok(3));
    assert_eq!(b.intrinsics().unwrap().fx, 800.0);
    assert_eq!(store.current().unwrap().unwrap().restored_from, Some(1));
    assert_eq!(b.rollback(), Err(Refusal::NotAvailable));
}

/// The service as a bench tool sees it: the daemon listens on a socketcand endpoint
/// (`[service] transport = "socketcand:..."`); our client connects, reads the state,
/// unlocks with the secret file's key, starts a run (0x78 until it ends), rolls back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn service_listens_on_socketcand_and_runs_a_calibration() {
    use roomcal::service::client::UdsClient;
    use roomcal::service::socketcand::SocketcandClient;
    use roomcal::service::uds::Session;
    // A free port: bound, then released for the daemon.
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let service = format!(
        "mode = \"manual\"\n[service]\ntransport = \"socketcand:127.0.0.1:{port}\"\n\
         secret_file = \"secret\"\n"
    );
    let (dir, cfg) = scene("uds", &service);
    crate::common::write_secret(&dir.join("secret"), b"bench secret\n");
    let store = Store::open(dir.join("store"), 4).unwrap();
    store.commit(&result(800.0, Status::Accepted), 1_700_000_000).unwrap();
    let (cal, _, runs) = fake(6, Status::Accepted);
    let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn(daemon::run(cfg, cal, RunOptions::default(), async {
        let _ = stopped.await;
    }));
    let mut transport = None;
    for _ in 0..50 {
        match SocketcandClient::connect(&format!("127.0.0.1:{port}"), "can0").await {
            Ok(t) => {
                transport = Some(t);
                break;
            }
            Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
        }
    }
    let mut c = UdsClient::with_defaults(transport.expect("the daemon listens on its endpoint"));
    assert_eq!(c.status().await.unwrap().generation, 1);
    assert_eq!(c.intrinsics().await.unwrap().fx, 800.0);
    c.session(Session::Extended).await.unwrap();
    assert!(c.unlock(b"wrong").await.is_err());
    // The secret file's trailing newline is not part of the secret.
    c.unlock(b"bench secret").await.unwrap();
    let outcome = c.start_calibration().await.unwrap();
    assert_eq!((outcome.state, outcome.generation), (DaemonState::Accepted, 2));
    assert_eq!(runs.load(Ordering::SeqCst), 1);
    let fx = c.intrinsics().await.unwrap().fx;
    assert_eq!(fx, (500.0 + 2.0 * 16.0 * 720.0) as f32, "two sweeps of 16 × 720 points");
    assert_eq!(store.current().unwrap().unwrap().generation, 2);
    assert_eq!(c.rollback().await.unwrap(), 3);
    assert_eq!(c.intrinsics().await.unwrap().fx, 800.0);
    assert_eq!(store.current().unwrap().unwrap().restored_from, Some(1));
    stop.send(()).unwrap();
    let summary = task.await.unwrap().unwrap();
    assert_eq!((summary.runs, summary.accepted, summary.generation()), (1, 1, 3));
}

#[test]
fn shipped_vehicle_config_parses() {
    let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/roomcal.toml"));
    let c = config::load(path).unwrap();
    assert_eq!(c.room, path.parent().unwrap().join("room.toml"));
    assert_eq!(c.camera, config::CameraSource::V4l2("/dev/video0".into()));
    assert_eq!(c.service.unwrap().transport, "socketcan:can0");
    // The interop check's replay configuration: a socketcand endpoint the daemon serves.
    let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/replay-uds.toml"));
    let c = config::load(path).unwrap();
    let s = c.service.unwrap();
    assert_eq!(s.transport, "socketcand:127.0.0.1:29536");
    assert_eq!(s.socketcand, config::SocketcandRole::Listen);
    assert_eq!(c.trigger.mode, roomcal::daemon::trigger::Mode::Manual);
}

/// CPU seconds (user + system) of this process so far, from /proc/self/stat.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0) // USER_HZ is 100 on Linux
}

/// Idle CPU of a replay run in real time (10 s, room not seen): run with `--ignored`.
#[test]
#[ignore]
fn idle_cpu_of_a_replay_run() {
    let (_dir, cfg) = scene("idlecpu", "");
    let (cal, counts, _) = fake(0, Status::Accepted);
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();
    let before = cpu_seconds().unwrap();
    let wall = std::time::Instant::now();
    rt.block_on(async {
        daemon::run(cfg, cal, RunOptions::default(), tokio::time::sleep(Duration::from_secs(10)))
            .await
    })
    .unwrap();
    let cpu = cpu_seconds().unwrap() - before;
    let secs = wall.elapsed().as_secs_f64();
    println!(
        "idle replay run: {:.2} s CPU over {secs:.1} s = {:.1} % of a core ({} detection passes)",
        cpu,
        100.0 * cpu / secs,
        counts.load(Ordering::SeqCst)
    );
    assert!(counts.load(Ordering::SeqCst) >= 8);
}

/// `--once`: a run whose result cannot be written is an error (the binary exits 1), not
/// a success with nothing in the store.
#[tokio::test(start_paused = true)]
async fn once_fails_when_the_store_cannot_be_written() {
    let (dir, cfg) = scene("unwritable", "");
    let (cal, _, _) = fake(6, Status::Accepted);
    let task = tokio::spawn(daemon::run(cfg, cal, ONCE, std::future::pending()));
    // The daemon opened its store; now its history becomes a plain file.
    tokio::time::sleep(Duration::from_millis(500)).await;
    std::fs::remove_dir_all(dir.join("store/history")).unwrap();
    std::fs::write(dir.join("store/history"), b"not a directory").unwrap();
    let err = task.await.unwrap().unwrap_err().to_string();
    assert!(err.contains("store/history"), "the error names the store path: {err}");
    assert!(current_bytes(&dir).is_none());
}

/// `current.json` emptied while the daemon runs is put back from the record in force
/// (within the second-by-second check), and before any UDS read of the backend.
#[tokio::test(start_paused = true)]
async fn current_json_emptied_while_running_is_restored() {
    let (dir, cfg) = scene("emptied", "");
    let (cal, _, _) = fake(6, Status::Accepted);
    let (d, handle) = Daemon::new(cfg, cal, RunOptions::default());
    let task = tokio::spawn(d.run(tokio::time::sleep(Duration::from_secs(30))));
    tokio::time::sleep(Duration::from_secs(15)).await;
    assert_eq!(handle.shared().current.unwrap().generation, 1, "a run was accepted");
    let good = current_bytes(&dir).unwrap();
    for damage in [&b""[..], b"{\"status\": \"acc"] {
        std::fs::write(dir.join("store/current.json"), damage).unwrap();
        tokio::time::sleep(Duration::from_millis(1500)).await;
        assert_eq!(current_bytes(&dir).unwrap(), good, "restored while running");
    }
    task.await.unwrap().unwrap();

    // The UDS backend checks before it answers.
    let store = Store::open(dir.join("store"), 4).unwrap();
    let rec = store.current().unwrap();
    let shared =
        Arc::new(std::sync::Mutex::new(daemon::Shared { current: rec, ..Default::default() }));
    let (tx, _rx) = tokio::sync::mpsc::channel(1);
    let b = daemon::DaemonBackend::new(shared, tx, store, SensorTable::one_pair(true));
    std::fs::write(dir.join("store/current.json"), b"").unwrap();
    assert_eq!(b.state().generation, 1);
    assert_eq!(current_bytes(&dir).unwrap(), good, "restored before the read was answered");
}

/// Three wrong keys, then the daemon restarts: the 10 s lockout still holds (it is kept in
/// STORE/security.json, written before the third refusal is sent, so a SIGKILL right after
/// it keeps it as well as this graceful stop).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn security_lockout_survives_a_restart() {
    use roomcal::service::client::{ClientError, UdsClient};
    use roomcal::service::socketcand::SocketcandClient;
    use roomcal::service::uds::Session;
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let service = format!(
        "mode = \"manual\"\n[service]\ntransport = \"socketcand:127.0.0.1:{port}\"\n\
         secret_file = \"secret\"\n"
    );
    let (dir, cfg) = scene("lockout", &service);
    crate::common::write_secret(&dir.join("secret"), b"bench secret\n");
    async fn connect(port: u16) -> UdsClient<SocketcandClient> {
        for _ in 0..50 {
            if let Ok(t) = SocketcandClient::connect(&format!("127.0.0.1:{port}"), "can0").await {
                return UdsClient::with_defaults(t);
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        panic!("the daemon listens on 127.0.0.1:{port}");
    }
    let start = |cfg: config::Config| {
        let (cal, _, _) = fake(6, Status::Accepted);
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let task = tokio::spawn(daemon::run(cfg, cal, RunOptions::default(), async {
            let _ = stopped.await;
        }));
        (stop, task)
    };
    let (stop, task) = start(cfg.clone());
    let mut c = connect(port).await;
    c.session(Session::Extended).await.unwrap();
    let mut nrcs = Vec::new();
    for _ in 0..3 {
        match c.unlock(b"wrong").await {
            Err(ClientError::Negative { service: 0x27, nrc }) => nrcs.push(nrc),
            other => panic!("expected a negative response, got {other:?}"),
        }
    }
    assert_eq!(nrcs, [0x35, 0x35, 0x36]);
    drop(c);
    stop.send(()).unwrap();
    task.await.unwrap().unwrap();
    assert!(dir.join("store/security.json").exists());

    let (stop, task) = start(cfg);
    let mut c = connect(port).await;
    c.session(Session::Extended).await.unwrap();
    match c.request(&[0x27, 0x01]).await {
        Err(ClientError::Negative { service: 0x27, nrc: 0x37 }) => {}
        other => panic!("expected requiredTimeDelayNotExpired after the restart, got {other:?}"),
    }
    drop(c);
    stop.send(()).unwrap();
    task.await.unwrap().unwrap();
}

#[test]
fn the_unit_raises_the_file_descriptor_limit() {
    let unit =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/systemd/roomcal.service"))
            .unwrap();
    let limit =
        unit.lines().find_map(|l| l.strip_prefix("LimitNOFILE=")).expect("LimitNOFILE in the unit");
    let limit: u64 = limit.trim().parse().unwrap();
    let clients = roomcal::service::socketcand::Limits::default().max_clients as u64;
    assert!(limit >= 1024 && limit > 8 * clients, "LimitNOFILE={limit}");
}

/// Sees six boards in every camera (or `boards[i]` in camera i); calibrates rigs only,
/// recording how many cameras' frames and LiDARs' sweeps each run got.
struct RigFake {
    seen: Arc<std::sync::Mutex<Vec<(usize, usize)>>>,
    boards: [usize; 2],
}

impl RigFake {
    fn new(seen: &Arc<std::sync::Mutex<Vec<(usize, usize)>>>) -> Self {
        RigFake { seen: seen.clone(), boards: [6, 6] }
    }
}

impl Calibrator for RigFake {
    fn count_boards(&mut self, camera: usize, _frame: &GreyFrame) -> Result<usize, DetectError> {
        Ok(self.boards[camera])
    }

    fn calibrate(
        &mut self,
        frames: &[GreyFrame],
        sweeps: &[Vec<Point>],
        _current: Option<&RigResult>,
    ) -> CalibrationOutcome {
        self.seen.lock().unwrap().push((frames.len(), sweeps.len()));
        CalibrationOutcome::Done(Box::new(results::rig_result()))
    }
}

/// `scene`'s folder with the example rig (config/rig.toml) and a daemon configuration
/// naming a source per sensor; `bumper` is the bumper LiDAR's source.
fn rig_scene(name: &str, bumper: &str) -> (Scratch, config::Config) {
    rig_scene_with(name, bumper, "", "")
}

/// [`rig_scene`] with keys added to the wide camera's table and to `[trigger]`.
fn rig_scene_with(
    name: &str,
    bumper: &str,
    wide: &str,
    trigger: &str,
) -> (Scratch, config::Config) {
    let (dir, _) = scene(name, "");
    std::fs::copy(concat!(env!("CARGO_MANIFEST_DIR"), "/config/rig.toml"), dir.join("rig.toml"))
        .unwrap();
    let text = format!(
        "room = \"room.toml\"\nstore = \"store\"\nrig = \"rig.toml\"\n\
         [[camera]]\nname = \"front\"\nsource = \"replay:frames\"\n\
         [[camera]]\nname = \"wide\"\nsource = \"replay:frames\"\n{wide}\
         [[lidar]]\nname = \"top\"\nsource = \"replay:cloud.pcd\"\n\
         [[lidar]]\nname = \"bumper\"\nsource = \"{bumper}\"\n\
         [trigger]\nsettle_s = 2.0\nframes = 3\nsweeps = 2\n{trigger}"
    );
    let path = dir.join("rig-daemon.toml");
    std::fs::write(&path, text).unwrap();
    (dir, config::load(&path).unwrap())
}

#[tokio::test(start_paused = true)]
async fn a_rig_daemon_captures_every_sensor_and_keeps_the_rig_in_force() {
    let (dir, cfg) = rig_scene("rig-run", "replay:cloud.pcd");
    assert_eq!(cfg.rig.as_ref().map(|r| r.cameras.len() + r.lidars.len()), Some(4));
    let seen = Arc::new(std::sync::Mutex::new(Vec::new()));
    let cal = RigFake::new(&seen);
    let summary = daemon::run(cfg, cal, ONCE, std::future::pending()).await.unwrap();
    assert_eq!((summary.runs, summary.accepted, summary.generation()), (1, 1, 1));
    assert_eq!(*seen.lock().unwrap(), [(2, 2)], "one frame per camera, one sweep per LiDAR");
    let record = Store::open(dir.join("store"), 4).unwrap().current().unwrap().unwrap();
    assert_eq!(record.rig(), Some(&results::rig_result()));
    for file in
        ["camera-front.yaml", "camera-wide.yaml", "extrinsics.yaml", "wide.camera_info.yaml"]
    {
        assert!(dir.join("store").join(file).exists(), "{file}");
    }
}

#[tokio::test(start_paused = true)]
async fn a_rig_run_times_out_naming_the_sensor_that_delivered_nothing() {
    let (_dir, cfg) = rig_scene("rig-timeout", "replay:missing.pcd");
    let seen = Arc::new(std::sync::Mutex::new(Vec::new()));
    let error = daemon::run(cfg, RigFake::new(&seen), ONCE, std::future::pending())
        .await
        .unwrap_err()
        .to_string();
    assert!(error.contains("0 of 2 sweeps of LiDAR `bumper`"), "{error}");
    assert!(error.contains("2 of 2 sweeps of LiDAR `top`"), "{error}");
    assert!(seen.lock().unwrap().is_empty(), "calibrated without the bumper LiDAR");
}

/// The room counts as seen when every camera sees its boards: a wide camera that sees two
/// of the six boards holds the trigger; it runs when `[trigger] cameras` leaves that
/// camera out, or when the camera's own `min_boards` is two.
#[tokio::test(start_paused = true)]
async fn a_rigs_trigger_waits_for_every_watched_camera() {
    let run = |name: &str, wide: &str, trigger: &str| {
        let (dir, cfg) = rig_scene_with(name, "replay:cloud.pcd", wide, trigger);
        let seen = Arc::new(std::sync::Mutex::new(Vec::new()));
        let cal = RigFake { boards: [6, 2], ..RigFake::new(&seen) };
        async move {
            let stop = tokio::time::sleep(Duration::from_secs(30));
            let summary = daemon::run(cfg, cal, ONCE, stop).await.unwrap();
            drop(dir);
            (summary.runs, seen.lock().unwrap().len())
        }
    };
    assert_eq!(run("rig-held", "", "").await, (0, 0), "ran with the wide camera short of boards");
    assert_eq!(run("rig-front", "", "cameras = [\"front\"]\n").await, (1, 1));
    assert_eq!(run("rig-own", "min_boards = 2\n", "").await, (1, 1));
}
