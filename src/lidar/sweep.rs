//! Sweep assembly from raw UDP payloads (no sockets, no heap): points go into a caller's
//! buffer and a sweep is handed out each time the firing azimuth passes the cut azimuth.
//! Lost packets are counted from timestamp jumps, reordered packets (older than the last
//! one) are kept in the current sweep without cutting it (and take back the loss their gap
//! counted), duplicates (byte-identical to one of the last 32 packets) are dropped, and
//! unknown, truncated, oversized and corrupted payloads are counted and dropped.
//!
//! One packet never moves the sweep's clock far: a packet must be consistent in itself
//! (azimuths advancing block by block — an Ouster's measurement ids column by column —, a
//! real date; the views' `check_consistency`), and
//! with the stream — its time within [`FORWARD_WINDOW_S`] after or [`REORDER_WINDOW_S`]
//! before the last packet's, its azimuth no further on than the sensor can turn in between
//! and, across a gap, where the sensor's measured turn rate puts it (so a packet with a
//! time a little ahead, as a flipped bit makes, cannot drag the clock along).
//! Anything else is dropped and counted (`out_of_sequence`) — unless [`RESYNC_AFTER`]
//! such packets in a row agree with each other, with no packet in sequence between them:
//! then the sensor's clock really jumped (a restart, a looped replay) and the assembler
//! follows it, marking the sweep in progress incomplete. (Valid packets of another clock
//! mixed into a live stream never take it over.)

use super::calibration::Calibration;
use super::common::{DecodeError, Model, Return};
use super::decoder::decode_packet;
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
    /// Bad magic, header, return mode, azimuth, azimuth order or timestamp field (dropped).
    pub corrupted: u64,
    /// Valid packets whose time or azimuth does not follow the stream's (dropped; see the
    /// module docs).
    pub out_of_sequence: u64,
    /// Times the assembler followed a jump of the sensor's clock.
    pub resyncs: u64,
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
            | DecodeError::BadAzimuth(_)
            | DecodeError::AzimuthOrder(_)
            | DecodeError::BadTimestamp => self.corrupted += 1,
        }
    }

    /// Payloads dropped for any reason.
    pub fn dropped(&self) -> u64 {
        self.duplicates
            + self.unknown
            + self.truncated
            + self.oversized
            + self.corrupted
            + self.out_of_sequence
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
    /// Data packets decoded into this sweep.
    pub packets: u64,
    /// Packets lost while this sweep was assembled (timestamp gaps not filled by late
    /// packets): the sensor sent `packets + lost`.
    pub lost: u64,
    /// Payloads dropped while this sweep was assembled (any reason in [`SweepStats::dropped`]).
    pub dropped: u64,
    /// Points that did not fit the buffer.
    pub overflow: u64,
}

/// Newest a packet may be after the last one and still be in sequence, seconds: a gap of
/// up to 2.5 turns at 10 Hz (a field-of-view limit leaves half a turn silent, every turn).
pub const FORWARD_WINDOW_S: f64 = 0.25;
/// Oldest a reordered packet may be, seconds: networks reorder by a few packets; anything
/// older belongs to a finished sweep.
pub const REORDER_WINDOW_S: f64 = 0.02;
/// Packets out of sequence but in sequence with each other after which the assembler takes
/// their clock as the sensor's.
pub const RESYNC_AFTER: u32 = 8;
/// The fastest turn of the supported sensors (20 Hz), 0.01° per second.
const MAX_TURN_RATE: f64 = 20.0 * 36000.0;
/// Azimuth a packet may run ahead of the turn rate (the packet time stamps its first or
/// last firing, depending on the vendor), 0.01°.
const AZIMUTH_SLACK: f64 = 1000.0;
/// Gaps (in packet periods) up to which consecutive packets measure the turn rate; beyond,
/// the rate predicts where the packet's azimuth must be.
const RATE_GAP: f64 = 4.0;
/// How far off the predicted azimuth a packet across a gap may be, as a share of the
/// predicted advance (on top of `AZIMUTH_SLACK`): the rate drifts and packets jitter.
const RATE_TOLERANCE: f64 = 0.05;

/// Number of recent packet fingerprints kept for duplicate detection.
const RECENT: usize = 32;

