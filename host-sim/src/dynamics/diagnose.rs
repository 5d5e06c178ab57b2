//! The moving machine's diagnosis: where the controller's telemetry of a motion and what its
//! dynamics model predicts for it disagree (the torques, and the following error of the closed
//! loop), which effect of the library (`effects`) is missing; the effects named are added to
//! the model and what is left shrinks.
//!
//! **Data.** The excitation's telemetry matched with its knots (`samples`): per sample the
//! reference's joint motion, the torque the controller wrote and its following error. The
//! machine's equation holds sample by sample whatever the controller did (the torque written
//! is what moved it), so the torque the model lacks is `r = τ − τ_model(motion)`, and every
//! library effect is linear in its parameters there: they are fitted by linear least squares
//! on the torques, jointly with the effects already named.
//!
//! **The residual (µm, the report's contract).** The torque the model lacks, as the following
//! error the servo's stiffness needs to supply it: `J·K⁻¹·r` at the tool (`K` the position
//! gains `kp`, `J` the model's Jacobian at the setpoint), its max and its RMS over the samples
//! beyond the samples' noise (the mean square the final model's residual has in the
//! differences of successive samples, half of it: what white noise contributes, and what no
//! model removes; `noise_um` in the report). Under QEMU the encoders' coarser counts put that
//! noise at 1 µm, near the size of a 20 % inertia error's at 2 g.
//! Why not the measured following error itself: the disturbance observer and the integrator
//! take up a missing torque within milliseconds, so on a smooth excitation the following error
//! an effect leaves is at the encoders' noise (a missing viscous friction of 0.03 N·m·s/rad
//! moves the 2 g excitation's following error by 0.01 µm RMS, below its 0.09 µm of
//! quantisation jitter); the torque it takes does not hide. The closed loop's own comparison is
//! reported beside it (`closed_loop`): the telemetry's following error against the loop
//! simulated with the model as a plant (`predict`, `model_plant`), before and after the effects
//! are added; and what the effects buy where they show, the machine's rated 5 g motion
//! (`figure8-5g`) simulated on the model with the effects, fed forward the model as it was and
//! the model with them (`rated_motion`).
//!
//! **Selection.** Forward, one effect per step: every library effect not yet named is fitted
//! with those named, scored by BIC on the torque residual (`n_eff·ln(RSS/n) + k·ln(n_eff)`,
//! `n_eff` the samples discounted by the residual's lag-1 correlation, which a fit of the whole
//! library leaves: neighbouring samples are not independent evidence). The best that lowers the
//! BIC by more than [`ADD_MARGIN`] is added, if it matters, removing at least [`MIN_SHRINK`]
//! of the residual or changing a parameter of the model by [`MIN_RELATIVE`] of its value (the
//! data support much that does not matter: with ~1600 samples a 2 % inertia error is
//! significant, and so is the trace a large effect leaves on the others), and if the model
//! with it is still a machine (inertias positive, a torque constant within a factor of two).
//! Cogging is scanned over its period first
//! (`effects`) and pays [`SCAN_PENALTY`] for the scan. At the end every named effect must still
//! earn its place (removing it must raise the BIC by more than [`ADD_MARGIN`]).
//!
//! **Report** (`report`): the steps, the final parameters, the effects the data cannot tell
//! from a named one (put in its place, within [`ADD_MARGIN`] of the BIC: `confounded`), how
//! large each effect not named could be, whether the torque residual still depends on the
//! motion (a fit of the joint angles, their squares and the speeds' squares on top of the final
//! model, [`ADD_MARGIN`] again: `unexplained`), and the dynamics block with the effects added:
//! Coulomb, viscous, tool mass and motor inertia are its parameters (added exactly); a torque
//! constant is fitted onto them (least squares over the excitation's samples, what is left
//! reported); cogging has no place in it (reported as not carried).
//!
//! Refused: what `samples` refuses (another machine, gaps, a fault, not these knots, too
//! short), and a log whose motion does not separate the block's effects (the column-scaled
//! regressor's smallest relative singular value below [`SEPARATE_TOL`], naming the effects).
//!
//! Cost: a few least-squares fits of ~3000 × 13 per step, the cogging scan (~400 small fits),
//! four closed-loop simulations (~0.1 s each).
use super::block::block_update;
use super::effects::{entry, LIBRARY};
use super::identify::checked_samples;
use super::model_plant::Extras;
use super::predict::{at_tool_um, closed_loop, following_error_rad, Controller};
use super::report::{ClosedLoop, DynamicReport, NotDetected, RatedMotion};
use super::samples::SampleOptions;
use super::torque_fit::{
    extension_columns, lag1_correlation, params_of, with_effects, Cand, Fit, Problem, SCAN_PENALTY,
};
use super::DynError;
use crate::diagnose::report::Step;
use crate::effect::PhysicalEffect;
use crate::io::telemetry_csv::TelemetryLog;
use crate::machine_spec::MachineSpec;
use crate::numeric::svd::ScaledSvd;
use crate::sim::knots::KnotPath;
use crate::sim::motions::Trajectory;
use kinematics_core::dynamics::{regressor, PARAMETER_NAMES};
use kinematics_core::FiveBarDynamics;
use nalgebra::DMatrix;
use std::collections::BTreeMap;

