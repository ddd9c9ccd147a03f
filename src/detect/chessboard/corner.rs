//! Corner-level image operations: bilinear sampling, the ring test that reads a corner's
//! two edge lines and polarity, and gradient (cornerSubPix-style) sub-pixel refinement
//! with a sandwich estimate of the position's covariance. All on the stack.

/// Largest refinement window half-size (pixels).
pub const MAX_REFINE_RADIUS: usize = 15;
const PATCH: usize = 2 * MAX_REFINE_RADIUS + 3;

/// A borrowed 8-bit grey frame.
#[derive(Clone, Copy)]
pub struct View<'a> {
    pub data: &'a [u8],
    pub w: usize,
    pub h: usize,
}

impl View<'_> {
    /// Bilinear intensity at (x, y); coordinates are clamped into the image.
    #[inline]
    pub fn bilinear(&self, x: f32, y: f32) -> f32 {
        let x = x.clamp(0.0, (self.w - 1) as f32 - 1e-3);
        let y = y.clamp(0.0, (self.h - 1) as f32 - 1e-3);
        let (x0, y0) = (x as usize, y as usize);
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let i = y0 * self.w + x0;
        let (p00, p01) = (self.data[i] as f32, self.data[i + 1] as f32);
        let (p10, p11) = (self.data[i + self.w] as f32, self.data[i + self.w + 1] as f32);
        let top = p00 + (p01 - p00) * fx;
        let bottom = p10 + (p11 - p10) * fx;
        top + (bottom - top) * fy
    }

    /// Whether (x, y) lies at least `margin` pixels inside the image.
    #[inline]
    pub fn inside(&self, x: f32, y: f32, margin: f32) -> bool {
        x >= margin
            && y >= margin
            && x <= self.w as f32 - 1.0 - margin
            && y <= self.h as f32 - 1.0 - margin
    }
}

/// The two edge lines through a saddle corner, as unit vectors (undirected).
///
/// Walking round the corner with increasing angle, line `a` is where the ring goes from
/// dark to light, line `b` where it goes from light to dark. Two grid neighbours joined
/// along one corner's `a` line are joined along the other's `b` line: that is the
/// polarity test of the grid growing.
#[derive(Clone, Copy, Debug, Default)]
pub struct Lines {
    pub a: [f32; 2],
    pub b: [f32; 2],
    /// Mean absolute deviation of the ring from its mean (grey levels).
    pub contrast: f32,
}

const RING_N: usize = 32;

/// Reads the edge lines of a corner at (x, y) from a ring of radius `r`; `None` unless
/// the ring crosses its mean exactly four times in alternating, roughly opposite pairs.
pub fn ring_lines(v: &View, x: f32, y: f32, r: f32, min_contrast: f32) -> Option<Lines> {
    if !v.inside(x, y, r + 1.0) {
        return None;
    }
    let mut s = [0f32; RING_N];
    let step = core::f32::consts::TAU / RING_N as f32;
    let (sin_step, cos_step) = step.sin_cos();
    let (mut c, mut sn) = (1.0f32, 0.0f32);
    let mut mean = 0.0;
    for value in s.iter_mut() {
        *value = v.bilinear(x + r * c, y + r * sn);
        mean += *value;
        (c, sn) = (c * cos_step - sn * sin_step, sn * cos_step + c * sin_step);
    }
    mean /= RING_N as f32;
    let contrast = s.iter().map(|value| (value - mean).abs()).sum::<f32>() / RING_N as f32;
    if contrast < min_contrast {
        return None;
    }
    // Smooth round the ring so that noise near an edge does not add crossings.
    let mut d = [0f32; RING_N];
    for k in 0..RING_N {
        let prev = s[(k + RING_N - 1) % RING_N];
        let next = s[(k + 1) % RING_N];
        d[k] = prev + 2.0 * s[k] + next - 4.0 * mean;
    }
    crossings_to_lines(&d, step, contrast)
}

