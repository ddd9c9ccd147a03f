//! LiDAR board detection: every board of the room in a sweep (XYZ only, no region of
//! interest), its pose and its hole centres with an uncertainty each.
//!
//! Steps, all on buffers kept in a [`HoleDetector`] and reused from sweep to sweep:
//!
//! 1. **Voxels**: points binned in 10 cm voxels; each voxel's local plane comes from the
//!    moments of its 3×3×3 neighbourhood (closed-form 3×3 eigen solve). The sweep's scan
//!    lines are learnt on the way (a census of elevation angles: no ring numbers needed).
//! 2. **Plane segments** (`holes/segment.rs`): planar voxels grown into regions
//!    (normals within 15° of the neighbour's and of the region's mean, coplanar centroids:
//!    two boards meeting in the sweep stay apart); regions larger than a board (floor, walls,
//!    ceiling) drop out. Fragments of one plane that together stay thin and no larger
//!    than a board are merged: a sparse ring pattern (a VLP-32C outside its dense band)
//!    leaves one board in several pieces. Each group's points are gathered from its plane
//!    within its voxel box widened by 30 cm (lines whose own voxels were not planar).
//! 3. **Scan lines**: of each line only its longest run without a gap wider than a hole
//!    is kept (a gap that returns in front of the plane hide joins the run: a board behind
//!    another is left in pieces between the occluder's edges; an end next to an occluder
//!    loses its last 8 cm's returns in front of the plane, which may be the occluder's side
//!    closing in on it), and lines shorter than a
//!    fifth of the board drop out (poles, stands, clutter touching the plane; a line through
//!    a rolled board's corner hole, or across a partly hidden board, is shorter than the
//!    width but kept). The plane is refitted on what
//!    remains, and the points are gathered again about the refit while it still moves: the
//!    group's own plane, from voxels that may cover part of the board, can be degrees off.
//! 4. **Ray projection**: each inlier is moved along its own beam onto the fitted plane.
//!    The beam direction is exact and the range noise lies along it, so the projected
//!    points carry no range noise in the plane (the key to millimetre hole centres).
//!    Where a line leaves the plane for about a hole's width and comes back, **gap
//!    points** are laid at the line's own spacing: evidence of a hole even when the
//!    lines are sparse; none where the line's beams returned from in front of the plane
//!    (an occluder: the board may be solid behind it, and a stretch hidden beside a hole
//!    would widen the hole's gap). Fewer than four such gaps: refused before any search.
//! 5. **Mask search** (the paper's idea): the board model (outline minus holes) is slid
//!    over the projected points in (x, y, yaw); the score counts returns on solid board
//!    and gap points in holes, and penalises returns in holes, gap points on solid board
//!    and anything outside the outline. The coarse grid keeps up to four distinct optima
//!    (a board whose lines cross one row of holes only has rivals a hole spacing apart);
//!    each is refined on the medium grid and scored on every point there, those near the
//!    best are refined on and scored again, and the best is kept only when it leads every
//!    distinct rival by a margin ([`Refusal::Ambiguous`] otherwise). When coplanar
//!    clutter beside the board (a neighbouring board's edge) widens the points beyond the
//!    outline, the coarse centres span where the board lies within them.
//!    **See-through points** weigh in too: returns from behind the plane whose beams
//!    crossed it near the board, moved along their beams onto it. Such a beam met no
//!    board there, so they score −3 on solid board and nothing elsewhere: beams passing
//!    beside the outline pin its edges, and a line that runs into a hole whose far side
//!    is hidden (a board partly behind another, a corner hole a few centimetres from the
//!    edge) still shows the hole.
//!    Coarse, medium and fine grids (each scoring only
//!    the points within its window's reach of an edge, the points turned once per yaw;
//!    per yaw the centres lie on a lattice along the turned board's axes, so a point's
//!    mask column and row are found once and each centre costs one table lookup);
//!    the final estimate is the centroid of the fine grid's top plateau (every pose the
//!    points cannot tell from the best), its spread the pose covariance. A plateau wider
//!    than the window walks on at a coarser step.
//! 6. **Checks**: where the scan lines end must agree with the fitted outline (ends a few
//!    centimetres outside it mean a turned or shifted fit: [`Refusal::OutlineDisagrees`];
//!    returns past a side cut off from the board by a gap are a stand beside it, no end);
//!    beams must not pass through where the fitted board is solid
//!    ([`Refusal::SeenThrough`]); a hole counts a line as crossing it when the line leaves
//!    and re-enters the board across it with nothing in front hiding the gap, or returns
//!    from behind the plane inside it next to a return of its own on the hole's rim; the
//!    two best-seen holes need
//!    [`HoleConfig::min_hole_lines`] lines each ([`Refusal::FewLines`]);
//!    scan lines crossing each hole are counted; a board with fewer than two
//!    holes crossed by two lines, a wide plateau, points where the holes should be (a
//!    crate face), or most of the sensor's lines across its height missing (a structure
//!    smaller than a board) is refused with a [`Refusal`] instead of guessed. Every
//!    hole — well seen or not — is placed through the rigid board model. Once placed,
//!    the plane is fitted again on the returns within the outline; when that turns it by
//!    more than 0.3° (clutter beyond the outline within the band had tilted it) the
//!    board is placed again on that plane. Two groups that settle on one board (a stand
//!    below it whose gathered plane turns onto the board's) place it once, from the plane
//!    with more returns.
//! 7. **Uncertainty**: each hole's σ in the plane is the larger of what the plateau's
//!    pose covariance and the edge crossings' give it (each end of a scan line and each
//!    side of a gap crossed an edge of the model within one of the line's spacings: a
//!    position known to spacing/√12 along the line; the plateau alone can be far too
//!    narrow when one row of holes is crossed), plus the plane's offset and tilt errors,
//!    the latter divided by the cosine of the beam's incidence (the points were moved
//!    along their beams). On the simulator the RMS of error / σ is 0.63 (Pandar64-like)
//!    and 0.52 (VLP-32C-like) over 12 scenes each (`tests/holes_sim.rs`,
//!    `sigma_calibration_over_many_scenes`), 0.70–0.79 over issue 14's 600 random rooms
//!    per model: cautious, since many crossings together pin an edge closer than their
//!    quantisation taken as Gaussian, where the plateau alone (1.04) left 4–18 holes per
//!    200 rooms beyond 3σ against 0–10 now.
//!
//! **Where a board is expected** ([`HoleDetector::detect_expected`], `holes/expected.rs`):
//! given each board's predicted pose (a surveyed room's, through the camera's room pose and
//! the LiDAR's nominal mounting) steps 1–2 are replaced by the densest band about the
//! predicted plane near the predicted centre; steps 3–7 are the same.
//!
//! Several sweeps of a static scene may be concatenated into one `detect` call: the
//! lines interleave, the gaps and the plateau narrow (the simulator's four sweeps take the
//! mean hole error from 1.73 to 1.40 mm over three scenes, `tests/holes_sim.rs`; they
//! repeat the scan pattern, so what the lines' spacing leaves unknown stays).
//!
//! **Frames and hole order.** `pose` maps board → LiDAR (board x right, y down, z into the
//! board). A board whose hole pattern is symmetric under a 180° in-plane turn (the usual
//! four holes on a rectangle) cannot be told from its turned self by LiDAR alone; the
//! detector then picks the in-plane orientation whose board y axis points as close as
//! possible to the LiDAR's −z (down), so x points to the right as seen from the sensor
//! and an upright board gets the room's hole order. The association step may turn a
//! board by 180° about its z axis (reordering the holes 0↔3, 1↔2 for the usual pattern)
//! when the camera says otherwise; see [`LidarBoard::turned`].

mod expected;
pub use expected::EXPECTED_REACH_M;
mod segment;

use core::f64::consts::PI;
use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::path::{Path, PathBuf};

use crate::geometry::{Mat3, Se3, Vec3};
use crate::lidar::{pcd, Point};
use crate::target::{BoardSpec, Room, MAX_HOLES};

/// Tuning of the detector; [`HoleConfig::default`] suits 16–128-ring spinning LiDARs
/// and boards of about a metre at 2–10 m.
#[derive(Clone, Debug, PartialEq)]
pub struct HoleConfig {
    /// Voxel edge (m).
    pub voxel_m: f64,
    /// Points nearer or farther than this are ignored (m).
    pub range_m: (f64, f64),
    /// Largest angle between the normals of neighbouring voxels in one segment (degrees).
    pub normal_angle_deg: f64,
    /// Largest distance of a point from its segment's plane (m); about 3σ of range noise.
    pub plane_tolerance_m: f64,
    /// How much a segment may exceed the board outline (m).
    pub size_tolerance_m: f64,
    /// Fewest points on a board.
    pub min_points: usize,
    /// Largest pose uncertainty (1σ of the plateau, m) for a board to be placed.
    pub max_sigma_m: f64,
    /// Fewest scan lines that must cross each of the two best-seen holes for a board to
    /// be placed (at least 2). Two lines through a hole near a corner can leave the
    /// board's turn weak (issue 14's study placed one such board turned by 6° at 2); 3
    /// refuses it, but also many boards that 2 lines place within a few millimetres
    /// (`tests/holes_sim.rs`, the fixtures' calibrations), so the default is 2.
    pub min_hole_lines: u16,
}

impl Default for HoleConfig {
    fn default() -> Self {
        HoleConfig {
            voxel_m: 0.1,
            range_m: (0.5, 40.0),
            normal_angle_deg: 15.0,
            plane_tolerance_m: 0.07,
            size_tolerance_m: 0.12,
            min_points: 40,
            max_sigma_m: 0.01,
            min_hole_lines: 2,
        }
    }
}

/// One board found in the cloud.
#[derive(Clone, Debug, PartialEq)]
pub struct LidarBoard {
    /// Hole centres in the LiDAR frame (m), in the room's hole order (see the module doc
    /// on the 180° ambiguity).
    pub holes: heapless::Vec<Vec3, MAX_HOLES>,
    /// 1σ uncertainty of each hole centre (m, radial in the plane plus the plane's own).
    pub hole_sigma_m: heapless::Vec<f64, MAX_HOLES>,
    /// Scan lines (distinct elevations) that cross each hole.
    pub hole_scan_lines: heapless::Vec<u16, MAX_HOLES>,
    /// Board → LiDAR.
    pub pose: Se3,
    /// Unit plane normal in the LiDAR frame, pointing away from the sensor (board z).
    pub normal: Vec3,
    /// Points on the board plane.
    pub inliers: usize,
    /// RMS distance of the inliers from the plane (m).
    pub plane_rms_m: f64,
    /// 1σ of the in-plane pose: x, y (m) and yaw (rad).
    pub pose_sigma: [f64; 3],
}

impl LidarBoard {
    /// The same board turned by 180° about its z axis, holes renumbered to match: what the
    /// association step uses when the camera shows the board the other way round.
    pub fn turned(&self, spec: &BoardSpec) -> LidarBoard {
        let mut out = self.clone();
        let flip = Mat3::from_diagonal(&Vec3::new(-1.0, -1.0, 1.0));
        out.pose.rotation = self.pose.rotation * flip;
        for (k, h) in spec.holes.iter().enumerate() {
            let mirrored = nearest_hole(spec, -h[0], -h[1]);
            out.holes[k] = self.holes[mirrored];
            out.hole_sigma_m[k] = self.hole_sigma_m[mirrored];
            out.hole_scan_lines[k] = self.hole_scan_lines[mirrored];
        }
        out
    }
}

/// Why a board-sized plane was not placed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Refusal {
    /// Too few points on the plane.
    TooFewPoints { points: usize },
    /// Points lie where the holes would be: no hole pattern (a crate face, a door...).
    NoHolePattern { points_in_holes: usize },
    /// Fewer than four scan-line gaps of about a hole's width: no two holes can be crossed
    /// by two lines each (a crate face, a door, a board seen edge-on).
    NoHoleGaps { chords: usize },
    /// Fewer than three quarters of the sensor's scan lines that cross the board's height
    /// return from it: the structure is smaller than a board (or partly hidden).
    LinesMissing { seen: usize, expected: usize },
    /// Fewer than two holes crossed by at least two scan lines each.
    HolesUnseen { holes_with_two_lines: usize },
    /// The second best-seen hole is crossed by only `lines` scan lines, fewer than
    /// [`HoleConfig::min_hole_lines`] (`need`): too few to pin the board's turn.
    FewLines { lines: u16, need: u16 },
    /// The points do not pin the in-plane pose down (an outline edge or the holes unseen).
    Unconstrained { sigma_m: f64 },
    /// Two distinct in-plane poses (a hole spacing or a turn apart) fit the points about
    /// as well: mask scores `best` and `second`.
    Ambiguous { best: i64, second: i64 },
    /// `outside` of the `ends` scan-line ends lie outside the fitted outline: the fit
    /// disagrees with where the lines leave the board.
    OutlineDisagrees { outside: usize, ends: usize },
    /// `beams` beams passed through the plane (returned from behind it) where the fitted
    /// board is solid: no board lies there as fitted.
    SeenThrough { beams: usize },
}

impl core::fmt::Display for Refusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            Refusal::TooFewPoints { points } => write!(f, "only {points} points on the plane"),
            Refusal::NoHolePattern { points_in_holes } => {
                write!(f, "{points_in_holes} points where the holes should be: not a board")
            }
            Refusal::NoHoleGaps { chords } => write!(
                f,
                "only {chords} scan-line gap(s) of a hole's width (need 4: two holes crossed twice)"
            ),
            Refusal::LinesMissing { seen, expected } => write!(
                f,
                "only {seen} of the {expected} scan lines across the outline return from it"
            ),
            Refusal::HolesUnseen { holes_with_two_lines } => write!(
                f,
                "only {holes_with_two_lines} hole(s) crossed by two or more scan lines (need 2)"
            ),
            Refusal::FewLines { lines, need } => write!(
                f,
                "the second best-seen hole is crossed by only {lines} scan line(s) (need {need}): \
                 too few to pin the board's turn"
            ),
            Refusal::Unconstrained { sigma_m } => {
                write!(f, "in-plane position undetermined (σ {:.1} mm)", sigma_m * 1e3)
            }
            Refusal::Ambiguous { best, second } => write!(
                f,
                "two distinct in-plane poses fit about as well (mask score {best} and {second})"
            ),
            Refusal::OutlineDisagrees { outside, ends } => {
                write!(f, "{outside} of {ends} scan-line ends lie outside the fitted outline")
            }
            Refusal::SeenThrough { beams } => write!(
                f,
                "{beams} beam(s) passed through the plane where the fitted board would be solid"
            ),
        }
    }
}

/// A board-sized plane that was not placed, for diagnostics.
#[derive(Clone, Debug, PartialEq)]
pub struct RefusedBoard {
    /// Centroid of the plane's points (LiDAR frame).
    pub centroid: Vec3,
    pub normal: Vec3,
    pub points: usize,
    /// Scan lines crossing each hole at the best pose (empty when not counted).
    pub hole_scan_lines: heapless::Vec<u16, MAX_HOLES>,
    /// The mask search's best guess (board → LiDAR) when it ran; not to be trusted.
    pub best_guess: Option<Se3>,
    pub reason: Refusal,
}

