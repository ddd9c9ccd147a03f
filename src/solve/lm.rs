//! The free-board problem's solve: Levenberg–Marquardt ([`minimize`]) on the joint
//! problem with the Schur complement over board poses ([`SchurSystem`], 15 shared
//! parameters).
//!
//! The normal equations `JᵀWJ`, `−JᵀWr` are accumulated block by block from the streamed
//! residuals: per board a 6×6 `U_b`, a 15×6 cross block `W_b` and a gradient `g_b`; one
//! 15×15 `V` over the shared parameters. Fixed shared parameters have their rows and
//! columns removed (unit diagonal, zero update). Robust losses enter as IRLS weights
//! `ρ'(s)`.

use core::marker::PhantomData;

use super::minimize::{minimize, Problem, Settings};
use super::problem::{JointParams, JointProblem, ParamMask, ResidualKind};
use super::schur::{self, SchurSystem};
use super::{Projector, SolveError, EXT_ROTATION, EXT_TRANSLATION, INTRINSICS, SHARED};

pub use super::minimize::{Termination, DIAG_FLOOR};
pub use super::problem::KindWeights;

/// The free-board solve's stopping numbers ([`LmOptions::settings`]) and parameter mask.
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

/// The accumulated normal equations (undamped) at one estimate: the Schur system over
/// the 15 shared parameters and one block per board pose.
pub type NormalEquations<const B: usize> = SchurSystem<SHARED, B>;

/// One LM step: shared update and one update per board.
pub type Step<const B: usize> = schur::Step<SHARED, B>;

impl<const B: usize> SchurSystem<SHARED, B> {
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
        let mut ne = SchurSystem::<SHARED, B>::new(problem.boards().len(), 0);
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
            ne.g_block[b].gemv_tr(weight, &res.j_board, &res.r, 1.0);
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
}

impl LmOptions {
    /// The [`minimize`] settings of these options: Marquardt's schedule with these
    /// tolerances, λ start and iterations.
    pub fn settings(&self) -> Settings {
        Settings {
            max_iterations: self.max_iterations,
            cost_tolerance: self.cost_tolerance,
            step_tolerance: Some(self.step_tolerance),
            gradient_tolerance: Some(self.gradient_tolerance),
            initial_lambda: self.initial_lambda,
            ..Settings::MARQUARDT
        }
    }
}

/// Runs LM ([`LmOptions::settings`]) from `params` (updated in place to the best
/// estimate found).
pub fn solve<C: Projector + Clone, const B: usize>(
    problem: &JointProblem<'_, B>,
    params: &mut JointParams<C, B>,
    options: &LmOptions,
) -> Result<SolveReport, SolveError> {
    problem.check_params(params)?;
    let mut boards =
        FreeBoards { problem, ne: None, mask: options.mask, step: None, params: PhantomData };
    let report = minimize(&mut boards, params, &options.settings())?;
    let ne = boards.ne.as_ref().expect("minimize linearises first");
    let (corner_rms_px, hole_rms_px) = problem.rms_px(params)?;
    Ok(SolveReport {
        iterations: report.iterations,
        initial_cost: report.initial_cost,
        final_cost: report.final_cost,
        termination: report.termination,
        residuals: ne.residuals,
        free_parameters: boards.mask.free_count() + 6 * problem.boards().len(),
        corner_rms_px,
        hole_rms_px,
        final_lambda: report.final_lambda,
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
    out.lidar_to_camera = params.lidar_to_camera.perturb_left(&ext);
    for (pose, d) in out.board_poses.iter_mut().zip(step.boards.iter()) {
        *pose = pose.perturb_left(d);
    }
    out
}

/// The free-board problem as [`minimize`] drives it: its equations, mask and step.
struct FreeBoards<'p, 'a, C, const B: usize> {
    problem: &'p JointProblem<'a, B>,
    ne: Option<NormalEquations<B>>,
    /// The options' mask until the first linearisation, then with the structural mask and
    /// every parameter nothing touches there (held for the whole solve).
    mask: ParamMask,
    step: Option<Step<B>>,
    params: PhantomData<fn() -> C>,
}

impl<C: Projector + Clone, const B: usize> Problem for FreeBoards<'_, '_, C, B> {
    type Params = JointParams<C, B>;

    fn linearize(&mut self, params: &Self::Params) -> Result<f64, SolveError> {
        let ne = NormalEquations::build(self.problem, params)?;
        if self.ne.is_none() {
            let structural = self.problem.structural_mask(&params.camera);
            self.mask = ne.effective_mask(self.mask.union(structural));
        }
        let cost = ne.cost;
        self.ne = Some(ne);
        Ok(cost)
    }

    fn solve_step(&mut self, lambda: f64) -> Result<(), SolveError> {
        let ne = self.ne.as_ref().expect("linearised before a step");
        self.step = Some(ne.step(lambda, self.mask)?);
        Ok(())
    }

    fn apply(&self, params: &Self::Params) -> Self::Params {
        apply_step(params, self.step.as_ref().expect("a step before applying it"))
    }

    fn cost(&self, params: &Self::Params) -> Result<f64, SolveError> {
        self.problem.cost(params)
    }

    fn max_gradient(&self) -> f64 {
        self.ne.as_ref().map_or(f64::INFINITY, |ne| ne.max_gradient(self.mask))
    }

    /// Over the shared parameters and the board poses; a rotation counts with the size
    /// of a half turn, so rotations and metres mix.
    fn step_size(&self, params: &Self::Params) -> (f64, f64) {
        const PI2: f64 = core::f64::consts::PI * core::f64::consts::PI;
        let (Some(step), Some(ne)) = (&self.step, &self.ne) else { return (f64::INFINITY, 0.0) };
        let k = params.camera.params();
        let ext = &params.lidar_to_camera;
        let mut x2: f64 = k.iter().map(|v| v * v).sum();
        x2 += ext.translation.norm_squared() + PI2;
        let mut d2 = step.shared.norm_squared();
        for (pose, d) in params.board_poses.iter().zip(step.boards.iter()).take(ne.blocks) {
            x2 += pose.translation.norm_squared() + PI2;
            d2 += d.norm_squared();
        }
        (libm::sqrt(d2), libm::sqrt(x2))
    }
}

// `apply_step` reads the extrinsic as the 6 entries after the intrinsics.
const _: () = assert!(EXT_TRANSLATION == EXT_ROTATION + 3 && EXT_ROTATION == INTRINSICS);
