//! The survey's joint covariance (`survey.covariance`) as the modes the surveyed
//! calibration moves the room by ([`crate::solve::room_modes`]).
//!
//! The covariance `C` (file order: every board's `[δω δt]`, every plane's `[δω δd]`) is
//! split into its eigenvectors, `C = Σ σᵢ² vᵢ vᵢᵀ`. Its null directions (the room's frame,
//! six; a plane's turn about its own normal, one each) are no modes. At most
//! [`MAX_MODES`] are kept, the largest: a room of 7 boards and 5 planes has 51, and a
//! dropped mode is one of the combinations the survey knows best, held exact. Each
//! problem block then gets its rows of the modes, in the solver's perturbation of its
//! block → room pose: a board's are the file's; a plane's turn is its frame's rotation and
//! its offset change `δd` a shift `n δd` of its frame's origin.

use nalgebra::{DMatrix, SVector};

use crate::solve::room_modes::{ModeBasis, MAX_MODES};
use crate::target::{SurveySpec, COVARIANCE_PER_BOARD, COVARIANCE_PER_PLANE};

/// What one block of the room problem is in the survey.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum SurveyEntry {
    Board(usize),
    Plane(usize),
}

/// The survey's modes: σ per mode and the modes as columns over the file's parameters.
#[derive(Clone, Debug)]
pub(super) struct SurveyModes {
    pub sigma: SVector<f64, MAX_MODES>,
    vectors: DMatrix<f64>,
}

/// Eigenvalues below this fraction of the largest are the covariance's null directions
/// (rounding leaves them 10⁻¹¹ of the largest; the smallest real one of a 16-visit survey
/// is 10⁻⁶ of it).
const NULL_FRACTION: f64 = 1e-9;

impl SurveyModes {
    /// The modes of `survey.covariance`; `None` without one (or with nothing in it).
    pub fn of(survey: &SurveySpec) -> Option<SurveyModes> {
        let rows = &survey.covariance;
        let n = rows.len();
        if n == 0 || n != survey.covariance_size() {
            return None;
        }
        let full = DMatrix::from_fn(n, n, |i, j| if j <= i { rows[i][j] } else { rows[j][i] });
        let eigen = nalgebra::SymmetricEigen::new(full);
        let largest = eigen.eigenvalues.max();
        let mut order: Vec<usize> = (0..n)
            .filter(|&i| eigen.eigenvalues[i] > NULL_FRACTION * largest && largest > 0.0)
            .collect();
        order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
        if order.len() > MAX_MODES {
            tracing::debug!(
                modes = order.len(),
                kept = MAX_MODES,
                "survey modes beyond capacity held exact"
            );
        }
        order.truncate(MAX_MODES);
        if order.is_empty() {
            return None;
        }
        let mut sigma = SVector::<f64, MAX_MODES>::zeros();
        let mut vectors = DMatrix::zeros(n, order.len());
        for (m, &i) in order.iter().enumerate() {
            sigma[m] = eigen.eigenvalues[i].sqrt();
            vectors.set_column(m, &eigen.eigenvectors.column(i));
        }
        Some(SurveyModes { sigma, vectors })
    }

    /// Per problem block (`entries`, in the problem's order), its perturbation per unit
    /// amplitude of every mode.
    pub fn basis(&self, survey: &SurveySpec, entries: &[SurveyEntry]) -> Vec<ModeBasis> {
        let planes_at = COVARIANCE_PER_BOARD * survey.boards.len();
        entries
            .iter()
            .map(|entry| {
                let mut basis = ModeBasis::zeros();
                for m in 0..self.vectors.ncols() {
                    match *entry {
                        SurveyEntry::Board(b) => {
                            for r in 0..6 {
                                basis[(r, m)] = self.vectors[(COVARIANCE_PER_BOARD * b + r, m)];
                            }
                        }
                        SurveyEntry::Plane(p) => {
                            let at = planes_at + COVARIANCE_PER_PLANE * p;
                            let normal = survey.planes[p].normal;
                            for r in 0..3 {
                                basis[(r, m)] = self.vectors[(at + r, m)];
                                basis[(3 + r, m)] = normal[r] * self.vectors[(at + 3, m)];
                            }
                        }
                    }
                }
                basis
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A one-board, one-plane survey with this covariance.
    fn survey(covariance: Vec<Vec<f64>>) -> SurveySpec {
        let text = r#"
            visits = 3
            frame = "test"
            [[boards]]
            rotation = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
            translation = [0, 0, 4]
            sigma_m = 0.001
            sigma_deg = 0.01
            [[planes]]
            name = "floor"
            normal = [0, -1, 0]
            offset = 1.5
            sigma_m = 0.002
            sigma_deg = 0.01
        "#;
        let mut s: SurveySpec = toml::from_str(text).unwrap();
        s.covariance = covariance;
        s
    }

    fn lower(full: &DMatrix<f64>) -> Vec<Vec<f64>> {
        (0..full.nrows()).map(|i| (0..=i).map(|j| full[(i, j)]).collect()).collect()
    }

    #[test]
    fn the_modes_give_back_the_covariance_in_each_blocks_perturbation() {
        // A correlated covariance over [board δω δt | plane δω δd] with no turn about the
        // plane's normal (y): build it as A Aᵀ from columns that leave row 7 (δω_y) zero.
        let a = DMatrix::<f64>::from_fn(10, 6, |i, j| {
            if i == 7 {
                0.0
            } else {
                1e-4 * (((i * 31 + j * 17 + i * j * 7) % 23) as f64 - 11.0)
            }
        });
        let c = &a * a.transpose();
        let s = survey(lower(&c));
        let modes = SurveyModes::of(&s).unwrap();
        assert_eq!((0..MAX_MODES).filter(|&i| modes.sigma[i] > 0.0).count(), 6, "rank 6");
        let basis = modes.basis(&s, &[SurveyEntry::Board(0), SurveyEntry::Plane(0)]);
        let sigma2 = DMatrix::from_diagonal(&nalgebra::DVector::from_iterator(
            MAX_MODES,
            modes.sigma.iter().map(|x| x * x),
        ));
        let stack = |k: usize| DMatrix::from_fn(6, MAX_MODES, |r, m| basis[k][(r, m)]);
        // Board: its 6×6 block of C.
        let board = stack(0) * &sigma2 * stack(0).transpose();
        assert!((board - c.view((0, 0), (6, 6))).norm() < 1e-12 * c.norm());
        // Plane: [δω; n δd] of its 4×4 block, and its cross terms with the board.
        let mut t = DMatrix::<f64>::zeros(6, 4);
        for r in 0..3 {
            t[(r, r)] = 1.0;
        }
        t[(4, 3)] = -1.0; // n = (0, −1, 0)
        let plane = stack(1) * &sigma2 * stack(1).transpose();
        let want = &t * c.view((6, 6), (4, 4)) * t.transpose();
        assert!((plane - want).norm() < 1e-12 * c.norm());
        let cross = stack(0) * &sigma2 * stack(1).transpose();
        let want = c.view((0, 6), (6, 4)) * t.transpose();
        assert!((cross - want).norm() < 1e-12 * c.norm());
    }

    #[test]
    fn no_covariance_no_modes() {
        assert!(SurveyModes::of(&survey(Vec::new())).is_none());
        assert!(SurveyModes::of(&survey(vec![vec![0.0]; 1])).is_none(), "wrong size");
    }
}
