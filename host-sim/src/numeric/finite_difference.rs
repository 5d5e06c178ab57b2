//! The central-difference Jacobian of a [`Residuals`] problem: the one every fit in this crate
//! uses (the calibration's `full` fit, the diagnosis, the identifiability check).
//!
//! `J[:, k] = (r(p + h_k·e_k) − r(p − h_k·e_k)) / (2·h_k)` with the problem's own step `h_k`
//! ([`Residuals::fd_step`]). Error: truncation O(h²·r''') and rounding O(ε·|r| / h); the problems
//! choose h so both are far below the rank tolerance of [`super::svd::RANK_TOL`] (the five-bar
//! fit: 1e-6 mm and 1e-8 rad, about 1e-12 and 1e-10 relative; the diagnosis: 1e-2 in its µm /
//! µrad / ppm units). Cost: 2 residual evaluations per column, through the problem's
//! [`Residuals::neighbours`] (which may share the work the columns' parameters leave unchanged).
//!
//! Why not analytic: every model here is the closed-form five-bar plus small extensions; the
//! differences are accurate enough and keep each model a single forward function.

use super::{NumericError, Residuals};
use nalgebra::DMatrix;

/// `∂r/∂p` at `p` for the parameters `cols` (one column each, in that order).
pub fn jacobian<R: Residuals + ?Sized>(
    problem: &R,
    p: &[f64],
    cols: &[usize],
) -> Result<DMatrix<f64>, NumericError> {
    let n_params = problem.n_params();
    if let Some(&param) = cols.iter().find(|&&k| k >= n_params) {
        return Err(NumericError::NoSuchParameter { param, n_params });
    }
    let mut j: Option<DMatrix<f64>> = None;
    let mut q = p.to_vec();
    let mut near = problem.neighbours(p);
    for (col, &k) in cols.iter().enumerate() {
        let h = problem.fd_step(k);
        q[k] = p[k] + h;
        let hi = near(&q, k);
        q[k] = p[k] - h;
        let lo = near(&q, k);
        q[k] = p[k];
        let (Some(hi), Some(lo)) = (hi, lo) else {
            return Err(NumericError::JacobianOutsideDomain { param: k });
        };
        let m = j.get_or_insert_with(|| DMatrix::zeros(hi.len(), cols.len()));
        m.set_column(col, &((hi - lo) / (2.0 * h)));
    }
    match j {
        Some(j) => Ok(j),
        // No column asked for: an m × 0 matrix (m from the residuals at p).
        None => {
            let r = problem
                .residuals(p)
                .ok_or(NumericError::StartOutsideDomain)?;
            Ok(DMatrix::zeros(r.len(), 0))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DVector;

    /// r(p) = (p0², p0·p1, sin p1): J = [[2p0, 0], [p1, p0], [0, cos p1]].
    struct Quadratic;
    impl Residuals for Quadratic {
        fn n_params(&self) -> usize {
            2
        }
        fn residuals(&self, p: &[f64]) -> Option<DVector<f64>> {
            Some(DVector::from_vec(vec![
                p[0] * p[0],
                p[0] * p[1],
                p[1].sin(),
            ]))
        }
        fn fd_step(&self, _k: usize) -> f64 {
            1e-6
        }
    }

    #[test]
    fn matches_the_analytic_jacobian() {
        let p = [1.5, -0.7];
        let j = jacobian(&Quadratic, &p, &[0, 1]).unwrap();
        let want = [[3.0, 0.0], [-0.7, 1.5], [0.0, (-0.7f64).cos()]];
        for (r, row) in want.iter().enumerate() {
            for (c, w) in row.iter().enumerate() {
                assert!(
                    (j[(r, c)] - w).abs() < 1e-9,
                    "({r}, {c}): {} vs {w}",
                    j[(r, c)]
                );
            }
        }
        // Column selection and order follow `cols`; none asked for is an m × 0 matrix.
        let j1 = jacobian(&Quadratic, &p, &[1]).unwrap();
        assert_eq!(j1.column(0), j.column(1));
        assert_eq!(jacobian(&Quadratic, &p, &[]).unwrap().shape(), (3, 0));
        assert_eq!(
            jacobian(&Quadratic, &p, &[2]).unwrap_err(),
            NumericError::NoSuchParameter {
                param: 2,
                n_params: 2
            }
        );
    }
}