/// Assembles sweeps of one sensor into a caller-provided buffer (or, with `std`, one it
/// grows itself: [`SweepAssembler::growing`]).
pub struct SweepAssembler<'b> {
    cal: Calibration,
    config: SweepConfig,
    buf: Buffer<'b>,
    current: Current,
    stats: SweepStats,
    recent: [Option<u64>; RECENT],
    recent_next: usize,
    /// Time and last block azimuth of the newest packet in sequence.
    last: Option<Stamp>,
    /// The newest of the packets out of sequence that agree with each other, and how many.
    candidate: Option<(Stamp, u32)>,
    /// The sensor's turn rate measured from consecutive packets, 0.01° per second.
    turn_rate: Option<f64>,
}

/// Where a packet sits in the stream: its time (s) and its first and last block azimuths.
#[derive(Clone, Copy, Debug)]
struct Stamp {
    time: f64,
    first_azimuth: u16,
    last_azimuth: u16,
}

/// How a packet relates to the newest one in sequence.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Order {
    /// Later (by `dt` seconds).
    Next { dt: f64 },
    /// Slightly older: kept, never cuts.
    Reordered,
    /// Too far off in time or azimuth.
    OutOfSequence,
}

/// State of the sweep being filled.
#[derive(Clone, Copy, Debug, Default)]
struct Current {
    len: usize,
    start_time: f64,
    end_time: f64,
    complete: bool,
    packets: u64,
    lost: u64,
    dropped: u64,
    overflow: u64,
    /// Azimuth of the last return relative to the cut, 0.01°.
    last_rel: Option<u16>,
}

impl<'b> SweepAssembler<'b> {
    /// An assembler writing into `buffer` (size it for a full turn: e.g. 2 × 64 × 1800 points
    /// for a dual-return Pandar64 at 10 Hz).
    pub fn new(cal: Calibration, config: SweepConfig, buffer: &'b mut [Point]) -> Self {
        Self::with_buffer(cal, config, Buffer::Slice(buffer))
    }

    fn with_buffer(cal: Calibration, config: SweepConfig, buf: Buffer<'b>) -> Self {
        SweepAssembler {
            cal,
            config,
            buf,
            current: Current::default(),
            stats: SweepStats::default(),
            recent: [None; RECENT],
            recent_next: 0,
            last: None,
            candidate: None,
            turn_rate: None,
        }
    }

    /// Counters since creation.
    pub fn stats(&self) -> SweepStats {
        self.stats
    }

