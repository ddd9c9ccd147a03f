//! pcap and pcapng capture reader: the UDP datagrams of a capture, with their times.
//!
//! Reads classic pcap (either byte order, microsecond or nanosecond magic) and pcapng
//! (section header, interface description, enhanced and simple packet blocks; per
//! interface link type, `if_tsresol` and `if_tsoffset`; either byte order, several
//! sections). Link types: Ethernet (1, with 802.1Q / 802.1ad VLAN tags), raw IP (101,
//! 228), Linux cooked capture SLL (113) and SLL2 (276). IPv4 + UDP datagrams come out;
//! everything else is counted in [`PcapStats`] and skipped: IP fragments, non-IPv4,
//! non-UDP, packets cut short by the snap length, unknown link types.
//!
//! A capture whose last record is cut off (a killed `tcpdump`) ends with one
//! [`PcapError::Truncated`] item; `.map_while(Result::ok)` keeps everything before it.
//!
//! Headers are zero-copy views in smoltcp style: named field ranges, `new_checked`
//! verifies the length once so every accessor is panic-free.
//!
//! [`PcapWriter`] writes classic pcap of UDP datagrams (Ethernet + IPv4 + UDP frames built
//! by [`UdpFrameRepr::emit`]) for captures we produce.
//!
//! [`ReplayPacer`] turns capture timestamps into release delays for replay at the
//! capture's own pace, without reading a clock.

use std::io::{self, Write};
use std::net::{Ipv4Addr, SocketAddrV4};
use std::path::Path;
use std::time::Duration;

/// One UDP datagram of a capture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UdpDatagram<'a> {
    /// Capture time, nanoseconds since the Unix epoch.
    pub timestamp_ns: u64,
    pub src: SocketAddrV4,
    pub dst: SocketAddrV4,
    /// The UDP payload (for LiDARs: the sensor's packet).
    pub payload: &'a [u8],
}

/// What the reader saw besides the datagrams it returned.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PcapStats {
    /// Packet records read (pcap records, pcapng EPB/SPB).
    pub records: u64,
    /// IPv4 UDP datagrams returned.
    pub udp: u64,
    /// IPv4 fragments (first or later) skipped.
    pub ip_fragments: u64,
    /// Frames that were not IPv4 (ARP, IPv6, ...).
    pub non_ipv4: u64,
    /// IPv4 packets that were not UDP.
    pub non_udp: u64,
    /// Frames cut short by the snap length or with inconsistent headers.
    pub malformed: u64,
    /// Records on interfaces of a link type we do not decode.
    pub unsupported_link: u64,
    /// Whether the file ended inside a record (0 or 1).
    pub truncated: u64,
}

/// Container format of a capture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CaptureFormat {
    Pcap,
    PcapNg,
}

