//! Covariance of the shared parameters (intrinsics, extrinsic) at a solution, for the
//! quality gate: the inverse of the undamped reduced normal matrix `S` (the Schur
//! complement, i.e. the shared block of the full inverse with the board poses
//! marginalised), each residual kind's information scaled by that kind's own residual
//! variance ([`covariance`]).
//!
//! For a two-stage run (intrinsics from the corners, then the extrinsic with them held),
//! [`with_fixed_intrinsics`] adds what the first stage's intrinsic uncertainty does to the
//! extrinsic: holding the intrinsics does not make them exact.
//!
//! Rotation and translation uncertainties are "worst axis" figures: the square root of
//! the largest eigenvalue of the 3×3 covariance of the left-perturbation rotation vector
//! (reported in degrees) and of the translation (metres).

use nalgebra::{SMatrix, SVector};

use super::linalg::{max_eigenvalue3, Cholesky, Touched};
use super::lm::NormalEquations;
use super::problem::{JointParams, JointProblem, KindWeights, Loss, ParamMask, ResidualKind};
use super::schur::{SchurProblem, SchurSystem, SystemBlocks};
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
    /// Each residual kind's own `σ̂ₖ²` (the global one where a kind has too little
    /// redundancy, 1 for a kind the problem lacks).
    pub kind_variances: KindWeights,
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
///
/// Each residual kind (corners, holes, board planes) gets its own variance factor
/// `σ̂ₖ² = 2·costₖ / rₖ`, `rₖ = mₖ − tr(H⁻¹Hₖ)` its share of the redundancy, and the
/// covariance is the estimate's own under those factors, `H⁻¹ (Σₖ σ̂ₖ² Hₖ) H⁻¹` (the
/// boards' blocks marginalised). One factor for all kinds would let the worst-modelled
/// kind scale the others: corners that fit five times better than their σ, beside hole
/// centres that fit as their σ says, made the joint solve's σ larger than the corners'
/// alone. A kind with less than [`MIN_KIND_REDUNDANCY`] of the redundancy takes the
/// global factor (its own would rest on too few residuals).
pub fn covariance<C: Projector, const B: usize>(
    problem: &JointProblem<'_, B>,
    params: &JointParams<C, B>,
    mask: ParamMask,
) -> Result<SharedCovariance, SolveError> {
    let ne = NormalEquations::build(problem, params)?;
    let mask = ne.effective_mask(mask.union(problem.structural_mask(&params.camera)));
    let n = mask.free_count() + 6 * ne.blocks;
    if ne.residuals <= n {
        return Err(SolveError::TooFewPoints { needed: n + 1, got: ne.residuals });
    }
    let dof = ne.residuals - n;
    let residual_variance = 2.0 * ne.cost / dof as f64;
    let (s, _) = ne.reduce(0.0, mask)?;
    let inverse: InverseBlocks<SHARED, B> =
        InverseBlocks::new(&s, |i| mask.is_fixed(i), ne.system())?;
    let factors = kind_variances(&inverse, residual_variance, |w| {
        NormalEquations::build_weighted(problem, params, w)
    })?;
    let weighted = NormalEquations::build_weighted(problem, params, factors)?;
    let matrix = inverse.sandwich(weighted.system());
    Ok(SharedCovariance { matrix, residual_variance, dof, mask, kind_variances: factors })
}

/// Least redundancy (residuals less the parameters they determine) a residual kind needs
/// for a variance factor of its own.
pub const MIN_KIND_REDUNDANCY: f64 = 5.0;

/// Each residual kind's variance factor `2·costₖ / rₖ`, `rₖ = mₖ − tr(H⁻¹Hₖ)` its share
/// of the redundancy (`equations` builds one kind's system `Hₖ`, given that kind alone):
/// the `pooled` factor where `rₖ` is below [`MIN_KIND_REDUNDANCY`], 1 for an absent kind.
pub(crate) fn kind_variances<const N: usize, const B: usize, E: KindSystem<N>>(
    inverse: &InverseBlocks<N, B>,
    pooled: f64,
    mut equations: impl FnMut(KindWeights) -> Result<E, SolveError>,
) -> Result<KindWeights, SolveError> {
    let mut factors = KindWeights::ALL;
    for kind in [ResidualKind::Corner(0), ResidualKind::Hole(0), ResidualKind::Plane(0)] {
        let part = equations(KindWeights::only(kind))?;
        let determined = inverse.trace_with(part.system());
        *factors.of_mut(kind) =
            variance_factor(part.rows() as f64, part.cost(), determined, pooled);
    }
    Ok(factors)
}

