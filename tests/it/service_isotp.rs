//! ISO-TP (ISO 15765-2) endpoint tests: byte vectors both ways (frames in → message,
//! message → frames), flow control, block size, STmin, timeouts, malformed input, abandoning
//! a transmission.

use core::time::Duration;

use proptest::prelude::*;
use roomcal::service::isotp::{Config, Event, FlowStatus, IsoTp, PduRepr, RxError, StMin, TxError};
use roomcal::service::{CanFrame, Instant};

const TX: u32 = 0x7A8;
const RX: u32 = 0x7A0;

fn ms(t: u64) -> Instant {
    Instant::from_millis(t)
}

fn frame(id: u32, data: &[u8]) -> CanFrame {
    CanFrame::new_standard(id, data).unwrap()
}

/// Takes the next frame and confirms it sent at the same instant.
fn transmit<const N: usize>(tp: &mut IsoTp<N>, now: Instant) -> Option<(Vec<u8>, Option<Event>)> {
    let f = tp.poll_transmit(now)?;
    assert_eq!(f.id, tp.config().tx_id);
    let ev = tp.frame_sent(now);
    Some((f.data.to_vec(), ev))
}

#[test]
fn single_frame_both_ways() {
    let mut tp: IsoTp = IsoTp::new(Config::new(TX, RX));
    tp.send(&[0x62, 0xC0, 0x01]).unwrap();
    let (bytes, ev) = transmit(&mut tp, ms(0)).unwrap();
    assert_eq!(bytes, [0x03, 0x62, 0xC0, 0x01, 0xCC, 0xCC, 0xCC, 0xCC]);
    assert_eq!(ev, Some(Event::Sent));
    assert!(tp.poll_transmit(ms(0)).is_none());

    // Padding off: the frame is as short as its data.
    let mut cfg = Config::new(TX, RX);
    cfg.padding = None;
    let mut tp: IsoTp = IsoTp::new(cfg);
    tp.send(&[0x3E, 0x00]).unwrap();
    assert_eq!(transmit(&mut tp, ms(0)).unwrap().0, [0x02, 0x3E, 0x00]);

    // Frames in: padded and unpadded single frames, other IDs ignored.
    let ev = tp.on_frame(&frame(RX, &[0x03, 0x22, 0xC0, 0x01, 0xAA, 0xAA, 0xAA, 0xAA]), ms(1));
    assert_eq!(ev, Some(Event::Received(3)));
    assert_eq!(tp.received(), [0x22, 0xC0, 0x01]);
    assert_eq!(tp.on_frame(&frame(RX, &[0x02, 0x10, 0x03]), ms(1)), Some(Event::Received(2)));
    assert_eq!(tp.received(), [0x10, 0x03]);
    assert_eq!(tp.on_frame(&frame(0x123, &[0x02, 0x10, 0x01]), ms(1)), None);
    assert_eq!(tp.on_frame(&CanFrame::new_extended(RX, &[0x02, 0x10, 0x01]).unwrap(), ms(1)), None);
    assert_eq!(tp.received(), [0x10, 0x03]);
}

#[test]
fn segmented_message_out() {
    let msg: Vec<u8> = (0..25).collect();
    let mut tp: IsoTp = IsoTp::new(Config::new(TX, RX));
    tp.send(&msg).unwrap();
    assert_eq!(tp.send(&msg), Err(TxError::Busy));
    let (ff, ev) = transmit(&mut tp, ms(0)).unwrap();
    assert_eq!(ff, [0x10, 25, 0, 1, 2, 3, 4, 5]);
    assert_eq!(ev, None);
    // Nothing more until flow control arrives.
    assert!(tp.poll_transmit(ms(1)).is_none());
    assert_eq!(tp.poll_at(), Some(ms(1000)), "N_Bs deadline");
    assert_eq!(tp.on_frame(&frame(RX, &[0x30, 0x00, 0x00]), ms(2)), None);
    let (cf1, _) = transmit(&mut tp, ms(2)).unwrap();
    let (cf2, _) = transmit(&mut tp, ms(2)).unwrap();
    let (cf3, ev) = transmit(&mut tp, ms(2)).unwrap();
    assert_eq!(cf1, [0x21, 6, 7, 8, 9, 10, 11, 12]);
    assert_eq!(cf2, [0x22, 13, 14, 15, 16, 17, 18, 19]);
    assert_eq!(cf3, [0x23, 20, 21, 22, 23, 24, 0xCC, 0xCC]);
    assert_eq!(ev, Some(Event::Sent));
    assert!(!tp.is_sending());
}

