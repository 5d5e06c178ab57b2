//! The torque-space least squares of the moving machine's diagnosis: the library's candidates
//! (`effects`) fitted jointly to the torque the model lacks, scored by BIC with the samples
//! discounted for their correlation, the cogging period scanned, the parameters named and
//! signed as the report has them, and the model with a fit's effects added (the plant the
//! closed-loop prediction runs). `diagnose` decides with them; see its module doc.
//!
//! Cost: one column-scaled SVD of 2N × k per fit (N ≈ 1600, k ≤ 13); the cogging scan is
//! 381 periods × N sine-cosine pairs.

use super::effects::{columns, DynamicEffect, COGGING_CYCLES};
use super::model_plant::Extras;
use super::samples::MotionSample;
use crate::diagnose::report::Param;
use crate::effect::PhysicalEffect;
use crate::numeric::svd::{ScaledSvd, RANK_TOL};
use crate::numeric::two_regressors::TwoRegressors;
use kinematics_core::FiveBarDynamics;
use nalgebra::{DMatrix, DVector};
use std::collections::BTreeMap;

/// A motor's torque per command minus one from the torque-constant column's coefficient `c`
/// (%): the column is the first order, `τ/(1 + k) = τ·(1 − c/100)`, so `k = c/(100 − c)`.
pub fn torque_error_of(c_pct: f64) -> f64 {
    c_pct / (100.0 - c_pct)
}

/// What the cogging scan costs in the BIC (twice the log of the periods tried).
pub const SCAN_PENALTY: f64 = 12.0;

/// A candidate: a library effect (cogging with its period).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Cand {
    pub e: &'static DynamicEffect,
    pub cycles: f64,
}

impl Cand {
    pub fn name(&self) -> &'static str {
        self.e.effect.name()
    }
    pub fn is_cogging(&self) -> bool {
        self.e.effect == PhysicalEffect::Cogging
    }
}

/// A least-squares fit of some candidates to the torque residual.
#[derive(Clone, Debug)]
pub(super) struct Fit {
    pub cands: Vec<Cand>,
    pub beta: Vec<f64>,
    /// Diagonal of `(XᵀX)⁻¹`.
    pub cov_diag: Vec<f64>,
    pub rss: f64,
    pub resid: Vec<f64>,
}

impl Fit {
    /// The coefficients of candidate `i`.
    pub fn coefs(&self, i: usize) -> &[f64] {
        let start: usize = self.cands[..i].iter().map(|c| c.e.params.len()).sum();
        &self.beta[start..start + self.cands[i].e.params.len()]
    }
}

/// The problem: samples, torque residual, columns.
pub(super) struct Problem<'a> {
    pub samples: &'a [MotionSample],
    /// The model's torque at each sample (N·m).
    pub model_torque: Vec<[f64; 2]>,
    pub r: Vec<f64>,
    pub n_eff: f64,
    pub coulomb_speed: f64,
}

