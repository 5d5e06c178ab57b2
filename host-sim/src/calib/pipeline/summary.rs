//! The demo's report: the JSON summary of a calibration run (`host-sim demo`'s stdout and
//! `summary.json`), from [`super::Calibrated`]. Cost: one FK per fit pose.

use super::Calibrated;
use crate::calib::fit::evaluate::{self, Criterion};
use crate::calib::fit::params::{self, NAMES};
use crate::calib::fit::ModelFigures;
use crate::calib::frame::FrameSummary;
use crate::calib::grid;
use crate::calib::measure::{measured_error_vectors_um, registered, rows, Approach};
use crate::numeric::{max_rms, round3, MaxRms};
use kinematics_core::FiveBar;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One stage in the summary.
#[derive(Clone, Debug, Serialize)]
pub struct StageSummary {
    pub step: &'static str,
    pub description: String,
    pub max_um: f64,
    pub rms_um: f64,
    pub measured_max_um: f64,
    pub measured_rms_um: f64,
    pub n_targets: usize,
    pub gain_vs_before: f64,
    pub paper_max: &'static str,
}

/// The `full` fit in the summary.
#[derive(Clone, Debug, Serialize)]
pub struct FullFitSummary {
    #[serde(flatten)]
    pub model: ModelFigures,
    pub std_dev: BTreeMap<String, f64>,
    pub sigma_um: f64,
    pub fit_residual_max_um: f64,
    pub fit_residual_rms_um: f64,
    pub fixed: Vec<&'static str>,
    pub iterations: usize,
}

/// The `ls` fit in the summary.
#[derive(Clone, Debug, Serialize)]
pub struct LsFitSummary {
    #[serde(flatten)]
    pub model: ModelFigures,
    pub fit_residual_max_um: f64,
    pub fit_residual_rms_um: f64,
}

/// The grid in the summary.
#[derive(Clone, Debug, Serialize)]
pub struct GridSummary {
    pub nx: usize,
    pub ny: usize,
    pub x0_mm: f64,
    pub y0_mm: f64,
    pub step_mm: f64,
    pub round1_node_err_max_um: f64,
    pub round1_node_err_rms_um: f64,
    pub round2_node_err_max_um: f64,
    pub round2_node_err_rms_um: f64,
    pub image_bytes: usize,
    /// What each grid knew of the noise and did about it (`grid::NoiseReport`).
    pub round1_noise: grid::NoiseReport,
    pub round2_noise: grid::NoiseReport,
}

/// The final accuracy against the target.
#[derive(Clone, Debug, Serialize)]
pub struct FinalSummary {
    pub max_um: Option<f64>,
    pub rms_um: Option<f64>,
    pub target_max_um: f64,
    pub target_rms_um: f64,
    pub met: bool,
}

/// The JSON summary (`host-sim demo`'s stdout and `summary.json`).
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub machine: String,
    pub seed: u64,
    pub out_dir: String,
    pub fit_poses: usize,
    pub approach: Approach,
    pub stages: Vec<StageSummary>,
    pub fit_full: FullFitSummary,
    /// The paper's `ls` fit; `null` when it failed (`ls_error` says why).
    pub fit_ls: Option<LsFitSummary>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ls_error: Option<String>,
    /// The instrument's frame the `full` fit registered: where the instrument stood.
    pub instrument_frame: FrameSummary,
    pub grid: GridSummary,
    /// The plan's identification design against random poses of the same count.
    pub identification: crate::calib::plan::IdentificationReport,
    /// The backlash corrected by direction (µrad; random approach only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub backlash_urad: Option<[f64; 2]>,
    #[serde(rename = "final")]
    pub final_: FinalSummary,
    pub files: Vec<String>,
}

/// Residual of a model on the fit data (µm): max and RMS of |FK(θ) − measured|.
fn residual_um(m: &FiveBar<f64>, data: &[crate::io::measurement_csv::Measurement]) -> MaxRms {
    max_rms(&evaluate::errors_um(m, data, Criterion::Measured))
}

/// The summary of a run written to `out_dir` (`files`: what was written).
pub fn summary(cal: &Calibrated, seed: u64, out_dir: &Path, files: &[PathBuf]) -> Summary {
    let before = cal.stages.first().map_or(f64::NAN, |s| s.accuracy.max_um);
    let fit_rows = rows(&cal.fit_data);
    let full_res = residual_um(&cal.full.model, &cal.frame.register(&fit_rows));
    let n1 = cal.grid.stats().node_err;
    let n2 = max_rms(
        &measured_error_vectors_um(&registered(&cal.grid2_data, &cal.frame))
            .iter()
            .map(|e| e[0].hypot(e[1]))
            .collect::<Vec<f64>>(),
    );
    let fin = cal.final_accuracy();
    Summary {
        machine: cal.machine.clone(),
        seed,
        out_dir: out_dir.display().to_string(),
        fit_poses: cal.fit_data.len(),
        approach: cal.approach,
        stages: cal
            .stages
            .iter()
            .map(|s| StageSummary {
                step: s.key,
                description: s.description.clone(),
                max_um: round3(s.accuracy.max_um),
                rms_um: round3(s.accuracy.rms_um),
                measured_max_um: round3(s.accuracy.measured_max_um),
                measured_rms_um: round3(s.accuracy.measured_rms_um),
                n_targets: s.accuracy.n_targets,
                gain_vs_before: round3(before / s.accuracy.max_um),
                paper_max: s.paper,
            })
            .collect(),
        fit_full: FullFitSummary {
            model: ModelFigures::of(&cal.full.model),
            std_dev: params::std_dev_map(&cal.full.std_dev),
            sigma_um: round3(cal.full.sigma_mm * 1e3),
            fit_residual_max_um: round3(full_res.max),
            fit_residual_rms_um: round3(full_res.rms),
            fixed: cal
                .full
                .identifiability
                .fixed
                .iter()
                .map(|(k, _)| NAMES[*k])
                .collect(),
            iterations: cal.full.iterations,
        },
        fit_ls: cal.ls.as_ref().ok().map(|(m, f)| {
            let r = residual_um(m, &f.register(&fit_rows));
            LsFitSummary {
                model: ModelFigures::of(m),
                fit_residual_max_um: round3(r.max),
                fit_residual_rms_um: round3(r.rms),
            }
        }),
        ls_error: cal.ls.as_ref().err().cloned(),
        instrument_frame: cal.frame.summary(),
        grid: GridSummary {
            nx: cal.grid.lattice.nx,
            ny: cal.grid.lattice.ny,
            x0_mm: cal.grid.lattice.x0_mm,
            y0_mm: cal.grid.lattice.y0_mm,
            step_mm: cal.grid.lattice.step_mm,
            round1_node_err_max_um: round3(n1.max),
            round1_node_err_rms_um: round3(n1.rms),
            round2_node_err_max_um: round3(n2.max),
            round2_node_err_rms_um: round3(n2.rms),
            image_bytes: cal.grid2.image.len(),
            round1_noise: cal.grid.noise.clone(),
            round2_noise: cal.grid2.noise.clone(),
        },
        identification: cal.plan.report.identification.clone(),
        backlash_urad: cal.backlash.map(|b| b.lost_motion_urad.map(round3)),
        final_: FinalSummary {
            max_um: fin.map(|a| round3(a.max_um)),
            rms_um: fin.map(|a| round3(a.rms_um)),
            target_max_um: cal.goal_um[0],
            target_rms_um: cal.goal_um[1],
            met: cal.target_met(),
        },
        files: files.iter().map(|p| p.display().to_string()).collect(),
    }
}
