//! The server's end of the diagnostic link: one ISO-TP endpoint feeding the [`Server`],
//! sans I/O and clock-free like both (time is passed in).
//!
//! What is in progress is bounded by construction: one request being received and one
//! response being sent, nothing queued. A response is bound to the request it answers by
//! being sent at once: the server answers synchronously, and a newer response (to a newer
//! request, or a routine's owed answer) abandons an older one still in transmission. On one
//! pair of CAN IDs a flow control frame does not say which message it is for, so an old
//! response still waiting for one would be continued by the flow control of whoever asked
//! next, and delivered to them as their answer. A UDS client sends its next request only
//! after the previous answer or its own timeout, so nobody still waits for the old one.
//! A response whose flow control never comes is abandoned after N_Bs, a request whose
//! consecutive frames never come after N_Cr (both ISO 15765-2, see [`isotp::Config`]).

use super::{sid, Backend, SeedSource, Server};
use crate::service::isotp::{self, Event, IsoTp, RxError, TxError, MAX_MESSAGE_LEN};
use crate::service::{CanFrame, Instant};

/// Why a response did not reach its client.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Abandoned {
    /// A newer response took the link before this one was completely sent.
    Superseded,
    /// ISO-TP gave up on it (N_Bs or N_As timeout, overflow, too many WAITs, ...).
    Transport(TxError),
}

/// What happened on the link that the caller may want to log; answers themselves need
/// no attention (they go out through [`Link::poll_transmit`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkEvent {
    /// The response to `service` was abandoned.
    ResponseAbandoned { service: u8, why: Abandoned },
    /// A request's reception was abandoned (N_Cr, wrong sequence number, ...).
    RequestAborted(RxError),
}

impl core::fmt::Display for LinkEvent {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            LinkEvent::ResponseAbandoned { service, why: Abandoned::Superseded } => {
                write!(f, "response to service 0x{service:02X} abandoned: a newer request came")
            }
            LinkEvent::ResponseAbandoned { service, why: Abandoned::Transport(e) } => {
                write!(f, "response to service 0x{service:02X} abandoned: {e}")
            }
            LinkEvent::RequestAborted(e) => write!(f, "request abandoned: {e}"),
        }
    }
}

/// One ISO-TP endpoint (buffers of `N` bytes) and the binding of responses to requests.
/// The [`Server`] stays the caller's; every method that may produce an answer takes it.
pub struct Link<const N: usize = MAX_MESSAGE_LEN> {
    tp: IsoTp<N>,
    /// Service of the response being sent, for the event if it is abandoned.
    sending: Option<u8>,
}

impl<const N: usize> Link<N> {
    /// A link on an endpoint configured by `cfg` (its `rx_id` is the request ID).
    pub fn new(cfg: isotp::Config) -> Self {
        Link { tp: IsoTp::new(cfg), sending: None }
    }

    /// Feeds one received CAN frame; a complete request is answered at once.
    pub fn on_frame<B: Backend, R: SeedSource>(
        &mut self,
        server: &mut Server<B, R>,
        frame: &CanFrame,
        now: Instant,
    ) -> Option<LinkEvent> {
        match self.tp.on_frame(frame, now)? {
            Event::Received(_) => {
                let response = server.handle(self.tp.received(), now)?;
                self.respond(&response)
            }
            ev => self.event(ev),
        }
    }

    /// Runs the timers of the server (its owed answers) and of ISO-TP; call it at
    /// [`Link::poll_at`], again while it returns events.
    pub fn poll<B: Backend, R: SeedSource>(
        &mut self,
        server: &mut Server<B, R>,
        now: Instant,
    ) -> Option<LinkEvent> {
        if let Some(response) = server.poll(now) {
            if let Some(ev) = self.respond(&response) {
                return Some(ev);
            }
        }
        let ev = self.tp.poll(now)?;
        self.event(ev)
    }

    /// The next frame to put on the bus at `now` (see [`IsoTp::poll_transmit`]).
    pub fn poll_transmit(&mut self, now: Instant) -> Option<CanFrame> {
        self.tp.poll_transmit(now)
    }

    /// Confirms the frame last handed out is on the bus.
    pub fn frame_sent(&mut self, now: Instant) -> Option<LinkEvent> {
        let ev = self.tp.frame_sent(now)?;
        self.event(ev)
    }

    /// When [`Link::poll`] or [`Link::poll_transmit`] next has something to do.
    pub fn poll_at<B: Backend, R: SeedSource>(&self, server: &Server<B, R>) -> Option<Instant> {
        [self.tp.poll_at(), server.poll_at()].into_iter().flatten().min()
    }

    /// Starts sending `response`, abandoning an older one still in transmission (also when
    /// ISO-TP refuses the new one: longer than the link's `N`, which is then reported).
    fn respond(&mut self, response: &[u8]) -> Option<LinkEvent> {
        let older = self.sending.take();
        let superseded = self.tp.abort_send();
        let service = response_service(response);
        if let Err(e) = self.tp.send(response) {
            return Some(LinkEvent::ResponseAbandoned { service, why: Abandoned::Transport(e) });
        }
        self.sending = Some(service);
        let service = older.unwrap_or(0);
        superseded.then_some(LinkEvent::ResponseAbandoned { service, why: Abandoned::Superseded })
    }

    fn event(&mut self, ev: Event) -> Option<LinkEvent> {
        match ev {
            Event::Received(_) => None,
            Event::Sent => {
                self.sending = None;
                None
            }
            Event::RxAborted(e) => Some(LinkEvent::RequestAborted(e)),
            Event::TxAborted(e) => {
                let service = self.sending.take().unwrap_or(0);
                Some(LinkEvent::ResponseAbandoned { service, why: Abandoned::Transport(e) })
            }
        }
    }
}

/// The request service a response answers: `7F SID NRC` names it, a positive response
/// carries it plus 0x40.
fn response_service(response: &[u8]) -> u8 {
    match response {
        [sid::NEGATIVE_RESPONSE, service, ..] => *service,
        [first, ..] => first.wrapping_sub(sid::POSITIVE_OFFSET),
        [] => 0,
    }
}