#[test]
fn segmented_message_in_with_block_size() {
    let mut cfg = Config::new(TX, RX);
    cfg.block_size = 2;
    cfg.st_min = StMin(0x05);
    let mut tp: IsoTp = IsoTp::new(cfg);
    assert_eq!(tp.on_frame(&frame(RX, &[0x10, 25, 0, 1, 2, 3, 4, 5]), ms(0)), None);
    let (fc, _) = transmit(&mut tp, ms(0)).unwrap();
    assert_eq!(fc, [0x30, 0x02, 0x05, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC]);
    assert_eq!(tp.on_frame(&frame(RX, &[0x21, 6, 7, 8, 9, 10, 11, 12]), ms(1)), None);
    assert!(tp.poll_transmit(ms(1)).is_none(), "no flow control inside a block");
    assert_eq!(tp.on_frame(&frame(RX, &[0x22, 13, 14, 15, 16, 17, 18, 19]), ms(2)), None);
    let (fc, _) = transmit(&mut tp, ms(2)).unwrap();
    assert_eq!(fc[..3], [0x30, 0x02, 0x05]);
    // Last frame unpadded (padding is the sender's choice).
    let ev = tp.on_frame(&frame(RX, &[0x23, 20, 21, 22, 23, 24]), ms(3));
    assert_eq!(ev, Some(Event::Received(25)));
    assert_eq!(tp.received(), (0..25).collect::<Vec<u8>>());
}

#[test]
fn st_min_values() {
    assert_eq!(StMin(0x00).duration(), Duration::ZERO);
    assert_eq!(StMin(0x7F).duration(), Duration::from_millis(127));
    assert_eq!(StMin(0xF1).duration(), Duration::from_micros(100));
    assert_eq!(StMin(0xF9).duration(), Duration::from_micros(900));
    // Reserved values mean the longest STmin.
    for reserved in [0x80, 0xF0, 0xFA, 0xFF] {
        assert_eq!(StMin(reserved).duration(), Duration::from_millis(127));
    }
    assert_eq!(StMin::from_duration(Duration::from_micros(250)), StMin(0xF3));
    assert_eq!(StMin::from_duration(Duration::from_micros(1500)), StMin(2));
    assert_eq!(StMin::from_duration(Duration::from_secs(1)), StMin(0x7F));
    for b in (0x00..=0x7F).chain(0xF1..=0xF9) {
        assert_eq!(StMin::from_duration(StMin(b).duration()), StMin(b), "{b:#x}");
    }
}

/// Sends a 40-byte message against the given flow control; returns the instants at
/// which consecutive frames went out.
fn cf_times(fc: [u8; 3]) -> Vec<Instant> {
    let mut tp: IsoTp = IsoTp::new(Config::new(TX, RX));
    tp.send(&[0x55; 40]).unwrap();
    transmit(&mut tp, Instant::from_micros(0)).unwrap();
    tp.on_frame(&frame(RX, &fc), Instant::from_micros(0));
    let mut times = Vec::new();
    let mut now = Instant::from_micros(0);
    while tp.is_sending() && now < ms(100) {
        while let Some((bytes, _)) = transmit(&mut tp, now) {
            assert_eq!(bytes[0] >> 4, 2);
            times.push(now);
        }
        now = now + Duration::from_micros(50);
    }
    times
}

