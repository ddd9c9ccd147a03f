//! Plane segments of a sweep: planar voxels grown into regions, then coplanar fragments
//! of one board merged, then every board-sized group's points gathered from its plane.
//!
//! Why the merge: a sparse ring pattern (a VLP-32C outside its dense band, 1–2.5° between
//! rings, i.e. 10–25 cm at 5 m) leaves voxel neighbourhoods that hold one scan line only;
//! those are not planar, so one board falls apart into fragments that each hold two or
//! three of its lines. Fragments whose union is still one thin plane no larger than the
//! board are one board.

use super::{
    neighbour_keys, point_of, smallest_eigen, HoleDetector, Moments, Vec3, KEY_BIAS, KEY_MASK,
};

/// A region of planar voxels; at a union-find root also the whole merged group.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Segment {
    /// Union-find parent (itself at a root).
    parent: u32,
    /// The region's own centroid x (m), for pruning pairs.
    x: f64,
    /// At a root: the group's point moments, plane normal and voxel bounding box.
    m: Moments,
    normal: Vec3,
    lo: [i64; 3],
    hi: [i64; 3],
}

/// How many voxels beyond a group's own the gathering reaches: a sparse ring up to 30 cm
/// from the nearest planar voxel (a VLP-32C's 2.5° spacing at 6 m) still belongs.
const REACH: i64 = 3;

/// Label of voxels that belong to a region too large to be a board (walls, floor).
const HUGE: u32 = u32::MAX - 1;

impl HoleDetector {
    /// Grows planar voxels into regions (normals within the configured angle, coplanar
    /// centroids); regions larger than a board are dropped here.
    #[inline(never)]
    pub(super) fn grow_regions(&mut self) {
        let nv = self.voxels.len();
        self.label.clear();
        self.label.resize(nv, u32::MAX);
        self.region_voxels.clear();
        self.segs.clear();
        let cos_max = self.config.normal_angle_deg.to_radians().cos();
        let tol = self.config.plane_tolerance_m;
        let reach = self.board_diagonal() + 0.3;
        for seed in 0..nv {
            if !self.voxels[seed].planar || self.label[seed] != u32::MAX {
                continue;
            }
            let id = self.segs.len() as u32;
            let start = self.region_voxels.len();
            self.queue.clear();
            self.queue.push(seed as u32);
            self.label[seed] = id;
            let mut too_big = false;
            let c0 = self.voxels[seed].centroid;
            // The sum of the region's voxel normals (each turned to the seed's side): a
            // neighbour must agree with the region's mean normal as well as with the voxel
            // it touches, or a chain of small turns across the voxels where two boards meet
            // (their neighbourhoods mixing both) grows two boards 28° apart into one region
            // too large to be a board (issue 14's Pandar40P room 241).
            let mut normal_sum = self.voxels[seed].normal;
            while let Some(i) = self.queue.pop() {
                let vi = self.voxels[i as usize];
                self.region_voxels.push(i);
                too_big |= (vi.centroid - c0).norm() > reach;
                let mean_normal = normal_sum.normalize();
                for nk in neighbour_keys(vi.key) {
                    let Some(&j) = self.map.get(&nk) else { continue };
                    let vj = &self.voxels[j as usize];
                    if !vj.planar || self.label[j as usize] != u32::MAX {
                        continue;
                    }
                    let along_region = vj.normal.dot(&mean_normal);
                    let coplanar = along_region.abs() > cos_max
                        && vi.normal.dot(&vj.normal).abs() > cos_max
                        && vi.normal.dot(&(vj.centroid - vi.centroid)).abs() < tol
                        && vj.normal.dot(&(vi.centroid - vj.centroid)).abs() < tol;
                    if coplanar {
                        self.label[j as usize] = id;
                        self.queue.push(j);
                        normal_sum += vj.normal * along_region.signum();
                    }
                }
            }
            if too_big {
                for &v in &self.region_voxels[start..] {
                    self.label[v as usize] = HUGE;
                }
                self.region_voxels.truncate(start);
                continue;
            }
            let seg = self.new_segment(id, start);
            self.segs.push(seg);
        }
    }

    /// The segment of the region in `region_voxels[start..]`.
    fn new_segment(&self, id: u32, start: usize) -> Segment {
        let mut m = Moments::default();
        let (mut lo, mut hi) = ([i64::MAX; 3], [i64::MIN; 3]);
        for &v in &self.region_voxels[start..] {
            let voxel = &self.voxels[v as usize];
            m.merge(&voxel.m);
            let c = key_coords(voxel.key);
            for a in 0..3 {
                lo[a] = lo[a].min(c[a]);
                hi[a] = hi[a].max(c[a]);
            }
        }
        let (c, cov) = m.mean_cov();
        let (_, normal) = smallest_eigen(&cov);
        Segment { parent: id, x: c.x, m, normal, lo, hi }
    }

    /// Merges regions that are fragments of one plane no larger than a board.
    #[inline(never)]
    pub(super) fn merge_fragments(&mut self) {
        let n = self.segs.len();
        self.order.clear();
        self.order.extend(0..n as u32);
        let segs = &self.segs;
        self.order.sort_unstable_by(|&a, &b| segs[a as usize].x.total_cmp(&segs[b as usize].x));
        let diag = self.board_diagonal();
        for ii in 0..n {
            let a = self.order[ii];
            for jj in ii + 1..n {
                let b = self.order[jj];
                if self.segs[b as usize].x - self.segs[a as usize].x > diag {
                    break;
                }
                let (ra, rb) = (self.find(a), self.find(b));
                if ra != rb {
                    if let Some(merged) = self.merged(ra, rb) {
                        self.segs[rb as usize].parent = ra;
                        let keep = &mut self.segs[ra as usize];
                        (keep.m, keep.normal, keep.lo, keep.hi) = merged;
                    }
                }
            }
        }
    }

