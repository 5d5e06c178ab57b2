//! A penalised least-squares smoother of values on a rectangular lattice (a 2-D Whittaker
//! smoother), with its smoothing chosen by generalised cross-validation: the noise-aware
//! correction grid smooths the measured node errors with it (`calib::grid`).
//!
//! # Method
//! For values `y` on an `nx × ny` lattice (x fastest), the smooth field `f` minimises
//!
//! ```text
//! ‖y − f‖² + λ·(‖D_x f‖² + ‖D_y f‖²)
//! ```
//!
//! where `D_x`, `D_y` take second differences along x and along y (Eilers' 2-D Whittaker
//! smoother, the discrete thin plate without its cross term). The penalty vanishes on
//! `a + b·x + c·y + d·x·y`: an error field of that form is kept whatever λ, so a large λ never
//! biases a bilinear field, only the curvature is damped. The penalty is
//! `P = I ⊗ G_x + G_y ⊗ I` with `G = DᵀD` per axis, so with the eigen-decompositions
//! `G_x = U_x M U_xᵀ`, `G_y = U_y N U_yᵀ` the hat matrix `H(λ) = (I + λP)⁻¹` is diagonal in the
//! basis `U_x ⊗ U_y` with eigenvalues `1 / (1 + λ(μ_i + ν_j))`. Hence, exactly and for every λ
//! at once:
//! * the fit `f = U_x (Ỹ ∘ g) U_yᵀ` with `Ỹ = U_xᵀ Y U_y`, `g_ij = 1 / (1 + λ(μ_i + ν_j))`;
//! * the residual `‖y − f‖² = Σ ỹ_ij² (1 − g_ij)²`, the degrees of freedom `tr H = Σ g_ij`
//!   and the noise gain `tr H² = Σ g_ij²`;
//! * the generalised cross-validation score (Craven and Wahba 1979)
//!   `V(λ) = (‖y − f‖² / n) / (1 − tr H / n)²`, minimised over λ on a logarithmic scan
//!   ([`LAMBDA_RANGE`], 16 points per decade) refined by golden-section search.
//!
//! Several components (the x and y errors of a node) share one λ: their noise has one σ (an
//! instrument's σ per axis), so their scores add.
//!
//! # Why GCV
//! It needs no noise level: it works with one reading per node, the normal measurement. It
//! estimates the prediction error `‖f_true − f‖²/n + σ²` from the data alone and is, for
//! linear smoothers, asymptotically optimal. [`Smoothed::noise_sigma`] is the classical
//! estimate `σ̂² = ‖y − f‖² / (n − tr H)` it implies. Known weakness: noise that is correlated
//! between neighbouring nodes looks like signal to it (then it smooths too little, never too
//! much); the grid's report compares σ̂ with the scatter of repeated readings when there are any.
//!
//! Cost: two symmetric eigen-decompositions (`O(nx³ + ny³)`), then per component
//! `O(nx·ny·(nx + ny))` for each transform and `O(nx·ny)` per λ tried (about 300). A 21 × 31
//! lattice takes well under a millisecond; 1024 × 1024 a few seconds.

use nalgebra::{DMatrix, SymmetricEigen};

/// The λ range scanned (`log10`), in units of the lattice step (λ ~ the fourth power of the
/// smoothing length in nodes): from no smoothing at all to only the bilinear part.
pub const LAMBDA_RANGE: [f64; 2] = [-6.0, 12.0];
const SCAN_PER_DECADE: f64 = 16.0;

/// `DᵀD` of the second-difference operator on `n` points (zero for `n < 3`).
fn second_difference_gram(n: usize) -> DMatrix<f64> {
    let mut g = DMatrix::zeros(n, n);
    for r in 0..n.saturating_sub(2) {
        let d = [(r, 1.0), (r + 1, -2.0), (r + 2, 1.0)];
        for &(a, va) in &d {
            for &(b, vb) in &d {
                g[(a, b)] += va * vb;
            }
        }
    }
    g
}

