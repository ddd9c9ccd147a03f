//! Impairments for packet streams (tests/it/lidar_sweep.rs, tests/it/daemon_udp.rs): a seeded
//! generator and garbage made from a real Pandar64 packet, as a corrupted sender makes it.
#![allow(dead_code)]

/// xorshift64*: a seeded, reproducible stream.
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// True with probability `p` (never for p = 0).
    pub fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && (self.next() >> 11) as f64 / (1u64 << 53) as f64 <= p
    }

    pub fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    pub fn fill(&mut self, bytes: &mut [u8]) {
        bytes.iter_mut().for_each(|b| *b = self.next() as u8);
    }
}

/// Where the Pandar64 tail starts, and its fields (`hesai::PANDAR64`, the manual).
pub const TAIL: usize = 1172;
pub const TAIL_US: usize = TAIL + 10;
pub const TAIL_MODE: usize = TAIL + 14;
pub const TAIL_DATE: usize = TAIL + 16;
/// Offset and length of block `b`: azimuth, then 64 three-byte units.
pub const BLOCK0: usize = 8;
pub const BLOCK_LEN: usize = 2 + 64 * 3;

/// Garbage with a valid header: a real Pandar64 packet's header, random blocks (every
/// azimuth below 360°) and a random tail with a valid return mode. It passes the length,
/// magic, header, azimuth-range and return-mode checks; its date and time are anything (a
/// far-future or far-past timestamp, a month 200).
pub fn header_garbage(rng: &mut Rng, real: &[u8]) -> Vec<u8> {
    let mut p = real.to_vec();
    rng.fill(&mut p[BLOCK0..]);
    for b in 0..6 {
        let at = BLOCK0 + b * BLOCK_LEN;
        let az = (rng.next() % 36000) as u16;
        p[at..at + 2].copy_from_slice(&az.to_le_bytes());
    }
    p[TAIL_MODE] = 0x37;
    p
}

/// A real Pandar64 packet a day later: valid in every field, far from the stream's clock.
pub fn next_day(real: &[u8]) -> Vec<u8> {
    let mut p = real.to_vec();
    p[TAIL_DATE + 2] = p[TAIL_DATE + 2] % 27 + 2;
    p
}

/// Garbage of one of five kinds: random bytes of a random length, `header_garbage`, a real
/// packet with a few bytes changed, a real packet cut short, or `next_day`.
pub fn mixed_garbage(rng: &mut Rng, real: &[u8]) -> Vec<u8> {
    match rng.below(5) {
        0 => {
            let mut p = vec![0u8; 1 + rng.below(1500)];
            rng.fill(&mut p);
            p
        }
        1 => header_garbage(rng, real),
        2 => {
            let mut p = real.to_vec();
            for _ in 0..1 + rng.below(8) {
                let at = rng.below(p.len());
                p[at] ^= 1 + rng.below(255) as u8;
            }
            p
        }
        3 => real[..rng.below(real.len())].to_vec(),
        _ => next_day(real),
    }
}
