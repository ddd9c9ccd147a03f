//! Where the boards stand: spread over the image so that together they cover it,
//! corners included, each tilted 15–35° in its own direction, 3–6 m from the camera.
//!
//! Two arrangements ([`Layout`]): a grid over the image, or a row held at the image row
//! where the LiDAR's densest 8° of beams cross, with two more boards in the image's top
//! corners — a room built for a LiDAR with a narrow dense band (a Pandar64's fine beams
//! span 8°), where a board only gets its holes placed when several scan lines cross them.

use crate::geometry::{se3::so3_exp, Camera, Mat3, Se3, Vec2, Vec3};
use crate::target::BoardSpec;

use super::rng::Rng;
use super::SimError;

/// Distance range from the camera (m).
pub const DISTANCE: (f64, f64) = (3.0, 6.0);
/// Tilt range away from facing the camera (degrees).
pub const TILT_DEG: (f64, f64) = (15.0, 35.0);
/// Pixels kept free between a board and the image border or another board.
const MARGIN_PX: f64 = 8.0;
/// Attempts per board before the layout gives up.
const ATTEMPTS: usize = 400;

/// How the boards are arranged over the image.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Layout {
    /// A grid of cells over the whole image, outer cells first.
    #[default]
    Grid,
    /// Two boards in the image's top corners, the others in a row at the LiDAR's dense
    /// band.
    Band,
}

/// Board → camera poses for `count` boards, or an error when they do not fit.
/// `band_row_px` is the image row of the LiDAR's dense band ([`Layout::Band`] only);
/// `fits` says whether a board pose (board → camera) stays inside the room.
pub fn lay_out(
    spec: &BoardSpec,
    camera: &Camera,
    count: usize,
    band_row_px: Option<f64>,
    rng: &mut Rng,
    fits: &dyn Fn(&Se3) -> bool,
) -> Result<Vec<Se3>, SimError> {
    let (cols, rows, cells) = match band_row_px {
        None => {
            let (cols, rows) = grid_for(count, camera.width as f64 / camera.height as f64);
            (cols, rows, pick_cells(cols, rows, count))
        }
        Some(_) => band_cells(count),
    };
    let placed = place(spec, camera, (cols, rows), &cells, band_row_px, Vec::new(), rng, fits)?;
    Ok(placed.into_iter().map(|(pose, _)| pose).collect())
}

/// `count` more boards beside `existing` (board → camera), in the outer columns of
/// `camera`'s view: a 4 × 3 grid's left and right middle cells first, then its corners,
/// then the top and bottom rows' inner cells; none overlapping another in that view. With
/// `existing` laid out for a narrower lens, a room for a rig whose cameras' fields differ:
/// the narrow camera sees the inner boards whole, the wide one every board.
pub fn lay_out_ring(
    spec: &BoardSpec,
    camera: &Camera,
    count: usize,
    existing: &[Se3],
    rng: &mut Rng,
    fits: &dyn Fn(&Se3) -> bool,
) -> Result<Vec<Se3>, SimError> {
    const RING: [(usize, usize); 10] =
        [(0, 1), (3, 1), (0, 0), (3, 0), (0, 2), (3, 2), (1, 0), (2, 0), (1, 2), (2, 2)];
    if count > RING.len() {
        return Err(SimError::Layout { count, board: existing.len() + RING.len() });
    }
    // Inner boards a little beyond the wider view (none, laid out for a narrower lens)
    // block nothing there.
    let inner: Vec<(Se3, [f64; 4])> =
        existing.iter().filter_map(|p| Some((*p, image_box(spec, camera, p)?))).collect();
    let kept = inner.len();
    let placed = place(spec, camera, (4, 3), &RING[..count], None, inner, rng, fits)?;
    Ok(placed[kept..].iter().map(|(pose, _)| *pose).collect())
}

/// Places one board in each of `cells` of a `grid` over `camera`'s image, after `placed`
/// (poses and image boxes), clear of every other; `placed` with the new boards after it.
#[allow(clippy::too_many_arguments)]
fn place(
    spec: &BoardSpec,
    camera: &Camera,
    grid: (usize, usize),
    cells: &[(usize, usize)],
    band_row_px: Option<f64>,
    mut placed: Vec<(Se3, [f64; 4])>,
    rng: &mut Rng,
    fits: &dyn Fn(&Se3) -> bool,
) -> Result<Vec<(Se3, [f64; 4])>, SimError> {
    for &(cell_col, cell_row) in cells {
        let i = placed.len();
        // The band row's boards aim at the band itself, not at their cell's centre.
        let row_at = band_row_px.filter(|_| cell_row == 1);
        let pose = (0..ATTEMPTS)
            .find_map(|attempt| {
                let shrink = attempt as f64 / ATTEMPTS as f64;
                let candidate =
                    propose(camera, grid, (cell_col, cell_row), row_at, i, shrink, rng)?;
                let bbox = image_box(spec, camera, &candidate)?;
                let clear = placed.iter().all(|(_, other)| !boxes_overlap(&bbox, other));
                (clear && fits(&candidate)).then_some((candidate, bbox))
            })
            .ok_or(SimError::Layout { count: cells.len(), board: i })?;
        placed.push(pose);
    }
    Ok(placed)
}

/// Columns and rows of the layout grid for `count` boards on an image of this aspect.
fn grid_for(count: usize, aspect: f64) -> (usize, usize) {
    let cols = ((count as f64 * aspect).sqrt().round() as usize).clamp(1, count);
    let rows = count.div_ceil(cols);
    (cols, rows)
}

