//! A tiny checkerboard renderer for the detector tests: boards posed in 3D, a pinhole
//! camera with one-parameter barrel distortion, 4×4 supersampling, Gaussian blur, light
//! gradient, sensor noise and a textured background. Truth corners come from the same
//! model, solved exactly, in the board model's order.

// Each test binary that includes this file uses a different part of it.
#![allow(dead_code)]

/// One board: pose (board → camera) and pattern.
#[derive(Clone, Copy, Debug)]
pub struct BoardPose {
    /// Rotation (row-major 3×3) and translation (m).
    pub r: [[f64; 3]; 3],
    pub t: [f64; 3],
    pub cols: usize,
    pub rows: usize,
    pub square: f64,
}

/// A scene: camera, boards, degradations.
#[derive(Clone, Debug)]
pub struct Scene {
    pub w: usize,
    pub h: usize,
    pub f: f64,
    /// Distortion: undistorted = distorted · (1 + k r²), r in units of f (k > 0: barrel).
    pub k: f64,
    pub boards: Vec<BoardPose>,
    pub blur: f64,
    pub noise: f64,
    pub seed: u64,
    /// Background texture strength (0 flat grey).
    pub texture: f64,
    /// A rectangle (x0, y0, x1, y1) painted mid grey over everything (an occluder).
    pub occluder: Option<[f64; 4]>,
}

/// Rotation from tilts about x then y then z (radians).
pub fn rotation(ax: f64, ay: f64, az: f64) -> [[f64; 3]; 3] {
    let (sx, cx) = ax.sin_cos();
    let (sy, cy) = ay.sin_cos();
    let (sz, cz) = az.sin_cos();
    let rx = [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]];
    let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
    let rz = [[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]];
    mul(&rz, &mul(&ry, &rx))
}

fn mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut m = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

impl BoardPose {
    /// Board point (x, y) in metres relative to the checker centre → camera frame.
    fn board_to_camera(&self, x: f64, y: f64) -> [f64; 3] {
        let r = &self.r;
        [
            r[0][0] * x + r[0][1] * y + self.t[0],
            r[1][0] * x + r[1][1] * y + self.t[1],
            r[2][0] * x + r[2][1] * y + self.t[2],
        ]
    }

    /// Where the camera ray (x, y, 1) meets the board, in board metres.
    fn intersect(&self, ray: [f64; 3]) -> Option<(f64, f64)> {
        let r = &self.r;
        let n = [r[0][2], r[1][2], r[2][2]];
        let denom = n[0] * ray[0] + n[1] * ray[1] + n[2] * ray[2];
        if denom.abs() < 1e-9 {
            return None;
        }
        let s = (n[0] * self.t[0] + n[1] * self.t[1] + n[2] * self.t[2]) / denom;
        if s <= 0.0 {
            return None;
        }
        let d = [ray[0] * s - self.t[0], ray[1] * s - self.t[1], ray[2] * s - self.t[2]];
        // Board coordinates: columns of R are the board axes.
        let x = r[0][0] * d[0] + r[1][0] * d[1] + r[2][0] * d[2];
        let y = r[0][1] * d[0] + r[1][1] * d[1] + r[2][1] * d[2];
        Some((x, y))
    }

    /// Albedo at board point (x, y): checker inside, white margin of one square, else None.
    fn albedo(&self, x: f64, y: f64) -> Option<f64> {
        let u = x / self.square + (self.cols as f64 + 1.0) / 2.0;
        let v = y / self.square + (self.rows as f64 + 1.0) / 2.0;
        let (uc, vc) = (self.cols as f64 + 1.0, self.rows as f64 + 1.0);
        if u < -0.8 || v < -0.8 || u > uc + 0.8 || v > vc + 0.8 {
            return None;
        }
        if u < 0.0 || v < 0.0 || u >= uc || v >= vc {
            return Some(0.85);
        }
        let black = (u.floor() as i64 + v.floor() as i64) % 2 == 0;
        Some(if black { 0.08 } else { 0.85 })
    }

