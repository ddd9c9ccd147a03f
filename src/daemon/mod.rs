//! The vehicle daemon (tokio), in the style of mini-redis: [`run`] loads nothing itself —
//! it takes a [`Config`] (see [`config::load`]), an injected [`Calibrator`] and a
//! shutdown future, and runs until the future resolves (or, with `once`, until the first
//! run ends).
//!
//! Tasks: the camera (latest frame in a `watch` channel; replay paced by tokio's clock,
//! a failing device reopened with exponential backoff), the LiDAR (sweeps on a small
//! channel), the UDS service (when configured), and the control loop here: a cheap board
//! count about once a second and the sweep-to-sweep motion drive the [`trigger`]; a run
//! averages `frames` frames, accumulates `sweeps` sweeps, calibrates on a blocking thread
//! and commits to the [`Store`] (accepted) or keeps the result among the rejected runs.
//! A failed or rejected run on sweeps that lost packets says so in its reason ("LiDAR sweep
//! incomplete: 812 of 1800 packets lost"): the counts travel with each sweep.
//! Every second (and before every UDS read) `current.json` is checked against the record
//! in force and put back if it was emptied or damaged. With `once`, a run that left nothing
//! in the store (it failed, or the store could not be written) ends the daemon with an error.
//! A stop while a run captures or calibrates abandons the run and logs that nothing of it
//! was stored.
//! A rig (`rig = …` with `[[camera]]` / `[[lidar]]`): one task per camera and per LiDAR;
//! the trigger watches the first camera's boards and the first LiDAR's motion, a run
//! waits for `frames` frames of every camera and `sweeps` sweeps of every LiDAR (its
//! timeout names the sensors short of them) and calibrates the whole rig; the store keeps
//! the rig's record. The one-pair vehicle is the same with one camera and one LiDAR.
//! systemd: READY=1 once the sources are open, STATUS= on every state change, WATCHDOG=1
//! at half the watchdog interval (all no-ops without `NOTIFY_SOCKET`).

pub mod backend;
pub mod config;
pub mod motion;
pub mod room_calibrator;
pub mod sources;
pub mod trigger;

use std::future::Future;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::sync::{mpsc, watch};

use crate::capture::{Backoff, CaptureError, FrameSource, FrameSum, GreyFrame, ImageReplay};
use crate::detect::DetectError;
use crate::lidar::{Calibration, Model, Point};
use crate::result::{RigResult, Status};
use crate::service::uds::{DaemonState, Outcome};
use crate::store::{Record, Store, StoreError};

pub use backend::{DaemonBackend, Shared};
pub use config::{CameraSource, Config, LidarSource};
use motion::{sweep_motion, RangeImage};
use sources::{AnySweepSource, OwnedSweep, PacketCounts, SweepError, SweepSource};
use trigger::{Action, Trigger, Verdict};

/// The calibration pipeline, injected (the real one is [`RoomCalibrator`]; tests use a
/// fake). Called on a blocking thread.
pub trait Calibrator: Send + 'static {
    /// A cheap detection pass: how many boards camera `camera`'s `frame` shows (about once
    /// a second; `camera` in the rig file's order, 0 for the one-pair vehicle), or why the
    /// frame cannot be searched (a frame of another size than the camera's).
    fn count_boards(&mut self, camera: usize, frame: &GreyFrame) -> Result<usize, DetectError>;

    /// A full run: one averaged frame per camera and one accumulated sweep per LiDAR, in
    /// the rig file's order (one of each for the one-pair vehicle); `current` is the
    /// calibration in force, for the gate's change checks.
    fn calibrate(
        &mut self,
        frames: &[GreyFrame],
        sweeps: &[Vec<Point>],
        current: Option<&RigResult>,
    ) -> CalibrationOutcome;
}

/// How a calibration run ended.
#[derive(Clone, Debug, PartialEq)]
pub enum CalibrationOutcome {
    /// A result, accepted or rejected by the quality gate (`pair.status`; a rig's as a
    /// whole).
    Done(Box<RigResult>),
    /// The run could not produce a result (too few boards, ...).
    Failed(String),
}

/// Options of a run of the daemon.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RunOptions {
    /// Stop after the first calibration run ends (`roomcal daemon --once`).
    pub once: bool,
    /// With `once`: end with [`DaemonError::GaveUp`] when no run has started this long
    /// after the start, saying what the daemon was waiting for.
    pub give_up_after: Option<Duration>,
}

/// What a finished daemon run did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunSummary {
    /// Calibration runs that ended.
    pub runs: u64,
    pub accepted: u64,
    pub rejected: u64,
    pub failed: u64,
    /// The record in force at exit.
    pub in_force: Option<Record>,
}