/// Why a capture could not be read. Every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum PcapError {
    #[error("{file}: {source}")]
    Io {
        file: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{file}: not a pcap or pcapng capture (magic {magic:#010x})")]
    NotACapture { file: String, magic: u32 },
    #[error("{file}: capture truncated at byte {offset}: {what}")]
    Truncated { file: String, offset: usize, what: &'static str },
    #[error("{file}: malformed capture at byte {offset}: {what}")]
    Malformed { file: String, offset: usize, what: &'static str },
}

/// A capture file held in memory.
#[derive(Debug)]
pub struct Capture {
    name: String,
    bytes: Vec<u8>,
}

impl Capture {
    /// Reads the capture at `path`.
    pub fn open(path: impl AsRef<Path>) -> Result<Capture, PcapError> {
        let path = path.as_ref();
        let name = path.display().to_string();
        match std::fs::read(path) {
            Ok(bytes) => Ok(Capture { name, bytes }),
            Err(source) => Err(PcapError::Io { file: name, source }),
        }
    }

    /// The UDP datagrams of the capture, in file order.
    pub fn datagrams(&self) -> Result<Datagrams<'_>, PcapError> {
        datagrams(&self.bytes, &self.name)
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }
}

/// Whether a file's first four bytes are a pcap or pcapng magic number.
pub fn is_capture_magic(first: &[u8; 4]) -> bool {
    let magic = u32::from_le_bytes(*first);
    let known = [PCAP_MAGIC_US, PCAP_MAGIC_NS];
    magic == ng::SHB_TYPE || known.contains(&magic) || known.contains(&magic.swap_bytes())
}

/// The UDP datagrams of capture contents `bytes`; `name` is used in errors. Fails only if
/// the file header is missing or wrong.
pub fn datagrams<'a>(bytes: &'a [u8], name: &'a str) -> Result<Datagrams<'a>, PcapError> {
    let magic =
        bytes.get(0..4).map(|m| u32::from_le_bytes([m[0], m[1], m[2], m[3]])).ok_or_else(|| {
            PcapError::Truncated { file: name.into(), offset: 0, what: "file header" }
        })?;
    let (format, state) = if magic == ng::SHB_TYPE {
        (CaptureFormat::PcapNg, State::Ng(NgState::default()))
    } else {
        let known = [PCAP_MAGIC_US, PCAP_MAGIC_NS];
        if !known.contains(&magic) && !known.contains(&magic.swap_bytes()) {
            return Err(PcapError::NotACapture { file: name.into(), magic });
        }
        let header = PcapHeader::new_checked(bytes).map_err(|e| match e {
            ViewError::Truncated => {
                PcapError::Truncated { file: name.into(), offset: 0, what: "file header" }
            }
            ViewError::Malformed => PcapError::NotACapture { file: name.into(), magic },
        })?;
        let classic =
            Classic { endian: header.endian(), nanos: header.nanos(), link: header.link_type() };
        (CaptureFormat::Pcap, State::Classic(classic))
    };
    let pos = if format == CaptureFormat::Pcap { PcapHeader::<&[u8]>::LEN } else { 0 };
    Ok(Datagrams { bytes, name, format, state, pos, stats: PcapStats::default(), done: false })
}

/// Iterator over the UDP datagrams of a capture.
#[derive(Debug)]
pub struct Datagrams<'a> {
    bytes: &'a [u8],
    name: &'a str,
    format: CaptureFormat,
    state: State,
    pos: usize,
    stats: PcapStats,
    done: bool,
}

impl<'a> Datagrams<'a> {
    /// Counters so far (complete once the iterator is exhausted).
    pub fn stats(&self) -> &PcapStats {
        &self.stats
    }

    pub fn format(&self) -> CaptureFormat {
        self.format
    }

    /// The next packet record: (link type, timestamp, frame), `None` at the end.
    fn next_record(&mut self) -> Result<Option<Record<'a>>, PcapError> {
        loop {
            if self.pos >= self.bytes.len() {
                return Ok(None);
            }
            let bytes: &'a [u8] = self.bytes;
            let rest = &bytes[self.pos..];
            let at = self.pos;
            let step = match &mut self.state {
                State::Classic(c) => c.record(rest),
                State::Ng(s) => s.block(rest),
            };
            match step {
                Ok((len, record)) => {
                    self.pos += len;
                    if let Some(r) = record {
                        return Ok(Some(r));
                    }
                }
                Err(e) => return Err(e.into_error(self.name, at)),
            }
        }
    }
}

impl<'a> Iterator for Datagrams<'a> {
    type Item = Result<UdpDatagram<'a>, PcapError>;

    fn next(&mut self) -> Option<Self::Item> {
        while !self.done {
            match self.next_record() {
                Ok(Some((link, timestamp_ns, frame))) => {
                    self.stats.records += 1;
                    if let Some(d) = decode_frame(link, timestamp_ns, frame, &mut self.stats) {
                        self.stats.udp += 1;
                        return Some(Ok(d));
                    }
                }
                Ok(None) => self.done = true,
                Err(e) => {
                    self.done = true;
                    if matches!(e, PcapError::Truncated { .. }) {
                        self.stats.truncated += 1;
                    }
                    return Some(Err(e));
                }
            }
        }
        None
    }
}

/// Releases replayed datagrams at the capture's own pace. Pure arithmetic on the
/// capture's timestamps: the caller owns the clock (e.g. `tokio::time::sleep_until(start
/// + pacer.delay_until(ts))`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReplayPacer {
    first_ns: u64,
    speed: f64,
}

impl ReplayPacer {
    /// A pacer whose start instant corresponds to capture time `first_ts_ns`.
    pub fn new(first_ts_ns: u64) -> Self {
        ReplayPacer { first_ns: first_ts_ns, speed: 1.0 }
    }

    /// Plays `speed` times faster than real time (values ≤ 0 or NaN mean 1).
    pub fn with_speed(mut self, speed: f64) -> Self {
        self.speed = if speed > 0.0 { speed } else { 1.0 };
        self
    }

    /// When, after the start instant, the datagram stamped `ts_ns` is due. Times before
    /// the first one (clock steps in the capture) are due at once.
    pub fn delay_until(&self, ts_ns: u64) -> Duration {
        let offset = ts_ns.saturating_sub(self.first_ns);
        if self.speed == 1.0 {
            Duration::from_nanos(offset)
        } else {
            Duration::from_secs_f64(offset as f64 * 1e-9 / self.speed)
        }
    }

    /// How long to wait for the datagram stamped `ts_ns` when `elapsed` has passed since
    /// the start instant (zero if it is already due).
    pub fn wait(&self, ts_ns: u64, elapsed: Duration) -> Duration {
        self.delay_until(ts_ns).saturating_sub(elapsed)
    }
}

/// Writes classic pcap (little-endian, nanosecond timestamps, link type Ethernet) holding
/// UDP datagrams, e.g. the packets the simulator produces; [`datagrams`] reads it back.
#[derive(Debug)]
pub struct PcapWriter<W: Write> {
    out: W,
    frame: Vec<u8>,
}

impl<W: Write> PcapWriter<W> {
    /// Writes the file header to `out`.
    pub fn new(mut out: W) -> io::Result<Self> {
        let mut h = [0u8; 24];
        h[0..4].copy_from_slice(&PCAP_MAGIC_NS.to_le_bytes());
        h[4..6].copy_from_slice(&2u16.to_le_bytes());
        h[6..8].copy_from_slice(&4u16.to_le_bytes());
        h[16..20].copy_from_slice(&65535u32.to_le_bytes());
        h[20..24].copy_from_slice(&u32::from(link::ETHERNET).to_le_bytes());
        out.write_all(&h)?;
        Ok(PcapWriter { out, frame: Vec::new() })
    }

