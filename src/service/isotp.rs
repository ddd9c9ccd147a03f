//! ISO-TP (ISO 15765-2) on classic CAN, normal addressing: the frame (PCI) wire format
//! and a sans-I/O endpoint state machine.
//!
//! [`Pdu`] is a zero-copy view over one CAN frame's data with a checked constructor;
//! [`PduRepr`] parses and emits single, first, consecutive and flow-control frames.
//! [`IsoTp`] segments outgoing messages and reassembles incoming ones (up to `N` bytes,
//! at most 4095 on classic CAN), honours block size and STmin both ways and enforces the
//! N_As/N_Ar, N_Bs and N_Cr timeouts. It never reads a clock and never blocks: the caller
//! feeds received frames ([`IsoTp::on_frame`]), asks for frames to put on the bus
//! ([`IsoTp::poll_transmit`]), confirms each one once the bus took it
//! ([`IsoTp::frame_sent`]) and calls [`IsoTp::poll`] at [`IsoTp::poll_at`] for timeouts.

use core::fmt;
use core::time::Duration;

use super::{CanFrame, Instant};

/// Largest message ISO-TP carries on classic CAN (12-bit first-frame length).
pub const MAX_MESSAGE_LEN: usize = 4095;
/// Classic CAN frame data length.
pub const CAN_DATA_LEN: usize = 8;
/// Default padding byte for unused frame bytes.
pub const DEFAULT_PADDING: u8 = 0xCC;

/// Byte offsets of the protocol control information, per frame type.
mod field {
    use core::ops::{Range, RangeFrom};
    /// High nibble: frame type; low nibble: SF_DL, FF_DL high bits, SN or FS.
    pub const PCI: usize = 0;
    pub const SF_DATA: RangeFrom<usize> = 1..;
    pub const FF_LEN: Range<usize> = 0..2;
    pub const FF_DATA: RangeFrom<usize> = 2..;
    pub const CF_DATA: RangeFrom<usize> = 1..;
    pub const FC_BLOCK_SIZE: usize = 1;
    pub const FC_ST_MIN: usize = 2;
    pub const FC_LEN: usize = 3;
}

/// Frame type, the high nibble of the first byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameType {
    Single = 0,
    First = 1,
    Consecutive = 2,
    FlowControl = 3,
}

/// Why a CAN frame's data is not a valid ISO-TP frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ParseError {
    /// Fewer bytes than the frame type needs (the value: bytes present).
    Truncated(usize),
    /// Frame type nibble 4..15 (the value: the nibble).
    UnknownType(u8),
    /// SF_DL 0 or above 7, or FF_DL 0 (escape sequences are CAN FD only).
    BadLength,
    /// Flow status 3..15 (the value: the nibble).
    BadFlowStatus(u8),
}

impl fmt::Display for ParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ParseError::Truncated(n) => write!(f, "ISO-TP frame truncated ({n} bytes)"),
            ParseError::UnknownType(t) => write!(f, "unknown ISO-TP frame type {t:#x}"),
            ParseError::BadLength => write!(f, "ISO-TP length field out of range for classic CAN"),
            ParseError::BadFlowStatus(s) => write!(f, "invalid ISO-TP flow status {s:#x}"),
        }
    }
}

/// A read-only view of one ISO-TP frame (the data of one CAN frame).
#[derive(Clone, Copy, Debug)]
pub struct Pdu<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> Pdu<T> {
    /// Wraps bytes without checking; accessors may panic on short input.
    pub const fn new_unchecked(buffer: T) -> Self {
        Pdu { buffer }
    }

    /// Wraps bytes after [`Pdu::check_len`]: every accessor is then panic-free.
    pub fn new_checked(buffer: T) -> Result<Self, ParseError> {
        let pdu = Self::new_unchecked(buffer);
        pdu.check_len()?;
        Ok(pdu)
    }

