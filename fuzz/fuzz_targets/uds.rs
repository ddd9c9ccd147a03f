//! Fuzzes the UDS server and record parsers: arbitrary bytes become a sequence of
//! requests (a length byte, then the request) handled at advancing times by a server
//! with the fake backend (one pair, or a four-sensor rig when the first byte is odd);
//! nothing may panic and every response must be well-formed. A sensor table that parses
//! emits back to the same bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use roomcal::service::fake::FakeBackend;
use roomcal::service::uds::{
    ExtrinsicRecord, IntrinsicsRecord, Outcome, QualityRecord, RequestRepr, ResponseRepr,
    SensorTable, Server, ServerConfig, StateRecord, SEED_LEN,
};
use roomcal::service::Instant;

fuzz_target!(|data: &[u8]| {
    let _ = StateRecord::parse(data);
    let _ = IntrinsicsRecord::parse(data);
    let _ = ExtrinsicRecord::parse(data);
    let _ = QualityRecord::parse(data);
    let _ = Outcome::parse(data);
    let _ = ResponseRepr::parse(data);
    if let Ok(table) = SensorTable::parse(data) {
        let mut buf = [0u8; 1024];
        let n = table.emit(&mut buf).expect("fits");
        assert_eq!(&buf[..n], data);
    }
    // Requests that parse emit back to the same bytes.
    if let Ok(req) = RequestRepr::parse(data) {
        let mut buf = [0u8; 64];
        let n = req.emit(&mut buf).expect("fits");
        assert_eq!(&buf[..n], data);
    }

    let seeds = |s: &mut [u8; SEED_LEN]| *s = [0xA5; SEED_LEN];
    let backend = match data.first() {
        Some(b) if b & 1 == 1 => FakeBackend::rig(),
        _ => FakeBackend::calibrated(),
    };
    let mut server = Server::new(backend, seeds, b"fuzz", ServerConfig::default());
    let mut rest = data;
    let mut now = 0u64;
    while let Some((&head, tail)) = rest.split_first() {
        let len = usize::from(head & 0x1F).min(tail.len());
        let (req, tail) = tail.split_at(len);
        rest = tail;
        now += u64::from(head >> 5) * 700_000;
        let t = Instant::from_micros(now);
        for r in server.handle(req, t).into_iter().chain(server.poll(t)) {
            assert!(ResponseRepr::parse(&r).is_some(), "malformed response {r:02X?}");
        }
    }
});
