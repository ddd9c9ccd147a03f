//! Grid assembly: a bucket index over corner candidates, and a board grid grown from a
//! 3×3 seed one row at a time, each new corner predicted by extrapolating its column
//! (quadratic when three corners are known, so perspective and strong lens distortion
//! are followed without a homography) and accepted only with the right edge lines.

use super::corner::{self, Lines, View};

/// A corner candidate: refined position, edge lines, strength, and whether a grid owns it.
#[derive(Clone, Copy, Debug, Default)]
pub struct Cand {
    pub x: f32,
    pub y: f32,
    pub lines: Lines,
    pub score: f32,
    pub used: bool,
}

/// Bucket index (cells of `cell` pixels) over the candidates, rebuilt per frame.
pub struct Index {
    cell: f32,
    ncx: usize,
    ncy: usize,
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Index {
    /// An index for a `w`×`h` image and up to `capacity` candidates.
    pub fn new(w: usize, h: usize, capacity: usize) -> Self {
        let cell = 16.0;
        let ncx = w.div_ceil(16).max(1);
        let ncy = h.div_ceil(16).max(1);
        Index { cell, ncx, ncy, start: vec![0; ncx * ncy + 1], items: Vec::with_capacity(capacity) }
    }

    fn cell_of(&self, x: f32, y: f32) -> (usize, usize) {
        let cx = ((x / self.cell).max(0.0) as usize).min(self.ncx - 1);
        let cy = ((y / self.cell).max(0.0) as usize).min(self.ncy - 1);
        (cx, cy)
    }

    /// Counting sort of the candidates into their cells.
    pub fn build(&mut self, cands: &[Cand]) {
        self.start.fill(0);
        for c in cands {
            let (cx, cy) = self.cell_of(c.x, c.y);
            self.start[cy * self.ncx + cx + 1] += 1;
        }
        for k in 1..self.start.len() {
            self.start[k] += self.start[k - 1];
        }
        self.items.clear();
        self.items.resize(cands.len(), 0);
        // Place items using a running cursor per cell (reusing `start` shifted by one).
        for (i, c) in cands.iter().enumerate() {
            let (cx, cy) = self.cell_of(c.x, c.y);
            let slot = &mut self.start[cy * self.ncx + cx];
            self.items[*slot as usize] = i as u32;
            *slot += 1;
        }
        // Cursors now point at each cell's end = next cell's start: shift back.
        for k in (1..self.start.len()).rev() {
            self.start[k] = self.start[k - 1];
        }
        self.start[0] = 0;
    }

    /// Calls `f` with every candidate index within the square of half-size `r` round (x, y).
    pub fn for_each_near(&self, x: f32, y: f32, r: f32, mut f: impl FnMut(usize)) {
        let (x0, y0) = self.cell_of(x - r, y - r);
        let (x1, y1) = self.cell_of(x + r, y + r);
        for cy in y0..=y1 {
            let row = cy * self.ncx;
            let (s, e) = (self.start[row + x0] as usize, self.start[row + x1 + 1] as usize);
            for &i in &self.items[s..e] {
                f(i as usize);
            }
        }
    }
}

/// sin of the largest angle between a corner's edge line and the way to its neighbour.
const LINE_TOL: f32 = 0.42;

#[inline]
fn cross(a: [f32; 2], b: [f32; 2]) -> f32 {
    a[0] * b[1] - a[1] * b[0]
}

#[inline]
fn dot(a: [f32; 2], b: [f32; 2]) -> f32 {
    a[0] * b[0] + a[1] * b[1]
}

#[inline]
fn norm(a: [f32; 2]) -> f32 {
    dot(a, a).sqrt()
}

/// Which of a corner's lines runs along unit direction `d`: `Some(true)` for `a`,
/// `Some(false)` for `b`, `None` when neither does.
pub fn line_along(lines: &Lines, d: [f32; 2]) -> Option<bool> {
    let (ea, eb) = (cross(lines.a, d).abs(), cross(lines.b, d).abs());
    if ea.min(eb) > LINE_TOL {
        return None;
    }
    Some(ea < eb)
}

/// A board grid under construction: candidate indices, row-major with a fixed stride.
pub struct Grid {
    pub cols: usize,
    pub rows: usize,
    pub cap: usize,
    pub cells: Vec<i32>,
    tmp: Vec<i32>,
}

impl Grid {
    /// A grid that may grow to `cap` × `cap`.
    pub fn new(cap: usize) -> Self {
        Grid { cols: 0, rows: 0, cap, cells: vec![-1; cap * cap], tmp: vec![-1; cap * cap] }
    }

