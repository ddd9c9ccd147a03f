//! The daemon configuration file (TOML), exactly as DESIGN.md's "Daemon configuration",
//! plus optional tuning keys with defaults. Relative paths are resolved against the
//! directory of the configuration file.
//!
//! Extra keys (all optional): `[camera] replay_fps` (10); `[lidar] multicast` (an IPv4
//! group to join), `replay_speed` (1.0), `calibration` (the unit's own angle-correction
//! file: Hesai CSV or Velodyne YAML; default the model's nominal table); `[trigger] min_boards` (the room's board
//! count, `board.count`), `still_m` (0.01),
//! `leave_s` (3.0), `frames` (5, averaged), `sweeps` (3, accumulated),
//! `detect_interval_s` (1.0), `capture_timeout_s` (10.0); `keep` (16, history bound);
//! `[service] socketcand` (`"listen"`: the daemon serves the socketcand endpoint, a
//! virtual CAN bus on TCP that service tools connect to; `"connect"`: it connects to a
//! socketcand server bridging a real bus).
//!
//! A rig (DESIGN.md "Vehicles with several sensors"): `rig = "rig.toml"` and one
//! `[[camera]]` / `[[lidar]]` table per sensor of the rig, each with its `name` and the
//! keys of `[camera]` / `[lidar]`. Every sensor of the rig needs exactly one source, and
//! the rig at least one LiDAR (the trigger watches the first LiDAR's motion); the first
//! camera's and first LiDAR's sources are also [`Config::camera`] / [`Config::lidar`].
//! The room counts as seen when every camera sees its boards: `[trigger] cameras` (names
//! of the rig's cameras) narrows that to a subset, a `[[camera]]` table's `min_boards`
//! sets that camera's count (default `[trigger] min_boards`).

use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::trigger::{Mode, TriggerConfig};

/// Where camera frames come from.
#[derive(Clone, Debug, PartialEq)]
pub enum CameraSource {
    /// A V4L2 device (`v4l2:/dev/video0`).
    V4l2(PathBuf),
    /// An image file or a folder of them, looped (`replay:PATH`).
    Replay(PathBuf),
}

/// Where LiDAR sweeps come from.
#[derive(Clone, Debug, PartialEq)]
pub enum LidarSource {
    /// Live packets (`udp:0.0.0.0:2368`).
    Udp(SocketAddr),
    /// A pcap/pcapng capture, or a PCD file or folder (`replay:PATH`).
    Replay(PathBuf),
}

/// What the daemon does with a `socketcand:HOST:PORT` transport.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SocketcandRole {
    /// Listen on HOST:PORT: the daemon is the socketcand endpoint (DESIGN.md: bench
    /// tools, python-can's `socketcand` interface and `roomcal query` connect to it).
    #[default]
    Listen,
    /// Connect to a socketcand server at HOST:PORT that bridges a real CAN bus.
    Connect,
}

/// The UDS service on CAN.
#[derive(Clone, Debug, PartialEq)]
pub struct ServiceConfig {
    /// `socketcan:IFACE` or `socketcand:HOST:PORT[/CHANNEL]`.
    pub transport: String,
    /// For `socketcand:` transports: listen (default) or connect.
    pub socketcand: SocketcandRole,
    pub request_id: u32,
    pub response_id: u32,
    pub secret_file: PathBuf,
}

/// One camera of a rig and its source.
#[derive(Clone, Debug, PartialEq)]
pub struct RigCameraSource {
    pub name: String,
    pub source: CameraSource,
    pub replay_fps: f64,
    /// Whether the trigger waits for this camera to see the room (`[trigger] cameras`;
    /// every camera when that key is absent).
    pub watched: bool,
    /// Boards this camera must see for the room to count as seen (`min_boards` of its
    /// `[[camera]]` table); `None`: `[trigger] min_boards`.
    pub min_boards: Option<usize>,
}

/// One LiDAR of a rig and its source.
#[derive(Clone, Debug, PartialEq)]
pub struct RigLidarSource {
    pub name: String,
    /// The rig file's model (itself `None` for `pcd`); `None` for the one-pair vehicle's
    /// LiDAR (the room file's).
    pub model: Option<Option<crate::lidar::Model>>,
    pub source: LidarSource,
    pub multicast: Option<Ipv4Addr>,
    pub replay_speed: f64,
    pub calibration: Option<PathBuf>,
}

/// A rig's sensors and their sources, in the rig file's order.
#[derive(Clone, Debug, PartialEq)]
pub struct RigSources {
    /// The rig file, resolved.
    pub path: PathBuf,
    pub rig: crate::rig::Rig,
    pub cameras: Vec<RigCameraSource>,
    pub lidars: Vec<RigLidarSource>,
}

