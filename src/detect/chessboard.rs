//! Checkerboard detection: every board of the room's pattern in one 8-bit grey frame,
//! in one pass, with sub-pixel corners and a per-corner accuracy estimate.
//!
//! Method:
//! 1. ChESS corner response (16-sample ring, radius 5) and non-maximum suppression;
//! 2. a ring test at each peak keeps only saddles (exactly four alternating crossings)
//!    and reads the corner's two edge lines and their polarity;
//! 3. seeds: strongest free candidate with four neighbours along its lines and the four
//!    diagonals (a 3×3 grid); the grid then grows one line at a time, each corner
//!    predicted by extrapolating its column (quadratic from three corners: follows
//!    perspective and strong barrel/fisheye distortion without a homography) and
//!    accepted only with the right edge-line polarity; corners the response missed are
//!    probed in the image;
//! 4. squares must alternate dark/light; the grid is made right-handed like the board
//!    frame, turned to the spec's `cols × rows`, and the square colours fix the
//!    orientation (top-left square black) where the pattern is asymmetric;
//! 5. every corner is refined with a gradient-orthogonality fit (cornerSubPix-style)
//!    whose window follows the local square size; the fit's sandwich covariance gives
//!    the per-corner standard deviation.
//!
//! A board whose grid is not exactly `cols × rows` with every corner is reported with
//! `complete = false` and local grid indices only: its corners are real, but which board
//! corners they are is not claimed.
//!
//! All buffers live in [`ChessboardDetector`], sized once per image size: after the
//! first call `detect` makes no heap allocation.

mod corner;
mod grid;
mod response;

use crate::target::{BoardSpec, MAX_BOARDS};

use super::DetectError;
use corner::View;
use grid::{Cand, Grid, Grower, Index};

/// Most inner corners a board pattern may have.
pub const MAX_BOARD_CORNERS: usize = 512;
/// Most inner corners along one side of a pattern.
const MAX_SIDE: usize = 60;
/// Most corner candidates kept per frame (the response threshold rises until they fit).
const MAX_CANDIDATES: usize = 1 << 15;
/// Lowest ChESS response taken as a candidate (≈ 8 × the black–white contrast).
const BASE_THRESHOLD: i16 = 64;
/// Least ring contrast (mean absolute deviation, grey levels) of a corner.
const MIN_CONTRAST: f32 = 6.0;
/// Empirical factor from the sandwich covariance to the observed error spread.
const SIGMA_SCALE: f32 = 0.3;
/// Most the corner may move between the full and the half window (px): more means
/// something else in the window (a stand in front of the board, a reflection) biases
/// it, and the corner is dropped rather than reported wrong.
const MAX_WINDOW_SHIFT: f32 = 0.3;
/// Floor of the reported standard deviation (px).
const SIGMA_FLOOR: f32 = 0.01;

/// One inner corner of a detected board.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Corner {
    /// Sub-pixel position (px; pixel centres at integer coordinates).
    pub x: f64,
    pub y: f64,
    /// Estimated standard deviation of each coordinate (px), for solver weights.
    pub sigma: f64,
    /// Column and row in the board's grid (for a complete board, the board's own
    /// corner numbering: index = row · cols + col).
    pub col: u16,
    pub row: u16,
}

/// One detected board.
#[derive(Clone, Debug, PartialEq)]
pub struct Board {
    /// Grid size found: the spec's `inner_corners` when `complete`.
    pub cols: u16,
    pub rows: u16,
    /// Every corner of the spec was found and ordered as the board model numbers them.
    /// An incomplete board's `col`/`row` are local to what was seen.
    pub complete: bool,
    /// Corners in row-major order (`row · cols + col` for a complete board).
    pub corners: heapless::Vec<Corner, MAX_BOARD_CORNERS>,
}

impl Board {
    /// The corner at (col, row), if found.
    pub fn corner(&self, col: u16, row: u16) -> Option<&Corner> {
        self.corners.iter().find(|c| c.col == col && c.row == row)
    }
}

/// The detector and its workspace, sized for one image size and one board pattern.
pub struct ChessboardDetector {
    w: usize,
    h: usize,
    cols: usize,
    rows: usize,
    resp: Vec<i16>,
    peaks: Vec<(u16, u16, i16)>,
    cands: Vec<Cand>,
    order: Vec<u32>,
    index: Index,
    grid: Grid,
}

