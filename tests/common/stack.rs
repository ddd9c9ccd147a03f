//! Dense stacking of a problem made of shared unknowns and 6-DoF blocks (`solve::rig`,
//! the surveyed room's pair among them): every whitened residual, measurements then priors, as one vector, and
//! its analytic Jacobian over `[shared | block 0 | block 1 | …]`, one dense row per
//! residual, for checks against central differences.

use nalgebra::{SMatrix, SVector};

/// Residuals and Jacobian rows, stacked as a problem's callbacks hand them over.
#[derive(Debug)]
pub struct Stacker {
    shared: usize,
    columns: usize,
    residuals: Vec<f64>,
    jacobian: Vec<Vec<f64>>,
}

impl Stacker {
    /// `shared` unknowns followed by `blocks` blocks of six.
    pub fn new(shared: usize, blocks: usize) -> Self {
        Stacker {
            shared,
            columns: shared + 6 * blocks,
            residuals: Vec::new(),
            jacobian: Vec::new(),
        }
    }

    /// A measurement's two rows: `js` over the shared unknowns, `jb` over block `k`.
    pub fn measurement<const S: usize>(
        &mut self,
        k: usize,
        r: &SVector<f64, 2>,
        js: &SMatrix<f64, 2, S>,
        jb: &SMatrix<f64, 2, 6>,
    ) {
        for row in 0..2 {
            let line = self.row(r[row]);
            for c in 0..S {
                line[c] = js[(row, c)];
            }
            self.block(k, jb.row(row).iter().copied());
        }
    }

    /// A block prior's six rows, over block `k` alone.
    pub fn prior(&mut self, k: usize, r: &SVector<f64, 6>, jp: &SMatrix<f64, 6, 6>) {
        for row in 0..6 {
            self.row(r[row]);
            self.block(k, jp.row(row).iter().copied());
        }
    }

    /// The residual vector and the Jacobian's rows.
    pub fn finish(self) -> (Vec<f64>, Vec<Vec<f64>>) {
        (self.residuals, self.jacobian)
    }

    /// A new row with residual `r`, all zeros in the Jacobian.
    fn row(&mut self, r: f64) -> &mut Vec<f64> {
        self.residuals.push(r);
        self.jacobian.push(vec![0.0; self.columns]);
        self.jacobian.last_mut().unwrap()
    }

    /// Block `k`'s six columns of the last row.
    fn block(&mut self, k: usize, values: impl Iterator<Item = f64>) {
        let at = self.shared + 6 * k;
        let line = self.jacobian.last_mut().unwrap();
        for (c, v) in values.enumerate() {
            line[at + c] = v;
        }
    }
}