    /// Appends one datagram as an Ethernet + IPv4 + UDP frame.
    pub fn write_udp(&mut self, d: &UdpDatagram<'_>) -> io::Result<()> {
        let repr = UdpFrameRepr { src: d.src, dst: d.dst, payload_len: d.payload.len() };
        let len = repr.frame_len();
        self.frame.clear();
        self.frame.resize(len, 0);
        repr.emit(&mut self.frame)
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "UDP payload too long"))?;
        self.frame[UdpFrameRepr::HEADER_LEN..].copy_from_slice(d.payload);
        let mut r = [0u8; 16];
        r[0..4].copy_from_slice(&((d.timestamp_ns / 1_000_000_000) as u32).to_le_bytes());
        r[4..8].copy_from_slice(&((d.timestamp_ns % 1_000_000_000) as u32).to_le_bytes());
        r[8..12].copy_from_slice(&(len as u32).to_le_bytes());
        r[12..16].copy_from_slice(&(len as u32).to_le_bytes());
        self.out.write_all(&r)?;
        self.out.write_all(&self.frame)
    }

    pub fn into_inner(self) -> W {
        self.out
    }
}

/// An Ethernet + IPv4 + UDP frame without options or VLAN tags, as a LiDAR sends it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UdpFrameRepr {
    pub src: SocketAddrV4,
    pub dst: SocketAddrV4,
    pub payload_len: usize,
}

impl UdpFrameRepr {
    /// Ethernet (14) + IPv4 (20) + UDP (8) header bytes before the payload.
    pub const HEADER_LEN: usize = EthernetFrame::<&[u8]>::LEN + 20 + UdpPacket::<&[u8]>::LEN;
    /// Source MAC of emitted frames (locally administered).
    pub const SRC_MAC: [u8; 6] = [0x02, 0, 0, 0, 0, 0x01];

    /// Parses an Ethernet frame (VLAN tags allowed) down to the UDP payload.
    pub fn parse(frame: &[u8]) -> Result<(UdpFrameRepr, &[u8]), ViewError> {
        let (ethertype, l3) =
            link_payload(link::ETHERNET, frame).map_err(|_| ViewError::Truncated)?;
        let ip = Ipv4Packet::new_checked(l3)?;
        let fragmented = ip.more_fragments() || ip.fragment_offset() != 0;
        if ethertype != ETHERTYPE_IPV4 || ip.protocol() != IP_PROTO_UDP || fragmented {
            return Err(ViewError::Malformed);
        }
        let udp = UdpPacket::new_checked(ip.payload())?;
        let src = SocketAddrV4::new(ip.src_addr(), udp.src_port());
        let dst = SocketAddrV4::new(ip.dst_addr(), udp.dst_port());
        let payload = udp.into_payload();
        Ok((UdpFrameRepr { src, dst, payload_len: payload.len() }, payload))
    }

    /// Length of the whole frame.
    pub fn frame_len(&self) -> usize {
        Self::HEADER_LEN + self.payload_len
    }

    /// Writes the headers into `buf[..HEADER_LEN]` (the payload goes after them; `buf`
    /// must hold [`Self::frame_len`] bytes). The IPv4 header checksum is filled in, the
    /// UDP checksum left 0 (allowed for IPv4).
    pub fn emit(&self, buf: &mut [u8]) -> Result<(), ViewError> {
        let ip_len = 20 + UdpPacket::<&[u8]>::LEN + self.payload_len;
        let ip_total = u16::try_from(ip_len).map_err(|_| ViewError::Malformed)?;
        let buf = buf.get_mut(..self.frame_len()).ok_or(ViewError::Truncated)?;
        let dst_mac =
            if self.dst.ip().is_broadcast() { [0xff; 6] } else { [0x02, 0, 0, 0, 0, 0x02] };
        buf[0..6].copy_from_slice(&dst_mac);
        buf[6..12].copy_from_slice(&Self::SRC_MAC);
        buf[12..14].copy_from_slice(&ETHERTYPE_IPV4.to_be_bytes());
        let ip = &mut buf[14..34];
        ip[0] = 0x45;
        ip[1] = 0;
        ip[2..4].copy_from_slice(&ip_total.to_be_bytes());
        ip[4..8].copy_from_slice(&[0, 0, 0x40, 0]); // ident 0, don't fragment
        ip[8] = 64;
        ip[9] = IP_PROTO_UDP;
        ip[10..12].copy_from_slice(&[0, 0]);
        ip[12..16].copy_from_slice(&self.src.ip().octets());
        ip[16..20].copy_from_slice(&self.dst.ip().octets());
        let sum = internet_checksum(ip);
        ip[10..12].copy_from_slice(&sum.to_be_bytes());
        let udp = &mut buf[34..42];
        udp[0..2].copy_from_slice(&self.src.port().to_be_bytes());
        udp[2..4].copy_from_slice(&self.dst.port().to_be_bytes());
        udp[4..6].copy_from_slice(&((ip_len - 20) as u16).to_be_bytes());
        udp[6..8].copy_from_slice(&[0, 0]);
        Ok(())
    }
}

/// RFC 1071 checksum of `bytes` (an odd last byte is padded with zero).
fn internet_checksum(bytes: &[u8]) -> u16 {
    let word = |c: &[u8]| u32::from(u16::from_be_bytes([c[0], c.get(1).copied().unwrap_or(0)]));
    let mut sum: u32 = bytes.chunks(2).map(word).sum();
    while sum > 0xffff {
        sum = (sum & 0xffff) + (sum >> 16);
    }
    !(sum as u16)
}

