//! Runs the UDS server on a CAN transport (std, tokio): the glue between
//! [`CanTransport`], the ISO-TP endpoint and the [`Server`] state machine. This is the
//! layer that sends the 0x78 responsePending and, later, the final response the server
//! produces from [`Server::poll`].

use std::collections::VecDeque;
use std::fs::File;
use std::future::Future;
use std::io::Read;

use super::isotp::{self, Event, IsoTp};
use super::transport::{CanTransport, TransportError};
use super::uds::{Backend, Response, SeedSource, Server, SEED_LEN};
use super::Instant;

/// Responses waiting for the ISO-TP transmitter. A well-behaved client waits for each
/// response before its next request, so one is the norm; a client that floods requests
/// while a segmented response waits for its flow control would otherwise grow the queue
/// without bound. Responses beyond this are dropped (the client times out and retries,
/// as after a lost frame).
pub const MAX_QUEUED_RESPONSES: usize = 8;

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
/// transport fails. ISO-TP aborts (timeouts, wrong sequence numbers) are logged (debug
/// level, `tracing`) and the endpoint carries on.
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
    let mut tp: Box<IsoTp> = Box::new(IsoTp::new(cfg));
    let mut outbox: VecDeque<Response> = VecDeque::new();
    tokio::pin!(shutdown);
    loop {
        let now = clock.now();
        if let Some(r) = server.poll(now) {
            queue(&mut outbox, r);
        }
        flush(transport, &mut tp, &mut outbox, &clock).await?;
        if let Some(ev) = tp.poll(clock.now()) {
            report(ev);
        }
        let wake = [tp.poll_at(), server.poll_at()].into_iter().flatten().min();
        let sleep = tokio::time::sleep_until(wake.map_or_else(
            || tokio::time::Instant::now() + std::time::Duration::from_secs(3600),
            |t| clock.at(t),
        ));
        tokio::select! {
            frame = transport.recv() => {
                let frame = frame?;
                let now = clock.now();
                match tp.on_frame(&frame, now) {
                    Some(Event::Received(_)) => {
                        if let Some(r) = server.handle(tp.received(), now) {
                            queue(&mut outbox, r);
                        }
                    }
                    Some(ev) => report(ev),
                    None => {}
                }
            }
            _ = sleep => {}
            _ = &mut shutdown => return Ok(()),
        }
    }
}

fn queue(outbox: &mut VecDeque<Response>, r: Response) {
    if outbox.len() < MAX_QUEUED_RESPONSES {
        outbox.push_back(r);
    } else {
        tracing::warn!("roomcal service: {} responses queued, response dropped", outbox.len());
    }
}

/// Hands queued responses to ISO-TP and puts every frame that is due on the bus.
async fn flush<T: CanTransport, const N: usize>(
    transport: &mut T,
    tp: &mut IsoTp<N>,
    outbox: &mut VecDeque<Response>,
    clock: &Clock,
) -> Result<(), TransportError> {
    loop {
        if !tp.is_sending() {
            if let Some(r) = outbox.pop_front() {
                if let Err(e) = tp.send(&r) {
                    tracing::warn!("roomcal service: response dropped: {e}");
                }
            }
        }
        let Some(frame) = tp.poll_transmit(clock.now()) else {
            return Ok(());
        };
        transport.send(&frame).await?;
        if let Some(ev) = tp.frame_sent(clock.now()) {
            report(ev);
        }
    }
}

fn report(ev: Event) {
    match ev {
        // Debug level: a noisy or hostile bus must not flood the journal.
        Event::RxAborted(e) => tracing::debug!("roomcal service: {e}"),
        Event::TxAborted(e) => tracing::debug!("roomcal service: {e}"),
        Event::Received(_) | Event::Sent => {}
    }
}
