//! pcap / pcapng reader tests: crafted captures in every supported container, byte order
//! and link type (written by the tiny writers below), the skip counters, truncation, the
//! replay pacer, random bytes, and the real LiDAR captures in `../shared/data/pcap`.
#![cfg(feature = "std")]

use std::net::{Ipv4Addr, SocketAddrV4};
use std::path::PathBuf;
use std::time::Duration;

use proptest::prelude::*;
use roomcal::lidar::pcap::{
    self, link, CaptureFormat, EthernetFrame, Ipv4Packet, PcapError, PcapStats, ReplayPacer,
    UdpPacket, ViewError,
};

// ---------------------------------------------------------------------------------------
// Frame builders

const SRC: SocketAddrV4 = SocketAddrV4::new(Ipv4Addr::new(192, 168, 1, 201), 2368);
const DST: SocketAddrV4 = SocketAddrV4::new(Ipv4Addr::new(255, 255, 255, 255), 2369);

/// IPv4 header + `l4` with protocol `proto` and flags/fragment word `frag`.
fn ipv4(proto: u8, frag: u16, l4: &[u8]) -> Vec<u8> {
    let total = (20 + l4.len()) as u16;
    let mut v = vec![0x45, 0];
    v.extend_from_slice(&total.to_be_bytes());
    v.extend_from_slice(&[0x12, 0x34]);
    v.extend_from_slice(&frag.to_be_bytes());
    v.extend_from_slice(&[64, proto, 0, 0]);
    v.extend_from_slice(&SRC.ip().octets());
    v.extend_from_slice(&DST.ip().octets());
    v.extend_from_slice(l4);
    v
}

fn udp(payload: &[u8]) -> Vec<u8> {
    let mut v = Vec::new();
    v.extend_from_slice(&SRC.port().to_be_bytes());
    v.extend_from_slice(&DST.port().to_be_bytes());
    v.extend_from_slice(&((8 + payload.len()) as u16).to_be_bytes());
    v.extend_from_slice(&[0, 0]);
    v.extend_from_slice(payload);
    v
}

fn ip_udp(payload: &[u8]) -> Vec<u8> {
    ipv4(17, 0x4000, &udp(payload)) // DF set, not a fragment
}

/// Ethernet frame with VLAN tags `vlans` (outer first), padded to 60 bytes like a NIC.
fn ethernet(vlans: &[(u16, u16)], ethertype: u16, l3: &[u8]) -> Vec<u8> {
    let mut v = vec![0xff; 6];
    v.extend_from_slice(&[0x60, 0x76, 0x88, 0, 0, 1]);
    for &(tpid, id) in vlans {
        v.extend_from_slice(&tpid.to_be_bytes());
        v.extend_from_slice(&id.to_be_bytes());
    }
    v.extend_from_slice(&ethertype.to_be_bytes());
    v.extend_from_slice(l3);
    v.resize(v.len().max(60), 0);
    v
}

fn sll(protocol: u16, l3: &[u8]) -> Vec<u8> {
    let mut v = vec![0, 0, 0, 1, 0, 6, 0x60, 0x76, 0x88, 0, 0, 1, 0, 0];
    v.extend_from_slice(&protocol.to_be_bytes());
    v.extend_from_slice(l3);
    v
}

fn sll2(protocol: u16, l3: &[u8]) -> Vec<u8> {
    let mut v = protocol.to_be_bytes().to_vec();
    v.extend_from_slice(&[0, 0, 0, 0, 0, 3, 0, 1, 0, 6, 0x60, 0x76, 0x88, 0, 0, 1, 0, 0]);
    v.extend_from_slice(l3);
    v
}

// ---------------------------------------------------------------------------------------
// Container writers

fn put32(v: &mut Vec<u8>, x: u32, be: bool) {
    v.extend_from_slice(&if be { x.to_be_bytes() } else { x.to_le_bytes() });
}

fn put16(v: &mut Vec<u8>, x: u16, be: bool) {
    v.extend_from_slice(&if be { x.to_be_bytes() } else { x.to_le_bytes() });
}

