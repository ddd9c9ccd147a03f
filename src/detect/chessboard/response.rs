//! ChESS corner response (Bennett & Lazaridis 2014) on a 16-sample ring of radius 5, and
//! non-maximum suppression over it. Integer arithmetic, one pass, no allocation.

/// Ring half-size: the response is zero within this many pixels of the border.
pub const RING_RADIUS: usize = 5;
/// Non-maximum suppression half-window.
const NMS_RADIUS: usize = 3;

/// The ring, in angular order (quarter turns are 4 samples apart).
const RING: [(isize, isize); 16] = [
    (0, -5),
    (2, -5),
    (3, -3),
    (5, -2),
    (5, 0),
    (5, 2),
    (3, 3),
    (2, 5),
    (0, 5),
    (-2, 5),
    (-3, 3),
    (-5, 2),
    (-5, 0),
    (-5, -2),
    (-3, -3),
    (-2, -5),
];

/// Fills `resp` (`w * h`) with the ChESS response of `img`: high at X-junctions of a
/// checkerboard, low or negative on edges, lines and blobs.
pub fn chess_response(img: &[u8], w: usize, h: usize, resp: &mut [i16]) {
    let r = RING_RADIUS;
    resp.fill(0);
    if w <= 2 * r || h <= 2 * r {
        return;
    }
    let n = w - 2 * r;
    for y in r..h - r {
        // One slice per ring sample, aligned so that index i is pixel (r + i, y) + offset.
        let rows: [&[u8]; 16] = RING.map(|(dx, dy)| {
            let start = ((y as isize + dy) as usize) * w + (r as isize + dx) as usize;
            &img[start..start + n]
        });
        let centre = &img[y * w + r..y * w + r + n];
        let up = &img[(y - 1) * w + r..(y - 1) * w + r + n];
        let down = &img[(y + 1) * w + r..(y + 1) * w + r + n];
        let left = &img[y * w + r - 1..y * w + r - 1 + n];
        let right = &img[y * w + r + 1..y * w + r + 1 + n];
        let out = &mut resp[y * w + r..y * w + r + n];
        for i in 0..n {
            let s: [i32; 16] = core::array::from_fn(|k| rows[k][i] as i32);
            let mut sum = 0;
            for k in 0..4 {
                sum += (s[k] + s[k + 8] - s[k + 4] - s[k + 12]).abs();
            }
            let mut diff = 0;
            for k in 0..8 {
                diff += (s[k] - s[k + 8]).abs();
            }
            let ring_sum: i32 = s.iter().sum();
            let local =
                centre[i] as i32 + up[i] as i32 + down[i] as i32 + left[i] as i32 + right[i] as i32;
            // |ring mean - local mean| · 16, in integers: |5·ring − 16·local| / 5.
            let mean = (5 * ring_sum - 16 * local).abs() / 5;
            out[i] = (sum - diff - mean).clamp(i16::MIN as i32, i16::MAX as i32) as i16;
        }
    }
}

/// Local maxima of `resp` above `threshold`, pushed as pixel (x, y, response) until
/// `peaks` is full; returns false when it overflowed (the caller raises the threshold).
pub fn local_maxima(
    resp: &[i16],
    w: usize,
    h: usize,
    threshold: i16,
    peaks: &mut Vec<(u16, u16, i16)>,
) -> bool {
    peaks.clear();
    let m = RING_RADIUS + NMS_RADIUS;
    if w <= 2 * m || h <= 2 * m {
        return true;
    }
    for y in m..h - m {
        let row = &resp[y * w..(y + 1) * w];
        for (x, &v) in row.iter().enumerate().take(w - m).skip(m) {
            if v <= threshold || !is_peak(resp, w, x, y, v) {
                continue;
            }
            if peaks.len() == peaks.capacity() {
                return false;
            }
            peaks.push((x as u16, y as u16, v));
        }
    }
    true
}

/// Strict maximum in its window; ties go to the first pixel in raster order.
fn is_peak(resp: &[i16], w: usize, x: usize, y: usize, v: i16) -> bool {
    for yy in y - NMS_RADIUS..=y + NMS_RADIUS {
        let row = &resp[yy * w + x - NMS_RADIUS..=yy * w + x + NMS_RADIUS];
        for (k, &o) in row.iter().enumerate() {
            let xx = x - NMS_RADIUS + k;
            let before = yy < y || (yy == y && xx < x);
            if o > v || (o == v && before) {
                return false;
            }
        }
    }
    true
}
