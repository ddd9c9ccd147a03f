//! Levenberg–Marquardt on the joint problem with the Schur complement over board poses.
//!
//! The normal equations `(JᵀWJ + λD) δ = −JᵀWr` are accumulated block by block from the
//! streamed residuals: per board a 6×6 `U_b`, a 15×6 cross block `W_b` and a gradient
//! `g_b`; one 15×15 `V` over the shared parameters. The board poses are eliminated,
//! `S = V − Σ W_b U_b⁻¹ W_bᵀ`, `S` is factorised (Cholesky), and each board's update is
//! back-substituted. Damping is Marquardt's: `A_ii += λ · max(A_ii, DIAG_FLOOR)`.
//! Fixed shared parameters have their rows and columns removed (unit diagonal, zero
//! update). Robust losses enter as IRLS weights `ρ'(s)`.

use nalgebra::{SMatrix, SVector};

use super::init::perturb;
use super::linalg::Cholesky;
use super::problem::{JointParams, JointProblem, ParamMask, ResidualKind};
use super::{Projector, SolveError, EXT_ROTATION, EXT_TRANSLATION, INTRINSICS, SHARED};

/// Smallest diagonal used for Marquardt scaling, so unconstrained directions still damp.
pub const DIAG_FLOOR: f64 = 1e-9;

/// Stopping rules and the parameter mask.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LmOptions {
    /// Most outer iterations (Jacobian evaluations).
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub cost_tolerance: f64,
    /// Stop when `|δ| ≤ tol · (|x| + tol)` over all parameters.
    pub step_tolerance: f64,
    /// Stop when the largest gradient entry is below this (whitened units).
    pub gradient_tolerance: f64,
    /// Starting damping λ.
    pub initial_lambda: f64,
    /// Shared parameters held fixed (added to the problem's structural mask).
    pub mask: ParamMask,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions {
            max_iterations: 100,
            // Ceres' defaults: below 1e-6 the cost change is far inside the noise, and a
            // robust loss switching blocks between its regimes can crawl for a long time.
            cost_tolerance: 1e-6,
            step_tolerance: 1e-8,
            gradient_tolerance: 1e-10,
            initial_lambda: 1e-4,
            mask: ParamMask::free(),
        }
    }
}

/// Why the solver stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    /// Relative cost decrease below `cost_tolerance`.
    CostConverged,
    /// Step below `step_tolerance`.
    StepConverged,
    /// Gradient below `gradient_tolerance`.
    GradientConverged,
    /// `max_iterations` reached.
    MaxIterations,
    /// No damping lowered the cost (at a minimum up to rounding, or stuck).
    NoProgress,
}

/// What a solve did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveReport {
    /// Outer iterations (Jacobian evaluations).
    pub iterations: usize,
    /// Robust cost `½ Σ ρ(|r/σ|²)` at the start and at the end.
    pub initial_cost: f64,
    pub final_cost: f64,
    pub termination: Termination,
    /// Scalar residuals (2 per corner and per hole).
    pub residuals: usize,
    /// Free parameters (shared + 6 per board).
    pub free_parameters: usize,
    /// Plain RMS pixel errors at the end (corners; hole term, 0 without holes).
    pub corner_rms_px: f64,
    pub hole_rms_px: f64,
    /// The damping in force at the end.
    pub final_lambda: f64,
}

/// The accumulated normal equations (undamped) at one estimate.
#[derive(Clone, Debug)]
pub struct NormalEquations<const B: usize> {
    /// Boards in use (the first `boards` entries of the arrays below).
    pub boards: usize,
    /// `JᵀWJ` per board pose (6×6).
    pub u: [SMatrix<f64, 6, 6>; B],
    /// `J_sharedᵀ W J_board` per board (15×6).
    pub w: [SMatrix<f64, SHARED, 6>; B],
    /// `J_boardᵀ W r` per board.
    pub g_board: [SVector<f64, 6>; B],
    /// `J_sharedᵀ W J_shared` (15×15).
    pub v: SMatrix<f64, SHARED, SHARED>,
    /// `J_sharedᵀ W r`.
    pub g_shared: SVector<f64, SHARED>,
    /// Robust cost `½ Σ ρ` at this estimate.
    pub cost: f64,
    /// Scalar residuals.
    pub residuals: usize,
}

/// A factor per residual kind (corners, holes, board planes) for
/// [`NormalEquations::build_weighted`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KindWeights {
    pub corner: f64,
    pub hole: f64,
    pub plane: f64,
}