/// Classic pcap with `frames` = (timestamp ns, frame).
fn classic(be: bool, nanos: bool, link: u16, frames: &[(u64, Vec<u8>)]) -> Vec<u8> {
    let mut v = Vec::new();
    put32(&mut v, if nanos { 0xa1b2_3c4d } else { 0xa1b2_c3d4 }, be);
    put16(&mut v, 2, be);
    put16(&mut v, 4, be);
    put32(&mut v, 0, be);
    put32(&mut v, 0, be);
    put32(&mut v, 65535, be);
    put32(&mut v, u32::from(link), be);
    for (ts, f) in frames {
        let frac = if nanos { ts % 1_000_000_000 } else { ts % 1_000_000_000 / 1000 };
        put32(&mut v, (ts / 1_000_000_000) as u32, be);
        put32(&mut v, frac as u32, be);
        put32(&mut v, f.len() as u32, be);
        put32(&mut v, f.len() as u32, be);
        v.extend_from_slice(f);
    }
    v
}

/// Minimal pcapng writer.
struct Ng {
    be: bool,
    out: Vec<u8>,
}

impl Ng {
    fn new(be: bool) -> Ng {
        let mut ng = Ng { be, out: Vec::new() };
        ng.shb();
        ng
    }

    fn block(&mut self, kind: u32, body: &[u8]) {
        let len = 12 + body.len().div_ceil(4) * 4;
        put32(&mut self.out, kind, self.be);
        put32(&mut self.out, len as u32, self.be);
        self.out.extend_from_slice(body);
        self.out.resize(self.out.len() + (len - 12 - body.len()), 0);
        put32(&mut self.out, len as u32, self.be);
    }

    fn shb(&mut self) {
        let mut b = Vec::new();
        put32(&mut b, 0x1a2b_3c4d, self.be);
        put16(&mut b, 1, self.be);
        put16(&mut b, 0, self.be);
        b.extend_from_slice(&[0xff; 8]); // section length unknown
        self.block(0x0a0d_0d0a, &b);
    }

    /// Interface with `tsresol` (None = default µs) and `tsoffset` seconds.
    fn idb(&mut self, link: u16, snaplen: u32, tsresol: Option<u8>, tsoffset: Option<u64>) {
        let mut b = Vec::new();
        put16(&mut b, link, self.be);
        put16(&mut b, 0, self.be);
        put32(&mut b, snaplen, self.be);
        // An option we do not read first (if_name), to exercise option skipping.
        put16(&mut b, 2, self.be);
        put16(&mut b, 3, self.be);
        b.extend_from_slice(b"et0\0");
        if let Some(r) = tsresol {
            put16(&mut b, 9, self.be);
            put16(&mut b, 1, self.be);
            b.extend_from_slice(&[r, 0, 0, 0]);
        }
        if let Some(o) = tsoffset {
            put16(&mut b, 14, self.be);
            put16(&mut b, 8, self.be);
            b.extend_from_slice(&if self.be { o.to_be_bytes() } else { o.to_le_bytes() });
        }
        put32(&mut b, 0, self.be); // opt_endofopt
        self.block(1, &b);
    }

    fn epb(&mut self, iface: u32, ts_units: u64, frame: &[u8]) {
        let mut b = Vec::new();
        put32(&mut b, iface, self.be);
        put32(&mut b, (ts_units >> 32) as u32, self.be);
        put32(&mut b, ts_units as u32, self.be);
        put32(&mut b, frame.len() as u32, self.be);
        put32(&mut b, frame.len() as u32, self.be);
        b.extend_from_slice(frame);
        self.block(6, &b);
    }

    fn spb(&mut self, frame: &[u8]) {
        let mut b = Vec::new();
        put32(&mut b, frame.len() as u32, self.be);
        b.extend_from_slice(frame);
        self.block(3, &b);
    }
}

/// (timestamp ns, source, destination, payload) of one datagram.
type Got = (u64, SocketAddrV4, SocketAddrV4, Vec<u8>);

/// All datagrams of `bytes` as owned tuples, plus the stats; panics on errors.
fn collect(bytes: &[u8]) -> (Vec<Got>, PcapStats) {
    let mut it = pcap::datagrams(bytes, "test.pcap").expect("header");
    let v = it
        .by_ref()
        .map(|d| {
            let d = d.expect("datagram");
            (d.timestamp_ns, d.src, d.dst, d.payload.to_vec())
        })
        .collect();
    (v, *it.stats())
}