/// One residual kind's variance factor `2·costₖ / rₖ` from its `rows`, robust cost `½Σρ`
/// and the parameters it `determined` (`tr(H⁻¹Hₖ)`; `rₖ = rows − determined`): the `pooled`
/// factor where `rₖ` is below [`MIN_KIND_REDUNDANCY`], 1 for an absent kind.
pub(crate) fn variance_factor(rows: f64, cost: f64, determined: f64, pooled: f64) -> f64 {
    let redundancy = rows - determined;
    if rows == 0.0 {
        1.0
    } else if redundancy >= MIN_KIND_REDUNDANCY {
        2.0 * cost / redundancy
    } else {
        pooled
    }
}

/// Normal equations of some residuals, as [`kind_variances`] reads them: scalar residuals,
/// robust cost and blocks.
pub(crate) trait KindSystem<const N: usize> {
    fn rows(&self) -> usize;
    fn cost(&self) -> f64;
    fn system(&self) -> SystemBlocks<'_, N>;
}

/// The blocks of `H⁻¹` that a shared covariance needs, from the Schur complement `S` of a
/// system with `N` shared parameters and blocks of 6 (board poses, frames): `Σ_ss = S⁻¹`
/// (fixed rows zero), per block `Σ_sb = −Σ_ss W U⁻¹` and `Σ_bb = U⁻¹ − U⁻¹ Wᵀ Σ_sb`.
pub(crate) struct InverseBlocks<const N: usize, const B: usize> {
    shared: SMatrix<f64, N, N>,
    shared_block: [SMatrix<f64, N, 6>; B],
    block: [SMatrix<f64, 6, 6>; B],
    blocks: usize,
}

impl<const N: usize, const B: usize> InverseBlocks<N, B> {
    /// From the undamped reduced matrix `s` (fixed rows already unit) and the system.
    pub(crate) fn new(
        s: &SMatrix<f64, N, N>,
        is_fixed: impl Fn(usize) -> bool,
        system: SystemBlocks<'_, N>,
    ) -> Result<Self, SolveError> {
        let mut out = InverseBlocks {
            shared: shared_inverse(s, is_fixed)?,
            shared_block: [SMatrix::zeros(); B],
            block: [SMatrix::zeros(); B],
            blocks: system.u.len(),
        };
        for (b, (u, w)) in system.u.iter().zip(system.w).enumerate() {
            let u_inv = Cholesky::new(u)?.inverse();
            let shared_block = -(out.shared * w * u_inv);
            out.block[b] = u_inv - u_inv * w.transpose() * shared_block;
            out.shared_block[b] = shared_block;
        }
        Ok(out)
    }

    /// `tr(H⁻¹ Hₖ)`, `part` the system `Hₖ` of some of the residuals: the number of
    /// parameters they determine.
    pub(crate) fn trace_with(&self, part: SystemBlocks<'_, N>) -> f64 {
        let mut trace = (self.shared * part.v).trace();
        for b in 0..self.blocks {
            trace +=
                2.0 * self.shared_block[b].dot(&part.w[b]) + (self.block[b] * part.u[b]).trace();
        }
        trace
    }

    /// The shared block of `H⁻¹ M H⁻¹` (`M`'s block-block part is block-diagonal: every
    /// residual sees one block).
    pub(crate) fn sandwich(&self, m: SystemBlocks<'_, N>) -> SMatrix<f64, N, N> {
        let mut out = self.shared * m.v * self.shared;
        for b in 0..self.blocks {
            let cross = self.shared * m.w[b] * self.shared_block[b].transpose();
            out += cross + cross.transpose();
            out += self.shared_block[b] * m.u[b] * self.shared_block[b].transpose();
        }
        out
    }
}