impl KindWeights {
    /// Every kind as the problem weights it.
    pub const ALL: Self = KindWeights { corner: 1.0, hole: 1.0, plane: 1.0 };
    /// Every kind left out (zero for each).
    pub const NONE: Self = KindWeights { corner: 0.0, hole: 0.0, plane: 0.0 };
    /// One kind alone (the kind of `kind`; its index is ignored).
    pub fn only(kind: ResidualKind) -> Self {
        let mut w = KindWeights { corner: 0.0, hole: 0.0, plane: 0.0 };
        *w.of_mut(kind) = 1.0;
        w
    }

    /// The factor of `kind`.
    pub fn of(&self, kind: ResidualKind) -> f64 {
        match kind {
            ResidualKind::Corner(_) => self.corner,
            ResidualKind::Hole(_) => self.hole,
            ResidualKind::Plane(_) => self.plane,
        }
    }

    /// The factor of `kind`, to set.
    pub fn of_mut(&mut self, kind: ResidualKind) -> &mut f64 {
        match kind {
            ResidualKind::Corner(_) => &mut self.corner,
            ResidualKind::Hole(_) => &mut self.hole,
            ResidualKind::Plane(_) => &mut self.plane,
        }
    }
}

/// One LM step: shared update and one update per board.
#[derive(Clone, Debug)]
pub struct Step<const B: usize> {
    pub shared: SVector<f64, SHARED>,
    pub boards: [SVector<f64, 6>; B],
}

impl<const B: usize> NormalEquations<B> {
    /// Accumulates the normal equations of `problem` at `params`.
    pub fn build<C: Projector>(
        problem: &JointProblem<'_, B>,
        params: &JointParams<C, B>,
    ) -> Result<Self, SolveError> {
        Self::build_weighted(problem, params, KindWeights::ALL)
    }

    /// The normal equations with every block of a residual kind weighted by that kind's
    /// factor in `weights` (its cost too); kinds weighted 0 are left out, rows and cost.
    pub fn build_weighted<C: Projector>(
        problem: &JointProblem<'_, B>,
        params: &JointParams<C, B>,
        weights: KindWeights,
    ) -> Result<Self, SolveError> {
        let mut ne = NormalEquations {
            boards: problem.boards().len(),
            u: [SMatrix::zeros(); B],
            w: [SMatrix::zeros(); B],
            g_board: [SVector::zeros(); B],
            v: SMatrix::zeros(),
            g_shared: SVector::zeros(),
            cost: 0.0,
            residuals: 0,
        };
        problem.for_each_residual(params, |res| {
            let factor = weights.of(res.kind);
            if factor == 0.0 {
                return;
            }
            let (rho, weight) = problem.loss_for(res.kind).eval(res.r.norm_squared());
            let weight = weight * factor;
            ne.cost += 0.5 * rho * factor;
            ne.residuals += res.rows;
            let b = res.board;
            ne.u[b].gemm_tr(weight, &res.j_board, &res.j_board, 1.0);
            ne.g_board[b].gemv_tr(weight, &res.j_board, &res.r, 1.0);
            if matches!(res.kind, ResidualKind::Corner(_)) {
                // Corners do not see the extrinsic: touch only the intrinsic rows.
                let jk = res.j_shared.fixed_view::<2, INTRINSICS>(0, 0);
                ne.w[b].fixed_view_mut::<INTRINSICS, 6>(0, 0).gemm_tr(
                    weight,
                    &jk,
                    &res.j_board,
                    1.0,
                );
                ne.v.fixed_view_mut::<INTRINSICS, INTRINSICS>(0, 0).gemm_tr(weight, &jk, &jk, 1.0);
                ne.g_shared.fixed_rows_mut::<INTRINSICS>(0).gemv_tr(weight, &jk, &res.r, 1.0);
            } else {
                ne.w[b].gemm_tr(weight, &res.j_shared, &res.j_board, 1.0);
                ne.v.gemm_tr(weight, &res.j_shared, &res.j_shared, 1.0);
                ne.g_shared.gemv_tr(weight, &res.j_shared, &res.r, 1.0);
            }
        })?;
        if ne.cost.is_finite() {
            Ok(ne)
        } else {
            Err(SolveError::NonFinite)
        }
    }

    /// `mask` plus every shared parameter no residual touches (zero diagonal).
    pub fn effective_mask(&self, mask: ParamMask) -> ParamMask {
        (0..SHARED).fold(mask, |m, i| if self.v[(i, i)] > 0.0 { m } else { m.fix(i) })
    }

