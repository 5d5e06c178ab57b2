//! The shapes a named effect's misfit is fitted with, as columns and as the shape-misfit
//! nuisance's modes written into the points: the **generalised stretch** (one smooth load law of
//! the configuration elongating both distal bars, [`stretch_columns`], [`stretch_blocks`]) and an
//! **external load** on the platform carried by the bars' own compliances ([`load_columns`]).
//! Why these shapes and how the check uses them: [`super::shape`]'s module doc; the standing of
//! an effect beside them: [`super::standing`].
//!
//! Cost: a Jacobian of the tool position per link elongation at every point (finite
//! differences), an SVD of n×20 (n the points' coordinates) for the modes.

use super::forward_model::Problem;
use super::library::{idx, Effect, N_SHAPE};
use crate::effect::PhysicalEffect;
use crate::numeric::finite_difference;
use crate::numeric::subspace::{orthonormal_basis, project_out};
use nalgebra::DMatrix;

/// Degree of the polynomial law of the generalised stretch.
const DEGREE: usize = 3;

/// A mode is kept when its singular value is above this fraction of the generalisation's
/// largest (before the projection): below it, the direction is the library's own to rounding.
const MODE_TOL: f64 = 1e-3;

/// The exponents (i, j) of the terms u^i·v^j of the polynomial law, total degree ≤ [`DEGREE`].
fn terms() -> Vec<(i32, i32)> {
    let mut t = Vec::new();
    for d in 0..=DEGREE as i32 {
        for i in (0..=d).rev() {
            t.push((i, d - i));
        }
    }
    t
}

/// The generalised stretch's columns at the shared ratio `ratio`: [`stretch_blocks`]' design
/// block, then b's block plus `ratio` times c's (module doc).
pub(super) fn stretch_columns(problem: &Problem, kc_pct: f64, ratio: f64) -> Option<DMatrix<f64>> {
    let [design, b, c] = stretch_blocks(problem, kc_pct)?;
    Some(at_ratio(&design, &b, &c, ratio))
}

/// [`stretch_blocks`]' three blocks (or any linear image of them, such as their projection)
/// assembled at the shared ratio `ratio`: the design block, then `b + ratio·c`.
pub(super) fn at_ratio(
    design: &DMatrix<f64>,
    b: &DMatrix<f64>,
    c: &DMatrix<f64>,
    ratio: f64,
) -> DMatrix<f64> {
    let t = design.ncols();
    let mut g = DMatrix::zeros(design.nrows(), 2 * t);
    g.columns_mut(0, t).copy_from(design);
    g.columns_mut(t, t).copy_from(&(b + c * ratio));
    g
}

/// The generalised stretch's blocks of columns: tool displacement (µm, x,y per point) per µm of
/// each term of the load law `g` as b's elongation, c elongating by `(1 + kc/100)·α(θ)·g` (the
/// design's self-stress ratio at the point, the library modes' own, times the fitted compliance
/// ratio); then per µm of `g` as b's elongation alone, and as c's alone (module doc).
pub(super) fn stretch_blocks(problem: &Problem, kc_pct: f64) -> Option<[DMatrix<f64>; 3]> {
    let n = problem.points.len();
    let spread = spread(problem);
    let terms = terms();
    let mut g = DMatrix::zeros(2 * n, 3 * terms.len());
    for (i, p) in problem.points.iter().enumerate() {
        let [jb, jc] = distal_jacobians(problem, p.theta_rad)?;
        let sb: f64 = p.stretch_u[0].iter().map(|v| v * v).sum();
        let alpha = if sb > 0.0 {
            p.stretch_u[0]
                .iter()
                .zip(&p.stretch_u[1])
                .map(|(b, c)| b * c)
                .sum::<f64>()
                / sb
        } else {
            1.0
        };
        // µm of tool per µm of b's elongation with c's by each ratio.
        let along = |r: f64| [0, 1].map(|a| jb[a] + r * jc[a]);
        let design = along((1.0 + kc_pct * 0.01) * alpha);
        let (b_only, c_only) = (jb, jc);
        let (u, v) = (
            p.theta_centred_rad[0] / spread[0],
            p.theta_centred_rad[1] / spread[1],
        );
        for (k, &(a, b)) in terms.iter().enumerate() {
            let gk = u.powi(a) * v.powi(b);
            for axis in 0..2 {
                g[(2 * i + axis, k)] = gk * design[axis];
                g[(2 * i + axis, terms.len() + k)] = gk * b_only[axis];
                g[(2 * i + axis, 2 * terms.len() + k)] = gk * c_only[axis];
            }
        }
    }
    let t = terms.len();
    Some([0, 1, 2].map(|b| g.columns(b * t, t).into_owned()))
}