impl Problem<'_> {
    pub fn n(&self) -> usize {
        self.r.len()
    }

    /// The columns of `c` (each 2N long, interleaved by motor).
    pub fn cols(&self, c: &Cand) -> Vec<Vec<f64>> {
        let p = c.e.params.len();
        let mut out = vec![Vec::with_capacity(self.n()); p];
        for (s, t) in self.samples.iter().zip(&self.model_torque) {
            let cols =
                columns(c.e, s, *t, self.coulomb_speed, c.cycles).unwrap_or(vec![[0.0; 2]; p]);
            for (o, col) in out.iter_mut().zip(cols) {
                o.extend_from_slice(&col);
            }
        }
        out
    }

    pub fn fit_cols(&self, cands: &[Cand], cols: &[Vec<f64>]) -> Option<Fit> {
        let n = self.n();
        let r = DVector::from_column_slice(&self.r);
        if cols.is_empty() {
            return Some(Fit {
                cands: Vec::new(),
                beta: Vec::new(),
                cov_diag: Vec::new(),
                rss: r.norm_squared(),
                resid: self.r.clone(),
            });
        }
        let x = DMatrix::from_fn(n, cols.len(), |i, j| cols[j][i]);
        let svd = ScaledSvd::new(&x);
        if svd.rank(RANK_TOL) < cols.len() {
            return None;
        }
        let cov = svd.normal_pseudo_inverse(RANK_TOL);
        let beta = &cov * (x.transpose() * &r);
        let resid = &r - &x * &beta;
        Some(Fit {
            cands: cands.to_vec(),
            beta: beta.iter().copied().collect(),
            cov_diag: (0..cols.len()).map(|i| cov[(i, i)]).collect(),
            rss: resid.norm_squared(),
            resid: resid.iter().copied().collect(),
        })
    }

    pub fn fit(&self, cands: &[Cand]) -> Option<Fit> {
        let cols: Vec<Vec<f64>> = cands.iter().flat_map(|c| self.cols(c)).collect();
        self.fit_cols(cands, &cols)
    }

    pub fn bic(&self, f: &Fit) -> f64 {
        let n = self.n() as f64;
        let k = f.beta.len() as f64;
        let scan = if f.cands.iter().any(Cand::is_cogging) {
            SCAN_PENALTY
        } else {
            0.0
        };
        self.n_eff * (f.rss.max(1e-300) / n).ln() + k * self.n_eff.ln() + scan
    }

    /// One standard deviation per coefficient of `f` (the residual's variance, inflated for the
    /// samples that are not independent).
    pub fn std_devs(&self, f: &Fit) -> Vec<f64> {
        let n = self.n() as f64;
        let dof = (n - f.beta.len() as f64).max(1.0);
        let s2 = f.rss / dof * (n / self.n_eff);
        f.cov_diag
            .iter()
            .map(|c| (s2 * c).max(0.0).sqrt())
            .collect()
    }

    /// The cogging period that explains most of `resid` (sine and cosine per motor, each
    /// motor's pair projected alone: the motors' columns do not overlap), cycles per joint
    /// revolution.
    pub fn best_cogging(&self, resid: &[f64]) -> f64 {
        let mut best = (f64::NEG_INFINITY, f64::from(COGGING_CYCLES.0));
        for n in COGGING_CYCLES.0..=COGGING_CYCLES.1 {
            let nf = f64::from(n);
            let mut explained = 0.0;
            for k in 0..2 {
                // Normal equations of [sin, cos] for motor k.
                let mut ne = TwoRegressors::default();
                for (i, smp) in self.samples.iter().enumerate() {
                    let (sn, cs) = (nf * smp.motion.angle_rad[k]).sin_cos();
                    ne.add(sn, cs, resid[2 * i + k]);
                }
                if ne.det() > 1e-12 * (ne.uu * ne.vv).max(1e-300) {
                    explained += ne.explained();
                }
            }
            if explained > best.0 {
                best = (explained, nf);
            }
        }
        best.1
    }
}

/// The model with `fit`'s effects added: the plant the prediction runs (the block's own
/// parameters added, the torque constant and cogging as extras).
pub(super) fn with_effects(d0: &FiveBarDynamics<f64>, fit: &Fit) -> (FiveBarDynamics<f64>, Extras) {
    let mut d = *d0;
    let mut x = Extras::default();
    for (i, c) in fit.cands.iter().enumerate() {
        let v = fit.coefs(i);
        match c.e.effect {
            PhysicalEffect::CoulombFriction => (0..2).for_each(|k| d.coulomb_nm[k] += v[k]),
            PhysicalEffect::ViscousFriction => {
                (0..2).for_each(|k| d.viscous_nm_s_per_rad[k] += v[k])
            }
            PhysicalEffect::ToolMass => d.tool_mass_kg += v[0],
            PhysicalEffect::MotorInertia => (0..2).for_each(|k| d.motor_inertia_kg_m2[k] += v[k]),
            PhysicalEffect::TorqueConstant => {
                x.torque_error = [torque_error_of(v[0]), torque_error_of(v[1])]
            }
            PhysicalEffect::Cogging => {
                x.cogging_nm = [[v[0], v[1]], [v[2], v[3]]];
                x.cogging_cycles = c.cycles;
            }
            _ => {}
        }
    }
    (d, x)
}

