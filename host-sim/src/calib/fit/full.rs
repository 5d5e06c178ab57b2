//! `full`: Levenberg–Marquardt over the identifiable parameters of the five-bar, minimising the
//! position residual `Σ |FK(θi; p) − measured_i|²`, with a standard deviation per parameter.
//!
//! Why: the paper's dyad fits minimise an algebraic residual, one arm at a time, over four link
//! lengths only. The quantity that matters is the distance between where the model puts the tool
//! and where it is; this fits exactly that, and can also fit the encoder offsets and the base
//! offset B0 when the data identify them (see [`super::identifiability`]).
//!
//! Method: the crate's one Levenberg–Marquardt (`crate::numeric::lm`, whose module doc states
//! its acceptance, stopping and damping rules) on [`params::PositionResiduals`], over the
//! parameters the identifiability check leaves free. Covariance `σ²·(JᵀJ)⁺` at the solution with
//! `σ² = SSR / (2N − k)` (k free parameters): the textbook estimate assuming independent
//! equal-variance errors on x and y, first-order in the errors; a solution whose Jacobian has
//! lost rank is refused. Cost: a few to ~20 iterations of 2·k FK sweeps over the data each.

use super::identifiability::{self, Identifiability};
use super::params::{self, PositionResiduals, NAMES, N_PARAMS};
use crate::calib::{invalid, CalibError};
use crate::io::measurement_csv::Measurement;
use crate::numeric::{levenberg_marquardt, LmFit, LmOptions, NumericError};
use kinematics_core::FiveBar;
use nalgebra::DVector;

/// A converged fit.
#[derive(Clone, Debug)]
pub struct FullFit {
    pub model: FiveBar<f64>,
    /// One standard deviation per parameter (code units); `None` for fixed parameters.
    pub std_dev: [Option<f64>; N_PARAMS],
    pub identifiability: Identifiability,
    /// Residual standard deviation per coordinate (mm), `sqrt(SSR / (2N − k))`.
    pub sigma_mm: f64,
    pub iterations: usize,
    /// The solver's record: cost history, stop reason, Jacobian and covariance at the solution.
    pub lm: LmFit,
}

/// What an LM failure means for a five-bar fit.
fn unreachable(e: NumericError) -> String {
    match e {
        NumericError::JacobianOutsideDomain { param } => {
            format!(
                "a measured pose is unreachable by the model near {}",
                NAMES.get(param).unwrap_or(&"?")
            )
        }
        _ => "the start model cannot reach every measured pose".into(),
    }
}

/// Refuses a set of held parameters that is not a proper subset of the parameters: an unknown
/// index, one named twice, or all of them (nothing would be left to fit).
pub fn check_fixed(fixed_by_user: &[usize]) -> Result<(), CalibError> {
    for (i, &k) in fixed_by_user.iter().enumerate() {
        if k >= N_PARAMS {
            return Err(invalid!(
                "parameter index {k} to hold does not exist (there are {N_PARAMS})"
            ));
        }
        if fixed_by_user[..i].contains(&k) {
            return Err(invalid!("{} is held twice", NAMES[k]));
        }
    }
    if fixed_by_user.len() == N_PARAMS {
        return Err(invalid!(
            "every parameter is held at nominal: nothing is left to fit"
        ));
    }
    Ok(())
}

