//! LiDAR board detection: every board of the room in a sweep (XYZ only, no region of
//! interest), its pose and its hole centres with an uncertainty each.
//!
//! [`HoleDetector`] runs the stages in order, each on a workspace of its own that is kept
//! and reused from sweep to sweep (after the first sweep of a size no allocation happens);
//! each stage's file says how and why it works:
//!
//! 1. **Sweep** (`sweep.rs`): the returns within range; the sweep's scan lines are learnt
//!    on the way (a census of elevation angles: no ring numbers needed) and every return
//!    indexed by line and azimuth.
//! 2. **Voxels** (`voxels.rs`): returns binned in 10 cm voxels, each voxel's local plane
//!    from the moments of its 3×3×3 neighbourhood.
//! 3. **Plane segments** (`segment.rs`): planar voxels grown into regions; regions larger
//!    than a board drop out; fragments of one plane that together stay thin and no larger
//!    than a board are merged; each group's points are gathered from its plane.
//! 4. **Board plane** (`plane.rs`) on the board's **scan lines** (`scan_lines.rs`): of
//!    each line only its longest run without a hole-wide gap is kept, short lines drop
//!    out, the plane is refitted along the beams on what remains and the points gathered
//!    again about the refit while it still moves.
//! 5. **Ray projection** (`projection.rs`): each inlier moved along its own beam onto the
//!    plane (no range noise in the plane), gap points where lines cross holes, see-through
//!    points where beams crossed the plane. Fewer than four hole-wide gaps: refused before
//!    any search.
//! 6. **Mask search** (`search.rs` over the board model in `mask.rs`): the board model
//!    slid over the evidence in (x, y, yaw) on coarse, medium and fine grids; the best of
//!    several distinct optima kept only when it leads every rival by a margin
//!    ([`Refusal::Ambiguous`] otherwise).
//! 7. **Checks** (`checks.rs`): the scan lines' ends against the outline, beams through
//!    solid board, points in holes, lines per hole, lines missing, and the face: stepping
//!    along every scan line that crosses the fitted board through the whole sweep, the
//!    beams meeting its solid face must return from it and those meeting its holes must
//!    not. A board that fails one is refused with a [`Refusal`] instead of guessed.
//! 8. **Placement** (`placement.rs`): every hole — well seen or not — placed through the
//!    rigid board model, each with its σ. Once placed, the plane is fitted again on the
//!    returns within the outline; when that turns it by more than 0.3° (clutter beyond the
//!    outline within the band had tilted it) the board is placed again on that plane. Two
//!    groups that settle on one board (a stand below it whose gathered plane turns onto the
//!    board's) place it once, from the plane with more returns.
//!
//! **Where a board is expected** ([`HoleDetector::detect_expected`], `expected.rs`):
//! given each board's predicted pose (a surveyed room's, through the camera's room pose and
//! the LiDAR's nominal mounting) steps 2–3 are replaced by the densest band about the
//! predicted plane near the predicted centre; steps 4–8 are the same.
//!
//! Several sweeps of a static scene may be concatenated into one `detect` call: the
//! lines interleave, the gaps and the plateau narrow (the simulator's four sweeps take the
//! mean hole error from 1.73 to 1.40 mm over three scenes, `tests/it/holes_sim.rs`; they
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

mod checks;
mod expected;
mod mask;
mod placement;
mod plane;
mod projection;
mod scan_lines;
mod search;
mod segment;
mod sweep;
mod voxels;

pub use expected::EXPECTED_REACH_M;
pub use mask::MAX_MASK_SIDE;
pub use search::EXPECTED_YAW_DEG;

use std::path::{Path, PathBuf};

use crate::geometry::{Mat3, Se3, Vec3};
use crate::lidar::{pcd, Point};
use crate::target::{BoardSpec, Room, MAX_HOLES};

