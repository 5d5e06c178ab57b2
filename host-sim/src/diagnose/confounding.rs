//! Which effects the data cannot tell apart, and what measurement would.
//!
//! Two effects are confounded on a data set when the residual one of them explains could be
//! explained as well by the other: swapping them would not change the fit by more than the noise
//! can resolve (see [`overlaps`]; linearised with the identification Jacobian, after projecting
//! out the other effects of the final model, since what they explain cannot tell the two apart
//! either). Partial overlaps (some combination of one's parameters acts exactly like the other)
//! are listed with the smallest principal angle between the column spaces.
//!
//! Examples on this machine (A0 = B0): a common encoder offset rotates the whole mechanism about
//! A0, exactly what a frame rotation does (cos = 1); a common scale of all links scales every
//! point about A0, exactly what the instrument scale does (cos = 1).
//!
//! Cost: one Jacobian over all library parameters (≤ 37 residual evaluations) and a few thin
//! SVDs of n×≤18 matrices.

use super::fit::{jacobian, Fit};
use super::forward_model::Problem;
use super::library::{Effect, PARAM_NAMES};
use crate::numeric::subspace::{max_cos, orthonormal_basis, project_out};
use nalgebra::{DMatrix, DVector};
use serde::Serialize;

/// χ² cost of swapping below which two effects are confounded (5σ of one degree of freedom).
pub const SWAP_CHI2: f64 = 25.0;
/// z-score of the shared part above which a partial overlap counts as confounded.
pub const SHARED_Z: f64 = 5.0;
/// Principal-angle cosine from which a partial overlap is listed (1 − 1e-6: exact up to rounding).
pub const PARTIAL_COS: f64 = 1.0 - 1e-6;

/// One pair of effects and how much of their residual signatures coincide.
#[derive(Clone, Debug, Serialize)]
pub struct Overlap {
    /// The effect of the final model.
    pub effect: String,
    /// The other candidate (in the final model or not).
    pub other: String,
    /// Share (cosine) of the effect's fitted contribution the other can reproduce.
    pub cos: f64,
    /// χ² cost of explaining the effect's contribution with the other instead.
    pub swap_chi2: f64,
    /// Cosine of the smallest principal angle between their Jacobian column spaces (1 = some
    /// combination of the effect's parameters is indistinguishable from the other).
    pub principal_cos: f64,
    /// When `principal_cos` is 1: the combination of the effect's parameters that acts exactly
    /// like the other (unit vector, e.g. "0.707·dtheta1_urad + 0.707·dtheta2_urad").
    pub shared_direction: String,
    /// The fitted value along that combination, and its z-score.
    pub shared_value: f64,
    pub shared_z: f64,
    /// Confounded: `swap_chi2` < [`SWAP_CHI2`] (the data cannot prefer one over the other), or a
    /// significant part of the effect (`shared_z` > [`SHARED_Z`]) could equally be the other.
    pub confounded: bool,
    /// What measurement would separate them.
    pub separate_by: String,
}

/// What would separate two effects.
pub fn separating_measurement(a: &str, b: &str) -> String {
    let mut pair = [a, b];
    pair.sort();
    match pair {
        ["encoder_offset", "frame"] => "measure with the instrument rotated by a known angle, or measure a reference \
             direction (two points on a straight edge of known orientation): a common motor offset turns the mechanism \
             about A0 exactly as an instrument rotation turns the readings"
            .into(),
        ["link_lengths", "scale"] => "measure a reference length (gauge block / step gauge) with the instrument: a \
             common scale of all links scales every point about A0 exactly as the instrument scale does"
            .into(),
        ["encoder_offset", "gear_ratio"] | ["backlash", "encoder_offset"] => {
            "measure over a wider range of motor angles, from both approach directions".into()
        }
        ["base_offset", "frame"] | ["base_offset", "link_lengths"] => {
            "measure poses farther apart in the workspace (larger motor angle range), or measure B0 directly".into()
        }
        _ => "measure configurations where the two act differently (wider motor-angle range, both approach \
              directions, the instrument moved)"
            .into(),
    }
}

fn columns(j: &DMatrix<f64>, all: &[usize], params: &[usize]) -> DMatrix<f64> {
    let idx: Vec<usize> = params
        .iter()
        .filter_map(|p| all.iter().position(|q| q == p))
        .collect();
    DMatrix::from_fn(j.nrows(), idx.len(), |r, c| j[(r, idx[c])])
}

