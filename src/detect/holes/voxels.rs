//! Voxels: the sweep's returns binned in voxels (10 cm by default), each voxel's local
//! plane from the moments of its 3×3×3 neighbourhood (a closed-form 3×3 eigen solve).
//! The planar voxels are what the plane segments grow from.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use crate::geometry::{Mat3, Vec3};

use super::sweep::{point_of, Sweep};
use super::HoleConfig;

/// The voxel workspace, sized by the largest sweep seen.
#[derive(Debug, Default)]
pub(super) struct Voxels {
    /// Every return's voxel key and index in the sweep's points, sorted by key.
    keys: Vec<(u64, u32)>,
    voxels: Vec<Voxel>,
    map: HashMap<u64, u32, BuildHasherDefault<KeyHasher>>,
}

/// One occupied voxel: its returns (`keys[start..end]`), their moments and the local plane
/// of its neighbourhood.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Voxel {
    pub(super) key: u64,
    start: u32,
    end: u32,
    pub(super) m: Moments,
    pub(super) normal: Vec3,
    pub(super) centroid: Vec3,
    pub(super) planar: bool,
}

impl Voxels {
    /// Bins the sweep's returns and finds every voxel's local plane.
    pub(super) fn build(&mut self, sweep: &Sweep, config: &HoleConfig) {
        self.voxelise(sweep, config);
        self.local_planes(config);
    }

    /// Frees the buffers sized by the last sweep.
    pub(super) fn release(&mut self) {
        self.keys = Vec::new();
        self.voxels = Vec::new();
        self.map = HashMap::default();
    }

    /// The voxels, in key order.
    pub(super) fn all(&self) -> &[Voxel] {
        &self.voxels
    }

    /// The index of the voxel of `key`, if it holds returns.
    pub(super) fn index_of(&self, key: u64) -> Option<u32> {
        self.map.get(&key).copied()
    }

    /// Indices in the sweep's points of `voxel`'s returns.
    pub(super) fn returns_of(&self, voxel: &Voxel) -> impl Iterator<Item = u32> + '_ {
        self.keys[voxel.start as usize..voxel.end as usize].iter().map(|&(_, p)| p)
    }

    #[inline(never)]
    fn voxelise(&mut self, sweep: &Sweep, config: &HoleConfig) {
        let pts = sweep.points();
        let inv = 1.0 / config.voxel_m;
        self.keys.clear();
        // Exactly the sweep's size, not a doubling's slack (the daemon frees it after each
        // run, `release_workspace`).
        self.keys.reserve_exact(pts.len());
        self.keys.extend(
            pts.iter().enumerate().map(|(i, p)| (voxel_key(&(point_of(p) * inv)), i as u32)),
        );
        self.keys.sort_unstable();
        self.voxels.clear();
        self.map.clear();
        let mut i = 0;
        while i < self.keys.len() {
            let key = self.keys[i].0;
            let start = i;
            let mut m = Moments::default();
            while i < self.keys.len() && self.keys[i].0 == key {
                m.add(&point_of(&pts[self.keys[i].1 as usize]));
                i += 1;
            }
            self.map.insert(key, self.voxels.len() as u32);
            let v = Voxel { key, start: start as u32, end: i as u32, m, ..Voxel::default() };
            self.voxels.push(v);
        }
    }

    /// Plane of every voxel's 3×3×3 neighbourhood.
    #[inline(never)]
    fn local_planes(&mut self, config: &HoleConfig) {
        let spread2 = 0.04 * 0.04;
        for i in 0..self.voxels.len() {
            let key = self.voxels[i].key;
            let mut m = Moments::default();
            for nk in neighbour_keys(key) {
                if let Some(&j) = self.map.get(&nk) {
                    m.merge(&self.voxels[j as usize].m);
                }
            }
            let v = &mut self.voxels[i];
            v.planar = false;
            if m.n < 6.0 {
                continue;
            }
            let (centroid, cov) = m.mean_cov();
            let (l, normal) = smallest_eigen(&cov);
            v.centroid = centroid;
            v.normal = normal;
            let t = config.plane_tolerance_m / 2.0;
            v.planar = l[0] < t * t && l[1] > spread2 && l[0] < 0.3 * l[1];
        }
    }
}

/// Point count, sum and sum of outer products.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Moments {
    pub(super) n: f64,
    pub(super) s: Vec3,
    ss: [f64; 6],
}

impl Moments {
    pub(super) fn add(&mut self, p: &Vec3) {
        self.n += 1.0;
        self.s += p;
        let s = &mut self.ss;
        s[0] += p.x * p.x;
        s[1] += p.x * p.y;
        s[2] += p.x * p.z;
        s[3] += p.y * p.y;
        s[4] += p.y * p.z;
        s[5] += p.z * p.z;
    }

    pub(super) fn merge(&mut self, o: &Moments) {
        self.n += o.n;
        self.s += o.s;
        for (a, b) in self.ss.iter_mut().zip(&o.ss) {
            *a += b;
        }
    }

    pub(super) fn mean_cov(&self) -> (Vec3, Mat3) {
        let c = self.s / self.n;
        let s = &self.ss;
        let n = self.n;
        let xx = s[0] / n - c.x * c.x;
        let xy = s[1] / n - c.x * c.y;
        let xz = s[2] / n - c.x * c.z;
        let yy = s[3] / n - c.y * c.y;
        let yz = s[4] / n - c.y * c.z;
        let zz = s[5] / n - c.z * c.z;
        (c, Mat3::new(xx, xy, xz, xy, yy, yz, xz, yz, zz))
    }
}