// ---------------------------------------------------------------------------------------
// Link, network and transport layers

/// Link types we decode (LINKTYPE_* numbers).
pub mod link {
    pub const ETHERNET: u16 = 1;
    pub const RAW: u16 = 101;
    pub const LINUX_SLL: u16 = 113;
    pub const IPV4: u16 = 228;
    pub const LINUX_SLL2: u16 = 276;
}

const ETHERTYPE_IPV4: u16 = 0x0800;
const ETHERTYPE_VLAN: u16 = 0x8100;
const ETHERTYPE_QINQ: u16 = 0x88a8;
const IP_PROTO_UDP: u8 = 17;

/// Decodes one captured frame down to its UDP payload, counting what it skips.
fn decode_frame<'a>(
    link: u16,
    timestamp_ns: u64,
    frame: &'a [u8],
    stats: &mut PcapStats,
) -> Option<UdpDatagram<'a>> {
    let (ethertype, l3) = match link_payload(link, frame) {
        Ok(x) => x,
        Err(LinkError::Unsupported) => {
            stats.unsupported_link += 1;
            return None;
        }
        Err(LinkError::Short) => {
            stats.malformed += 1;
            return None;
        }
    };
    if ethertype != ETHERTYPE_IPV4 {
        stats.non_ipv4 += 1;
        return None;
    }
    let Ok(ip) = Ipv4Packet::new_checked(l3) else {
        stats.malformed += 1;
        return None;
    };
    if ip.more_fragments() || ip.fragment_offset() != 0 {
        stats.ip_fragments += 1;
        return None;
    }
    if ip.protocol() != IP_PROTO_UDP {
        stats.non_udp += 1;
        return None;
    }
    let Ok(udp) = UdpPacket::new_checked(ip.payload()) else {
        stats.malformed += 1;
        return None;
    };
    Some(UdpDatagram {
        timestamp_ns,
        src: SocketAddrV4::new(ip.src_addr(), udp.src_port()),
        dst: SocketAddrV4::new(ip.dst_addr(), udp.dst_port()),
        payload: udp.into_payload(),
    })
}

enum LinkError {
    Unsupported,
    Short,
}

/// (ethertype, network-layer bytes) of a frame of link type `link`.
fn link_payload(link: u16, frame: &[u8]) -> Result<(u16, &[u8]), LinkError> {
    match link {
        link::ETHERNET => {
            let eth = EthernetFrame::new_checked(frame).map_err(|_| LinkError::Short)?;
            skip_vlan_tags(eth.ethertype(), eth.into_payload())
        }
        link::RAW | link::IPV4 => {
            // Raw IP: the version nibble tells IPv4 from IPv6.
            let version = frame.first().ok_or(LinkError::Short)? >> 4;
            Ok((if version == 4 { ETHERTYPE_IPV4 } else { 0 }, frame))
        }
        link::LINUX_SLL => {
            let sll = SllHeader::new_checked(frame).map_err(|_| LinkError::Short)?;
            skip_vlan_tags(sll.protocol(), sll.into_payload())
        }
        link::LINUX_SLL2 => {
            let sll = Sll2Header::new_checked(frame).map_err(|_| LinkError::Short)?;
            skip_vlan_tags(sll.protocol(), sll.into_payload())
        }
        _ => Err(LinkError::Unsupported),
    }
}

/// Steps over 802.1Q / 802.1ad tags (any depth): (inner ethertype, payload).
fn skip_vlan_tags(mut ethertype: u16, mut payload: &[u8]) -> Result<(u16, &[u8]), LinkError> {
    while ethertype == ETHERTYPE_VLAN || ethertype == ETHERTYPE_QINQ {
        let tag = VlanTag::new_checked(payload).map_err(|_| LinkError::Short)?;
        ethertype = tag.ethertype();
        payload = tag.into_payload();
    }
    Ok((ethertype, payload))
}

/// Why a view could not be made over some bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ViewError {
    /// Fewer bytes than the header (or its length fields) need.
    Truncated,
    /// A field has a value the format does not allow.
    Malformed,
}

type Field = core::ops::Range<usize>;

fn be16(b: &[u8], f: Field) -> u16 {
    u16::from_be_bytes([b[f.start], b[f.start + 1]])
}