fn crossings_to_lines(d: &[f32; RING_N], step: f32, contrast: f32) -> Option<Lines> {
    // Angles of dark→light (up) and light→dark (down) crossings.
    let (mut up, mut down) = ([0f32; 2], [0f32; 2]);
    let (mut n_up, mut n_down) = (0, 0);
    for k in 0..RING_N {
        let (p, q) = (d[k], d[(k + 1) % RING_N]);
        let rising = p < 0.0 && q >= 0.0;
        let falling = p >= 0.0 && q < 0.0;
        if !(rising || falling) {
            continue;
        }
        let angle = (k as f32 + p / (p - q)) * step;
        let (list, n) = if rising { (&mut up, &mut n_up) } else { (&mut down, &mut n_down) };
        if *n == 2 {
            return None;
        }
        list[*n] = angle;
        *n += 1;
    }
    if n_up != 2 || n_down != 2 {
        return None;
    }
    let a = line_from_pair(up[0], up[1])?;
    let b = line_from_pair(down[0], down[1])?;
    // The two lines must not nearly coincide (a tilted board still keeps them apart).
    if (a[0] * b[1] - a[1] * b[0]).abs() < 0.25 {
        return None;
    }
    Some(Lines { a, b, contrast })
}

/// The line through two crossing angles that should be half a turn apart.
fn line_from_pair(t0: f32, t1: f32) -> Option<[f32; 2]> {
    use core::f32::consts::PI;
    let mut gap = t1 - t0 - PI;
    while gap > PI {
        gap -= 2.0 * PI;
    }
    while gap < -PI {
        gap += 2.0 * PI;
    }
    if gap.abs() > 0.6 {
        return None;
    }
    let angle = t0 + 0.5 * gap;
    Some([angle.cos(), angle.sin()])
}

/// A refined corner: position and the covariance of its estimate (px²).
#[derive(Clone, Copy, Debug)]
pub struct Refined {
    pub x: f32,
    pub y: f32,
    pub cxx: f32,
    pub cxy: f32,
    pub cyy: f32,
}

/// Gradient sub-pixel refinement round (x0, y0): the corner is the point every gradient
/// in the window is orthogonal to (Förstner / cornerSubPix), Gaussian-weighted with a
/// window of half-size `radius`. Returns `None` when the system is singular or the
/// estimate leaves the image.
pub fn refine(v: &View, x0: f32, y0: f32, radius: usize, max_iter: usize) -> Option<Refined> {
    let radius = radius.clamp(1, MAX_REFINE_RADIUS);
    let n = 2 * radius + 3;
    let half = (radius + 1) as f32;
    // Gaussian window weights, once per call.
    let sigma = 0.5 * radius as f32 + 0.5;
    let inv_2s2 = 1.0 / (2.0 * sigma * sigma);
    let mut weight = [0f32; PATCH * PATCH];
    for r in 1..n - 1 {
        let dy = r as f32 - half;
        for c in 1..n - 1 {
            let dx = c as f32 - half;
            weight[r * PATCH + c] = (-(dx * dx + dy * dy) * inv_2s2).exp();
        }
    }
    let mut patch = [0f32; PATCH * PATCH];
    let (mut x, mut y) = (x0, y0);
    let mut last = None;
    for _ in 0..max_iter.max(1) {
        if !v.inside(x, y, radius as f32 + 2.0) {
            return None;
        }
        sample_patch(v, x, y, n, half, &mut patch);
        let (step, inv) = solve_step(&patch, &weight, n, half)?;
        x += step.0;
        y += step.1;
        last = Some((step, inv));
        if step.0 * step.0 + step.1 * step.1 < 1e-4 {
            break;
        }
    }
    let (step, inv) = last?;
    // Covariance from the last window (the residuals round the last estimate).
    let meat = residual_meat(&patch, &weight, n, half, step);
    let (cxx, cxy, cyy) = sandwich(inv, meat);
    Some(Refined { x, y, cxx, cxy, cyy })
}

/// Integer-offset samples of a window centred on the sub-pixel estimate (x, y).
fn sample_patch(v: &View, x: f32, y: f32, n: usize, half: f32, patch: &mut [f32]) {
    let (fx, fy) = ((x - half).floor(), (y - half).floor());
    let (ax, ay) = (x - half - fx, y - half - fy);
    let (bx, by) = (fx as isize, fy as isize);
    for r in 0..n {
        for c in 0..n {
            patch[r * PATCH + c] = sample_at(v, bx + c as isize, by + r as isize, ax, ay);
        }
    }
}

