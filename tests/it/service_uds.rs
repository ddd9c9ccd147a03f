//! UDS server tests: byte vectors both ways for every service and DID, the NRC cases
//! and their priority, S3, SecurityAccess lockout, 0x78 while a calibration runs, and a
//! flood of 10,000 requests through ISO-TP + server (rate printed); the link binding each
//! answer to its request through floods of unanswered answers and unfinished requests, with
//! N_Bs and N_Cr to the microsecond; the per-sensor DIDs of rigs (sensor table 0xC010,
//! intrinsics 0xC200 + i, extrinsics 0xC300 + i).

use core::time::Duration;

use roomcal::service::fake::FakeBackend;
use roomcal::service::isotp::{Config, Event, IsoTp, RxError, TxError};
use roomcal::service::uds::{
    security_key, Abandoned, DaemonState, DecodeError, ExtrinsicRecord, IntrinsicsRecord, Link,
    LinkEvent, Nrc, Outcome, QualityRecord, RequestRepr, ResponseRepr, SensorKind, SensorTable,
    Server, ServerConfig, Session, StateRecord, MAX_SENSORS, MAX_SENSOR_NAME, SEED_LEN,
};
use roomcal::service::{CanFrame, Instant, WarnThrottle};

const SECRET: &[u8] = b"roomcal-secret";

/// Seeds 0, 1, 2, ... in every byte, so each seed differs and is known.
fn counting_seeds() -> impl FnMut(&mut [u8; SEED_LEN]) {
    let mut n = 0u8;
    move |seed: &mut [u8; SEED_LEN]| {
        for (i, b) in seed.iter_mut().enumerate() {
            *b = n.wrapping_add(i as u8);
        }
        n = n.wrapping_add(1);
    }
}

type TestServer = Server<FakeBackend, Box<dyn FnMut(&mut [u8; SEED_LEN])>>;

fn server(backend: FakeBackend) -> TestServer {
    Server::new(backend, Box::new(counting_seeds()), SECRET, ServerConfig::default())
}

fn ms(t: u64) -> Instant {
    Instant::from_millis(t)
}

fn ask(s: &mut TestServer, req: &[u8], now: Instant) -> Option<Vec<u8>> {
    s.handle(req, now).map(|r| r.to_vec())
}

fn nrc(s: &mut TestServer, req: &[u8], now: Instant) -> u8 {
    match ask(s, req, now).as_deref() {
        Some([0x7F, sid, code]) if *sid == req[0] => *code,
        other => panic!("expected a negative response to {req:02X?}, got {other:02X?}"),
    }
}

fn unlock(s: &mut TestServer, now: Instant) {
    assert_eq!(ask(s, &[0x10, 0x03], now).unwrap()[..2], [0x50, 0x03]);
    let r = ask(s, &[0x27, 0x01], now).unwrap();
    assert_eq!(r[..2], [0x67, 0x01]);
    let mut req = vec![0x27, 0x02];
    req.extend_from_slice(&security_key(SECRET, &r[2..]));
    assert_eq!(ask(s, &req, now).unwrap(), [0x67, 0x02]);
    assert!(s.is_unlocked());
}

#[test]
fn hmac_key_matches_rfc4231() {
    // RFC 4231 test case 2, truncated to 16 bytes.
    let key = security_key(b"Jefe", b"what do ya want for nothing?");
    let want = [
        0x5b, 0xdc, 0xc1, 0x46, 0xbf, 0x60, 0x75, 0x4e, 0x6a, 0x04, 0x24, 0x26, 0x08, 0x95, 0x75,
        0xc7,
    ];
    assert_eq!(key, want);
}

#[test]
fn session_control_and_tester_present() {
    let mut s = server(FakeBackend::calibrated());
    // P2 = 50 ms (0x0032), P2* = 5000 ms in 10 ms units (0x01F4).
    assert_eq!(ask(&mut s, &[0x10, 0x03], ms(0)).unwrap(), [0x50, 0x03, 0x00, 0x32, 0x01, 0xF4]);
    assert_eq!(ask(&mut s, &[0x10, 0x01], ms(0)).unwrap(), [0x50, 0x01, 0x00, 0x32, 0x01, 0xF4]);
    assert_eq!(ask(&mut s, &[0x10, 0x83], ms(0)), None, "suppressed positive response");
    assert_eq!(s.session(), roomcal::service::uds::Session::Extended);
    assert_eq!(nrc(&mut s, &[0x10, 0x02], ms(0)), 0x12);
    assert_eq!(nrc(&mut s, &[0x10], ms(0)), 0x13);
    assert_eq!(nrc(&mut s, &[0x10, 0x03, 0x00], ms(0)), 0x13);
    assert_eq!(nrc(&mut s, &[0x10, 0x05, 0x00], ms(0)), 0x12, "0x12 before total length");

    assert_eq!(ask(&mut s, &[0x3E, 0x00], ms(0)).unwrap(), [0x7E, 0x00]);
    assert_eq!(ask(&mut s, &[0x3E, 0x80], ms(0)), None);
    assert_eq!(nrc(&mut s, &[0x3E, 0x01], ms(0)), 0x12);
    assert_eq!(nrc(&mut s, &[0x3E, 0x00, 0x00], ms(0)), 0x13);
    assert_eq!(nrc(&mut s, &[0x3E], ms(0)), 0x13);

    for unsupported in [0x11u8, 0x14, 0x19, 0x2E, 0x34, 0x85, 0x00, 0xFF] {
        assert_eq!(nrc(&mut s, &[unsupported, 0x01], ms(0)), 0x11);
    }
    assert_eq!(ask(&mut s, &[], ms(0)), None);
}