/// Defines a zero-copy view type with `new_unchecked`, `into_inner` and `as_bytes`.
macro_rules! view {
    ($(#[$m:meta])* $name:ident) => {
        $(#[$m])*
        #[derive(Clone, Copy, Debug)]
        pub struct $name<T: AsRef<[u8]>> {
            buffer: T,
        }

        impl<T: AsRef<[u8]>> $name<T> {
            /// Wraps `buffer` without checking it; accessors may then panic.
            pub fn new_unchecked(buffer: T) -> Self {
                $name { buffer }
            }

            pub fn into_inner(self) -> T {
                self.buffer
            }
        }
    };
}

view!(
    /// Ethernet II frame header.
    EthernetFrame
);

impl<T: AsRef<[u8]>> EthernetFrame<T> {
    pub const DST: Field = 0..6;
    pub const SRC: Field = 6..12;
    pub const ETHERTYPE: Field = 12..14;
    pub const LEN: usize = 14;

    pub fn new_checked(buffer: T) -> Result<Self, ViewError> {
        if buffer.as_ref().len() < Self::LEN {
            return Err(ViewError::Truncated);
        }
        Ok(Self::new_unchecked(buffer))
    }

    pub fn dst_addr(&self) -> [u8; 6] {
        let mut a = [0; 6];
        a.copy_from_slice(&self.buffer.as_ref()[Self::DST]);
        a
    }

    pub fn src_addr(&self) -> [u8; 6] {
        let mut a = [0; 6];
        a.copy_from_slice(&self.buffer.as_ref()[Self::SRC]);
        a
    }

    pub fn ethertype(&self) -> u16 {
        be16(self.buffer.as_ref(), Self::ETHERTYPE)
    }
}

impl<'a> EthernetFrame<&'a [u8]> {
    pub fn into_payload(self) -> &'a [u8] {
        &self.buffer[Self::LEN..]
    }
}

view!(
    /// 802.1Q / 802.1ad tag: TCI and the encapsulated ethertype.
    VlanTag
);

impl<T: AsRef<[u8]>> VlanTag<T> {
    pub const TCI: Field = 0..2;
    pub const ETHERTYPE: Field = 2..4;
    pub const LEN: usize = 4;

    pub fn new_checked(buffer: T) -> Result<Self, ViewError> {
        if buffer.as_ref().len() < Self::LEN {
            return Err(ViewError::Truncated);
        }
        Ok(Self::new_unchecked(buffer))
    }

    pub fn ethertype(&self) -> u16 {
        be16(self.buffer.as_ref(), Self::ETHERTYPE)
    }
}

impl<'a> VlanTag<&'a [u8]> {
    pub fn into_payload(self) -> &'a [u8] {
        &self.buffer[Self::LEN..]
    }
}

view!(
    /// Linux cooked capture v1 header (LINKTYPE_LINUX_SLL).
    SllHeader
);

impl<T: AsRef<[u8]>> SllHeader<T> {
    pub const PACKET_TYPE: Field = 0..2;
    pub const ARPHRD: Field = 2..4;
    pub const ADDR_LEN: Field = 4..6;
    pub const ADDR: Field = 6..14;
    pub const PROTOCOL: Field = 14..16;
    pub const LEN: usize = 16;

    pub fn new_checked(buffer: T) -> Result<Self, ViewError> {
        if buffer.as_ref().len() < Self::LEN {
            return Err(ViewError::Truncated);
        }
        Ok(Self::new_unchecked(buffer))
    }

    pub fn packet_type(&self) -> u16 {
        be16(self.buffer.as_ref(), Self::PACKET_TYPE)
    }

    pub fn protocol(&self) -> u16 {
        be16(self.buffer.as_ref(), Self::PROTOCOL)
    }
}

impl<'a> SllHeader<&'a [u8]> {
    pub fn into_payload(self) -> &'a [u8] {
        &self.buffer[Self::LEN..]
    }
}

view!(
    /// Linux cooked capture v2 header (LINKTYPE_LINUX_SLL2).
    Sll2Header
);

impl<T: AsRef<[u8]>> Sll2Header<T> {
    pub const PROTOCOL: Field = 0..2;
    pub const RESERVED: Field = 2..4;
    pub const IFINDEX: Field = 4..8;
    pub const ARPHRD: Field = 8..10;
    pub const PACKET_TYPE: usize = 10;
    pub const ADDR_LEN: usize = 11;
    pub const ADDR: Field = 12..20;
    pub const LEN: usize = 20;

    pub fn new_checked(buffer: T) -> Result<Self, ViewError> {
        if buffer.as_ref().len() < Self::LEN {
            return Err(ViewError::Truncated);
        }
        Ok(Self::new_unchecked(buffer))
    }

    pub fn protocol(&self) -> u16 {
        be16(self.buffer.as_ref(), Self::PROTOCOL)
    }
}

impl<'a> Sll2Header<&'a [u8]> {
    pub fn into_payload(self) -> &'a [u8] {
        &self.buffer[Self::LEN..]
    }
}

view!(
    /// IPv4 packet. `new_checked` verifies version, header length and total length
    /// against the buffer, so the payload excludes Ethernet padding.
    Ipv4Packet
);

impl<T: AsRef<[u8]>> Ipv4Packet<T> {
    pub const VER_IHL: usize = 0;
    pub const TOTAL_LEN: Field = 2..4;
    pub const IDENT: Field = 4..6;
    pub const FLAGS_FRAG: Field = 6..8;
    pub const TTL: usize = 8;
    pub const PROTOCOL: usize = 9;
    pub const CHECKSUM: Field = 10..12;
    pub const SRC: Field = 12..16;
    pub const DST: Field = 16..20;
    pub const MIN_LEN: usize = 20;

    pub fn new_checked(buffer: T) -> Result<Self, ViewError> {
        let b = buffer.as_ref();
        if b.len() < Self::MIN_LEN {
            return Err(ViewError::Truncated);
        }
        let p = Self::new_unchecked(buffer);
        let (hl, tl) = (p.header_len(), usize::from(p.total_len()));
        if p.version() != 4 || hl < Self::MIN_LEN || tl < hl {
            return Err(ViewError::Malformed);
        }
        if p.buffer.as_ref().len() < tl {
            return Err(ViewError::Truncated);
        }
        Ok(p)
    }

    pub fn version(&self) -> u8 {
        self.buffer.as_ref()[Self::VER_IHL] >> 4
    }