/// BIC decrease an effect must bring to be added (and keep to stay).
pub const ADD_MARGIN: f64 = 10.0;
/// Share of the residual (µm) an effect must remove to be added, unless it changes the model by
/// [`MIN_RELATIVE`]: one that the data support but that changes nothing that matters is not
/// named.
pub const MIN_SHRINK: f64 = 0.1;
/// Relative change of a model parameter that makes an effect matter whatever share of the
/// residual it removes (a torque constant: its error; cogging, which the model has none of:
/// always).
pub const MIN_RELATIVE: f64 = 0.1;
/// The rated motion the effects' benefit is predicted on (`sim::motions`).
pub const RATED_MOTION: &str = "figure8-5g";
/// Smallest relative singular value of the block effects' columns a log must give.
pub const SEPARATE_TOL: f64 = 1e-3;

/// What to diagnose against.
#[derive(Clone, Debug)]
pub struct DiagnoseOptions {
    pub spec: MachineSpec,
    /// How to read the log (the controller's model, its torque limit).
    pub samples: SampleOptions,
    /// The controller: model, servo settings, the dynamics it fed forward during the log.
    pub controller: Controller,
}

/// Max and RMS (µm) of the following-error residual at the tool: the telemetry's minus the
/// prediction's.
#[derive(Clone, Copy, Debug)]
struct Residual {
    rms_um: f64,
    max_um: f64,
}

/// The diagnosis' state shared by its steps.
struct Run<'a> {
    problem: Problem<'a>,
    path: &'a KnotPath,
    ticks: Vec<u64>,
    opts: &'a DiagnoseOptions,
    /// The position gains the controller runs with the dynamics it feeds forward (N·m/rad per
    /// motor; `Controller::designed_servo`), designed once for the whole diagnosis.
    kp_nm_per_rad: [f64; 2],
}