#[test]
fn st_min_honoured_when_sending() {
    let t = cf_times([0x30, 0x00, 0x0A]); // 10 ms
    assert_eq!(t.len(), 5, "40 bytes: first frame + 5 consecutive frames");
    for w in t.windows(2) {
        assert_eq!(w[1].saturating_since(w[0]), Duration::from_millis(10));
    }
    let t = cf_times([0x30, 0x00, 0xF5]); // 500 µs
    for w in t.windows(2) {
        assert_eq!(w[1].saturating_since(w[0]), Duration::from_micros(500));
    }
    let t = cf_times([0x30, 0x00, 0x00]);
    assert!(t.iter().all(|&x| x == t[0]), "STmin 0: back to back");
}

#[test]
fn block_size_honoured_when_sending() {
    let mut tp: IsoTp = IsoTp::new(Config::new(TX, RX));
    tp.send(&[0x11; 40]).unwrap(); // FF + 5 CFs
    transmit(&mut tp, ms(0)).unwrap();
    tp.on_frame(&frame(RX, &[0x30, 0x02, 0x00]), ms(1));
    assert_eq!(transmit(&mut tp, ms(1)).unwrap().0[0], 0x21);
    assert_eq!(transmit(&mut tp, ms(1)).unwrap().0[0], 0x22);
    assert!(tp.poll_transmit(ms(1)).is_none(), "block of 2 done: wait for flow control");
    assert_eq!(tp.poll_at(), Some(ms(1001)));
    tp.on_frame(&frame(RX, &[0x30, 0x00, 0x00]), ms(5));
    assert_eq!(transmit(&mut tp, ms(5)).unwrap().0[0], 0x23);
    assert_eq!(transmit(&mut tp, ms(5)).unwrap().0[0], 0x24);
    let (last, ev) = transmit(&mut tp, ms(5)).unwrap();
    assert_eq!(last[0], 0x25);
    assert_eq!(ev, Some(Event::Sent));
}

#[test]
fn flow_control_wait_and_overflow() {
    let mut tp: IsoTp = IsoTp::new(Config::new(TX, RX));
    tp.send(&[0; 20]).unwrap();
    transmit(&mut tp, ms(0)).unwrap();
    // Each WAIT restarts N_Bs.
    for i in 1..=10u64 {
        assert_eq!(tp.on_frame(&frame(RX, &[0x31, 0, 0]), ms(900 * i)), None);
        assert_eq!(tp.poll(ms(900 * i + 899)), None);
    }
    assert_eq!(
        tp.on_frame(&frame(RX, &[0x31, 0, 0]), ms(9001)),
        Some(Event::TxAborted(TxError::TooManyWaits))
    );

    tp.send(&[0; 20]).unwrap();
    transmit(&mut tp, ms(0)).unwrap();
    let ev = tp.on_frame(&frame(RX, &[0x32, 0, 0]), ms(1));
    assert_eq!(ev, Some(Event::TxAborted(TxError::Overflow)));
    assert!(!tp.is_sending());

    tp.send(&[0; 20]).unwrap();
    transmit(&mut tp, ms(0)).unwrap();
    let ev = tp.on_frame(&frame(RX, &[0x37, 0, 0]), ms(1));
    assert_eq!(ev, Some(Event::TxAborted(TxError::InvalidFlowStatus(7))));
}

#[test]
fn receiver_overflow_answers_flow_status_overflow() {
    let mut tp: IsoTp<64> = IsoTp::new(Config::new(TX, RX));
    assert_eq!(tp.on_frame(&frame(RX, &[0x10, 100, 0, 0, 0, 0, 0, 0]), ms(0)), None);
    let (fc, _) = transmit(&mut tp, ms(0)).unwrap();
    assert_eq!(fc[..3], [0x32, 0x00, 0x00]);
    assert!(!tp.is_receiving());
    assert_eq!(tp.send(&[0; 65]), Err(TxError::TooLong(65)));
    let mut big: IsoTp = IsoTp::new(Config::new(TX, RX));
    assert_eq!(big.send(&[0; 4096]), Err(TxError::TooLong(4096)));
    assert_eq!(big.send(&[]), Err(TxError::Empty));
}