impl ChessboardDetector {
    /// A detector for `width`×`height` frames of boards with `spec.inner_corners`.
    pub fn new(width: u32, height: u32, spec: &BoardSpec) -> Result<Self, DetectError> {
        let [cols, rows] = spec.inner_corners;
        if width < 32 || height < 32 || width > u16::MAX as u32 || height > u16::MAX as u32 {
            return Err(DetectError::ImageTooSmall { width, height });
        }
        let pattern_ok = (2..=MAX_SIDE as u32).contains(&cols)
            && (2..=MAX_SIDE as u32).contains(&rows)
            && (cols * rows) as usize <= MAX_BOARD_CORNERS;
        if !pattern_ok {
            return Err(DetectError::Pattern { cols, rows, max: MAX_SIDE as u32 });
        }
        let (w, h) = (width as usize, height as usize);
        let cap = cols.max(rows) as usize + 2;
        Ok(ChessboardDetector {
            w,
            h,
            cols: cols as usize,
            rows: rows as usize,
            resp: vec![0; w * h],
            peaks: Vec::with_capacity(MAX_CANDIDATES),
            cands: Vec::with_capacity(MAX_CANDIDATES + MAX_BOARDS * MAX_BOARD_CORNERS),
            order: Vec::with_capacity(MAX_CANDIDATES),
            index: Index::new(w, h, MAX_CANDIDATES),
            grid: Grid::new(cap),
        })
    }

    /// Frame width the detector was built for.
    pub fn width(&self) -> u32 {
        self.w as u32
    }

    /// Frame height the detector was built for.
    pub fn height(&self) -> u32 {
        self.h as u32
    }

    /// Frees the frame-sized response buffer (2 bytes a pixel) until the next detection,
    /// which makes it again; see [`crate::detect::holes::HoleDetector::release_workspace`].
    pub fn release_workspace(&mut self) {
        self.resp = Vec::new();
    }

    /// Finds every board in `img` (row-major 8-bit grey, `width * height` bytes) and
    /// replaces the contents of `out` with them (at most [`MAX_BOARDS`]).
    pub fn detect(&mut self, img: &[u8], out: &mut Vec<Board>) -> Result<(), DetectError> {
        if img.len() != self.w * self.h {
            return Err(DetectError::FrameSize {
                width: self.w as u32,
                height: self.h as u32,
                got: img.len(),
            });
        }
        out.clear();
        out.reserve(MAX_BOARDS);
        if self.resp.len() != self.w * self.h {
            self.resp = vec![0; self.w * self.h];
        }
        let view = View { data: img, w: self.w, h: self.h };
        response::chess_response(img, self.w, self.h, &mut self.resp);
        self.find_peaks();
        self.make_candidates(&view);
        self.index.build(&self.cands);
        self.order.clear();
        self.order.extend(0..self.cands.len() as u32);
        let cands = &self.cands;
        self.order
            .sort_unstable_by(|&a, &b| cands[b as usize].score.total_cmp(&cands[a as usize].score));
        self.assemble(&view, out);
        Ok(())
    }

    /// Response peaks; the threshold doubles until they fit the workspace.
    fn find_peaks(&mut self) {
        let mut threshold = BASE_THRESHOLD;
        while !response::local_maxima(&self.resp, self.w, self.h, threshold, &mut self.peaks) {
            threshold = threshold.saturating_mul(2);
        }
    }

    /// Saddle candidates from the peaks: ring test, then a small refinement.
    fn make_candidates(&mut self, view: &View) {
        self.cands.clear();
        for &(x, y, v) in &self.peaks {
            let (x, y) = (x as f32, y as f32);
            let Some(lines) = corner::ring_lines(view, x, y, 5.0, MIN_CONTRAST) else {
                continue;
            };
            let Some(r) = corner::refine(view, x, y, 3, 4) else { continue };
            if (r.x - x).abs() > 2.5 || (r.y - y).abs() > 2.5 {
                continue;
            }
            self.cands.push(Cand {
                x: r.x,
                y: r.y,
                lines,
                score: v as f32 + lines.contrast,
                used: false,
            });
        }
    }

    /// Seeds and grows grids from the strongest free candidates; keeps the boards.
    fn assemble(&mut self, view: &View, out: &mut Vec<Board>) {
        let search = 0.15 * self.w.max(self.h) as f32;
        for k in 0..self.order.len() {
            if out.len() == MAX_BOARDS {
                break;
            }
            let c = self.order[k] as usize;
            if self.cands[c].used {
                continue;
            }
            let mut grower = Grower {
                view: *view,
                cands: &mut self.cands,
                index: &self.index,
                grid: &mut self.grid,
                min_contrast: MIN_CONTRAST,
            };
            if !grower.seed(c, search) {
                continue;
            }
            grower.grow();
            grower.fill_holes();
            if let Some(board) = self.finish(view) {
                out.push(board);
            }
        }
    }

