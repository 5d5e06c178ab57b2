//! The nodes' error field estimated from noisy node means: the model's own parameter shapes,
//! the six-bar's part-error responses under a prior (the default, section "The six-bar prior"),
//! and a smooth remainder, the smoothing chosen from the data (restricted maximum likelihood;
//! generalised cross-validation, GCV, for the generic bases). [`super::build`] corrects what
//! this estimates.
//!
//! # Model
//! `y_k = f(node_k) + noise` (µm, x and y per node). The field is written as
//! `f = S·β + g`: `S` holds the hidden robot's own parameter shapes at the nodes
//! (`∂FK/∂p` at each node's IK, the ten columns of `calib::fit::params`), optionally each
//! multiplied by a coordinate of the node so the parameters may drift linearly across the
//! workspace; `g` is smooth (the 2-D Whittaker smoother of `numeric::lattice_smoother`).
//! Why the shapes: after a fit the error is mostly what the fit's own parameter errors leave
//! (with 40 poses read at σ = 10 µm: 20-50 µm, growing fast towards the workspace corners
//! where no smoother follows it) plus what no five-bar describes (the six-bar's parallelogram
//! loops, compliance: a few µm, smooth, also steepest in the corners, where parameters that
//! vary across the workspace describe it). Fitting the shapes on the nodes is a linearised refit
//! of the model on 2·nodes equations (1302 on the paper lattice); measured on simulated six-bar
//! plants with a 10 µm instrument, the shapes halve the smoother's bias in the corners.
//!
//! # The generic bases (without the six-bar prior): two stages, one hat matrix
//! With `P` the projection onto the columns of `S` (orthonormal basis from the column-scaled SVD,
//! directions below `numeric::RANK_TOL` dropped: the shapes of A0 and B0 overlap) and `H(λ)` the
//! smoother: `f̂ = P·y + H·(I − P)·y`, i.e. the hat matrix `A = P + H(I − P)`. Exactly, with the
//! smoother's eigenbasis and `q` the columns of the basis of `P`:
//! * `‖y − f̂‖² = ‖(I − H)(I − P)y‖²`;
//! * `tr A = rank + tr H − Σ qᵀHq` (the degrees of freedom: the basis and the smoother share the
//!   bilinear fields, which are counted once);
//! * `tr AᵀA = rank + tr H² − Σ qᵀH²q` (how much white noise the estimate keeps: its variance
//!   per node is `σ²·tr AᵀA / n`).
//!
//! GCV `V = (‖y − f̂‖²/2n) / (1 − tr A/2n)²` picks λ for every candidate basis and then the
//! candidate ([`Basis`]): the data decide whether a richer basis is worth the noise it takes in.
//!
//! Cost: one thin SVD of a 2n × 30 matrix and 2 lattice transforms per basis column, then
//! `O(n·columns)` per λ tried; about 10 ms on the paper lattice.
//!
//! # The six-bar prior ([`Basis::SixBar`], the default when the responses are given)
//! The bases above describe the six-bar's own error (what no five-bar has) by generic shapes,
//! which either miss it (bias up to 5 µm max at the lattice corners on simulated machines) or
//! take in noise with many columns. The six-bar's loop closure (`loop_closure`,
//! linearised about the nominal machine) gives the field's physical form instead: the tool
//! displacement per µm of each of the 24 part errors (bar lengths, pin positions, bearings)
//! at every node, `R` (2n × 24, µm/µm). The field is then `f = S·β + R·γ + g`: the model's
//! shapes `S` free (the fit's parameter errors, whatever their size), the part errors `γ` under
//! a prior of independent equal variances τ² (ridge regression, `λ = σ²/τ²`), and the smoother
//! `g` on what is left. With `P` the projection on `S` and `(I − P)R = U·diag(s)·Vᵀ`, the
//! parametric part is `A_p·y = P·y + Σ dᵢ·uᵢuᵢᵀy`, `dᵢ = sᵢ²/(sᵢ² + λ)`: a combination of
//! part errors the nodes see strongly is taken whole, one they barely see is shrunk towards
//! zero instead of copying the noise into the corners where such combinations are steep. The
//! whole estimate is `A = A_p + H(I − A_p)`, its traces exact ([`Candidate`]).
//!
//! Both λ are chosen by **restricted maximum likelihood** (REML: the marginal likelihood of the
//! data outside the free columns, σ profiled out): the prior's from `uᵢᵀy ~ N(0, σ²(1 +
//! sᵢ²/λ))` and the rest `N(0, σ²)`; then the smoother's on the remainder `(I − A_p)y`, the
//! smoother read as a Gaussian prior too (`LatticeSmoother::restricted_deviance`). Why not
//! GCV: measured on 24 simulated machines (`benches/grid_noise.rs`, 10 µm instrument, one
//! reading per node, max/RMS at 400 fresh targets after one round), the prior with REML's λs
//! leaves mean 4.3/1.42, worst 6.04/1.93 µm (22 of 24 within 6); with GCV's λ for the prior (and no smoother) mean
//! 4.6/1.43, worst 6.7/1.91; GCV's λ for the smoother on the remainder took in noise (worst
//! 6.8: on a six-bar the remainder is mostly noise, and GCV smooths too little there). The
//! generic bases by GCV on the same readings: mean 5.4/1.68, worst 7.1/2.06. On a machine whose
//! error is not a six-bar's (a smooth distortion) the smoother still takes what the prior
//! cannot. The 1 µm instrument is unharmed (12 machines, worst 1.3/0.33 against 1.2/0.33).
//!
//! The part errors' design (platform pins, parallelogram offsets, stiffnesses) is
//! `SixBarDesign::for_model`: the paper machine's proportions when no drawing is given; on
//! `plants/second.toml`, whose parallelograms are placed otherwise, the prior still took one
//! round from 4.6/1.54 to 2.8/1.22 µm (the responses' span is nearly the same). A machine that
//! is not such a six-bar can turn it off (`GridOptions::six_bar_prior`, `grid
//! --no-six-bar-prior`). Cost: one thin SVD of a 2n × 24 matrix, a 24-term sum per λ tried, and
//! the lattice transforms of 34 directions: about 20 ms on the paper lattice.