#[test]
fn wrong_sequence_number_aborts_reception() {
    let mut tp: IsoTp = IsoTp::new(Config::new(TX, RX));
    tp.on_frame(&frame(RX, &[0x10, 20, 0, 1, 2, 3, 4, 5]), ms(0));
    transmit(&mut tp, ms(0)).unwrap();
    let ev = tp.on_frame(&frame(RX, &[0x22, 6, 7, 8, 9, 10, 11, 12]), ms(1));
    assert_eq!(ev, Some(Event::RxAborted(RxError::WrongSequence { expected: 1, got: 2 })));
    assert!(!tp.is_receiving());
    // The rest of that message is now unexpected and ignored.
    assert_eq!(tp.on_frame(&frame(RX, &[0x21, 6, 7, 8, 9, 10, 11, 12]), ms(2)), None);
}

#[test]
fn unexpected_and_malformed_frames_are_ignored() {
    let mut tp: IsoTp = IsoTp::new(Config::new(TX, RX));
    let junk: [&[u8]; 9] = [
        &[],                             // empty
        &[0x21, 1, 2, 3],                // CF while idle
        &[0x30, 0, 0],                   // FC while not sending
        &[0x00, 1, 2],                   // SF_DL 0 (CAN FD escape)
        &[0x08, 1, 2, 3, 4, 5, 6, 7],    // SF_DL 8 on classic CAN
        &[0x05, 1, 2],                   // SF_DL beyond the frame
        &[0x10, 20, 1, 2, 3],            // short first frame
        &[0x10, 0x05, 1, 2, 3, 4, 5, 6], // FF_DL fits a single frame
        &[0x45, 1, 2, 3, 4, 5, 6, 7],    // unknown frame type
    ];
    for j in junk {
        assert_eq!(tp.on_frame(&frame(RX, j), ms(0)), None, "{j:02X?}");
    }
    assert!(!tp.is_receiving() && !tp.is_sending());
    assert!(tp.poll_transmit(ms(0)).is_none(), "no flow control for junk");

    // A CF before our flow control went out is ignored; a short non-final CF too.
    tp.on_frame(&frame(RX, &[0x10, 20, 0, 1, 2, 3, 4, 5]), ms(0));
    assert_eq!(tp.on_frame(&frame(RX, &[0x21, 6, 7, 8, 9, 10, 11, 12]), ms(0)), None);
    transmit(&mut tp, ms(0)).unwrap();
    assert_eq!(tp.on_frame(&frame(RX, &[0x21, 6, 7]), ms(1)), None);
    assert_eq!(tp.on_frame(&frame(RX, &[0x21, 6, 7, 8, 9, 10, 11, 12]), ms(1)), None);
    // A single frame in the middle ends the reception and is delivered.
    assert_eq!(tp.on_frame(&frame(RX, &[0x02, 0x3E, 0x00]), ms(2)), Some(Event::Received(2)));
    assert!(!tp.is_receiving());
}

#[test]
fn timeouts() {
    // N_Bs: no flow control after the first frame.
    let mut tp: IsoTp = IsoTp::new(Config::new(TX, RX));
    tp.send(&[0; 20]).unwrap();
    transmit(&mut tp, ms(0)).unwrap();
    assert_eq!(tp.poll(ms(999)), None);
    assert_eq!(tp.poll(ms(1000)), Some(Event::TxAborted(TxError::Timeout)));
    // N_Cr: no consecutive frame.
    tp.on_frame(&frame(RX, &[0x10, 20, 0, 1, 2, 3, 4, 5]), ms(0));
    transmit(&mut tp, ms(10)).unwrap();
    tp.on_frame(&frame(RX, &[0x21, 6, 7, 8, 9, 10, 11, 12]), ms(20));
    assert_eq!(tp.poll_at(), Some(ms(1020)));
    assert_eq!(tp.poll(ms(1019)), None);
    assert_eq!(tp.poll(ms(1020)), Some(Event::RxAborted(RxError::Timeout)));
    // N_As: a frame handed out but never confirmed.
    tp.send(&[1, 2]).unwrap();
    assert!(tp.poll_transmit(ms(0)).is_some());
    assert!(tp.poll_transmit(ms(1)).is_none(), "one frame in flight at a time");
    assert_eq!(tp.poll(ms(1000)), Some(Event::TxAborted(TxError::NotSent)));
    assert!(!tp.is_sending());
}