use checks::{Checks, HoleLines, SLACK};
use expected::Expected;
use placement::Placement;
use plane::{BoardPlane, PlaneFit, REGATHER_ANGLE_RAD};
use projection::{Frame, Projection};
use scan_lines::ScanLines;
use search::{Fit, Search, CANDIDATES};
use segment::Segments;
use sweep::Sweep;
use voxels::Voxels;

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
    /// board's turn weak (the random-room study placed one such board turned by 6° at 2); 3
    /// refuses it, but also many boards that 2 lines place within a few millimetres
    /// (`tests/it/holes_sim.rs`, the fixtures' calibrations), so the default is 2.
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
    /// The sensor's beams do not show a board's face at the fitted pose: of the `solid`
    /// beams meeting its solid face (and not hidden by something in front) `returned`
    /// came back from it, and `filled` holes returned most of their beams from its plane.
    /// A board's face returns nearly every beam and its holes none; a structure with gaps
    /// on the hole lattice (a post and two patches, a fence) leaves the face empty, a wall
    /// fills the holes.
    FaceEmpty { returned: usize, solid: usize, filled: usize },
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
            Refusal::FaceEmpty { returned, solid, filled } => write!(
                f,
                "{returned} of the {solid} beams that meet the fitted board's solid face returned \
                 from it and {filled} of its holes are filled: not a board's face"
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
            Refusal::NoHolePattern { .. } => {
                "if it is a board, check the room file's hole positions and radius"
            }
            // Most often a board too few scan lines cross (far, or in sparse beams); a
            // room file whose holes are elsewhere looks the same.
            Refusal::NoHoleGaps { .. } => {
                "if it is a board, too few scan lines cross its holes: bring it closer or into the LiDAR's denser beams, or check the room file's hole positions"
            }
            Refusal::HolesUnseen { .. }
            | Refusal::FewLines { .. }
            | Refusal::Unconstrained { .. } => {
                "if it is a board, bring it closer or into the LiDAR's denser beams"
            }
            Refusal::Ambiguous { .. } => {
                "if it is a board, turn or move it so more scan lines cross its holes"
            }
            Refusal::FaceEmpty { .. } => {
                "if it is a board, check the room file's board size and that its face returns the LiDAR's beams (not black or glossy)"
            }
            Refusal::OutlineDisagrees { .. } | Refusal::SeenThrough { .. } => {
                "if it is a board, check the room file's board size and clear what touches its edges"
            }
        }
    }
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

/// The detector: one workspace per stage, every buffer kept and reused from sweep to
/// sweep, so after the first sweep of a size no allocation happens.
#[derive(Debug)]
pub struct HoleDetector {
    spec: BoardSpec,
    config: HoleConfig,
    sweep: Sweep,
    voxels: Voxels,
    segments: Segments,
    expected: Expected,
    plane: BoardPlane,
    scan_lines: ScanLines,
    projection: Projection,
    search: Search,
    checks: Checks,
    placement: Placement,
    refused: Vec<RefusedBoard>,
}

