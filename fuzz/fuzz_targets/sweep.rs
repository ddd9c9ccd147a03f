//! Fuzzes the sweep assembler with a stream of payloads cut from the input (2-byte length
//! prefixes, port from the first byte): no panic, and every payload is accounted for.
#![no_main]

use libfuzzer_sys::fuzz_target;
use roomcal::lidar::{Calibration, Model, Point, SweepAssembler, SweepConfig};

fuzz_target!(|data: &[u8]| {
    let Some((&selector, mut rest)) = data.split_first() else { return };
    let model = Model::ALL[usize::from(selector) % Model::ALL.len()];
    let cal = Calibration::nominal(model);
    let mut buf = vec![Point::default(); 4096];
    let mut asm = SweepAssembler::new(cal, SweepConfig::for_calibration(&cal), &mut buf);
    let mut pushed = 0u64;
    while rest.len() >= 3 {
        let len = usize::from(u16::from_le_bytes([rest[0], rest[1]])) % 1300;
        let port = if rest[2] & 1 == 0 { model.data_port() } else { model.position_port() };
        rest = &rest[3..];
        let payload = &rest[..len.min(rest.len())];
        rest = &rest[payload.len()..];
        asm.push(port, payload, &mut |s| assert!(s.points.len() <= 4096));
        pushed += 1;
    }
    asm.flush(&mut |_| {});
    let s = asm.stats();
    assert_eq!(s.packets + s.position + s.dropped(), pushed);
});