    #[inline]
    pub fn get(&self, i: usize, j: usize) -> Option<usize> {
        let v = self.cells[j * self.cap + i];
        (v >= 0).then_some(v as usize)
    }

    #[inline]
    pub fn set(&mut self, i: usize, j: usize, v: Option<usize>) {
        self.cells[j * self.cap + i] = v.map_or(-1, |v| v as i32);
    }

    pub fn clear(&mut self) {
        self.cells.fill(-1);
        self.cols = 0;
        self.rows = 0;
    }

    /// Rotates the grid a quarter turn: the last column becomes the last row... in
    /// index terms new(i, j) = old(j, rows − 1 − i).
    pub fn rotate(&mut self) {
        let (cols, rows, cap) = (self.cols, self.rows, self.cap);
        self.tmp.fill(-1);
        for j in 0..cols {
            for i in 0..rows {
                self.tmp[j * cap + i] = self.cells[(rows - 1 - i) * cap + j];
            }
        }
        core::mem::swap(&mut self.cells, &mut self.tmp);
        self.cols = rows;
        self.rows = cols;
    }

    /// Mirrors the grid across its diagonal: new(i, j) = old(j, i).
    pub fn transpose(&mut self) {
        let (cols, rows, cap) = (self.cols, self.rows, self.cap);
        self.tmp.fill(-1);
        for j in 0..rows {
            for i in 0..cols {
                self.tmp[i * cap + j] = self.cells[j * cap + i];
            }
        }
        core::mem::swap(&mut self.cells, &mut self.tmp);
        self.cols = rows;
        self.rows = cols;
    }

    /// Number of filled cells.
    pub fn filled(&self) -> usize {
        (0..self.rows).map(|j| (0..self.cols).filter(|&i| self.get(i, j).is_some()).count()).sum()
    }
}

/// Everything the grid growing reads and writes.
pub struct Grower<'a> {
    pub view: View<'a>,
    pub cands: &'a mut Vec<Cand>,
    pub index: &'a Index,
    pub grid: &'a mut Grid,
    pub min_contrast: f32,
}

