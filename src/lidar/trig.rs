//! Sine and cosine of packet azimuths (whole hundredths of a degree) by table lookup: a
//! quarter-wave table built at compile time (36 KB, no heap, no start-up work), so the
//! decoders spend no per-point time on trigonometry.

use core::f64::consts::PI;

/// Hundredths of a degree in a quarter turn.
const QUARTER: usize = 9000;

/// sin(i · 0.01°) for i in 0..=9000, rounded to f32.
static SIN_QUARTER: [f32; QUARTER + 1] = {
    let mut t = [0.0f32; QUARTER + 1];
    let mut i = 0;
    while i <= QUARTER {
        t[i] = sin_0_to_half_pi(i as f64 * (PI / 18000.0)) as f32;
        i += 1;
    }
    t
};

/// (sin, cos) of `azimuth` hundredths of a degree; any value, taken modulo 360°.
#[inline]
pub fn sin_cos_hundredths(azimuth: u32) -> (f32, f32) {
    sin_cos_turn((azimuth % 36000) as u16)
}

/// (sin, cos) of `azimuth` hundredths of a degree below 36000 (as packets carry them; larger
/// values give a wrong but finite answer, never a panic).
#[inline]
pub fn sin_cos_turn(azimuth: u16) -> (f32, f32) {
    let a = usize::from(azimuth);
    let quadrant = a / QUARTER;
    let r = a - quadrant * QUARTER;
    // Both indices are ≤ QUARTER by construction; `get` keeps the path panic-free anyway.
    let s = SIN_QUARTER.get(r).copied().unwrap_or(0.0);
    let c = SIN_QUARTER.get(QUARTER.wrapping_sub(r)).copied().unwrap_or(1.0);
    match quadrant {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// Taylor series of sine on [0, π/2], to f64 precision (the last term kept is below 1e-25).
const fn sin_0_to_half_pi(x: f64) -> f64 {
    let x2 = x * x;
    let (mut term, mut sum) = (x, x);
    let mut k = 1;
    while k < 14 {
        term = -term * x2 / ((2 * k) * (2 * k + 1)) as f64;
        sum += term;
        k += 1;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_matches_libm_everywhere() {
        let mut worst = 0.0f64;
        for a in 0..36000u32 {
            let (s, c) = sin_cos_hundredths(a);
            let x = f64::from(a) * (PI / 18000.0);
            worst = worst.max((f64::from(s) - libm::sin(x)).abs());
            worst = worst.max((f64::from(c) - libm::cos(x)).abs());
        }
        assert!(worst < 6e-8, "{worst}");
        assert_eq!(sin_cos_hundredths(9000), (1.0, 0.0));
        assert_eq!(sin_cos_hundredths(36000), sin_cos_hundredths(0));
    }
}
