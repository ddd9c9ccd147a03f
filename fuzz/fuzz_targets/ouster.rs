//! Fuzzes the Ouster packet view, `Repr` and decoder (LEGACY and DUAL, 16 and 32 beams, the
//! geometry taken from the first input bytes): no panic on any bytes, finite points, and every
//! packet that parses re-emits to a packet that parses to the same `Repr`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use roomcal::lidar::calibration::Calibration;
use roomcal::lidar::ouster::{OusterGeometry, Packet, Profile, Repr};
use roomcal::lidar::{decode_packet, Model};

fn round_trip<const BEAMS: usize>(data: &[u8], g: &OusterGeometry) {
    if let Ok(packet) = Packet::new_checked(data, g) {
        let repr = Repr::<BEAMS>::parse(&packet).expect("checked packets parse");
        let mut out = vec![0u8; repr.buffer_len()];
        let emitted = repr.emit(&mut out[..]).expect("emit into the right size");
        let again = Repr::<BEAMS>::parse(&Packet::new_checked(emitted.into_inner(), g).unwrap());
        assert_eq!(again.unwrap(), repr);
    }
}

fuzz_target!(|input: &[u8]| {
    let Some((&selector, data)) = input.split_first() else { return };
    let profile = if selector & 1 == 0 { Profile::Legacy } else { Profile::Dual };
    let beams = if selector & 2 == 0 { 16 } else { 32 };
    let columns = 1 + u16::from(selector >> 4);
    let g = OusterGeometry {
        profile,
        pixels_per_column: beams,
        columns_per_packet: columns,
        beam_origin: 0.015,
        ..OusterGeometry::default()
    };
    let mut cal = Calibration::nominal(Model::Ouster);
    cal.ouster = g;
    let _ = decode_packet(&cal, data, &mut |r| {
        assert!(r.point.x.is_finite() && r.point.y.is_finite() && r.point.z.is_finite());
        assert!(r.azimuth < 36000);
    });
    if beams == 16 {
        round_trip::<16>(data, &g);
    } else {
        round_trip::<32>(data, &g);
    }
});