#[test]
fn abort_send_drops_the_transmission_only() {
    let mut tp: IsoTp = IsoTp::new(Config::new(TX, RX));
    assert!(!tp.abort_send(), "nothing to abort");
    tp.on_frame(&frame(RX, &[0x10, 20, 0, 1, 2, 3, 4, 5]), ms(0));
    tp.send(&[7; 20]).unwrap();
    assert_eq!(transmit(&mut tp, ms(1)).unwrap().0[0], 0x30, "the flow control we owe first");
    assert_eq!(transmit(&mut tp, ms(1)).unwrap().0[..2], [0x10, 20]);
    assert!(tp.abort_send());
    assert!(!tp.is_sending() && tp.is_receiving());
    assert_eq!(tp.on_frame(&frame(RX, &[0x30, 0, 0]), ms(2)), None);
    assert_eq!(tp.poll_transmit(ms(2)), None, "its flow control continues nothing");
    assert_eq!(tp.poll_at(), Some(ms(1001)), "only the reception's N_Cr is left");
    tp.on_frame(&frame(RX, &[0x21, 6, 7, 8, 9, 10, 11, 12]), ms(3));
    let ev = tp.on_frame(&frame(RX, &[0x22, 13, 14, 15, 16, 17, 18, 19]), ms(4));
    assert_eq!(ev, Some(Event::Received(20)));
    tp.send(&[1, 2, 3]).unwrap();
    assert_eq!(
        transmit(&mut tp, ms(5)).unwrap(),
        (vec![0x03, 1, 2, 3, 0xCC, 0xCC, 0xCC, 0xCC], Some(Event::Sent))
    );
}

#[test]
fn pdu_repr_round_trip() {
    let cases = [
        PduRepr::Single { data: &[1, 2, 3] },
        PduRepr::First { len: 4095, data: &[1, 2, 3, 4, 5, 6] },
        PduRepr::Consecutive { sequence: 15, data: &[9; 7] },
        PduRepr::FlowControl { status: FlowStatus::Wait, block_size: 8, st_min: StMin(0xF3) },
    ];
    let expected: [&[u8]; 4] = [
        &[0x03, 1, 2, 3],
        &[0x1F, 0xFF, 1, 2, 3, 4, 5, 6],
        &[0x2F, 9, 9, 9, 9, 9, 9, 9],
        &[0x31, 0x08, 0xF3],
    ];
    for (repr, bytes) in cases.iter().zip(expected) {
        let mut buf = [0u8; 8];
        let n = repr.emit(&mut buf);
        assert_eq!(&buf[..n], bytes);
        assert_eq!(PduRepr::parse(bytes).unwrap(), *repr);
    }
}

/// Moves frames between two endpoints until both are idle; returns the receiver's
/// message and the simulated time it took.
fn exchange(a_cfg: Config, b_cfg: Config, msg: &[u8]) -> (Vec<u8>, Instant) {
    let mut a: Box<IsoTp> = Box::new(IsoTp::new(a_cfg));
    let mut b: Box<IsoTp> = Box::new(IsoTp::new(b_cfg));
    a.send(msg).unwrap();
    let mut now = Instant::from_micros(0);
    let mut got = None;
    for _ in 0..100_000 {
        let mut moved = false;
        while let Some(f) = a.poll_transmit(now) {
            a.frame_sent(now);
            if let Some(Event::Received(_)) = b.on_frame(&f, now) {
                got = Some(b.received().to_vec());
            }
            moved = true;
        }
        while let Some(f) = b.poll_transmit(now) {
            b.frame_sent(now);
            assert_eq!(a.on_frame(&f, now), None);
            moved = true;
        }
        assert_eq!(a.poll(now), None);
        assert_eq!(b.poll(now), None);
        if let Some(m) = got.take() {
            assert!(!a.is_sending());
            return (m, now);
        }
        if !moved {
            now = a.poll_at().unwrap_or(now + Duration::from_micros(100)).max(now);
        }
    }
    panic!("exchange did not finish");
}