    pub fn header_len(&self) -> usize {
        usize::from(self.buffer.as_ref()[Self::VER_IHL] & 0x0f) * 4
    }

    pub fn total_len(&self) -> u16 {
        be16(self.buffer.as_ref(), Self::TOTAL_LEN)
    }

    /// Whether the header checksum is right (captures with checksum offload often
    /// carry wrong ones, so the reader does not insist).
    pub fn checksum_valid(&self) -> bool {
        let b = self.buffer.as_ref();
        internet_checksum(&b[..self.header_len()]) == 0
    }

    pub fn ident(&self) -> u16 {
        be16(self.buffer.as_ref(), Self::IDENT)
    }

    pub fn more_fragments(&self) -> bool {
        be16(self.buffer.as_ref(), Self::FLAGS_FRAG) & 0x2000 != 0
    }

    /// Fragment offset in bytes.
    pub fn fragment_offset(&self) -> u16 {
        (be16(self.buffer.as_ref(), Self::FLAGS_FRAG) & 0x1fff) * 8
    }

    pub fn protocol(&self) -> u8 {
        self.buffer.as_ref()[Self::PROTOCOL]
    }

    pub fn src_addr(&self) -> Ipv4Addr {
        let b = &self.buffer.as_ref()[Self::SRC];
        Ipv4Addr::new(b[0], b[1], b[2], b[3])
    }

    pub fn dst_addr(&self) -> Ipv4Addr {
        let b = &self.buffer.as_ref()[Self::DST];
        Ipv4Addr::new(b[0], b[1], b[2], b[3])
    }
}

impl<'a> Ipv4Packet<&'a [u8]> {
    /// Bytes after the header up to the total length.
    pub fn payload(&self) -> &'a [u8] {
        &self.buffer[self.header_len()..usize::from(self.total_len())]
    }
}

view!(
    /// UDP datagram. `new_checked` verifies the length field against the buffer.
    UdpPacket
);

impl<T: AsRef<[u8]>> UdpPacket<T> {
    pub const SRC_PORT: Field = 0..2;
    pub const DST_PORT: Field = 2..4;
    pub const LENGTH: Field = 4..6;
    pub const CHECKSUM: Field = 6..8;
    pub const LEN: usize = 8;

    pub fn new_checked(buffer: T) -> Result<Self, ViewError> {
        let b = buffer.as_ref();
        if b.len() < Self::LEN {
            return Err(ViewError::Truncated);
        }
        let len = usize::from(be16(b, Self::LENGTH));
        if len < Self::LEN {
            return Err(ViewError::Malformed);
        }
        if b.len() < len {
            return Err(ViewError::Truncated);
        }
        Ok(Self::new_unchecked(buffer))
    }

    pub fn src_port(&self) -> u16 {
        be16(self.buffer.as_ref(), Self::SRC_PORT)
    }

    pub fn dst_port(&self) -> u16 {
        be16(self.buffer.as_ref(), Self::DST_PORT)
    }

    pub fn len(&self) -> u16 {
        be16(self.buffer.as_ref(), Self::LENGTH)
    }

    pub fn is_empty(&self) -> bool {
        usize::from(self.len()) == Self::LEN
    }
}

impl<'a> UdpPacket<&'a [u8]> {
    pub fn into_payload(self) -> &'a [u8] {
        &self.buffer[Self::LEN..usize::from(self.len())]
    }
}

// ---------------------------------------------------------------------------------------
// Containers

/// Byte order of a capture's headers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Endian {
    Little,
    Big,
}

impl Endian {
    fn u16(self, b: &[u8], at: usize) -> u16 {
        let v = [b[at], b[at + 1]];
        match self {
            Endian::Little => u16::from_le_bytes(v),
            Endian::Big => u16::from_be_bytes(v),
        }
    }

    fn u32(self, b: &[u8], at: usize) -> u32 {
        let v = [b[at], b[at + 1], b[at + 2], b[at + 3]];
        match self {
            Endian::Little => u32::from_le_bytes(v),
            Endian::Big => u32::from_be_bytes(v),
        }
    }

    fn u64(self, b: &[u8], at: usize) -> u64 {
        let (first, second) = (u64::from(self.u32(b, at)), u64::from(self.u32(b, at + 4)));
        match self {
            Endian::Little => (second << 32) | first,
            Endian::Big => (first << 32) | second,
        }
    }
}

const PCAP_MAGIC_US: u32 = 0xa1b2_c3d4;
const PCAP_MAGIC_NS: u32 = 0xa1b2_3c4d;

view!(
    /// Classic pcap file header. `new_checked` accepts the microsecond and nanosecond
    /// magics in either byte order.
    PcapHeader
);

impl<T: AsRef<[u8]>> PcapHeader<T> {
    pub const MAGIC: Field = 0..4;
    pub const VERSION_MAJOR: Field = 4..6;
    pub const VERSION_MINOR: Field = 6..8;
    pub const SNAPLEN: Field = 16..20;
    pub const LINK_TYPE: Field = 20..24;
    pub const LEN: usize = 24;

    pub fn new_checked(buffer: T) -> Result<Self, ViewError> {
        let b = buffer.as_ref();
        if b.len() < Self::LEN {
            return Err(ViewError::Truncated);
        }
        let magic = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let known = [PCAP_MAGIC_US, PCAP_MAGIC_NS];
        if !known.contains(&magic) && !known.contains(&magic.swap_bytes()) {
            return Err(ViewError::Malformed);
        }
        Ok(Self::new_unchecked(buffer))
    }