#[test]
fn s3_timeout_falls_back_to_default_and_relocks() {
    let mut s = server(FakeBackend::calibrated());
    unlock(&mut s, ms(0));
    assert_eq!(s.poll_at(), Some(ms(5000)));
    assert_eq!(s.poll(ms(4999)), None);
    assert!(s.is_unlocked());
    // TesterPresent (even suppressed) keeps the session alive.
    assert_eq!(ask(&mut s, &[0x3E, 0x80], ms(4000)), None);
    s.poll(ms(8999));
    assert!(s.is_unlocked());
    s.poll(ms(9000));
    assert!(!s.is_unlocked());
    assert_eq!(s.session(), roomcal::service::uds::Session::Default);
    assert_eq!(nrc(&mut s, &[0x27, 0x01], ms(9001)), 0x7F);
    // A session change relocks too.
    unlock(&mut s, ms(10_000));
    ask(&mut s, &[0x10, 0x03], ms(10_001));
    assert!(!s.is_unlocked());
}

#[test]
fn read_data_by_identifier_byte_vectors() {
    let mut s = server(FakeBackend::calibrated());
    // 0xC001: state idle (0), generation 7, time 1_700_000_000 (0x6553F100).
    let r = ask(&mut s, &[0x22, 0xC0, 0x01], ms(0)).unwrap();
    assert_eq!(r, [0x62, 0xC0, 0x01, 0x00, 0, 0, 0, 7, 0x65, 0x53, 0xF1, 0x00]);
    // 0xC002: model 0, fx fy cx cy, n = 5, distortion.
    let r = ask(&mut s, &[0x22, 0xC0, 0x02], ms(0)).unwrap();
    let mut want = vec![0x62, 0xC0, 0x02, 0x00];
    for hex in ["447a0000", "447a2000", "44700000", "44160000"] {
        want.extend(u32::from_str_radix(hex, 16).unwrap().to_be_bytes());
    }
    want.push(5);
    for d in [-0.25f32, 0.0625, 0.001, -0.0005, 0.0] {
        want.extend(d.to_be_bytes());
    }
    assert_eq!(r, want);
    let rec = IntrinsicsRecord::parse(&r[3..]).unwrap();
    assert_eq!(Some(&rec), s.backend().intrinsics.as_ref());
    // 0xC003 and 0xC004 decode back to the backend's values.
    let r = ask(&mut s, &[0x22, 0xC0, 0x03], ms(0)).unwrap();
    assert_eq!(r.len(), 3 + ExtrinsicRecord::LEN);
    assert_eq!(r[3..7], 0.5f32.to_be_bytes());
    assert_eq!(Some(ExtrinsicRecord::parse(&r[3..]).unwrap()), s.backend().extrinsic);
    let r = ask(&mut s, &[0x22, 0xC0, 0x04], ms(0)).unwrap();
    assert_eq!(r, [0x62, 0xC0, 0x04, 0x3E, 0, 0, 0, 0x3F, 0x40, 0, 0, 6]);
    assert_eq!(QualityRecord::parse(&r[3..]).unwrap().boards, 6);
    // Several DIDs in one request; unsupported ones among them are left out.
    let r = ask(&mut s, &[0x22, 0xC0, 0x04, 0xF1, 0x90, 0xC0, 0x01], ms(0)).unwrap();
    assert_eq!(r.len(), 1 + (2 + 9) * 2);
    assert_eq!(r[1..3], [0xC0, 0x04]);
    assert_eq!(r[12..14], [0xC0, 0x01]);
    // The most DIDs, each the largest intrinsics record (8 coefficients): the data, never
    // 0x14 responseTooLong.
    let mut big = FakeBackend::calibrated();
    if let Some(k) = big.intrinsics.as_mut() {
        k.distortion = heapless::Vec::from_slice(&[0.5; 8]).unwrap();
    }
    let mut s = server(big);
    let eight: Vec<u8> = std::iter::once(0x22).chain([0xC0, 0x02].repeat(8)).collect();
    let r = ask(&mut s, &eight, ms(0)).unwrap();
    assert_eq!(r.len(), 1 + 8 * (2 + 18 + 4 * 8));
    for rec in r[1..].chunks(2 + 50) {
        assert_eq!(rec[..2], [0xC0, 0x02]);
        assert_eq!(IntrinsicsRecord::parse(&rec[2..]).unwrap().distortion.len(), 8);
    }
}