use crate::numeric::lattice_smoother::{minimise_log10, Coefficients, LatticeSmoother};
use crate::numeric::RANK_TOL;
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

/// How the nodes' mean errors are smoothed before they become corrections.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Smoothing {
    /// Basis and λ by generalised cross-validation (the default; see the module doc).
    Gcv,
    /// This λ (lattice-step units, see `numeric::lattice_smoother`), the basis by GCV.
    Fixed(f64),
    /// None: each node's own mean error (the unsmoothed grid of the paper).
    None,
    /// This basis, this smoother λ and this six-bar prior λ (used by [`Basis::SixBar`] only),
    /// nothing chosen from the data: re-applies another grid's choice (its `NoiseReport`'s
    /// `basis`, `lambda` and `six_bar_lambda`) to other readings. The estimate is then linear
    /// in the readings, so applied to the nodes' noiseless errors it gives the smoothing's bias
    /// alone, and the rest of the noisy grid's error is the noise it kept (bench `grid_noise`).
    Exactly(Basis, f64, f64),
}

/// The parametric part of the field.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Basis {
    /// No parametric part (no smoothing, or the shapes could not be computed).
    None,
    /// The model's parameter shapes.
    Model,
    /// The shapes, each also times the node's x.
    ModelX,
    /// The shapes, each also times the node's y.
    ModelY,
    /// The shapes, each also times x and times y.
    ModelXy,
    /// The shapes and the six-bar's part-error responses under a prior (module doc), then the
    /// smoother on the rest.
    SixBar,
}

/// The estimated field and the figures that judge it.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldEstimate {
    /// Per node (µm).
    pub fitted_um: Vec<[f64; 2]>,
    pub basis: Basis,
    /// Independent columns of the basis used.
    pub columns: usize,
    pub lambda: f64,
    /// The six-bar prior's λ (µm² per µm² of part error; 0 for the other bases).
    pub prior_lambda: f64,
    /// `tr A` over both components.
    pub dof: f64,
    /// `tr AᵀA` over both components.
    pub noise_dof: f64,
    /// `‖y − f̂‖²` (µm²).
    pub rss: f64,
    pub gcv: f64,
    /// Nodes.
    pub n: usize,
}

impl FieldEstimate {
    /// σ per axis of a node's value implied by the residual, `sqrt(RSS / (2n − tr A))`; `None`
    /// when the estimate interpolates.
    pub fn noise_sigma_um(&self) -> Option<f64> {
        let dof = 2.0 * self.n as f64 - self.dof;
        (dof > 0.5).then(|| (self.rss / dof).sqrt())
    }
}

/// One candidate basis prepared for the λ search. Its parametric part is `A_p = Σ eₖ·wₖwₖᵀ`
/// over orthonormal directions `wₖ` with weights `eₖ` ∈ (0, 1]: a projection `P` (every
/// weight 1) or the six-bar prior's shrinkage (module doc). With `A = A_p + H(I − A_p)`,
/// exactly (only the directions' own quadratic forms enter):
/// `tr A = Σ eₖ + tr H − Σ eₖ·wₖᵀHwₖ`,
/// `tr AᵀA = Σ eₖ² + 2Σ eₖ(1 − eₖ)·wₖᵀHwₖ + tr H² − Σ (1 − (1 − eₖ)²)·wₖᵀH²wₖ`.
struct Candidate {
    basis: Basis,
    /// `A_p·y`, interleaved x, y per node.
    py: Vec<f64>,
    /// `(I − A_p)y` per component, as smoother coefficients.
    rest: [Coefficients; 2],
    /// Each direction per component, as smoother coefficients.
    q: Vec<[Coefficients; 2]>,
    /// The directions' weights `eₖ`.
    weights: Vec<f64>,
}

