//! LiDAR input: no_std packet views and decoders per vendor, sweep assembly, and (std)
//! pcap/pcapng and PCD readers and writers.
//!
//! Decoding: [`Calibration::nominal`] (or `calibration::load` for a unit's Hesai CSV /
//! Velodyne YAML) and [`decode_packet`] per UDP payload, or [`SweepAssembler`] for whole
//! turns, or (std) [`decode_payloads`] for a capture. Units of `Point::time`: seconds past
//! the top of the hour on the sensor clock for Velodyne, Unix seconds for Hesai, each plus
//! the firing offset within the packet. `Point::ring` is the vendor's laser number;
//! `Calibration::rings` maps it to the bottom-up ring index.

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

pub mod calibration;
pub mod decoder;
pub mod hesai;
pub mod lzf;
#[cfg(feature = "std")]
pub mod pcap;
#[cfg(feature = "std")]
pub mod pcd;
pub mod sweep;
pub mod velodyne;

pub use calibration::Calibration;
pub use decoder::{
    decode_into, decode_packet, encode_sweep, DecodeError, Model, PacketSummary, Return,
    ReturnMode, SimReturn,
};
pub use sweep::{Sweep, SweepAssembler, SweepConfig, SweepStats};

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
            Err(_) if velodyne::PositionPacket::new_checked(payload).is_ok() => {
                stats.position += 1;
            }
            Err(e) => stats.count_error(e),
        }
    }
    (points, stats)
}