impl RunSummary {
    /// The generation in force at exit (0: none).
    pub fn generation(&self) -> u32 {
        self.in_force.as_ref().map_or(0, |r| r.generation)
    }
}

/// Errors that stop the daemon; each names its input.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error(transparent)]
    Capture(#[from] CaptureError),
    #[error(transparent)]
    Sweeps(#[from] SweepError),
    #[error("room {path}: {message}")]
    Room { path: String, message: String },
    #[error("service: {0}")]
    Service(String),
    #[error("LiDAR angle corrections: {0}")]
    LidarCalibration(String),
    /// `--once`: no run started within the time given.
    #[error("gave up after {seconds} s without a calibration run: {waiting}")]
    GaveUp { seconds: u64, waiting: String },
    /// `--once`: the run ended without a result in the store.
    #[error("the calibration run failed: {0}")]
    RunFailed(String),
}

/// Asks a running daemon for things (the library side of `roomcal query start`).
#[derive(Clone)]
pub struct DaemonHandle {
    requests: mpsc::Sender<()>,
    shared: Arc<Mutex<Shared>>,
}

impl DaemonHandle {
    /// Requests a calibration run (manual mode's trigger); `false` if one is already queued
    /// or the daemon has stopped.
    pub fn request_calibration(&self) -> bool {
        self.requests.try_send(()).is_ok()
    }

    /// The daemon's state and the calibration in force.
    pub fn shared(&self) -> Shared {
        self.shared.lock().map(|s| s.clone()).unwrap_or_default()
    }
}

/// A daemon ready to run, and its handle.
pub struct Daemon<C: Calibrator> {
    config: Config,
    calibrator: C,
    options: RunOptions,
    requests_tx: mpsc::Sender<()>,
    requests: mpsc::Receiver<()>,
    shared: Arc<Mutex<Shared>>,
}

impl<C: Calibrator> Daemon<C> {
    /// Prepares a daemon; nothing is opened yet.
    pub fn new(config: Config, calibrator: C, options: RunOptions) -> (Self, DaemonHandle) {
        let (requests_tx, requests) = mpsc::channel(1);
        let shared = Arc::new(Mutex::new(Shared::default()));
        let handle = DaemonHandle { requests: requests_tx.clone(), shared: shared.clone() };
        (Daemon { config, calibrator, options, requests_tx, requests, shared }, handle)
    }

    /// Runs until `shutdown` resolves (or the first run ends, with `once`).
    pub async fn run(
        self,
        shutdown: impl Future<Output = ()> + Send,
    ) -> Result<RunSummary, DaemonError> {
        run_daemon(self, shutdown).await
    }
}

/// Runs the daemon (see the module docs) until `shutdown` resolves.
pub async fn run<C: Calibrator>(
    config: Config,
    calibrator: C,
    options: RunOptions,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<RunSummary, DaemonError> {
    Daemon::new(config, calibrator, options).0.run(shutdown).await
}

/// Installs a `tracing` subscriber writing to stderr (journald records it under systemd);
/// `RUST_LOG` filters (default `info`). Call once, from `main`.
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    // Colour codes only for a person at a terminal, not in the journal.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(ansi)
        .try_init();
}

/// Unix seconds now (the daemon's clock for store records).
pub(crate) fn unix_now() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs())
}

/// Opens the configured camera.
pub fn open_camera(config: &Config) -> Result<Box<dyn FrameSource>, CaptureError> {
    match &config.camera {
        CameraSource::Replay(path) => {
            let period = Duration::from_secs_f64(1.0 / config.replay_fps);
            Ok(Box::new(ImageReplay::open(path, period)?))
        }
        CameraSource::V4l2(dev) => open_v4l2(dev),
    }
}

#[cfg(feature = "v4l2")]
fn open_v4l2(dev: &std::path::Path) -> Result<Box<dyn FrameSource>, CaptureError> {
    Ok(Box::new(crate::capture::v4l2::V4l2Source::open(dev)?))
}

#[cfg(not(feature = "v4l2"))]
fn open_v4l2(dev: &std::path::Path) -> Result<Box<dyn FrameSource>, CaptureError> {
    let device = dev.display().to_string();
    if !dev.exists() {
        return Err(CaptureError::NoDevice { device });
    }
    Err(CaptureError::Device { device, message: "roomcal was built without feature `v4l2`".into() })
}

fn load_room(config: &Config) -> Result<crate::target::Room, DaemonError> {
    crate::room::load(&config.room).map_err(|e| DaemonError::Room {
        path: config.room.display().to_string(),
        message: e.to_string(),
    })
}