/// Splits an interleaved vector into its x and y fields.
fn components(v: &[f64]) -> [Vec<f64>; 2] {
    [
        v.iter().step_by(2).copied().collect(),
        v.iter().skip(1).step_by(2).copied().collect(),
    ]
}

/// An orthonormal basis (columns) of the span of `s`, from the column-scaled SVD.
fn orthonormal_basis(s: &DMatrix<f64>) -> DMatrix<f64> {
    let mut scaled = s.clone();
    for mut c in scaled.column_iter_mut() {
        let n = c.norm();
        if n > 0.0 {
            c /= n;
        }
    }
    let svd = scaled.svd(true, false);
    let u = svd.u.expect("U was requested");
    let top = svd.singular_values.iter().fold(0.0f64, |m, v| m.max(*v));
    let keep: Vec<usize> = (0..svd.singular_values.len())
        .filter(|&k| svd.singular_values[k] > RANK_TOL * top)
        .collect();
    u.select_columns(&keep)
}

impl Candidate {
    fn new(
        smoother: &LatticeSmoother,
        y: &[f64],
        basis: Basis,
        s: Option<DMatrix<f64>>,
    ) -> Candidate {
        let q = s
            .map(|s| orthonormal_basis(&s))
            .unwrap_or_else(|| DMatrix::zeros(y.len(), 0));
        let weights = vec![1.0; q.ncols()];
        Candidate::weighted(smoother, y, basis, &q, weights)
    }

    /// The candidate of the directions `q` (orthonormal columns) with the weights `eₖ`.
    fn weighted(
        smoother: &LatticeSmoother,
        y: &[f64],
        basis: Basis,
        q: &DMatrix<f64>,
        weights: Vec<f64>,
    ) -> Candidate {
        let yv = DVector::from_column_slice(y);
        let qy = q.transpose() * &yv;
        let py = q * DVector::from_iterator(qy.len(), qy.iter().zip(&weights).map(|(v, e)| v * e));
        let rest: Vec<f64> = yv.iter().zip(py.iter()).map(|(a, b)| a - b).collect();
        let coeffs = |v: &[f64]| {
            let [x, y] = components(v);
            [smoother.coefficients(&x), smoother.coefficients(&y)]
        };
        Candidate {
            basis,
            py: py.as_slice().to_vec(),
            rest: coeffs(&rest),
            q: q.column_iter().map(|c| coeffs(c.as_slice())).collect(),
            weights,
        }
    }

    /// The figures at λ (see the type's doc), fitted field left empty.
    fn evaluate(&self, smoother: &LatticeSmoother, lambda: f64) -> FieldEstimate {
        let n = smoother.len();
        let (mut tr_h, mut tr_h2) = (0.0, 0.0);
        for g in smoother.gains(lambda) {
            tr_h += 2.0 * g;
            tr_h2 += 2.0 * g * g;
        }
        // Σ eₖ, Σ eₖ², Σ eₖ·wᵀHw, Σ eₖ(1 − eₖ)·wᵀHw, Σ (1 − (1 − eₖ)²)·wᵀH²w.
        let (mut sum_e, mut sum_e2, mut qhq, mut cross, mut qh2q) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (qc, &e) in self.q.iter().zip(&self.weights) {
            sum_e += e;
            sum_e2 += e * e;
            for c in qc {
                let (h, h2) = (
                    smoother.quadratic(c, c, lambda, 1),
                    smoother.quadratic(c, c, lambda, 2),
                );
                qhq += e * h;
                cross += e * (1.0 - e) * h;
                qh2q += (1.0 - (1.0 - e) * (1.0 - e)) * h2;
            }
        }
        let rss = self
            .rest
            .iter()
            .map(|c| smoother.residual_sq(c, lambda))
            .sum::<f64>();
        let dof = sum_e + tr_h - qhq;
        let m = 2.0 * n as f64;
        let denom = (1.0 - dof / m).powi(2);
        let gcv = if denom > 1e-12 {
            rss / m / denom
        } else {
            f64::INFINITY
        };
        FieldEstimate {
            fitted_um: Vec::new(),
            basis: self.basis,
            columns: self.q.len(),
            lambda,
            prior_lambda: 0.0,
            dof,
            noise_dof: sum_e2 + 2.0 * cross + tr_h2 - qh2q,
            rss,
            gcv,
            n,
        }
    }