    /// Checks that the bytes hold a complete frame of the type they announce.
    pub fn check_len(&self) -> Result<(), ParseError> {
        let b = self.buffer.as_ref();
        let Some(&pci) = b.first() else {
            return Err(ParseError::Truncated(0));
        };
        let need = match pci >> 4 {
            0 => {
                let sf_dl = usize::from(pci & 0x0F);
                if sf_dl == 0 || sf_dl > CAN_DATA_LEN - 1 {
                    return Err(ParseError::BadLength);
                }
                1 + sf_dl
            }
            // A classic-CAN first frame always fills the frame.
            1 => CAN_DATA_LEN,
            2 => 2,
            3 => field::FC_LEN,
            t => return Err(ParseError::UnknownType(t)),
        };
        if b.len() < need {
            return Err(ParseError::Truncated(b.len()));
        }
        if pci >> 4 == 1 && self.ff_len() == 0 {
            return Err(ParseError::BadLength);
        }
        Ok(())
    }

    /// The frame type nibble (0..=3 once checked).
    pub fn frame_type(&self) -> FrameType {
        match self.buffer.as_ref()[field::PCI] >> 4 {
            0 => FrameType::Single,
            1 => FrameType::First,
            2 => FrameType::Consecutive,
            _ => FrameType::FlowControl,
        }
    }

    /// Single frame: SF_DL, the payload length.
    pub fn sf_len(&self) -> usize {
        usize::from(self.buffer.as_ref()[field::PCI] & 0x0F)
    }

    /// First frame: FF_DL, the whole message length.
    pub fn ff_len(&self) -> usize {
        let b = &self.buffer.as_ref()[field::FF_LEN];
        usize::from(u16::from_be_bytes([b[0], b[1]]) & 0x0FFF)
    }

    /// Consecutive frame: the sequence number (0..=15).
    pub fn sequence(&self) -> u8 {
        self.buffer.as_ref()[field::PCI] & 0x0F
    }

    /// Flow control: the raw flow status nibble.
    pub fn flow_status(&self) -> u8 {
        self.buffer.as_ref()[field::PCI] & 0x0F
    }

    /// Flow control: block size (0 = send everything without further flow control).
    pub fn block_size(&self) -> u8 {
        self.buffer.as_ref()[field::FC_BLOCK_SIZE]
    }

    /// Flow control: raw STmin byte.
    pub fn st_min(&self) -> StMin {
        StMin(self.buffer.as_ref()[field::FC_ST_MIN])
    }

    /// Payload bytes: SF data (exactly SF_DL), FF and CF data (to the end of the frame,
    /// padding included: only the receiver knows how much of it is data), none for FC.
    pub fn payload(&self) -> &[u8] {
        let b = self.buffer.as_ref();
        match self.frame_type() {
            FrameType::Single => &b[field::SF_DATA][..self.sf_len()],
            FrameType::First => &b[field::FF_DATA],
            FrameType::Consecutive => &b[field::CF_DATA],
            FrameType::FlowControl => &[],
        }
    }
}

/// Flow status of a flow-control frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlowStatus {
    ContinueToSend = 0,
    Wait = 1,
    Overflow = 2,
}

/// Separation time minimum, as the raw byte of a flow-control frame.
///
/// 0x00–0x7F: that many milliseconds; 0xF1–0xF9: 100–900 µs. Reserved values are read as
/// 0x7F (127 ms), as ISO 15765-2 asks of a sender that receives one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StMin(pub u8);

impl StMin {
    /// The separation time the byte asks for.
    pub fn duration(self) -> Duration {
        match self.0 {
            ms @ 0x00..=0x7F => Duration::from_millis(u64::from(ms)),
            us @ 0xF1..=0xF9 => Duration::from_micros(u64::from(us - 0xF0) * 100),
            _ => Duration::from_millis(0x7F),
        }
    }

    /// The smallest encodable STmin not shorter than `d` (127 ms at most).
    pub fn from_duration(d: Duration) -> StMin {
        let us = d.as_micros();
        if us == 0 {
            StMin(0)
        } else if us <= 900 {
            // 100 µs steps, rounded up.
            StMin(0xF0 + u8::try_from(us.div_ceil(100)).unwrap_or(9))
        } else {
            StMin(u8::try_from(us.div_ceil(1000)).unwrap_or(0x7F).min(0x7F))
        }
    }
}

