//! The simulated sweep as the sensor sends it: the firings encoded as the model's data
//! packets (`lidar::encode_sweep`) in a classic pcap capture (`lidar::pcap::PcapWriter`),
//! stamped at the model's packet rate, plus the unit's angle-correction file (Hesai CSV)
//! that decoding needs when it is not the model's nominal table.

use std::io::BufWriter;
use std::net::{Ipv4Addr, SocketAddrV4};
use std::path::{Path, PathBuf};

use crate::lidar::calibration::{to_hesai_csv, Calibration};
use crate::lidar::pcap::{PcapWriter, UdpDatagram};
use crate::lidar::{encode_sweep, packet_period};

use super::{Firings, Scene, SimError};

/// Unix time of the first packet (2026-01-01T00:00:00Z): fixed, so a seed gives the same bytes.
pub const START_UNIX_S: f64 = 1_767_225_600.0;
/// The sensor's factory source address (both vendors ship 192.168.1.201).
pub const SENSOR_ADDR: Ipv4Addr = Ipv4Addr::new(192, 168, 1, 201);

/// One packet of a capture.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CapturedPacket {
    /// Capture time, ns since the Unix epoch.
    pub timestamp_ns: u64,
    /// The UDP payload: one data packet of the model.
    pub payload: Vec<u8>,
}

/// The files [`write_capture`] wrote.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CaptureFiles {
    /// `cloud.pcap`.
    pub capture: PathBuf,
    /// `angles.csv` for Hesai units (the unit's table; `roomcal decode --calibration`).
    pub calibration: Option<PathBuf>,
}

/// Encodes the firings as data packets, the first at [`START_UNIX_S`], the others at the
/// model's packet period.
pub fn packets(firings: &Firings) -> Result<Vec<CapturedPacket>, SimError> {
    let cal = &firings.calibration;
    let period = packet_period(cal.model);
    let mut out = Vec::new();
    encode_sweep(cal, &firings.returns, START_UNIX_S, &mut |bytes| {
        let t = START_UNIX_S + out.len() as f64 * period;
        out.push(CapturedPacket {
            timestamp_ns: (t * 1e9).round() as u64,
            payload: bytes.to_vec(),
        });
    })
    .map_err(|e| SimError::Encode { model: cal.model, message: e.to_string() })?;
    Ok(out)
}

/// Writes the scene's sweep as `cloud.pcap` in `dir` (UDP from the sensor's address to the
/// broadcast address on the model's data port), and `angles.csv` for Hesai models.
pub fn write_capture(scene: &Scene, dir: &Path) -> Result<CaptureFiles, SimError> {
    let firings = scene.firings.as_ref().ok_or(SimError::NoSweep)?;
    std::fs::create_dir_all(dir).map_err(|e| SimError::write(dir, &e))?;
    let capture = dir.join("cloud.pcap");
    let port = firings.calibration.model.data_port();
    let (src, dst) =
        (SocketAddrV4::new(SENSOR_ADDR, port), SocketAddrV4::new(Ipv4Addr::BROADCAST, port));
    let file = std::fs::File::create(&capture).map_err(|e| SimError::write(&capture, &e))?;
    let mut writer =
        PcapWriter::new(BufWriter::new(file)).map_err(|e| SimError::write(&capture, &e))?;
    for p in packets(firings)? {
        let d = UdpDatagram { timestamp_ns: p.timestamp_ns, src, dst, payload: &p.payload };
        writer.write_udp(&d).map_err(|e| SimError::write(&capture, &e))?;
    }
    std::io::Write::flush(&mut writer.into_inner()).map_err(|e| SimError::write(&capture, &e))?;
    let calibration = write_calibration(&firings.calibration, dir)?;
    Ok(CaptureFiles { capture, calibration })
}

/// Writes the Hesai angle-correction file of a Hesai unit; Velodyne units are simulated
/// with their nominal table, which the decoder has built in (there is no YAML writer).
fn write_calibration(cal: &Calibration, dir: &Path) -> Result<Option<PathBuf>, SimError> {
    if cal.model.is_velodyne() {
        if *cal != Calibration::nominal(cal.model) {
            let message = "only the nominal Velodyne table can go without a file".to_owned();
            return Err(SimError::Encode { model: cal.model, message });
        }
        return Ok(None);
    }
    let path = dir.join("angles.csv");
    std::fs::write(&path, to_hesai_csv(cal)).map_err(|e| SimError::write(&path, &e))?;
    Ok(Some(path))
}