/// Why `detect_file` failed.
#[derive(Debug, thiserror::Error)]
pub enum DetectError {
    #[error(transparent)]
    Pcd(#[from] pcd::PcdError),
    #[error("{file}: the room's board has no holes to find in a cloud")]
    NoHoles { file: PathBuf },
}

/// Reads a PCD cloud and finds every board of `room` in it (the `roomcal detect --cloud`
/// entry point).
pub fn detect_file(room: &Room, path: &Path) -> Result<Vec<LidarBoard>, DetectError> {
    if room.board.holes.is_empty() {
        return Err(DetectError::NoHoles { file: path.to_owned() });
    }
    let points = pcd::read(path)?;
    let mut detector = HoleDetector::new(&room.board, HoleConfig::default());
    let mut out = Vec::new();
    detector.detect(&points, &mut out);
    Ok(out)
}

/// The detector's workspace: every buffer is kept and reused from sweep to sweep, so after
/// the first sweep of a size no allocation happens.
#[derive(Debug)]
pub struct HoleDetector {
    spec: BoardSpec,
    config: HoleConfig,
    mask: Mask,
    coarse_mask: Mask,
    yaws: Vec<f64>,
    /// The returns within range, as the sweep holds them (f32: half a `Vec3`'s memory for
    /// the largest buffer a rig's daemon makes; [`point_of`] gives the same f64 values the
    /// sweep's f32 would).
    pts: Vec<[f32; 3]>,
    /// Every return as (azimuth, range, elevation), by elevation bin ([`RING_BIN_DEG`],
    /// bin `k` at `beams[bin_start[k]..bin_start[k + 1]]`), each bin by azimuth: what a
    /// stretch of a scan line returned ([`HoleDetector::hidden_stretch`]).
    beams: Vec<(f32, f32, f32)>,
    bin_start: Vec<u32>,
    /// The next free slot of each bin while `beams` is filled.
    bin_fill: Vec<u32>,
    keys: Vec<(u64, u32)>,
    voxels: Vec<Voxel>,
    map: HashMap<u64, u32, BuildHasherDefault<KeyHasher>>,
    label: Vec<u32>,
    queue: Vec<u32>,
    region_voxels: Vec<u32>,
    segs: Vec<segment::Segment>,
    order: Vec<u32>,
    roots: Vec<u32>,
    seg: Vec<Vec3>,
    /// Returns near the plane examined, on it or off it ([`HoleDetector::find_see_through`]).
    aside: Vec<Vec3>,
    /// Half-width (m) of the band about the board's plane that `seg` was last cut to.
    band: f64,
    flat: Vec<[f64; 2]>,
    sample: Vec<[f64; 2]>,
    gaps: Vec<[f64; 2]>,
    gap_sample: Vec<[f64; 2]>,
    through: Vec<[f64; 2]>,
    through_sample: Vec<[f64; 2]>,
    turned_through: Vec<[f64; 2]>,
    through_lines: Vec<(f64, u32)>,
    /// Returns in front of the plane examined (an occluder's), moved along their beams
    /// onto it (plane frame, with their elevations in `front_lines`, sorted).
    front: Vec<[f64; 2]>,
    front_lines: Vec<(f64, u32)>,
    crossings: Vec<(usize, f64)>,
    turned: Vec<[f64; 2]>,
    lattice: Vec<i32>,
    keep: Vec<bool>,
    hist: Vec<u32>,
    /// The other expected boards' centres near the one searched ([`HoleDetector::detect_expected`]).
    rivals: Vec<Vec3>,
    /// The expected board's x axis while a board is searched where it is expected: the
    /// coarse search then tries only the yaws near it ([`EXPECTED_YAW_DEG`]).
    expected_axis: Option<Vec3>,
    rings: Vec<u32>,
    spacings: Vec<f64>,
    residuals: Vec<f64>,
    run: Vec<(f64, u32)>,
    /// One scan line's returns in board coordinates ([`HoleDetector::edge_covariance`]).
    line_points: Vec<[f64; 2]>,
    /// The returns on a placed board ([`HoleDetector::plane_within_outline`]).
    on_board: Vec<Vec3>,
    turned_gaps: Vec<[f64; 2]>,
    lines: Vec<(f64, u32)>,
    refused: Vec<RefusedBoard>,
}

#[derive(Clone, Copy, Debug, Default)]
struct Voxel {
    key: u64,
    start: u32,
    end: u32,
    m: Moments,
    normal: Vec3,
    centroid: Vec3,
    planar: bool,
}

/// Point count, sum and sum of outer products.
#[derive(Clone, Copy, Debug, Default)]
struct Moments {
    n: f64,
    s: Vec3,
    ss: [f64; 6],
}

impl HoleDetector {
    /// A detector for boards of `spec`.
    pub fn new(spec: &BoardSpec, config: HoleConfig) -> Self {
        let mut yaws = Vec::new();
        let turns: &[f64] = if symmetric(spec) { &[0.0] } else { &[0.0, 180.0] };
        for &turn in turns {
            for k in -10..=10 {
                yaws.push((turn + 4.0 * k as f64).to_radians());
            }
        }
        HoleDetector {
            spec: spec.clone(),
            mask: Mask::new(spec, 0.002),
            coarse_mask: Mask::new(spec, 0.01),
            yaws,
            config,
            pts: Vec::new(),
            beams: Vec::new(),
            bin_start: Vec::new(),
            bin_fill: Vec::new(),
            keys: Vec::new(),
            voxels: Vec::new(),
            map: HashMap::default(),
            label: Vec::new(),
            queue: Vec::new(),
            region_voxels: Vec::new(),
            segs: Vec::new(),
            order: Vec::new(),
            roots: Vec::new(),
            seg: Vec::new(),
            aside: Vec::new(),
            band: 0.0,
            flat: Vec::new(),
            sample: Vec::new(),
            gaps: Vec::new(),
            gap_sample: Vec::new(),
            through: Vec::new(),
            through_sample: Vec::new(),
            turned_through: Vec::new(),
            through_lines: Vec::new(),
            front: Vec::new(),
            front_lines: Vec::new(),
            crossings: Vec::new(),
            turned: Vec::new(),
            lattice: Vec::new(),
            keep: Vec::new(),
            hist: Vec::new(),
            rivals: Vec::new(),
            expected_axis: None,
            rings: Vec::new(),
            spacings: Vec::new(),
            residuals: Vec::new(),
            run: Vec::new(),
            line_points: Vec::new(),
            on_board: Vec::new(),
            turned_gaps: Vec::new(),
            lines: Vec::new(),
            refused: Vec::new(),
        }
    }

    /// Board-sized planes of the last `detect` that were not placed, with the reason.
    pub fn refused(&self) -> &[RefusedBoard] {
        &self.refused
    }

    /// Frees the buffers sized by the last sweep (its points, beam index, voxels and
    /// regions: tens of MB for a rig's accumulated sweeps) until the next detection, which
    /// grows them again. The daemon calls it once a run's clouds are detected, so they do
    /// not sit idle under its solve, its report and between visits (README, "Speed and
    /// memory"); what was refused stays for the report.
    pub fn release_workspace(&mut self) {
        self.pts = Vec::new();
        self.beams = Vec::new();
        self.bin_start = Vec::new();
        self.bin_fill = Vec::new();
        self.keys = Vec::new();
        self.voxels = Vec::new();
        self.map = HashMap::default();
        self.label = Vec::new();
        self.queue = Vec::new();
        self.region_voxels = Vec::new();
        self.segs = Vec::new();
        self.order = Vec::new();
        self.roots = Vec::new();
        self.seg = Vec::new();
        self.aside = Vec::new();
        self.on_board = Vec::new();
    }

    /// Finds every board in `points` (LiDAR frame; several sweeps of a static scene may be
    /// concatenated) and writes them to `out` (cleared first).
    pub fn detect(&mut self, points: &[Point], out: &mut Vec<LidarBoard>) {
        out.clear();
        self.refused.clear();
        self.voxelise(points);
        self.local_planes();
        self.segment(out);
    }

    #[inline(never)]
    fn voxelise(&mut self, points: &[Point]) {
        self.load(points);
        self.keys.sort_unstable();
        self.voxels.clear();
        self.map.clear();
        let mut i = 0;
        while i < self.keys.len() {
            let key = self.keys[i].0;
            let start = i;
            let mut m = Moments::default();
            while i < self.keys.len() && self.keys[i].0 == key {
                m.add(&point_of(&self.pts[self.keys[i].1 as usize]));
                i += 1;
            }
            self.map.insert(key, self.voxels.len() as u32);
            let v = Voxel { key, start: start as u32, end: i as u32, m, ..Voxel::default() };
            self.voxels.push(v);
        }
    }

    /// The points within the range limits into `pts` (with their voxel keys, unsorted),
    /// and the sweep's scan lines learnt from them.
    fn load(&mut self, points: &[Point]) {
        let (near, far) = self.config.range_m;
        self.pts.clear();
        self.keys.clear();
        // Exactly the sweep's size, not a doubling's slack (the daemon frees it after each
        // run, `release_workspace`).
        self.pts.reserve_exact(points.len());
        self.keys.reserve_exact(points.len());
        let inv = 1.0 / self.config.voxel_m;
        for p in points {
            let v = p.position();
            let r = v.norm();
            if !r.is_finite() || r < near || r > far {
                continue;
            }
            let key = voxel_key(&(v * inv));
            self.keys.push((key, self.pts.len() as u32));
            self.pts.push([p.x, p.y, p.z]);
        }
        self.learn_rings();
        self.index_beams();
    }

    /// Plane of every voxel's 3×3×3 neighbourhood.
    #[inline(never)]
    fn local_planes(&mut self) {
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
            let t = self.config.plane_tolerance_m / 2.0;
            v.planar = l[0] < t * t && l[1] > spread2 && l[0] < 0.3 * l[1];
        }
    }

    /// Plane segments (regions of planar voxels, coplanar fragments merged); each
    /// board-sized one is examined.
    fn segment(&mut self, out: &mut Vec<LidarBoard>) {
        self.grow_regions();
        self.merge_fragments();
        for k in 0..self.group_roots() {
            let root = self.roots[k];
            let Some(group_plane) = self.group_plane(root) else { continue };
            if let Some(plane) = self.settled_plane(Region::Group(root), group_plane) {
                self.examine(plane, out);
            }
        }
    }

    /// Gathers the points of `region` about the plane `start` into `seg`, fits the board's
    /// plane on them ([`HoleDetector::fit_board_plane`]) and gathers again about the fit while
    /// it moves: the plane gathered about may be degrees off (a group's, from planar voxels
    /// that cover part of the board: 5° on boards pitched 26–34° at 6–8 m in issue 14's
    /// study, whose band left the board's far end out and whose refit, on the rest, stayed 2°
    /// off, putting holes off the tilt axis 2–4 cm out; or an expected pose's).
    fn settled_plane(&mut self, region: Region, start: (Vec3, Vec3)) -> Option<(Vec3, Vec3, f64)> {
        self.gather_in(region, start);
        let mut plane = self.fit_board_plane(start)?;
        let mut previous = start.1;
        for _ in 0..REGATHER_ROUNDS {
            if plane.1.angle(&previous) < REGATHER_ANGLE_RAD {
                break;
            }
            previous = plane.1;
            self.gather_in(region, (plane.0, plane.1));
            let Some(refit) = self.fit_board_plane((plane.0, plane.1)) else { break };
            plane = refit;
        }
        Some(plane)
    }

    fn gather_in(&mut self, region: Region, plane: (Vec3, Vec3)) {
        match region {
            Region::Group(root) => self.gather_in_group(root, plane),
            Region::Ball(centre, radius) => self.gather_in_ball(centre, radius, plane),
        }
    }

    /// Keeps the board's scan-line runs in `seg` (see [`HoleDetector::keep_board_runs`]),
    /// refits their plane (starting from `c`, `n`) and keeps the points within its band:
    /// the plane's centroid, normal (towards the sensor's far side, `n·c > 0`) and RMS.
    fn fit_board_plane(&mut self, (c, n): (Vec3, Vec3)) -> Option<(Vec3, Vec3, f64)> {
        let (mut c, mut n, mut rms) = (c, n, 0.0);
        self.keep_board_runs((c, n));
        // The band kept about the plane is three robust σ of the residuals (their median
        // absolute value): clutter touching the board a few centimetres off its plane (a box
        // at its foot) inflates the RMS and would stay within 3 RMS, tilting the plane.
        // Each pass chooses its band from every gathered point, so points an earlier,
        // tilted band left out come back (cutting one tail of the noise at a board's end
        // would keep the plane tilted); the plane is fitted on the points in the band on
        // scan lines that agree with it (`seg[..fitted]`, [`HoleDetector::lines_agreeing`]).
        let mut fitted = self.seg.len();
        let mut keep = self.config.plane_tolerance_m;
        for pass in 0..4 {
            (c, n, rms) = fit_plane(&self.seg[..fitted], c, n)?;
            if pass == 3 {
                break;
            }
            self.residuals.clear();
            self.residuals.extend(self.seg[..fitted].iter().map(|p| n.dot(&(p - c)).abs()));
            let mid = self.residuals.len() / 2;
            let mad = *self.residuals.select_nth_unstable_by(mid, f64::total_cmp).1;
            keep = (3.0 * 1.4826 * mad).clamp(0.01, self.config.plane_tolerance_m);
            fitted = self.lines_agreeing((c, n), keep, 1.4826 * mad);
        }
        self.seg.retain(|p| n.dot(&(p - c)).abs() < keep);
        self.band = keep;
        if n.dot(&c) < 0.0 {
            n = -n;
        }
        Some((c, n, rms))
    }

    /// Places the board on one group's points (in `seg`, within the band of the refitted
    /// plane `c`, `n` of RMS `rms`) when it is board-sized.
    fn examine(&mut self, plane: (Vec3, Vec3, f64), out: &mut Vec<LidarBoard>) {
        self.examine_on(plane, out, true);
    }

    /// [`HoleDetector::examine`]; once the board is placed, its plane is fitted again on
    /// the points within its outline alone, and when that turns it by more than
    /// [`REGATHER_ANGLE_RAD`] the board is placed again on that plane (`may_refit` false
    /// then): clutter beside the board that lies within the band (a box face crossing
    /// the board's plane above its top, issue 14's Pandar64 room 505) tilts a plane fitted
    /// on every point, and a tilt moves the far holes along the normal.
    #[inline(never)]
    fn examine_on(
        &mut self,
        (c, n, rms): (Vec3, Vec3, f64),
        out: &mut Vec<LidarBoard>,
        may_refit: bool,
    ) {
        let spec = self.spec.clone();
        let points = self.seg.len();
        if points < self.config.min_points {
            return;
        }
        let frame = self.flatten((c, n));
        let (_, ex, ey, _) = frame;
        self.find_see_through(frame);
        let chords = self.find_gaps();
        if !self.extent_fits(&spec) {
            return;
        }
        let refuse = |reason| RefusedBoard {
            centroid: c,
            normal: n,
            points,
            hole_scan_lines: heapless::Vec::new(),
            best_guess: None,
            reason,
        };
        if self.flat.len() < self.config.min_points {
            self.refused.push(refuse(Refusal::TooFewPoints { points }));
            return;
        }
        // Two holes crossed by two lines each leave at least four gaps: without them no
        // pose can place the board, and the mask search is not run.
        if chords < 4 {
            self.refused.push(refuse(Refusal::NoHoleGaps { chords }));
            return;
        }
        // Every distinct coarse optimum is refined and scored on all points; the best is
        // taken only when no other optimum comes close (the evidence is unambiguous).
        // The candidates are ranked at their medium-grid poses (5 mm, 0.5° cells); only
        // those near the best are refined on (the fine grid is most of the cost).
        let expected_yaw = self.expected_axis.map(|bx| bx.dot(&ey).atan2(bx.dot(&ex)));
        let candidates = self.coarse(expected_yaw);
        let mut first_refusal = None;
        let mut fits: heapless::Vec<(i64, Fit), CANDIDATES> = heapless::Vec::new();
        for &(_, coarse) in &candidates {
            match self.rough_check(coarse) {
                Err(r) => {
                    first_refusal.get_or_insert((r, coarse));
                }
                Ok(()) => {
                    let fit = self.medium(coarse);
                    let score = self.full_score(fit.pose);
                    let _ = fits.push((score, fit));
                }
            }
        }
        fits.sort_unstable_by_key(|f| core::cmp::Reverse(f.0));
        // Candidates the medium grid leaves close to the best are refined on and compared
        // again: a many-point board gains more from the fine alignment than the margin.
        let close = fits.first().map_or(i64::MAX, |f| f.0 - 2 * self.margin());
        for candidate in fits.iter_mut().filter(|f| f.0 >= close) {
            let fine = self.fine(candidate.1.pose);
            *candidate = (self.full_score(fine.pose), fine);
        }
        fits.sort_unstable_by_key(|f| core::cmp::Reverse(f.0));
        let Some(&(best_score, fit)) = fits.first() else {
            let (reason, coarse) = first_refusal.unwrap_or((
                (Refusal::HolesUnseen { holes_with_two_lines: 0 }, heapless::Vec::new()),
                [0.0; 3],
            ));
            let mut r = refuse(reason.0);
            r.hole_scan_lines = reason.1;
            let rough = Fit { pose: coarse, cov: [0.0; 9], at_window_edge: false };
            r.best_guess = Some(self.pose(&rough, (c, ex, ey, n)));
            self.refused.push(r);
            return;
        };
        let rival = fits[1..].iter().find(|(_, f)| !self.same_holes(&fit, f)).map(|(s, _)| *s);
        if let Some(second) = rival {
            if best_score - second < self.margin() {
                let mut r = refuse(Refusal::Ambiguous { best: best_score, second });
                r.best_guess = Some(self.pose(&fit, (c, ex, ey, n)));
                self.refused.push(r);
                return;
            }
        }
        let in_holes = self.points_in_holes(&fit, 0.015);
        if in_holes > 3 + self.flat.len() / 100 {
            let mut r = refuse(Refusal::NoHolePattern { points_in_holes: in_holes });
            r.best_guess = Some(self.pose(&fit, (c, ex, ey, n)));
            self.refused.push(r);
            return;
        }
        let (outside, ends) = self.line_ends_outside(&fit, frame);
        if outside > 1 + ends / 10 {
            let mut r = refuse(Refusal::OutlineDisagrees { outside, ends });
            r.best_guess = Some(self.pose(&fit, (c, ex, ey, n)));
            self.refused.push(r);
            return;
        }
        let beams = self.through_solid(&fit);
        if beams > 2 + self.flat.len() / 100 {
            let mut r = refuse(Refusal::SeenThrough { beams });
            r.best_guess = Some(self.pose(&fit, (c, ex, ey, n)));
            self.refused.push(r);
            return;
        }
        let lines = self.scan_lines_per_hole(&fit, SLACK);
        let seen = lines.iter().filter(|&&l| l >= 2).count();
        if seen < 2 {
            let mut r = refuse(Refusal::HolesUnseen { holes_with_two_lines: seen });
            r.hole_scan_lines = lines;
            r.best_guess = Some(self.pose(&fit, (c, ex, ey, n)));
            self.refused.push(r);
            return;
        }
        let mut ranked = lines.clone();
        ranked.sort_unstable_by(|a, b| b.cmp(a));
        let need = self.config.min_hole_lines;
        if ranked[1] < need {
            let mut r = refuse(Refusal::FewLines { lines: ranked[1], need });
            r.hole_scan_lines = lines;
            r.best_guess = Some(self.pose(&fit, (c, ex, ey, n)));
            self.refused.push(r);
            return;
        }
        // The sensor's scan lines that pass through the board's outline should return from
        // it: a structure that shows only part of the board's height is not one.
        let (seen_lines, expected) = self.lines_over_outline(&self.pose(&fit, (c, ex, ey, n)));
        if 4 * seen_lines < 3 * expected {
            self.refused.push(refuse(Refusal::LinesMissing { seen: seen_lines, expected }));
            return;
        }
        // The plateau's spread, or what the edge crossings allow where that is more.
        let Some(edges) = self.edge_covariance(&fit) else {
            self.refused.push(refuse(Refusal::Unconstrained { sigma_m: f64::INFINITY }));
            return;
        };
        let sigma_xy = fit.cov[0].max(fit.cov[4]).max(edges[0]).max(edges[4]).sqrt();
        if sigma_xy > self.config.max_sigma_m || fit.at_window_edge {
            let sigma_m = if fit.at_window_edge { f64::INFINITY } else { sigma_xy };
            self.refused.push(refuse(Refusal::Unconstrained { sigma_m }));
            return;
        }
        if may_refit {
            if let Some(plane) = self.plane_within_outline(&fit, (c, n)) {
                if plane.1.angle(&n) > REGATHER_ANGLE_RAD {
                    return self.examine_on(plane, out, false);
                }
            }
        }
        // Plane uncertainty: offset along the normal and tilt about either in-plane axis.
        let (su, sv) =
            self.flat.iter().fold((0.0, 0.0), |(a, b), p| (a + p[0] * p[0], b + p[1] * p[1]));
        let plane_sigma = [rms / (points as f64).sqrt(), rms / su.sqrt(), rms / sv.sqrt()];
        let board = self.board(&fit, &edges, (c, ex, ey, n), plane_sigma, rms, lines);
        self.keep_distinct(board, out);
    }