    /// The estimate at λ with its fitted field.
    fn fit(&self, smoother: &LatticeSmoother, lambda: f64) -> FieldEstimate {
        let mut e = self.evaluate(smoother, lambda);
        let [hx, hy] = [
            smoother.apply(&self.rest[0], lambda),
            smoother.apply(&self.rest[1], lambda),
        ];
        e.fitted_um = (0..smoother.len())
            .map(|k| [self.py[2 * k] + hx[k], self.py[2 * k + 1] + hy[k]])
            .collect();
        e
    }
}

/// The six-bar prior's part (module doc): the shapes' projection and the part-error responses'
/// remainder in its singular directions.
struct SixBarPrior {
    /// The shapes' orthonormal basis (the projection `P`).
    q: DMatrix<f64>,
    /// Independent columns of the shapes.
    rank: usize,
    /// Data points (2 per node).
    m: usize,
    /// `uᵢ`: orthonormal directions of `(I − P)R`.
    u: DMatrix<f64>,
    /// `sᵢ²`.
    s2: Vec<f64>,
    /// `uᵢᵀy`.
    uy: Vec<f64>,
    /// `‖y‖² − ‖P·y‖² − Σ (uᵢᵀy)²`: the data outside both spans.
    rss_outside: f64,
}

impl SixBarPrior {
    fn new(y: &[f64], shapes: &DMatrix<f64>, responses: &DMatrix<f64>) -> SixBarPrior {
        let q = orthonormal_basis(shapes);
        let yv = DVector::from_column_slice(y);
        let py = &q * (q.transpose() * &yv);
        let rest = responses - &q * (q.transpose() * responses);
        let svd = rest.svd(true, false);
        let u = svd.u.expect("U was requested");
        // Relative to the responses' own scale: a direction the shapes take whole is dropped.
        let top = responses
            .column_iter()
            .map(|c| c.norm())
            .fold(0.0f64, f64::max);
        let keep: Vec<usize> = (0..svd.singular_values.len())
            .filter(|&k| svd.singular_values[k] > RANK_TOL * top)
            .collect();
        let u = u.select_columns(&keep);
        let s2: Vec<f64> = keep
            .iter()
            .map(|&k| svd.singular_values[k].powi(2))
            .collect();
        let outside = &yv - &py;
        let uy: Vec<f64> = u.column_iter().map(|c| c.dot(&outside)).collect();
        let rss_outside = (outside.norm_squared() - uy.iter().map(|v| v * v).sum::<f64>()).max(0.0);
        SixBarPrior {
            rank: q.ncols(),
            m: y.len(),
            q,
            u,
            s2,
            uy,
            rss_outside,
        }
    }

    /// The shrink factors `dᵢ = sᵢ²/(sᵢ² + λ)`.
    fn gains(&self, lambda: f64) -> impl Iterator<Item = f64> + '_ {
        self.s2.iter().map(move |s2| s2 / (s2 + lambda))
    }

    /// −2 log of the restricted likelihood at λ, σ² profiled out, up to a constant.
    fn restricted_deviance(&self, lambda: f64) -> f64 {
        let n = (self.m - self.rank) as f64;
        let (mut quad, mut log_det) = (self.rss_outside, 0.0);
        for (s2, uy) in self.s2.iter().zip(&self.uy) {
            let inflation = 1.0 + s2 / lambda;
            quad += uy * uy / inflation;
            log_det += inflation.ln();
        }
        n * (quad / n).max(f64::MIN_POSITIVE).ln() + log_det
    }

    /// λ by restricted maximum likelihood, searched from 10⁻⁸ to 10² of the largest `sᵢ²`.
    fn lambda_by_reml(&self) -> f64 {
        let top = self.s2.iter().fold(0.0f64, |m, v| m.max(*v));
        if top <= 0.0 {
            return 1.0;
        }
        let t = top.log10();
        minimise_log10([t - 8.0, t + 2.0], 16.0, |l| self.restricted_deviance(l))
    }

    /// The candidate of the shapes (weight 1) and the responses' directions (weights `dᵢ`).
    fn candidate(&self, smoother: &LatticeSmoother, y: &[f64], lambda: f64) -> Candidate {
        let mut w = DMatrix::zeros(self.m, self.rank + self.u.ncols());
        w.columns_mut(0, self.rank).copy_from(&self.q);
        w.columns_mut(self.rank, self.u.ncols()).copy_from(&self.u);
        let weights = std::iter::repeat_n(1.0, self.rank)
            .chain(self.gains(lambda))
            .collect();
        Candidate::weighted(smoother, y, Basis::SixBar, &w, weights)
    }
}

