//! The column-scaled SVD of a Jacobian: which parameter combinations the data identify, the
//! rank and condition, and the pseudo-inverse of `JᵀJ` (the unscaled covariance).
//!
//! Why scaled: the columns of an identification Jacobian carry different units (mm, rad, µm,
//! ppm); the singular values of `J` itself would compare millimetres with radians. Dividing every
//! column by its norm (`J·D⁻¹`, D = column norms) makes them unit-free, so "relative singular
//! value below [`RANK_TOL`]" means the same for every problem: some combination of parameters
//! moves the residuals by less than 1e-7 of the best-determined one, i.e. below the
//! finite-difference noise (~1e-10) only by a safe margin, and is not identified.
//!
//! Covariance: `(JᵀJ)⁺ = D⁻¹·V·Σ⁻²·Vᵀ·D⁻¹` over the singular values above [`RANK_TOL`]
//! (relative). Computed from the SVD of the scaled `J` rather than by inverting `JᵀJ`, which
//! squares the condition number; on a well-conditioned fit the two agree to rounding. Directions
//! below the tolerance get no variance (a pseudo-inverse): the caller decides what a deficient
//! rank means (the `full` fit refuses it, the diagnosis reports the effect as not identifiable).
//! A zero column (a parameter with no effect) is a singular value 0 and its own null direction.
//!
//! Cost: one thin SVD of an m × k matrix, O(m·k²).

use nalgebra::DMatrix;

/// Relative singular value (to the largest) below which a direction counts as not identified.
pub const RANK_TOL: f64 = 1e-7;

/// The SVD of a column-normalised matrix, singular values in descending order.
#[derive(Clone, Debug)]
pub struct ScaledSvd {
    /// Singular values of `J·D⁻¹`, largest first (each ≤ √k).
    pub singular_values: Vec<f64>,
    /// Right singular vectors (rows, in the order of `singular_values`), in scaled coordinates.
    v_rows: Vec<Vec<f64>>,
    /// Column norms `D` of the matrix given.
    column_norms: Vec<f64>,
}

impl ScaledSvd {
    /// Decomposes `J·D⁻¹`; zero columns stay zero.
    pub fn new(j: &DMatrix<f64>) -> Self {
        let k = j.ncols();
        let column_norms: Vec<f64> = j.column_iter().map(|c| c.norm()).collect();
        if k == 0 {
            return ScaledSvd {
                singular_values: Vec::new(),
                v_rows: Vec::new(),
                column_norms,
            };
        }
        // Fewer rows than columns: pad with zero rows (JᵀJ is unchanged) so the SVD gives every
        // right singular vector, the null directions included.
        let mut s = DMatrix::zeros(j.nrows().max(k), k);
        s.rows_mut(0, j.nrows()).copy_from(j);
        for (mut c, &n) in s.column_iter_mut().zip(&column_norms) {
            if n > 0.0 {
                c /= n;
            }
        }
        let svd = s.svd(false, true);
        let v_t = svd.v_t.expect("V was requested");
        let mut pairs: Vec<(f64, Vec<f64>)> = (0..svd.singular_values.len())
            .map(|i| (svd.singular_values[i], v_t.row(i).iter().copied().collect()))
            .collect();
        pairs.sort_by(|a, b| b.0.total_cmp(&a.0));
        // A zero column is exactly a null direction: name it as such rather than leave the
        // choice among equal (zero) singular values to the SVD.
        if let Some(c) = column_norms.iter().position(|&n| n == 0.0) {
            let last = pairs.len() - 1;
            pairs[last] = (
                0.0,
                (0..k).map(|i| if i == c { 1.0 } else { 0.0 }).collect(),
            );
        }
        let (singular_values, v_rows) = pairs.into_iter().unzip();
        ScaledSvd {
            singular_values,
            v_rows,
            column_norms,
        }
    }

    /// Singular values relative to the largest (1 for the first), descending.
    pub fn relative(&self) -> Vec<f64> {
        let top = self
            .singular_values
            .first()
            .copied()
            .unwrap_or(0.0)
            .max(f64::MIN_POSITIVE);
        self.singular_values.iter().map(|s| s / top).collect()
    }