    /// Adds `board` to `out` unless a board placed before stands where it does; of two
    /// such the one fitted on more returns stays. Two groups can settle on one board: a
    /// stand or a box below it grows into a region of its own whose gathered plane turns
    /// onto the board's, placing it again a few degrees off on fewer of its returns
    /// (issue 14's Pandar40P room 208, Pandar64 room 347).
    fn keep_distinct(&self, board: LidarBoard, out: &mut Vec<LidarBoard>) {
        let apart = 0.5 * self.spec.width.min(self.spec.height);
        let same =
            out.iter().position(|b| (b.pose.translation - board.pose.translation).norm() < apart);
        match same {
            Some(k) if out[k].inliers >= board.inliers => {}
            Some(k) => out[k] = board,
            None => out.push(board),
        }
    }

    /// The plane (centroid, normal away from the sensor, RMS) of the returns in `seg` that
    /// lie on the board placed at `fit` (within its outline, outside its holes) on the
    /// plane (`c`, `n`) that `flat` was projected onto; `None` with too few of them.
    fn plane_within_outline(
        &mut self,
        fit: &Fit,
        (c, n): (Vec3, Vec3),
    ) -> Option<(Vec3, Vec3, f64)> {
        let (hw, hh, r) = (self.spec.width / 2.0, self.spec.height / 2.0, self.spec.hole_radius);
        self.on_board.clear();
        for (p, f) in self.seg.iter().zip(&self.flat) {
            let (x, y) = to_board(fit.pose, f);
            let solid = self.spec.holes.iter().all(|h| (x - h[0]).hypot(y - h[1]) > r);
            if x.abs() <= hw && y.abs() <= hh && solid {
                self.on_board.push(*p);
            }
        }
        if self.on_board.len() < self.config.min_points {
            return None;
        }
        let (c, n, rms) = fit_plane(&self.on_board, c, n)?;
        Some((c, if n.dot(&c) < 0.0 { -n } else { n }, rms))
    }

    /// The board frame of the plane (`c`, `n`) — `y` as close to the LiDAR's down as the
    /// plane allows — with `seg` projected along its beams into `flat` and each point's
    /// elevation in `lines`.
    fn flatten(&mut self, (c, n): (Vec3, Vec3)) -> (Vec3, Vec3, Vec3, Vec3) {
        let down = Vec3::new(0.0, 0.0, -1.0);
        let mut ey = down - n * n.dot(&down);
        if ey.norm() < 0.2 {
            ey = Vec3::new(-1.0, 0.0, 0.0) - n * (-n.x);
        }
        let ey = ey.normalize();
        let ex = ey.cross(&n);
        // Ray projection onto the plane n·p = d.
        let d = n.dot(&c);
        self.flat.clear();
        self.lines.clear();
        for p in &self.seg {
            // `flat[i]` is `seg[i]`'s: a beam along the plane (never on a board) unprojected.
            let s = n.dot(p);
            let q = if s.abs() < 1e-6 { p - c } else { p * (d / s) - c };
            self.flat.push([q.dot(&ex), q.dot(&ey)]);
            self.lines.push((elevation(p), self.flat.len() as u32 - 1));
        }
        (c, ex, ey, n)
    }

    /// Cheap checks of a coarse pose (within 2 cm) before it is refined: points deep
    /// inside the holes (no hole pattern there), or fewer than two holes crossed by any
    /// scan line (no refinement can make two of them well seen).
    fn rough_check(
        &mut self,
        coarse: [f64; 3],
    ) -> Result<(), (Refusal, heapless::Vec<u16, MAX_HOLES>)> {
        let rough = Fit { pose: coarse, cov: [0.0; 9], at_window_edge: false };
        let in_holes = self.points_in_holes(&rough, 0.035);
        if in_holes > 3 + self.flat.len() / 100 {
            let reason = Refusal::NoHolePattern { points_in_holes: in_holes };
            return Err((reason, heapless::Vec::new()));
        }
        let rough_lines = self.scan_lines_per_hole(&rough, 3.0 * SLACK);
        if rough_lines.iter().filter(|&&l| l >= 1).count() < 2 {
            return Err((Refusal::HolesUnseen { holes_with_two_lines: 0 }, rough_lines));
        }
        Ok(())
    }

    /// Scan-line ends (each line's first and last return along board x on the board: past
    /// returns a gap across the side cuts off, [`board_ends`]) between
    /// [`OUTLINE_TOLERANCE`] and [`OUTLINE_CLUTTER`] outside the fitted outline, and the
    /// ends counted: a line ends where it leaves the board, so a board turned or shifted in
    /// its plane leaves ends outside its outline (ends inside it may be an occluder's).
    /// A line past the board's side whose points there lie off the plane on average and
    /// that runs on beyond them without a jump in range
    /// ([`HoleDetector::ran_onto_another_surface`]) did not end at an edge: it ran onto a
    /// surface crossing the board's plane there at an angle (a box beside the board), and
    /// says nothing of the outline. A line that goes on in the plane (a wall) or ends at a corner of it
    /// still counts (issue 14's held-out rooms: a wall's patch placed as a board when every
    /// line running on was excused).
    fn line_ends_outside(&mut self, fit: &Fit, frame: (Vec3, Vec3, Vec3, Vec3)) -> (usize, usize) {
        let (hw, hh) = (self.spec.width / 2.0, self.spec.height / 2.0);
        // Ends far outside are coplanar clutter the line ran on into (a neighbouring
        // board's edge, a wall), not the pose's error: those do not count.
        let beyond = |d: f64| d > OUTLINE_TOLERANCE && d < OUTLINE_CLUTTER;
        let outside = |(x, y): (f64, f64)| {
            let (dx, dy) = (x.abs() - hw, y.abs() - hh);
            dx < OUTLINE_CLUTTER && dy < OUTLINE_CLUTTER && (beyond(dx) || beyond(dy))
        };
        self.lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let (mut bad, mut ends) = (0, 0);
        let mut run = core::mem::take(&mut self.run);
        for line in scan_lines(&self.lines).filter(|line| line.len() >= 3) {
            run.clear();
            run.extend(
                line.iter().map(|&(_, i)| (to_board(fit.pose, &self.flat[i as usize]).0, i)),
            );
            run.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            let (first, last) = board_ends(&run, hw, &mut self.spacings);
            for (i, towards) in [(run[first].1, -1.0), (run[last].1, 1.0)] {
                let p = to_board(fit.pose, &self.flat[i as usize]);
                if !outside(p) {
                    ends += 1;
                } else if !self.ran_onto_another_surface(line, (p, i as usize), towards, fit, frame)
                {
                    ends += 1;
                    bad += 1;
                }
            }
        }
        self.run = run;
        (bad, ends)
    }

    /// Whether scan `line`, whose end `(p, i)` (board coordinates, index in `seg`) lies past
    /// the board's side (`towards` +1 or −1 along board x, at `fit`, plane frame `frame`),
    /// ran on there onto a surface crossing the board's plane: its points beyond the side
    /// lie off the plane on average, by more than 2.5 of their mean's σ (the plane's band
    /// being 3σ), and it goes on beyond them off the plane ([`HoleDetector::runs_on`]).
    fn ran_onto_another_surface(
        &self,
        line: &[(f64, u32)],
        ((_, y), i): ((f64, f64), usize),
        towards: f64,
        fit: &Fit,
        frame: (Vec3, Vec3, Vec3, Vec3),
    ) -> bool {
        let (hw, hh) = (self.spec.width / 2.0, self.spec.height / 2.0);
        if y.abs() - hh > OUTLINE_TOLERANCE {
            return false; // above or below the board: the whole line is outside
        }
        let (c, _, _, n) = frame;
        let (mut sum, mut count) = (0.0, 0.0);
        for &(_, k) in line {
            let x = to_board(fit.pose, &self.flat[k as usize]).0;
            if towards * x > hw + OUTLINE_TOLERANCE {
                sum += n.dot(&(self.seg[k as usize] - c));
                count += 1.0;
            }
        }
        let sigma = self.band / 3.0;
        let turns_off = count >= 2.0 && (sum / count).abs() > 2.5 * sigma / f64::sqrt(count);
        turns_off && self.runs_on(i, towards, fit, frame)
    }

    /// Whether the scan line through `seg[i]` goes on beyond it along the board's x
    /// (`towards` +1 or −1, at `fit`, plane frame `frame`) off the board's plane: its next
    /// return in `aside` lies within [`RUN_ON_M`] of it and outside the band `seg` was cut
    /// to. The line then turned onto another surface without a jump in range; a line that
    /// goes on in the plane (a wall beyond a window of it) did not.
    fn runs_on(
        &self,
        i: usize,
        towards: f64,
        fit: &Fit,
        (c, ex, ey, n): (Vec3, Vec3, Vec3, Vec3),
    ) -> bool {
        let p = self.seg[i];
        let (e, d) = (elevation(&p), n.dot(&c));
        let board_x = |q: &Vec3| {
            let f = q * (d / n.dot(q)) - c;
            to_board(fit.pose, &[f.dot(&ex), f.dot(&ey)]).0
        };
        let x = board_x(&p);
        let next = self
            .aside
            .iter()
            .filter(|q| {
                (elevation(q) - e).abs() < LINE_GAP_RAD && towards * (board_x(q) - x) > 0.002
            })
            .map(|q| ((q - p).norm(), q))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        next.is_some_and(|(distance, q)| distance < RUN_ON_M && n.dot(&(q - c)).abs() >= self.band)
    }

    /// See-through points clearly on solid board at the fitted pose (2 cm inside the
    /// outline and outside the holes): beams that crossed the plane where the board should
    /// have returned them.
    fn through_solid(&self, fit: &Fit) -> usize {
        let (hw, hh) = (self.spec.width / 2.0 - 0.02, self.spec.height / 2.0 - 0.02);
        let r = self.spec.hole_radius + 0.02;
        let solid = |p: &[f64; 2]| {
            let (x, y) = to_board(fit.pose, p);
            x.abs() < hw
                && y.abs() < hh
                && self.spec.holes.iter().all(|h| (x - h[0]).hypot(y - h[1]) > r)
        };
        self.through.iter().filter(|p| solid(p)).count()
    }

    /// Whether two fits put every hole within 1.5 cm of the other's: one optimum.
    fn same_holes(&self, a: &Fit, b: &Fit) -> bool {
        self.spec.holes.iter().all(|h| {
            let at = |f: &Fit| {
                let (s, c) = f.pose[2].sin_cos();
                (f.pose[0] + c * h[0] - s * h[1], f.pose[1] + s * h[0] + c * h[1])
            };
            let (pa, pb) = (at(a), at(b));
            (pa.0 - pb.0).hypot(pa.1 - pb.1) < 0.015
        })
    }

    /// How much better than any distinct rival the best pose must score: a few returns or
    /// gap points of evidence, more on a board with many points.
    fn margin(&self) -> i64 {
        AMBIGUITY_MARGIN + (self.flat.len() / 200) as i64
    }

    /// Keeps of each scan line in `seg` only its longest run without a gap wider than a
    /// hole, or a gap the line's returns in front of the plane (`c`, `n`) hide
    /// ([`HoleDetector::hidden_stretch`]), and drops lines whose run is shorter than
    /// [`MIN_RUN`] of the board's width: a pole or stand below the board, a corner grazed,
    /// coplanar clutter beside it. Every line across a board spans its width in one run,
    /// broken only by the holes and what stands in front of it, unless it leaves through
    /// the top or bottom edge. (A board behind another, Pandar40P room 303: the pieces
    /// either side of its holes left between the occluder's edges, 17–20 cm of a 1.2 m
    /// board, were each too short, and the lines crossing two holes were dropped.)
    #[inline(never)]
    fn keep_board_runs(&mut self, plane: (Vec3, Vec3)) {
        let Some(first) = self.seg.first() else { return };
        let towards = first.y.atan2(first.x);
        self.lines.clear();
        for (i, p) in self.seg.iter().enumerate() {
            self.lines.push((elevation(p), i as u32));
        }
        self.lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        self.keep.clear();
        self.keep.resize(self.seg.len(), false);
        let min_run = MIN_RUN * self.spec.width;
        // A hole's chord, the line's spacing on either side (2–4 cm) and range noise.
        let max_gap = 2.0 * self.spec.hole_radius + 0.15;
        let mut start = 0;
        while start < self.lines.len() {
            let end = line_end(&self.lines, start);
            // The line's points by azimuth (relative to the plane's first point, so a
            // board behind the sensor does not wrap).
            self.run.clear();
            for &(_, i) in &self.lines[start..end] {
                let p = &self.seg[i as usize];
                let a = p.y.atan2(p.x) - towards;
                let a = if a > PI {
                    a - 2.0 * PI
                } else if a < -PI {
                    a + 2.0 * PI
                } else {
                    a
                };
                self.run.push((a, i));
            }
            start = end;
            self.run.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            // The line's azimuth step, found only when a gap needs it.
            let mut step = None;
            let (mut best, mut from) = ((0, 0, 0.0), 0);
            for k in 1..=self.run.len() {
                let split = k < self.run.len() && {
                    let (a, b) =
                        (self.seg[self.run[k - 1].1 as usize], self.seg[self.run[k].1 as usize]);
                    let gap = (b - a).norm();
                    gap > max_gap
                        && (gap > self.spec.width || {
                            let step = *step
                                .get_or_insert_with(|| median_step(&self.run, &mut self.spacings));
                            !self.hidden_stretch(&a, &b, plane, step)
                        })
                };
                if k == self.run.len() || split {
                    let len = (self.seg[self.run[k - 1].1 as usize]
                        - self.seg[self.run[from].1 as usize])
                        .norm();
                    if len > best.2 {
                        best = (from, k, len);
                    }
                    from = k;
                }
            }
            if best.2 >= min_run {
                let step = *step.get_or_insert_with(|| median_step(&self.run, &mut self.spacings));
                let (from, to) = self.unoccluded_part(best.0, best.1, plane, step);
                for &(_, i) in &self.run[from..to] {
                    self.keep[i as usize] = true;
                }
            }
        }
        let mut k = 0;
        let keep = &self.keep;
        self.seg.retain(|_| {
            k += 1;
            keep[k - 1]
        });
    }