/// One parsed ISO-TP frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PduRepr<'a> {
    /// The whole message (1–7 bytes).
    Single { data: &'a [u8] },
    /// Start of a segmented message of `len` bytes; `data` are its first 6 bytes.
    First { len: u16, data: &'a [u8] },
    /// Continuation; `data` may end in padding.
    Consecutive { sequence: u8, data: &'a [u8] },
    /// The receiver's flow control.
    FlowControl { status: FlowStatus, block_size: u8, st_min: StMin },
}

impl<'a> PduRepr<'a> {
    /// Parses the data of one CAN frame.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, ParseError> {
        let pdu = Pdu::new_checked(bytes)?;
        Ok(match pdu.frame_type() {
            FrameType::Single => PduRepr::Single { data: &bytes[1..1 + pdu.sf_len()] },
            FrameType::First => PduRepr::First {
                len: u16::try_from(pdu.ff_len()).unwrap_or(0),
                data: &bytes[field::FF_DATA][..CAN_DATA_LEN - 2],
            },
            FrameType::Consecutive => {
                PduRepr::Consecutive { sequence: pdu.sequence(), data: &bytes[field::CF_DATA] }
            }
            FrameType::FlowControl => PduRepr::FlowControl {
                status: match pdu.flow_status() {
                    0 => FlowStatus::ContinueToSend,
                    1 => FlowStatus::Wait,
                    2 => FlowStatus::Overflow,
                    s => return Err(ParseError::BadFlowStatus(s)),
                },
                block_size: pdu.block_size(),
                st_min: pdu.st_min(),
            },
        })
    }

    /// Bytes [`PduRepr::emit`] writes (before padding).
    pub fn buffer_len(&self) -> usize {
        match self {
            PduRepr::Single { data } => 1 + data.len().min(7),
            PduRepr::First { data, .. } => 2 + data.len().min(6),
            PduRepr::Consecutive { data, .. } => 1 + data.len().min(7),
            PduRepr::FlowControl { .. } => field::FC_LEN,
        }
    }

    /// Writes the frame into `buf` (at least [`PduRepr::buffer_len`] bytes, else nothing
    /// is written and 0 returned); returns the bytes written. Data beyond what one frame
    /// carries is cut.
    pub fn emit(&self, buf: &mut [u8]) -> usize {
        let n = self.buffer_len();
        if buf.len() < n {
            return 0;
        }
        match *self {
            PduRepr::Single { data } => {
                buf[0] = (n - 1) as u8; // n - 1 <= 7
                buf[1..n].copy_from_slice(&data[..n - 1]);
            }
            PduRepr::First { len, data } => {
                buf[..2].copy_from_slice(&(0x1000 | (len & 0x0FFF)).to_be_bytes());
                buf[2..n].copy_from_slice(&data[..n - 2]);
            }
            PduRepr::Consecutive { sequence, data } => {
                buf[0] = 0x20 | (sequence & 0x0F);
                buf[1..n].copy_from_slice(&data[..n - 1]);
            }
            PduRepr::FlowControl { status, block_size, st_min } => {
                buf[0] = 0x30 | status as u8;
                buf[field::FC_BLOCK_SIZE] = block_size;
                buf[field::FC_ST_MIN] = st_min.0;
            }
        }
        n
    }
}

/// Parameters of one ISO-TP endpoint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Config {
    /// CAN ID of frames this endpoint sends.
    pub tx_id: u32,
    /// CAN ID of frames this endpoint accepts; all others are ignored.
    pub rx_id: u32,
    /// Whether both IDs are 29-bit.
    pub extended: bool,
    /// Pad every frame to 8 bytes with this byte; `None`: frames as short as their data.
    pub padding: Option<u8>,
    /// Block size this endpoint asks of senders (0: no further flow control).
    pub block_size: u8,
    /// STmin this endpoint asks of senders.
    pub st_min: StMin,
    /// N_As / N_Ar: time for the bus to take a frame once handed out.
    pub n_as: Duration,
    /// N_Bs: time to wait for a flow-control frame.
    pub n_bs: Duration,
    /// N_Cr: time to wait for the next consecutive frame.
    pub n_cr: Duration,
    /// N_WFTmax: flow-control WAIT frames accepted in a row before giving up.
    pub max_wait_frames: u8,
}

