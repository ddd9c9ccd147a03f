//! The projection map's contours over the frame: the map's grid values interpolated
//! bilinearly at every pixel, and a pixel drawn where its level band differs from its
//! right or lower neighbour's.

use image::{Rgb, RgbImage};

use crate::geometry::Vec2;
use crate::result::ProjectionMap;

/// Draws `map`'s contours at `levels` (px, ascending) over `image` (the frame, of the map's
/// camera) in `colour`; each level drawn, with a pixel on it for its label.
pub fn draw(
    image: &mut RgbImage,
    map: &ProjectionMap,
    levels: &[f64],
    colour: Rgb<u8>,
) -> Vec<(f64, Vec2)> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    // Two rows of bands at a time: a whole frame of them would be a frame-sized buffer
    // (tens of MB) at the report, the daemon's peak.
    let row = |y: usize| -> Vec<Option<usize>> {
        (0..w)
            .map(|x| {
                let sigma = interpolate(map, x as f64, y as f64)?;
                Some(levels.iter().take_while(|&&l| l <= sigma).count())
            })
            .collect()
    };
    let mut labels: Vec<(f64, Vec2)> = Vec::new();
    let mut next = row(0);
    for y in 0..h {
        let here_row =
            std::mem::replace(&mut next, if y + 1 < h { row(y + 1) } else { Vec::new() });
        for x in 0..w {
            let here = here_row[x];
            let right = here_row.get(x + 1).copied();
            let below = next.get(x).copied();
            let Some(edge) =
                [right, below].into_iter().flatten().find_map(|other| match (here, other) {
                    (Some(a), Some(b)) if a != b => Some(a.max(b)),
                    _ => None,
                })
            else {
                continue;
            };
            image.put_pixel(x as u32, y as u32, colour);
            let level = levels[edge - 1];
            if !labels.iter().any(|(l, _)| *l == level) {
                labels.push((level, Vec2::new(x as f64, y as f64)));
            }
        }
    }
    labels
}

/// The map's value at pixel (u, v), bilinear between its grid pixels; `None` where a
/// neighbouring grid value is missing or the pixel is outside the grid.
pub fn interpolate(map: &ProjectionMap, u: f64, v: f64) -> Option<f64> {
    let (c, s) = cell(&map.columns, u)?;
    let (r, t) = cell(&map.rows, v)?;
    let at = |r: usize, c: usize| map.sigma_px.get(r)?.get(c).copied().flatten();
    let top = at(r, c)? * (1.0 - s) + at(r, c + 1)? * s;
    let bottom = at(r + 1, c)? * (1.0 - s) + at(r + 1, c + 1)? * s;
    Some(top * (1.0 - t) + bottom * t)
}

/// The grid interval holding `x` (its first index) and where in it `x` lies (0–1).
fn cell(grid: &[f64], x: f64) -> Option<(usize, f64)> {
    if grid.len() < 2 || x < grid[0] || x > grid[grid.len() - 1] {
        return None;
    }
    let i = grid.windows(2).position(|p| x <= p[1])?;
    Some((i, (x - grid[i]) / (grid[i + 1] - grid[i])))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map() -> ProjectionMap {
        // Rising from 0 px on the left to 4 px on the right, the same on every row.
        ProjectionMap {
            range_m: 10.0,
            lidar: true,
            columns: vec![0.0, 50.0, 99.0],
            rows: vec![0.0, 49.0],
            sigma_px: vec![vec![Some(0.0), Some(2.0), Some(4.0)]; 2],
        }
    }

    #[test]
    fn interpolation_meets_the_grid_and_is_linear_between() {
        let m = map();
        assert_eq!(interpolate(&m, 50.0, 0.0), Some(2.0));
        assert_eq!(interpolate(&m, 25.0, 30.0), Some(1.0));
        assert_eq!(interpolate(&m, 100.0, 0.0), None);
        let gap = ProjectionMap { sigma_px: vec![vec![Some(0.0), None, Some(4.0)]; 2], ..m };
        assert_eq!(interpolate(&gap, 25.0, 0.0), None);
    }

    #[test]
    fn each_level_is_drawn_once_where_the_map_crosses_it() {
        let mut image = RgbImage::new(100, 50);
        let pink = Rgb([255, 110, 230]);
        let labels = draw(&mut image, &map(), &[1.0, 3.0, 10.0], pink);
        // 1 px at u = 25, 3 px at u ≈ 74.5; 10 px is never reached.
        assert_eq!(labels.iter().map(|(l, _)| *l).collect::<Vec<_>>(), vec![1.0, 3.0]);
        for (level, at) in &labels {
            let expected = if *level == 1.0 { 25.0 } else { 74.5 };
            assert!((at.x - expected).abs() <= 1.0, "{level} px at {}", at.x);
        }
        for y in 0..50 {
            let row: Vec<u32> = (0..100).filter(|&x| *image.get_pixel(x, y) == pink).collect();
            assert_eq!(row.len(), 2, "row {y}: {row:?}");
        }
    }
}
