//! The demo's files: the plan's lists, every measurement CSV (instrument readings as
//! measured), the models with their registered frames, the grid image and table, and the
//! error-vector plots (in the machine frame), staged into the command's outputs and renamed
//! together.

use super::{Calibrated, Stage};
use crate::calib::fit::params;
use crate::calib::grid;
use crate::calib::measure::{measured_error_vectors_um, registered, rows, true_error_vectors_um};
use crate::calib::plan::list_rows;
use crate::io::atomic::Outputs;
use crate::io::measurement_csv::format_measurements_of;
use crate::io::model_file::{model_file_text, ModelFile};
use crate::io::plot::{vector_plot_png, VectorField};
use crate::io::targets_csv::format_target_list;
use crate::io::IoError;
use std::path::{Path, PathBuf};

/// The names of the files [`write_outputs`] writes, relative to the output directory.
pub const FILES: [&str; 21] = [
    "plan_identify.csv",
    "plan_grid.csv",
    "plan_verify.csv",
    "plan_repeat.csv",
    "fit_measurements.csv",
    "grid_measurements.csv",
    "grid_measurements_round2.csv",
    "verify_nominal.csv",
    "verify_ls.csv",
    "verify_full.csv",
    "verify_full_grid.csv",
    "verify_full_grid2.csv",
    "model.json",
    "model_ls.json",
    "grid.bin",
    "grid.csv",
    "errors_fit.png",
    "errors_grid.png",
    "errors_final.png",
    "grid_nodes.png",
    "summary.json",
];

fn stage<'a>(cal: &'a Calibrated, key: &str) -> Result<&'a Stage, IoError> {
    cal.stages
        .iter()
        .find(|s| s.key == key)
        .ok_or_else(|| IoError::Invalid(format!("internal: no stage '{key}'")))
}

/// Stages every output into `dir` in `out` (renamed into place with the command's other files
/// by `out.commit()`) and returns the paths, in [`FILES`] order but for `summary.json`, which
/// the caller stages last from [`super::summary`].
pub fn write_outputs(
    cal: &Calibrated,
    dir: &Path,
    out: &mut Outputs,
) -> Result<Vec<PathBuf>, IoError> {
    let p = |name: &str| dir.join(name);
    let mut files: Vec<(String, Vec<u8>)> = Vec::new();
    let mut text = |name: &str, bytes: &[u8]| -> Result<(), IoError> {
        files.push((name.to_string(), bytes.to_vec()));
        Ok(())
    };
    for (name, list) in cal.plan.lists() {
        text(
            &format!("plan_{name}.csv"),
            format_target_list(&list_rows(list)).as_bytes(),
        )?;
    }
    text(
        "fit_measurements.csv",
        format_measurements_of(&rows(&cal.fit_data), &cal.identity).as_bytes(),
    )?;
    text(
        "grid_measurements.csv",
        format_measurements_of(&rows(&cal.grid_data), &cal.identity).as_bytes(),
    )?;
    text(
        "grid_measurements_round2.csv",
        format_measurements_of(&rows(&cal.grid2_data), &cal.identity).as_bytes(),
    )?;
    for s in &cal.stages {
        text(
            &format!("verify_{}.csv", s.key.replace('+', "_")),
            format_measurements_of(&rows(&s.landed), &cal.identity).as_bytes(),
        )?;
    }
    // The grid to flash: round 2. (Round 1 is in the round-2 data: nodes commanded through it.)
    text("grid.bin", &cal.grid2.image)?;
    text("grid.csv", grid::format_csv(&cal.grid2.nodes).as_bytes())?;

    let mut full_file = ModelFile::from_model(&cal.full.model);
    full_file.std_dev = params::std_dev_map(&cal.full.std_dev);
    full_file.fit = Some(
        serde_json::json!({ "method": "full", "source": "host-sim demo", "n_points": cal.fit_data.len() }),
    );
    full_file.backlash_urad = cal.backlash.map(|b| b.lost_motion_urad);
    full_file.instrument_frame = Some(cal.frame.record());
    full_file.machine = Some(cal.identity.clone());
    files.push((
        "model.json".into(),
        model_file_text(&full_file)?.into_bytes(),
    ));
    if let Ok((ls_model, ls_frame)) = &cal.ls {
        let mut ls_file = ModelFile::from_model(ls_model);
        ls_file.machine = Some(cal.identity.clone());
        ls_file.fit = Some(
            serde_json::json!({ "method": "ls", "source": "host-sim demo", "n_points": cal.fit_data.len() }),
        );
        ls_file.instrument_frame = Some(ls_frame.record());
        files.push((
            "model_ls.json".into(),
            model_file_text(&ls_file)?.into_bytes(),
        ));
    }

    // Plots: the same fresh targets for every stage, in the machine frame; fields in one plot
    // share one scale.
    let (nominal, full) = (stage(cal, "nominal")?, stage(cal, "full")?);
    let ls = stage(cal, "ls").ok();
    let (gridded, gridded2) = (stage(cal, "full+grid")?, stage(cal, "full+grid2")?);
    let base: Vec<[f64; 2]> = gridded
        .landed_in_machine_frame()
        .iter()
        .map(|l| l.row.target_mm.unwrap_or(l.true_mm))
        .collect();
    let errors = |s: &Stage| true_error_vectors_um(&s.landed_in_machine_frame());
    let (e_nom, e_full, e_grid, e_grid2) = (
        errors(nominal),
        errors(full),
        errors(gridded),
        errors(gridded2),
    );
    let e_ls = ls.map(errors);
    let mut fit_fields = vec![VectorField::new("nominal model", &base, &e_nom)];
    if let Some(e) = &e_ls {
        fit_fields.push(VectorField::new("paper's ls fit", &base, e));
    }
    fit_fields.push(VectorField::new("full fit", &base, &e_full));
    files.push((
        "errors_fit.png".into(),
        vector_plot_png(
            "step 2, fit: true − target at fresh targets",
            &fit_fields,
            &[],
        )?,
    ));
    files.push((
        "errors_grid.png".into(),
        vector_plot_png(
            "step 3, grid: true − target at fresh targets",
            &[
                VectorField::new("full fit", &base, &e_full),
                VectorField::new("full fit + grid (1 round)", &base, &e_grid),
                VectorField::new("full fit + grid (2 rounds)", &base, &e_grid2),
            ],
            &[],
        )?,
    ));
    files.push((
        "errors_final.png".into(),
        vector_plot_png(
            "after calibration: true − target at fresh targets",
            &[
                VectorField::new("full fit + grid (1 round)", &base, &e_grid),
                VectorField::new("full fit + grid (2 rounds)", &base, &e_grid2),
            ],
            &[],
        )?,
    ));
    let node_base: Vec<[f64; 2]> = cal.grid.nodes.iter().map(|n| n.target_mm).collect();
    let (node_err1, node_err2) = (
        measured_error_vectors_um(&registered(&cal.grid_data, &cal.frame)),
        measured_error_vectors_um(&registered(&cal.grid2_data, &cal.frame)),
    );
    files.push((
        "grid_nodes.png".into(),
        vector_plot_png(
            "grid nodes: measured − target",
            &[
                VectorField::new("round 1 (full fit)", &node_base, &node_err1),
                VectorField::new("round 2 (through the round-1 grid)", &node_base, &node_err2),
            ],
            &[],
        )?,
    ));
    let mut written = Vec::with_capacity(files.len());
    for (name, bytes) in &files {
        out.bytes(&p(name), bytes)?;
        written.push(p(name));
    }
    Ok(written)
}