#[test]
fn read_data_by_identifier_negative_responses() {
    let mut s = server(FakeBackend::calibrated());
    assert_eq!(nrc(&mut s, &[0x22, 0xF1, 0x90], ms(0)), 0x31, "unknown DID");
    assert_eq!(nrc(&mut s, &[0x22, 0xC0, 0x00], ms(0)), 0x31);
    assert_eq!(nrc(&mut s, &[0x22, 0xC0, 0x05], ms(0)), 0x31);
    assert_eq!(nrc(&mut s, &[0x22], ms(0)), 0x13);
    assert_eq!(nrc(&mut s, &[0x22, 0xC0], ms(0)), 0x13);
    assert_eq!(nrc(&mut s, &[0x22, 0xC0, 0x01, 0xC0], ms(0)), 0x13);
    let nine: Vec<u8> = std::iter::once(0x22).chain([0xC0, 0x01].repeat(9)).collect();
    assert_eq!(nrc(&mut s, &nine, ms(0)), 0x13, "more DIDs than the server takes");
    // No calibration yet: the data is not available.
    let mut s = server(FakeBackend::empty());
    assert_eq!(nrc(&mut s, &[0x22, 0xC0, 0x02], ms(0)), 0x22);
    let r = ask(&mut s, &[0x22, 0xC0, 0x01], ms(0)).unwrap();
    assert_eq!(StateRecord::parse(&r[3..]).unwrap().generation, 0);
}

#[test]
fn security_access() {
    let mut s = server(FakeBackend::calibrated());
    assert_eq!(nrc(&mut s, &[0x27, 0x01], ms(0)), 0x7F, "not in the default session");
    assert_eq!(nrc(&mut s, &[0x27], ms(0)), 0x7F, "session checked before length");
    ask(&mut s, &[0x10, 0x03], ms(0));
    assert_eq!(nrc(&mut s, &[0x27], ms(0)), 0x13);
    assert_eq!(nrc(&mut s, &[0x27, 0x03], ms(0)), 0x12);
    assert_eq!(nrc(&mut s, &[0x27, 0x01, 0x00], ms(0)), 0x13);
    let mut key = vec![0x27, 0x02];
    key.extend([0u8; 16]);
    assert_eq!(nrc(&mut s, &key, ms(0)), 0x24, "key without a seed");
    assert_eq!(nrc(&mut s, &key[..17], ms(0)), 0x13);

    // Three wrong keys: 0x35, 0x35, 0x36, then 0x37 for 10 s.
    for (i, want) in [0x35u8, 0x35, 0x36].into_iter().enumerate() {
        let r = ask(&mut s, &[0x27, 0x01], ms(i as u64)).unwrap();
        assert_eq!(r.len(), 2 + SEED_LEN);
        assert_ne!(r[2..], [0u8; 16]);
        let mut bad = security_key(SECRET, &r[2..]);
        bad[0] ^= 1;
        let mut req = vec![0x27, 0x02];
        req.extend(bad);
        assert_eq!(nrc(&mut s, &req, ms(i as u64)), want);
        assert_eq!(nrc(&mut s, &req, ms(i as u64)), 0x24, "seed used up");
    }
    assert_eq!(nrc(&mut s, &[0x27, 0x01], ms(5000)), 0x37);
    ask(&mut s, &[0x3E, 0x80], ms(7000));
    assert_eq!(nrc(&mut s, &[0x27, 0x01], ms(10_001)), 0x37);
    // The delay has expired 10 s after the third wrong key.
    let r = ask(&mut s, &[0x27, 0x01], ms(10_002)).unwrap();
    let mut req = vec![0x27, 0x02];
    req.extend(security_key(SECRET, &r[2..]));
    assert_eq!(ask(&mut s, &req, ms(10_002)).unwrap(), [0x67, 0x02]);
    // Unlocked: the seed is all zeros.
    assert_eq!(ask(&mut s, &[0x27, 0x01], ms(10_003)).unwrap()[2..], [0u8; 16]);
    // A key from another secret is refused.
    let mut s = server(FakeBackend::calibrated());
    ask(&mut s, &[0x10, 0x03], ms(0));
    let r = ask(&mut s, &[0x27, 0x01], ms(0)).unwrap();
    let mut req = vec![0x27, 0x02];
    req.extend(security_key(b"other", &r[2..]));
    assert_eq!(nrc(&mut s, &req, ms(0)), 0x35);
}

#[test]
fn routine_control_nrc_priority() {
    let mut s = server(FakeBackend::calibrated());
    assert_eq!(nrc(&mut s, &[0x31, 0x01, 0xC1, 0x00], ms(0)), 0x7F);
    assert_eq!(nrc(&mut s, &[0x31, 0x05], ms(0)), 0x7F, "session before length");
    ask(&mut s, &[0x10, 0x03], ms(0));
    assert_eq!(nrc(&mut s, &[0x31, 0x05], ms(0)), 0x13, "length before sub-function");
    assert_eq!(nrc(&mut s, &[0x31, 0x01, 0xC1], ms(0)), 0x13);
    assert_eq!(nrc(&mut s, &[0x31, 0x05, 0xC1, 0x00], ms(0)), 0x12);
    assert_eq!(nrc(&mut s, &[0x31, 0x02, 0xC1, 0x00], ms(0)), 0x12, "stop not supported");
    assert_eq!(nrc(&mut s, &[0x31, 0x01, 0x12, 0x34], ms(0)), 0x31, "RID before security");
    assert_eq!(nrc(&mut s, &[0x31, 0x01, 0xC1, 0x00], ms(0)), 0x33);
    assert_eq!(nrc(&mut s, &[0x31, 0x01, 0xC1, 0x00, 0xFF], ms(0)), 0x33, "security before length");
    unlock(&mut s, ms(0));
    assert_eq!(nrc(&mut s, &[0x31, 0x01, 0xC1, 0x00, 0xFF], ms(0)), 0x13);
    assert_eq!(nrc(&mut s, &[0x31, 0x03, 0xC1, 0x00], ms(0)), 0x24, "no run yet");
    assert_eq!(nrc(&mut s, &[0x31, 0x03, 0xC1, 0x01], ms(0)), 0x12, "rollback has no results");
    s.backend_mut().refuse_start = true;
    assert_eq!(nrc(&mut s, &[0x31, 0x01, 0xC1, 0x00], ms(0)), 0x22);
}

