//! A named effect whose library shape does not fully explain its part of the residual: the shape
//! misfit, reported as such, so that the rest is not handed to unrelated effects.
//!
//! A real machine never matches a library shape exactly. The distal bars' stretch, for one, is
//! the library's self-stress modes of the six-bar as drawn (`link_stretch`), but a machine whose
//! bars stiffen or slip under load, whose compliance changes across the workspace, stretches its
//! bars by another law of the configuration. What the library shape leaves is smooth and large
//! next to a micrometre of noise, and effects whose signatures overlap it (on the paper
//! machine's poses the stretch is within a principal cosine of 0.999 of link lengths and of
//! encoder offsets: the report's `pose_overlaps`) each pass the add test on its account: the selection names
//! `link_stretch` + `encoder_offset` + `link_lengths` with neither of the last two there.
//!
//! The rule: an effect named beside a generalisable effect E must stand on its own against E's
//! **generalised shape**, E's physical form with a smooth law of the configuration instead of the
//! library's. For `link_stretch` that is one load law `g` of the link angles (a cubic
//! polynomial, centred and scaled over the data: 10 terms) in place of the linearised loop
//! closure's five modes, elongating b by `g` and c by `r·g`, the ratio `r` a combination of the
//! design's (`(1 + kc/100)·α(θ)`, α the two bars' elongation ratio under the loops'
//! self-stress at the point, the library modes' own, kc the fitted compliance ratio) and of
//! one shared ratio (a load or a warming the two bars share, in the ratio of their compliances
//! or expansions: 1 for the misfit itself; near 1, within a factor 3 either way, the data's, when
//! an effect's standing is judged, `standing.rs`): 20 columns. Their
//! part outside E's own span at the fitted model, reduced by SVD to at most [`N_SHAPE`] unit-RMS
//! modes, is the **shape misfit**, fitted as a nuisance: in every model, never named, what it
//! explains staying in the residual the report prints.
//!
//! The check ([`check_shapes`], after the selection and its nuisances, for each generalisable
//! effect E named): with E's misfit modes fitted alongside, does every other named effect still
//! lower the BIC by more than [`ADD_MARGIN`] (the add test)? The weakest that does not is set
//! aside, the rest refitted, until every one does. No effect the selection did not name comes in
//! (the question is which of the named ones stand, not a new search). Then: is E's misfit
//! significant beside **every** named effect (the BIC lower by more than [`ADD_MARGIN`] with
//! every mode charged, the cross-validated RSS lower by more than the modes cost, k·σ²)?
//! * If so, the named model leaves a misfit: the effects set aside are **not named**
//!   (`not_named`), and the misfit is **kept** (a nuisance: reported, `unexplained`, described
//!   by the law it fits) when it is significant beside what is left; otherwise the final model
//!   is the one left, refitted without it.
//! * If not, the named model explains the data and stays: each named effect that does not lower
//!   the BIC by more than [`ADD_MARGIN`] beside E's misfit modes with every other named effect in
//!   place (the model that stays; no effect set aside first, so that one stand-in cannot carry
//!   another's part and stand in its place) is **declared open** (`open`), named but not
//!   claimed, as an ambiguous pair is. Why not drop them here
//!   too: the generalised shape, flexible as it is, can stand in for a real frame or base
//!   offset beside a library-shaped stretch on sparse data, and dropping them would trade a
//!   false name for a miss; only a misfit the named model leaves is a reason to drop them.
//!
//! Why a generalised shape and not a test of the newcomer's contribution alone: a newcomer's
//! evidence is all in its part orthogonal to the named effects (that is what the joint least
//! squares measure), so orthogonality cannot tell a real encoder offset from one carrying the
//! stretch's misfit; only an alternative explanation of the same residual can. Why the misfit is
//! not charged when the newcomers are judged: the question is what they explain that the named
//! effect's other laws cannot, not whether another law is proven. Why one law for both bars: an
//! arbitrary elongation of each bar reproduces any tool displacement field (two lengths, two
//! coordinates), so it would stand in for every effect; one law with c's ratio in a
//! two-dimensional family leaves a large part of the signature beyond the library's stretch of
//! link lengths, encoder offsets, a base offset, a frame or a gear ratio outside it, so a real
//! one of those of some size stays named. What it costs: an
//! instrument scale, whose signature beyond the stretch lies wholly in it (the stretch alone is
//! within a principal cosine of 0.9988 of it), is not named beside a stretch whose shape
//! misfits, and is listed under `not_named`. Why not the design's ratio alone (10 columns,
//! nearly orthogonal to every five-bar effect): a stiffening or slipping bar changes the ratio
//! with the load, and the part it leaves, c's alone, is what link lengths then take.
//!
//! Cost: when a generalisable effect is named, one Jacobian of its parameters, an SVD of n×20,
//! and one LM fit per named effect and per effect not named (with up to 20 more parameters),
//! two cross-validations.

