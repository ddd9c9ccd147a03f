//! socketcand-compatible TCP endpoint, rawmode only: a server (the vehicle side, or a
//! bench) and a client (the service tool side).
//!
//! Protocol (linux-can/socketcand, as python-can's `socketcand` interface speaks it):
//! the server greets with `< hi >`; the client sends `< open CHANNEL >` and `< rawmode >`,
//! each answered `< ok >`. Then the server sends every bus frame as
//! `< frame ID SECS.USECS DATAHEX >` (ID 3 hex digits for 11-bit, 8 for 29-bit; data as
//! one hex string) and the client sends `< send ID LEN B0 B1 ... >` (LEN and bytes in
//! hex, any case, with or without leading zeros). Replies are written one per TCP
//! write, with no separators, because python-can compares each greeting exactly.
//!
//! The server bounds what clients can hold ([`Limits`]): at most 16 connections, 5 s to
//! reach rawmode, 60 s of silence in rawmode; its warnings are throttled to one a second.

use std::net::SocketAddr;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{broadcast, mpsc};
use tokio::task::JoinHandle;

use super::transport::{CanTransport, TransportError};
use super::CanFrame;

/// Longest protocol message accepted; anything longer is junk and dropped.
pub const MAX_MESSAGE_LEN: usize = 256;

/// What a server tolerates from its clients. Idle and half-open connections hold file
/// descriptors; without limits 1100 of them exhausted the daemon's 1024.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Connections served at once; more are answered `< error too many connections >`
    /// and closed.
    pub max_clients: usize,
    /// A client that has not reached rawmode by then is closed.
    pub handshake_timeout: Duration,
    /// A client in rawmode that sends nothing for this long is closed (a service tool sends
    /// TesterPresent every few seconds).
    pub idle_timeout: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_clients: 16,
            handshake_timeout: Duration::from_secs(5),
            idle_timeout: Duration::from_secs(60),
        }
    }
}

/// The accept loop's warning throttle (tokio's clock).
type WarnThrottle = super::WarnThrottle<tokio::time::Instant>;

/// Logs `message` through `throttle`, with the count of warnings it held back.
fn warn_throttled(throttle: &mut WarnThrottle, message: std::fmt::Arguments<'_>) {
    if let Some(suppressed) = throttle.allow(tokio::time::Instant::now()) {
        if suppressed > 0 {
            tracing::warn!("socketcand: {message} ({suppressed} similar warnings suppressed)");
        } else {
            tracing::warn!("socketcand: {message}");
        }
    }
}

/// One socketcand protocol message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Message {
    Hi,
    Ok,
    Open(String),
    RawMode,
    Echo,
    /// `< send ... >`: a frame from the client to the bus.
    Send(CanFrame),
    /// `< frame ... >`: a frame from the bus to the client (timestamp dropped).
    Frame(CanFrame),
    /// `< error TEXT >`.
    Error(String),
    /// Anything else (the whole text between the brackets).
    Other(String),
}

impl Message {
    /// Parses the text of one message, brackets included.
    pub fn parse(text: &str) -> Message {
        let inner = text.trim().trim_start_matches('<').trim_end_matches('>').trim();
        let mut words = inner.split_ascii_whitespace();
        let other = || Message::Other(inner.to_string());
        match words.next() {
            Some("hi") => Message::Hi,
            Some("ok") => Message::Ok,
            Some("rawmode") => Message::RawMode,
            Some("echo") => Message::Echo,
            Some("open") => words.next().map_or_else(other, |c| Message::Open(c.to_string())),
            Some("error") => Message::Error(words.collect::<Vec<_>>().join(" ")),
            Some("send") => parse_send(words).map_or_else(other, Message::Send),
            Some("frame") => parse_frame(words).map_or_else(other, Message::Frame),
            _ => other(),
        }
    }
}

fn parse_id(word: &str) -> Option<CanFrame> {
    let id = u32::from_str_radix(word, 16).ok()?;
    // socketcand tells 29-bit IDs by their 8-digit spelling.
    if word.len() > 3 {
        CanFrame::new_extended(id, &[])
    } else {
        CanFrame::new_standard(id, &[])
    }
}

fn parse_send<'a>(mut words: impl Iterator<Item = &'a str>) -> Option<CanFrame> {
    let mut frame = parse_id(words.next()?)?;
    let len = usize::from_str_radix(words.next()?, 16).ok()?;
    for w in words {
        frame.data.push(u8::from_str_radix(w, 16).ok()?).ok()?;
    }
    (frame.data.len() == len).then_some(frame)
}