impl Grower<'_> {
    /// Tries to seed a 3×3 grid round candidate `c`; on success the grid holds it.
    pub fn seed(&mut self, c: usize, search: f32) -> bool {
        let lines = self.cands[c].lines;
        let mut nb = [0usize; 4];
        let dirs = [lines.b, neg(lines.b), lines.a, neg(lines.a)];
        for (k, d) in dirs.iter().enumerate() {
            match self.nearest_along(c, *d, k < 2, search) {
                Some(n) => nb[k] = n,
                None => return false,
            }
        }
        let p = self.pos(c);
        let v: [[f32; 2]; 4] = nb.map(|n| sub(self.pos(n), p));
        let ratio_b = norm(v[0]) / norm(v[1]);
        let ratio_a = norm(v[2]) / norm(v[3]);
        if !(0.6..1.67).contains(&ratio_b) || !(0.6..1.67).contains(&ratio_a) {
            return false;
        }
        self.grid.clear();
        self.grid.cols = 3;
        self.grid.rows = 3;
        self.grid.set(1, 1, Some(c));
        self.grid.set(2, 1, Some(nb[0]));
        self.grid.set(0, 1, Some(nb[1]));
        self.grid.set(1, 2, Some(nb[2]));
        self.grid.set(1, 0, Some(nb[3]));
        for &n in &nb {
            self.cands[n].used = true;
        }
        self.cands[c].used = true;
        for (i, j) in [(0, 0), (2, 0), (0, 2), (2, 2)] {
            let (a, b) = (self.grid.get(i, 1).unwrap_or(c), self.grid.get(1, j).unwrap_or(c));
            let pred = add(sub(self.pos(a), p), self.pos(b));
            let step = norm(sub(self.pos(a), p)).min(norm(sub(self.pos(b), p)));
            // The diagonal corner is joined to `a` along the column direction.
            let d = unit(sub(pred, self.pos(a)));
            match self.find_at(a, pred, d, step) {
                Some(n) => {
                    self.grid.set(i, j, Some(n));
                    self.cands[n].used = true;
                }
                None => {
                    self.release();
                    return false;
                }
            }
        }
        true
    }

    /// Gives the grid's candidates back (a failed seed).
    fn release(&mut self) {
        for j in 0..self.grid.rows {
            for i in 0..self.grid.cols {
                if let Some(n) = self.grid.get(i, j) {
                    self.cands[n].used = false;
                }
            }
        }
        self.grid.clear();
    }

    /// Grows the grid on all four sides until none accepts a new line.
    pub fn grow(&mut self) {
        let mut stalled = 0;
        let mut turns = 0;
        while stalled < 4 && turns < 4 * 4 * self.grid.cap {
            if self.grow_right() {
                stalled = 0;
            } else {
                stalled += 1;
            }
            self.grid.rotate();
            turns += 1;
        }
    }

    /// Adds a column on the right when enough of its predicted corners are found.
    fn grow_right(&mut self) -> bool {
        let (cols, rows) = (self.grid.cols, self.grid.rows);
        if cols >= self.grid.cap || cols < 2 {
            return false;
        }
        let mut pending = [-1i32; 64];
        let (mut predictable, mut matched) = (0, 0);
        for (j, slot) in pending.iter_mut().enumerate().take(rows.min(64)) {
            let (Some(a), Some(b)) = (self.grid.get(cols - 1, j), self.grid.get(cols - 2, j))
            else {
                continue;
            };
            let (pa, pb) = (self.pos(a), self.pos(b));
            let pred = match (cols >= 3).then(|| self.grid.get(cols - 3, j)).flatten() {
                Some(c) => {
                    let pc = self.pos(c);
                    [3.0 * pa[0] - 3.0 * pb[0] + pc[0], 3.0 * pa[1] - 3.0 * pb[1] + pc[1]]
                }
                None => [2.0 * pa[0] - pb[0], 2.0 * pa[1] - pb[1]],
            };
            predictable += 1;
            let step = norm(sub(pa, pb)).min(self.cross_step(cols - 1, j));
            let d = unit(sub(pred, pa));
            if let Some(n) = self.find_at(a, pred, d, step) {
                *slot = n as i32;
                self.cands[n].used = true;
                matched += 1;
            }
        }
        let accept = matched >= 2 && 2 * matched >= predictable;
        for (j, &n) in pending.iter().enumerate().take(rows.min(64)) {
            if n < 0 {
                continue;
            }
            if accept {
                self.grid.set(cols, j, Some(n as usize));
            } else {
                self.cands[n as usize].used = false;
            }
        }
        if accept {
            self.grid.cols += 1;
        }
        accept
    }

    /// Distance from cell (i, j) to its neighbours in the same column (the other axis),
    /// or infinity when it has none.
    fn cross_step(&self, i: usize, j: usize) -> f32 {
        let Some(c) = self.grid.get(i, j) else { return f32::INFINITY };
        let p = self.pos(c);
        let mut best = f32::INFINITY;
        if j > 0 {
            if let Some(n) = self.grid.get(i, j - 1) {
                best = best.min(norm(sub(self.pos(n), p)));
            }
        }
        if j + 1 < self.grid.rows {
            if let Some(n) = self.grid.get(i, j + 1) {
                best = best.min(norm(sub(self.pos(n), p)));
            }
        }
        best
    }

    /// Fills empty cells inside the grid from their neighbours (probing the image).
    pub fn fill_holes(&mut self) {
        for j in 0..self.grid.rows {
            for i in 0..self.grid.cols {
                if self.grid.get(i, j).is_some() {
                    continue;
                }
                let left = (i > 0).then(|| self.grid.get(i - 1, j)).flatten();
                let right = (i + 1 < self.grid.cols).then(|| self.grid.get(i + 1, j)).flatten();
                let up = (j > 0).then(|| self.grid.get(i, j - 1)).flatten();
                let down = (j + 1 < self.grid.rows).then(|| self.grid.get(i, j + 1)).flatten();
                let pair = match (left, right, up, down) {
                    (Some(l), Some(r), _, _) => (l, r),
                    (_, _, Some(u), Some(d)) => (u, d),
                    _ => continue,
                };
                let (p0, p1) = (self.pos(pair.0), self.pos(pair.1));
                let pred = [(p0[0] + p1[0]) * 0.5, (p0[1] + p1[1]) * 0.5];
                let step = 0.5 * norm(sub(p1, p0));
                let d = unit(sub(pred, p0));
                if let Some(n) = self.find_at(pair.0, pred, d, step) {
                    self.cands[n].used = true;
                    self.grid.set(i, j, Some(n));
                }
            }
        }
    }

    /// The corner near `pred` that joins `from` along unit direction `d` (spacing
    /// `step`): the nearest free candidate, else one probed in the image.
    fn find_at(&mut self, from: usize, pred: [f32; 2], d: [f32; 2], step: f32) -> Option<usize> {
        let want_a = !line_along(&self.cands[from].lines, d)?;
        let radius = (0.3 * step).max(1.5);
        let mut best: Option<(usize, f32)> = None;
        self.index.for_each_near(pred[0], pred[1], radius, |n| {
            let c = &self.cands[n];
            let dist = norm([c.x - pred[0], c.y - pred[1]]);
            if c.used || dist > radius || best.is_some_and(|(_, b)| b <= dist) {
                return;
            }
            let way = unit([c.x - self.cands[from].x, c.y - self.cands[from].y]);
            if line_along(&c.lines, way) == Some(want_a) {
                best = Some((n, dist));
            }
        });
        match best {
            Some((n, _)) => Some(n),
            None => self.probe(from, pred, want_a, step, radius),
        }
    }

    /// Looks for a corner in the image itself near `pred` (a candidate the response
    /// missed: low contrast, heavy tilt) and adds it to the candidates.
    fn probe(
        &mut self,
        from: usize,
        pred: [f32; 2],
        want_a: bool,
        step: f32,
        radius: f32,
    ) -> Option<usize> {
        if self.cands.len() == self.cands.capacity() {
            return None;
        }
        let window = ((0.25 * step) as usize).clamp(2, 8);
        let r = corner::refine(&self.view, pred[0], pred[1], window, 6)?;
        if norm([r.x - pred[0], r.y - pred[1]]) > radius {
            return None;
        }
        let ring = (0.4 * step).clamp(2.5, 5.0);
        let lines = corner::ring_lines(&self.view, r.x, r.y, ring, self.min_contrast)?;
        let way = unit([r.x - self.cands[from].x, r.y - self.cands[from].y]);
        if line_along(&lines, way) != Some(want_a) {
            return None;
        }
        self.cands.push(Cand { x: r.x, y: r.y, lines, score: 0.0, used: true });
        Some(self.cands.len() - 1)
    }

    /// The nearest free candidate from `c` along unit direction `d` within `search`
    /// pixels, joined along `c`'s line `b` (`along_b`) or `a`, with the other line type.
    fn nearest_along(&self, c: usize, d: [f32; 2], along_b: bool, search: f32) -> Option<usize> {
        let p = self.pos(c);
        let mut best: Option<(usize, f32)> = None;
        self.index.for_each_near(
            p[0] + 0.5 * search * d[0],
            p[1] + 0.5 * search * d[1],
            0.5 * search,
            |n| {
                let q = &self.cands[n];
                if n == c || q.used {
                    return;
                }
                let v = [q.x - p[0], q.y - p[1]];
                let dist = norm(v);
                if dist < 4.0 || dist > search || best.is_some_and(|(_, b)| b <= dist) {
                    return;
                }
                let u = [v[0] / dist, v[1] / dist];
                if dot(u, d) < 0.9 || cross(u, d).abs() > LINE_TOL {
                    return;
                }
                // Joined along our `b` line means along the neighbour's `a` line.
                if line_along(&q.lines, u) == Some(along_b) {
                    best = Some((n, dist));
                }
            },
        );
        best.map(|(n, _)| n)
    }

    pub fn pos(&self, c: usize) -> [f32; 2] {
        [self.cands[c].x, self.cands[c].y]
    }
}

#[inline]
fn sub(a: [f32; 2], b: [f32; 2]) -> [f32; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

#[inline]
fn add(a: [f32; 2], b: [f32; 2]) -> [f32; 2] {
    [a[0] + b[0], a[1] + b[1]]
}

#[inline]
fn neg(a: [f32; 2]) -> [f32; 2] {
    [-a[0], -a[1]]
}

#[inline]
fn unit(a: [f32; 2]) -> [f32; 2] {
    let n = norm(a).max(1e-9);
    [a[0] / n, a[1] / n]
}
