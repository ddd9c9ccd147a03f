//! Sweep assembly from raw UDP payloads: cut at an azimuth, counting lost, reordered,
//! duplicate and malformed packets.

use super::decoder::DecodeError;

/// Packet and point counters of an assembler (or of `decode_payloads`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SweepStats {
    /// Data packets decoded.
    pub packets: u64,
    /// Points decoded.
    pub points: u64,
    /// Position / GPS packets seen (ignored).
    pub position: u64,
    pub truncated: u64,
    pub oversized: u64,
    /// Bad magic, header, return mode or azimuth.
    pub corrupted: u64,
    /// Valid packets of another model.
    pub unknown: u64,
}

impl SweepStats {
    /// Counts a payload that did not decode.
    pub fn count_error(&mut self, e: DecodeError) {
        match e {
            DecodeError::Truncated { .. } => self.truncated += 1,
            DecodeError::Oversized { .. } => self.oversized += 1,
            DecodeError::WrongCalibration => self.unknown += 1,
            DecodeError::BadMagic
            | DecodeError::BadHeader
            | DecodeError::BadReturnMode(_)
            | DecodeError::BadAzimuth(_) => self.corrupted += 1,
        }
    }
}
