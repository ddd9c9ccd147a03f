//! Plane segments of a sweep: planar voxels grown into regions (normals within 15° of the
//! neighbour's and of the region's mean, coplanar centroids: two boards meeting in the
//! sweep stay apart); regions larger than a board (floor, walls, ceiling) drop out. Then
//! coplanar fragments of one board are merged, and every board-sized group's points are
//! gathered from its plane within its voxel box widened by 30 cm.
//!
//! Why the merge: a sparse ring pattern (a VLP-32C outside its dense band, 1–2.5° between
//! rings, i.e. 10–25 cm at 5 m) leaves voxel neighbourhoods that hold one scan line only;
//! those are not planar, so one board falls apart into fragments that each hold two or
//! three of its lines. Fragments whose union is still one thin plane no larger than the
//! board are one board.

use crate::geometry::Vec3;

use super::sweep::{point_of, Sweep};
use super::voxels::{coords_key, key_coords, neighbour_keys, smallest_eigen, Moments, Voxels};
use super::HoleConfig;

/// How many voxels beyond a group's own the gathering reaches: a sparse ring up to 30 cm
/// from the nearest planar voxel (a VLP-32C's 2.5° spacing at 6 m) still belongs.
const REACH: i64 = 3;

/// Label of voxels that belong to a region too large to be a board (walls, floor).
const HUGE: u32 = u32::MAX - 1;

/// The segmentation workspace, sized by the largest sweep seen.
#[derive(Debug, Default)]
pub(super) struct Segments {
    /// Each voxel's region (`u32::MAX` unlabelled, [`HUGE`] too large).
    label: Vec<u32>,
    queue: Vec<u32>,
    region_voxels: Vec<u32>,
    segs: Vec<Segment>,
    order: Vec<u32>,
    roots: Vec<u32>,
}

/// A region of planar voxels; at a union-find root also the whole merged group.
#[derive(Clone, Copy, Debug, Default)]
struct Segment {
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

impl Segments {
    /// The merged groups of planar voxels that may be boards (at most `diagonal` across,
    /// with enough points), in region order: each group's root.
    pub(super) fn groups(&mut self, voxels: &Voxels, config: &HoleConfig, diagonal: f64) -> &[u32] {
        self.grow_regions(voxels, config, diagonal);
        self.merge_fragments(config, diagonal);
        self.group_roots(config);
        &self.roots
    }

    /// Frees the buffers sized by the last sweep.
    pub(super) fn release(&mut self) {
        self.label = Vec::new();
        self.queue = Vec::new();
        self.region_voxels = Vec::new();
        self.segs = Vec::new();
        self.order = Vec::new();
        self.roots = Vec::new();
    }

    /// The `k`-th group's root ([`Segments::groups`]).
    pub(super) fn root(&self, k: usize) -> u32 {
        self.roots[k]
    }

    /// The plane of group `root` (its voxels' centroid and normal), or `None` when the
    /// group is longer than `diagonal`: a piece of wall or floor.
    #[inline(never)]
    pub(super) fn group_plane(&self, root: u32, diagonal: f64) -> Option<(Vec3, Vec3)> {
        let (c, cov) = self.segs[root as usize].m.mean_cov();
        let (l, n) = smallest_eigen(&cov);
        if l[2].max(0.0).sqrt() > diagonal / 2.0 {
            return None;
        }
        Some((c, n))
    }

    /// Collects into `seg` every point within the plane tolerance of the plane (`c`, `n`)
    /// in group `root`'s voxel box widened by [`REACH`] voxels (the scan lines whose own
    /// voxels were not planar).
    pub(super) fn gather(
        &self,
        root: u32,
        (c, n): (Vec3, Vec3),
        (voxels, sweep): (&Voxels, &Sweep),
        config: &HoleConfig,
        seg: &mut Vec<Vec3>,
    ) {
        let g = self.segs[root as usize];
        let tol = config.plane_tolerance_m;
        let voxel_reach = tol + 0.87 * config.voxel_m;
        let pts = sweep.points();
        seg.clear();
        for x in g.lo[0] - REACH..=g.hi[0] + REACH {
            for y in g.lo[1] - REACH..=g.hi[1] + REACH {
                for z in g.lo[2] - REACH..=g.hi[2] + REACH {
                    let Some(j) = voxels.index_of(coords_key([x, y, z])) else { continue };
                    let v = &voxels.all()[j as usize];
                    if n.dot(&(v.m.s / v.m.n - c)).abs() > voxel_reach {
                        continue;
                    }
                    for p in voxels.returns_of(v) {
                        let p = point_of(&pts[p as usize]);
                        // The band, not twice it: a wider gather let a neighbouring
                        // surface into the random-room study's 4.5 m board and lost its
                        // plane.
                        if n.dot(&(p - c)).abs() < tol {
                            seg.push(p);
                        }
                    }
                }
            }
        }
    }