/// The LiDAR calibration for the room's model: the unit's angle file when the
/// configuration names one, else the model's nominal tables.
fn lidar_calibration(config: &Config) -> Result<Calibration, DaemonError> {
    let room_model = match config.lidar_model {
        Some(model) => Some(model),
        None => load_room(config)?.lidar.map(|l| l.model),
    };
    let model = room_model.flatten().unwrap_or(Model::Vlp16);
    match &config.lidar_calibration {
        Some(path) => crate::lidar::calibration::load(model, path)
            .map_err(|e| DaemonError::LidarCalibration(e.to_string())),
        // Ouster geometry is per unit: there is no nominal table to fall back on.
        None if model == Model::Ouster => Err(DaemonError::LidarCalibration(
            "an Ouster LiDAR needs `[lidar] calibration` = the sensor's metadata json".into(),
        )),
        None => Ok(Calibration::nominal(model)),
    }
}

/// Opens the configured LiDAR source.
pub async fn open_lidar(config: &Config) -> Result<AnySweepSource, DaemonError> {
    let period = Duration::from_millis(100);
    Ok(match &config.lidar {
        LidarSource::Udp(addr) => {
            let cal = lidar_calibration(config)?;
            AnySweepSource::Packets(sources::udp(*addr, config.multicast, cal).await?)
        }
        LidarSource::Replay(path) => {
            let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
            if ext == "pcap" || ext == "pcapng" {
                let cal = lidar_calibration(config)?;
                AnySweepSource::Packets(sources::pcap_replay(path, cal, config.replay_speed)?)
            } else {
                AnySweepSource::Pcd(sources::PcdReplay::open(path, period)?)
            }
        }
    })
}

/// Logs a source's failure and sleeps the backoff's next delay before `then` (retrying
/// to open it, reopening it).
async fn wait_after_failure(
    backoff: &mut Backoff,
    error: &(dyn std::fmt::Display + Sync),
    then: &str,
) {
    let d = backoff.next_delay();
    tracing::error!("{error}; {then} in {:.1} s", d.as_secs_f64());
    tokio::time::sleep(d).await;
}

/// Camera task: publishes every frame (and says on `news` that camera `index` has one);
/// reopens a failed source with backoff.
async fn camera_task(
    config: Config,
    tx: watch::Sender<Option<Arc<GreyFrame>>>,
    (index, news): (usize, mpsc::Sender<usize>),
) {
    let mut backoff = Backoff::default();
    loop {
        let mut source = match open_camera(&config) {
            Ok(s) => s,
            Err(e) => {
                wait_after_failure(&mut backoff, &e, "retrying").await;
                continue;
            }
        };
        loop {
            let period = source.period();
            // Devices block until their next buffer: keep them off the runtime's threads.
            let got = if period.is_some() {
                source.next_frame().map(|f| (source, f))
            } else {
                let joined =
                    tokio::task::spawn_blocking(move || source.next_frame().map(|f| (source, f)))
                        .await;
                match joined {
                    Ok(r) => r,
                    Err(_) => break,
                }
            };
            match got {
                Ok((s, frame)) => {
                    source = s;
                    backoff.reset();
                    if tx.send(Some(Arc::new(frame))).is_err() {
                        return;
                    }
                    // A full queue already holds news: the loop checks every camera then.
                    let _ = news.try_send(index);
                    if let Some(p) = period {
                        tokio::time::sleep(p).await;
                    }
                }
                Err(e) => {
                    wait_after_failure(&mut backoff, &e, "reopening").await;
                    break;
                }
            }
        }
    }
}

/// LiDAR task: forwards sweeps of LiDAR `index`; reopens a failed source with backoff.
async fn lidar_task(config: Config, tx: mpsc::Sender<(usize, OwnedSweep)>, index: usize) {
    let mut backoff = Backoff::default();
    loop {
        let mut source = match open_lidar(&config).await {
            Ok(s) => s,
            Err(e) => {
                wait_after_failure(&mut backoff, &e, "retrying").await;
                continue;
            }
        };
        loop {
            match source.next_sweep().await {
                Ok(s) => {
                    backoff.reset();
                    if tx.send((index, s)).await.is_err() {
                        return;
                    }
                }
                Err(e) => {
                    wait_after_failure(&mut backoff, &e, "reopening").await;
                    break;
                }
            }
        }
    }
}