/// Cells of the band layout (columns × 3 rows, the middle row moved to the band): two
/// boards in the top corners, all others in the band row. The band of a LiDAR mounted
/// below the camera crosses the image below its centre, so no row fits under it.
fn band_cells(count: usize) -> (usize, usize, Vec<(usize, usize)>) {
    let in_band = count.saturating_sub(2).max(count.min(1));
    let cols = in_band.max(2);
    let mut cells: Vec<(usize, usize)> = (0..in_band).map(|c| (c, 1)).collect();
    cells.extend([(0, 0), (cols - 1, 0)].iter().take(count - in_band));
    (cols, 3, cells)
}

/// The cells to fill: all of them when the grid is full, otherwise the outer ones first
/// so that the image corners are covered.
fn pick_cells(cols: usize, rows: usize, count: usize) -> Vec<(usize, usize)> {
    let mut cells: Vec<(usize, usize)> =
        (0..rows).flat_map(|r| (0..cols).map(move |c| (c, r))).collect();
    let centre = ((cols as f64 - 1.0) / 2.0, (rows as f64 - 1.0) / 2.0);
    cells.sort_by(|a, b| {
        let da = (a.0 as f64 - centre.0).abs() + (a.1 as f64 - centre.1).abs();
        let db = (b.0 as f64 - centre.0).abs() + (b.1 as f64 - centre.1).abs();
        db.total_cmp(&da)
    });
    cells.truncate(count);
    cells
}

/// A random pose aiming at a point of the cell, pushed towards the image border.
/// `shrink` (0→1 over the attempts) draws the aim towards the cell centre and the board
/// farther away, so that crowded layouts still fit.
fn propose(
    camera: &Camera,
    (cols, rows): (usize, usize),
    (col, row): (usize, usize),
    row_at_px: Option<f64>,
    index: usize,
    shrink: f64,
    rng: &mut Rng,
) -> Option<Se3> {
    let (w, h) = (camera.width as f64, camera.height as f64);
    let cell = (w / cols as f64, h / rows as f64);
    // Offset from the cell centre towards the image border, so the corners get covered.
    let outward =
        |k: usize, n: usize| if n == 1 { 0.0 } else { (k as f64 / (n - 1) as f64) * 2.0 - 1.0 };
    let push = 0.22 * (1.0 - shrink);
    let aim = Vec2::new(
        cell.0 * (col as f64 + 0.5 + outward(col, cols) * push + rng.range(-0.05, 0.05)),
        match row_at_px {
            Some(y) => y + cell.1 * rng.range(-0.03, 0.03),
            None => {
                cell.1 * (row as f64 + 0.5 + outward(row, rows) * push + rng.range(-0.05, 0.05))
            }
        },
    );
    let ray = camera.unproject(&aim)?;
    let near = DISTANCE.0 + (DISTANCE.1 - DISTANCE.0) * 0.6 * shrink;
    let distance = rng.range(near, DISTANCE.1);
    let centre = ray * distance;
    let facing = facing_camera(&centre);
    // Tilt about an in-plane axis whose direction turns from board to board.
    let tilt = rng.range(TILT_DEG.0, TILT_DEG.1).to_radians();
    let axis_angle = index as f64 * 2.39996 + rng.range(-0.4, 0.4);
    let axis = Vec3::new(axis_angle.cos(), axis_angle.sin(), 0.0);
    let roll = Vec3::new(0.0, 0.0, rng.range(-8.0, 8.0).to_radians());
    let rotation = facing * so3_exp(&(axis * tilt)) * so3_exp(&roll);
    Some(Se3 { rotation, translation: centre })
}

/// The rotation of a board at `centre` whose z axis (into the board) points away from
/// the camera along the line of sight, x as close to the camera's x as possible.
fn facing_camera(centre: &Vec3) -> Mat3 {
    let z = centre.normalize();
    let x = (Vec3::x() - z * z.x).normalize();
    let y = z.cross(&x);
    Mat3::from_columns(&[x, y, z])
}

/// The board's bounding box in the image [min x, min y, max x, max y], or `None` when
/// any part of it leaves the image (with margin) or cannot be projected.
fn image_box(spec: &BoardSpec, camera: &Camera, pose: &Se3) -> Option<[f64; 4]> {
    let (hw, hh) = (spec.width / 2.0, spec.height / 2.0);
    let mut bbox = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
    let steps = 16;
    for k in 0..(4 * steps) {
        let t = (k % steps) as f64 / steps as f64;
        let p = match k / steps {
            0 => Vec3::new(-hw + 2.0 * hw * t, -hh, 0.0),
            1 => Vec3::new(hw, -hh + 2.0 * hh * t, 0.0),
            2 => Vec3::new(hw - 2.0 * hw * t, hh, 0.0),
            _ => Vec3::new(-hw, hh - 2.0 * hh * t, 0.0),
        };
        let px = camera.project(&pose.act(&p))?;
        let inside = px.x >= MARGIN_PX
            && px.y >= MARGIN_PX
            && px.x <= camera.width as f64 - MARGIN_PX
            && px.y <= camera.height as f64 - MARGIN_PX;
        if !inside {
            return None;
        }
        bbox = [bbox[0].min(px.x), bbox[1].min(px.y), bbox[2].max(px.x), bbox[3].max(px.y)];
    }
    Some(bbox)
}

fn boxes_overlap(a: &[f64; 4], b: &[f64; 4]) -> bool {
    a[0] - MARGIN_PX < b[2]
        && b[0] - MARGIN_PX < a[2]
        && a[1] - MARGIN_PX < b[3]
        && b[1] - MARGIN_PX < a[3]
}
