//! The survey's gauge: the room frame its boards and planes are given in, and their σ.
//!
//! The bundle ([`super::bundle`]) fixes the frame on board 0 (it has no unknowns), which
//! makes every other board's σ that of its pose *relative to board 0*: board 0's own error
//! (a few tenths of a degree from one board's corners over a few visits) is shared by every
//! other board and plane, and a calibration that takes each board's σ as an independent
//! prior then holds the room to board 0's error. The survey is therefore re-expressed in
//! **the boards' mean frame** ([`mean_pose`]: rotation the mean of every board's rotation,
//! origin the mean of their centres) — one rigid motion, which leaves every relative pose
//! and every measurement unchanged — and its covariance carried over to that frame to first
//! order: `Σ' = L Σ Lᵀ` with `L` the derivative of the mean-frame poses with respect to the
//! bundle's board-0-gauge parameters (central differences; the map is smooth and cheap).
//! Every board, board 0 included, then has the σ of its pose relative to the room as a
//! whole, and no board carries the others' error.

use nalgebra::{DMatrix, DVector, SVector};

use crate::geometry::se3::{so3_log, so3_plus};
use crate::geometry::{Mat3, Se3, Vec3};
use crate::solve::linalg::max_eigenvalue3;

use super::bundle::{tangent_basis, RoomPlane, Sigma, SurveyState, VISIT};

/// How the survey's room frame is defined (`survey.frame` before the parking frame).
pub const MEAN_FRAME: &str = "the boards' mean: rotation the mean of every board's rotation, \
                              origin the mean of their centres";

/// The mean of board poses: the rotation at which the boards' rotation offsets
/// `log(R_b Rᵀ)` sum to zero (the Karcher mean, by fixed-point iteration from the first),
/// and the mean of the translations.
pub fn mean_pose(boards: &[Se3]) -> Se3 {
    let Some(first) = boards.first() else { return Se3::identity() };
    let n = boards.len() as f64;
    let mut rotation = first.rotation;
    for _ in 0..MEAN_ITERATIONS {
        let step = boards
            .iter()
            .map(|b| so3_log(&(b.rotation * rotation.transpose())))
            .fold(Vec3::zeros(), |a, w| a + w)
            / n;
        rotation = so3_plus(&rotation, &step);
        if step.norm() < 1e-15 {
            break;
        }
    }
    let translation = boards.iter().fold(Vec3::zeros(), |a, b| a + b.translation) / n;
    Se3 { rotation, translation }
}

/// `state` re-expressed in its boards' mean frame ([`mean_pose`]): boards `M⁻¹ B`, planes
/// carried along, every visit's room→camera `T · M`.
pub fn in_mean_frame(state: &SurveyState) -> SurveyState {
    let mean = mean_pose(&state.boards);
    let to_new = mean.inverse();
    SurveyState {
        visits: state
            .visits
            .iter()
            .map(|v| super::bundle::VisitState {
                room_to_camera: v.room_to_camera.compose(&mean),
                ..v.clone()
            })
            .collect(),
        boards: state.boards.iter().map(|b| to_new.compose(b)).collect(),
        planes: state.planes.iter().map(|p| plane_in(&mean, p)).collect(),
    }
}

/// The covariance of every board and plane in the boards' mean frame from `cov`, the
/// covariance of the bundle's global parameters at `state` (board-0 gauge: boards 1.. then
/// planes): rows `[δω δt]` per board (all of them), then `[turn (2, in its tangent basis);
/// offset]` per plane, a plane's offset at the frame's origin.
pub fn mean_frame_covariance(state: &SurveyState, cov: &DMatrix<f64>) -> DMatrix<f64> {
    let l = mean_frame_jacobian(state);
    &l * cov * l.transpose()
}

/// σ of every board and plane from their [`mean_frame_covariance`] `full`.
pub fn mean_frame_sigmas(boards: usize, full: &DMatrix<f64>) -> (Vec<Sigma>, Vec<Sigma>) {
    let block3 = |at: usize| Mat3::from_fn(|i, j| full[(at + i, at + j)]);
    let board_sigmas = (0..boards)
        .map(|b| Sigma {
            m: max_eigenvalue3(&block3(6 * b + 3)).max(0.0).sqrt(),
            deg: max_eigenvalue3(&block3(6 * b)).max(0.0).sqrt().to_degrees(),
        })
        .collect();
    let planes = (full.nrows() - 6 * boards) / 3;
    let plane_sigmas = (0..planes)
        .map(|p| {
            let block = plane_block(boards, full, p);
            let turn = nalgebra::Matrix2::from_fn(|i, j| block[(i, j)]);
            let worst = nalgebra::SymmetricEigen::new(turn).eigenvalues.max();
            Sigma { m: block[(2, 2)].max(0.0).sqrt(), deg: worst.max(0.0).sqrt().to_degrees() }
        })
        .collect();
    (board_sigmas, plane_sigmas)
}