    /// Points of the sweep being assembled.
    pub fn pending(&self) -> &[Point] {
        self.buf.filled(self.current.len)
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
            self.current.dropped += 1;
            return;
        }
        let (stamp, period) = match self.stamp(payload) {
            Ok(s) => s,
            Err(e) => {
                self.stats.count_error(e);
                self.current.dropped += 1;
                return;
            }
        };
        let reordered = match self.order(stamp, period) {
            Order::Next { dt } => {
                // The clock in use is alive: packets that disagree with it are garbage.
                self.candidate = None;
                self.count_gap(dt, period);
                self.measure_turn_rate(stamp, dt, period);
                false
            }
            Order::Reordered => {
                self.candidate = None;
                // A late packet fills a gap its successor counted as lost.
                self.stats.lost = self.stats.lost.saturating_sub(1);
                self.current.lost = self.current.lost.saturating_sub(1);
                true
            }
            Order::OutOfSequence => {
                if !self.follow_clock_jump(stamp) {
                    self.stats.out_of_sequence += 1;
                    self.current.dropped += 1;
                    return;
                }
                false
            }
        };
        self.recent[self.recent_next] = Some(fingerprint);
        self.recent_next = (self.recent_next + 1) % RECENT;
        self.stats.reordered += u64::from(reordered);
        let (cut, cal) = (self.config.cut_azimuth, self.cal);
        let (buf, cur, stats) = (&mut self.buf, &mut self.current, &mut self.stats);
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
            // Unreachable after `stamp`, but never trust bytes.
            self.stats.count_error(e);
            return;
        }
        self.stats.packets += 1;
        self.current.packets += 1;
        if !reordered {
            self.last = Some(stamp);
        }
    }

    /// Hands out the sweep being assembled (marked incomplete), e.g. at the end of a capture.
    pub fn flush(&mut self, on_sweep: &mut dyn FnMut(Sweep<'_>)) {
        if self.current.len > 0 {
            self.current.complete = false;
            emit(&self.buf, &mut self.current, &mut self.stats, on_sweep);
        }
    }

    /// Validates a payload, in itself (the view's checks and `check_consistency`): its
    /// time, block azimuths and the packet period of its return mode.
    fn stamp(&self, payload: &[u8]) -> Result<(Stamp, f64), DecodeError> {
        let model = self.cal.model;
        let (stamp, returns, period) = if model == Model::Ouster {
            let p = ouster::Packet::new_checked(payload, &self.cal.ouster)?;
            p.check_consistency()?;
            // The columns' encoder directions stand for block azimuths. Both returns travel
            // in one packet: the period is the packet period.
            let columns = usize::from(self.cal.ouster.columns_per_packet);
            let stamp = Stamp {
                time: p.time(),
                first_azimuth: p.azimuth(0),
                last_azimuth: p.azimuth(columns - 1),
            };
            (stamp, 1, ouster::packet_period(&self.cal.ouster))
        } else if model.is_velodyne() {
            let p = velodyne::Packet::new_checked(payload)?;
            let product = velodyne::Product::from_id(p.product_id());
            if product.map(|p| p.model()) != Some(model) {
                return Err(DecodeError::WrongCalibration);
            }
            p.check_consistency()?;
            let stamp = Stamp {
                time: f64::from(p.timestamp_us()) * 1e-6,
                first_azimuth: p.azimuth(0),
                last_azimuth: p.azimuth(velodyne::field::BLOCKS - 1),
            };
            (stamp, p.return_mode().returns(), velodyne::packet_period(model))
        } else {
            let p = hesai::Packet::new_checked(payload, model)?;
            p.check_consistency()?;
            let stamp = Stamp {
                time: p.time(),
                first_azimuth: p.azimuth(0),
                last_azimuth: p.azimuth(p.layout().blocks - 1),
            };
            (stamp, p.return_mode().returns(), hesai::packet_period(model))
        };
        // Dual-return packets carry half a turn's worth of blocks as often.
        Ok((stamp, period / returns as f64))
    }

    /// Compares a packet with the newest one in sequence.
    fn order(&self, stamp: Stamp, period: f64) -> Order {
        match self.last {
            None => Order::Next { dt: 0.0 },
            Some(last) => self.follows(last, stamp, period),
        }
    }

    /// Whether `next` follows `last` in time (within the windows) and in azimuth (no further
    /// on than the fastest sensor turns in the time between).
    fn follows(&self, last: Stamp, next: Stamp, period: f64) -> Order {
        let mut dt = next.time - last.time;
        // Velodyne time counts from the top of the hour.
        if self.cal.model.is_velodyne() && dt < -1800.0 {
            dt += 3600.0;
        }
        if !(-REORDER_WINDOW_S..=FORWARD_WINDOW_S).contains(&dt) {
            return Order::OutOfSequence;
        }
        if dt < 0.0 {
            return Order::Reordered;
        }
        let reach = (dt + period) * MAX_TURN_RATE + AZIMUTH_SLACK;
        if f64::from(advance(last.last_azimuth, next.first_azimuth)) > reach {
            return Order::OutOfSequence;
        }
        if let Some(rate) = self.turn_rate.filter(|_| dt > RATE_GAP * period) {
            let predicted = dt * rate;
            let measured = f64::from(advance(last.first_azimuth, next.first_azimuth));
            let off = libm::fabs(measured - libm::fmod(predicted, 36000.0));
            let off = off.min(36000.0 - off);
            if off > AZIMUTH_SLACK + RATE_TOLERANCE * predicted {
                return Order::OutOfSequence;
            }
        }
        Order::Next { dt }
    }

    /// Updates the turn rate from a packet `dt` after the last one in sequence (a running
    /// mean over about 16 packets), when the gap is short enough to measure it.
    fn measure_turn_rate(&mut self, stamp: Stamp, dt: f64, period: f64) {
        let Some(last) = self.last else { return };
        if dt <= 0.0 || dt > RATE_GAP * period {
            return;
        }
        let rate = f64::from(advance(last.first_azimuth, stamp.first_azimuth)) / dt;
        if rate > 2.0 * MAX_TURN_RATE {
            return;
        }
        self.turn_rate = Some(match self.turn_rate {
            Some(r) => r + (rate - r) / 16.0,
            None => rate,
        });
    }

    /// Counts the packets a forward gap of `dt` seconds implies were lost.
    fn count_gap(&mut self, dt: f64, period: f64) {
        if dt > 1.5 * period {
            let lost = libm::round(dt / period) as u64 - 1;
            self.stats.lost += lost;
            self.current.lost += lost;
        }
    }

    /// A packet out of sequence: remembers it, and once [`RESYNC_AFTER`] of them follow each
    /// other, takes their clock (true: decode this packet). The sweep in progress spans
    /// the jump: it is marked incomplete.
    fn follow_clock_jump(&mut self, stamp: Stamp) -> bool {
        let chained = self.candidate.and_then(|(c, n)| {
            matches!(self.follows(c, stamp, 0.0), Order::Next { .. }).then_some(n + 1)
        });
        let n = chained.unwrap_or(1);
        if n < RESYNC_AFTER {
            self.candidate = Some((stamp, n));
            return false;
        }
        self.candidate = None;
        self.stats.resyncs += 1;
        self.current.complete = false;
        true
    }
}