/// sd_notify, ignoring errors (no-op without `NOTIFY_SOCKET`).
fn notify(state: &[sd_notify::NotifyState<'_>]) {
    let _ = sd_notify::notify(false, state);
}

/// What the control loop holds during a run: per camera its frames, per LiDAR its sweeps.
#[derive(Default)]
struct RunBuffers {
    /// Every camera's frames, summed as they arrive (the mean is what is calibrated).
    frames: Vec<FrameSum>,
    sweeps: Vec<Vec<Vec<Point>>>,
    /// The packets of `sweeps`.
    counts: PacketCounts,
    deadline: Option<tokio::time::Instant>,
}

impl RunBuffers {
    fn new(cameras: usize, lidars: usize, deadline: tokio::time::Instant) -> Self {
        RunBuffers {
            frames: vec![FrameSum::default(); cameras],
            sweeps: vec![Vec::new(); lidars],
            counts: PacketCounts::default(),
            deadline: Some(deadline),
        }
    }

    fn complete(&self, frames: usize, sweeps: usize) -> bool {
        self.frames.iter().all(|f| f.frames() >= frames)
            && self.sweeps.iter().all(|s| s.len() >= sweeps)
    }

    /// The timeout's reason: what every sensor delivered.
    fn shortfall(&self, config: &Config, names: &SensorNames) -> String {
        let mut parts = Vec::new();
        for (name, f) in names.cameras.iter().zip(&self.frames) {
            parts.push(format!("{} of {} frames{name}", f.frames(), config.frames));
        }
        for (name, s) in names.lidars.iter().zip(&self.sweeps) {
            parts.push(format!("{} of {} sweeps{name}", s.len(), config.sweeps));
        }
        format!("capture timed out with {}", parts.join(" and "))
    }
}

/// How the timeout names each sensor: nothing for the one-pair vehicle, " of camera `NAME`"
/// for a rig's.
#[derive(Clone)]
struct SensorNames {
    cameras: Vec<String>,
    lidars: Vec<String>,
}

impl SensorNames {
    fn of(config: &Config) -> Self {
        match &config.rig {
            None => SensorNames { cameras: vec![String::new()], lidars: vec![String::new()] },
            Some(r) => SensorNames {
                cameras: r.cameras.iter().map(|c| format!(" of camera `{}`", c.name)).collect(),
                lidars: r.lidars.iter().map(|l| format!(" of LiDAR `{}`", l.name)).collect(),
            },
        }
    }
}

/// What the latest frames show of the room.
#[derive(Clone, Debug, PartialEq)]
enum RoomView {
    /// Every watched camera shows its boards.
    Seen,
    /// A camera shows too few: "2 of 6 boards seen of camera `front`".
    Short(String),
    /// A camera's frames cannot be searched (the operator must hear of it once).
    Unsearchable(String),
}

/// What every watched camera's latest frame, `(camera, boards it needs, frame)`, shows;
/// stops at the first camera short of its boards (the trigger polls about once a second).
fn room_seen<C: Calibrator>(
    calibrator: &mut C,
    latest: &[(usize, usize, Arc<GreyFrame>)],
    names: &SensorNames,
) -> RoomView {
    for (camera, need, frame) in latest {
        let name = names.cameras.get(*camera).map_or("", String::as_str);
        match calibrator.count_boards(*camera, frame) {
            Err(e) => return RoomView::Unsearchable(frame_problem(name, frame, &e)),
            Ok(boards) if boards < *need => {
                return RoomView::Short(format!("{boards} of {need} boards seen{name}"))
            }
            Ok(_) => {}
        }
    }
    RoomView::Seen
}

/// Why a camera's frames cannot be searched, in the operator's terms; `name` as
/// [`SensorNames`] gives it (empty for the one-pair vehicle's camera).
fn frame_problem(name: &str, frame: &GreyFrame, e: &DetectError) -> String {
    let camera = match name.strip_prefix(" of ") {
        Some(named) => named.to_string(),
        None => "the camera".to_string(),
    };
    match e {
        DetectError::FrameSize { width, height, .. } => format!(
            "{camera}: its frames are {}x{}, the room's camera is {width}x{height}: no board \
             can be found in them; check the device's format or the camera's size in the room \
             (or rig) file",
            frame.width, frame.height
        ),
        e => format!("{camera}: its frames cannot be searched for boards: {e}"),
    }
}

/// What the daemon last saw while it waited for a run, for the reason it gives up with.
#[derive(Default)]
struct Waiting {
    /// The latest board count's view (`None`: no frame from every watched camera yet).
    room: Option<RoomView>,
    /// Sweeps received from any LiDAR.
    sweeps: u64,
}

impl Waiting {
    /// "the room was never seen: 2 of 6 boards seen of camera `front`", ...
    fn describe(&self, phase: trigger::Phase, names: &SensorNames) -> String {
        let lidars = names.lidars.len();
        match (&self.room, phase) {
            (None, _) => "no frame from every camera yet (see the camera's warnings)".into(),
            (Some(RoomView::Unsearchable(problem)), _) => problem.clone(),
            (Some(RoomView::Short(short)), trigger::Phase::Idle) => {
                format!("the room was never seen: {short}")
            }
            (Some(_), _) if self.sweeps == 0 => {
                let from = match lidars {
                    1 => "the LiDAR".to_string(),
                    n => format!("any of the {n} LiDARs"),
                };
                format!(
                    "the room is seen but no LiDAR sweep arrived from {from} (see its warnings)"
                )
            }
            (Some(_), trigger::Phase::Done(_)) => {
                "a run ended and the room must be left before the next".into()
            }
            (Some(_), _) => "the room is seen but the vehicle never stood still long enough \
                 (the LiDAR's sweeps kept moving; see `[trigger]` settle_s and still_m)"
                .into(),
        }
    }
}

/// Warnings given once each: a problem that lasts is said when it appears, not every
/// second.
#[derive(Default)]
struct SaidOnce(std::collections::HashSet<String>);

impl SaidOnce {
    fn warn(&mut self, problem: String) {
        if !self.0.contains(&problem) {
            tracing::warn!("{problem}");
            self.0.insert(problem);
        }
    }
}

/// The configuration of each camera task and each LiDAR task.
fn sensor_configs(config: &Config) -> (Vec<Config>, Vec<Config>) {
    match &config.rig {
        None => (vec![config.clone()], vec![config.clone()]),
        Some(r) => (
            r.cameras.iter().map(|c| config.with_camera(c)).collect(),
            r.lidars.iter().map(|l| config.with_lidar(l)).collect(),
        ),
    }
}

/// The sensor table the service describes before a rig's record is in force.
fn configured_sensors(
    config: &Config,
    room: &crate::target::Room,
) -> crate::service::uds::SensorTable {
    use crate::service::uds::{SensorKind, SensorTable};
    let Some(r) = &config.rig else { return SensorTable::one_pair(room.lidar.is_some()) };
    let sensors = r
        .cameras
        .iter()
        .map(|c| (SensorKind::Camera, c.name.as_str()))
        .chain(r.lidars.iter().map(|l| (SensorKind::Lidar, l.name.as_str())));
    // A rig holds at most 8 + 8 checked names: they fit the table's 16.
    SensorTable::of(sensors).unwrap_or_default()
}

async fn run_daemon<C: Calibrator>(
    d: Daemon<C>,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<RunSummary, DaemonError> {
    let Daemon { mut config, calibrator, options, requests_tx, mut requests, shared } = d;
    let room = load_room(&config)?;
    if config.trigger.min_boards == 0 {
        config.trigger.min_boards = room.board.count.max(1) as usize;
    }
    let store = Store::open(&config.store, config.keep)?;
    let _writer = store.lock_writer()?;
    let current = store.current()?;
    if let Some(r) = &current {
        tracing::info!(generation = r.generation, "calibration in force");
    }
    set_shared(&shared, |s| s.current = current);
    let calibrator = Arc::new(Mutex::new(calibrator));

    let (camera_configs, lidar_configs) = sensor_configs(&config);
    let names = SensorNames::of(&config);
    let watched = config.watched_cameras();
    let (news_tx, mut news) = mpsc::channel::<usize>(2 * camera_configs.len());
    let (sweep_tx, mut sweeps) = mpsc::channel::<(usize, OwnedSweep)>(4 * lidar_configs.len());
    let (stop_tx, stop_rx) = watch::channel(false);
    let mut tasks = tokio::task::JoinSet::new();
    let mut frames = Vec::new();
    for (i, camera) in camera_configs.into_iter().enumerate() {
        let (frame_tx, rx) = watch::channel(None::<Arc<GreyFrame>>);
        frames.push(rx);
        tasks.spawn(camera_task(camera, frame_tx, (i, news_tx.clone())));
    }
    drop(news_tx);
    let (cameras, lidars) = (frames.len(), lidar_configs.len());
    for (i, lidar) in lidar_configs.into_iter().enumerate() {
        tasks.spawn(lidar_task(lidar, sweep_tx.clone(), i));
    }
    drop(sweep_tx);
    if let Some(svc) = config.service.clone() {
        let sensors = configured_sensors(&config, &room);
        let backend =
            DaemonBackend::new(shared.clone(), requests_tx.clone(), store.clone(), sensors);
        tasks.spawn(backend::service_task(svc, backend, stop_rx));
    }
    drop(requests_tx);
    notify(&[sd_notify::NotifyState::Ready, sd_notify::NotifyState::Status("idle")]);

    let start = tokio::time::Instant::now();
    let now_s = || start.elapsed().as_secs_f64();
    let mut trigger = Trigger::new(config.trigger);
    let mut detect = tokio::time::interval(Duration::from_secs_f64(config.detect_interval_s));
    detect.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut watchdog_usec = 0u64;
    let watchdog_on = sd_notify::watchdog_enabled(false, &mut watchdog_usec);
    let wd_period = Duration::from_micros(if watchdog_on {
        (watchdog_usec / 2).max(1000)
    } else {
        3_600_000_000
    });
    let mut watchdog = tokio::time::interval(wd_period);
    // current.json emptied or damaged behind the daemon's back is put back within a second.
    let mut store_check = tokio::time::interval(Duration::from_secs(1));
    store_check.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let (mut image_prev, mut image_next) = (RangeImage::new(360, 128), RangeImage::new(360, 128));
    let mut have_prev = false;
    let mut scratch = Vec::new();
    let mut run = RunBuffers::default();
    let mut solving: Option<tokio::task::JoinHandle<CalibrationOutcome>> = None;
    // The packets of the sweeps being calibrated, for the run's reason.
    let mut solving_counts = PacketCounts::default();
    let mut summary = RunSummary::default();
    let mut last_state = DaemonState::Idle;
    let mut fatal: Option<DaemonError> = None;
    let mut said = SaidOnce::default();
    let mut waiting = Waiting::default();
    let give_up = options.give_up_after.filter(|_| options.once);
    let give_up_at = give_up.map(|after| tokio::time::Instant::now() + after);
    tokio::pin!(shutdown);

    loop {
        let capturing = trigger.phase() == trigger::Phase::Capturing;
        let mut action = Action::None;
        let mut outcome: Option<CalibrationOutcome> = None;
        tokio::select! {
            _ = &mut shutdown => {
                log_abandoned(capturing, solving.is_some(), &shared);
                break;
            }
            _ = watchdog.tick(), if watchdog_on => notify(&[sd_notify::NotifyState::Watchdog]),
            _ = store_check.tick() => verify_store(&store, &shared),
            _ = detect.tick(), if !capturing && solving.is_none() => {
                let latest: Option<Vec<_>> = watched
                    .iter()
                    .map(|&(camera, need)| frames[camera].borrow().clone().map(|f| (camera, need, f)))
                    .collect();
                if let Some(latest) = latest {
                    let (cal, names) = (calibrator.clone(), names.clone());
                    let view = tokio::task::spawn_blocking(move || {
                        let poisoned = RoomView::Short("the calibrator is poisoned".into());
                        cal.lock().map_or(poisoned, |mut c| room_seen(&mut *c, &latest, &names))
                    }).await.unwrap_or(RoomView::Short("the board count failed".into()));
                    match &view {
                        RoomView::Short(short) => tracing::debug!("{short}"),
                        RoomView::Unsearchable(problem) => said.warn(problem.clone()),
                        RoomView::Seen => {}
                    }
                    action = trigger.on_room(now_s(), view == RoomView::Seen);
                    waiting.room = Some(view);
                }
            }
            _ = sleep_until_opt(give_up_at), if !capturing && solving.is_none() && summary.runs == 0 => {
                let seconds = give_up.map_or(0, |d| d.as_secs());
                let waiting = waiting.describe(trigger.phase(), &names);
                tracing::error!("gave up after {seconds} s without a calibration run: {waiting}");
                fatal = Some(DaemonError::GaveUp { seconds, waiting });
                break;
            }
            _ = sleep_until_opt(run.deadline), if capturing => {
                outcome = Some(CalibrationOutcome::Failed(run.shortfall(&config, &names)));
            }
            Some(_) = news.recv() => {
                for (rx, taken) in frames.iter_mut().zip(run.frames.iter_mut()) {
                    if !capturing || !rx.has_changed().unwrap_or(false) {
                        continue;
                    }
                    let frame = rx.borrow_and_update().clone();
                    if let Some(f) = frame.filter(|_| taken.frames() < config.frames) {
                        if let Err(e) = taken.add(&f) {
                            tracing::warn!("camera frame left out of the run: {e}");
                        }
                    }
                }
            }
            Some((lidar, sweep)) = sweeps.recv() => {
                waiting.sweeps += 1;
                if lidar == 0 {
                    image_next.fill(&sweep.points);
                    if have_prev {
                        if let Some(m) = sweep_motion(&image_prev, &image_next, &mut scratch) {
                            action = trigger.on_motion(now_s(), m);
                        }
                    }
                    std::mem::swap(&mut image_prev, &mut image_next);
                    have_prev = true;
                }
                if let Some(taken) = run.sweeps.get_mut(lidar).filter(|t| capturing && t.len() < config.sweeps) {
                    let of = format!("{}{}", config.sweeps, names.lidars[lidar]);
                    log_captured_sweep(&sweep, taken.len() + 1, &of);
                    run.counts.add(sweep.counts);
                    taken.push(sweep.points);
                }
            }
            Some(()) = requests.recv() => {
                let (accepted, a) = trigger.request();
                if !accepted {
                    tracing::info!("calibration request ignored: a run is in progress");
                }
                action = a;
            }
            joined = async {
                match solving.as_mut() {
                    Some(h) => h.await,
                    None => std::future::pending().await,
                }
            }, if solving.is_some() => {
                solving = None;
                let joined = joined.unwrap_or_else(|e| CalibrationOutcome::Failed(format!("calibrator panicked: {e}")));
                outcome = Some(with_sweep_counts(joined, &solving_counts));
            }
        }
        if action == Action::Capture {
            tracing::info!("capturing {} frames and {} sweeps", config.frames, config.sweeps);
            let deadline =
                tokio::time::Instant::now() + Duration::from_secs_f64(config.capture_timeout_s);
            run = RunBuffers::new(cameras, lidars, deadline);
            // The frames in the channels now may predate the trigger: wait for fresh ones.
            for rx in &mut frames {
                rx.borrow_and_update();
            }
        }
        if trigger.phase() == trigger::Phase::Capturing
            && run.complete(config.frames, config.sweeps)
        {
            trigger.on_captured();
            solving_counts = run.counts;
            solving = Some(start_solve(&calibrator, &shared, std::mem::take(&mut run)));
        }
        if let Some(outcome) = outcome {
            let (verdict, failure) = finish_run(&store, &shared, outcome, &mut summary).await;
            trigger.on_outcome(verdict);
            if options.once {
                publish_state(&shared, trigger.state(), &mut last_state);
                // `--once` reports a run that left nothing in the store as an error.
                fatal = failure;
                break;
            }
        }
        publish_state(&shared, trigger.state(), &mut last_state);
    }
    let _ = stop_tx.send(true);
    notify(&[sd_notify::NotifyState::Stopping]);
    // Give the service a moment to finish its exchange, then stop the sources.
    let _ = tokio::time::timeout(Duration::from_millis(200), async {
        while tasks.len() > 1 {
            if tasks.join_next().await.is_none() {
                break;
            }
        }
    })
    .await;
    tasks.shutdown().await;
    summary.in_force = shared.lock().ok().and_then(|s| s.current.clone());
    match fatal {
        Some(e) => Err(e),
        None => Ok(summary),
    }
}

/// Says that a stop ended a run before its result reached the store (nothing when no run
/// was under way): the report picture of a run can exist, its result cannot.
fn log_abandoned(capturing: bool, solving: bool, shared: &Arc<Mutex<Shared>>) {
    let doing = match (capturing, solving) {
        (true, _) => "capturing",
        (_, true) => "calibrating",
        _ => return,
    };
    let generation =
        shared.lock().ok().and_then(|s| s.current.as_ref().map(|r| r.generation)).unwrap_or(0);
    let in_force = match generation {
        0 => "no calibration is in force".to_string(),
        g => format!("generation {g} stays in force"),
    };
    tracing::warn!(
        "stopped while {doing}: the run in progress is abandoned and nothing of it was \
         stored; {in_force}"
    );
}

/// Puts `current.json` back from the record in force when it was emptied, damaged or
/// replaced (see [`Store::verify_current`]); takes a newer valid one written by another
/// process.
pub(crate) fn verify_store(store: &Store, shared: &Arc<Mutex<Shared>>) {
    let held = shared.lock().ok().and_then(|s| s.current.clone());
    match store.verify_current(held.as_ref()) {
        Ok(now) if now != held => set_shared(shared, |s| s.current = now),
        Ok(_) => {}
        Err(e) => tracing::error!("{e}"),
    }
}

async fn sleep_until_opt(at: Option<tokio::time::Instant>) {
    match at {
        Some(t) => tokio::time::sleep_until(t).await,
        None => std::future::pending().await,
    }
}

fn set_shared(shared: &Arc<Mutex<Shared>>, f: impl FnOnce(&mut Shared)) {
    if let Ok(mut s) = shared.lock() {
        f(&mut s);
    }
}

fn publish_state(shared: &Arc<Mutex<Shared>>, state: DaemonState, last: &mut DaemonState) {
    if state != *last {
        *last = state;
        tracing::info!("state: {}", state.name());
        set_shared(shared, |s| s.state = state);
        notify(&[sd_notify::NotifyState::Status(state.name())]);
    }
}

/// Logs a sweep taken into a run, with its packet counts.
fn log_captured_sweep(sweep: &OwnedSweep, n: usize, of: &str) {
    let points = sweep.points.len();
    match sweep.counts.incomplete() {
        Some(note) => tracing::warn!("sweep {n} of {of}: {points} points; {note}"),
        None if sweep.counts.packets > 0 => {
            tracing::info!("sweep {n} of {of}: {points} points, {}", sweep.counts)
        }
        None => tracing::info!("sweep {n} of {of}: {points} points"),
    }
}

/// A failed or rejected outcome's reason, with the sweeps' lost packets when they lost
/// some: "no LiDAR board could be paired; LiDAR sweep incomplete: 812 of 1800 packets
/// lost". An accepted result is left as it is.
fn with_sweep_counts(outcome: CalibrationOutcome, counts: &PacketCounts) -> CalibrationOutcome {
    let Some(note) = counts.incomplete() else { return outcome };
    match outcome {
        CalibrationOutcome::Failed(why) => CalibrationOutcome::Failed(format!("{why}; {note}")),
        CalibrationOutcome::Done(mut r) if r.pair.status != Status::Accepted => {
            r.pair.reason = Some(match r.pair.reason.take() {
                Some(why) => format!("{why}; {note}"),
                None => note,
            });
            CalibrationOutcome::Done(r)
        }
        done => done,
    }
}

/// Averages each camera's frames, accumulates each LiDAR's sweeps, calibrates on a
/// blocking thread.
fn start_solve<C: Calibrator>(
    calibrator: &Arc<Mutex<C>>,
    shared: &Arc<Mutex<Shared>>,
    run: RunBuffers,
) -> tokio::task::JoinHandle<CalibrationOutcome> {
    let cal = calibrator.clone();
    let current = shared.lock().ok().and_then(|s| s.current.clone());
    tokio::task::spawn_blocking(move || {
        // The sums become means, and a camera's sweeps one cloud, before the detectors run:
        // the run's buffers are not held beside the detectors' workspaces.
        let Some(frames) =
            run.frames.into_iter().map(FrameSum::into_mean).collect::<Option<Vec<_>>>()
        else {
            return CalibrationOutcome::Failed("a camera delivered no frame".into());
        };
        let clouds: Vec<Vec<Point>> =
            run.sweeps.into_iter().map(crate::lidar::accumulate_sweeps).collect();
        let Ok(mut c) = cal.lock() else {
            return CalibrationOutcome::Failed("calibrator poisoned by an earlier panic".into());
        };
        c.calibrate(&frames, &clouds, current.as_ref().map(|r| &r.result))
    })
}

/// Stores the outcome (accepted → new generation; rejected → kept aside) and reports it;
/// with the verdict, the error when nothing reached the store (a failed run or write).
async fn finish_run(
    store: &Store,
    shared: &Arc<Mutex<Shared>>,
    outcome: CalibrationOutcome,
    summary: &mut RunSummary,
) -> (Verdict, Option<DaemonError>) {
    summary.runs += 1;
    let now = unix_now();
    let store = store.clone();
    let stored = tokio::task::spawn_blocking(move || match outcome {
        CalibrationOutcome::Done(r) if r.pair.status == Status::Accepted => {
            store.commit(&r, now).map(|rec| (Verdict::Accepted, Ok(Some(rec))))
        }
        CalibrationOutcome::Done(r) => {
            let what = if r.is_rig() { "rig calibration" } else { "calibration" };
            let why = r.pair.reason.as_deref().unwrap_or("no reason given");
            tracing::warn!("{what} rejected: {why}");
            store.record_rejected(&r, now).map(|_| (Verdict::Rejected, Ok(None)))
        }
        CalibrationOutcome::Failed(why) => {
            tracing::error!("calibration failed: {why}");
            Ok((Verdict::Error, Err(why)))
        }
    })
    .await;
    let (verdict, record, failure) = match stored {
        Ok(Ok((v, Ok(record)))) => (v, record, None),
        Ok(Ok((v, Err(why)))) => (v, None, Some(DaemonError::RunFailed(why))),
        // InForce and Pending say themselves what holds; any other error stored nothing.
        Ok(Err(e)) => {
            let record = e.in_force().cloned();
            match (&record, &e) {
                (Some(_), _) | (_, StoreError::Pending { .. }) => tracing::error!("{e}"),
                _ => tracing::error!("{e}; the run's result was not stored"),
            }
            let verdict = if record.is_some() { Verdict::Accepted } else { Verdict::Error };
            (verdict, record, Some(DaemonError::Store(e)))
        }
        Err(e) => {
            tracing::error!("store task: {e}");
            (Verdict::Error, None, Some(DaemonError::RunFailed(format!("store task: {e}"))))
        }
    };
    match verdict {
        Verdict::Accepted => summary.accepted += 1,
        Verdict::Rejected => summary.rejected += 1,
        Verdict::Error => summary.failed += 1,
    }
    set_shared(shared, |s| {
        if let Some(rec) = record {
            tracing::info!(generation = rec.generation, "calibration accepted and in force");
            s.current = Some(rec);
        }
        let state = match verdict {
            Verdict::Accepted => DaemonState::Accepted,
            Verdict::Rejected => DaemonState::Rejected,
            Verdict::Error => DaemonState::Error,
        };
        s.runs += 1;
        s.last =
            Some(Outcome { state, generation: s.current.as_ref().map_or(0, |r| r.generation) });
    });
    (verdict, failure)
}
