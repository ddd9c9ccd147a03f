//! The one Levenberg–Marquardt loop: every problem of the crate (free boards, surveyed
//! room, rig, room modes, survey bundle, pose refinement) implements [`Problem`] and is
//! solved by [`minimize`] with its own [`Settings`].
//!
//! The rule, in this order, per outer iteration (one linearisation):
//! 1. stop ([`Termination::GradientConverged`]) if the largest gradient entry is at most
//!    the gradient tolerance;
//! 2. solve the damped normal equations `(A + λ·diag(max(A_ii, DIAG_FLOOR))) δ = −g`
//!    ([`damp`]); a matrix that is not positive definite raises λ and tries again;
//! 3. stop ([`Termination::StepConverged`]) if `|δ| ≤ tol · (|x| + tol)` (the step test,
//!    [`StepTest::BeforeTrial`]: the step is not tried);
//! 4. evaluate the cost at `x ⊕ δ`. Lower: accept, re-linearise there, lower λ, and stop
//!    ([`Termination::CostConverged`]) if the decrease is at most `cost_tolerance` of the
//!    cost, or the step test holds ([`StepTest::OnAcceptance`]: a small step is tried and
//!    kept). Not lower (or a point leaves the camera, or overflow): raise λ and go to 2;
//! 5. stop ([`Termination::NoProgress`]) once λ exceeds its cap, and
//!    ([`Termination::MaxIterations`]) after `max_iterations` linearisations.
//!
//! The tolerances are each problem's (its `Settings` constant says why); the loop and the
//! damping are written here once. Nothing allocates.

use nalgebra::{Dim, Matrix, StorageMut};

use super::SolveError;

/// Smallest diagonal used for Marquardt scaling, so unconstrained directions still damp.
pub const DIAG_FLOOR: f64 = 1e-9;

/// A least-squares problem as [`minimize`] sees it. The problem keeps its own normal
/// equations and step between calls, so their memory is its own (fixed-size, or sized
/// once before the solve).
pub trait Problem {
    /// The estimate.
    type Params: Clone;

    /// Linearises at `params` (keeps the undamped normal equations); the cost there.
    fn linearize(&mut self, params: &Self::Params) -> Result<f64, SolveError>;

    /// Solves the last linearisation's equations damped by `λ` ([`damp`]) and keeps the
    /// step. [`SolveError::NotPositiveDefinite`] makes [`minimize`] raise λ.
    fn solve_step(&mut self, lambda: f64) -> Result<(), SolveError>;

    /// `params ⊕ step` (the last step).
    fn apply(&self, params: &Self::Params) -> Self::Params;

    /// The cost at `params`. [`SolveError::NotProjectable`] and [`SolveError::NonFinite`]
    /// reject the step; other errors end the solve.
    fn cost(&self, params: &Self::Params) -> Result<f64, SolveError>;

    /// Largest gradient entry over the free parameters at the last linearisation. A
    /// problem that does not say never stops on the gradient.
    fn max_gradient(&self) -> f64 {
        f64::INFINITY
    }

    /// `(|δ|, |x|)` of the last step at `params`, for the step test. A problem that does
    /// not say never stops on the step.
    fn step_size(&self, _params: &Self::Params) -> (f64, f64) {
        (f64::INFINITY, 0.0)
    }
}

/// A problem's stopping and damping numbers (the rule is [`minimize`]'s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// Most outer iterations (linearisations).
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by at most this fraction of it.
    pub cost_tolerance: f64,
    /// Stop when `|δ| ≤ tol · (|x| + tol)`; `None`: no step test.
    pub step_tolerance: Option<f64>,
    /// Where the step test stands in the rule.
    pub step_test: StepTest,
    /// Stop when the largest gradient entry is at most this; `None`: no gradient test.
    pub gradient_tolerance: Option<f64>,
    /// Starting damping λ.
    pub initial_lambda: f64,
    /// Largest λ tried; beyond it the solve stops with [`Termination::NoProgress`].
    pub max_lambda: f64,
    /// Smallest λ after a decrease.
    pub min_lambda: f64,
    /// λ is multiplied by this after a rejected step, by `lambda_down` after an accepted one.
    pub lambda_up: f64,
    pub lambda_down: f64,
}