/// Plane `p`'s `[turn; offset]` block of a [`mean_frame_covariance`] over `boards` boards.
pub fn plane_block(boards: usize, full: &DMatrix<f64>, p: usize) -> Mat3 {
    let at = 6 * boards + 3 * p;
    Mat3::from_fn(|i, j| full[(at + i, at + j)])
}

/// The room file's `survey.covariance` (lower triangle by rows) from the
/// [`mean_frame_covariance`] `full` of `state` (in the mean frame), the file's frame being
/// `p_mean = g · p_file`: each board's `[δω δt]` turned into the file's frame, each plane's
/// turn written as the rotation vector `B δφ` in the file's frame and its offset taken at
/// the file's origin (`δd + (B δφ)·(o × n)`, as [`plane_offset_sigma_at`]).
pub fn file_covariance(state: &SurveyState, full: &DMatrix<f64>, g: &Se3) -> Vec<Vec<f64>> {
    let (nb, np) = (state.boards.len(), state.planes.len());
    let to_file = g.rotation.transpose();
    let mut t = DMatrix::<f64>::zeros(6 * nb + 4 * np, 6 * nb + 3 * np);
    for b in 0..nb {
        t.fixed_view_mut::<3, 3>(6 * b, 6 * b).copy_from(&to_file);
        t.fixed_view_mut::<3, 3>(6 * b + 3, 6 * b + 3).copy_from(&to_file);
    }
    for (p, plane) in state.planes.iter().enumerate() {
        let (row, col) = (6 * nb + 4 * p, 6 * nb + 3 * p);
        let basis = tangent_basis(&plane.normal);
        t.fixed_view_mut::<3, 2>(row, col).copy_from(&(to_file * basis));
        let lever = basis.transpose() * g.translation.cross(&plane.normal);
        t[(row + 3, col)] = lever.x;
        t[(row + 3, col + 1)] = lever.y;
        t[(row + 3, col + 2)] = 1.0;
    }
    let file = &t * full * t.transpose();
    let entry = |i: usize, j: usize| significant(0.5 * (file[(i, j)] + file[(j, i)]));
    (0..file.nrows()).map(|i| (0..=i).map(|j| entry(i, j)).collect()).collect()
}

/// `x` to 9 significant digits: the file stays a third of its size at full precision, and
/// the rounding (10⁻⁹ of each entry) is far below what any σ is known to.
fn significant(x: f64) -> f64 {
    format!("{x:.8e}").parse().unwrap_or(x)
}

/// σ of a plane's offset taken at `origin` instead of its frame's origin (same frame): the
/// offset there is `d − n·o`, so a turn of the normal moves it by the lever `o`. A floor
/// known to 0.015° through boards 6 m ahead is known at the vehicle to ≈ 1.6 mm, however well
/// its offset is known beneath the boards. `block` as [`mean_frame_sigmas`] gives it.
pub fn plane_offset_sigma_at(plane: &RoomPlane, block: &Mat3, origin: &Vec3) -> f64 {
    // δn = −n × (B δφ), so δ(d − n·o) = δd + (B δφ)·(o × n).
    let lever = tangent_basis(&plane.normal).transpose() * origin.cross(&plane.normal);
    let j = Vec3::new(lever.x, lever.y, 1.0);
    (j.transpose() * block * j)[(0, 0)].max(0.0).sqrt()
}

/// Rounds of the Karcher mean's fixed-point iteration (it converges in a handful).
const MEAN_ITERATIONS: usize = 50;
/// Step of the central differences (rad and m): far above rounding, far below curvature.
const STEP: f64 = 1e-6;