/// The external load's columns: tool displacement (µm, x,y per point) per unit of b's
/// compliance times a unit force on the platform along x and along y, then the same for c's
/// (the `load` alternative of `standing.rs`).
///
/// Why this form: a force `F` from outside the loops (a hose's or a cable's drag, a weight on a
/// tilted machine) is carried by the two distal bars as the pose's statics say, `t = U⁻ᵀ·F`
/// (`U`'s rows the bars' unit vectors toward the tool point); each bar elongates by its tension
/// times its compliance, and the tool moves by `d = U⁻¹·δ`. With `J_b = U⁻¹·e_b` the tool's
/// displacement per µm of b's elongation alone (what the finite differences give), b's tension
/// is `J_b·F`, so `d = k_b·J_b·(J_b·F) + k_c·J_c·(J_c·F)`: four columns linear in the products
/// of each bar's compliance and each force component, the compliance shape `J·K·Jᵀ·F` of the
/// load. The two bars' tensions have opposite signs over much of the workspace, so no shared
/// ratio of the generalised shape follows them.
pub(super) fn load_columns(problem: &Problem) -> Option<DMatrix<f64>> {
    let mut g = DMatrix::zeros(2 * problem.points.len(), 4);
    for (i, p) in problem.points.iter().enumerate() {
        let [jb, jc] = distal_jacobians(problem, p.theta_rad)?;
        for (bar, j) in [jb, jc].iter().enumerate() {
            for force_axis in 0..2 {
                for axis in 0..2 {
                    g[(2 * i + axis, 2 * bar + force_axis)] = j[axis] * j[force_axis];
                }
            }
        }
    }
    Some(g)
}

/// The tool's displacement (µm) per µm of elongation of b and of c at the link angles
/// `theta_rad` of the model the problem is linearised about (central differences, 1 µm step);
/// `None` when a point leaves the model's workspace.
fn distal_jacobians(problem: &Problem, theta_rad: [f64; 2]) -> Option<[[f64; 2]; 2]> {
    let h_mm = 1e-3;
    let at = |db: f64, dc: f64| {
        let mut m = problem.base;
        m.b_mm += db;
        m.c_mm += dc;
        m.forward(theta_rad, 0.0).ok()
    };
    let (b1, b0) = (at(h_mm, 0.0)?, at(-h_mm, 0.0)?);
    let (c1, c0) = (at(0.0, h_mm)?, at(0.0, -h_mm)?);
    Some([
        [0, 1].map(|a| (b1[a] - b0[a]) / (2.0 * h_mm)),
        [0, 1].map(|a| (c1[a] - c0[a]) / (2.0 * h_mm)),
    ])
}

