//! Runs the UDS server on a CAN transport (std, tokio): the glue between
//! [`CanTransport`] and the sans-I/O [`Link`] (ISO-TP endpoint + [`Server`]), which sends
//! each response at once, the 0x78 responsePending and, later, a routine's final response.
//! Responses abandoned (superseded, or no flow control within N_Bs) are logged at most once
//! a second with a count of the ones not logged: a hostile tester must not flood the journal.

use std::fs::File;
use std::future::Future;
use std::io::Read;

use super::isotp;
use super::transport::{CanTransport, TransportError};
use super::uds::{Backend, Link, LinkEvent, SeedSource, Server, SEED_LEN};
use super::{Instant, WarnThrottle};

/// Seeds from the operating system's random source (`/dev/urandom`).
pub struct OsRandom {
    file: File,
}

impl OsRandom {
    /// Opens `/dev/urandom`.
    pub fn open() -> std::io::Result<Self> {
        Ok(OsRandom { file: File::open("/dev/urandom")? })
    }
}

impl SeedSource for OsRandom {
    fn fill_seed(&mut self, seed: &mut [u8; SEED_LEN]) {
        if self.file.read_exact(seed).is_err() {
            // A failed read leaves an all-zero seed, which no client can tell from an
            // unlocked server's: unlocking then fails rather than using a weak seed.
            *seed = [0; SEED_LEN];
        }
    }
}

/// Monotonic clock for the state machines, microseconds since the driver started.
struct Clock(tokio::time::Instant);

impl Clock {
    fn now(&self) -> Instant {
        Instant::from_micros(self.0.elapsed().as_micros() as u64)
    }

    fn at(&self, t: Instant) -> tokio::time::Instant {
        self.0 + std::time::Duration::from_micros(t.as_micros())
    }
}

/// Serves UDS requests arriving on `transport` until `shutdown` resolves or the
/// transport fails. Abandoned responses are logged as warnings (throttled), abandoned
/// request receptions at debug level (`tracing`); the link carries on.
pub async fn serve<T, B, R>(
    transport: &mut T,
    server: &mut Server<B, R>,
    cfg: isotp::Config,
    shutdown: impl Future<Output = ()>,
) -> Result<(), TransportError>
where
    T: CanTransport,
    B: Backend,
    R: SeedSource,
{
    let clock = Clock(tokio::time::Instant::now());
    let mut link: Box<Link> = Box::new(Link::new(cfg));
    let mut log = Log::default();
    tokio::pin!(shutdown);
    loop {
        while let Some(ev) = link.poll(server, clock.now()) {
            log.report(ev, clock.now());
        }
        log.flush(clock.now());
        flush(transport, &mut link, &mut log, &clock).await?;
        let at = [link.poll_at(server), log.flush_at()].into_iter().flatten().min();
        let wake = tokio::time::sleep_until(at.map_or_else(
            || tokio::time::Instant::now() + std::time::Duration::from_secs(3600),
            |t| clock.at(t),
        ));
        tokio::select! {
            frame = transport.recv() => {
                let now = clock.now();
                if let Some(ev) = link.on_frame(server, &frame?, now) {
                    log.report(ev, now);
                }
            }
            _ = wake => {}
            _ = &mut shutdown => return Ok(()),
        }
    }
}

/// Puts every frame that is due on the bus.
async fn flush<T: CanTransport>(
    transport: &mut T,
    link: &mut Link,
    log: &mut Log,
    clock: &Clock,
) -> Result<(), TransportError> {
    while let Some(frame) = link.poll_transmit(clock.now()) {
        transport.send(&frame).await?;
        if let Some(ev) = link.frame_sent(clock.now()) {
            log.report(ev, clock.now());
        }
    }
    Ok(())
}

/// The link's events as log lines.
#[derive(Default)]
struct Log {
    abandoned: WarnThrottle<Instant>,
}

impl Log {
    fn report(&mut self, ev: LinkEvent, now: Instant) {
        match ev {
            LinkEvent::ResponseAbandoned { .. } => match self.abandoned.allow(now) {
                Some(0) => tracing::warn!("roomcal service: {ev}"),
                Some(n) => tracing::warn!(
                    "roomcal service: {ev} ({n} more responses abandoned since the last warning)"
                ),
                None => {}
            },
            // Debug level: a noisy or hostile bus must not flood the journal.
            LinkEvent::RequestAborted(_) => tracing::debug!("roomcal service: {ev}"),
        }
    }

    /// When the count of warnings held back is due.
    fn flush_at(&self) -> Option<Instant> {
        self.abandoned.flush_at()
    }

    /// Logs the count of warnings held back once it is due: a burst that stops is still
    /// counted in the log.
    fn flush(&mut self, now: Instant) {
        if let Some(n) = self.abandoned.flush(now) {
            tracing::warn!("roomcal service: {n} more responses abandoned since the last warning");
        }
    }
}