/// `∂(mean-frame boards and planes)/∂(board-0-gauge parameters)`: rows `[δω δt]` per board
/// (all of them) then `[δφ δd]` per plane, in the mean frame at `state`; columns the bundle's
/// global parameters.
fn mean_frame_jacobian(state: &SurveyState) -> DMatrix<f64> {
    let (nb, np) = (state.boards.len(), state.planes.len());
    let columns = 6 * nb.saturating_sub(1) + 3 * np;
    let at = in_mean_frame(state);
    let still = vec![SVector::<f64, VISIT>::zeros(); state.visits.len()];
    let mut l = DMatrix::zeros(6 * nb + 3 * np, columns);
    for c in 0..columns {
        let mut step = DVector::zeros(columns);
        step[c] = STEP;
        let plus = in_mean_frame(&state.updated(&still, &step));
        step[c] = -STEP;
        let minus = in_mean_frame(&state.updated(&still, &step));
        let d = |a: &SurveyState, b: &SurveyState| difference(&at, a) - difference(&at, b);
        l.set_column(c, &(d(&plus, &minus) / (2.0 * STEP)));
    }
    l
}

/// The perturbation that takes `base` to `moved` (same frame, same boards and planes), in
/// the bundle's coordinates: left rotation and additive translation per board, the turn of
/// each plane's normal in its tangent basis and its offset.
fn difference(base: &SurveyState, moved: &SurveyState) -> DVector<f64> {
    let (nb, np) = (base.boards.len(), base.planes.len());
    let mut out = DVector::zeros(6 * nb + 3 * np);
    for (b, (x, y)) in base.boards.iter().zip(&moved.boards).enumerate() {
        let w = so3_log(&(y.rotation * x.rotation.transpose()));
        let t = y.translation - x.translation;
        out.fixed_rows_mut::<3>(6 * b).copy_from(&w);
        out.fixed_rows_mut::<3>(6 * b + 3).copy_from(&t);
    }
    for (p, (x, y)) in base.planes.iter().zip(&moved.planes).enumerate() {
        let turn = tangent_basis(&x.normal).transpose() * x.normal.cross(&y.normal);
        out[6 * nb + 3 * p] = turn.x;
        out[6 * nb + 3 * p + 1] = turn.y;
        out[6 * nb + 3 * p + 2] = y.offset - x.offset;
    }
    out
}

/// A plane `n · p_old = d` in the frame `new` is given in (`p_old = new · p_new`).
fn plane_in(new: &Se3, plane: &RoomPlane) -> RoomPlane {
    RoomPlane {
        normal: new.rotation.transpose() * plane.normal,
        offset: plane.offset - plane.normal.dot(&new.translation),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The offset at `origin` of the plane turned by `turn` and shifted by `shift`.
    fn offset_at(
        plane: &RoomPlane,
        turn: &nalgebra::Vector2<f64>,
        shift: f64,
        origin: &Vec3,
    ) -> f64 {
        let n = plane.normal;
        let normal = (n - n.cross(&(tangent_basis(&n) * turn))).normalize();
        (plane.offset + shift) - normal.dot(origin)
    }

    #[test]
    fn a_planes_offset_sigma_moves_with_the_origin_as_its_turn_does() {
        let plane = RoomPlane { normal: Vec3::new(0.1, -0.05, -1.0).normalize(), offset: 2.0 };
        let origin = Vec3::new(-6.0, 1.5, 0.3);
        // A correlated covariance of [turn; offset].
        let a = Mat3::new(2e-4, 0.0, 0.0, 5e-5, 1e-4, 0.0, 3e-4, -1e-4, 5e-4);
        let block = a * a.transpose();
        // The same σ through the numeric derivative of the offset at the origin.
        let h = 1e-7;
        let mut j = Vec3::zeros();
        for k in 0..3 {
            let mut step = Vec3::zeros();
            step[k] = h;
            let at = |s: &Vec3| offset_at(&plane, &nalgebra::Vector2::new(s.x, s.y), s.z, &origin);
            j[k] = (at(&step) - at(&(-step))) / (2.0 * h);
        }
        let numeric = (j.transpose() * block * j)[(0, 0)].sqrt();
        let analytic = plane_offset_sigma_at(&plane, &block, &origin);
        assert!((analytic / numeric - 1.0).abs() < 1e-6, "{analytic} vs {numeric}");
        // At the frame's own origin it is the offset's σ.
        let own = plane_offset_sigma_at(&plane, &block, &Vec3::zeros());
        assert!((own - block[(2, 2)].sqrt()).abs() < 1e-15);
        assert!(analytic > 1.2 * own, "the lever should count: {analytic} vs {own}");
    }
}