fn parse_frame<'a>(mut words: impl Iterator<Item = &'a str>) -> Option<CanFrame> {
    let mut frame = parse_id(words.next()?)?;
    let _timestamp = words.next()?;
    let hex = words.next().unwrap_or("");
    if !hex.len().is_multiple_of(2) || words.next().is_some() {
        return None;
    }
    for i in (0..hex.len()).step_by(2) {
        frame.data.push(u8::from_str_radix(hex.get(i..i + 2)?, 16).ok()?).ok()?;
    }
    Some(frame)
}

fn format_id(frame: &CanFrame) -> String {
    if frame.extended {
        format!("{:08X}", frame.id)
    } else {
        format!("{:03X}", frame.id)
    }
}

/// `< frame ID SECS.USECS DATAHEX >` for a frame seen at `unix_micros`.
pub fn format_frame(frame: &CanFrame, unix_micros: u64) -> String {
    let data: String = frame.data.iter().map(|b| format!("{b:02X}")).collect();
    let (secs, usecs) = (unix_micros / 1_000_000, unix_micros % 1_000_000);
    format!("< frame {} {secs}.{usecs:06} {data} >", format_id(frame))
}

/// `< send ID LEN B0 B1 ... >`.
pub fn format_send(frame: &CanFrame) -> String {
    let mut s = format!("< send {} {:X}", format_id(frame), frame.data.len());
    for b in &frame.data {
        s.push_str(&format!(" {b:02X}"));
    }
    s.push_str(" >");
    s
}

/// Splits complete `< ... >` messages off the front of a byte stream buffer.
#[derive(Default)]
struct Splitter {
    buf: Vec<u8>,
}

impl Splitter {
    fn next_message(&mut self) -> Option<String> {
        loop {
            // Bytes before the first '<' are junk.
            let Some(start) = self.buf.iter().position(|&b| b == b'<') else {
                self.buf.clear();
                return None;
            };
            self.buf.drain(..start);
            let Some(end) = self.buf.iter().position(|&b| b == b'>') else {
                if self.buf.len() > MAX_MESSAGE_LEN {
                    self.buf.clear();
                }
                return None;
            };
            let msg: Vec<u8> = self.buf.drain(..=end).collect();
            if let Ok(text) = String::from_utf8(msg) {
                return Some(text);
            }
        }
    }
}

fn unix_micros() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_micros() as u64)
}

/// Reads messages from a TCP stream (cancel-safe: partial input stays buffered).
struct Conn {
    stream: TcpStream,
    split: Splitter,
    peer: String,
}

impl Conn {
    fn new(stream: TcpStream, peer: String) -> Self {
        // Frames are tiny and latency matters more than throughput.
        let _ = stream.set_nodelay(true);
        Conn { stream, split: Splitter::default(), peer }
    }

    async fn read_message(&mut self) -> Result<Message, TransportError> {
        loop {
            if let Some(text) = self.split.next_message() {
                return Ok(Message::parse(&text));
            }
            let mut chunk = [0u8; 1024];
            let n = self.stream.read(&mut chunk).await.map_err(|source| self.io(source))?;
            if n == 0 {
                return Err(TransportError::Closed {
                    endpoint: format!("socketcand {}", self.peer),
                });
            }
            self.split.buf.extend_from_slice(&chunk[..n]);
        }
    }

    async fn write(&mut self, text: &str) -> Result<(), TransportError> {
        let r = self.stream.write_all(text.as_bytes()).await;
        r.map_err(|source| self.io(source))
    }

    fn io(&self, source: std::io::Error) -> TransportError {
        TransportError::Io { endpoint: format!("socketcand {}", self.peer), source }
    }

    fn protocol(&self, message: String) -> TransportError {
        TransportError::Protocol { peer: self.peer.clone(), message }
    }
}

/// Client side: connects to a socketcand server and opens a channel in rawmode.
pub struct SocketcandClient {
    conn: Conn,
}

impl SocketcandClient {
    /// Connects to `addr` (`HOST:PORT`), opens `channel`, enters rawmode.
    pub async fn connect(addr: &str, channel: &str) -> Result<Self, TransportError> {
        let stream = TcpStream::connect(addr)
            .await
            .map_err(|source| TransportError::Connect { addr: addr.to_string(), source })?;
        let mut conn = Conn::new(stream, addr.to_string());
        conn.expect(Message::Hi, "greeting").await?;
        conn.write(&format!("< open {channel} >")).await?;
        conn.expect(Message::Ok, &format!("open {channel}")).await?;
        conn.write("< rawmode >").await?;
        conn.expect(Message::Ok, "rawmode").await?;
        Ok(SocketcandClient { conn })
    }
}

