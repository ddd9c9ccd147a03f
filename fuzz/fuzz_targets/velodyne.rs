//! Fuzzes the Velodyne packet view, `Repr` and decoder: no panic on any bytes, and every
//! packet that parses re-emits to the same bytes; the stream checks (`check_consistency`)
//! never panic either.
#![no_main]

use libfuzzer_sys::fuzz_target;
use roomcal::lidar::calibration::{Calibration, Interpolation};
use roomcal::lidar::velodyne::{Packet, Repr};
use roomcal::lidar::{decode_packet, Model};

fuzz_target!(|data: &[u8]| {
    for model in [Model::Vlp16, Model::Vlp32c, Model::Hdl32e] {
        for interpolation in [Interpolation::Manual, Interpolation::Nebula] {
            let mut cal = Calibration::nominal(model);
            cal.interpolation = interpolation;
            let _ = decode_packet(&cal, data, &mut |r| {
                assert!(r.point.x.is_finite() && r.point.y.is_finite() && r.point.z.is_finite());
            });
        }
    }
    if let Ok(packet) = Packet::new_checked(data) {
        let _ = packet.check_consistency();
        let repr = Repr::parse(&packet).expect("checked packets parse");
        let mut out = vec![0u8; repr.buffer_len()];
        repr.emit(&mut Packet::new_unchecked(&mut out[..])).expect("emit into the right size");
        assert_eq!(out, data);
    }
});