/// The smoother of one lattice shape.
#[derive(Clone, Debug)]
pub struct LatticeSmoother {
    nx: usize,
    ny: usize,
    /// Eigenvectors (columns) of `G_x` and `G_y`.
    ux: DMatrix<f64>,
    uy: DMatrix<f64>,
    /// `μ_i + ν_j`, x index fastest.
    penalty: Vec<f64>,
}

/// One field's coefficients in the smoother's eigenbasis.
#[derive(Clone, Debug)]
pub struct Coefficients(Vec<f64>);

/// A smoothing chosen and what it implies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Smoothed {
    pub lambda: f64,
    /// `tr H`: the effective number of parameters per component (n = no smoothing, 4 = only a
    /// bilinear field).
    pub dof: f64,
    /// `tr H²`: how many "nodes' worth" of white noise stay in the smoothed field per
    /// component (its variance is `σ²·tr H² / n` on average).
    pub noise_dof: f64,
    /// `Σ ‖y − f‖²` over the components.
    pub rss: f64,
    /// The GCV score, per residual.
    pub gcv: f64,
    /// Nodes.
    pub n: usize,
    /// Components smoothed together.
    pub components: usize,
}

impl Smoothed {
    /// The noise σ per component this smoothing implies, `sqrt(RSS / (c·(n − tr H)))`; `None`
    /// when the smoother interpolates (no residual degrees of freedom).
    pub fn noise_sigma(&self) -> Option<f64> {
        let dof = self.components as f64 * (self.n as f64 - self.dof);
        (dof > 0.5).then(|| (self.rss / dof).sqrt())
    }
}

impl LatticeSmoother {
    /// The smoother of an `nx × ny` lattice (each ≥ 1).
    pub fn new(nx: usize, ny: usize) -> Self {
        let eig = |n: usize| {
            let e = SymmetricEigen::new(second_difference_gram(n));
            // The penalty's null space (constant and linear along the axis) has eigenvalue 0
            // exactly; rounding gives ±1e-15, which a λ of 1e12 would turn into damping.
            let top = e.eigenvalues.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let clean = e
                .eigenvalues
                .iter()
                .map(|&v| if v > 1e-10 * top { v } else { 0.0 })
                .collect::<Vec<f64>>();
            (e.eigenvectors, clean)
        };
        let (ux, mu) = eig(nx);
        let (uy, nu) = eig(ny);
        let penalty = (0..nx * ny).map(|k| mu[k % nx] + nu[k / nx]).collect();
        LatticeSmoother {
            nx,
            ny,
            ux,
            uy,
            penalty,
        }
    }

    /// Nodes of the lattice.
    pub fn len(&self) -> usize {
        self.nx * self.ny
    }

    /// True for an empty lattice.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The coefficients of `field` (x fastest, `nx·ny` values) in the eigenbasis.
    pub fn coefficients(&self, field: &[f64]) -> Coefficients {
        assert_eq!(field.len(), self.len(), "a field has one value per node");
        let y = DMatrix::from_column_slice(self.nx, self.ny, field);
        let c = self.ux.transpose() * y * &self.uy;
        Coefficients(c.as_slice().to_vec())
    }

