//! The one Schur system: normal equations over `N` shared parameters and up to `B`
//! blocks of 6 (board or block poses), the blocks eliminated by the Schur complement.
//!
//! Per block `U_k` (6×6), `W_k` (N×6) and `g_k`; one `V` (N×N) and `g` over the shared
//! parameters. The reduced system `S = V − Σ W_k U_k⁻¹ W_kᵀ` is factorised (Cholesky) and
//! each block's update back-substituted. The free-board problem ([`super::lm`]), the rig
//! ([`super::rig`], the surveyed room's one pair among them, [`super::room`]) and the room
//! modes ([`super::room_modes`]) accumulate into it; the last two through [`SchurProblem`],
//! solved by [`solve`] (the one [`minimize`]). Fixed size: nothing here allocates.

use core::marker::PhantomData;

use nalgebra::{SMatrix, SVector};

use super::linalg::{Cholesky, Touched};
use super::minimize::{damp, damped, minimize, Problem, Report, Settings};
use super::problem::{Loss, ParamMask};
use super::SolveError;

/// The undamped normal equations with their blocks (see the module doc).
#[derive(Clone, Debug)]
pub struct SchurSystem<const N: usize, const B: usize> {
    /// Blocks in use (the first `blocks` entries of the arrays below).
    pub blocks: usize,
    /// `JᵀWJ` per block (6×6).
    pub u: [SMatrix<f64, 6, 6>; B],
    /// `J_sharedᵀ W J_block` per block (N×6).
    pub w: [SMatrix<f64, N, 6>; B],
    /// `J_blockᵀ W r` per block.
    pub g_block: [SVector<f64, 6>; B],
    /// `J_sharedᵀ W J_shared` (N×N).
    pub v: SMatrix<f64, N, N>,
    /// `J_sharedᵀ W r`.
    pub g_shared: SVector<f64, N>,
    /// Robust cost `½ Σ ρ` at this estimate.
    pub cost: f64,
    /// Scalar residuals.
    pub residuals: usize,
}

/// One damped step: shared update and one update per block.
#[derive(Clone, Debug)]
pub struct Step<const N: usize, const B: usize> {
    pub shared: SVector<f64, N>,
    /// Per block (a board pose of the free-board problem, a room block).
    pub boards: [SVector<f64, 6>; B],
}

/// Which shared parameters a reduction holds fixed.
pub trait Fixed {
    fn is_fixed(&self, i: usize) -> bool;
}

impl Fixed for ParamMask {
    fn is_fixed(&self, i: usize) -> bool {
        ParamMask::is_fixed(self, i)
    }
}

impl<const N: usize> Fixed for &[bool; N] {
    fn is_fixed(&self, i: usize) -> bool {
        self[i]
    }
}

/// A least-squares problem over `N` shared parameters and blocks of 6 that [`solve`] and
/// [`super::covariance::kinds_covariance`] solve (`P`: its parameters): the cost functions
/// side; [`solve`] adapts it to [`Problem`].
pub trait SchurProblem<P, const N: usize, const B: usize> {
    /// The undamped normal equations at `params`.
    fn normal_equations(&self, params: &P) -> Result<SchurSystem<N, B>, SolveError>;
    /// The robust cost `½ Σ ρ` (measurements and priors) at `params`.
    fn cost(&self, params: &P) -> Result<f64, SolveError>;
    /// `params ⊕ (shared, blocks)`.
    fn apply(&self, params: &P, shared: &SVector<f64, N>, blocks: &[SVector<f64, 6>; B]) -> P;
    /// Shared parameters the data cannot move whatever they are (unused intrinsics,
    /// absent sensors); [`SchurSystem::mask`] adds those nothing touched.
    fn structural_mask(&self, params: &P) -> [bool; N];
}

/// Levenberg–Marquardt ([`minimize`]) on a [`SchurProblem`] from `params` (updated in
/// place). The shared parameters nothing touches at the start stay fixed throughout.
pub fn solve<P: Clone, Q: SchurProblem<P, N, B>, const N: usize, const B: usize>(
    problem: &Q,
    params: &mut P,
    settings: &Settings,
) -> Result<(Report, usize), SolveError> {
    let mut solver =
        Solver { problem, ne: None, fixed: [false; N], step: None, params: PhantomData };
    let report = minimize(&mut solver, params, settings)?;
    let residuals = solver.ne.map_or(0, |ne| ne.residuals);
    Ok((report, residuals))
}

