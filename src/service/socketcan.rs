//! SocketCAN transport (Linux kernel CAN, through the `socketcan` crate's tokio socket).

use ::socketcan::tokio::CanSocket;
use ::socketcan::EmbeddedFrame;

use super::transport::{CanTransport, TransportError};
use super::CanFrame;

/// A raw CAN socket bound to one interface.
pub struct SocketCan {
    socket: CanSocket,
    interface: String,
}

impl SocketCan {
    /// Opens `interface` (e.g. `can0`); the error names the interface.
    pub fn open(interface: &str) -> Result<Self, TransportError> {
        let socket = CanSocket::open(interface)
            .map_err(|source| TransportError::Open { interface: interface.to_string(), source })?;
        Ok(SocketCan { socket, interface: interface.to_string() })
    }

    /// The interface name.
    pub fn interface(&self) -> &str {
        &self.interface
    }

    fn io_error(&self, source: std::io::Error) -> TransportError {
        TransportError::Io { endpoint: format!("socketcan:{}", self.interface), source }
    }
}

impl CanTransport for SocketCan {
    async fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        let Some(out) = frame.to_frame::<::socketcan::CanFrame>() else {
            let msg = format!("CAN ID {:#x} out of range", frame.id);
            return Err(self.io_error(std::io::Error::new(std::io::ErrorKind::InvalidInput, msg)));
        };
        self.socket.write_frame(out).await.map_err(|e| self.io_error(e))
    }

    async fn recv(&mut self) -> Result<CanFrame, TransportError> {
        loop {
            let frame = self.socket.read_frame().await.map_err(|e| self.io_error(e))?;
            // Remote and error frames carry no ISO-TP data.
            if frame.is_data_frame() {
                if let Some(f) = CanFrame::from_frame(&frame) {
                    return Ok(f);
                }
            }
        }
    }
}
