//! CAN transports for the service (std, tokio): the [`CanTransport`] trait, endpoint
//! strings (`socketcand:HOST:PORT[/CHANNEL]`, `socketcan:IFACE`) and a transport that is
//! either of the two.

use std::future::Future;

use super::socketcan::SocketCan;
use super::socketcand::SocketcandClient;
use super::CanFrame;

/// Default socketcand port.
pub const DEFAULT_SOCKETCAND_PORT: u16 = 29536;
/// Channel (bus name) used on socketcand when the endpoint names none.
pub const DEFAULT_CHANNEL: &str = "can0";

/// Errors of the transports; each names the endpoint.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    #[error("cannot open CAN interface `{interface}`: {source}")]
    Open { interface: String, source: std::io::Error },
    #[error("cannot connect to socketcand at {addr}: {source}")]
    Connect { addr: String, source: std::io::Error },
    #[error("cannot listen on {addr}: {source}")]
    Bind { addr: String, source: std::io::Error },
    #[error("socketcand at {peer}: {message}")]
    Protocol { peer: String, message: String },
    #[error("{endpoint}: {source}")]
    Io { endpoint: String, source: std::io::Error },
    #[error("{endpoint}: connection closed")]
    Closed { endpoint: String },
    #[error("invalid endpoint `{0}`: expected socketcand:HOST:PORT[/CHANNEL] or socketcan:IFACE")]
    BadEndpoint(String),
}

/// Sends and receives classic CAN frames.
///
/// `recv` must be cancel-safe (a frame is never lost when its future is dropped), so
/// drivers can `select!` it against timers.
pub trait CanTransport: Send {
    /// Puts one frame on the bus; resolves once the bus (or the socket) took it.
    fn send(&mut self, frame: &CanFrame)
        -> impl Future<Output = Result<(), TransportError>> + Send;
    /// The next frame from the bus.
    fn recv(&mut self) -> impl Future<Output = Result<CanFrame, TransportError>> + Send;
}

/// Where to reach a CAN bus.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Endpoint {
    /// A socketcand server (TCP), and the bus name to open there.
    Socketcand { addr: String, channel: String },
    /// A SocketCAN network interface.
    Socketcan { interface: String },
}

impl Endpoint {
    /// Parses `socketcand:HOST:PORT[/CHANNEL]` or `socketcan:IFACE`.
    pub fn parse(s: &str) -> Result<Self, TransportError> {
        let bad = || TransportError::BadEndpoint(s.to_string());
        if let Some(rest) = s.strip_prefix("socketcand:") {
            let (addr, channel) = rest.split_once('/').unwrap_or((rest, DEFAULT_CHANNEL));
            let (host, port) = addr.rsplit_once(':').ok_or_else(bad)?;
            if host.is_empty() || port.parse::<u16>().is_err() || channel.is_empty() {
                return Err(bad());
            }
            return Ok(Endpoint::Socketcand {
                addr: addr.to_string(),
                channel: channel.to_string(),
            });
        }
        if let Some(interface) = s.strip_prefix("socketcan:") {
            if interface.is_empty() || interface.len() > 15 {
                return Err(bad());
            }
            return Ok(Endpoint::Socketcan { interface: interface.to_string() });
        }
        Err(bad())
    }

    /// Connects (socketcand client) or opens (SocketCAN) the endpoint.
    pub async fn connect(&self) -> Result<AnyTransport, TransportError> {
        Ok(match self {
            Endpoint::Socketcand { addr, channel } => {
                AnyTransport::Socketcand(SocketcandClient::connect(addr, channel).await?)
            }
            Endpoint::Socketcan { interface } => {
                AnyTransport::Socketcan(SocketCan::open(interface)?)
            }
        })
    }
}

/// Either client-side transport, as chosen by an [`Endpoint`].
pub enum AnyTransport {
    Socketcand(SocketcandClient),
    Socketcan(SocketCan),
}

impl CanTransport for AnyTransport {
    async fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        match self {
            AnyTransport::Socketcand(t) => t.send(frame).await,
            AnyTransport::Socketcan(t) => t.send(frame).await,
        }
    }

    async fn recv(&mut self) -> Result<CanFrame, TransportError> {
        match self {
            AnyTransport::Socketcand(t) => t.recv().await,
            AnyTransport::Socketcan(t) => t.recv().await,
        }
    }
}

/// One end of an in-memory CAN bus between two nodes (tests, simulations).
pub struct MemoryTransport {
    tx: tokio::sync::mpsc::Sender<CanFrame>,
    rx: tokio::sync::mpsc::Receiver<CanFrame>,
}

/// Two connected in-memory transports: what one sends, the other receives.
pub fn memory_pair() -> (MemoryTransport, MemoryTransport) {
    let (a_tx, b_rx) = tokio::sync::mpsc::channel(256);
    let (b_tx, a_rx) = tokio::sync::mpsc::channel(256);
    (MemoryTransport { tx: a_tx, rx: a_rx }, MemoryTransport { tx: b_tx, rx: b_rx })
}

impl CanTransport for MemoryTransport {
    async fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        let closed = |_| TransportError::Closed { endpoint: "memory bus".to_string() };
        self.tx.send(frame.clone()).await.map_err(closed)
    }

    async fn recv(&mut self) -> Result<CanFrame, TransportError> {
        let closed = || TransportError::Closed { endpoint: "memory bus".to_string() };
        self.rx.recv().await.ok_or_else(closed)
    }
}