#[test]
fn calibration_answers_pending_then_final() {
    let mut backend = FakeBackend::calibrated();
    backend.run_polls = 300; // 3 s at the 10 ms check interval
    let mut s = server(backend);
    unlock(&mut s, ms(0));
    assert_eq!(ask(&mut s, &[0x31, 0x01, 0xC1, 0x00], ms(100)).unwrap(), [0x7F, 0x31, 0x78]);
    assert!(s.is_pending());
    // Another request while the routine runs.
    assert_eq!(nrc(&mut s, &[0x3E, 0x00], ms(150)), 0x21);
    let mut now = ms(100);
    let mut pendings = vec![];
    let final_response = loop {
        now = s.poll_at().unwrap().max(now);
        if let Some(r) = s.poll(now) {
            if r[..] == [0x7F, 0x31, 0x78] {
                pendings.push(now);
                continue;
            }
            break r.to_vec();
        }
        assert!(now < ms(10_000), "calibration never finished");
    };
    // 0x78 repeated every 2 s (well inside P2* = 5 s); no S3 fallback meanwhile.
    assert_eq!(pendings, [ms(2100)]);
    assert_eq!(final_response, [0x71, 0x01, 0xC1, 0x00, 0x04, 0, 0, 0, 8]);
    assert!(s.is_unlocked());
    let r = ask(&mut s, &[0x31, 0x03, 0xC1, 0x00], now).unwrap();
    assert_eq!(
        Outcome::parse(&r[4..]).unwrap(),
        Outcome { state: DaemonState::Accepted, generation: 8 }
    );
    // Suppressed start: the 0x78 cancels the suppression, the final answer comes.
    assert_eq!(ask(&mut s, &[0x31, 0x81, 0xC1, 0x00], now).unwrap(), [0x7F, 0x31, 0x78]);
    let mut t = now;
    let r = loop {
        t = s.poll_at().unwrap().max(t);
        if let Some(r) = s.poll(t) {
            if r[2] != 0x78 {
                break r;
            }
        }
    };
    assert_eq!(r[..5], [0x71, 0x01, 0xC1, 0x00, 0x04]);
    // Roll back: 9 → 8; suppressed variant answers nothing but acts.
    assert_eq!(
        ask(&mut s, &[0x31, 0x01, 0xC1, 0x01], t).unwrap(),
        [0x71, 0x01, 0xC1, 0x01, 0, 0, 0, 8]
    );
    assert_eq!(ask(&mut s, &[0x31, 0x81, 0xC1, 0x01], t), None);
    assert_eq!(s.backend().state.generation, 7);
}

#[test]
fn response_repr_parses_both_kinds() {
    assert_eq!(
        ResponseRepr::parse(&[0x7F, 0x22, 0x31]),
        Some(ResponseRepr::Negative { service: 0x22, nrc: 0x31 })
    );
    assert_eq!(
        ResponseRepr::parse(&[0x62, 0xC0, 0x01]),
        Some(ResponseRepr::Positive { service: 0x22, data: &[0xC0, 0x01] })
    );
    assert_eq!(ResponseRepr::parse(&[0x7F, 0x22]), None);
    assert_eq!(ResponseRepr::parse(&[0x22]), None);
    assert_eq!(ResponseRepr::parse(&[]), None);
    assert_eq!(Nrc::from_u8(0x36), Some(Nrc::ExceededNumberOfAttempts));
    assert_eq!(Nrc::InvalidKey.to_string(), "invalidKey (0x35)");
}