impl Config {
    /// Defaults: padding 0xCC, block size 0, STmin 0, all timeouts 1000 ms (ISO 15765-2
    /// defaults), 10 WAIT frames at most. The IDs are 29-bit when either does not fit 11
    /// bits (set `extended` for 29-bit IDs below 0x800).
    pub const fn new(tx_id: u32, rx_id: u32) -> Self {
        Config {
            tx_id,
            rx_id,
            // An 11-bit endpoint would never match frames with such an ID.
            extended: tx_id > super::MAX_STANDARD_ID || rx_id > super::MAX_STANDARD_ID,
            padding: Some(DEFAULT_PADDING),
            block_size: 0,
            st_min: StMin(0),
            n_as: Duration::from_millis(1000),
            n_bs: Duration::from_millis(1000),
            n_cr: Duration::from_millis(1000),
            max_wait_frames: 10,
        }
    }
}

/// Why a reception was abandoned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RxError {
    /// A consecutive frame carried the wrong sequence number (expected, got).
    WrongSequence { expected: u8, got: u8 },
    /// N_Cr expired waiting for a consecutive frame.
    Timeout,
    /// N_Ar expired: our flow-control frame was not confirmed sent.
    FlowControlNotSent,
    /// A new first frame replaced the message being received.
    Interrupted,
}

/// Why a transmission was refused or abandoned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TxError {
    /// A message is still being sent.
    Busy,
    /// Empty messages cannot be sent.
    Empty,
    /// Longer than the endpoint's buffer or 4095 bytes.
    TooLong(usize),
    /// N_Bs expired waiting for flow control.
    Timeout,
    /// N_As expired: a frame was not confirmed sent.
    NotSent,
    /// The receiver answered flow status Overflow.
    Overflow,
    /// More WAIT flow-control frames than `max_wait_frames`.
    TooManyWaits,
    /// A flow-control frame with a reserved flow status.
    InvalidFlowStatus(u8),
}

impl fmt::Display for RxError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RxError::WrongSequence { expected, got } => {
                write!(f, "ISO-TP reception aborted: sequence number {got}, expected {expected}")
            }
            RxError::Timeout => write!(f, "ISO-TP reception aborted: N_Cr timeout"),
            RxError::FlowControlNotSent => write!(f, "ISO-TP reception aborted: N_Ar timeout"),
            RxError::Interrupted => write!(f, "ISO-TP reception aborted by a new first frame"),
        }
    }
}

impl fmt::Display for TxError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TxError::Busy => write!(f, "ISO-TP transmitter busy"),
            TxError::Empty => write!(f, "empty ISO-TP message"),
            TxError::TooLong(n) => write!(f, "ISO-TP message of {n} bytes is too long"),
            TxError::Timeout => write!(f, "ISO-TP transmission aborted: N_Bs timeout"),
            TxError::NotSent => write!(f, "ISO-TP transmission aborted: N_As timeout"),
            TxError::Overflow => write!(f, "ISO-TP transmission aborted: receiver overflow"),
            TxError::TooManyWaits => write!(f, "ISO-TP transmission aborted: too many WAIT frames"),
            TxError::InvalidFlowStatus(s) => {
                write!(f, "ISO-TP transmission aborted: invalid flow status {s:#x}")
            }
        }
    }
}

/// What happened, as reported by the endpoint's methods.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Event {
    /// A whole message of this many bytes arrived: read it with [`IsoTp::received`]
    /// before feeding the next frame.
    Received(usize),
    /// The message given to [`IsoTp::send`] is completely on the bus.
    Sent,
    /// Reception abandoned.
    RxAborted(RxError),
    /// Transmission abandoned.
    TxAborted(TxError),
}

