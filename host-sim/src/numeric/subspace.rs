//! Column spaces: an orthonormal basis, the projection onto a complement, and the smallest
//! principal angle between two spaces. What the diagnosis asks of two effects ("can some
//! combination of one act like the other?") and what its six-bar modes are made orthogonal to.
//!
//! Basis from the SVD, directions kept above 1e-9 of the largest singular value: a column
//! dependent on the others to rounding adds no direction. Cost: one thin SVD of the matrix.

use nalgebra::DMatrix;

/// An orthonormal basis (columns) of the column space of `m` (SVD, relative tolerance 1e-9);
/// no columns for an empty or zero matrix.
pub fn orthonormal_basis(m: &DMatrix<f64>) -> DMatrix<f64> {
    if m.ncols() == 0 {
        return m.clone();
    }
    let svd = m.clone().svd(true, false);
    let Some(u) = svd.u else {
        return DMatrix::zeros(m.nrows(), 0);
    };
    let smax = svd.singular_values.max();
    let keep: Vec<usize> = (0..svd.singular_values.len())
        .filter(|&i| svd.singular_values[i] > 1e-9 * smax.max(1e-300))
        .collect();
    DMatrix::from_fn(m.nrows(), keep.len(), |r, c| u[(r, keep[c])])
}

/// Projects the columns of `m` onto the orthogonal complement of the orthonormal basis `q`.
pub fn project_out(m: &DMatrix<f64>, q: &DMatrix<f64>) -> DMatrix<f64> {
    if q.ncols() == 0 {
        return m.clone();
    }
    m - q * (q.transpose() * m)
}

/// Cosine of the smallest principal angle between the column spaces of `a` and `b` (0 when
/// either is empty).
pub fn max_cos(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
    let (qa, qb) = (orthonormal_basis(a), orthonormal_basis(b));
    if qa.ncols() == 0 || qb.ncols() == 0 {
        return 0.0;
    }
    (qa.transpose() * qb).singular_values().max().min(1.0)
}