    /// The union of groups `a` and `b` when it is one thin plane no larger than a board:
    /// each part lies within the voxel planes' thickness of the union's plane (a part
    /// that is one scan line has no normal of its own, so normals are not compared).
    #[allow(clippy::type_complexity)]
    fn merged(&self, a: u32, b: u32) -> Option<(Moments, Vec3, [i64; 3], [i64; 3])> {
        let (sa, sb) = (&self.segs[a as usize], &self.segs[b as usize]);
        let diag = self.board_diagonal();
        let (ca, cb) = (sa.m.s / sa.m.n, sb.m.s / sb.m.n);
        if (ca - cb).norm() > diag {
            return None;
        }
        let (mut lo, mut hi) = (sa.lo, sa.hi);
        for k in 0..3 {
            lo[k] = lo[k].min(sb.lo[k]);
            hi[k] = hi[k].max(sb.hi[k]);
            if (hi[k] - lo[k]) as f64 * self.config.voxel_m > diag + self.config.voxel_m {
                return None;
            }
        }
        let mut m = sa.m;
        m.merge(&sb.m);
        let (c, cov) = m.mean_cov();
        let (l, normal) = smallest_eigen(&cov);
        let t = self.config.plane_tolerance_m / 2.0;
        let thin = mean_square_distance(&sa.m, &c, &normal) < t * t
            && mean_square_distance(&sb.m, &c, &normal) < t * t;
        let small = l[2].max(0.0).sqrt() <= diag / 2.0;
        (thin && small).then_some((m, normal, lo, hi))
    }

    fn find(&mut self, mut s: u32) -> u32 {
        while self.segs[s as usize].parent != s {
            let p = self.segs[s as usize].parent;
            self.segs[s as usize].parent = self.segs[p as usize].parent;
            s = p;
        }
        s
    }

    /// Roots of merged groups with enough points to be a board, in region order.
    pub(super) fn group_roots(&mut self) -> usize {
        self.roots.clear();
        for s in 0..self.segs.len() as u32 {
            if self.find(s) == s && self.segs[s as usize].m.n >= self.config.min_points as f64 {
                self.roots.push(s);
            }
        }
        self.roots.len()
    }

    /// The plane of group `root` (its voxels' centroid and normal), or `None` when the
    /// group cannot be a board.
    #[inline(never)]
    pub(super) fn group_plane(&mut self, root: u32) -> Option<(Vec3, Vec3)> {
        let (c, cov) = self.segs[root as usize].m.mean_cov();
        let (l, n) = smallest_eigen(&cov);
        // Longer than the board's diagonal: a piece of wall or floor.
        if l[2].max(0.0).sqrt() > self.board_diagonal() / 2.0 {
            return None;
        }
        Some((c, n))
    }

    /// Collects into `seg` every point within the plane tolerance of the plane (`c`, `n`)
    /// in group `root`'s voxel box widened by [`REACH`] voxels (the scan lines whose own
    /// voxels were not planar).
    pub(super) fn gather_in_group(&mut self, root: u32, (c, n): (Vec3, Vec3)) {
        let g = self.segs[root as usize];
        let tol = self.config.plane_tolerance_m;
        let voxel_reach = tol + 0.87 * self.config.voxel_m;
        self.seg.clear();
        for x in g.lo[0] - REACH..=g.hi[0] + REACH {
            for y in g.lo[1] - REACH..=g.hi[1] + REACH {
                for z in g.lo[2] - REACH..=g.hi[2] + REACH {
                    let Some(&j) = self.map.get(&coords_key([x, y, z])) else { continue };
                    let v = self.voxels[j as usize];
                    if n.dot(&(v.m.s / v.m.n - c)).abs() > voxel_reach {
                        continue;
                    }
                    for &(_, p) in &self.keys[v.start as usize..v.end as usize] {
                        let p = point_of(&self.pts[p as usize]);
                        // The band, not twice it: a wider gather let a neighbouring
                        // surface into issue 14's 4.5 m board and lost its plane.
                        if n.dot(&(p - c)).abs() < tol {
                            self.seg.push(p);
                        }
                    }
                }
            }
        }
    }

    /// The board's diagonal plus the size tolerance on either side (m).
    pub(super) fn board_diagonal(&self) -> f64 {
        self.spec.width.hypot(self.spec.height) + 2.0 * self.config.size_tolerance_m
    }
}

/// Mean squared distance of the points of `m` from the plane through `c` with normal `n`.
fn mean_square_distance(m: &Moments, c: &Vec3, n: &Vec3) -> f64 {
    let (cm, cov) = m.mean_cov();
    (n.transpose() * cov * n)[0] + n.dot(&(cm - c)).powi(2)
}

/// Integer voxel coordinates of a key.
fn key_coords(key: u64) -> [i64; 3] {
    let f = |k: u64| (k & KEY_MASK) as i64 - KEY_BIAS;
    [f(key >> 42), f(key >> 21), f(key)]
}

/// The key of integer voxel coordinates.
fn coords_key(c: [i64; 3]) -> u64 {
    let f = |x: i64| ((x + KEY_BIAS) as u64) & KEY_MASK;
    (f(c[0]) << 42) | (f(c[1]) << 21) | f(c[2])
}
