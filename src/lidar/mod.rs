//! LiDAR input: no_std packet views and decoders per vendor, sweep assembly, and (std)
//! pcap/pcapng and PCD readers and writers.
//!
//! Decoding: [`Calibration::nominal`] (or `calibration::load` for a unit's Hesai CSV /
//! Velodyne YAML / Ouster metadata json) and [`decode_packet`] per UDP payload, or [`SweepAssembler`] for whole
//! turns, or (std) [`decode_payloads`] for a capture. Units of `Point::time`: seconds past
//! the top of the hour on the sensor clock for Velodyne, Unix seconds for Hesai, each plus
//! the firing offset within the packet; the column timestamp for Ouster. `Point::ring` is the vendor's laser number;
//! `Calibration::rings` maps it to the bottom-up ring index.
//!
//! Simulation: [`firing_azimuth`] and [`beam_direction`] say where the decoder puts each
//! laser's return, so a simulator casts its rays there and [`encode_sweep`]s the ranges
//! (in [`range_resolution`] counts) into packets that decode back onto the cast points.
//! Speed: azimuth trigonometry is a compile-time table ([`trig`]), the per-model firing
//! pattern is computed at compile time, and sinks are generic so closures inline.

/// One LiDAR return in the sensor frame (x forward, y left, z up), metres.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Point {
    pub x: f32,
    pub y: f32,
    pub z: f32,
    /// Reflectivity / intensity as the sensor reports it (0–255 for the supported units).
    pub intensity: f32,
    /// Laser (channel) index, 0 = as the vendor numbers it.
    pub ring: u16,
    /// Time of the return, seconds (packet timestamp plus the firing offset).
    pub time: f64,
}

impl Point {
    /// The return's position in double precision, as the geometry and the solver take it.
    pub fn position(&self) -> crate::geometry::Vec3 {
        crate::geometry::Vec3::new(self.x as f64, self.y as f64, self.z as f64)
    }
}

pub mod calibration;
pub mod common;
pub mod decoder;
pub mod hesai;
pub mod lzf;
pub mod ouster;
#[cfg(feature = "std")]
pub mod pcap;
#[cfg(feature = "std")]
pub mod pcd;
pub mod sweep;
pub mod trig;
pub mod velodyne;

pub use calibration::Calibration;
pub use common::{DecodeError, Model, PacketSummary, Return, ReturnMode, SimReturn};
pub use decoder::{
    beam_direction, decode_into, decode_packet, detect_model, encode_sweep, firing_azimuth,
    packet_period, range_resolution,
};
pub use sweep::{Sweep, SweepAssembler, SweepConfig, SweepStats};

/// One LiDAR's sweeps of a standing vehicle as one cloud, in the order given: the daemon's
/// run, `calibrate --standing` and a rig's repeated `NAME=` clouds all accumulate this way.
/// A single sweep is moved, not copied.
#[cfg(feature = "std")]
pub fn accumulate_sweeps(mut sweeps: Vec<Vec<Point>>) -> Vec<Point> {
    if sweeps.len() == 1 {
        return sweeps.pop().unwrap_or_default();
    }
    let mut cloud = Vec::with_capacity(sweeps.iter().map(Vec::len).sum());
    for sweep in sweeps {
        cloud.extend_from_slice(&sweep);
    }
    cloud
}

/// Decodes every return of every data payload (zero-range returns and identical dual echoes
/// dropped), in order; payloads that are not valid data packets of the calibration's model
/// (512-byte position packets, truncated, corrupted...) are skipped and counted in the stats.
#[cfg(feature = "std")]
pub fn decode_payloads<'a, I>(
    calibration: &Calibration,
    payloads: I,
) -> (Vec<Point>, sweep::SweepStats)
where
    I: IntoIterator<Item = &'a [u8]>,
{
    let mut points = Vec::new();
    let mut stats = sweep::SweepStats::default();
    for payload in payloads {
        match decode_packet(calibration, payload, &mut |r: Return| points.push(r.point)) {
            Ok(s) => {
                stats.packets += 1;
                stats.points += s.returns as u64;
            }
            Err(_) if is_position_packet(calibration.model, payload) => {
                stats.position += 1;
            }
            Err(e) => stats.count_error(e),
        }
    }
    (points, stats)
}

/// Whether a payload that is not a data packet is the model's position / IMU packet
/// (Velodyne 512-byte position packets, Ouster 48-byte IMU packets).
#[cfg(feature = "std")]
fn is_position_packet(model: Model, payload: &[u8]) -> bool {
    match model {
        Model::Ouster => payload.len() == ouster::field::IMU_PACKET_LEN,
        _ => velodyne::PositionPacket::new_checked(payload).is_ok(),
    }
}

