//! No panic on any bytes for the PandarXT32, PandarQT64 and Ouster views and decoders: random
//! payloads of every length near the real ones, and real-length packets with random bodies
//! behind valid headers (so the checks pass and the accessors and decoders run).

use proptest::prelude::*;
use roomcal::lidar::calibration::Calibration;
use roomcal::lidar::ouster::{OusterGeometry, Profile};
use roomcal::lidar::{decode_packet, hesai, ouster, Model};

fn finite_points(cal: &Calibration, bytes: &[u8]) {
    let _ = decode_packet(cal, bytes, &mut |r| {
        assert!(r.point.x.is_finite() && r.point.y.is_finite() && r.point.z.is_finite());
        assert!(r.azimuth < 36000);
    });
}

fn ouster_calibration(profile: Profile) -> Calibration {
    let mut cal = Calibration::nominal(Model::Ouster);
    cal.ouster = OusterGeometry { profile, beam_origin: 0.0158, ..OusterGeometry::default() };
    cal
}

proptest! {
    #[test]
    fn hesai_xt32_qt64_never_panic(mut bytes in proptest::collection::vec(any::<u8>(), 1060..1090), qt in any::<bool>()) {
        let model = if qt { Model::PandarQt64 } else { Model::PandarXt32 };
        let cal = Calibration::nominal(model);
        finite_points(&cal, &bytes);
        // A valid header and return mode, the rest random: the decoder runs over it.
        let (blocks, lasers, version) = if qt { (4u8, 64u8, [3u8, 1]) } else { (8, 32, [6, 1]) };
        bytes[..12].copy_from_slice(&[0xEE, 0xFF, version[0], version[1], 0, 0, lasers, blocks, 0, 4, 2, 0]);
        let layout = hesai::Layout::of(model).unwrap();
        let len = layout.packet_len() + 4;
        if bytes.len() >= len {
            bytes.truncate(len);
            bytes[layout.tail_at() + layout.tail.return_mode] = 0x39;
            for b in 0..layout.blocks {
                let at = layout.header_len + b * layout.block_len();
                let az = u16::from_le_bytes([bytes[at], bytes[at + 1]]) % 36000;
                bytes[at..at + 2].copy_from_slice(&az.to_le_bytes());
            }
            prop_assert!(hesai::Packet::new_checked(&bytes[..], model).is_ok());
            finite_points(&cal, &bytes);
        }
    }

    #[test]
    fn ouster_never_panics(mut bytes in proptest::collection::vec(any::<u8>(), 6400..8500), dual in any::<bool>()) {
        let profile = if dual { Profile::Dual } else { Profile::Legacy };
        let cal = ouster_calibration(profile);
        finite_points(&cal, &bytes);
        let g = cal.ouster;
        if bytes.len() >= g.packet_len() {
            bytes.truncate(g.packet_len());
            if dual {
                bytes[0..2].copy_from_slice(&1u16.to_le_bytes());
            }
            let (header, column) = (if dual { 32 } else { 0 }, g.column_len());
            for c in 0..16 {
                let at = header + c * column + 8;
                let m = u16::from_le_bytes([bytes[at], bytes[at + 1]]) % 1024;
                bytes[at..at + 2].copy_from_slice(&m.to_le_bytes());
            }
            prop_assert!(ouster::Packet::new_checked(&bytes[..], &g).is_ok());
            finite_points(&cal, &bytes);
        }
    }
}