impl Run<'_> {
    /// The following error the loop predicts at every sample with the machine `plant` +
    /// `extras` and the controller feeding forward `fed_forward` (rad per motor).
    fn predict(
        &self,
        plant: &FiveBarDynamics<f64>,
        extras: &Extras,
        fed_forward: &FiveBarDynamics<f64>,
    ) -> Result<Vec<[f64; 2]>, DynError> {
        let controller = Controller {
            fed_forward: *fed_forward,
            ..self.opts.controller
        };
        following_error_rad(self.path, &self.ticks, &controller, plant, extras)
    }

    /// The following error at the tool (µm) of joint errors per sample: max and RMS.
    fn at_tool(&self, e: impl Fn(usize) -> [f64; 2]) -> Residual {
        let model = &self.opts.controller.model;
        let mt = self.opts.spec.min_transmission;
        let (mut sum, mut max, mut n) = (0.0, 0.0f64, 0usize);
        for (i, s) in self.problem.samples.iter().enumerate() {
            if let Some(d) = at_tool_um(model, s.setpoint_mm, e(i), mt) {
                let v = d[0].hypot(d[1]);
                sum += v * v;
                max = max.max(v);
                n += 1;
            }
        }
        Residual {
            rms_um: (sum / n.max(1) as f64).sqrt(),
            max_um: max,
        }
    }

    /// Whether the model with `fit`'s effects is a machine: motor inertias positive, the tool
    /// mass not negative, the inertia matrix positive definite at the workspace's centre, a
    /// motor's torque per command within a factor of two of the nominal.
    fn plausible(&self, fit: &Fit) -> bool {
        let (d, x) = with_effects(&self.opts.controller.fed_forward, fit);
        let centre = self.opts.spec.workspace.centre_mm();
        let pd = self
            .opts
            .controller
            .model
            .inverse_pose(centre, self.opts.spec.min_transmission)
            .and_then(|pose| d.mass_matrix_and_bias(&pose, [0.0; 2]))
            .is_ok_and(|(m, _)| m[0][0] > 0.0 && m[0][0] * m[1][1] - m[0][1] * m[1][0] > 0.0);
        pd && d.motor_inertia_kg_m2.iter().all(|v| *v > 0.0)
            && d.tool_mass_kg >= 0.0
            && x.torque_error.iter().all(|e| *e > -0.5 && *e < 1.0)
    }

    /// The torque `fit` leaves as the following error the position gains need to supply it,
    /// at the tool (µm, x and y per sample; zero where the model has no Jacobian).
    fn stiffness_series(&self, resid: &[f64]) -> Vec<[f64; 2]> {
        let kp = self.kp_nm_per_rad;
        let model = &self.opts.controller.model;
        let mt = self.opts.spec.min_transmission;
        self.problem
            .samples
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let e = [resid[2 * i] / kp[0], resid[2 * i + 1] / kp[1]];
                at_tool_um(model, s.setpoint_mm, e, mt).unwrap_or([0.0; 2])
            })
            .collect()
    }

    /// Its RMS and max (µm).
    fn stiffness_residual(&self, resid: &[f64]) -> Residual {
        let d = self.stiffness_series(resid);
        let sq: Vec<f64> = d.iter().map(|v| v[0] * v[0] + v[1] * v[1]).collect();
        Residual {
            rms_um: (sq.iter().sum::<f64>() / sq.len().max(1) as f64).sqrt(),
            max_um: sq.iter().fold(0.0f64, |m, v| m.max(*v)).sqrt(),
        }
    }

    /// The contract's residual: [`Run::stiffness_residual`], its RMS beyond the noise
    /// (`noise_ms_um2`, the mean square the samples' noise contributes).
    fn contract_residual(&self, resid: &[f64], noise_ms_um2: f64) -> Residual {
        let r = self.stiffness_residual(resid);
        Residual {
            rms_um: (r.rms_um * r.rms_um - noise_ms_um2).max(0.0).sqrt(),
            max_um: r.max_um,
        }
    }

    /// The mean square the noise contributes to the stiffness residual of `resid` (µm²): from
    /// successive samples' differences, which a smooth misfit hardly has and white noise has
    /// twice (`mean |dₖ − dₖ₋₁|² / 2`).
    fn noise_ms_um2(&self, resid: &[f64]) -> f64 {
        let d = self.stiffness_series(resid);
        let sq: f64 = d
            .windows(2)
            .map(|w| (w[1][0] - w[0][0]).powi(2) + (w[1][1] - w[0][1]).powi(2))
            .sum();
        sq / (2.0 * (d.len().max(2) - 1) as f64)
    }

    /// The closed loop's residual: the telemetry's following error minus the loop's predicted
    /// with `fit`'s effects in the model (µm at the tool).
    fn closed_loop_residual(&self, fit: &Fit) -> Result<Residual, DynError> {
        let d0 = &self.opts.controller.fed_forward;
        let (plant, extras) = with_effects(d0, fit);
        let pred = self.predict(&plant, &extras, d0)?;
        let samples = self.problem.samples;
        Ok(self.at_tool(|i| {
            let t = samples[i].following_error_rad;
            [t[0] - pred[i][0], t[1] - pred[i][1]]
        }))
    }

    /// The following error of the rated 5 g motion on the machine `plant` + `extras` with
    /// `fed_forward` (µm at the tool).
    fn rated(
        &self,
        trajectory: &Trajectory,
        plant: &FiveBarDynamics<f64>,
        extras: &Extras,
        fed_forward: &FiveBarDynamics<f64>,
    ) -> Result<Residual, DynError> {
        let controller = Controller {
            fed_forward: *fed_forward,
            ..self.opts.controller
        };
        let dt = f64::from(controller.servo.sample_period_s);
        let n = (trajectory.natural_duration_s() / dt) as u64;
        let all: Vec<u64> = (0..n).collect();
        let at = |t: f64| {
            trajectory.motion_at(t).unwrap_or_else(|| {
                kinematics_core::trajectory::MotionSetpoint::at_rest(trajectory.at(t))
            })
        };
        let e = closed_loop(&at, &all, &controller, plant, extras)?;
        let model = &controller.model;
        let mt = self.opts.spec.min_transmission;
        let (mut sum, mut max, mut k) = (0.0, 0.0f64, 0usize);
        for (e, p) in &e {
            if let Some(d) = at_tool_um(model, *p, *e, mt) {
                let v = d[0].hypot(d[1]);
                sum += v * v;
                max = max.max(v);
                k += 1;
            }
        }
        Ok(Residual {
            rms_um: (sum / k.max(1) as f64).sqrt(),
            max_um: max,
        })
    }
}