impl Settings {
    /// Marquardt's damping schedule shared by every problem: λ from 10⁻⁴, ×10 on a
    /// rejected step, ×0.1 on an accepted one, between 10⁻¹⁵ and 10¹⁶; no gradient or
    /// step test. Problems start from it and state their tolerances.
    pub const MARQUARDT: Settings = Settings {
        max_iterations: 100,
        cost_tolerance: 1e-6,
        step_tolerance: None,
        step_test: StepTest::BeforeTrial,
        gradient_tolerance: None,
        initial_lambda: 1e-4,
        max_lambda: 1e16,
        min_lambda: 1e-15,
        lambda_up: 10.0,
        lambda_down: 0.1,
    };

    /// These settings with `max_iterations` replaced.
    pub const fn with_max_iterations(self, max_iterations: usize) -> Settings {
        Settings { max_iterations, ..self }
    }
}

/// Where the step test (`|δ| ≤ tol · (|x| + tol)`) stands in [`minimize`]'s rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepTest {
    /// Before the cost is evaluated: a small step ends the solve untried.
    BeforeTrial,
    /// With the cost test: an accepted small step ends the solve (a small step is still
    /// tried, and damped further while it does not lower the cost).
    OnAcceptance,
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

/// What [`minimize`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Report {
    /// Outer iterations (linearisations asked for).
    pub iterations: usize,
    /// Cost at the start and at the end (the linearisations' costs).
    pub initial_cost: f64,
    pub final_cost: f64,
    pub termination: Termination,
    /// The damping in force at the end.
    pub final_lambda: f64,
}

/// Levenberg–Marquardt from `params` (updated in place to the best estimate found), by the
/// rule of the module doc with `settings`' numbers.
pub fn minimize<P: Problem>(
    problem: &mut P,
    params: &mut P::Params,
    settings: &Settings,
) -> Result<Report, SolveError> {
    let mut cost = problem.linearize(params)?;
    let initial_cost = cost;
    let mut lambda = settings.initial_lambda;
    let mut iterations = 0;
    let mut termination = Termination::MaxIterations;
    'outer: while iterations < settings.max_iterations {
        iterations += 1;
        if settings.gradient_tolerance.is_some_and(|tol| problem.max_gradient() <= tol) {
            termination = Termination::GradientConverged;
            break;
        }
        loop {
            if lambda > settings.max_lambda {
                termination = Termination::NoProgress;
                break 'outer;
            }
            match problem.solve_step(lambda) {
                Ok(()) => {}
                Err(SolveError::NotPositiveDefinite { .. }) => {
                    lambda *= settings.lambda_up;
                    continue;
                }
                Err(e) => return Err(e),
            }
            if settings.step_test == StepTest::BeforeTrial && small_step(problem, params, settings)
            {
                termination = Termination::StepConverged;
                break 'outer;
            }
            let trial = problem.apply(params);
            match problem.cost(&trial) {
                Ok(c) if c < cost => {
                    let converged = cost - c <= settings.cost_tolerance * cost
                        || (settings.step_test == StepTest::OnAcceptance
                            && small_step(problem, params, settings));
                    *params = trial;
                    cost = problem.linearize(params)?;
                    lambda = (lambda * settings.lambda_down).max(settings.min_lambda);
                    if converged {
                        termination = Termination::CostConverged;
                        break 'outer;
                    }
                    continue 'outer;
                }
                // Higher cost, a point leaving the image, or overflow: damp more.
                Ok(_) | Err(SolveError::NotProjectable { .. }) | Err(SolveError::NonFinite) => {
                    lambda *= settings.lambda_up;
                }
                Err(e) => return Err(e),
            }
        }
    }
    Ok(Report { iterations, initial_cost, final_cost: cost, termination, final_lambda: lambda })
}

