//! Fuzzes the Hesai packet views, `Repr` and decoder for the Pandar64, Pandar40P, PandarXT32
//! and PandarQT64: no panic
//! on any bytes, and every packet that parses re-emits to the same bytes (reserved bytes
//! aside, which `emit` zeroes); the stream checks (`check_consistency`) never panic either.
#![no_main]

use libfuzzer_sys::fuzz_target;
use roomcal::lidar::calibration::Calibration;
use roomcal::lidar::hesai::{Packet, Repr};
use roomcal::lidar::{decode_packet, Model};

fuzz_target!(|data: &[u8]| {
    for model in [Model::Pandar64, Model::Pandar40p, Model::PandarXt32, Model::PandarQt64] {
        let cal = Calibration::nominal(model);
        let _ = decode_packet(&cal, data, &mut |r| {
            assert!(r.point.x.is_finite() && r.point.y.is_finite() && r.point.z.is_finite());
        });
        if let Ok(packet) = Packet::new_checked(data, model) {
            let _ = packet.check_consistency();
            let repr = Repr::parse(&packet).expect("checked packets parse");
            let mut out = vec![0u8; repr.buffer_len()];
            let emitted = repr.emit(&mut out[..]).expect("emit into the right size");
            let again = Repr::parse(&Packet::new_checked(emitted.into_inner(), model).unwrap());
            assert_eq!(again.unwrap(), repr);
        }
    }
});