use super::fit::Fit;
use super::forward_model::Problem;
use super::library::{idx, Effect, LIBRARY, N_SHAPE};
use super::report::ShapeMisfit;
use super::scoring::{delta_bic, sigma2, Fitter, ADD_MARGIN};
use super::selection::Selection;
use super::standing::{judge_standing, JudgedAs};
use crate::effect::PhysicalEffect;
use crate::numeric::finite_difference;
use crate::numeric::subspace::{orthonormal_basis, project_out};
use nalgebra::DMatrix;

/// Effects with a generalised shape.
pub const GENERALISED: [PhysicalEffect; 1] = [PhysicalEffect::LinkStretch];

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
    let t = design.ncols();
    let mut g = DMatrix::zeros(design.nrows(), 2 * t);
    g.columns_mut(0, t).copy_from(&design);
    g.columns_mut(t, t).copy_from(&(b + c * ratio));
    Some(g)
}

/// The generalised stretch's blocks of columns: tool displacement (µm, x,y per point) per µm of
/// each term of the load law `g` as b's elongation, c elongating by `(1 + kc/100)·α(θ)·g` (the
/// design's self-stress ratio at the point, the library modes' own, times the fitted compliance
/// ratio); then per µm of `g` as b's elongation alone, and as c's alone (module doc).
pub(super) fn stretch_blocks(problem: &Problem, kc_pct: f64) -> Option<[DMatrix<f64>; 3]> {
    let n = problem.points.len();
    let spread = spread(problem);
    let terms = terms();
    let h_mm = 1e-3;
    let mut g = DMatrix::zeros(2 * n, 3 * terms.len());
    for (i, p) in problem.points.iter().enumerate() {
        let at = |db: f64, dc: f64| {
            let mut m = problem.base;
            m.b_mm += db;
            m.c_mm += dc;
            m.forward(p.theta_rad, 0.0).ok()
        };
        let (b1, b0) = (at(h_mm, 0.0)?, at(-h_mm, 0.0)?);
        let (c1, c0) = (at(0.0, h_mm)?, at(0.0, -h_mm)?);
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
        let along = |r: f64| [0, 1].map(|a| ((b1[a] - b0[a]) + r * (c1[a] - c0[a])) / (2.0 * h_mm));
        let design = along((1.0 + kc_pct * 0.01) * alpha);
        let (b_only, c_only) = (along(0.0), [0, 1].map(|a| (c1[a] - c0[a]) / (2.0 * h_mm)));
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
    let h_mm = 1e-3;
    let mut g = DMatrix::zeros(2 * problem.points.len(), 4);
    for (i, p) in problem.points.iter().enumerate() {
        let at = |db: f64, dc: f64| {
            let mut m = problem.base;
            m.b_mm += db;
            m.c_mm += dc;
            m.forward(p.theta_rad, 0.0).ok()
        };
        let (b1, b0) = (at(h_mm, 0.0)?, at(-h_mm, 0.0)?);
        let (c1, c0) = (at(0.0, h_mm)?, at(0.0, -h_mm)?);
        let jb = [0, 1].map(|a| (b1[a] - b0[a]) / (2.0 * h_mm));
        let jc = [0, 1].map(|a| (c1[a] - c0[a]) / (2.0 * h_mm));
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
fn misfit_rms_um(problem: &Problem, x: &[f64]) -> f64 {
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

/// The shape-misfit check of the module doc on the selection `sel` (its nuisances set in
/// `problem`). Returns the selection to report, the misfit for the report (when an effect was
/// not named on its account or the misfit is kept) and log lines; when the misfit is kept,
/// `problem` has it as a nuisance.
pub fn check_shapes(
    problem: &mut Problem,
    sel: Selection,
    noise_um: Option<f64>,
) -> (Selection, Option<ShapeMisfit>, Vec<String>) {
    let mut log = Vec::new();
    for kind in GENERALISED {
        let Some(e) = LIBRARY.iter().find(|e| e.kind == kind) else {
            continue;
        };
        if !sel.effects.contains(&e) || problem.available(e).is_err() {
            continue;
        }
        match check_one(problem, &sel, e, noise_um, &mut log) {
            Some((Some((with, p)), misfit)) => {
                *problem = p;
                return (with, Some(misfit), log);
            }
            Some((None, misfit)) => return (sel, Some(misfit), log),
            None => {}
        }
    }
    (sel, None, log)
}

/// [`check_shapes`] for one named generalisable effect `e`: `Some` with the selection, the misfit
/// and the problem to report when the misfit changes the outcome (an effect not named, or the
/// misfit kept).
fn check_one(
    problem: &Problem,
    sel: &Selection,
    e: &'static Effect,
    noise_um: Option<f64>,
    log: &mut Vec<String>,
) -> Option<(Option<(Selection, Problem)>, ShapeMisfit)> {
    // The misfit the named model leaves is judged, and kept, at equal elongations of the two
    // bars (a shared ratio fitted beside every named effect can run to the end of its range and
    // trade hundreds of micrometres with them); each effect's standing at the ratio the data
    // give without it (`standing.rs`).
    let mut with = problem.clone();
    with.nuisance.shape = None;
    let modes = match set_misfit_modes(&mut with, e, &sel.fit.p, 1.0) {
        Ok(m) => m,
        Err(why) => {
            log.push(format!("{}: no shape-misfit check: {why}", e.name()));
            return None;
        }
    };
    let k_modes = with.nuisance.shape.map_or(0, |(_, k)| k);
    let mut plain = with.clone();
    plain.nuisance.shape = None;
    let mut fitter = Fitter::new(&with);
    let mut set = sel.effects.clone();
    let mut cur = fitter.fit(&set, &sel.fit.p)?;
    // First: does the named model leave a misfit at all? Judged with every named effect in
    // place, so that a model that explains the data (the library's own stretch beside a real
    // frame, to the noise) is left alone: the generalised shape could stand in for those
    // effects too, and only a misfit the named model cannot explain is a reason to doubt them.
    let first = significance(&with, &plain, &set, &sel.fit, &cur, noise_um, k_modes)?;
    if !first.significant {
        // The named model explains the data: it stays, but each named effect that does not stand
        // beside the generalised shape, judged with every other named effect in place (the model
        // that stays), is declared open (a stretch of another law explains what it does as well),
        // not claimed.
        let judged = judge_standing(
            &plain,
            e,
            &sel.fit.p,
            &set,
            &JudgedAs {
                exempt: &[e],
                load_only: &[],
            },
            &cur,
            noise_um,
        );
        let supports = supports_text(&judged);
        let open: Vec<String> = judged
            .iter()
            .filter(|(_, _, stands)| !stands)
            .map(|(c, _, _)| c.name().to_string())
            .collect();
        if open.is_empty() {
            log.push(format!(
                "{}'s shape misfit not significant beside the named effects ({}) and every named effect stands \
                 beside its generalised shape (lowering the BIC by {supports})",
                e.name(),
                first.text()
            ));
            return None;
        }
        log.push(format!(
            "{}'s shape misfit not significant beside the named effects ({}): they stay named; open: {} (beside \
             {}'s generalised shape and the other named effects they do not lower the BIC by > {ADD_MARGIN}: \
             {supports})",
            e.name(),
            first.text(),
            open.join(", "),
            e.name()
        ));
        let description = describe(&with, &modes, &cur.p);
        return Some((
            None,
            ShapeMisfit {
                effect: e.name().to_string(),
                effect_named: true,
                significant: false,
                rms_um: 0.0,
                delta_bic: first.delta_bic,
                delta_cv_rss_um2: first.cv_with - first.cv_without,
                not_named: Vec::new(),
                open,
                description: format!(
                    "not significant beside the named effects; what the effects declared open explain, a stretch of \
                     another law explains as well ({description})"
                ),
            },
        ));
    }
    // The named model leaves a misfit: does every other named effect stand on its own beside
    // e's generalised shape? The weakest that does not is dropped, the rest refitted, until every
    // one does.
    loop {
        let mut weakest: Option<(f64, usize, Fit)> = None;
        for (i, c) in set.iter().enumerate() {
            if *c == e {
                continue;
            }
            let mut trial = set.clone();
            trial.remove(i);
            let Some(f) = fitter.fit(&trial, &cur.p) else {
                continue;
            };
            let support = delta_bic(&with, noise_um, &cur, &f);
            if support < ADD_MARGIN && weakest.as_ref().is_none_or(|w| support < w.0) {
                weakest = Some((support, i, f));
            }
        }
        let Some((support, i, f)) = weakest else {
            break;
        };
        log.push(format!(
            "beside {}'s generalised shape ({k_modes} modes) {} lowers the BIC by {support:.1} (an effect needs > \
             {ADD_MARGIN}): not named",
            e.name(),
            set[i].name()
        ));
        set.remove(i);
        cur = f;
    }
    let mut outcome = Selection {
        effects: set,
        fit: cur,
        log: Vec::new(),
        skipped: Vec::new(),
    };
    let not_named: Vec<String> = sel
        .effects
        .iter()
        .filter(|c| !outcome.effects.contains(c))
        .map(|c| c.name().to_string())
        .collect();
    // Is the misfit itself significant beside what is left, every mode charged?
    let without = Fitter::new(&plain).fit(&outcome.effects, &outcome.fit.p)?;
    let last = significance(
        &with,
        &plain,
        &outcome.effects,
        &without,
        &outcome.fit,
        noise_um,
        k_modes,
    )?;
    let (significant, d_misfit) = (last.significant, last.delta_bic);
    let (cv_without, cv_with) = (last.cv_without, last.cv_with);
    if not_named.is_empty() {
        log.push(format!(
            "{}'s shape misfit ({}): every named effect stands beside it",
            e.name(),
            last.text()
        ));
        if !significant {
            return None;
        }
    }
    let rms_um = misfit_rms_um(&with, &outcome.fit.p);
    let description = describe(&with, &modes, &outcome.fit.p);
    let why_not = if not_named.is_empty() {
        String::new()
    } else {
        format!(
            "; not named: {} (beside {}'s generalised shape they do not lower the BIC by > {ADD_MARGIN})",
            not_named.join(", "),
            e.name()
        )
    };
    let mut first_log = sel.log.clone();
    first_log.append(&mut outcome.log);
    outcome.log = first_log;
    outcome.skipped = sel.skipped.clone();
    let report_problem = if significant {
        log.push(format!(
            "{}'s shape misfit kept as a nuisance ({k_modes} modes, {rms_um:.2} µm RMS; ΔBIC {d_misfit:.1}, \
             cross-validated RSS {cv_without:.1} → {cv_with:.1} µm²){why_not}",
            e.name()
        ));
        with
    } else {
        log.push(format!(
            "{}'s shape misfit not significant on its own (ΔBIC {d_misfit:.1}, cross-validated RSS {cv_without:.1} → \
             {cv_with:.1} µm²): not kept{why_not}",
            e.name()
        ));
        outcome.fit = without;
        plain
    };
    let misfit = ShapeMisfit {
        effect: e.name().to_string(),
        effect_named: true,
        significant,
        rms_um: if significant { rms_um } else { 0.0 },
        delta_bic: d_misfit,
        delta_cv_rss_um2: cv_with - cv_without,
        not_named,
        open: Vec::new(),
        description: if significant {
            description
        } else {
            format!(
                "not significant on its own; what the effects not named explain, a stretch of another law explains as \
                 well ({description})"
            )
        },
    };
    Some((Some((outcome, report_problem)), misfit))
}

/// Each judged effect's support (how much it lowers the BIC beside the generalised shape), for
/// the log.
pub(super) fn supports_text(judged: &[(&'static Effect, f64, bool)]) -> String {
    judged
        .iter()
        .map(|(c, s, _)| format!("{} {s:.1}", c.name()))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The misfit's significance: the BIC lower by more than [`ADD_MARGIN`] with every mode charged,
/// and the cross-validated RSS lower by more than the modes cost (k·σ²).
struct Significance {
    significant: bool,
    delta_bic: f64,
    cv_without: f64,
    cv_with: f64,
    margin: f64,
}

impl Significance {
    fn text(&self) -> String {
        format!(
            "ΔBIC {:.1}, needs < −{ADD_MARGIN}; cross-validated RSS {:.1} → {:.1} µm², needs a drop > {:.1}",
            self.delta_bic, self.cv_without, self.cv_with, self.margin
        )
    }
}

/// [`Significance`] of the misfit modes of `with` for the effects `set`, fitted without them
/// (`plain`, `fit_plain`) and with them (`fit_with`).
fn significance(
    with: &Problem,
    plain: &Problem,
    set: &[&'static Effect],
    fit_plain: &Fit,
    fit_with: &Fit,
    noise_um: Option<f64>,
    k_modes: usize,
) -> Option<Significance> {
    let delta_bic = delta_bic(with, noise_um, fit_plain, fit_with);
    let s2 = sigma2(with, noise_um, &[fit_plain, fit_with]);
    let cv_without = Fitter::new(plain).cv_rss(set, &fit_plain.p)?;
    let cv_with = Fitter::new(with).cv_rss(set, &fit_with.p)?;
    let margin = k_modes as f64 * s2;
    Some(Significance {
        significant: delta_bic < -ADD_MARGIN && cv_with < cv_without - margin,
        delta_bic,
        cv_without,
        cv_with,
        margin,
    })
}
