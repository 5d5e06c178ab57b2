//! The nodes' error field estimated from noisy node means: the model's own parameter shapes
//! plus a smooth remainder, the basis and the smoothing chosen from the data by generalised
//! cross-validation (GCV). [`super::build`] corrects what this estimates.
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
//! # Estimate (two stages, one hat matrix)
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

use crate::numeric::lattice_smoother::{Coefficients, LatticeSmoother};
use crate::numeric::RANK_TOL;
use nalgebra::DMatrix;
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
    /// This basis and this λ, nothing chosen from the data: re-applies another grid's choice
    /// (its `NoiseReport`'s `basis` and `lambda`) to other readings. The estimate is then linear
    /// in the readings, so applied to the nodes' noiseless errors it gives the smoothing's bias
    /// alone, and the rest of the noisy grid's error is the noise it kept (bench `grid_noise`).
    Exactly(Basis, f64),
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

/// One candidate basis prepared for the λ search.
struct Candidate {
    basis: Basis,
    /// `P·y`, interleaved x, y per node.
    py: Vec<f64>,
    /// `(I − P)y` per component, as smoother coefficients.
    rest: [Coefficients; 2],
    /// Each basis column per component, as smoother coefficients.
    q: Vec<[Coefficients; 2]>,
}

/// Splits an interleaved vector into its x and y fields.
fn components(v: &[f64]) -> [Vec<f64>; 2] {
    [v.iter().step_by(2).copied().collect(), v.iter().skip(1).step_by(2).copied().collect()]
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
    let keep: Vec<usize> = (0..svd.singular_values.len()).filter(|&k| svd.singular_values[k] > RANK_TOL * top).collect();
    u.select_columns(&keep)
}

impl Candidate {
    fn new(smoother: &LatticeSmoother, y: &[f64], basis: Basis, s: Option<DMatrix<f64>>) -> Candidate {
        let q = s.map(|s| orthonormal_basis(&s)).unwrap_or_else(|| DMatrix::zeros(y.len(), 0));
        let yv = nalgebra::DVector::from_column_slice(y);
        let py = &q * (q.transpose() * &yv);
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
        }
    }

    /// The figures at λ (see the module doc), fitted field left empty.
    fn evaluate(&self, smoother: &LatticeSmoother, lambda: f64) -> FieldEstimate {
        let n = smoother.len();
        let rank = self.q.len() as f64;
        let (mut tr_h, mut tr_h2) = (0.0, 0.0);
        for g in smoother.gains(lambda) {
            tr_h += 2.0 * g;
            tr_h2 += 2.0 * g * g;
        }
        let (mut qhq, mut qh2q) = (0.0, 0.0);
        for qc in &self.q {
            for c in qc {
                qhq += smoother.quadratic(c, c, lambda, 1);
                qh2q += smoother.quadratic(c, c, lambda, 2);
            }
        }
        let rss = self.rest.iter().map(|c| smoother.residual_sq(c, lambda)).sum::<f64>();
        let dof = rank + tr_h - qhq;
        let m = 2.0 * n as f64;
        let denom = (1.0 - dof / m).powi(2);
        let gcv = if denom > 1e-12 { rss / m / denom } else { f64::INFINITY };
        FieldEstimate {
            fitted_um: Vec::new(),
            basis: self.basis,
            columns: self.q.len(),
            lambda,
            dof,
            noise_dof: rank + tr_h2 - qh2q,
            rss,
            gcv,
            n,
        }
    }

    /// The estimate at λ with its fitted field.
    fn fit(&self, smoother: &LatticeSmoother, lambda: f64) -> FieldEstimate {
        let mut e = self.evaluate(smoother, lambda);
        let [hx, hy] = [smoother.apply(&self.rest[0], lambda), smoother.apply(&self.rest[1], lambda)];
        e.fitted_um = (0..smoother.len()).map(|k| [self.py[2 * k] + hx[k], self.py[2 * k + 1] + hy[k]]).collect();
        e
    }
}