type Inverse = (f32, f32, f32);

/// One Gauss–Newton step: the offset from the window centre to the point all gradients
/// are orthogonal to, and the inverse normal matrix.
fn solve_step(patch: &[f32], weight: &[f32], n: usize, half: f32) -> Option<((f32, f32), Inverse)> {
    let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0f32, 0f32, 0f32, 0f32, 0f32);
    for_each_gradient(patch, weight, n, half, |dx, dy, w, gx, gy| {
        let (gxx, gxy, gyy) = (w * gx * gx, w * gx * gy, w * gy * gy);
        a11 += gxx;
        a12 += gxy;
        a22 += gyy;
        b1 += gxx * dx + gxy * dy;
        b2 += gxy * dx + gyy * dy;
    });
    let det = a11 * a22 - a12 * a12;
    // Also refuses NaN.
    if det.partial_cmp(&(1e-6 * (a11 + a22) * (a11 + a22))) != Some(core::cmp::Ordering::Greater) {
        return None;
    }
    let (i11, i12, i22) = (a22 / det, -a12 / det, a11 / det);
    Some(((i11 * b1 + i12 * b2, i12 * b1 + i22 * b2), (i11, i12, i22)))
}

/// Σ w² r² g gᵀ with r = gᵀ(p − q): the spread of the orthogonality residuals.
fn residual_meat(
    patch: &[f32],
    weight: &[f32],
    n: usize,
    half: f32,
    q: (f32, f32),
) -> (f32, f32, f32) {
    let (mut m11, mut m12, mut m22) = (0f32, 0f32, 0f32);
    for_each_gradient(patch, weight, n, half, |dx, dy, w, gx, gy| {
        let res = gx * (dx - q.0) + gy * (dy - q.1);
        let k = w * w * res * res;
        m11 += k * gx * gx;
        m12 += k * gx * gy;
        m22 += k * gy * gy;
    });
    (m11, m12, m22)
}

/// Calls `f(dx, dy, weight, gx, gy)` for every interior pixel of the `n × n` patch:
/// its offset from the window centre, its weight and its central-difference gradient.
#[inline(always)]
fn for_each_gradient(
    patch: &[f32],
    weight: &[f32],
    n: usize,
    half: f32,
    mut f: impl FnMut(f32, f32, f32, f32, f32),
) {
    for r in 1..n - 1 {
        let dy = r as f32 - half;
        for c in 1..n - 1 {
            let dx = c as f32 - half;
            let gx = 0.5 * (patch[r * PATCH + c + 1] - patch[r * PATCH + c - 1]);
            let gy = 0.5 * (patch[(r + 1) * PATCH + c] - patch[(r - 1) * PATCH + c]);
            f(dx, dy, weight[r * PATCH + c], gx, gy);
        }
    }
}

fn sandwich(i: (f32, f32, f32), m: (f32, f32, f32)) -> (f32, f32, f32) {
    // C = A⁻¹ M A⁻¹ with symmetric 2×2 matrices.
    let t11 = i.0 * m.0 + i.1 * m.1;
    let t12 = i.0 * m.1 + i.1 * m.2;
    let t21 = i.1 * m.0 + i.2 * m.1;
    let t22 = i.1 * m.1 + i.2 * m.2;
    (t11 * i.0 + t12 * i.1, t11 * i.1 + t12 * i.2, t21 * i.1 + t22 * i.2)
}

#[inline]
fn sample_at(v: &View, x: isize, y: isize, ax: f32, ay: f32) -> f32 {
    let clamp_x = |x: isize| x.clamp(0, v.w as isize - 1) as usize;
    let clamp_y = |y: isize| y.clamp(0, v.h as isize - 1) as usize;
    let (x0, x1, y0, y1) = (clamp_x(x), clamp_x(x + 1), clamp_y(y), clamp_y(y + 1));
    let p00 = v.data[y0 * v.w + x0] as f32;
    let p01 = v.data[y0 * v.w + x1] as f32;
    let p10 = v.data[y1 * v.w + x0] as f32;
    let p11 = v.data[y1 * v.w + x1] as f32;
    let top = p00 + (p01 - p00) * ax;
    let bottom = p10 + (p11 - p10) * ax;
    top + (bottom - top) * ay
}
