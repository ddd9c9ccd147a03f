//! `roomcal decode`: a LiDAR packet capture (pcap/pcapng) → a PCD cloud (x y z intensity
//! ring), every return of every packet.

use std::path::PathBuf;

use anyhow::anyhow;
use clap::{Args, ValueEnum};

use super::{bad_input, Failure};

#[derive(Args)]
pub struct DecodeArgs {
    /// LiDAR model: pandar64, pandar40p, pandarxt32, pandarqt64, vlp16, vlp32c, hdl32e, ouster.
    #[arg(long)]
    lidar: String,
    /// The unit's angle corrections (Hesai CSV or Velodyne YAML; for ouster the sensor's
    /// metadata json); default: nominal table.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// How Velodyne firing azimuths are interpolated: `manual` (the user manuals' firing
    /// timing, the default) or `nebula` (tier4/nebula's, to reproduce its clouds).
    #[arg(long, value_enum, default_value = "manual")]
    velodyne_interpolation: InterpolationArg,
    /// The capture.
    capture: PathBuf,
    /// Output PCD (binary).
    #[arg(long)]
    out: PathBuf,
}

#[derive(Clone, Copy, ValueEnum)]
enum InterpolationArg {
    Manual,
    Nebula,
}

/// `roomcal decode`: the capture's every return written as PCD; prints the packet counts.
pub fn run(args: DecodeArgs) -> Result<(), Failure> {
    let model = roomcal::lidar::Model::from_name(&args.lidar).ok_or_else(|| {
        bad_input(anyhow!(
            "--lidar {}: unknown model ({})",
            args.lidar,
            roomcal::lidar::Model::NAMES
        ))
    })?;
    let mut calibration =
        roomcal::lidar::capture_calibration(model, args.calibration.as_deref(), &args.capture)
            .map_err(bad_input)?;
    calibration.interpolation = match args.velodyne_interpolation {
        InterpolationArg::Manual => roomcal::lidar::calibration::Interpolation::Manual,
        InterpolationArg::Nebula => roomcal::lidar::calibration::Interpolation::Nebula,
    };
    let (points, stats, capture) =
        roomcal::lidar::decode_capture_with(&calibration, &args.capture).map_err(bad_input)?;
    roomcal::lidar::pcd::write(&args.out, &points, roomcal::lidar::pcd::PcdFormat::Binary)
        .map_err(bad_input)?;
    say!(
        "{}: {} points from {} packets ({} position, {} dropped; {} UDP datagrams, {} other records) -> {}",
        args.capture.display(),
        points.len(),
        stats.packets,
        stats.position,
        stats.unknown + stats.truncated + stats.oversized + stats.corrupted,
        capture.udp,
        capture.records.saturating_sub(capture.udp),
        args.out.display()
    );
    Ok(())
}