/// The shapes of a basis: the model's columns `shapes` (2n × p, rows x, y per node), each
/// also times the coordinates the basis names (`coords`: per node, scaled to [−1, 1]).
fn basis_matrix(shapes: &DMatrix<f64>, coords: &[[f64; 2]], basis: Basis) -> Option<DMatrix<f64>> {
    let factors: &[Option<usize>] = match basis {
        Basis::None => return None,
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
/// computed; `coords`: the nodes' coordinates scaled to [−1, 1].
pub fn estimate(
    smoother: &LatticeSmoother,
    y_um: &[[f64; 2]],
    shapes: Option<&DMatrix<f64>>,
    coords: &[[f64; 2]],
    smoothing: Smoothing,
) -> FieldEstimate {
    let y: Vec<f64> = y_um.iter().flat_map(|v| *v).collect();
    let exactly;
    let bases: &[Basis] = match (smoothing, shapes) {
        (Smoothing::None, _) | (_, None) => &[Basis::None],
        (Smoothing::Exactly(b, _), _) => {
            exactly = [b];
            &exactly
        }
        _ => &[Basis::Model, Basis::ModelX, Basis::ModelY, Basis::ModelXy],
    };
    let mut best: Option<(Candidate, FieldEstimate)> = None;
    for &b in bases {
        let c = Candidate::new(smoother, &y, b, shapes.and_then(|s| basis_matrix(s, coords, b)));
        let lambda = match smoothing {
            Smoothing::None => 0.0,
            Smoothing::Fixed(l) | Smoothing::Exactly(_, l) => l,
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
        return FieldEstimate { fitted_um: y_um.to_vec(), ..e };
    }
    c.fit(smoother, e.lambda)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

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
        let y: Vec<[f64; 2]> = (0..n).map(|k| [((k * 37) % 11) as f64, ((k * 53) % 7) as f64]).collect();
        let lambda = 0.3;
        let e = estimate(&sm, &y, Some(&s), &vec![[0.0; 2]; n], Smoothing::Fixed(lambda));
        assert_eq!((e.basis, e.columns), (Basis::Model, 2));
        // Explicit: H per component, interleaved.
        let mut h1 = DMatrix::zeros(n, n);
        for k in 0..n {
            let mut unit = vec![0.0; n];
            unit[k] = 1.0;
            h1.set_column(k, &nalgebra::DVector::from_vec(sm.apply(&sm.coefficients(&unit), lambda)));
        }
        let mut h = DMatrix::zeros(2 * n, 2 * n);
        for a in 0..n {
            for b in 0..n {
                h[(2 * a, 2 * b)] = h1[(a, b)];
                h[(2 * a + 1, 2 * b + 1)] = h1[(a, b)];
            }
        }
        let q = orthonormal_basis(&s);
        let p = &q * q.transpose();
        let i = DMatrix::identity(2 * n, 2 * n);
        let a = &p + &h * (&i - &p);
        assert!((e.dof - a.trace()).abs() < 1e-9, "{} vs {}", e.dof, a.trace());
        assert!((e.noise_dof - (a.transpose() * &a).trace()).abs() < 1e-9);
        let yv = nalgebra::DVector::from_iterator(2 * n, y.iter().flat_map(|v| *v));
        let fitted = &a * &yv;
        for k in 0..n {
            assert!((e.fitted_um[k][0] - fitted[2 * k]).abs() < 1e-9 && (e.fitted_um[k][1] - fitted[2 * k + 1]).abs() < 1e-9);
        }
        assert!((e.rss - (&yv - fitted).norm_squared()).abs() < 1e-9);
    }

    /// With the basis and λ given the estimate is linear in the data (what splits a grid's
    /// error into bias and noise), and it reproduces the estimate that chose them.
    #[test]
    fn a_given_basis_and_lambda_make_the_estimate_linear() {
        let (nx, ny) = (6, 5);
        let n = nx * ny;
        let sm = LatticeSmoother::new(nx, ny);
        let mut s = DMatrix::zeros(2 * n, 2);
        let coords: Vec<[f64; 2]> = (0..n).map(|k| [(k % nx) as f64 / 2.5 - 1.0, (k / nx) as f64 / 2.0 - 1.0]).collect();
        for k in 0..n {
            s[(2 * k, 0)] = ((k % nx) as f64).powi(3);
            s[(2 * k + 1, 1)] = ((k / nx) as f64).exp();
        }
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let noise = Normal::new(0.0, 1.0).unwrap();
        let signal: Vec<[f64; 2]> = (0..n).map(|k| [0.3 * s[(2 * k, 0)] + (k as f64).sin(), 0.2 * s[(2 * k + 1, 1)]]).collect();
        let noisy_part: Vec<[f64; 2]> = (0..n).map(|_| [noise.sample(&mut rng), noise.sample(&mut rng)]).collect();
        let y: Vec<[f64; 2]> = signal.iter().zip(&noisy_part).map(|(a, b)| [a[0] + b[0], a[1] + b[1]]).collect();
        let chosen = estimate(&sm, &y, Some(&s), &coords, Smoothing::Gcv);
        let again = estimate(&sm, &y, Some(&s), &coords, Smoothing::Exactly(chosen.basis, chosen.lambda));
        assert_eq!((again.basis, again.lambda), (chosen.basis, chosen.lambda));
        let exactly = |v: &[[f64; 2]]| estimate(&sm, v, Some(&s), &coords, Smoothing::Exactly(chosen.basis, chosen.lambda)).fitted_um;
        let (whole, a, b) = (exactly(&y), exactly(&signal), exactly(&noisy_part));
        for k in 0..n {
            for c in 0..2 {
                assert!((again.fitted_um[k][c] - chosen.fitted_um[k][c]).abs() < 1e-9);
                assert!((whole[k][c] - a[k][c] - b[k][c]).abs() < 1e-9, "node {k}: {} vs {} + {}", whole[k][c], a[k][c], b[k][c]);
            }
        }
        // A basis other than the one GCV chose is taken as given.
        let other = if chosen.basis == Basis::Model { Basis::ModelXy } else { Basis::Model };
        assert_eq!(estimate(&sm, &y, Some(&s), &coords, Smoothing::Exactly(other, 1.0)).basis, other);
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
            let (u, v) = ((k % nx) as f64 / (nx - 1) as f64, (k / nx) as f64 / (ny - 1) as f64);
            let steep = 1.0 / (1.08 - u * v);
            s[(2 * k, 0)] = steep;
            s[(2 * k + 1, 0)] = -0.5 * steep;
            truth[k] = [3.0 * steep + 2.0 * (3.0 * u).sin(), -1.5 * steep + (2.0 * v).cos()];
        }
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let noise = Normal::new(0.0, 2.0).unwrap();
        let y: Vec<[f64; 2]> = truth.iter().map(|t| [t[0] + noise.sample(&mut rng), t[1] + noise.sample(&mut rng)]).collect();
        let err = |e: &FieldEstimate| {
            e.fitted_um.iter().zip(&truth).map(|(f, t)| (f[0] - t[0]).hypot(f[1] - t[1])).fold(0.0, f64::max)
        };
        let with = estimate(&sm, &y, Some(&s), &vec![[0.0; 2]; n], Smoothing::Gcv);
        let without = estimate(&sm, &y, None, &vec![[0.0; 2]; n], Smoothing::Gcv);
        assert_eq!(with.basis, Basis::Model);
        assert!(err(&with) < 0.5 * err(&without), "with the shape {} µm, without {} µm", err(&with), err(&without));
        assert!(err(&with) < 2.0, "{}", err(&with));
        let sigma = with.noise_sigma_um().unwrap();
        assert!((1.8..2.2).contains(&sigma), "σ̂ {sigma}");
        let raw = estimate(&sm, &y, Some(&s), &vec![[0.0; 2]; n], Smoothing::None);
        assert_eq!(raw.fitted_um, y);
    }
}