    /// The part of the run `run[from..to]` (one line's returns by azimuth, `step` apart)
    /// left when each end next to an occluder loses its last [`OCCLUDED_END_M`]: where the
    /// line's next beams beyond an end return from in front of the plane (beyond its band),
    /// the returns just inside that end may be the occluder's own side closing in on the
    /// plane. Issue 14's room 783 (Pandar40P and VLP-32C): half a board hidden by a box
    /// 16–23 cm in front, whose side reached within 2–7 cm of the plane along the seen
    /// half's edge; in the band, those returns tilted the plane fitted on that half 1.5–1.8°
    /// and put its unseen holes 2 cm out.
    fn unoccluded_part(
        &self,
        from: usize,
        to: usize,
        plane: (Vec3, Vec3),
        step: f64,
    ) -> (usize, usize) {
        let (mut from, mut to) = (from, to);
        if to - from < 2 || step <= 0.0 {
            return (from, to);
        }
        let margin = self.config.plane_tolerance_m;
        let beyond = 3.0 * step;
        let (c, n) = plane;
        let forward = if n.dot(&c) < 0.0 { n } else { -n };
        let in_front = |p: &Vec3, end: &Vec3| {
            (p - end).norm() < OCCLUDED_END_M && forward.dot(&(p - c)) > OCCLUDED_FRONT_M
        };
        let first = self.seg[self.run[from].1 as usize];
        let az = first.y.atan2(first.x);
        if az - beyond > -PI
            && self.returns_in_front(elevation(&first), (az - beyond, az), plane, margin) > 0
        {
            while from < to && in_front(&self.seg[self.run[from].1 as usize], &first) {
                from += 1;
            }
        }
        let last = self.seg[self.run[to - 1].1 as usize];
        let az = last.y.atan2(last.x);
        if az + beyond < PI
            && self.returns_in_front(elevation(&last), (az, az + beyond), plane, margin) > 0
        {
            while to > from && in_front(&self.seg[self.run[to - 1].1 as usize], &last) {
                to -= 1;
            }
        }
        (from, to)
    }

    /// Whether the stretch of a scan line between its returns `a` and `b` on the plane
    /// (`c`, `n`), its beams `step` (rad of azimuth) apart, was hidden by something in
    /// front: all of it but a hole's chord (what may have been seen through) returned
    /// from more than [`BEHIND_M`] in front of the plane.
    fn hidden_stretch(&self, a: &Vec3, b: &Vec3, (c, n): (Vec3, Vec3), step: f64) -> bool {
        let (e, d) = (elevation(a), n.dot(&c));
        let (az_a, az_b) = (a.y.atan2(a.x), b.y.atan2(b.x));
        if (az_a - az_b).abs() > PI || d <= 0.0 || step <= 0.0 {
            return false; // across the sensor's back, or a plane through the sensor
        }
        let (lo, hi) = (az_a.min(az_b), az_a.max(az_b));
        let front = self.returns_in_front(e, (lo, hi), (c, n), BEHIND_M);
        // The stretch and a hole's chord (with a spacing either side) in azimuth.
        let stretch = hi - lo;
        let chord = (2.0 * self.spec.hole_radius) / a.norm().min(b.norm()) + 2.0 * step;
        front > 0 && front as f64 * step >= stretch - chord
    }

