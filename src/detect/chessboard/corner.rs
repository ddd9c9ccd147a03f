//! Corner-level image operations: bilinear sampling, the ring test that reads a corner's
//! two edge lines and polarity, and gradient (cornerSubPix-style) sub-pixel refinement
//! with a sandwich estimate of the position's covariance. All on the stack.

/// Largest refinement window half-size (pixels).
pub const MAX_REFINE_RADIUS: usize = 15;

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
/// in the window is orthogonal to (Förstner / cornerSubPix), weighted by a window of
/// half-size `radius`. Returns `None` when the system is singular or the estimate leaves
/// the image.
///
/// The gradients are taken at whole pixels and only the weights follow the sub-pixel
/// estimate, through a window that falls smoothly to zero at its edge: resampling the
/// window at the estimate (bilinear, as cornerSubPix does) blurs it by an amount that
/// depends on the estimate's fractional part, and a window cut off where its weights are
/// still large changes with it too. Either pulls the corner towards pixel positions
/// ("pixel locking": ±0.03 px on the simulator's boards, most of the corner error).
pub fn refine(v: &View, x0: f32, y0: f32, radius: usize, max_iter: usize) -> Option<Refined> {
    let window = Window::new(radius);
    let (mut x, mut y) = (x0, y0);
    let mut inverse = None;
    for _ in 0..max_iter.max(1) {
        if !v.inside(x, y, window.reach + 2.0) {
            return None;
        }
        let (step, inv) = solve_step(v, &window, x, y)?;
        x += step.0;
        y += step.1;
        inverse = Some(inv);
        if step.0 * step.0 + step.1 * step.1 < 1e-6 {
            break;
        }
    }
    if !v.inside(x, y, window.reach + 2.0) {
        return None;
    }
    // Covariance round the final estimate.
    let meat = residual_meat(v, &window, x, y);
    let (cxx, cxy, cyy) = sandwich(inverse?, meat);
    Some(Refined { x, y, cxx, cxy, cyy })
}

/// The refinement window: weight `1 − d²/reach²` at distance `d` from the estimate, zero
/// beyond `reach` (= half-size + 1). Its spread (reach²/5 per axis) is that of the
/// Gaussian of σ = reach / 2 cut at `reach` that the window was before it became smooth.
struct Window {
    reach: f32,
    inv_reach2: f32,
}

impl Window {
    fn new(radius: usize) -> Self {
        let reach = (radius.clamp(1, MAX_REFINE_RADIUS) + 1) as f32;
        Window { reach, inv_reach2: 1.0 / (reach * reach) }
    }
}

type Inverse = (f32, f32, f32);

/// One Gauss–Newton step: the offset from (x, y) to the point all gradients are
/// orthogonal to, and the inverse normal matrix.
fn solve_step(v: &View, window: &Window, x: f32, y: f32) -> Option<((f32, f32), Inverse)> {
    let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0f32, 0f32, 0f32, 0f32, 0f32);
    for_each_gradient(v, window, x, y, |dx, dy, w, gx, gy| {
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

/// Σ w² r² g gᵀ with r = gᵀ(p − q), q = (x, y): the spread of the orthogonality residuals.
fn residual_meat(v: &View, window: &Window, x: f32, y: f32) -> (f32, f32, f32) {
    let (mut m11, mut m12, mut m22) = (0f32, 0f32, 0f32);
    for_each_gradient(v, window, x, y, |dx, dy, w, gx, gy| {
        let res = gx * dx + gy * dy;
        let k = w * w * res * res;
        m11 += k * gx * gx;
        m12 += k * gx * gy;
        m22 += k * gy * gy;
    });
    (m11, m12, m22)
}

/// Calls `f(dx, dy, weight, gx, gy)` for every whole pixel within the window's reach of
/// (x, y): its offset from (x, y), its weight and its Sobel gradient. The
/// caller keeps (x, y) at least `reach + 2` pixels inside the image.
#[inline(always)]
fn for_each_gradient(
    v: &View,
    window: &Window,
    x: f32,
    y: f32,
    mut f: impl FnMut(f32, f32, f32, f32, f32),
) {
    let at = |c: usize, r: usize| f32::from(v.data[r * v.w + c]);
    let (x_lo, x_hi) = ((x - window.reach).ceil() as usize, (x + window.reach).floor() as usize);
    let (y_lo, y_hi) = ((y - window.reach).ceil() as usize, (y + window.reach).floor() as usize);
    for r in y_lo..=y_hi {
        let dy = r as f32 - y;
        for c in x_lo..=x_hi {
            let dx = c as f32 - x;
            let t = 1.0 - (dx * dx + dy * dy) * window.inv_reach2;
            if t <= 0.0 {
                continue;
            }
            // Sobel: the central difference smoothed across it ([1 2 1] / 4), which
            // halves the noise of the gradients without moving an edge.
            let across_x = |r: usize| at(c + 1, r) - at(c - 1, r);
            let across_y = |c: usize| at(c, r + 1) - at(c, r - 1);
            let gx = 0.125 * (across_x(r - 1) + 2.0 * across_x(r) + across_x(r + 1));
            let gy = 0.125 * (across_y(c - 1) + 2.0 * across_y(c) + across_y(c + 1));
            f(dx, dy, t, gx, gy);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A grey image of an ideal saddle at (x0, y0): two straight edges (at `angle` and
    /// `angle + 90° + shear`) under a Gaussian lens blur of `blur` px, each pixel the mean
    /// of 8 × 8 sub-samples — an optical blur before the pixel, as a real camera has it.
    fn saddle(x0: f64, y0: f64, angle: f64, shear: f64, blur: f64) -> (Vec<u8>, usize) {
        const N: usize = 41;
        const SS: usize = 8;
        let edge = |d: f64| libm::erf(d / (core::f64::consts::SQRT_2 * blur));
        let mut img = vec![0u8; N * N];
        for (i, px) in img.iter_mut().enumerate() {
            let (c, r) = ((i % N) as f64, (i / N) as f64);
            let mut sum = 0.0;
            for k in 0..SS * SS {
                let x = c - 0.5 + ((k % SS) as f64 + 0.5) / SS as f64 - x0;
                let y = r - 0.5 + ((k / SS) as f64 + 0.5) / SS as f64 - y0;
                let d1 = angle.cos() * x + angle.sin() * y;
                let d2 = -(angle + shear).sin() * x + (angle + shear).cos() * y;
                sum += 0.5 + 0.5 * edge(d1) * edge(d2);
            }
            *px = (30.0 + 190.0 * sum / (SS * SS) as f64).round() as u8;
        }
        (img, N)
    }

    #[test]
    fn refinement_has_no_pull_towards_whole_pixels() {
        // Resampling the window bilinearly at the estimate pulled these corners by up to
        // 0.033 px towards pixel positions; whole-pixel gradients with a smooth window
        // leave 0.006 px, mostly the 8-bit rounding of the test image.
        let mut worst = 0f64;
        for (angle, shear) in [(0.0, 0.0), (0.35, 0.0), (0.2, 0.4), (0.9, -0.3)] {
            for step in 0..10 {
                let f = step as f64 / 10.0;
                let (x0, y0) = (20.0 + f, 20.0 + 0.37 * f);
                let (img, n) = saddle(x0, y0, angle, shear, 0.8);
                let view = View { data: &img, w: n, h: n };
                let r = refine(&view, x0 as f32 + 0.3, y0 as f32 - 0.2, 8, 20).expect("refines");
                worst = worst.max((r.x as f64 - x0).hypot(r.y as f64 - y0));
            }
        }
        assert!(worst < 0.01, "worst corner error {worst:.4} px");
    }
}
