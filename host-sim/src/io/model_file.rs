//! `model.json`: a fitted hidden robot, as `fit` writes it and `grid`, `command`, `measure
//! --model` and `diagnose --model` read it.
//!
//! ```json
//! {
//!   "format": "hidden-robot-model", "version": 1,
//!   "machine": { "name": "paper", "digest": "1a2b3c4d" }, // optional: the machine it is of
//!   "a_mm": 149.959, "b_mm": 150.013, "c_mm": 150.033, "d_mm": 150.040,
//!   "base_a0_mm": [0.0, 0.0], "base_b0_mm": [0.0, 0.0], "encoder_offset_deg": [0.0, 0.0],
//!   "mode": { "elbow_1": "positive", "elbow_2": "negative", "assembly": "positive" },
//!   "std_dev": { "a_mm": 0.002, ... },          // optional: one standard deviation per fitted parameter
//!   "fit": { ... },                             // optional: how it was obtained (free-form)
//!   "backlash_urad": [20.0, 20.0],              // optional: lost motion, corrected by direction
//!   "diagnosed": { ... },                       // optional: diagnose's other named effects
//!   "instrument_frame": {                       // optional: the registered instrument frame
//!     "rotation_deg": 0.35, "offset_mm": [2500.0, -12.5],
//!     "std_dev": { "rotation_deg": 1e-5, ... }, "convention": "..."
//!   }
//! }
//! ```
//! The model is in the machine frame when `instrument_frame` is there (every fit writes it:
//! `calib::frame` states the convention); the readings of the same instrument set-up are mapped
//! into the machine frame by it (`reading = offset_mm + R(rotation_deg)·machine`). Files
//! without it (older fits) hold a model in the instrument's frame, and readings are used as
//! they are.
//! Angles are degrees in files (like the measurement CSV) and radians in code.

use super::atomic::write_atomic;
use super::{read_text, IoError};
use crate::machine_identity::MachineIdentity;
use kinematics_core::{Branch, FiveBar, WorkingMode};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// The value of the `format` field.
pub const FORMAT: &str = "hidden-robot-model";

#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
enum BranchName {
    Positive,
    Negative,
}

#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(deny_unknown_fields)]
struct ModeFile {
    elbow_1: BranchName,
    elbow_2: BranchName,
    assembly: BranchName,
}

/// The file's contents.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ModelFile {
    pub format: String,
    pub version: u32,
    /// The machine the model is of (`crate::machine_identity`); absent in files written before
    /// files carried it (read with a note).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub machine: Option<MachineIdentity>,
    pub a_mm: f64,
    pub b_mm: f64,
    pub c_mm: f64,
    pub d_mm: f64,
    /// A0 in the measurement frame; absent in files written before it existed (then 0, 0).
    #[serde(default)]
    pub base_a0_mm: [f64; 2],
    /// B0 relative to A0.
    pub base_b0_mm: [f64; 2],
    pub encoder_offset_deg: [f64; 2],
    mode: ModeFile,
    /// One standard deviation of each fitted parameter, by parameter name.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub std_dev: BTreeMap<String, f64>,
    /// How the model was obtained (method, data, errors); free-form.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit: Option<serde_json::Value>,
    /// Lost motion per motor (µrad), corrected by direction in every command
    /// (`calib::backlash`); absent: no backlash correction. Written by `diagnose --out-model`
    /// and the demo (random approach).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub backlash_urad: Option<[f64; 2]>,
    /// What `diagnose --out-model` named that is not a five-bar parameter nor backlash (the
    /// six-bar's effects, gear ratio, instrument rotation and scale), with its fitted values;
    /// free-form, for the record: the correction grid built with this model takes them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub diagnosed: Option<serde_json::Value>,
    /// The instrument's frame the model was registered in (`calib::frame`); absent in files
    /// written before registration existed (the model is then in the instrument's frame).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instrument_frame: Option<FrameRecord>,
}

/// The registered instrument frame as `model.json` stores it: `reading = offset_mm +
/// R(rotation_deg)·machine`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FrameRecord {
    pub rotation_deg: f64,
    pub offset_mm: [f64; 2],
    /// One standard deviation of `rotation_deg`, `offset_x_mm`, `offset_y_mm`, when estimated.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub std_dev: BTreeMap<String, f64>,
    /// The convention that defines the machine frame, in words.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub convention: Option<String>,
}