    /// Returns of the scan line at elevation `e` between azimuths `lo` and `hi` (open
    /// interval, rad) that lie more than `margin` in front of the plane (`c`, `n`, `n·c > 0`).
    fn returns_in_front(
        &self,
        e: f64,
        (lo, hi): (f64, f64),
        (c, n): (Vec3, Vec3),
        margin: f64,
    ) -> usize {
        let d = n.dot(&c);
        let (lo, hi) = (lo as f32, hi as f32);
        let mut front = 0usize;
        for bin in ring_bin(e - LINE_GAP_RAD)..=ring_bin(e + LINE_GAP_RAD) {
            let beams = &self.beams[self.bin_start[bin] as usize..self.bin_start[bin + 1] as usize];
            let from = beams.partition_point(|q| q.0 <= lo);
            for &(az, range, el) in beams[from..].iter().take_while(|q| q.0 < hi) {
                let (el, az) = (f64::from(el), f64::from(az));
                if (el - e).abs() >= LINE_GAP_RAD {
                    continue;
                }
                let u = Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin());
                let to_plane = d / n.dot(&u);
                if to_plane > 0.0 && f64::from(range) < to_plane - margin {
                    front += 1;
                }
            }
        }
        front
    }

    /// Moves the points within `band` of the plane (`c`, `n`) on scan lines whose mean
    /// residual (of those points) is within [`LINE_Z`] of its σ (σ the points' own /
    /// √count) to the front of `seg` and returns how many there are. Range noise is
    /// zero-mean along every line, so a line off the plane on average carries something
    /// else within the band: the edge of an occluder in front, clutter at the board's foot,
    /// a surface crossing the plane at a shallow angle. Left in the fit they tilt the plane
    /// by degrees, turning the projected points and so the hole mask's fit. When most
    /// points in the band disagree the plane itself is in doubt: all of them are fitted.
    fn lines_agreeing(&mut self, (c, n): (Vec3, Vec3), band: f64, sigma: f64) -> usize {
        self.lines.clear();
        for (i, p) in self.seg.iter().enumerate() {
            if n.dot(&(p - c)).abs() < band {
                self.lines.push((elevation(p), i as u32));
            }
        }
        self.lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        self.keep.clear();
        self.keep.resize(self.seg.len(), false);
        let mut agreeing = 0;
        for line in scan_lines(&self.lines) {
            let sum: f64 = line.iter().map(|&(_, i)| n.dot(&(self.seg[i as usize] - c))).sum();
            let count = line.len() as f64;
            if (sum / count).abs() <= LINE_Z * sigma / count.sqrt() {
                agreeing += line.len();
                for &(_, i) in line {
                    self.keep[i as usize] = true;
                }
            }
        }
        if 2 * agreeing < self.lines.len() {
            for &(_, i) in &self.lines {
                self.keep[i as usize] = true;
            }
        }
        // The chosen points first, swapped in place (no buffer; every later step sorts).
        let mut next = 0;
        for i in 0..self.seg.len() {
            if self.keep[i] {
                self.seg.swap(next, i);
                self.keep.swap(next, i);
                next += 1;
            }
        }
        next
    }

    /// The sensor's scan lines as seen in this sweep: elevation bins (0.05°) holding
    /// returns, so no ring numbers or beam table are needed.
    #[inline(never)]
    fn learn_rings(&mut self) {
        self.rings.clear();
        self.rings.resize(RING_BINS, 0);
        for p in self.pts.iter().map(point_of) {
            self.rings[ring_bin(elevation(&p))] += 1;
        }
    }

    /// Fills `beams` from `pts`: a counting sort by elevation bin (`rings` holds the
    /// counts), then each bin by azimuth (an unstable sort: it allocates nothing). A
    /// counting sort first, as the sweep's bins are few and large, instead of one sort of
    /// every return on (bin, azimuth).
    #[inline(never)]
    fn index_beams(&mut self) {
        self.bin_start.clear();
        self.bin_start.push(0);
        for &count in &self.rings {
            let last = *self.bin_start.last().unwrap_or(&0);
            self.bin_start.push(last + count);
        }
        self.beams.clear();
        self.beams.resize(self.pts.len(), (0.0, 0.0, 0.0));
        self.bin_fill.clear();
        self.bin_fill.extend_from_slice(&self.bin_start);
        for p in self.pts.iter().map(point_of) {
            let e = elevation(&p);
            let slot = &mut self.bin_fill[ring_bin(e)];
            self.beams[*slot as usize] = (p.y.atan2(p.x) as f32, p.norm() as f32, e as f32);
            *slot += 1;
        }
        for k in 0..RING_BINS {
            let (from, to) = (self.bin_start[k] as usize, self.bin_start[k + 1] as usize);
            self.beams[from..to].sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        }
    }

    /// Scan lines on the plane (elevation clusters in `lines`) and the sensor's lines whose
    /// elevation lies within the board's height at `pose`.
    fn lines_over_outline(&self, pose: &Se3) -> (usize, usize) {
        // Lines that cross the board's middle (its top and bottom edges' midpoints, 3 cm
        // in): those cross the whole width, corners clipped at a tilt do not count.
        let hh = self.spec.height / 2.0 - 0.03;
        let (mut lo, mut hi) = (f64::MAX, f64::MIN);
        for (x, y) in [(0.0, -hh), (0.0, hh)] {
            let p = pose.act(&Vec3::new(x, y, 0.0));
            let e = elevation(&p);
            (lo, hi) = (lo.min(e), hi.max(e));
        }
        // A line is a run of occupied bins with a few returns (not a stray point).
        let mut expected = 0;
        let mut inside = false;
        for b in ring_bin(lo)..=ring_bin(hi) {
            let occupied = self.rings[b] >= 3;
            if occupied && !inside {
                expected += 1;
            }
            inside = occupied;
        }
        let seen = scan_lines(&self.lines).filter(|line| line.len() >= 3).count();
        (seen, expected)
    }

    /// Gap points: where a scan line crossing the plane returned nothing between two of its
    /// returns over about a hole's width, points at the line's own spacing (plane frame).
    /// They tell the mask search where the holes are even when the lines are sparse.
    /// Returns how many gaps could be a line crossing a hole by the (looser) measure of
    /// [`HoleDetector::scan_lines_per_hole`].
    #[inline(never)]
    fn find_gaps(&mut self) -> usize {
        let mut chords = 0;
        self.gaps.clear();
        let (lines, flat) = (&mut self.lines, &self.flat);
        lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let max_chord = 2.0 * self.spec.hole_radius + 0.01;
        let loose_chord = 2.0 * (self.spec.hole_radius + HOLE_BAND) + 0.01;
        let mut start = 0;
        while start < lines.len() {
            let end = line_end(lines, start);
            let line = &mut lines[start..end];
            start = end;
            if line.len() < 4 {
                continue;
            }
            line.sort_unstable_by(|a, b| flat[a.1 as usize][0].total_cmp(&flat[b.1 as usize][0]));
            let (first, last) = (flat[line[0].1 as usize], flat[line[line.len() - 1].1 as usize]);
            let spacing = (last[0] - first[0]) / (line.len() - 1) as f64;
            for w in line.windows(2) {
                let (a, b) = (flat[w[0].1 as usize], flat[w[1].1 as usize]);
                let d = (b[0] - a[0]).hypot(b[1] - a[1]);
                // The line's spacing along the board's x is at most 1.3× shorter (40° yaw).
                if d > 1.1 * spacing && d < loose_chord + 2.0 * spacing {
                    chords += 1;
                }
                // A hole's chord plus up to a spacing on either side.
                if d <= 2.0 * spacing || d >= max_chord + 2.0 * spacing {
                    continue;
                }
                let k = (d / spacing) as usize - 1;
                let e = w[0].0;
                let from = self.front_lines.partition_point(|l| l.0 < e - LINE_GAP_RAD);
                let to = self.front_lines.partition_point(|l| l.0 < e + LINE_GAP_RAD);
                let occluders = &self.front_lines[from..to];
                for j in 1..=k {
                    let f = j as f64 / (k + 1) as f64;
                    let g = [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])];
                    // A beam there returned from in front of the plane: the board may be
                    // solid behind the occluder, so the gap says nothing of a hole.
                    let hidden = occluders.iter().any(|&(_, i)| {
                        let o = self.front[i as usize];
                        (o[0] - g[0]).hypot(o[1] - g[1]) < spacing
                    });
                    if !hidden {
                        self.gaps.push(g);
                    }
                }
            }
        }
        chords
    }

    /// Whether the points' smallest bounding rectangle fits the board outline, a few
    /// stray points (3 %: clutter touching the plane, an occluder's edge) left out on
    /// each side, or, for points up to twice the board's size, whether one board-sized
    /// window holds [`BOARD_WINDOW_SHARE`] of them; the mask search weighs the rest.
    #[inline(never)]
    fn extent_fits(&mut self, spec: &BoardSpec) -> bool {
        let tol = self.config.size_tolerance_m;
        let trim = 3 + self.flat.len() * 3 / 100;
        let mut best = (f64::MAX, 0.0, 0.0);
        for k in -15..=15 {
            let (s, co) = (k as f64 * 3.0).to_radians().sin_cos();
            let a = self.trimmed_span(|p| co * p[0] + s * p[1], trim);
            let b = self.trimmed_span(|p| -s * p[0] + co * p[1], trim);
            if a * b < best.0 {
                best = (a * b, a, b);
            }
        }
        let (_, a, b) = best;
        // Every scan line across the board spans its width unless something hides part of it;
        // the height may be covered only in part.
        if a < MIN_WIDTH_SEEN * spec.width {
            return false;
        }
        if a <= spec.width + tol && b <= spec.height + tol {
            return true;
        }
        // Wider or taller than the board: a board with clutter in its plane beside or below
        // it (a box it stands by, the floor's crossing of its plane under a pitched board,
        // a stand) or no board. Issue 14's study missed 10 of 606 placeable boards so. The
        // mask search places a board among such points; it is tried when one board-sized
        // window holds nearly all of them.
        let (w, h) = (spec.width + tol, spec.height + tol);
        a <= 2.0 * w && b <= 2.0 * h && self.board_window_share(w, h) >= BOARD_WINDOW_SHARE
    }

    /// Largest share of `flat` inside one `w` × `h` window, turned in 3° steps up to ±45°
    /// (counted on a 4 cm grid through a summed-area table kept in `hist`).
    fn board_window_share(&mut self, w: f64, h: f64) -> f64 {
        const CELL: f64 = 0.04;
        const SIDE: usize = 128;
        let (kw, kh) = (((w / CELL).round() as usize).max(1), ((h / CELL).round() as usize).max(1));
        let mut most = 0;
        for k in -15..=15 {
            let (s, co) = (k as f64 * 3.0).to_radians().sin_cos();
            let turn = |p: &[f64; 2]| (co * p[0] + s * p[1], -s * p[0] + co * p[1]);
            let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
            for p in &self.flat {
                let (u, v) = turn(p);
                (lo, hi) = ([lo[0].min(u), lo[1].min(v)], [hi[0].max(u), hi[1].max(v)]);
            }
            let cells = |d: usize| (((hi[d] - lo[d]) / CELL) as usize + 1).min(SIDE);
            let (nu, nv) = (cells(0), cells(1));
            // The table's row and column 0 stay zero: entry (i, j) sums the cells < (i, j).
            let stride = nu + 1;
            self.hist.clear();
            self.hist.resize(stride * (nv + 1), 0);
            for p in &self.flat {
                let (u, v) = turn(p);
                let (i, j) = (((u - lo[0]) / CELL) as usize, ((v - lo[1]) / CELL) as usize);
                if i < nu && j < nv {
                    self.hist[(j + 1) * stride + i + 1] += 1;
                }
            }
            for j in 1..=nv {
                for i in 1..=nu {
                    self.hist[j * stride + i] += self.hist[j * stride + i - 1]
                        + self.hist[(j - 1) * stride + i]
                        - self.hist[(j - 1) * stride + i - 1];
                }
            }
            let at = |i: usize, j: usize| self.hist[j * stride + i];
            for j in kh.min(nv)..=nv {
                for i in kw.min(nu)..=nu {
                    let (i0, j0) = (i - kw.min(i), j - kh.min(j));
                    most = most.max(at(i, j) + at(i0, j0) - at(i0, j) - at(i, j0));
                }
            }
        }
        most as f64 / self.flat.len().max(1) as f64
    }

    /// Span of `f` over `flat` without the `trim` lowest and highest values (1 cm bins).
    fn trimmed_span(&mut self, f: impl Fn(&[f64; 2]) -> f64, trim: usize) -> f64 {
        let (mut lo, mut hi) = (f64::MAX, f64::MIN);
        for p in &self.flat {
            let x = f(p);
            (lo, hi) = (lo.min(x), hi.max(x));
        }
        let bins = ((hi - lo) / 0.01) as usize + 1;
        if bins > 1000 {
            return hi - lo; // far larger than any board
        }
        self.hist.clear();
        self.hist.resize(bins, 0);
        for p in &self.flat {
            self.hist[((f(p) - lo) / 0.01) as usize] += 1;
        }
        let first = cut(self.hist.iter(), trim);
        let last = bins - 1 - cut(self.hist.iter().rev(), trim);
        (last.saturating_sub(first)) as f64 * 0.01
    }

    /// Coarse mask search over (x, y, yaw) on a subsample: 4° steps in yaw, 4 cm then
    /// 2 cm in translation. Yaws ±40° about the "y down" convention (and the same turned
    /// by 180° for an asymmetric hole pattern) are tried. Returns the best distinct optima
    /// (best first): a board whose holes leave its pose weak (lines only across one row of
    /// holes, the outline's top and bottom unseen) has several, one a hole spacing from
    /// another, and the subsample cannot be trusted to rank them. With `expected` (the
    /// yaw a board is expected at, [`HoleDetector::detect_expected`]) only the yaws within
    /// [`EXPECTED_YAW_DEG`] of it, either way round, are tried.
    #[inline(never)]
    fn coarse(&mut self, expected: Option<f64>) -> Candidates {
        let stride = (self.flat.len() / COARSE_POINTS).max(1);
        let (hw, hh) = (self.spec.width / 2.0, self.spec.height / 2.0);
        let cell = self.coarse_mask.step;
        let mut found = Candidates::new();
        for k in 0..self.yaws.len() {
            let yaw = self.yaws[k];
            if expected.is_some_and(|e| !near_yaw(yaw, e)) {
                continue;
            }
            // The points in board-aligned axes (coarse cells); the board centre is then a
            // plain shift.
            self.sample.clear();
            self.sample.extend(self.flat.iter().step_by(stride));
            self.gap_sample.clear();
            self.gap_sample.extend(self.gaps.iter().step_by(stride));
            self.through_sample.clear();
            self.through_sample.extend(self.through.iter().step_by(stride));
            self.coarse_mask.turn(&self.sample, yaw, &mut self.turned);
            self.coarse_mask.turn(&self.gap_sample, yaw, &mut self.turned_gaps);
            self.coarse_mask.turn(&self.through_sample, yaw, &mut self.turned_through);
            let mut lo = [f64::MAX; 2];
            let mut hi = [f64::MIN; 2];
            for p in &self.turned {
                lo = [lo[0].min(p[0] * cell), lo[1].min(p[1] * cell)];
                hi = [hi[0].max(p[0] * cell), hi[1].max(p[1] * cell)];
            }
            // Board centres for which the board covers the points or, when the points
            // span more than the board (coplanar clutter beside it: a neighbouring board,
            // a wall), for which the board lies within them.
            let range = |lo: f64, hi: f64, half: f64| {
                let (a, b) = (hi - half, lo + half);
                (a.min(b) - 0.04, a.max(b) + 0.04)
            };
            let (ur, vr) = (range(lo[0], hi[0], hw), range(lo[1], hi[1], hh));
            // Centres at twice the coarse step (at most ~100 per yaw: a wide window, little
            // of the board seen, takes larger steps), then the best
            // ones' neighbours at the coarse step; the medium grid recentres from there.
            let area = (ur.1 - ur.0 + COARSE_STEP) * (vr.1 - vr.0 + COARSE_STEP);
            let step = (area / 100.0).sqrt().clamp(2.0 * COARSE_STEP, 4.0 * COARSE_STEP);
            // (A window wider than a lattice holds, never a board's, takes larger steps still.)
            let widest = (ur.1 - ur.0).max(vr.1 - vr.0);
            let step = step.max(widest / (MAX_LATTICE - 1) as f64);
            let n = [((ur.1 - ur.0) / step) as usize + 1, ((vr.1 - vr.0) / step) as usize + 1];
            let first = [ur.0 / cell, vr.0 / cell];
            self.lattice.resize(n[0] * n[1], 0);
            let e = Evidence {
                returns: &self.turned,
                gaps: &self.turned_gaps,
                through: &self.turned_through,
            };
            self.coarse_mask.score_lattice(e, first, step / cell, n, &mut self.lattice);
            let mut here = Candidates::new();
            for i in 0..n[0] {
                for j in 0..n[1] {
                    let (u, v) = (ur.0 + i as f64 * step, vr.0 + j as f64 * step);
                    let score = self.lattice[j * n[0] + i] as i64;
                    keep_best(&mut here, score, [u, v, yaw], 2.0 * step);
                }
            }
            let half = (step / COARSE_STEP / 2.0).ceil() as usize;
            let side = 2 * half + 1;
            for &(_, [u0, v0, _]) in here.iter().take(2) {
                let (u1, v1) = (u0 - half as f64 * COARSE_STEP, v0 - half as f64 * COARSE_STEP);
                let e = self.turned_evidence();
                let mut local_scores = [0i32; 81];
                self.coarse_mask.score_lattice(
                    e,
                    [u1 / cell, v1 / cell],
                    COARSE_STEP / cell,
                    [side, side],
                    &mut local_scores,
                );
                let mut local = (i64::MIN, [0.0; 3]);
                for a in 0..side {
                    for b in 0..side {
                        let score = local_scores[b * side + a] as i64;
                        if score > local.0 {
                            let (u, v) = (u1 + a as f64 * COARSE_STEP, v1 + b as f64 * COARSE_STEP);
                            // The centre back in the plane frame.
                            let (s, c) = yaw.sin_cos();
                            local = (score, [c * u - s * v, s * u + c * v, yaw]);
                        }
                    }
                }
                keep_best(&mut found, local.0, local.1, DISTINCT_M);
            }
        }
        found
    }

    /// The evidence turned by [`Mask::turn`] (`turned`, `turned_gaps`, `turned_through`).
    fn turned_evidence(&self) -> Evidence<'_> {
        Evidence { returns: &self.turned, gaps: &self.turned_gaps, through: &self.turned_through }
    }

    /// See-through points: returns from behind the plane (beyond it along their beams by
    /// more than the range noise) whose beams crossed it within the board's reach, moved
    /// along their beams onto the plane (plane frame, into `through`; their elevations in
    /// `through_lines`, sorted). Such a beam met no board where it crossed the plane: that
    /// spot is a hole or beside the board, never solid board. This is the evidence a line
    /// leaves where it runs into a hole and the board beyond is hidden or too narrow to
    /// return (a corner hole a few centimetres from the edge), and where lines pass just
    /// beside the outline. Returns as far in front of the plane (an occluder's) go the
    /// same way into `front` and `front_lines`: where a gap is hidden, not a hole
    /// ([`HoleDetector::find_gaps`]). The returns within [`ASIDE_M`] of the plane, on it or
    /// not, go into `aside`: where a scan line runs on past the board's points
    /// ([`HoleDetector::line_ends_outside`]).
    #[inline(never)]
    fn find_see_through(&mut self, (c, ex, ey, n): (Vec3, Vec3, Vec3, Vec3)) {
        self.through.clear();
        self.through_lines.clear();
        self.front.clear();
        self.front_lines.clear();
        self.aside.clear();
        let d = n.dot(&c);
        let reach2 = (self.board_diagonal() / 2.0).powi(2);
        let aside2 = (self.board_diagonal() / 2.0 + OUTLINE_CLUTTER).powi(2);
        for p in self.pts.iter().map(point_of) {
            let s = n.dot(&p);
            if (s - d).abs() < ASIDE_M && d > 0.0 && (p * (d / s) - c).norm_squared() < aside2 {
                self.aside.push(p);
            }
            if s <= 0.0 || d <= 0.0 {
                continue;
            }
            let t = d / s;
            let q = p * t - c;
            if q.norm_squared() > reach2 || (1.0 - t).abs() * p.norm() < BEHIND_M {
                continue;
            }
            if t < 1.0 {
                self.through_lines.push((elevation(&p), self.through.len() as u32));
                self.through.push([q.dot(&ex), q.dot(&ey)]);
            } else {
                self.front_lines.push((elevation(&p), self.front.len() as u32));
                self.front.push([q.dot(&ex), q.dot(&ey)]);
            }
        }
        self.through_lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        self.front_lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    }

    /// The mask score of every return and gap point at `pose`: what the candidates'
    /// poses are compared by.
    fn full_score(&mut self, pose: [f64; 3]) -> i64 {
        self.mask.turn(&self.flat, pose[2], &mut self.turned);
        self.mask.turn(&self.gaps, pose[2], &mut self.turned_gaps);
        self.mask.turn(&self.through, pose[2], &mut self.turned_through);
        self.mask.score_turned(self.turned_evidence(), [pose[0], pose[1]], pose[2])
    }

    /// The medium grid around the coarse pose (5 mm, 0.5° cells, on a subsample): where
    /// the plateau lies. Only points near an edge of the model can change their mask value
    /// within a window; the rest add a constant, so each grid scores only the points
    /// within its window's reach of an edge.
    #[inline(never)]
    fn medium(&mut self, coarse: [f64; 3]) -> Fit {
        let medium_step = (0.005, 0.5f64.to_radians());
        self.near_edges(coarse, 0.07);
        // The medium grid only finds the plateau (5 mm, 0.5° cells): a subsample will do.
        self.thin_sample(MEDIUM_POINTS);
        let mut medium = self.grid(coarse, medium_step, 4);
        for _ in 0..2 {
            if !medium.at_window_edge {
                break;
            }
            medium = self.grid(medium.pose, medium_step, 4);
        }
        medium
    }

    /// The fine grid around the medium pose (every point near an edge), walked on at a
    /// coarser step while its plateau reaches the window's edge.
    #[inline(never)]
    fn fine(&mut self, medium: [f64; 3]) -> Fit {
        // The fine window reaches 9 mm and 0.36° (5 mm at the board's corners).
        self.near_edges(medium, 0.02);
        let fine = self.grid(medium, (0.0015, 0.06f64.to_radians()), 6);
        if !fine.at_window_edge {
            return fine;
        }
        // A plateau wider than the fine window (or a coarse yaw a few degrees off, which
        // an occluded board can cause): a wide window at a coarser step, walked on over a
        // subsample (each step of the walk only recentres), then scored once on every
        // point near an edge for the plateau and its spread.
        let walk_step = (0.004, 0.3f64.to_radians());
        let mut pose = fine.pose;
        for _ in 0..6 {
            self.near_edges(pose, 0.07);
            self.thin_sample(MEDIUM_POINTS);
            let walked = self.grid(pose, walk_step, 8);
            pose = walked.pose;
            if !walked.at_window_edge {
                break;
            }
        }
        self.near_edges(pose, 0.07);
        self.grid(pose, walk_step, 8)
    }

    /// Keeps every k-th of `sample`, `gap_sample` and `through_sample` so that about
    /// `budget` points of evidence remain.
    fn thin_sample(&mut self, budget: usize) {
        let evidence = self.sample.len() + self.gap_sample.len() + self.through_sample.len();
        let stride = evidence / budget + 1;
        if stride > 1 {
            keep_every(&mut self.sample, stride);
            keep_every(&mut self.gap_sample, stride);
            keep_every(&mut self.through_sample, stride);
        }
    }

    /// Returns and gap points within `near` of the model's outline or a hole's edge at
    /// `pose`, into `sample`, `gap_sample` and `through_sample`.
    fn near_edges(&mut self, pose: [f64; 3], near: f64) {
        let (hw, hh, r) = (self.spec.width / 2.0, self.spec.height / 2.0, self.spec.hole_radius);
        let spec = &self.spec;
        let close = |p: &[f64; 2]| {
            let (x, y) = to_board(pose, p);
            let outline = (x.abs() - hw).abs() < near || (y.abs() - hh).abs() < near;
            outline || spec.holes.iter().any(|h| ((x - h[0]).hypot(y - h[1]) - r).abs() < near)
        };
        self.sample.clear();
        self.sample.extend(self.flat.iter().filter(|p| close(p)));
        self.gap_sample.clear();
        self.gap_sample.extend(self.gaps.iter().filter(|p| close(p)));
        self.through_sample.clear();
        self.through_sample.extend(self.through.iter().filter(|p| close(p)));
    }

    /// Scores the (2k+1)³ grid around `centre`, `step` = (translation in fine-mask cells,
    /// yaw in radians); returns the plateau centroid and spread. Per yaw the centres lie on
    /// a lattice along the turned board's axes (whole cells apart: [`Mask::score_lattice`]).
    #[inline(never)]
    fn grid(&mut self, centre: [f64; 3], (step, yaw_step): (f64, f64), k: i32) -> Fit {
        let span = (2 * k + 1) as usize;
        let mut scores = [0i64; 17 * 17 * 17];
        let mut turns = [(0.0, 0.0); 17];
        let mut max = i64::MIN;
        let off = |i: usize| (i as i32 - k) as f64;
        for g in 0..span {
            // Per yaw the points are turned once; each centre is then a plain shift.
            let yaw = centre[2] + off(g) * yaw_step;
            turns[g] = yaw.sin_cos();
            self.mask.turn(&self.sample, yaw, &mut self.turned);
            self.mask.turn(&self.gap_sample, yaw, &mut self.turned_gaps);
            self.mask.turn(&self.through_sample, yaw, &mut self.turned_through);
            let u = self.mask.turned_centre([centre[0], centre[1]], yaw);
            let reach = k as f64 * step / self.mask.step;
            let first = [u[0] - reach, u[1] - reach];
            let mut block = [0i32; 17 * 17];
            let cells = step / self.mask.step;
            self.mask.score_lattice(self.turned_evidence(), first, cells, [span, span], &mut block);
            for a in 0..span {
                for b in 0..span {
                    let sc = block[b * span + a] as i64;
                    scores[(a * span + b) * span + g] = sc;
                    max = max.max(sc);
                }
            }
        }
        // Weights fall by e per penalty unit below the best: the plateau dominates.
        let mut w_sum = 0.0;
        let mut mean = [0.0; 3];
        let mut second = [0.0; 6];
        let mut edge = false;
        for a in 0..span {
            for b in 0..span {
                for g in 0..span {
                    let sc = scores[(a * span + b) * span + g];
                    let w = ((sc - max) as f64).exp();
                    if w < 1e-6 {
                        continue;
                    }
                    // The centre's offset along the turned axes, back in the plane frame.
                    let (s, c) = turns[g];
                    let (du, dv) = (off(a) * step, off(b) * step);
                    let x = [c * du - s * dv, s * du + c * dv, off(g) * yaw_step];
                    if w > 0.1 && [a, b, g].iter().any(|&i| i == 0 || i == span - 1) {
                        edge = true;
                    }
                    w_sum += w;
                    for i in 0..3 {
                        mean[i] += w * x[i];
                    }
                    let mut n = 0;
                    for i in 0..3 {
                        for j in i..3 {
                            second[n] += w * x[i] * x[j];
                            n += 1;
                        }
                    }
                }
            }
        }
        for m in mean.iter_mut() {
            *m /= w_sum;
        }
        let mut cov = [0.0; 9];
        let mut n = 0;
        for i in 0..3 {
            for j in i..3 {
                // A one-cell plateau still has the grid's own quantisation spread.
                let cell = [step, step, yaw_step][i];
                let q = if i == j { cell * cell / 12.0 } else { 0.0 };
                let c = second[n] / w_sum - mean[i] * mean[j] + q;
                cov[i * 3 + j] = c;
                cov[j * 3 + i] = c;
                n += 1;
            }
        }
        let pose = [centre[0] + mean[0], centre[1] + mean[1], centre[2] + mean[2]];
        Fit { pose, cov, at_window_edge: edge }
    }

    /// Covariance of the in-plane pose (x, y, yaw; row-major 3×3) that the scan lines'
    /// edge crossings allow, whatever the search: where a line leaves or re-enters the
    /// board (its ends, the sides of its gaps) it crossed an edge of the model (outline or
    /// hole) somewhere within one of its own spacings, a position known to that spacing
    /// over √12 along the line. Each crossing that lies near an edge at `fit` pins the pose
    /// along that edge's normal, and its distance from the board's centre pins the yaw;
    /// crossings far from every edge (an occluder's) pin nothing. `None` when the
    /// crossings leave a direction free. The mask's plateau can be far narrower than this
    /// when only one row of holes is crossed (issue 14's VLP-32C room 383: a board placed
    /// turned 3°, its plateau's yaw σ 0.37°).
    fn edge_covariance(&mut self, fit: &Fit) -> Option<[f64; 9]> {
        let (hw, hh, r) = (self.spec.width / 2.0, self.spec.height / 2.0, self.spec.hole_radius);
        let (sy, cy) = fit.pose[2].sin_cos();
        let mut info = Mat3::zeros();
        self.lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        for line in scan_lines(&self.lines).filter(|line| line.len() >= 3) {
            self.line_points.clear();
            let flat = &self.flat;
            self.run.clear();
            self.run.extend(line.iter().map(|&(_, i)| (flat[i as usize][0], i)));
            self.run.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            self.line_points.extend(self.run.iter().map(|&(_, i)| {
                let (x, y) = to_board(fit.pose, &flat[i as usize]);
                [x, y]
            }));
            let pts = &self.line_points;
            self.spacings.clear();
            self.spacings
                .extend(pts.windows(2).map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1])));
            let mid = self.spacings.len() / 2;
            let spacing = *self.spacings.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1;
            if spacing.is_nan() || spacing <= 1e-4 {
                continue;
            }
            // Where the line crosses the model's edges: its two ends, outwards, and either
            // side of every gap wider than its sampling, inwards.
            let along = |a: &[f64; 2], b: &[f64; 2]| {
                let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
                let l = dx.hypot(dy).max(1e-9);
                [dx / l, dy / l]
            };
            let last = pts.len() - 1;
            let mut crossings: heapless::Vec<([f64; 2], [f64; 2]), 64> = heapless::Vec::new();
            let s0 = along(&pts[1], &pts[0]);
            let _ = crossings.push((pts[0], s0));
            let s1 = along(&pts[last - 1], &pts[last]);
            let _ = crossings.push((pts[last], s1));
            for w in pts.windows(2) {
                let d = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
                if d > 1.5 * spacing {
                    let s = along(&w[0], &w[1]);
                    let _ = crossings.push((w[0], s));
                    let _ = crossings.push((w[1], [-s[0], -s[1]]));
                }
            }
            let sigma2 = (spacing * spacing / 12.0).max(0.002f64.powi(2));
            for &(p, s) in &crossings {
                // The crossing lies half a spacing beyond the return, on average.
                let q = [p[0] + s[0] * spacing / 2.0, p[1] + s[1] * spacing / 2.0];
                let Some((distance, m)) = nearest_edge(q, s, (hw, hh, r), &self.spec.holes) else {
                    continue;
                };
                if distance > spacing.max(0.02) {
                    continue;
                }
                let cos = (m[0] * s[0] + m[1] * s[1]).abs();
                // d(distance)/d(x, y, yaw): the edge's normal in the plane frame, and the
                // turn of the point about the board's centre.
                let g = Vec3::new(
                    -(cy * m[0] - sy * m[1]),
                    -(sy * m[0] + cy * m[1]),
                    -(m[0] * -q[1] + m[1] * q[0]),
                );
                info += g * g.transpose() / (sigma2 * cos * cos);
            }
        }
        let cov = info.try_inverse()?;
        let mut out = [0.0; 9];
        for i in 0..3 {
            for j in 0..3 {
                out[i * 3 + j] = cov[(i, j)];
            }
        }
        out.iter().all(|v| v.is_finite()).then_some(out)
    }

    /// Points clearly inside a hole at the fitted pose.
    #[inline(never)]
    fn points_in_holes(&self, fit: &Fit, margin: f64) -> usize {
        let r = (self.spec.hole_radius - margin).max(0.3 * self.spec.hole_radius);
        self.flat
            .iter()
            .filter(|p| {
                let (x, y) = to_board(fit.pose, p);
                self.spec.holes.iter().any(|h| (x - h[0]).hypot(y - h[1]) < r)
            })
            .count()
    }

    /// Scan lines (clusters of elevation angle) that leave and re-enter the board across
    /// each hole.
    #[inline(never)]
    fn scan_lines_per_hole(&mut self, fit: &Fit, slack: f64) -> heapless::Vec<u16, MAX_HOLES> {
        self.crossings.clear();
        self.lines.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        let r = self.spec.hole_radius;
        let band = HOLE_BAND;
        let mut start = 0;
        while start < self.lines.len() {
            let end = line_end(&self.lines, start);
            let spacing = self.median_spacing(fit, start, end);
            for (k, h) in self.spec.holes.iter().enumerate() {
                // Nearest points on either side of the hole along board x.
                let (mut left, mut right) = (None::<(f64, f64)>, None::<(f64, f64)>);
                for &(_, i) in &self.lines[start..end] {
                    let (x, y) = to_board(fit.pose, &self.flat[i as usize]);
                    let (dx, dy) = (x - h[0], y - h[1]);
                    let dist = dx.hypot(dy);
                    if dist < r - slack || dist > r + band {
                        continue;
                    }
                    if dx < 0.0 && left.is_none_or(|l| dx > l.0) {
                        left = Some((dx, dy));
                    } else if dx >= 0.0 && right.is_none_or(|l| dx < l.0) {
                        right = Some((dx, dy));
                    }
                }
                if let (Some(a), Some(b)) = (left, right) {
                    // A gap wider than the line's sampling whose chord meets the hole
                    // (allowing for the pose's own error on a grazing line), and that
                    // nothing in front hid.
                    let wide = (b.0 - a.0).hypot(b.1 - a.1) > 1.5 * spacing;
                    let e = self.lines[start].0;
                    if wide
                        && segment_distance(a, b) < r + slack
                        && !self.hidden_between(fit, e, h, (a.0, b.0))
                    {
                        self.crossings.push((k, e));
                    }
                }
            }
            start = end;
        }
        self.see_through_crossings(fit, slack);
        self.count_crossings()
    }

    /// Whether a return in front of the plane on the scan line at elevation `e` lies
    /// within the hole at `h` between board x `h.x + from` and `h.x + to` at `fit`: the
    /// line's gap there was hidden by an occluder, and says nothing of a hole (Pandar64
    /// room 536: a box face's line, whose stretch behind a stand was kept, read as crossing
    /// a hole that the mask put on it).
    fn hidden_between(&self, fit: &Fit, e: f64, h: &[f64; 2], (from, to): (f64, f64)) -> bool {
        let first = self.front_lines.partition_point(|l| l.0 < e - LINE_GAP_RAD);
        self.front_lines[first..].iter().take_while(|l| l.0 < e + LINE_GAP_RAD).any(|&(_, i)| {
            let (x, y) = to_board(fit.pose, &self.front[i as usize]);
            let (dx, dy) = (x - h[0], y - h[1]);
            dx > from && dx < to && dx.hypot(dy) < self.spec.hole_radius + HOLE_BAND
        })
    }

    /// Adds to `crossings` the lines with a see-through point inside a hole at `fit`
    /// (within the hole's radius, widened by a loose `slack`'s excess over [`SLACK`]) and
    /// a return of their own on the board at the hole's rim: the hole is in the board as
    /// that line saw it, not beside it. `lines` must be sorted by elevation.
    fn see_through_crossings(&mut self, fit: &Fit, slack: f64) {
        let r = self.spec.hole_radius + (slack - SLACK).max(0.0);
        let rim = self.spec.hole_radius + HOLE_BAND;
        let mut start = 0;
        while start < self.through_lines.len() {
            let end = line_end(&self.through_lines, start);
            let e = self.through_lines[start].0;
            let from = self.lines.partition_point(|l| l.0 < e - LINE_GAP_RAD);
            let last = self.through_lines[end - 1].0;
            let to = self.lines.partition_point(|l| l.0 < last + LINE_GAP_RAD);
            for (k, h) in self.spec.holes.iter().enumerate() {
                let near = |p: &[f64; 2], reach: f64| {
                    let (x, y) = to_board(fit.pose, p);
                    (x - h[0]).hypot(y - h[1]) < reach
                };
                let inside = self.through_lines[start..end]
                    .iter()
                    .any(|&(_, i)| near(&self.through[i as usize], r));
                let on_rim = inside
                    && self.lines[from..to].iter().any(|&(_, i)| near(&self.flat[i as usize], rim));
                if on_rim {
                    self.crossings.push((k, self.through_lines[start].0));
                }
            }
            start = end;
        }
    }

    /// Distinct scan lines (elevations 0.06° apart) per hole in `crossings`: a line seen
    /// both as a gap and through the hole counts once.
    fn count_crossings(&mut self) -> heapless::Vec<u16, MAX_HOLES> {
        let mut counts: heapless::Vec<u16, MAX_HOLES> = heapless::Vec::new();
        for _ in 0..self.spec.holes.len() {
            let _ = counts.push(0);
        }
        self.crossings.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        let mut last: Option<(usize, f64)> = None;
        for &(k, e) in &self.crossings {
            let same = last.is_some_and(|(lk, le)| lk == k && e - le < LINE_GAP_RAD);
            if !same {
                counts[k] += 1;
            }
            last = Some((k, e));
        }
        counts
    }

    /// Median spacing along board x of the returns of the line `lines[start..end]` (the
    /// holes' own gaps do not stretch it, as they would a mean).
    fn median_spacing(&mut self, fit: &Fit, start: usize, end: usize) -> f64 {
        self.run.clear();
        for &(_, i) in &self.lines[start..end] {
            self.run.push((to_board(fit.pose, &self.flat[i as usize]).0, i));
        }
        self.run.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        median_step(&self.run, &mut self.spacings)
    }

    /// Board → LiDAR for an in-plane pose in the plane frame (c; ex, ey, n).
    fn pose(&self, fit: &Fit, (c, ex, ey, n): (Vec3, Vec3, Vec3, Vec3)) -> Se3 {
        let [tx, ty, yaw] = fit.pose;
        let (s, co) = yaw.sin_cos();
        let bx = ex * co + ey * s;
        let by = -ex * s + ey * co;
        Se3 { rotation: Mat3::from_columns(&[bx, by, n]), translation: c + ex * tx + ey * ty }
    }

    /// The placed board at `fit`; each hole's σ in the plane is the larger of what the
    /// plateau's spread and the edge crossings' covariance `edges` give it (two estimates
    /// of one spread: the more cautious is kept, not their sum).
    fn board(
        &self,
        fit: &Fit,
        edges: &[f64; 9],
        (c, ex, ey, n): (Vec3, Vec3, Vec3, Vec3),
        plane_sigma: [f64; 3],
        rms: f64,
        lines: heapless::Vec<u16, MAX_HOLES>,
    ) -> LidarBoard {
        let pose = self.pose(fit, (c, ex, ey, n));
        let (s, co) = fit.pose[2].sin_cos();
        let mut holes = heapless::Vec::new();
        let mut sigma = heapless::Vec::new();
        let cv = &fit.cov;
        for h in &self.spec.holes {
            let centre = pose.act(&Vec3::new(h[0], h[1], 0.0));
            let _ = holes.push(centre);
            // Hole offset in the plane frame; its Jacobian wrt (tx, ty, yaw).
            let (px, py) = (co * h[0] - s * h[1], s * h[0] + co * h[1]);
            let j = [[1.0, 0.0, -py], [0.0, 1.0, px]];
            let in_plane = |cv: &[f64; 9]| {
                let mut var = 0.0;
                for row in &j {
                    for a in 0..3 {
                        for b in 0..3 {
                            var += row[a] * cv[a * 3 + b] * row[b];
                        }
                    }
                }
                var
            };
            let mut var = in_plane(cv).max(in_plane(edges));
            // The plane's offset, and its tilts times the hole's lever arm. The points
            // were moved along their beams onto the plane, so a plane error δ along the
            // normal moves the hole by δ / cos(incidence) along its beam.
            let (lu, lv) = (fit.pose[0] + px, fit.pose[1] + py);
            let [offset, tilt_u, tilt_v] = plane_sigma;
            let cos = n.dot(&centre.normalize()).abs().max(0.3);
            var += (offset * offset + (lu * tilt_u).powi(2) + (lv * tilt_v).powi(2)) / (cos * cos);
            let _ = sigma.push(var.sqrt());
        }
        LidarBoard {
            holes,
            hole_sigma_m: sigma,
            hole_scan_lines: lines,
            pose,
            normal: n,
            inliers: self.seg.len(),
            plane_rms_m: rms,
            pose_sigma: [0, 4, 8].map(|k| cv[k].max(edges[k]).sqrt()),
        }
    }
}