/// Fits `data` starting from `start`; parameters in `fixed_by_user` stay at their start value,
/// and so do those the identifiability check fixes.
pub fn fit_full(
    data: &[Measurement],
    start: &FiveBar<f64>,
    fixed_by_user: &[usize],
) -> Result<FullFit, CalibError> {
    check_fixed(fixed_by_user)?;
    let requested = N_PARAMS - fixed_by_user.len();
    if 2 * data.len() <= requested {
        return Err(invalid!(
            "{} points give {} equations, not more than the {requested} parameters to fit: need at least {} points (or --fix some)",
            data.len(),
            2 * data.len(),
            requested / 2 + 1
        ));
    }
    let j0 = params::jacobian(start, data)
        .map_err(|e| invalid!("at the start model: {}", unreachable(e)))?;
    let ident = identifiability::check(&j0, fixed_by_user);
    let free = ident.free.clone();
    let k = free.len();
    let n_eq = 2 * data.len();
    if n_eq <= k {
        return Err(invalid!(
            "{} points give {n_eq} equations, not more than the {k} identifiable parameters ({}): need at least {} points",
            data.len(),
            free.iter().map(|&i| NAMES[i]).collect::<Vec<_>>().join(", "),
            k / 2 + 1
        ));
    }
    let problem = PositionResiduals { data, like: *start };
    let lm = levenberg_marquardt(
        &problem,
        &params::to_vector(start),
        &free,
        &LmOptions::default(),
    )
    .map_err(|e| invalid!("{}", unreachable(e)))?;
    if lm.rank() < k {
        return Err(invalid!(
            "JᵀJ is singular at the solution: the data do not identify the parameters"
        ));
    }
    let p: [f64; N_PARAMS] =
        lm.p.as_slice()
            .try_into()
            .expect("the problem has N_PARAMS parameters");
    let model = params::from_vector(&p, start);
    let sigma2 = lm.residual_variance();
    let mut std_dev = [None; N_PARAMS];
    for &i in &free {
        std_dev[i] = lm.std_dev(i, sigma2);
    }
    Ok(FullFit {
        model,
        std_dev,
        identifiability: ident,
        sigma_mm: sigma2.sqrt(),
        iterations: lm.iterations,
        lm,
    })
}

/// Up to this many points, [`leave_one_out_um`] refits without each point (exact); above, it uses
/// the linearised update [`leave_one_out_linearised_um`]. 200 exact refits take well under a
/// second; 2,000 took 39 s and 20,000 would take hours (O(N²)).
pub const EXACT_LOO_MAX_POINTS: usize = 200;

/// How the leave-one-out predictions were computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LooMethod {
    /// One refit on the other points per point (N fits).
    ExactRefits,
    /// The hat-matrix update of the fit on all points (no refit).
    Linearised,
    /// `ls`: the normal equations' sums less the point (exact, no refit).
    ExactSums,
}

/// Leave-one-out of `fit` (the fit of `data` from `start` holding `fixed_by_user`): exact refits
/// up to [`EXACT_LOO_MAX_POINTS`] points, the linearised update above. `progress` hears
/// `(done, total)` during exact refits.
pub fn leave_one_out_um(
    data: &[Measurement],
    fit: &FullFit,
    start: &FiveBar<f64>,
    fixed_by_user: &[usize],
    progress: &mut dyn FnMut(usize, usize),
) -> (LooMethod, Vec<Option<f64>>) {
    if data.len() <= EXACT_LOO_MAX_POINTS {
        (
            LooMethod::ExactRefits,
            leave_one_out_exact_um(data, start, fixed_by_user, progress),
        )
    } else {
        (LooMethod::Linearised, leave_one_out_linearised_um(fit))
    }
}

/// Leave-one-out: for each point, fit on the others (same start and fixed set) and return the
/// distance (µm) between the left-out point's prediction and its measurement. `None` where the
/// fit on the rest failed. Cost: N fits.
pub fn leave_one_out_exact_um(
    data: &[Measurement],
    start: &FiveBar<f64>,
    fixed_by_user: &[usize],
    progress: &mut dyn FnMut(usize, usize),
) -> Vec<Option<f64>> {
    let n = data.len();
    (0..n)
        .map(|i| {
            progress(i, n);
            let rest: Vec<Measurement> = data
                .iter()
                .enumerate()
                .filter(|(k, _)| *k != i)
                .map(|(_, m)| m.clone())
                .collect();
            let fit = fit_full(&rest, start, fixed_by_user).ok()?;
            let r: DVector<f64> = params::residuals_mm(&fit.model, std::slice::from_ref(&data[i]))?;
            Some(r.norm() * 1e3)
        })
        .collect()
}