/// The estimate of [`Basis::SixBar`] (module doc); `smoothing` is `Gcv` or `Exactly`.
fn six_bar_estimate(
    smoother: &LatticeSmoother,
    y: &[f64],
    shapes: &DMatrix<f64>,
    responses: &DMatrix<f64>,
    smoothing: Smoothing,
) -> FieldEstimate {
    let prior = SixBarPrior::new(y, shapes, responses);
    let (lambda, prior_lambda) = match smoothing {
        Smoothing::Exactly(_, l, p) => (Some(l), p),
        _ => (None, prior.lambda_by_reml()),
    };
    let c = prior.candidate(smoother, y, prior_lambda);
    let lambda = lambda.unwrap_or_else(|| {
        smoother.minimise(|l| smoother.restricted_deviance(&[&c.rest[0], &c.rest[1]], l))
    });
    FieldEstimate {
        prior_lambda,
        ..c.fit(smoother, lambda)
    }
}

/// The shapes of a basis: the model's columns `shapes` (2n × p, rows x, y per node), each
/// also times the coordinates the basis names (`coords`: per node, scaled to [−1, 1]).
fn basis_matrix(shapes: &DMatrix<f64>, coords: &[[f64; 2]], basis: Basis) -> Option<DMatrix<f64>> {
    let factors: &[Option<usize>] = match basis {
        Basis::None | Basis::SixBar => return None,
        Basis::Model => &[None],
        Basis::ModelX => &[None, Some(0)],
        Basis::ModelY => &[None, Some(1)],
        Basis::ModelXy => &[None, Some(0), Some(1)],
    };
    let p = shapes.ncols();
    let mut m = DMatrix::zeros(shapes.nrows(), p * factors.len());
    for (f, factor) in factors.iter().enumerate() {
        for c in 0..p {
            for r in 0..shapes.nrows() {
                m[(r, f * p + c)] = shapes[(r, c)] * factor.map_or(1.0, |a| coords[r / 2][a]);
            }
        }
    }
    Some(m)
}