/// Where a board's points are gathered from: a plane group's voxels, or a ball about where
/// a board is expected (centre, radius in m).
#[derive(Clone, Copy)]
enum Region {
    Group(u32),
    Ball(Vec3, f64),
}

/// Result of a grid search: pose (x, y, yaw) in the plane frame, its covariance
/// (row-major 3×3) and whether the plateau reached the window's edge.
#[derive(Clone, Copy, Debug)]
struct Fit {
    pose: [f64; 3],
    cov: [f64; 9],
    at_window_edge: bool,
}

/// The board model rasterised (2 mm for the fine search, 1 cm for the coarse): each
/// cell holds +1 on solid board, −1 in a hole and 0 outside (as does everything beyond
/// the grid). The scores follow from it: a return scores 2v − 1 (+1 on solid board, −3 in
/// a hole, −1 outside); a gap point (where a scan line crossing the plane returned
/// nothing) −2v − 1 (+1 in a hole, −3 on solid board: it would have returned, −1
/// outside); a see-through point (a beam that crossed the plane and returned from behind
/// it) −3 on solid board and nothing elsewhere (beams pass beside a board as freely as
/// through its holes, so they only veto solid board).
#[derive(Clone, Debug)]
struct Mask {
    step: f64,
    cells: Vec<i8>,
    cols: usize,
    rows: usize,
    origin: [f64; 2],
}

const MASK_MARGIN: f64 = 0.15;
/// Most cells along a mask side: the fine mask of the largest board the room file accepts
/// (`MAX_BOARD_SIDE_M` + margins at 2 mm) needs 2650, so this bounds the allocation
/// (4096² bytes per mask) even for a board that bypassed validation.
pub const MAX_MASK_SIDE: usize = 4096;

/// Score of a return, a gap point and a see-through point on a cell of value `v`.
fn return_score(v: i8) -> i32 {
    2 * v as i32 - 1
}
fn gap_score(v: i8) -> i32 {
    -2 * v as i32 - 1
}
fn through_score(v: i8) -> i32 {
    -3 * v.max(0) as i32
}

impl Mask {
    fn new(spec: &BoardSpec, step: f64) -> Self {
        let origin = [-spec.width / 2.0 - MASK_MARGIN, -spec.height / 2.0 - MASK_MARGIN];
        // `as` saturates (NaN → 0); the cap keeps a hostile size from sizing the buffers.
        let cols = (((spec.width + 2.0 * MASK_MARGIN) / step).ceil() as usize).min(MAX_MASK_SIDE);
        let rows = (((spec.height + 2.0 * MASK_MARGIN) / step).ceil() as usize).min(MAX_MASK_SIDE);
        let mut cells = vec![0; cols * rows];
        let centre = |i: usize, o: f64| o + (i as f64 + 0.5) * step;
        let (xs, ys) =
            ((0..cols).map(|c| centre(c, origin[0])), (0..rows).map(|r| centre(r, origin[1])));
        // The board's cells, then each hole's within its bounding box: a hole test for
        // every cell and hole cost a rig's daemon 28 M instructions per detector.
        let on_board = |x: f64, y: f64| x.abs() <= spec.width / 2.0 && y.abs() <= spec.height / 2.0;
        for (row, y) in ys.enumerate() {
            for (col, x) in xs.clone().enumerate() {
                cells[row * cols + col] = i8::from(on_board(x, y));
            }
        }
        let r2 = spec.hole_radius * spec.hole_radius;
        let cell_of =
            |v: f64, o: f64, n: usize| (((v - o) / step).floor().max(0.0) as usize).min(n);
        for h in spec.holes.iter().filter(|_| cols > 0 && rows > 0) {
            let (r, [hx, hy]) = (spec.hole_radius, *h);
            let (c0, c1) =
                (cell_of(hx - r, origin[0], cols), cell_of(hx + r, origin[0], cols - 1) + 1);
            let (r0, r1) =
                (cell_of(hy - r, origin[1], rows), cell_of(hy + r, origin[1], rows - 1) + 1);
            for row in r0..r1.min(rows) {
                for col in c0..c1.min(cols) {
                    let (x, y) = (centre(col, origin[0]), centre(row, origin[1]));
                    if on_board(x, y) && (x - hx).powi(2) + (y - hy).powi(2) < r2 {
                        cells[row * cols + col] = -1;
                    }
                }
            }
        }
        Mask { step, cells, cols, rows, origin }
    }

    /// Plane-frame points turned by −`yaw` and scaled to cells, into `out`.
    fn turn(&self, points: &[[f64; 2]], yaw: f64, out: &mut Vec<[f64; 2]>) {
        let (s, c) = yaw.sin_cos();
        let inv = 1.0 / self.step;
        out.clear();
        out.extend(
            points.iter().map(|p| [(c * p[0] + s * p[1]) * inv, (c * p[1] - s * p[0]) * inv]),
        );
    }

    /// The board centre `t` (plane frame, m) in the frame of points turned by −`yaw` and
    /// scaled to cells.
    fn turned_centre(&self, t: [f64; 2], yaw: f64) -> [f64; 2] {
        let (s, c) = yaw.sin_cos();
        [(c * t[0] + s * t[1]) / self.step, (c * t[1] - s * t[0]) / self.step]
    }

    /// Score of evidence turned by [`Mask::turn`] for board centre `t` (plane frame) and
    /// the same `yaw`.
    fn score_turned(&self, e: Evidence, t: [f64; 2], yaw: f64) -> i64 {
        let u = self.turned_centre(t, yaw);
        let (ox, oy) = (u[0] + self.origin[0] / self.step, u[1] + self.origin[1] / self.step);
        let sum = |pts: &[[f64; 2]], score: fn(i8) -> i32| -> i64 {
            pts.iter().map(|p| score(self.at(p[0] - ox, p[1] - oy)) as i64).sum()
        };
        sum(e.returns, return_score) + sum(e.gaps, gap_score) + sum(e.through, through_score)
    }

    /// The cell value at fractional cell coordinates (col, row); 0 beyond the grid.
    fn at(&self, col: f64, row: f64) -> i8 {
        if col >= 0.0 && row >= 0.0 && (col as usize) < self.cols && (row as usize) < self.rows {
            self.cells[row as usize * self.cols + col as usize]
        } else {
            0
        }
    }

