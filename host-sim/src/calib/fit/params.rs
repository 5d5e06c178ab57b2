//! The ten parameters of the five-bar as one vector, the position residual and its Jacobian.
//!
//! Why one file: `identifiability` and `levenberg_marquardt` must agree on the order, the names
//! and the residual. Residual of point i: `FK(θi; p) − measured_i` (mm), two rows per point
//! ([`PositionResiduals`], the problem the one LM of `crate::numeric` solves). Jacobian by
//! central differences (steps 1e-6 mm / 1e-8 rad): truncation error O(h²) ≈ 1e-12 relative,
//! rounding ≈ 1e-10 relative, far below the rank tolerance of `identifiability`.

use crate::io::measurement_csv::Measurement;
use crate::numeric::{finite_difference, NumericError, Residuals};
use kinematics_core::FiveBar;
use nalgebra::{DMatrix, DVector};
use std::collections::BTreeMap;

/// Number of model parameters.
pub const N_PARAMS: usize = 10;

/// Parameter names, in vector order (code units: mm and rad).
pub const NAMES: [&str; N_PARAMS] = [
    "a_mm",
    "b_mm",
    "c_mm",
    "d_mm",
    "base_b0_x_mm",
    "base_b0_y_mm",
    "encoder_offset_1_rad",
    "encoder_offset_2_rad",
    "base_a0_x_mm",
    "base_a0_y_mm",
];

/// A standard deviation as files and reports name it: angles in degrees (`encoder_offset_1_deg`),
/// everything else as [`NAMES`] has it (`a_mm`). The one naming of std devs (`model.json`'s
/// `std_dev`, `fit`'s and `demo`'s JSON).
pub fn std_dev_entry(k: usize, v: f64) -> (String, f64) {
    match NAMES[k].strip_suffix("_rad") {
        Some(stem) => (format!("{stem}_deg"), v.to_degrees()),
        None => (NAMES[k].to_string(), v),
    }
}

/// Every known standard deviation, named by [`std_dev_entry`].
pub fn std_dev_map(std_dev: &[Option<f64>; N_PARAMS]) -> BTreeMap<String, f64> {
    std_dev
        .iter()
        .enumerate()
        .filter_map(|(k, sd)| sd.map(|v| std_dev_entry(k, v)))
        .collect()
}

/// Finite-difference step per parameter.
pub const STEP: [f64; N_PARAMS] = [1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-8, 1e-8, 1e-6, 1e-6];

pub fn to_vector(m: &FiveBar<f64>) -> [f64; N_PARAMS] {
    [
        m.a_mm,
        m.b_mm,
        m.c_mm,
        m.d_mm,
        m.base_b0_mm[0],
        m.base_b0_mm[1],
        m.encoder_offset_rad[0],
        m.encoder_offset_rad[1],
        m.base_a0_mm[0],
        m.base_a0_mm[1],
    ]
}

/// The model with parameters `p` (working mode from `like`).
pub fn from_vector(p: &[f64; N_PARAMS], like: &FiveBar<f64>) -> FiveBar<f64> {
    FiveBar {
        a_mm: p[0],
        b_mm: p[1],
        c_mm: p[2],
        d_mm: p[3],
        base_a0_mm: [p[8], p[9]],
        base_b0_mm: [p[4], p[5]],
        encoder_offset_rad: [p[6], p[7]],
        mode: like.mode,
    }
}

/// Stacked residuals `FK(θi) − measured_i` (mm); `None` if some pose is unreachable.
pub fn residuals_mm(m: &FiveBar<f64>, data: &[Measurement]) -> Option<DVector<f64>> {
    let mut r = DVector::zeros(2 * data.len());
    for (i, d) in data.iter().enumerate() {
        let c = m.forward(d.theta_rad(), 0.0).ok()?;
        r[2 * i] = c[0] - d.measured_mm[0];
        r[2 * i + 1] = c[1] - d.measured_mm[1];
    }
    Some(r)
}

/// The position residual of a data set as a least-squares problem over the ten parameters;
/// invalid models (non-finite numbers, non-positive links) and unreachable poses have none.
pub struct PositionResiduals<'a> {
    pub data: &'a [Measurement],
    /// Supplies the working mode.
    pub like: FiveBar<f64>,
}

impl Residuals for PositionResiduals<'_> {
    fn n_params(&self) -> usize {
        N_PARAMS
    }

    fn residuals(&self, p: &[f64]) -> Option<DVector<f64>> {
        let p: &[f64; N_PARAMS] = p.try_into().ok()?;
        let m = from_vector(p, &self.like);
        m.validate().ok()?;
        residuals_mm(&m, self.data)
    }

    fn fd_step(&self, k: usize) -> f64 {
        STEP[k]
    }
}

/// `∂r/∂p` (2N x 10) at `m`, central differences.
pub fn jacobian(m: &FiveBar<f64>, data: &[Measurement]) -> Result<DMatrix<f64>, NumericError> {
    let all: Vec<usize> = (0..N_PARAMS).collect();
    finite_difference::jacobian(&PositionResiduals { data, like: *m }, &to_vector(m), &all)
}