    fn magic_le(&self) -> u32 {
        Endian::Little.u32(self.buffer.as_ref(), Self::MAGIC.start)
    }

    pub fn endian(&self) -> Endian {
        let m = self.magic_le();
        if m == PCAP_MAGIC_US || m == PCAP_MAGIC_NS {
            Endian::Little
        } else {
            Endian::Big
        }
    }

    /// Whether record timestamps carry nanoseconds (else microseconds).
    pub fn nanos(&self) -> bool {
        let m = self.magic_le();
        m == PCAP_MAGIC_NS || m.swap_bytes() == PCAP_MAGIC_NS
    }

    pub fn snaplen(&self) -> u32 {
        self.endian().u32(self.buffer.as_ref(), Self::SNAPLEN.start)
    }

    /// Link type (the low 16 bits; the high bits carry FCS information).
    pub fn link_type(&self) -> u16 {
        self.endian().u32(self.buffer.as_ref(), Self::LINK_TYPE.start) as u16
    }
}

/// Largest packet record we accept (pcapng and libpcap use 256 KiB snap lengths; this
/// leaves room for odd ones while rejecting garbage lengths).
const MAX_RECORD: usize = 16 << 20;

/// A packet record: (link type, timestamp ns, frame bytes).
type Record<'a> = (u16, u64, &'a [u8]);

/// Reading a container: (bytes consumed, record if this step produced one).
type Step<'a> = Result<(usize, Option<Record<'a>>), StepError>;

/// Container-level problem at the current position.
#[derive(Debug)]
enum StepError {
    Truncated(&'static str),
    Malformed(&'static str),
}

impl StepError {
    fn into_error(self, file: &str, offset: usize) -> PcapError {
        match self {
            StepError::Truncated(what) => PcapError::Truncated { file: file.into(), offset, what },
            StepError::Malformed(what) => PcapError::Malformed { file: file.into(), offset, what },
        }
    }
}

#[derive(Debug)]
enum State {
    Classic(Classic),
    Ng(NgState),
}

/// Classic pcap parameters from the file header.
#[derive(Debug)]
struct Classic {
    endian: Endian,
    nanos: bool,
    link: u16,
}

impl Classic {
    const RECORD_HEADER: usize = 16;

    fn record<'a>(&self, rest: &'a [u8]) -> Step<'a> {
        let h = rest.get(..Self::RECORD_HEADER).ok_or(StepError::Truncated("record header"))?;
        let e = self.endian;
        let (sec, frac) = (u64::from(e.u32(h, 0)), u64::from(e.u32(h, 4)));
        let incl = e.u32(h, 8) as usize;
        if incl > MAX_RECORD {
            return Err(StepError::Malformed("record length out of range"));
        }
        let end = Self::RECORD_HEADER + incl;
        let frame =
            rest.get(Self::RECORD_HEADER..end).ok_or(StepError::Truncated("record data"))?;
        let ns = sec * 1_000_000_000 + if self.nanos { frac } else { frac * 1000 };
        Ok((end, Some((self.link, ns, frame))))
    }
}

/// pcapng block types and the byte-order magic.
mod ng {
    pub const SHB_TYPE: u32 = 0x0a0d_0d0a;
    pub const IDB_TYPE: u32 = 1;
    pub const SPB_TYPE: u32 = 3;
    pub const EPB_TYPE: u32 = 6;
    pub const BYTE_ORDER_MAGIC: u32 = 0x1a2b_3c4d;
    pub const OPT_END: u16 = 0;
    pub const OPT_TSRESOL: u16 = 9;
    pub const OPT_TSOFFSET: u16 = 14;
}

/// pcapng reading state: the current section's byte order and interfaces.
#[derive(Debug, Default)]
struct NgState {
    endian: Option<Endian>,
    interfaces: Vec<Interface>,
    last_ns: u64,
}

/// One interface of a pcapng section.
#[derive(Clone, Copy, Debug)]
struct Interface {
    link: u16,
    snaplen: u32,
    /// Timestamp units: `(true, n)` = 2^-n s, `(false, n)` = 10^-n s.
    resol: (bool, u8),
    offset_s: i64,
}

impl Interface {
    fn to_ns(self, ts: u64) -> u64 {
        let ts = u128::from(ts);
        let ns = match self.resol {
            (false, n) if n <= 9 => ts * 10u128.pow(u32::from(9 - n)),
            (false, n) => ts / 10u128.pow(u32::from(n - 9).min(38)),
            (true, n) => (ts * 1_000_000_000) >> n.min(127),
        };
        let ns = ns as i128 + i128::from(self.offset_s) * 1_000_000_000;
        ns.clamp(0, i128::from(u64::MAX)) as u64
    }
}