    /// Largest absolute gradient entry over free parameters.
    pub fn max_gradient(&self, mask: ParamMask) -> f64 {
        let shared = (0..SHARED)
            .filter(|&i| !mask.is_fixed(i))
            .map(|i| self.g_shared[i].abs())
            .fold(0.0, f64::max);
        self.g_board[..self.boards].iter().map(|g| g.amax()).fold(shared, f64::max)
    }

    /// The reduced camera system `S δs = rhs` after eliminating the board poses, with
    /// damping `λ`. Fixed parameters get a unit row/column and a zero right-hand side.
    pub fn reduce(
        &self,
        lambda: f64,
        mask: ParamMask,
    ) -> Result<(SMatrix<f64, SHARED, SHARED>, SVector<f64, SHARED>), SolveError> {
        let mut s = self.v;
        damp(&mut s, lambda);
        let mut rhs = -self.g_shared;
        for b in 0..self.boards {
            let u = damped(&self.u[b], lambda);
            let ch = Cholesky::new(&u)
                .map_err(|e| SolveError::NotPositiveDefinite { pivot: e.pivot })?;
            // Y = W U⁻¹ (15×6) via U⁻¹ Wᵀ, U symmetric.
            let y_t = ch.solve_matrix(&self.w[b].transpose());
            s.gemm(-1.0, &self.w[b], &y_t, 1.0);
            rhs.gemv_tr(1.0, &y_t, &self.g_board[b], 1.0);
        }
        for i in 0..SHARED {
            if mask.is_fixed(i) {
                s.row_mut(i).fill(0.0);
                s.column_mut(i).fill(0.0);
                s[(i, i)] = 1.0;
                rhs[i] = 0.0;
            }
        }
        Ok((s, rhs))
    }

    /// Solves the damped system by the Schur complement.
    pub fn step(&self, lambda: f64, mask: ParamMask) -> Result<Step<B>, SolveError> {
        let (s, rhs) = self.reduce(lambda, mask)?;
        let shared = Cholesky::new(&s)?.solve(&rhs);
        let mut boards = [SVector::<f64, 6>::zeros(); B];
        for (b, out) in boards.iter_mut().enumerate().take(self.boards) {
            let u = damped(&self.u[b], lambda);
            let ch = Cholesky::new(&u)?;
            let mut rhs_b = -self.g_board[b];
            rhs_b.gemv_tr(-1.0, &self.w[b], &shared, 1.0);
            *out = ch.solve(&rhs_b);
        }
        Ok(Step { shared, boards })
    }
}

/// Runs LM from `params` (updated in place to the best estimate found).
pub fn solve<C: Projector + Clone, const B: usize>(
    problem: &JointProblem<'_, B>,
    params: &mut JointParams<C, B>,
    options: &LmOptions,
) -> Result<SolveReport, SolveError> {
    problem.check_params(params)?;
    let mut ne = NormalEquations::build(problem, params)?;
    let mask = ne.effective_mask(options.mask.union(problem.structural_mask(&params.camera)));
    let free = mask.free_count() + 6 * problem.boards().len();
    let initial_cost = ne.cost;
    let mut lambda = options.initial_lambda;
    let mut iterations = 0;
    let mut termination = Termination::MaxIterations;
    while iterations < options.max_iterations {
        iterations += 1;
        if ne.max_gradient(mask) <= options.gradient_tolerance {
            termination = Termination::GradientConverged;
            break;
        }
        match try_steps(problem, params, &ne, mask, &mut lambda, options)? {
            Outcome::Accepted(trial, converged) => {
                *params = trial;
                ne = NormalEquations::build(problem, params)?;
                if let Some(t) = converged {
                    termination = t;
                    break;
                }
            }
            Outcome::Converged(t) => {
                termination = t;
                break;
            }
        }
    }
    let (corner_rms_px, hole_rms_px) = problem.rms_px(params)?;
    Ok(SolveReport {
        iterations,
        initial_cost,
        final_cost: ne.cost,
        termination,
        residuals: ne.residuals,
        free_parameters: free,
        corner_rms_px,
        hole_rms_px,
        final_lambda: lambda,
    })
}

impl<'a, const B: usize> JointProblem<'a, B> {
    /// [`solve`] as a method.
    pub fn solve<C: Projector + Clone>(
        &self,
        params: &mut JointParams<C, B>,
        options: &LmOptions,
    ) -> Result<SolveReport, SolveError> {
        solve(self, params, options)
    }
}

