//! Covariance of the shared parameters (intrinsics, extrinsic) at a solution, for the
//! quality gate: the inverse of the undamped reduced normal matrix `S` (the Schur
//! complement, i.e. the shared block of the full inverse with the board poses
//! marginalised) scaled by the residual variance `σ̂² = 2·cost / (m − n)`.
//!
//! Rotation and translation uncertainties are "worst axis" figures: the square root of
//! the largest eigenvalue of the 3×3 covariance of the left-perturbation rotation vector
//! (reported in degrees) and of the translation (metres).

use nalgebra::SMatrix;

use super::linalg::{max_eigenvalue3, Cholesky};
use super::lm::NormalEquations;
use super::problem::{JointParams, JointProblem, ParamMask};
use super::{Projector, SolveError, EXT_ROTATION, EXT_TRANSLATION, SHARED};
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