    /// Grows planar voxels into regions (normals within the configured angle, coplanar
    /// centroids); regions larger than a board are dropped here.
    #[inline(never)]
    fn grow_regions(&mut self, voxels: &Voxels, config: &HoleConfig, diagonal: f64) {
        let all = voxels.all();
        let nv = all.len();
        self.label.clear();
        self.label.resize(nv, u32::MAX);
        self.region_voxels.clear();
        self.segs.clear();
        let cos_max = config.normal_angle_deg.to_radians().cos();
        let tol = config.plane_tolerance_m;
        let reach = diagonal + 0.3;
        for seed in 0..nv {
            if !all[seed].planar || self.label[seed] != u32::MAX {
                continue;
            }
            let id = self.segs.len() as u32;
            let start = self.region_voxels.len();
            self.queue.clear();
            self.queue.push(seed as u32);
            self.label[seed] = id;
            let mut too_big = false;
            let c0 = all[seed].centroid;
            // The sum of the region's voxel normals (each turned to the seed's side): a
            // neighbour must agree with the region's mean normal as well as with the voxel
            // it touches, or a chain of small turns across the voxels where two boards meet
            // (their neighbourhoods mixing both) grows two boards 28° apart into one region
            // too large to be a board (the random-room study's Pandar40P room 241).
            let mut normal_sum = all[seed].normal;
            while let Some(i) = self.queue.pop() {
                let vi = all[i as usize];
                self.region_voxels.push(i);
                too_big |= (vi.centroid - c0).norm() > reach;
                let mean_normal = normal_sum.normalize();
                for nk in neighbour_keys(vi.key) {
                    let Some(j) = voxels.index_of(nk) else { continue };
                    let vj = &all[j as usize];
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
            let seg = self.new_segment(voxels, id, start);
            self.segs.push(seg);
        }
    }

    /// The segment of the region in `region_voxels[start..]`.
    fn new_segment(&self, voxels: &Voxels, id: u32, start: usize) -> Segment {
        let mut m = Moments::default();
        let (mut lo, mut hi) = ([i64::MAX; 3], [i64::MIN; 3]);
        for &v in &self.region_voxels[start..] {
            let voxel = &voxels.all()[v as usize];
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
    fn merge_fragments(&mut self, config: &HoleConfig, diagonal: f64) {
        let n = self.segs.len();
        self.order.clear();
        self.order.extend(0..n as u32);
        let segs = &self.segs;
        self.order.sort_unstable_by(|&a, &b| segs[a as usize].x.total_cmp(&segs[b as usize].x));
        for ii in 0..n {
            let a = self.order[ii];
            for jj in ii + 1..n {
                let b = self.order[jj];
                if self.segs[b as usize].x - self.segs[a as usize].x > diagonal {
                    break;
                }
                let (ra, rb) = (self.find(a), self.find(b));
                if ra != rb {
                    if let Some(merged) = self.merged(ra, rb, config, diagonal) {
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
    fn merged(
        &self,
        a: u32,
        b: u32,
        config: &HoleConfig,
        diag: f64,
    ) -> Option<(Moments, Vec3, [i64; 3], [i64; 3])> {
        let (sa, sb) = (&self.segs[a as usize], &self.segs[b as usize]);
        let (ca, cb) = (sa.m.s / sa.m.n, sb.m.s / sb.m.n);
        if (ca - cb).norm() > diag {
            return None;
        }
        let (mut lo, mut hi) = (sa.lo, sa.hi);
        for k in 0..3 {
            lo[k] = lo[k].min(sb.lo[k]);
            hi[k] = hi[k].max(sb.hi[k]);
            if (hi[k] - lo[k]) as f64 * config.voxel_m > diag + config.voxel_m {
                return None;
            }
        }
        let mut m = sa.m;
        m.merge(&sb.m);
        let (c, cov) = m.mean_cov();
        let (l, normal) = smallest_eigen(&cov);
        let t = config.plane_tolerance_m / 2.0;
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
    fn group_roots(&mut self, config: &HoleConfig) {
        self.roots.clear();
        for s in 0..self.segs.len() as u32 {
            if self.find(s) == s && self.segs[s as usize].m.n >= config.min_points as f64 {
                self.roots.push(s);
            }
        }
    }
}

/// Mean squared distance of the points of `m` from the plane through `c` with normal `n`.
fn mean_square_distance(m: &Moments, c: &Vec3, n: &Vec3) -> f64 {
    let (cm, cov) = m.mean_cov();
    (n.transpose() * cov * n)[0] + n.dot(&(cm - c)).powi(2)
}