/// A [`SchurProblem`] with its equations, mask and step, as [`minimize`] drives it.
struct Solver<'q, P, Q, const N: usize, const B: usize> {
    problem: &'q Q,
    ne: Option<SchurSystem<N, B>>,
    fixed: [bool; N],
    step: Option<Step<N, B>>,
    params: PhantomData<fn() -> P>,
}

impl<P: Clone, Q: SchurProblem<P, N, B>, const N: usize, const B: usize> Problem
    for Solver<'_, P, Q, N, B>
{
    type Params = P;

    fn linearize(&mut self, params: &P) -> Result<f64, SolveError> {
        let ne = self.problem.normal_equations(params)?;
        if self.ne.is_none() {
            self.fixed = ne.mask(&self.problem.structural_mask(params));
        }
        let cost = ne.cost;
        self.ne = Some(ne);
        Ok(cost)
    }

    fn solve_step(&mut self, lambda: f64) -> Result<(), SolveError> {
        let ne = self.ne.as_ref().expect("linearised before a step");
        self.step = Some(ne.step(lambda, &self.fixed)?);
        Ok(())
    }

    fn apply(&self, params: &P) -> P {
        let step = self.step.as_ref().expect("a step before applying it");
        self.problem.apply(params, &step.shared, &step.boards)
    }

    fn cost(&self, params: &P) -> Result<f64, SolveError> {
        self.problem.cost(params)
    }
}

impl<const N: usize, const B: usize> SchurSystem<N, B> {
    /// Empty equations for `blocks` blocks, `prior_rows` scalar prior residuals counted.
    pub fn new(blocks: usize, prior_rows: usize) -> Self {
        SchurSystem {
            blocks,
            u: [SMatrix::zeros(); B],
            w: [SMatrix::zeros(); B],
            g_block: [SVector::zeros(); B],
            v: SMatrix::zeros(),
            g_shared: SVector::zeros(),
            cost: 0.0,
            residuals: prior_rows,
        }
    }

    /// Adds one whitened 2-row block `r` of block `k` under `loss` (IRLS weight), standing
    /// for `rows` scalar measurements.
    pub fn add(
        &mut self,
        k: usize,
        loss: Loss,
        r: &SVector<f64, 2>,
        js: &SMatrix<f64, 2, N>,
        jb: &SMatrix<f64, 2, 6>,
        rows: usize,
    ) {
        self.add_weighted(k, (loss, 1.0), r, js, jb, rows);
    }

    /// [`Self::add`] with the block's weight and cost multiplied by `factor`.
    pub fn add_weighted(
        &mut self,
        k: usize,
        (loss, factor): (Loss, f64),
        r: &SVector<f64, 2>,
        js: &SMatrix<f64, 2, N>,
        jb: &SMatrix<f64, 2, 6>,
        rows: usize,
    ) {
        let (rho, weight) = loss.eval(r.norm_squared());
        let weight = weight * factor;
        self.cost += 0.5 * rho * factor;
        self.residuals += rows;
        self.u[k].gemm_tr(weight, jb, jb, 1.0);
        self.g_block[k].gemv_tr(weight, jb, r, 1.0);
        // Only the columns a measurement touches are accumulated ([`Touched`]): the dense
        // products were a tenth of a rig's run.
        let touched = Touched::of(js);
        if 2 * touched.columns().len() > N {
            self.w[k].gemm_tr(weight, js, jb, 1.0);
            self.v.gemm_tr(weight, js, js, 1.0);
            self.g_shared.gemv_tr(weight, js, r, 1.0);
            return;
        }
        touched.add_products((&mut self.v, &mut self.w[k]), weight, js, jb);
        for &a in touched.columns() {
            let (a0, a1) = (weight * js[(0, a)], weight * js[(1, a)]);
            self.g_shared[a] += a0 * r[0] + a1 * r[1];
        }
    }