/// `params ⊕ step`: additive intrinsics, left-perturbed extrinsic and board poses.
pub fn apply_step<C: Projector + Clone, const B: usize>(
    params: &JointParams<C, B>,
    step: &Step<B>,
) -> JointParams<C, B> {
    let mut out = params.clone();
    let mut k = params.camera.params();
    for (i, v) in k.iter_mut().enumerate() {
        *v += step.shared[i];
    }
    out.camera.set_params(&k);
    let ext = step.shared.fixed_rows::<6>(EXT_ROTATION).into_owned();
    out.lidar_to_camera = perturb(&params.lidar_to_camera, &ext);
    for (pose, d) in out.board_poses.iter_mut().zip(step.boards.iter()) {
        *pose = perturb(pose, d);
    }
    out
}

/// Result of the inner damping loop.
enum Outcome<C, const B: usize> {
    /// A step lowered the cost; `Some` if it also met a stopping rule.
    Accepted(JointParams<C, B>, Option<Termination>),
    /// Nothing to do: the step is negligible or no damping helps.
    Converged(Termination),
}

/// Raises λ until a step lowers the cost (then lowers λ for the next iteration).
fn try_steps<C: Projector + Clone, const B: usize>(
    problem: &JointProblem<'_, B>,
    params: &JointParams<C, B>,
    ne: &NormalEquations<B>,
    mask: ParamMask,
    lambda: &mut f64,
    options: &LmOptions,
) -> Result<Outcome<C, B>, SolveError> {
    const MAX_LAMBDA: f64 = 1e16;
    while *lambda <= MAX_LAMBDA {
        let step = match ne.step(*lambda, mask) {
            Ok(s) => s,
            Err(SolveError::NotPositiveDefinite { .. }) => {
                *lambda *= 10.0;
                continue;
            }
            Err(e) => return Err(e),
        };
        if step_is_small(params, &step, ne.boards, options.step_tolerance) {
            return Ok(Outcome::Converged(Termination::StepConverged));
        }
        let trial = apply_step(params, &step);
        match problem.cost(&trial) {
            Ok(c) if c < ne.cost => {
                *lambda = (*lambda * 0.1).max(1e-15);
                let converged = (ne.cost - c <= options.cost_tolerance * ne.cost)
                    .then_some(Termination::CostConverged);
                return Ok(Outcome::Accepted(trial, converged));
            }
            // Higher cost, a point leaving the image, or overflow: damp more.
            Ok(_) | Err(SolveError::NotProjectable { .. }) | Err(SolveError::NonFinite) => {
                *lambda *= 10.0;
            }
            Err(e) => return Err(e),
        }
    }
    Ok(Outcome::Converged(Termination::NoProgress))
}

/// `|δ| ≤ tol · (|x| + tol)` over the shared parameters and the board poses.
fn step_is_small<C: Projector, const B: usize>(
    params: &JointParams<C, B>,
    step: &Step<B>,
    boards: usize,
    tol: f64,
) -> bool {
    // A rotation counts with the size of a half turn, so rotations and metres mix.
    const PI2: f64 = core::f64::consts::PI * core::f64::consts::PI;
    let k = params.camera.params();
    let ext = &params.lidar_to_camera;
    let mut x2: f64 = k.iter().map(|v| v * v).sum();
    x2 += ext.translation.norm_squared() + PI2;
    let mut d2 = step.shared.norm_squared();
    for (pose, d) in params.board_poses.iter().zip(step.boards.iter()).take(boards) {
        x2 += pose.translation.norm_squared() + PI2;
        d2 += d.norm_squared();
    }
    libm::sqrt(d2) <= tol * (libm::sqrt(x2) + tol)
}

/// `A + λ · diag(max(A_ii, DIAG_FLOOR))`.
fn damped<const N: usize>(a: &SMatrix<f64, N, N>, lambda: f64) -> SMatrix<f64, N, N> {
    let mut d = *a;
    damp(&mut d, lambda);
    d
}

fn damp<const N: usize>(a: &mut SMatrix<f64, N, N>, lambda: f64) {
    for i in 0..N {
        a[(i, i)] += lambda * a[(i, i)].max(DIAG_FLOOR);
    }
}

// `apply_step` reads the extrinsic as the 6 entries after the intrinsics.
const _: () = assert!(EXT_TRANSLATION == EXT_ROTATION + 3 && EXT_ROTATION == INTRINSICS);