/// `Σ_ss = S⁻¹` of the reduced matrix `s`, its fixed rows and columns zero.
pub(crate) fn shared_inverse<const N: usize>(
    s: &SMatrix<f64, N, N>,
    is_fixed: impl Fn(usize) -> bool,
) -> Result<SMatrix<f64, N, N>, SolveError> {
    let mut shared = Cholesky::new(s)?.inverse();
    for i in (0..N).filter(|&i| is_fixed(i)) {
        shared.row_mut(i).fill(0.0);
        shared.column_mut(i).fill(0.0);
    }
    Ok(shared)
}

/// `H⁻¹ M H⁻¹` over the shared parameters, `M` gathered one measurement at a time: `V`
/// whole, `W` and `U` of the block being read only (their part of the product added when
/// the next measurement is on another block: it is linear in them, so a block read twice
/// is added twice, rightly).
pub(crate) struct Sandwich<const N: usize> {
    v: SMatrix<f64, N, N>,
    current: Option<(usize, SMatrix<f64, N, 6>, SMatrix<f64, 6, 6>)>,
    out: SMatrix<f64, N, N>,
}

impl<const N: usize> Sandwich<N> {
    pub(crate) fn new() -> Self {
        Sandwich { v: SMatrix::zeros(), current: None, out: SMatrix::zeros() }
    }

    /// One measurement on block `k` with weight `weight` (`js`, `jb`: its Jacobians).
    pub(crate) fn add(
        &mut self,
        inverse: &mut StreamedInverse<'_, N>,
        k: usize,
        weight: f64,
        js: &SMatrix<f64, 2, N>,
        jb: &SMatrix<f64, 2, 6>,
    ) {
        self.select(inverse, k);
        let (v, Some((_, w, u))) = (&mut self.v, self.current.as_mut()) else {
            return;
        };
        u.gemm_tr(weight, jb, jb, 1.0);
        Touched::of(js).add_products((v, w), weight, js, jb);
    }

    /// A whitened prior on block `k` (`j`: its Jacobian).
    pub(crate) fn add_prior(
        &mut self,
        inverse: &mut StreamedInverse<'_, N>,
        k: usize,
        j: &SMatrix<f64, 6, 6>,
    ) {
        self.select(inverse, k);
        if let Some((_, _, u)) = self.current.as_mut() {
            u.gemm_tr(1.0, j, j, 1.0);
        }
    }

    /// The product. (In place and in a frame of its own, as [`Self::flush`].)
    #[inline(never)]
    pub(crate) fn finish(mut self, inverse: &mut StreamedInverse<'_, N>) -> SMatrix<f64, N, N> {
        self.flush(inverse);
        let left = inverse.shared * self.v;
        self.out.gemm(1.0, &left, &inverse.shared, 1.0);
        self.out
    }

    /// Makes block `k` the one added to, the previous block's part added first.
    fn select(&mut self, inverse: &mut StreamedInverse<'_, N>, k: usize) {
        if self.current.as_ref().is_none_or(|(at, _, _)| *at != k) {
            self.flush(inverse);
            self.current = Some((k, SMatrix::zeros(), SMatrix::zeros()));
        }
    }

    /// Adds `Σ_ss W Σ_sbᵀ + (…)ᵀ + Σ_sb U Σ_sbᵀ` of the block being read, in place: it
    /// runs inside the measurements' stream, where N×N temporaries would be that much more
    /// stack at its deepest.
    #[inline(never)]
    fn flush(&mut self, inverse: &mut StreamedInverse<'_, N>) {
        if let Some((k, w, u)) = self.current.take() {
            let (shared_block, _) = inverse.block(k);
            let cross = inverse.shared * w;
            self.out.gemm(1.0, &cross, &shared_block.transpose(), 1.0);
            self.out.gemm(1.0, &shared_block, &cross.transpose(), 1.0);
            self.out.gemm(1.0, &(shared_block * u), &shared_block.transpose(), 1.0);
        }
    }
}