/// The whole configuration, paths resolved.
#[derive(Clone, Debug, PartialEq)]
pub struct Config {
    pub room: PathBuf,
    pub store: PathBuf,
    pub keep: usize,
    pub camera: CameraSource,
    pub replay_fps: f64,
    pub lidar: LidarSource,
    pub multicast: Option<Ipv4Addr>,
    pub replay_speed: f64,
    /// The LiDAR unit's angle-correction file (nominal tables when absent).
    pub lidar_calibration: Option<PathBuf>,
    /// `min_boards` here is 0 when the file does not set it: the daemon then uses the
    /// room's board count.
    pub trigger: TriggerConfig,
    /// Frames averaged and sweeps accumulated per run.
    pub frames: usize,
    pub sweeps: usize,
    pub detect_interval_s: f64,
    pub capture_timeout_s: f64,
    pub service: Option<ServiceConfig>,
    /// A rig's sensors (`rig = …` with `[[camera]]` / `[[lidar]]`); `None`: the room's
    /// one-pair vehicle.
    pub rig: Option<RigSources>,
    /// The LiDAR model of [`Config::lidar`] when it is not the room file's (a rig's
    /// LiDAR, itself `None` for `pcd`); `None`: the room's.
    pub lidar_model: Option<Option<crate::lidar::Model>>,
}

impl Config {
    /// The cameras the trigger waits for, each with the boards it must see: (index in the
    /// rig's order, boards). The one-pair vehicle's camera needs `trigger.min_boards`.
    pub fn watched_cameras(&self) -> Vec<(usize, usize)> {
        let need = |own: Option<usize>| own.unwrap_or(self.trigger.min_boards);
        match &self.rig {
            None => vec![(0, self.trigger.min_boards)],
            Some(r) => (r.cameras.iter().enumerate())
                .filter(|(_, c)| c.watched)
                .map(|(i, c)| (i, need(c.min_boards)))
                .collect(),
        }
    }

    /// This configuration with `camera` as its camera (a rig's camera task).
    pub fn with_camera(&self, camera: &RigCameraSource) -> Config {
        Config { camera: camera.source.clone(), replay_fps: camera.replay_fps, ..self.clone() }
    }

    /// This configuration with `lidar` as its LiDAR (a rig's LiDAR task).
    pub fn with_lidar(&self, lidar: &RigLidarSource) -> Config {
        Config {
            lidar: lidar.source.clone(),
            multicast: lidar.multicast,
            replay_speed: lidar.replay_speed,
            lidar_calibration: lidar.calibration.clone(),
            lidar_model: lidar.model,
            ..self.clone()
        }
    }
}

/// Why the configuration cannot be used; names the file.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("{path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    room: PathBuf,
    store: PathBuf,
    #[serde(default = "default_keep")]
    keep: usize,
    camera: Sensors<RawCamera>,
    lidar: Sensors<RawLidar>,
    rig: Option<PathBuf>,
    #[serde(default)]
    trigger: RawTrigger,
    service: Option<RawService>,
}

/// `[camera]` (the one-pair vehicle) or `[[camera]]` (a rig's sensors, named); the same
/// for `[lidar]`.
enum Sensors<T> {
    One(T),
    Named(Vec<T>),
}

impl<'de, T: serde::de::DeserializeOwned> Deserialize<'de> for Sensors<T> {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        // Through a value, so each form keeps its own precise error (an untagged enum
        // would only say that neither form matched).
        let value = toml::Value::deserialize(d)?;
        let parsed = match value {
            toml::Value::Array(_) => value.try_into().map(Sensors::Named),
            _ => value.try_into().map(Sensors::One),
        };
        parsed.map_err(serde::de::Error::custom)
    }
}