/// Parameters of candidate `i` of `fit` by name, with standard deviations (cogging as
/// amplitude and phase per motor, and its period).
pub(super) fn params_of(fit: &Fit, std: &[f64], i: usize) -> BTreeMap<String, Param> {
    let c = &fit.cands[i];
    let start: usize = fit.cands[..i].iter().map(|c| c.e.params.len()).sum();
    let v = fit.coefs(i);
    let s = &std[start..start + v.len()];
    let mut out = BTreeMap::new();
    if c.is_cogging() {
        for k in 0..2 {
            let (a, b) = (v[2 * k], v[2 * k + 1]);
            let amp = a.hypot(b);
            let sd = if amp > 0.0 {
                ((a * s[2 * k]).powi(2) + (b * s[2 * k + 1]).powi(2)).sqrt() / amp
            } else {
                s[2 * k].max(s[2 * k + 1])
            };
            out.insert(
                format!("cogging_{}_nm", k + 1),
                Param {
                    value: amp,
                    std_dev: sd,
                },
            );
            out.insert(
                format!("cogging_{}_phase_deg", k + 1),
                Param {
                    value: b.atan2(a).to_degrees(),
                    std_dev: if amp > 0.0 {
                        (sd / amp).to_degrees()
                    } else {
                        f64::INFINITY
                    },
                },
            );
        }
        out.insert(
            "cogging_cycles_per_rev".into(),
            Param {
                value: c.cycles,
                std_dev: 0.0,
            },
        );
    } else if c.e.effect == PhysicalEffect::TorqueConstant {
        // Reported as the torque per command's error (%), its deviation through dk/dc.
        for (k, name) in c.e.params.iter().enumerate() {
            let slope = 100.0 / (100.0 - v[k]).powi(2);
            out.insert(
                name.to_string(),
                Param {
                    value: 100.0 * torque_error_of(v[k]),
                    std_dev: 100.0 * slope * s[k],
                },
            );
        }
    } else {
        for (k, name) in c.e.params.iter().enumerate() {
            out.insert(
                name.to_string(),
                Param {
                    value: v[k],
                    std_dev: s[k],
                },
            );
        }
    }
    out
}

/// Lag-1 correlation of each motor's series in the interleaved `resid`, averaged.
pub(super) fn lag1_correlation(resid: &[f64]) -> f64 {
    let mut rho = 0.0;
    for k in 0..2 {
        let x: Vec<f64> = resid.iter().skip(k).step_by(2).copied().collect();
        let mean = x.iter().sum::<f64>() / x.len().max(1) as f64;
        let var: f64 = x.iter().map(|v| (v - mean).powi(2)).sum();
        let cov: f64 = x.windows(2).map(|w| (w[0] - mean) * (w[1] - mean)).sum();
        rho += if var > 0.0 { cov / var } else { 0.0 };
    }
    (rho / 2.0).clamp(0.0, 0.95)
}

/// The structure test's columns: per motor, its angle about the mean, the square of that, and
/// its speed times its magnitude (zero on the other motor).
pub(super) fn extension_columns(samples: &[MotionSample]) -> Vec<Vec<f64>> {
    let n = samples.len().max(1) as f64;
    let mean = [0, 1].map(|k| samples.iter().map(|s| s.motion.angle_rad[k]).sum::<f64>() / n);
    let mut cols = Vec::new();
    #[allow(clippy::needless_range_loop)] // k picks the motor in three places
    for k in 0..2 {
        let f: [&dyn Fn(&MotionSample) -> f64; 3] = [
            &|s| s.motion.angle_rad[k] - mean[k],
            &|s| (s.motion.angle_rad[k] - mean[k]).powi(2),
            &|s| s.motion.velocity_rad_s[k] * s.motion.velocity_rad_s[k].abs(),
        ];
        for g in f {
            let mut c = Vec::with_capacity(2 * samples.len());
            for s in samples {
                let v = g(s);
                c.extend(if k == 0 { [v, 0.0] } else { [0.0, v] });
            }
            cols.push(c);
        }
    }
    cols
}