/// The step test: `|δ| ≤ tol · (|x| + tol)` for the last step at `params`.
fn small_step<P: Problem>(problem: &P, params: &P::Params, settings: &Settings) -> bool {
    settings.step_tolerance.is_some_and(|tol| {
        let (step, size) = problem.step_size(params);
        step <= tol * (size + tol)
    })
}

/// Marquardt's damping, the one every problem uses: `A_ii += λ · max(A_ii, DIAG_FLOOR)`.
pub fn damp<D: Dim, S: StorageMut<f64, D, D>>(a: &mut Matrix<f64, D, D, S>, lambda: f64) {
    for i in 0..a.nrows() {
        a[(i, i)] += lambda * a[(i, i)].max(DIAG_FLOOR);
    }
}

/// `a` damped by `λ` ([`damp`]).
pub fn damped<const N: usize>(
    a: &nalgebra::SMatrix<f64, N, N>,
    lambda: f64,
) -> nalgebra::SMatrix<f64, N, N> {
    let mut d = *a;
    damp(&mut d, lambda);
    d
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::SMatrix;

    /// Residuals `eˣ − 2` and a constant ½ (so the minimum cost is not zero); steps
    /// refused (not positive definite) below `refuse_below`.
    struct Exp {
        a: SMatrix<f64, 1, 1>,
        g: f64,
        delta: f64,
        refuse_below: f64,
    }

    impl Problem for Exp {
        type Params = f64;
        fn linearize(&mut self, x: &f64) -> Result<f64, SolveError> {
            let (j, r) = (libm::exp(*x), libm::exp(*x) - 2.0);
            (self.a, self.g) = (SMatrix::<f64, 1, 1>::new(j * j), j * r);
            self.cost(x)
        }
        fn solve_step(&mut self, lambda: f64) -> Result<(), SolveError> {
            if lambda < self.refuse_below {
                return Err(SolveError::NotPositiveDefinite { pivot: 0 });
            }
            self.delta = -self.g / damped(&self.a, lambda)[(0, 0)];
            Ok(())
        }
        fn apply(&self, x: &f64) -> f64 {
            x + self.delta
        }
        fn cost(&self, x: &f64) -> Result<f64, SolveError> {
            let r = libm::exp(*x) - 2.0;
            Ok(0.5 * r * r + 0.125)
        }
    }

    fn exp(refuse_below: f64) -> Exp {
        Exp { a: SMatrix::zeros(), g: 0.0, delta: 0.0, refuse_below }
    }

    #[test]
    fn converges_on_the_cost_and_raises_lambda_past_refused_steps() {
        let settings = Settings::MARQUARDT;
        let mut x = 0.0;
        let report = minimize(&mut exp(0.0), &mut x, &settings).unwrap();
        assert_eq!(report.termination, Termination::CostConverged);
        assert!((x - libm::log(2.0)).abs() < 1e-3, "{x}");
        let mut y = 0.0;
        let refused = minimize(&mut exp(1e-2), &mut y, &settings).unwrap();
        assert_eq!(refused.termination, Termination::CostConverged);
        assert!((y - libm::log(2.0)).abs() < 1e-3, "{y}");
    }

    #[test]
    fn stops_without_progress_past_the_lambda_cap_and_after_max_iterations() {
        let capped = Settings { max_lambda: 1e-3, ..Settings::MARQUARDT };
        let report = minimize(&mut exp(1.0), &mut 0.0, &capped).unwrap();
        assert_eq!(report.termination, Termination::NoProgress);
        let one = Settings::MARQUARDT.with_max_iterations(1);
        let report = minimize(&mut exp(0.0), &mut 0.0, &one).unwrap();
        assert_eq!((report.iterations, report.termination), (1, Termination::MaxIterations));
    }

    #[test]
    fn damping_scales_the_diagonal_with_a_floor() {
        let mut a = SMatrix::<f64, 2, 2>::new(4.0, 1.0, 1.0, 0.0);
        damp(&mut a, 0.5);
        assert_eq!(a, SMatrix::<f64, 2, 2>::new(6.0, 1.0, 1.0, 0.5 * DIAG_FLOOR));
    }
}