// ---------------------------------------------------------------------------------------
// Tests

#[test]
fn classic_both_byte_orders_and_resolutions() {
    let t0 = 1_673_400_471_737_763_166u64;
    for be in [false, true] {
        for nanos in [false, true] {
            let frames: Vec<_> = (0..5u64)
                .map(|i| (t0 + i * 1_327_000, ethernet(&[], 0x0800, &ip_udp(&[i as u8; 1206]))))
                .collect();
            let bytes = classic(be, nanos, link::ETHERNET, &frames);
            let it = pcap::datagrams(&bytes, "x").unwrap();
            assert_eq!(it.format(), CaptureFormat::Pcap);
            let (got, stats) = collect(&bytes);
            assert_eq!(got.len(), 5, "be={be} nanos={nanos}");
            for (i, (ts, src, dst, payload)) in got.iter().enumerate() {
                let want = frames[i].0;
                let want = if nanos { want } else { want / 1000 * 1000 };
                assert_eq!(*ts, want);
                assert_eq!((*src, *dst), (SRC, DST));
                assert_eq!(payload, &vec![i as u8; 1206]);
            }
            assert_eq!(stats, PcapStats { records: 5, udp: 5, ..Default::default() });
        }
    }
}

#[test]
fn ethernet_padding_is_not_payload() {
    let frame = ethernet(&[], 0x0800, &ip_udp(b"hi"));
    assert_eq!(frame.len(), 60);
    let (got, _) = collect(&classic(false, false, link::ETHERNET, &[(0, frame)]));
    assert_eq!(got[0].3, b"hi");
}

#[test]
fn vlan_sll_sll2_and_raw_links() {
    let payload = [7u8; 100];
    let cases = [
        (link::ETHERNET, ethernet(&[(0x8100, 5)], 0x0800, &ip_udp(&payload))),
        (link::ETHERNET, ethernet(&[(0x88a8, 100), (0x8100, 5)], 0x0800, &ip_udp(&payload))),
        (link::LINUX_SLL, sll(0x0800, &ip_udp(&payload))),
        (link::LINUX_SLL2, sll2(0x0800, &ip_udp(&payload))),
        (link::RAW, ip_udp(&payload)),
        (link::IPV4, ip_udp(&payload)),
    ];
    for (lt, frame) in cases {
        let (got, stats) = collect(&classic(false, true, lt, &[(1, frame)]));
        assert_eq!(got.len(), 1, "link {lt}: {stats:?}");
        assert_eq!(got[0].3, payload);
    }
}

#[test]
fn skipped_packets_are_counted() {
    let frames = vec![
        (1, ethernet(&[], 0x0800, &ip_udp(b"keep"))),
        (2, ethernet(&[], 0x0800, &ipv4(17, 0x2000, &udp(&[1; 64])))), // first fragment
        (3, ethernet(&[], 0x0800, &ipv4(17, 0x0008, &[2; 64]))),       // later fragment
        (4, ethernet(&[], 0x0800, &ipv4(6, 0x4000, &[0; 20]))),        // TCP
        (5, ethernet(&[], 0x86dd, &[0x60; 60])),                       // IPv6
        (6, ethernet(&[(0x8100, 1)], 0x0806, &[0; 28])),               // ARP behind a VLAN tag
        (7, ethernet(&[], 0x0800, &ip_udp(&[9; 300]))[..100].to_vec()), // snapped
        (8, ethernet(&[], 0x0800, &ip_udp(b"also"))),
    ];
    let (got, stats) = collect(&classic(false, false, link::ETHERNET, &frames));
    let payloads: Vec<_> = got.iter().map(|g| g.3.clone()).collect();
    assert_eq!(payloads, vec![b"keep".to_vec(), b"also".to_vec()]);
    let want = PcapStats {
        records: 8,
        udp: 2,
        ip_fragments: 2,
        non_ipv4: 2,
        non_udp: 1,
        malformed: 1,
        unsupported_link: 0,
        truncated: 0,
    };
    assert_eq!(stats, want);
    let (_, stats) = collect(&classic(false, false, 147, &frames[..1]));
    assert_eq!(stats.unsupported_link, 1);
}