impl NgState {
    fn block<'a>(&mut self, rest: &'a [u8]) -> Step<'a> {
        let head = rest.get(..12).ok_or(StepError::Truncated("block header"))?;
        let raw_type = u32::from_le_bytes([head[0], head[1], head[2], head[3]]);
        if raw_type == ng::SHB_TYPE {
            // The section header fixes the byte order of everything up to the next one.
            let magic = u32::from_le_bytes([head[8], head[9], head[10], head[11]]);
            self.endian = match magic {
                ng::BYTE_ORDER_MAGIC => Some(Endian::Little),
                m if m.swap_bytes() == ng::BYTE_ORDER_MAGIC => Some(Endian::Big),
                _ => return Err(StepError::Malformed("bad section header byte-order magic")),
            };
            self.interfaces.clear();
        }
        let e = self.endian.ok_or(StepError::Malformed("no section header block"))?;
        let block_type = e.u32(head, 0);
        let len = e.u32(head, 4) as usize;
        if len < 12 || !len.is_multiple_of(4) || len > MAX_RECORD {
            return Err(StepError::Malformed("bad block length"));
        }
        let block = rest.get(..len).ok_or(StepError::Truncated("block"))?;
        if e.u32(block, len - 4) as usize != len {
            return Err(StepError::Malformed("block trailer length differs from header"));
        }
        let body = &block[8..len - 4];
        let record = match block_type {
            ng::IDB_TYPE => {
                self.interfaces.push(parse_idb(e, body)?);
                None
            }
            ng::EPB_TYPE => Some(self.epb(e, body)?),
            ng::SPB_TYPE => Some(self.spb(e, body)?),
            _ => None, // statistics, name resolution, custom blocks: not needed
        };
        Ok((len, record))
    }

    fn interface(&self, id: u32) -> Result<Interface, StepError> {
        self.interfaces
            .get(id as usize)
            .copied()
            .ok_or(StepError::Malformed("packet on an undeclared interface"))
    }

    /// Enhanced packet block: interface, 64-bit timestamp, captured and original length.
    fn epb<'a>(&mut self, e: Endian, body: &'a [u8]) -> Result<Record<'a>, StepError> {
        if body.len() < 20 {
            return Err(StepError::Malformed("enhanced packet block too short"));
        }
        let iface = self.interface(e.u32(body, 0))?;
        let ts = (u64::from(e.u32(body, 4)) << 32) | u64::from(e.u32(body, 8));
        let captured = e.u32(body, 12) as usize;
        let data = body
            .get(20..20 + captured)
            .ok_or(StepError::Malformed("packet data longer than its block"))?;
        self.last_ns = iface.to_ns(ts);
        Ok((iface.link, self.last_ns, data))
    }

    /// Simple packet block: interface 0, no timestamp (the previous packet's time is
    /// used), captured length = min(original length, snap length, block).
    fn spb<'a>(&mut self, e: Endian, body: &'a [u8]) -> Result<Record<'a>, StepError> {
        let iface = self.interface(0)?;
        if body.len() < 4 {
            return Err(StepError::Malformed("simple packet block too short"));
        }
        let orig = e.u32(body, 0) as usize;
        let snap = if iface.snaplen == 0 { usize::MAX } else { iface.snaplen as usize };
        let captured = orig.min(snap).min(body.len() - 4);
        Ok((iface.link, self.last_ns, &body[4..4 + captured]))
    }
}

/// Interface description block: link type, snap length, options.
fn parse_idb(e: Endian, body: &[u8]) -> Result<Interface, StepError> {
    if body.len() < 8 {
        return Err(StepError::Malformed("interface description block too short"));
    }
    let mut iface =
        Interface { link: e.u16(body, 0), snaplen: e.u32(body, 4), resol: (false, 6), offset_s: 0 };
    let mut opts = &body[8..];
    while opts.len() >= 4 {
        let (code, len) = (e.u16(opts, 0), usize::from(e.u16(opts, 2)));
        if code == ng::OPT_END {
            break;
        }
        let value =
            opts.get(4..4 + len).ok_or(StepError::Malformed("option overruns its block"))?;
        match (code, value.len()) {
            (ng::OPT_TSRESOL, 1) => iface.resol = (value[0] & 0x80 != 0, value[0] & 0x7f),
            (ng::OPT_TSOFFSET, 8) => iface.offset_s = e.u64(value, 0) as i64,
            _ => {}
        }
        let padded = (4 + len).div_ceil(4) * 4;
        opts = opts.get(padded..).unwrap_or(&[]);
    }
    Ok(iface)
}

/// Reads the capture at `path` and returns its datagram payloads with timestamps, owned;
/// a cut-off final record is dropped (see [`PcapStats::truncated`]).
pub fn read_udp(path: impl AsRef<Path>) -> Result<(Vec<OwnedDatagram>, PcapStats), PcapError> {
    let capture = Capture::open(path)?;
    let mut it = capture.datagrams()?;
    let mut out = Vec::new();
    for d in it.by_ref() {
        match d {
            Ok(d) => out.push(OwnedDatagram::from(d)),
            Err(PcapError::Truncated { .. }) => break,
            Err(e) => return Err(e),
        }
    }
    Ok((out, *it.stats()))
}

/// A [`UdpDatagram`] that owns its payload.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OwnedDatagram {
    pub timestamp_ns: u64,
    pub src: SocketAddrV4,
    pub dst: SocketAddrV4,
    pub payload: Vec<u8>,
}

impl From<UdpDatagram<'_>> for OwnedDatagram {
    fn from(d: UdpDatagram<'_>) -> Self {
        OwnedDatagram {
            timestamp_ns: d.timestamp_ns,
            src: d.src,
            dst: d.dst,
            payload: d.payload.to_vec(),
        }
    }
}