impl<T> Sensors<T> {
    fn all(&self) -> &[T] {
        match self {
            Sensors::One(one) => std::slice::from_ref(one),
            Sensors::Named(many) => many,
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    /// A rig's camera: its name in the rig file.
    name: Option<String>,
    source: String,
    #[serde(default = "default_fps")]
    replay_fps: f64,
    /// A rig's camera: the boards it must see for the room to count as seen.
    min_boards: Option<usize>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLidar {
    /// A rig's LiDAR: its name in the rig file.
    name: Option<String>,
    source: String,
    multicast: Option<Ipv4Addr>,
    #[serde(default = "one")]
    replay_speed: f64,
    calibration: Option<PathBuf>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawTrigger {
    mode: Mode,
    settle_s: f64,
    min_boards: Option<usize>,
    /// A rig's cameras the trigger waits for (default: every camera).
    cameras: Option<Vec<String>>,
    still_m: f32,
    leave_s: f64,
    frames: usize,
    sweeps: usize,
    detect_interval_s: f64,
    capture_timeout_s: f64,
}

impl Default for RawTrigger {
    fn default() -> Self {
        let t = TriggerConfig::default();
        RawTrigger {
            mode: t.mode,
            settle_s: t.settle_s,
            min_boards: None,
            cameras: None,
            still_m: t.still_m,
            leave_s: t.leave_s,
            frames: 5,
            sweeps: 3,
            detect_interval_s: 1.0,
            capture_timeout_s: 10.0,
        }
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawService {
    transport: String,
    #[serde(default)]
    socketcand: SocketcandRole,
    #[serde(default = "default_request_id")]
    request_id: u32,
    #[serde(default = "default_response_id")]
    response_id: u32,
    secret_file: PathBuf,
}

fn default_keep() -> usize {
    crate::store::DEFAULT_KEEP
}
fn default_fps() -> f64 {
    10.0
}
fn one() -> f64 {
    1.0
}
fn default_request_id() -> u32 {
    crate::service::DEFAULT_REQUEST_ID
}
fn default_response_id() -> u32 {
    crate::service::DEFAULT_RESPONSE_ID
}

/// Reads and checks the configuration file at `path`.
pub fn load(path: &Path) -> Result<Config, ConfigError> {
    let text = std::fs::read_to_string(path)
        .map_err(|source| ConfigError::Read { path: path.to_path_buf(), source })?;
    parse(&text, path)
}

/// Parses configuration text; `path` names it and anchors relative paths.
pub fn parse(text: &str, path: &Path) -> Result<Config, ConfigError> {
    let invalid = |message: String| ConfigError::Invalid { path: path.to_path_buf(), message };
    let raw: RawConfig =
        toml::from_str(text).map_err(|e| invalid(crate::room::toml_message(text, &e)))?;
    let base = path.parent().unwrap_or(Path::new("."));
    let resolve = |p: &Path| if p.is_absolute() { p.to_path_buf() } else { base.join(p) };
    let rig = match &raw.rig {
        Some(rig) => Some(rig_sources(&resolve(rig), &raw, &resolve).map_err(invalid)?),
        None => {
            one_pair_only(&raw).map_err(invalid)?;
            None
        }
    };
    // The first camera and LiDAR: the one-pair vehicle's, or the rig's first.
    let (camera, lidar) = match &rig {
        Some(r) => (r.cameras[0].clone(), r.lidars[0].clone()),
        None => {
            let (c, l) = (&raw.camera.all()[0], &raw.lidar.all()[0]);
            let camera = RigCameraSource {
                name: crate::rig::PAIR_CAMERA.into(),
                source: camera_source(&c.source, "camera.source", &resolve).map_err(invalid)?,
                replay_fps: c.replay_fps,
                watched: true,
                min_boards: None,
            };
            let lidar = RigLidarSource {
                name: crate::rig::PAIR_LIDAR.into(),
                model: None,
                source: lidar_source(&l.source, "lidar.source", &resolve).map_err(invalid)?,
                multicast: l.multicast,
                replay_speed: l.replay_speed,
                calibration: l.calibration.as_deref().map(&resolve),
            };
            (camera, lidar)
        }
    };
    check_numbers(&raw).map_err(|e| invalid(e.to_string()))?;
    check_paths(&raw).map_err(invalid)?;
    let t = raw.trigger;
    if let Some(s) = &raw.service {
        crate::service::endpoint::Endpoint::parse(&s.transport)
            .map_err(|e| invalid(format!("service.transport: {e}")))?;
        check_ids(s.request_id, s.response_id).map_err(invalid)?;
    }
    Ok(Config {
        room: resolve(&raw.room),
        store: resolve(&raw.store),
        keep: raw.keep,
        camera: camera.source,
        replay_fps: camera.replay_fps,
        lidar: lidar.source,
        multicast: lidar.multicast,
        replay_speed: lidar.replay_speed,
        lidar_calibration: lidar.calibration,
        lidar_model: lidar.model,
        rig,
        trigger: TriggerConfig {
            mode: t.mode,
            min_boards: t.min_boards.unwrap_or(0),
            settle_s: t.settle_s,
            still_m: t.still_m,
            leave_s: t.leave_s,
        },
        frames: t.frames,
        sweeps: t.sweeps,
        detect_interval_s: t.detect_interval_s,
        capture_timeout_s: t.capture_timeout_s,
        service: raw.service.map(|s| ServiceConfig {
            transport: s.transport,
            socketcand: s.socketcand,
            request_id: s.request_id,
            response_id: s.response_id,
            secret_file: resolve(&s.secret_file),
        }),
    })
}

fn camera_source(
    text: &str,
    key: &str,
    resolve: &impl Fn(&Path) -> PathBuf,
) -> Result<CameraSource, String> {
    if let Some(dev) = text.strip_prefix("v4l2:") {
        Ok(CameraSource::V4l2(PathBuf::from(dev)))
    } else if let Some(p) = text.strip_prefix("replay:") {
        Ok(CameraSource::Replay(resolve(Path::new(p))))
    } else {
        Err(format!("{key} `{text}`: expected v4l2:DEVICE or replay:PATH"))
    }
}

fn lidar_source(
    text: &str,
    key: &str,
    resolve: &impl Fn(&Path) -> PathBuf,
) -> Result<LidarSource, String> {
    if let Some(a) = text.strip_prefix("udp:") {
        Ok(LidarSource::Udp(a.parse().map_err(|_| format!("{key} `{text}`: bad address"))?))
    } else if let Some(p) = text.strip_prefix("replay:") {
        Ok(LidarSource::Replay(resolve(Path::new(p))))
    } else {
        Err(format!("{key} `{text}`: expected udp:ADDR:PORT or replay:PATH"))
    }
}

/// Without `rig`: one `[camera]` and one `[lidar]`, unnamed.
fn one_pair_only(raw: &RawConfig) -> Result<(), String> {
    let (Sensors::One(c), Sensors::One(l)) = (&raw.camera, &raw.lidar) else {
        return Err("[[camera]] / [[lidar]] tables are a rig's: add rig = \"RIG.toml\" naming \
                    its sensors, or use one [camera] and one [lidar] table"
            .into());
    };
    if c.name.is_some() || l.name.is_some() {
        return Err("camera.name / lidar.name: only a rig's [[camera]] / [[lidar]] tables are \
                    named (add rig = \"RIG.toml\")"
            .into());
    }
    if c.min_boards.is_some() || raw.trigger.cameras.is_some() {
        return Err("camera.min_boards / trigger.cameras choose among a rig's cameras: the one \
                    camera's boards are trigger.min_boards"
            .into());
    }
    Ok(())
}

/// With `rig`: the rig file, and exactly one named `[[camera]]` / `[[lidar]]` source per
/// sensor of it, in its order.
fn rig_sources(
    path: &Path,
    raw: &RawConfig,
    resolve: &impl Fn(&Path) -> PathBuf,
) -> Result<RigSources, String> {
    let rig = crate::rig::load(path).map_err(|e| format!("rig: {e}"))?;
    let (Sensors::Named(cameras), Sensors::Named(lidars)) = (&raw.camera, &raw.lidar) else {
        return Err(format!(
            "rig = {}: name each sensor's source in [[camera]] and [[lidar]] tables \
             (name = \"…\", source = \"…\"), not in one [camera] / [lidar] table",
            path.display()
        ));
    };
    if rig.lidars.is_empty() {
        return Err(format!(
            "rig {}: the daemon needs at least one LiDAR (its motion drives the trigger)",
            path.display()
        ));
    }
    let rig_names: Vec<(&str, &str)> = rig
        .cameras
        .iter()
        .map(|c| ("camera", c.name.as_str()))
        .chain(rig.lidars.iter().map(|l| ("lidar", l.name.as_str())))
        .collect();
    let given: Vec<(&str, Option<&str>)> = cameras
        .iter()
        .map(|c| ("camera", c.name.as_deref()))
        .chain(lidars.iter().map(|l| ("lidar", l.name.as_deref())))
        .collect();
    for (i, (kind, name)) in given.iter().enumerate() {
        let Some(name) = name else {
            return Err(format!("[[{kind}]] table {}: `name` is missing", i + 1));
        };
        if !rig_names.contains(&(kind, name)) {
            return Err(format!(
                "[[{kind}]] `{name}`: the rig {} has no {kind} of that name",
                path.display()
            ));
        }
        if given[..i].iter().any(|(k, n)| k == kind && *n == Some(*name)) {
            return Err(format!("[[{kind}]] `{name}` is given twice"));
        }
    }
    let find = |kind: &str, name: &str| {
        given.iter().position(|(k, n)| *k == kind && *n == Some(name)).ok_or_else(|| {
            format!("{kind} `{name}` of the rig {} has no [[{kind}]] source", path.display())
        })
    };
    let mut out = RigSources {
        path: path.to_owned(),
        rig: rig.clone(),
        cameras: Vec::new(),
        lidars: Vec::new(),
    };
    let watched = watched_cameras(&rig, raw.trigger.cameras.as_deref(), path)?;
    for (c, watched) in rig.cameras.iter().zip(watched) {
        let raw = &cameras[find("camera", &c.name)?];
        let key = format!("camera `{}` source", c.name);
        out.cameras.push(RigCameraSource {
            name: c.name.to_string(),
            source: camera_source(&raw.source, &key, resolve)?,
            replay_fps: raw.replay_fps,
            watched,
            min_boards: raw.min_boards,
        });
    }
    for l in &rig.lidars {
        let raw = &lidars[find("lidar", &l.name)? - cameras.len()];
        let key = format!("lidar `{}` source", l.name);
        out.lidars.push(RigLidarSource {
            name: l.name.to_string(),
            model: Some(l.model),
            source: lidar_source(&raw.source, &key, resolve)?,
            multicast: raw.multicast,
            replay_speed: raw.replay_speed,
            calibration: raw.calibration.as_deref().map(resolve),
        });
    }
    Ok(out)
}

/// Which of the rig's cameras the trigger waits for: those `[trigger] cameras` names (each
/// a camera of the rig), or every camera.
fn watched_cameras(
    rig: &crate::rig::Rig,
    names: Option<&[String]>,
    path: &Path,
) -> Result<Vec<bool>, String> {
    let Some(names) = names else { return Ok(vec![true; rig.cameras.len()]) };
    if names.is_empty() {
        return Err("trigger.cameras is empty: name the cameras that must see the room".into());
    }
    let known: Vec<&str> = rig.cameras.iter().map(|c| c.name.as_str()).collect();
    if let Some(unknown) = names.iter().find(|n| !known.contains(&n.as_str())) {
        return Err(format!(
            "trigger.cameras: `{unknown}` is not a camera of the rig {} (its cameras: {})",
            path.display(),
            known.join(", ")
        ));
    }
    Ok(known.iter().map(|k| names.iter().any(|n| n == k)).collect())
}

/// Longest time setting (s): an hour; longer waits are typing mistakes.
pub const MAX_SECONDS: f64 = 3600.0;
/// Most frames averaged, and sweeps accumulated, per run: each frame is held in memory
/// (a 64 Mpx camera's 100 frames are 6.4 GB), so this bounds the run's buffers.
pub const MAX_FRAMES: usize = 100;
/// Most generations and rejected runs the store may be told to keep.
pub const MAX_KEEP: usize = 10_000;
/// Fastest replay rate (frames per second) and replay speed-up.
pub const MAX_REPLAY_RATE: f64 = 1000.0;
/// Largest `trigger.still_m` (m): the vehicle counts as still below this motion.
pub const MAX_STILL_M: f64 = 10.0;

/// Every number within its range (docs/limits.md); the error names the key.
fn check_numbers(raw: &RawConfig) -> Result<(), crate::target::RoomError> {
    use crate::target::{Index, Range};
    let t = &raw.trigger;
    let seconds = Range::closed(0.0, MAX_SECONDS, "s");
    let positive_seconds = Range::positive(MAX_SECONDS, "s");
    let rate = Range::positive(MAX_REPLAY_RATE, "");
    let count = |max: usize| Range::closed(1.0, max as f64, "");
    for (i, c) in raw.camera.all().iter().enumerate() {
        rate.check("camera.replay_fps", sensor_index(&raw.camera, i), c.replay_fps)?;
    }
    for (i, l) in raw.lidar.all().iter().enumerate() {
        rate.check("lidar.replay_speed", sensor_index(&raw.lidar, i), l.replay_speed)?;
    }
    let numbers = [
        ("keep", raw.keep as f64, count(MAX_KEEP)),
        ("trigger.settle_s", t.settle_s, seconds),
        ("trigger.leave_s", t.leave_s, seconds),
        ("trigger.still_m", f64::from(t.still_m), Range::closed(0.0, MAX_STILL_M, "m")),
        ("trigger.frames", t.frames as f64, count(MAX_FRAMES)),
        ("trigger.sweeps", t.sweeps as f64, count(MAX_FRAMES)),
        ("trigger.detect_interval_s", t.detect_interval_s, positive_seconds),
        ("trigger.capture_timeout_s", t.capture_timeout_s, positive_seconds),
    ];
    for (key, value, range) in numbers {
        range.check(key, Index::None, value)?;
    }
    let boards = Range::closed(0.0, crate::target::MAX_BOARDS as f64, "boards");
    if let Some(n) = t.min_boards {
        boards.check("trigger.min_boards", Index::None, n as f64)?;
    }
    for (i, c) in raw.camera.all().iter().enumerate() {
        if let Some(n) = c.min_boards {
            boards.check("camera.min_boards", sensor_index(&raw.camera, i), n as f64)?;
        }
    }
    Ok(())
}

/// `[i]` of a rig's `[[camera]]` / `[[lidar]]` table in a key; nothing for `[camera]`.
fn sensor_index<T>(sensors: &Sensors<T>, i: usize) -> crate::target::Index {
    match sensors {
        Sensors::One(_) => crate::target::Index::None,
        Sensors::Named(_) => crate::target::Index::One(i.min(255) as u8),
    }
}

/// Every path given is non-empty (an empty one would resolve to the config's folder).
fn check_paths(raw: &RawConfig) -> Result<(), String> {
    let mut paths = vec![("room", raw.room.as_os_str()), ("store", raw.store.as_os_str())];
    if let Some(rig) = &raw.rig {
        paths.push(("rig", rig.as_os_str()));
    }
    for c in raw.lidar.all().iter().filter_map(|l| l.calibration.as_ref()) {
        paths.push(("lidar.calibration", c.as_os_str()));
    }
    if let Some(s) = &raw.service {
        paths.push(("service.secret_file", s.secret_file.as_os_str()));
    }
    let sources = raw
        .camera
        .all()
        .iter()
        .map(|c| ("camera.source", &c.source))
        .chain(raw.lidar.all().iter().map(|l| ("lidar.source", &l.source)));
    for (key, sources) in sources {
        if sources.strip_prefix("replay:").is_some_and(str::is_empty) {
            return Err(format!("{key} `{sources}`: the replay path is empty"));
        }
    }
    match paths.into_iter().find(|(_, p)| p.is_empty()) {
        Some((key, _)) => Err(format!("{key} is empty: a path is needed")),
        None => Ok(()),
    }
}

/// Request and response IDs: CAN identifiers, distinct, both 11-bit or both 29-bit (one
/// ISO-TP endpoint uses one identifier format).
fn check_ids(request: u32, response: u32) -> Result<(), String> {
    use crate::service::{MAX_EXTENDED_ID, MAX_STANDARD_ID};
    for (key, id) in [("service.request_id", request), ("service.response_id", response)] {
        if id > MAX_EXTENDED_ID {
            return Err(format!("{key} = {id:#X}: not a CAN identifier (29 bits at most)"));
        }
    }
    if request == response {
        return Err(format!("service.request_id and service.response_id are both {request:#X}"));
    }
    if (request > MAX_STANDARD_ID) != (response > MAX_STANDARD_ID) {
        return Err(format!(
            "service.request_id {request:#X} and service.response_id {response:#X}: \
             one is 11-bit, the other 29-bit"
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const DESIGN: &str = r#"
room = "room.toml"                 # relative to this file
store = "/var/lib/roomcal"         # the vehicle config store (a directory)

[camera]
source = "v4l2:/dev/video0"        # or "replay:PATH" (an image file or a folder of them, looped)
[lidar]
source = "udp:0.0.0.0:2368"        # or "replay:PATH" (pcap replayed at its own pace, or PCD)
[trigger]
mode = "auto"                      # auto: room seen + vehicle still; manual: only on request
settle_s = 2.0
[service]
transport = "socketcan:can0"       # or "socketcand:127.0.0.1:29536"
request_id = 0x7A0
response_id = 0x7A8
secret_file = "/etc/roomcal/secret"
"#;

    #[test]
    fn design_example_parses_with_paths_resolved() {
        let c = parse(DESIGN, Path::new("/etc/roomcal/roomcal.toml")).unwrap();
        assert_eq!(c.room, PathBuf::from("/etc/roomcal/room.toml"));
        assert_eq!(c.store, PathBuf::from("/var/lib/roomcal"));
        assert_eq!(c.camera, CameraSource::V4l2("/dev/video0".into()));
        assert_eq!(c.lidar, LidarSource::Udp("0.0.0.0:2368".parse().unwrap()));
        assert_eq!(c.trigger.mode, Mode::Auto);
        assert_eq!(c.trigger.settle_s, 2.0);
        let s = c.service.unwrap();
        assert_eq!((s.request_id, s.response_id), (0x7A0, 0x7A8));
        assert_eq!(s.socketcand, SocketcandRole::Listen);
    }

    #[test]
    fn lidar_angle_file_resolves_beside_the_config() {
        let c = parse(DESIGN, Path::new("/etc/roomcal/roomcal.toml")).unwrap();
        assert_eq!(c.lidar_calibration, None, "nominal tables by default");
        let text = DESIGN.replace(
            "source = \"udp:0.0.0.0:2368\"",
            "source = \"udp:0.0.0.0:2368\"\ncalibration = \"angles.csv\"",
        );
        let c = parse(&text, Path::new("/etc/roomcal/roomcal.toml")).unwrap();
        assert_eq!(c.lidar_calibration, Some(PathBuf::from("/etc/roomcal/angles.csv")));
    }

    #[test]
    fn socketcand_role_and_29_bit_ids() {
        let text = DESIGN
            .replace("socketcan:can0", "socketcand:127.0.0.1:29536")
            .replace("0x7A0", "0x18DA00F1")
            .replace("0x7A8", "0x18DAF100\nsocketcand = \"connect\"");
        let s = parse(&text, Path::new("x.toml")).unwrap().service.unwrap();
        assert_eq!(s.socketcand, SocketcandRole::Connect);
        assert_eq!((s.request_id, s.response_id), (0x18DA00F1, 0x18DAF100));
        let bad = text.replace("\"connect\"", "\"both\"");
        assert!(parse(&bad, Path::new("x.toml")).is_err());
    }

    #[test]
    fn replay_paths_resolve_and_errors_name_the_file() {
        let text = DESIGN
            .replace("v4l2:/dev/video0", "replay:frames")
            .replace("udp:0.0.0.0:2368", "replay:../caps/a.pcap")
            .replace("\"auto\"", "\"manual\"");
        let c = parse(&text, Path::new("cfg/roomcal.toml")).unwrap();
        assert_eq!(c.camera, CameraSource::Replay("cfg/frames".into()));
        assert_eq!(c.lidar, LidarSource::Replay("cfg/../caps/a.pcap".into()));
        assert_eq!(c.trigger.mode, Mode::Manual);
        let bad = DESIGN.replace("v4l2:/dev/video0", "usb:0");
        let e = parse(&bad, Path::new("x.toml")).unwrap_err().to_string();
        assert!(e.contains("x.toml") && e.contains("usb:0"), "{e}");
        let bad = DESIGN.replace("settle_s = 2.0", "settle_s = 2.0\nsettle = 1");
        assert!(parse(&bad, Path::new("x.toml")).is_err(), "unknown keys are errors");
        for (from, to, what) in [
            ("0x7A8", "0x7A0", "both 0x7A0"),
            ("0x7A8", "0x18DAF100", "one is 11-bit"),
            ("0x7A8", "0x20000000", "not a CAN identifier"),
        ] {
            let bad = DESIGN.replace(from, to);
            let e = parse(&bad, Path::new("x.toml")).unwrap_err().to_string();
            assert!(e.contains("x.toml") && e.contains(what), "{e}");
        }
        let bad = DESIGN.replace("socketcan:can0", "can0");
        assert!(parse(&bad, Path::new("x.toml"))
            .unwrap_err()
            .to_string()
            .contains("service.transport"));
    }

    #[test]
    fn numbers_and_paths_out_of_range_name_their_key() {
        let cases = [
            ("settle_s = 2.0", "settle_s = nan", "`trigger.settle_s` = NaN"),
            ("settle_s = 2.0", "settle_s = 1e308", "`trigger.settle_s` = 1e308"),
            ("settle_s = 2.0", "settle_s = 2.0\nleave_s = -1.0", "`trigger.leave_s` = -1"),
            ("settle_s = 2.0", "settle_s = 2.0\nstill_m = nan", "`trigger.still_m` = NaN"),
            ("settle_s = 2.0", "settle_s = 2.0\nframes = 100000", "`trigger.frames` = 100000"),
            ("settle_s = 2.0", "settle_s = 2.0\nsweeps = 0", "`trigger.sweeps` = 0"),
            ("settle_s = 2.0", "settle_s = 2.0\nmin_boards = 99", "`trigger.min_boards` = 99"),
            ("settle_s = 2.0", "settle_s = 2.0\ncapture_timeout_s = 0", "capture_timeout_s"),
            ("settle_s = 2.0", "settle_s = 2.0\ndetect_interval_s = inf", "detect_interval_s"),
            (
                "\"udp:0.0.0.0:2368\"",
                "\"udp:0.0.0.0:2368\"\nreplay_speed = -1.0",
                "`lidar.replay_speed` = -1",
            ),
            (
                "\"v4l2:/dev/video0\"",
                "\"v4l2:/dev/video0\"\nreplay_fps = 1e9",
                "`camera.replay_fps`",
            ),
            (
                "store = \"/var/lib/roomcal\"",
                "store = \"/var/lib/roomcal\"\nkeep = 0",
                "`keep` = 0",
            ),
            ("store = \"/var/lib/roomcal\"", "store = \"\"", "store is empty"),
            ("room = \"room.toml\"", "room = \"\"", "room is empty"),
            ("\"v4l2:/dev/video0\"", "\"replay:\"", "replay path is empty"),
        ];
        for (from, to, expect) in cases {
            let text = DESIGN.replacen(from, to, 1);
            assert_ne!(text, DESIGN, "{from}");
            let e = parse(&text, Path::new("x.toml")).unwrap_err().to_string();
            assert!(e.contains("x.toml") && e.contains(expect), "`{expect}` not in: {e}");
        }
    }

    fn rig_config(sensors: &str) -> String {
        let rig = concat!(env!("CARGO_MANIFEST_DIR"), "/config/rig.toml");
        format!("room = \"room.toml\"\nstore = \"store\"\nrig = \"{rig}\"\n{sensors}")
    }

    const RIG_SOURCES: &str = "[[lidar]]\nname = \"bumper\"\nsource = \"udp:0.0.0.0:2369\"\n\
        [[camera]]\nname = \"wide\"\nsource = \"replay:wide\"\n\
        [[camera]]\nname = \"front\"\nsource = \"v4l2:/dev/video0\"\nreplay_fps = 5.0\n\
        [[lidar]]\nname = \"top\"\nsource = \"udp:0.0.0.0:2368\"\nreplay_speed = 2.0\n";

    #[test]
    fn a_rigs_sources_are_taken_in_the_rig_files_order() {
        let c = parse(&rig_config(RIG_SOURCES), Path::new("/etc/roomcal/roomcal.toml")).unwrap();
        let rig = c.rig.as_ref().unwrap();
        let cameras: Vec<&str> = rig.cameras.iter().map(|s| s.name.as_str()).collect();
        let lidars: Vec<&str> = rig.lidars.iter().map(|s| s.name.as_str()).collect();
        assert_eq!((cameras, lidars), (vec!["front", "wide"], vec!["top", "bumper"]));
        assert_eq!(rig.cameras[1].source, CameraSource::Replay("/etc/roomcal/wide".into()));
        // The first camera and first LiDAR are also the one-pair fields.
        assert_eq!(
            (c.camera.clone(), c.replay_fps),
            (CameraSource::V4l2("/dev/video0".into()), 5.0)
        );
        assert_eq!(
            (c.lidar.clone(), c.replay_speed),
            (LidarSource::Udp("0.0.0.0:2368".parse().unwrap()), 2.0)
        );
        assert_eq!(c.lidar_model, Some(Some(crate::lidar::Model::Pandar64)));
        let bumper = c.with_lidar(&rig.lidars[1]);
        assert_eq!(bumper.lidar, LidarSource::Udp("0.0.0.0:2369".parse().unwrap()));
        assert_eq!(bumper.lidar_model, Some(Some(crate::lidar::Model::Vlp32c)));
    }

    #[test]
    fn the_example_rig_daemon_configuration_parses() {
        let path = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/config/rig-daemon.toml"));
        let c = load(path).unwrap();
        let rig = c.rig.unwrap();
        assert_eq!(rig.lidars[1].source, LidarSource::Udp("0.0.0.0:2369".parse().unwrap()));
        assert_eq!(rig.cameras[1].source, CameraSource::V4l2("/dev/video2".into()));
    }

    #[test]
    fn a_rigs_sources_that_do_not_match_it_are_named() {
        let top = "[[lidar]]\nname = \"top\"\nsource = \"udp:0.0.0.0:2368\"\n";
        let bumper = "[[lidar]]\nname = \"bumper\"\nsource = \"udp:0.0.0.0:2369\"\n";
        let front = "[[camera]]\nname = \"front\"\nsource = \"replay:f\"\n";
        let wide = "[[camera]]\nname = \"wide\"\nsource = \"replay:w\"\n";
        let cases = [
            (format!("{front}{top}{bumper}"), "camera `wide` of the rig"),
            (format!("{front}{wide}{wide}{top}{bumper}"), "[[camera]] `wide` is given twice"),
            (format!("{front}{wide}{top}{bumper}[[lidar]]\nname = \"roof\"\nsource = \"udp:0.0.0.0:1\"\n"), "[[lidar]] `roof`: the rig"),
            (format!("{front}{wide}{top}{bumper}").replace("name = \"top\"\n", ""), "`name` is missing"),
            ("[camera]\nsource = \"replay:f\"\n[lidar]\nsource = \"udp:0.0.0.0:1\"\n".into(), "name each sensor's source in [[camera]]"),
            (format!("{front}{wide}{top}").replace("udp:0.0.0.0:2368", "tcp:1"), "lidar `top` source `tcp:1`"),
        ];
        for (sensors, expect) in cases {
            let e = parse(&rig_config(&sensors), Path::new("x.toml")).unwrap_err().to_string();
            assert!(e.contains(expect), "`{expect}` not in: {e}");
        }
        let no_rig = format!("room = \"r\"\nstore = \"s\"\n{front}{top}");
        let e = parse(&no_rig, Path::new("x.toml")).unwrap_err().to_string();
        assert!(e.contains("add rig = "), "{e}");
        let named =
            "room = \"r\"\nstore = \"s\"\n[camera]\nname = \"front\"\nsource = \"replay:f\"\n\
                     [lidar]\nsource = \"udp:0.0.0.0:1\"\n";
        let e = parse(named, Path::new("x.toml")).unwrap_err().to_string();
        assert!(e.contains("only a rig's"), "{e}");
    }

    /// Every camera by default; `[trigger] cameras` a subset, `min_boards` per camera; a
    /// name that is not one of the rig's cameras, an empty list, or either key without a
    /// rig is named.
    #[test]
    fn the_trigger_watches_every_camera_or_the_configured_ones() {
        let path = Path::new("x.toml");
        let watched = |extra: &str| {
            let mut c = parse(&(rig_config(RIG_SOURCES) + extra), path).unwrap();
            c.trigger.min_boards = 6;
            c.watched_cameras()
        };
        assert_eq!(watched(""), [(0, 6), (1, 6)]);
        assert_eq!(watched("[trigger]\ncameras = [\"wide\"]\n"), [(1, 6)]);
        let sources = RIG_SOURCES
            .replace("source = \"replay:wide\"\n", "source = \"replay:wide\"\nmin_boards = 2\n");
        let mut c = parse(&rig_config(&sources), path).unwrap();
        c.trigger.min_boards = 6;
        assert_eq!(c.watched_cameras(), [(0, 6), (1, 2)]);
        let cases = [
            (
                "[trigger]\ncameras = [\"front\", \"rear\"]\n",
                "trigger.cameras: `rear` is not a camera of the rig",
            ),
            ("[trigger]\ncameras = []\n", "trigger.cameras is empty"),
        ];
        for (extra, expect) in cases {
            let e = parse(&(rig_config(RIG_SOURCES) + extra), path).unwrap_err().to_string();
            assert!(
                e.contains(expect) && e.contains("front, wide") == expect.contains("rear"),
                "`{expect}` not in: {e}"
            );
        }
        let pair = "room = \"r\"\nstore = \"s\"\n[camera]\nsource = \"replay:f\"\n[lidar]\nsource = \"udp:0.0.0.0:1\"\n";
        let c = parse(pair, path).unwrap();
        assert_eq!(c.watched_cameras(), [(0, 0)], "the one camera, at trigger.min_boards");
        let extra = "[trigger]\ncameras = [\"front\"]\n";
        let e = parse(&format!("{pair}{extra}"), path).unwrap_err().to_string();
        assert!(e.contains("trigger.cameras choose among a rig's cameras"), "{e}");
        let e =
            parse(&pair.replace("replay:f\"\n", "replay:f\"\nmin_boards = 3\n"), path).unwrap_err();
        assert!(e.to_string().contains("camera.min_boards"), "{e}");
    }
}
