//! The verdict on what is left: is the final residual above the noise, and what does it look
//! like? `unexplained` with the structure that describes it (never a name).
//!
//! With σ known: χ²/dof of the library model above max(1 + 4·√(2/dof), 1.21) (the χ² test at
//! about 4σ of its distribution, with a practical floor of 10 % over the noise, so that a
//! slightly misjudged noise figure does not read as a missing effect), or any nuisance fitted.
//! With σ unknown: the structure tests decide. Cost: two structure analyses.

use super::forward_model::Problem;
use super::nuisance::describe_nuisance;
use super::scoring::n_res;
use super::selection::Selection;
use super::structure::{self, Finding};
use crate::io::measurement_csv::Measurement;

/// What the report says about the residual.
pub struct Verdict {
    pub unexplained: bool,
    pub description: String,
    /// RSS / (n − k) / σ² of the library model, if σ is known.
    pub chi2_per_dof: Option<f64>,
    pub initial_structure: Vec<Finding>,
    pub final_structure: Vec<Finding>,
}

/// The verdict on the final residual `last_residual` of the selection `sel` (and the structure of
/// the starting residual, for the report).
pub fn verdict(
    problem: &Problem,
    data: &[Measurement],
    sel: &Selection,
    start_residual: &[f64],
    last_residual: &[f64],
    noise_um: Option<f64>,
) -> Verdict {
    let n = n_res(problem);
    let last_cost: f64 = last_residual.iter().map(|v| v * v).sum();
    // The library model's own degrees of freedom (the nuisances' part is in its residual).
    let dof_library =
        (n - sel.effects.iter().map(|e| e.params.len()).sum::<usize>() as f64).max(1.0);
    let initial_structure = structure::analyse(problem, data, start_residual);
    let final_structure = structure::analyse(problem, data, last_residual);
    let significant: Vec<&Finding> = final_structure.iter().filter(|f| f.significant).collect();
    let chi2_per_dof = noise_um.map(|s| last_cost / dof_library / (s * s));
    let (unexplained, mut description) = match chi2_per_dof {
        Some(_) if !problem.nuisance.is_empty() => (
            true,
            format!("a structure outside the library is in the data ({}); no library effect is named on its account", describe_nuisance(&problem.nuisance)),
        ),
        Some(c) => {
            let limit = (1.0 + 4.0 * (2.0 / dof_library).sqrt()).max(1.21);
            if c > limit {
                (true, format!("residual is {:.2}× the noise variance (limit {:.2}) and no further library effect is significant", c, limit))
            } else {
                (false, format!("residual at the noise level (χ²/dof {:.2} ≤ {:.2})", c, limit))
            }
        }
        None if final_structure.iter().any(|f| f.kind == "too_few_points") => (
            false,
            "UNDECIDED: noise unknown (no --noise-um, no repeats) and too few points to test the residual's structure; \
             give --noise-um to decide"
                .to_string(),
        ),
        None => {
            if significant.is_empty() {
                (false, "noise unknown; no significant structure left in the residual".to_string())
            } else {
                (true, "noise unknown; the residual has significant structure no library effect explains".to_string())
            }
        }
    };
    if !significant.is_empty() {
        let d: Vec<String> = significant
            .iter()
            .map(|f| format!("[{}] {}", f.kind, f.description))
            .collect();
        description.push_str(&format!(". Structure of the residual: {}", d.join("; ")));
    } else if unexplained && final_structure.iter().any(|f| f.kind == "too_few_points") {
        description.push_str(&format!(
            ". Too few points ({}) to describe its structure; largest radial residuals: {}",
            problem.points.len(),
            largest_points(data, problem, last_residual)
        ));
    } else if unexplained {
        description.push_str(&format!(
            ". No test found a structure (not periodic in a motor angle, not direction-dependent, no drift, not smooth over \
             the workspace): looks like extra noise or isolated outliers; largest radial residuals: {}",
            largest_points(data, problem, last_residual)
        ));
    }
    Verdict {
        unexplained,
        description,
        chi2_per_dof,
        initial_structure,
        final_structure,
    }
}

/// The three largest radial residuals, with their file line (or index) and position.
fn largest_points(data: &[Measurement], problem: &Problem, residual_um: &[f64]) -> String {
    let kept: Vec<&Measurement> = problem
        .points
        .iter()
        .filter_map(|p| data.get(p.index))
        .collect();
    let mut idx: Vec<usize> = (0..problem.points.len()).collect();
    let mag = |i: usize| residual_um[2 * i].hypot(residual_um[2 * i + 1]);
    idx.sort_by(|&a, &b| mag(b).total_cmp(&mag(a)));
    idx.iter()
        .take(3)
        .map(|&i| {
            let p = problem.points[i].measured_mm;
            let line = kept.get(i).map(|m| m.line).unwrap_or(0);
            format!(
                "{:.0} µm at line {line} ({:.1}, {:.1}) mm",
                mag(i),
                p[0],
                p[1]
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}