    /// The smallest singular value of the column-normalised matrix (∞ without columns).
    pub fn min(&self) -> f64 {
        self.singular_values
            .last()
            .copied()
            .unwrap_or(f64::INFINITY)
    }

    /// The smallest relative singular value (1 without columns).
    pub fn min_relative(&self) -> f64 {
        self.relative().last().copied().unwrap_or(1.0)
    }

    /// The right singular vector of the smallest singular value, in scaled coordinates (one
    /// weight per column: the combination that moves the residuals least).
    pub fn smallest_direction(&self) -> &[f64] {
        self.v_rows.last().map_or(&[], Vec::as_slice)
    }

    /// Number of relative singular values above `rel_tol`.
    pub fn rank(&self, rel_tol: f64) -> usize {
        self.relative().iter().filter(|&&s| s > rel_tol).count()
    }

    /// `(JᵀJ)⁺` in the original units, directions with a relative singular value at or below
    /// `rel_tol` left out (see the module doc).
    pub fn normal_pseudo_inverse(&self, rel_tol: f64) -> DMatrix<f64> {
        let k = self.column_norms.len();
        let rel = self.relative();
        let mut c = DMatrix::zeros(k, k);
        for ((s, r), v) in self.singular_values.iter().zip(&rel).zip(&self.v_rows) {
            if !(*r > rel_tol) || !(*s > 0.0) {
                continue;
            }
            let w = 1.0 / (s * s);
            for a in 0..k {
                for b in 0..k {
                    c[(a, b)] += w * v[a] * v[b];
                }
            }
        }
        for a in 0..k {
            for b in 0..k {
                let d = self.column_norms[a] * self.column_norms[b];
                c[(a, b)] = if d > 0.0 { c[(a, b)] / d } else { 0.0 };
            }
        }
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaling_makes_units_irrelevant_and_the_inverse_matches() {
        // Two columns in very different units, not collinear.
        let j = DMatrix::from_row_slice(3, 2, &[1.0, 2e3, 2.0, -1e3, 0.5, 4e3]);
        let s = ScaledSvd::new(&j);
        let mut k = j.clone();
        k.column_mut(1).scale_mut(1e-6);
        let t = ScaledSvd::new(&k);
        for (a, b) in s.singular_values.iter().zip(&t.singular_values) {
            assert!((a - b).abs() < 1e-12);
        }
        let inv = (j.transpose() * &j).try_inverse().unwrap();
        let pinv = s.normal_pseudo_inverse(RANK_TOL);
        assert!(
            (&inv - &pinv).abs().max() < 1e-9 * pinv.abs().max(),
            "pinv differs from the inverse"
        );
        assert_eq!(s.rank(RANK_TOL), 2);
    }

    #[test]
    fn collinear_and_zero_columns_are_null_directions() {
        // Column 2 = 3 × column 0 (in other units): the combination (3, 0, −1)/√10 scaled.
        let j = DMatrix::from_row_slice(3, 3, &[1.0, 0.0, 3.0, 2.0, 1.0, 6.0, -1.0, 1.0, -3.0]);
        let s = ScaledSvd::new(&j);
        assert_eq!(s.rank(RANK_TOL), 2);
        let v = s.smallest_direction();
        assert!(
            (v[0].abs() - v[2].abs()).abs() < 1e-9 && v[1].abs() < 1e-9,
            "{v:?}"
        );
        // No variance along the null direction: the pseudo-inverse stays finite.
        assert!(s
            .normal_pseudo_inverse(RANK_TOL)
            .iter()
            .all(|x| x.is_finite()));
        let z = DMatrix::from_row_slice(2, 2, &[1.0, 0.0, 2.0, 0.0]);
        let s = ScaledSvd::new(&z);
        assert_eq!(
            (s.rank(RANK_TOL), s.smallest_direction()),
            (1, &[0.0, 1.0][..])
        );
        assert_eq!(ScaledSvd::new(&DMatrix::zeros(4, 0)).min(), f64::INFINITY);
    }
}
