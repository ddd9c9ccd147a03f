//! Small dense linear algebra on fixed-size matrices (no heap): a Cholesky (LLᵀ)
//! factorisation with an explicit failure on matrices that are not positive definite,
//! solves and inverses from it, the nearest rotation to a 3×3 matrix, and the weighted
//! products of a measurement's Jacobian over the columns it touches.

use nalgebra::{SMatrix, SVector};

use crate::geometry::Mat3;

/// A symmetric matrix was not (numerically) positive definite; `pivot` is the first
/// row whose pivot was not positive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NotPositiveDefinite {
    pub pivot: usize,
}

impl core::fmt::Display for NotPositiveDefinite {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "matrix not positive definite at pivot {}", self.pivot)
    }
}

/// Relative size under which a pivot counts as zero (scaled by the largest diagonal).
const PIVOT_TOLERANCE: f64 = 1e-13;

/// The lower-triangular factor `L` of `A = L Lᵀ`.
#[derive(Clone, Copy, Debug)]
pub struct Cholesky<const N: usize> {
    l: SMatrix<f64, N, N>,
}

impl<const N: usize> Cholesky<N> {
    /// Factorises a symmetric matrix (only its lower triangle is read). Fails when a
    /// pivot is not positive, not finite, or below `1e-13 ×` the largest diagonal entry.
    pub fn new(a: &SMatrix<f64, N, N>) -> Result<Self, NotPositiveDefinite> {
        let max_diag = (0..N).map(|i| a[(i, i)].abs()).fold(0.0, f64::max);
        let floor = PIVOT_TOLERANCE * max_diag;
        let mut l = SMatrix::<f64, N, N>::zeros();
        for j in 0..N {
            let mut d = a[(j, j)];
            for k in 0..j {
                d -= l[(j, k)] * l[(j, k)];
            }
            if !d.is_finite() || d <= floor {
                return Err(NotPositiveDefinite { pivot: j });
            }
            let djj = libm::sqrt(d);
            l[(j, j)] = djj;
            for i in (j + 1)..N {
                let mut s = a[(i, j)];
                for k in 0..j {
                    s -= l[(i, k)] * l[(j, k)];
                }
                l[(i, j)] = s / djj;
            }
        }
        Ok(Cholesky { l })
    }

    /// The factor `L`.
    pub fn l(&self) -> &SMatrix<f64, N, N> {
        &self.l
    }

    /// `x` with `A x = b`.
    pub fn solve(&self, b: &SVector<f64, N>) -> SVector<f64, N> {
        let mut x = *b;
        self.solve_in_place(x.as_mut_slice());
        x
    }

    /// `X` with `A X = B`, column by column.
    pub fn solve_matrix<const M: usize>(&self, b: &SMatrix<f64, N, M>) -> SMatrix<f64, N, M> {
        let mut x = *b;
        for c in 0..M {
            let mut col = x.column(c).into_owned();
            self.solve_in_place(col.as_mut_slice());
            x.set_column(c, &col);
        }
        x
    }

    /// `A⁻¹`.
    pub fn inverse(&self) -> SMatrix<f64, N, N> {
        self.solve_matrix(&SMatrix::<f64, N, N>::identity())
    }

    /// Forward then backward substitution on one right-hand side.
    fn solve_in_place(&self, x: &mut [f64]) {
        for i in 0..N {
            let s: f64 = x[..i].iter().enumerate().map(|(k, xk)| self.l[(i, k)] * xk).sum();
            x[i] = (x[i] - s) / self.l[(i, i)];
        }
        for i in (0..N).rev() {
            let s: f64 =
                x[i + 1..].iter().enumerate().map(|(k, xk)| self.l[(i + 1 + k, i)] * xk).sum();
            x[i] = (x[i] - s) / self.l[(i, i)];
        }
    }
}

/// `A⁻¹` for a symmetric positive-definite `A`.
pub fn spd_inverse<const N: usize>(
    a: &SMatrix<f64, N, N>,
) -> Result<SMatrix<f64, N, N>, NotPositiveDefinite> {
    Ok(Cholesky::new(a)?.inverse())
}

/// The rotation nearest to `m` in the Frobenius norm (`U diag(1, 1, ±1) Vᵀ` from the
/// SVD, the sign making the determinant +1). `None` if the SVD does not converge.
pub fn nearest_rotation(m: &Mat3) -> Option<Mat3> {
    let svd = nalgebra::SVD::try_new(*m, true, true, f64::EPSILON, 200)?;
    let (u, v_t) = (svd.u?, svd.v_t?);
    let d = (u * v_t).determinant();
    let fix = Mat3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, d.signum()));
    Some(u * fix * v_t)
}

/// Largest eigenvalue of a symmetric 3×3 matrix (for "worst axis" standard deviations).
pub fn max_eigenvalue3(m: &Mat3) -> f64 {
    let e = nalgebra::SymmetricEigen::new(*m);
    e.eigenvalues.iter().copied().fold(f64::NEG_INFINITY, f64::max)
}

/// The columns of a measurement's 2-row Jacobian `js` that are not zero: a rig's measurement
/// touches a few of its shared parameters (one camera's intrinsics, a mounting or two, its
/// frame: 27 of the joint solve's 84), and only those need accumulating.
pub struct Touched<const N: usize> {
    columns: [usize; N],
    count: usize,
}

impl<const N: usize> Touched<N> {
    pub fn of(js: &SMatrix<f64, 2, N>) -> Self {
        let mut columns = [0usize; N];
        let mut count = 0;
        for i in (0..N).filter(|&i| js[(0, i)] != 0.0 || js[(1, i)] != 0.0) {
            columns[count] = i;
            count += 1;
        }
        Touched { columns, count }
    }

    pub fn columns(&self) -> &[usize] {
        &self.columns[..self.count]
    }

    /// `v += weight · jsᵀ js` and `w += weight · jsᵀ jb`, over the touched columns only.
    pub fn add_products(
        &self,
        (v, w): (&mut SMatrix<f64, N, N>, &mut SMatrix<f64, N, 6>),
        weight: f64,
        js: &SMatrix<f64, 2, N>,
        jb: &SMatrix<f64, 2, 6>,
    ) {
        for &a in self.columns() {
            let (a0, a1) = (weight * js[(0, a)], weight * js[(1, a)]);
            for &b in self.columns() {
                v[(a, b)] += a0 * js[(0, b)] + a1 * js[(1, b)];
            }
            for c in 0..6 {
                w[(a, c)] += a0 * jb[(0, c)] + a1 * jb[(1, c)];
            }
        }
    }
}