    /// The gains `g = 1 / (1 + λ·penalty)` per basis function (the eigenvalues of `H(λ)`, in
    /// the order of [`Coefficients`]).
    pub fn gains(&self, lambda: f64) -> impl Iterator<Item = f64> + '_ {
        self.penalty.iter().map(move |p| 1.0 / (1.0 + lambda * p))
    }

    /// `Σ g(λ)^power·a·b` over the basis: `aᵀ H^power b` for two fields' coefficients.
    pub fn quadratic(&self, a: &Coefficients, b: &Coefficients, lambda: f64, power: i32) -> f64 {
        a.0.iter()
            .zip(&b.0)
            .zip(self.gains(lambda))
            .map(|((x, y), g)| g.powi(power) * x * y)
            .sum()
    }

    /// −2 log of the restricted likelihood of `fields` at λ, σ² profiled out, up to a
    /// constant: the smoother read as a Gaussian prior (precision `λ·P/σ²` on the field, the
    /// bilinear null space free), so each coefficient outside the null space is
    /// `N(0, σ²·(1 + 1/(λ·pⱼ)))`. Minimised over λ it is REML's choice of the smoothing, which
    /// smooths more than GCV where the data are mostly noise.
    pub fn restricted_deviance(&self, fields: &[&Coefficients], lambda: f64) -> f64 {
        let floor = 1e-9 * self.penalty.iter().fold(0.0f64, |m, p| m.max(*p));
        let (mut quad, mut log_det, mut count) = (0.0, 0.0, 0usize);
        for c in fields {
            for (y, &p) in c.0.iter().zip(&self.penalty) {
                if p > floor {
                    let inflation = 1.0 + 1.0 / (lambda * p);
                    quad += y * y / inflation;
                    log_det += inflation.ln();
                    count += 1;
                }
            }
        }
        let n = count.max(1) as f64;
        n * (quad / n).max(f64::MIN_POSITIVE).ln() + log_det
    }

    /// `‖(I − H(λ))·y‖²` of a field from its coefficients.
    pub fn residual_sq(&self, c: &Coefficients, lambda: f64) -> f64 {
        c.0.iter()
            .zip(self.gains(lambda))
            .map(|(y, g)| (y * (1.0 - g)).powi(2))
            .sum()
    }

    /// The λ in [`LAMBDA_RANGE`] minimising `score(λ)`: a logarithmic scan, 16 points per
    /// decade, refined by golden-section search between the best point's neighbours.
    pub fn minimise(&self, score: impl Fn(f64) -> f64) -> f64 {
        minimise_log10(LAMBDA_RANGE, SCAN_PER_DECADE, score)
    }

    /// The figures of smoothing `fields` with `lambda`.
    pub fn evaluate(&self, fields: &[Coefficients], lambda: f64) -> Smoothed {
        let (mut dof, mut noise_dof) = (0.0, 0.0);
        for g in self.gains(lambda) {
            dof += g;
            noise_dof += g * g;
        }
        let rss: f64 = fields.iter().map(|c| self.residual_sq(c, lambda)).sum();
        let n = self.len();
        let denom = (1.0 - dof / n as f64).powi(2);
        let gcv = if denom > 0.0 {
            rss / (fields.len() * n) as f64 / denom
        } else {
            f64::INFINITY
        };
        Smoothed {
            lambda,
            dof,
            noise_dof,
            rss,
            gcv,
            n,
            components: fields.len(),
        }
    }

    /// The λ minimising the GCV score of `fields` together (see the module doc).
    pub fn choose_by_gcv(&self, fields: &[Coefficients]) -> Smoothed {
        let lambda = self.minimise(|l| self.evaluate(fields, l).gcv);
        self.evaluate(fields, lambda)
    }

    /// The smoothed field of `coeffs` with `lambda` (x fastest).
    pub fn apply(&self, coeffs: &Coefficients, lambda: f64) -> Vec<f64> {
        let scaled: Vec<f64> = coeffs
            .0
            .iter()
            .zip(self.gains(lambda))
            .map(|(c, g)| c * g)
            .collect();
        let c = DMatrix::from_column_slice(self.nx, self.ny, &scaled);
        let f = &self.ux * c * self.uy.transpose();
        f.as_slice().to_vec()
    }
}

