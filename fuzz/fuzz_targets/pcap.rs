//! Fuzz target: the pcap/pcapng reader must never panic, whatever the bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use roomcal::lidar::pcap;

fuzz_target!(|data: &[u8]| {
    if let Ok(datagrams) = pcap::datagrams(data, "fuzz") {
        for d in datagrams {
            if let Ok(d) = d {
                // Touch the payload so the slice bounds are exercised.
                std::hint::black_box(d.payload.iter().map(|&b| u32::from(b)).sum::<u32>());
            }
        }
    }
});
