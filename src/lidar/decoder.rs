//! The one dispatcher over the vendor decoders: which model a payload is, and decode, encode,
//! beam geometry and timing of a payload or a sweep for any supported model. The vocabulary
//! the vendors share is [`super::common`] (re-exported here); no heap: returns go to a
//! caller's sink.

pub use super::common::{
    check_azimuth_order, DecodeError, Model, PacketSummary, Return, ReturnMode, SimReturn,
    MAX_BLOCK_STEP,
};

use super::calibration::Calibration;
use super::{hesai, ouster, velodyne, Point};

/// Guesses the model from a data payload (length, magic, Velodyne product id).
pub fn detect_model(payload: &[u8]) -> Option<Model> {
    if let Ok(p) = velodyne::Packet::new_checked(payload) {
        return velodyne::Product::from_id(p.product_id()).map(|p| p.model());
    }
    [Model::Pandar64, Model::Pandar40p, Model::PandarXt32, Model::PandarQt64]
        .into_iter()
        .find(|m| hesai::Packet::new_checked(payload, *m).is_ok())
}

/// Encodes `returns` (in firing order; consecutive returns with the same azimuth are one
/// firing, i.e. one block) as single-return
/// data packets of `calibration.model`, handing each packet to `out`; returns the packet count.
/// `start_time` stamps the first packet: seconds past the hour for Velodyne models (the
/// packet field), Unix seconds for Hesai models. Decoding the packets gives the returns back
/// (range to the model's resolution).
pub fn encode_sweep(
    calibration: &Calibration,
    returns: &[SimReturn],
    start_time: f64,
    out: &mut dyn FnMut(&[u8]),
) -> Result<usize, DecodeError> {
    if calibration.model.is_velodyne() {
        let past_hour = start_time - 3600.0 * libm::floor(start_time / 3600.0);
        let us = libm::round(past_hour * 1e6) as u32;
        velodyne::encode_sweep(calibration, returns, us, out)
    } else if calibration.model.is_hesai() {
        hesai::encode_sweep(calibration, returns, start_time, out)
    } else {
        Err(DecodeError::WrongCalibration)
    }
}

/// The azimuth (0.01°, clockwise, before the laser's offset) the decoder gives `laser`'s
/// return in single-return packets when firing sequence number `sequence` of a capture
/// (counted from 0; the VLP-16 puts two sequences in a block) starts at `azimuth` and the
/// sensor turns `advance` (0.01°) per sequence: the block azimuth for Hesai units, plus the
/// firing-time interpolation for Velodyne units. A simulator casts its rays here.
pub fn firing_azimuth(
    calibration: &Calibration,
    laser: usize,
    sequence: usize,
    azimuth: u16,
    advance: u16,
) -> u16 {
    if calibration.model.is_velodyne() {
        velodyne::firing_azimuth(calibration, laser, sequence, azimuth, advance)
    } else {
        azimuth % 36000
    }
}

/// Unit vector (sensor frame: x forward, y left, z up) of `laser` fired at `firing_azimuth`
/// (0.01°, clockwise, from [`firing_azimuth`]), with the laser's elevation and azimuth
/// offset: the decoder puts a return of range r at r times this vector (for tables without
/// Velodyne optical-centre offsets, as the nominal ones).
pub fn beam_direction(calibration: &Calibration, laser: usize, firing_azimuth: u16) -> [f64; 3] {
    let c = calibration.lasers.get(laser).copied().unwrap_or_default();
    let azimuth =
        f64::from(firing_azimuth) * (core::f64::consts::PI / 18000.0) + f64::from(c.azimuth_offset);
    let elevation = f64::from(c.elevation);
    let horizontal = libm::cos(elevation);
    [horizontal * libm::cos(azimuth), -horizontal * libm::sin(azimuth), libm::sin(elevation)]
}

/// Metres per range count in the packets [`encode_sweep`] writes (and the decoder reads):
/// the calibration's resolution for Velodyne units, the 4 mm unit the Hesai encoder sets.
/// A range `n × resolution` (computed in f32) survives encoding exactly.
pub fn range_resolution(calibration: &Calibration) -> f32 {
    match calibration.model {
        Model::Ouster => 1e-3,
        m if m.is_velodyne() => calibration.distance_resolution,
        _ => f32::from(hesai::ENCODE_DIS_UNIT_MM) * 1e-3,
    }
}

/// Nominal time between data packets of `model` in single-return mode, seconds.
/// (Ouster: the 1024×10 mode's; a unit's own is `ouster::packet_period`.)
pub fn packet_period(model: Model) -> f64 {
    match model {
        Model::Ouster => ouster::packet_period(&super::calibration::OusterGeometry::default()),
        m if m.is_velodyne() => velodyne::packet_period(model),
        _ => hesai::packet_period(model),
    }
}

/// Decodes one data payload of `calibration.model`, handing each valid return to `sink`
/// (zero ranges and identical dual echoes are dropped). Never panics on any bytes. Generic
/// over the sink (a `&mut dyn FnMut` works too) so closures inline into the point loop.
pub fn decode_packet<F: FnMut(Return) + ?Sized>(
    calibration: &Calibration,
    payload: &[u8],
    sink: &mut F,
) -> Result<PacketSummary, DecodeError> {
    match calibration.model {
        Model::Ouster => ouster::decode(calibration, payload, sink),
        m if m.is_velodyne() => velodyne::decode(calibration, payload, sink),
        _ => hesai::decode(calibration, payload, sink),
    }
}

/// Decodes one data payload into `out`, returning how many points were written; returns
/// beyond `out.len()` are counted in `PacketSummary::returns` but not stored.
pub fn decode_into(
    calibration: &Calibration,
    payload: &[u8],
    out: &mut [Point],
) -> Result<(usize, PacketSummary), DecodeError> {
    let mut n = 0;
    let summary = decode_packet(calibration, payload, &mut |r: Return| {
        if let Some(slot) = out.get_mut(n) {
            *slot = r.point;
            n += 1;
        }
    })?;
    Ok((n, summary))
}
