//! Service over CAN: UDS (ISO 14229) on ISO-TP (ISO 15765-2).
//!
//! The protocol layers are `no_std`, allocation-free state machines that never read a
//! clock (time comes in as an [`Instant`]):
//!
//! * [`isotp`]: segmentation and reassembly of messages up to 4095 bytes over classic
//!   CAN, flow control, STmin and block size in both directions, N_As/N_Bs/N_Cr timeouts.
//! * [`uds`]: the roomcal UDS server (sessions, SecurityAccess, ReadDataByIdentifier,
//!   RoutineControl) over a [`uds::Backend`] trait the daemon implements, the wire
//!   encodings of every data identifier, and [`uds::Link`], which puts the server on an
//!   ISO-TP endpoint with each answer bound to its request.
//!
//! With the `daemon` feature come the transports and tools (std, tokio): the
//! [`transport::CanTransport`] trait with a socketcand TCP endpoint (server and client,
//! rawmode) and SocketCAN, an async driver that runs the server on a transport, and the
//! UDS client behind `roomcal query`.

#[cfg(feature = "fake")]
pub mod fake;
pub mod isotp;
pub mod uds;

#[cfg(feature = "daemon")]
pub mod client;
#[cfg(feature = "daemon")]
pub mod driver;
#[cfg(feature = "daemon")]
pub mod endpoint;
#[cfg(feature = "daemon")]
pub mod socketcan;
#[cfg(feature = "daemon")]
pub mod socketcand;
#[cfg(feature = "daemon")]
pub mod transport;

use core::ops::Add;
use core::time::Duration;

/// Default CAN identifier of UDS requests to roomcal.
pub const DEFAULT_REQUEST_ID: u32 = 0x7A0;
/// Default CAN identifier of roomcal's UDS responses.
pub const DEFAULT_RESPONSE_ID: u32 = 0x7A8;

/// A point in time, microseconds since an arbitrary epoch chosen by the caller.
///
/// The state machines only compare instants and add durations to them, so any monotonic
/// clock works; they never read one themselves.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Instant(u64);

impl Instant {
    /// The instant `micros` microseconds after the epoch.
    pub const fn from_micros(micros: u64) -> Self {
        Instant(micros)
    }

    /// The instant `millis` milliseconds after the epoch.
    pub const fn from_millis(millis: u64) -> Self {
        Instant(millis.saturating_mul(1000))
    }

    /// Microseconds since the epoch.
    pub const fn as_micros(self) -> u64 {
        self.0
    }

    /// Time from `earlier` to `self`, zero if `earlier` is later.
    pub fn saturating_since(self, earlier: Instant) -> Duration {
        Duration::from_micros(self.0.saturating_sub(earlier.0))
    }
}

impl Add<Duration> for Instant {
    type Output = Instant;

    fn add(self, rhs: Duration) -> Instant {
        // Saturate: a deadline past the end of time is simply never reached.
        let micros = u64::try_from(rhs.as_micros()).unwrap_or(u64::MAX);
        Instant(self.0.saturating_add(micros))
    }
}

/// At most one warning per [`WarnThrottle::INTERVAL`]; the ones held back are counted into
/// the next. Generic over the clock (`T`: this module's [`Instant`], tokio's, ...) so the
/// transports and the protocol loop share it and tests can pass instants in.
#[derive(Clone, Copy, Debug)]
pub struct WarnThrottle<T> {
    last: Option<T>,
    suppressed: u64,
}

impl<T> Default for WarnThrottle<T> {
    fn default() -> Self {
        WarnThrottle { last: None, suppressed: 0 }
    }
}

impl<T: Copy + Ord + Add<Duration, Output = T>> WarnThrottle<T> {
    /// Shortest time between two warnings logged.
    pub const INTERVAL: Duration = Duration::from_secs(1);

    /// `Some(n)` when a warning may be logged at `now` (`n` were suppressed since the last
    /// one), `None` when this one is suppressed.
    pub fn allow(&mut self, now: T) -> Option<u64> {
        if self.last.is_some_and(|t| now < t + Self::INTERVAL) {
            self.suppressed += 1;
            return None;
        }
        self.last = Some(now);
        Some(core::mem::take(&mut self.suppressed))
    }

    /// When the warnings held back are due to be reported, if any are: one interval after
    /// the last one logged (so a burst that stops is still counted in the log).
    pub fn flush_at(&self) -> Option<T> {
        self.last.filter(|_| self.suppressed > 0).map(|t| t + Self::INTERVAL)
    }