#[cfg(feature = "std")]
impl SweepAssembler<'static> {
    /// An assembler that keeps the sweep in a vector of its own, grown as points arrive up
    /// to `limit` points (then they count as overflow): memory follows the sensor's real
    /// sweep (a single-return Pandar64 at 10 Hz fills 115 k points, 3.7 MB) instead of the
    /// worst case a fixed buffer must be sized for (dual return at 5 Hz: 460 k, 14.7 MB).
    pub fn growing(cal: Calibration, config: SweepConfig, limit: usize) -> Self {
        Self::with_buffer(cal, config, Buffer::Growing { points: Vec::new(), limit })
    }
}

/// Where the sweep being filled is kept.
enum Buffer<'b> {
    /// The caller's, fixed.
    Slice(&'b mut [Point]),
    /// The assembler's own, grown on demand up to `limit` points.
    #[cfg(feature = "std")]
    Growing { points: Vec<Point>, limit: usize },
}

impl Buffer<'_> {
    /// The slot of point `i` (points are pushed in order), or `None` when full.
    fn slot(&mut self, i: usize) -> Option<&mut Point> {
        match self {
            Buffer::Slice(s) => s.get_mut(i),
            #[cfg(feature = "std")]
            Buffer::Growing { points, limit } => {
                if i == points.len() && i < *limit {
                    points.push(Point::default());
                }
                points.get_mut(i)
            }
        }
    }

    /// The first `len` points (`len` never exceeds what [`Buffer::slot`] handed out).
    fn filled(&self, len: usize) -> &[Point] {
        match self {
            Buffer::Slice(s) => &s[..len],
            #[cfg(feature = "std")]
            Buffer::Growing { points, .. } => &points[..len],
        }
    }
}

/// Clockwise advance from azimuth `from` to `to`, 0.01° (0 ..< 36000).
fn advance(from: u16, to: u16) -> u32 {
    (36000 + u32::from(to) - u32::from(from)) % 36000
}

fn push_point(buf: &mut Buffer<'_>, cur: &mut Current, stats: &mut SweepStats, p: Point) {
    stats.points += 1;
    if cur.len == 0 && cur.overflow == 0 {
        (cur.start_time, cur.end_time) = (p.time, p.time);
    }
    cur.start_time = cur.start_time.min(p.time);
    cur.end_time = cur.end_time.max(p.time);
    match buf.slot(cur.len) {
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
    buf: &Buffer<'_>,
    cur: &mut Current,
    stats: &mut SweepStats,
    on_sweep: &mut dyn FnMut(Sweep<'_>),
) {
    stats.sweeps += 1;
    on_sweep(Sweep {
        points: buf.filled(cur.len),
        start_time: cur.start_time,
        end_time: cur.end_time,
        complete: cur.complete,
        packets: cur.packets,
        lost: cur.lost,
        dropped: cur.dropped,
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