/// The largest relative change candidate `i` of `fit` makes to a parameter of the model `d0`
/// (infinite for what the model has none of).
fn relative_size(d0: &FiveBarDynamics<f64>, fit: &Fit, i: usize) -> f64 {
    let v = fit.coefs(i);
    let rel = |dv: f64, of: f64| {
        if of.abs() > 0.0 {
            (dv / of).abs()
        } else if dv == 0.0 {
            0.0
        } else {
            f64::INFINITY
        }
    };
    let pair = |dv: &[f64], of: [f64; 2]| rel(dv[0], of[0]).max(rel(dv[1], of[1]));
    match fit.cands[i].e.effect {
        PhysicalEffect::CoulombFriction => pair(v, d0.coulomb_nm),
        PhysicalEffect::ViscousFriction => pair(v, d0.viscous_nm_s_per_rad),
        PhysicalEffect::ToolMass => rel(v[0], d0.tool_mass_kg),
        PhysicalEffect::MotorInertia => pair(v, d0.motor_inertia_kg_m2),
        PhysicalEffect::TorqueConstant => v.iter().fold(0.0f64, |m, c| m.max(c.abs() / 100.0)),
        _ => f64::INFINITY,
    }
}

/// Diagnoses `log`, a run of the knots `path` (see the module doc).
pub fn diagnose_telemetry(
    log: &TelemetryLog,
    path: &KnotPath,
    opts: &DiagnoseOptions,
) -> Result<DynamicReport, DynError> {
    let (facts, m) = checked_samples(log, path, &opts.spec, &opts.samples)?;
    let d0 = opts.controller.fed_forward;
    d0.validate()
        .map_err(|e| DynError::Invalid(format!("the controller's dynamics model: {e}")))?;
    // The torque the model lacks, sample by sample.
    let mut samples = Vec::with_capacity(m.samples.len());
    let mut r = Vec::with_capacity(2 * m.samples.len());
    for s in &m.samples {
        let (Ok(tau), Ok(_)) = (
            d0.torque_nm(&s.motion),
            regressor(&s.motion, d0.coulomb_speed_rad_s),
        ) else {
            continue;
        };
        r.extend([s.torque_nm[0] - tau[0], s.torque_nm[1] - tau[1]]);
        samples.push(*s);
    }
    let lin: Vec<Cand> = LIBRARY
        .iter()
        .filter(|e| e.effect != PhysicalEffect::Cogging)
        .map(|e| Cand { e, cycles: 0.0 })
        .collect();
    let model_torque: Vec<[f64; 2]> = samples
        .iter()
        .map(|s| d0.torque_nm(&s.motion).unwrap_or([0.0; 2]))
        .collect();
    let mut problem = Problem {
        samples: &samples,
        model_torque,
        r,
        n_eff: 1.0,
        coulomb_speed: d0.coulomb_speed_rad_s,
    };
    // The block's effects must be separable on this motion.
    let block: Vec<Cand> = lin
        .iter()
        .copied()
        .filter(|c| c.e.effect != PhysicalEffect::TorqueConstant)
        .collect();
    let block_cols: Vec<Vec<f64>> = block.iter().flat_map(|c| problem.cols(c)).collect();
    let names: Vec<&str> = block
        .iter()
        .flat_map(|c| c.e.params.iter().copied())
        .collect();
    let needed = 10 * names.len();
    if samples.len() < needed {
        return Err(DynError::NotIdentifiable(format!(
            "the log has {} usable samples of motion; separating the dynamic effects takes at \
             least {needed}: record the whole excitation",
            samples.len()
        )));
    }
    let x = DMatrix::from_fn(problem.n(), block_cols.len(), |i, j| block_cols[j][i]);
    let svd = ScaledSvd::new(&x);
    if !(svd.min_relative() > SEPARATE_TOL) {
        let dir = svd.smallest_direction();
        let mut order: Vec<usize> = (0..dir.len()).collect();
        order.sort_by(|&a, &b| dir[b].abs().total_cmp(&dir[a].abs()));
        return Err(DynError::NotIdentifiable(format!(
            "the log's motion does not separate {} from {} (relative singular value {:.1e}, \
             below {SEPARATE_TOL:.0e}): record the whole excitation (host-sim identify \
             --telemetry-csv, or simulate --trajectory excitation)",
            names[order[0]],
            names[order[1]],
            svd.min_relative()
        )));
    }
    // Independent samples: discounted by the correlation the full library's fit leaves.
    let full = problem
        .fit(&lin)
        .or_else(|| problem.fit(&block))
        .ok_or_else(|| {
            DynError::NotIdentifiable("the library's effects are not separable on this log".into())
        })?;
    let rho = lag1_correlation(&full.resid);
    problem.n_eff = problem.n() as f64 * (1.0 - rho) / (1.0 + rho);
    let run = Run {
        ticks: samples
            .iter()
            .map(|s| (s.tick as i64 - m.start_tick) as u64)
            .collect(),
        problem,
        path,
        opts,
        kp_nm_per_rad: opts
            .controller
            .designed_servo()
            .axes
            .map(|a| f64::from(a.kp_nm_per_rad)),
    };
    let p = &run.problem;
    // Forward selection.
    let mut current = p.fit(&[]).expect("the empty fit");
    loop {
        let named: Vec<Cand> = current.cands.clone();
        let mut options: Vec<Cand> = lin
            .iter()
            .copied()
            .filter(|c| !named.iter().any(|n| n.e.effect == c.e.effect))
            .collect();
        let cogging = entry(PhysicalEffect::Cogging).expect("in the library");
        if !named.iter().any(Cand::is_cogging) {
            options.push(Cand {
                e: cogging,
                cycles: p.best_cogging(&current.resid),
            });
        }
        let bic_now = p.bic(&current);
        let best = options
            .iter()
            .filter_map(|c| {
                let mut set = named.clone();
                set.push(*c);
                p.fit(&set)
                    .filter(|f| run.plausible(f))
                    .map(|f| (p.bic(&f), f))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0));
        let now = run.stiffness_residual(&current.resid).rms_um;
        match best {
            Some((b, f))
                if b < bic_now - ADD_MARGIN
                    && (run.stiffness_residual(&f.resid).rms_um <= (1.0 - MIN_SHRINK) * now
                        || relative_size(&d0, &f, f.cands.len() - 1) >= MIN_RELATIVE) =>
            {
                current = f
            }
            _ => break,
        }
    }
    // Every named effect must still earn its place.
    loop {
        let bic = p.bic(&current);
        let weakest = (0..current.cands.len())
            .filter_map(|i| {
                let mut rest = current.cands.clone();
                rest.remove(i);
                p.fit(&rest).map(|f| (p.bic(&f) - bic, f))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0));
        match weakest {
            Some((gain, f)) if gain < ADD_MARGIN => current = f,
            _ => break,
        }
    }
    // The steps: each row fitted with the effects up to it; the residual beyond the noise the
    // final model's residual shows.
    let noise_ms = run.noise_ms_um2(&current.resid);
    let initial = run.contract_residual(&p.r, noise_ms);
    let mut rows = Vec::new();
    let mut before = initial;
    for k in 0..current.cands.len() {
        let f = p
            .fit(&current.cands[..=k])
            .expect("a subset of a fitted set");
        let std = p.std_devs(&f);
        let after = run.contract_residual(&f.resid, noise_ms);
        rows.push(Step {
            effect: current.cands[k].name().to_string(),
            params: params_of(&f, &std, k),
            rms_before_um: before.rms_um,
            rms_after_um: after.rms_um,
            max_before_um: before.max_um,
            max_after_um: after.max_um,
        });
        before = after;
    }
    let final_res = before;
    let bic_final = p.bic(&current);
    let std = p.std_devs(&current);
    let mut final_params = BTreeMap::new();
    for i in 0..current.cands.len() {
        final_params.extend(params_of(&current, &std, i));
    }
    // Confounded: a library effect in a named one's place fits as well.
    let mut confounded = Vec::new();
    for (i, named) in current.cands.iter().enumerate() {
        let mut group = vec![named.name().to_string()];
        for alt in lin
            .iter()
            .filter(|c| !current.cands.iter().any(|n| n.e.effect == c.e.effect))
        {
            let mut set = current.cands.clone();
            set[i] = *alt;
            if let Some(f) = p.fit(&set) {
                if p.bic(&f) - bic_final < ADD_MARGIN {
                    group.push(alt.name().to_string());
                }
            }
        }
        if group.len() > 1 {
            confounded.push(group);
        }
    }
    // What was not named, fitted on top.
    let mut not_detected = Vec::new();
    let cogging = entry(PhysicalEffect::Cogging).expect("in the library");
    let mut rest: Vec<Cand> = lin
        .iter()
        .copied()
        .filter(|c| !current.cands.iter().any(|n| n.e.effect == c.e.effect))
        .collect();
    if !current.cands.iter().any(Cand::is_cogging) {
        rest.push(Cand {
            e: cogging,
            cycles: p.best_cogging(&current.resid),
        });
    }
    for c in rest {
        let mut set = current.cands.clone();
        set.push(c);
        match p.fit(&set) {
            Some(f) => {
                let std = p.std_devs(&f);
                not_detected.push(NotDetected {
                    effect: c.name().to_string(),
                    params: params_of(&f, &std, set.len() - 1),
                    delta_bic: p.bic(&f) - bic_final,
                });
            }
            None => {
                let mut group: Vec<String> =
                    current.cands.iter().map(|n| n.name().to_string()).collect();
                group.push(c.name().to_string());
                confounded.push(group);
            }
        }
    }
    // Unexplained: the torque residual against the joint angles, their squares, the speeds'.
    let ext = extension_columns(&samples);
    let mut cols: Vec<Vec<f64>> = current.cands.iter().flat_map(|c| p.cols(c)).collect();
    let k_final = cols.len();
    cols.extend(ext);
    let (unexplained, unexplained_description) = match p.fit_cols(&current.cands, &cols) {
        Some(f) => {
            // The extension's columns count as parameters.
            let n = p.n() as f64;
            let bic_ext = p.n_eff * (f.rss.max(1e-300) / n).ln()
                + cols.len() as f64 * p.n_eff.ln()
                + if current.cands.iter().any(Cand::is_cogging) {
                    SCAN_PENALTY
                } else {
                    0.0
                };
            let gain = bic_final - bic_ext;
            let share = 1.0 - f.rss / current.rss.max(1e-300);
            if gain > ADD_MARGIN {
                (
                    true,
                    format!(
                        "the torque residual still depends on the joint angles or speeds (BIC {gain:.1} \
                         lower with them, {:.0} % of it): an effect outside the library ({} \
                         parameters named)",
                        100.0 * share,
                        k_final
                    ),
                )
            } else {
                (
                    false,
                    format!(
                        "the torque residual ({:.4} N·m) shows no dependence on the joint angles \
                         or speeds beyond noise (BIC {:.1} with them)",
                        (current.rss / n).sqrt(),
                        -gain
                    ),
                )
            }
        }
        None => (
            false,
            "the structure test's fit is degenerate on this log".into(),
        ),
    };
    // The block with the effects added; the closed loop on this motion and on the rated one.
    let (estimated, extras) = with_effects(&d0, &current);
    let (model_out, carried) = block_update(&d0, &current, &samples);
    let empty = p.fit(&[]).expect("the empty fit");
    let closed = ClosedLoop {
        telemetry_rms_um: run
            .at_tool(|i| run.problem.samples[i].following_error_rad)
            .rms_um,
        residual_initial_rms_um: run.closed_loop_residual(&empty)?.rms_um,
        residual_final_rms_um: run.closed_loop_residual(&current)?.rms_um,
    };
    let rated_motion = match (&model_out, Trajectory::by_name(RATED_MOTION, &opts.spec)) {
        (Some(d1), Ok(tr)) => {
            let before = run.rated(&tr, &estimated, &extras, &d0)?;
            let after = run.rated(&tr, &estimated, &extras, d1)?;
            Some(RatedMotion {
                motion: RATED_MOTION.into(),
                before_rms_um: before.rms_um,
                before_max_um: before.max_um,
                after_rms_um: after.rms_um,
                after_max_um: after.max_um,
            })
        }
        _ => None,
    };
    let n = run.problem.n() as f64;
    Ok(DynamicReport {
        machine: opts.spec.name.clone(),
        telemetry_samples: log.rows.len(),
        samples_used: samples.len(),
        decimation: facts.decimation,
        score: format!(
            "BIC on the torque residual (margin {ADD_MARGIN}, {:.0} effective of {} samples, \
             lag-1 correlation {rho:.2}); an effect added removes at least {:.0} % of the residual",
            run.problem.n_eff,
            run.problem.n(),
            100.0 * MIN_SHRINK
        ),
        residual: format!(
            "the torque the model lacks as the following error the position gains need to \
             supply it (J·r/kp at the tool): RMS beyond the samples' noise ({:.3} µm RMS), max \
             as it is",
            noise_ms.sqrt()
        ),
        noise_um: noise_ms.sqrt(),
        noise_nm: (current.rss / (n - current.beta.len() as f64).max(1.0)).sqrt(),
        effective_samples: run.problem.n_eff,
        initial_rms_um: initial.rms_um,
        initial_max_um: initial.max_um,
        steps: rows,
        final_params,
        final_rms_um: final_res.rms_um,
        final_max_um: final_res.max_um,
        confounded,
        unexplained,
        unexplained_description,
        not_detected,
        carried,
        model_out: model_out.map(|d| {
            PARAMETER_NAMES
                .iter()
                .map(|s| s.to_string())
                .zip(d.to_array())
                .collect()
        }),
        closed_loop: closed,
        rated_motion,
    })
}