    /// Checks the grown grid, orients it to the board model and refines its corners.
    fn finish(&mut self, view: &View) -> Option<Board> {
        let (gc, gr) = (self.grid.cols, self.grid.rows);
        let fits = (gc <= self.cols && gr <= self.rows) || (gc <= self.rows && gr <= self.cols);
        if !fits || self.grid.filled() < 9 {
            return None;
        }
        if handedness(&self.grid, &self.cands) < 0.0 {
            self.grid.transpose();
        }
        let (votes, total) = square_votes(view, &self.grid, &self.cands);
        if total < 4 || (votes.max(total - votes) as f32) < 0.9 * total as f32 {
            return None;
        }
        self.orient(view);
        let complete = self.grid.cols == self.cols
            && self.grid.rows == self.rows
            && self.grid.filled() == self.cols * self.rows;
        self.refine_output(view, complete)
    }

    /// Turns the grid to the spec's cols × rows with the top-left square black; for a
    /// symmetric pattern the turn whose first corner is nearest the image's top-left.
    fn orient(&mut self, view: &View) {
        let mut best: Option<(usize, f32)> = None;
        for k in 0..4 {
            let dims_ok = self.grid.cols == self.cols && self.grid.rows == self.rows;
            if dims_ok && self.grid.filled() == self.cols * self.rows {
                let (votes, total) = square_votes(view, &self.grid, &self.cands);
                // `votes` counts pairs where the even-parity square is the darker one.
                if 2 * votes > total {
                    let c0 = self
                        .grid
                        .get(0, 0)
                        .map_or(f32::INFINITY, |c| self.cands[c].x + self.cands[c].y);
                    if !best.is_some_and(|(_, b)| c0 >= b) {
                        best = Some((k, c0));
                    }
                }
            }
            self.grid.rotate();
        }
        let turns = match best {
            Some((k, _)) => k,
            // Incomplete: any turn that fits inside the pattern, else as found.
            None => (0..4)
                .find(|&k| {
                    let (c, r) = if k % 2 == 0 {
                        (self.grid.cols, self.grid.rows)
                    } else {
                        (self.grid.rows, self.grid.cols)
                    };
                    c <= self.cols && r <= self.rows
                })
                .unwrap_or(0),
        };
        for _ in 0..turns {
            self.grid.rotate();
        }
    }

    /// Final refinement with windows sized by the local spacing; builds the board.
    fn refine_output(&mut self, view: &View, complete: bool) -> Option<Board> {
        let mut board = Board {
            cols: self.grid.cols as u16,
            rows: self.grid.rows as u16,
            complete,
            corners: heapless::Vec::new(),
        };
        for j in 0..self.grid.rows {
            for i in 0..self.grid.cols {
                let Some(c) = self.grid.get(i, j) else { continue };
                let spacing = local_spacing(&self.grid, &self.cands, i, j);
                let radius = ((0.4 * spacing).round() as usize).clamp(2, corner::MAX_REFINE_RADIUS);
                let (x0, y0) = (self.cands[c].x, self.cands[c].y);
                let Some((r, shift)) = refine_stable(view, x0, y0, radius) else {
                    board.complete = false;
                    continue;
                };
                let moved = (r.x - x0).abs() > 0.25 * spacing || (r.y - y0).abs() > 0.25 * spacing;
                if moved || !clean_window(view, r.x, r.y, radius as f32) {
                    board.complete = false;
                    continue;
                }
                // Larger eigenvalue of the 2×2 covariance: the worse direction.
                let half_trace = 0.5 * (r.cxx + r.cyy);
                let gap = (0.25 * (r.cxx - r.cyy).powi(2) + r.cxy * r.cxy).sqrt();
                let var = (half_trace + gap).max(0.0);
                let sigma = (SIGMA_SCALE * var.sqrt()).max(SIGMA_FLOOR).max(shift);
                let corner = Corner {
                    x: r.x as f64,
                    y: r.y as f64,
                    sigma: sigma as f64,
                    col: i as u16,
                    row: j as u16,
                };
                // Capacity is checked in `new` (cols · rows ≤ MAX_BOARD_CORNERS).
                board.corners.push(corner).ok()?;
            }
        }
        Some(board)
    }
}