/// `H⁻¹` of a Schur system read one block at a time: `Σ_ss` kept, each block's `Σ_sb` and
/// `Σ_bb` made from the system's `W` and `U` when a measurement on it asks (and kept until
/// one on another block does). [`InverseBlocks`] holds every block's at once, which for a
/// rig (84 shared parameters, 32 blocks) is 0.15 MB more on a worker thread's stack.
pub(crate) struct StreamedInverse<'s, const N: usize> {
    shared: SMatrix<f64, N, N>,
    system: SystemBlocks<'s, N>,
    current: Option<(usize, SMatrix<f64, N, 6>, SMatrix<f64, 6, 6>)>,
}

impl<'s, const N: usize> StreamedInverse<'s, N> {
    /// From `Σ_ss` ([`shared_inverse`]) and the system; an error when a block's `U` is not
    /// positive definite.
    pub(crate) fn new(
        shared: SMatrix<f64, N, N>,
        system: SystemBlocks<'s, N>,
    ) -> Result<Self, SolveError> {
        for u in system.u {
            Cholesky::new(u)?;
        }
        Ok(StreamedInverse { shared, system, current: None })
    }

    /// `tr(J H⁻¹ Jᵀ)` of one measurement on block `k` (`js`, `jb`: its Jacobians in the
    /// shared parameters and the block): its share of the parameters the data determine.
    /// Only the shared columns `js` touches are read (a rig's measurement: 27 of 84).
    pub(crate) fn leverage(
        &mut self,
        k: usize,
        js: &SMatrix<f64, 2, N>,
        jb: &SMatrix<f64, 2, 6>,
    ) -> f64 {
        let (shared_block, block) = self.block(k);
        let mut image = jb * shared_block.transpose();
        for &a in Touched::of(js).columns() {
            let (j0, j1) = (js[(0, a)], js[(1, a)]);
            for c in 0..N {
                let shared = self.shared[(a, c)];
                image[(0, c)] += j0 * shared;
                image[(1, c)] += j1 * shared;
            }
        }
        image.dot(js) + (js * shared_block + jb * block).dot(jb)
    }

    /// Block `k`'s `Σ_sb = −Σ_ss W U⁻¹` and `Σ_bb = U⁻¹ − U⁻¹ Wᵀ Σ_sb`.
    fn block(&mut self, k: usize) -> (SMatrix<f64, N, 6>, SMatrix<f64, 6, 6>) {
        match self.current {
            Some((at, shared_block, block)) if at == k => (shared_block, block),
            _ => {
                let (u, w) = (&self.system.u[k], &self.system.w[k]);
                // Every U was factorised in `new`: this cannot fail.
                let u_inv = Cholesky::new(u).map_or(SMatrix::zeros(), |c| c.inverse());
                let shared_block = -(self.shared * w * u_inv);
                let block = u_inv - u_inv * w.transpose() * shared_block;
                self.current = Some((k, shared_block, block));
                (shared_block, block)
            }
        }
    }
}

impl<const B: usize> KindSystem<SHARED> for NormalEquations<B> {
    fn rows(&self) -> usize {
        self.residuals
    }
    fn cost(&self) -> f64 {
        self.cost
    }
    fn system(&self) -> SystemBlocks<'_, SHARED> {
        SchurSystem::system(self)
    }
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

