//! The moving machine's diagnosis report: the same contract as the static diagnosis' (`steps`
//! with `effect`, `params`, `rms_before_um`, `rms_after_um`, `max_before_um`, `max_after_um`;
//! `confounded`; `unexplained`; `final_rms_um`), the residual being the torque the model lacks
//! as a following error at the tool (µm; `dynamics::diagnose` says why), the closed loop's
//! comparison beside it. The step and parameter types are the static diagnosis' own
//! (`diagnose::report`). What goes beyond the contract explains it for people.

use crate::diagnose::report::{Param, Step};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// How a named effect goes into the image's dynamics block.
#[derive(Clone, Debug, Serialize)]
pub struct Carried {
    pub effect: String,
    /// `exact` (it is block parameters), `projected` (fitted onto the block's parameters by
    /// least squares over the excitation; `residual_nm` is what they leave) or `not_carried`
    /// (the block has no parameter for it).
    pub how: String,
    pub residual_nm: f64,
}

/// The report.
#[derive(Clone, Debug, Serialize)]
pub struct DynamicReport {
    /// The machine and the log.
    pub machine: String,
    pub telemetry_samples: usize,
    pub samples_used: usize,
    pub decimation: u64,
    /// How the effects were scored.
    pub score: String,
    /// What the residual (µm) is.
    pub residual: String,
    /// The noise the residual's RMS is given beyond (µm RMS).
    pub noise_um: f64,
    /// The torque residual's standard deviation with the final model (N·m), and the samples
    /// it counts as independent (its lag-1 correlation discounted).
    pub noise_nm: f64,
    pub effective_samples: f64,
    /// The following-error residual with the model alone (µm at the tool).
    pub initial_rms_um: f64,
    pub initial_max_um: f64,
    pub steps: Vec<Step>,
    /// Every parameter of the final model (jointly fitted).
    pub final_params: BTreeMap<String, Param>,
    pub final_rms_um: f64,
    pub final_max_um: f64,
    /// Groups of library effects these data cannot tell apart, at least one of them named.
    pub confounded: Vec<Vec<String>>,
    /// Whether the torque still depends on the motion in a way no library effect has.
    pub unexplained: bool,
    pub unexplained_description: String,
    /// The library effects not named, fitted on top of the final model: how large each could be
    /// and hide in these data (about three standard deviations, per parameter).
    pub not_detected: Vec<NotDetected>,
    /// How the named effects go into the dynamics block.
    pub carried: Vec<Carried>,
    /// The dynamics block with the named effects added (by name, as dynamics.json has them).
    pub model_out: Option<BTreeMap<String, f64>>,
    /// The closed loop's comparison on the log's motion.
    pub closed_loop: ClosedLoop,
    /// What the named effects buy on the machine's rated motion (predicted).
    pub rated_motion: Option<RatedMotion>,
}

/// The telemetry's following error against the closed loop's predicted with the model (µm at
/// the tool, RMS over the samples).
#[derive(Clone, Debug, Serialize)]
pub struct ClosedLoop {
    /// The following error the telemetry reports.
    pub telemetry_rms_um: f64,
    /// The telemetry's minus the loop's with the model as it is, and with the effects named.
    pub residual_initial_rms_um: f64,
    pub residual_final_rms_um: f64,
}

/// The following error of the rated motion on the machine as diagnosed (the model with the
/// effects named), fed forward the model as it was (`before`) and the updated block (`after`).
#[derive(Clone, Debug, Serialize)]
pub struct RatedMotion {
    pub motion: String,
    pub before_rms_um: f64,
    pub before_max_um: f64,
    pub after_rms_um: f64,
    pub after_max_um: f64,
}

/// A library effect not named: its fitted size on top of the final model.
#[derive(Clone, Debug, Serialize)]
pub struct NotDetected {
    pub effect: String,
    pub params: BTreeMap<String, Param>,
    /// BIC change had it been added (positive or small: not supported by the data).
    pub delta_bic: f64,
}

/// The gap-shrink table (stdout of `diagnose --telemetry`).
pub fn table(r: &DynamicReport) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "moving machine ({}): {} telemetry samples, {} used; following-error residual at the tool (µm)",
        r.machine, r.telemetry_samples, r.samples_used
    );
    let _ = writeln!(s, "{:<22} {:>10} {:>10}  parameters", "step", "rms", "max");
    let _ = writeln!(
        s,
        "{:<22} {:>10.3} {:>10.3}",
        "model as it is", r.initial_rms_um, r.initial_max_um
    );
    for st in &r.steps {
        let params: Vec<String> = st
            .params
            .iter()
            .map(|(k, p)| format!("{k} {:.4e} ± {:.1e}", p.value, p.std_dev))
            .collect();
        let _ = writeln!(
            s,
            "{:<22} {:>10.3} {:>10.3}  {}",
            format!("+ {}", st.effect),
            st.rms_after_um,
            st.max_after_um,
            params.join(", ")
        );
    }
    if r.steps.is_empty() {
        let _ = writeln!(s, "nothing named: the model explains the telemetry");
    }
    for g in &r.confounded {
        let _ = writeln!(s, "confounded: {}", g.join(" / "));
    }
    for c in &r.carried {
        let _ = writeln!(
            s,
            "{}: {} in the dynamics block (residual {:.4} N·m)",
            c.effect, c.how, c.residual_nm
        );
    }
    let c = &r.closed_loop;
    let _ = writeln!(
        s,
        "closed loop on this motion: telemetry {:.3} µm RMS, residual against the prediction {:.3} -> {:.3} µm RMS",
        c.telemetry_rms_um, c.residual_initial_rms_um, c.residual_final_rms_um
    );
    if let Some(m) = &r.rated_motion {
        let _ = writeln!(
            s,
            "{} on the machine as diagnosed: {:.3} µm RMS / {:.3} max with the model as it was, {:.3} / {:.3} with the updated block",
            m.motion, m.before_rms_um, m.before_max_um, m.after_rms_um, m.after_max_um
        );
    }
    let _ = writeln!(
        s,
        "unexplained: {} ({})",
        r.unexplained, r.unexplained_description
    );
    s
}