impl Conn {
    async fn expect(&mut self, want: Message, what: &str) -> Result<(), TransportError> {
        let got = self.read_message().await?;
        if got == want {
            Ok(())
        } else {
            Err(self.protocol(format!("expected {want:?} after {what}, got {got:?}")))
        }
    }
}

impl CanTransport for SocketcandClient {
    async fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        self.conn.write(&format_send(frame)).await
    }

    async fn recv(&mut self) -> Result<CanFrame, TransportError> {
        loop {
            match self.conn.read_message().await? {
                Message::Frame(f) => return Ok(f),
                Message::Error(e) => return Err(self.conn.protocol(format!("error: {e}"))),
                // Anything else in rawmode is not for us.
                _ => continue,
            }
        }
    }
}

/// Server side: a virtual CAN bus on TCP. Frames clients send come out of
/// [`CanTransport::recv`]; frames given to [`CanTransport::send`] go to every client in
/// rawmode (clients do not see each other's frames).
pub struct SocketcandServer {
    local_addr: SocketAddr,
    from_clients: mpsc::Receiver<CanFrame>,
    to_clients: broadcast::Sender<CanFrame>,
    accept: JoinHandle<()>,
}

impl SocketcandServer {
    /// Listens on `addr` (e.g. `127.0.0.1:29536`, port 0 for any) serving the bus `channel`.
    pub async fn bind(addr: &str, channel: &str) -> Result<Self, TransportError> {
        Self::bind_with_limits(addr, channel, Limits::default()).await
    }

    /// [`SocketcandServer::bind`] with other [`Limits`].
    pub async fn bind_with_limits(
        addr: &str,
        channel: &str,
        limits: Limits,
    ) -> Result<Self, TransportError> {
        let bind_err = |source| TransportError::Bind { addr: addr.to_string(), source };
        let listener = TcpListener::bind(addr).await.map_err(bind_err)?;
        let local_addr = listener.local_addr().map_err(bind_err)?;
        let (in_tx, from_clients) = mpsc::channel(1024);
        let (to_clients, _) = broadcast::channel(1024);
        let accept = tokio::spawn(accept_loop(
            listener,
            channel.to_string(),
            in_tx,
            to_clients.clone(),
            limits,
        ));
        Ok(SocketcandServer { local_addr, from_clients, to_clients, accept })
    }

    /// The address actually bound.
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }
}

impl Drop for SocketcandServer {
    fn drop(&mut self) {
        self.accept.abort();
    }
}

impl CanTransport for SocketcandServer {
    async fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        // No client in rawmode is like an empty bus: the frame is simply not seen.
        let _ = self.to_clients.send(frame.clone());
        Ok(())
    }

    async fn recv(&mut self) -> Result<CanFrame, TransportError> {
        let closed = || TransportError::Closed { endpoint: "socketcand server".to_string() };
        self.from_clients.recv().await.ok_or_else(closed)
    }
}