impl HoleDetector {
    /// A detector for boards of `spec`.
    pub fn new(spec: &BoardSpec, config: HoleConfig) -> Self {
        HoleDetector {
            spec: spec.clone(),
            config,
            sweep: Sweep::default(),
            voxels: Voxels::default(),
            segments: Segments::default(),
            expected: Expected::default(),
            plane: BoardPlane::default(),
            scan_lines: ScanLines::default(),
            projection: Projection::default(),
            search: Search::new(spec, symmetric(spec)),
            checks: Checks::default(),
            placement: Placement::default(),
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
    /// not sit idle under its solve, its report and between visits (docs/design-notes.md, "Daemon
    /// and memory"); what was refused stays for the report.
    pub fn release_workspace(&mut self) {
        self.sweep.release();
        self.voxels.release();
        self.segments.release();
        self.plane.release();
        self.projection.release();
    }

    /// Finds every board in `points` (LiDAR frame; several sweeps of a static scene may be
    /// concatenated) and writes them to `out` (cleared first).
    pub fn detect(&mut self, points: &[Point], out: &mut Vec<LidarBoard>) {
        out.clear();
        self.refused.clear();
        self.sweep.load(points, &self.config);
        self.voxels.build(&self.sweep, &self.config);
        let diagonal = self.board_diagonal();
        let groups = self.segments.groups(&self.voxels, &self.config, diagonal).len();
        for k in 0..groups {
            let root = self.segments.root(k);
            let Some(group_plane) = self.segments.group_plane(root, diagonal) else { continue };
            if let Some(plane) = self.settled_plane(Region::Group(root), group_plane) {
                self.examine(plane, None, out, true);
            }
        }
    }

    /// Places the board expected at each of `expected` (board → LiDAR) in `points`: `out[i]`
    /// is the board placed within its half diagonal and 0.3 m of `expected[i]`, or `None` (the
    /// reason, if a plane was there, in [`HoleDetector::refused`]).
    pub fn detect_expected(
        &mut self,
        points: &[Point],
        expected: &[Se3],
        out: &mut Vec<Option<LidarBoard>>,
    ) {
        out.clear();
        self.refused.clear();
        self.sweep.load(points, &self.config);
        let diagonal = self.board_diagonal();
        let reach = diagonal / 2.0 + EXPECTED_REACH_M;
        Expected::keep_in_sight(&mut self.sweep, expected, reach, diagonal);
        let mut placed = Vec::with_capacity(1);
        for pose in expected {
            placed.clear();
            let centre = pose.translation;
            self.expected.set_rivals(expected, centre, reach);
            if let Some(start) = self.expected.densest_band(pose, reach, &self.sweep, &self.config)
            {
                if let Some(plane) = self.settled_plane(Region::Ball(centre, reach), start) {
                    let axis = pose.rotation.column(0).into_owned();
                    self.examine(plane, Some(axis), &mut placed, true);
                }
            }
            let near = |b: &LidarBoard| (b.pose.translation - centre).norm() <= reach;
            out.push(placed.pop().filter(near));
        }
    }

    /// The board's plane settled from `start` on the points of `region` ([`BoardPlane`]),
    /// its points left in the plane's workspace.
    fn settled_plane(&mut self, region: Region, start: (Vec3, Vec3)) -> Option<PlaneFit> {
        let HoleDetector { spec, config, sweep, voxels, segments, expected, plane, .. } = self;
        let (sweep, voxels, segments, expected) = (&*sweep, &*voxels, &*segments, &*expected);
        let gather = |seg: &mut Vec<Vec3>, about| match region {
            Region::Group(root) => segments.gather(root, about, (voxels, sweep), config, seg),
            Region::Ball(centre, radius) => {
                expected.gather((centre, radius), about, sweep, config, seg)
            }
        };
        plane.settle(start, gather, &mut self.scan_lines, sweep, (spec, config))
    }

    /// Places the board on one plane's points (in the plane's workspace, within the band of
    /// the fitted plane `c`, `n` of RMS `rms`) when it is board-sized, or notes why not in
    /// `refused`. With `expected_axis` (the x axis of the board expected there) the search
    /// tries only the yaws near it. With `may_refit`, once the board is placed its plane is
    /// fitted again on the points within its outline alone, and when that turns it by more
    /// than [`REGATHER_ANGLE_RAD`] the board is placed again on that plane: clutter beside
    /// the board that lies within the band (a box face crossing the board's plane above its
    /// top, the random-room study's Pandar64 room 505) tilts a plane fitted on every point,
    /// and a tilt moves the far holes along the normal.
    #[inline(never)]
    fn examine(
        &mut self,
        (c, n, rms): PlaneFit,
        expected_axis: Option<Vec3>,
        out: &mut Vec<LidarBoard>,
        may_refit: bool,
    ) {
        let points = self.plane.points.len();
        if points < self.config.min_points {
            return;
        }
        let frame = self.projection.flatten(&self.plane.points, (c, n));
        let (_, ex, ey, _) = frame;
        self.projection.find_see_through(frame, &self.sweep, self.board_diagonal());
        let chords = self.projection.find_gaps(&self.spec);
        if !self.projection.extent_fits(&self.spec, &self.config) {
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
        if self.projection.flat.len() < self.config.min_points {
            self.refused.push(refuse(Refusal::TooFewPoints { points }));
            return;
        }
        // Two holes crossed by two lines each leave at least four gaps: without them no
        // pose can place the board, and the mask search is not run.
        if chords < 4 {
            self.refused.push(refuse(Refusal::NoHoleGaps { chords }));
            return;
        }
        let expected_yaw = expected_axis.map(|bx| bx.dot(&ey).atan2(bx.dot(&ex)));
        let checked = self
            .best_fit(expected_yaw)
            .and_then(|fit| self.check(&fit, frame).map(|lines| (fit, lines)));
        let (fit, lines) = match checked {
            Ok(placed) => placed,
            Err(Unplaced { reason, lines, guess }) => {
                let best_guess = guess.map(|pose| placement::pose(pose, frame));
                self.refused.push(RefusedBoard {
                    hole_scan_lines: lines,
                    best_guess,
                    ..refuse(reason)
                });
                return;
            }
        };
        let edges = match self.pinned(&fit) {
            Ok(edges) => edges,
            Err(reason) => {
                self.refused.push(refuse(reason));
                return;
            }
        };
        if may_refit {
            let board = (&self.spec, &self.config);
            if let Some(plane) =
                self.plane.within_outline(&fit, (c, n), &self.projection.flat, board)
            {
                if plane.1.angle(&n) > REGATHER_ANGLE_RAD {
                    return self.examine(plane, expected_axis, out, false);
                }
            }
        }
        let plane_sigma = placement::plane_sigma(&self.projection.flat, rms, points);
        let fitted = (plane_sigma, rms, points);
        let board = placement::board(&fit, &edges, frame, fitted, lines, &self.spec);
        placement::keep_distinct(board, out, &self.spec);
    }

    /// The best in-plane pose of the board on the projected evidence: every distinct
    /// coarse optimum (with the expected yaw, only those near it) is refined and scored on
    /// all points; the best is taken only when no other optimum comes close (the evidence
    /// is unambiguous). The candidates are ranked at their medium-grid poses (5 mm, 0.5°
    /// cells); only those near the best are refined on (the fine grid is most of the cost).
    fn best_fit(&mut self, expected_yaw: Option<f64>) -> Result<Fit, Unplaced> {
        let candidates = self.search.coarse(&self.projection, &self.spec, expected_yaw);
        let mut first_refusal = None;
        let mut fits: heapless::Vec<(i64, Fit), CANDIDATES> = heapless::Vec::new();
        for &(_, coarse) in &candidates {
            match self.checks.rough(coarse, &mut self.projection, &self.spec) {
                Err(r) => {
                    first_refusal.get_or_insert((r, coarse));
                }
                Ok(()) => {
                    let fit = self.search.medium(&self.projection, &self.spec, coarse);
                    let score = self.search.full_score(&self.projection, fit.pose);
                    let _ = fits.push((score, fit));
                }
            }
        }
        fits.sort_unstable_by_key(|f| core::cmp::Reverse(f.0));
        // Candidates the medium grid leaves close to the best are refined on and compared
        // again: a many-point board gains more from the fine alignment than the margin.
        let margin = search::margin(self.projection.flat.len());
        let close = fits.first().map_or(i64::MAX, |f| f.0 - 2 * margin);
        for candidate in fits.iter_mut().filter(|f| f.0 >= close) {
            let fine = self.search.fine(&self.projection, &self.spec, candidate.1.pose);
            *candidate = (self.search.full_score(&self.projection, fine.pose), fine);
        }
        fits.sort_unstable_by_key(|f| core::cmp::Reverse(f.0));
        let Some(&(best_score, fit)) = fits.first() else {
            let unseen = (Refusal::HolesUnseen { holes_with_two_lines: 0 }, heapless::Vec::new());
            let ((reason, lines), coarse) = first_refusal.unwrap_or((unseen, [0.0; 3]));
            return Err(Unplaced { reason, lines, guess: Some(coarse) });
        };
        let rival =
            fits[1..].iter().find(|(_, f)| !search::same_holes(&self.spec, &fit, f)).map(|f| f.0);
        if let Some(second) = rival {
            if best_score - second < margin {
                let reason = Refusal::Ambiguous { best: best_score, second };
                return Err(Unplaced {
                    reason,
                    lines: heapless::Vec::new(),
                    guess: Some(fit.pose),
                });
            }
        }
        Ok(fit)
    }

    /// The checks of the best pose `fit` (plane frame `frame`), in order: the first that
    /// fails refuses the board. When all pass, the scan lines crossing each hole.
    fn check(&mut self, fit: &Fit, frame: Frame) -> Result<HoleLines, Unplaced> {
        let refuse = |reason, lines| Err(Unplaced { reason, lines, guess: Some(fit.pose) });
        let (spec, returns) = (&self.spec, self.projection.flat.len());
        let in_holes = checks::points_in_holes(fit, 0.015, &self.projection.flat, spec);
        if in_holes > 3 + returns / 100 {
            return refuse(
                Refusal::NoHolePattern { points_in_holes: in_holes },
                heapless::Vec::new(),
            );
        }
        let evidence = (&mut self.projection, &self.plane);
        let (outside, ends) = self.checks.line_ends_outside(fit, frame, evidence, spec);
        if outside > 1 + ends / 10 {
            return refuse(Refusal::OutlineDisagrees { outside, ends }, heapless::Vec::new());
        }
        let beams = checks::through_solid(fit, &self.projection.through, spec);
        if beams > 2 + returns / 100 {
            return refuse(Refusal::SeenThrough { beams }, heapless::Vec::new());
        }
        let lines = self.checks.scan_lines_per_hole(fit, SLACK, &mut self.projection, spec);
        let seen = lines.iter().filter(|&&l| l >= 2).count();
        if seen < 2 {
            return refuse(Refusal::HolesUnseen { holes_with_two_lines: seen }, lines);
        }
        let mut ranked = lines.clone();
        ranked.sort_unstable_by(|a, b| b.cmp(a));
        let need = self.config.min_hole_lines;
        if ranked[1] < need {
            return refuse(Refusal::FewLines { lines: ranked[1], need }, lines);
        }
        // The sensor's scan lines that pass through the board's outline should return from
        // it: a structure that shows only part of the board's height is not one.
        let pose = placement::pose(fit.pose, frame);
        let (seen_lines, expected) =
            checks::lines_over_outline(&pose, &self.projection.lines, &self.sweep, spec);
        if 4 * seen_lines < 3 * expected {
            let reason = Refusal::LinesMissing { seen: seen_lines, expected };
            return Err(Unplaced { reason, lines: heapless::Vec::new(), guess: None });
        }
        // Its solid face must return the beams that meet it: scan lines crossing a post and
        // two patches whose gaps fall on the hole lattice return from little of it.
        let face = checks::face_evidence(&pose, &self.sweep, spec, self.plane.band);
        if !face.shows_a_board() {
            let reason = Refusal::FaceEmpty {
                returned: face.solid_returned,
                solid: face.solid,
                filled: face.filled(),
            };
            return Err(Unplaced { reason, lines: heapless::Vec::new(), guess: Some(fit.pose) });
        }
        Ok(lines)
    }

    /// The covariance the edge crossings allow at `fit` ([`Placement::edge_covariance`]),
    /// when they and the plateau pin the board's position within
    /// [`HoleConfig::max_sigma_m`]: the plateau's spread, or what the edge crossings allow
    /// where that is more.
    fn pinned(&mut self, fit: &Fit) -> Result<[f64; 9], Refusal> {
        let Some(edges) = self.placement.edge_covariance(fit, &mut self.projection, &self.spec)
        else {
            return Err(Refusal::Unconstrained { sigma_m: f64::INFINITY });
        };
        let sigma_xy = fit.cov[0].max(fit.cov[4]).max(edges[0]).max(edges[4]).sqrt();
        if sigma_xy > self.config.max_sigma_m || fit.at_window_edge {
            let sigma_m = if fit.at_window_edge { f64::INFINITY } else { sigma_xy };
            return Err(Refusal::Unconstrained { sigma_m });
        }
        Ok(edges)
    }

    /// The board's diagonal plus the size tolerance on either side (m): the most a board's
    /// points span.
    fn board_diagonal(&self) -> f64 {
        self.spec.width.hypot(self.spec.height) + 2.0 * self.config.size_tolerance_m
    }
}

/// Where a board's points are gathered from: a plane group's voxels, or a ball about where
/// a board is expected (centre, radius in m).
#[derive(Clone, Copy)]
enum Region {
    Group(u32),
    Ball(Vec3, f64),
}

/// A board the search or the checks refused: why, the scan lines crossing each hole when
/// they were counted, and the search's best in-plane pose when it ran.
struct Unplaced {
    reason: Refusal,
    lines: HoleLines,
    guess: Option<[f64; 3]>,
}

/// Whether the hole pattern maps onto itself under a 180° turn.
fn symmetric(spec: &BoardSpec) -> bool {
    spec.holes.iter().all(|h| {
        let k = nearest_hole(spec, -h[0], -h[1]);
        (spec.holes[k][0] + h[0]).hypot(spec.holes[k][1] + h[1]) < 1e-3
    })
}

/// The hole of `spec` nearest the board point (`x`, `y`).
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

/// The room's usual board (1.2 × 1.0 m, four holes of 8 cm radius), for the stages' tests.
#[cfg(test)]
fn test_board() -> BoardSpec {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The usual four holes map onto themselves under a half turn; a fifth off-centre hole
    /// does not, and then the search tries both ways round.
    #[test]
    fn a_hole_pattern_is_symmetric_when_a_half_turn_maps_it_onto_itself() {
        let mut spec = test_board();
        assert!(symmetric(&spec));
        assert_eq!(nearest_hole(&spec, 0.45, 0.35), 3);
        spec.holes.push([0.1, 0.0]).unwrap();
        assert!(!symmetric(&spec));
    }
}