/// An ISO-TP endpoint with `N`-byte receive and transmit buffers (`N` ≤ 4095).
pub struct IsoTp<const N: usize = MAX_MESSAGE_LEN> {
    cfg: Config,
    rx: Rx,
    tx: Tx,
    in_flight: Option<InFlight>,
    rx_buf: [u8; N],
    rx_len: usize,
    tx_buf: [u8; N],
    tx_len: usize,
}

#[derive(Clone, Copy, Debug)]
enum Rx {
    Idle,
    /// An overflow flow control is owed to a first frame we cannot take.
    OverflowDue,
    Receiving {
        total: usize,
        got: usize,
        next_sn: u8,
        block_left: u8,
        fc_due: bool,
        deadline: Option<Instant>,
    },
}

#[derive(Clone, Copy, Debug)]
enum Tx {
    Idle,
    Single,
    First,
    /// `last_cf`: when the previous block's last consecutive frame went out; STmin
    /// also separates it from the next block's first.
    WaitFc {
        offset: usize,
        sn: u8,
        deadline: Option<Instant>,
        waits: u8,
        last_cf: Option<Instant>,
    },
    Consecutive {
        offset: usize,
        sn: u8,
        block_left: u8,
        unlimited: bool,
        st_min: Duration,
        next_at: Instant,
    },
}

#[derive(Clone, Copy, Debug)]
enum InFlight {
    TxSingle(Instant),
    TxFirst(Instant),
    TxConsecutive { deadline: Instant, last: bool, block_done: bool },
    RxFlowControl { deadline: Instant, overflow: bool },
}

impl InFlight {
    fn deadline(self) -> Instant {
        match self {
            InFlight::TxSingle(d) | InFlight::TxFirst(d) => d,
            InFlight::TxConsecutive { deadline, .. } | InFlight::RxFlowControl { deadline, .. } => {
                deadline
            }
        }
    }
}