#[test]
fn request_repr_both_ways() {
    let dids = heapless::Vec::from_slice(&[0xC001, 0xC004]).unwrap();
    let cases: [(RequestRepr, &[u8]); 6] = [
        (RequestRepr::SessionControl { session: Session::Extended, suppress: true }, &[0x10, 0x83]),
        (RequestRepr::TesterPresent { suppress: false }, &[0x3E, 0x00]),
        (RequestRepr::RequestSeed { suppress: false }, &[0x27, 0x01]),
        (RequestRepr::ReadData { dids }, &[0x22, 0xC0, 0x01, 0xC0, 0x04]),
        (
            RequestRepr::RoutineControl { sub: 0x01, routine: 0xC101, suppress: false },
            &[0x31, 0x01, 0xC1, 0x01],
        ),
        (
            RequestRepr::SendKey { key: [7; 16], suppress: false },
            &[0x27, 0x02, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7, 7],
        ),
    ];
    for (repr, bytes) in cases {
        let mut buf = [0u8; 32];
        let n = repr.emit(&mut buf).unwrap();
        assert_eq!(&buf[..n], bytes);
        assert_eq!(n, repr.buffer_len());
        assert_eq!(RequestRepr::parse(bytes), Ok(repr));
    }
    assert_eq!(RequestRepr::parse(&[]), Err(Nrc::IncorrectMessageLengthOrInvalidFormat));
    assert_eq!(RequestRepr::parse(&[0x11, 0x01]), Err(Nrc::ServiceNotSupported));
    assert_eq!(RequestRepr::parse(&[0x10, 0x02]), Err(Nrc::SubFunctionNotSupported));
    assert_eq!(RequestRepr::parse(&[0x22, 0xC0]), Err(Nrc::IncorrectMessageLengthOrInvalidFormat));
    assert_eq!(
        RequestRepr::parse(&[0x31, 0x01, 0xC1]),
        Err(Nrc::IncorrectMessageLengthOrInvalidFormat)
    );
    assert!(RequestRepr::SendKey { key: [0; 16], suppress: false }.emit(&mut [0u8; 17]).is_none());
}

#[test]
fn records_reject_malformed_bytes() {
    assert!(StateRecord::parse(&[0, 0, 0, 0, 1, 0, 0, 0]).is_err());
    assert!(StateRecord::parse(&[7, 0, 0, 0, 1, 0, 0, 0, 0]).is_err(), "state 7");
    assert!(StateRecord::parse(&[0; 10]).is_err(), "trailing byte");
    assert!(IntrinsicsRecord::parse(&[0; 17]).is_err());
    let mut b = vec![2u8];
    b.extend([0; 17]);
    assert!(IntrinsicsRecord::parse(&b).is_err(), "model 2");
    let mut b = vec![0u8; 17];
    b.push(9);
    b.extend([0; 36]);
    assert!(IntrinsicsRecord::parse(&b).is_err(), "9 coefficients");
    let mut b = vec![1u8; 17];
    b.push(2);
    b.extend([0; 7]);
    assert!(IntrinsicsRecord::parse(&b).is_err(), "coefficients truncated");
    assert!(ExtrinsicRecord::parse(&[0; 27]).is_err());
    assert!(QualityRecord::parse(&[0; 10]).is_err());
    assert!(Outcome::parse(&[4, 0, 0, 0]).is_err());
}

/// The server's end of the link ([`Link`] + server) and a tester's ISO-TP endpoint, frames
/// moved in memory; time passes only as a test says. Events of the link are kept.
struct Bench {
    client: Box<IsoTp>,
    link: Box<Link>,
    server: TestServer,
    now: Instant,
    events: Vec<(Instant, LinkEvent)>,
}

impl Bench {
    fn new() -> Self {
        Bench {
            client: Box::new(IsoTp::new(Config::new(0x7A0, 0x7A8))),
            link: Box::new(Link::new(Config::new(0x7A8, 0x7A0))),
            server: server(FakeBackend::calibrated()),
            now: Instant::from_micros(0),
            events: Vec::new(),
        }
    }

    fn note(&mut self, ev: Option<LinkEvent>) {
        self.events.extend(ev.map(|ev| (self.now, ev)));
    }

    /// Runs the link's timers at `now` and takes every frame it has for the bus.
    fn server_frames(&mut self) -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        loop {
            while let Some(ev) = self.link.poll(&mut self.server, self.now) {
                self.events.push((self.now, ev));
            }
            let Some(f) = self.link.poll_transmit(self.now) else {
                return out;
            };
            assert_eq!(f.id, 0x7A8);
            let ev = self.link.frame_sent(self.now);
            self.note(ev);
            out.push(f.data.to_vec());
        }
    }

    /// One frame from a tester to the server at `now`; the frames the server sends back.
    fn tester_sends(&mut self, data: &[u8]) -> Vec<Vec<u8>> {
        let f = CanFrame::new_standard(0x7A0, data).unwrap();
        let ev = self.link.on_frame(&mut self.server, &f, self.now);
        self.note(ev);
        self.server_frames()
    }

    /// A well-behaved tester's request: its ISO-TP endpoint sees only what the server
    /// sends after it; the message it receives (`None`: nothing within 10 ms).
    fn request(&mut self, req: &[u8]) -> Option<Vec<u8>> {
        self.client.send(req).unwrap();
        for _ in 0..1000 {
            self.now = self.now + Duration::from_micros(10);
            while let Some(f) = self.client.poll_transmit(self.now) {
                self.client.frame_sent(self.now);
                let ev = self.link.on_frame(&mut self.server, &f, self.now);
                self.note(ev);
            }
            for data in self.server_frames() {
                let f = CanFrame::new_standard(0x7A8, &data).unwrap();
                if let Some(Event::Received(_)) = self.client.on_frame(&f, self.now) {
                    return Some(self.client.received().to_vec());
                }
            }
        }
        None
    }

    fn abandoned(&self, why: Abandoned) -> usize {
        let hit =
            |ev: &LinkEvent| matches!(ev, LinkEvent::ResponseAbandoned { why: w, .. } if *w == why);
        self.events.iter().filter(|(_, ev)| hit(ev)).count()
    }
}

