//! Fuzz target: LZF decompression of arbitrary bytes must never panic, and compressing
//! then decompressing must give the input back.
#![no_main]

use libfuzzer_sys::fuzz_target;
use roomcal::lidar::lzf;

fuzz_target!(|data: &[u8]| {
    let mut out = vec![0u8; 1 << 16];
    let _ = lzf::decompress(data, &mut out);
    let mut packed = vec![0u8; lzf::max_compressed_len(data.len())];
    let n = lzf::compress(data, &mut packed).expect("worst-case buffer");
    let mut back = vec![0u8; data.len()];
    assert_eq!(lzf::decompress(&packed[..n], &mut back), Ok(data.len()));
    assert_eq!(back, data);
});
