//! Endpoint strings (`socketcand:HOST:PORT[/CHANNEL]`, `socketcan:IFACE`) and the transport
//! they choose: the one place that knows every transport.

use super::socketcan::SocketCan;
use super::socketcand::SocketcandClient;
use super::transport::{CanTransport, TransportError, DEFAULT_CHANNEL};
use super::CanFrame;

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
