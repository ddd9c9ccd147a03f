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
    camera: RawCamera,
    lidar: RawLidar,
    #[serde(default)]
    trigger: RawTrigger,
    service: Option<RawService>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    source: String,
    #[serde(default = "default_fps")]
    replay_fps: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLidar {
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
    let raw: RawConfig = toml::from_str(text).map_err(|e| invalid(e.to_string()))?;
    let base = path.parent().unwrap_or(Path::new("."));
    let resolve = |p: &Path| if p.is_absolute() { p.to_path_buf() } else { base.join(p) };
    let camera = if let Some(dev) = raw.camera.source.strip_prefix("v4l2:") {
        CameraSource::V4l2(PathBuf::from(dev))
    } else if let Some(p) = raw.camera.source.strip_prefix("replay:") {
        CameraSource::Replay(resolve(Path::new(p)))
    } else {
        return Err(invalid(format!(
            "camera.source `{}`: expected v4l2:DEVICE or replay:PATH",
            raw.camera.source
        )));
    };
    let lidar =
        if let Some(a) = raw.lidar.source.strip_prefix("udp:") {
            LidarSource::Udp(a.parse().map_err(|_| {
                invalid(format!("lidar.source `{}`: bad address", raw.lidar.source))
            })?)
        } else if let Some(p) = raw.lidar.source.strip_prefix("replay:") {
            LidarSource::Replay(resolve(Path::new(p)))
        } else {
            return Err(invalid(format!(
                "lidar.source `{}`: expected udp:ADDR:PORT or replay:PATH",
                raw.lidar.source
            )));
        };
    check_numbers(&raw).map_err(|e| invalid(e.to_string()))?;
    check_paths(&raw).map_err(invalid)?;
    let t = raw.trigger;
    if let Some(s) = &raw.service {
        crate::service::transport::Endpoint::parse(&s.transport)
            .map_err(|e| invalid(format!("service.transport: {e}")))?;
        check_ids(s.request_id, s.response_id).map_err(invalid)?;
    }
    Ok(Config {
        room: resolve(&raw.room),
        store: resolve(&raw.store),
        keep: raw.keep,
        camera,
        replay_fps: raw.camera.replay_fps,
        lidar,
        multicast: raw.lidar.multicast,
        replay_speed: raw.lidar.replay_speed,
        lidar_calibration: raw.lidar.calibration.as_deref().map(resolve),
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

/// Every number within its range (README "Limits"); the error names the key.
fn check_numbers(raw: &RawConfig) -> Result<(), crate::target::RoomError> {
    use crate::target::{Index, Range};
    let t = &raw.trigger;
    let seconds = Range::closed(0.0, MAX_SECONDS, "s");
    let positive_seconds = Range::positive(MAX_SECONDS, "s");
    let rate = Range::positive(MAX_REPLAY_RATE, "");
    let count = |max: usize| Range::closed(1.0, max as f64, "");
    let numbers = [
        ("keep", raw.keep as f64, count(MAX_KEEP)),
        ("camera.replay_fps", raw.camera.replay_fps, rate),
        ("lidar.replay_speed", raw.lidar.replay_speed, rate),
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
    if let Some(n) = t.min_boards {
        let boards = Range::closed(0.0, crate::target::MAX_BOARDS as f64, "boards");
        boards.check("trigger.min_boards", Index::None, n as f64)?;
    }
    Ok(())
}

/// Every path given is non-empty (an empty one would resolve to the config's folder).
fn check_paths(raw: &RawConfig) -> Result<(), String> {
    let mut paths = vec![("room", raw.room.as_os_str()), ("store", raw.store.as_os_str())];
    if let Some(c) = &raw.lidar.calibration {
        paths.push(("lidar.calibration", c.as_os_str()));
    }
    if let Some(s) = &raw.service {
        paths.push(("service.secret_file", s.secret_file.as_os_str()));
    }
    for (key, sources) in
        [("camera.source", &raw.camera.source), ("lidar.source", &raw.lidar.source)]
    {
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
}