async fn accept_loop(
    listener: TcpListener,
    channel: String,
    to_bus: mpsc::Sender<CanFrame>,
    from_bus: broadcast::Sender<CanFrame>,
    limits: Limits,
) {
    let mut clients = tokio::task::JoinSet::new();
    let mut throttle = WarnThrottle::default();
    loop {
        let (stream, peer) = match listener.accept().await {
            Ok(accepted) => accepted,
            Err(e) => {
                // Out of file descriptors and the like: accept fails at once until a
                // connection closes, so pause instead of spinning on the error.
                warn_throttled(&mut throttle, format_args!("accept: {e}"));
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        // Reap finished connections so the set does not grow.
        while clients.try_join_next().is_some() {}
        let mut conn = Conn::new(stream, peer.to_string());
        if clients.len() >= limits.max_clients {
            warn_throttled(
                &mut throttle,
                format_args!("{peer} refused: {} connections already", clients.len()),
            );
            // Best effort, bounded: the refused peer must not hold the accept loop.
            let _ = tokio::time::timeout(
                Duration::from_millis(100),
                conn.write("< error too many connections >"),
            )
            .await;
            continue;
        }
        let client = serve_client(conn, channel.clone(), to_bus.clone(), from_bus.clone(), limits);
        clients.spawn(client);
    }
}

/// One client: handshake, then relay frames both ways until it disconnects.
async fn serve_client(
    mut conn: Conn,
    channel: String,
    to_bus: mpsc::Sender<CanFrame>,
    from_bus: broadcast::Sender<CanFrame>,
    limits: Limits,
) -> Result<(), TransportError> {
    let handshake = handshake(&mut conn, &channel, &from_bus);
    let mut bus = match tokio::time::timeout(limits.handshake_timeout, handshake).await {
        Ok(bus) => bus?,
        Err(_) => {
            tracing::debug!("socketcand: {} closed: no handshake", conn.peer);
            return Ok(());
        }
    };
    let idle = tokio::time::sleep(limits.idle_timeout);
    tokio::pin!(idle);
    loop {
        tokio::select! {
            () = &mut idle => {
                tracing::debug!("socketcand: {} closed: idle", conn.peer);
                return Ok(());
            }
            msg = conn.read_message() => {
                idle.as_mut().reset(tokio::time::Instant::now() + limits.idle_timeout);
                match msg? {
                    Message::Send(frame) => {
                        if to_bus.send(frame).await.is_err() {
                            return Ok(());
                        }
                    }
                    Message::Echo => conn.write("< echo >").await?,
                    _ => conn.write("< error unsupported command >").await?,
                }
            }
            frame = bus.recv() => match frame {
                Ok(frame) => conn.write(&format_frame(&frame, unix_micros())).await?,
                // A slow client missed frames: as on a real bus, they are gone.
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => return Ok(()),
            },
        }
    }
}

/// Greeting, `open CHANNEL`, `rawmode`: returns the bus subscription once in rawmode.
async fn handshake(
    conn: &mut Conn,
    channel: &str,
    from_bus: &broadcast::Sender<CanFrame>,
) -> Result<broadcast::Receiver<CanFrame>, TransportError> {
    conn.write("< hi >").await?;
    let mut opened = false;
    loop {
        match conn.read_message().await? {
            Message::Open(c) if c == channel => {
                opened = true;
                conn.write("< ok >").await?;
            }
            Message::Open(c) => conn.write(&format!("< error could not open bus {c} >")).await?,
            Message::RawMode if opened => {
                // Subscribe before acknowledging so no frame after `< ok >` is missed.
                let bus = from_bus.subscribe();
                conn.write("< ok >").await?;
                return Ok(bus);
            }
            Message::Echo => conn.write("< echo >").await?,
            _ => conn.write("< error unsupported command >").await?,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_python_can_send() {
        // python-can writes bytes in lower-case hex without leading zeros.
        let m = Message::parse("< send 7A0 8 2 10 3 cc cc cc cc cc >");
        let want = CanFrame::new_standard(0x7A0, &[2, 0x10, 3, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]);
        assert_eq!(m, Message::Send(want.unwrap()));
        let m = Message::parse("< send 000007A0 2 3e 0 >");
        assert_eq!(m, Message::Send(CanFrame::new_extended(0x7A0, &[0x3E, 0]).unwrap()));
        // Length that disagrees with the bytes is not a frame.
        assert!(matches!(Message::parse("< send 7A0 3 1 2 >"), Message::Other(_)));
        assert!(matches!(Message::parse("< send 7A0 9 1 2 3 4 5 6 7 8 9 >"), Message::Other(_)));
    }

    #[test]
    fn frame_round_trip() {
        let f = CanFrame::new_standard(0x7A8, &[0x06, 0x50, 0x03, 0x00, 0x32, 0x01, 0xF4]).unwrap();
        let text = format_frame(&f, 1_680_000_000_000_042);
        assert_eq!(text, "< frame 7A8 1680000000.000042 065003003201F4 >");
        assert_eq!(Message::parse(&text), Message::Frame(f));
        let empty = CanFrame::new_extended(0x18DA00F1, &[]).unwrap();
        assert_eq!(Message::parse(&format_frame(&empty, 0)), Message::Frame(empty));
    }

    #[test]
    fn warnings_are_throttled_to_one_a_second_with_a_count() {
        let t0 = tokio::time::Instant::now();
        let mut w = WarnThrottle::default();
        assert_eq!(w.allow(t0), Some(0));
        let held = (1..10).filter(|i| w.allow(t0 + Duration::from_millis(i * 100)).is_none());
        assert_eq!(held.count(), 9, "ten a second: one logged");
        assert_eq!(w.allow(t0 + Duration::from_millis(1000)), Some(9));
    }

    #[test]
    fn splitter_handles_junk_and_partial_input() {
        let mut s = Splitter::default();
        s.buf.extend_from_slice(b"junk< hi >< ok");
        assert_eq!(s.next_message().as_deref(), Some("< hi >"));
        assert_eq!(s.next_message(), None);
        s.buf.extend_from_slice(b" >");
        assert_eq!(s.next_message().as_deref(), Some("< ok >"));
        s.buf.extend_from_slice(&[b'<'; 300]);
        assert_eq!(s.next_message(), None);
        assert!(s.buf.is_empty());
    }
}