impl<const N: usize> IsoTp<N> {
    /// A fresh endpoint; `N` above 4095 is usable only up to 4095.
    pub fn new(cfg: Config) -> Self {
        IsoTp {
            cfg,
            rx: Rx::Idle,
            tx: Tx::Idle,
            in_flight: None,
            rx_buf: [0; N],
            rx_len: 0,
            tx_buf: [0; N],
            tx_len: 0,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// Drops any message in progress in both directions.
    pub fn reset(&mut self) {
        self.rx = Rx::Idle;
        self.tx = Tx::Idle;
        self.in_flight = None;
        self.rx_len = 0;
    }

    /// Abandons the message being sent, if any (the receiving side of the endpoint
    /// carries on); true when there was one. A flow control that arrives afterwards is
    /// ignored, as any flow control outside a transmission.
    pub fn abort_send(&mut self) -> bool {
        let was_sending = self.is_sending();
        self.tx = Tx::Idle;
        if matches!(self.in_flight, Some(f) if !matches!(f, InFlight::RxFlowControl { .. })) {
            self.in_flight = None;
        }
        was_sending
    }

    /// True while a message is being sent.
    pub fn is_sending(&self) -> bool {
        !matches!(self.tx, Tx::Idle)
    }

    /// True while a segmented message is being received.
    pub fn is_receiving(&self) -> bool {
        !matches!(self.rx, Rx::Idle)
    }

    /// The last message received (valid after [`Event::Received`]).
    pub fn received(&self) -> &[u8] {
        &self.rx_buf[..self.rx_len]
    }

    /// Queues `msg` for sending.
    pub fn send(&mut self, msg: &[u8]) -> Result<(), TxError> {
        if self.is_sending() {
            return Err(TxError::Busy);
        }
        if msg.is_empty() {
            return Err(TxError::Empty);
        }
        if msg.len() > N.min(MAX_MESSAGE_LEN) {
            return Err(TxError::TooLong(msg.len()));
        }
        self.tx_buf[..msg.len()].copy_from_slice(msg);
        self.tx_len = msg.len();
        self.tx = if msg.len() < CAN_DATA_LEN { Tx::Single } else { Tx::First };
        Ok(())
    }

    /// Feeds one received CAN frame. Frames with other IDs, malformed frames and
    /// unexpected consecutive or flow-control frames are ignored.
    pub fn on_frame(&mut self, frame: &CanFrame, now: Instant) -> Option<Event> {
        if frame.id != self.cfg.rx_id || frame.extended != self.cfg.extended {
            return None;
        }
        match PduRepr::parse(&frame.data) {
            Ok(PduRepr::Single { data }) => Some(self.on_single(data)),
            Ok(PduRepr::First { len, data }) => self.on_first(usize::from(len), data),
            Ok(PduRepr::Consecutive { sequence, data }) => self.on_consecutive(sequence, data, now),
            Ok(PduRepr::FlowControl { status, block_size, st_min }) => {
                self.on_flow_control(Ok(status), block_size, st_min, now)
            }
            Err(ParseError::BadFlowStatus(s)) => self.on_flow_control(Err(s), 0, StMin(0), now),
            Err(_) => None,
        }
    }

    /// The next frame to put on the bus at `now`, if any. After handing one out the
    /// endpoint waits for [`IsoTp::frame_sent`] before the next.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<CanFrame> {
        if self.in_flight.is_some() {
            return None;
        }
        let deadline = now + self.cfg.n_as;
        if let Some(frame) = self.flow_control_due(deadline) {
            return Some(frame);
        }
        match self.tx {
            Tx::Single => {
                self.in_flight = Some(InFlight::TxSingle(deadline));
                let len = self.tx_len;
                Some(self.frame(&PduRepr::Single { data: &self.tx_buf[..len] }))
            }
            Tx::First => {
                self.in_flight = Some(InFlight::TxFirst(deadline));
                // len <= 4095 by construction of `send`.
                let len = self.tx_len as u16;
                Some(self.frame(&PduRepr::First { len, data: &self.tx_buf[..6] }))
            }
            Tx::Consecutive { offset, sn, block_left, unlimited, st_min, next_at } => {
                if now < next_at {
                    return None;
                }
                let end = (offset + 7).min(self.tx_len);
                let block_left = if unlimited { block_left } else { block_left.saturating_sub(1) };
                let last = end == self.tx_len;
                let block_done = !unlimited && block_left == 0;
                self.tx = Tx::Consecutive {
                    offset: end,
                    sn: (sn + 1) & 0x0F,
                    block_left,
                    unlimited,
                    st_min,
                    next_at,
                };
                self.in_flight = Some(InFlight::TxConsecutive { deadline, last, block_done });
                Some(
                    self.frame(&PduRepr::Consecutive {
                        sequence: sn,
                        data: &self.tx_buf[offset..end],
                    }),
                )
            }
            Tx::Idle | Tx::WaitFc { .. } => None,
        }
    }

    /// Confirms that the frame last handed out by [`IsoTp::poll_transmit`] is on the bus.
    pub fn frame_sent(&mut self, now: Instant) -> Option<Event> {
        match self.in_flight.take()? {
            InFlight::TxSingle(_) => {
                self.tx = Tx::Idle;
                Some(Event::Sent)
            }
            InFlight::TxFirst(_) => {
                let deadline = Some(now + self.cfg.n_bs);
                let offset = CAN_DATA_LEN - 2;
                self.tx = Tx::WaitFc { offset, sn: 1, deadline, waits: 0, last_cf: None };
                None
            }
            InFlight::TxConsecutive { last, block_done, .. } => {
                if last {
                    self.tx = Tx::Idle;
                    return Some(Event::Sent);
                }
                if let Tx::Consecutive { offset, sn, st_min, ref mut next_at, .. } = self.tx {
                    if block_done {
                        let deadline = Some(now + self.cfg.n_bs);
                        let last_cf = Some(now);
                        self.tx = Tx::WaitFc { offset, sn, deadline, waits: 0, last_cf };
                    } else {
                        *next_at = now + st_min;
                    }
                }
                None
            }
            InFlight::RxFlowControl { overflow, .. } => {
                if overflow {
                    self.rx = Rx::Idle;
                } else if let Rx::Receiving { ref mut deadline, .. } = self.rx {
                    *deadline = Some(now + self.cfg.n_cr);
                }
                None
            }
        }
    }

    /// Checks the timeouts at `now`; call it at [`IsoTp::poll_at`].
    pub fn poll(&mut self, now: Instant) -> Option<Event> {
        if let Some(f) = self.in_flight {
            if now >= f.deadline() {
                self.in_flight = None;
                return Some(match f {
                    InFlight::RxFlowControl { .. } => {
                        self.rx = Rx::Idle;
                        Event::RxAborted(RxError::FlowControlNotSent)
                    }
                    _ => {
                        self.tx = Tx::Idle;
                        Event::TxAborted(TxError::NotSent)
                    }
                });
            }
        }
        if let Rx::Receiving { deadline: Some(d), .. } = self.rx {
            if now >= d {
                self.rx = Rx::Idle;
                return Some(Event::RxAborted(RxError::Timeout));
            }
        }
        if let Tx::WaitFc { deadline: Some(d), .. } = self.tx {
            if now >= d {
                self.tx = Tx::Idle;
                return Some(Event::TxAborted(TxError::Timeout));
            }
        }
        None
    }

    /// The earliest instant at which [`IsoTp::poll`] or [`IsoTp::poll_transmit`] has
    /// something to do; `Instant::from_micros(0)` when a frame is ready now.
    pub fn poll_at(&self) -> Option<Instant> {
        let mut at: Option<Instant> = None;
        let mut consider = |t: Instant| at = Some(at.map_or(t, |a| a.min(t)));
        if let Some(f) = self.in_flight {
            consider(f.deadline());
        } else {
            let fc_due = matches!(self.rx, Rx::OverflowDue | Rx::Receiving { fc_due: true, .. });
            match self.tx {
                _ if fc_due => consider(Instant::from_micros(0)),
                Tx::Single | Tx::First => consider(Instant::from_micros(0)),
                Tx::Consecutive { next_at, .. } => consider(next_at),
                _ => {}
            }
        }
        if let Rx::Receiving { deadline: Some(d), .. } = self.rx {
            consider(d);
        }
        if let Tx::WaitFc { deadline: Some(d), .. } = self.tx {
            consider(d);
        }
        at
    }

    fn on_single(&mut self, data: &[u8]) -> Event {
        // A single frame ends any reception in progress (ISO 15765-2: unexpected SF
        // starts a new reception).
        self.rx = Rx::Idle;
        if data.len() > N {
            return Event::RxAborted(RxError::Interrupted);
        }
        self.rx_buf[..data.len()].copy_from_slice(data);
        self.rx_len = data.len();
        Event::Received(data.len())
    }

    fn on_first(&mut self, len: usize, data: &[u8]) -> Option<Event> {
        // A first frame whose message would fit a single frame is invalid: ignore it.
        if len < CAN_DATA_LEN {
            return None;
        }
        let was_receiving = matches!(self.rx, Rx::Receiving { .. });
        if len > N {
            self.rx = Rx::OverflowDue;
            return was_receiving.then_some(Event::RxAborted(RxError::Interrupted));
        }
        self.rx_buf[..data.len()].copy_from_slice(data);
        self.rx_len = 0;
        self.rx = Rx::Receiving {
            total: len,
            got: data.len(),
            next_sn: 1,
            block_left: self.cfg.block_size,
            fc_due: true,
            deadline: None,
        };
        was_receiving.then_some(Event::RxAborted(RxError::Interrupted))
    }

    fn on_consecutive(&mut self, sn: u8, data: &[u8], now: Instant) -> Option<Event> {
        // Consecutive frames before our flow control went out are unexpected: ignore.
        let Rx::Receiving { total, got, next_sn, block_left, fc_due: false, .. } = self.rx else {
            return None;
        };
        if matches!(self.in_flight, Some(InFlight::RxFlowControl { .. })) {
            return None;
        }
        if sn != next_sn {
            self.rx = Rx::Idle;
            return Some(Event::RxAborted(RxError::WrongSequence { expected: next_sn, got: sn }));
        }
        let take = (total - got).min(CAN_DATA_LEN - 1);
        // A frame shorter than the data it must carry is ignored (ISO 15765-2 9.6.3).
        if data.len() < take {
            return None;
        }
        self.rx_buf[got..got + take].copy_from_slice(&data[..take]);
        let got = got + take;
        if got == total {
            self.rx = Rx::Idle;
            self.rx_len = total;
            return Some(Event::Received(total));
        }
        let bs = self.cfg.block_size;
        let (block_left, fc_due) = match bs {
            0 => (0, false),
            _ if block_left <= 1 => (bs, true),
            _ => (block_left - 1, false),
        };
        self.rx = Rx::Receiving {
            total,
            got,
            next_sn: (sn + 1) & 0x0F,
            block_left,
            fc_due,
            deadline: if fc_due { None } else { Some(now + self.cfg.n_cr) },
        };
        None
    }

    fn on_flow_control(
        &mut self,
        status: Result<FlowStatus, u8>,
        block_size: u8,
        st_min: StMin,
        now: Instant,
    ) -> Option<Event> {
        // Flow control is only expected while waiting for it.
        let Tx::WaitFc { offset, sn, waits, last_cf, .. } = self.tx else {
            return None;
        };
        match status {
            Ok(FlowStatus::ContinueToSend) => {
                let st_min = st_min.duration();
                self.tx = Tx::Consecutive {
                    offset,
                    sn,
                    block_left: block_size,
                    unlimited: block_size == 0,
                    st_min,
                    next_at: last_cf.map_or(now, |t| (t + st_min).max(now)),
                };
                None
            }
            Ok(FlowStatus::Wait) => {
                if waits >= self.cfg.max_wait_frames {
                    self.tx = Tx::Idle;
                    return Some(Event::TxAborted(TxError::TooManyWaits));
                }
                let deadline = Some(now + self.cfg.n_bs);
                self.tx = Tx::WaitFc { offset, sn, deadline, waits: waits + 1, last_cf };
                None
            }
            Ok(FlowStatus::Overflow) => {
                self.tx = Tx::Idle;
                Some(Event::TxAborted(TxError::Overflow))
            }
            Err(s) => {
                self.tx = Tx::Idle;
                Some(Event::TxAborted(TxError::InvalidFlowStatus(s)))
            }
        }
    }

    /// Hands out the flow-control frame the receiver owes, if any.
    fn flow_control_due(&mut self, deadline: Instant) -> Option<CanFrame> {
        let (status, overflow) = match self.rx {
            Rx::OverflowDue => (FlowStatus::Overflow, true),
            Rx::Receiving { fc_due: true, .. } => (FlowStatus::ContinueToSend, false),
            _ => return None,
        };
        if let Rx::Receiving { ref mut fc_due, .. } = self.rx {
            *fc_due = false;
        }
        self.in_flight = Some(InFlight::RxFlowControl { deadline, overflow });
        Some(self.frame(&PduRepr::FlowControl {
            status,
            block_size: self.cfg.block_size,
            st_min: self.cfg.st_min,
        }))
    }

    fn frame(&self, repr: &PduRepr<'_>) -> CanFrame {
        let mut buf = [self.cfg.padding.unwrap_or(0); CAN_DATA_LEN];
        let n = repr.emit(&mut buf);
        let len = if self.cfg.padding.is_some() { CAN_DATA_LEN } else { n };
        let data = heapless::Vec::from_slice(&buf[..len]).unwrap_or_default();
        CanFrame { id: self.cfg.tx_id, extended: self.cfg.extended, data }
    }
}