#[test]
fn truncated_last_record_is_reported_after_the_good_ones() {
    let frames: Vec<_> =
        (0..3u64).map(|i| (i, ethernet(&[], 0x0800, &ip_udp(&[i as u8; 500])))).collect();
    let bytes = classic(false, false, link::ETHERNET, &frames);
    for cut in [bytes.len() - 1, bytes.len() - 200, bytes.len() - 530] {
        let mut it = pcap::datagrams(&bytes[..cut], "cut.pcap").unwrap();
        let items: Vec<_> = it.by_ref().collect();
        assert_eq!(items.len(), 3, "cut {cut}");
        assert!(items[..2].iter().all(Result::is_ok));
        let err = items[2].as_ref().unwrap_err();
        assert!(matches!(err, PcapError::Truncated { .. }), "{err}");
        assert!(err.to_string().contains("cut.pcap"), "{err}");
        assert_eq!(it.stats().truncated, 1);
        assert_eq!(it.stats().udp, 2);
        assert!(it.next().is_none());
    }
    // A record length that cannot be right is malformed, not truncated.
    let mut bad = bytes.clone();
    bad[24 + 8..24 + 12].copy_from_slice(&u32::MAX.to_le_bytes());
    let first = pcap::datagrams(&bad, "bad.pcap").unwrap().next().unwrap();
    assert!(matches!(first, Err(PcapError::Malformed { .. })));
}

#[test]
fn not_a_capture() {
    let err = pcap::datagrams(b"# .PCD v0.7\nVERSION", "cloud.pcd").unwrap_err();
    assert!(matches!(err, PcapError::NotACapture { .. }));
    assert!(err.to_string().contains("cloud.pcd"));
    assert!(matches!(pcap::datagrams(b"\xd4\xc3", "x").unwrap_err(), PcapError::Truncated { .. }));
    let err = pcap::Capture::open("/nonexistent/file.pcap").unwrap_err();
    assert!(err.to_string().contains("/nonexistent/file.pcap"));
}

#[test]
fn pcapng_interfaces_resolutions_and_byte_orders() {
    let t0 = 1_713_492_677_327_771_785u64; // ns
    for be in [false, true] {
        let mut ng = Ng::new(be);
        ng.idb(link::ETHERNET, 0, None, None); // µs
        ng.idb(link::LINUX_SLL2, 0, Some(9), None); // ns
        ng.idb(link::LINUX_SLL, 0, Some(0x80 | 20), Some(100)); // 2^-20 s, +100 s
        ng.epb(0, t0 / 1000, &ethernet(&[], 0x0800, &ip_udp(b"eth")));
        ng.epb(1, t0 + 5, &sll2(0x0800, &ip_udp(b"sll2")));
        let units = ((t0 as u128) << 20) / 1_000_000_000;
        ng.epb(2, units as u64, &sll(0x0800, &ip_udp(b"sll")));
        ng.block(5, &[0; 16]); // interface statistics: skipped
        let (got, stats) = collect(&ng.out);
        assert_eq!(pcap::datagrams(&ng.out, "x").unwrap().format(), CaptureFormat::PcapNg);
        let payloads: Vec<_> = got.iter().map(|g| g.3.as_slice()).collect();
        assert_eq!(payloads, [b"eth".as_slice(), b"sll2", b"sll"], "be={be}");
        assert_eq!(got[0].0, t0 / 1000 * 1000);
        assert_eq!(got[1].0, t0 + 5);
        let want = t0 + 100_000_000_000;
        assert!(got[2].0.abs_diff(want) < 1000, "{} vs {want}", got[2].0);
        assert_eq!(stats.udp, 3);
    }
}

#[test]
fn pcapng_simple_packets_and_new_sections() {
    let mut ng = Ng::new(false);
    ng.idb(link::ETHERNET, 0, Some(9), None);
    ng.epb(0, 42, &ethernet(&[], 0x0800, &ip_udp(b"one")));
    ng.spb(&ethernet(&[], 0x0800, &ip_udp(b"two")));
    // A big-endian section follows with its own interfaces.
    let mut second = Ng::new(true);
    second.idb(link::RAW, 0, Some(9), None);
    second.epb(0, 77, &ip_udp(b"three"));
    ng.out.extend_from_slice(&second.out);
    let (got, _) = collect(&ng.out);
    let got: Vec<_> = got.iter().map(|g| (g.0, g.3.as_slice())).collect();
    assert_eq!(got, [(42, b"one".as_slice()), (42, b"two"), (77, b"three")]);
}