    /// Inner corner (col, row) in board metres.
    fn corner(&self, col: usize, row: usize) -> (f64, f64) {
        let x = (col as f64 - (self.cols as f64 - 1.0) / 2.0) * self.square;
        let y = (row as f64 - (self.rows as f64 - 1.0) / 2.0) * self.square;
        (x, y)
    }
}

impl Scene {
    fn undistort(&self, px: f64, py: f64) -> [f64; 3] {
        let (cx, cy) = (self.w as f64 / 2.0 - 0.5, self.h as f64 / 2.0 - 0.5);
        let (xd, yd) = ((px - cx) / self.f, (py - cy) / self.f);
        let s = 1.0 + self.k * (xd * xd + yd * yd);
        [xd * s, yd * s, 1.0]
    }

    fn distort(&self, xu: f64, yu: f64) -> (f64, f64) {
        // Solve r_d (1 + k r_d²) = r_u by Newton.
        let ru = (xu * xu + yu * yu).sqrt();
        let mut rd = ru;
        for _ in 0..50 {
            let g = rd * (1.0 + self.k * rd * rd) - ru;
            rd -= g / (1.0 + 3.0 * self.k * rd * rd);
        }
        let s = if ru > 0.0 { rd / ru } else { 1.0 };
        let (cx, cy) = (self.w as f64 / 2.0 - 0.5, self.h as f64 / 2.0 - 0.5);
        (cx + self.f * xu * s, cy + self.f * yu * s)
    }

    /// True inner corners of every board, row-major.
    pub fn truth(&self) -> Vec<Vec<[f64; 2]>> {
        self.boards
            .iter()
            .map(|b| {
                let mut v = Vec::new();
                for row in 0..b.rows {
                    for col in 0..b.cols {
                        let (x, y) = b.corner(col, row);
                        let p = b.board_to_camera(x, y);
                        let (u, w) = self.distort(p[0] / p[2], p[1] / p[2]);
                        v.push([u, w]);
                    }
                }
                v
            })
            .collect()
    }

    /// Renders the grey frame.
    pub fn render(&self) -> Vec<u8> {
        const SS: usize = 4;
        let (w, h) = (self.w, self.h);
        let mut img = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let mut sum = 0.0;
                for j in 0..SS {
                    for i in 0..SS {
                        let px = x as f64 - 0.5 + (i as f64 + 0.5) / SS as f64;
                        let py = y as f64 - 0.5 + (j as f64 + 0.5) / SS as f64;
                        sum += self.albedo_at(px, py);
                    }
                }
                let light = 0.75 + 0.5 * (x as f64 / w as f64) * (0.6 + 0.4 * y as f64 / h as f64);
                img[y * w + x] = (255.0 * light * sum / (SS * SS) as f64) as f32;
            }
        }
        if self.blur > 0.0 {
            blur(&mut img, w, h, self.blur);
        }
        let mut rng = self.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        img.iter()
            .map(|&v| (v as f64 + self.noise * gauss(&mut rng)).round().clamp(0.0, 255.0) as u8)
            .collect()
    }

    fn albedo_at(&self, px: f64, py: f64) -> f64 {
        if let Some([x0, y0, x1, y1]) = self.occluder {
            if px >= x0 && px <= x1 && py >= y0 && py <= y1 {
                return 0.45;
            }
        }
        let ray = self.undistort(px, py);
        let mut best: Option<(f64, f64)> = None;
        for b in &self.boards {
            if let Some((x, y)) = b.intersect(ray) {
                if let Some(a) = b.albedo(x, y) {
                    let p = b.board_to_camera(x, y);
                    if !best.is_some_and(|(z, _)| p[2] >= z) {
                        best = Some((p[2], a));
                    }
                }
            }
        }
        match best {
            Some((_, a)) => a,
            None => self.background(px, py),
        }
    }

    /// Value noise at several scales plus sharp-edged blobs (edges, T and L junctions).
    fn background(&self, x: f64, y: f64) -> f64 {
        let t = self.texture;
        let smooth = 0.5 * value_noise(self.seed, x / 90.0, y / 90.0)
            + 0.3 * value_noise(self.seed + 1, x / 23.0, y / 23.0)
            + 0.2 * value_noise(self.seed + 2, x / 7.0, y / 7.0);
        let blobs = if value_noise(self.seed + 3, x / 40.0, y / 31.0) > 0.6 { 0.35 } else { 0.0 };
        let stripes = if (x * 0.05 + 0.3 * (y * 0.01).sin()).sin() > 0.8 { -0.3 } else { 0.0 };
        (0.3 + t * (0.4 * smooth + blobs + stripes)).clamp(0.02, 0.98)
    }
}

