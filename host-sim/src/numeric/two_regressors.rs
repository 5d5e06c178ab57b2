//! Least squares on two regressors, `y ≈ b·u + c·v`, by its 2×2 normal equations summed one
//! sample at a time: the import's plane through the points' z and the dynamics fit's search of
//! the cogging period (the sine and cosine of one period) both solve one. Each caller judges
//! near-collinear regressors against its own scale ([`TwoRegressors::det`]).

/// The sums of the normal equations of `y ≈ b·u + c·v`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TwoRegressors {
    /// Σu².
    pub uu: f64,
    /// Σuv.
    pub uv: f64,
    /// Σv².
    pub vv: f64,
    /// Σuy.
    pub uy: f64,
    /// Σvy.
    pub vy: f64,
}

impl TwoRegressors {
    /// Adds the sample `(u, v, y)`.
    pub fn add(&mut self, u: f64, v: f64, y: f64) {
        self.uu += u * u;
        self.uv += u * v;
        self.vv += v * v;
        self.uy += u * y;
        self.vy += v * y;
    }

    /// The determinant of the normal matrix: near zero, the regressors are near collinear.
    pub fn det(&self) -> f64 {
        self.uu * self.vv - self.uv * self.uv
    }

    /// The least-squares `(b, c)`, for a determinant the caller judged far enough from zero.
    pub fn solve(&self) -> (f64, f64) {
        let det = self.det();
        (
            (self.uy * self.vv - self.vy * self.uv) / det,
            (self.vy * self.uu - self.uy * self.uv) / det,
        )
    }

    /// The sum of squares of `y` the fit explains (`yᵀX (XᵀX)⁻¹ Xᵀy`), for a determinant the
    /// caller judged far enough from zero.
    pub fn explained(&self) -> f64 {
        (self.vv * self.uy * self.uy - 2.0 * self.uv * self.uy * self.vy
            + self.uu * self.vy * self.vy)
            / self.det()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_an_exact_fit_and_explains_all_of_it() {
        let mut n = TwoRegressors::default();
        for (u, v) in [(1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (2.0, -1.0)] {
            n.add(u, v, 3.0 * u - 2.0 * v);
        }
        let (b, c) = n.solve();
        assert!(
            (b - 3.0).abs() < 1e-12 && (c + 2.0).abs() < 1e-12,
            "{b} {c}"
        );
        // y² summed: 9 + 4 + 1 + 64.
        assert!((n.explained() - 78.0).abs() < 1e-9, "{}", n.explained());
        let mut collinear = TwoRegressors::default();
        for u in [1.0, 2.0, 3.0] {
            collinear.add(u, 2.0 * u, u);
        }
        assert_eq!(collinear.det(), 0.0);
    }
}