    /// Adds a whitened prior on block `k` (its rows are counted by [`Self::new`]).
    pub fn add_prior(&mut self, k: usize, r: &SVector<f64, 6>, j: &SMatrix<f64, 6, 6>) {
        self.cost += 0.5 * r.norm_squared();
        self.u[k].gemm_tr(1.0, j, j, 1.0);
        self.g_block[k].gemv_tr(1.0, j, r, 1.0);
    }

    /// The equations, or [`SolveError::NonFinite`] if the cost overflowed.
    pub fn finite(self) -> Result<Self, SolveError> {
        if self.cost.is_finite() {
            Ok(self)
        } else {
            Err(SolveError::NonFinite)
        }
    }

    /// `structural` plus every shared parameter nothing touches.
    pub fn mask(&self, structural: &[bool; N]) -> [bool; N] {
        let mut fixed = *structural;
        for (i, f) in fixed.iter_mut().enumerate() {
            *f |= self.v[(i, i)] <= 0.0;
        }
        fixed
    }

    /// Largest absolute gradient entry over the free shared parameters and the blocks.
    pub fn max_gradient(&self, fixed: impl Fixed) -> f64 {
        let shared = (0..N)
            .filter(|&i| !fixed.is_fixed(i))
            .map(|i| self.g_shared[i].abs())
            .fold(0.0, f64::max);
        self.g_block[..self.blocks].iter().map(|g| g.amax()).fold(shared, f64::max)
    }

    /// The reduced system `S δs = rhs` after eliminating the blocks, damped by `λ`
    /// ([`damp`]); fixed parameters get a unit row/column and a zero right-hand side.
    pub fn reduce(
        &self,
        lambda: f64,
        fixed: impl Fixed,
    ) -> Result<(SMatrix<f64, N, N>, SVector<f64, N>), SolveError> {
        let mut s = self.v;
        damp(&mut s, lambda);
        let mut rhs = -self.g_shared;
        for k in 0..self.blocks {
            let ch = Cholesky::new(&damped(&self.u[k], lambda))?;
            // Y = W U⁻¹ (N×6) via U⁻¹ Wᵀ, U symmetric.
            let y_t = ch.solve_matrix(&self.w[k].transpose());
            s.gemm(-1.0, &self.w[k], &y_t, 1.0);
            rhs.gemv_tr(1.0, &y_t, &self.g_block[k], 1.0);
        }
        for i in 0..N {
            if fixed.is_fixed(i) {
                s.row_mut(i).fill(0.0);
                s.column_mut(i).fill(0.0);
                s[(i, i)] = 1.0;
                rhs[i] = 0.0;
            }
        }
        Ok((s, rhs))
    }

    /// The damped step: shared and per block.
    pub fn step(&self, lambda: f64, fixed: impl Fixed) -> Result<Step<N, B>, SolveError> {
        let (s, rhs) = self.reduce(lambda, fixed)?;
        let shared = Cholesky::new(&s)?.solve(&rhs);
        let mut boards = [SVector::<f64, 6>::zeros(); B];
        for (k, out) in boards.iter_mut().enumerate().take(self.blocks) {
            let ch = Cholesky::new(&damped(&self.u[k], lambda))?;
            let mut rhs_k = -self.g_block[k];
            rhs_k.gemv_tr(-1.0, &self.w[k], &shared, 1.0);
            *out = ch.solve(&rhs_k);
        }
        Ok(Step { shared, boards })
    }

    /// The blocks as the covariance reads them.
    pub(crate) fn system(&self) -> SystemBlocks<'_, N> {
        SystemBlocks { v: &self.v, w: &self.w[..self.blocks], u: &self.u[..self.blocks] }
    }
}

/// One system's blocks as [`super::covariance`] reads them: `V` (shared × shared), per
/// block `W` (shared × block) and `U` (block × block).
pub(crate) struct SystemBlocks<'s, const N: usize> {
    pub v: &'s SMatrix<f64, N, N>,
    pub w: &'s [SMatrix<f64, N, 6>],
    pub u: &'s [SMatrix<f64, 6, 6>],
}