#[test]
fn flood_of_requests_through_isotp_and_server() {
    let mut bench = Bench::new();
    let requests: [&[u8]; 4] = [
        &[0x22, 0xC0, 0x02],
        &[0x3E, 0x00],
        &[0x22, 0xC0, 0x01, 0xC0, 0x03, 0xC0, 0x04],
        &[0x22, 0xF1, 0x90],
    ];
    let start = std::time::Instant::now();
    let mut bytes = 0usize;
    for i in 0..10_000 {
        let req = requests[i % requests.len()];
        let r = bench.request(req).unwrap();
        match i % 4 {
            0 => assert_eq!(r.len(), 3 + 18 + 20),
            1 => assert_eq!(r, [0x7E, 0x00]),
            2 => assert_eq!(r.len(), 1 + 11 + 30 + 11),
            _ => assert_eq!(r, [0x7F, 0x22, 0x31]),
        }
        bytes += r.len();
    }
    let dt = start.elapsed();
    println!(
        "10000 UDS requests through ISO-TP + server in {:.1} ms: {:.0} requests/s ({bytes} response bytes)",
        dt.as_secs_f64() * 1e3,
        10_000.0 / dt.as_secs_f64()
    );
}

/// The flood at the protocol level, time passed in: 1000 reads whose segmented
/// answers never get flow control, each followed by the first frame of a request never
/// finished. Each read is answered at once with its own first frame (the older answer is
/// abandoned, not queued); the tester that comes next gets its own answer to every DID;
/// the abandoned answers, warned through the throttle, make one line and, a second
/// later, one with the count of the others.
#[test]
fn link_answers_each_request_itself_through_1000_unanswered_answers_and_unfinished_requests() {
    let mut b = Bench::new();
    for i in 0..1000u32 {
        let did = 1 + (i % 4) as u8;
        b.now = b.now + Duration::from_micros(100);
        let out = b.tester_sends(&[0x03, 0x22, 0xC0, did]);
        assert_eq!(out.len(), 1, "read {i}: one first frame at once");
        assert_eq!((out[0][0], &out[0][2..5]), (0x10, &[0x62, 0xC0, did][..]), "read {i}: its own");
        b.now = b.now + Duration::from_micros(100);
        let out = b.tester_sends(&[0x10, 0x0A, 0x22, 0xC0, 0x01, 0xC0, 0x02, 0xC0]);
        assert_eq!(out, [vec![0x30, 0, 0, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]], "unfinished request {i}");
    }
    assert_eq!(b.abandoned(Abandoned::Superseded), 999, "each answer gave way to the next");
    let flood_end = b.now;
    for did in [0x01, 0x02, 0x03, 0x04, 0x01] {
        let r = b.request(&[0x22, 0xC0, did]).expect("answered");
        assert_eq!(r[..3], [0x62, 0xC0, did], "DID 0xC0{did:02X}: its own answer");
    }
    let took = b.now.saturating_since(flood_end);
    assert!(took < Duration::from_millis(1), "five reads took {took:?}");
    assert_eq!(b.abandoned(Abandoned::Superseded), 1000, "the flood's last answer too");
    assert_eq!(b.events.len(), 1000, "{:?}", &b.events[990..]);

    let mut throttle = WarnThrottle::<Instant>::default();
    let lines: Vec<u64> = b.events.iter().filter_map(|(t, _)| throttle.allow(*t)).collect();
    assert_eq!(lines, [0], "0.2 s of abandoned answers: one warning line");
    let first = b.events[0].0;
    assert_eq!(throttle.flush_at(), Some(first + WarnThrottle::<Instant>::INTERVAL));
    assert_eq!(throttle.flush(first + Duration::from_millis(999)), None);
    assert_eq!(throttle.flush(first + Duration::from_secs(1)), Some(999), "then the rest, counted");
    assert_eq!((throttle.flush_at(), throttle.flush(first + Duration::from_secs(9))), (None, None));
}