/// The x in `[10^lo, 10^hi]` (`range = [lo, hi]`) minimising `score(x)`: a logarithmic scan,
/// `per_decade` points per decade, refined by golden-section search about the best scanned
/// point. A smoothing criterion (GCV, a marginal likelihood) can have several local minima and
/// flat stretches; the scan finds the basin, the refinement its bottom. Cost: about
/// `(hi − lo)·per_decade + 80` evaluations.
pub fn minimise_log10(range: [f64; 2], per_decade: f64, score: impl Fn(f64) -> f64) -> f64 {
    let [lo, hi] = range;
    let steps = (((hi - lo) * per_decade) as usize).max(1);
    let at = |l: f64| score(10f64.powf(l));
    let mut best = (lo, at(lo));
    for k in 1..=steps {
        let l = lo + (hi - lo) * k as f64 / steps as f64;
        let v = at(l);
        if v < best.1 {
            best = (l, v);
        }
    }
    let h = (hi - lo) / steps as f64;
    let (mut a, mut b) = ((best.0 - h).max(lo), (best.0 + h).min(hi));
    let r = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..40 {
        let (c, d) = (b - r * (b - a), a + r * (b - a));
        if at(c) < at(d) {
            b = d;
        } else {
            a = c;
        }
    }
    let m = 0.5 * (a + b);
    10f64.powf(if at(m) < best.1 { m } else { best.0 })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// The closed form equals solving `(I + λP) f = y` directly.
    #[test]
    fn matches_the_direct_solution() {
        let (nx, ny) = (5, 4);
        let y: Vec<f64> = (0..nx * ny)
            .map(|k| ((k * 7919) % 13) as f64 - 6.0)
            .collect();
        let s = LatticeSmoother::new(nx, ny);
        let lambda = 0.7;
        let fast = s.apply(&s.coefficients(&y), lambda);
        let (gx, gy) = (second_difference_gram(nx), second_difference_gram(ny));
        let p = DMatrix::identity(ny, ny).kronecker(&gx) + gy.kronecker(&DMatrix::identity(nx, nx));
        let a = DMatrix::identity(nx * ny, nx * ny) + p * lambda;
        let direct = a
            .clone()
            .lu()
            .solve(&nalgebra::DVector::from_column_slice(&y))
            .unwrap();
        for (f, d) in fast.iter().zip(direct.iter()) {
            assert!((f - d).abs() < 1e-10, "{f} vs {d}");
        }
        let h = a.try_inverse().unwrap();
        let e = s.evaluate(&[s.coefficients(&y)], lambda);
        assert!((e.dof - h.trace()).abs() < 1e-9 && (e.noise_dof - (&h * &h).trace()).abs() < 1e-9);
    }

    /// A bilinear field is kept exactly by any λ; noise on a smooth field is mostly removed and
    /// the implied σ is the noise's.
    #[test]
    fn keeps_bilinear_fields_and_removes_noise() {
        let (nx, ny) = (21, 31);
        let s = LatticeSmoother::new(nx, ny);
        let bilinear: Vec<f64> = (0..nx * ny)
            .map(|k| {
                3.0 + 0.5 * (k % nx) as f64 - 0.2 * (k / nx) as f64
                    + 0.01 * ((k % nx) * (k / nx)) as f64
            })
            .collect();
        let f = s.apply(&s.coefficients(&bilinear), 1e9);
        assert!(f.iter().zip(&bilinear).all(|(a, b)| (a - b).abs() < 1e-9));

        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, 1.0).unwrap();
        let truth: Vec<f64> = (0..nx * ny)
            .map(|k| 5.0 * ((k % nx) as f64 / 6.0).sin() * ((k / nx) as f64 / 9.0).cos())
            .collect();
        let y: Vec<f64> = truth.iter().map(|t| t + noise.sample(&mut rng)).collect();
        let c = s.coefficients(&y);
        let chosen = s.choose_by_gcv(std::slice::from_ref(&c));
        let f = s.apply(&c, chosen.lambda);
        let rms = |a: &[f64]| (a.iter().map(|v| v * v).sum::<f64>() / a.len() as f64).sqrt();
        let err: Vec<f64> = f.iter().zip(&truth).map(|(a, b)| a - b).collect();
        let sigma = chosen.noise_sigma().unwrap();
        assert!(
            rms(&err) < 0.35,
            "error left {} of σ = 1 (λ {}, dof {})",
            rms(&err),
            chosen.lambda,
            chosen.dof
        );
        assert!((0.85..1.15).contains(&sigma), "σ̂ = {sigma}");
        // Without noise the smoother hardly smooths.
        let c = s.coefficients(&truth);
        let clean = s.choose_by_gcv(std::slice::from_ref(&c));
        let f = s.apply(&c, clean.lambda);
        let err: Vec<f64> = f.iter().zip(&truth).map(|(a, b)| a - b).collect();
        assert!(rms(&err) < 0.01, "noiseless field changed by {}", rms(&err));
    }
}
