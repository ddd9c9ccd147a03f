//! Covariance of the shared parameters (intrinsics, extrinsic) at a solution, for the
//! quality gate: the inverse of the undamped reduced normal matrix `S` (the Schur
//! complement, i.e. the shared block of the full inverse with the board poses
//! marginalised) scaled by the residual variance `σ̂² = 2·cost / (m − n)`.
//!
//! For a two-stage run (intrinsics from the corners, then the extrinsic with them held),
//! [`with_fixed_intrinsics`] adds what the first stage's intrinsic uncertainty does to the
//! extrinsic: holding the intrinsics does not make them exact.
//!
//! Rotation and translation uncertainties are "worst axis" figures: the square root of
//! the largest eigenvalue of the 3×3 covariance of the left-perturbation rotation vector
//! (reported in degrees) and of the translation (metres).

use nalgebra::SMatrix;

use super::linalg::{max_eigenvalue3, Cholesky};
use super::lm::NormalEquations;
use super::problem::{JointParams, JointProblem, ParamMask};
use super::{Projector, SolveError, EXT_ROTATION, EXT_TRANSLATION, INTRINSICS, SHARED};
use crate::geometry::Mat3;

/// Covariance of `[fx fy cx cy d0..d4 | δω δt]`; fixed parameters have zero rows/columns.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SharedCovariance {
    pub matrix: SMatrix<f64, SHARED, SHARED>,
    /// `σ̂² = 2·cost / (m − n)` (1 when the σ given to the problem are right).
    pub residual_variance: f64,
    /// Degrees of freedom `m − n`.
    pub dof: usize,
    /// Parameters that were held fixed.
    pub mask: ParamMask,
}

/// One-σ uncertainties as the result file reports them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Uncertainty {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Per distortion coefficient, the model's order.
    pub distortion: [f64; 5],
    /// Worst-axis rotation σ of the extrinsic (degrees).
    pub rotation_deg: f64,
    /// Worst-axis translation σ of the extrinsic (metres).
    pub translation_m: f64,
}

impl SharedCovariance {
    /// Standard deviation of shared parameter `i` (0 if fixed).
    pub fn sigma(&self, i: usize) -> f64 {
        libm::sqrt(self.matrix[(i, i)].max(0.0))
    }

    /// The 3×3 covariance block starting at shared index `at`.
    pub fn block3(&self, at: usize) -> Mat3 {
        self.matrix.fixed_view::<3, 3>(at, at).into_owned()
    }

    /// The result file's uncertainty figures.
    pub fn uncertainty(&self) -> Uncertainty {
        let mut distortion = [0.0; 5];
        for (i, d) in distortion.iter_mut().enumerate() {
            *d = self.sigma(4 + i);
        }
        let worst = |m: Mat3| libm::sqrt(max_eigenvalue3(&m).max(0.0));
        Uncertainty {
            fx: self.sigma(0),
            fy: self.sigma(1),
            cx: self.sigma(2),
            cy: self.sigma(3),
            distortion,
            rotation_deg: worst(self.block3(EXT_ROTATION)).to_degrees(),
            translation_m: worst(self.block3(EXT_TRANSLATION)),
        }
    }
}

/// Covariance of the shared parameters at `params` (normally the solution), holding the
/// parameters in `mask` (plus the problem's structural mask) fixed.
pub fn covariance<C: Projector, const B: usize>(
    problem: &JointProblem<'_, B>,
    params: &JointParams<C, B>,
    mask: ParamMask,
) -> Result<SharedCovariance, SolveError> {
    let ne = NormalEquations::build(problem, params)?;
    let mask = ne.effective_mask(mask.union(problem.structural_mask(&params.camera)));
    let n = mask.free_count() + 6 * ne.boards;
    if ne.residuals <= n {
        return Err(SolveError::TooFewPoints { needed: n + 1, got: ne.residuals });
    }
    let dof = ne.residuals - n;
    let residual_variance = 2.0 * ne.cost / dof as f64;
    let (s, _) = ne.reduce(0.0, mask)?;
    let mut matrix = Cholesky::new(&s)?.inverse() * residual_variance;
    for i in (0..SHARED).filter(|&i| mask.is_fixed(i)) {
        matrix.row_mut(i).fill(0.0);
        matrix.column_mut(i).fill(0.0);
    }
    Ok(SharedCovariance { matrix, residual_variance, dof, mask })
}

/// The covariance of a second stage that solved the extrinsic (and board poses) with the
/// intrinsics held at a first stage's estimate whose covariance is `intrinsics`: the
/// extrinsic block is its conditional covariance plus the first stage's spread carried
/// through the second stage's sensitivity `G = −S_ee⁻¹ S_eK` (from the undamped reduced
/// normal matrix of `problem` at `params`, intrinsics free), `Σ_ee = σ̂² S_ee⁻¹ + G Σ_KK Gᵀ`;
/// the intrinsic block is the first stage's. Cross terms are left at zero.
pub fn with_fixed_intrinsics<C: Projector, const B: usize>(
    problem: &JointProblem<'_, B>,
    params: &JointParams<C, B>,
    intrinsics: &SharedCovariance,
) -> Result<SharedCovariance, SolveError> {
    const E: usize = SHARED - INTRINSICS;
    let conditional = covariance(problem, params, ParamMask::free().fix_intrinsics())?;
    let ne = NormalEquations::build(problem, params)?;
    let mask = ne.effective_mask(problem.structural_mask(&params.camera));
    let (s, _) = ne.reduce(0.0, mask)?;
    let s_ee: SMatrix<f64, E, E> = s.fixed_view::<E, E>(INTRINSICS, INTRINSICS).into_owned();
    let s_ek: SMatrix<f64, E, INTRINSICS> =
        s.fixed_view::<E, INTRINSICS>(INTRINSICS, 0).into_owned();
    let sensitivity = -(Cholesky::new(&s_ee)?.solve_matrix(&s_ek));
    let sigma_kk: SMatrix<f64, INTRINSICS, INTRINSICS> =
        intrinsics.matrix.fixed_view::<INTRINSICS, INTRINSICS>(0, 0).into_owned();
    let carried = sensitivity * sigma_kk * sensitivity.transpose();
    let mut matrix = SMatrix::<f64, SHARED, SHARED>::zeros();
    matrix.fixed_view_mut::<INTRINSICS, INTRINSICS>(0, 0).copy_from(&sigma_kk);
    let ee = conditional.matrix.fixed_view::<E, E>(INTRINSICS, INTRINSICS) + carried;
    matrix.fixed_view_mut::<E, E>(INTRINSICS, INTRINSICS).copy_from(&ee);
    Ok(SharedCovariance { matrix, ..conditional })
}
