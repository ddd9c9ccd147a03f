//! The board model as a mask: the outline minus the holes rasterised (2 mm for the fine
//! search, 1 cm for the coarse), and the scores of the evidence at a pose, one centre at a
//! time or a whole lattice of centres at once (the paper's idea: slide the board model over
//! the projected points).

use crate::target::BoardSpec;

/// The board model rasterised (2 mm for the fine search, 1 cm for the coarse): each
/// cell holds +1 on solid board, −1 in a hole and 0 outside (as does everything beyond
/// the grid). The scores follow from it: a return scores 2v − 1 (+1 on solid board, −3 in
/// a hole, −1 outside); a gap point (where a scan line crossing the plane returned
/// nothing) −2v − 1 (+1 in a hole, −3 on solid board: it would have returned, −1
/// outside); a see-through point (a beam that crossed the plane and returned from behind
/// it) −3 on solid board and nothing elsewhere (beams pass beside a board as freely as
/// through its holes, so they only veto solid board).
#[derive(Clone, Debug)]
pub(super) struct Mask {
    /// Cell side (m).
    pub(super) step: f64,
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
    pub(super) fn new(spec: &BoardSpec, step: f64) -> Self {
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
    pub(super) fn turn(&self, points: &[[f64; 2]], yaw: f64, out: &mut Vec<[f64; 2]>) {
        let (s, c) = yaw.sin_cos();
        let inv = 1.0 / self.step;
        out.clear();
        out.extend(
            points.iter().map(|p| [(c * p[0] + s * p[1]) * inv, (c * p[1] - s * p[0]) * inv]),
        );
    }

    /// The board centre `t` (plane frame, m) in the frame of points turned by −`yaw` and
    /// scaled to cells.
    pub(super) fn turned_centre(&self, t: [f64; 2], yaw: f64) -> [f64; 2] {
        let (s, c) = yaw.sin_cos();
        [(c * t[0] + s * t[1]) / self.step, (c * t[1] - s * t[0]) / self.step]
    }

    /// Score of evidence turned by [`Mask::turn`] for board centre `t` (plane frame) and
    /// the same `yaw`.
    pub(super) fn score_turned(&self, e: Evidence, t: [f64; 2], yaw: f64) -> i64 {
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
    pub(super) fn score_lattice(
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
pub(super) const MAX_LATTICE: usize = 128;

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
pub(super) struct Evidence<'a> {
    pub(super) returns: &'a [[f64; 2]],
    pub(super) gaps: &'a [[f64; 2]],
    pub(super) through: &'a [[f64; 2]],
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::holes::test_board;

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
        let mut odd = test_board();
        odd.holes.clear();
        for h in [[-0.58, -0.46], [0.2, 0.1], [0.25, 0.12], [0.61, 0.0], [0.0, 0.55]] {
            odd.holes.push(h).unwrap();
        }
        odd.hole_radius = 0.0731;
        for spec in [test_board(), odd] {
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
        let spec = test_board();
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
}