/// Estimates the field of `y_um` (per node, x fastest on the smoother's lattice). `shapes`: the
/// model's parameter shapes (2n × p, rows x, y per node), `None` when they could not be
/// computed; `responses`: the six-bar's part-error responses (2n × 24, µm/µm), `None` when
/// they could not be computed; `coords`: the nodes' coordinates scaled to [−1, 1].
///
/// With GCV and both shapes and responses given the estimate is [`Basis::SixBar`]'s (module
/// doc: the physical form of the field, chosen over the generic bases without a contest: on
/// simulated machines GCV's score between the bases did not predict which one landed closer,
/// and picking a generic basis on its score cost up to 2 µm of maximum error); otherwise the
/// generic bases compete by GCV.
pub fn estimate(
    smoother: &LatticeSmoother,
    y_um: &[[f64; 2]],
    shapes: Option<&DMatrix<f64>>,
    responses: Option<&DMatrix<f64>>,
    coords: &[[f64; 2]],
    smoothing: Smoothing,
) -> FieldEstimate {
    let y: Vec<f64> = y_um.iter().flat_map(|v| *v).collect();
    if let (Smoothing::Gcv | Smoothing::Exactly(Basis::SixBar, ..), Some(s), Some(r)) =
        (smoothing, shapes, responses)
    {
        return six_bar_estimate(smoother, &y, s, r, smoothing);
    }
    let exactly;
    let bases: &[Basis] = match (smoothing, shapes) {
        (Smoothing::None, _) | (_, None) => &[Basis::None],
        (Smoothing::Exactly(b, ..), _) => {
            exactly = [b];
            &exactly
        }
        _ => &[Basis::Model, Basis::ModelX, Basis::ModelY, Basis::ModelXy],
    };
    let mut best: Option<(Candidate, FieldEstimate)> = None;
    for &b in bases {
        let c = Candidate::new(
            smoother,
            &y,
            b,
            shapes.and_then(|s| basis_matrix(s, coords, b)),
        );
        let lambda = match smoothing {
            Smoothing::None => 0.0,
            Smoothing::Fixed(l) | Smoothing::Exactly(_, l, _) => l,
            Smoothing::Gcv => smoother.minimise(|l| c.evaluate(smoother, l).gcv),
        };
        let e = c.evaluate(smoother, lambda);
        if best.as_ref().is_none_or(|(_, b)| e.gcv < b.gcv) {
            best = Some((c, e));
        }
    }
    let (c, e) = best.expect("at least one basis");
    if smoothing == Smoothing::None {
        // H(0) = I: the node values themselves.
        return FieldEstimate {
            fitted_um: y_um.to_vec(),
            ..e
        };
    }
    c.fit(smoother, e.lambda)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// The smoother's hat matrix `H(λ)` on interleaved x, y values, built column by column.
    fn explicit_smoother(sm: &LatticeSmoother, lambda: f64) -> DMatrix<f64> {
        let n = sm.len();
        let mut h1 = DMatrix::zeros(n, n);
        for k in 0..n {
            let mut unit = vec![0.0; n];
            unit[k] = 1.0;
            h1.set_column(
                k,
                &DVector::from_vec(sm.apply(&sm.coefficients(&unit), lambda)),
            );
        }
        let mut h = DMatrix::zeros(2 * n, 2 * n);
        for a in 0..n {
            for b in 0..n {
                h[(2 * a, 2 * b)] = h1[(a, b)];
                h[(2 * a + 1, 2 * b + 1)] = h1[(a, b)];
            }
        }
        h
    }

    /// `e`'s traces, fitted field and residual equal those of the explicit hat matrix `a`.
    fn assert_matches_hat_matrix(e: &FieldEstimate, a: &DMatrix<f64>, y: &[[f64; 2]]) {
        let n = y.len();
        assert!(
            (e.dof - a.trace()).abs() < 1e-9,
            "{} vs {}",
            e.dof,
            a.trace()
        );
        let noise = (a.transpose() * a).trace();
        assert!(
            (e.noise_dof - noise).abs() < 1e-9,
            "{} vs {noise}",
            e.noise_dof
        );
        let yv = DVector::from_iterator(2 * n, y.iter().flat_map(|v| *v));
        let fitted = a * &yv;
        for k in 0..n {
            assert!(
                (e.fitted_um[k][0] - fitted[2 * k]).abs() < 1e-9
                    && (e.fitted_um[k][1] - fitted[2 * k + 1]).abs() < 1e-9
            );
        }
        assert!((e.rss - (&yv - fitted).norm_squared()).abs() < 1e-9);
    }

    /// The traces equal those of the explicit hat matrix `A = P + H(I − P)`.
    #[test]
    fn traces_match_the_explicit_hat_matrix() {
        let (nx, ny) = (5, 4);
        let n = nx * ny;
        let sm = LatticeSmoother::new(nx, ny);
        // Two shape columns: one steep in x, one a constant field in y (shared with the
        // smoother's null space).
        let mut s = DMatrix::zeros(2 * n, 2);
        for k in 0..n {
            s[(2 * k, 0)] = ((k % nx) as f64).powi(3);
            s[(2 * k + 1, 1)] = 1.0;
        }
        let y: Vec<[f64; 2]> = (0..n)
            .map(|k| [((k * 37) % 11) as f64, ((k * 53) % 7) as f64])
            .collect();
        let lambda = 0.3;
        let e = estimate(
            &sm,
            &y,
            Some(&s),
            None,
            &vec![[0.0; 2]; n],
            Smoothing::Fixed(lambda),
        );
        assert_eq!((e.basis, e.columns), (Basis::Model, 2));
        let h = explicit_smoother(&sm, lambda);
        let q = orthonormal_basis(&s);
        let p = &q * q.transpose();
        let i = DMatrix::identity(2 * n, 2 * n);
        assert_matches_hat_matrix(&e, &(&p + &h * (&i - &p)), &y);
    }

    /// The six-bar prior's estimate and traces equal those of the explicit hat matrix
    /// `A = A_p + H(I − A_p)`, `A_p = QQᵀ + U·diag(s²/(s² + λ_p))·Uᵀ`.
    #[test]
    fn the_six_bar_prior_matches_its_explicit_hat_matrix() {
        let (nx, ny) = (5, 4);
        let n = nx * ny;
        let sm = LatticeSmoother::new(nx, ny);
        let mut s = DMatrix::zeros(2 * n, 2);
        let mut r = DMatrix::zeros(2 * n, 3);
        for k in 0..n {
            let (u, v) = ((k % nx) as f64, (k / nx) as f64);
            s[(2 * k, 0)] = u.powi(3);
            s[(2 * k + 1, 1)] = 1.0;
            // One response shares a shape's direction, the others are their own.
            r[(2 * k, 0)] = 0.5 * u.powi(3) + 0.1 * v;
            r[(2 * k + 1, 1)] = (0.7 * u).sin() * v;
            r[(2 * k, 2)] = (u * v).sqrt();
            r[(2 * k + 1, 2)] = 0.3 * u - v * v;
        }
        let y: Vec<[f64; 2]> = (0..n)
            .map(|k| [((k * 37) % 11) as f64, ((k * 53) % 7) as f64])
            .collect();
        let (lambda, prior_lambda) = (0.3, 2.0);
        let e = estimate(
            &sm,
            &y,
            Some(&s),
            Some(&r),
            &vec![[0.0; 2]; n],
            Smoothing::Exactly(Basis::SixBar, lambda, prior_lambda),
        );
        assert_eq!(
            (e.basis, e.lambda, e.prior_lambda),
            (Basis::SixBar, lambda, prior_lambda)
        );
        let h = explicit_smoother(&sm, lambda);
        let q = orthonormal_basis(&s);
        let i = DMatrix::identity(2 * n, 2 * n);
        let rest = (&i - &q * q.transpose()) * &r;
        let svd = rest.svd(true, false);
        let u = svd.u.unwrap();
        let mut ap = &q * q.transpose();
        let mut kept = 0;
        for (k, sv) in svd.singular_values.iter().enumerate() {
            if *sv > 1e-6 {
                let d = sv * sv / (sv * sv + prior_lambda);
                ap += u.column(k) * u.column(k).transpose() * d;
                kept += 1;
            }
        }
        assert_eq!(e.columns, 2 + kept);
        assert_matches_hat_matrix(&e, &(&ap + &h * (&i - &ap)), &y);
    }

    /// Data of the prior's own form (part errors drawn with variance τ², noise σ²): REML's λ
    /// is near σ²/τ², and the estimate is closer to the truth than the generic bases' (which
    /// do not have the responses).
    #[test]
    fn reml_finds_the_prior_of_data_drawn_from_it() {
        let (nx, ny) = (21, 31);
        let n = nx * ny;
        let sm = LatticeSmoother::new(nx, ny);
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let unit = Normal::new(0.0, 1.0).unwrap();
        // Twelve smooth, steep-cornered responses and two free shapes.
        let mut r = DMatrix::zeros(2 * n, 12);
        let mut s = DMatrix::zeros(2 * n, 2);
        for k in 0..n {
            let (u, v) = (
                (k % nx) as f64 / (nx - 1) as f64,
                (k / nx) as f64 / (ny - 1) as f64,
            );
            s[(2 * k, 0)] = 1.0;
            s[(2 * k + 1, 1)] = 1.0;
            for c in 0..12 {
                let f = (c as f64 + 1.0) * 0.7;
                let w = 1.0 / (1.1 - u * v);
                r[(2 * k, c)] = 0.05 * w * (f * u).cos() * (0.5 * f * v).sin();
                r[(2 * k + 1, c)] = 0.05 * w * (f * v + c as f64).cos();
            }
        }
        let (sigma, tau) = (2.0, 30.0);
        let gamma = DVector::from_iterator(12, (0..12).map(|_| tau * unit.sample(&mut rng)));
        let truth = &r * &gamma + &s * DVector::from_vec(vec![40.0, -25.0]);
        let y: Vec<[f64; 2]> = (0..n)
            .map(|k| {
                [
                    truth[2 * k] + sigma * unit.sample(&mut rng),
                    truth[2 * k + 1] + sigma * unit.sample(&mut rng),
                ]
            })
            .collect();
        let coords = vec![[0.0; 2]; n];
        let with = estimate(&sm, &y, Some(&s), Some(&r), &coords, Smoothing::Gcv);
        let without = estimate(&sm, &y, Some(&s), None, &coords, Smoothing::Gcv);
        let err = |e: &FieldEstimate| {
            let sq: f64 = (0..n)
                .map(|k| {
                    (e.fitted_um[k][0] - truth[2 * k]).powi(2)
                        + (e.fitted_um[k][1] - truth[2 * k + 1]).powi(2)
                })
                .sum();
            (sq / n as f64).sqrt()
        };
        let expected = sigma * sigma / (tau * tau);
        assert_eq!(with.basis, Basis::SixBar);
        assert!(
            (expected / 30.0..expected * 30.0).contains(&with.prior_lambda),
            "λ {} vs σ²/τ² {expected}",
            with.prior_lambda
        );
        assert!(
            err(&with) < 0.7 * err(&without),
            "with the prior {} µm RMS, generic {} µm",
            err(&with),
            err(&without)
        );
        assert!(err(&with) < sigma, "{}", err(&with));
    }

    /// With the basis and λ given the estimate is linear in the data (what splits a grid's
    /// error into bias and noise), and it reproduces the estimate that chose them.
    #[test]
    fn a_given_basis_and_lambda_make_the_estimate_linear() {
        let (nx, ny) = (6, 5);
        let n = nx * ny;
        let sm = LatticeSmoother::new(nx, ny);
        let mut s = DMatrix::zeros(2 * n, 2);
        let coords: Vec<[f64; 2]> = (0..n)
            .map(|k| [(k % nx) as f64 / 2.5 - 1.0, (k / nx) as f64 / 2.0 - 1.0])
            .collect();
        for k in 0..n {
            s[(2 * k, 0)] = ((k % nx) as f64).powi(3);
            s[(2 * k + 1, 1)] = ((k / nx) as f64).exp();
        }
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let noise = Normal::new(0.0, 1.0).unwrap();
        let signal: Vec<[f64; 2]> = (0..n)
            .map(|k| {
                [
                    0.3 * s[(2 * k, 0)] + (k as f64).sin(),
                    0.2 * s[(2 * k + 1, 1)],
                ]
            })
            .collect();
        let noisy_part: Vec<[f64; 2]> = (0..n)
            .map(|_| [noise.sample(&mut rng), noise.sample(&mut rng)])
            .collect();
        let y: Vec<[f64; 2]> = signal
            .iter()
            .zip(&noisy_part)
            .map(|(a, b)| [a[0] + b[0], a[1] + b[1]])
            .collect();
        let chosen = estimate(&sm, &y, Some(&s), None, &coords, Smoothing::Gcv);
        let again = estimate(
            &sm,
            &y,
            Some(&s),
            None,
            &coords,
            Smoothing::Exactly(chosen.basis, chosen.lambda, 0.0),
        );
        assert_eq!((again.basis, again.lambda), (chosen.basis, chosen.lambda));
        let exactly = |v: &[[f64; 2]]| {
            estimate(
                &sm,
                v,
                Some(&s),
                None,
                &coords,
                Smoothing::Exactly(chosen.basis, chosen.lambda, 0.0),
            )
            .fitted_um
        };
        let (whole, a, b) = (exactly(&y), exactly(&signal), exactly(&noisy_part));
        for k in 0..n {
            for c in 0..2 {
                assert!((again.fitted_um[k][c] - chosen.fitted_um[k][c]).abs() < 1e-9);
                assert!(
                    (whole[k][c] - a[k][c] - b[k][c]).abs() < 1e-9,
                    "node {k}: {} vs {} + {}",
                    whole[k][c],
                    a[k][c],
                    b[k][c]
                );
            }
        }
        // A basis other than the one GCV chose is taken as given.
        let other = if chosen.basis == Basis::Model {
            Basis::ModelXy
        } else {
            Basis::Model
        };
        assert_eq!(
            estimate(
                &sm,
                &y,
                Some(&s),
                None,
                &coords,
                Smoothing::Exactly(other, 1.0, 0.0)
            )
            .basis,
            other
        );
    }

    /// A field made of a shape (steep in one corner) plus noise: GCV takes the shape into the
    /// basis and smooths the rest, so the estimate is far closer to the truth than the noise;
    /// the smoother alone is biased where the shape is steep.
    #[test]
    fn the_basis_takes_what_the_smoother_cannot_follow() {
        let (nx, ny) = (21, 31);
        let n = nx * ny;
        let sm = LatticeSmoother::new(nx, ny);
        let mut s = DMatrix::zeros(2 * n, 1);
        let mut truth = vec![[0.0; 2]; n];
        for k in 0..n {
            let (u, v) = (
                (k % nx) as f64 / (nx - 1) as f64,
                (k / nx) as f64 / (ny - 1) as f64,
            );
            let steep = 1.0 / (1.08 - u * v);
            s[(2 * k, 0)] = steep;
            s[(2 * k + 1, 0)] = -0.5 * steep;
            truth[k] = [
                3.0 * steep + 2.0 * (3.0 * u).sin(),
                -1.5 * steep + (2.0 * v).cos(),
            ];
        }
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let noise = Normal::new(0.0, 2.0).unwrap();
        let y: Vec<[f64; 2]> = truth
            .iter()
            .map(|t| [t[0] + noise.sample(&mut rng), t[1] + noise.sample(&mut rng)])
            .collect();
        let err = |e: &FieldEstimate| {
            e.fitted_um
                .iter()
                .zip(&truth)
                .map(|(f, t)| (f[0] - t[0]).hypot(f[1] - t[1]))
                .fold(0.0, f64::max)
        };
        let with = estimate(&sm, &y, Some(&s), None, &vec![[0.0; 2]; n], Smoothing::Gcv);
        let without = estimate(&sm, &y, None, None, &vec![[0.0; 2]; n], Smoothing::Gcv);
        assert_eq!(with.basis, Basis::Model);
        assert!(
            err(&with) < 0.5 * err(&without),
            "with the shape {} µm, without {} µm",
            err(&with),
            err(&without)
        );
        assert!(err(&with) < 2.0, "{}", err(&with));
        let sigma = with.noise_sigma_um().unwrap();
        assert!((1.8..2.2).contains(&sigma), "σ̂ {sigma}");
        let raw = estimate(&sm, &y, Some(&s), None, &vec![[0.0; 2]; n], Smoothing::None);
        assert_eq!(raw.fitted_um, y);
    }
}
