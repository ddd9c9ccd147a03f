//! A small deterministic random source for the simulator.
//!
//! Our own SplitMix64 rather than the `rand` crate: the fixtures and every test's ground
//! truth depend on the exact stream for a seed, and this one can never change under us
//! with a dependency upgrade.

/// SplitMix64 (Steele, Lea, Flood 2014) with uniform and Gaussian draws.
#[derive(Clone, Debug)]
pub struct Rng {
    state: u64,
    spare_normal: Option<f64>,
}

impl Rng {
    /// A stream for `seed`; different seeds give unrelated streams.
    pub fn new(seed: u64) -> Self {
        Rng { state: seed ^ 0x6A09_E667_F3BC_C909, spare_normal: None }
    }

    /// A derived stream, so that one part of the scene does not shift another's draws.
    pub fn fork(&mut self, salt: u64) -> Rng {
        Rng::new(self.next_u64() ^ salt.wrapping_mul(0x9E37_79B9_7F4A_7C15))
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Standard normal (Box–Muller, both values used).
    pub fn normal(&mut self) -> f64 {
        if let Some(v) = self.spare_normal.take() {
            return v;
        }
        let u1 = self.uniform().max(f64::MIN_POSITIVE);
        let u2 = self.uniform();
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (2.0 * std::f64::consts::PI * u2).sin_cos();
        self.spare_normal = Some(r * s);
        r * c
    }
}

/// A smooth deterministic texture in [0, 1] over a plane: value noise, four octaves.
/// Hash-based, so it needs no tables and is the same for a seed everywhere.
pub fn texture(seed: u64, u: f64, v: f64) -> f64 {
    let mut sum = 0.0;
    let mut amplitude = 0.5;
    let mut frequency = 2.0;
    for octave in 0..4u64 {
        sum +=
            amplitude * value_noise(seed.wrapping_add(octave * 7919), u * frequency, v * frequency);
        amplitude *= 0.5;
        frequency *= 2.3;
    }
    sum / 0.9375
}

fn value_noise(seed: u64, u: f64, v: f64) -> f64 {
    let (iu, iv) = (u.floor(), v.floor());
    let (fu, fv) = (u - iu, v - iv);
    let (su, sv) = (fu * fu * (3.0 - 2.0 * fu), fv * fv * (3.0 - 2.0 * fv));
    let lattice = |du: i64, dv: i64| {
        let h = hash(seed, iu as i64 + du, iv as i64 + dv);
        (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    };
    let top = lattice(0, 0) * (1.0 - su) + lattice(1, 0) * su;
    let bottom = lattice(0, 1) * (1.0 - su) + lattice(1, 1) * su;
    top * (1.0 - sv) + bottom * sv
}

fn hash(seed: u64, a: i64, b: i64) -> u64 {
    let mut rng = Rng::new(
        seed ^ (a as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93) ^ (b as u64).rotate_left(32),
    );
    rng.next_u64()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_stream_other_seed_other_stream() {
        let a: Vec<u64> = (0..4).scan(Rng::new(7), |r, _| Some(r.next_u64())).collect();
        let b: Vec<u64> = (0..4).scan(Rng::new(7), |r, _| Some(r.next_u64())).collect();
        let c: Vec<u64> = (0..4).scan(Rng::new(8), |r, _| Some(r.next_u64())).collect();
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn normal_has_unit_variance() {
        let mut rng = Rng::new(1);
        let n = 200_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for _ in 0..n {
            let x = rng.normal();
            s += x;
            s2 += x * x;
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.01, "variance {var}");
    }

    #[test]
    fn texture_stays_in_unit_range_and_varies() {
        let values: Vec<f64> =
            (0..1000).map(|i| texture(3, i as f64 * 0.037, i as f64 * 0.011)).collect();
        assert!(values.iter().all(|v| (0.0..=1.0).contains(v)));
        let spread = values.iter().cloned().fold(f64::MIN, f64::max)
            - values.iter().cloned().fold(f64::MAX, f64::min);
        assert!(spread > 0.3, "texture too flat: {spread}");
    }
}