/// The RMS of each centred link angle over the points (rad): the law's units.
fn spread(problem: &Problem) -> [f64; 2] {
    let n = problem.points.len().max(1) as f64;
    [0, 1].map(|j| {
        (problem
            .points
            .iter()
            .map(|p| p.theta_centred_rad[j].powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
            .max(1e-9)
    })
}

/// The law behind the misfit modes: each mode's coefficients on the law's terms (µm of b's
/// elongation per unit of the mode), for [`describe`].
pub struct MisfitModes {
    pub effect: PhysicalEffect,
    /// The shared ratio of c's elongation to b's in the second block of the law.
    pub ratio: f64,
    /// Per mode: the coefficients of the terms (u^i·v^j) it stands for.
    pub law: Vec<Vec<f64>>,
}

/// Sets the problem's shape-misfit nuisance for `e` fitted at `x`: the generalised shape's part
/// outside `e`'s own span there, as at most [`N_SHAPE`] unit-RMS modes written into the points.
/// Returns the modes' law; `Err` says why there are none.
pub fn set_misfit_modes(
    problem: &mut Problem,
    e: &Effect,
    x: &[f64],
    ratio: f64,
) -> Result<MisfitModes, String> {
    if e.kind != PhysicalEffect::LinkStretch {
        return Err(format!("{} has no generalised shape", e.name()));
    }
    let g = stretch_columns(problem, x[idx::STRETCH_RATIO], ratio)
        .ok_or("a point left the model's workspace while differentiating")?;
    let law = set_modes(problem, e, x, &g)?;
    Ok(MisfitModes {
        effect: e.kind,
        ratio,
        law,
    })
}

/// Sets the problem's shape-misfit nuisance for the stretch `e` fitted at `x` to an external
/// load's compliance shape ([`load_columns`]) outside `e`'s own span there: the number of
/// modes, or why there are none.
pub fn set_load_modes(problem: &mut Problem, e: &Effect, x: &[f64]) -> Result<usize, String> {
    if e.kind != PhysicalEffect::LinkStretch {
        return Err(format!("{} has no generalised shape", e.name()));
    }
    let g =
        load_columns(problem).ok_or("a point left the model's workspace while differentiating")?;
    set_modes(problem, e, x, &g).map(|law| law.len())
}

/// Writes the part of the columns `g` outside `e`'s own span at `x` into the problem's
/// shape-misfit nuisance, as at most [`N_SHAPE`] unit-RMS modes; returns each mode's
/// coefficients on `g`'s columns.
fn set_modes(
    problem: &mut Problem,
    e: &Effect,
    x: &[f64],
    g: &DMatrix<f64>,
) -> Result<Vec<Vec<f64>>, String> {
    let n = problem.points.len();
    let mut without = problem.clone();
    without.nuisance.shape = None;
    let own = finite_difference::jacobian(&without, x, e.params)
        .map_err(|_| "a point left the model's workspace while differentiating")?;
    let projected = project_out(g, &orthonormal_basis(&own));
    let top = g.clone().singular_values().max();
    let svd = projected.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return Err("no SVD of the generalised shape".into());
    };
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let keep: Vec<usize> = order
        .into_iter()
        .filter(|&k| svd.singular_values[k] > MODE_TOL * top)
        .take(N_SHAPE)
        .collect();
    if keep.is_empty() {
        return Err("the generalised shape adds nothing to the library's on these poses".into());
    }
    // Unit RMS over the points: column norm √n (x and y of a point together).
    let scale = (n as f64).sqrt();
    for (i, p) in problem.points.iter_mut().enumerate() {
        p.shape_um = [[0.0; 2]; N_SHAPE];
        for (m, &k) in keep.iter().enumerate() {
            p.shape_um[m] = [u[(2 * i, k)] * scale, u[(2 * i + 1, k)] * scale];
        }
    }
    let law = keep
        .iter()
        .map(|&k| {
            (0..vt.ncols())
                .map(|t| vt[(k, t)] * scale / svd.singular_values[k])
                .collect()
        })
        .collect();
    problem.nuisance.shape = Some((e.kind, keep.len()));
    Ok(law)
}

/// The radial RMS (µm) of the shape misfit's fitted part.
pub(super) fn misfit_rms_um(problem: &Problem, x: &[f64]) -> f64 {
    let k = problem.nuisance.shape.map_or(0, |(_, k)| k);
    let ss: f64 = problem
        .points
        .iter()
        .map(|p| {
            let d = (0..k).fold([0.0; 2], |d, m| {
                [
                    d[0] + x[idx::SHAPE + m] * p.shape_um[m][0],
                    d[1] + x[idx::SHAPE + m] * p.shape_um[m][1],
                ]
            });
            d[0] * d[0] + d[1] * d[1]
        })
        .sum();
    (ss / problem.points.len().max(1) as f64).sqrt()
}

/// The misfit's law as text: b's elongation (µm) as a polynomial of the centred, scaled link
/// angles u, v, its RMS over the data and its largest terms, and how much of it c follows in the
/// design's self-stress ratio.
pub(super) fn describe(problem: &Problem, modes: &MisfitModes, x: &[f64]) -> String {
    let terms = terms();
    let t = terms.len();
    let mut coef = vec![0.0; 2 * t];
    for (m, law) in modes.law.iter().enumerate() {
        for (c, l) in coef.iter_mut().zip(law) {
            *c += x[idx::SHAPE + m] * l;
        }
    }
    let n = problem.points.len().max(1) as f64;
    let spread = spread(problem);
    let rms = |c: &[f64]| {
        (problem
            .points
            .iter()
            .map(|p| {
                let (u, v) = (
                    p.theta_centred_rad[0] / spread[0],
                    p.theta_centred_rad[1] / spread[1],
                );
                terms
                    .iter()
                    .zip(c)
                    .map(|(&(a, b), c)| c * u.powi(a) * v.powi(b))
                    .sum::<f64>()
                    .powi(2)
            })
            .sum::<f64>()
            / n)
            .sqrt()
    };
    let b_law: Vec<f64> = (0..t).map(|k| coef[k] + coef[t + k]).collect();
    let name = |(a, b): (i32, i32)| {
        let p = |s: &str, e: i32| match e {
            0 => String::new(),
            1 => s.to_string(),
            e => format!("{s}^{e}"),
        };
        let parts: Vec<String> = [p("u", a), p("v", b)]
            .into_iter()
            .filter(|s| !s.is_empty())
            .collect();
        if parts.is_empty() {
            "1".to_string()
        } else {
            parts.join("·")
        }
    };
    let mut order: Vec<usize> = (0..t).collect();
    order.sort_by(|&a, &b| b_law[b].abs().total_cmp(&b_law[a].abs()));
    let largest: Vec<String> = order
        .iter()
        .take(3)
        .map(|&k| format!("{:+.2}·{}", b_law[k], name(terms[k])))
        .collect();
    format!(
        "the distal bars stretch by another law of the configuration than the library's self-stress modes: b's \
         elongation beyond them {:.2} µm RMS over the data, largest terms {} (u, v: the link angles about their \
         circular means, in units of their spread); of it, {:.2} µm RMS with c in the design's self-stress ratio, \
         {:.2} µm RMS with c at {:.2} times b's",
        rms(&b_law),
        largest.join(" "),
        rms(&coef[..t]),
        rms(&coef[t..]),
        modes.ratio
    )
}