/// Leave-one-out without refits: the prediction residual of point i from the fit on all points,
/// linearised at the solution. With `J` the Jacobian (2N x k), `P = (JᵀJ)⁺` and point i's rows
/// `Jᵢ` (2 x k) and residual `rᵢ`, removing the point moves the solution by
/// `P·Jᵢᵀ·(I − Hᵢᵢ)⁻¹·rᵢ` with `Hᵢᵢ = Jᵢ·P·Jᵢᵀ`, and its residual becomes
/// `(I − Hᵢᵢ)⁻¹·rᵢ` (the block form of the textbook `eᵢ / (1 − hᵢᵢ)`; Cook & Weisberg 1982).
/// Exact for a linear model; for the five-bar the error is second order in the parameter shift
/// a point causes, i.e. negligible wherever the point does not dominate the fit (verified
/// against [`leave_one_out_exact_um`] in `tests/full_fit.rs`). `None` for a point the rest
/// cannot predict (`I − Hᵢᵢ` singular: the point alone determines a direction).
/// Cost: O(N·k²), no FK evaluation.
pub fn leave_one_out_linearised_um(fit: &FullFit) -> Vec<Option<f64>> {
    leave_one_out_blocks(fit)
        .map(|(m, r)| {
            // A leverage of (nearly) one: the rest of the data do not see this point's direction.
            if m.determinant().abs() < 1e-9 {
                return None;
            }
            let v = (m.try_inverse()? * r).norm() * 1e3;
            v.is_finite().then_some(v)
        })
        .collect()
}

/// Per point, `I − Hᵢᵢ` (the 2×2 block of the fit's hat matrix `H = J·(JᵀJ)⁺·Jᵀ`, symmetric)
/// and its residual `rᵢ` (mm).
fn leave_one_out_blocks(
    fit: &FullFit,
) -> impl Iterator<Item = (nalgebra::Matrix2<f64>, nalgebra::Vector2<f64>)> + '_ {
    let (j, p, r) = (&fit.lm.jacobian, &fit.lm.normal_pinv, &fit.lm.residuals);
    (0..r.len() / 2).map(move |i| {
        let ji = j.rows(2 * i, 2);
        let h = ji * p * ji.transpose();
        let m = nalgebra::Matrix2::new(1.0 - h[(0, 0)], -h[(0, 1)], -h[(1, 0)], 1.0 - h[(1, 1)]);
        (m, nalgebra::Vector2::new(r[2 * i], r[2 * i + 1]))
    })
}

/// Each point's *studentized* deleted residual (µm): `|(I − Hᵢᵢ)^(−1/2)·rᵢ|`, the deleted
/// residual `(I − Hᵢᵢ)⁻¹·rᵢ` scaled to the spread it has under pure noise. Why: under Gaussian
/// noise of σ per coordinate the deleted residual's covariance is `σ²(I − Hᵢᵢ)⁻¹`, so a point
/// of high leverage (a D-optimal pose at the workspace's edge) has a larger one by nature, and
/// a test of it against a fixed number of σ rejects good high-leverage points; the studentized
/// one is `N(0, σ²I)` at every point (`blunders.rs` tests it against the Rayleigh bound).
/// `None` where [`leave_one_out_linearised_um`] has none. Cost: O(N·k²).
pub fn studentized_deleted_residuals_um(fit: &FullFit) -> Vec<Option<f64>> {
    leave_one_out_blocks(fit)
        .map(|(m, r)| {
            // Symmetrised against rounding: the block of a symmetric matrix.
            let eig = nalgebra::SymmetricEigen::new(0.5 * (m + m.transpose()));
            // A leverage of (nearly) one: the rest of the data do not see this point's direction.
            if eig.eigenvalues.iter().any(|&l| !(l > 1e-9)) {
                return None;
            }
            let inv_sqrt = eig.eigenvectors
                * nalgebra::Matrix2::from_diagonal(&eig.eigenvalues.map(|l| 1.0 / l.sqrt()))
                * eig.eigenvectors.transpose();
            let v = (inv_sqrt * r).norm() * 1e3;
            v.is_finite().then_some(v)
        })
        .collect()
}