/// Why a capture or cloud file could not be turned into points.
#[cfg(feature = "std")]
#[derive(Debug, thiserror::Error)]
pub enum CloudFileError {
    #[error(transparent)]
    Calibration(#[from] calibration::CalibrationFileError),
    #[error(transparent)]
    Capture(#[from] pcap::PcapError),
    #[error(transparent)]
    Pcd(#[from] pcd::PcdError),
    #[error("{path}: no {model:?} data packets in the capture ({packets} UDP datagrams, {rejected} not valid for this model)")]
    NoData { path: std::path::PathBuf, model: Model, packets: usize, rejected: u64 },
    #[error("{path}: a capture needs the LiDAR model (the room's `lidar.model` is \"pcd\")")]
    NoModel { path: std::path::PathBuf },
    /// Every point was NaN, infinite or at the origin (or there were none).
    #[error(
        "{path}: the cloud has no usable point ({declared} points, none finite and off the origin)"
    )]
    NoUsablePoint { path: std::path::PathBuf, declared: usize },
    #[error("{path}: an Ouster capture needs the sensor's metadata json as its calibration file")]
    NoOusterMetadata { path: std::path::PathBuf },
}

/// The calibration a capture of `model` is decoded with: the unit's file if given (Hesai CSV /
/// Velodyne YAML / Ouster metadata json), else the model's nominal table (Ouster has none
/// worth the name: its metadata is required). `capture` names the input in the error.
#[cfg(feature = "std")]
pub fn capture_calibration(
    model: Model,
    calibration_file: Option<&std::path::Path>,
    capture: &std::path::Path,
) -> Result<Calibration, CloudFileError> {
    match calibration_file {
        Some(path) => Ok(calibration::load(model, path)?),
        // Ouster has no nominal geometry: beam angles and packet layout are per unit.
        None if model == Model::Ouster => {
            Err(CloudFileError::NoOusterMetadata { path: capture.to_owned() })
        }
        None => Ok(Calibration::nominal(model)),
    }
}

/// Every return of every data packet in a pcap/pcapng capture, decoded with
/// [`capture_calibration`].
#[cfg(feature = "std")]
pub fn decode_capture(
    model: Model,
    calibration_file: Option<&std::path::Path>,
    capture: &std::path::Path,
) -> Result<(Vec<Point>, SweepStats, pcap::PcapStats), CloudFileError> {
    let calibration = capture_calibration(model, calibration_file, capture)?;
    decode_capture_with(&calibration, capture)
}

/// Every return of every data packet in a pcap/pcapng capture, decoded with `calibration`.
#[cfg(feature = "std")]
pub fn decode_capture_with(
    calibration: &Calibration,
    capture: &std::path::Path,
) -> Result<(Vec<Point>, SweepStats, pcap::PcapStats), CloudFileError> {
    let (datagrams, capture_stats) = pcap::read_udp(capture)?;
    let (points, stats) =
        decode_payloads(calibration, datagrams.iter().map(|d| d.payload.as_slice()));
    if stats.packets == 0 {
        return Err(CloudFileError::NoData {
            path: capture.to_owned(),
            model: calibration.model,
            packets: datagrams.len(),
            rejected: stats.unknown + stats.truncated + stats.oversized + stats.corrupted,
        });
    }
    Ok((points, stats, capture_stats))
}

/// Whether `path` is a packet capture (pcap or pcapng, by its first bytes): its points are
/// decoded here, with the unit's angle file or the model's nominal table
/// ([`read_cloud`]).
#[cfg(feature = "std")]
pub fn is_packet_capture(path: &std::path::Path) -> bool {
    first_bytes(path).is_some_and(|m| pcap::is_capture_magic(&m))
}

/// The first four bytes of `path`, if it has them.
#[cfg(feature = "std")]
fn first_bytes(path: &std::path::Path) -> Option<[u8; 4]> {
    let mut first = [0u8; 4];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut first))
        .ok()
        .map(|()| first)
}

/// The points of a cloud file: PCD as it is, or a pcap/pcapng capture decoded as `model`
/// (told apart by their first bytes, not their names; a file named `.pcap`/`.pcapng`
/// without a capture's magic is reported as not a capture). A cloud without one usable
/// point is an error naming the file.
#[cfg(feature = "std")]
pub fn read_cloud(
    path: &std::path::Path,
    model: Option<Model>,
    calibration_file: Option<&std::path::Path>,
) -> Result<Vec<Point>, CloudFileError> {
    let magic = first_bytes(path);
    let is_capture = magic.is_some_and(|m| pcap::is_capture_magic(&m));
    let named_capture = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("pcap") || e.eq_ignore_ascii_case("pcapng"));
    let (points, declared) = if is_capture {
        let model = model.ok_or_else(|| CloudFileError::NoModel { path: path.to_owned() })?;
        let (points, stats, _) = decode_capture(model, calibration_file, path)?;
        (points, stats.points as usize)
    } else if named_capture && path.is_file() {
        let file = path.display().to_string();
        return Err(match magic {
            Some(m) => pcap::PcapError::NotACapture { file, magic: u32::from_le_bytes(m) },
            None => pcap::PcapError::Truncated { file, offset: 0, what: "file header" },
        }
        .into());
    } else {
        let mut points = Vec::new();
        let info = pcd::read_into(path, &mut points)?;
        (points, info.declared_points)
    };
    if points.is_empty() {
        return Err(CloudFileError::NoUsablePoint { path: path.to_owned(), declared });
    }
    Ok(points)
}
