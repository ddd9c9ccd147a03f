//! LiDAR input: no_std packet views and decoders per vendor, sweep assembly, and (std)
//! pcap/pcapng and PCD readers and writers.

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

pub mod lzf;
#[cfg(feature = "std")]
pub mod pcap;
#[cfg(feature = "std")]
pub mod pcd;