impl FrameRecord {
    /// Refuses numbers that are no frame (non-finite, an offset beyond 1e6 mm like every length
    /// of the measurement CSV, a negative standard deviation).
    pub fn check(&self) -> Result<(), IoError> {
        let bad = |what: &str| {
            Err(IoError::Invalid(format!(
                "invalid model: instrument_frame {what}"
            )))
        };
        if !self.rotation_deg.is_finite() {
            return bad(&format!(
                "rotation_deg {} is not a number",
                self.rotation_deg
            ));
        }
        if !self
            .offset_mm
            .iter()
            .all(|v| v.is_finite() && v.abs() <= 1e6)
        {
            return bad(&format!(
                "offset_mm {:?} is not a position (finite, within 1e6 mm)",
                self.offset_mm
            ));
        }
        if let Some((k, v)) = self
            .std_dev
            .iter()
            .find(|(_, v)| !(v.is_finite() && **v >= 0.0))
        {
            return bad(&format!("std_dev {k} = {v} is not a standard deviation"));
        }
        Ok(())
    }
}

fn to_name(b: Branch) -> BranchName {
    match b {
        Branch::Positive => BranchName::Positive,
        Branch::Negative => BranchName::Negative,
    }
}

fn from_name(b: BranchName) -> Branch {
    match b {
        BranchName::Positive => Branch::Positive,
        BranchName::Negative => Branch::Negative,
    }
}

impl ModelFile {
    /// Wraps a model (no standard deviations, no fit record).
    pub fn from_model(m: &FiveBar<f64>) -> Self {
        ModelFile {
            format: FORMAT.into(),
            version: 1,
            machine: None,
            a_mm: m.a_mm,
            b_mm: m.b_mm,
            c_mm: m.c_mm,
            d_mm: m.d_mm,
            base_a0_mm: m.base_a0_mm,
            base_b0_mm: m.base_b0_mm,
            encoder_offset_deg: [
                m.encoder_offset_rad[0].to_degrees(),
                m.encoder_offset_rad[1].to_degrees(),
            ],
            mode: ModeFile {
                elbow_1: to_name(m.mode.elbow_1),
                elbow_2: to_name(m.mode.elbow_2),
                assembly: to_name(m.mode.assembly),
            },
            std_dev: BTreeMap::new(),
            fit: None,
            backlash_urad: None,
            diagnosed: None,
            instrument_frame: None,
        }
    }

    /// The model, validated.
    pub fn model(&self) -> Result<FiveBar<f64>, IoError> {
        super::check_format("model", &self.format, FORMAT, self.version, 1)?;
        let m = FiveBar {
            a_mm: self.a_mm,
            b_mm: self.b_mm,
            c_mm: self.c_mm,
            d_mm: self.d_mm,
            base_a0_mm: self.base_a0_mm,
            base_b0_mm: self.base_b0_mm,
            encoder_offset_rad: [
                self.encoder_offset_deg[0].to_radians(),
                self.encoder_offset_deg[1].to_radians(),
            ],
            mode: WorkingMode {
                elbow_1: from_name(self.mode.elbow_1),
                elbow_2: from_name(self.mode.elbow_2),
                assembly: from_name(self.mode.assembly),
            },
        };
        m.validate()
            .map_err(|e| IoError::Invalid(format!("invalid model: {e}")))?;
        self.backlash()?;
        if let Some(f) = &self.instrument_frame {
            f.check()?;
        }
        Ok(m)
    }

    /// The backlash correction, validated (finite, 0..=0.01 rad).
    pub fn backlash(&self) -> Result<Option<crate::calib::backlash::Backlash>, IoError> {
        self.backlash_urad
            .map(crate::calib::backlash::Backlash::new)
            .transpose()
            .map_err(|e| IoError::Invalid(format!("invalid model: {e}")))
    }
}

/// Reads and validates a model file.
pub fn read_model(path: &Path) -> Result<FiveBar<f64>, IoError> {
    read_model_file(path)?
        .model()
        .map_err(|e| IoError::content(path, e))
}

