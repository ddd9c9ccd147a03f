//! Fuzz target: the PCD parser (all three encodings) must never panic. Named `pcap_*`
//! to sit with the capture targets of the LiDAR file readers.
#![no_main]

use libfuzzer_sys::fuzz_target;
use roomcal::lidar::pcd::PcdReader;

fuzz_target!(|data: &[u8]| {
    let mut out = Vec::new();
    let _ = PcdReader::new().parse_into(data, "fuzz", &mut out);
});