#[test]
fn max_length_message_between_endpoints() {
    let msg: Vec<u8> = (0..4095u32).map(|i| (i * 7 + 3) as u8).collect();
    let mut rx_cfg = Config::new(0x7A8, 0x7A0);
    rx_cfg.block_size = 8;
    rx_cfg.st_min = StMin(0xF2); // 200 µs
    rx_cfg.padding = None;
    let (got, t) = exchange(Config::new(0x7A0, 0x7A8), rx_cfg, &msg);
    assert_eq!(got, msg);
    // 585 consecutive frames in blocks of 8, every two 200 µs apart (also across a
    // block's flow control, which here comes back at once).
    assert_eq!(t, Instant::from_micros(584 * 200), "STmin not honoured");
}

proptest! {
    #[test]
    fn any_message_round_trips(
        msg in prop::collection::vec(any::<u8>(), 1..600),
        bs in 0u8..5,
        pad in prop::option::of(any::<u8>()),
    ) {
        let mut a = Config::new(0x7A0, 0x7A8);
        a.padding = pad;
        let mut b = Config::new(0x7A8, 0x7A0);
        b.block_size = bs;
        let (got, _) = exchange(a, b, &msg);
        prop_assert_eq!(got, msg);
    }

    #[test]
    fn arbitrary_frames_never_panic(frames in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..=8), 0..50)) {
        let mut tp: IsoTp<128> = IsoTp::new(Config::new(TX, RX));
        let _ = tp.send(&[0u8; 100]);
        for (i, data) in frames.iter().enumerate() {
            let now = Instant::from_millis(i as u64);
            let _ = tp.on_frame(&frame(RX, data), now);
            while let Some(_f) = tp.poll_transmit(now) {
                tp.frame_sent(now);
            }
            let _ = tp.poll(now);
            prop_assert!(tp.received().len() <= 128);
        }
    }
}

#[test]
fn identifiers_above_11_bits_make_a_29_bit_endpoint() {
    // Normal fixed addressing style IDs (tester 0xF1 → ECU 0x00 and back).
    let (req, resp) = (0x18DA_00F1, 0x18DA_F100);
    assert!(!Config::new(TX, RX).extended);
    let server_cfg = Config::new(resp, req);
    let client_cfg = Config::new(req, resp);
    assert!(server_cfg.extended && client_cfg.extended);
    let mut server: IsoTp = IsoTp::new(server_cfg);
    let mut client: IsoTp = IsoTp::new(client_cfg);
    client.send(&[0x22, 0xC0, 0x01]).unwrap();
    let f = client.poll_transmit(ms(0)).unwrap();
    assert!(f.extended && f.id == req, "{f:?}");
    client.frame_sent(ms(0));
    assert_eq!(server.on_frame(&f, ms(1)), Some(Event::Received(3)));
    assert_eq!(server.received(), [0x22, 0xC0, 0x01]);
    // The same bytes on an 11-bit ID are not for this endpoint.
    let short = CanFrame::new_standard(0x7A0, &f.data).unwrap();
    assert_eq!(server.on_frame(&short, ms(2)), None);
    // A segmented answer goes back on the 29-bit response ID.
    let msg: Vec<u8> = (0..20).collect();
    server.send(&msg).unwrap();
    let ff = server.poll_transmit(ms(3)).unwrap();
    assert!(ff.extended && ff.id == resp);
    server.frame_sent(ms(3));
    client.on_frame(&ff, ms(4));
    let fc = client.poll_transmit(ms(4)).unwrap();
    client.frame_sent(ms(4));
    server.on_frame(&fc, ms(5));
    let mut got = None;
    while let Some(cf) = server.poll_transmit(ms(6)) {
        server.frame_sent(ms(6));
        got = client.on_frame(&cf, ms(6)).or(got);
    }
    assert_eq!(got, Some(Event::Received(20)));
    assert_eq!(client.received(), &msg[..]);
}