/// N_Bs and N_Cr at the link, to the microsecond: an answer whose flow control never
/// comes is abandoned at N_Bs after its first frame, a request whose consecutive frames
/// never come at N_Cr after our flow control; then nothing is in progress and late flow
/// control or consecutive frames are ignored.
#[test]
fn link_abandons_an_answer_at_n_bs_and_an_unfinished_request_at_n_cr() {
    let mut b = Bench::new();
    let cfg = Config::new(0x7A8, 0x7A0);
    let t0 = Instant::from_millis(5);
    b.now = t0;
    assert_eq!(b.tester_sends(&[0x03, 0x22, 0xC0, 0x02])[0][..2], [0x10, 41]);
    let t1 = t0 + Duration::from_millis(10);
    b.now = t1;
    assert_eq!(b.tester_sends(&[0x10, 0x0A, 0x22, 0xC0, 0x01, 0xC0, 0x02, 0xC0])[0][0], 0x30);
    assert_eq!(b.link.poll_at(&b.server), Some(t0 + cfg.n_bs));
    b.now = t0 + (cfg.n_bs - Duration::from_micros(1));
    assert!(b.server_frames().is_empty() && b.events.is_empty());
    b.now = t0 + cfg.n_bs;
    assert!(b.server_frames().is_empty());
    let timeout =
        LinkEvent::ResponseAbandoned { service: 0x22, why: Abandoned::Transport(TxError::Timeout) };
    assert_eq!(b.events, [(t0 + cfg.n_bs, timeout)]);
    assert_eq!(b.link.poll_at(&b.server), Some(t1 + cfg.n_cr));
    b.now = t1 + (cfg.n_cr - Duration::from_micros(1));
    assert!(b.server_frames().is_empty() && b.events.len() == 1);
    b.now = t1 + cfg.n_cr;
    assert!(b.server_frames().is_empty());
    assert_eq!(b.events[1], (t1 + cfg.n_cr, LinkEvent::RequestAborted(RxError::Timeout)));
    assert_eq!(b.link.poll_at(&b.server), None, "nothing in progress");
    assert!(b.tester_sends(&[0x30, 0, 0]).is_empty(), "late flow control: no consecutive frame");
    assert!(b.tester_sends(&[0x21, 0xC0, 0x03, 0, 0, 0, 0, 0]).is_empty());
    assert_eq!(b.events.len(), 2);
    assert_eq!(b.request(&[0x3E, 0x00]).unwrap(), [0x7E, 0x00]);
}

/// A request whose answer is suppressed does not disturb the answer being sent; one
/// whose answer is not abandons it (reported), and the flow control that follows
/// continues the new answer only.
#[test]
fn only_a_newer_answer_takes_the_link() {
    let mut b = Bench::new();
    assert_eq!(b.tester_sends(&[0x03, 0x22, 0xC0, 0x02])[0][..5], [0x10, 41, 0x62, 0xC0, 0x02]);
    assert!(b.tester_sends(&[0x02, 0x3E, 0x80]).is_empty(), "TesterPresent, suppressed");
    let cfs = b.tester_sends(&[0x30, 0, 0]);
    assert_eq!(cfs.len(), 5, "the read's answer carries on");
    assert_eq!(b.tester_sends(&[0x03, 0x22, 0xC0, 0x03])[0][..5], [0x10, 31, 0x62, 0xC0, 0x03]);
    let out = b.tester_sends(&[0x02, 0x3E, 0x00]);
    assert_eq!(out, [vec![0x02, 0x7E, 0x00, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]]);
    let superseded = LinkEvent::ResponseAbandoned { service: 0x22, why: Abandoned::Superseded };
    assert_eq!(b.events, [(b.now, superseded)]);
    assert!(b.tester_sends(&[0x30, 0, 0]).is_empty(), "no flow control continues an old answer");
}

/// The response's data after the echoed DID, asserting the DID.
fn data(s: &mut TestServer, did: u16) -> Vec<u8> {
    let [hi, lo] = did.to_be_bytes();
    let r = ask(s, &[0x22, hi, lo], ms(0)).unwrap();
    assert_eq!(r[..3], [0x62, hi, lo], "DID 0x{did:04X}");
    r[3..].to_vec()
}

#[test]
fn sensor_dids_of_the_one_pair_rig() {
    let mut s = server(FakeBackend::calibrated());
    // 0xC010: two sensors, camera "camera" (kind 0) and LiDAR "lidar" (kind 1).
    let mut want = vec![2, 0, 6];
    want.extend(b"camera");
    want.extend([1, 5]);
    want.extend(b"lidar");
    assert_eq!(data(&mut s, 0xC010), want);
    assert_eq!(SensorTable::parse(&want).unwrap(), SensorTable::one_pair(true));
    // Camera 0's intrinsics are 0xC002's; sensor 1's extrinsic is 0xC003's; the first
    // camera's own is the identity (w = 1.0 = 0x3F800000).
    assert_eq!(data(&mut s, 0xC200), data(&mut s, 0xC002));
    assert_eq!(data(&mut s, 0xC301), data(&mut s, 0xC003));
    let mut identity = vec![0x3F, 0x80, 0, 0];
    identity.extend([0u8; 24]);
    assert_eq!(data(&mut s, 0xC300), identity);
    // The LiDAR has no intrinsics, there is no sensor 2, and 0xC208 is past the most
    // sensors: requestOutOfRange, as for any DID not served.
    for did in [0xC201u16, 0xC202, 0xC302, 0xC208, 0xC2FF, 0xC3FF] {
        let [hi, lo] = did.to_be_bytes();
        assert_eq!(nrc(&mut s, &[0x22, hi, lo], ms(0)), 0x31, "DID 0x{did:04X}");
    }
    // Among served DIDs, one not served is left out.
    let r = ask(&mut s, &[0x22, 0xC2, 0x01, 0xC3, 0x00], ms(0)).unwrap();
    assert_eq!(r[1..3], [0xC3, 0x00]);
    assert_eq!(r.len(), 3 + ExtrinsicRecord::LEN);
    // Before the first calibration: the camera's intrinsics are not available (0x22).
    let mut s = server(FakeBackend::empty());
    assert_eq!(nrc(&mut s, &[0x22, 0xC2, 0x00], ms(0)), 0x22);
    assert_eq!(nrc(&mut s, &[0x22, 0xC3, 0x01], ms(0)), 0x22);
}