/// Zeroes the columns that the projection reduced to rounding (< 1e-4 of their norm before):
/// what is left of them has no direction.
fn drop_vanished(mut projected: DMatrix<f64>, before: &DMatrix<f64>) -> DMatrix<f64> {
    for c in 0..projected.ncols() {
        if projected.column(c).norm() < 1e-4 * before.column(c).norm() {
            projected.column_mut(c).fill(0.0);
        }
    }
    projected
}

/// For each effect E of the final model and each other available candidate C: can C (with the
/// rest of the final model) reproduce what E explains in these data? `vE = J_E·p_E` is E's fitted
/// contribution; after projecting out the rest of the model, the part of `vE` that C's columns
/// cannot reproduce costs `miss/σ²` in χ² if E were swapped for C. Confounded when that cost is
/// below [`SWAP_CHI2`] (the data cannot prefer E over C). Independently, the smallest principal
/// angle between the two column spaces says whether *some* combination of E's parameters is
/// indistinguishable from C (e.g. the common part of two encoder offsets and a frame rotation):
/// if E's fitted value along that combination is significant (z > [`SHARED_Z`]), that part of
/// E could equally be C, and the pair is confounded too; otherwise it is listed as partial.
pub fn overlaps(
    problem: &Problem,
    fit: &Fit,
    final_set: &[&'static Effect],
    candidates: &[&'static Effect],
    s2_um2: f64,
) -> Vec<Overlap> {
    let x = &fit.p;
    let all = super::library::params_of(candidates);
    let Some(j) = jacobian(problem, x, &all) else {
        return vec![];
    };
    let mut out: Vec<Overlap> = Vec::new();
    for &e in final_set {
        for &c in candidates {
            if c.name() == e.name() {
                continue;
            }
            let rest: Vec<usize> = final_set
                .iter()
                .filter(|f| f.name() != e.name() && f.name() != c.name())
                .flat_map(|f| f.params.iter().copied())
                .collect();
            let q = orthonormal_basis(&columns(&j, &all, &rest));
            let je = drop_vanished(
                project_out(&columns(&j, &all, e.params), &q),
                &columns(&j, &all, e.params),
            );
            let jc = drop_vanished(
                project_out(&columns(&j, &all, c.params), &q),
                &columns(&j, &all, c.params),
            );
            let pe = DVector::from_iterator(e.params.len(), e.params.iter().map(|&k| x[k]));
            let ve = &je * pe;
            let qc = orthonormal_basis(&jc);
            let explained = if qc.ncols() > 0 {
                &qc * (qc.transpose() * &ve)
            } else {
                ve.clone() * 0.0
            };
            let miss = (&ve - &explained).norm_squared();
            let cos = if ve.norm() > 0.0 {
                explained.norm() / ve.norm()
            } else {
                0.0
            };
            let swap_chi2 = miss / s2_um2.max(1e-12);
            let principal_cos = max_cos(&je, &jc);
            let (shared_direction, shared_value, shared_z) = if principal_cos >= PARTIAL_COS {
                shared_part(e, &je, &jc, fit, s2_um2)
            } else {
                (String::new(), 0.0, 0.0)
            };
            let confounded = (swap_chi2 < SWAP_CHI2
                && ve.norm_squared() / s2_um2.max(1e-12) > SWAP_CHI2)
                || shared_z > SHARED_Z;
            if confounded || principal_cos >= PARTIAL_COS {
                out.push(Overlap {
                    effect: e.name().into(),
                    other: c.name().into(),
                    cos,
                    swap_chi2,
                    principal_cos,
                    shared_direction,
                    shared_value,
                    shared_z,
                    confounded,
                    separate_by: separating_measurement(e.name(), c.name()),
                });
            }
        }
    }
    out.sort_by(|a, b| a.swap_chi2.total_cmp(&b.swap_chi2));
    out
}

/// The exactly shared part of effect `e` with another candidate: the null direction of
/// `[J_E, J_C]` restricted to E's parameters (unit vector in E's parameter units), E's fitted value
/// along it and that value's z-score under the final fit's covariance.
fn shared_part(
    e: &Effect,
    je: &DMatrix<f64>,
    jc: &DMatrix<f64>,
    fit: &Fit,
    s2_um2: f64,
) -> (String, f64, f64) {
    let (ke, kc) = (je.ncols(), jc.ncols());
    let mut m = DMatrix::zeros(je.nrows(), ke + kc);
    m.columns_mut(0, ke).copy_from(je);
    m.columns_mut(ke, kc).copy_from(jc);
    let svd = m.svd(false, true);
    let Some(vt) = svd.v_t else {
        return (String::new(), 0.0, 0.0);
    };
    let Some((imin, _)) = svd
        .singular_values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
    else {
        return (String::new(), 0.0, 0.0);
    };
    let d = DVector::from_iterator(ke, (0..ke).map(|i| vt[(imin, i)]));
    let norm = d.norm();
    if norm < 1e-6 {
        return (String::new(), 0.0, 0.0);
    }
    let mut d = d / norm;
    // Sign: make the largest component positive, for a readable description.
    if d.iter()
        .fold(0.0f64, |a, &v| if v.abs() > a.abs() { v } else { a })
        < 0.0
    {
        d = -d;
    }
    let cols: Vec<Option<usize>> = e
        .params
        .iter()
        .map(|k| fit.free.iter().position(|f| f == k))
        .collect();
    let alpha: f64 = e
        .params
        .iter()
        .zip(d.iter())
        .map(|(&k, &w)| fit.p[k] * w)
        .sum();
    let mut var = 0.0;
    for (a, ca) in cols.iter().enumerate() {
        for (b, cb) in cols.iter().enumerate() {
            if let (Some(ca), Some(cb)) = (ca, cb) {
                var += d[a] * d[b] * fit.normal_pinv[(*ca, *cb)] * s2_um2;
            }
        }
    }
    let z = if var > 0.0 {
        alpha.abs() / var.sqrt()
    } else {
        0.0
    };
    let desc: Vec<String> = e
        .params
        .iter()
        .zip(d.iter())
        .filter(|(_, w)| w.abs() > 1e-3)
        .map(|(&k, w)| format!("{w:.3}·{}", PARAM_NAMES[k]))
        .collect();
    (desc.join(" + "), alpha, z)
}

/// The confounded pairs, names sorted within a pair.
pub fn confounded(overlaps: &[Overlap]) -> Vec<Vec<String>> {
    let mut out: Vec<Vec<String>> = Vec::new();
    for o in overlaps.iter().filter(|o| o.confounded) {
        let mut pair = vec![o.effect.clone(), o.other.clone()];
        pair.sort();
        if !out.contains(&pair) {
            out.push(pair);
        }
    }
    out
}

/// A pair of candidates whose signatures share a direction on these poses, whatever the model.
#[derive(Clone, Debug, Serialize)]
pub struct PoseOverlap {
    pub a: String,
    pub b: String,
    /// Cosine of the smallest principal angle between their Jacobian column spaces.
    pub principal_cos: f64,
}

/// What the pose set itself can separate: every pair of available candidates whose column
/// spaces share a direction with cos ≥ `min_cos` (no other effect projected out). On few poses
/// (Table I) this lists what no fit on these data could tell apart.
pub fn pose_set_overlaps(
    problem: &Problem,
    x: &[f64],
    candidates: &[&'static Effect],
    min_cos: f64,
) -> Vec<PoseOverlap> {
    let all = super::library::params_of(candidates);
    let Some(j) = jacobian(problem, x, &all) else {
        return vec![];
    };
    let mut out = Vec::new();
    for (i, a) in candidates.iter().enumerate() {
        for b in &candidates[i + 1..] {
            let cos = max_cos(&columns(&j, &all, a.params), &columns(&j, &all, b.params));
            if cos >= min_cos {
                out.push(PoseOverlap {
                    a: a.name().into(),
                    b: b.name().into(),
                    principal_cos: cos,
                });
            }
        }
    }
    // Largest cosine first; cosines equal to 1e-9 (e.g. two exact confoundings, 1 to rounding)
    // in name order, so rounding noise does not reorder the report.
    let key = |o: &PoseOverlap| (o.principal_cos * 1e9).round();
    out.sort_by(|p, q| {
        key(q)
            .total_cmp(&key(p))
            .then_with(|| (&p.a, &p.b).cmp(&(&q.a, &q.b)))
    });
    out
}