#[test]
fn pcapng_structural_errors() {
    let mut ng = Ng::new(false);
    ng.epb(0, 1, &ethernet(&[], 0x0800, &ip_udp(b"x"))); // no interface declared
    let first = pcap::datagrams(&ng.out, "noif.pcapng").unwrap().next().unwrap();
    let err = first.unwrap_err();
    assert!(matches!(err, PcapError::Malformed { .. }) && err.to_string().contains("noif"));

    let mut ng = Ng::new(false);
    ng.idb(link::ETHERNET, 0, None, None);
    ng.epb(0, 1, &ethernet(&[], 0x0800, &ip_udp(b"x")));
    let n = ng.out.len();
    ng.out[n - 4] ^= 4; // trailer length differs
    assert!(pcap::datagrams(&ng.out, "x").unwrap().next().unwrap().is_err());
    let cut = &ng.out[..n - 10];
    let mut it = pcap::datagrams(cut, "x").unwrap();
    assert!(matches!(it.next(), Some(Err(PcapError::Truncated { .. }))));
    assert_eq!(it.stats().truncated, 1);
}

#[test]
fn views_read_fields_and_reject_short_buffers() {
    let bytes = ip_udp(b"payload");
    let ip = Ipv4Packet::new_checked(bytes.as_slice()).unwrap();
    assert_eq!((ip.version(), ip.header_len(), ip.protocol()), (4, 20, 17));
    assert_eq!(ip.src_addr(), *SRC.ip());
    assert!(!ip.more_fragments());
    let udp = UdpPacket::new_checked(ip.payload()).unwrap();
    assert_eq!((udp.src_port(), udp.dst_port(), udp.len()), (2368, 2369, 15));
    assert_eq!(udp.into_payload(), b"payload");
    assert_eq!(Ipv4Packet::new_checked(&bytes[..19]).unwrap_err(), ViewError::Truncated);
    assert_eq!(Ipv4Packet::new_checked(&bytes[..25]).unwrap_err(), ViewError::Truncated);
    let mut v6 = bytes.clone();
    v6[0] = 0x65;
    assert_eq!(Ipv4Packet::new_checked(v6.as_slice()).unwrap_err(), ViewError::Malformed);
    assert_eq!(UdpPacket::new_checked(&[0u8; 7][..]).unwrap_err(), ViewError::Truncated);
    assert_eq!(UdpPacket::new_checked(&[0u8; 8][..]).unwrap_err(), ViewError::Malformed);
    let eth = ethernet(&[], 0x0800, &bytes);
    let frame = EthernetFrame::new_checked(eth.as_slice()).unwrap();
    assert_eq!((frame.ethertype(), frame.src_addr()[0]), (0x0800, 0x60));
    assert!(EthernetFrame::new_checked(&eth[..13]).is_err());
}

