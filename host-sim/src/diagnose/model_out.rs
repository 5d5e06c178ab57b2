//! "Add it to the model": the effects a diagnosis named, put into the model the tools and the
//! controller use (`diagnose --out-model M.json`).
//!
//! What goes where, and why:
//! * `link_lengths`, `encoder_offset`, `base_offset`: the hidden robot's own parameters, folded
//!   into the five-bar (a, b, c, d; the encoder offsets; B0);
//! * `frame`'s offset: the model's A0 in the measurement frame (B0 is relative to A0, so the
//!   whole machine moves with it, as `fit`'s free A0 does);
//! * `backlash`: the lost motion per motor (`backlash_urad`), corrected by direction in every
//!   command (`calib::backlash`: `command` and the measurement path add dir·β/2; `grid` builds
//!   from link angles, so the grid is free of it);
//! * configuration-dependent effects (`link_stretch`, `parallelogram_mismatch`, `gear_ratio`)
//!   and the instrument's rotation and scale: no five-bar parameter holds them; they are written
//!   under `diagnosed` with their fitted values (for the record), and the correction grid built
//!   on this model from measurements at the nodes takes them out (it corrects any smooth error;
//!   they are all smooth over the workspace).
//!
//! Every value is the final model's joint fit (`Report::final_params`).

use super::report::Report;
use super::DiagnoseError;
use crate::io::model_file::ModelFile;
use kinematics_core::FiveBar;
use std::collections::BTreeMap;

/// The extended model of a diagnosis (see the module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct ExtendedModel {
    pub model: FiveBar<f64>,
    /// Lost motion per motor (µrad, ≥ 0), when `backlash` was named.
    pub backlash_urad: Option<[f64; 2]>,
    /// Named effects not folded into the five-bar nor the backlash, with their parameters
    /// (value, one standard deviation).
    pub for_the_grid: BTreeMap<String, BTreeMap<String, [f64; 2]>>,
}

/// Folds the report's named effects into `base` (the model the diagnosis ran against).
pub fn extended_model(
    base: &FiveBar<f64>,
    report: &Report,
) -> Result<ExtendedModel, DiagnoseError> {
    let value = |name: &str| -> Result<f64, DiagnoseError> {
        report
            .final_params
            .get(name)
            .map(|p| p.value)
            .filter(|v| v.is_finite())
            .ok_or_else(|| {
                DiagnoseError::Invalid(format!("the report has no finite value of {name}"))
            })
    };
    let mut m = *base;
    let mut backlash_urad = None;
    let mut for_the_grid = BTreeMap::new();
    for step in &report.steps {
        match step.effect.as_str() {
            "link_lengths" => {
                m.a_mm += value("da_um")? * 1e-3;
                m.b_mm += value("db_um")? * 1e-3;
                m.c_mm += value("dc_um")? * 1e-3;
                m.d_mm += value("dd_um")? * 1e-3;
            }
            "encoder_offset" => {
                m.encoder_offset_rad[0] += value("dtheta1_urad")? * 1e-6;
                m.encoder_offset_rad[1] += value("dtheta2_urad")? * 1e-6;
            }
            "base_offset" => {
                m.base_b0_mm[0] += value("b0x_um")? * 1e-3;
                m.base_b0_mm[1] += value("b0y_um")? * 1e-3;
            }
            "backlash" => {
                backlash_urad = Some([value("beta1_urad")?.max(0.0), value("beta2_urad")?.max(0.0)])
            }
            other => {
                if other == "frame" {
                    m.base_a0_mm[0] += value("tx_um")? * 1e-3;
                    m.base_a0_mm[1] += value("ty_um")? * 1e-3;
                }
                let params = step
                    .params
                    .keys()
                    .filter(|k| other != "frame" || k.as_str() == "rot_urad")
                    .filter_map(|k| {
                        report
                            .final_params
                            .get(k)
                            .map(|p| (k.clone(), [p.value, p.std_dev]))
                    })
                    .collect::<BTreeMap<_, _>>();
                if !params.is_empty() {
                    for_the_grid.insert(other.to_string(), params);
                }
            }
        }
    }
    m.validate().map_err(|e| {
        DiagnoseError::Invalid(format!("the extended model is not a five-bar: {e}"))
    })?;
    Ok(ExtendedModel {
        model: m,
        backlash_urad,
        for_the_grid,
    })
}

impl ExtendedModel {
    /// The model file (`io::model_file`) of this model.
    pub fn file(&self, source: &str) -> ModelFile {
        let mut f = ModelFile::from_model(&self.model);
        f.backlash_urad = self.backlash_urad;
        f.fit = Some(serde_json::json!({ "method": "diagnose", "source": source }));
        if !self.for_the_grid.is_empty() {
            f.diagnosed = Some(serde_json::json!({
                "note": "named by diagnose, not a five-bar parameter: the correction grid built on this model takes them",
                "effects": self.for_the_grid,
            }));
        }
        f
    }
}