    /// `Some(n)` at or after [`WarnThrottle::flush_at`]: log that `n` were held back (the
    /// report counts as a logged warning).
    pub fn flush(&mut self, now: T) -> Option<u64> {
        if self.flush_at().is_none_or(|t| now < t) {
            return None;
        }
        self.last = Some(now);
        Some(core::mem::take(&mut self.suppressed))
    }
}

/// Largest standard (11-bit) CAN identifier.
pub const MAX_STANDARD_ID: u32 = 0x7FF;
/// Largest extended (29-bit) CAN identifier.
pub const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;

/// A classic CAN data frame: identifier and 0–8 data bytes.
///
/// The protocol layers use this small type; [`CanFrame::from_frame`] and the
/// `embedded_can::Frame` implementation convert to and from any HAL driver's frames.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CanFrame {
    /// Identifier (11 or 29 bits, see `extended`).
    pub id: u32,
    /// True for a 29-bit identifier.
    pub extended: bool,
    /// Data bytes; the DLC is their count.
    pub data: heapless::Vec<u8, 8>,
}

impl CanFrame {
    /// A standard-ID frame; `None` if the ID has more than 11 bits or `data` more than 8 bytes.
    pub fn new_standard(id: u32, data: &[u8]) -> Option<Self> {
        if id > MAX_STANDARD_ID {
            return None;
        }
        Some(CanFrame { id, extended: false, data: heapless::Vec::from_slice(data).ok()? })
    }

    /// An extended-ID frame; `None` if the ID has more than 29 bits or `data` more than 8 bytes.
    pub fn new_extended(id: u32, data: &[u8]) -> Option<Self> {
        if id > MAX_EXTENDED_ID {
            return None;
        }
        Some(CanFrame { id, extended: true, data: heapless::Vec::from_slice(data).ok()? })
    }

    /// A frame with the given ID, extended if it does not fit 11 bits.
    pub fn new(id: u32, data: &[u8]) -> Option<Self> {
        if id > MAX_STANDARD_ID {
            Self::new_extended(id, data)
        } else {
            Self::new_standard(id, data)
        }
    }

    /// Converts a HAL frame; `None` for remote frames, which carry no ISO-TP data.
    pub fn from_frame<F: embedded_can::Frame>(frame: &F) -> Option<Self> {
        if frame.is_remote_frame() {
            return None;
        }
        match frame.id() {
            embedded_can::Id::Standard(id) => {
                Self::new_standard(u32::from(id.as_raw()), frame.data())
            }
            embedded_can::Id::Extended(id) => Self::new_extended(id.as_raw(), frame.data()),
        }
    }

    /// Converts to a HAL frame.
    pub fn to_frame<F: embedded_can::Frame>(&self) -> Option<F> {
        F::new(self.embedded_id()?, &self.data)
    }

    fn embedded_id(&self) -> Option<embedded_can::Id> {
        if self.extended {
            embedded_can::ExtendedId::new(self.id).map(embedded_can::Id::Extended)
        } else {
            let id = u16::try_from(self.id).ok()?;
            embedded_can::StandardId::new(id).map(embedded_can::Id::Standard)
        }
    }
}

impl embedded_can::Frame for CanFrame {
    fn new(id: impl Into<embedded_can::Id>, data: &[u8]) -> Option<Self> {
        match id.into() {
            embedded_can::Id::Standard(id) => Self::new_standard(u32::from(id.as_raw()), data),
            embedded_can::Id::Extended(id) => Self::new_extended(id.as_raw(), data),
        }
    }

    /// Remote frames are not represented: ISO-TP never uses them.
    fn new_remote(_id: impl Into<embedded_can::Id>, _dlc: usize) -> Option<Self> {
        None
    }

    fn is_extended(&self) -> bool {
        self.extended
    }

    fn is_remote_frame(&self) -> bool {
        false
    }

    fn id(&self) -> embedded_can::Id {
        // Constructors keep the ID in range; fall back to the masked value otherwise.
        self.embedded_id().unwrap_or_else(|| {
            embedded_can::Id::Extended(
                embedded_can::ExtendedId::new(self.id & MAX_EXTENDED_ID)
                    .unwrap_or(embedded_can::ExtendedId::ZERO),
            )
        })
    }

    fn dlc(&self) -> usize {
        self.data.len()
    }

    fn data(&self) -> &[u8] {
        &self.data
    }
}