#[test]
fn replay_pacer_follows_capture_time() {
    let pacer = ReplayPacer::new(1_000_000_000);
    assert_eq!(pacer.delay_until(1_000_000_000), Duration::ZERO);
    assert_eq!(pacer.delay_until(1_250_000_000), Duration::from_millis(250));
    assert_eq!(pacer.delay_until(999_000_000), Duration::ZERO); // clock stepped back
    assert_eq!(pacer.wait(1_250_000_000, Duration::from_millis(100)), Duration::from_millis(150));
    assert_eq!(pacer.wait(1_250_000_000, Duration::from_millis(300)), Duration::ZERO);
    let fast = pacer.with_speed(2.0);
    assert_eq!(fast.delay_until(1_500_000_000), Duration::from_millis(250));
    assert_eq!(pacer.with_speed(-1.0), pacer);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        if let Ok(it) = pcap::datagrams(&bytes, "fuzz") {
            for _ in it {}
        }
    }

    #[test]
    fn mutated_captures_never_panic(
        be in any::<bool>(),
        flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8),
        cut in any::<usize>(),
    ) {
        let mut ng = Ng::new(be);
        ng.idb(link::ETHERNET, 0, Some(9), Some(3));
        ng.idb(link::LINUX_SLL2, 64, None, None);
        ng.epb(0, 5, &ethernet(&[(0x8100, 3)], 0x0800, &ip_udp(&[1; 40])));
        ng.epb(1, 6, &sll2(0x0800, &ip_udp(&[2; 40])));
        ng.spb(&ethernet(&[], 0x0800, &ip_udp(&[3; 40])));
        let classic = classic(be, true, link::LINUX_SLL, &[(1, sll(0x0800, &ip_udp(&[4; 30])))]);
        for mut bytes in [ng.out, classic] {
            for &(at, v) in &flips {
                let n = bytes.len();
                bytes[at % n] ^= v;
            }
            let n = bytes.len();
            if let Ok(it) = pcap::datagrams(&bytes[..cut % (n + 1)], "fuzz") {
                for _ in it {}
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// Real captures

fn data_dir() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/pcap"))
}

/// Independent count of the capture's frames whose UDP payload (at the fixed offset of
/// Ethernet + 20-byte IPv4 + UDP) has length `size`: walks the record headers only.
fn count_payloads(bytes: &[u8], size: usize) -> (usize, usize) {
    assert_eq!(&bytes[..4], &[0xd4, 0xc3, 0xb2, 0xa1], "expected little-endian µs pcap");
    let (mut pos, mut records, mut matching) = (24, 0, 0);
    while pos + 16 <= bytes.len() {
        let incl = u32::from_le_bytes(bytes[pos + 8..pos + 12].try_into().unwrap()) as usize;
        records += 1;
        matching += usize::from(incl == 14 + 20 + 8 + size);
        pos += 16 + incl;
    }
    assert_eq!(pos, bytes.len());
    (records, matching)
}

/// Sum of `"packets": N` in the converter's summary (another independent count).
fn summary_packets(dir: &std::path::Path) -> Option<usize> {
    let text = std::fs::read_to_string(dir.join("conversion_summary.json")).ok()?;
    let sum = text
        .split("\"packets\":")
        .skip(1)
        .map(|s| s.trim_start().split(|c: char| !c.is_ascii_digit()).next().unwrap())
        .map(|n| n.parse::<usize>().unwrap())
        .sum();
    Some(sum)
}

#[test]
fn real_lidar_captures() {
    let cases =
        [("velodyne-vlp16", 1206usize), ("velodyne-vlp32c", 1206), ("hesai-pandar64", 1198)];
    for (name, size) in cases {
        let dir = data_dir().join(name);
        let path = dir.join(format!("{name}.pcap"));
        if !path.exists() {
            crate::common::skipped(format_args!("{} absent", path.display()));
            continue;
        }
        let capture = pcap::Capture::open(&path).unwrap();
        let (records, matching) = count_payloads(capture.bytes(), size);
        let mut it = capture.datagrams().unwrap();
        let mut n = 0;
        let mut last = 0;
        for d in it.by_ref() {
            let d = d.unwrap();
            assert_eq!(d.payload.len(), size, "{name}");
            assert_eq!(d.src.port(), 2368);
            assert!(d.timestamp_ns >= last, "{name}: time goes back");
            last = d.timestamp_ns;
            n += 1;
        }
        assert_eq!(n, matching, "{name}");
        assert_eq!(n, records, "{name}: every record is a sensor packet");
        if let Some(packets) = summary_packets(&dir) {
            assert_eq!(n, packets, "{name}: conversion summary");
        }
        assert_eq!(it.stats().udp as usize, n);
        let (owned, stats) = pcap::read_udp(&path).unwrap();
        assert_eq!((owned.len(), stats.truncated), (n, 0));
        eprintln!("{name}: {n} datagrams of {size} B");
    }
}

#[test]
#[ignore = "timing; run with --release -- --ignored --nocapture"]
fn real_capture_speed() {
    let path = data_dir().join("hesai-pandar64/hesai-pandar64.pcap");
    if !path.exists() {
        crate::common::skipped(format_args!("{} absent", path.display()));
        return;
    }
    let capture = pcap::Capture::open(&path).unwrap();
    let reps = 200;
    let t = std::time::Instant::now();
    let mut datagrams = 0usize;
    for _ in 0..reps {
        for d in capture.datagrams().unwrap() {
            std::hint::black_box(d.unwrap().payload);
            datagrams += 1;
        }
    }
    let s = t.elapsed().as_secs_f64() / reps as f64;
    let n = datagrams / reps;
    eprintln!(
        "pcap: {n} datagrams in {:.1} µs: {:.0} ns per datagram, {:.0} MB/s of capture",
        s * 1e6,
        s * 1e9 / n as f64,
        capture.bytes().len() as f64 / s / 1e6
    );
}

#[test]
fn frame_repr_emits_known_bytes_and_parses_back() {
    let repr = pcap::UdpFrameRepr { src: SRC, dst: DST, payload_len: 2 };
    let mut frame = vec![0u8; repr.frame_len()];
    repr.emit(&mut frame).unwrap();
    frame[42..].copy_from_slice(b"hi");
    #[rustfmt::skip]
    let want: [u8; 44] = [
        0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0x02, 0, 0, 0, 0, 0x01, 0x08, 0x00, // Ethernet
        0x45, 0, 0, 30, 0, 0, 0x40, 0, 64, 17, 0x78, 0x5e, // IPv4; checksum by RFC 1071 by hand
        192, 168, 1, 201, 255, 255, 255, 255,
        0x09, 0x40, 0x09, 0x41, 0, 10, 0, 0, b'h', b'i', // UDP + payload
    ];
    assert_eq!(frame, want);
    let ip = Ipv4Packet::new_checked(&frame[14..]).unwrap();
    assert!(ip.checksum_valid());
    assert_eq!(pcap::UdpFrameRepr::parse(&frame).unwrap(), (repr, b"hi".as_slice()));
    // Through a VLAN tag too; and a buffer too small or a payload too big are refused.
    let tagged = ethernet(&[(0x8100, 7)], 0x0800, &frame[14..]);
    assert_eq!(pcap::UdpFrameRepr::parse(&tagged).unwrap().1, b"hi");
    assert_eq!(repr.emit(&mut [0u8; 43]), Err(ViewError::Truncated));
    let huge = pcap::UdpFrameRepr { payload_len: 70_000, ..repr };
    assert_eq!(huge.emit(&mut vec![0; huge.frame_len()]), Err(ViewError::Malformed));
    assert!(pcap::UdpFrameRepr::parse(&ethernet(&[], 0x0800, &ipv4(6, 0, &[0; 20]))).is_err());
}

#[test]
fn writer_output_reads_back() {
    let data: Vec<(u64, Vec<u8>)> = (0..50u64)
        .map(|i| (1_700_000_000_123_456_789 + i * 1_327_000, vec![i as u8; 1206]))
        .collect();
    let mut w = pcap::PcapWriter::new(Vec::new()).unwrap();
    for (ts, p) in &data {
        w.write_udp(&pcap::UdpDatagram { timestamp_ns: *ts, src: SRC, dst: DST, payload: p })
            .unwrap();
    }
    let bytes = w.into_inner();
    let (got, stats) = collect(&bytes);
    assert_eq!(stats.udp, 50);
    for ((ts, p), g) in data.iter().zip(&got) {
        assert_eq!((g.0, g.1, g.2, &g.3), (*ts, SRC, DST, p));
    }
}

#[test]
fn real_capture_rewritten_reads_back_the_same() {
    let path = data_dir().join("velodyne-vlp16/velodyne-vlp16.pcap");
    if !path.exists() {
        crate::common::skipped(format_args!("{} absent", path.display()));
        return;
    }
    let capture = pcap::Capture::open(&path).unwrap();
    let mut w = pcap::PcapWriter::new(Vec::new()).unwrap();
    for d in capture.datagrams().unwrap() {
        w.write_udp(&d.unwrap()).unwrap();
    }
    let bytes = w.into_inner();
    let again = pcap::datagrams(&bytes, "rewritten").unwrap();
    let original = capture.datagrams().unwrap();
    assert!(original.map(Result::unwrap).eq(again.map(Result::unwrap)));
    // Same framing as the original (no VLAN tags, no IP options, no padding).
    assert_eq!(bytes.len(), capture.bytes().len());
}