    /// Scores of a lattice of board centres at once, for evidence turned by
    /// [`Mask::turn`]: centre (i, j) lies at `first + (i, j)·step` (turned frame, cells;
    /// at most [`MAX_LATTICE`] a side), its score goes to `out[j·n[0] + i]`. Along the
    /// turned board's axes a point's column depends on i alone and its row on j alone:
    /// both are found once per point, and each centre then costs one table lookup.
    fn score_lattice(
        &self,
        e: Evidence,
        first: [f64; 2],
        step: f64,
        n: [usize; 2],
        out: &mut [i32],
    ) {
        let n = [n[0].min(MAX_LATTICE), n[1].min(MAX_LATTICE)];
        let out = &mut out[..n[0] * n[1]];
        // Every return and gap point scores −1 outside; the cells add the rest.
        out.fill(-((e.returns.len() + e.gaps.len()) as i32));
        let o = [first[0] + self.origin[0] / self.step, first[1] + self.origin[1] / self.step];
        let mut index = Lattice { step, n, cols: [0; MAX_LATTICE], rows: [0; MAX_LATTICE] };
        for p in e.returns {
            self.add_lattice(p, o, &mut index, out, |v| 2 * v as i32);
        }
        for p in e.gaps {
            self.add_lattice(p, o, &mut index, out, |v| -2 * v as i32);
        }
        for p in e.through {
            self.add_lattice(p, o, &mut index, out, through_score);
        }
    }

    /// Adds one point's `score` of the cell under it to every centre of the lattice
    /// (`score_lattice`'s layout; `o` is the first centre's cell origin). Cells beyond the
    /// grid hold 0 and add nothing.
    #[inline(always)]
    fn add_lattice(
        &self,
        p: &[f64; 2],
        o: [f64; 2],
        index: &mut Lattice,
        out: &mut [i32],
        score: impl Fn(i8) -> i32,
    ) {
        let n = index.n;
        let (i_lo, i_hi) = cells_along(p[0] - o[0], index.step, self.cols, &mut index.cols[..n[0]]);
        let (j_lo, j_hi) = cells_along(p[1] - o[1], index.step, self.rows, &mut index.rows[..n[1]]);
        if i_lo >= i_hi {
            return;
        }
        for j in j_lo..j_hi {
            let row = &self.cells[index.rows[j] as usize * self.cols..][..self.cols];
            let cols = &index.cols[i_lo..i_hi];
            for (acc, &c) in out[j * n[0] + i_lo..j * n[0] + i_hi].iter_mut().zip(cols) {
                *acc += score(row[c as usize]);
            }
        }
    }
}

/// Most lattice centres along a side in one [`Mask::score_lattice`] call.
const MAX_LATTICE: usize = 128;

/// A lattice's spacing (cells) and size, and one point's column and row per centre.
struct Lattice {
    step: f64,
    n: [usize; 2],
    cols: [u32; MAX_LATTICE],
    rows: [u32; MAX_LATTICE],
}

/// The cell `x − k·step` for every lattice centre k into `cells` (`x` in cells from the
/// grid's origin for the first centre); returns the range of centres for which it lies
/// within the `len` cells of the grid (it falls with k, so the range is contiguous).
fn cells_along(x: f64, step: f64, len: usize, cells: &mut [u32]) -> (usize, usize) {
    let (mut lo, mut hi) = (cells.len(), 0);
    for (k, cell) in cells.iter_mut().enumerate() {
        let at = x - k as f64 * step;
        if at >= 0.0 && at < len as f64 {
            *cell = at as u32;
            lo = lo.min(k);
            hi = k + 1;
        }
    }
    (lo, hi)
}

/// What the mask scores: returns on the plane, gap points and see-through points, in one
/// frame (plane, board-aligned or turned and scaled, as the caller says).
#[derive(Clone, Copy)]
struct Evidence<'a> {
    returns: &'a [[f64; 2]],
    gaps: &'a [[f64; 2]],
    through: &'a [[f64; 2]],
}

/// How far outside a hole's edge a scan line's last return before the hole may lie (m).
const HOLE_BAND: f64 = 0.06;

/// Translation step of the coarse search (m).
const COARSE_STEP: f64 = 0.02;

/// How far a scan line's gap may miss a hole and still count as crossing it (m): the
/// pose's own error on a grazing line. A line that misses the hole leaves no gap, so a
/// generous slack counts no false crossings.
const SLACK: f64 = 0.02;

/// The first bin after the lowest `trim` counts.
fn cut<'a>(counts: impl Iterator<Item = &'a u32>, trim: usize) -> usize {
    let mut seen = 0;
    for (i, &c) in counts.enumerate() {
        seen += c as usize;
        if seen > trim {
            return i;
        }
    }
    0
}

/// Elevation bins of the sweep's scan-line census.
const RING_BIN_DEG: f64 = 0.05;
const RING_BINS: usize = (180.0 / RING_BIN_DEG) as usize + 1;

/// Most points the medium grid (and each step of a walk) scores.
const MEDIUM_POINTS: usize = 600;

/// Shortest scan-line run kept on a board, as a fraction of its width: a line through a
/// corner hole of a rolled board leaves through the bottom edge soon after, and one across
/// a partly hidden board ends at the occluder; poles and stands are far narrower. At a
/// quarter, the 21–25 cm that an occluder left of a 1 m board's lines beside a hole dropped
/// them and with them the hole (issue 14, Pandar40P room 231). A fifth found 1–8 more
/// boards per model over issue 14's rooms 1–600 and placed none wrong; 15 % found a few
/// more still, but placed two structures 7.5 m away in the real OpenCalib frame as boards
/// (`tests/holes_real.rs`): their shorter runs filled the lines that
/// [`Refusal::LinesMissing`] counts (28 of 47 lines at a fifth, 15 at a quarter, 36 needed).
const MIN_RUN: f64 = 0.2;
/// A board's points are gathered again about their refitted plane while it moves more than
/// [`REGATHER_ANGLE_RAD`] from the plane they were gathered about, at most this often.
const REGATHER_ROUNDS: usize = 3;
const REGATHER_ANGLE_RAD: f64 = 0.3 * PI / 180.0;
/// A scan line whose mean residual from the board's plane exceeds this many of its σ is
/// left out of the plane fit ([`HoleDetector::lines_agreeing`]): about 1 in 2000 lines of
/// pure noise.
const LINE_Z: f64 = 3.5;
/// Least part of the board's width the points must span: a board partly hidden behind
/// another shows a third of it or more; the mask search and the hole checks judge the rest.
const MIN_WIDTH_SEEN: f64 = 0.35;
/// Least share of a plane's points inside one board-sized window for a plane larger than
/// the board to be searched for one ([`HoleDetector::extent_fits`]).
const BOARD_WINDOW_SHARE: f64 = 0.85;
/// How far beyond the plane along its beam a return must lie to be a see-through point
/// (m): well over the range noise (2 cm σ) and the plane's thickness.
const BEHIND_M: f64 = 0.15;
/// What a scan line's end next to an occluder loses (m): the occluder's side may close in on
/// the plane there ([`HoleDetector::unoccluded_part`]).
const OCCLUDED_END_M: f64 = 0.08;
/// How far in front of the plane such an end's returns must lie to be dropped (m): a
/// range σ.
const OCCLUDED_FRONT_M: f64 = 0.02;
/// How far outside the fitted outline a scan line may end (m): the pose's own error and a
/// beam's footprint over the edge.
const OUTLINE_TOLERANCE: f64 = 0.03;
/// Largest elevation step (rad) between returns of one scan line ([`line_end`]).
const LINE_GAP_RAD: f64 = 0.06 * (PI / 180.0);
/// Largest distance (m) of the next return along a scan line for the line to run on rather
/// than end ([`HoleDetector::runs_on`]): a few of a line's spacings (2–3 cm at 7 m, more on a
/// surface seen at a slant) plus range noise; a board's edge against what stands behind it
/// is a jump of more than [`BEHIND_M`].
const RUN_ON_M: f64 = 0.1;
/// How near the examined plane (m) a return must lie to be kept in `aside`.
const ASIDE_M: f64 = 0.3;
/// Scan-line ends farther outside the outline than this are clutter beside the board (m).
const OUTLINE_CLUTTER: f64 = 0.12;

/// The least gap along a scan line that cuts returns past a board's side off from the
/// board ([`board_ends`]): wider than a line's spacing on any board the room file allows
/// at 8 m, narrower than a stand's distance from the edge that matters.
const DETACHED_GAP_M: f64 = 0.04;
/// Least score lead of the best pose over a distinct rival (see `HoleDetector::margin`).
const AMBIGUITY_MARGIN: i64 = 8;
/// Most distinct coarse optima refined and compared.
const CANDIDATES: usize = 4;
/// Returns the coarse search scores (of a subsample); more would only cost time.
const COARSE_POINTS: usize = 400;
/// Two poses whose centres lie this far apart (or whose yaws differ by [`DISTINCT_YAW`])
/// are distinct optima (m).
const DISTINCT_M: f64 = 0.05;
const DISTINCT_YAW: f64 = 5.0 * PI / 180.0;
/// The coarse yaws tried about an expected board's (degrees either side): its yaw in the
/// plane is off by the mounting's error about the board's normal (a degree or two for a
/// nominal mounting; a LiDAR mounted 10° off is still found), and the coarse step is 4°.
pub const EXPECTED_YAW_DEG: f64 = 14.0;

/// Whether `yaw` lies within [`EXPECTED_YAW_DEG`] of `expected`, either way round (the
/// expected axis is a direction in the room; which way the detector's axis points along
/// it is the board's half-turn, which the mask search settles).
fn near_yaw(yaw: f64, expected: f64) -> bool {
    let off = (yaw - expected).rem_euclid(PI);
    off.min(PI - off) <= EXPECTED_YAW_DEG.to_radians()
}

/// Scored poses (x, y, yaw), best first.
type Candidates = heapless::Vec<(i64, [f64; 3]), CANDIDATES>;

/// Whether two in-plane poses are one optimum.
fn same_optimum(a: &[f64; 3], b: &[f64; 3], apart_m: f64) -> bool {
    (a[0] - b[0]).hypot(a[1] - b[1]) < apart_m && (a[2] - b[2]).abs() < DISTINCT_YAW
}

/// Adds `pose` to the best-first list `list` of distinct optima: it replaces a worse pose
/// of its own optimum, or the worst when the list is full.
fn keep_best(list: &mut Candidates, score: i64, pose: [f64; 3], apart_m: f64) {
    if let Some(k) = list.iter().position(|(_, p)| same_optimum(p, &pose, apart_m)) {
        if list[k].0 >= score {
            return;
        }
        list.remove(k);
    } else if list.is_full() {
        if list[CANDIDATES - 1].0 >= score {
            return;
        }
        list.pop();
    }
    let at = list.iter().position(|(s, _)| *s < score).unwrap_or(list.len());
    let _ = list.insert(at, (score, pose));
}

/// Keeps every `stride`-th element of `v`, in order.
fn keep_every<T: Copy>(v: &mut Vec<T>, stride: usize) {
    let mut i = 0;
    v.retain(|_| {
        i += 1;
        (i - 1) % stride == 0
    });
}

/// End of the scan line (run of elevations closer than [`LINE_GAP_RAD`] to the previous)
/// that starts at `start` in `lines` sorted by elevation.
fn line_end(lines: &[(f64, u32)], start: usize) -> usize {
    let mut end = start + 1;
    while end < lines.len() && lines[end].0 - lines[end - 1].0 < LINE_GAP_RAD {
        end += 1;
    }
    end
}

/// Indices in `run` (one scan line's returns as (board x, index), sorted by x) of the
/// line's two ends on the board of half-width `hw`. Returns past a side that a gap of
/// three spacings (and at least [`DETACHED_GAP_M`]) cuts off from the rest, the gap's
/// inner side within the outline, are something standing beside the board (a stand's
/// pole a few centimetres off its edge, issue 14's Pandar64 room 247): the line left the
/// board at the gap. `spacings` is scratch.
fn board_ends(run: &[(f64, u32)], hw: f64, spacings: &mut Vec<f64>) -> (usize, usize) {
    let side = hw + OUTLINE_TOLERANCE;
    let (low, high) = (
        run.iter().take_while(|p| p.0 < -side).count(),
        run.iter().rev().take_while(|p| p.0 > side).count(),
    );
    let last = run.len() - 1;
    if low == 0 && high == 0 {
        return (0, last);
    }
    let gap = (3.0 * median_step(run, spacings)).max(DETACHED_GAP_M);
    let cut_off = |outer: usize, inner: usize| (run[inner].0 - run[outer].0).abs() > gap;
    let first = if low > 0 && low <= last && cut_off(low - 1, low) { low } else { 0 };
    let end = if high > 0 && high <= last && cut_off(last + 1 - high, last - high) {
        last - high
    } else {
        last
    };
    (first, end)
}