fn value_noise(seed: u64, u: f64, v: f64) -> f64 {
    let (iu, iv) = (u.floor(), v.floor());
    let (fu, fv) = (u - iu, v - iv);
    let (su, sv) = (fu * fu * (3.0 - 2.0 * fu), fv * fv * (3.0 - 2.0 * fv));
    let lattice = |du: i64, dv: i64| {
        let mut h = seed
            ^ ((iu as i64 + du) as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93)
            ^ ((iv as i64 + dv) as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15).rotate_left(29);
        h ^= h >> 31;
        h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 29;
        (h >> 11) as f64 / (1u64 << 53) as f64
    };
    let top = lattice(0, 0) * (1.0 - su) + lattice(1, 0) * su;
    let bottom = lattice(0, 1) * (1.0 - su) + lattice(1, 1) * su;
    top * (1.0 - sv) + bottom * sv
}

fn gauss(state: &mut u64) -> f64 {
    let mut next = || {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        ((*state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let (u1, u2) = (next(), next());
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

fn blur(img: &mut [f32], w: usize, h: usize, sigma: f64) {
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f32> =
        (-r..=r).map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32).collect();
    let norm: f32 = k.iter().sum();
    let mut tmp = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (i, kv) in k.iter().enumerate() {
                let xx = (x as isize + i as isize - r).clamp(0, w as isize - 1) as usize;
                s += kv * img[y * w + xx];
            }
            tmp[y * w + x] = s / norm;
        }
    }
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (i, kv) in k.iter().enumerate() {
                let yy = (y as isize + i as isize - r).clamp(0, h as isize - 1) as usize;
                s += kv * tmp[yy * w + x];
            }
            img[y * w + x] = s / norm;
        }
    }
}

/// Six boards in a 3 × 2 layout filling a `w`×`h` frame, tilted up to `tilt_deg`, about
/// `z` metres away.
pub fn six_boards(w: usize, h: usize, f: f64, k: f64, tilt_deg: f64, seed: u64, z: f64) -> Scene {
    grid_boards(w, h, f, k, tilt_deg, seed, z, 3, 2)
}

/// `nx` × `ny` boards in a grid filling a `w`×`h` frame (see [`six_boards`]).
#[allow(clippy::too_many_arguments)]
pub fn grid_boards(
    w: usize,
    h: usize,
    f: f64,
    k: f64,
    tilt_deg: f64,
    seed: u64,
    z: f64,
    nx: usize,
    ny: usize,
) -> Scene {
    let (cols, rows, square) = (7, 5, 0.08);
    let mut boards = Vec::new();
    let tilt = tilt_deg.to_radians();
    let signs = [(1.0, 0.4), (-0.5, 1.0), (0.8, -0.8), (-1.0, -0.3), (0.3, 1.0), (-0.7, 0.7)];
    for n in 0..nx * ny {
        let (sx, sy) = signs[n % signs.len()];
        let (gx, gy) = ((n % nx) as f64, (n / nx) as f64);
        let (u, v) = ((gx + 0.5) / nx as f64 * w as f64, (gy + 0.5) / ny as f64 * h as f64);
        let z = z * (1.0 + 0.12 * ((seed + n as u64) % 3) as f64);
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        let (xn, yn) = ((u - cx) / f, (v - cy) / f);
        // Undistorted position of the intended distorted pixel.
        let s = 1.0 + k * (xn * xn + yn * yn);
        let r = rotation(tilt * sy, tilt * sx, 0.15 * (n as f64 - 2.5));
        boards.push(BoardPose { r, t: [xn * s * z, yn * s * z, z], cols, rows, square });
    }
    Scene { w, h, f, k, boards, blur: 0.8, noise: 2.0, seed, texture: 1.0, occluder: None }
}
