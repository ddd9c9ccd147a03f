//! Sweep assembly from raw UDP payloads (no sockets, no heap): points go into a caller's
//! buffer and a sweep is handed out each time the firing azimuth passes the cut azimuth.
//! Lost packets are counted from timestamp jumps, reordered packets (older than the last
//! one) are kept in the current sweep without cutting it, duplicates (byte-identical to one
//! of the last 32 packets) are dropped, and unknown, truncated, oversized and corrupted
//! payloads are counted and dropped.

use super::calibration::Calibration;
use super::decoder::Model;
use super::decoder::{decode_packet, DecodeError, Return};
use super::{hesai, ouster, velodyne, Point};

/// Packet and point counters of an assembler (or of `decode_payloads`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SweepStats {
    /// Data packets decoded.
    pub packets: u64,
    /// Points decoded (including any dropped for lack of buffer space).
    pub points: u64,
    /// Sweeps handed out.
    pub sweeps: u64,
    /// Position / GPS packets seen (ignored).
    pub position: u64,
    /// Packets missing, estimated from timestamp gaps.
    pub lost: u64,
    /// Packets older than the one before them.
    pub reordered: u64,
    /// Packets identical to a recent one (dropped).
    pub duplicates: u64,
    /// Payloads on another port, or valid packets of another model (dropped).
    pub unknown: u64,
    pub truncated: u64,
    pub oversized: u64,
    /// Bad magic, header, return mode or azimuth (dropped).
    pub corrupted: u64,
    /// Points that did not fit the caller's buffer.
    pub overflow: u64,
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

    /// Payloads dropped for any reason.
    pub fn dropped(&self) -> u64 {
        self.duplicates + self.unknown + self.truncated + self.oversized + self.corrupted
    }
}

/// Where to cut and which ports carry what.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SweepConfig {
    /// Sweeps start when the firing azimuth passes this angle, 0.01° (0 = straight ahead,
    /// clockwise seen from above; 18000 cuts behind the vehicle).
    pub cut_azimuth: u16,
    pub data_port: u16,
    pub position_port: u16,
}

impl SweepConfig {
    /// The model's factory ports, cut straight behind (so the front is never split).
    pub fn for_calibration(cal: &Calibration) -> Self {
        SweepConfig {
            cut_azimuth: 18000,
            data_port: cal.model.data_port(),
            position_port: cal.model.position_port(),
        }
    }
}

/// A finished sweep, borrowed from the assembler's buffer until the callback returns.
#[derive(Debug)]
pub struct Sweep<'a> {
    pub points: &'a [Point],
    /// Time of the first and last point (see `Point::time` for the clock).
    pub start_time: f64,
    pub end_time: f64,
    /// Whether the sweep started at the cut (false for the first, partial one and a flush).
    pub complete: bool,
    /// Packets lost while this sweep was assembled.
    pub lost: u64,
    /// Points that did not fit the buffer.
    pub overflow: u64,
}

/// Number of recent packet fingerprints kept for duplicate detection.
const RECENT: usize = 32;

/// Assembles sweeps of one sensor into a caller-provided buffer.
pub struct SweepAssembler<'b> {
    cal: Calibration,
    config: SweepConfig,
    buf: &'b mut [Point],
    current: Current,
    stats: SweepStats,
    recent: [Option<u64>; RECENT],
    recent_next: usize,
    last_time: Option<f64>,
}

/// State of the sweep being filled.
#[derive(Clone, Copy, Debug, Default)]
struct Current {
    len: usize,
    start_time: f64,
    end_time: f64,
    complete: bool,
    lost: u64,
    overflow: u64,
    /// Azimuth of the last return relative to the cut, 0.01°.
    last_rel: Option<u16>,
}

impl<'b> SweepAssembler<'b> {
    /// An assembler writing into `buffer` (size it for a full turn: e.g. 2 × 64 × 1800 points
    /// for a dual-return Pandar64 at 10 Hz).
    pub fn new(cal: Calibration, config: SweepConfig, buffer: &'b mut [Point]) -> Self {
        SweepAssembler {
            cal,
            config,
            buf: buffer,
            current: Current::default(),
            stats: SweepStats::default(),
            recent: [None; RECENT],
            recent_next: 0,
            last_time: None,
        }
    }

    /// Counters since creation.
    pub fn stats(&self) -> SweepStats {
        self.stats
    }

    /// Points of the sweep being assembled.
    pub fn pending(&self) -> &[Point] {
        &self.buf[..self.current.len]
    }