/// The median step between consecutive values of `run` (sorted by its first field), 0
/// for fewer than two: a scan line's spacing, which its holes' gaps do not stretch as
/// they would a mean. `steps` is scratch.
fn median_step(run: &[(f64, u32)], steps: &mut Vec<f64>) -> f64 {
    steps.clear();
    steps.extend(run.windows(2).map(|w| w[1].0 - w[0].0));
    if steps.is_empty() {
        return 0.0;
    }
    let mid = steps.len() / 2;
    *steps.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The scan lines of `lines` (sorted by elevation), each as its slice: runs of elevations
/// closer than [`LINE_GAP_RAD`] to the previous ([`line_end`]).
fn scan_lines(lines: &[(f64, u32)]) -> impl Iterator<Item = &[(f64, u32)]> {
    let mut start = 0;
    core::iter::from_fn(move || {
        (start < lines.len()).then(|| {
            let end = line_end(lines, start);
            let line = &lines[start..end];
            start = end;
            line
        })
    })
}

/// The elevation bin ([`RING_BIN_DEG`]) of elevation `e` (rad).
fn ring_bin(e: f64) -> usize {
    (((e.to_degrees() + 90.0) / RING_BIN_DEG) as usize).min(RING_BINS - 1)
}

/// Elevation angle of `p` seen from the sensor (rad): what tells its scan line.
/// A return as the detector keeps it, in the solver's type (the same values as the
/// sweep's f32 converted directly).
fn point_of(p: &[f32; 3]) -> Vec3 {
    Vec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
}

fn elevation(p: &Vec3) -> f64 {
    p.z.atan2(p.x.hypot(p.y))
}

/// Board-frame coordinates of plane-frame point `p` for pose (x, y, yaw).
fn to_board(pose: [f64; 3], p: &[f64; 2]) -> (f64, f64) {
    let (s, c) = pose[2].sin_cos();
    let (dx, dy) = (p[0] - pose[0], p[1] - pose[1]);
    (c * dx + s * dy, -s * dx + c * dy)
}

/// Distance from board point `q` to the nearest edge of the model (outline of half-size
/// (`hw`, `hh`), holes of radius `r` at `holes`) that a line along `s` crosses at 30° or
/// more (a line running along an edge does not tell where it is), and that edge's unit
/// normal there.
fn nearest_edge(
    q: [f64; 2],
    s: [f64; 2],
    (hw, hh, r): (f64, f64, f64),
    holes: &[[f64; 2]],
) -> Option<(f64, [f64; 2])> {
    let mut best: Option<(f64, [f64; 2])> = None;
    let mut consider = |d: f64, m: [f64; 2]| {
        let crossed = (m[0] * s[0] + m[1] * s[1]).abs() >= 0.5;
        if crossed && best.is_none_or(|b| d < b.0) {
            best = Some((d, m));
        }
    };
    if q[1].abs() <= hh {
        consider((q[0].abs() - hw).abs(), [q[0].signum(), 0.0]);
    }
    if q[0].abs() <= hw {
        consider((q[1].abs() - hh).abs(), [0.0, q[1].signum()]);
    }
    for h in holes {
        let (dx, dy) = (q[0] - h[0], q[1] - h[1]);
        let l = dx.hypot(dy);
        if l > 1e-9 {
            consider((l - r).abs(), [dx / l, dy / l]);
        }
    }
    best
}

/// Distance from the origin to the segment a–b.
fn segment_distance(a: (f64, f64), b: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let l2 = dx * dx + dy * dy;
    let t = if l2 > 0.0 { (-(a.0 * dx + a.1 * dy) / l2).clamp(0.0, 1.0) } else { 0.0 };
    (a.0 + t * dx).hypot(a.1 + t * dy)
}

/// Whether the hole pattern maps onto itself under a 180° turn.
fn symmetric(spec: &BoardSpec) -> bool {
    spec.holes.iter().all(|h| {
        let k = nearest_hole(spec, -h[0], -h[1]);
        (spec.holes[k][0] + h[0]).hypot(spec.holes[k][1] + h[1]) < 1e-3
    })
}

fn nearest_hole(spec: &BoardSpec, x: f64, y: f64) -> usize {
    let mut best = (f64::MAX, 0);
    for (k, h) in spec.holes.iter().enumerate() {
        let d = (h[0] - x).hypot(h[1] - y);
        if d < best.0 {
            best = (d, k);
        }
    }
    best.1
}

/// The plane that best explains `points` (LiDAR frame, the sensor at the origin) as ranges
/// measured along their own beams: a point on the board's centroid, the unit normal and the
/// RMS distance of the points from the plane.
///
/// A LiDAR's noise lies along its beams, nearly parallel over one board, so an orthogonal
/// least-squares fit (the smallest eigenvector of the scatter) sees the board's scatter
/// plus σ²·b·bᵀ and turns the normal towards the beam by about σ²·cos θ·sin θ / λ (θ the
/// incidence, λ the points' variance across the few scan lines that cross the board):
/// 1–3° for a board pitched 30° at 7 m. Here the plane is m·x = 1 and each point gives
/// b̂·m = 1/r: the beam direction b̂ is exact and only the inverse range is noisy, so the
/// linear least squares is unbiased. Weights r̂⁴ (r̂ the range the `prior` plane predicts,
/// through `prior_c` with normal `prior_n`) make the residuals those of the range itself,
/// δ(1/r) ≈ −δr/r²; taken from the prior plane rather than the point's own range they carry
/// none of its noise.
fn fit_plane(points: &[Vec3], prior_c: Vec3, prior_n: Vec3) -> Option<(Vec3, Vec3, f64)> {
    if points.len() < 3 {
        return None;
    }
    let prior_d = prior_n.dot(&prior_c);
    let (mut normal, mut rhs, mut sum) = (Mat3::zeros(), Vec3::zeros(), Vec3::zeros());
    for p in points {
        let r = p.norm();
        if r < 1e-6 {
            continue;
        }
        let b = p / r;
        // A beam nearly along the prior plane predicts no sensible range: its own then.
        let predicted = prior_d / prior_n.dot(&b);
        let r_hat = if (0.5 * r..2.0 * r).contains(&predicted) { predicted } else { r };
        let w = r_hat.powi(4);
        normal += b * b.transpose() * w;
        rhs += b * (w / r);
        sum += p;
    }
    let m = normal.cholesky()?.solve(&rhs);
    let d = 1.0 / m.norm();
    let n = m * d;
    if !(d.is_finite() && n.iter().all(|v| v.is_finite())) {
        return None;
    }
    let centroid = sum / points.len() as f64;
    let c = centroid - n * (n.dot(&centroid) - d);
    let ss: f64 = points.iter().map(|p| (n.dot(p) - d).powi(2)).sum();
    Some((c, n, (ss / points.len() as f64).sqrt()))
}

impl Moments {
    fn add(&mut self, p: &Vec3) {
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

    fn merge(&mut self, o: &Moments) {
        self.n += o.n;
        self.s += o.s;
        for (a, b) in self.ss.iter_mut().zip(&o.ss) {
            *a += b;
        }
    }

    fn mean_cov(&self) -> (Vec3, Mat3) {
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
fn smallest_eigen(a: &Mat3) -> ([f64; 3], Vec3) {
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

const KEY_BIAS: i64 = 1 << 20;
const KEY_MASK: u64 = (1 << 21) - 1;

fn voxel_key(v: &Vec3) -> u64 {
    let f = |x: f64| ((x.floor() as i64 + KEY_BIAS) as u64) & KEY_MASK;
    (f(v.x) << 42) | (f(v.y) << 21) | f(v.z)
}

/// The 27 keys of a voxel's 3×3×3 neighbourhood (itself included).
fn neighbour_keys(key: u64) -> impl Iterator<Item = u64> {
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

/// A refused plane as a user reads it: where it is (in the sensor's x forward, y left,
/// z up), how big it was and why it is not a board, e.g. "plane of 127 points 6.2 m away
/// (3.6 m ahead, 4.9 m right, 1.3 m below), turned 12° from facing the sensor: only 0
/// hole(s) crossed by two or more scan lines (need 2)".
impl core::fmt::Display for RefusedBoard {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let c = &self.centroid;
        let side = |v: f64, plus: &'static str, minus: &'static str| {
            (v.abs(), if v >= 0.0 { plus } else { minus })
        };
        let (ahead, ahead_word) = side(c.x, "ahead", "behind");
        let (left, left_word) = side(c.y, "left", "right");
        let (up, up_word) = side(c.z, "above", "below");
        // The normal points away from the sensor: its angle to the line of sight is how
        // far the plane is turned from facing the sensor.
        let facing = c.norm().max(1e-9);
        let cos = (self.normal.dot(c) / facing).clamp(-1.0, 1.0);
        write!(
            f,
            "plane of {} points {:.1} m away ({ahead:.1} m {ahead_word}, {left:.1} m {left_word}, \
             {up:.1} m {up_word}), turned {:.0}° from facing the sensor: {}",
            self.points,
            c.norm(),
            cos.abs().acos().to_degrees(),
            self.reason
        )
    }
}

impl Refusal {
    /// What a person can do about this refusal, as a short imperative clause.
    pub fn advice(&self) -> &'static str {
        match self {
            Refusal::TooFewPoints { .. } | Refusal::LinesMissing { .. } => {
                "if it is a board, bring it closer or clear what hides it"
            }
            Refusal::NoHolePattern { .. } | Refusal::NoHoleGaps { .. } => {
                "if it is a board, check the room file's hole positions and radius"
            }
            Refusal::HolesUnseen { .. }
            | Refusal::FewLines { .. }
            | Refusal::Unconstrained { .. } => {
                "if it is a board, bring it closer or into the LiDAR's denser beams"
            }
            Refusal::Ambiguous { .. } => {
                "if it is a board, turn or move it so more scan lines cross its holes"
            }
            Refusal::OutlineDisagrees { .. } | Refusal::SeenThrough { .. } => {
                "if it is a board, check the room file's board size and clear what touches its edges"
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn board() -> BoardSpec {
        let mut holes = heapless::Vec::new();
        for h in [[-0.45, -0.35], [0.45, -0.35], [-0.45, 0.35], [0.45, 0.35]] {
            holes.push(h).unwrap();
        }
        BoardSpec {
            width: 1.2,
            height: 1.0,
            inner_corners: [7, 5],
            square: 0.08,
            hole_radius: 0.08,
            holes,
            count: 1,
            checker_offset: [0.0, 0.0],
        }
    }

    /// The mask cell by cell from its definition: solid board 1, hole −1, beyond 0.
    fn mask_by_definition(spec: &BoardSpec, step: f64) -> Vec<i8> {
        let m = Mask::new(spec, step);
        let r2 = spec.hole_radius * spec.hole_radius;
        let mut cells = Vec::new();
        for row in 0..m.rows {
            for col in 0..m.cols {
                let x = m.origin[0] + (col as f64 + 0.5) * step;
                let y = m.origin[1] + (row as f64 + 0.5) * step;
                let inside = x.abs() <= spec.width / 2.0 && y.abs() <= spec.height / 2.0;
                let hole = spec.holes.iter().any(|h| (x - h[0]).powi(2) + (y - h[1]).powi(2) < r2);
                cells.push(match (inside, hole) {
                    (true, false) => 1,
                    (true, true) => -1,
                    _ => 0,
                });
            }
        }
        cells
    }

    /// The mask filled hole by hole is the mask by definition: this board, an asymmetric
    /// one whose holes overlap its edge and each other, and odd steps.
    #[test]
    fn the_mask_holds_the_board_and_its_holes_cell_by_cell() {
        let mut odd = board();
        odd.holes.clear();
        for h in [[-0.58, -0.46], [0.2, 0.1], [0.25, 0.12], [0.61, 0.0], [0.0, 0.55]] {
            odd.holes.push(h).unwrap();
        }
        odd.hole_radius = 0.0731;
        for spec in [board(), odd] {
            for step in [0.002, 0.01, 0.0037] {
                let m = Mask::new(&spec, step);
                assert_eq!(m.cells, mask_by_definition(&spec, step), "step {step}");
                assert!(m.cells.contains(&-1) && m.cells.contains(&1));
            }
        }
    }

    /// Points spread over and beyond the board (plane frame), from a fixed LCG.
    fn scatter(n: usize, seed: u64) -> Vec<[f64; 2]> {
        let mut s = seed;
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        (0..n).map(|_| [0.8 * next(), 0.7 * next()]).collect()
    }

    /// The lattice scorer gives every centre the score that scoring it alone gives (the
    /// fine and the coarse mask, a step that is no whole number of cells, centres whose
    /// points fall off the grid).
    #[test]
    fn lattice_scores_equal_scores_one_centre_at_a_time() {
        let spec = board();
        let (returns, gaps, through) = (scatter(400, 1), scatter(60, 2), scatter(90, 3));
        for (mask, step_m, n) in
            [(Mask::new(&spec, 0.002), 0.0015, [13, 11]), (Mask::new(&spec, 0.01), 0.07, [30, 25])]
        {
            let yaw = 0.3;
            let (mut r, mut g, mut t) = (Vec::new(), Vec::new(), Vec::new());
            mask.turn(&returns, yaw, &mut r);
            mask.turn(&gaps, yaw, &mut g);
            mask.turn(&through, yaw, &mut t);
            let e = Evidence { returns: &r, gaps: &g, through: &t };
            let step = step_m / mask.step;
            let u = mask.turned_centre([0.013, -0.021], yaw);
            let first = [u[0] - 6.0 * step, u[1] - 5.0 * step];
            let mut lattice = vec![0; n[0] * n[1]];
            mask.score_lattice(e, first, step, n, &mut lattice);
            let (s, c) = yaw.sin_cos();
            for j in 0..n[1] {
                for i in 0..n[0] {
                    // The centre back in the plane frame (m).
                    let (a, b) = (first[0] + i as f64 * step, first[1] + j as f64 * step);
                    let centre = [(c * a - s * b) * mask.step, (s * a + c * b) * mask.step];
                    let alone = mask.score_turned(e, centre, yaw);
                    assert_eq!(lattice[j * n[0] + i] as i64, alone, "centre ({i}, {j})");
                }
            }
        }
    }

    /// Scan lines across `spec` at board heights `rows` (plane frame = board frame),
    /// returns every `spacing` from a phase of their own, none in the holes: `flat` and
    /// `lines` as [`HoleDetector::flatten`] leaves them.
    fn scanned(spec: &BoardSpec, rows: &[f64], spacing: f64) -> HoleDetector {
        let mut detector = HoleDetector::new(spec, HoleConfig::default());
        let (hw, r) = (spec.width / 2.0, spec.hole_radius);
        for (k, &y) in rows.iter().enumerate() {
            let phase = (k as f64 * 0.618).fract() * spacing;
            let mut x = -hw + phase;
            while x < hw {
                if spec.holes.iter().all(|h| (x - h[0]).hypot(y - h[1]) > r) {
                    detector.lines.push((k as f64 * 0.01, detector.flat.len() as u32));
                    detector.flat.push([x, y]);
                }
                x += spacing;
            }
        }
        detector
    }

    /// A line's returns past a side, cut off from the board by a gap of more than three
    /// spacings (a stand beside it), are not its end; past a side with no such gap, or a
    /// gap inside the outline (a hole), they are.
    #[test]
    fn returns_cut_off_past_a_side_are_no_end_of_the_line() {
        let line = |xs: &[f64]| -> Vec<(f64, u32)> {
            xs.iter().enumerate().map(|(k, &x)| (x, k as u32)).collect()
        };
        let mut scratch = Vec::new();
        let board: Vec<f64> = (0..=40).map(|k| -0.5 + 0.025 * k as f64).collect();
        let stand_both = [&[-0.62, -0.61][..], &board, &[0.58]].concat();
        assert_eq!(board_ends(&line(&stand_both), 0.5, &mut scratch), (2, 42));
        let running_on = [&board[..], &[0.525, 0.55, 0.575]].concat();
        assert_eq!(board_ends(&line(&running_on), 0.5, &mut scratch), (0, 43));
        let hole: Vec<f64> = board.iter().copied().filter(|x| (x - 0.3).abs() > 0.1).collect();
        let hole_then_stand = [&hole[..], &[0.6]].concat();
        let n = hole_then_stand.len();
        assert_eq!(board_ends(&line(&hole_then_stand), 0.5, &mut scratch), (0, n - 2));
        let all_past = line(&[0.6, 0.61, 0.7]);
        assert_eq!(board_ends(&all_past, 0.5, &mut scratch), (0, 2));
    }

    /// The edge crossings pin the board's turn through the holes and sides they reach:
    /// lines 4 cm apart over both rows of holes leave the yaw to about a tenth of a degree
    /// (the sides' ends, 7 mm each, on levers up to 0.46 m); lines over the lower row
    /// only, a few times less certain; and the position along x to about a spacing over
    /// √12 shared among the crossings.
    #[test]
    fn edge_crossings_pin_the_turn_by_the_rows_they_cross() {
        let spec = board();
        let fit = Fit { pose: [0.0; 3], cov: [0.0; 9], at_window_edge: false };
        let spacing = 0.025;
        let both: Vec<f64> = (0..24).map(|k| -0.46 + 0.04 * k as f64).collect();
        let lower: Vec<f64> = both.iter().copied().filter(|&y| y > 0.2).collect();
        let cov_both = scanned(&spec, &both, spacing).edge_covariance(&fit).expect("pinned");
        let cov_lower = scanned(&spec, &lower, spacing).edge_covariance(&fit).expect("pinned");
        let yaw_deg = |c: &[f64; 9]| c[8].sqrt().to_degrees();
        assert!(yaw_deg(&cov_both) < 0.2, "both rows: yaw σ {:.3}°", yaw_deg(&cov_both));
        assert!(
            yaw_deg(&cov_lower) > 2.0 * yaw_deg(&cov_both),
            "lower row {:.3}° against both rows {:.3}°",
            yaw_deg(&cov_lower),
            yaw_deg(&cov_both)
        );
        // 24 lines, each crossing both sides and two hole edges on most: x to about
        // 7 mm / √(4·24).
        let sigma_x = cov_both[0].sqrt();
        assert!(sigma_x > 0.0005 && sigma_x < 0.0015, "σ x {:.2} mm", sigma_x * 1e3);
        // A single line running along the board's top pins nothing about y or the turn.
        assert!(scanned(&spec, &[-0.49], spacing).edge_covariance(&fit).is_none());
    }

    /// A board pitched 30° at 7 m, crossed by three scan lines 0.15 m apart, its ranges
    /// noisy along the beams (σ 2 cm): the points' scatter across the lines is so small that
    /// the noise's own scatter along the beams turns an orthogonal least-squares normal by
    /// about half a degree; the fit along the beams does not. Also its offset and RMS.
    #[test]
    fn plane_fit_along_the_beams_is_unbiased_for_range_noise() {
        let (pitch, range, sigma) = (30f64.to_radians(), 7.0, 0.02);
        let n_true = Vec3::new(pitch.cos(), 0.0, pitch.sin());
        let d_true = range * pitch.cos();
        let mut rng = crate::sim::rng::Rng::new(14);
        let mut points = Vec::new();
        for line in -1..=1 {
            let elevation = (0.15 * line as f64 / range).atan();
            for k in -20_000..=20_000 {
                let azimuth = 0.5 / range * k as f64 / 20_000.0;
                let (se, ce) = elevation.sin_cos();
                let b = Vec3::new(ce * azimuth.cos(), ce * azimuth.sin(), se);
                let r = d_true / n_true.dot(&b);
                points.push(b * (r + sigma * rng.normal()));
            }
        }
        let tilt = |n: Vec3| n.angle(&n_true).to_degrees();

        // Today's orthogonal fit, the prior the detector starts from.
        let mut m = Moments::default();
        points.iter().for_each(|p| m.add(p));
        let (c0, cov) = m.mean_cov();
        let (_, n0) = smallest_eigen(&cov);
        let n0 = if n0.dot(&c0) < 0.0 { -n0 } else { n0 };
        println!("orthogonal fit: normal {:.3}° off", tilt(n0));
        assert!(tilt(n0) > 0.3, "the orthogonal fit is biased: {:.3}°", tilt(n0));

        let (c, n, rms) = fit_plane(&points, c0, n0).unwrap();
        // The fitted plane's offset at the board's centre (the origin is 7 m away).
        let offset = n.dot(&(Vec3::new(range, 0.0, 0.0) - c));
        println!("fit along the beams: normal {:.3}° off, offset {:.2} mm", tilt(n), 1e3 * offset);
        assert!(tilt(n) < 0.1, "normal {:.3}° off", tilt(n));
        assert!(offset.abs() < 1e-3, "offset {:.2} mm", 1e3 * offset);
        // The orthogonal distance of range noise σ at incidence θ is σ·cos θ.
        assert!((rms / (sigma * pitch.cos()) - 1.0).abs() < 0.03, "rms {:.2} mm", rms * 1e3);
    }
}