/// Refines with the given window, and checks it against half that window: when the two
/// disagree by more than [`MAX_WINDOW_SHIFT`], something else in the larger window (the
/// board's edge under steep tilt, a stand in front of the board) biases it, and the
/// smaller window is tried in turn, down to a half-size of 4. Returns the estimate and
/// its shift from the check; `None` when the fit itself fails.
fn refine_stable(view: &View, x0: f32, y0: f32, radius: usize) -> Option<(corner::Refined, f32)> {
    let mut radius = radius;
    let mut current = corner::refine(view, x0, y0, radius, 10)?;
    // Below this half-size a window is too small to check against its half.
    while radius >= 6 {
        // Half the window, plus one pixel: a half-size of 3 alone is too noisy a check
        // under heavy blur and noise (it moved good corners by 0.5 px).
        let smaller = radius / 2 + 1;
        let half = corner::refine(view, current.x, current.y, smaller, 10)?;
        let shift = ((half.x - current.x).powi(2) + (half.y - current.y).powi(2)).sqrt();
        // The half window is noisier: allow for some of its own spread.
        let half_sigma = (0.5 * (half.cxx + half.cyy)).max(0.0).sqrt() * SIGMA_SCALE;
        if shift <= MAX_WINDOW_SHIFT + (2.0 * half_sigma).min(0.2) {
            return Some((current, shift));
        }
        radius = smaller;
        current = half;
    }
    Some((current, 0.0))
}

/// Whether the refinement window round (x, y) holds a plain saddle: rings inside and at
/// the edge of the window each cross the mean exactly four times.
fn clean_window(view: &View, x: f32, y: f32, radius: f32) -> bool {
    if radius < 3.0 {
        return true;
    }
    [0.6, 1.2].iter().all(|k| corner::ring_lines(view, x, y, k * radius, MIN_CONTRAST).is_some())
}

/// Sign of the cross product of the grid's mean column and row steps: positive when the
/// grid is right-handed in image coordinates, like the board frame seen from the front.
fn handedness(grid: &Grid, cands: &[Cand]) -> f32 {
    let (mut ei, mut ej) = ([0f32; 2], [0f32; 2]);
    for j in 0..grid.rows {
        for i in 0..grid.cols {
            let Some(c) = grid.get(i, j) else { continue };
            if let Some(n) = (i + 1 < grid.cols).then(|| grid.get(i + 1, j)).flatten() {
                ei[0] += cands[n].x - cands[c].x;
                ei[1] += cands[n].y - cands[c].y;
            }
            if let Some(n) = (j + 1 < grid.rows).then(|| grid.get(i, j + 1)).flatten() {
                ej[0] += cands[n].x - cands[c].x;
                ej[1] += cands[n].y - cands[c].y;
            }
        }
    }
    ei[0] * ej[1] - ei[1] * ej[0]
}

/// Mean grey level inside the square whose top-left corner is grid (i, j).
fn square_value(view: &View, grid: &Grid, cands: &[Cand], i: usize, j: usize) -> Option<f32> {
    let ids = [grid.get(i, j)?, grid.get(i + 1, j)?, grid.get(i, j + 1)?, grid.get(i + 1, j + 1)?];
    let (mut cx, mut cy) = (0f32, 0f32);
    for &c in &ids {
        cx += 0.25 * cands[c].x;
        cy += 0.25 * cands[c].y;
    }
    let mut sum = view.bilinear(cx, cy);
    for &c in &ids {
        sum += view.bilinear(0.5 * (cx + cands[c].x), 0.5 * (cy + cands[c].y));
    }
    Some(sum / 5.0)
}

/// Over adjacent square pairs: how many have the even-parity square (i + j even) darker,
/// and how many pairs were compared.
fn square_votes(view: &View, grid: &Grid, cands: &[Cand]) -> (usize, usize) {
    let (mut votes, mut total) = (0, 0);
    if grid.cols < 2 || grid.rows < 2 {
        return (0, 0);
    }
    for j in 0..grid.rows - 1 {
        for i in 0..grid.cols - 1 {
            let Some(v) = square_value(view, grid, cands, i, j) else { continue };
            for (ni, nj) in [(i + 1, j), (i, j + 1)] {
                if ni + 1 >= grid.cols || nj + 1 >= grid.rows {
                    continue;
                }
                let Some(n) = square_value(view, grid, cands, ni, nj) else { continue };
                let even_is_darker = if (i + j) % 2 == 0 { v < n } else { n < v };
                total += 1;
                votes += even_is_darker as usize;
            }
        }
    }
    (votes, total)
}

/// Distance from grid (i, j) to its nearest found 4-neighbour.
fn local_spacing(grid: &Grid, cands: &[Cand], i: usize, j: usize) -> f32 {
    let Some(c) = grid.get(i, j) else { return 0.0 };
    let mut best = f32::INFINITY;
    let neighbours = [(i.wrapping_sub(1), j), (i + 1, j), (i, j.wrapping_sub(1)), (i, j + 1)];
    for (ni, nj) in neighbours {
        if ni >= grid.cols || nj >= grid.rows {
            continue;
        }
        if let Some(n) = grid.get(ni, nj) {
            let d = ((cands[n].x - cands[c].x).powi(2) + (cands[n].y - cands[c].y).powi(2)).sqrt();
            best = best.min(d);
        }
    }
    if best.is_finite() {
        best
    } else {
        10.0
    }
}
