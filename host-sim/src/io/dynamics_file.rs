//! `dynamics.json`: the hidden robot's identified dynamic parameters, as `identify` writes them
//! and `simulate --dynamics` and `grid --dynamics` read them (`kinematics_core::dynamics`).
//!
//! ```json
//! {
//!   "format": "hidden-robot-dynamics", "version": 1,
//!   "machine": { "name": "paper", "digest": "1a2b3c4d" }, // optional: the machine they are of
//!   "motor_inertia_kg_m2": [0.0037, 0.0037], "tool_mass_kg": 0.165,
//!   "distal_inertia_kg_m2": [0.0, 0.0],
//!   "viscous_nm_s_per_rad": [0.02, 0.02], "coulomb_nm": [0.05, 0.05],
//!   "coulomb_speed_rad_s": 0.01,
//!   "std_dev": { "tool_mass_kg": 0.0002, ... },   // optional: one standard deviation each
//!   "identification": { ... }                      // optional: how it was obtained (free-form)
//! }
//! ```
//! Every number is validated on reading (`FiveBarDynamics::validate`: inertias and the Coulomb
//! speed positive, masses and friction not negative, all finite).

use super::atomic::write_atomic;
use super::{read_text, IoError};
use crate::machine_identity::MachineIdentity;
use kinematics_core::FiveBarDynamics;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// The value of the `format` field.
pub const FORMAT: &str = "hidden-robot-dynamics";

/// The file's contents.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DynamicsFile {
    pub format: String,
    pub version: u32,
    /// The machine the parameters are of (`crate::machine_identity`); absent in files written
    /// before files carried it (read with a note).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub machine: Option<MachineIdentity>,
    pub motor_inertia_kg_m2: [f64; 2],
    pub tool_mass_kg: f64,
    pub distal_inertia_kg_m2: [f64; 2],
    pub viscous_nm_s_per_rad: [f64; 2],
    pub coulomb_nm: [f64; 2],
    pub coulomb_speed_rad_s: f64,
    /// One standard deviation of each identified parameter, by name.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub std_dev: BTreeMap<String, f64>,
    /// How the parameters were obtained; free-form.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub identification: Option<serde_json::Value>,
}

impl DynamicsFile {
    /// Wraps parameters (no standard deviations, no record).
    pub fn from_dynamics(d: &FiveBarDynamics<f64>) -> Self {
        DynamicsFile {
            format: FORMAT.into(),
            version: 1,
            machine: None,
            motor_inertia_kg_m2: d.motor_inertia_kg_m2,
            tool_mass_kg: d.tool_mass_kg,
            distal_inertia_kg_m2: d.distal_inertia_kg_m2,
            viscous_nm_s_per_rad: d.viscous_nm_s_per_rad,
            coulomb_nm: d.coulomb_nm,
            coulomb_speed_rad_s: d.coulomb_speed_rad_s,
            std_dev: BTreeMap::new(),
            identification: None,
        }
    }

    /// The parameters, validated.
    pub fn dynamics(&self) -> Result<FiveBarDynamics<f64>, IoError> {
        super::check_format("dynamics", &self.format, FORMAT, self.version, 1)?;
        let d = FiveBarDynamics {
            motor_inertia_kg_m2: self.motor_inertia_kg_m2,
            tool_mass_kg: self.tool_mass_kg,
            distal_inertia_kg_m2: self.distal_inertia_kg_m2,
            viscous_nm_s_per_rad: self.viscous_nm_s_per_rad,
            coulomb_nm: self.coulomb_nm,
            coulomb_speed_rad_s: self.coulomb_speed_rad_s,
        };
        d.validate()
            .map_err(|e| IoError::Invalid(format!("invalid dynamics: {e}")))?;
        Ok(d)
    }
}

/// Reads and validates a dynamics file.
pub fn read_dynamics(path: &Path) -> Result<FiveBarDynamics<f64>, IoError> {
    read_dynamics_file(path)?
        .dynamics()
        .map_err(|e| IoError::content(path, e))
}

/// Reads a dynamics file with its machine, standard deviations and record.
pub fn read_dynamics_file(path: &Path) -> Result<DynamicsFile, IoError> {
    serde_json::from_str(&read_text(path)?).map_err(|e| IoError::NotA {
        path: path.to_path_buf(),
        what: "dynamics file",
        message: e.to_string(),
    })
}

/// Writes a dynamics file atomically (refused if its parameters are invalid).
pub fn write_dynamics_file(path: &Path, file: &DynamicsFile) -> Result<(), IoError> {
    file.dynamics()?;
    write_atomic(
        path,
        super::json_text(file, super::KeyOrder::Declared)?.as_bytes(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> FiveBarDynamics<f64> {
        FiveBarDynamics {
            motor_inertia_kg_m2: [3.7e-3, 3.6e-3],
            tool_mass_kg: 0.165,
            distal_inertia_kg_m2: [0.0, -1e-4],
            viscous_nm_s_per_rad: [0.02, 0.021],
            coulomb_nm: [0.05, 0.049],
            coulomb_speed_rad_s: 0.01,
        }
    }

    #[test]
    fn round_trip_and_refusals() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("d.json");
        let mut f = DynamicsFile::from_dynamics(&params());
        f.std_dev.insert("tool_mass_kg".into(), 2e-4);
        write_dynamics_file(&p, &f).unwrap();
        assert_eq!(read_dynamics(&p).unwrap(), params());
        // Invalid values are neither written nor read.
        let bad = DynamicsFile {
            coulomb_nm: [-0.1, 0.0],
            ..f.clone()
        };
        let q = dir.path().join("bad.json");
        assert!(write_dynamics_file(&q, &bad).is_err());
        assert!(!q.exists(), "nothing half-written");
        std::fs::write(&q, serde_json::to_string(&bad).unwrap()).unwrap();
        assert!(read_dynamics(&q)
            .unwrap_err()
            .to_string()
            .contains("invalid dynamics"));
        std::fs::write(&q, r#"{"format": "hidden-robot-model"}"#).unwrap();
        assert!(read_dynamics(&q).is_err());
        std::fs::write(
            &q,
            serde_json::to_string(&DynamicsFile { version: 2, ..f }).unwrap(),
        )
        .unwrap();
        assert!(read_dynamics(&q)
            .unwrap_err()
            .to_string()
            .contains("version 2"));
    }
}