/// Reads a model file with its standard deviations and fit record.
pub fn read_model_file(path: &Path) -> Result<ModelFile, IoError> {
    let text = read_text(path)?;
    serde_json::from_str(&text).map_err(|e| IoError::NotA {
        path: path.to_path_buf(),
        what: "model file",
        message: match not_json(&text) {
            Some(first) => format!(
                "it is not JSON (its first line of data is '{first}'{}); a model file is the model.json that `host-sim fit` writes",
                if first.contains(',') || first.contains(';') { ": a CSV table?" } else { "" }
            ),
            None => e.to_string(),
        },
    })
}

/// The first line of `text` (shortened) if the text is not a JSON object at all.
fn not_json(text: &str) -> Option<String> {
    let t = text.trim_start();
    if t.starts_with('{') {
        return None;
    }
    let first = t
        .lines()
        .find(|l| !l.trim_start().starts_with('#'))
        .or(t.lines().next())
        .unwrap_or("");
    Some(first.chars().take(60).collect())
}

/// A model file's text (the model checked first), for a command that stages it with its other
/// outputs (`super::atomic::Outputs`).
pub fn model_file_text(file: &ModelFile) -> Result<String, IoError> {
    file.model()?;
    super::json_text(file, super::KeyOrder::Declared)
}

/// Writes a model file atomically.
pub fn write_model_file(path: &Path, file: &ModelFile) -> Result<(), IoError> {
    write_atomic(path, model_file_text(file)?.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let mut m = FiveBar::<f64>::paper_nominal();
        m.a_mm = 149.959;
        m.base_b0_mm = [0.1, -0.2];
        m.base_a0_mm = [-3.0, 0.5];
        m.encoder_offset_rad = [0.001, -0.002];
        let f = ModelFile::from_model(&m);
        let text = serde_json::to_string(&f).unwrap();
        let back: ModelFile = serde_json::from_str(&text).unwrap();
        let m2 = back.model().unwrap();
        assert_eq!(m2.a_mm, m.a_mm);
        assert_eq!(m2.base_a0_mm, m.base_a0_mm);
        assert!((m2.encoder_offset_rad[1] - m.encoder_offset_rad[1]).abs() < 1e-15);
        assert_eq!(m2.mode, m.mode);
    }

    #[test]
    fn rejects_bad_models() {
        let mut f = ModelFile::from_model(&FiveBar::paper_nominal());
        f.b_mm = -1.0;
        assert!(f.model().is_err());
        let mut f = ModelFile::from_model(&FiveBar::paper_nominal());
        f.format = "something".into();
        assert!(f.model().is_err());
        let text =
            serde_json::to_string(&ModelFile::from_model(&FiveBar::paper_nominal())).unwrap();
        let typo = text.replace("\"a_mm\"", "\"a_m\"");
        assert!(serde_json::from_str::<ModelFile>(&typo).is_err());
        let mut f = ModelFile::from_model(&FiveBar::paper_nominal());
        f.instrument_frame = Some(FrameRecord {
            rotation_deg: f64::NAN,
            offset_mm: [0.0, 0.0],
            std_dev: BTreeMap::new(),
            convention: None,
        });
        assert!(f
            .model()
            .unwrap_err()
            .to_string()
            .contains("instrument_frame"));
    }

    #[test]
    fn the_frame_is_optional_and_round_trips() {
        let old = serde_json::to_string(&ModelFile::from_model(&FiveBar::paper_nominal())).unwrap();
        assert!(!old.contains("instrument_frame"));
        let back: ModelFile = serde_json::from_str(&old).unwrap();
        assert_eq!(
            crate::calib::frame::InstrumentFrame::of_model_file(&back).unwrap(),
            crate::calib::frame::InstrumentFrame::IDENTITY
        );
        let mut f = ModelFile::from_model(&FiveBar::paper_nominal());
        f.instrument_frame = Some(FrameRecord {
            rotation_deg: 90.5,
            offset_mm: [2500.0, -1200.0],
            std_dev: BTreeMap::new(),
            convention: None,
        });
        let back: ModelFile = serde_json::from_str(&serde_json::to_string(&f).unwrap()).unwrap();
        assert_eq!(back, f);
        let p = crate::calib::frame::InstrumentFrame::of_model_file(&back)
            .unwrap()
            .to_instrument_mm([0.0, 0.0]);
        assert_eq!(p, [2500.0, -1200.0]);
    }
}
