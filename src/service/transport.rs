//! What every CAN transport of the service speaks (std, tokio): the [`CanTransport`] trait,
//! its errors, and an in-memory bus for tests. The transports themselves are
//! [`super::socketcand`] and [`super::socketcan`]; [`super::endpoint`] chooses one.

use std::future::Future;

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