    /// Feeds one UDP payload received on destination `port`; calls `on_sweep` for each sweep
    /// this payload completes (at most one in practice).
    pub fn push(&mut self, port: u16, payload: &[u8], on_sweep: &mut dyn FnMut(Sweep<'_>)) {
        let velodyne_position =
            self.cal.model.is_velodyne() && velodyne::PositionPacket::new_checked(payload).is_ok();
        if port == self.config.position_port || velodyne_position {
            self.stats.position += 1;
            return;
        }
        if port != self.config.data_port {
            self.stats.unknown += 1;
            return;
        }
        let fingerprint = fnv1a(payload);
        if self.recent.contains(&Some(fingerprint)) {
            self.stats.duplicates += 1;
            return;
        }
        let (time, reordered) = match self.check(payload) {
            Ok(t) => t,
            Err(e) => {
                self.stats.count_error(e);
                return;
            }
        };
        self.recent[self.recent_next] = Some(fingerprint);
        self.recent_next = (self.recent_next + 1) % RECENT;
        self.stats.reordered += u64::from(reordered);
        let (cut, cal) = (self.config.cut_azimuth, self.cal);
        let (buf, cur, stats) = (&mut *self.buf, &mut self.current, &mut self.stats);
        let mut sink = |r: Return| {
            let rel = ((36000 + u32::from(r.azimuth) - u32::from(cut)) % 36000) as u16;
            // A drop of more than half a turn is the wrap past the cut (reordered packets lag
            // by a few degrees at most and never cut).
            if !reordered && cur.last_rel.is_some_and(|last| rel + 18000 < last) {
                emit(buf, cur, stats, on_sweep);
                cur.complete = true;
            }
            if !reordered || cur.last_rel.is_none() {
                cur.last_rel = Some(rel);
            }
            push_point(buf, cur, stats, r.point);
        };
        if let Err(e) = decode_packet(&cal, payload, &mut sink) {
            // Unreachable after `check`, but never trust bytes.
            self.stats.count_error(e);
            return;
        }
        self.stats.packets += 1;
        if !reordered {
            self.last_time = Some(time);
        }
    }

    /// Hands out the sweep being assembled (marked incomplete), e.g. at the end of a capture.
    pub fn flush(&mut self, on_sweep: &mut dyn FnMut(Sweep<'_>)) {
        if self.current.len > 0 {
            self.current.complete = false;
            emit(self.buf, &mut self.current, &mut self.stats, on_sweep);
        }
    }

    /// Validates a payload and compares its time with the last packet's: returns its time and
    /// whether it is older (reordered); counts lost packets from a forward gap.
    fn check(&mut self, payload: &[u8]) -> Result<(f64, bool), DecodeError> {
        let model = self.cal.model;
        let (time, returns, period) = if model == Model::Ouster {
            let p = ouster::Packet::new_checked(payload, &self.cal.ouster)?;
            // Both returns travel in one packet: the period is the packet period.
            (p.timestamp(0) as f64 * 1e-9, 1, ouster::packet_period(&self.cal.ouster))
        } else if model.is_velodyne() {
            let p = velodyne::Packet::new_checked(payload)?;
            let product = velodyne::Product::from_id(p.product_id());
            if product.map(|p| p.model()) != Some(model) {
                return Err(DecodeError::WrongCalibration);
            }
            (
                f64::from(p.timestamp_us()) * 1e-6,
                p.return_mode().returns(),
                velodyne::packet_period(model),
            )
        } else {
            let p = hesai::Packet::new_checked(payload, model)?;
            (p.time(), p.return_mode().returns(), hesai::packet_period(model))
        };
        let Some(last) = self.last_time else { return Ok((time, false)) };
        let mut dt = time - last;
        // Velodyne time counts from the top of the hour.
        if model.is_velodyne() && dt < -1800.0 {
            dt += 3600.0;
        }
        if dt < 0.0 {
            return Ok((time, true));
        }
        // Dual-return packets carry half a turn's worth of blocks as often.
        let period = period / returns as f64;
        if dt > 1.5 * period {
            let lost = libm::round(dt / period) as u64 - 1;
            self.stats.lost += lost;
            self.current.lost += lost;
        }
        Ok((time, false))
    }
}

fn push_point(buf: &mut [Point], cur: &mut Current, stats: &mut SweepStats, p: Point) {
    stats.points += 1;
    if cur.len == 0 && cur.overflow == 0 {
        (cur.start_time, cur.end_time) = (p.time, p.time);
    }
    cur.start_time = cur.start_time.min(p.time);
    cur.end_time = cur.end_time.max(p.time);
    match buf.get_mut(cur.len) {
        Some(slot) => {
            *slot = p;
            cur.len += 1;
        }
        None => {
            cur.overflow += 1;
            stats.overflow += 1;
        }
    }
}

fn emit(
    buf: &[Point],
    cur: &mut Current,
    stats: &mut SweepStats,
    on_sweep: &mut dyn FnMut(Sweep<'_>),
) {
    stats.sweeps += 1;
    on_sweep(Sweep {
        points: &buf[..cur.len],
        start_time: cur.start_time,
        end_time: cur.end_time,
        complete: cur.complete,
        lost: cur.lost,
        overflow: cur.overflow,
    });
    *cur = Current { last_rel: cur.last_rel, ..Current::default() };
}

/// 64-bit FNV-1a of the payload: cheap, and enough to spot byte-identical repeats.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes
        .iter()
        .fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(*b)).wrapping_mul(0x100_0000_01b3))
}