#[test]
fn sensor_dids_of_a_four_sensor_rig() {
    let mut s = server(FakeBackend::rig());
    let table = SensorTable::parse(&data(&mut s, 0xC010)).unwrap();
    let names: Vec<_> = table.sensors.iter().map(|e| (e.kind, e.name.as_str())).collect();
    assert_eq!(
        names,
        [
            (SensorKind::Camera, "front"),
            (SensorKind::Camera, "wide"),
            (SensorKind::Lidar, "top"),
            (SensorKind::Lidar, "bumper")
        ]
    );
    assert_eq!(
        table.to_string(),
        "0: front (camera)\n1: wide (camera)\n2: top (LiDAR)\n3: bumper (LiDAR)"
    );
    let wide = IntrinsicsRecord::parse(&data(&mut s, 0xC201)).unwrap();
    assert_eq!((wide.fx, wide.fy), (600.0, 600.25));
    let side = ExtrinsicRecord::parse(&data(&mut s, 0xC301)).unwrap();
    assert_eq!(side.translation, [0.4, 0.0, 0.1]);
    assert_eq!(data(&mut s, 0xC302), data(&mut s, 0xC003));
    // LiDARs have no intrinsics; the bumper LiDAR is not calibrated yet.
    assert_eq!(nrc(&mut s, &[0x22, 0xC2, 0x02], ms(0)), 0x31);
    assert_eq!(nrc(&mut s, &[0x22, 0xC3, 0x03], ms(0)), 0x22);
    assert_eq!(nrc(&mut s, &[0x22, 0xC3, 0x04], ms(0)), 0x31);
}

#[test]
fn sensor_table_bytes_both_ways_and_malformed() {
    let mut table = SensorTable::default();
    table.push(SensorKind::Lidar, "roof-2").unwrap();
    let mut buf = [0u8; 16];
    let n = table.emit(&mut buf).unwrap();
    assert_eq!(buf[..n], [1, 1, 6, b'r', b'o', b'o', b'f', b'-', b'2']);
    assert_eq!(n, table.buffer_len());
    assert_eq!(SensorTable::parse(&buf[..n]).unwrap(), table);
    assert!(table.emit(&mut buf[..5]).is_none(), "too short a buffer");
    let bad = |bytes: &[u8]| SensorTable::parse(bytes).unwrap_err();
    assert_eq!(bad(&[17]), DecodeError::BadValue("sensor count"));
    assert_eq!(bad(&[1, 2, 1, b'a']), DecodeError::BadValue("sensor kind"));
    assert_eq!(bad(&[1, 0, 1, b'A']), DecodeError::BadValue("sensor name"));
    assert_eq!(bad(&[1, 0, 0]), DecodeError::BadValue("sensor name"));
    assert_eq!(bad(&[1, 0, 1, 0xFF]), DecodeError::BadValue("sensor name"));
    assert!(matches!(bad(&[1, 0, 3, b'a']), DecodeError::Truncated { .. }));
    assert!(matches!(bad(&[0, 0]), DecodeError::TrailingBytes { .. }));
    assert_eq!(table.push(SensorKind::Camera, "Front"), Err(DecodeError::BadValue("sensor name")));
    let long = "a".repeat(MAX_SENSOR_NAME + 1);
    assert_eq!(table.push(SensorKind::Camera, &long), Err(DecodeError::BadValue("sensor name")));
    assert_eq!(table.index_of("roof-2"), Some(0));
    assert_eq!(table.index_of("roof"), None);
}

#[test]
fn sensor_tables_fit_a_response_up_to_one_isotp_message() {
    // A full table (16 sensors of 32-byte names, 545 bytes) seven times in one request fits
    // one ISO-TP message; eight times (4377 bytes) does not: 0x14, the one such request.
    let mut backend = FakeBackend::rig();
    let rig = backend.rig.as_mut().unwrap();
    rig.sensors = SensorTable::default();
    for i in 0..MAX_SENSORS {
        let name = format!("{i:02}{}", "x".repeat(MAX_SENSOR_NAME - 2));
        rig.sensors.push(SensorKind::Camera, &name).unwrap();
    }
    assert!(rig.sensors.push(SensorKind::Camera, "seventeenth").is_err(), "the table is full");
    let mut s = server(backend);
    let seven: Vec<u8> = std::iter::once(0x22).chain([0xC0, 0x10].repeat(7)).collect();
    let r = ask(&mut s, &seven, ms(0)).unwrap();
    let one = 1 + MAX_SENSORS * (2 + MAX_SENSOR_NAME);
    assert_eq!((MAX_SENSORS, one), (16, 545));
    assert_eq!(r.len(), 1 + 7 * (2 + one));
    let eight: Vec<u8> = std::iter::once(0x22).chain([0xC0, 0x10].repeat(8)).collect();
    assert_eq!(nrc(&mut s, &eight, ms(0)), 0x14);
    let table = SensorTable::parse(&r[3..3 + one]).unwrap();
    assert_eq!(table.sensors.len(), MAX_SENSORS);
}
