//! Fuzzes the ISO-TP frame parser and endpoint: arbitrary bytes become a sequence of
//! CAN frames (a length byte, then up to 8 data bytes) fed to an endpoint that is also
//! sending, with time advancing; nothing may panic and parse/emit must round-trip.
#![no_main]

use libfuzzer_sys::fuzz_target;
use roomcal::service::isotp::{Config, IsoTp, PduRepr};
use roomcal::service::{CanFrame, Instant};

fuzz_target!(|data: &[u8]| {
    let mut tp: IsoTp<256> = IsoTp::new(Config::new(0x7A8, 0x7A0));
    let _ = tp.send(&[0x5A; 100]);
    let mut rest = data;
    let mut now = 0u64;
    while let Some((&head, tail)) = rest.split_first() {
        let len = usize::from(head & 0x0F).min(8).min(tail.len());
        let (bytes, tail) = tail.split_at(len);
        rest = tail;
        // Parsed frames emit back to the same bytes (up to padding).
        if let Ok(repr) = PduRepr::parse(bytes) {
            let mut buf = [0u8; 8];
            let n = repr.emit(&mut buf);
            assert!(n <= bytes.len());
            if !matches!(repr, PduRepr::Consecutive { .. } | PduRepr::First { .. }) {
                assert_eq!(&buf[..n], &bytes[..n]);
            }
        }
        now += u64::from(head >> 4) * 100_000;
        let t = Instant::from_micros(now);
        let id = if head & 0x80 != 0 { 0x7A0 } else { 0x7A1 };
        if let Some(frame) = CanFrame::new_standard(id, bytes) {
            let _ = tp.on_frame(&frame, t);
        }
        while tp.poll_transmit(t).is_some() {
            let _ = tp.frame_sent(t);
        }
        let _ = tp.poll(t);
        assert!(tp.received().len() <= 256);
    }
});