/// Eigenvalues (ascending) of a symmetric 3×3 matrix and the unit eigenvector of the
/// smallest, in closed form (trigonometric solution of the characteristic cubic).
pub(super) fn smallest_eigen(a: &Mat3) -> ([f64; 3], Vec3) {
    let p1 = a[(0, 1)].powi(2) + a[(0, 2)].powi(2) + a[(1, 2)].powi(2);
    let q = a.trace() / 3.0;
    let p2 = (a[(0, 0)] - q).powi(2) + (a[(1, 1)] - q).powi(2) + (a[(2, 2)] - q).powi(2) + 2.0 * p1;
    let p = (p2 / 6.0).sqrt();
    if p < 1e-15 {
        return ([q; 3], Vec3::z());
    }
    let b = (a - Mat3::identity() * q) / p;
    let r = (b.determinant() / 2.0).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let l_max = q + 2.0 * p * phi.cos();
    let l_min = q + 2.0 * p * (phi + 2.0 * core::f64::consts::PI / 3.0).cos();
    let l_mid = 3.0 * q - l_max - l_min;
    let m = a - Mat3::identity() * l_min;
    let (r0, r1, r2) = (
        m.row(0).transpose().into_owned(),
        m.row(1).transpose().into_owned(),
        m.row(2).transpose().into_owned(),
    );
    let cands = [r0.cross(&r1), r0.cross(&r2), r1.cross(&r2)];
    let mut best = cands[0];
    for c in &cands[1..] {
        if c.norm_squared() > best.norm_squared() {
            best = *c;
        }
    }
    let nrm = best.norm();
    let v = if nrm > 0.0 { best / nrm } else { Vec3::z() };
    ([l_min, l_mid, l_max], v)
}

/// A voxel key packs the integer voxel coordinates, each biased by `KEY_BIAS` into 21 bits.
const KEY_BIAS: i64 = 1 << 20;
const KEY_MASK: u64 = (1 << 21) - 1;

fn voxel_key(v: &Vec3) -> u64 {
    let f = |x: f64| ((x.floor() as i64 + KEY_BIAS) as u64) & KEY_MASK;
    (f(v.x) << 42) | (f(v.y) << 21) | f(v.z)
}

/// Integer voxel coordinates of a key.
pub(super) fn key_coords(key: u64) -> [i64; 3] {
    let f = |k: u64| (k & KEY_MASK) as i64 - KEY_BIAS;
    [f(key >> 42), f(key >> 21), f(key)]
}

/// The key of integer voxel coordinates.
pub(super) fn coords_key(c: [i64; 3]) -> u64 {
    let f = |x: i64| ((x + KEY_BIAS) as u64) & KEY_MASK;
    (f(c[0]) << 42) | (f(c[1]) << 21) | f(c[2])
}

/// The 27 keys of a voxel's 3×3×3 neighbourhood (itself included).
pub(super) fn neighbour_keys(key: u64) -> impl Iterator<Item = u64> {
    let (x, y, z) = ((key >> 42) & KEY_MASK, (key >> 21) & KEY_MASK, key & KEY_MASK);
    (0..27u64).map(move |i| {
        let (dx, dy, dz) = (i % 3, (i / 3) % 3, i / 9);
        let f = |c: u64, d: u64| (c + d).wrapping_sub(1) & KEY_MASK;
        (f(x, dx) << 42) | (f(y, dy) << 21) | f(z, dz)
    })
}

/// A multiplicative hasher for voxel keys (std's SipHash is needlessly slow here and
/// the keys are not attacker-controlled).
#[derive(Default, Clone, Copy, Debug)]
struct KeyHasher(u64);

impl Hasher for KeyHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(5) ^ b as u64).wrapping_mul(0x517c_c1b7_2722_0a95);
        }
    }
    fn write_u64(&mut self, v: u64) {
        let h = v.wrapping_mul(0x9e37_79b9_7f4a_7c15);
        self.0 = h ^ (h >> 32);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A key holds negative and positive voxel coordinates, and its neighbourhood is the
    /// 27 voxels about it.
    #[test]
    fn keys_round_trip_and_neighbours_surround_the_voxel() {
        for c in [[0, 0, 0], [-3, 7, -1_000], [1_000, -1, 5]] {
            let key = coords_key(c);
            assert_eq!(key_coords(key), c);
            let inside = Vec3::new(c[0] as f64 + 0.5, c[1] as f64 + 0.5, c[2] as f64 + 0.5);
            assert_eq!(voxel_key(&inside), key);
            let mut around: Vec<[i64; 3]> = neighbour_keys(key).map(key_coords).collect();
            let mut expected = Vec::new();
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        expected.push([c[0] + dx, c[1] + dy, c[2] + dz]);
                    }
                }
            }
            around.sort_unstable();
            expected.sort_unstable();
            assert_eq!(around, expected);
        }
    }

    /// The closed-form eigen solve finds a flat scatter's normal as its smallest
    /// eigenvector, with a zero eigenvalue.
    #[test]
    fn smallest_eigenvector_of_a_flat_scatter_is_its_normal() {
        let n = Vec3::new(1.0, 2.0, 2.0) / 3.0;
        let u = Vec3::new(2.0, -1.0, 0.0).normalize();
        let v = n.cross(&u);
        let mut m = Moments::default();
        for a in -5..=5 {
            for b in -3..=3 {
                m.add(&(Vec3::new(4.0, 1.0, -0.5) + u * (0.1 * a as f64) + v * (0.1 * b as f64)));
            }
        }
        let (_, cov) = m.mean_cov();
        let (l, normal) = smallest_eigen(&cov);
        assert!(l[0].abs() < 1e-12 && l[0] < l[1] && l[1] < l[2], "eigenvalues {l:?}");
        assert!((normal.dot(&n).abs() - 1.0).abs() < 1e-9, "normal {normal:?}");
    }
}