/// The covariance of a Schur problem's `N` shared parameters at `params` with each
/// measurement kind scaled by its own variance factor ([`variance_factor`]) and the priors
/// as they are: `H⁻¹ (Σₖ fₖ Hₖ + H_p) H⁻¹`, `H` as the solve weighed it.
/// One pooled factor would let the kind that fits best (corners, weighed by the detector's
/// σ, fit 0.2× their variance) shrink every other kind's σ, and the kind that fits worst
/// inflate the corners'.
///
/// `measurements` calls its argument once per measurement (block, kind, loss, whitened
/// residual, ∂r/∂shared, ∂r/∂block, rows), `priors` once per block prior (block, whitened
/// residual, Jacobian). The measurements are streamed twice (the factors, then the
/// sandwich) instead of being gathered into a system per kind, and `H⁻¹`'s blocks made one
/// at a time ([`StreamedInverse`]): a rig's system (84 shared parameters, 32 blocks) is
/// 0.2 MB, and a calibration runs on a 2 MiB worker thread.
pub(crate) fn kinds_covariance<P, Q, const N: usize, const B: usize>(
    problem: &Q,
    params: &P,
    measurements: impl Fn(&mut Measurements<'_, N>) -> Result<(), SolveError>,
    priors: impl FnOnce(&mut dyn FnMut(usize, &SVector<f64, 6>, &SMatrix<f64, 6, 6>)),
) -> Result<SMatrix<f64, N, N>, SolveError>
where
    Q: SchurProblem<P, N, B>,
{
    let ne = problem.normal_equations(params)?;
    let fixed = ne.mask(&problem.structural_mask(params));
    let pooled = pooled_variance(&ne, &fixed)?;
    let mut inverse = StreamedInverse::new(reduced_inverse(&ne, &fixed)?, ne.system())?;
    // Per kind: rows, robust cost ½Σρ and the parameters it determines, tr(H⁻¹Hₖ).
    let (mut rows, mut cost, mut determined) =
        (KindWeights::NONE, KindWeights::NONE, KindWeights::NONE);
    measurements(&mut |k, kind, loss, r, js, jb, n| {
        let (rho, weight) = loss.eval(r.norm_squared());
        *rows.of_mut(kind) += n as f64;
        *cost.of_mut(kind) += 0.5 * rho;
        *determined.of_mut(kind) += weight * inverse.leverage(k, js, jb);
    })?;
    let mut factors = KindWeights::ALL;
    for kind in [ResidualKind::Corner(0), ResidualKind::Hole(0), ResidualKind::Plane(0)] {
        *factors.of_mut(kind) =
            variance_factor(rows.of(kind), cost.of(kind), determined.of(kind), pooled);
    }
    let mut sandwich = Sandwich::new();
    measurements(&mut |k, kind, loss, r, js, jb, _| {
        let (_, weight) = loss.eval(r.norm_squared());
        sandwich.add(&mut inverse, k, weight * factors.of(kind), js, jb);
    })?;
    priors(&mut |k, _, j| sandwich.add_prior(&mut inverse, k, j));
    Ok(sandwich.finish(&mut inverse))
}

/// The residual variance `2·cost/dof` of `ne` (its free parameters those not `fixed` and
/// 6 per block); an error when the measurements do not outnumber them.
pub(crate) fn pooled_variance<const N: usize, const B: usize>(
    ne: &SchurSystem<N, B>,
    fixed: &[bool; N],
) -> Result<f64, SolveError> {
    let free = fixed.iter().filter(|f| !**f).count() + 6 * ne.blocks;
    if ne.residuals <= free {
        return Err(SolveError::TooFewPoints { needed: free + 1, got: ne.residuals });
    }
    Ok(2.0 * ne.cost / (ne.residuals - free) as f64)
}

/// `Σ_ss` of `ne` with the `fixed` parameters' rows and columns zero (a function of its
/// own: the reduced matrix and its factor are off the stack when it returns).
#[inline(never)]
pub(crate) fn reduced_inverse<const N: usize, const B: usize>(
    ne: &SchurSystem<N, B>,
    fixed: &[bool; N],
) -> Result<SMatrix<f64, N, N>, SolveError> {
    let (s, _) = ne.reduce(0.0, fixed)?;
    shared_inverse(&s, |i| fixed[i])
}

/// What [`kinds_covariance`] is handed for each measurement: block, kind, loss, whitened
/// residual, ∂r/∂shared, ∂r/∂block, rows.
pub(crate) type Measurements<'m, const N: usize> = dyn FnMut(
        usize,
        ResidualKind,
        Loss,
        &SVector<f64, 2>,
        &SMatrix<f64, 2, N>,
        &SMatrix<f64, 2, 6>,
        usize,
    ) + 'm;
